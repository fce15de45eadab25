//! [`LmnModel`]: a local model network with separate x/z regressor spaces,
//! polynomial local models and Gaussian or decision-tree weights.
//!
//! ŷ(k) = Σᵢ Φᵢ(z(k)) · θᵢᵀ φ(x(k), e(k))
//!
//! All signals are normalised (mean 0, standard deviation 1 over the training
//! experiments); parameters live in those units.
use crate::regressors::Experiment;
use crate::regressors::{Layout, NormExp};
use crate::tree::{Partition, WScratch, WeightKind};
use crate::{LmnError, RegressorSpec, Scaling};
use gb_core::Record;
use serde::{Deserialize, Serialize};

/// Bound on |ŷ| (normalised units) beyond which a simulation counts as diverged.
pub(crate) const DIVERGED: f64 = 1e3;

/// How the number of local models was chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum Criterion {
    /// Corrected Akaike: N ln(SSE/N) + 2 n_eff + 2 n_eff (n_eff+1)/(N − n_eff − 1).
    Aicc,
    /// Bayesian: N ln(SSE/N) + n_eff ln N.
    Bic,
    /// Smallest error on validation experiments (simulation or one-step, by focus).
    Validation,
}

/// What the model is trained for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum Focus {
    /// One-step prediction (NARX, series-parallel): measured output lags.
    Prediction,
    /// Free-run simulation (NOE, parallel): the model's own output lags.
    Simulation,
}

/// How a network was built and how well it fits (for reports).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitSummary {
    /// Criterion that chose the number of leaves.
    pub criterion: Criterion,
    /// Criterion value of the chosen network (validation: mean squared error, normalised).
    pub criterion_value: f64,
    /// (leaves, criterion value) after every split of the growth phase.
    pub history: Vec<(usize, f64)>,
    /// Splits removed by pruning.
    pub pruned: usize,
    /// Focus of the global optimisation.
    pub focus: Focus,
    /// Levenberg–Marquardt iterations of the global optimisation.
    pub lm_iterations: usize,
    /// Training RMS error (normalised units) of the focus before/after global optimisation.
    pub rms_before_lm: f64,
    /// See `rms_before_lm`.
    pub rms_after_lm: f64,
}

/// A fitted local model network.
///
/// ```
/// use gb_core::{Record, Records};
/// use gb_lmn::{LmnParams, RegressorSpec};
/// // static function of one input: y = |u|
/// let u: Vec<f64> = (0..400).map(|k| -1.0 + 2.0 * k as f64 / 399.0).collect();
/// let y: Vec<f64> = u.iter().map(|v| v.abs()).collect();
/// let data = Record::new(vec!["u".into()], "y".into(), vec![u], y.clone()).unwrap();
/// let reg = RegressorSpec::arx(0, &[1], &[0]);
/// let m = LmnParams::new(reg).max_leaves(4).fit(&Records::single(data.clone())).unwrap();
/// let p = m.predict(&data).unwrap();
/// assert!(gb_core::metrics::rmse(&y, &p).unwrap() < 0.02);
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LmnModel {
    /// Regressor structure.
    pub regressors: RegressorSpec,
    /// Normalisation of each input.
    pub input_scaling: Vec<Scaling>,
    /// Normalisation of the output.
    pub output_scaling: Scaling,
    /// Normalisation of each user column.
    pub extra_scaling: Vec<Scaling>,
    /// Partition tree and local models.
    pub partition: Partition,
    /// How it was built.
    pub summary: FitSummary,
}

/// Evaluation scratch: regressors, basis, weights, gradients.
#[derive(Debug, Clone)]
pub(crate) struct Eval {
    pub lay: Layout,
    pub w: WScratch,
    pub x: Vec<f64>,
    pub z: Vec<f64>,
    pub phi: Vec<f64>,
    pub gx: Vec<f64>,
    pub gz: Vec<f64>,
}

/// One split of the tree, for introspection.
#[derive(Debug, Clone, PartialEq)]
pub struct SplitInfo {
    /// Node index.
    pub node: usize,
    /// Depth (root 0).
    pub depth: usize,
    /// Axis dimension (None: oblique).
    pub axis: Option<usize>,
    /// Unit normal of the split hyperplane over z (normalised units).
    pub direction: Vec<f64>,
    /// Position: the hyperplane is directionᵀz = position.
    pub position: f64,
    /// Steepness ‖w‖ (inverse transition width; tree weights).
    pub steepness: f64,
}

impl LmnModel {
    /// Number of local models.
    pub fn n_leaves(&self) -> usize {
        self.partition.n_leaves()
    }

    /// Local parameters θᵢ of every leaf (normalised units), in leaf order.
    pub fn local_parameters(&self) -> Vec<Vec<f64>> {
        self.partition
            .leaves()
            .into_iter()
            .map(|l| self.partition.nodes[l].theta.clone())
            .collect()
    }

    /// The splits: direction, position and steepness.
    pub fn splits(&self) -> Vec<SplitInfo> {
        let mut depth = vec![0usize; self.partition.nodes.len()];
        let mut out = Vec::new();
        for n in self.partition.preorder() {
            let nd = &self.partition.nodes[n];
            if let Some(p) = nd.parent {
                depth[n] = depth[p] + 1;
            }
            if let Some(s) = &nd.split {
                let norm = s.w.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300);
                out.push(SplitInfo {
                    node: n,
                    depth: depth[n],
                    axis: s.axis,
                    direction: s.w.iter().map(|v| v / norm).collect(),
                    position: -s.w0 / norm,
                    steepness: norm,
                });
            }
        }
        out
    }

    /// Effective number of parameters: Σ over leaves of tr((XᵀQᵢX)⁻¹XᵀQᵢ²X)
    /// (local estimation, Nelles 2020, sec. 13.3) plus the split parameters.
    pub fn effective_parameters(&self) -> f64 {
        let leaves: f64 = self
            .partition
            .leaves()
            .iter()
            .map(|&l| self.partition.nodes[l].n_eff)
            .sum();
        leaves + split_params(&self.partition)
    }

    /// Total number of parameters (local + split parameters).
    pub fn n_parameters(&self) -> usize {
        self.n_leaves() * self.regressors.n_local() + self.partition.n_split_parameters()
    }

    /// Samples at the start of an experiment that initialise the regressors.
    pub fn max_lag(&self) -> usize {
        self.regressors.max_lag()
    }

    /// One-line description.
    pub fn describe(&self) -> String {
        let kind = match self.partition.kind {
            WeightKind::Gaussian => "normalised Gaussian",
            WeightKind::Tree => "decision-tree sigmoid",
        };
        let oblique = self.splits().iter().any(|s| s.axis.is_none());
        let r = &self.regressors;
        let local = match r.degree {
            1 => "affine".to_string(),
            d => format!("polynomial degree {d}"),
        };
        format!(
            "local model network, {} {} local models over x = {} regressors ({}{}), {} weights over z = {} regressors, {} splits, {:?} focus, chosen by {:?}",
            self.n_leaves(),
            local,
            r.nx(),
            format_delays(&r.x_output, &r.x_inputs),
            if r.n_extra > 0 { format!(" + {} user columns", r.n_extra) } else { String::new() },
            kind,
            r.nz(),
            if oblique { "oblique" } else { "axis-orthogonal" },
            self.summary.focus,
            self.summary.criterion,
        )
    }

    /// Check internal consistency (after deserialisation).
    pub fn check_consistency(&self) -> Result<(), LmnError> {
        self.regressors.check()?;
        let r = &self.regressors;
        if self.input_scaling.len() != r.n_inputs()
            || self.extra_scaling.len() != r.n_extra
            || !self.partition.is_consistent(r.n_local(), r.nz())
        {
            return Err(LmnError::InvalidArgument(
                "inconsistent network parameters".into(),
            ));
        }
        Ok(())
    }

    pub(crate) fn eval_scratch(&self) -> Eval {
        let lay = Layout::new(&self.regressors);
        Eval {
            w: self.partition.scratch(),
            x: vec![0.0; self.regressors.nx()],
            z: vec![0.0; self.regressors.nz()],
            phi: vec![0.0; lay.p],
            gx: vec![0.0; self.regressors.nx()],
            gz: vec![0.0; self.regressors.nz()],
            lay,
        }
    }

    /// Normalise an experiment (checks dimensions).
    pub(crate) fn normalise(&self, e: &Experiment) -> Result<NormExp, LmnError> {
        let r = &self.regressors;
        if e.inputs.len() != r.n_inputs() || e.extra.len() != r.n_extra {
            return Err(LmnError::Dimension(format!(
                "model has {} inputs and {} user columns, data has {} and {}",
                r.n_inputs(),
                r.n_extra,
                e.inputs.len(),
                e.extra.len()
            )));
        }
        let n = e.inputs.first().map_or(e.output.len(), Vec::len);
        if e.inputs.iter().chain(e.extra).any(|u| u.len() != n) {
            return Err(LmnError::Dimension("signals of different lengths".into()));
        }
        Ok(NormExp {
            u: e.inputs
                .iter()
                .zip(&self.input_scaling)
                .map(|(u, s)| u.iter().map(|&v| s.to_norm(v)).collect())
                .collect(),
            y: e.output
                .iter()
                .map(|&v| self.output_scaling.to_norm(v))
                .collect(),
            e: e.extra
                .iter()
                .zip(&self.extra_scaling)
                .map(|(u, s)| u.iter().map(|&v| s.to_norm(v)).collect())
                .collect(),
        })
    }

    /// [`normalise`](Self::normalise) for data with a full output record
    /// (fitting, prediction, pruning, refinement): the output must be as
    /// long as the inputs.
    pub(crate) fn normalise_full(&self, e: &Experiment) -> Result<NormExp, LmnError> {
        if let Some(u) = e.inputs.first() {
            if u.len() != e.output.len() {
                return Err(LmnError::Dimension(format!(
                    "the output has {} samples, the inputs {}",
                    e.output.len(),
                    u.len()
                )));
            }
        }
        self.normalise(e)
    }

    /// Network output (normalised) at the regressors in `ev.x`, `ev.z`, `ev.phi`.
    /// With `grad_p` the derivative w.r.t. all parameters (see
    /// [`parameters`](Self::parameters)); with `grad_xz` ∂ŷ/∂x and ∂ŷ/∂z in
    /// `ev.gx`, `ev.gz`.
    #[inline]
    pub(crate) fn eval(&self, ev: &mut Eval, grad_p: Option<&mut [f64]>, grad_xz: bool) -> f64 {
        let part = &self.partition;
        part.weights(&ev.z, &mut ev.w);
        let mut y = 0.0;
        for &l in &ev.w.leaves {
            let ph = ev.w.phi[l];
            if ph < crate::tree::TINY && grad_p.is_none() && !grad_xz {
                continue;
            }
            let v = gb_core::gram::dot(&part.nodes[l].theta, &ev.phi);
            ev.w.yc[l] = v;
            y += ph * v;
        }
        let need_da = grad_p.is_some() || grad_xz;
        if need_da {
            ev.gz.fill(0.0);
            part.weight_derivatives(&ev.z, &mut ev.w, &mut ev.gz);
        }
        if let Some(g) = grad_p {
            let p = ev.lay.p;
            for (i, &l) in ev.w.leaves.iter().enumerate() {
                let ph = ev.w.phi[l];
                let dst = &mut g[i * p..(i + 1) * p];
                for (d, b) in dst.iter_mut().zip(&ev.phi) {
                    *d = ph * b;
                }
            }
            if part.kind == WeightKind::Tree {
                let nz = ev.z.len();
                let off = ev.w.leaves.len() * p;
                for (i, &n) in ev.w.inner.iter().enumerate() {
                    let da = ev.w.da[n];
                    let dst = &mut g[off + i * (nz + 1)..off + (i + 1) * (nz + 1)];
                    for (d, zd) in dst.iter_mut().zip(&ev.z) {
                        *d = da * zd;
                    }
                    dst[nz] = da;
                }
            }
        }
        if grad_xz {
            ev.gx.fill(0.0);
            for &l in &ev.w.leaves {
                let ph = ev.w.phi[l];
                if ph != 0.0 {
                    ev.lay
                        .add_local_grad(&part.nodes[l].theta, &ev.x, ph, &mut ev.gx);
                }
            }
        }
        y
    }

    /// Flattened parameters: θ of every leaf (leaf order), then for tree
    /// weights (w, w0) of every inner node (preorder).
    pub fn parameters(&self) -> Vec<f64> {
        let part = &self.partition;
        let mut v = Vec::new();
        for l in part.leaves() {
            v.extend_from_slice(&part.nodes[l].theta);
        }
        if part.kind == WeightKind::Tree {
            for n in part.inner() {
                if let Some(s) = &part.nodes[n].split {
                    v.extend_from_slice(&s.w);
                    v.push(s.w0);
                }
            }
        }
        v
    }

    /// Set parameters from a vector laid out as [`parameters`](Self::parameters).
    pub fn set_parameters(&mut self, p: &[f64]) -> Result<(), LmnError> {
        let np = self.parameters().len();
        if p.len() != np {
            return Err(LmnError::Dimension(format!(
                "{} parameters given, the network has {np}",
                p.len()
            )));
        }
        let pl = self.regressors.n_local();
        let nz = self.regressors.nz();
        let leaves = self.partition.leaves();
        let inner = self.partition.inner();
        let mut c = 0;
        for l in leaves {
            self.partition.nodes[l].theta.copy_from_slice(&p[c..c + pl]);
            c += pl;
        }
        if self.partition.kind == WeightKind::Tree {
            for n in inner {
                if let Some(s) = &mut self.partition.nodes[n].split {
                    s.w.copy_from_slice(&p[c..c + nz]);
                    s.w0 = p[c + nz];
                    c += nz + 1;
                }
            }
        }
        Ok(())
    }

    /// Free-run simulation of a normalised experiment into `out`; the first
    /// `k0` samples (≥ max_lag) are copied from `init` (normalised; missing
    /// values start at 0, the mean). Returns false if it diverged.
    pub(crate) fn simulate_norm(
        &self,
        ne: &NormExp,
        init: &[f64],
        k0: usize,
        ev: &mut Eval,
        out: &mut Vec<f64>,
    ) -> bool {
        let n = ne.u.first().map_or(ne.y.len(), Vec::len);
        let k0 = k0.max(self.max_lag()).min(n);
        out.clear();
        out.resize(n, 0.0);
        for k in 0..k0 {
            out[k] = init.get(k).copied().unwrap_or(0.0);
        }
        if self.partition.kind == WeightKind::Tree {
            return self.simulate_tree(ne, k0, ev, out);
        }
        for k in k0..n {
            ev.lay.fill(k, out, &ne.u, &mut ev.x, &mut ev.z);
            ev.lay.basis(&ev.x, &ne.e, k, &mut ev.phi);
            let v = self.eval(ev, None, false);
            if !v.is_finite() || v.abs() > DIVERGED {
                return false;
            }
            out[k] = v;
        }
        true
    }

    /// The simulation hot loop for tree weights on flat arrays: all split
    /// activations, then all exponentials in one vectorisable pass, then the
    /// products down the tree and the local models.
    fn simulate_tree(&self, ne: &NormExp, k0: usize, ev: &mut Eval, out: &mut [f64]) -> bool {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                // SAFETY: the CPU supports AVX2 and FMA (checked just above).
                return unsafe { self.simulate_tree_avx2(ne, k0, ev, out) };
            }
        }
        self.simulate_tree_body::<false>(ne, k0, ev, out)
    }

    /// [`simulate_tree`](Self::simulate_tree) compiled for AVX2 + FMA (4-wide
    /// exponentials).
    ///
    /// # Safety
    /// The CPU must support AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn simulate_tree_avx2(
        &self,
        ne: &NormExp,
        k0: usize,
        ev: &mut Eval,
        out: &mut [f64],
    ) -> bool {
        self.simulate_tree_body::<true>(ne, k0, ev, out)
    }

    /// The hot loop itself (kept inline here for speed; [`TreeSim::step`]
    /// is the same arithmetic for one sample, for the stepper — the
    /// stepping test checks that they agree bit for bit).
    #[inline(always)]
    fn simulate_tree_body<const FMA: bool>(
        &self,
        ne: &NormExp,
        k0: usize,
        ev: &mut Eval,
        out: &mut [f64],
    ) -> bool {
        let part = &self.partition;
        let nz = ev.z.len();
        let p = ev.lay.p;
        let inner = &ev.w.inner;
        let ni = inner.len();
        let Some((w, w0, kids)) = split_table(part, inner, nz) else {
            return false;
        };
        let leaves = &ev.w.leaves;
        let nl = leaves.len();
        // local parameters transposed (p × leaves): L = Θᵀφ vectorises over leaves
        let mut theta_t = vec![0.0; p * nl];
        for (c, &l) in leaves.iter().enumerate() {
            for (j, v) in part.nodes[l].theta.iter().enumerate() {
                theta_t[j * nl + c] = *v;
            }
        }
        // activations padded to a multiple of 4 (whole vectors, no scalar tail)
        let ni4 = ni.div_ceil(4) * 4;
        let mut ea = vec![0.0; ni4];
        let mut lw = vec![0.0; nl];
        let mut loc = vec![0.0; nl];
        let mut phi_n = vec![0.0; part.nodes.len()];
        let n = out.len();
        // taps as (signal, delay): signal 0 = output, j + 1 = input j
        let code = |t: &crate::regressors::Tap| match t.signal {
            crate::regressors::Signal::Output => (0usize, t.delay),
            crate::regressors::Signal::Input(j) => (j + 1, t.delay),
        };
        let xs: Vec<(usize, usize)> = ev.lay.x.iter().map(code).collect();
        let zs: Vec<(usize, usize)> = ev.lay.z.iter().map(code).collect();
        let affine = ev.lay.mono.is_empty() && ne.e.is_empty();
        let mut z = vec![0.0; nz];
        let phi_b = &mut ev.phi;
        for k in k0..n {
            let tap = |sig: usize, d: usize, out: &[f64]| {
                if sig == 0 {
                    out[k - d]
                } else {
                    ne.u[sig - 1][k - d]
                }
            };
            if affine {
                phi_b[0] = 1.0;
                for (f, &(sig, d)) in phi_b[1..].iter_mut().zip(&xs) {
                    *f = tap(sig, d, out);
                }
            } else {
                for (f, &(sig, d)) in ev.x.iter_mut().zip(&xs) {
                    *f = tap(sig, d, out);
                }
                ev.lay.basis(&ev.x, &ne.e, k, phi_b);
            }
            for (f, &(sig, d)) in z.iter_mut().zip(&zs) {
                *f = tap(sig, d, out);
            }
            for ((e, wi), b) in ea.iter_mut().zip(w.chunks_exact(nz.max(1))).zip(&w0) {
                let mut a = *b;
                for (wd, zd) in wi.iter().zip(&z) {
                    a += wd * zd;
                }
                *e = -a;
            }
            // ψ = 1 / (1 + e^{−a}) for all splits in one pass
            for e in ea.iter_mut() {
                *e = 1.0 / (1.0 + crate::tree::fast_exp_g::<FMA>(*e));
            }
            // weights down the tree (preorder: parents first)
            phi_n[0] = 1.0;
            for (psi, &(i, l, r)) in ea.iter().zip(&kids) {
                let pn = phi_n[i];
                let pr = pn * psi;
                phi_n[r] = pr;
                phi_n[l] = pn - pr;
            }
            for (v, &l) in lw.iter_mut().zip(leaves) {
                *v = phi_n[l];
            }
            loc.fill(0.0);
            for (row, f) in theta_t.chunks_exact(nl).zip(phi_b.iter()) {
                for (o, t) in loc.iter_mut().zip(row) {
                    *o += t * f;
                }
            }
            // four partial sums: a short dependency chain
            let mut acc = [0.0; 4];
            let (lw4, lwr) = lw.split_at(nl - nl % 4);
            let (lo4, lor) = loc.split_at(nl - nl % 4);
            for (a, b) in lw4.chunks_exact(4).zip(lo4.chunks_exact(4)) {
                for i in 0..4 {
                    acc[i] += a[i] * b[i];
                }
            }
            for (a, b) in lwr.iter().zip(lor) {
                acc[0] += a * b;
            }
            let y = (acc[0] + acc[1]) + (acc[2] + acc[3]);
            if !y.is_finite() || y.abs() > DIVERGED {
                return false;
            }
            out[k] = y;
        }
        true
    }

    /// Free-run simulation (physical units) of a record. The first
    /// `init_window` samples of its output initialise the output lags (at
    /// least `max_lag` samples are taken from the record; the inputs and
    /// user columns drive the rest).
    pub fn simulate(&self, data: &Record, init_window: usize) -> Result<Vec<f64>, LmnError> {
        self.simulate_experiment(&Experiment::of_record(data, &self.regressors)?, init_window)
    }

    /// Free-run simulation (physical units) of input signals (the inputs,
    /// then any user columns). The output lags start from the measured
    /// outputs `y_init` — the first `max(y_init.len(), max_lag)` samples;
    /// samples missing from `y_init` start at the training mean.
    pub fn simulate_signals(
        &self,
        inputs: &[Vec<f64>],
        y_init: &[f64],
    ) -> Result<Vec<f64>, LmnError> {
        let r = &self.regressors;
        let e = Experiment::split(inputs, y_init, r.n_inputs(), r.n_extra)?;
        self.simulate_experiment(&e, y_init.len())
    }

    pub(crate) fn simulate_experiment(
        &self,
        e: &Experiment,
        init_window: usize,
    ) -> Result<Vec<f64>, LmnError> {
        let ne = self.normalise(e)?;
        let n = ne.u.first().map_or(e.output.len(), Vec::len);
        let k0 = init_window.max(self.max_lag()).min(n);
        let init: Vec<f64> = ne.y.iter().take(k0).copied().collect();
        let mut ev = self.eval_scratch();
        let mut out = Vec::with_capacity(n);
        if !self.simulate_norm(&ne, &init, k0, &mut ev, &mut out) {
            return Err(LmnError::Unstable(
                "the simulation diverged on these inputs".into(),
            ));
        }
        for v in out.iter_mut() {
            *v = self.output_scaling.from_norm(*v);
        }
        Ok(out)
    }

    /// One-step-ahead prediction (NARX, measured output lags), physical
    /// units; the first `max_lag` samples are copied from the measurement.
    pub fn predict(&self, data: &Record) -> Result<Vec<f64>, LmnError> {
        let e = Experiment::of_record(data, &self.regressors)?;
        let ne = self.normalise_full(&e)?;
        let n = ne.y.len();
        let k0 = self.max_lag().min(n);
        let mut ev = self.eval_scratch();
        let mut out = e.output.to_vec();
        for k in k0..n {
            ev.lay.fill(k, &ne.y, &ne.u, &mut ev.x, &mut ev.z);
            ev.lay.basis(&ev.x, &ne.e, k, &mut ev.phi);
            out[k] = self
                .output_scaling
                .from_norm(self.eval(&mut ev, None, false));
        }
        Ok(out)
    }

    /// Largest spectral radius of the local models' autoregressive parts
    /// (affine local models; 0 without output lags in x).
    pub fn max_spectral_radius(&self) -> f64 {
        let r = &self.regressors;
        let na = r.x_output.iter().copied().max().unwrap_or(0);
        if na == 0 {
            return 0.0;
        }
        let mut worst: f64 = 0.0;
        for l in self.partition.leaves() {
            let th = &self.partition.nodes[l].theta;
            let mut a = vec![0.0; na];
            for (j, &d) in r.x_output.iter().enumerate() {
                a[d - 1] += th[1 + j];
            }
            worst = worst.max(crate::network::spectral_radius(&a));
        }
        worst
    }
}

/// The tree network's simulation on flat arrays for one sample at a time
/// (the stepper): all split activations, then all exponentials (branch-free
/// exp), then the products down the tree and the local models — the
/// arithmetic of [`LmnModel::simulate_tree_body`], so stepping through a
/// record gives bit-identical outputs.
pub(crate) struct TreeSim {
    nz: usize,
    w: Vec<f64>,
    w0: Vec<f64>,
    kids: Vec<(usize, usize, usize)>,
    leaves: Vec<usize>,
    nl: usize,
    theta_t: Vec<f64>,
    ea: Vec<f64>,
    lw: Vec<f64>,
    loc: Vec<f64>,
    phi_n: Vec<f64>,
    xs: Vec<(usize, usize)>,
    zs: Vec<(usize, usize)>,
    affine: bool,
    z: Vec<f64>,
}

/// The splits of the inner nodes `inner` in one table: the weight vectors
/// (`nz` each, concatenated), the offsets and `(node, left, right)`.
/// `None` when an inner node has no split (an inconsistent tree).
#[allow(clippy::type_complexity)]
fn split_table(
    part: &Partition,
    inner: &[usize],
    nz: usize,
) -> Option<(Vec<f64>, Vec<f64>, Vec<(usize, usize, usize)>)> {
    let ni = inner.len();
    let mut w = Vec::with_capacity(ni * nz);
    let mut w0 = Vec::with_capacity(ni);
    let mut kids = Vec::with_capacity(ni);
    for &i in inner {
        let sp = part.nodes[i].split.as_ref()?;
        w.extend_from_slice(&sp.w);
        w0.push(sp.w0);
        kids.push((i, sp.left, sp.right));
    }
    Some((w, w0, kids))
}

impl TreeSim {
    /// `None` when an inner node has no split (an inconsistent tree);
    /// `no_extra`: the data have no user columns.
    pub(crate) fn new(m: &LmnModel, ev: &Eval, no_extra: bool) -> Option<Self> {
        let part = &m.partition;
        let nz = ev.z.len();
        let p = ev.lay.p;
        let inner = &ev.w.inner;
        let ni = inner.len();
        let (w, w0, kids) = split_table(part, inner, nz)?;
        let leaves = ev.w.leaves.clone();
        let nl = leaves.len();
        // local parameters transposed (p × leaves): L = Θᵀφ vectorises over leaves
        let mut theta_t = vec![0.0; p * nl];
        for (c, &l) in leaves.iter().enumerate() {
            for (j, v) in part.nodes[l].theta.iter().enumerate() {
                theta_t[j * nl + c] = *v;
            }
        }
        // activations padded to a multiple of 4 (whole vectors, no scalar tail)
        let ni4 = ni.div_ceil(4) * 4;
        // taps as (signal, delay): signal 0 = output, j + 1 = input j
        let code = |t: &crate::regressors::Tap| match t.signal {
            crate::regressors::Signal::Output => (0usize, t.delay),
            crate::regressors::Signal::Input(j) => (j + 1, t.delay),
        };
        Some(Self {
            nz,
            w,
            w0,
            kids,
            nl,
            theta_t,
            ea: vec![0.0; ni4],
            lw: vec![0.0; nl],
            loc: vec![0.0; nl],
            phi_n: vec![0.0; part.nodes.len()],
            xs: ev.lay.x.iter().map(code).collect(),
            zs: ev.lay.z.iter().map(code).collect(),
            affine: ev.lay.mono.is_empty() && no_extra,
            z: vec![0.0; nz],
            leaves,
        })
    }

    /// The network output (normalised) at sample k from the outputs
    /// `out[..k]`, the inputs `u` and user columns `e` (all normalised).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn step<const FMA: bool>(
        &mut self,
        k: usize,
        out: &[f64],
        u: &[Vec<f64>],
        e: &[Vec<f64>],
        lay: &Layout,
        x: &mut [f64],
        phi_b: &mut [f64],
    ) -> f64 {
        let Self {
            nz,
            w,
            w0,
            kids,
            leaves,
            nl,
            theta_t,
            ea,
            lw,
            loc,
            phi_n,
            xs,
            zs,
            affine,
            z,
        } = self;
        let (nl, nz) = (*nl, *nz);
        let tap = |sig: usize, d: usize| {
            if sig == 0 {
                out[k - d]
            } else {
                u[sig - 1][k - d]
            }
        };
        if *affine {
            phi_b[0] = 1.0;
            for (f, &(sig, d)) in phi_b[1..].iter_mut().zip(xs.iter()) {
                *f = tap(sig, d);
            }
        } else {
            for (f, &(sig, d)) in x.iter_mut().zip(xs.iter()) {
                *f = tap(sig, d);
            }
            lay.basis(x, e, k, phi_b);
        }
        for (f, &(sig, d)) in z.iter_mut().zip(zs.iter()) {
            *f = tap(sig, d);
        }
        for ((ea, wi), b) in ea.iter_mut().zip(w.chunks_exact(nz.max(1))).zip(w0.iter()) {
            let mut a = *b;
            for (wd, zd) in wi.iter().zip(z.iter()) {
                a += wd * zd;
            }
            *ea = -a;
        }
        // ψ = 1 / (1 + e^{−a}) for all splits in one pass
        for ea in ea.iter_mut() {
            *ea = 1.0 / (1.0 + crate::tree::fast_exp_g::<FMA>(*ea));
        }
        // weights down the tree (preorder: parents first)
        phi_n[0] = 1.0;
        for (psi, &(i, l, r)) in ea.iter().zip(kids.iter()) {
            let pn = phi_n[i];
            let pr = pn * psi;
            phi_n[r] = pr;
            phi_n[l] = pn - pr;
        }
        for (v, &l) in lw.iter_mut().zip(leaves.iter()) {
            *v = phi_n[l];
        }
        loc.fill(0.0);
        for (row, f) in theta_t.chunks_exact(nl).zip(phi_b.iter()) {
            for (o, t) in loc.iter_mut().zip(row) {
                *o += t * f;
            }
        }
        // four partial sums: a short dependency chain
        let mut acc = [0.0; 4];
        let (lw4, lwr) = lw.split_at(nl - nl % 4);
        let (lo4, lor) = loc.split_at(nl - nl % 4);
        for (a, b) in lw4.chunks_exact(4).zip(lo4.chunks_exact(4)) {
            for i in 0..4 {
                acc[i] += a[i] * b[i];
            }
        }
        for (a, b) in lwr.iter().zip(lor) {
            acc[0] += a * b;
        }
        (acc[0] + acc[1]) + (acc[2] + acc[3])
    }
}

/// An [`LmnModel`] running one sample at a time from normalised initial
/// outputs: the arithmetic of the simulation (the tree's flat-array step or
/// the generic evaluation) on a sliding history, so stepping through a
/// record gives bit-identical outputs.
pub(crate) struct LmnStepper<'a> {
    m: &'a LmnModel,
    /// Normalised initial outputs (the first `init.len()` ≥ `max_lag`
    /// samples).
    init: Vec<f64>,
    /// Sliding history of the normalised inputs, user columns and outputs;
    /// `base` samples have been dropped from their front.
    u: Vec<Vec<f64>>,
    e: Vec<Vec<f64>>,
    out: Vec<f64>,
    base: usize,
    k: usize,
    ev: Eval,
    tree: Option<TreeSim>,
    fma: bool,
    failed: bool,
}

impl<'a> LmnStepper<'a> {
    /// Start with the physical output history `init` (at least `max_lag`
    /// samples; see [`gb_core::DynamicModel::stepper`]).
    pub(crate) fn new(m: &'a LmnModel, init: &[f64]) -> Result<Self, LmnError> {
        let ev = m.eval_scratch();
        let tree = if m.partition.kind == WeightKind::Tree {
            Some(
                TreeSim::new(m, &ev, m.regressors.n_extra == 0)
                    .ok_or_else(|| LmnError::InvalidArgument("inconsistent tree network".into()))?,
            )
        } else {
            None
        };
        #[cfg(target_arch = "x86_64")]
        let fma = std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma");
        #[cfg(not(target_arch = "x86_64"))]
        let fma = false;
        Ok(Self {
            init: init.iter().map(|&v| m.output_scaling.to_norm(v)).collect(),
            u: vec![vec![]; m.regressors.n_inputs()],
            e: vec![vec![]; m.regressors.n_extra],
            out: vec![],
            base: 0,
            k: 0,
            ev,
            tree,
            fma,
            failed: false,
            m,
        })
    }

    /// Advance one sample with the physical inputs (then user columns) `u`;
    /// the physical output.
    pub(crate) fn step(&mut self, u: &[f64]) -> Result<f64, LmnError> {
        let m = self.m;
        let r = &m.regressors;
        if u.len() != r.n_signals() {
            return Err(LmnError::Dimension(format!(
                "the network has {} input signals, {} values were given",
                r.n_signals(),
                u.len()
            )));
        }
        if self.failed {
            return Err(LmnError::Unstable("the simulation diverged".into()));
        }
        let ni = r.n_inputs();
        for (j, s) in m.input_scaling.iter().enumerate() {
            self.u[j].push(s.to_norm(u[j]));
        }
        for (j, s) in m.extra_scaling.iter().enumerate() {
            self.e[j].push(s.to_norm(u[ni + j]));
        }
        let k0 = self.init.len().max(m.max_lag());
        let k = self.k;
        let v = if k < k0 {
            self.init.get(k).copied().unwrap_or(0.0)
        } else {
            let kl = k - self.base;
            let ev = &mut self.ev;
            let v = match &mut self.tree {
                Some(t) if self.fma => t.step::<true>(
                    kl,
                    &self.out,
                    &self.u,
                    &self.e,
                    &ev.lay,
                    &mut ev.x,
                    &mut ev.phi,
                ),
                Some(t) => t.step::<false>(
                    kl,
                    &self.out,
                    &self.u,
                    &self.e,
                    &ev.lay,
                    &mut ev.x,
                    &mut ev.phi,
                ),
                None => {
                    ev.lay.fill(kl, &self.out, &self.u, &mut ev.x, &mut ev.z);
                    ev.lay.basis(&ev.x, &self.e, kl, &mut ev.phi);
                    m.eval(ev, None, false)
                }
            };
            if !v.is_finite() || v.abs() > DIVERGED {
                self.failed = true;
                return Err(LmnError::Unstable("the simulation diverged".into()));
            }
            v
        };
        self.out.push(v);
        self.k += 1;
        // drop history no regressor reads any more
        let keep = m.max_lag() + 1;
        let len = self.out.len();
        if len >= 4 * keep + 64 && self.k > k0 {
            let d = len - keep;
            self.out.drain(..d);
            for c in self.u.iter_mut().chain(self.e.iter_mut()) {
                c.drain(..d);
            }
            self.base += d;
        }
        Ok(m.output_scaling.from_norm(v))
    }
}

/// Split parameters counted in the effective number of parameters: one per
/// axis split (its dimension), nz + 1 per oblique split.
pub(crate) fn split_params(p: &Partition) -> f64 {
    let nz = p.nz() as f64;
    p.inner()
        .iter()
        .map(|&n| match p.nodes[n].split.as_ref().and_then(|s| s.axis) {
            Some(_) => 1.0,
            None => nz + 1.0,
        })
        .sum()
}

fn format_delays(out: &[usize], inp: &[Vec<usize>]) -> String {
    let mut parts = Vec::new();
    if !out.is_empty() {
        parts.push(format!("y{:?}", out));
    }
    for (j, d) in inp.iter().enumerate() {
        if !d.is_empty() {
            parts.push(format!("u{}{:?}", j + 1, d));
        }
    }
    parts.join(" ")
}
