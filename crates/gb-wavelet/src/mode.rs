//! Signal extension modes at the boundaries.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::error::WaveletError;

/// How a finite signal `x[0..N]` is extended beyond its ends before filtering,
/// with the same coefficient layout as PyWavelets' modes of the same name.
///
/// | mode | `x[-1], x[-2], …` | `x[N], x[N+1], …` | coefficients per level |
/// |---|---|---|---|
/// | `Zero` | `0, 0` | `0, 0` | `⌊(N+F−1)/2⌋` |
/// | `Constant` | `x[0], x[0]` | `x[N−1], x[N−1]` | `⌊(N+F−1)/2⌋` |
/// | `Symmetric` | `x[0], x[1]` | `x[N−1], x[N−2]` | `⌊(N+F−1)/2⌋` |
/// | `Periodic` | `x[N−1], x[N−2]` | `x[0], x[1]` | `⌊(N+F−1)/2⌋` |
/// | `Periodization` | circular (odd `N`: `x[N−1]` appended first) | | `⌈N/2⌉` |
///
/// `Periodization` is the orthogonal (non-redundant) transform.
///
/// ```
/// use gb_wavelet::Mode;
/// let m: Mode = "periodization".parse().unwrap();
/// assert_eq!(m, Mode::Periodization);
/// assert_eq!(m.to_string(), "periodization");
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Zero padding.
    Zero,
    /// Repeat the border values.
    Constant,
    /// Half-sample symmetric reflection (PyWavelets' default).
    #[default]
    Symmetric,
    /// Periodic extension (redundant: `⌊(N+F−1)/2⌋` coefficients).
    Periodic,
    /// Circular convolution with `⌈N/2⌉` coefficients (orthogonal transform).
    Periodization,
}

impl Mode {
    /// All supported modes.
    pub const ALL: [Mode; 5] = [
        Mode::Zero,
        Mode::Constant,
        Mode::Symmetric,
        Mode::Periodic,
        Mode::Periodization,
    ];

    /// The PyWavelets name of the mode.
    pub fn name(self) -> &'static str {
        match self {
            Mode::Zero => "zero",
            Mode::Constant => "constant",
            Mode::Symmetric => "symmetric",
            Mode::Periodic => "periodic",
            Mode::Periodization => "periodization",
        }
    }
}

impl fmt::Display for Mode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Mode {
    type Err = WaveletError;

    /// Parses the PyWavelets names (and their MATLAB aliases `zpd`, `sp0`, `sym`, `ppd`, `per`).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "zero" | "zpd" => Ok(Mode::Zero),
            "constant" | "sp0" => Ok(Mode::Constant),
            "symmetric" | "sym" | "symh" => Ok(Mode::Symmetric),
            "periodic" | "ppd" => Ok(Mode::Periodic),
            "periodization" | "per" => Ok(Mode::Periodization),
            _ => Err(WaveletError::UnknownMode(s.to_string())),
        }
    }
}
