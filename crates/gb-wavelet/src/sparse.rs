//! Sparse wavelet coefficients: index + value storage, best n-term
//! approximation, compression ratio.

use serde::{Deserialize, Serialize};

use crate::error::{Result, WaveletError};

/// Coefficients `[a_J, d_J, …, d₁]` stored sparsely as (flat index, value)
/// pairs, with the band lengths needed to restore the dense layout.
///
/// ```
/// use gb_wavelet::SparseCoefficients;
/// let bands = vec![vec![5.0, 0.0], vec![0.0, 0.01], vec![3.0, 0.0, 0.0, -2.0]];
/// let s = SparseCoefficients::from_bands(&bands, 0.1);
/// assert_eq!(s.nnz(), 3);
/// assert_eq!(s.compression_ratio(), 8.0 / 3.0);
/// assert_eq!(s.to_bands()[2], vec![3.0, 0.0, 0.0, -2.0]);
/// ```
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct SparseCoefficients {
    /// Lengths of the bands `[a_J, d_J, …, d₁]`.
    pub band_lens: Vec<usize>,
    /// Flat indices (into the concatenated bands) of the kept coefficients, increasing.
    pub indices: Vec<usize>,
    /// Values of the kept coefficients.
    pub values: Vec<f64>,
}

impl SparseCoefficients {
    /// Keeps the coefficients with `|c| > tolerance`.
    pub fn from_bands(bands: &[Vec<f64>], tolerance: f64) -> Self {
        let mut s = Self {
            band_lens: bands.iter().map(Vec::len).collect(),
            ..Self::default()
        };
        for (i, &v) in bands.iter().flatten().enumerate() {
            if v.abs() > tolerance {
                s.indices.push(i);
                s.values.push(v);
            }
        }
        s
    }

    /// Total number of (dense) coefficients.
    pub fn len(&self) -> usize {
        self.band_lens.iter().sum()
    }
    /// `true` if there are no (dense) coefficients.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Number of stored (non-zero) coefficients.
    pub fn nnz(&self) -> usize {
        self.values.len()
    }
    /// Dense over stored count, `len/nnz` (∞ if nothing is stored).
    pub fn compression_ratio(&self) -> f64 {
        self.len() as f64 / self.nnz() as f64
    }

    /// Restores the dense bands.
    pub fn to_bands(&self) -> Vec<Vec<f64>> {
        let dense = self.to_dense();
        let mut out = Vec::with_capacity(self.band_lens.len());
        let mut offset = 0;
        for &l in &self.band_lens {
            out.push(dense[offset..offset + l].to_vec());
            offset += l;
        }
        out
    }

    /// The dense concatenated coefficients.
    pub fn to_dense(&self) -> Vec<f64> {
        let mut dense = vec![0.0; self.len()];
        for (&i, &v) in self.indices.iter().zip(&self.values) {
            if let Some(slot) = dense.get_mut(i) {
                *slot = v;
            }
        }
        dense
    }

    /// `(level, index within level, value)` of the stored coefficients, level 0
    /// being the approximation and then details coarse to fine.
    pub fn entries(&self) -> Vec<(usize, usize, f64)> {
        let mut starts = Vec::with_capacity(self.band_lens.len());
        let mut offset = 0;
        for &l in &self.band_lens {
            starts.push(offset);
            offset += l;
        }
        self.indices
            .iter()
            .zip(&self.values)
            .map(|(&i, &v)| {
                let level = starts.partition_point(|&s| s <= i) - 1;
                (level, i - starts[level], v)
            })
            .collect()
    }

    /// Checks the indices are increasing and in range.
    pub fn validate(&self) -> Result<()> {
        let len = self.len();
        if self.indices.len() != self.values.len() {
            return Err(WaveletError::ShapeMismatch(
                "indices and values differ in length".into(),
            ));
        }
        if self.indices.windows(2).any(|w| w[0] >= w[1])
            || self.indices.last().is_some_and(|&i| i >= len)
        {
            return Err(WaveletError::ShapeMismatch(
                "indices must be increasing and below the coefficient count".into(),
            ));
        }
        Ok(())
    }
}

/// `(level, index, value)` rows for every coefficient of `[a_J, d_J, …, d₁]`
/// (level 0 = approximation), the layout of `greybox wavelet`'s CSV output.
pub fn coefficient_rows(bands: &[Vec<f64>]) -> Vec<(usize, usize, f64)> {
    bands
        .iter()
        .enumerate()
        .flat_map(|(level, band)| band.iter().enumerate().map(move |(i, &v)| (level, i, v)))
        .collect()
}

/// Best n-term approximation in the coefficient domain.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NTermApproximation {
    /// The `n` largest-magnitude coefficients.
    pub coefficients: SparseCoefficients,
    /// `‖c − c_n‖₂`: the ℓ² norm of the discarded coefficients (equal to the
    /// signal-domain error for orthogonal wavelets with periodization).
    pub error: f64,
    /// `error / ‖c‖₂` (0 for zero coefficients).
    pub relative_error: f64,
}

/// Keeps the `n` largest `|c|` of `[a_J, d_J, …, d₁]` (ties broken by index).
///
/// ```
/// use gb_wavelet::best_n_term;
/// let a = best_n_term(&[vec![3.0, -4.0], vec![0.5, 1.0]], 2);
/// assert_eq!(a.coefficients.indices, vec![0, 1]);
/// assert!((a.error - 1.25f64.sqrt()).abs() < 1e-15);
/// ```
pub fn best_n_term(bands: &[Vec<f64>], n: usize) -> NTermApproximation {
    let flat: Vec<f64> = bands.iter().flatten().copied().collect();
    let mut order: Vec<usize> = (0..flat.len()).collect();
    order.sort_by(|&i, &j| flat[j].abs().total_cmp(&flat[i].abs()).then(i.cmp(&j)));
    let mut kept: Vec<usize> = order.iter().take(n).copied().collect();
    kept.sort_unstable();
    let total: f64 = flat.iter().map(|v| v * v).sum();
    let discarded: f64 = order.iter().skip(n).map(|&i| flat[i] * flat[i]).sum();
    NTermApproximation {
        coefficients: SparseCoefficients {
            band_lens: bands.iter().map(Vec::len).collect(),
            values: kept.iter().map(|&i| flat[i]).collect(),
            indices: kept,
        },
        error: discarded.sqrt(),
        relative_error: if total > 0.0 {
            (discarded / total).sqrt()
        } else {
            0.0
        },
    }
}
