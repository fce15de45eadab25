//! Multilevel decomposition and reconstruction (Mallat's pyramid algorithm).
//!
//! `wavedec` iterates the analysis step on the approximation:
//! `x = a₀ → (a₁, d₁) → (a₂, d₂) → … → (a_J, d_J)` and returns
//! `[a_J, d_J, d_{J−1}, …, d₁]` — PyWavelets' `wavedec` order.

use std::ops::Range;

use crate::error::{Result, WaveletError};
use crate::mode::Mode;
use crate::transform::{analysis, synthesis};
use crate::wavelet::Wavelet;

/// Largest decomposition level accepted (1-D and 2-D).
pub const MAX_LEVEL: usize = 64;

/// A planned multilevel transform of signals of a fixed length: coefficient
/// layout, buffer sizes, and the filter bank. Reuse it across calls; the
/// `decompose`/`reconstruct` methods do not allocate.
///
/// The flat coefficient buffer holds the bands `[a_J | d_J | … | d₁]`
/// (see [`DecompositionPlan::bands`]).
///
/// ```
/// use gb_wavelet::{DecompositionPlan, Mode, Wavelet};
/// let w = Wavelet::new("db4")?;
/// let plan = DecompositionPlan::new(&w, 1024, Mode::Periodization, None)?;
/// assert_eq!(plan.level(), 7);
/// let x: Vec<f64> = (0..1024).map(|i| (i as f64 * 0.05).sin()).collect();
/// let mut coeffs = vec![0.0; plan.coeff_len()];
/// let mut scratch = vec![0.0; plan.scratch_len()];
/// plan.decompose(&x, &mut coeffs, &mut scratch)?;
/// let mut y = vec![0.0; plan.output_len()];
/// plan.reconstruct(&coeffs, &mut y, &mut scratch)?;
/// assert!(x.iter().zip(&y).all(|(u, v)| (u - v).abs() < 1e-12));
/// # Ok::<(), gb_wavelet::WaveletError>(())
/// ```
#[derive(Debug, Clone)]
pub struct DecompositionPlan {
    wavelet: Wavelet,
    mode: Mode,
    signal_len: usize,
    /// `approx_lens[j]` = length of `a_j`, `j = 0..=J` (`a_0` = the signal).
    approx_lens: Vec<usize>,
    /// Bands in output order.
    bands: Vec<Range<usize>>,
    /// Lengths produced by each synthesis step, coarse to fine.
    rec_lens: Vec<usize>,
    scratch_half: usize,
}

impl DecompositionPlan {
    /// Plans a `level`-level transform (`None`: [`Wavelet::max_level`]) of
    /// signals of `signal_len` samples. Levels above the maximum are allowed
    /// (as in PyWavelets) as long as every reconstruction step is defined.
    pub fn new(
        wavelet: &Wavelet,
        signal_len: usize,
        mode: Mode,
        level: Option<usize>,
    ) -> Result<Self> {
        if signal_len == 0 {
            return Err(WaveletError::EmptyInput("signal"));
        }
        let f = wavelet.filter_len();
        let level = level.unwrap_or_else(|| wavelet.max_level(signal_len));
        if level > MAX_LEVEL {
            return Err(WaveletError::InvalidParameter(format!(
                "level {level} > {MAX_LEVEL}"
            )));
        }
        let mut approx_lens = vec![signal_len];
        for _ in 0..level {
            let prev = approx_lens[approx_lens.len() - 1];
            approx_lens.push(wavelet.dwt_len(prev, mode));
        }
        // bands: a_J, d_J, ..., d_1
        let mut bands = Vec::with_capacity(level + 1);
        let mut offset = 0;
        bands.push(offset..offset + approx_lens[level]);
        offset += approx_lens[level];
        for j in (1..=level).rev() {
            bands.push(offset..offset + approx_lens[j]);
            offset += approx_lens[j];
        }
        // reconstruction lengths, coarse to fine, with PyWavelets' trimming of a
        // one-longer approximation.
        let mut rec_lens = Vec::with_capacity(level);
        let mut a_len = approx_lens[level];
        for j in (1..=level).rev() {
            let d_len = approx_lens[j];
            if a_len != d_len && a_len != d_len + 1 {
                return Err(WaveletError::ShapeMismatch(format!(
                    "level {j}: approximation {a_len} vs detail {d_len}"
                )));
            }
            a_len = idwt_len_checked(d_len, f, mode)?;
            rec_lens.push(a_len);
        }
        let scratch_half = approx_lens[1..]
            .iter()
            .chain(rec_lens.iter())
            .copied()
            .max()
            .unwrap_or(0);
        Ok(Self {
            wavelet: wavelet.clone(),
            mode,
            signal_len,
            approx_lens,
            bands,
            rec_lens,
            scratch_half,
        })
    }

    /// Number of levels `J`.
    pub fn level(&self) -> usize {
        self.approx_lens.len() - 1
    }
    /// The extension mode.
    pub fn mode(&self) -> Mode {
        self.mode
    }
    /// The filter bank.
    pub fn wavelet(&self) -> &Wavelet {
        &self.wavelet
    }
    /// Input signal length.
    pub fn signal_len(&self) -> usize {
        self.signal_len
    }
    /// Total number of coefficients.
    pub fn coeff_len(&self) -> usize {
        self.bands.last().map_or(0, |r| r.end)
    }
    /// Ranges of the bands in the flat coefficient buffer, `[a_J, d_J, …, d₁]`.
    pub fn bands(&self) -> &[Range<usize>] {
        &self.bands
    }
    /// Required scratch length for [`decompose`](Self::decompose) and
    /// [`reconstruct`](Self::reconstruct).
    pub fn scratch_len(&self) -> usize {
        2 * self.scratch_half
    }
    /// Length of the reconstructed signal: the signal length, or one more for
    /// odd lengths in some modes (as `pywt.waverec`).
    pub fn output_len(&self) -> usize {
        self.rec_lens.last().copied().unwrap_or(self.signal_len)
    }

    /// Decomposes `signal` into the flat buffer `coeffs` (length
    /// [`coeff_len`](Self::coeff_len)) using `scratch` (length ≥
    /// [`scratch_len`](Self::scratch_len)). No allocation.
    pub fn decompose(&self, signal: &[f64], coeffs: &mut [f64], scratch: &mut [f64]) -> Result<()> {
        check("signal", self.signal_len, signal.len(), true)?;
        check("coeffs", self.coeff_len(), coeffs.len(), true)?;
        check("scratch", self.scratch_len(), scratch.len(), false)?;
        let level = self.level();
        if level == 0 {
            coeffs.copy_from_slice(signal);
            return Ok(());
        }
        let (buf0, rest) = scratch.split_at_mut(self.scratch_half);
        let buf1 = &mut rest[..self.scratch_half];
        let (lo, hi) = (&self.wavelet.dec_lo_rev, &self.wavelet.dec_hi_rev);
        let (approx_out, details) = coeffs.split_at_mut(self.bands[0].end);
        let mut bufs = [buf0, buf1];
        for j in 1..=level {
            let n_in = self.approx_lens[j - 1];
            let n_out = self.approx_lens[j];
            // detail d_j lives in band index level + 1 − j
            let band = &self.bands[level + 1 - j];
            let d = &mut details[band.start - approx_out.len()..band.end - approx_out.len()];
            let [b0, b1] = &mut bufs;
            let (src, dst): (&[f64], &mut [f64]) = if j == 1 {
                (signal, &mut b0[..n_out])
            } else if j % 2 == 0 {
                (&b0[..n_in], &mut b1[..n_out])
            } else {
                (&b1[..n_in], &mut b0[..n_out])
            };
            if j == level {
                analysis(src, lo, hi, self.mode, approx_out, d);
            } else {
                analysis(src, lo, hi, self.mode, dst, d);
            }
        }
        Ok(())
    }

    /// Reconstructs from the flat buffer `coeffs` into `out` (length
    /// [`output_len`](Self::output_len)) using `scratch`. No allocation.
    pub fn reconstruct(&self, coeffs: &[f64], out: &mut [f64], scratch: &mut [f64]) -> Result<()> {
        check("coeffs", self.coeff_len(), coeffs.len(), true)?;
        check("out", self.output_len(), out.len(), true)?;
        check("scratch", self.scratch_len(), scratch.len(), false)?;
        let level = self.level();
        if level == 0 {
            out.copy_from_slice(coeffs);
            return Ok(());
        }
        let (b0, rest) = scratch.split_at_mut(self.scratch_half);
        let b1 = &mut rest[..self.scratch_half];
        let poly = &self.wavelet.rec_poly;
        let mut a_len = self.bands[0].len();
        for step in 0..level {
            let d = &coeffs[self.bands[step + 1].clone()];
            a_len = a_len.min(d.len());
            let n_out = self.rec_lens[step];
            let last = step + 1 == level;
            let (src, dst): (&[f64], &mut [f64]) = if step == 0 {
                (
                    &coeffs[self.bands[0].start..self.bands[0].start + a_len],
                    &mut b0[..n_out],
                )
            } else if step % 2 == 1 {
                (&b0[..a_len], &mut b1[..n_out])
            } else {
                (&b1[..a_len], &mut b0[..n_out])
            };
            if last {
                synthesis(src, d, poly, self.mode, out);
            } else {
                synthesis(src, d, poly, self.mode, dst);
            }
            a_len = n_out;
        }
        Ok(())
    }
}

fn idwt_len_checked(coeff_len: usize, filter_len: usize, mode: Mode) -> Result<usize> {
    crate::transform::idwt_len(coeff_len, filter_len, mode).ok_or(WaveletError::TooShort {
        coeff_len,
        filter_len,
    })
}

fn check(name: &'static str, expected: usize, got: usize, exact: bool) -> Result<()> {
    if got == expected || (!exact && got > expected) {
        Ok(())
    } else {
        Err(WaveletError::BufferLength {
            name,
            expected,
            got,
        })
    }
}

/// Multilevel decomposition like `pywt.wavedec(signal, wavelet, mode, level)`:
/// returns `[a_J, d_J, …, d₁]`; `level = None` uses [`Wavelet::max_level`].
///
/// ```
/// use gb_wavelet::{wavedec, waverec, Mode, Wavelet};
/// let w = Wavelet::new("sym4")?;
/// let x: Vec<f64> = (0..100).map(|i| ((i * i) % 17) as f64).collect();
/// let c = wavedec(&x, &w, Mode::Symmetric, Some(3))?;
/// assert_eq!(c.len(), 4);
/// let y = waverec(&c, &w, Mode::Symmetric)?;
/// assert!(x.iter().zip(&y).all(|(u, v)| (u - v).abs() < 1e-10));
/// # Ok::<(), gb_wavelet::WaveletError>(())
/// ```
pub fn wavedec(
    signal: &[f64],
    wavelet: &Wavelet,
    mode: Mode,
    level: Option<usize>,
) -> Result<Vec<Vec<f64>>> {
    let plan = DecompositionPlan::new(wavelet, signal.len(), mode, level)?;
    let mut flat = vec![0.0; plan.coeff_len()];
    let mut scratch = vec![0.0; plan.scratch_len()];
    plan.decompose(signal, &mut flat, &mut scratch)?;
    Ok(plan
        .bands()
        .iter()
        .map(|r| flat[r.clone()].to_vec())
        .collect())
}

/// Multilevel reconstruction like `pywt.waverec(coeffs, wavelet, mode)` from
/// `[a_J, d_J, …, d₁]`. An approximation one longer than the next detail band
/// is trimmed, as PyWavelets does.
pub fn waverec(coeffs: &[Vec<f64>], wavelet: &Wavelet, mode: Mode) -> Result<Vec<f64>> {
    let (first, details) = coeffs
        .split_first()
        .ok_or(WaveletError::EmptyInput("coefficient list"))?;
    let mut a = first.clone();
    for d in details {
        if a.len() == d.len() + 1 {
            a.truncate(d.len());
        } else if a.len() != d.len() {
            return Err(WaveletError::ShapeMismatch(format!(
                "approximation of length {} does not fit detail of length {}",
                a.len(),
                d.len()
            )));
        }
        a = crate::transform::idwt(&a, d, wavelet, mode)?;
    }
    Ok(a)
}
