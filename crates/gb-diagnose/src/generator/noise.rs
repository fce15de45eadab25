//! Output and process noise of the generated cases.
use super::excite::lowpass_noise;
use gb_core::CoreError;
use rand::Rng;
use rand_distr::{Distribution, StandardNormal, StudentT};
use serde::{Deserialize, Serialize};

/// The noise put into a case.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum NoiseKind {
    /// White Gaussian output noise.
    White,
    /// White Student-t output noise with `nu` degrees of freedom, scaled to
    /// the nominal standard deviation.
    StudentT {
        /// Degrees of freedom.
        nu: f64,
    },
    /// ARMA(1,1)-filtered Gaussian output noise e(k) = a·e(k−1) + w(k) + c·w(k−1),
    /// scaled to the nominal standard deviation.
    Coloured {
        /// AR coefficient.
        a: f64,
        /// MA coefficient.
        c: f64,
    },
    /// A low-pass filtered Gaussian force entering the dynamics (cut-off
    /// `cutoff` cycles/sample), sized so that its effect on the output has
    /// the nominal standard deviation, plus white output noise of a third of it.
    Process {
        /// Cut-off of the force disturbance (cycles/sample).
        cutoff: f64,
    },
}

impl NoiseKind {
    /// Short description.
    pub fn describe(&self) -> String {
        match self {
            Self::White => "white Gaussian output noise".into(),
            Self::StudentT { nu } => format!("Student-t (nu {nu:.2}) output noise"),
            Self::Coloured { a, c } => format!("ARMA(1,1) output noise (a {a:.2}, c {c:.2})"),
            Self::Process { cutoff } => {
                format!("process noise: low-pass force (cut-off {cutoff:.3} cycles/sample)")
            }
        }
    }
}

/// White Gaussian noise of standard deviation `sigma`.
pub(crate) fn white(n: usize, sigma: f64, r: &mut impl Rng) -> Vec<f64> {
    (0..n)
        .map(|_| {
            let e: f64 = StandardNormal.sample(r);
            sigma * e
        })
        .collect()
}

/// Output noise of kind `kind` (not `Process`) with nominal std `sigma`.
pub(crate) fn output_noise(
    kind: NoiseKind,
    n: usize,
    sigma: f64,
    r: &mut impl Rng,
) -> Result<Vec<f64>, CoreError> {
    Ok(match kind {
        NoiseKind::White | NoiseKind::Process { .. } => white(n, sigma, r),
        NoiseKind::StudentT { nu } => {
            let t = StudentT::new(nu).map_err(|e| CoreError::InvalidArgument(e.to_string()))?;
            let scale = sigma * ((nu - 2.0) / nu).sqrt();
            (0..n).map(|_| scale * t.sample(r)).collect()
        }
        NoiseKind::Coloured { a, c } => {
            let (mut e, mut w_prev) = (0.0, 0.0);
            let warm = 200;
            let mut out = Vec::with_capacity(n);
            for k in 0..n + warm {
                let w: f64 = StandardNormal.sample(r);
                e = a * e + w + c * w_prev;
                w_prev = w;
                if k >= warm {
                    out.push(e);
                }
            }
            // stationary variance of ARMA(1,1): (1 + 2ac + c²) / (1 − a²)
            let s = ((1.0 + 2.0 * a * c + c * c) / (1.0 - a * a)).sqrt();
            out.iter_mut().for_each(|v| *v *= sigma / s);
            out
        }
    })
}

/// A unit-rms low-pass force disturbance.
pub(crate) fn process_force(n: usize, cutoff: f64, r: &mut impl Rng) -> Vec<f64> {
    lowpass_noise(n, cutoff, r)
}
