//! # gb-diagnose
//!
//! Given measured data and the engineer's model (a linear output-error model
//! of order n), show what the free-run simulation gets wrong, name the cause
//! from a fixed vocabulary (`nonlinearity`, `hysteresis`, `dynamics`,
//! `noise`), extend the model accordingly, and measure the gain on held-out
//! data. A cause is only named when its extension pays significantly on
//! data not used for fitting (moving-block bootstrap interval of the gain
//! excluding zero, and a minimum effect size).
//!
//! ```no_run
//! use gb_diagnose::{diagnose, DiagnoseData, DiagnoseOptions, systems};
//! let g = systems::generate("bouc-wen", 1, 8000, 4000).unwrap();
//! let data = DiagnoseData::with_validation(g.train, g.validate).unwrap();
//! let d = diagnose(&data, &DiagnoseOptions::default(), None).unwrap();
//! assert_eq!(d.report.causes, ["hysteresis"]);
//! ```
#![warn(missing_docs)]
// Index loops mirror the subscripts of the formulas they implement.
#![allow(clippy::needless_range_loop)]

mod diagnose;
pub mod evidence;
pub mod generator;
pub mod html;
mod model;
pub mod stats;
pub mod sweep;
pub mod systems;

pub use diagnose::{
    diagnose, residuals_on, DataSummary, DiagnoseData, DiagnoseOptions, Diagnosis, ModelSummary,
    Observer, OrderChoice, Report, Scores, Step, CAUSES, EVAL_SKIP,
};
pub use evidence::Evidence;
pub use html::render_html;
pub use model::{GreyBoxModel, ModelFitOptions, Structure, MAX_ORDER, MODEL_FORMAT_VERSION};

/// Errors of the diagnosis crate.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DiagnoseError {
    /// Data or I/O problem.
    #[error(transparent)]
    Core(#[from] gb_core::CoreError),
    /// Model fitting problem.
    #[error(transparent)]
    Lmn(#[from] gb_lmn::LmnError),
    /// Hidden-state model problem.
    #[error(transparent)]
    StateSpace(#[from] gb_model::ModelError),
    /// Unknown model SPEC.
    #[error("unknown model spec '{0}' (known: linear, lmn, linear+preisach, lmn+preisach, each optionally +student-t)")]
    UnknownSpec(String),
    /// Model file problem.
    #[error("{0}")]
    ModelFile(String),
    /// Invalid argument.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// The HTML report could not be drawn.
    #[error("report: {0}")]
    Report(String),
}
