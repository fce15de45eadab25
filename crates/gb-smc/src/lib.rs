//! # gb-smc — sequential Monte Carlo for hidden states and parameters
//!
//! Particle filters (bootstrap, guided, auxiliary) with four resampling
//! schemes and adaptive resampling, unbiased likelihood estimates, smoothers
//! (FFBSm, backward simulation with an O(N) rejection sampler, fixed-lag),
//! particle marginal Metropolis–Hastings and iterated filtering (IF2), and
//! non-Gaussian noise families. Work is parallel over particles with rayon and
//! bit-identical for a given seed on any number of threads.
//!
//! See `docs/smc.md` for the mathematics and references.
//!
//! ```
//! use gb_smc::{FilterConfig, LinearGaussian, Observations, Resampling};
//! let model = LinearGaussian::ar1(0.9, 1.0, 0.5).unwrap();
//! let (_x, y) = model.simulate(200, 7);
//! let pf = FilterConfig::new(1000)
//!     .resampling(Resampling::Systematic)
//!     .ess_threshold(0.5)
//!     .seed(42)
//!     .build()
//!     .unwrap();
//! let out = pf.run(&model, &Observations::new(&y)).unwrap();
//! assert!(out.log_likelihood.is_finite());
//! assert_eq!(out.ess.len(), 200);
//! ```
#![warn(missing_docs)]

pub mod diagnostics;
pub mod error;
pub mod estimation;
pub mod filter;
pub mod kalman;
pub mod model;
pub mod models;
pub mod noise;
pub mod resampling;
pub mod rng;
pub mod smoothing;

pub use error::{Result, SmcError};
pub use filter::{
    summarise, weighted_quantiles, FilterConfig, FilterHistory, FilterKind, FilterOutput,
    FilterStep, FilterWorkspace, OnlineFilter, ParticleFilter, StepSummary,
};
pub use kalman::{KalmanFilter, KalmanOutput, LinearGaussian};
pub use model::{Observations, StateSpaceModel, StateVector, TransitionDensity};
pub use resampling::{ess, resample, Resampling};
pub use rng::SmcRng;
