//! Noise families for state and observation equations: Gaussian, Student-t,
//! Laplace and finite mixtures (heavy tails, outliers, multi-modal sources).
use crate::error::{check, Result, SmcError};
use crate::rng::SmcRng;
use rand::Rng;
use rand_distr::Distribution;

const LN_2PI: f64 = 1.837_877_066_409_345_3;

/// `ln Γ(x)` (Lanczos), shared with the other crates.
pub use gb_core::special::ln_gamma;

/// A scalar noise distribution.
///
/// ```
/// use gb_smc::noise::Noise;
/// let n = Noise::mixture(vec![
///     (0.9, Noise::gaussian(0.0, 1.0).unwrap()),
///     (0.1, Noise::student_t(3.0, 0.0, 5.0).unwrap()),
/// ]).unwrap();
/// let mut rng = gb_smc::rng::stream(1, 0, 0, 0);
/// let x = n.sample(&mut rng);
/// assert!(n.log_pdf(x).is_finite());
/// ```
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum Noise {
    /// `N(mean, sd²)`.
    Gaussian {
        /// Mean.
        mean: f64,
        /// Standard deviation.
        sd: f64,
    },
    /// Student-t with `nu` degrees of freedom, location `loc`, scale `scale`:
    /// `p(x) = Γ((ν+1)/2) / (Γ(ν/2) √(νπ) s) · (1 + z²/ν)^{−(ν+1)/2}`, `z = (x − loc)/s`.
    StudentT {
        /// Degrees of freedom.
        nu: f64,
        /// Location.
        loc: f64,
        /// Scale.
        scale: f64,
        /// Cached log normalising constant.
        log_norm: f64,
    },
    /// Laplace `p(x) = exp(−|x − loc|/b) / (2b)`.
    Laplace {
        /// Location.
        loc: f64,
        /// Scale `b`.
        scale: f64,
    },
    /// Finite mixture `Σ_k w_k p_k(x)`.
    Mixture {
        /// Normalised weights.
        weights: Vec<f64>,
        /// Components.
        components: Vec<Noise>,
    },
}

impl Noise {
    /// The zero-location distribution of a fitted model's noise model.
    pub fn from_model(m: &gb_core::NoiseModel) -> Result<Self> {
        use gb_core::NoiseModel as M;
        match m {
            M::Gaussian { sd } => Self::gaussian(0.0, *sd),
            M::StudentT { nu, scale } => Self::student_t(*nu, 0.0, *scale),
            M::Laplace { scale } => Self::laplace(0.0, *scale),
            M::Mixture(parts) => Self::mixture(
                parts
                    .iter()
                    .map(|(w, n)| Self::from_model(n).map(|n| (*w, n)))
                    .collect::<Result<Vec<_>>>()?,
            ),
            _ => Err(SmcError::InvalidWeights("unsupported noise family")),
        }
    }

    /// Gaussian `N(mean, sd²)`, `sd > 0`.
    pub fn gaussian(mean: f64, sd: f64) -> Result<Self> {
        check("mean", mean, mean.is_finite(), "must be finite")?;
        check(
            "sd",
            sd,
            sd > 0.0 && sd.is_finite(),
            "must be positive and finite",
        )?;
        Ok(Self::Gaussian { mean, sd })
    }
    /// Student-t, `nu > 0`, `scale > 0`.
    pub fn student_t(nu: f64, loc: f64, scale: f64) -> Result<Self> {
        check(
            "nu",
            nu,
            nu > 0.0 && nu.is_finite(),
            "must be positive and finite",
        )?;
        check("loc", loc, loc.is_finite(), "must be finite")?;
        check(
            "scale",
            scale,
            scale > 0.0 && scale.is_finite(),
            "must be positive and finite",
        )?;
        let log_norm = ln_gamma(0.5 * (nu + 1.0))
            - ln_gamma(0.5 * nu)
            - 0.5 * (nu * std::f64::consts::PI).ln()
            - scale.ln();
        Ok(Self::StudentT {
            nu,
            loc,
            scale,
            log_norm,
        })
    }
    /// Laplace, `scale > 0`.
    pub fn laplace(loc: f64, scale: f64) -> Result<Self> {
        check("loc", loc, loc.is_finite(), "must be finite")?;
        check(
            "scale",
            scale,
            scale > 0.0 && scale.is_finite(),
            "must be positive and finite",
        )?;
        Ok(Self::Laplace { loc, scale })
    }
    /// Mixture of `(weight, component)` pairs; weights are normalised.
    pub fn mixture(parts: Vec<(f64, Noise)>) -> Result<Self> {
        if parts.is_empty() {
            return Err(SmcError::InvalidWeights("empty mixture"));
        }
        let total: f64 = parts.iter().map(|p| p.0).sum();
        for p in &parts {
            check(
                "mixture weight",
                p.0,
                p.0 >= 0.0 && p.0.is_finite(),
                "must be non-negative",
            )?;
        }
        if !(total > 0.0 && total.is_finite()) {
            return Err(SmcError::InvalidWeights("mixture weights sum to zero"));
        }
        let (weights, components) = parts.into_iter().map(|(w, c)| (w / total, c)).unzip();
        Ok(Self::Mixture {
            weights,
            components,
        })
    }

    /// Draws one value.
    pub fn sample(&self, rng: &mut SmcRng) -> f64 {
        match self {
            Self::Gaussian { mean, sd } => mean + sd * crate::rng::standard_normal(rng),
            Self::StudentT { nu, loc, scale, .. } => {
                // z / sqrt(V / ν), V ~ χ²_ν = 2 Gamma(ν/2)
                let z = crate::rng::standard_normal(rng);
                let g = rand_distr::Gamma::new(0.5 * nu, 2.0).map_or(f64::NAN, |d| d.sample(rng));
                loc + scale * z / (g / nu).sqrt()
            }
            Self::Laplace { loc, scale } => {
                let u: f64 = rng.random::<f64>() - 0.5;
                loc - scale * u.signum() * (1.0 - 2.0 * u.abs()).ln()
            }
            Self::Mixture {
                weights,
                components,
            } => {
                let u: f64 = rng.random();
                let mut c = 0.0;
                for (w, comp) in weights.iter().zip(components) {
                    c += w;
                    if u < c {
                        return comp.sample(rng);
                    }
                }
                components[components.len() - 1].sample(rng)
            }
        }
    }

    /// `log p(x)`.
    pub fn log_pdf(&self, x: f64) -> f64 {
        match self {
            Self::Gaussian { mean, sd } => {
                let z = (x - mean) / sd;
                -0.5 * (LN_2PI + z * z) - sd.ln()
            }
            Self::StudentT {
                nu,
                loc,
                scale,
                log_norm,
            } => {
                let z = (x - loc) / scale;
                log_norm - 0.5 * (nu + 1.0) * (z * z / nu).ln_1p()
            }
            Self::Laplace { loc, scale } => -(2.0 * scale).ln() - (x - loc).abs() / scale,
            Self::Mixture {
                weights,
                components,
            } => {
                let mut max = f64::NEG_INFINITY;
                let mut sum = 0.0;
                for (w, c) in weights.iter().zip(components) {
                    if *w <= 0.0 {
                        continue;
                    }
                    let v = w.ln() + c.log_pdf(x);
                    if v > max {
                        sum = sum * (max - v).exp() + 1.0;
                        max = v;
                    } else if v > f64::NEG_INFINITY {
                        sum += (v - max).exp();
                    }
                }
                max + sum.ln()
            }
        }
    }

    /// Mean, if it exists.
    pub fn mean(&self) -> Option<f64> {
        match self {
            Self::Gaussian { mean, .. } => Some(*mean),
            Self::StudentT { nu, loc, .. } => (*nu > 1.0).then_some(*loc),
            Self::Laplace { loc, .. } => Some(*loc),
            Self::Mixture {
                weights,
                components,
            } => weights
                .iter()
                .zip(components)
                .try_fold(0.0, |s, (w, c)| c.mean().map(|m| s + w * m)),
        }
    }

    /// Variance, if it exists.
    pub fn variance(&self) -> Option<f64> {
        match self {
            Self::Gaussian { sd, .. } => Some(sd * sd),
            Self::StudentT { nu, scale, .. } => {
                (*nu > 2.0).then(|| scale * scale * nu / (nu - 2.0))
            }
            Self::Laplace { scale, .. } => Some(2.0 * scale * scale),
            Self::Mixture {
                weights,
                components,
            } => {
                let m = self.mean()?;
                weights.iter().zip(components).try_fold(0.0, |s, (w, c)| {
                    let (cm, cv) = (c.mean()?, c.variance()?);
                    Some(s + w * (cv + (cm - m) * (cm - m)))
                })
            }
        }
    }
}
