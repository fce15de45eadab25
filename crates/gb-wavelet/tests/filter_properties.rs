//! Orthogonality, perfect-reconstruction and vanishing-moment conditions of
//! every tabulated filter bank.

use gb_wavelet::{Family, Wavelet};

/// `Σ_k (k−c)^p f[k]` relative to `Σ_k |k−c|^p |f[k]|`, `c` the centre.
fn relative_moment(f: &[f64], p: i32) -> f64 {
    let c = (f.len() as f64 - 1.0) / 2.0;
    let (m, s) = f.iter().enumerate().fold((0.0, 0.0), |(m, s), (k, v)| {
        let t = (k as f64 - c).powi(p);
        (m + t * v, s + (t * v).abs())
    });
    m / s
}

#[test]
fn orthogonal_filters_are_orthonormal() {
    for name in Wavelet::available() {
        let w = Wavelet::new(name).expect("wavelet");
        if !w.is_orthogonal() {
            continue;
        }
        let h = w.dec_lo();
        let f = h.len();
        for m in 0..f / 2 {
            let ip: f64 = (0..f - 2 * m).map(|k| h[k] * h[k + 2 * m]).sum();
            let expect = if m == 0 { 1.0 } else { 0.0 };
            assert!(
                (ip - expect).abs() < 1e-14,
                "{name}: <h, h(·−{})> = {ip}",
                2 * m
            );
        }
        let s: f64 = h.iter().sum();
        assert!((s - 2f64.sqrt()).abs() < 1e-14, "{name}: Σh = {s}");
        // high-pass orthogonal to low-pass at every even shift
        let g = w.dec_hi();
        for m in -(f as isize / 2)..=(f as isize / 2) {
            let ip: f64 = (0..f as isize)
                .filter(|k| (0..f as isize).contains(&(k + 2 * m)))
                .map(|k| h[k as usize] * g[(k + 2 * m) as usize])
                .sum();
            assert!(ip.abs() < 1e-14, "{name}: <h, g(·−{})> = {ip}", 2 * m);
        }
    }
}

#[test]
fn biorthogonal_filters_reconstruct_perfectly() {
    for name in Wavelet::available() {
        let w = Wavelet::new(name).expect("wavelet");
        let (h, r) = (w.dec_lo(), w.rec_lo());
        let f = h.len();
        // P(z) = H̃(z)H(z): odd coefficients are δ_{n, F−1}
        for n in (1..2 * f - 1).step_by(2) {
            let p: f64 = (0..f)
                .filter(|&k| n >= k && n - k < f)
                .map(|k| h[k] * r[n - k])
                .sum();
            let expect = if n == f - 1 { 1.0 } else { 0.0 };
            assert!((p - expect).abs() < 1e-14, "{name}: p[{n}] = {p}");
        }
    }
}

#[test]
fn analysis_wavelets_have_their_vanishing_moments() {
    for name in Wavelet::available() {
        let w = Wavelet::new(name).expect("wavelet");
        let n = w.vanishing_moments_psi();
        assert!(n >= 1, "{name}");
        // PyWavelets' count for rbioNr.Nd refers to the synthesis wavelet
        // (the analysis wavelet of biorNr.Nd)
        let filter = if w.family() == Family::ReverseBiorthogonal {
            w.rec_hi()
        } else {
            w.dec_hi()
        };
        for p in 0..n as i32 {
            let m = relative_moment(filter, p);
            assert!(m.abs() < 1e-9, "{name}: moment {p} of dec_hi = {m}");
        }
        // and the next moment does not vanish (the count is exact) for the
        // orthogonal families up to 20 moments (beyond, the relative size of
        // the first non-vanishing moment drops below what this measure resolves)
        if w.is_orthogonal() && n <= 20 {
            let m = relative_moment(w.dec_hi(), n as i32);
            assert!(m.abs() > 1e-8, "{name}: moment {n} = {m} vanishes too");
        }
    }
}
