//! Everett (primitive) functions of Preisach densities.
//!
//! For a Preisach density μ(α, β) on the half-plane α ≥ β the Everett
//! function (Everett 1955; Mayergoyz 2003, ch. 1) is the mass of the triangle
//! T(α, β) = {(α', β') : β ≤ β' ≤ α' ≤ α}:
//!
//! F(α, β) = ∫∫_{T(α,β)} μ(α', β') dα' dβ',  F(α, α) = 0,  μ = −∂²F/∂α∂β.
//!
//! The Preisach output is a signed sum of F at the corners of the memory
//! staircase (see [`crate::Preisach`]), so any Everett function, parametric or
//! tabulated, defines a model.

use crate::special::{
    cauchy_cdf, cauchy_pdf, normal_cdf_at, normal_cdf_in_table, normal_pdf, phi_table, PhiTable,
    PHI_T_MAX, PHI_T_MIN, PHI_T_OFFSET, PHI_T_SCALE,
};
use crate::PreisachError;
use serde::{Deserialize, Serialize};
use std::fmt::Debug;

/// An Everett function F(α, β) on the limiting triangle β₀ ≤ β ≤ α ≤ α₀
/// (the [`support`](Everett::support), possibly infinite).
///
/// A point is first turned into a [`Node`](Everett::Node) (e.g. the
/// distribution-function values, or a grid cell and offset); the memory keeps
/// the nodes of its corners so one step of the operator costs one
/// [`node`](Everett::node) and one [`value`](Everett::value).
pub trait Everett {
    /// Precomputed data of one point, cached for memory corners.
    type Node: Copy + Debug;

    /// Limiting triangle (β₀, α₀); inputs are clamped into it (the density
    /// vanishes outside). Either bound may be infinite.
    fn support(&self) -> (f64, f64);

    /// Node of a point of the support.
    fn node(&self, x: f64) -> Self::Node;

    /// F(α, β) for nodes with α ≥ β.
    fn value(&self, alpha: &Self::Node, beta: &Self::Node) -> f64;

    /// Signed open link of the staircase from corner `s` to the input `x`:
    /// F(x, s) when `ascending`, −F(s, x) otherwise.
    #[inline]
    fn link(&self, x: &Self::Node, s: &Self::Node, ascending: bool) -> f64 {
        if ascending {
            self.value(x, s)
        } else {
            -self.value(s, x)
        }
    }

    /// Partial derivatives (∂F/∂α, ∂F/∂β) at α ≥ β; ∂F/∂α ≥ 0 ≥ ∂F/∂β for a
    /// non-negative density.
    fn partials(&self, alpha: &Self::Node, beta: &Self::Node) -> (f64, f64);

    /// F(α, β) from plain numbers: arguments are clamped into the support and
    /// F = 0 for α ≤ β.
    fn everett(&self, alpha: f64, beta: f64) -> f64 {
        let (lo, hi) = self.support();
        let a = alpha.max(lo).min(hi);
        let b = beta.max(lo).min(hi);
        if a <= b {
            return 0.0;
        }
        self.value(&self.node(a), &self.node(b))
    }

    /// Total mass F(α₀, β₀) of the limiting triangle (the saturation output).
    fn total(&self) -> f64 {
        let (lo, hi) = self.support();
        self.value(&self.node(hi), &self.node(lo))
    }

    /// Plot data: F on an (n+1)×(n+1) grid over `[lo, hi]`, as
    /// `(α, β, F(α, β))` for the nodes with α ≥ β.
    fn everett_table(&self, lo: f64, hi: f64, n: usize) -> Vec<(f64, f64, f64)> {
        let n = n.max(1);
        let h = |i: usize| lo + (hi - lo) * i as f64 / n as f64;
        let mut out = Vec::with_capacity((n + 1) * (n + 2) / 2);
        for i in 0..=n {
            for j in 0..=i {
                out.push((h(i), h(j), self.everett(h(i), h(j))));
            }
        }
        out
    }
}

/// Shape of the one-dimensional threshold distributions of a
/// [`ParametricEverett`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum DensityShape {
    /// Normal distribution (centre = mean, width = standard deviation).
    Gaussian,
    /// Cauchy / Lorentzian distribution (centre = location, width = half
    /// width at half maximum).
    Lorentzian,
}

impl DensityShape {
    #[inline]
    fn pdf(self, z: f64) -> f64 {
        match self {
            DensityShape::Gaussian => normal_pdf(z),
            DensityShape::Lorentzian => cauchy_pdf(z),
        }
    }
}

/// Parametric Everett function with a closed form.
///
/// With P, Q the distribution functions (shape [`DensityShape`]) of the
/// up-switching thresholds α (centre `a`, width `w_a`) and of the
/// down-switching thresholds β (centre `b`, width `w_b`), and total mass `c`,
///
/// F(α, β) = c · (P(α) − P(β)) · (Q(α) − Q(β)),
///
/// which is exactly the Everett function of the Preisach density
/// μ(α, β) = c · [p(α) q(β) + p(β) q(α)] on α ≥ β: the product density
/// (Gaussian or Lorentzian in α and β) plus its mirror image in the
/// diagonal, folded into the half-plane. For `a > b` the mirror term is only
/// the tail beyond the diagonal. The support is the whole half-plane and
/// F(∞, −∞) = c.
///
/// ```
/// use gb_preisach::{Everett, ParametricEverett};
/// let f = ParametricEverett::gaussian(2.0, 0.5, 0.3, -0.5, 0.3).unwrap();
/// assert!((f.total() - 2.0).abs() < 1e-15);
/// assert_eq!(f.everett(0.2, 0.2), 0.0);
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "ParametricEverettData")]
pub struct ParametricEverett {
    shape: DensityShape,
    mass: f64,
    up_center: f64,
    up_width: f64,
    down_center: f64,
    down_width: f64,
    #[serde(skip)]
    fast: FastCdf,
}

/// Precomputed affine maps x ↦ k·x + c to the argument of the distribution
/// functions (table coordinate for Gaussian, z for Lorentzian), the Φ
/// table and the inputs [lo, hi) for which both coordinates lie inside the
/// table (with a margin of ¼ cell for rounding); derived from the
/// parameters, so ignored by `==` and serde.
#[derive(Clone, Copy)]
struct FastCdf {
    table: &'static PhiTable,
    ka: f64,
    ca: f64,
    kb: f64,
    cb: f64,
    lo: f64,
    hi: f64,
}

impl FastCdf {
    fn new(shape: DensityShape, a: f64, wa: f64, b: f64, wb: f64) -> Self {
        let (scale, offset) = match shape {
            DensityShape::Gaussian => (PHI_T_SCALE, PHI_T_OFFSET),
            DensityShape::Lorentzian => (1.0, 0.0),
        };
        let (ka, ca, kb, cb) = (
            scale / wa,
            offset - a * scale / wa,
            scale / wb,
            offset - b * scale / wb,
        );
        let (t0, t1) = (PHI_T_MIN + 0.25, PHI_T_MAX - 0.25);
        Self {
            table: phi_table(),
            ka,
            ca,
            kb,
            cb,
            lo: ((t0 - ca) / ka).max((t0 - cb) / kb),
            hi: ((t1 - ca) / ka).min((t1 - cb) / kb),
        }
    }
}

impl Default for FastCdf {
    fn default() -> Self {
        Self::new(DensityShape::Gaussian, 0.0, 1.0, 0.0, 1.0)
    }
}

impl PartialEq for FastCdf {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl std::fmt::Debug for FastCdf {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("..")
    }
}

/// Serialised form of a [`ParametricEverett`] (validated on load).
#[derive(Deserialize)]
struct ParametricEverettData {
    shape: DensityShape,
    mass: f64,
    up_center: f64,
    up_width: f64,
    down_center: f64,
    down_width: f64,
}

impl TryFrom<ParametricEverettData> for ParametricEverett {
    type Error = PreisachError;
    fn try_from(d: ParametricEverettData) -> Result<Self, PreisachError> {
        ParametricEverett::new(
            d.shape,
            d.mass,
            d.up_center,
            d.up_width,
            d.down_center,
            d.down_width,
        )
    }
}

/// Node of a [`ParametricEverett`]: the point and its two distribution
/// function values.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ParametricNode {
    x: f64,
    p: f64,
    q: f64,
}

impl ParametricEverett {
    /// A parametric Everett function; `mass` > 0 and the widths > 0, all
    /// finite.
    pub fn new(
        shape: DensityShape,
        mass: f64,
        up_center: f64,
        up_width: f64,
        down_center: f64,
        down_width: f64,
    ) -> Result<Self, PreisachError> {
        let all = [mass, up_center, up_width, down_center, down_width];
        if all.iter().any(|v| !v.is_finite()) || mass <= 0.0 || up_width <= 0.0 || down_width <= 0.0
        {
            return Err(PreisachError::InvalidArgument(format!(
                "parametric Everett needs finite values, mass > 0 and widths > 0, got {all:?}"
            )));
        }
        Ok(Self {
            shape,
            mass,
            up_center,
            up_width,
            down_center,
            down_width,
            fast: FastCdf::new(shape, up_center, up_width, down_center, down_width),
        })
    }

    /// Gaussian thresholds: α ~ N(`up_mean`, `up_sd`²), β ~ N(`down_mean`,
    /// `down_sd`²).
    pub fn gaussian(
        mass: f64,
        up_mean: f64,
        up_sd: f64,
        down_mean: f64,
        down_sd: f64,
    ) -> Result<Self, PreisachError> {
        Self::new(
            DensityShape::Gaussian,
            mass,
            up_mean,
            up_sd,
            down_mean,
            down_sd,
        )
    }

    /// Lorentzian (Cauchy) thresholds with locations and half widths.
    pub fn lorentzian(
        mass: f64,
        up_loc: f64,
        up_hw: f64,
        down_loc: f64,
        down_hw: f64,
    ) -> Result<Self, PreisachError> {
        Self::new(
            DensityShape::Lorentzian,
            mass,
            up_loc,
            up_hw,
            down_loc,
            down_hw,
        )
    }

    /// Shape of the threshold distributions.
    pub fn shape(&self) -> DensityShape {
        self.shape
    }

    /// Total mass c.
    pub fn mass(&self) -> f64 {
        self.mass
    }

    /// Preisach density μ(α, β) = c [p(α) q(β) + p(β) q(α)] for α ≥ β, 0
    /// otherwise.
    pub fn density(&self, alpha: f64, beta: f64) -> f64 {
        if alpha < beta {
            return 0.0;
        }
        let p = |x: f64| self.shape.pdf((x - self.up_center) / self.up_width) / self.up_width;
        let q = |x: f64| self.shape.pdf((x - self.down_center) / self.down_width) / self.down_width;
        self.mass * (p(alpha) * q(beta) + p(beta) * q(alpha))
    }
}

impl Everett for ParametricEverett {
    type Node = ParametricNode;

    fn support(&self) -> (f64, f64) {
        (f64::NEG_INFINITY, f64::INFINITY)
    }

    #[inline(always)]
    fn node(&self, x: f64) -> ParametricNode {
        let f = &self.fast;
        let (ta, tb) = (f.ka * x + f.ca, f.kb * x + f.cb);
        let (p, q) = match self.shape {
            // One range check for both table look-ups.
            DensityShape::Gaussian if x >= f.lo && x < f.hi => (
                normal_cdf_in_table(f.table, ta),
                normal_cdf_in_table(f.table, tb),
            ),
            DensityShape::Gaussian => (normal_cdf_at(f.table, ta), normal_cdf_at(f.table, tb)),
            DensityShape::Lorentzian => (cauchy_cdf(ta), cauchy_cdf(tb)),
        };
        ParametricNode { x, p, q }
    }

    #[inline]
    fn value(&self, a: &ParametricNode, b: &ParametricNode) -> f64 {
        self.mass * (a.p - b.p) * (a.q - b.q)
    }

    /// F is symmetric in its nodes, so only the sign depends on the
    /// direction (branch-free).
    #[inline(always)]
    fn link(&self, x: &ParametricNode, s: &ParametricNode, ascending: bool) -> f64 {
        let v = self.mass * (x.p - s.p) * (x.q - s.q);
        f64::from_bits(v.to_bits() ^ (u64::from(!ascending) << 63))
    }

    fn partials(&self, a: &ParametricNode, b: &ParametricNode) -> (f64, f64) {
        let pd = |x: f64| {
            if x.is_finite() {
                self.shape.pdf((x - self.up_center) / self.up_width) / self.up_width
            } else {
                0.0
            }
        };
        let qd = |x: f64| {
            if x.is_finite() {
                self.shape.pdf((x - self.down_center) / self.down_width) / self.down_width
            } else {
                0.0
            }
        };
        let dp = a.p - b.p;
        let dq = a.q - b.q;
        (
            self.mass * (pd(a.x) * dq + dp * qd(a.x)),
            -self.mass * (pd(b.x) * dq + dp * qd(b.x)),
        )
    }

    fn total(&self) -> f64 {
        self.mass
    }
}

/// Nonparametric Everett function on a uniform triangular grid
/// h_i = lo + iΔ, i = 0..n, with piecewise-bilinear interpolation — the
/// identifiable form.
///
/// Parameters are the masses w_kl (0 ≤ l ≤ k < n) of the cells
/// [h_k, h_{k+1}] × [h_l, h_{l+1}]: a square cell (l < k) carries a uniform
/// density w_kl/Δ², a diagonal cell (l = k) a uniform line mass w_kk/Δ on
/// α = β (reversible part). Then F(h_i, h_j) = Σ_{j ≤ l ≤ k < i} w_kl and F is
/// exactly the bilinear interpolant of its node values (linear on diagonal
/// cells). A non-negative density is w ≥ 0.
///
/// ```
/// use gb_preisach::{Everett, GridEverett};
/// let g = GridEverett::uniform_density(-1.0, 1.0, 4, 1.0).unwrap();
/// assert!((g.total() - 1.0).abs() < 1e-12);
/// assert!(g.everett(1.0, 0.0) > 0.0 && g.everett(0.0, 0.0) == 0.0);
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "GridEverettData")]
pub struct GridEverett {
    lo: f64,
    hi: f64,
    n: usize,
    masses: Vec<f64>,
    #[serde(skip)]
    nodes: Vec<f64>,
}

/// Node of a [`GridEverett`]: cell index and offset in [0, 1].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct GridNode {
    /// Cell index i (h_i ≤ x ≤ h_{i+1}).
    pub cell: usize,
    /// Offset (x − h_i)/Δ.
    pub t: f64,
}

/// Index of cell (k, l), l ≤ k, in the mass vector.
#[inline]
pub(crate) fn cell_index(k: usize, l: usize) -> usize {
    k * (k + 1) / 2 + l
}

impl GridEverett {
    /// Number of cells (parameters) of a grid with `n` intervals:
    /// n(n+1)/2.
    pub fn parameter_count(n: usize) -> usize {
        n * (n + 1) / 2
    }

    /// A grid Everett function on `[lo, hi]` with `n` ≥ 1 intervals and the
    /// given cell masses (length n(n+1)/2, cell (k, l) at k(k+1)/2 + l).
    pub fn new(lo: f64, hi: f64, n: usize, masses: Vec<f64>) -> Result<Self, PreisachError> {
        if !(lo.is_finite() && hi.is_finite() && lo < hi) || n == 0 {
            return Err(PreisachError::InvalidArgument(format!(
                "grid needs finite lo < hi and n >= 1, got [{lo}, {hi}], n = {n}"
            )));
        }
        if masses.len() != Self::parameter_count(n) {
            return Err(PreisachError::DimensionMismatch {
                expected: Self::parameter_count(n),
                got: masses.len(),
            });
        }
        if masses.iter().any(|m| !m.is_finite()) {
            return Err(PreisachError::InvalidArgument(
                "grid cell masses must be finite".into(),
            ));
        }
        let mut g = Self {
            lo,
            hi,
            n,
            masses,
            nodes: Vec::new(),
        };
        g.rebuild();
        Ok(g)
    }

    /// Grid with a uniform density of total mass `mass` (diagonal cells get
    /// the mass a continuous uniform density would give their triangles).
    pub fn uniform_density(lo: f64, hi: f64, n: usize, mass: f64) -> Result<Self, PreisachError> {
        let nn = n.max(1) as f64;
        let sq = mass / (nn * nn / 2.0);
        let masses = (0..n)
            .flat_map(|k| (0..=k).map(move |l| if l == k { sq / 2.0 } else { sq }))
            .collect();
        Self::new(lo, hi, n, masses)
    }

    /// Discretise any Everett function onto the grid: each cell gets the mass
    /// of `f` in it (square cells by the second difference of F, diagonal
    /// cells by F(h_{k+1}, h_k)). Exact at the grid nodes.
    pub fn from_everett<E: Everett>(
        f: &E,
        lo: f64,
        hi: f64,
        n: usize,
    ) -> Result<Self, PreisachError> {
        if !(lo.is_finite() && hi.is_finite() && lo < hi) || n == 0 {
            return Err(PreisachError::InvalidArgument(format!(
                "grid needs finite lo < hi and n >= 1, got [{lo}, {hi}], n = {n}"
            )));
        }
        let h = |i: usize| lo + (hi - lo) * i as f64 / n as f64;
        let mut masses = Vec::with_capacity(Self::parameter_count(n));
        for k in 0..n {
            for l in 0..=k {
                let m = if l == k {
                    f.everett(h(k + 1), h(k))
                } else {
                    f.everett(h(k + 1), h(l))
                        - f.everett(h(k + 1), h(l + 1))
                        - f.everett(h(k), h(l))
                        + f.everett(h(k), h(l + 1))
                };
                masses.push(m);
            }
        }
        Self::new(lo, hi, n, masses)
    }

    fn rebuild(&mut self) {
        // F(h_i, h_j) = F(h_{i-1}, h_j) + Σ_{l=j}^{i-1} w_{i-1,l}.
        let n = self.n;
        let mut nodes = vec![0.0; (n + 1) * (n + 2) / 2];
        for i in 1..=n {
            let k = i - 1;
            let mut row = 0.0;
            for j in (0..i).rev() {
                row += self.masses[cell_index(k, j)];
                let prev = if j <= k { nodes[cell_index(k, j)] } else { 0.0 };
                nodes[cell_index(i, j)] = prev + row;
            }
        }
        self.nodes = nodes;
    }

    /// Number of intervals n.
    pub fn intervals(&self) -> usize {
        self.n
    }

    /// Grid bounds (lo, hi).
    pub fn bounds(&self) -> (f64, f64) {
        (self.lo, self.hi)
    }

    /// Grid spacing Δ.
    pub fn spacing(&self) -> f64 {
        (self.hi - self.lo) / self.n as f64
    }

    /// Cell masses w_kl (the parameters).
    pub fn masses(&self) -> &[f64] {
        &self.masses
    }

    /// F at grid node (h_i, h_j), i ≥ j.
    pub fn node_value(&self, i: usize, j: usize) -> f64 {
        if i <= j || i > self.n {
            0.0
        } else {
            self.nodes[cell_index(i, j)]
        }
    }

    /// Introspection / plot data of the identified density: one entry per
    /// cell `(α_centre, β_centre, mass, density)`; density = mass/Δ² for a
    /// square cell and the line density mass/Δ for a diagonal cell.
    pub fn density_table(&self) -> Vec<DensityCell> {
        let d = self.spacing();
        let mut out = Vec::with_capacity(self.masses.len());
        for k in 0..self.n {
            for l in 0..=k {
                let m = self.masses[cell_index(k, l)];
                out.push(DensityCell {
                    alpha: self.lo + (k as f64 + 0.5) * d,
                    beta: self.lo + (l as f64 + 0.5) * d,
                    mass: m,
                    density: if l == k { m / d } else { m / (d * d) },
                    diagonal: l == k,
                });
            }
        }
        out
    }

    /// Add `coef · ∂F(α, β)/∂w` to `out` (length n(n+1)/2): F is linear in
    /// the masses, F(α, β) = Σ w_kl A_k(α) B_l(β) with A_k, B_l the covered
    /// fractions of the cell in α and β (and (α−β)/Δ inside one diagonal
    /// cell).
    pub(crate) fn add_basis(&self, a: &GridNode, b: &GridNode, coef: f64, out: &mut [f64]) {
        let (i, j) = (a.cell, b.cell);
        if i == j {
            out[cell_index(i, i)] += coef * (a.t - b.t);
            return;
        }
        for k in j..=i {
            let ak = if k == i { a.t } else { 1.0 };
            if ak == 0.0 {
                continue;
            }
            let base = cell_index(k, 0);
            for l in j..=k {
                let bl = if l == j { 1.0 - b.t } else { 1.0 };
                out[base + l] += coef * ak * bl;
            }
        }
    }

    /// Add `coef · ∂/∂α ∂F(α, β)/∂w` (`wrt_alpha`) or the β derivative.
    pub(crate) fn add_basis_derivative(
        &self,
        a: &GridNode,
        b: &GridNode,
        coef: f64,
        wrt_alpha: bool,
        out: &mut [f64],
    ) {
        let inv = 1.0 / self.spacing();
        let (i, j) = (a.cell, b.cell);
        if i == j {
            out[cell_index(i, i)] += coef * if wrt_alpha { inv } else { -inv };
            return;
        }
        if wrt_alpha {
            let base = cell_index(i, 0);
            for l in j..=i {
                let bl = if l == j { 1.0 - b.t } else { 1.0 };
                out[base + l] += coef * inv * bl;
            }
        } else {
            for k in j..=i {
                let ak = if k == i { a.t } else { 1.0 };
                out[cell_index(k, j)] -= coef * inv * ak;
            }
        }
    }
}

/// Serialised form of a [`GridEverett`] (validated on deserialisation).
#[derive(Deserialize)]
struct GridEverettData {
    lo: f64,
    hi: f64,
    n: usize,
    masses: Vec<f64>,
}

impl TryFrom<GridEverettData> for GridEverett {
    type Error = PreisachError;
    fn try_from(d: GridEverettData) -> Result<Self, PreisachError> {
        GridEverett::new(d.lo, d.hi, d.n, d.masses)
    }
}

/// One cell of a [`GridEverett`] density table.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DensityCell {
    /// α at the cell centre.
    pub alpha: f64,
    /// β at the cell centre.
    pub beta: f64,
    /// Mass of the cell (the parameter).
    pub mass: f64,
    /// Density: mass/Δ² (square cell) or line density mass/Δ (diagonal).
    pub density: f64,
    /// Whether the cell lies on the diagonal α = β.
    pub diagonal: bool,
}

impl Everett for GridEverett {
    type Node = GridNode;

    fn support(&self) -> (f64, f64) {
        (self.lo, self.hi)
    }

    #[inline]
    fn node(&self, x: f64) -> GridNode {
        let u = ((x - self.lo) / (self.hi - self.lo) * self.n as f64).max(0.0);
        let cell = (u as usize).min(self.n - 1);
        GridNode {
            cell,
            t: (u - cell as f64).min(1.0),
        }
    }

    #[inline]
    fn value(&self, a: &GridNode, b: &GridNode) -> f64 {
        let (i, j) = (a.cell, b.cell);
        if i == j {
            return self.masses[cell_index(i, i)] * (a.t - b.t);
        }
        let f00 = self.nodes[cell_index(i, j)];
        let f10 = self.nodes[cell_index(i + 1, j)];
        let f01 = if i > j + 1 {
            self.nodes[cell_index(i, j + 1)]
        } else {
            0.0
        };
        let f11 = self.nodes[cell_index(i + 1, j + 1)];
        let (s, t) = (a.t, b.t);
        (1.0 - s) * ((1.0 - t) * f00 + t * f01) + s * ((1.0 - t) * f10 + t * f11)
    }

    fn partials(&self, a: &GridNode, b: &GridNode) -> (f64, f64) {
        let inv = 1.0 / self.spacing();
        let (i, j) = (a.cell, b.cell);
        if i == j {
            let w = self.masses[cell_index(i, i)] * inv;
            return (w, -w);
        }
        let f00 = self.nodes[cell_index(i, j)];
        let f10 = self.nodes[cell_index(i + 1, j)];
        let f01 = if i > j + 1 {
            self.nodes[cell_index(i, j + 1)]
        } else {
            0.0
        };
        let f11 = self.nodes[cell_index(i + 1, j + 1)];
        let (s, t) = (a.t, b.t);
        (
            inv * ((1.0 - t) * (f10 - f00) + t * (f11 - f01)),
            inv * ((1.0 - s) * (f01 - f00) + s * (f11 - f10)),
        )
    }

    fn total(&self) -> f64 {
        self.nodes[cell_index(self.n, 0)]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_nodes_match_exact_cdf_across_the_table_edges() {
        // The single range check of `node` (both table coordinates inside
        // the table) and the checked fallback agree with the exact Φ, also
        // just inside and outside the table ends of either coordinate.
        use crate::special::normal_cdf;
        let f = ParametricEverett::gaussian(1.0, 0.4, 0.3, -0.7, 0.2).unwrap();
        let (lo, hi) = (f.fast.lo, f.fast.hi);
        assert!(lo < hi);
        let edges = [
            lo,
            hi,
            0.4 - 9.0 * 0.3,
            0.4 + 9.0 * 0.3,
            -0.7 - 1.8,
            -0.7 + 1.8,
        ];
        let mut worst: f64 = 0.0;
        for e in edges {
            for k in -200..=200 {
                let x = e + k as f64 * 1e-4;
                let n = f.node(x);
                worst = worst
                    .max((n.p - normal_cdf((x - 0.4) / 0.3)).abs())
                    .max((n.q - normal_cdf((x + 0.7) / 0.2)).abs());
            }
        }
        assert!(worst < 5e-15, "max abs error {worst}");
    }

    #[test]
    fn parametric_is_everett_of_its_density() {
        // F(α, β) equals the numerical integral of μ over T(α, β).
        for f in [
            ParametricEverett::gaussian(1.5, 0.4, 0.3, -0.3, 0.5).unwrap(),
            ParametricEverett::lorentzian(1.0, 0.2, 0.2, -0.4, 0.3).unwrap(),
        ] {
            let (al, be) = (1.1, -0.9);
            let m = 400;
            let h = (al - be) / m as f64;
            let mut s = 0.0;
            for i in 0..m {
                for j in 0..m {
                    let a = be + (i as f64 + 0.5) * h;
                    let b = be + (j as f64 + 0.5) * h;
                    if b < a {
                        s += f.density(a, b) * h * h;
                    } else if i == j {
                        s += 0.5 * f.density(a, b) * h * h;
                    }
                }
            }
            let e = f.everett(al, be);
            assert!((s - e).abs() < 2e-4 * e.max(1.0), "{s} vs {e}");
        }
    }

    #[test]
    fn parametric_partials_match_differences() {
        let f = ParametricEverett::gaussian(1.5, 0.4, 0.3, -0.3, 0.5).unwrap();
        let (a, b) = (0.7, -0.2);
        let (da, db) = f.partials(&f.node(a), &f.node(b));
        let h = 1e-6;
        let na = (f.everett(a + h, b) - f.everett(a - h, b)) / (2.0 * h);
        let nb = (f.everett(a, b + h) - f.everett(a, b - h)) / (2.0 * h);
        assert!((da - na).abs() < 1e-7 && (db - nb).abs() < 1e-7);
        assert!(da > 0.0 && db < 0.0);
    }

    #[test]
    fn grid_nodes_are_mass_sums_and_basis_is_consistent() {
        let n = 5;
        let masses: Vec<f64> = (0..GridEverett::parameter_count(n))
            .map(|i| 0.1 + 0.03 * i as f64)
            .collect();
        let g = GridEverett::new(-1.0, 1.5, n, masses.clone()).unwrap();
        // F(h_i, h_j) = Σ_{j ≤ l ≤ k < i} w_kl.
        for i in 0..=n {
            for j in 0..i {
                let mut s = 0.0;
                for k in j..i {
                    for l in j..=k {
                        s += masses[cell_index(k, l)];
                    }
                }
                assert!((g.node_value(i, j) - s).abs() < 1e-12);
            }
        }
        // value == basis · masses at arbitrary points; partials by differences.
        let pts = [-1.0, -0.93, -0.5, -0.2, 0.0, 0.31, 0.5, 0.77, 1.2, 1.5];
        for &a in &pts {
            for &b in &pts {
                if b > a {
                    continue;
                }
                let (na, nb) = (g.node(a), g.node(b));
                let mut basis = vec![0.0; masses.len()];
                g.add_basis(&na, &nb, 1.0, &mut basis);
                let lin: f64 = basis.iter().zip(&masses).map(|(x, w)| x * w).sum();
                assert!((lin - g.value(&na, &nb)).abs() < 1e-12, "{a} {b}");
                let (da, db) = g.partials(&na, &nb);
                let mut dba = vec![0.0; masses.len()];
                let mut dbb = vec![0.0; masses.len()];
                g.add_basis_derivative(&na, &nb, 1.0, true, &mut dba);
                g.add_basis_derivative(&na, &nb, 1.0, false, &mut dbb);
                let la: f64 = dba.iter().zip(&masses).map(|(x, w)| x * w).sum();
                let lb: f64 = dbb.iter().zip(&masses).map(|(x, w)| x * w).sum();
                assert!((la - da).abs() < 1e-10 && (lb - db).abs() < 1e-10);
            }
        }
        // Continuity across cell boundaries (bilinear interpolant is C0).
        let e = 1e-9;
        assert!((g.everett(0.0 + e, -0.5) - g.everett(0.0 - e, -0.5)).abs() < 1e-8);
        assert!((g.everett(1.0, -0.5 + e) - g.everett(1.0, -0.5 - e)).abs() < 1e-8);
    }

    #[test]
    fn grid_from_everett_is_exact_at_nodes() {
        let f = ParametricEverett::gaussian(1.0, 0.3, 0.25, -0.3, 0.25).unwrap();
        let g = GridEverett::from_everett(&f, -2.0, 2.0, 8).unwrap();
        for i in 0..=8 {
            for j in 0..i {
                let h = |k: usize| -2.0 + 0.5 * k as f64;
                assert!((g.everett(h(i), h(j)) - f.everett(h(i), h(j))).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn invalid_everett_rejected() {
        assert!(ParametricEverett::gaussian(1.0, 0.0, -0.1, 0.0, 0.1).is_err());
        assert!(ParametricEverett::gaussian(f64::NAN, 0.0, 0.1, 0.0, 0.1).is_err());
        assert!(GridEverett::new(1.0, 0.0, 3, vec![0.0; 6]).is_err());
        assert!(GridEverett::new(0.0, 1.0, 3, vec![0.0; 5]).is_err());
        assert!(GridEverett::new(0.0, 1.0, 0, vec![]).is_err());
    }
}
