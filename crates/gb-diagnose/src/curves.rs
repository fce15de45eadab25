//! Curves computed from residuals for the evidence plots: binned means by
//! direction of motion, the periodogram, the normal Q–Q plot. Data only;
//! drawing is the renderers' business.

/// Points (x, y) of one curve.
pub type Curve = Vec<(f64, f64)>;

/// The padded range of finite values.
pub(crate) fn range(points: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in points.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (-1.0, 1.0);
    }
    let pad = if hi > lo {
        0.05 * (hi - lo)
    } else {
        0.5 * lo.abs().max(1e-12)
    };
    (lo - pad, hi + pad)
}

/// At most `max` points of the curve `(x, y)`, evenly strided.
pub fn thin(x: &[f64], y: &[f64], max: usize) -> Curve {
    let n = x.len().min(y.len());
    let stride = n.div_ceil(max.max(1)).max(1);
    (0..n).step_by(stride).map(|k| (x[k], y[k])).collect()
}

/// Periodogram |Σ e_k e^{−iωk}|²/N at `m` frequencies f = ω/2π ∈ (0, ½]
/// (Goertzel recursion per frequency).
pub fn periodogram(e: &[f64], m: usize) -> Curve {
    let n = e.len().max(1) as f64;
    (1..=m)
        .map(|i| {
            let f = 0.5 * i as f64 / m as f64;
            let w = 2.0 * std::f64::consts::PI * f;
            let c = 2.0 * w.cos();
            let (mut s1, mut s2) = (0.0, 0.0);
            for &v in e {
                let s0 = v + c * s1 - s2;
                s2 = s1;
                s1 = s0;
            }
            let p = s1 * s1 + s2 * s2 - c * s1 * s2;
            (f, p / n)
        })
        .collect()
}

/// Moving average over `half` neighbours on each side.
pub fn smooth(p: &[(f64, f64)], half: usize) -> Curve {
    (0..p.len())
        .map(|i| {
            let a = i.saturating_sub(half);
            let b = (i + half + 1).min(p.len());
            let m = p[a..b].iter().map(|v| v.1).sum::<f64>() / (b - a) as f64;
            (p[i].0, m)
        })
        .collect()
}

/// Standard normal quantile Φ⁻¹(p) (Acklam's rational approximation,
/// relative error < 1.2e-9).
pub fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.383_577_518_672_69e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e1,
        1.615858368580409e2,
        -1.556989798598866e2,
        6.680131188771972e1,
        -1.328068155288572e1,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    const D: [f64; 4] = [
        7.784695709041462e-3,
        3.224671290700398e-1,
        2.445134137142996,
        3.754408661907416,
    ];
    let p = p.clamp(1e-300, 1.0 - 1e-16);
    let pl = 0.02425;
    if p < pl {
        let q = (-2.0 * p.ln()).sqrt();
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    } else if p <= 1.0 - pl {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    } else {
        let q = (-2.0 * (1.0 - p).ln()).sqrt();
        -(((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    }
}

/// Mean of `e` in `bins` equal bins of `x` (bins with ≥ 5 samples).
pub fn binned_mean(x: &[f64], e: &[f64], bins: usize) -> Curve {
    let (lo, hi) = range(x.iter().copied());
    let mut s = vec![0.0; bins];
    let mut c = vec![0usize; bins];
    for (&xv, &ev) in x.iter().zip(e) {
        let b = (((xv - lo) / (hi - lo)) * bins as f64) as usize;
        let b = b.min(bins - 1);
        s[b] += ev;
        c[b] += 1;
    }
    (0..bins)
        .filter(|&b| c[b] >= 5)
        .map(|b| {
            (
                lo + (b as f64 + 0.5) * (hi - lo) / bins as f64,
                s[b] / c[b] as f64,
            )
        })
        .collect()
}

/// Binned mean of `e` over the level of `x`, separately for samples where
/// `x` rises and where it falls: without memory both branches coincide.
pub fn direction_means(x: &[f64], e: &[f64], bins: usize) -> (Curve, Curve) {
    let (mut xu, mut eu, mut xd, mut ed) = (vec![], vec![], vec![], vec![]);
    for k in 1..x.len().min(e.len()) {
        if x[k] > x[k - 1] {
            xu.push(x[k]);
            eu.push(e[k]);
        } else if x[k] < x[k - 1] {
            xd.push(x[k]);
            ed.push(e[k]);
        }
    }
    (binned_mean(&xu, &eu, bins), binned_mean(&xd, &ed, bins))
}

/// Normal Q–Q points of the standardised residual (at most ~1500) and the
/// reference line.
pub fn qq(e: &[f64]) -> (Curve, Curve) {
    let m = gb_core::metrics::mean(e);
    let sd = gb_core::metrics::std(e).max(1e-300);
    let mut z: Vec<f64> = e.iter().map(|v| (v - m) / sd).collect();
    z.sort_by(f64::total_cmp);
    let n = z.len();
    let stride = n.div_ceil(1500).max(1);
    let mut pts: Vec<(f64, f64)> = (0..n)
        .step_by(stride)
        .map(|i| (normal_quantile((i as f64 + 0.5) / n as f64), z[i]))
        .collect();
    if n > 0 && (n - 1) % stride != 0 {
        pts.push((normal_quantile((n as f64 - 0.5) / n as f64), z[n - 1]));
    }
    let q = normal_quantile(0.5 / n.max(1) as f64).abs();
    (pts, vec![(-q, -q), (q, q)])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_quantile_matches_known_values() {
        for (p, z) in [
            (0.5, 0.0),
            (0.975, 1.959_963_984_540_054),
            (0.01, -2.326_347_874_040_841),
        ] {
            assert!((normal_quantile(p) - z).abs() < 1e-8, "{p}");
        }
    }

    #[test]
    fn periodogram_finds_a_sinusoid() {
        let e: Vec<f64> = (0..1000)
            .map(|k| (2.0 * std::f64::consts::PI * 0.1 * k as f64).sin())
            .collect();
        let p = periodogram(&e, 200);
        let peak = p
            .iter()
            .cloned()
            .fold((0.0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
        assert!((peak.0 - 0.1).abs() < 0.003, "{peak:?}");
    }

    #[test]
    fn direction_means_separate_a_loop() {
        // e = +1 while x rises, −1 while it falls: two branches 2 apart
        let x: Vec<f64> = (0..2000).map(|k| (k as f64 * 0.05).sin()).collect();
        let e: Vec<f64> = (0..2000)
            .map(|k| if k > 0 && x[k] > x[k - 1] { 1.0 } else { -1.0 })
            .collect();
        let (up, down) = direction_means(&x, &e, 10);
        assert!(up.iter().all(|p| (p.1 - 1.0).abs() < 1e-12));
        assert!(down.iter().all(|p| (p.1 + 1.0).abs() < 1e-12));
    }
}
