//! The crate's error type.

use thiserror::Error;

/// Everything that can go wrong in `gb-wavelet`.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum WaveletError {
    /// The wavelet name is not one of [`crate::Wavelet::available`].
    #[error("unknown wavelet `{0}` (try db1..db38, sym2..sym20, coif1..coif17, bior*.*, rbio*.*, haar, cdf53, cdf97)")]
    UnknownWavelet(String),
    /// The extension mode name is not recognised.
    #[error("unknown extension mode `{0}` (expected periodization, symmetric, zero, constant or periodic)")]
    UnknownMode(String),
    /// The threshold rule name is not recognised.
    #[error("unknown threshold rule `{0}` (expected sure, universal, bayes or ebayes)")]
    UnknownThresholdRule(String),
    /// The threshold function name is not recognised.
    #[error("unknown threshold function `{0}` (expected hard, soft or garrote)")]
    UnknownThresholdFunction(String),
    /// The entropy cost name is not recognised.
    #[error("unknown cost `{0}` (expected shannon, log-energy, threshold or norm)")]
    UnknownCost(String),
    /// A signal or coefficient array was empty.
    #[error("empty input: {0}")]
    EmptyInput(&'static str),
    /// A user-supplied filter is invalid.
    #[error("invalid filter: {0}")]
    InvalidFilter(String),
    /// An output or scratch buffer has the wrong length.
    #[error("buffer `{name}` has length {got}, expected {expected}")]
    BufferLength {
        /// Which buffer.
        name: &'static str,
        /// The length required.
        expected: usize,
        /// The length supplied.
        got: usize,
    },
    /// Coefficient arrays do not fit together (e.g. approximation and detail lengths differ).
    #[error("coefficient shape mismatch: {0}")]
    ShapeMismatch(String),
    /// The coefficients are too short to reconstruct with this filter in this mode.
    #[error("coefficients of length {coeff_len} are too short for a filter of length {filter_len} in this mode")]
    TooShort {
        /// Coefficient length.
        coeff_len: usize,
        /// Filter length.
        filter_len: usize,
    },
    /// A numeric parameter is out of its domain.
    #[error("invalid parameter: {0}")]
    InvalidParameter(String),
    /// A non-finite value (NaN or infinity) was found in the input.
    #[error("non-finite value in input: {0}")]
    NonFinite(&'static str),
}

/// Result alias for this crate.
pub type Result<T> = std::result::Result<T, WaveletError>;
