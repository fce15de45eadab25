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
//! use gb_diagnose::{diagnose, Cause, DiagnoseData, DiagnoseOptions, systems};
//! let g = systems::generate("bouc-wen", 1, 8000, 4000).unwrap();
//! let data = DiagnoseData::with_validation(g.train, g.validate).unwrap();
//! let d = diagnose(&data, &DiagnoseOptions::default(), None).unwrap();
//! assert_eq!(d.report.causes, [Cause::Hysteresis]);
//! ```
//!
//! The diagnosis is a loop over the [`EXTENSIONS`] registry: each
//! [`Extension`] tests one [`Cause`], proposes candidates for the current
//! model and fits them; the [`DecisionPolicy`] holds every threshold; the
//! [`Diagnosis`] keeps every accepted model's residuals, so the text
//! ([`Report::to_text`]), JSON and HTML ([`render_html`]) reports only render.
#![warn(missing_docs)]
// Index loops mirror the subscripts of the formulas they implement.
#![allow(clippy::needless_range_loop)]

mod baseline;
mod cause;
pub mod curves;
mod data;
mod decide;
mod diagnose;
mod evaluate;
pub mod evidence;
mod extension;
pub mod extensions;
pub mod generator;
pub mod html;
mod long;
mod physics;
mod plan;
mod policy;
mod refit;
mod repeat;
mod report;
mod select;
pub mod stats;
mod structure;
pub mod sweep;
pub mod systems;
mod verdict;

pub use baseline::{DelayRescan, StructureChoice};
pub use cause::Cause;
pub use data::{DiagnoseData, Part, TrainPart};
pub use diagnose::{diagnose, DiagnoseOptions, Diagnosis, OrderChoice};
pub use evaluate::{
    evaluate, residuals_on, select_residuals, Evaluated, Lineage, Residuals, Scores,
};
pub use evidence::Evidence;
pub use extension::{introducing, Context, Extension, GainMetric, Proposal, Role, EXTENSIONS};
pub use html::{render_html, render_html_outputs};
pub use policy::DecisionPolicy;
pub use report::{
    DataSummary, ModelSummary, NoiseFound, RecordSummary, Report, Step, REPORT_VERSION,
};
pub use select::{choose_structure, ChosenStructure};
pub use verdict::{white_noise_level, Verdict, VerdictKind};

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
