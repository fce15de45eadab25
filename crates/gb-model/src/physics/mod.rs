//! "State your physics": the engineer's continuous-time state-space model
//! with named states, inputs, outputs and parameters,
//!
//! ```text
//! ẋ = f(x, u, θ),    y = g(x, u, θ),
//! ```
//!
//! the equations written as expressions (each a list of additive terms),
//! discretised by classical RK4 with N sub-steps per sample under
//! zero-order hold of the input, fitted by output error with the
//! workspace's Levenberg–Marquardt solver, with standard errors, 95 %
//! intervals, correlations and identifiability warnings from `JᵀJ` at the
//! optimum, and prediction bands from the parameter covariance.
//!
//! * [`PhysicsSpec`]: the model in Rust ([`State`], [`Parameter`],
//!   [`Prior`], [`Output`]); [`ModelFile`]: the same in TOML.
//! * [`PhysicsFitParams`] → [`PhysicsFit`] (`gb_core::Identify`) →
//!   [`PhysicsModel`] (`gb_core::DynamicModel`, class tag `physics`) with
//!   its [`FitReport`].
//! * [`PhysicsModel::prediction_bands`] / [`prediction_bands`]: 95 %
//!   prediction bands.
//!
//! Sensitivities `∂y/∂θ` come from the forward sensitivity equations
//! `Ṡ = f_x S + f_θ`, integrated by the same RK4 steps, with `f_x S + f_θ`
//! evaluated by forward-mode differentiation of the compiled expressions
//! (`tape`; see its docs for why the tape and not exmex's evaluator, and
//! how exmex's symbolic `partial` checks it). See `docs/physics.md`.
//!
//! ```
//! use gb_model::physics::*;
//! let spec = PhysicsSpec::new("first order")
//!     .input("u")
//!     .parameter(Parameter::new("a", 2.0).bounds(0.0, 10.0))
//!     .state(State::new("x", 0.0), "-a*x + u")
//!     .output("y", "x")
//!     .sample_time(0.1)
//!     .substeps(2);
//! let m = PhysicsModel::new(spec).unwrap();
//! let y = gb_core::DynamicModel::simulate(&m, &[vec![1.0; 50]], gb_core::Init::Rest).unwrap();
//! assert!((y[49] - 0.5).abs() < 1e-3); // steady state u/a
//! ```
mod bands;
mod error;
mod file;
mod fit;
mod identify;
mod model;
mod simulate;
mod smc;
mod spec;
mod tape;
#[cfg(test)]
mod tests;

pub use bands::{prediction_bands, BandParams, Bands};
pub use error::{Item, Location, PhysicsError, PhysicsResult};
pub use file::ModelFile;
pub use fit::{t_quantile_95, Coordinate, Estimate, FitReport, ILL_CONDITIONED, ZERO_SENSITIVITY};
pub use identify::{PhysicsFit, PhysicsFitParams};
pub use model::{PhysicsModel, StateNoise, CLASS};
pub use spec::{Output, Parameter, PhysicsSpec, Prior, State, StateHysteresis, TermTarget};

impl PhysicsModel {
    /// The model with its signal names, sample time and Gaussian noise of
    /// the fit's σ̂ (σ = 0 before a fit), ready to save.
    pub fn to_fitted(&self) -> PhysicsResult<gb_core::FittedModel> {
        let spec = self.spec();
        // a noise-free fit still needs a valid (positive) noise model
        let sd = self.fit_report().map_or(0.0, |f| f.sigma).max(1e-300);
        let mut m = gb_core::FittedModel::new(
            spec.inputs.clone(),
            spec.outputs.iter().map(|o| o.name.clone()).collect(),
            Box::new(self.clone()),
            gb_core::NoiseModel::Gaussian { sd },
        )?;
        m.sample_time = spec.sample_time;
        Ok(m)
    }
}
