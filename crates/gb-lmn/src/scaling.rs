use serde::{Deserialize, Serialize};

/// Affine normalisation v_n = (v − offset) / scale applied to every signal
/// before identification, so that conditioning and regularisation do not
/// depend on physical units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Scaling {
    /// Subtracted offset (the fit data's mean).
    pub offset: f64,
    /// Divisor (the fit data's standard deviation, 1 if that is 0).
    pub scale: f64,
}

impl Scaling {
    /// Every signal of `u` mapped by its own scaling: `(uⱼ − offsetⱼ) / scaleⱼ`.
    pub fn normalise_all(scalings: &[Scaling], u: &[Vec<f64>]) -> Vec<Vec<f64>> {
        u.iter()
            .zip(scalings)
            .map(|(s, sc)| s.iter().map(|&v| sc.to_norm(v)).collect())
            .collect()
    }

    /// Scaling from a signal's mean and standard deviation.
    pub fn of(x: &[f64]) -> Self {
        let m = gb_core::metrics::mean(x);
        let s = gb_core::metrics::std(x);
        Self {
            offset: m,
            scale: if s > 0.0 && s.is_finite() { s } else { 1.0 },
        }
    }
    /// Normalise one value.
    #[inline]
    pub fn to_norm(&self, v: f64) -> f64 {
        (v - self.offset) / self.scale
    }
    /// Undo the normalisation.
    #[inline]
    pub fn from_norm(&self, v: f64) -> f64 {
        v * self.scale + self.offset
    }
}
