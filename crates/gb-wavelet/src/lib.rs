//! # gb-wavelet
//!
//! Fast wavelet transforms for greybox, with PyWavelets' coefficient layout
//! and extension modes as the reference:
//!
//! * [`Wavelet`]: a planned two-channel filter bank (`haar`, `db1`–`db38`,
//!   `sym2`–`sym20`, `coif1`–`coif17`, `bior*`, `rbio*`, `cdf53`, `cdf97`);
//!   [`Mode`]: `zero`, `constant`, `symmetric`, `periodic`, `periodization`.
//! * One level: [`dwt`]/[`idwt`] and the allocation-free
//!   [`Wavelet::dwt_into`]/[`Wavelet::idwt_into`]; multilevel: [`wavedec`],
//!   [`waverec`] and the planned [`DecompositionPlan`] (caller-supplied
//!   buffers and scratch, RustFFT style).
//! * 2-D: [`dwt2`], [`idwt2`], [`wavedec2`], [`waverec2`]; packets:
//!   [`WaveletPacket`] with [`WaveletPacket::best_basis`].
//! * Thresholding: [`ThresholdFunction`] (hard, soft, garrote) and
//!   [`ThresholdRule`] (universal, SURE, BayesShrink, empirical Bayes);
//!   [`denoise`], [`denoise_with`].
//! * Sparse storage: [`SparseCoefficients`], [`best_n_term`],
//!   [`coefficient_rows`].
//! * Point evaluation: [`wavefun`] (cascade), [`RefinableFunctions`] (exact
//!   dyadic values of φ, ψ), [`WaveletExpansion`] (n-D tensor products).
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
pub use multilevel::{wavedec, waverec, DecompositionPlan, MAX_LEVEL};
pub use packet::{EntropyCost, PacketNode, WaveletPacket, MAX_PACKET_LEVEL};
pub use refinable::{
    wavefun, Atom, AtomKind, ExpansionTerm, RefinableFunctions, WaveletExpansion, WaveletFunctions,
    MAX_RESOLUTION,
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
