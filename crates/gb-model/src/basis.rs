//! Sparse tensor-product wavelet expansions on a box.
//!
//! A function `f : [lo, hi] ⊂ ℝᵈ → ℝ` is written in the normalised
//! coordinates `s_d = (x_d − lo_d)/(hi_d − lo_d) ∈ [0, 1]` (clamped, so `f` is
//! constant beyond the box) as
//!
//! ```text
//! f(x) = Σ_λ c_λ Π_d 2^{j/2} f_{λ,d}(2^j s_d − k_{λ,d}),   f_{λ,d} ∈ {φ, ψ},
//! ```
//!
//! the multiresolution form of Mallat (2009, §7.7): scaling functions
//! `φ⊗…⊗φ` on a coarse level `j₀` and the `2ᵈ − 1` detail products (at least
//! one `ψ`) on the levels `j ≥ j₀`. Only the non-zero coefficients `c_λ` are
//! stored (Hauth 2008, ch. 5: sparse coefficient matrices). The 1-D φ and ψ
//! come from `gb-wavelet`'s exact dyadic point evaluation
//! ([`gb_wavelet::RefinableFunctions`]); the default wavelet `bior2.2` has
//! the hat function (linear B-spline) as synthesis φ, so `f` is piecewise
//! multilinear, its point values and derivatives are exact and affine
//! functions are reproduced by the coarse level alone.
//!
//! For evaluation the coefficients are compiled into dense blocks per
//! (level, kinds) group: at a point only `⌈support⌉` shifts per dimension
//! are non-zero, so one group costs `O(supportᵈ)` whatever the number of
//! stored coefficients.
use crate::error::{ModelError, Result};
use gb_wavelet::{AtomKind, RefinableFunctions, Wavelet};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Dyadic resolution of the φ/ψ tables (`2^{−10}` spacing).
pub const TABLE_RESOLUTION: usize = 10;
/// Largest number of arguments of one expansion.
pub const MAX_DIMS: usize = 4;

/// Most grid cells one (level, kinds) group of coefficients may span (the
/// dense evaluation grid over the bounding box of its shifts).
pub const MAX_GROUP_CELLS: u128 = 1 << 26;

/// One stored coefficient `c_λ` with its atom indices.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Coefficient {
    /// Scale `j` (the same for all dimensions).
    pub level: i32,
    /// φ or ψ per dimension.
    pub kinds: Vec<AtomKind>,
    /// Translation `k` per dimension.
    pub shifts: Vec<i64>,
    /// The coefficient.
    pub value: f64,
}

/// The serialised form of a [`SparseExpansion`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct ExpansionData {
    wavelet: String,
    lo: Vec<f64>,
    hi: Vec<f64>,
    coefficients: Vec<Coefficient>,
}

#[derive(Debug)]
struct Tables {
    per: f64,
    phi: Vec<f64>,
    psi: Vec<f64>,
    phi_support: (f64, f64),
    psi_support: (f64, f64),
    /// `Some(r)` when φ and ψ are linear between the points `m/2^r`
    /// (spline wavelets such as `bior2.x`): expansions are then exactly
    /// multilinear on a dyadic grid and evaluate through it.
    linear_resolution: Option<u32>,
}

/// Smallest `r ≤ 3` such that `table` is linear between the points `m/2^r`.
fn linear_resolution(table: &[f64], res: usize) -> Option<u32> {
    (0..=3u32).find(|&r| {
        let step = 1usize << (res as u32 - r);
        table.iter().enumerate().all(|(i, &v)| {
            let a = i / step * step;
            let b = (a + step).min(table.len() - 1);
            let t = if b > a {
                (i - a) as f64 / (b - a) as f64
            } else {
                0.0
            };
            let li = table[a] + t * (table[b] - table[a]);
            (li - v).abs() <= 1e-12 * (1.0 + v.abs())
        })
    })
}

impl Tables {
    fn new(name: &str) -> Result<Self> {
        let w = Wavelet::new(name)?;
        let r = RefinableFunctions::new(&w, TABLE_RESOLUTION)?;
        let per = (1u64 << TABLE_RESOLUTION) as f64;
        let support = |t: &[f64]| {
            let first = t.iter().position(|v| v.abs() > 1e-13).unwrap_or(0);
            let last = t.iter().rposition(|v| v.abs() > 1e-13).unwrap_or(0);
            (
                first.saturating_sub(1) as f64 / per,
                ((last + 1).min(t.len() - 1)) as f64 / per,
            )
        };
        let lr = linear_resolution(r.phi_samples(), TABLE_RESOLUTION)
            .zip(linear_resolution(r.psi_samples(), TABLE_RESOLUTION))
            .map(|(a, b)| a.max(b));
        Ok(Self {
            per,
            linear_resolution: lr,
            phi_support: support(r.phi_samples()),
            psi_support: support(r.psi_samples()),
            phi: r.phi_samples().to_vec(),
            psi: r.psi_samples().to_vec(),
        })
    }

    #[inline]
    fn table(&self, kind: AtomKind) -> (&[f64], (f64, f64)) {
        match kind {
            AtomKind::Scaling => (&self.phi, self.phi_support),
            AtomKind::Wavelet => (&self.psi, self.psi_support),
        }
    }

    /// Value and derivative of the 1-D function at `u` (linear interpolation).
    #[inline]
    fn eval(table: &[f64], per: f64, u: f64) -> (f64, f64) {
        let pos = u * per;
        if pos.is_nan() || pos < 0.0 {
            return (0.0, 0.0);
        }
        let i = pos as usize;
        if i + 1 >= table.len() {
            return (table.last().copied().unwrap_or(0.0), 0.0);
        }
        let a = table[i];
        let b = table[i + 1];
        let t = pos - i as f64;
        (a + t * (b - a), (b - a) * per)
    }
}

/// One (level, kinds) group compiled into a dense block.
#[derive(Debug, Clone)]
struct Group {
    scale: f64,
    norm: f64,
    kinds: Vec<AtomKind>,
    k_lo: Vec<i64>,
    len: Vec<usize>,
    stride: Vec<usize>,
    coef: Vec<f64>,
    index: Vec<u32>,
}

/// `f` and its nodes on the dyadic grid of the finest level, for
/// piecewise-linear wavelets (exact multilinear interpolation).
#[derive(Debug, Clone)]
struct Grid {
    d: usize,
    n: [usize; MAX_DIMS],
    stride: [usize; MAX_DIMS],
    values: Vec<f64>,
}

/// Most grid nodes built for fast evaluation.
const MAX_GRID_NODES: usize = 1 << 20;

impl Grid {
    /// Multilinear interpolation at the normalised point `s ∈ [0, 1]ᵈ`;
    /// gradient with respect to `s` into `grad`.
    #[inline(always)]
    fn eval(&self, s: &[f64], grad: Option<&mut [f64; MAX_DIMS]>) -> f64 {
        let d = self.d;
        let mut base = 0usize;
        let mut frac = [0.0f64; MAX_DIMS];
        let mut scale = [0.0f64; MAX_DIMS];
        for i in 0..d {
            let cells = (self.n[i] - 1) as f64;
            let pos = s[i] * cells;
            let mut c = pos as usize;
            if c >= self.n[i] - 1 {
                c = self.n[i] - 2;
            }
            frac[i] = pos - c as f64;
            scale[i] = cells;
            base += c * self.stride[i];
        }
        match d {
            1 => {
                let a = self.values[base];
                let b = self.values[base + 1];
                if let Some(g) = grad {
                    g[0] = (b - a) * scale[0];
                }
                a + frac[0] * (b - a)
            }
            2 => {
                let s0 = self.stride[0];
                let v00 = self.values[base];
                let v01 = self.values[base + 1];
                let v10 = self.values[base + s0];
                let v11 = self.values[base + s0 + 1];
                let (t0, t1) = (frac[0], frac[1]);
                let a = v00 + t1 * (v01 - v00);
                let b = v10 + t1 * (v11 - v10);
                if let Some(g) = grad {
                    g[0] = (b - a) * scale[0];
                    let c0 = v01 - v00;
                    let c1 = v11 - v10;
                    g[1] = (c0 + t0 * (c1 - c0)) * scale[1];
                }
                a + t0 * (b - a)
            }
            _ => {
                let corners = 1usize << d;
                let mut total = 0.0;
                let mut gacc = [0.0f64; MAX_DIMS];
                for c in 0..corners {
                    let mut off = base;
                    let mut w = 1.0;
                    for i in 0..d {
                        if c >> i & 1 == 1 {
                            off += self.stride[i];
                            w *= frac[i];
                        } else {
                            w *= 1.0 - frac[i];
                        }
                    }
                    let v = self.values[off];
                    total += w * v;
                    for i in 0..d {
                        let mut wi = scale[i];
                        for e in 0..d {
                            let up = c >> e & 1 == 1;
                            if e == i {
                                wi *= if up { 1.0 } else { -1.0 };
                            } else {
                                wi *= if up { frac[e] } else { 1.0 - frac[e] };
                            }
                        }
                        gacc[i] += wi * v;
                    }
                }
                if let Some(g) = grad {
                    g[..d].copy_from_slice(&gacc[..d]);
                }
                total
            }
        }
    }
}

/// Borrowed grid evaluator of an expansion (the simulation fast path).
#[derive(Debug, Clone, Copy)]
pub(crate) struct FastEval<'a> {
    grid: &'a Grid,
    lo: &'a [f64],
    inv: &'a [f64],
}

impl FastEval<'_> {
    /// `f(x)` for the first `d` entries of `x`.
    #[inline(always)]
    pub(crate) fn eval(&self, x: &[f64; MAX_DIMS], d: usize) -> f64 {
        let mut s = [0.0f64; MAX_DIMS];
        for i in 0..d {
            let v = (x[i] - self.lo[i]) * self.inv[i];
            s[i] = if v > 0.0 { v.min(1.0) } else { 0.0 };
        }
        self.grid.eval(&s[..d], None)
    }
}

/// Caller-owned scratch for [`SparseExpansion::eval_with`] (no allocation per call).
#[derive(Debug, Clone, Default)]
pub struct EvalScratch {
    off: Vec<usize>,
    val: Vec<f64>,
    der: Vec<f64>,
    cnt: Vec<usize>,
    /// `(coefficient index, basis value)` of the atoms that are non-zero at
    /// the last point, filled when requested.
    pub basis: Vec<(u32, f64)>,
}

/// A sparse tensor-product wavelet expansion on a box; see the module docs.
///
/// ```
/// use gb_model::{SparseExpansion, Coefficient};
/// use gb_wavelet::AtomKind;
/// // f(x) on [-1, 1]: the coarse hat functions on level 1 reproduce |x|
/// let mut f = SparseExpansion::new("bior2.2", vec![-1.0], vec![1.0])?;
/// f.add_coarse_grid(1)?;
/// let values: Vec<f64> = f.coefficients().iter().map(|c| {
///     let node = -1.0 + 2.0 * (c.shifts[0] as f64 + f.phi_center()) / 2.0;
///     node.abs() / 2f64.sqrt()
/// }).collect();
/// f.set_values(&values)?;
/// assert!((f.eval(&[0.3]) - 0.3).abs() < 1e-12);
/// assert!((f.eval(&[-0.8]) - 0.8).abs() < 1e-12);
/// # Ok::<(), gb_model::ModelError>(())
/// ```
#[derive(Debug, Clone)]
pub struct SparseExpansion {
    wavelet: String,
    lo: Vec<f64>,
    hi: Vec<f64>,
    coefficients: Vec<Coefficient>,
    tables: Arc<Tables>,
    groups: Vec<Group>,
    inv_width: Vec<f64>,
    grid: std::sync::OnceLock<Option<Arc<Grid>>>,
}

impl PartialEq for SparseExpansion {
    fn eq(&self, other: &Self) -> bool {
        self.wavelet == other.wavelet
            && self.lo == other.lo
            && self.hi == other.hi
            && self.coefficients == other.coefficients
    }
}

impl Serialize for SparseExpansion {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        ExpansionData {
            wavelet: self.wavelet.clone(),
            lo: self.lo.clone(),
            hi: self.hi.clone(),
            coefficients: self.coefficients.clone(),
        }
        .serialize(s)
    }
}

impl<'de> Deserialize<'de> for SparseExpansion {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let data = ExpansionData::deserialize(d)?;
        let mut e = SparseExpansion::new(&data.wavelet, data.lo, data.hi)
            .map_err(serde::de::Error::custom)?;
        for c in data.coefficients {
            e.push(c).map_err(serde::de::Error::custom)?;
        }
        Ok(e)
    }
}

impl SparseExpansion {
    /// An empty expansion (f = 0) of `lo.len()` arguments on the box `[lo, hi]`.
    pub fn new(wavelet: &str, lo: Vec<f64>, hi: Vec<f64>) -> Result<Self> {
        if lo.is_empty() || lo.len() > MAX_DIMS || lo.len() != hi.len() {
            return Err(ModelError::InvalidArgument(format!(
                "box needs 1..={MAX_DIMS} dimensions with lo and hi of equal length, got {} and {}",
                lo.len(),
                hi.len()
            )));
        }
        if lo
            .iter()
            .zip(&hi)
            .any(|(a, b)| !(a.is_finite() && b.is_finite() && b > a))
        {
            return Err(ModelError::InvalidArgument(format!(
                "box bounds must be finite with lo < hi, got {lo:?} / {hi:?}"
            )));
        }
        let inv_width = lo.iter().zip(&hi).map(|(a, b)| 1.0 / (b - a)).collect();
        Ok(Self {
            tables: Arc::new(Tables::new(wavelet)?),
            wavelet: wavelet.to_string(),
            lo,
            hi,
            coefficients: Vec::new(),
            groups: Vec::new(),
            inv_width,
            grid: std::sync::OnceLock::new(),
        })
    }

    /// Number of arguments.
    pub fn dims(&self) -> usize {
        self.lo.len()
    }
    /// The wavelet's name.
    pub fn wavelet(&self) -> &str {
        &self.wavelet
    }
    /// Lower corner of the box.
    pub fn lo(&self) -> &[f64] {
        &self.lo
    }
    /// Upper corner of the box.
    pub fn hi(&self) -> &[f64] {
        &self.hi
    }
    /// The stored coefficients (the parameter order of identification).
    pub fn coefficients(&self) -> &[Coefficient] {
        &self.coefficients
    }
    /// Number of stored coefficients.
    pub fn len(&self) -> usize {
        self.coefficients.len()
    }
    /// True when no coefficient is stored.
    pub fn is_empty(&self) -> bool {
        self.coefficients.is_empty()
    }
    /// Number of stored coefficients that are not zero.
    pub fn nnz(&self) -> usize {
        self.coefficients.iter().filter(|c| c.value != 0.0).count()
    }

    /// Centre of φ's effective support (e.g. 3 for the `bior2.2` hat on
    /// `[2, 4]`): the atom `φ_{j,k}` peaks at `s = (k + centre)/2^j`.
    pub fn phi_center(&self) -> f64 {
        let (a, b) = self.tables.phi_support;
        0.5 * (a + b)
    }

    /// Shifts `k` of level-`level` atoms of `kind` whose support meets `[0, 1]`.
    pub fn shift_range(&self, kind: AtomKind, level: i32) -> (i64, i64) {
        let (e0, e1) = self.tables.table(kind).1;
        let n = 2f64.powi(level);
        ((-e1).floor() as i64 + 1, (n - e0).ceil() as i64 - 1)
    }

    /// Adds a coefficient (a new atom, or replaces the value of a stored one).
    pub fn push(&mut self, c: Coefficient) -> Result<()> {
        let d = self.dims();
        if c.kinds.len() != d || c.shifts.len() != d {
            return Err(ModelError::Dimension(format!(
                "coefficient has {} kinds / {} shifts, expansion has {d} dimensions",
                c.kinds.len(),
                c.shifts.len()
            )));
        }
        if !c.value.is_finite() || !(-30..=30).contains(&c.level) {
            return Err(ModelError::InvalidArgument(format!(
                "coefficient must be finite with level in -30..=30, got {} at level {}",
                c.value, c.level
            )));
        }
        // Each (level, kinds) group is evaluated on a dense grid over the
        // bounding box of its shifts: refuse a coefficient that would make it
        // absurdly large (a corrupt model file), instead of aborting on the
        // allocation.
        let mut cells: u128 = 1;
        for dd in 0..d {
            let (mut lo, mut hi) = (c.shifts[dd], c.shifts[dd]);
            for o in &self.coefficients {
                if o.level == c.level && o.kinds == c.kinds {
                    lo = lo.min(o.shifts[dd]);
                    hi = hi.max(o.shifts[dd]);
                }
            }
            let len = (i128::from(hi) - i128::from(lo) + 1) as u128;
            cells = cells.saturating_mul(len);
        }
        if cells > MAX_GROUP_CELLS {
            return Err(ModelError::InvalidArgument(format!(
                "coefficient shifts {:?} at level {} spread the atoms of one level over {cells} grid cells (at most {MAX_GROUP_CELLS})",
                c.shifts, c.level
            )));
        }
        if let Some(old) = self
            .coefficients
            .iter_mut()
            .find(|o| o.level == c.level && o.kinds == c.kinds && o.shifts == c.shifts)
        {
            old.value = c.value;
        } else {
            self.coefficients.push(c);
        }
        self.compile();
        Ok(())
    }

    /// Adds the full tensor grid of scaling functions `φ_{j₀,k}⊗…` whose
    /// support meets the box (value 0 where not stored yet).
    pub fn add_coarse_grid(&mut self, level: i32) -> Result<()> {
        let kinds = vec![AtomKind::Scaling; self.dims()];
        for shifts in self.all_shifts(&kinds, level) {
            if !self.contains(level, &kinds, &shifts) {
                self.coefficients.push(Coefficient {
                    level,
                    kinds: kinds.clone(),
                    shifts,
                    value: 0.0,
                });
            }
        }
        self.compile();
        Ok(())
    }

    /// All detail atoms (at least one ψ) of `level` whose support meets the
    /// box and which are not stored yet.
    pub fn detail_candidates(&self, level: i32) -> Vec<Coefficient> {
        let d = self.dims();
        let mut out = Vec::new();
        for mask in 1..(1usize << d) {
            let kinds: Vec<AtomKind> = (0..d)
                .map(|i| {
                    if mask >> i & 1 == 1 {
                        AtomKind::Wavelet
                    } else {
                        AtomKind::Scaling
                    }
                })
                .collect();
            for shifts in self.all_shifts(&kinds, level) {
                if !self.contains(level, &kinds, &shifts) {
                    out.push(Coefficient {
                        level,
                        kinds: kinds.clone(),
                        shifts,
                        value: 0.0,
                    });
                }
            }
        }
        out
    }

    fn contains(&self, level: i32, kinds: &[AtomKind], shifts: &[i64]) -> bool {
        self.coefficients
            .iter()
            .any(|c| c.level == level && c.kinds == kinds && c.shifts == shifts)
    }

    fn all_shifts(&self, kinds: &[AtomKind], level: i32) -> Vec<Vec<i64>> {
        let ranges: Vec<(i64, i64)> = kinds.iter().map(|&k| self.shift_range(k, level)).collect();
        let mut out = vec![Vec::new()];
        for &(a, b) in &ranges {
            let mut next = Vec::new();
            for prefix in &out {
                for k in a..=b {
                    let mut p = prefix.clone();
                    p.push(k);
                    next.push(p);
                }
            }
            out = next;
        }
        out
    }

    /// Appends coefficients (e.g. candidates) without checking duplicates.
    pub(crate) fn extend_unchecked(&mut self, cs: Vec<Coefficient>) {
        self.coefficients.extend(cs);
        self.compile();
    }

    /// Sets all coefficient values (in [`coefficients`](Self::coefficients) order).
    pub fn set_values(&mut self, values: &[f64]) -> Result<()> {
        if values.len() != self.coefficients.len() {
            return Err(ModelError::Dimension(format!(
                "{} values for {} coefficients",
                values.len(),
                self.coefficients.len()
            )));
        }
        if values.iter().any(|v| !v.is_finite()) {
            return Err(ModelError::InvalidArgument(
                "coefficients must be finite".into(),
            ));
        }
        for (c, &v) in self.coefficients.iter_mut().zip(values) {
            c.value = v;
        }
        self.refresh_values();
        Ok(())
    }

    /// Keeps only the coefficients for which `keep(index, coefficient)` holds.
    pub fn retain(&mut self, mut keep: impl FnMut(usize, &Coefficient) -> bool) {
        let mut i = 0;
        self.coefficients.retain(|c| {
            let k = keep(i, c);
            i += 1;
            k
        });
        self.compile();
    }

    /// Removes the coefficients that are exactly zero (the sparse form).
    pub fn drop_zeros(&mut self) {
        self.retain(|_, c| c.value != 0.0);
    }

    fn refresh_values(&mut self) {
        self.grid = std::sync::OnceLock::new();
        for g in self.groups.iter_mut() {
            for (slot, &ix) in g.coef.iter_mut().zip(&g.index) {
                if ix != u32::MAX {
                    *slot = self.coefficients[ix as usize].value;
                }
            }
        }
    }

    fn compile(&mut self) {
        self.grid = std::sync::OnceLock::new();
        let d = self.dims();
        let mut groups: Vec<Group> = Vec::new();
        let mut keys: Vec<(i32, Vec<AtomKind>)> = Vec::new();
        for c in &self.coefficients {
            if !keys.iter().any(|(l, k)| *l == c.level && *k == c.kinds) {
                keys.push((c.level, c.kinds.clone()));
            }
        }
        for (level, kinds) in keys {
            let members: Vec<usize> = (0..self.coefficients.len())
                .filter(|&i| {
                    self.coefficients[i].level == level && self.coefficients[i].kinds == kinds
                })
                .collect();
            let mut k_lo = vec![i64::MAX; d];
            let mut k_hi = vec![i64::MIN; d];
            for &i in &members {
                for (dd, &k) in self.coefficients[i].shifts.iter().enumerate() {
                    k_lo[dd] = k_lo[dd].min(k);
                    k_hi[dd] = k_hi[dd].max(k);
                }
            }
            let len: Vec<usize> = (0..d).map(|i| (k_hi[i] - k_lo[i] + 1) as usize).collect();
            let mut stride = vec![1usize; d];
            for i in (0..d.saturating_sub(1)).rev() {
                stride[i] = stride[i + 1] * len[i + 1];
            }
            let total: usize = len.iter().product();
            let mut coef = vec![0.0; total];
            let mut index = vec![u32::MAX; total];
            for &i in &members {
                let c = &self.coefficients[i];
                let flat: usize = (0..d)
                    .map(|dd| (c.shifts[dd] - k_lo[dd]) as usize * stride[dd])
                    .sum();
                coef[flat] = c.value;
                index[flat] = i as u32;
            }
            groups.push(Group {
                scale: 2f64.powi(level),
                norm: 2f64.powf(0.5 * level as f64),
                kinds,
                k_lo,
                len,
                stride,
                coef,
                index,
            });
        }
        self.groups = groups;
    }

    /// The grid evaluator, for piecewise-linear wavelets.
    pub(crate) fn fast(&self) -> Option<FastEval<'_>> {
        self.grid().map(|grid| FastEval {
            grid,
            lo: &self.lo,
            inv: &self.inv_width,
        })
    }

    /// The fast-evaluation grid (built on first use), for piecewise-linear wavelets.
    fn grid(&self) -> Option<&Grid> {
        self.grid
            .get_or_init(|| {
                let r = self.tables.linear_resolution?;
                let d = self.dims();
                let jmax = self.coefficients.iter().map(|c| c.level).max()?;
                let level = jmax + r as i32;
                if !(0..=20).contains(&level) {
                    return None;
                }
                let cells = 1usize << level;
                let n = vec![cells + 1; d];
                let total = n.iter().try_fold(1usize, |a, &b| a.checked_mul(b))?;
                if total > MAX_GRID_NODES {
                    return None;
                }
                let mut stride = vec![1usize; d];
                for i in (0..d.saturating_sub(1)).rev() {
                    stride[i] = stride[i + 1] * n[i + 1];
                }
                let mut values = vec![0.0; total];
                let mut scratch = EvalScratch::default();
                let mut x = [0.0f64; MAX_DIMS];
                for (flat, v) in values.iter_mut().enumerate() {
                    for i in 0..d {
                        let k = flat / stride[i] % n[i];
                        x[i] = self.lo[i] + (self.hi[i] - self.lo[i]) * k as f64 / cells as f64;
                    }
                    *v = self.eval_atoms(&x[..d], None, false, &mut scratch);
                }
                let mut na = [0usize; MAX_DIMS];
                let mut sa = [0usize; MAX_DIMS];
                na[..d].copy_from_slice(&n);
                sa[..d].copy_from_slice(&stride);
                Some(Arc::new(Grid {
                    d,
                    n: na,
                    stride: sa,
                    values,
                }))
            })
            .as_deref()
    }

    /// `f(x)` (allocates a scratch; use [`eval_with`](Self::eval_with) in loops).
    pub fn eval(&self, x: &[f64]) -> f64 {
        let mut s = EvalScratch::default();
        self.eval_with(x, None, false, &mut s)
    }

    /// `f(x)`; with `grad` also `∂f/∂x` (0 outside the box), with `basis` the
    /// non-zero basis values `(index, Ψ_λ(x))` in `scratch.basis`.
    #[inline]
    pub fn eval_with(
        &self,
        x: &[f64],
        grad: Option<&mut [f64]>,
        basis: bool,
        scratch: &mut EvalScratch,
    ) -> f64 {
        if !basis {
            if let Some(g) = self.grid() {
                let d = self.dims();
                let mut s = [0.0f64; MAX_DIMS];
                let mut inside = [0.0f64; MAX_DIMS];
                for i in 0..d {
                    let v = (x[i] - self.lo[i]) * self.inv_width[i];
                    if v > 0.0 && v < 1.0 {
                        s[i] = v;
                        inside[i] = self.inv_width[i];
                    } else {
                        s[i] = if v >= 1.0 { 1.0 } else { 0.0 };
                    }
                }
                return match grad {
                    Some(gr) => {
                        let mut gs = [0.0f64; MAX_DIMS];
                        let v = g.eval(&s[..d], Some(&mut gs));
                        for i in 0..d {
                            gr[i] = gs[i] * inside[i];
                        }
                        v
                    }
                    None => g.eval(&s[..d], None),
                };
            }
        }
        self.eval_atoms(x, grad, basis, scratch)
    }

    /// [`eval_with`](Self::eval_with) through the atoms (no grid).
    pub fn eval_atoms(
        &self,
        x: &[f64],
        mut grad: Option<&mut [f64]>,
        basis: bool,
        scratch: &mut EvalScratch,
    ) -> f64 {
        let d = self.dims();
        let tables = &*self.tables;
        let per = tables.per;
        let mut s = [0.0f64; MAX_DIMS];
        let mut inside = [0.0f64; MAX_DIMS];
        for i in 0..d {
            let v = (x[i] - self.lo[i]) * self.inv_width[i];
            if v > 0.0 && v < 1.0 {
                s[i] = v;
                inside[i] = self.inv_width[i];
            } else {
                s[i] = if v >= 1.0 { 1.0 } else { 0.0 };
            }
        }
        if let Some(g) = grad.as_deref_mut() {
            g[..d].fill(0.0);
        }
        if basis {
            scratch.basis.clear();
        }
        let maxk = tables.phi.len() / per as usize + 2;
        if scratch.off.len() < d * maxk {
            scratch.off.resize(d * maxk, 0);
            scratch.val.resize(d * maxk, 0.0);
            scratch.der.resize(d * maxk, 0.0);
        }
        if scratch.cnt.len() < d {
            scratch.cnt.resize(d, 0);
        }
        let mut total = 0.0;
        let mut gacc = [0.0f64; MAX_DIMS];
        'groups: for g in &self.groups {
            for i in 0..d {
                let (table, (e0, e1)) = tables.table(g.kinds[i]);
                let t = g.scale * s[i];
                let k_first = ((t - e1).floor() as i64 + 1).max(g.k_lo[i]);
                let k_last = ((t - e0).floor() as i64).min(g.k_lo[i] + g.len[i] as i64 - 1);
                if k_first > k_last {
                    continue 'groups;
                }
                let mut n = 0;
                for k in k_first..=k_last {
                    let (v, dv) = Tables::eval(table, per, t - k as f64);
                    let slot = i * maxk + n;
                    scratch.off[slot] = (k - g.k_lo[i]) as usize * g.stride[i];
                    scratch.val[slot] = g.norm * v;
                    scratch.der[slot] = g.norm * g.scale * dv;
                    n += 1;
                }
                scratch.cnt[i] = n;
            }
            // odometer over the product of the per-dimension ranges
            let mut pos = [0usize; MAX_DIMS];
            loop {
                let mut flat = 0;
                let mut prod = 1.0;
                for i in 0..d {
                    let slot = i * maxk + pos[i];
                    flat += scratch.off[slot];
                    prod *= scratch.val[slot];
                }
                let c = g.coef[flat];
                if basis && g.index[flat] != u32::MAX {
                    scratch.basis.push((g.index[flat], prod));
                }
                if c != 0.0 {
                    total += c * prod;
                    if grad.is_some() {
                        for i in 0..d {
                            let mut p = c;
                            for e in 0..d {
                                let slot = e * maxk + pos[e];
                                p *= if e == i {
                                    scratch.der[slot]
                                } else {
                                    scratch.val[slot]
                                };
                            }
                            gacc[i] += p;
                        }
                    }
                }
                // advance
                let mut i = d;
                loop {
                    if i == 0 {
                        break;
                    }
                    i -= 1;
                    pos[i] += 1;
                    if pos[i] < scratch.cnt[i] {
                        break;
                    }
                    pos[i] = 0;
                    if i == 0 {
                        i = usize::MAX;
                        break;
                    }
                }
                if i == usize::MAX {
                    break;
                }
            }
        }
        if let Some(gr) = grad {
            for i in 0..d {
                gr[i] = gacc[i] * inside[i];
            }
        }
        total
    }

    /// `f` on a regular grid of `n` points per dimension of a 1-D or 2-D box
    /// (plot data): rows `(x…, f(x))`.
    pub fn table(&self, n: usize) -> Vec<Vec<f64>> {
        let d = self.dims();
        let n = n.max(2);
        let mut out = Vec::new();
        let mut idx = vec![0usize; d];
        let mut scratch = EvalScratch::default();
        loop {
            let x: Vec<f64> = (0..d)
                .map(|i| self.lo[i] + (self.hi[i] - self.lo[i]) * idx[i] as f64 / (n - 1) as f64)
                .collect();
            let v = self.eval_with(&x, None, false, &mut scratch);
            let mut row = x;
            row.push(v);
            out.push(row);
            let mut i = d;
            loop {
                if i == 0 {
                    return out;
                }
                i -= 1;
                idx[i] += 1;
                if idx[i] < n {
                    break;
                }
                idx[i] = 0;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hat_grid(
        level: i32,
        f: impl Fn(&[f64]) -> f64,
        lo: Vec<f64>,
        hi: Vec<f64>,
    ) -> SparseExpansion {
        let mut e = SparseExpansion::new("bior2.2", lo.clone(), hi.clone()).unwrap();
        e.add_coarse_grid(level).unwrap();
        let c = e.phi_center();
        let n = 2f64.powi(level);
        let norm = 2f64.powf(0.5 * level as f64);
        let vals: Vec<f64> = e
            .coefficients()
            .iter()
            .map(|co| {
                let x: Vec<f64> = (0..lo.len())
                    .map(|d| lo[d] + (hi[d] - lo[d]) * (co.shifts[d] as f64 + c) / n)
                    .collect();
                f(&x) / norm.powi(lo.len() as i32)
            })
            .collect();
        e.set_values(&vals).unwrap();
        e
    }

    #[test]
    fn hat_basis_reproduces_piecewise_bilinear_functions_exactly() {
        // Bouc-Wen-like f(v, z) = -0.8|v|z + 1.1 v|z| is bilinear in each quadrant
        let f = |x: &[f64]| -0.8 * x[0].abs() * x[1] + 1.1 * x[0] * x[1].abs();
        let e = hat_grid(1, f, vec![-1.0, -2.0], vec![1.0, 2.0]);
        let mut s = EvalScratch::default();
        let mut g = [0.0; 2];
        for &(v, z) in &[(0.3, -1.2), (-0.7, 0.4), (0.99, 1.9), (-0.2, -0.1)] {
            let y = e.eval_with(&[v, z], Some(&mut g), false, &mut s);
            assert!((y - f(&[v, z])).abs() < 1e-12, "{v} {z}: {y}");
            let h = 1e-6;
            let fd = (f(&[v + h, z]) - f(&[v - h, z])) / (2.0 * h);
            assert!((g[0] - fd).abs() < 1e-6, "{} vs {fd}", g[0]);
        }
    }

    #[test]
    fn details_refine_and_basis_values_match() {
        let mut e = SparseExpansion::new("db4", vec![0.0], vec![1.0]).unwrap();
        e.add_coarse_grid(2).unwrap();
        let cands = e.detail_candidates(3);
        assert!(!cands.is_empty());
        e.extend_unchecked(cands);
        let vals: Vec<f64> = (0..e.len()).map(|i| ((i * 37) % 11) as f64 - 5.0).collect();
        e.set_values(&vals).unwrap();
        let mut s = EvalScratch::default();
        let y = e.eval_with(&[0.37], None, true, &mut s);
        let recon: f64 = s.basis.iter().map(|&(i, b)| vals[i as usize] * b).sum();
        assert!((y - recon).abs() < 1e-9);
        // against gb-wavelet's generic expansion
        let w = Wavelet::new("db4").unwrap();
        let mut g = gb_wavelet::WaveletExpansion::new(&w, 1, TABLE_RESOLUTION).unwrap();
        for c in e.coefficients() {
            g.push(gb_wavelet::ExpansionTerm {
                coefficient: c.value,
                atoms: vec![gb_wavelet::Atom {
                    kind: c.kinds[0],
                    level: c.level,
                    shift: c.shifts[0],
                }],
            })
            .unwrap();
        }
        for &x in &[0.01, 0.37, 0.5, 0.93] {
            assert!((e.eval(&[x]) - g.eval(&[x]).unwrap()).abs() < 1e-9, "{x}");
        }
    }

    #[test]
    fn grid_evaluation_equals_atom_evaluation_for_spline_wavelets() {
        for d in 1..=3usize {
            let mut e = SparseExpansion::new("bior2.2", vec![-1.0; d], vec![2.0; d]).unwrap();
            assert!(e.tables.linear_resolution.is_some());
            e.add_coarse_grid(1).unwrap();
            let c = e.detail_candidates(1);
            e.extend_unchecked(c);
            let c = e.detail_candidates(2);
            e.extend_unchecked(c);
            let vals: Vec<f64> = (0..e.len())
                .map(|i| ((i * 7919) % 13) as f64 - 6.0)
                .collect();
            e.set_values(&vals).unwrap();
            let mut s = EvalScratch::default();
            for k in 0..50 {
                let x: Vec<f64> = (0..d)
                    .map(|i| -1.2 + 3.4 * (((k * 31 + i * 17) % 97) as f64 / 96.0))
                    .collect();
                let mut g1 = [0.0; MAX_DIMS];
                let mut g2 = [0.0; MAX_DIMS];
                let a = e.eval_with(&x, Some(&mut g1[..d]), false, &mut s);
                let b = e.eval_atoms(&x, Some(&mut g2[..d]), false, &mut s);
                assert!(
                    (a - b).abs() < 1e-9 * (1.0 + b.abs()),
                    "d {d} x {x:?}: {a} vs {b}"
                );
                for i in 0..d {
                    // derivatives agree except on cell boundaries
                    assert!((g1[i] - g2[i]).abs() < 1e-6 * (1.0 + g2[i].abs()) || k % 8 == 0,);
                }
            }
        }
        assert!(SparseExpansion::new("db4", vec![0.0], vec![1.0])
            .unwrap()
            .tables
            .linear_resolution
            .is_none());
    }

    #[test]
    fn serde_roundtrip_rebuilds_the_evaluator() {
        let e = hat_grid(2, |x| x[0] * x[0], vec![-1.0], vec![1.0]);
        let bytes = postcard::to_allocvec(&e).unwrap();
        let back: SparseExpansion = postcard::from_bytes(&bytes).unwrap();
        assert_eq!(back, e);
        assert_eq!(back.eval(&[0.3]), e.eval(&[0.3]));
    }
}
