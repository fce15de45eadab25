//! The noise model of a fitted model: a zero-location distribution of the
//! output error `e = y − ŷ`, used for the log-likelihood of residuals, robust
//! (IRLS) weights and, in gb-smc, sampling. One type for every crate.
//!
//! The postcard layout (variant order and field order) is that of the model
//! files written since format 1, so old files still decode.
use crate::special::ln_gamma;
use serde::{Deserialize, Serialize};

const LN_2PI: f64 = 1.837_877_066_409_345_3;

/// A zero-location noise distribution.
///
/// ```
/// use gb_core::NoiseModel;
/// // Gaussian: nll(e) = ½ ln(2πσ²) + e²/(2σ²)
/// let n = NoiseModel::Gaussian { sd: 2.0 };
/// let want = 0.5 * (2.0 * std::f64::consts::PI * 4.0).ln() + 1.0 / 8.0;
/// assert!((n.nll(1.0) - want).abs() < 1e-12);
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum NoiseModel {
    /// `N(0, sd²)`.
    Gaussian {
        /// Standard deviation.
        sd: f64,
    },
    /// `scale · t_ν` (Student-t, heavy tailed).
    StudentT {
        /// Degrees of freedom ν.
        nu: f64,
        /// Scale.
        scale: f64,
    },
    /// Laplace with scale `b`: `p(e) = exp(−|e|/b)/(2b)`.
    Laplace {
        /// Scale b.
        scale: f64,
    },
    /// Finite mixture `Σ wₖ pₖ(e)` (weights sum to one).
    Mixture(Vec<(f64, NoiseModel)>),
}

impl NoiseModel {
    /// Gaussian noise fitted to residuals by maximum likelihood (σ = rms).
    pub fn gaussian(res: &[f64]) -> Self {
        NoiseModel::Gaussian {
            sd: crate::metrics::rms(res).max(f64::MIN_POSITIVE.sqrt()),
        }
    }

    /// Student-t noise fitted to residuals by maximum likelihood
    /// ([`fit_student_t`]).
    pub fn student_t(res: &[f64]) -> Self {
        let (nu, scale) = fit_student_t(res);
        NoiseModel::StudentT { nu, scale }
    }

    /// `ln p(e)`.
    pub fn log_pdf(&self, e: f64) -> f64 {
        match self {
            NoiseModel::Gaussian { sd } => -0.5 * (LN_2PI + 2.0 * sd.ln()) - 0.5 * (e / sd).powi(2),
            NoiseModel::StudentT { nu, scale } => student_t_logpdf(e / scale, *nu) - scale.ln(),
            NoiseModel::Laplace { scale } => -(2.0 * scale).ln() - e.abs() / scale,
            NoiseModel::Mixture(parts) => {
                let logs: Vec<f64> = parts.iter().map(|(w, n)| w.ln() + n.log_pdf(e)).collect();
                let m = logs.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
                if m == f64::NEG_INFINITY {
                    return m;
                }
                m + logs.iter().map(|l| (l - m).exp()).sum::<f64>().ln()
            }
        }
    }

    /// Negative log-density of one residual, `−ln p(e)`.
    pub fn nll(&self, e: f64) -> f64 {
        -self.log_pdf(e)
    }

    /// Mean negative log-likelihood per sample (0 for no samples).
    pub fn mean_nll(&self, res: &[f64]) -> f64 {
        if res.is_empty() {
            return 0.0;
        }
        if let NoiseModel::StudentT { nu, scale } = self {
            return -student_t_log_likelihood(res, *nu, *scale) / res.len() as f64;
        }
        res.iter().map(|&e| self.nll(e)).sum::<f64>() / res.len() as f64
    }

    /// IRLS weight of a residual, `−(d ln p/de)/e`: 1 for Gaussian,
    /// `(ν+1)/(ν+(e/s)²)` for Student-t, `b/|e|`-type for Laplace (capped).
    pub fn weight(&self, e: f64) -> f64 {
        match self {
            NoiseModel::Gaussian { .. } => 1.0,
            NoiseModel::StudentT { nu, scale } => (nu + 1.0) / (nu + (e / scale).powi(2)),
            NoiseModel::Laplace { scale } => (scale / e.abs().max(1e-6 * scale)).min(1e6),
            NoiseModel::Mixture(_) => 1.0,
        }
    }

    /// The same family with every scale multiplied by `k > 0`.
    pub fn scaled(&self, k: f64) -> Self {
        match self {
            NoiseModel::Gaussian { sd } => NoiseModel::Gaussian { sd: sd * k },
            NoiseModel::StudentT { nu, scale } => NoiseModel::StudentT {
                nu: *nu,
                scale: scale * k,
            },
            NoiseModel::Laplace { scale } => NoiseModel::Laplace { scale: scale * k },
            NoiseModel::Mixture(p) => {
                NoiseModel::Mixture(p.iter().map(|(w, n)| (*w, n.scaled(k))).collect())
            }
        }
    }

    /// Standard deviation (infinite for Student-t with ν ≤ 2).
    pub fn sd(&self) -> f64 {
        match self {
            NoiseModel::Gaussian { sd } => *sd,
            NoiseModel::StudentT { nu, scale } => {
                if *nu > 2.0 {
                    scale * (nu / (nu - 2.0)).sqrt()
                } else {
                    f64::INFINITY
                }
            }
            NoiseModel::Laplace { scale } => scale * std::f64::consts::SQRT_2,
            NoiseModel::Mixture(p) => p
                .iter()
                .map(|(w, n)| w * n.sd().powi(2))
                .sum::<f64>()
                .sqrt(),
        }
    }

    /// Whether the parameters are valid (positive finite scales, ν > 0,
    /// mixture weights positive and summing to one).
    pub fn is_valid(&self) -> bool {
        let pos = |v: f64| v > 0.0 && v.is_finite();
        match self {
            NoiseModel::Gaussian { sd } => pos(*sd),
            NoiseModel::StudentT { nu, scale } => pos(*nu) && pos(*scale),
            NoiseModel::Laplace { scale } => pos(*scale),
            NoiseModel::Mixture(p) => {
                !p.is_empty()
                    && p.iter().all(|(w, n)| pos(*w) && n.is_valid())
                    && (p.iter().map(|(w, _)| w).sum::<f64>() - 1.0).abs() < 1e-9
            }
        }
    }

    /// A short description, e.g. `Gaussian (sd 1.000e-2)`.
    pub fn describe(&self) -> String {
        match self {
            NoiseModel::Gaussian { sd } => format!("Gaussian (sigma {sd:.3e})"),
            NoiseModel::StudentT { nu, scale } => {
                format!("Student-t (nu {nu:.2}, scale {scale:.3e})")
            }
            NoiseModel::Laplace { scale } => format!("Laplace (scale {scale:.3e})"),
            NoiseModel::Mixture(p) => format!("mixture of {} components", p.len()),
        }
    }
}

/// `ln` density of the standard Student-t distribution with ν degrees of
/// freedom: `ln Γ((ν+1)/2) − ln Γ(ν/2) − ½ ln(νπ) − (ν+1)/2 · ln(1 + t²/ν)`.
pub fn student_t_logpdf(t: f64, nu: f64) -> f64 {
    student_t_norm(nu) - 0.5 * (nu + 1.0) * (1.0 + t * t / nu).ln()
}

/// The normalising term of [`student_t_logpdf`],
/// `ln Γ((ν+1)/2) − ln Γ(ν/2) − ½ ln(νπ)`.
fn student_t_norm(nu: f64) -> f64 {
    ln_gamma(0.5 * (nu + 1.0)) - ln_gamma(0.5 * nu) - 0.5 * (nu * std::f64::consts::PI).ln()
}

/// `Σₖ ln p(eₖ)` for `e ~ s·t_ν`, the normalising term taken once.
fn student_t_log_likelihood(res: &[f64], nu: f64, s: f64) -> f64 {
    let tails: f64 = res
        .iter()
        .map(|&e| {
            let t = e / s;
            (1.0 + t * t / nu).ln()
        })
        .sum();
    res.len() as f64 * (student_t_norm(nu) - s.ln()) - 0.5 * (nu + 1.0) * tails
}

/// Maximum-likelihood `(ν, s)` for residuals `e ~ s·t_ν`: EM iterations for
/// `s` at each ν of a grid (1.2 … 300), keeping the best log-likelihood.
pub fn fit_student_t(res: &[f64]) -> (f64, f64) {
    let n = res.len().max(1) as f64;
    let s0 = crate::metrics::rms(res).max(1e-300);
    let mut best = (f64::NEG_INFINITY, 200.0, s0);
    for &nu in &[
        1.2, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 7.0, 10.0, 15.0, 25.0, 50.0, 100.0, 300.0,
    ] {
        let mut s2 = s0 * s0;
        for _ in 0..50 {
            let acc: f64 = res
                .iter()
                .map(|&e| (nu + 1.0) / (nu + e * e / s2) * e * e)
                .sum();
            let new = (acc / n).max(1e-300);
            let conv = (new - s2).abs() <= 1e-10 * s2;
            s2 = new;
            if conv {
                break;
            }
        }
        let s = s2.sqrt();
        let ll = student_t_log_likelihood(res, nu, s);
        if ll > best.0 {
            best = (ll, nu, s);
        }
    }
    (best.1, best.2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn densities_integrate_to_one() {
        let models = [
            NoiseModel::Gaussian { sd: 0.7 },
            NoiseModel::StudentT {
                nu: 3.0,
                scale: 0.5,
            },
            NoiseModel::Laplace { scale: 0.3 },
            NoiseModel::Mixture(vec![
                (0.8, NoiseModel::Gaussian { sd: 0.2 }),
                (0.2, NoiseModel::Gaussian { sd: 2.0 }),
            ]),
        ];
        for m in &models {
            assert!(m.is_valid());
            // trapezoid on [−200, 200]; heavy tails converge slowly, so 1e-3
            let h = 1e-3;
            let s: f64 = (-200_000..=200_000)
                .map(|i| m.log_pdf(i as f64 * h).exp())
                .sum::<f64>()
                * h;
            assert!((s - 1.0).abs() < 2e-3, "{m:?}: {s}");
        }
    }

    #[test]
    fn student_t_fit_recovers_nu_and_gaussian_fit_the_rms() {
        // t₃ samples by inversion of a deterministic grid of quantiles is
        // awkward; use the ratio of Gaussians Z / sqrt(χ²₃/3) from a
        // seeded stream instead
        use rand::Rng;
        let mut r = crate::rng::seeded(3);
        let mut g = || -> f64 {
            // Box–Muller
            let (a, b): (f64, f64) = (r.random(), r.random());
            (-2.0 * (1.0 - a).ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
        };
        let res: Vec<f64> = (0..20_000)
            .map(|_| {
                let z = g();
                let chi: f64 = (0..3).map(|_| g().powi(2)).sum();
                0.1 * z / (chi / 3.0).sqrt()
            })
            .collect();
        let (nu, s) = fit_student_t(&res);
        assert!((2.0..=4.0).contains(&nu), "nu {nu}");
        assert!((s - 0.1).abs() < 0.01, "scale {s}");
        let gm = NoiseModel::gaussian(&[3.0, -4.0]);
        assert!((gm.sd() - (12.5f64).sqrt()).abs() < 1e-12);
    }

    #[test]
    fn student_t_mean_nll_is_the_mean_of_the_densities() {
        let t = NoiseModel::StudentT {
            nu: 3.5,
            scale: 0.7,
        };
        let res = [0.1, -2.0, 0.35, 4.0, -0.01];
        // ln p(e) = ln Γ(2.25) − ln Γ(1.75) − ½ ln(3.5π) − ln 0.7 − 2.25 ln(1 + (e/0.7)²/3.5)
        let c = 0.12487171489239657
            - (-0.08440112102048558)
            - 0.5 * (3.5 * std::f64::consts::PI).ln()
            - 0.7f64.ln();
        let want = -res
            .iter()
            .map(|e| c - 2.25 * (1.0 + (e / 0.7f64).powi(2) / 3.5).ln())
            .sum::<f64>()
            / 5.0;
        assert!(
            (t.mean_nll(&res) - want).abs() < 1e-12,
            "{} {want}",
            t.mean_nll(&res)
        );
    }

    #[test]
    fn sd_and_scaling() {
        let t = NoiseModel::StudentT {
            nu: 4.0,
            scale: 1.0,
        };
        assert!((t.sd() - 2f64.sqrt()).abs() < 1e-12);
        assert!((t.scaled(3.0).sd() - 3.0 * 2f64.sqrt()).abs() < 1e-12);
        assert!(NoiseModel::StudentT {
            nu: 2.0,
            scale: 1.0
        }
        .sd()
        .is_infinite());
        assert!(!NoiseModel::Gaussian { sd: -1.0 }.is_valid());
    }
}
