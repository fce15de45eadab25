//! # greybox
//!
//! Grey-box identification of nonlinear dynamical systems, after J. Hauth,
//! *Grey-Box Modelling for Nonlinear Systems* (TU Kaiserslautern, 2008).
//! This umbrella crate re-exports the workspace crates:
//!
//! - [`core`]: data sets, CSV I/O, metrics, model traits
//! - [`wavelet`]: fast wavelet transforms, thresholding, sparse coefficients
//! - [`smc`]: particle filters, smoothers, parameter estimation
//! - [`preisach`]: Preisach and Prandtl–Ishlinskii hysteresis
//! - [`lmn`]: local model networks (LOLIMOT) trained for simulation
//! - [`model`]: the wavelet-sparse grey-box state-space class
//! - [`diagnose`]: residual tests, cause naming, model extension, gain
//!
//! ```
//! use greybox::diagnose::systems;
//! let g = systems::generate("linear", 1, 500, 300).unwrap();
//! assert_eq!(g.expected_cause, None);
//! ```
pub use gb_core as core;
pub use gb_diagnose as diagnose;
pub use gb_lmn as lmn;
pub use gb_model as model;
pub use gb_preisach as preisach;
pub use gb_smc as smc;
pub use gb_wavelet as wavelet;
