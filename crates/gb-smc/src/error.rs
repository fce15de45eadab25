//! The crate's error type.

/// Errors of `gb-smc`.
///
/// Numerical failures name the time step at which they happened, so a model
/// that cannot explain an observation is located instead of producing `NaN`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SmcError {
    /// Every particle weight was zero (log-weight `-inf`) at time step `t`:
    /// no particle can explain observation `t`.
    #[error("all particle weights are zero at time step {t}")]
    AllWeightsZero {
        /// The time step.
        t: usize,
    },
    /// A log-weight was `NaN` or `+inf` at time step `t` (a model bug, e.g. a
    /// zero observation variance).
    #[error("non-finite log-weight (NaN or +inf) at time step {t}")]
    InvalidLogWeight {
        /// The time step.
        t: usize,
    },
    /// A configuration or distribution parameter is out of range.
    #[error("invalid parameter `{name}` = {value}: {reason}")]
    InvalidParameter {
        /// Name of the parameter.
        name: &'static str,
        /// Offending value.
        value: f64,
        /// Why it is invalid.
        reason: &'static str,
    },
    /// The observation sequence is empty.
    #[error("no observations")]
    EmptyData,
    /// Two lengths that must agree do not.
    #[error("length mismatch for {what}: expected {expected}, got {got}")]
    LengthMismatch {
        /// What was measured.
        what: &'static str,
        /// Expected length.
        expected: usize,
        /// Actual length.
        got: usize,
    },
    /// Weights passed to a resampling routine are negative, non-finite or sum to zero.
    #[error("invalid resampling weights: {0}")]
    InvalidWeights(&'static str),
    /// Smoothing was asked for but the filter did not store its history.
    #[error("the filter history was not stored (set `store_history`)")]
    MissingHistory,
    /// The initial parameter vector has zero prior density or cannot build a model.
    #[error("the initial parameter vector is outside the prior support or rejected by the model")]
    InvalidInitialParameter,
}

/// Result alias of this crate.
pub type Result<T> = std::result::Result<T, SmcError>;

/// Validates `value` with `ok`, naming it in the error otherwise.
pub(crate) fn check(name: &'static str, value: f64, ok: bool, reason: &'static str) -> Result<()> {
    if ok {
        Ok(())
    } else {
        Err(SmcError::InvalidParameter {
            name,
            value,
            reason,
        })
    }
}
