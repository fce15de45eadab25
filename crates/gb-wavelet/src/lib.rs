//! # gb-wavelet
//!
//! Fast wavelet transforms for greybox: planned two-channel filter banks
//! ([`Wavelet`]), single-level and multilevel transforms with PyWavelets'
//! coefficient layout and extension modes ([`Mode`]).
//!
//! ```
//! use gb_wavelet::{wavedec, waverec, Mode, Wavelet};
//! let w = Wavelet::new("db4")?;
//! let x: Vec<f64> = (0..256).map(|i| (i as f64 / 10.0).sin()).collect();
//! let coeffs = wavedec(&x, &w, Mode::Periodization, None)?; // [a_J, d_J, …, d_1]
//! let y = waverec(&coeffs, &w, Mode::Periodization)?;
//! assert!(x.iter().zip(&y).all(|(a, b)| (a - b).abs() < 1e-12));
//! # Ok::<(), gb_wavelet::WaveletError>(())
//! ```
#![warn(missing_docs)]

mod dwt2;
mod error;
#[rustfmt::skip]
mod filters;
mod mode;
mod multilevel;
mod packet;
mod refinable;
mod simd;
mod sparse;
mod special;
mod threshold;
mod transform;
mod wavelet;

pub use dwt2::{dwt2, idwt2, wavedec2, waverec2, Array2D, Coefficients2D, Details2D};
pub use error::{Result, WaveletError};
pub use mode::Mode;
pub use multilevel::{wavedec, waverec, DecompositionPlan};
pub use packet::{EntropyCost, PacketNode, WaveletPacket};
pub use refinable::{
    wavefun, Atom, AtomKind, ExpansionTerm, RefinableFunctions, WaveletExpansion, WaveletFunctions,
};
pub use sparse::{best_n_term, coefficient_rows, NTermApproximation, SparseCoefficients};
pub use special::{mills_ratio, norm_cdf, norm_pdf, norm_quantile, upper_tail};
pub use threshold::{
    bayes_shrink_threshold, denoise, denoise_with, noise_sigma, sure_risk, sure_shrink_threshold,
    sure_threshold, universal_threshold, DenoiseOptions, Denoised, EmpiricalBayes,
    ThresholdFunction, ThresholdRule,
};
pub use transform::{dwt, dwt_len, idwt, idwt_len};
pub use wavelet::{Family, Symmetry, Wavelet};
