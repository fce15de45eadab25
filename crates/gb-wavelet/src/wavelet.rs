//! Wavelet filter banks: the planned object reused by every transform.

use serde::{Deserialize, Serialize};

use crate::error::{Result, WaveletError};
use crate::filters::FILTERS;

/// Wavelet family.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[non_exhaustive]
pub enum Family {
    /// Haar (= db1).
    Haar,
    /// Daubechies' extremal-phase wavelets `dbN` (N vanishing moments, 2N taps).
    Daubechies,
    /// Daubechies' least-asymmetric wavelets `symN`.
    Symlets,
    /// Coiflets `coifN` (2N vanishing moments for ψ and 2N−1 for φ, 6N taps).
    Coiflets,
    /// Cohen–Daubechies–Feauveau biorthogonal spline wavelets `biorNr.Nd`.
    Biorthogonal,
    /// Biorthogonal with analysis and synthesis swapped, `rbioNr.Nd`.
    ReverseBiorthogonal,
    /// User-supplied filters.
    Custom,
}

/// Symmetry of the filters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[non_exhaustive]
pub enum Symmetry {
    /// No symmetry.
    Asymmetric,
    /// Close to linear phase.
    NearSymmetric,
    /// Linear phase.
    Symmetric,
    /// Not known (custom filters).
    Unknown,
}

/// A planned two-channel filter bank `(h̃, g̃; h, g)`: analysis low/high-pass
/// `dec_lo`, `dec_hi` and synthesis low/high-pass `rec_lo`, `rec_hi`, all of the
/// same even length `F`, in PyWavelets' conventions:
///
/// `dec_hi[k] = (−1)^{k+1} rec_lo[k]`, `rec_hi[k] = (−1)^k dec_lo[k]`, and for
/// orthogonal wavelets `rec_lo[k] = dec_lo[F−1−k]`.
///
/// Construction precomputes the reversed and polyphase filters the transform
/// kernels use, so create it once and reuse it (it is cheap to clone).
///
/// ```
/// use gb_wavelet::Wavelet;
/// let w = Wavelet::new("db2")?;
/// assert_eq!(w.filter_len(), 4);
/// // Orthonormal low-pass filter: Σ h_k = √2, Σ h_k² = 1.
/// let s: f64 = w.dec_lo().iter().sum();
/// assert!((s - 2f64.sqrt()).abs() < 1e-14);
/// # Ok::<(), gb_wavelet::WaveletError>(())
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct Wavelet {
    name: String,
    family: Family,
    symmetry: Symmetry,
    orthogonal: bool,
    vanishing_moments_psi: usize,
    vanishing_moments_phi: usize,
    dec_lo: Vec<f64>,
    dec_hi: Vec<f64>,
    rec_lo: Vec<f64>,
    rec_hi: Vec<f64>,
    /// `dec_lo` reversed (correlation form used by the analysis kernel).
    pub(crate) dec_lo_rev: Vec<f64>,
    /// `dec_hi` reversed.
    pub(crate) dec_hi_rev: Vec<f64>,
    /// Synthesis polyphase components, reversed: `[lo_even, lo_odd, hi_even, hi_odd]`,
    /// `lo_even[t] = rec_lo[2(H−1−t)]`, `lo_odd[t] = rec_lo[2(H−1−t)+1]`, `H = F/2`.
    pub(crate) rec_poly: [Vec<f64>; 4],
}

/// Names accepted besides the PyWavelets ones.
const ALIASES: &[(&str, &str)] = &[
    ("cdf53", "bior2.2"),
    ("cdf5/3", "bior2.2"),
    ("legall53", "bior2.2"),
    ("cdf97", "bior4.4"),
    ("cdf9/7", "bior4.4"),
];

impl Wavelet {
    /// Plans the filter bank of a named wavelet: `haar`, `db1`–`db38`, `sym2`–`sym20`,
    /// `coif1`–`coif17`, `bior1.1`…`bior6.8`, `rbio1.1`…`rbio6.8`, and the aliases
    /// `cdf53` (= `bior2.2`, LeGall 5/3) and `cdf97` (= `bior4.4`, CDF 9/7).
    pub fn new(name: &str) -> Result<Self> {
        let lower = name.trim().to_ascii_lowercase();
        let canonical = ALIASES
            .iter()
            .find(|(alias, _)| *alias == lower)
            .map_or(lower.as_str(), |(_, target)| *target);
        let entry = FILTERS
            .iter()
            .find(|e| e.name == canonical)
            .ok_or_else(|| WaveletError::UnknownWavelet(name.to_string()))?;
        let dec_lo = entry.dec_lo.to_vec();
        let rec_lo = match entry.rec_lo {
            Some(r) => r.to_vec(),
            None => dec_lo.iter().rev().copied().collect(),
        };
        let f = dec_lo.len();
        let dec_hi = (0..f)
            .map(|k| if k % 2 == 0 { -rec_lo[k] } else { rec_lo[k] })
            .collect();
        let rec_hi = (0..f)
            .map(|k| if k % 2 == 0 { dec_lo[k] } else { -dec_lo[k] })
            .collect();
        Ok(Self::assemble(
            entry.name.to_string(),
            entry.family,
            entry.symmetry,
            entry.orthogonal,
            (entry.vanishing_moments_psi, entry.vanishing_moments_phi),
            [dec_lo, dec_hi, rec_lo, rec_hi],
        ))
    }

    /// A filter bank from user-supplied filters (all of the same even length ≥ 2,
    /// finite). Perfect reconstruction is the caller's responsibility.
    pub fn from_filters(
        name: &str,
        dec_lo: &[f64],
        dec_hi: &[f64],
        rec_lo: &[f64],
        rec_hi: &[f64],
    ) -> Result<Self> {
        let f = dec_lo.len();
        if f < 2 || f % 2 != 0 {
            return Err(WaveletError::InvalidFilter(format!(
                "filter length must be even and at least 2, got {f}"
            )));
        }
        if [dec_hi.len(), rec_lo.len(), rec_hi.len()]
            .iter()
            .any(|&l| l != f)
        {
            return Err(WaveletError::InvalidFilter(
                "all four filters must have the same length".into(),
            ));
        }
        if [dec_lo, dec_hi, rec_lo, rec_hi]
            .iter()
            .any(|h| h.iter().any(|v| !v.is_finite()))
        {
            return Err(WaveletError::InvalidFilter(
                "filter taps must be finite".into(),
            ));
        }
        let orthogonal = rec_lo.iter().eq(dec_lo.iter().rev());
        Ok(Self::assemble(
            name.to_string(),
            Family::Custom,
            Symmetry::Unknown,
            orthogonal,
            (0, 0),
            [
                dec_lo.to_vec(),
                dec_hi.to_vec(),
                rec_lo.to_vec(),
                rec_hi.to_vec(),
            ],
        ))
    }

    fn assemble(
        name: String,
        family: Family,
        symmetry: Symmetry,
        orthogonal: bool,
        moments: (usize, usize),
        [dec_lo, dec_hi, rec_lo, rec_hi]: [Vec<f64>; 4],
    ) -> Self {
        let h = dec_lo.len() / 2;
        let poly = |filter: &[f64], phase: usize| -> Vec<f64> {
            (0..h).map(|t| filter[2 * (h - 1 - t) + phase]).collect()
        };
        let rec_poly = [
            poly(&rec_lo, 0),
            poly(&rec_lo, 1),
            poly(&rec_hi, 0),
            poly(&rec_hi, 1),
        ];
        Self {
            name,
            family,
            symmetry,
            orthogonal,
            vanishing_moments_psi: moments.0,
            vanishing_moments_phi: moments.1,
            dec_lo_rev: dec_lo.iter().rev().copied().collect(),
            dec_hi_rev: dec_hi.iter().rev().copied().collect(),
            dec_lo,
            dec_hi,
            rec_lo,
            rec_hi,
            rec_poly,
        }
    }

    /// Names of all tabulated wavelets.
    pub fn available() -> Vec<&'static str> {
        FILTERS.iter().map(|e| e.name).collect()
    }

    /// The wavelet's name, e.g. `"db4"`.
    pub fn name(&self) -> &str {
        &self.name
    }
    /// The family.
    pub fn family(&self) -> Family {
        self.family
    }
    /// The symmetry of the filters.
    pub fn symmetry(&self) -> Symmetry {
        self.symmetry
    }
    /// `true` for orthogonal wavelets (`rec_lo` is `dec_lo` reversed).
    pub fn is_orthogonal(&self) -> bool {
        self.orthogonal
    }
    /// Number of vanishing moments of the (analysis) wavelet ψ.
    pub fn vanishing_moments_psi(&self) -> usize {
        self.vanishing_moments_psi
    }
    /// Number of vanishing moments of the scaling function φ (PyWavelets' value).
    pub fn vanishing_moments_phi(&self) -> usize {
        self.vanishing_moments_phi
    }
    /// Filter length `F` (PyWavelets' `dec_len`).
    pub fn filter_len(&self) -> usize {
        self.dec_lo.len()
    }
    /// Analysis low-pass filter.
    pub fn dec_lo(&self) -> &[f64] {
        &self.dec_lo
    }
    /// Analysis high-pass filter.
    pub fn dec_hi(&self) -> &[f64] {
        &self.dec_hi
    }
    /// Synthesis low-pass filter.
    pub fn rec_lo(&self) -> &[f64] {
        &self.rec_lo
    }
    /// Synthesis high-pass filter.
    pub fn rec_hi(&self) -> &[f64] {
        &self.rec_hi
    }

    /// Maximum useful decomposition level for a signal of `signal_len` samples,
    /// `⌊log₂(N/(F−1))⌋` (0 when `N < F−1`), as PyWavelets' `dwt_max_level`.
    ///
    /// ```
    /// let w = gb_wavelet::Wavelet::new("sym5")?;
    /// assert_eq!(w.max_level(1000), 6);
    /// # Ok::<(), gb_wavelet::WaveletError>(())
    /// ```
    pub fn max_level(&self, signal_len: usize) -> usize {
        max_level(signal_len, self.filter_len())
    }
}

/// `⌊log₂(N/(F−1))⌋`, 0 if `F ≤ 1` or `N < F−1`.
pub(crate) fn max_level(signal_len: usize, filter_len: usize) -> usize {
    if filter_len <= 1 || signal_len < filter_len - 1 {
        return 0;
    }
    let q = signal_len / (filter_len - 1);
    (usize::BITS - 1 - q.leading_zeros()) as usize
}
