//! # gb-preisach
//!
//! Rate-independent hysteresis operators. This first part holds the play
//! (backlash) operator and banks of them, whose outputs enter models linearly
//! (a Prandtl–Ishlinskii model is a weighted sum of play operators).
//!
//! ```
//! use gb_preisach::PlayOperatorBank;
//! let bank = PlayOperatorBank::new(vec![0.0, 0.5]).unwrap();
//! let cols = bank.apply(&[0.0, 1.0, 0.8, 0.0]);
//! assert_eq!(cols[0], vec![0.0, 1.0, 0.8, 0.0]); // r = 0 is the identity
//! assert_eq!(cols[1], vec![0.0, 0.5, 0.5, 0.5]); // backlash of half-width 0.5
//! ```
#![warn(missing_docs)]

mod play;

pub use play::{PlayOperator, PlayOperatorBank};

/// Errors of the Preisach crate.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PreisachError {
    /// An argument is out of its domain.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
}
