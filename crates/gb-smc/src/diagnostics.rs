//! Convergence diagnostics of MCMC chains (PMMH output).
//!
//! * **Effective sample size** (Geyer 1992): `ESS = n / (1 + 2 Σ_{k≥1} ρ_k)`, the
//!   autocorrelations `ρ_k` summed in pairs `Γ_m = ρ_{2m} + ρ_{2m+1}` (with
//!   `ρ_0 = 1`) while `Γ_m > 0` (initial positive sequence), each pair capped by
//!   the previous one (initial monotone sequence): `τ = −1 + 2 Σ_m Γ_m`, `ESS = n / τ`.
//! * **Split-R̂** (Gelman et al. 2013, §11.4): each chain is cut into halves; with
//!   `m` half-chains of length `n`, the within variance `W` (mean of the
//!   half-chain variances) and the between variance `B = n Var(half-chain means)`,
//!   `R̂ = √(((n − 1)/n · W + B/n) / W)`. Values above 1.1 mean the halves have
//!   not forgotten their start or are still drifting.

/// Effective sample size of one chain (see the module docs). A chain that
/// never moves has ESS 1; an empty chain 0.
///
/// ```
/// use gb_smc::diagnostics::effective_sample_size;
/// // alternating draws are negatively correlated: no worse than independent
/// let x: Vec<f64> = (0..100).map(|i| (i % 2) as f64).collect();
/// assert!(effective_sample_size(&x) >= 100.0);
/// assert_eq!(effective_sample_size(&[1.0; 100]), 1.0);
/// ```
pub fn effective_sample_size(x: &[f64]) -> f64 {
    let n = x.len();
    if n < 4 {
        return n as f64;
    }
    let nf = n as f64;
    let mean = x.iter().sum::<f64>() / nf;
    let c0 = x.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / nf;
    if !(c0 > 0.0 && c0.is_finite()) {
        return 1.0;
    }
    let rho = |k: usize| -> f64 {
        (0..n - k)
            .map(|i| (x[i] - mean) * (x[i + k] - mean))
            .sum::<f64>()
            / (nf * c0)
    };
    let mut tau = -1.0;
    let mut prev = f64::INFINITY;
    let mut m = 0;
    while 2 * m + 1 < n {
        let r0 = if m == 0 { 1.0 } else { rho(2 * m) };
        let pair = r0 + rho(2 * m + 1);
        if pair <= 0.0 {
            break;
        }
        let pair = pair.min(prev);
        tau += 2.0 * pair;
        prev = pair;
        m += 1;
    }
    (nf / tau.max(1.0 / nf)).min(nf * (n as f64).log10().max(1.0))
}

/// Split-R̂ of one or more chains of one parameter (see the module docs).
/// Chains are truncated to the shortest; `INFINITY` when every half-chain is
/// constant (a chain that never moved), NaN for chains shorter than 4.
pub fn split_rhat(chains: &[&[f64]]) -> f64 {
    let len = chains.iter().map(|c| c.len()).min().unwrap_or(0);
    if len < 4 || chains.is_empty() {
        return f64::NAN;
    }
    let n = len / 2;
    let halves: Vec<&[f64]> = chains
        .iter()
        .flat_map(|c| [&c[..n], &c[len - n..len]])
        .collect();
    let nf = n as f64;
    let stats: Vec<(f64, f64)> = halves
        .iter()
        .map(|h| {
            let m = h.iter().sum::<f64>() / nf;
            let v = h.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (nf - 1.0);
            (m, v)
        })
        .collect();
    let k = stats.len() as f64;
    let w = stats.iter().map(|s| s.1).sum::<f64>() / k;
    let grand = stats.iter().map(|s| s.0).sum::<f64>() / k;
    let b = nf * stats.iter().map(|s| (s.0 - grand).powi(2)).sum::<f64>() / (k - 1.0);
    if w.is_nan() || w <= 0.0 {
        return f64::INFINITY;
    }
    (((nf - 1.0) / nf * w + b / nf) / w).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::standard_normal;
    use gb_core::rng::seeded;

    fn ar1(phi: f64, n: usize, seed: u64) -> Vec<f64> {
        let mut r = seeded(seed);
        let mut x = 0.0;
        (0..n)
            .map(|_| {
                x = phi * x + standard_normal(&mut r);
                x
            })
            .collect()
    }

    /// White noise: ESS ≈ n. AR(1) with φ = 0.9: ESS ≈ n (1 − φ)/(1 + φ) = n/19
    /// (integrated autocorrelation time 19), within 30 %.
    #[test]
    fn ess_matches_the_ar1_autocorrelation_time() {
        let n = 20_000;
        let e = effective_sample_size(&ar1(0.0, n, 1));
        assert!(e > 0.85 * n as f64 && e < 1.15 * n as f64, "white ESS {e}");
        let e = effective_sample_size(&ar1(0.9, n, 2));
        let expect = n as f64 / 19.0;
        assert!(
            e > 0.7 * expect && e < 1.3 * expect,
            "AR(0.9) ESS {e}, expected {expect}"
        );
        assert_eq!(effective_sample_size(&[2.0; 50]), 1.0);
    }

    /// Stationary chains give R̂ < 1.05; a chain that drifts (a trend of
    /// 3 sd over its length) or two chains stuck in different places give > 1.1.
    #[test]
    fn split_rhat_flags_drift_and_disagreement() {
        let a = ar1(0.5, 4000, 3);
        let b = ar1(0.5, 4000, 4);
        let r = split_rhat(&[&a, &b]);
        assert!(r < 1.05, "stationary R̂ {r}");
        let drift: Vec<f64> = a
            .iter()
            .enumerate()
            .map(|(i, v)| v + 3.0 * 1.15 * i as f64 / 4000.0)
            .collect();
        let r = split_rhat(&[&drift]);
        assert!(r > 1.1, "drifting R̂ {r}");
        let shifted: Vec<f64> = b.iter().map(|v| v + 3.0).collect();
        let r = split_rhat(&[&a, &shifted]);
        assert!(r > 1.1, "disagreeing R̂ {r}");
        assert!(split_rhat(&[&[1.0; 10]]).is_infinite());
    }
}
