//! The crate error.

/// Errors of the grey-box state-space crate.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ModelError {
    /// An argument, option or structure is out of its domain.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// Signals or matrices of inconsistent sizes.
    #[error("dimension mismatch: {0}")]
    Dimension(String),
    /// The simulation left the finite numbers (unstable model).
    #[error("simulation diverged at sample {0}")]
    Diverged(usize),
    /// A linear system could not be solved.
    #[error("numerical failure: {0}")]
    Numerical(String),
    /// A model file is not a grey-box state-space model or is corrupt.
    #[error("model file: {0}")]
    Format(String),
    /// From the wavelet crate.
    #[error(transparent)]
    Wavelet(#[from] gb_wavelet::WaveletError),
    /// From the SMC crate.
    #[error(transparent)]
    Smc(#[from] gb_smc::SmcError),
    /// From the Preisach crate.
    #[error(transparent)]
    Preisach(#[from] gb_preisach::PreisachError),
    /// From the local-model-network crate (linear initialisation).
    #[error(transparent)]
    Lmn(#[from] gb_lmn::LmnError),
    /// From the core crate (the solver's settings).
    #[error(transparent)]
    Core(#[from] gb_core::CoreError),
}

impl From<ModelError> for gb_core::CoreError {
    fn from(e: ModelError) -> Self {
        match e {
            ModelError::Core(e) => e,
            e => gb_core::CoreError::InvalidArgument(e.to_string()),
        }
    }
}

/// Result alias.
pub type Result<T> = std::result::Result<T, ModelError>;
