//! # gb-core
//!
//! The base of the greybox workspace: measured data ([`Record`],
//! [`Records`]), CSV input/output with precise error messages
//! ([`CsvTable`]), goodness-of-fit metrics ([`metrics`]), the traits every
//! model class implements ([`DynamicModel`], [`Identify`]), the fitted-model
//! envelope and its file format ([`FittedModel`]), the noise model
//! ([`NoiseModel`]), the one Levenberg–Marquardt [`solver`], the one
//! [`Observer`] of long work, reproducible random streams ([`rng`]) and the
//! crate error ([`CoreError`]).
//!
//! ```
//! use gb_core::{Record, metrics};
//! let ds = Record::new(vec!["u".into()], "y".into(), vec![vec![0.0, 1.0, 2.0]], vec![0.0, 1.0, 2.5]).unwrap();
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
mod fitted;
pub mod gram;
pub mod integrated;
pub mod metrics;
mod model;
pub mod noise;
mod observe;
pub mod rng;
pub mod solver;
mod spec;
pub mod special;

pub use csv_io::{write_atomic, write_csv_atomic, CsvTable};
pub use data::{
    benchmark_data_dir, index_like, output_like, BlockSplit, Record, Records, INDEX_COLUMNS,
};
pub use error::CoreError;
pub use fitted::{
    decode_postcard, ClassDecoder, FittedModel, MODEL_FILE_MAGIC, MODEL_FORMAT_VERSION,
};
pub use model::{
    check_inputs, DynamicModel, Identify, Init, ModelView, Series, Stepper, ViewData, Workspace,
};
pub use noise::NoiseModel;
pub use observe::{IterationInfo, Observer, Silent, SubTask};
pub use spec::{ModelSpec, Options};
