//! Construction of a local model network: LOLIMOT's greedy split of the
//! worst local model (Nelles 2020, sec. 14.3) with axis-orthogonal or oblique
//! splits whose direction and steepness are optimised by gradient (HILOMOT:
//! O. Nelles, "Axes-oblique partitioning strategies for local model
//! networks", IEEE ISIC 2006; Nelles 2020, sec. 14.8), local weighted least
//! squares with ridge regularisation, termination by AICc, BIC or validation
//! data, optional pruning and global Levenberg–Marquardt.
//!
//! Each iteration takes the leaf with the largest local loss
//! Lᵢ = Σ_k Φᵢ(z_k) e_k², tries halving its cell along every dimension of z
//! (in parallel), estimates the two children by weighted least squares
//! θ = (XᵀQX + ρ tr(XᵀQX)/p · I)⁻¹ XᵀQ y (Q = diag of the child's weights) and
//! keeps the split with the smallest loss. With oblique splits the best axis
//! split is the start of a Levenberg–Marquardt search over (w, w0) of
//! ψ = σ(wᵀz + w0), alternating with re-estimating the two local models.
use crate::lmn::{split_params, Criterion, Eval, FitSummary, Focus, LmnModel};
use crate::regressors::Experiment;
use crate::regressors::{Layout, NormExp};
use crate::tree::{Node, Partition, Split, WeightKind, TINY};
use crate::{LmnError, RegressorSpec, Scaling};
use gb_core::solver::{LeastSquaresProblem, LmParams, LmWorkspace};
use gb_core::{Identify, Observer, Records, Silent, SubTask};
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

/// Split geometry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum SplitKind {
    /// Axis-orthogonal halving of the cell (LOLIMOT).
    Axis,
    /// Oblique: direction and steepness optimised by gradient (HILOMOT; tree weights only).
    Oblique,
}

/// Parameters of [`LmnModel`] construction (linfa-style builder; validated once
/// by [`check`](Self::check), then [`fit`](ValidLmnParams::fit)).
///
/// ```
/// use gb_lmn::{Criterion, Focus, LmnParams, RegressorSpec, SplitKind, WeightKind};
/// let p = LmnParams::new(RegressorSpec::arx(2, &[2], &[1]))
///     .weights(WeightKind::Tree)
///     .splits(SplitKind::Oblique)
///     .criterion(Criterion::Bic)
///     .prune(true)
///     .focus(Focus::Simulation)
///     .max_leaves(8);
/// assert!(p.check().is_ok());
/// assert!(LmnParams::new(RegressorSpec::arx(1, &[1], &[1])).max_leaves(0).check().is_err());
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct LmnParams {
    regressors: RegressorSpec,
    weights: WeightKind,
    splits: SplitKind,
    max_leaves: usize,
    criterion: Criterion,
    prune: bool,
    focus: Focus,
    smoothness: f64,
    ridge: f64,
    min_samples_per_param: f64,
    lm_iterations: usize,
    stability_guard: bool,
    optimise_splits: bool,
    patience: usize,
    noe_construction: bool,
}

/// Validated [`LmnParams`].
#[derive(Debug, Clone, PartialEq)]
pub struct ValidLmnParams(LmnParams);

impl LmnParams {
    /// Defaults: tree weights, axis splits, at most 20 leaves, AICc, no
    /// pruning, simulation focus, smoothness 0.1, ridge 1e-8, 30 LM iterations.
    pub fn new(regressors: RegressorSpec) -> Self {
        Self {
            regressors,
            weights: WeightKind::Tree,
            splits: SplitKind::Axis,
            max_leaves: 20,
            criterion: Criterion::Aicc,
            prune: false,
            focus: Focus::Simulation,
            smoothness: 0.1,
            ridge: 1e-8,
            min_samples_per_param: 2.0,
            lm_iterations: 30,
            stability_guard: true,
            optimise_splits: true,
            patience: 3,
            noe_construction: false,
        }
    }
    /// Weight functions.
    pub fn weights(mut self, w: WeightKind) -> Self {
        self.weights = w;
        self
    }
    /// Split geometry.
    pub fn splits(mut self, s: SplitKind) -> Self {
        self.splits = s;
        self
    }
    /// Largest number of local models.
    pub fn max_leaves(mut self, m: usize) -> Self {
        self.max_leaves = m;
        self
    }
    /// Termination criterion.
    pub fn criterion(mut self, c: Criterion) -> Self {
        self.criterion = c;
        self
    }
    /// Prune splits that do not pay by the criterion after growing.
    pub fn prune(mut self, p: bool) -> Self {
        self.prune = p;
        self
    }
    /// Focus of the global optimisation (and of validation).
    pub fn focus(mut self, f: Focus) -> Self {
        self.focus = f;
        self
    }
    /// Transition width of tree splits relative to the cell extent (> 0).
    pub fn smoothness(mut self, s: f64) -> Self {
        self.smoothness = s;
        self
    }
    /// Relative ridge regularisation of the local least squares.
    pub fn ridge(mut self, r: f64) -> Self {
        self.ridge = r;
        self
    }
    /// A child needs Σ weights ≥ this × local parameters.
    pub fn min_samples_per_param(mut self, m: f64) -> Self {
        self.min_samples_per_param = m;
        self
    }
    /// Levenberg–Marquardt iterations of the global optimisation (0: none).
    pub fn lm_iterations(mut self, n: usize) -> Self {
        self.lm_iterations = n;
        self
    }
    /// Reject LM steps that make an affine local model unstable (NOE).
    pub fn stability_guard(mut self, g: bool) -> Self {
        self.stability_guard = g;
        self
    }
    /// Include the split parameters in the global optimisation (tree weights).
    pub fn optimise_splits(mut self, o: bool) -> Self {
        self.optimise_splits = o;
        self
    }
    /// Simulation focus: after the first network is trained, grow a second
    /// one with output lags taken from the first one's free-run simulation
    /// (output-error construction) and keep the one that simulates better
    /// (on the validation experiments if given, else on the training data).
    pub fn noe_construction(mut self, on: bool) -> Self {
        self.noe_construction = on;
        self
    }
    /// Stop growing after this many splits in a row that do not improve the criterion.
    pub fn patience(mut self, p: usize) -> Self {
        self.patience = p;
        self
    }

    /// Validate the parameters.
    pub fn check(&self) -> Result<ValidLmnParams, LmnError> {
        self.regressors.check()?;
        if self.max_leaves == 0 || self.max_leaves > 500 {
            return Err(LmnError::InvalidArgument(format!(
                "max_leaves must be in 1..=500, got {}",
                self.max_leaves
            )));
        }
        if !(self.smoothness.is_finite() && self.smoothness > 0.0) {
            return Err(LmnError::InvalidArgument("smoothness must be > 0".into()));
        }
        if !(self.ridge.is_finite() && self.ridge >= 0.0) {
            return Err(LmnError::InvalidArgument("ridge must be >= 0".into()));
        }
        if !(self.min_samples_per_param.is_finite() && self.min_samples_per_param > 0.0) {
            return Err(LmnError::InvalidArgument(
                "min_samples_per_param must be > 0".into(),
            ));
        }
        if self.splits == SplitKind::Oblique && self.weights == WeightKind::Gaussian {
            return Err(LmnError::InvalidArgument(
                "oblique splits need tree weights (normalised Gaussians are axis-orthogonal)"
                    .into(),
            ));
        }
        if self.patience == 0 {
            return Err(LmnError::InvalidArgument("patience must be >= 1".into()));
        }
        Ok(ValidLmnParams(self.clone()))
    }

    /// Check and fit on training records, each a separate experiment
    /// (criterion AICc or BIC).
    pub fn fit(&self, train: &Records) -> Result<LmnModel, LmnError> {
        self.check()?.fit(train, None)
    }
}

/// Regression data: basis rows φ (N × p), partition rows z (N × nz), targets.
pub(crate) struct Rows {
    pub a: Vec<f64>,
    pub z: Vec<f64>,
    pub t: Vec<f64>,
    pub p: usize,
    pub nz: usize,
    pub n: usize,
}

impl Rows {
    pub fn build(lay: &Layout, exps: &[NormExp], nx: usize) -> Self {
        Self::build_from(lay, exps, nx, None)
    }

    /// Rows with output lags from `lags` (one signal per experiment, e.g. a
    /// free-run simulation) instead of the measured outputs; targets stay measured.
    pub fn build_from(
        lay: &Layout,
        exps: &[NormExp],
        nx: usize,
        lags: Option<&[Vec<f64>]>,
    ) -> Self {
        let nz = lay.z.len();
        let p = lay.p;
        let mut a = Vec::new();
        let mut zz = Vec::new();
        let mut t = Vec::new();
        let mut x = vec![0.0; nx];
        let mut z = vec![0.0; nz];
        let mut phi = vec![0.0; p];
        for (i, e) in exps.iter().enumerate() {
            let src = lags.and_then(|l| l.get(i)).unwrap_or(&e.y);
            for k in lay.max_lag..e.y.len() {
                lay.fill(k, src, &e.u, &mut x, &mut z);
                lay.basis(&x, &e.e, k, &mut phi);
                a.extend_from_slice(&phi);
                zz.extend_from_slice(&z);
                t.push(e.y[k]);
            }
        }
        let n = t.len();
        Self {
            a,
            z: zz,
            t,
            p,
            nz,
            n,
        }
    }
    #[inline]
    pub fn row(&self, r: usize) -> &[f64] {
        &self.a[r * self.p..(r + 1) * self.p]
    }
    #[inline]
    pub fn zrow(&self, r: usize) -> &[f64] {
        &self.z[r * self.nz..(r + 1) * self.nz]
    }
    #[inline]
    pub fn local(&self, r: usize, theta: &[f64]) -> f64 {
        self.row(r).iter().zip(theta).map(|(a, b)| a * b).sum()
    }
}

/// Weighted least squares over rows `idx` with weights `w`, ridge relative
/// to the mean diagonal; with `neff` also tr(G⁻¹H), H = Σ w² φφᵀ.
/// Gram + Cholesky, SVD fallback.
pub(crate) fn wls(
    rows: &Rows,
    idx: &[u32],
    w: &[f64],
    ridge: f64,
    neff: bool,
) -> Option<(Vec<f64>, f64)> {
    let p = rows.p;
    let mut g = vec![0.0; p * p];
    let mut h = if neff { vec![0.0; p * p] } else { vec![] };
    let mut b = vec![0.0; p];
    for (&r, &wk) in idx.iter().zip(w) {
        if wk <= 0.0 {
            continue;
        }
        let r = r as usize;
        let row = rows.row(r);
        let tk = rows.t[r];
        for i in 0..p {
            let wi = wk * row[i];
            b[i] += wi * tk;
            let gi = &mut g[i * p..(i + 1) * p];
            for j in i..p {
                gi[j] += wi * row[j];
            }
        }
        if neff {
            let w2 = wk * wk;
            for i in 0..p {
                let wi = w2 * row[i];
                let hi = &mut h[i * p..(i + 1) * p];
                for j in i..p {
                    hi[j] += wi * row[j];
                }
            }
        }
    }
    let tr = (0..p).map(|i| g[i * p + i]).sum::<f64>() / p as f64;
    if tr.is_nan() || tr <= 0.0 {
        return None;
    }
    let reg = ridge.max(1e-12) * tr;
    let mut gm = DMatrix::<f64>::from_fn(
        p,
        p,
        |i, j| if i <= j { g[i * p + j] } else { g[j * p + i] },
    );
    for i in 0..p {
        gm[(i, i)] += reg;
    }
    let bv = DVector::from_column_slice(&b);
    let (theta, inv_h) = match gm.clone().cholesky() {
        Some(ch) => {
            let th = ch.solve(&bv);
            let ih =
                if neff {
                    let hm = DMatrix::<f64>::from_fn(p, p, |i, j| {
                        if i <= j {
                            h[i * p + j]
                        } else {
                            h[j * p + i]
                        }
                    });
                    Some(ch.solve(&hm).trace())
                } else {
                    None
                };
            (th, ih)
        }
        None => {
            let svd = gm.svd(true, true);
            let th = svd.solve(&bv, 1e-12 * tr).ok()?;
            (th, neff.then_some(p as f64))
        }
    };
    if theta.iter().any(|v| !v.is_finite()) {
        return None;
    }
    Some((theta.iter().copied().collect(), inv_h.unwrap_or(0.0)))
}

/// Information criterion of a fit with `sse` over `n` samples and `neff` parameters.
pub(crate) fn info_criterion(c: Criterion, sse: f64, n: usize, neff: f64) -> f64 {
    let n = n as f64;
    let base = n * (sse / n).max(1e-300).ln();
    match c {
        Criterion::Bic => base + neff * n.ln(),
        _ => {
            if n - neff - 1.0 <= 0.0 {
                f64::INFINITY
            } else {
                base + 2.0 * neff + 2.0 * neff * (neff + 1.0) / (n - neff - 1.0)
            }
        }
    }
}

/// A leaf during growth: its rows with non-negligible weight.
#[derive(Clone)]
struct LeafSt {
    node: usize,
    idx: Vec<u32>,
    w: Vec<f64>,
    splittable: bool,
}

struct Trial {
    dsse: f64,
    w: Vec<f64>,
    w0: f64,
    axis: Option<usize>,
    tl: Vec<f64>,
    tr: Vec<f64>,
}

/// Children weights for split (w, w0) on the rows of a leaf.
fn psi_of(rows: &Rows, st: &LeafSt, w: &[f64], w0: f64, psi: &mut [f64]) {
    for (i, &r) in st.idx.iter().enumerate() {
        let zr = rows.zrow(r as usize);
        let mut a = w0;
        for (wd, zd) in w.iter().zip(zr) {
            a += wd * zd;
        }
        psi[i] = 1.0 / (1.0 + crate::tree::fast_exp(-a));
    }
}

/// Local SSE of the split's children: Σ (base − wl L_l − wr L_r)² over the leaf rows.
fn split_sse(rows: &Rows, st: &LeafSt, base: &[f64], psi: &[f64], tl: &[f64], tr: &[f64]) -> f64 {
    let mut s = 0.0;
    for (i, &r) in st.idx.iter().enumerate() {
        let r = r as usize;
        let wr = st.w[i] * psi[i];
        let wl = st.w[i] - wr;
        let e = base[i] - wl * rows.local(r, tl) - wr * rows.local(r, tr);
        s += e * e;
    }
    s
}

fn fit_children(
    rows: &Rows,
    st: &LeafSt,
    psi: &[f64],
    ridge: f64,
    min_eff: f64,
) -> Option<(Vec<f64>, Vec<f64>)> {
    let wr: Vec<f64> = st.w.iter().zip(psi).map(|(w, p)| w * p).collect();
    let wl: Vec<f64> = st.w.iter().zip(&wr).map(|(w, r)| w - r).collect();
    if wr.iter().sum::<f64>() < min_eff || wl.iter().sum::<f64>() < min_eff {
        return None;
    }
    let (tl, _) = wls(rows, &st.idx, &wl, ridge, false)?;
    let (tr, _) = wls(rows, &st.idx, &wr, ridge, false)?;
    Some((tl, tr))
}

/// The split parameters v = (w, w0) of HILOMOT as a least-squares problem
/// on the local SSE of the leaf, the two children's local models fixed:
/// residual e = base − w((1−ψ)L_l + ψ L_r), ∂e/∂a = −w ψ(1−ψ)(L_r − L_l),
/// a = wᵀz + w0. Trial points are projected onto ‖w‖ ≤ cap (steepness cap).
struct ObliqueProblem<'a> {
    rows: &'a Rows,
    st: &'a LeafSt,
    base: &'a [f64],
    tl: &'a [f64],
    tr: &'a [f64],
    ll: &'a [f64],
    lr: &'a [f64],
    cap: f64,
    psi: Vec<f64>,
    /// The last point evaluated and its SSE (the accepted point is
    /// linearised next).
    last: Option<(Vec<f64>, f64)>,
}

impl ObliqueProblem<'_> {
    fn sse(&mut self, v: &[f64]) -> f64 {
        let nz = self.rows.nz;
        psi_of(self.rows, self.st, &v[..nz], v[nz], &mut self.psi);
        let s = split_sse(self.rows, self.st, self.base, &self.psi, self.tl, self.tr);
        self.last = Some((v.to_vec(), s));
        s
    }
}

impl LeastSquaresProblem for ObliqueProblem<'_> {
    fn n_params(&self) -> usize {
        self.rows.nz + 1
    }
    fn cost(&mut self, v: &[f64]) -> Option<f64> {
        Some(self.sse(v))
    }
    fn linearize(&mut self, v: &[f64], gram: &mut [f64], grad: &mut [f64]) -> Option<f64> {
        let nz = self.rows.nz;
        let nv = nz + 1;
        let cost = match &self.last {
            Some((lv, s)) if lv.as_slice() == v => *s,
            _ => self.sse(v),
        };
        gram.fill(0.0);
        let mut jte = vec![0.0; nv];
        let mut acc = gb_core::gram::GramAccumulator::new(nv);
        for (i, &r) in self.st.idx.iter().enumerate() {
            let zr = self.rows.zrow(r as usize);
            let p = self.psi[i];
            let (wi, ll, lr) = (self.st.w[i], self.ll[i], self.lr[i]);
            let e = self.base[i] - wi * ((1.0 - p) * ll + p * lr);
            let g = -wi * p * (1.0 - p) * (lr - ll);
            if g == 0.0 {
                continue;
            }
            let jrow = acc.next_row(gram);
            jrow[..nz].iter_mut().zip(zr).for_each(|(j, z)| *j = g * z);
            jrow[nz] = g;
            for (t, j) in jte.iter_mut().zip(jrow.iter()) {
                *t += j * e;
            }
        }
        acc.finish(gram);
        // jrow is ∂e/∂v = −∂ŷ/∂v: the gradient Jᵀe is −jte
        for (g, t) in grad.iter_mut().zip(&jte) {
            *g = -t;
        }
        Some(cost)
    }
    fn project(&mut self, v: &mut [f64]) {
        let nz = self.rows.nz;
        let norm = v[..nz].iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm > self.cap {
            let s = self.cap / norm;
            v.iter_mut().for_each(|x| *x *= s);
        }
    }
}

/// HILOMOT: optimise (w, w0) of a split by Levenberg–Marquardt on the local
/// SSE, alternating with weighted least squares of the two children. Each of
/// at most 6 rounds runs at most 4 solver iterations (8 trials, λ ×4 / ÷3,
/// floor 1e-9, damping λ·max(Gᵢᵢ, 1e-12) + 1e-12); λ carries over between
/// rounds.
#[allow(clippy::too_many_arguments)]
fn optimise_oblique(
    rows: &Rows,
    st: &LeafSt,
    base: &[f64],
    start: &Trial,
    sse_old: f64,
    ridge: f64,
    min_eff: f64,
    cap: f64,
) -> Option<Trial> {
    let nz = rows.nz;
    let m = st.idx.len();
    let mut v: Vec<f64> = start.w.clone();
    v.push(start.w0);
    let (mut tl, mut tr) = (start.tl.clone(), start.tr.clone());
    let mut psi = vec![0.0; m];
    psi_of(rows, st, &v[..nz], v[nz], &mut psi);
    let mut best = split_sse(rows, st, base, &psi, &tl, &tr);
    let lm = LmParams {
        max_iter: 4,
        tol: 0.0,
        lambda_init: 1e-2,
        lambda_up: 4.0,
        lambda_up_singular: 10.0,
        lambda_down: 1.0 / 3.0,
        lambda_min: 1e-9,
        lambda_max: 1e300,
        max_trials: 8,
        diag_floor: 0.0,
        diag_floor_abs: 1e-12,
        diag_add: 0.0,
        jitter: 0.0,
        jitter_abs: 1e-12,
        stall_window: 0,
        stall_tol: 0.0,
        ..LmParams::default()
    }
    .check()
    .ok()?;
    let mut lambda = lm.params().lambda_init;
    let mut ll = vec![0.0; m];
    let mut lr = vec![0.0; m];
    let mut ws = LmWorkspace::new(nz + 1);
    for _outer in 0..6 {
        let before = best;
        for (i, &r) in st.idx.iter().enumerate() {
            ll[i] = rows.local(r as usize, &tl);
            lr[i] = rows.local(r as usize, &tr);
        }
        let mut problem = ObliqueProblem {
            rows,
            st,
            base,
            tl: &tl,
            tr: &tr,
            ll: &ll,
            lr: &lr,
            cap,
            psi: vec![0.0; m],
            last: None,
        };
        let mut state = lm.init(&mut problem, &v).ok()?;
        state.lambda = lambda;
        lm.run(&mut problem, &mut state, &mut ws, &Silent);
        lambda = state.lambda;
        v = state.theta;
        best = state.cost;
        psi_of(rows, st, &v[..nz], v[nz], &mut psi);
        // re-estimate the two local models under the new split
        let (a, b) = fit_children(rows, st, &psi, ridge, min_eff)?;
        let s = split_sse(rows, st, base, &psi, &a, &b);
        if s <= best {
            best = s;
            tl = a;
            tr = b;
        }
        if before - best <= 1e-6 * before {
            break;
        }
    }
    let w = v[..nz].to_vec();
    Some(Trial {
        dsse: best - sse_old,
        w,
        w0: v[nz],
        axis: None,
        tl,
        tr,
    })
}

/// Output of the growth phase.
pub(crate) struct Grown {
    /// (partition after each split, sse, n_eff)
    pub snapshots: Vec<(Partition, f64, f64)>,
}

/// Local cell box of z over the rows.
fn data_box(rows: &Rows) -> (Vec<f64>, Vec<f64>) {
    let nz = rows.nz;
    let mut lo = vec![f64::INFINITY; nz];
    let mut hi = vec![f64::NEG_INFINITY; nz];
    for r in 0..rows.n {
        for (d, &v) in rows.zrow(r).iter().enumerate() {
            lo[d] = lo[d].min(v);
            hi[d] = hi[d].max(v);
        }
    }
    for d in 0..nz {
        if hi[d] - lo[d] <= 1e-12 || (hi[d] - lo[d]).is_nan() {
            hi[d] = lo[d] + 1.0;
        }
    }
    (lo, hi)
}

fn leaf_node(parent: usize, lower: Vec<f64>, upper: Vec<f64>, theta: Vec<f64>) -> Node {
    Node {
        parent: Some(parent),
        lower,
        upper,
        split: None,
        theta,
        n_eff: 0.0,
    }
}

/// Split node `n` of `part` with (w, w0); children get the halves of the cell
/// along `axis` (or copies of the cell when oblique).
fn apply_split(
    part: &mut Partition,
    n: usize,
    t: &Trial,
    tl: Vec<f64>,
    tr: Vec<f64>,
) -> (usize, usize) {
    let nd = &part.nodes[n];
    let (mut lu, mut rl) = (nd.upper.clone(), nd.lower.clone());
    if let Some(d) = t.axis {
        let mid = 0.5 * (nd.lower[d] + nd.upper[d]);
        lu[d] = mid;
        rl[d] = mid;
    }
    let left = leaf_node(n, nd.lower.clone(), lu, tl);
    let right = leaf_node(n, rl, nd.upper.clone(), tr);
    let i = part.nodes.len();
    part.nodes.push(left);
    part.nodes.push(right);
    part.nodes[n].split = Some(Split {
        left: i,
        right: i + 1,
        w: t.w.clone(),
        w0: t.w0,
        axis: t.axis,
    });
    part.nodes[n].theta.clear();
    (i, i + 1)
}

/// Axis split of a cell: w = e_d / (s·extent), w0 = −centre·w_d.
fn axis_split(lo: &[f64], hi: &[f64], d: usize, smooth: f64) -> (Vec<f64>, f64) {
    let ext = (hi[d] - lo[d]).max(1e-9);
    let c = 0.5 * (lo[d] + hi[d]);
    let mut w = vec![0.0; lo.len()];
    w[d] = 1.0 / (smooth * ext);
    let w0 = -c * w[d];
    (w, w0)
}

/// The splittable leaf with the largest local loss
/// Lᵢ = Σ_{k∈leaf} w_k (t_k − ŷ_k)², if any.
fn worst_splittable_leaf(rows: &Rows, leaves: &[LeafSt], yhat: &[f64]) -> Option<usize> {
    let mut worst = None;
    let mut wl = -1.0;
    for (i, st) in leaves.iter().enumerate() {
        if !st.splittable {
            continue;
        }
        let l: f64 = st
            .idx
            .iter()
            .zip(&st.w)
            .map(|(&r, &w)| w * (rows.t[r as usize] - yhat[r as usize]).powi(2))
            .sum();
        if l > wl {
            wl = l;
            worst = Some(i);
        }
    }
    worst
}

/// The best split of leaf `st` (node `node`): the axis split with the
/// smallest ΔSSE over the partition dimensions (in parallel), refined by an
/// oblique search when asked for (and kept if better). `None` if no axis
/// split gives two fittable children. `base_k = t_k − ŷ_k + w_k a_kᵀθ_old` is
/// the target of the leaf's rows without the leaf's own contribution.
#[allow(clippy::too_many_arguments)]
fn best_split_trial(
    rows: &Rows,
    o: &LmnParams,
    node: &Node,
    st: &LeafSt,
    base: &[f64],
    sse_old: f64,
    min_eff: f64,
) -> Option<Trial> {
    let nz = rows.nz;
    let (clo, chi) = (node.lower.clone(), node.upper.clone());
    let trials: Vec<Trial> = (0..nz)
        .into_par_iter()
        .filter_map(|d| {
            if chi[d] - clo[d] < 1e-9 {
                return None;
            }
            let (w, w0) = axis_split(&clo, &chi, d, o.smoothness);
            let mut psi = vec![0.0; st.idx.len()];
            psi_of(rows, st, &w, w0, &mut psi);
            let (tl, tr) = fit_children(rows, st, &psi, o.ridge, min_eff)?;
            let s = split_sse(rows, st, base, &psi, &tl, &tr);
            Some(Trial {
                dsse: s - sse_old,
                w,
                w0,
                axis: Some(d),
                tl,
                tr,
            })
        })
        .collect();
    let mut best = trials
        .into_iter()
        .min_by(|a, b| a.dsse.total_cmp(&b.dsse))?;
    if o.splits == SplitKind::Oblique && nz > 1 {
        let w0n = best.w.iter().map(|v| v * v).sum::<f64>().sqrt();
        if let Some(ob) =
            optimise_oblique(rows, st, base, &best, sse_old, o.ridge, min_eff, 20.0 * w0n)
        {
            if ob.dsse < best.dsse {
                best = ob;
            }
        }
    }
    Some(best)
}

/// The two children of leaf `st` under the split's ψ: the left one keeps
/// the rows with w_k(1 − ψ_k) > TINY, the right one those with w_k ψ_k > TINY
/// (nodes not yet assigned).
fn child_leaves(st: &LeafSt, psi: &[f64]) -> [LeafSt; 2] {
    let mut kids = [
        LeafSt {
            node: 0,
            idx: vec![],
            w: vec![],
            splittable: true,
        },
        LeafSt {
            node: 0,
            idx: vec![],
            w: vec![],
            splittable: true,
        },
    ];
    for (i, &r) in st.idx.iter().enumerate() {
        let wr = st.w[i] * psi[i];
        let wl = st.w[i] - wr;
        if wl > TINY {
            kids[0].idx.push(r);
            kids[0].w.push(wl);
        }
        if wr > TINY {
            kids[1].idx.push(r);
            kids[1].w.push(wr);
        }
    }
    kids
}

/// Grow with tree weights: splitting a leaf changes only its own rows.
pub(crate) fn grow_tree(
    rows: &Rows,
    o: &LmnParams,
    keep_growing: &mut dyn FnMut(&Partition, f64, f64) -> bool,
) -> Result<Grown, LmnError> {
    let p = rows.p;
    let nz = rows.nz;
    let min_eff = o.min_samples_per_param * p as f64;
    let (lo, hi) = data_box(rows);
    let all: Vec<u32> = (0..rows.n as u32).collect();
    let ones = vec![1.0; rows.n];
    let (th, ne) = wls(rows, &all, &ones, o.ridge, true).ok_or_else(|| {
        LmnError::Numerical("least squares of the first local model failed".into())
    })?;
    let mut part = Partition::root(WeightKind::Tree, lo, hi, p);
    part.nodes[0].theta = th;
    part.nodes[0].n_eff = ne;
    let mut yhat: Vec<f64> = (0..rows.n)
        .map(|r| rows.local(r, &part.nodes[0].theta))
        .collect();
    let mut leaves = vec![LeafSt {
        node: 0,
        idx: all,
        w: ones,
        splittable: nz > 0,
    }];
    let mut sse: f64 = (0..rows.n).map(|r| (rows.t[r] - yhat[r]).powi(2)).sum();
    let mut snaps = vec![(part.clone(), sse, ne)];
    let mut neff = ne;
    if !keep_growing(&part, sse, neff) {
        return Ok(Grown { snapshots: snaps });
    }
    while leaves.len() < o.max_leaves {
        let Some(wi) = worst_splittable_leaf(rows, &leaves, &yhat) else {
            break;
        };
        let st = leaves[wi].clone();
        let th_old = part.nodes[st.node].theta.clone();
        let base: Vec<f64> = st
            .idx
            .iter()
            .zip(&st.w)
            .map(|(&r, &w)| {
                let r = r as usize;
                rows.t[r] - yhat[r] + w * rows.local(r, &th_old)
            })
            .collect();
        let sse_old: f64 = st
            .idx
            .iter()
            .map(|&r| (rows.t[r as usize] - yhat[r as usize]).powi(2))
            .sum();
        let Some(best) =
            best_split_trial(rows, o, &part.nodes[st.node], &st, &base, sse_old, min_eff)
        else {
            leaves[wi].splittable = false;
            continue;
        };
        // apply: children weights, local models with n_eff, predictions
        let mut psi = vec![0.0; st.idx.len()];
        psi_of(rows, &st, &best.w, best.w0, &mut psi);
        let mut kids = child_leaves(&st, &psi);
        let (Some((tl, nl)), Some((tr, nr))) = (
            wls(rows, &kids[0].idx, &kids[0].w, o.ridge, true),
            wls(rows, &kids[1].idx, &kids[1].w, o.ridge, true),
        ) else {
            leaves[wi].splittable = false;
            continue;
        };
        let (a, b) = apply_split(&mut part, st.node, &best, tl, tr);
        part.nodes[a].n_eff = nl;
        part.nodes[b].n_eff = nr;
        kids[0].node = a;
        kids[1].node = b;
        for (i, &r) in st.idx.iter().enumerate() {
            let r = r as usize;
            let wr = st.w[i] * psi[i];
            let wl = st.w[i] - wr;
            yhat[r] = rows.t[r] - base[i]
                + wl * rows.local(r, &part.nodes[a].theta)
                + wr * rows.local(r, &part.nodes[b].theta);
        }
        neff += nl + nr - part.nodes[st.node].n_eff;
        let [k0, k1] = kids;
        leaves.swap_remove(wi);
        leaves.push(k0);
        leaves.push(k1);
        sse = (0..rows.n).map(|r| (rows.t[r] - yhat[r]).powi(2)).sum();
        let ne_total = neff + split_params(&part);
        snaps.push((part.clone(), sse, ne_total));
        if !keep_growing(&part, sse, ne_total) {
            break;
        }
    }
    Ok(Grown { snapshots: snaps })
}

/// Dense leaf weights (leaf-major, leaves in preorder) of `part` over all rows.
pub(crate) fn dense_weights(part: &Partition, rows: &Rows) -> (Vec<usize>, Vec<f64>) {
    let leaves = part.leaves();
    let n = rows.n;
    let m = leaves.len();
    let mut out = vec![0.0; m * n];
    let mut s = part.scratch();
    for r in 0..n {
        part.weights(rows.zrow(r), &mut s);
        for (i, &l) in leaves.iter().enumerate() {
            out[i * n + r] = s.phi[l];
        }
    }
    (leaves, out)
}

/// Re-estimate every leaf of a Gaussian partition under its weights; returns (sse, n_eff).
pub(crate) fn refit_all(part: &mut Partition, rows: &Rows, ridge: f64) -> Option<(f64, f64)> {
    let (leaves, phi) = dense_weights(part, rows);
    let n = rows.n;
    let all: Vec<u32> = (0..n as u32).collect();
    let fits: Vec<Option<(Vec<f64>, f64)>> = leaves
        .par_iter()
        .enumerate()
        .map(|(i, _)| wls(rows, &all, &phi[i * n..(i + 1) * n], ridge, true))
        .collect();
    let mut neff = 0.0;
    for (&l, f) in leaves.iter().zip(fits) {
        let (th, ne) = f?;
        part.nodes[l].theta = th;
        part.nodes[l].n_eff = ne;
        neff += ne;
    }
    let mut sse = 0.0;
    for r in 0..n {
        let mut y = 0.0;
        for (i, &l) in leaves.iter().enumerate() {
            let w = phi[i * n + r];
            if w > 0.0 {
                y += w * rows.local(r, &part.nodes[l].theta);
            }
        }
        sse += (rows.t[r] - y).powi(2);
    }
    Some((sse, neff + split_params(part)))
}

/// Grow with normalised Gaussian weights (classic LOLIMOT).
pub(crate) fn grow_gauss(
    rows: &Rows,
    o: &LmnParams,
    keep_growing: &mut dyn FnMut(&Partition, f64, f64) -> bool,
) -> Result<Grown, LmnError> {
    let p = rows.p;
    let nz = rows.nz;
    let n = rows.n;
    let min_eff = o.min_samples_per_param * p as f64;
    let (lo, hi) = data_box(rows);
    let mut part = Partition::root(WeightKind::Gaussian, lo, hi, p);
    let (sse, neff) = refit_all(&mut part, rows, o.ridge).ok_or_else(|| {
        LmnError::Numerical("least squares of the first local model failed".into())
    })?;
    let mut snaps = vec![(part.clone(), sse, neff)];
    let mut unsplittable: Vec<usize> = vec![];
    if !keep_growing(&part, sse, neff) {
        return Ok(Grown { snapshots: snaps });
    }
    let all: Vec<u32> = (0..n as u32).collect();
    while part.n_leaves() < o.max_leaves {
        let (leaves, phi) = dense_weights(&part, rows);
        let mut yhat = vec![0.0; n];
        for (i, &l) in leaves.iter().enumerate() {
            for r in 0..n {
                let w = phi[i * n + r];
                if w > 0.0 {
                    yhat[r] += w * rows.local(r, &part.nodes[l].theta);
                }
            }
        }
        let mut worst = None;
        let mut wl = -1.0;
        for (i, &l) in leaves.iter().enumerate() {
            if unsplittable.contains(&l) {
                continue;
            }
            let loss: f64 = (0..n)
                .map(|r| phi[i * n + r] * (rows.t[r] - yhat[r]).powi(2))
                .sum();
            if loss > wl {
                wl = loss;
                worst = Some(l);
            }
        }
        let Some(w) = worst else { break };
        let trials: Vec<(f64, Partition)> = (0..nz)
            .into_par_iter()
            .filter_map(|d| {
                let nd = &part.nodes[w];
                if nd.upper[d] - nd.lower[d] < 1e-9 {
                    return None;
                }
                let (sw, sw0) = axis_split(&nd.lower, &nd.upper, d, o.smoothness);
                let t = Trial {
                    dsse: 0.0,
                    w: sw,
                    w0: sw0,
                    axis: Some(d),
                    tl: vec![],
                    tr: vec![],
                };
                let mut tp = part.clone();
                let (a, b) = apply_split(&mut tp, w, &t, vec![0.0; p], vec![0.0; p]);
                let (tleaves, tphi) = dense_weights(&tp, rows);
                for (i, &l) in tleaves.iter().enumerate() {
                    if l == a || l == b {
                        let col = &tphi[i * n..(i + 1) * n];
                        if col.iter().sum::<f64>() < min_eff {
                            return None;
                        }
                        let (th, _) = wls(rows, &all, col, o.ridge, false)?;
                        tp.nodes[l].theta = th;
                    }
                }
                let mut s = 0.0;
                for r in 0..n {
                    let mut y = 0.0;
                    for (i, &l) in tleaves.iter().enumerate() {
                        let wv = tphi[i * n + r];
                        if wv > 0.0 {
                            y += wv * rows.local(r, &tp.nodes[l].theta);
                        }
                    }
                    s += (rows.t[r] - y).powi(2);
                }
                Some((s, tp))
            })
            .collect();
        let Some((_, mut best)) = trials.into_iter().min_by(|a, b| a.0.total_cmp(&b.0)) else {
            unsplittable.push(w);
            continue;
        };
        let Some((sse, neff)) = refit_all(&mut best, rows, o.ridge) else {
            unsplittable.push(w);
            continue;
        };
        part = best;
        snaps.push((part.clone(), sse, neff));
        if !keep_growing(&part, sse, neff) {
            break;
        }
    }
    Ok(Grown { snapshots: snaps })
}

impl ValidLmnParams {
    /// The validated parameters.
    pub fn params(&self) -> &LmnParams {
        &self.0
    }

    /// Fit on training records (each a separate experiment: no regressor
    /// spans two records; the user columns are the last
    /// [`RegressorSpec::n_extra`] input signals); `val` (needed for
    /// [`Criterion::Validation`]) chooses the number of leaves and the
    /// pruning by its simulation (focus Simulation) or one-step (Prediction)
    /// error.
    pub fn fit(&self, train: &Records, val: Option<&Records>) -> Result<LmnModel, LmnError> {
        self.fit_with_observer(train, val, &Silent)
    }

    /// [`fit`](Self::fit), reporting progress (the growth of the network,
    /// then the global optimisation) and every Levenberg–Marquardt iteration
    /// to `observer`.
    pub fn fit_with_observer(
        &self,
        train: &Records,
        val: Option<&Records>,
        observer: &dyn Observer,
    ) -> Result<LmnModel, LmnError> {
        let r = &self.0.regressors;
        fn split<'a>(rs: &'a Records, r: &RegressorSpec) -> Result<Vec<Experiment<'a>>, LmnError> {
            rs.iter().map(|d| Experiment::of_record(d, r)).collect()
        }
        let t = split(train, r)?;
        let v = val.map(|v| split(v, r)).transpose()?;
        self.fit_experiments(&t, v.as_deref(), observer)
    }

    fn fit_experiments(
        &self,
        train: &[Experiment],
        val: Option<&[Experiment]>,
        observer: &dyn Observer,
    ) -> Result<LmnModel, LmnError> {
        let o = &self.0;
        let r = &o.regressors;
        if train.is_empty() {
            return Err(LmnError::InvalidArgument("no training experiments".into()));
        }
        if o.criterion == Criterion::Validation && val.is_none_or(<[Experiment]>::is_empty) {
            return Err(LmnError::InvalidArgument(
                "criterion Validation needs validation experiments".into(),
            ));
        }
        // scalings over all training experiments
        let cat = |f: &dyn for<'e> Fn(&Experiment<'e>) -> Option<&'e [f64]>| -> Vec<f64> {
            train.iter().filter_map(f).flatten().copied().collect()
        };
        for e in train.iter().chain(val.unwrap_or(&[])) {
            if e.inputs
                .iter()
                .chain(e.extra)
                .map(Vec::as_slice)
                .chain(std::iter::once(e.output))
                .flatten()
                .any(|v| !v.is_finite())
            {
                return Err(LmnError::InvalidArgument(
                    "the data contain NaN or infinite values".into(),
                ));
            }
            if e.inputs.len() != r.n_inputs() || e.extra.len() != r.n_extra {
                return Err(LmnError::Dimension(format!(
                    "structure has {} inputs and {} user columns, an experiment has {} and {}",
                    r.n_inputs(),
                    r.n_extra,
                    e.inputs.len(),
                    e.extra.len()
                )));
            }
        }
        let model = LmnModel {
            regressors: r.clone(),
            input_scaling: (0..r.n_inputs())
                .map(|j| Scaling::of(&cat(&|e| e.inputs.get(j).map(Vec::as_slice))))
                .collect(),
            output_scaling: Scaling::of(&cat(&|e| Some(e.output))),
            extra_scaling: (0..r.n_extra)
                .map(|j| Scaling::of(&cat(&|e| e.extra.get(j).map(Vec::as_slice))))
                .collect(),
            partition: Partition::root(o.weights, vec![], vec![], r.n_local()),
            summary: FitSummary {
                criterion: o.criterion,
                criterion_value: f64::NAN,
                history: vec![],
                pruned: 0,
                focus: o.focus,
                lm_iterations: 0,
                rms_before_lm: f64::NAN,
                rms_after_lm: f64::NAN,
            },
        };
        let nexps: Vec<NormExp> = train
            .iter()
            .map(|e| model.normalise_full(e))
            .collect::<Result<_, _>>()?;
        let nval: Vec<NormExp> = match val {
            Some(v) => v
                .iter()
                .map(|e| model.normalise_full(e))
                .collect::<Result<_, _>>()?,
            None => vec![],
        };
        let lay = Layout::new(r);
        let rows = Rows::build(&lay, &nexps, r.nx());
        let needed = 3 * lay.p + 10;
        if rows.n < needed {
            return Err(LmnError::TooShort {
                needed: needed + lay.max_lag,
                got: train.iter().map(Experiment::len).max().unwrap_or(0),
            });
        }
        let twice = o.noe_construction
            && o.focus == Focus::Simulation
            && r.max_output_lag() > 0
            && o.lm_iterations > 0;
        let part = |i: usize| SubTask {
            outer: observer,
            offset: i,
            span: 1,
            total: if twice { 2 } else { 1 },
        };
        let first = self.build(&model, &rows, &nexps, &nval, &part(0))?;
        if !twice {
            return Ok(first);
        }
        // NOE construction: grow again with output lags from the first
        // network's free-run simulation, train, keep the better simulation
        let mut ev = first.eval_scratch();
        let mut sims = Vec::with_capacity(nexps.len());
        for e in &nexps {
            let mut out = Vec::new();
            if !first.simulate_norm(e, &e.y, lay.max_lag, &mut ev, &mut out) {
                return Ok(first);
            }
            sims.push(out);
        }
        let rows2 = Rows::build_from(&lay, &nexps, r.nx(), Some(&sims));
        let judge = |m: &LmnModel| {
            validation_mse(
                m,
                if nval.is_empty() { &nexps } else { &nval },
                Focus::Simulation,
            )
        };
        match self.build(&model, &rows2, &nexps, &nval, &part(1)) {
            Ok(second) if judge(&second) < judge(&first) => Ok(second),
            _ => Ok(first),
        }
    }

    /// Grow, choose, prune and train one network on `rows`; progress in
    /// units of leaves grown (of `max_leaves`), then one for the global
    /// optimisation.
    fn build(
        &self,
        template: &LmnModel,
        rows: &Rows,
        nexps: &[NormExp],
        nval: &[NormExp],
        observer: &dyn Observer,
    ) -> Result<LmnModel, LmnError> {
        let o = &self.0;
        let units = o.max_leaves + 1;
        let mut model = template.clone();
        // score of a partition: information criterion or validation error
        let score = |part: &Partition, sse: f64, neff: f64| -> f64 {
            match o.criterion {
                Criterion::Validation => {
                    let mut m = template.clone();
                    m.partition = part.clone();
                    validation_mse(&m, nval, o.focus)
                }
                c => info_criterion(c, sse, rows.n, neff),
            }
        };
        let mut history: Vec<(usize, f64)> = vec![];
        let mut best = f64::INFINITY;
        let mut worse = 0;
        let mut keep = |part: &Partition, sse: f64, neff: f64| -> bool {
            observer.progress(part.n_leaves(), units, "growing the local model network");
            let s = score(part, sse, neff);
            history.push((part.n_leaves(), s));
            if s < best {
                best = s;
                worse = 0;
            } else {
                worse += 1;
            }
            worse < o.patience
        };
        let grown = match o.weights {
            WeightKind::Gaussian => grow_gauss(rows, o, &mut keep)?,
            _ => grow_tree(rows, o, &mut keep)?,
        };
        let (bi, _) = history
            .iter()
            .enumerate()
            .min_by(|a, b| a.1 .1.total_cmp(&b.1 .1))
            .map(|(i, v)| (i, v.1))
            .unwrap_or((0, f64::NAN));
        let mut part = grown.snapshots[bi].0.clone();
        let mut value = history.get(bi).map_or(f64::NAN, |h| h.1);
        if o.prune {
            let (mut full, sse, neff) = grown
                .snapshots
                .last()
                .cloned()
                .ok_or_else(|| LmnError::Numerical("no network grown".into()))?;
            let start = score(&full, sse, neff);
            let (removed, v) = crate::prune::prune(&mut full, rows, o.ridge, start, &score);
            if v <= value {
                part = full;
                value = v;
                model.summary.pruned = removed;
            }
        }
        part.compact();
        model.partition = part;
        model.summary.history = history.clone();
        model.summary.criterion_value = value;
        if o.lm_iterations > 0 {
            // a network grown on one-step errors may diverge in simulation:
            // then fall back to the next networks of the growth history
            let mut order: Vec<usize> = (0..history.len()).collect();
            order.sort_by(|a, b| history[*a].1.total_cmp(&history[*b].1));
            let mut tries = order.into_iter().filter(|&i| i != bi).take(3);
            observer.progress(
                o.max_leaves,
                units,
                match o.focus {
                    Focus::Simulation => "Levenberg-Marquardt on the simulation error",
                    _ => "Levenberg-Marquardt on the one-step error",
                },
            );
            loop {
                match crate::narx::optimise(
                    &mut model,
                    nexps,
                    o.focus,
                    o.lm_iterations,
                    o.stability_guard,
                    o.optimise_splits,
                    observer,
                ) {
                    Ok(rep) => {
                        model.summary.lm_iterations = rep.0;
                        model.summary.rms_before_lm = rep.1;
                        model.summary.rms_after_lm = rep.2;
                        break;
                    }
                    Err(LmnError::Unstable(m)) => {
                        let Some(i) = tries.next() else {
                            return Err(LmnError::Unstable(m));
                        };
                        let mut p = grown.snapshots[i].0.clone();
                        p.compact();
                        model.partition = p;
                        model.summary.criterion_value = history[i].1;
                        model.summary.pruned = 0;
                    }
                    Err(e) => return Err(e),
                }
            }
        }
        observer.progress(units, units, "local model network fitted");
        Ok(model)
    }
}

impl Identify for ValidLmnParams {
    type Model = LmnModel;
    type Error = LmnError;
    /// Every record a separate experiment; [`Criterion::Validation`] needs
    /// validation records ([`ValidLmnParams::fit`]) and is an error here.
    fn identify(&self, data: &Records, observer: &dyn Observer) -> Result<LmnModel, LmnError> {
        self.fit_with_observer(data, None, observer)
    }
}

/// Mean squared error (normalised) on validation experiments: free-run
/// simulation (focus Simulation) or one-step prediction.
pub(crate) fn validation_mse(m: &LmnModel, val: &[NormExp], focus: Focus) -> f64 {
    let mut ev: Eval = m.eval_scratch();
    let mut sum = 0.0;
    let mut cnt = 0usize;
    let k0 = m.max_lag();
    let mut out = Vec::new();
    for e in val {
        match focus {
            Focus::Prediction => {
                for k in k0..e.y.len() {
                    ev.lay.fill(k, &e.y, &e.u, &mut ev.x, &mut ev.z);
                    ev.lay.basis(&ev.x, &e.e, k, &mut ev.phi);
                    let v = m.eval(&mut ev, None, false);
                    sum += (e.y[k] - v).powi(2);
                    cnt += 1;
                }
            }
            _ => {
                if !m.simulate_norm(e, &e.y, k0, &mut ev, &mut out) {
                    return f64::INFINITY;
                }
                for k in k0..e.y.len() {
                    sum += (e.y[k] - out[k]).powi(2);
                    cnt += 1;
                }
            }
        }
    }
    if cnt == 0 {
        f64::INFINITY
    } else {
        sum / cnt as f64
    }
}
