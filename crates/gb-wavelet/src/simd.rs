//! AVX2 + FMA kernels for the interior of the transforms (x86-64 only, chosen
//! at run time). They compute exactly the sums of the portable kernels in
//! `transform.rs`, with fused multiply-adds.

#![allow(clippy::needless_range_loop)] // kernels index several arrays in step

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

/// Largest half filter length the AVX2 kernels accept (coif17 has `H = 51`).
pub(crate) const MAX_HALF: usize = 64;
/// Outputs deinterleaved at a time by the analysis kernel.
const CHUNK: usize = 64;

/// `true` if the running CPU has AVX2 and FMA.
#[inline]
pub(crate) fn available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Analysis interior: `a[i] = Σ_j lo[j] x[2i+j]`, `d[i] = Σ_j hi[j] x[2i+j]`
/// for the first `8⌊len/8⌋` outputs; returns how many were computed.
///
/// # Safety
/// The CPU must support AVX2 and FMA; `lo.len() = hi.len() = 2H` with
/// `1 ≤ H ≤ MAX_HALF`, and `x.len() ≥ 2(a.len()−1) + 2H`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub(crate) unsafe fn analysis(
    x: &[f64],
    lo: &[f64],
    hi: &[f64],
    a: &mut [f64],
    d: &mut [f64],
) -> usize {
    let h = lo.len() / 2;
    debug_assert!((1..=MAX_HALF).contains(&h) && hi.len() == 2 * h && d.len() == a.len());
    let mut coef = [[0.0f64; MAX_HALF]; 4];
    for t in 0..h {
        coef[0][t] = lo[2 * t];
        coef[1][t] = lo[2 * t + 1];
        coef[2][t] = hi[2 * t];
        coef[3][t] = hi[2 * t + 1];
    }
    let n = a.len() - a.len() % 8;
    let mut xe = [0.0f64; CHUNK + MAX_HALF + 4];
    let mut xo = [0.0f64; CHUNK + MAX_HALF + 4];
    let mut c0 = 0;
    while c0 < n {
        let len = CHUNK.min(n - c0);
        // deinterleave x[2c0 .. 2(c0+len+h−1)) into even / odd samples
        let span = len + h - 1;
        let src = &x[2 * c0..2 * (c0 + span)];
        let quads = span / 4;
        for k in 0..quads {
            let p = src.as_ptr().add(8 * k);
            let v0 = _mm256_loadu_pd(p);
            let v1 = _mm256_loadu_pd(p.add(4));
            let lo_v = _mm256_unpacklo_pd(v0, v1); // x0 x4 x2 x6
            let hi_v = _mm256_unpackhi_pd(v0, v1); // x1 x5 x3 x7
            _mm256_storeu_pd(
                xe.as_mut_ptr().add(4 * k),
                _mm256_permute4x64_pd(lo_v, 0b11_01_10_00),
            );
            _mm256_storeu_pd(
                xo.as_mut_ptr().add(4 * k),
                _mm256_permute4x64_pd(hi_v, 0b11_01_10_00),
            );
        }
        for k in 4 * quads..span {
            xe[k] = src[2 * k];
            xo[k] = src[2 * k + 1];
        }
        let mut b = 0;
        while b < len {
            let mut acc = [_mm256_setzero_pd(); 8];
            let pe = xe.as_ptr().add(b);
            let po = xo.as_ptr().add(b);
            for t in 0..h {
                let le = _mm256_set1_pd(coef[0][t]);
                let lo_c = _mm256_set1_pd(coef[1][t]);
                let he = _mm256_set1_pd(coef[2][t]);
                let ho = _mm256_set1_pd(coef[3][t]);
                let e0 = _mm256_loadu_pd(pe.add(t));
                let e1 = _mm256_loadu_pd(pe.add(t + 4));
                let o0 = _mm256_loadu_pd(po.add(t));
                let o1 = _mm256_loadu_pd(po.add(t + 4));
                acc[0] = _mm256_fmadd_pd(le, e0, acc[0]);
                acc[1] = _mm256_fmadd_pd(le, e1, acc[1]);
                acc[2] = _mm256_fmadd_pd(lo_c, o0, acc[2]);
                acc[3] = _mm256_fmadd_pd(lo_c, o1, acc[3]);
                acc[4] = _mm256_fmadd_pd(he, e0, acc[4]);
                acc[5] = _mm256_fmadd_pd(he, e1, acc[5]);
                acc[6] = _mm256_fmadd_pd(ho, o0, acc[6]);
                acc[7] = _mm256_fmadd_pd(ho, o1, acc[7]);
            }
            let i = c0 + b;
            let pa = a[i..i + 8].as_mut_ptr();
            let pd = d[i..i + 8].as_mut_ptr();
            _mm256_storeu_pd(pa, _mm256_add_pd(acc[0], acc[2]));
            _mm256_storeu_pd(pa.add(4), _mm256_add_pd(acc[1], acc[3]));
            _mm256_storeu_pd(pd, _mm256_add_pd(acc[4], acc[6]));
            _mm256_storeu_pd(pd.add(4), _mm256_add_pd(acc[5], acc[7]));
            b += 8;
        }
        c0 += len;
    }
    n
}

/// Synthesis pairs: `out[2u] = Σ_t a[u+t] le[t] + d[u+t] he[t]`,
/// `out[2u+1] = Σ_t a[u+t] lo[t] + d[u+t] ho[t]` for the first `8⌊pairs/8⌋`
/// pairs; returns how many pairs were computed.
///
/// # Safety
/// The CPU must support AVX2 and FMA; the four polyphase filters have length
/// `H ≥ 1`, and `a.len(), d.len() ≥ out.len()/2 + H − 1`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub(crate) unsafe fn synthesis_pairs(
    a: &[f64],
    d: &[f64],
    poly: &[Vec<f64>; 4],
    out: &mut [f64],
) -> usize {
    let h = poly[0].len();
    let pairs = out.len() / 2;
    let n = pairs - pairs % 8;
    let mut u = 0;
    debug_assert!(n == 0 || (a.len() >= n + h - 1 && d.len() >= n + h - 1));
    while u < n {
        let wa = a[u..u + h + 7].as_ptr();
        let wd = d[u..u + h + 7].as_ptr();
        let mut acc = [_mm256_setzero_pd(); 8];
        for t in 0..h {
            let le = _mm256_set1_pd(poly[0][t]);
            let lo = _mm256_set1_pd(poly[1][t]);
            let he = _mm256_set1_pd(poly[2][t]);
            let ho = _mm256_set1_pd(poly[3][t]);
            let a0 = _mm256_loadu_pd(wa.add(t));
            let a1 = _mm256_loadu_pd(wa.add(t + 4));
            let d0 = _mm256_loadu_pd(wd.add(t));
            let d1 = _mm256_loadu_pd(wd.add(t + 4));
            acc[0] = _mm256_fmadd_pd(le, a0, acc[0]);
            acc[1] = _mm256_fmadd_pd(le, a1, acc[1]);
            acc[2] = _mm256_fmadd_pd(he, d0, acc[2]);
            acc[3] = _mm256_fmadd_pd(he, d1, acc[3]);
            acc[4] = _mm256_fmadd_pd(lo, a0, acc[4]);
            acc[5] = _mm256_fmadd_pd(lo, a1, acc[5]);
            acc[6] = _mm256_fmadd_pd(ho, d0, acc[6]);
            acc[7] = _mm256_fmadd_pd(ho, d1, acc[7]);
        }
        let even0 = _mm256_add_pd(acc[0], acc[2]);
        let even1 = _mm256_add_pd(acc[1], acc[3]);
        let odd0 = _mm256_add_pd(acc[4], acc[6]);
        let odd1 = _mm256_add_pd(acc[5], acc[7]);
        let po = out[2 * u..2 * u + 16].as_mut_ptr();
        for (k, (ev, od)) in [(even0, odd0), (even1, odd1)].into_iter().enumerate() {
            let l = _mm256_unpacklo_pd(ev, od); // e0 o0 e2 o2
            let r = _mm256_unpackhi_pd(ev, od); // e1 o1 e3 o3
            _mm256_storeu_pd(po.add(8 * k), _mm256_permute2f128_pd(l, r, 0x20));
            _mm256_storeu_pd(po.add(8 * k + 4), _mm256_permute2f128_pd(l, r, 0x31));
        }
        u += 8;
    }
    n
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use crate::{Mode, Wavelet};

    /// The AVX2 kernels agree with the portable ones.
    #[test]
    fn avx2_matches_portable() {
        if !super::available() {
            return;
        }
        let x: Vec<f64> = (0..203)
            .map(|i| ((i * 37 % 101) as f64 - 50.0) / 7.0)
            .collect();
        for name in ["haar", "db4", "sym8", "coif5", "db20", "coif17", "bior4.4"] {
            let w = Wavelet::new(name).expect("wavelet");
            let f = w.filter_len();
            let n = (x.len() - f) / 2 + 1;
            let (mut a1, mut d1, mut a2, mut d2) =
                (vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]);
            // SAFETY: checked `available()`; window covers all outputs.
            let done =
                unsafe { super::analysis(&x, &w.dec_lo_rev, &w.dec_hi_rev, &mut a1, &mut d1) };
            assert_eq!(done, n - n % 8);
            crate::transform::analysis_portable(&x, &w.dec_lo_rev, &w.dec_hi_rev, &mut a2, &mut d2);
            for i in 0..done {
                assert!(
                    (a1[i] - a2[i]).abs() < 1e-12 && (d1[i] - d2[i]).abs() < 1e-12,
                    "{name} {i}"
                );
            }
            let (ca, cd) = crate::dwt(&x, &w, Mode::Zero).expect("dwt");
            let m = 2 * (ca.len() - w.filter_len() / 2 + 1);
            let mut o1 = vec![0.0; m];
            let mut o2 = vec![0.0; m];
            // SAFETY: as above.
            let pairs = unsafe { super::synthesis_pairs(&ca, &cd, &w.rec_poly, &mut o1) };
            crate::transform::synthesis_pairs_portable(&ca, &cd, &w.rec_poly, &mut o2);
            assert!(pairs > 0);
            for i in 0..2 * pairs {
                assert!((o1[i] - o2[i]).abs() < 1e-12, "{name} synthesis {i}");
            }
        }
    }
}
