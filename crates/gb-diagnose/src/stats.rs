//! Small statistics toolkit: correlation functions, chi-square and F tail
//! probabilities, moving-block bootstrap.
use rand::Rng;

pub use gb_core::special::ln_gamma;

/// Sample cross-correlation r_ab(τ) = Σ_k ã(k) b̃(k+τ) / (N σ_a σ_b), τ = 0..=max_lag,
/// with ã, b̃ the mean-removed signals (b lags a by τ).
pub fn cross_correlation(a: &[f64], b: &[f64], max_lag: usize) -> Vec<f64> {
    let n = a.len().min(b.len());
    let ma = gb_core::metrics::mean(&a[..n]);
    let mb = gb_core::metrics::mean(&b[..n]);
    let sa = (a[..n].iter().map(|v| (v - ma).powi(2)).sum::<f64>()).sqrt();
    let sb = (b[..n].iter().map(|v| (v - mb).powi(2)).sum::<f64>()).sqrt();
    let den = (sa * sb).max(1e-300);
    (0..=max_lag.min(n.saturating_sub(1)))
        .map(|tau| {
            (0..n - tau)
                .map(|k| (a[k] - ma) * (b[k + tau] - mb))
                .sum::<f64>()
                / den
        })
        .collect()
}

/// Auto-correlation r_ee(τ), τ = 0..=max_lag.
pub fn autocorrelation(e: &[f64], max_lag: usize) -> Vec<f64> {
    cross_correlation(e, e, max_lag)
}

/// The AR(`p`) coefficients `a₁…a_p` of a series from its
/// auto-correlation `r` (lags `0..=p`; a missing lag counts as 0) by the
/// Levinson–Durbin recursion on the Yule–Walker equations
/// `Σⱼ aⱼ r(|i − j|) = r(i)`, the reflection coefficients clamped inside
/// ±0.9999 (the filter `1 − Σ aᵢ q⁻ⁱ` always minimum phase).
///
/// ```
/// // AR(1) with a = 0.8: r(k) = 0.8^k, so a₁ = 0.8 and a₂ = 0
/// let a = gb_diagnose::stats::ar_yule_walker(&[1.0, 0.8, 0.64], 2);
/// assert!((a[0] - 0.8).abs() < 1e-12 && a[1].abs() < 1e-12);
/// ```
pub fn ar_yule_walker(r: &[f64], p: usize) -> Vec<f64> {
    let r = |i: usize| r.get(i).copied().unwrap_or(0.0);
    let mut a = vec![0.0; p + 1];
    let mut err = r(0).max(1e-300);
    for i in 1..=p {
        let acc: f64 = (1..i).map(|j| a[j] * r(i - j)).sum();
        let k = ((r(i) - acc) / err).clamp(-0.9999, 0.9999);
        let prev = a.clone();
        a[i] = k;
        for j in 1..i {
            a[j] = prev[j] - k * prev[i - j];
        }
        err *= 1.0 - k * k;
    }
    a.remove(0);
    a
}

/// Regularised upper incomplete gamma Q(a, x) (Numerical Recipes: series or
/// continued fraction).
pub fn gamma_q(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    if x < a + 1.0 {
        let mut sum = 1.0 / a;
        let mut del = sum;
        let mut ap = a;
        for _ in 0..500 {
            ap += 1.0;
            del *= x / ap;
            sum += del;
            if del.abs() < sum.abs() * 1e-15 {
                break;
            }
        }
        1.0 - (sum.ln() - x + a * x.ln() - ln_gamma(a)).exp()
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..500 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-15 {
                break;
            }
        }
        (-x + a * x.ln() - ln_gamma(a)).exp() * h
    }
}

/// P(χ²_k > x).
pub fn chi2_sf(x: f64, k: f64) -> f64 {
    gamma_q(0.5 * k, 0.5 * x).clamp(0.0, 1.0)
}

/// Ljung–Box statistic Q = N(N+2) Σ_{τ=1}^{h} r²(τ)/(N−τ) of auto-correlations
/// r (r[0] = 1), and its p-value under whiteness (χ² with h degrees of freedom).
pub fn ljung_box(r: &[f64], n: usize) -> (f64, f64) {
    let h = r.len().saturating_sub(1);
    let nf = n as f64;
    let q = nf * (nf + 2.0) * (1..=h).map(|t| r[t] * r[t] / (nf - t as f64)).sum::<f64>();
    (q, chi2_sf(q, h as f64))
}

/// Jarque–Bera normality test: (skewness, excess kurtosis, JB, p-value).
pub fn jarque_bera(e: &[f64]) -> (f64, f64, f64, f64) {
    let n = e.len() as f64;
    let m = gb_core::metrics::mean(e);
    let m2 = e.iter().map(|v| (v - m).powi(2)).sum::<f64>() / n;
    let m3 = e.iter().map(|v| (v - m).powi(3)).sum::<f64>() / n;
    let m4 = e.iter().map(|v| (v - m).powi(4)).sum::<f64>() / n;
    let s = m3 / m2.powf(1.5).max(1e-300);
    let k = m4 / (m2 * m2).max(1e-300) - 3.0;
    let jb = n / 6.0 * (s * s + 0.25 * k * k);
    (s, k, jb, chi2_sf(jb, 2.0))
}

/// Regularised incomplete beta I_x(a, b) (continued fraction).
pub fn beta_inc(a: f64, b: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if x >= 1.0 {
        return 1.0;
    }
    let lbeta = ln_gamma(a + b) - ln_gamma(a) - ln_gamma(b);
    let front = (lbeta + a * x.ln() + b * (1.0 - x).ln()).exp();
    let cf = |a: f64, b: f64, x: f64| {
        let tiny = 1e-300;
        let (qab, qap, qam) = (a + b, a + 1.0, a - 1.0);
        let mut c = 1.0;
        let mut d = 1.0 - qab * x / qap;
        if d.abs() < tiny {
            d = tiny;
        }
        d = 1.0 / d;
        let mut h = d;
        for m in 1..300 {
            let m = m as f64;
            let m2 = 2.0 * m;
            let aa = m * (b - m) * x / ((qam + m2) * (a + m2));
            d = 1.0 + aa * d;
            if d.abs() < tiny {
                d = tiny;
            }
            c = 1.0 + aa / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            h *= d * c;
            let aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2));
            d = 1.0 + aa * d;
            if d.abs() < tiny {
                d = tiny;
            }
            c = 1.0 + aa / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-15 {
                break;
            }
        }
        h
    };
    if x < (a + 1.0) / (a + b + 2.0) {
        front * cf(a, b, x) / a
    } else {
        1.0 - front * cf(b, a, 1.0 - x) / b
    }
}

/// P(F_{d1,d2} > f).
pub fn f_sf(f: f64, d1: f64, d2: f64) -> f64 {
    if f <= 0.0 {
        return 1.0;
    }
    beta_inc(0.5 * d2, 0.5 * d1, d2 / (d2 + d1 * f)).clamp(0.0, 1.0)
}

/// The dependence range of a series: the smallest lag `m` after which the
/// next `K = max(5, ⌈√log₁₀ n⌉)` autocorrelations all lie within
/// `±2·√(log₁₀ n / n)` (Politis & White 2004, the `m̂` of their automatic
/// block length). A moving-block bootstrap needs blocks at least this
/// long to keep the series' correlation. Lags are searched up to `n/2`.
///
/// ```
/// # use gb_diagnose::stats::dependence_range;
/// // a period-4 pattern stays correlated at every lag
/// let x: Vec<f64> = (0..400).map(|k| [1.0, 0.0, -1.0, 0.0][k % 4]).collect();
/// assert_eq!(dependence_range(&x), 200);
/// ```
pub fn dependence_range(x: &[f64]) -> usize {
    let n = x.len();
    if n < 8 {
        return 1;
    }
    let max_lag = n / 2;
    let r = autocorrelation(x, max_lag);
    let lg = (n as f64).log10();
    let band = 2.0 * (lg / n as f64).sqrt();
    let k = (lg.sqrt().ceil() as usize).max(5);
    let mut quiet = 0;
    for (lag, v) in r.iter().enumerate().skip(1) {
        if v.abs() < band {
            quiet += 1;
            if quiet == k {
                return lag - k;
            }
        } else {
            quiet = 0;
        }
    }
    max_lag
}

/// Moving-block bootstrap percentile interval of a statistic of paired
/// per-sample series: `stat` maps resampled index lists to a value.
/// Returns (2.5 %, 97.5 %) quantiles over `reps` replicates.
pub fn block_bootstrap<F: Fn(&[usize]) -> f64>(
    n: usize,
    block: usize,
    reps: usize,
    seed: u64,
    stat: F,
) -> (f64, f64) {
    let block = block.clamp(1, n.max(1));
    let mut r = gb_core::rng::stream(seed, 77);
    let mut vals = Vec::with_capacity(reps);
    let mut idx = Vec::with_capacity(n);
    for _ in 0..reps {
        idx.clear();
        while idx.len() < n {
            let start = r.random_range(0..=(n - block));
            for i in start..start + block {
                if idx.len() == n {
                    break;
                }
                idx.push(i);
            }
        }
        vals.push(stat(&idx));
    }
    vals.sort_by(|a, b| a.total_cmp(b));
    let q = |p: f64| vals[((p * (reps as f64 - 1.0)).round() as usize).min(reps - 1)];
    (q(0.025), q(0.975))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chi2_and_f_tails_match_tables() {
        // χ²(2): P(X > 5.991) = 0.05; χ²(10): P(X > 18.307) = 0.05
        assert!((chi2_sf(5.991, 2.0) - 0.05).abs() < 1e-4);
        assert!((chi2_sf(18.307, 10.0) - 0.05).abs() < 1e-4);
        assert!((chi2_sf(0.0, 3.0) - 1.0).abs() < 1e-12);
        // F(3, 20): P(F > 3.098) = 0.05; F(5, 100): P(F > 2.305) = 0.05
        assert!((f_sf(3.098, 3.0, 20.0) - 0.05).abs() < 1e-3);
        assert!((f_sf(2.305, 5.0, 100.0) - 0.05).abs() < 1e-3);
    }

    #[test]
    fn correlation_of_shifted_signal_peaks_at_shift() {
        let a: Vec<f64> = (0..500).map(|k| ((k * 7919 % 101) as f64).sin()).collect();
        let mut b = vec![0.0; 500];
        b[3..].copy_from_slice(&a[..497]);
        let r = cross_correlation(&a, &b, 6);
        let best = (0..r.len()).max_by(|&i, &j| r[i].total_cmp(&r[j])).unwrap();
        assert_eq!(best, 3);
    }

    #[test]
    fn the_dependence_range_follows_the_correlation_time() {
        use rand_distr::{Distribution, StandardNormal};
        let mut r = gb_core::rng::seeded(5);
        let white: Vec<f64> = (0..4000).map(|_| StandardNormal.sample(&mut r)).collect();
        // white noise: a few lags at most
        assert!(
            dependence_range(&white) <= 3,
            "{}",
            dependence_range(&white)
        );
        // AR(1): ρ(m) = a^m falls below the band 2√(log₁₀n/n) ≈ 0.058 at
        // m = ln 0.058 / ln a: 27 for a = 0.9, 284 for a = 0.99
        for (a, lo, hi) in [(0.9, 15, 45), (0.99, 120, 600)] {
            let mut x = vec![0.0; 4000];
            for k in 1..4000 {
                x[k] = a * x[k - 1] + white[k];
            }
            let m = dependence_range(&x);
            assert!(m >= lo && m <= hi, "a = {a}: {m}");
        }
    }

    #[test]
    fn bootstrap_interval_covers_mean_and_widens_with_correlation() {
        use rand_distr::{Distribution, StandardNormal};
        let mut r = gb_core::rng::seeded(3);
        let white: Vec<f64> = (0..2000).map(|_| StandardNormal.sample(&mut r)).collect();
        // AR(1) with coefficient 0.9: the same marginal scale, far fewer independent samples
        let mut ar = vec![0.0; 2000];
        for k in 1..2000 {
            ar[k] = 0.9 * ar[k - 1] + (1.0f64 - 0.81).sqrt() * white[k];
        }
        let mean =
            |x: &[f64], idx: &[usize]| idx.iter().map(|&i| x[i]).sum::<f64>() / idx.len() as f64;
        let (lw, hw) = block_bootstrap(2000, 50, 400, 1, |idx| mean(&white, idx));
        let (la, ha) = block_bootstrap(2000, 50, 400, 1, |idx| mean(&ar, idx));
        let mw = gb_core::metrics::mean(&white);
        let ma = gb_core::metrics::mean(&ar);
        assert!(lw < mw && mw < hw, "{lw} {mw} {hw}");
        assert!(la < ma && ma < ha, "{la} {ma} {ha}");
        // white: half-width ≈ 1.96/√2000 = 0.044; AR(1) 0.9: ≈ √19 times wider
        assert!(
            (hw - lw) > 0.05 && (hw - lw) < 0.13,
            "white width {}",
            hw - lw
        );
        assert!(
            (ha - la) > 2.5 * (hw - lw),
            "AR width {} vs white {}",
            ha - la,
            hw - lw
        );
    }
}
