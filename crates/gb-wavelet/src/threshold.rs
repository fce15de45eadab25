//! Thresholding: shrinkage functions and data-driven thresholds.
//!
//! With noisy detail coefficients `y = θ + σz`, `z ~ N(0,1)`:
//! * universal (VisuShrink): `λ = σ√(2 ln N)`;
//! * SURE (SureShrink): per level, `λ` minimises Stein's unbiased risk estimate
//!   of soft thresholding, `SURE(λ) = n − 2#{|y_i| ≤ λ} + Σ min(|y_i|, λ)²`
//!   (in units of σ), with Donoho–Johnstone's fallback to the universal
//!   threshold when the level is sparse;
//! * BayesShrink: per level, `λ = σ²/σ_θ`, `σ_θ² = max(mean(y²) − σ², 0)`;
//! * empirical Bayes (Johnstone–Silverman): prior `(1−w)δ₀ + w·Laplace(a)`
//!   on `θ/σ`, `w` by marginal maximum likelihood, estimate = posterior median.
//!
//! The noise level σ is estimated by `median(|d₁|)/0.6745` on the finest level.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::error::{Result, WaveletError};
use crate::mode::Mode;
use crate::multilevel::{wavedec, waverec};
use crate::special::{mills_ratio, norm_cdf, norm_pdf, norm_quantile};
use crate::wavelet::Wavelet;

/// Shrinkage function `η(x, λ)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ThresholdFunction {
    /// `x·1{|x| ≥ λ}` (keep or kill).
    Hard,
    /// `sign(x)·max(|x| − λ, 0)`.
    #[default]
    Soft,
    /// Non-negative garrote `x − λ²/x` for `|x| ≥ λ`, else 0.
    Garrote,
}

impl ThresholdFunction {
    /// `η(x, λ)`, as `pywt.threshold(x, λ, mode)`.
    ///
    /// ```
    /// use gb_wavelet::ThresholdFunction;
    /// assert_eq!(ThresholdFunction::Soft.apply(3.0, 1.0), 2.0);
    /// assert_eq!(ThresholdFunction::Hard.apply(0.5, 1.0), 0.0);
    /// assert_eq!(ThresholdFunction::Garrote.apply(2.0, 1.0), 1.5);
    /// ```
    #[inline]
    pub fn apply(self, x: f64, threshold: f64) -> f64 {
        let m = x.abs();
        if m < threshold || m == 0.0 {
            return 0.0;
        }
        match self {
            ThresholdFunction::Hard => x,
            ThresholdFunction::Soft => x.signum() * (m - threshold),
            ThresholdFunction::Garrote => x - threshold * threshold / x,
        }
    }

    /// Applies `η(·, λ)` in place.
    pub fn apply_in_place(self, data: &mut [f64], threshold: f64) {
        for v in data {
            *v = self.apply(*v, threshold);
        }
    }
}

impl FromStr for ThresholdFunction {
    type Err = WaveletError;
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "hard" => Ok(Self::Hard),
            "soft" => Ok(Self::Soft),
            "garrote" | "garotte" => Ok(Self::Garrote),
            _ => Err(WaveletError::UnknownThresholdFunction(s.to_string())),
        }
    }
}

impl fmt::Display for ThresholdFunction {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Hard => "hard",
            Self::Soft => "soft",
            Self::Garrote => "garrote",
        })
    }
}

/// How the threshold of each detail level is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ThresholdRule {
    /// VisuShrink: `σ√(2 ln N)` on every level.
    Universal,
    /// SureShrink (hybrid SURE / universal), per level.
    Sure,
    /// BayesShrink, per level.
    Bayes,
    /// Johnstone–Silverman empirical Bayes posterior median (Laplace prior), per level.
    EmpiricalBayes,
}

impl FromStr for ThresholdRule {
    type Err = WaveletError;
    /// `universal`/`visu`, `sure`, `bayes`/`bayesshrink`, `ebayes`/`empirical-bayes`.
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "universal" | "visu" | "visushrink" => Ok(Self::Universal),
            "sure" | "sureshrink" => Ok(Self::Sure),
            "bayes" | "bayesshrink" => Ok(Self::Bayes),
            "ebayes" | "empirical-bayes" | "empiricalbayes" | "eb" | "ebayesthresh" => {
                Ok(Self::EmpiricalBayes)
            }
            _ => Err(WaveletError::UnknownThresholdRule(s.to_string())),
        }
    }
}

impl fmt::Display for ThresholdRule {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Universal => "universal",
            Self::Sure => "sure",
            Self::Bayes => "bayes",
            Self::EmpiricalBayes => "ebayes",
        })
    }
}

/// `Φ⁻¹(3/4)`: the MAD of a standard normal.
const MAD_NORMAL: f64 = 0.674_489_750_196_081_7;

fn median_in_place(v: &mut [f64]) -> f64 {
    let n = v.len();
    if n == 0 {
        return 0.0;
    }
    v.sort_unstable_by(|a, b| a.total_cmp(b));
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Noise level from the finest detail coefficients: `σ̂ = median(|d|)/0.6745`.
///
/// ```
/// let s = gb_wavelet::noise_sigma(&[1.0, -2.0, 3.0]);
/// assert!((s - 2.0 / 0.6744897501960817).abs() < 1e-12);
/// ```
pub fn noise_sigma(finest_detail: &[f64]) -> f64 {
    let mut abs: Vec<f64> = finest_detail.iter().map(|v| v.abs()).collect();
    median_in_place(&mut abs) / MAD_NORMAL
}

/// Universal threshold `σ√(2 ln n)`.
pub fn universal_threshold(sigma: f64, n: usize) -> f64 {
    sigma * (2.0 * (n.max(1) as f64).ln()).sqrt()
}

/// Stein's unbiased risk estimate of soft thresholding at `t` for coefficients
/// `x` of unit noise: `n − 2#{|x_i| ≤ t} + Σ min(|x_i|, t)²`.
pub fn sure_risk(x: &[f64], t: f64) -> f64 {
    let n = x.len() as f64;
    let below = x.iter().filter(|v| v.abs() <= t).count() as f64;
    let clipped: f64 = x.iter().map(|v| v.abs().min(t).powi(2)).sum();
    n - 2.0 * below + clipped
}

/// The threshold in `[0, √(2 ln n)]` minimising [`sure_risk`] (unit noise),
/// found exactly in O(n log n): SURE is increasing between consecutive `|x_i|`
/// and drops at each, so the minimum is at `0` or some `|x_i|`.
pub fn sure_threshold(x: &[f64]) -> f64 {
    let n = x.len();
    if n == 0 {
        return 0.0;
    }
    let cap = (2.0 * (n as f64).ln()).sqrt();
    let mut sq: Vec<f64> = x.iter().map(|v| v * v).collect();
    sq.sort_unstable_by(|a, b| a.total_cmp(b));
    let mut best_t = 0.0;
    let mut best_risk = sure_risk_at_zero(&sq);
    let mut cum = 0.0;
    let mut k = 0;
    while k < n {
        // group ties
        let v = sq[k];
        let mut j = k;
        while j < n && sq[j] == v {
            cum += sq[j];
            j += 1;
        }
        let t = v.sqrt();
        if t > cap {
            break;
        }
        let risk = n as f64 - 2.0 * j as f64 + cum + (n - j) as f64 * v;
        if risk < best_risk {
            best_risk = risk;
            best_t = t;
        }
        k = j;
    }
    best_t
}

fn sure_risk_at_zero(sorted_sq: &[f64]) -> f64 {
    let zeros = sorted_sq.iter().take_while(|&&v| v == 0.0).count();
    sorted_sq.len() as f64 - 2.0 * zeros as f64
}

/// SureShrink's threshold for one level (unit noise): SURE, unless the level
/// is sparse — `(Σx² − n)/n ≤ (log₂ n)^{3/2}/√n` — then universal.
pub fn sure_shrink_threshold(x: &[f64]) -> f64 {
    let n = x.len() as f64;
    if x.is_empty() {
        return 0.0;
    }
    let energy = (x.iter().map(|v| v * v).sum::<f64>() - n) / n;
    let critical = n.log2().powf(1.5) / n.sqrt();
    if energy <= critical {
        (2.0 * n.ln()).sqrt()
    } else {
        sure_threshold(x)
    }
}

/// BayesShrink threshold `σ²/σ_θ` for one level (`max|y|` when `σ_θ = 0`).
pub fn bayes_shrink_threshold(y: &[f64], sigma: f64) -> f64 {
    if y.is_empty() {
        return 0.0;
    }
    let var_y = y.iter().map(|v| v * v).sum::<f64>() / y.len() as f64;
    let var_theta = (var_y - sigma * sigma).max(0.0);
    if var_theta <= 0.0 {
        y.iter().fold(0.0f64, |m, v| m.max(v.abs()))
    } else {
        sigma * sigma / var_theta.sqrt()
    }
}

/// Johnstone–Silverman empirical Bayes with a Laplace slab: prior
/// `(1−w)δ₀ + w·(a/2)e^{−a|θ|}` on unit-noise coefficients.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EmpiricalBayes {
    /// Mixing weight `w` of the slab (estimated).
    pub weight: f64,
    /// Laplace scale `a`.
    pub scale: f64,
}

impl EmpiricalBayes {
    /// `β(x) = g(x)/φ(x) − 1` with `g = γ ⋆ φ`:
    /// `β(x) = (a/2)[R(a−x) + R(a+x)] − 1`, `R` the Mills ratio.
    pub fn beta(x: f64, a: f64) -> f64 {
        let x = x.abs();
        0.5 * a * (mills_ratio(a - x) + mills_ratio(a + x)) - 1.0
    }

    /// Fits `w` by marginal maximum likelihood, `max_w Σ log(1 + wβ(x_i))`
    /// over `[w_min, 1]`, where `w_min` makes the posterior-median threshold
    /// equal the universal threshold `√(2 ln n)`. `a` is fixed (0.5 is the
    /// EbayesThresh default).
    pub fn fit(x: &[f64], a: f64) -> Result<Self> {
        if !(a > 0.0 && a.is_finite()) {
            return Err(WaveletError::InvalidParameter(format!(
                "Laplace scale must be positive, got {a}"
            )));
        }
        if x.is_empty() {
            return Ok(Self {
                weight: 1.0,
                scale: a,
            });
        }
        let betas: Vec<f64> = x.iter().map(|&v| Self::beta(v, a)).collect();
        let t_univ = (2.0 * (x.len() as f64).ln()).sqrt();
        let w_min = Self::weight_for_threshold(t_univ, a).clamp(1e-12, 1.0);
        // score S(w) = Σ β/(1+wβ) is decreasing in w.
        let score = |w: f64| -> f64 {
            betas
                .iter()
                .map(|&b| {
                    if b.is_finite() {
                        b / (1.0 + w * b)
                    } else {
                        1.0 / w
                    }
                })
                .sum()
        };
        let weight = if score(1.0) >= 0.0 {
            1.0
        } else if score(w_min) <= 0.0 {
            w_min
        } else {
            let (mut lo, mut hi) = (w_min, 1.0);
            for _ in 0..100 {
                let mid = 0.5 * (lo + hi);
                if score(mid) > 0.0 {
                    lo = mid;
                } else {
                    hi = mid;
                }
                if hi - lo < 1e-14 * hi {
                    break;
                }
            }
            0.5 * (lo + hi)
        };
        Ok(Self { weight, scale: a })
    }

    /// The `w` whose posterior median has threshold `t`. The median vanishes
    /// while `Φ⁻¹(ζ(x)) ≥ x − a`, so at the threshold `ζ(t) = Φ(t−a)`, i.e.
    /// `1/w = a·Φ(t−a)/φ(t−a) − β(t) = a·R(a−t) − β(t)`.
    pub fn weight_for_threshold(t: f64, a: f64) -> f64 {
        let inv = a * mills_ratio(a - t) - Self::beta(t, a);
        if inv.is_finite() && inv > 1.0 {
            1.0 / inv
        } else {
            1.0
        }
    }

    /// Posterior median of `θ` given `x` (unit noise): for `x ≥ 0`,
    /// `max(0, x − a − Φ⁻¹(ζ))`, `ζ = φ(x−a)(1/w + β(x))/a`, odd in `x`.
    pub fn posterior_median(&self, x: f64) -> f64 {
        let (w, a) = (self.weight, self.scale);
        let s = x.signum();
        let x = x.abs();
        let xma = x - a;
        // ζ written without overflow: φ(xma)R(−xma) = Φ(xma).
        let zeta = (norm_pdf(xma) * (1.0 / w - 1.0)
            + 0.5 * a * (norm_cdf(xma) + norm_pdf(xma) * mills_ratio(x + a)))
            / a;
        let correction = if zeta >= 1.0 {
            f64::INFINITY
        } else {
            norm_quantile(zeta)
        };
        s * (xma - correction).max(0.0)
    }

    /// The threshold below which the posterior median is zero (bisection).
    pub fn threshold(&self) -> f64 {
        let (mut lo, mut hi) = (0.0, 40.0);
        if self.posterior_median(hi) == 0.0 {
            return hi;
        }
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if self.posterior_median(mid) == 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        hi
    }
}

/// Options for [`denoise_with`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DenoiseOptions {
    /// Threshold rule.
    pub rule: ThresholdRule,
    /// Shrinkage function (ignored by the empirical-Bayes rule, which uses its
    /// posterior median).
    pub function: ThresholdFunction,
    /// Extension mode.
    pub mode: Mode,
    /// Decomposition level (`None`: [`Wavelet::max_level`]).
    pub level: Option<usize>,
    /// Known noise level (`None`: estimated from the finest level).
    pub sigma: Option<f64>,
}

impl DenoiseOptions {
    /// Soft thresholding at the maximum level with estimated σ.
    pub fn new(rule: ThresholdRule, mode: Mode) -> Self {
        Self {
            rule,
            function: ThresholdFunction::Soft,
            mode,
            level: None,
            sigma: None,
        }
    }
}

/// Result of [`denoise_with`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Denoised {
    /// The denoised signal (same length as the input).
    pub signal: Vec<f64>,
    /// Noise level used.
    pub sigma: f64,
    /// Threshold per detail level, coarse to fine (as `wavedec` orders them).
    pub thresholds: Vec<f64>,
    /// Thresholded coefficients `[a_J, d_J, …, d₁]`.
    pub coefficients: Vec<Vec<f64>>,
}

/// Wavelet denoising: decompose, threshold every detail level by `rule`
/// (soft), reconstruct.
///
/// ```
/// use gb_wavelet::{denoise, Mode, ThresholdRule, Wavelet};
/// let clean: Vec<f64> = (0..512).map(|i| if i < 256 { 1.0 } else { -1.0 }).collect();
/// let noisy: Vec<f64> = clean.iter().enumerate()
///     .map(|(i, c)| c + 0.1 * (((i * 7919) % 101) as f64 / 50.0 - 1.0)).collect();
/// let w = Wavelet::new("haar")?;
/// let rule: ThresholdRule = "sure".parse()?;
/// let y = denoise(&noisy, &w, rule, Mode::Periodization)?;
/// let err = |v: &[f64]| v.iter().zip(&clean).map(|(a, b)| (a - b).powi(2)).sum::<f64>();
/// assert!(err(&y) < err(&noisy));
/// # Ok::<(), gb_wavelet::WaveletError>(())
/// ```
pub fn denoise(
    signal: &[f64],
    wavelet: &Wavelet,
    rule: ThresholdRule,
    mode: Mode,
) -> Result<Vec<f64>> {
    Ok(denoise_with(signal, wavelet, &DenoiseOptions::new(rule, mode))?.signal)
}

/// Wavelet denoising with all options, returning thresholds and coefficients.
pub fn denoise_with(
    signal: &[f64],
    wavelet: &Wavelet,
    options: &DenoiseOptions,
) -> Result<Denoised> {
    if signal.iter().any(|v| !v.is_finite()) {
        return Err(WaveletError::NonFinite("signal"));
    }
    let mut coeffs = wavedec(signal, wavelet, options.mode, options.level)?;
    if coeffs.len() < 2 {
        return Ok(Denoised {
            signal: signal.to_vec(),
            sigma: options.sigma.unwrap_or(0.0),
            thresholds: Vec::new(),
            coefficients: coeffs,
        });
    }
    let sigma = match options.sigma {
        Some(s) if s >= 0.0 && s.is_finite() => s,
        Some(s) => return Err(WaveletError::InvalidParameter(format!("sigma = {s}"))),
        None => noise_sigma(&coeffs[coeffs.len() - 1]),
    };
    let mut thresholds = Vec::with_capacity(coeffs.len() - 1);
    for band in coeffs.iter_mut().skip(1) {
        if sigma == 0.0 {
            thresholds.push(0.0);
            continue;
        }
        let t = match options.rule {
            ThresholdRule::Universal => universal_threshold(sigma, signal.len()),
            ThresholdRule::Sure => {
                let unit: Vec<f64> = band.iter().map(|v| v / sigma).collect();
                sigma * sure_shrink_threshold(&unit)
            }
            ThresholdRule::Bayes => bayes_shrink_threshold(band, sigma),
            ThresholdRule::EmpiricalBayes => {
                let unit: Vec<f64> = band.iter().map(|v| v / sigma).collect();
                let eb = EmpiricalBayes::fit(&unit, 0.5)?;
                for (v, u) in band.iter_mut().zip(&unit) {
                    *v = sigma * eb.posterior_median(*u);
                }
                thresholds.push(sigma * eb.threshold());
                continue;
            }
        };
        options.function.apply_in_place(band, t);
        thresholds.push(t);
    }
    let mut out = waverec(&coeffs, wavelet, options.mode)?;
    out.truncate(signal.len());
    Ok(Denoised {
        signal: out,
        sigma,
        thresholds,
        coefficients: coeffs,
    })
}
