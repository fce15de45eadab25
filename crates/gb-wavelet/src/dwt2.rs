//! Separable 2-D transform: rows and columns filtered by the same 1-D filter bank.
//!
//! One level maps an image `X` to four sub-bands, filtering along the columns
//! (axis 0) and then along the rows (axis 1):
//! `A = (h̃ ⊗ h̃)X`, `H = (g̃ ⊗ h̃)X` (detail along axis 0), `V = (h̃ ⊗ g̃)X`,
//! `D = (g̃ ⊗ g̃)X` — PyWavelets' `cA, (cH, cV, cD)` of `dwt2`.

use serde::{Deserialize, Serialize};

use crate::error::{Result, WaveletError};
use crate::mode::Mode;
use crate::transform::{analysis, synthesis};
use crate::wavelet::{max_level, Wavelet};

/// A dense row-major 2-D array.
///
/// ```
/// let a = gb_wavelet::Array2D::new(2, 3, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0])?;
/// assert_eq!(a.get(1, 0), Some(4.0));
/// # Ok::<(), gb_wavelet::WaveletError>(())
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Array2D {
    rows: usize,
    cols: usize,
    data: Vec<f64>,
}

impl Array2D {
    /// An array from row-major data of length `rows·cols`.
    pub fn new(rows: usize, cols: usize, data: Vec<f64>) -> Result<Self> {
        if rows.checked_mul(cols) != Some(data.len()) {
            return Err(WaveletError::ShapeMismatch(format!(
                "{rows}×{cols} array needs {} values, got {}",
                rows.saturating_mul(cols),
                data.len()
            )));
        }
        Ok(Self { rows, cols, data })
    }
    /// A zero array.
    pub fn zeros(rows: usize, cols: usize) -> Self {
        Self {
            rows,
            cols,
            data: vec![0.0; rows * cols],
        }
    }
    /// Number of rows.
    pub fn rows(&self) -> usize {
        self.rows
    }
    /// Number of columns.
    pub fn cols(&self) -> usize {
        self.cols
    }
    /// `(rows, cols)`.
    pub fn shape(&self) -> (usize, usize) {
        (self.rows, self.cols)
    }
    /// Row-major values.
    pub fn data(&self) -> &[f64] {
        &self.data
    }
    /// Row-major values, mutable.
    pub fn data_mut(&mut self) -> &mut [f64] {
        &mut self.data
    }
    /// Consumes the array, returning its row-major values.
    pub fn into_data(self) -> Vec<f64> {
        self.data
    }
    /// Element `(r, c)`.
    pub fn get(&self, r: usize, c: usize) -> Option<f64> {
        (r < self.rows && c < self.cols).then(|| self.data[r * self.cols + c])
    }
    /// The top-left `rows × cols` block.
    fn crop(&self, rows: usize, cols: usize) -> Self {
        let mut out = Self::zeros(rows, cols);
        for r in 0..rows {
            out.data[r * cols..(r + 1) * cols]
                .copy_from_slice(&self.data[r * self.cols..r * self.cols + cols]);
        }
        out
    }
}

/// The three detail sub-bands of one 2-D level.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Details2D {
    /// Detail along axis 0 (PyWavelets' `cH`).
    pub horizontal: Array2D,
    /// Detail along axis 1 (`cV`).
    pub vertical: Array2D,
    /// Detail along both axes (`cD`).
    pub diagonal: Array2D,
}

/// Multilevel 2-D coefficients: the coarsest approximation and the details,
/// coarse to fine (PyWavelets' `wavedec2` order).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Coefficients2D {
    /// Approximation at the coarsest level.
    pub approx: Array2D,
    /// Details, coarse to fine.
    pub details: Vec<Details2D>,
}

/// Filters every column of `x` (rows × cols): returns `(low, high)`, each `n × cols`.
fn analyze_columns(x: &Array2D, w: &Wavelet, mode: Mode) -> (Array2D, Array2D) {
    let n = w.dwt_len(x.rows, mode);
    let mut low = Array2D::zeros(n, x.cols);
    let mut high = Array2D::zeros(n, x.cols);
    let mut col = vec![0.0; x.rows];
    let (mut a, mut d) = (vec![0.0; n], vec![0.0; n]);
    for c in 0..x.cols {
        for (r, v) in col.iter_mut().enumerate() {
            *v = x.data[r * x.cols + c];
        }
        analysis(&col, &w.dec_lo_rev, &w.dec_hi_rev, mode, &mut a, &mut d);
        for r in 0..n {
            low.data[r * x.cols + c] = a[r];
            high.data[r * x.cols + c] = d[r];
        }
    }
    (low, high)
}

/// Filters every row of `x`: returns `(low, high)`, each `rows × n`.
fn analyze_rows(x: &Array2D, w: &Wavelet, mode: Mode) -> (Array2D, Array2D) {
    let n = w.dwt_len(x.cols, mode);
    let mut low = Array2D::zeros(x.rows, n);
    let mut high = Array2D::zeros(x.rows, n);
    for r in 0..x.rows {
        analysis(
            &x.data[r * x.cols..(r + 1) * x.cols],
            &w.dec_lo_rev,
            &w.dec_hi_rev,
            mode,
            &mut low.data[r * n..(r + 1) * n],
            &mut high.data[r * n..(r + 1) * n],
        );
    }
    (low, high)
}

fn idwt_len_checked(w: &Wavelet, len: usize, mode: Mode) -> Result<usize> {
    w.idwt_len(len, mode).ok_or(WaveletError::TooShort {
        coeff_len: len,
        filter_len: w.filter_len(),
    })
}

/// Inverse of [`analyze_rows`].
fn synthesize_rows(low: &Array2D, high: &Array2D, w: &Wavelet, mode: Mode) -> Result<Array2D> {
    let n = idwt_len_checked(w, low.cols, mode)?;
    let mut out = Array2D::zeros(low.rows, n);
    for r in 0..low.rows {
        synthesis(
            &low.data[r * low.cols..(r + 1) * low.cols],
            &high.data[r * low.cols..(r + 1) * low.cols],
            &w.rec_poly,
            mode,
            &mut out.data[r * n..(r + 1) * n],
        );
    }
    Ok(out)
}

/// Inverse of [`analyze_columns`].
fn synthesize_columns(low: &Array2D, high: &Array2D, w: &Wavelet, mode: Mode) -> Result<Array2D> {
    let n = idwt_len_checked(w, low.rows, mode)?;
    let mut out = Array2D::zeros(n, low.cols);
    let (mut a, mut d, mut y) = (vec![0.0; low.rows], vec![0.0; low.rows], vec![0.0; n]);
    for c in 0..low.cols {
        for r in 0..low.rows {
            a[r] = low.data[r * low.cols + c];
            d[r] = high.data[r * low.cols + c];
        }
        synthesis(&a, &d, &w.rec_poly, mode, &mut y);
        for (r, v) in y.iter().enumerate() {
            out.data[r * low.cols + c] = *v;
        }
    }
    Ok(out)
}

/// One level of the 2-D transform, like `pywt.dwt2`: `(cA, (cH, cV, cD))`.
pub fn dwt2(image: &Array2D, wavelet: &Wavelet, mode: Mode) -> Result<(Array2D, Details2D)> {
    if image.rows == 0 || image.cols == 0 {
        return Err(WaveletError::EmptyInput("image"));
    }
    let (low, high) = analyze_columns(image, wavelet, mode);
    let (aa, ad) = analyze_rows(&low, wavelet, mode);
    let (da, dd) = analyze_rows(&high, wavelet, mode);
    Ok((
        aa,
        Details2D {
            horizontal: da,
            vertical: ad,
            diagonal: dd,
        },
    ))
}

/// Inverse of [`dwt2`], like `pywt.idwt2`; all four bands must have the same shape.
pub fn idwt2(
    approx: &Array2D,
    details: &Details2D,
    wavelet: &Wavelet,
    mode: Mode,
) -> Result<Array2D> {
    let shape = approx.shape();
    for band in [&details.horizontal, &details.vertical, &details.diagonal] {
        if band.shape() != shape {
            return Err(WaveletError::ShapeMismatch(format!(
                "sub-band shapes {:?} and {:?} differ",
                shape,
                band.shape()
            )));
        }
    }
    let low = synthesize_rows(approx, &details.vertical, wavelet, mode)?;
    let high = synthesize_rows(&details.horizontal, &details.diagonal, wavelet, mode)?;
    synthesize_columns(&low, &high, wavelet, mode)
}

/// Multilevel 2-D decomposition like `pywt.wavedec2` (`level = None`: the
/// maximum level of the shorter side).
///
/// ```
/// use gb_wavelet::{wavedec2, waverec2, Array2D, Mode, Wavelet};
/// let img = Array2D::new(8, 8, (0..64).map(|i| (i % 7) as f64).collect())?;
/// let w = Wavelet::new("haar")?;
/// let c = wavedec2(&img, &w, Mode::Periodization, Some(2))?;
/// assert_eq!(c.approx.shape(), (2, 2));
/// let back = waverec2(&c, &w, Mode::Periodization)?;
/// assert!(back.data().iter().zip(img.data()).all(|(a, b)| (a - b).abs() < 1e-12));
/// # Ok::<(), gb_wavelet::WaveletError>(())
/// ```
pub fn wavedec2(
    image: &Array2D,
    wavelet: &Wavelet,
    mode: Mode,
    level: Option<usize>,
) -> Result<Coefficients2D> {
    let level =
        level.unwrap_or_else(|| max_level(image.rows.min(image.cols), wavelet.filter_len()));
    if level > crate::multilevel::MAX_LEVEL {
        return Err(WaveletError::InvalidParameter(format!(
            "level {level} too large"
        )));
    }
    let mut approx = image.clone();
    let mut details = Vec::with_capacity(level);
    for _ in 0..level {
        let (a, d) = dwt2(&approx, wavelet, mode)?;
        approx = a;
        details.push(d);
    }
    details.reverse();
    Ok(Coefficients2D { approx, details })
}

/// Multilevel 2-D reconstruction like `pywt.waverec2` (an approximation one
/// row/column larger than the next details is cropped).
pub fn waverec2(coeffs: &Coefficients2D, wavelet: &Wavelet, mode: Mode) -> Result<Array2D> {
    let mut a = coeffs.approx.clone();
    for d in &coeffs.details {
        let (r, c) = d.horizontal.shape();
        if a.shape() != (r, c) {
            if (a.rows == r || a.rows == r + 1) && (a.cols == c || a.cols == c + 1) {
                a = a.crop(r, c);
            } else {
                return Err(WaveletError::ShapeMismatch(format!(
                    "approximation {:?} does not fit details {:?}",
                    a.shape(),
                    (r, c)
                )));
            }
        }
        a = idwt2(&a, d, wavelet, mode)?;
    }
    Ok(a)
}
