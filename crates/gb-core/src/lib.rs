//! # gb-core
//!
//! The base of the greybox workspace: measured data ([`DataSet`]), CSV
//! input/output with precise error messages ([`CsvTable`]), goodness-of-fit
//! metrics ([`metrics`]), the [`Simulate`] / [`Model`] traits every model class
//! implements, reproducible random streams ([`rng`]) and the crate error
//! ([`CoreError`]).
//!
//! ```
//! use gb_core::{DataSet, metrics};
//! let ds = DataSet::new(vec!["u".into()], "y".into(), vec![vec![0.0, 1.0, 2.0]], vec![0.0, 1.0, 2.5]).unwrap();
//! assert_eq!(ds.len(), 3);
//! let e = metrics::nrmse(&ds.output, &[0.0, 1.0, 2.0]).unwrap();
//! assert!(e > 0.0 && e < 0.5);
//! ```
#![warn(missing_docs)]
// Index loops mirror the subscripts of the formulas they implement.
#![allow(clippy::needless_range_loop)]

mod csv_io;
mod data;
mod error;
pub mod metrics;
mod model;
pub mod rng;
pub mod special;

pub use csv_io::{write_atomic, write_csv_atomic, CsvTable};
pub use data::{benchmark_data_dir, BlockSplit, DataSet};
pub use error::CoreError;
pub use model::{Model, Simulate};
