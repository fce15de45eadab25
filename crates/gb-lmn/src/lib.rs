//! # gb-lmn
//!
//! Local model networks for dynamic systems, trained for **simulation**
//! (output error, NOE):
//!
//! ŷ(k) = Σᵢ Φᵢ(z(k)) · [1, x(k)]ᵀ θᵢ + h(k)ᵀ β
//!
//! where x(k) holds delayed simulated outputs ŷ(k−1…k−n_a) and delayed inputs,
//! z(k) ⊂ x(k) spans the partition (regime) space, Φᵢ are normalised Gaussian
//! validity functions (LOLIMOT, Nelles 2001) and h(k) are optional global
//! hysteresis columns (play operators from `gb-preisach` on the simulated
//! output and on the inputs) whose weights β enter linearly.
//!
//! A single leaf gives the linear output-error model (OE / ARX structure with
//! offset). Training: least squares initialisation, then Levenberg–Marquardt on
//! the simulation error with analytic sensitivities propagated through time
//! ([`noe`]), rejecting unstable parameter sets. Every Levenberg–Marquardt
//! fit of the crate is a [`gb_core::solver::LeastSquaresProblem`] driven by
//! the workspace's one solver, [`gb_core::solver::LevenbergMarquardt`];
//! long fits report to a [`gb_core::Observer`].
//!
//! The full network of issue 3 is [`LmnModel`], built by [`LmnParams`]:
//! separate local-model space x and partition space z from per-signal tapped
//! delays ([`RegressorSpec`]), affine or polynomial (degree ≤ 3) local models
//! plus user columns, normalised Gaussian or decision-tree sigmoid weights
//! ([`WeightKind`]), axis or oblique (HILOMOT) splits ([`SplitKind`]),
//! termination by AICc/BIC/validation ([`Criterion`]), pruning, and global
//! Levenberg–Marquardt for one-step or simulation error ([`Focus`]); several
//! experiments per fit (every [`gb_core::Record`] of a [`gb_core::Records`]
//! is one). See docs/lmn.md.
//!
//! [`ssnet`] is the state-space counterpart with hidden states, a √ basis and
//! state saturation, x⁺ = min(Σᵢ Φᵢ(z)[Aᵢx + Gᵢ√x₊ + Bᵢu + cᵢ], x̄),
//! ŷ = min(Cᵀx + d, ȳ) ([`fit_ss_lmn`], [`SsLmnParams`], [`SsLmnModel`]);
//! [`WienerHammersteinNetwork`] puts a one-dimensional network between two
//! linear filters ([`WhParams`]).
//!
//! Every model class implements [`gb_core::DynamicModel`] (simulation from
//! an [`gb_core::Init`], stepping one sample at a time, encoding); the
//! validated parameters of the tree network ([`ValidLmnParams`]), the
//! input–output network ([`ValidIoNetworkParams`]), the Wiener–Hammerstein
//! network ([`WhFitter`]) and the state-space network ([`ValidSsLmnParams`])
//! implement [`gb_core::Identify`] on [`gb_core::Records`].
//!
//! ```
//! use gb_lmn::{NetworkSpec, fit_linear_oe, FitOptions};
//! // y(k) = 0.5 y(k-1) + u(k-1)
//! let u: Vec<f64> = (0..400).map(|k| ((k * 7919) % 13) as f64 - 6.0).collect();
//! let mut y = vec![0.0; 400];
//! for k in 1..400 { y[k] = 0.5 * y[k - 1] + u[k - 1]; }
//! let spec = NetworkSpec::linear(1, &[1]);
//! let model = fit_linear_oe(&spec, std::slice::from_ref(&u), &y, &FitOptions::default()).unwrap();
//! let sim = model.simulate_signals(&[u], &y[..1]).unwrap();
//! assert!(gb_core::metrics::nrmse(&y, &sim).unwrap() < 1e-6);
//! ```
#![warn(missing_docs)]
// Index loops mirror the subscripts of the formulas they implement.
#![allow(clippy::needless_range_loop)]

mod block;
mod dynamic;
mod hilomot;
mod io_network;
mod lmn;
mod lolimot;
mod narx;
mod network;
pub mod noe;
pub mod poly;
mod prune;
mod regressors;
mod scaling;
mod separable;
mod spec;
pub mod ssnet;
mod steiglitz;
pub mod tree;
mod views;
mod wiener_hammerstein;

pub use block::{BlockModel, BlockParams, MapBasis, StaticMap, ValidBlockParams};
pub use hilomot::{LmnParams, SplitKind, ValidLmnParams};
pub use io_network::{
    half_range, HysteresisOn, IoNetworkParams, ValidIoNetworkParams, WarmStart, MAX_IO_ORDER,
};
pub use lmn::{Criterion, FitSummary, Focus, LmnModel, SplitInfo};
pub use lolimot::{
    fit_lmn_oe, fit_lmn_oe_records, fit_lolimot, fit_lolimot_records, LolimotOptions,
    TerminationCriterion,
};
pub use narx::RefineReport;
pub use network::{Leaf, LocalModelNetwork};
pub use noe::{
    criterion_rms, embed_hysteresis, embed_linear, fit_linear_oe, fit_linear_oe_records,
    fit_linear_oe_warm, fit_linear_oe_warm_records, fixed_pole_start, fixed_pole_start_records,
    refine_output_error, refine_output_error_records, refine_output_error_with_observer,
    zero_linear_network, Experiment, FitOptions, TrainReport,
};
pub use poly::{PolyNarx, PolyParams, ValidPolyParams};
pub use regressors::{RegressorSpec, Signal, Tap};
pub use scaling::Scaling;
pub use spec::NetworkSpec;
pub use ssnet::{
    fit_ss_lmn, fit_ss_lmn_with_observer, Scheduling, SsLmnFit, SsLmnModel, SsLmnParams,
    ValidSsLmnParams,
};
pub use tree::{Partition, WeightKind};
pub use wiener_hammerstein::{
    StaticNetwork, WhFitter, WhParams, WhReport, WienerHammersteinNetwork,
};

/// Errors of the local-model-network crate.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LmnError {
    /// Not enough samples for the requested structure.
    #[error("{needed} samples are needed for this model structure, got {got}")]
    TooShort {
        /// Samples needed.
        needed: usize,
        /// Samples given.
        got: usize,
    },
    /// Signals of inconsistent sizes.
    #[error("dimension mismatch: {0}")]
    Dimension(String),
    /// Invalid structure or option.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// No stable model could be found.
    #[error("no stable model found: {0}")]
    Unstable(String),
    /// A linear system could not be solved.
    #[error("numerical failure: {0}")]
    Numerical(String),
}

impl From<LmnError> for gb_core::CoreError {
    fn from(e: LmnError) -> Self {
        match e {
            LmnError::Unstable(m) => gb_core::CoreError::Unstable(m),
            other => gb_core::CoreError::InvalidArgument(other.to_string()),
        }
    }
}
