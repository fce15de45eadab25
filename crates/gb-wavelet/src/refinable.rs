//! Point evaluation of scaling functions and wavelets, and of finite wavelet
//! expansions `f(x) = Σ c_λ Ψ_λ(x)` at arbitrary points (1-D and tensor
//! products in n-D).
//!
//! The synthesis scaling function solves the refinement equation
//! `φ(x) = √2 Σ_k h_k φ(2x − k)` (`h = rec_lo`), the wavelet is
//! `ψ(x) = √2 Σ_k g_k φ(2x − k)` (`g = rec_hi`); both live on `[0, F−1]`.
//! Exact values at the integers are the eigenvector of `M_{nm} = √2 h_{2n−m}`
//! for the eigenvalue 1 normalised by `Σ_n φ(n) = 1`; the refinement equation
//! then gives the exact values at every dyadic point `m/2^J` (dyadic
//! refinement); other points are interpolated linearly.

use serde::{Deserialize, Serialize};

use crate::error::{Result, WaveletError};
use crate::wavelet::Wavelet;

/// Finest dyadic resolution tabulated (`(F−1)·2^16 + 1` samples per function).
pub const MAX_RESOLUTION: usize = 16;

/// Full upsampled convolution `y[k] = Σ_i x[i] f[k−2i]` (length `2N+F−2`).
fn upsample_convolve(x: &[f64], f: &[f64]) -> Vec<f64> {
    let mut y = vec![0.0; 2 * x.len() + f.len() - 2];
    for (i, &xi) in x.iter().enumerate() {
        for (k, &fk) in f.iter().enumerate() {
            y[2 * i + k] += xi * fk;
        }
    }
    y
}

/// Scaling function and wavelet sampled on a grid, as `pywt.Wavelet.wavefun`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WaveletFunctions {
    /// Grid `x_m = m/2^level`.
    pub x: Vec<f64>,
    /// Synthesis scaling function φ.
    pub phi: Vec<f64>,
    /// Synthesis wavelet ψ.
    pub psi: Vec<f64>,
    /// Analysis (dual) scaling function φ̃ — biorthogonal wavelets only.
    pub phi_dual: Option<Vec<f64>>,
    /// Analysis (dual) wavelet ψ̃ — biorthogonal wavelets only.
    pub psi_dual: Option<Vec<f64>>,
}

/// The cascade algorithm from a unit impulse, `level` times (PyWavelets'
/// `wavefun`): `2^{level/2}`-scaled iterated synthesis of one coefficient.
///
/// ```
/// let w = gb_wavelet::Wavelet::new("db2")?;
/// let f = gb_wavelet::wavefun(&w, 8)?;
/// assert_eq!(f.x.len(), f.phi.len());
/// assert!((f.x[f.x.len() - 1] - 3.0).abs() < 1e-12);
/// # Ok::<(), gb_wavelet::WaveletError>(())
/// ```
pub fn wavefun(wavelet: &Wavelet, level: usize) -> Result<WaveletFunctions> {
    if level == 0 || level > MAX_RESOLUTION {
        return Err(WaveletError::InvalidParameter(format!(
            "cascade level {level} not in 1..={MAX_RESOLUTION}"
        )));
    }
    let p = (1usize << level) as f64;
    let scale = 2f64.sqrt().powi(level as i32);
    let f = wavelet.filter_len();
    let cascade = |first: &[f64], rest: &[f64], start: f64| -> Vec<f64> {
        let mut y = upsample_convolve(&[start], first);
        for _ in 1..level {
            y = upsample_convolve(&y, rest);
        }
        y
    };
    let padded = |core: Vec<f64>, len: usize| -> Vec<f64> {
        let mut v = Vec::with_capacity(len);
        v.push(0.0);
        v.extend(core);
        v.resize(len, 0.0);
        v
    };
    if wavelet.is_orthogonal() {
        let len = ((f - 1) * (1 << level) + 1).max((f - 1) * (1 << level) + 4 - f);
        let phi = padded(cascade(wavelet.rec_lo(), wavelet.rec_lo(), scale), len);
        let psi = padded(cascade(wavelet.rec_hi(), wavelet.rec_lo(), scale), len);
        let x = (0..len).map(|m| m as f64 / p).collect();
        return Ok(WaveletFunctions {
            x,
            phi,
            psi,
            phi_dual: None,
            psi_dual: None,
        });
    }
    // PyWavelets flips the sign of ψ unless ψ has 4k+1 vanishing moments.
    let sign = if wavelet.vanishing_moments_psi() % 4 != 1 {
        -1.0
    } else {
        1.0
    };
    let len = ((f - 1) * (1 << level)).max((f - 1) * (1 << level) - f + 4);
    let dual_lo: Vec<f64> = wavelet.dec_lo().iter().rev().copied().collect();
    let dual_hi: Vec<f64> = wavelet.dec_hi().iter().rev().copied().collect();
    Ok(WaveletFunctions {
        x: (0..len).map(|m| m as f64 / p).collect(),
        phi: padded(cascade(wavelet.rec_lo(), wavelet.rec_lo(), scale), len),
        psi: padded(
            cascade(wavelet.rec_hi(), wavelet.rec_lo(), sign * scale),
            len,
        ),
        phi_dual: Some(padded(cascade(&dual_lo, &dual_lo, scale), len)),
        psi_dual: Some(padded(cascade(&dual_hi, &dual_lo, sign * scale), len)),
    })
}

/// Exact dyadic samples of the synthesis φ and ψ on `[0, F−1]` with spacing
/// `2^{−J}`, evaluated anywhere by linear interpolation. Build once, evaluate
/// many times.
///
/// ```
/// use gb_wavelet::{RefinableFunctions, Wavelet};
/// let table = RefinableFunctions::new(&Wavelet::new("db2")?, 10)?;
/// // φ(1) = (1+√3)/2 for db2
/// assert!((table.phi(1.0) - (1.0 + 3f64.sqrt()) / 2.0).abs() < 1e-12);
/// // partition of unity
/// let s: f64 = (-3..=3).map(|k| table.phi(0.3 - k as f64)).sum();
/// assert!((s - 1.0).abs() < 1e-6);
/// # Ok::<(), gb_wavelet::WaveletError>(())
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RefinableFunctions {
    resolution: usize,
    support: f64,
    phi: Vec<f64>,
    psi: Vec<f64>,
}

impl RefinableFunctions {
    /// Tabulates φ and ψ of `wavelet` at the points `m/2^resolution`
    /// (`resolution ≤ MAX_RESOLUTION`). Fails when the cascade does not converge (e.g. the
    /// synthesis functions of some `rbio` wavelets are not continuous).
    pub fn new(wavelet: &Wavelet, resolution: usize) -> Result<Self> {
        if resolution > MAX_RESOLUTION {
            return Err(WaveletError::InvalidParameter(format!(
                "resolution {resolution} > {MAX_RESOLUTION}"
            )));
        }
        let h = wavelet.rec_lo();
        let g = wavelet.rec_hi();
        let f = h.len();
        let first = h.iter().position(|v| *v != 0.0).unwrap_or(0);
        let last = h.iter().rposition(|v| *v != 0.0).unwrap_or(0);
        let core = &h[first..=last];
        let l = core.len();
        let sqrt2 = 2f64.sqrt();
        // φ̂ at the integers 0..l−1 (φ(x) = φ̂(x − first)).
        let mut ints = vec![0.0; l];
        if l <= 2 {
            ints[0] = 1.0; // box function
        } else {
            // power iteration v ← M v on the interior points 1..l−2
            let m = l - 2;
            let mut v = vec![1.0 / m as f64; m];
            let mut next = vec![0.0; m];
            let mut converged = false;
            for _ in 0..2000 {
                for (ni, out) in next.iter_mut().enumerate() {
                    let n = ni + 1;
                    let mut s = 0.0;
                    for (mi, vm) in v.iter().enumerate() {
                        let k = 2 * n as isize - (mi + 1) as isize;
                        if (0..l as isize).contains(&k) {
                            s += core[k as usize] * vm;
                        }
                    }
                    *out = sqrt2 * s;
                }
                let total: f64 = next.iter().sum();
                if !total.is_finite() || total == 0.0 {
                    break;
                }
                next.iter_mut().for_each(|x| *x /= total);
                let delta = v
                    .iter()
                    .zip(&next)
                    .fold(0.0f64, |d, (a, b)| d.max((a - b).abs()));
                std::mem::swap(&mut v, &mut next);
                if delta < 8.0 * l as f64 * f64::EPSILON {
                    converged = true;
                    break;
                }
            }
            if !converged {
                return Err(WaveletError::InvalidParameter(format!(
                    "cascade for `{}` does not converge at the integers",
                    wavelet.name()
                )));
            }
            ints[1..=m].copy_from_slice(&v);
        }
        // dyadic refinement of φ̂: level j from level j−1
        let mut table = ints;
        for j in 1..=resolution {
            let step = 1usize << (j - 1); // points per unit at level j−1
            let len = (l - 1) * 2 * step + 1;
            let mut next = vec![0.0; len];
            for (mi, out) in next.iter_mut().enumerate() {
                // φ̂(m/2^j) = √2 Σ_k ĥ_k φ̂((m − k·2^{j−1})/2^{j−1})
                let mut s = 0.0;
                for (k, hk) in core.iter().enumerate() {
                    if let Some(idx) = mi.checked_sub(k * step) {
                        if let Some(v) = table.get(idx) {
                            s += hk * v;
                        }
                    }
                }
                *out = sqrt2 * s;
            }
            if l <= 2 {
                // box: right-continuous at the end point
                if let Some(e) = next.last_mut() {
                    *e = 0.0;
                }
            }
            table = next;
        }
        let per = 1usize << resolution;
        let grid = (f - 1) * per + 1;
        // φ on [0, F−1]: shift φ̂ by `first`
        let mut phi = vec![0.0; grid];
        for (i, v) in table.iter().enumerate() {
            if let Some(slot) = phi.get_mut(i + first * per) {
                *slot = *v;
            }
        }
        // ψ(m/2^J) = √2 Σ_k g_k φ((m − k·2^{J−1})/2^{J−1}), φ at resolution J−1
        let coarse: Vec<f64> = if resolution == 0 {
            Vec::new()
        } else {
            phi.iter().step_by(2).copied().collect()
        };
        let half = per / 2;
        let mut psi = vec![0.0; grid];
        if resolution > 0 {
            for (mi, out) in psi.iter_mut().enumerate() {
                let mut s = 0.0;
                for (k, gk) in g.iter().enumerate() {
                    if let Some(idx) = mi.checked_sub(k * half) {
                        if let Some(v) = coarse.get(idx) {
                            s += gk * v;
                        }
                    }
                }
                *out = sqrt2 * s;
            }
        }
        Ok(Self {
            resolution,
            support: (f - 1) as f64,
            phi,
            psi,
        })
    }

    /// Support `[0, F−1]` of φ and ψ.
    pub fn support(&self) -> (f64, f64) {
        (0.0, self.support)
    }
    /// Dyadic resolution `J` of the table.
    pub fn resolution(&self) -> usize {
        self.resolution
    }
    /// Exact samples `φ(m/2^J)`.
    pub fn phi_samples(&self) -> &[f64] {
        &self.phi
    }
    /// Exact samples `ψ(m/2^J)`.
    pub fn psi_samples(&self) -> &[f64] {
        &self.psi
    }

    fn interpolate(&self, table: &[f64], x: f64) -> f64 {
        if !(x >= 0.0 && x <= self.support) {
            return 0.0;
        }
        let pos = x * (1u64 << self.resolution) as f64;
        let i = pos.floor() as usize;
        let t = pos - i as f64;
        let a = table.get(i).copied().unwrap_or(0.0);
        if t == 0.0 {
            return a;
        }
        let b = table.get(i + 1).copied().unwrap_or(0.0);
        a + t * (b - a)
    }

    /// φ(x) (0 outside the support).
    pub fn phi(&self, x: f64) -> f64 {
        self.interpolate(&self.phi, x)
    }
    /// ψ(x) (0 outside the support).
    pub fn psi(&self, x: f64) -> f64 {
        self.interpolate(&self.psi, x)
    }
    /// `φ_{j,k}(x) = 2^{j/2} φ(2^j x − k)`.
    pub fn phi_jk(&self, j: i32, k: i64, x: f64) -> f64 {
        2f64.powf(0.5 * j as f64) * self.phi(2f64.powi(j) * x - k as f64)
    }
    /// `ψ_{j,k}(x) = 2^{j/2} ψ(2^j x − k)`.
    pub fn psi_jk(&self, j: i32, k: i64, x: f64) -> f64 {
        2f64.powf(0.5 * j as f64) * self.psi(2f64.powi(j) * x - k as f64)
    }
}

/// Scaling function or wavelet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum AtomKind {
    /// φ.
    Scaling,
    /// ψ.
    Wavelet,
}

/// One 1-D factor `2^{j/2} f(2^j x − k)` with `f` = φ or ψ.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Atom {
    /// φ or ψ.
    pub kind: AtomKind,
    /// Scale `j`.
    pub level: i32,
    /// Translation `k`.
    pub shift: i64,
}

/// A term `c · Π_d atom_d(x_d)` of a tensor-product expansion.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExpansionTerm {
    /// Coefficient `c`.
    pub coefficient: f64,
    /// One atom per dimension.
    pub atoms: Vec<Atom>,
}

/// A finite wavelet expansion `f(x) = Σ_λ c_λ Π_d f_{λ,d}(x_d)` in `dims`
/// dimensions (tensor products of 1-D φ/ψ atoms), evaluated at arbitrary points.
///
/// ```
/// use gb_wavelet::{Atom, AtomKind, ExpansionTerm, Wavelet, WaveletExpansion};
/// let mut f = WaveletExpansion::new(&Wavelet::new("db3")?, 2, 12)?;
/// let phi = |k| Atom { kind: AtomKind::Scaling, level: 0, shift: k };
/// // a constant is reproduced by Σ_k φ(x−k) ⊗ Σ_k φ(y−k)
/// for kx in -5..=5 {
///     for ky in -5..=5 {
///         f.push(ExpansionTerm { coefficient: 2.0, atoms: vec![phi(kx), phi(ky)] })?;
///     }
/// }
/// assert!((f.eval(&[0.37, 1.2])? - 2.0).abs() < 1e-5);
/// # Ok::<(), gb_wavelet::WaveletError>(())
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WaveletExpansion {
    functions: RefinableFunctions,
    dims: usize,
    terms: Vec<ExpansionTerm>,
}

impl WaveletExpansion {
    /// An empty expansion in `dims ≥ 1` dimensions, φ/ψ tabulated at `2^{−resolution}`.
    pub fn new(wavelet: &Wavelet, dims: usize, resolution: usize) -> Result<Self> {
        if dims == 0 {
            return Err(WaveletError::InvalidParameter(
                "dims must be at least 1".into(),
            ));
        }
        Ok(Self {
            functions: RefinableFunctions::new(wavelet, resolution)?,
            dims,
            terms: Vec::new(),
        })
    }

    /// Adds a term (one atom per dimension).
    pub fn push(&mut self, term: ExpansionTerm) -> Result<()> {
        if term.atoms.len() != self.dims {
            return Err(WaveletError::ShapeMismatch(format!(
                "term has {} atoms, expansion has {} dimensions",
                term.atoms.len(),
                self.dims
            )));
        }
        if !term.coefficient.is_finite() {
            return Err(WaveletError::NonFinite("coefficient"));
        }
        self.terms.push(term);
        Ok(())
    }

    /// The terms.
    pub fn terms(&self) -> &[ExpansionTerm] {
        &self.terms
    }
    /// The tabulated φ and ψ.
    pub fn functions(&self) -> &RefinableFunctions {
        &self.functions
    }

    /// `f(x)` for a point `x` of `dims` coordinates.
    pub fn eval(&self, x: &[f64]) -> Result<f64> {
        if x.len() != self.dims {
            return Err(WaveletError::ShapeMismatch(format!(
                "point has {} coordinates, expansion has {} dimensions",
                x.len(),
                self.dims
            )));
        }
        let (_, hi) = self.functions.support();
        let mut sum = 0.0;
        'terms: for term in &self.terms {
            let mut prod = term.coefficient;
            for (atom, &xd) in term.atoms.iter().zip(x) {
                let scale = 2f64.powi(atom.level);
                let u = scale * xd - atom.shift as f64;
                if !(0.0..=hi).contains(&u) {
                    continue 'terms;
                }
                let v = match atom.kind {
                    AtomKind::Scaling => self.functions.phi(u),
                    AtomKind::Wavelet => self.functions.psi(u),
                };
                prod *= scale.sqrt() * v;
            }
            sum += prod;
        }
        Ok(sum)
    }
}
