//! # gb-preisach
//!
//! Rate-independent hysteresis: the Preisach model evaluated exactly through
//! its primitive (Everett) function, the relay-grid form as a cross-check,
//! identification of a nonparametric Everett function by linear least
//! squares, play / stop / generalised play operators and the
//! Prandtl–Ishlinskii model with its exact inverse.
//!
//! References: I. D. Mayergoyz, *Mathematical Models of Hysteresis and their
//! Applications*, 2003; D. H. Everett, Trans. Faraday Soc. 1955;
//! M. Brokate and J. Sprekels, *Hysteresis and Phase Transitions*, 1996;
//! M. A. Krasnosel'skii and A. V. Pokrovskii, *Systems with Hysteresis*, 1989;
//! J. Hauth, *Grey-Box Modelling for Nonlinear Systems*, TU Kaiserslautern,
//! 2008 (the Everett/primitive-function trick making Preisach linear in its
//! parameters).
//!
//! Tour:
//! * [`Preisach`] with any [`Everett`] function — [`ParametricEverett`]
//!   (Gaussian / Lorentzian closed forms) or [`GridEverett`] (triangular
//!   grid, bilinear) — and caller-owned [`PreisachState`] memory of
//!   alternating dominant extrema; [`InitialState`] for the start.
//! * [`RelayGrid`]: the discrete relay model, a cross-check.
//! * [`fit_grid_preisach`]: regularised / non-negative least squares for the
//!   grid Everett function from any input/output record;
//!   [`fit_prandtl_ishlinskii`] likewise for PI weights.
//! * [`HysteresisRegressor`]: regressor columns and their derivatives
//!   ([`GridPreisachRegressor`], [`PlayOperatorBank`], [`StopOperatorBank`]).
//! * [`PlayOperator`], [`StopOperator`], [`GeneralizedPlay`],
//!   [`PrandtlIshlinskii`] with [`PrandtlIshlinskii::inverse`].
//!
//! See `docs/preisach.md` for the mathematics, tests and benchmarks.
//!
//! ```
//! use gb_preisach::PlayOperatorBank;
//! let bank = PlayOperatorBank::new(vec![0.0, 0.5]).unwrap();
//! let cols = bank.apply(&[0.0, 1.0, 0.8, 0.0]);
//! assert_eq!(cols[0], vec![0.0, 1.0, 0.8, 0.0]); // r = 0 is the identity
//! assert_eq!(cols[1], vec![0.0, 0.5, 0.5, 0.5]); // backlash of half-width 0.5
//! ```
#![warn(missing_docs)]

mod everett;
mod identify;
mod pi;
mod play;
mod preisach;
mod regressor;
mod relay;
mod special;

pub use everett::{
    DensityCell, DensityShape, Everett, GridEverett, GridNode, ParametricEverett, ParametricNode,
};
pub use identify::{
    fit_grid_preisach, fit_prandtl_ishlinskii, FitOptions, PrandtlIshlinskiiFit, PreisachFit,
};
pub use pi::{Envelope, GeneralizedPlay, PrandtlIshlinskii, StopOperator, StopOperatorBank};
pub use play::{PlayOperator, PlayOperatorBank};
pub use preisach::{InitialState, Preisach, PreisachState};
pub use regressor::{GridPreisachRegressor, HysteresisRegressor, PlayBankState, Regressors};
pub use relay::{RelayCells, RelayCellsState, RelayGrid};

/// Errors of the Preisach crate.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PreisachError {
    /// An argument is out of its domain.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// A vector or matrix has the wrong size.
    #[error("dimension mismatch: expected {expected}, got {got}")]
    DimensionMismatch {
        /// Expected length.
        expected: usize,
        /// Actual length.
        got: usize,
    },
    /// A least-squares problem could not be solved.
    #[error("numerical failure: {0}")]
    Numerical(String),
}
