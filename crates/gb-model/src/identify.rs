//! Deterministic identification: output-error (simulation-error) minimisation
//! with analytic forward sensitivities, Levenberg–Marquardt, and a
//! coarse-to-fine sparse refinement of the wavelet terms.
//!
//! Cost: `V(θ) = Σ_{t ≥ skip} (y_t − ŷ_t(θ))²` of the free-run simulation.
//! Sensitivities `S_t = ∂x_t/∂θ` follow the model through time (Hauth 2008,
//! ch. 5; Ljung 1999, §10.3):
//!
//! ```text
//! S_{t+1} = (A + ∂f/∂x) S_t + ∂(Ax + Bu + f + h)/∂θ |_direct,
//! ∂ŷ_t/∂θ = (C + ∂g/∂x) S_t + ∂(Cx + Du + g + h_y)/∂θ |_direct,
//! ```
//!
//! and Levenberg–Marquardt (`gb_core::solver`, the workspace's one solver)
//! solves `(JᵀJ + λ diag JᵀJ) δ = Jᵀe`; the sensitivity pass is the
//! problem's linearisation.
//!
//! **Multiresolution refinement.** The wavelet terms start from the scaling
//! functions of a coarse level `j₀` (a full tensor grid, value 0). For every
//! finer level `j`, each candidate detail atom `λ` is scored by the decrease of
//! the cost it would give alone, `(J_λᵀe)² / J_λᵀJ_λ` (one Gauss–Newton step),
//! and only candidates whose score exceeds the information-criterion price of
//! a parameter, `κ σ̂²` with `κ = ln N` (BIC), are added — finer coefficients
//! only where they pay. After each refit, hard thresholding removes every
//! coefficient with `c_λ² (JᵀJ)_λλ < κ σ̂²` (sparsity across scales, Mallat
//! 2009, ch. 10). A level that does not lower the BIC
//! `N ln(V/N) + p ln N` is discarded and the refinement stops.
use crate::basis::{EvalScratch, MAX_DIMS};
use crate::error::{ModelError, Result};
use crate::model::{Signal, SparseStateSpace, Target};
use gb_core::solver::{LeastSquaresProblem, LmParams};
use gb_core::{IterationInfo, Observer};
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicUsize, Ordering};

/// One free parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Param {
    A(usize),
    B(usize),
    C(usize),
    D(usize),
    X0(usize),
    Offset,
    Coef(usize, usize),
    Hyst(usize, usize),
}

/// All free parameters of `m` (free matrix entries, then every stored coefficient).
pub(crate) fn layout(m: &SparseStateSpace) -> Vec<Param> {
    let s = &m.structure;
    let mut p = Vec::new();
    let push = |v: &[bool], f: fn(usize) -> Param, p: &mut Vec<Param>| {
        p.extend(v.iter().enumerate().filter(|(_, &b)| b).map(|(i, _)| f(i)));
    };
    push(&s.a, Param::A, &mut p);
    push(&s.b, Param::B, &mut p);
    push(&s.c, Param::C, &mut p);
    push(&s.d, Param::D, &mut p);
    push(&s.x0, Param::X0, &mut p);
    if s.y_offset {
        p.push(Param::Offset);
    }
    for (k, t) in m.terms.iter().enumerate() {
        p.extend((0..t.expansion.len()).map(|i| Param::Coef(k, i)));
    }
    for (k, h) in m.hysteresis.iter().enumerate() {
        p.extend((0..h.everett.expansion().len()).map(|i| Param::Hyst(k, i)));
    }
    p
}

pub(crate) fn get_params(m: &SparseStateSpace, cols: &[Param]) -> Vec<f64> {
    cols.iter()
        .map(|p| match *p {
            Param::A(i) => m.a[i],
            Param::B(i) => m.b[i],
            Param::C(i) => m.c[i],
            Param::D(i) => m.d[i],
            Param::X0(i) => m.x0[i],
            Param::Offset => m.y_offset,
            Param::Coef(k, i) => m.terms[k].expansion.coefficients()[i].value,
            Param::Hyst(k, i) => m.hysteresis[k].everett.expansion().coefficients()[i].value,
        })
        .collect()
}

pub(crate) fn set_params(m: &mut SparseStateSpace, cols: &[Param], theta: &[f64]) -> Result<()> {
    let mut coef: Vec<Vec<f64>> = m
        .terms
        .iter()
        .map(|t| t.expansion.coefficients().iter().map(|c| c.value).collect())
        .collect();
    let mut hyst: Vec<Vec<f64>> = m
        .hysteresis
        .iter()
        .map(|h| {
            h.everett
                .expansion()
                .coefficients()
                .iter()
                .map(|c| c.value)
                .collect()
        })
        .collect();
    let (mut tc, mut th) = (false, false);
    for (p, &v) in cols.iter().zip(theta) {
        match *p {
            Param::A(i) => m.a[i] = v,
            Param::B(i) => m.b[i] = v,
            Param::C(i) => m.c[i] = v,
            Param::D(i) => m.d[i] = v,
            Param::X0(i) => m.x0[i] = v,
            Param::Offset => m.y_offset = v,
            Param::Coef(k, i) => {
                coef[k][i] = v;
                tc = true;
            }
            Param::Hyst(k, i) => {
                hyst[k][i] = v;
                th = true;
            }
        }
    }
    if tc {
        for (t, v) in m.terms.iter_mut().zip(&coef) {
            t.expansion.set_values(v)?;
        }
    }
    if th {
        for (h, v) in m.hysteresis.iter_mut().zip(&hyst) {
            h.everett.expansion_mut().set_values(v)?;
        }
    }
    Ok(())
}

/// Sum of squared simulation errors from `skip` on (∞ when the simulation diverges).
pub(crate) fn sse(m: &SparseStateSpace, inputs: &[Vec<f64>], y: &[f64], skip: usize) -> f64 {
    match m.simulate(inputs) {
        Ok(yh) => {
            let v: f64 = y[skip..]
                .iter()
                .zip(&yh[skip..])
                .map(|(a, b)| (a - b) * (a - b))
                .sum();
            if v.is_finite() {
                v
            } else {
                f64::INFINITY
            }
        }
        Err(_) => f64::INFINITY,
    }
}

/// Result of one sensitivity pass.
pub(crate) struct SensOut {
    pub sse: f64,
    /// Upper triangle of JᵀJ (row-major q×q) when requested.
    pub jtj: Vec<f64>,
    pub jte: Vec<f64>,
    pub diag: Vec<f64>,
}

/// Hysteresis regressors per term (`N × K_k`), computed once per basis set.
pub(crate) fn hysteresis_regressors(m: &SparseStateSpace, inputs: &[Vec<f64>]) -> Vec<Vec<f64>> {
    m.hysteresis
        .iter()
        .map(|h| h.everett.regressors(&inputs[h.input]))
        .collect()
}

/// Marks a model entry that is not a parameter of the pass.
const NONE: usize = usize::MAX;

/// Column of each model entry in the parameter vector (`NONE` when the
/// entry is held fixed): the inverse of the `cols` list.
struct ParamColumns {
    a: Vec<usize>,
    b: Vec<usize>,
    c: Vec<usize>,
    d: Vec<usize>,
    x0: Vec<usize>,
    offset: usize,
    /// Per nonlinear term, per expansion coefficient.
    coef: Vec<Vec<usize>>,
    /// Per hysteresis term, per Everett coefficient.
    hyst: Vec<Vec<usize>>,
}

impl ParamColumns {
    fn new(m: &SparseStateSpace, cols: &[Param]) -> Self {
        let n = m.n_states;
        let nu = m.n_inputs;
        let mut pc = Self {
            a: vec![NONE; n * n],
            b: vec![NONE; n * nu],
            c: vec![NONE; n],
            d: vec![NONE; nu],
            x0: vec![NONE; n],
            offset: NONE,
            coef: m
                .terms
                .iter()
                .map(|t| vec![NONE; t.expansion.len()])
                .collect(),
            hyst: m
                .hysteresis
                .iter()
                .map(|h| vec![NONE; h.everett.expansion().len()])
                .collect(),
        };
        for (c, p) in cols.iter().enumerate() {
            match *p {
                Param::A(i) => pc.a[i] = c,
                Param::B(i) => pc.b[i] = c,
                Param::C(i) => pc.c[i] = c,
                Param::D(i) => pc.d[i] = c,
                Param::X0(i) => pc.x0[i] = c,
                Param::Offset => pc.offset = c,
                Param::Coef(k, i) => pc.coef[k][i] = c,
                Param::Hyst(k, i) => pc.hyst[k][i] = c,
            }
        }
        pc
    }
}

/// Scratch of one expansion evaluation: basis values, arguments, gradient.
struct TermScratch {
    ev: EvalScratch,
    args: [f64; MAX_DIMS],
    grad: [f64; MAX_DIMS],
}

/// Current sample of a sensitivity pass: time `t`, state `x` (n), its
/// sensitivities `s = ∂x/∂θ` (n×q row-major), input `u`, hysteresis
/// outputs `hk`.
struct SampleState<'a> {
    t: usize,
    x: &'a [f64],
    s: &'a [f64],
    u: &'a [f64],
    hk: &'a [f64],
}

/// One forward-sensitivity simulation: model, parameter columns,
/// hysteresis regressors (`N × K_k` per term), number of parameters q.
struct SensitivityPass<'a> {
    m: &'a SparseStateSpace,
    cols: ParamColumns,
    hreg: &'a [Vec<f64>],
    q: usize,
}

impl SensitivityPass<'_> {
    /// Output ŷ = c·x + d·u + offset + Σ f_k + Σ h_k and its gradient
    /// `jrow = ∂ŷ/∂θ = cᵀS + ∂ŷ/∂θ|_explicit` (chain rule through the
    /// state arguments of the output terms).
    fn output(&self, st: &SampleState, jrow: &mut [f64], sc: &mut TermScratch) -> f64 {
        let (m, pc, q) = (self.m, &self.cols, self.q);
        let (n, nu) = (m.n_states, m.n_inputs);
        let (x, s, u, hk, t) = (st.x, st.s, st.u, st.hk, st.t);
        let mut yh = m.y_offset;
        jrow.fill(0.0);
        for i in 0..n {
            yh += m.c[i] * x[i];
            let ci = m.c[i];
            if ci != 0.0 {
                for (jr, sv) in jrow.iter_mut().zip(&s[i * q..(i + 1) * q]) {
                    *jr += ci * sv;
                }
            }
            if pc.c[i] != NONE {
                jrow[pc.c[i]] += x[i];
            }
        }
        for j in 0..nu {
            yh += m.d[j] * u[j];
            if pc.d[j] != NONE {
                jrow[pc.d[j]] += u[j];
            }
        }
        if pc.offset != NONE {
            jrow[pc.offset] += 1.0;
        }
        for (k, term) in m.terms.iter().enumerate() {
            if term.target != Target::Output {
                continue;
            }
            let d = term.args.len();
            SparseStateSpace::gather(&term.args, x, u, &mut sc.args);
            yh +=
                term.expansion
                    .eval_with(&sc.args[..d], Some(&mut sc.grad[..d]), true, &mut sc.ev);
            for (dd, a) in term.args.iter().enumerate() {
                if let Signal::State(i) = *a {
                    let g = sc.grad[dd];
                    if g != 0.0 {
                        for (jr, sv) in jrow.iter_mut().zip(&s[i * q..(i + 1) * q]) {
                            *jr += g * sv;
                        }
                    }
                }
            }
            for &(ix, v) in &sc.ev.basis {
                let c = pc.coef[k][ix as usize];
                if c != NONE {
                    jrow[c] += v;
                }
            }
        }
        for (k, hy) in m.hysteresis.iter().enumerate() {
            if hy.target == Target::Output {
                yh += hk[k];
                let kk = pc.hyst[k].len();
                for (i, &c) in pc.hyst[k].iter().enumerate() {
                    if c != NONE {
                        jrow[c] += self.hreg[k][t * kk + i];
                    }
                }
            }
        }
        yh
    }

    /// One sub-step x⁺ = A x + B u + Σ f_k + Σ h_k into `xn`, with the
    /// sensitivities S⁺ = A S + ∂x⁺/∂θ|_explicit + Σ ∇f_k S into `sn`.
    fn substep(&self, st: &SampleState, xn: &mut [f64], sn: &mut [f64], sc: &mut TermScratch) {
        let (m, pc, q) = (self.m, &self.cols, self.q);
        let (n, nu) = (m.n_states, m.n_inputs);
        let (x, s, u, hk, t) = (st.x, st.s, st.u, st.hk, st.t);
        for i in 0..n {
            let mut v = 0.0;
            let srow = &mut sn[i * q..(i + 1) * q];
            srow.fill(0.0);
            for j in 0..n {
                let aij = m.a[i * n + j];
                v += aij * x[j];
                if aij != 0.0 {
                    for (o, sv) in srow.iter_mut().zip(&s[j * q..(j + 1) * q]) {
                        *o += aij * sv;
                    }
                }
                let c = pc.a[i * n + j];
                if c != NONE {
                    srow[c] += x[j];
                }
            }
            for j in 0..nu {
                v += m.b[i * nu + j] * u[j];
                let c = pc.b[i * nu + j];
                if c != NONE {
                    srow[c] += u[j];
                }
            }
            xn[i] = v;
        }
        for (k, term) in m.terms.iter().enumerate() {
            let Target::State(i) = term.target else {
                continue;
            };
            let d = term.args.len();
            SparseStateSpace::gather(&term.args, x, u, &mut sc.args);
            xn[i] +=
                term.expansion
                    .eval_with(&sc.args[..d], Some(&mut sc.grad[..d]), true, &mut sc.ev);
            for (dd, a) in term.args.iter().enumerate() {
                if let Signal::State(src) = *a {
                    let g = sc.grad[dd];
                    if g != 0.0 {
                        for c in 0..q {
                            sn[i * q + c] += g * s[src * q + c];
                        }
                    }
                }
            }
            for &(ix, v) in &sc.ev.basis {
                let c = pc.coef[k][ix as usize];
                if c != NONE {
                    sn[i * q + c] += v;
                }
            }
        }
        for (k, hy) in m.hysteresis.iter().enumerate() {
            if let Target::State(i) = hy.target {
                xn[i] += hk[k];
                let kk = pc.hyst[k].len();
                for (ii, &c) in pc.hyst[k].iter().enumerate() {
                    if c != NONE {
                        sn[i * q + c] += self.hreg[k][t * kk + ii];
                    }
                }
            }
        }
    }
}

impl SensOut {
    /// Add one residual e with Jacobian row j: SSE += e², Jᵀe += j e,
    /// diag(JᵀJ) += j², and (when `full`) the upper triangle of JᵀJ += j jᵀ.
    fn accumulate(&mut self, jrow: &[f64], e: f64, full: bool) {
        let q = jrow.len();
        self.sse += e * e;
        for (c, &jv) in jrow.iter().enumerate() {
            self.jte[c] += jv * e;
            self.diag[c] += jv * jv;
        }
        if full {
            for a in 0..q {
                let ja = jrow[a];
                if ja == 0.0 {
                    continue;
                }
                let row = &mut self.jtj[a * q..(a + 1) * q];
                for b in a..q {
                    row[b] += ja * jrow[b];
                }
            }
        }
    }
}

/// Simulation with forward sensitivities for the parameters `cols`.
pub(crate) fn sensitivities(
    m: &SparseStateSpace,
    cols: &[Param],
    inputs: &[Vec<f64>],
    y: &[f64],
    skip: usize,
    full: bool,
    hreg: &[Vec<f64>],
) -> Result<SensOut> {
    let n = m.n_states;
    let nu = m.n_inputs;
    let q = cols.len();
    let len = y.len();
    let pass = SensitivityPass {
        m,
        cols: ParamColumns::new(m, cols),
        hreg,
        q,
    };
    let hout = m.hysteresis_outputs(inputs)?;
    let mut x = m.x0.clone();
    let mut xn = vec![0.0; n];
    let mut s = vec![0.0; n * q];
    let mut sn = vec![0.0; n * q];
    for (i, &c) in pass.cols.x0.iter().enumerate() {
        if c != NONE {
            s[i * q + c] = 1.0;
        }
    }
    let mut jrow = vec![0.0; q];
    let mut out = SensOut {
        sse: 0.0,
        jtj: if full { vec![0.0; q * q] } else { Vec::new() },
        jte: vec![0.0; q],
        diag: vec![0.0; q],
    };
    let mut u = vec![0.0; nu];
    let mut hk = vec![0.0; m.hysteresis.len()];
    let mut sc = TermScratch {
        ev: EvalScratch::default(),
        args: [0.0f64; MAX_DIMS],
        grad: [0.0f64; MAX_DIMS],
    };
    for t in 0..len {
        for j in 0..nu {
            u[j] = inputs[j][t];
        }
        for (k, v) in hk.iter_mut().enumerate() {
            *v = hout[k][t];
        }
        // output and its sensitivity
        let st = SampleState {
            t,
            x: &x,
            s: &s,
            u: &u,
            hk: &hk,
        };
        let yh = pass.output(&st, &mut jrow, &mut sc);
        if t >= skip {
            out.accumulate(&jrow, y[t] - yh, full);
        }
        // state update with sensitivities
        for _ in 0..m.substeps {
            let st = SampleState {
                t,
                x: &x,
                s: &s,
                u: &u,
                hk: &hk,
            };
            pass.substep(&st, &mut xn, &mut sn, &mut sc);
            std::mem::swap(&mut x, &mut xn);
            std::mem::swap(&mut s, &mut sn);
        }
        if !x.iter().all(|v| v.is_finite() && v.abs() < 1e150) {
            return Err(ModelError::Diverged(t));
        }
    }
    Ok(out)
}

/// Options of the output-error identification (validated by [`OeParams::check`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OeParams {
    /// Levenberg–Marquardt iterations per stage.
    pub max_iter: usize,
    /// Relative cost decrease below which LM stops.
    pub tol: f64,
    /// Coarse level `j₀` of the scaling-function grid of empty terms.
    pub coarse_level: i32,
    /// Finest detail level tried (`< j₀`: no refinement).
    pub max_level: i32,
    /// Price of a coefficient in units of σ̂² (`None`: `ln N`, BIC).
    pub penalty: Option<f64>,
    /// At most this many new detail coefficients per level and term.
    pub max_new: usize,
    /// Samples excluded from the cost at the start (transient).
    pub skip: usize,
    /// Hard-threshold coefficients that do not pay after each refit.
    pub prune: bool,
    /// Re-fit the boxes of empty wavelet terms to the range of their
    /// arguments (±25 %) in the simulation of the linear stage.
    #[serde(default)]
    pub adapt_boxes: bool,
    /// Tikhonov weight ρ on the wavelet coefficients: LM minimises
    /// `Σ e² + ρ Σ c²` (output units squared per squared coefficient), which
    /// keeps coefficients that the training data barely determine near 0
    /// (0: off).
    #[serde(default)]
    pub ridge: f64,
}

impl Default for OeParams {
    fn default() -> Self {
        Self {
            max_iter: 30,
            tol: 1e-8,
            coarse_level: 1,
            max_level: 3,
            penalty: None,
            max_new: 24,
            skip: 0,
            prune: true,
            adapt_boxes: false,
            ridge: 0.0,
        }
    }
}

/// Validated [`OeParams`]; [`fit`](OutputError::fit) runs the identification.
#[derive(Debug, Clone, PartialEq)]
pub struct OutputError {
    params: OeParams,
}

impl OeParams {
    /// Defaults: 30 LM iterations, levels 1 → 3, BIC price.
    pub fn new() -> Self {
        Self::default()
    }
    /// Sets the LM iterations per stage.
    pub fn max_iter(mut self, v: usize) -> Self {
        self.max_iter = v;
        self
    }
    /// Sets the coarse level.
    pub fn coarse_level(mut self, v: i32) -> Self {
        self.coarse_level = v;
        self
    }
    /// Sets the finest detail level.
    pub fn max_level(mut self, v: i32) -> Self {
        self.max_level = v;
        self
    }
    /// Sets the price of a coefficient (units of σ̂²).
    pub fn penalty(mut self, v: f64) -> Self {
        self.penalty = Some(v);
        self
    }
    /// Sets the number of leading samples left out of the cost.
    pub fn skip(mut self, v: usize) -> Self {
        self.skip = v;
        self
    }
    /// Sets the number of new coefficients per level and term.
    pub fn max_new(mut self, v: usize) -> Self {
        self.max_new = v;
        self
    }
    /// Sets the Tikhonov weight ρ on the wavelet coefficients.
    pub fn ridge(mut self, v: f64) -> Self {
        self.ridge = v;
        self
    }
    /// Re-fit the boxes of empty terms after the linear stage.
    pub fn adapt_boxes(mut self, yes: bool) -> Self {
        self.adapt_boxes = yes;
        self
    }
    /// Sets the stopping tolerance.
    pub fn tol(mut self, v: f64) -> Self {
        self.tol = v;
        self
    }
    /// Validates the options once.
    pub fn check(self) -> Result<OutputError> {
        if self.max_iter == 0 || !(self.tol.is_finite() && self.tol >= 0.0) {
            return Err(ModelError::InvalidArgument(
                "max_iter must be >= 1 and tol finite >= 0".into(),
            ));
        }
        if !(-10..=12).contains(&self.coarse_level) || self.max_level > 14 {
            return Err(ModelError::InvalidArgument(
                "coarse_level must be in -10..=12 and max_level <= 14".into(),
            ));
        }
        if !(self.ridge.is_finite() && self.ridge >= 0.0) {
            return Err(ModelError::InvalidArgument(
                "ridge must be finite and >= 0".into(),
            ));
        }
        if let Some(p) = self.penalty {
            if !(p.is_finite() && p >= 0.0) {
                return Err(ModelError::InvalidArgument(
                    "penalty must be finite and >= 0".into(),
                ));
            }
        }
        Ok(OutputError { params: self })
    }
}

/// Which identification path produced a model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum IdentificationPath {
    /// Deterministic output-error path.
    OutputError,
    /// Sequential Monte Carlo path.
    Smc,
}

/// One stage of the refinement.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageReport {
    /// `"linear"`, `"coarse j0"` or `"level j"`.
    pub stage: String,
    /// Non-zero wavelet coefficients after the stage.
    pub coefficients: usize,
    /// Training RMSE after the stage.
    pub rmse: f64,
    /// BIC after the stage.
    pub bic: f64,
    /// Whether the stage was kept.
    pub accepted: bool,
}

/// What the output-error identification did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OeReport {
    /// Stages in order.
    pub stages: Vec<StageReport>,
    /// LM iterations in all.
    pub iterations: usize,
    /// Final training RMSE.
    pub rmse: f64,
    /// Gaussian log-likelihood of the training residuals at σ̂ = RMSE.
    pub log_likelihood: f64,
    /// Always [`IdentificationPath::OutputError`].
    pub path: IdentificationPath,
}

/// Boxes of the empty wavelet terms fitted to the free-run trajectory: per
/// argument, the range [l, h] of the simulated states (or inputs) widened by
/// a quarter span on each side (the old box where the span is 0 or not
/// finite).
fn boxes_around_trajectory(
    m: &mut SparseStateSpace,
    inputs: &[Vec<f64>],
    len: usize,
) -> Result<()> {
    let (_, xs) = m.simulate_states(inputs)?;
    let n = m.n_states;
    for t in m.terms.iter_mut() {
        if !t.expansion.is_empty() {
            continue;
        }
        let mut lo = Vec::new();
        let mut hi = Vec::new();
        for (d, a) in t.args.iter().enumerate() {
            let (mut l, mut h) = (f64::MAX, f64::MIN);
            for k in 0..len {
                let v = match *a {
                    Signal::State(i) => xs[k * n + i],
                    Signal::Input(j) => inputs[j][k],
                };
                l = l.min(v);
                h = h.max(v);
            }
            let span = h - l;
            if span > 0.0 && span.is_finite() {
                lo.push(l - 0.25 * span);
                hi.push(h + 0.25 * span);
            } else {
                lo.push(t.expansion.lo()[d]);
                hi.push(t.expansion.hi()[d]);
            }
        }
        let w = t.expansion.wavelet().to_string();
        t.expansion = crate::basis::SparseExpansion::new(&w, lo, hi)?;
    }
    Ok(())
}

struct Ctx<'a, 'o> {
    inputs: &'a [Vec<f64>],
    y: &'a [f64],
    skip: usize,
    obs: &'o dyn Observer,
    done: usize,
    total: usize,
    iterations: usize,
}

/// The output-error cost of one stage as a least-squares problem for the
/// workspace's Levenberg–Marquardt solver: the cost is a free-run
/// simulation, the linearisation the forward-sensitivity pass, and the
/// ridge on the wavelet coefficients a Tikhonov penalty.
struct OeProblem<'m, 'c, 'a> {
    m: &'m mut SparseStateSpace,
    cols: &'c [Param],
    inputs: &'a [Vec<f64>],
    y: &'a [f64],
    skip: usize,
    hreg: Vec<Vec<f64>>,
    /// ρ on the wavelet-coefficient columns, 0 elsewhere.
    ridge: Vec<f64>,
    rho: f64,
    /// The parameters `m` holds now.
    installed: Vec<f64>,
    /// The lowest cost evaluated so far: (θ, SSE, SSE + penalty). The solver
    /// only accepts steps that lower the cost, so this is its current point.
    best: Option<(Vec<f64>, f64, f64)>,
    /// The first error of a sensitivity pass or a parameter update.
    error: Option<ModelError>,
}

fn same(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

impl OeProblem<'_, '_, '_> {
    fn penalty(&self, theta: &[f64]) -> f64 {
        if self.rho == 0.0 {
            return 0.0;
        }
        self.rho
            * theta
                .iter()
                .zip(&self.ridge)
                .filter(|(_, r)| **r != 0.0)
                .map(|(v, _)| v * v)
                .sum::<f64>()
    }

    fn install(&mut self, theta: &[f64]) -> bool {
        if same(&self.installed, theta) {
            return true;
        }
        match set_params(self.m, self.cols, theta) {
            Ok(()) => {
                self.installed.clear();
                self.installed.extend_from_slice(theta);
                true
            }
            Err(e) => {
                self.error.get_or_insert(e);
                false
            }
        }
    }

    /// `(SSE, SSE + penalty)` at θ (SSE = ∞ when the simulation diverges).
    fn evaluate(&mut self, theta: &[f64]) -> Option<(f64, f64)> {
        if let Some((t, e, c)) = &self.best {
            if same(t, theta) {
                return Some((*e, *c));
            }
        }
        if !self.install(theta) {
            return None;
        }
        let e = sse(self.m, self.inputs, self.y, self.skip);
        let c = e + self.penalty(theta);
        if c.is_finite() && self.best.as_ref().is_none_or(|b| c < b.2) {
            self.best = Some((theta.to_vec(), e, c));
        }
        Some((e, c))
    }
}

impl LeastSquaresProblem for OeProblem<'_, '_, '_> {
    fn n_params(&self) -> usize {
        self.cols.len()
    }
    fn cost(&mut self, theta: &[f64]) -> Option<f64> {
        self.evaluate(theta)
            .map(|(_, c)| c)
            .filter(|c| c.is_finite())
    }
    fn linearize(&mut self, theta: &[f64], gram: &mut [f64], grad: &mut [f64]) -> Option<f64> {
        let cost = self.cost(theta)?;
        if !self.install(theta) {
            return None;
        }
        let so = match sensitivities(
            self.m,
            self.cols,
            self.inputs,
            self.y,
            self.skip,
            true,
            &self.hreg,
        ) {
            Ok(so) => so,
            Err(e) => {
                self.error.get_or_insert(e);
                return None;
            }
        };
        let q = self.cols.len();
        for a in 0..q {
            for b in a..q {
                let v = so.jtj[a * q + b];
                gram[a * q + b] = v;
                gram[b * q + a] = v;
            }
        }
        grad.copy_from_slice(&so.jte);
        Some(cost)
    }
    fn tikhonov(&self) -> Option<&[f64]> {
        (self.rho != 0.0).then_some(&self.ridge[..])
    }
}

/// Reports every solver iteration of a stage as progress of the whole fit
/// (`done` counts iterations, capped below `total`) and passes it on.
struct StageProgress<'a> {
    outer: &'a dyn Observer,
    stage: &'a str,
    done: AtomicUsize,
    total: usize,
    n_eff: f64,
}

impl Observer for StageProgress<'_> {
    fn progress(&self, done: usize, total: usize, message: &str) {
        self.outer.progress(done, total, message);
    }
    fn iteration(&self, info: &IterationInfo) {
        let done = (self.done.load(Ordering::Relaxed) + 1).min(self.total.saturating_sub(1));
        self.done.store(done, Ordering::Relaxed);
        let msg = format!(
            "{}: rmse {:.3e}",
            self.stage,
            (info.cost / self.n_eff).sqrt()
        );
        self.outer.progress(done, self.total, &msg);
        self.outer.iteration(info);
    }
}

impl OutputError {
    /// The options.
    pub fn params(&self) -> &OeParams {
        &self.params
    }

    /// The Levenberg–Marquardt settings of a stage: λ from 1e-3, ×4 after a
    /// rejected step (×10 when the damped system is singular), ÷3 after an
    /// accepted one (≥ 1e-12), 12 trials, damping
    /// `λ·max(Gᵢᵢ, 1e-10·max G) + 1e-14·max G`.
    fn lm_params(&self) -> LmParams {
        LmParams {
            max_iter: self.params.max_iter,
            tol: self.params.tol,
            lambda_init: 1e-3,
            lambda_up: 4.0,
            lambda_up_singular: 10.0,
            lambda_down: 1.0 / 3.0,
            lambda_min: 1e-12,
            lambda_max: f64::MAX,
            max_trials: 12,
            diag_floor: 1e-10,
            diag_add: 0.0,
            jitter: 1e-14,
            diag_floor_abs: 0.0,
            jitter_abs: 0.0,
            stall_window: 0,
            stall_tol: 0.0,
            ..LmParams::default()
        }
    }

    /// Levenberg–Marquardt on the parameters `cols` of `m` (left at the
    /// result); returns the SSE (without the ridge penalty).
    fn lm(
        &self,
        m: &mut SparseStateSpace,
        cols: &[Param],
        ctx: &mut Ctx,
        stage: &str,
    ) -> Result<f64> {
        let theta0 = get_params(m, cols);
        let rho = self.params.ridge;
        let ridge: Vec<f64> = cols
            .iter()
            .map(|c| {
                if matches!(c, Param::Coef(..)) {
                    rho
                } else {
                    0.0
                }
            })
            .collect();
        let hreg = if cols.is_empty() {
            Vec::new()
        } else {
            hysteresis_regressors(m, ctx.inputs)
        };
        let mut problem = OeProblem {
            m,
            cols,
            inputs: ctx.inputs,
            y: ctx.y,
            skip: ctx.skip,
            hreg,
            ridge,
            rho,
            installed: theta0.clone(),
            best: None,
            error: None,
        };
        let Some((sse0, _)) = problem.evaluate(&theta0).filter(|(_, c)| c.is_finite()) else {
            return Err(ModelError::Diverged(0));
        };
        if cols.is_empty() {
            return Ok(sse0);
        }
        let solver = self.lm_params().check()?;
        let progress = StageProgress {
            outer: ctx.obs,
            stage,
            done: AtomicUsize::new(ctx.done),
            total: ctx.total,
            n_eff: (ctx.y.len() - ctx.skip) as f64,
        };
        let state = solver.minimize(&mut problem, &theta0, &progress)?;
        ctx.done = progress.done.load(Ordering::Relaxed);
        ctx.iterations += state.iterations;
        if let Some(e) = problem.error.take() {
            return Err(e);
        }
        let sse = match &problem.best {
            Some((t, e, _)) if same(t, &state.theta) => *e,
            _ => problem
                .evaluate(&state.theta)
                .map_or(f64::INFINITY, |v| v.0),
        };
        if !problem.install(&state.theta) {
            return Err(problem.error.take().unwrap_or(ModelError::Diverged(0)));
        }
        Ok(sse)
    }

    fn n_eff(&self, ctx: &Ctx) -> f64 {
        (ctx.y.len() - ctx.skip) as f64
    }

    fn bic(&self, m: &SparseStateSpace, cost: f64, ctx: &Ctx) -> f64 {
        let n = self.n_eff(ctx);
        let p = (layout(m).len() - count_zero_coefficients(m)) as f64;
        n * (cost / n).max(1e-300).ln() + p * n.ln()
    }

    fn penalty(&self, ctx: &Ctx) -> f64 {
        self.params.penalty.unwrap_or_else(|| self.n_eff(ctx).ln())
    }

    /// Hard thresholding of coefficients that do not pay; returns how many were removed.
    fn prune(&self, m: &mut SparseStateSpace, cost: f64, ctx: &Ctx) -> Result<usize> {
        let cols = layout(m);
        let hreg = hysteresis_regressors(m, ctx.inputs);
        let so = sensitivities(m, &cols, ctx.inputs, ctx.y, ctx.skip, false, &hreg)?;
        let sigma2 = cost / self.n_eff(ctx);
        let price = self.penalty(ctx) * sigma2;
        let theta = get_params(m, &cols);
        let mut drop_coef: Vec<Vec<bool>> = m
            .terms
            .iter()
            .map(|t| vec![false; t.expansion.len()])
            .collect();
        let mut drop_hyst: Vec<Vec<bool>> = m
            .hysteresis
            .iter()
            .map(|h| vec![false; h.everett.expansion().len()])
            .collect();
        let mut removed = 0;
        for (c, p) in cols.iter().enumerate() {
            let worth = theta[c] * theta[c] * so.diag[c];
            let zero = worth < price;
            match *p {
                Param::Coef(k, i) if zero => {
                    drop_coef[k][i] = true;
                    removed += 1;
                }
                Param::Hyst(k, i) if zero => {
                    drop_hyst[k][i] = true;
                    removed += 1;
                }
                _ => {}
            }
        }
        for (t, d) in m.terms.iter_mut().zip(&drop_coef) {
            t.expansion.retain(|i, _| !d[i]);
        }
        for (h, d) in m.hysteresis.iter_mut().zip(&drop_hyst) {
            h.everett.expansion_mut().retain(|i, _| !d[i]);
        }
        Ok(removed)
    }

    /// Identifies `start` (its structure, fixed entries and terms) on the
    /// record `inputs → y` by output error with coarse-to-fine sparse
    /// refinement; see the module docs. Empty wavelet terms get the coarse
    /// grid of level `j₀` first.
    ///
    /// ```
    /// use gb_model::{OeParams, SparseStateSpace, Silent};
    /// // true system x+ = 0.8 x + 0.5 u, y = x; start from a wrong linear model
    /// let u: Vec<f64> = (0..300).map(|t| ((t * 7919) % 23) as f64 / 11.0 - 1.0).collect();
    /// let truth = SparseStateSpace::linear(vec![0.8], vec![0.5], vec![1.0], vec![0.0])?;
    /// let y = truth.simulate(&[u.clone()])?;
    /// let mut start = SparseStateSpace::linear(vec![0.5], vec![1.0], vec![1.0], vec![0.0])?;
    /// start.structure.c = vec![false];
    /// start.structure.d = vec![false];
    /// let (m, report) = OeParams::new().check()?.fit(start, &[u], &y, &Silent)?;
    /// assert!((m.a[0] - 0.8).abs() < 1e-6 && report.rmse < 1e-8);
    /// # Ok::<(), gb_model::ModelError>(())
    /// ```
    pub fn fit(
        &self,
        start: SparseStateSpace,
        inputs: &[Vec<f64>],
        y: &[f64],
        obs: &dyn Observer,
    ) -> Result<(SparseStateSpace, OeReport)> {
        let len = self.checked_record_length(&start, inputs, y)?;
        let p = &self.params;
        let levels = (p.max_level - p.coarse_level + 1).max(0) as usize;
        let mut ctx = Ctx {
            inputs,
            y,
            skip: p.skip,
            obs,
            done: 0,
            total: p.max_iter * (3 + levels),
            iterations: 0,
        };
        let mut m = start;
        let mut stages = Vec::new();
        let nonlinear = !m.terms.is_empty() || !m.hysteresis.is_empty();
        // 1. the linear part alone
        let lin_cols: Vec<Param> = layout(&m)
            .into_iter()
            .filter(|p| !matches!(p, Param::Coef(..) | Param::Hyst(..)))
            .collect();
        let mut cost = self.lm(&mut m, &lin_cols, &mut ctx, "linear")?;
        let n_eff = self.n_eff(&ctx);
        stages.push(StageReport {
            stage: "linear".into(),
            coefficients: m.n_coefficients(),
            rmse: (cost / n_eff).sqrt(),
            bic: self.bic(&m, cost, &ctx),
            accepted: true,
        });
        if nonlinear && p.adapt_boxes {
            boxes_around_trajectory(&mut m, inputs, len)?;
        }
        if nonlinear {
            let best_bic;
            (cost, best_bic) = self.coarse_stage(&mut m, &mut ctx, &mut stages)?;
            cost = self.refine_levels(&mut m, cost, best_bic, &mut ctx, &mut stages)?;
            for t in m.terms.iter_mut() {
                t.expansion.drop_zeros();
            }
            for h in m.hysteresis.iter_mut() {
                h.everett.expansion_mut().drop_zeros();
            }
        }
        let rmse = (cost / n_eff).sqrt();
        m.measurement_noise = crate::model::NoiseModel::Gaussian { sd: rmse };
        let log_likelihood =
            -0.5 * n_eff * ((2.0 * std::f64::consts::PI * rmse * rmse).max(1e-300).ln() + 1.0);
        ctx.obs.progress(ctx.total, ctx.total, "done");
        Ok((
            m,
            OeReport {
                stages,
                iterations: ctx.iterations,
                rmse,
                log_likelihood,
                path: IdentificationPath::OutputError,
            },
        ))
    }

    /// Checks the model and the record (matching lengths, finite samples,
    /// at least `skip + 10` samples); returns the record length.
    fn checked_record_length(
        &self,
        start: &SparseStateSpace,
        inputs: &[Vec<f64>],
        y: &[f64],
    ) -> Result<usize> {
        start.check()?;
        let len = start.check_inputs(inputs)?;
        if len != y.len() {
            return Err(ModelError::Dimension(format!(
                "{len} input samples, {} output samples",
                y.len()
            )));
        }
        if y.iter().any(|v| !v.is_finite()) || inputs.iter().flatten().any(|v| !v.is_finite()) {
            return Err(ModelError::InvalidArgument("data must be finite".into()));
        }
        let p = &self.params;
        if len < p.skip + 10 {
            return Err(ModelError::InvalidArgument(format!(
                "{len} samples are too few (skip {})",
                p.skip
            )));
        }
        Ok(len)
    }

    /// Stage 2: the coarse grid of level `j₀` in every empty term, fitted
    /// (and thresholded and refitted when pruning). Returns the cost and
    /// its BIC.
    fn coarse_stage(
        &self,
        m: &mut SparseStateSpace,
        ctx: &mut Ctx,
        stages: &mut Vec<StageReport>,
    ) -> Result<(f64, f64)> {
        let p = &self.params;
        for t in m.terms.iter_mut() {
            if t.expansion.is_empty() {
                t.expansion.add_coarse_grid(p.coarse_level)?;
            }
        }
        for h in m.hysteresis.iter_mut() {
            if h.everett.expansion().is_empty() {
                h.everett.expansion_mut().add_coarse_grid(p.coarse_level)?;
            }
        }
        let cols = layout(m);
        let mut cost = self.lm(m, &cols, ctx, "coarse")?;
        if p.prune && self.prune(m, cost, ctx)? > 0 {
            let cols = layout(m);
            cost = self.lm(m, &cols, ctx, "coarse, thresholded")?;
        }
        let best_bic = self.bic(m, cost, ctx);
        stages.push(StageReport {
            stage: format!("coarse j0={}", p.coarse_level),
            coefficients: m.n_coefficients(),
            rmse: (cost / self.n_eff(ctx)).sqrt(),
            bic: best_bic,
            accepted: true,
        });
        Ok((cost, best_bic))
    }

    /// Stage 3: refinement from coarse to fine; each level adds the detail
    /// candidates that pay, refits (and prunes), and is kept only while the
    /// BIC falls (else the model before it is restored and refinement
    /// stops). Returns the cost of the kept model.
    fn refine_levels(
        &self,
        m: &mut SparseStateSpace,
        mut cost: f64,
        mut best_bic: f64,
        ctx: &mut Ctx,
        stages: &mut Vec<StageReport>,
    ) -> Result<f64> {
        let p = &self.params;
        let n_eff = self.n_eff(ctx);
        for level in p.coarse_level..=p.max_level {
            let before = m.clone();
            let before_cost = cost;
            let added = self.add_candidates(m, level, cost, ctx)?;
            if added == 0 {
                stages.push(StageReport {
                    stage: format!("level {level}"),
                    coefficients: m.n_coefficients(),
                    rmse: (cost / n_eff).sqrt(),
                    bic: best_bic,
                    accepted: false,
                });
                break;
            }
            let cols = layout(m);
            let stage = format!("level {level}");
            cost = self.lm(m, &cols, ctx, &stage).unwrap_or(f64::INFINITY);
            if cost.is_finite() && p.prune && self.prune(m, cost, ctx)? > 0 {
                let cols = layout(m);
                cost = self.lm(m, &cols, ctx, &stage).unwrap_or(f64::INFINITY);
            }
            let bic = if cost.is_finite() {
                self.bic(m, cost, ctx)
            } else {
                f64::INFINITY
            };
            let accepted = bic < best_bic;
            stages.push(StageReport {
                stage,
                coefficients: m.n_coefficients(),
                rmse: (cost / n_eff).sqrt(),
                bic,
                accepted,
            });
            if !accepted {
                *m = before;
                cost = before_cost;
                break;
            }
            best_bic = bic;
        }
        Ok(cost)
    }

    /// Scores the detail candidates of `level` and keeps those that pay.
    fn add_candidates(
        &self,
        m: &mut SparseStateSpace,
        level: i32,
        cost: f64,
        ctx: &mut Ctx,
    ) -> Result<usize> {
        let base_terms: Vec<usize> = m.terms.iter().map(|t| t.expansion.len()).collect();
        let base_hyst: Vec<usize> = m
            .hysteresis
            .iter()
            .map(|h| h.everett.expansion().len())
            .collect();
        let mut cand = m.clone();
        for t in cand.terms.iter_mut() {
            let c = t.expansion.detail_candidates(level);
            t.expansion.extend_unchecked(c);
        }
        for h in cand.hysteresis.iter_mut() {
            let c = h.everett.expansion().detail_candidates(level);
            h.everett.expansion_mut().extend_unchecked(c);
        }
        let cols: Vec<Param> = layout(&cand)
            .into_iter()
            .filter(|p| match *p {
                Param::Coef(k, i) => i >= base_terms[k],
                Param::Hyst(k, i) => i >= base_hyst[k],
                _ => false,
            })
            .collect();
        if cols.is_empty() {
            return Ok(0);
        }
        ctx.obs.progress(
            ctx.done,
            ctx.total,
            &format!("level {level}: scoring {} candidates", cols.len()),
        );
        let hreg = hysteresis_regressors(&cand, ctx.inputs);
        let so = sensitivities(&cand, &cols, ctx.inputs, ctx.y, ctx.skip, false, &hreg)?;
        let price = self.penalty(ctx) * cost / self.n_eff(ctx);
        // per term: candidates sorted by score
        let mut keep_t: Vec<Vec<bool>> = cand
            .terms
            .iter()
            .map(|t| vec![true; t.expansion.len()])
            .collect();
        let mut keep_h: Vec<Vec<bool>> = cand
            .hysteresis
            .iter()
            .map(|h| vec![true; h.everett.expansion().len()])
            .collect();
        let mut scored: Vec<(f64, Param)> = Vec::new();
        for (c, p) in cols.iter().enumerate() {
            let score = if so.diag[c] > 0.0 {
                so.jte[c] * so.jte[c] / so.diag[c]
            } else {
                0.0
            };
            match *p {
                Param::Coef(k, i) => keep_t[k][i] = false,
                Param::Hyst(k, i) => keep_h[k][i] = false,
                _ => {}
            }
            if score > price {
                scored.push((score, *p));
            }
        }
        scored.sort_by(|a, b| b.0.total_cmp(&a.0));
        let mut per_t = vec![0usize; keep_t.len()];
        let mut per_h = vec![0usize; keep_h.len()];
        let mut added = 0;
        for (_, p) in scored {
            match p {
                Param::Coef(k, i) if per_t[k] < self.params.max_new => {
                    keep_t[k][i] = true;
                    per_t[k] += 1;
                    added += 1;
                }
                Param::Hyst(k, i) if per_h[k] < self.params.max_new => {
                    keep_h[k][i] = true;
                    per_h[k] += 1;
                    added += 1;
                }
                _ => {}
            }
        }
        for (t, k) in cand.terms.iter_mut().zip(&keep_t) {
            t.expansion.retain(|i, _| k[i]);
        }
        for (h, k) in cand.hysteresis.iter_mut().zip(&keep_h) {
            h.everett.expansion_mut().retain(|i, _| k[i]);
        }
        *m = cand;
        Ok(added)
    }
}

fn count_zero_coefficients(m: &SparseStateSpace) -> usize {
    m.terms
        .iter()
        .map(|t| t.expansion.len() - t.expansion.nnz())
        .sum::<usize>()
        + m.hysteresis
            .iter()
            .map(|h| h.everett.expansion().len() - h.everett.expansion().nnz())
            .sum::<usize>()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::basis::SparseExpansion;
    use crate::model::NonlinearTerm;

    fn model_with_term() -> SparseStateSpace {
        let mut m = SparseStateSpace::linear(
            vec![0.9, 0.1, -0.2, 0.7],
            vec![0.0, 0.5],
            vec![1.0, 0.0],
            vec![0.0],
        )
        .unwrap();
        m.substeps = 2;
        let mut e = SparseExpansion::new("bior2.2", vec![-2.0, -2.0], vec![2.0, 2.0]).unwrap();
        e.add_coarse_grid(1).unwrap();
        let n = e.len();
        e.set_values(&(0..n).map(|i| 0.01 * (i as f64 - 4.0)).collect::<Vec<_>>())
            .unwrap();
        m.terms.push(NonlinearTerm {
            target: Target::State(1),
            args: vec![Signal::State(0), Signal::Input(0)],
            expansion: e,
        });
        let mut g = SparseExpansion::new("db2", vec![-2.0], vec![2.0]).unwrap();
        g.add_coarse_grid(1).unwrap();
        let n = g.len();
        g.set_values(&(0..n).map(|i| 0.02 * i as f64).collect::<Vec<_>>())
            .unwrap();
        m.terms.push(NonlinearTerm {
            target: Target::Output,
            args: vec![Signal::State(1)],
            expansion: g,
        });
        m.structure.x0 = vec![true, true];
        m.structure.y_offset = true;
        m
    }

    #[test]
    fn sensitivities_match_finite_differences() {
        let m = model_with_term();
        let u: Vec<Vec<f64>> = vec![(0..200).map(|t| (t as f64 * 0.37).sin() * 1.5).collect()];
        let y: Vec<f64> = (0..200).map(|t| (t as f64 * 0.1).cos()).collect();
        let cols = layout(&m);
        let so = sensitivities(&m, &cols, &u, &y, 5, true, &[]).unwrap();
        let theta = get_params(&m, &cols);
        for c in 0..cols.len() {
            let h = 1e-6;
            let mut mp = m.clone();
            let mut tp = theta.clone();
            tp[c] += h;
            set_params(&mut mp, &cols, &tp).unwrap();
            let sp = sse(&mp, &u, &y, 5);
            tp[c] -= 2.0 * h;
            set_params(&mut mp, &cols, &tp).unwrap();
            let sm = sse(&mp, &u, &y, 5);
            // d(sse)/dθ = −2 Jᵀe
            let fd = (sp - sm) / (2.0 * h);
            let an = -2.0 * so.jte[c];
            assert!(
                (fd - an).abs() < 1e-4 * (1.0 + an.abs()),
                "param {c} {:?}: fd {fd} vs analytic {an}",
                cols[c]
            );
        }
    }
}
