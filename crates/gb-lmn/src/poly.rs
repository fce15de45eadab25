//! Polynomial NARX / NOE models (the model class of SysIdentPy; Billings,
//! *Nonlinear System Identification: NARMAX Methods*, 2013):
//!
//! ```text
//! ŷ(k) = Σₜ θₜ Π_{r ∈ t} xᵣ(k),
//! x(k) = [y(k−1) … y(k−n_a), u_j(k−n_k,j) … u_j(k−n_k,j−n_b,j+1)]
//! ```
//!
//! a polynomial of degree ≤ 3 in lagged outputs and inputs, each signal
//! normalised to zero mean and unit variance over the training data (the
//! parameters live in those units). In simulation (NOE) the lagged outputs
//! are the model's own.
//!
//! Identification ([`PolyParams`] → [`ValidPolyParams`], which implements
//! [`gb_core::Identify`]):
//!
//! 1. every monomial of degree ≤ `degree` in the regressors is a candidate
//!    term; the terms are ordered by forward orthogonal least squares on the
//!    error reduction ratio (FROLS, Billings, Chen & Korenberg 1989) of the
//!    one-step (NARX) regression on the first `1 − holdout` of every record;
//! 2. every prefix of that order (1 … `max_terms` terms) is simulated in free
//!    run on the held-out rest of every record; with simulation focus the
//!    three best prefixes are refined for the simulation error and compared
//!    again on the hold-out, the smallest within 1 % of the best is kept;
//! 3. with simulation focus the chosen terms are refined on all the data by
//!    the one Levenberg–Marquardt solver ([`gb_core::solver`]) on the
//!    simulation error, with output sensitivities propagated through the
//!    lagged outputs.
//!
//! | field | default | meaning |
//! |---|---|---|
//! | `na` | 2 | output lags 1..=n_a |
//! | `nb` | n_a per input | input lags per input |
//! | `nk` | 1 per input | dead time per input (0: direct feedthrough) |
//! | `degree` | 3 | highest degree of a term (1..=3) |
//! | `max_terms` | 15 | most terms |
//! | `focus` | simulation | [`Focus::Simulation`]: NOE refinement; [`Focus::Prediction`]: least squares only |
//! | `holdout` | 0.25 | fraction of every record held out to choose the number of terms |
//! | `lm_iterations` | 40 | Levenberg–Marquardt iterations of each refinement |
//!
//! ```
//! use gb_core::{Identify, Record, Records, Silent, DynamicModel, Init};
//! use gb_lmn::poly::PolyParams;
//! // y(k) = 0.5 y(k−1) + u(k−1) + 0.3 u(k−1)²
//! let u: Vec<f64> = (0..600).map(|k| ((k * 7919) % 13) as f64 / 6.0 - 1.0).collect();
//! let mut y = vec![0.0; 600];
//! for k in 1..600 { y[k] = 0.5 * y[k - 1] + u[k - 1] + 0.3 * u[k - 1] * u[k - 1]; }
//! let rec = Record::new(vec!["u".into()], "y".into(), vec![u.clone()], y.clone()).unwrap();
//! let m = PolyParams::new(1).degree(2).check().unwrap()
//!     .identify(&Records::single(rec), &Silent).unwrap();
//! let sim = m.simulate(&[u], Init::History(&y[..1])).unwrap();
//! assert!(gb_core::metrics::nrmse(&y, &sim).unwrap() < 1e-6);
//! ```
use crate::{Focus, LmnError, Scaling, Signal, Tap};
use gb_core::gram::{add_gram, mirror_upper};
use gb_core::solver::{LeastSquaresProblem, LmParams};
use gb_core::{
    check_inputs, CoreError, DynamicModel, FittedModel, Identify, Init, ModelSpec, ModelView,
    NoiseModel, Observer, Records, Stepper, ViewData, Workspace,
};
use serde::{Deserialize, Serialize};
use std::any::Any;

/// Bound on |ŷ| (normalised units) beyond which a simulation has diverged.
const DIVERGED: f64 = 1e3;
/// Most candidate terms (memory of the FROLS regression matrix).
const MAX_CANDIDATES: usize = 2000;

/// A fitted polynomial NARX / NOE model (see the module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PolyNarx {
    /// The regressors: lagged output and inputs.
    pub regressors: Vec<Tap>,
    /// The terms: each the (sorted) regressor indices of a monomial, with
    /// repetition (`[]` the constant, `[0, 0, 2]` = x₀² x₂).
    pub terms: Vec<Vec<u16>>,
    /// Coefficients, one per term (normalised units).
    pub theta: Vec<f64>,
    /// Normalisation of the output.
    pub output_scaling: Scaling,
    /// Normalisation of each input.
    pub input_scaling: Vec<Scaling>,
}

impl PolyNarx {
    /// Largest lag of any regressor (samples taken from the history).
    pub fn max_lag(&self) -> usize {
        self.regressors.iter().map(|t| t.delay).max().unwrap_or(0)
    }

    /// Number of inputs.
    pub fn n_inputs(&self) -> usize {
        self.input_scaling.len()
    }

    /// The terms in words, e.g. `y(k-1)*u(k-1)`.
    pub fn term_names(&self, output: &str, inputs: &[String]) -> Vec<String> {
        let reg = |t: &Tap| match t.signal {
            Signal::Output => format!("{output}(k-{})", t.delay),
            Signal::Input(j) => {
                let name = inputs
                    .get(j)
                    .cloned()
                    .unwrap_or_else(|| format!("u{}", j + 1));
                if t.delay == 0 {
                    format!("{name}(k)")
                } else {
                    format!("{name}(k-{})", t.delay)
                }
            }
        };
        self.terms
            .iter()
            .map(|t| {
                if t.is_empty() {
                    "1".to_string()
                } else {
                    t.iter()
                        .map(|&r| reg(&self.regressors[r as usize]))
                        .collect::<Vec<_>>()
                        .join("*")
                }
            })
            .collect()
    }

    /// Whether some term reads input `j` (at any lag).
    pub fn reads_input(&self, j: usize) -> bool {
        self.terms.iter().flatten().any(|&r| {
            self.regressors
                .get(r as usize)
                .is_some_and(|t| t.signal == Signal::Input(j))
        })
    }

    /// Sizes, indices, finiteness.
    pub fn check_consistency(&self) -> Result<(), LmnError> {
        let bad = |m: &str| Err(LmnError::InvalidArgument(format!("polynomial model: {m}")));
        let nr = self.regressors.len();
        if self.terms.len() != self.theta.len() || self.terms.is_empty() {
            return bad("one coefficient per term, at least one term");
        }
        if self
            .terms
            .iter()
            .any(|t| t.len() > 3 || t.iter().any(|&r| r as usize >= nr))
        {
            return bad("a term of degree above 3 or naming no regressor");
        }
        for t in &self.regressors {
            let ok = match t.signal {
                Signal::Output => t.delay >= 1,
                Signal::Input(j) => j < self.n_inputs(),
            };
            if !ok || t.delay > 1024 {
                return bad("a regressor lag out of range");
            }
        }
        let scalings = self.input_scaling.iter().chain([&self.output_scaling]);
        let sc_ok = scalings
            .clone()
            .all(|s| s.offset.is_finite() && s.scale.is_finite() && s.scale > 0.0);
        if !sc_ok || !self.theta.iter().all(|v| v.is_finite()) {
            return bad("non-finite coefficients or scalings");
        }
        Ok(())
    }

    /// Decode a model-file body of class `poly-narx` (checked).
    pub fn decode(body: &[u8], version: u32) -> Result<Self, CoreError> {
        let m: Self = gb_core::decode_postcard("poly-narx", version, 1, body)?;
        m.check_consistency()
            .map_err(|e| CoreError::ModelFile(format!("inconsistent 'poly-narx' model ({e})")))?;
        Ok(m)
    }

    /// Free-run simulation in physical units; the first `max_lag` outputs
    /// are `history` (padded with the training mean).
    pub fn simulate_signals(&self, u: &[Vec<f64>], history: &[f64]) -> Result<Vec<f64>, LmnError> {
        let n = u.first().map_or(0, Vec::len);
        let un = Scaling::normalise_all(&self.input_scaling, u);
        let k0 = self.max_lag().min(n);
        let sc = self.output_scaling;
        let mut y: Vec<f64> = (0..n)
            .map(|k| {
                history
                    .get(k)
                    .filter(|_| k < k0)
                    .map_or(0.0, |&v| sc.to_norm(v))
            })
            .collect();
        let s = Structure::of(self);
        if !s.simulate(&self.theta, &un, &mut y, k0, None) {
            return Err(LmnError::Unstable(
                "the simulation diverged on these inputs".into(),
            ));
        }
        Ok(y.into_iter().map(|v| sc.from_norm(v)).collect())
    }
}

/// The compiled structure: regressor taps and terms for fast evaluation.
struct Structure {
    taps: Vec<Tap>,
    terms: Vec<Vec<usize>>,
    /// (regressor index, delay) of the output regressors.
    out_regs: Vec<(usize, usize)>,
}

impl Structure {
    fn of(m: &PolyNarx) -> Self {
        Self::new(&m.regressors, &m.terms)
    }

    fn new(taps: &[Tap], terms: &[Vec<u16>]) -> Self {
        let out_regs = taps
            .iter()
            .enumerate()
            .filter(|(_, t)| t.signal == Signal::Output)
            .map(|(i, t)| (i, t.delay))
            .collect();
        Self {
            taps: taps.to_vec(),
            terms: terms
                .iter()
                .map(|t| t.iter().map(|&r| r as usize).collect())
                .collect(),
            out_regs,
        }
    }

    fn max_lag(&self) -> usize {
        self.taps.iter().map(|t| t.delay).max().unwrap_or(0)
    }

    /// Regressors at sample k (`k ≥ max_lag`) from outputs `y` and inputs `u`.
    fn fill(&self, k: usize, y: &[f64], u: &[Vec<f64>], x: &mut [f64]) {
        for (xi, t) in x.iter_mut().zip(&self.taps) {
            *xi = match t.signal {
                Signal::Output => y[k - t.delay],
                Signal::Input(j) => u[j][k - t.delay],
            };
        }
    }

    /// Values of the terms at regressors `x`.
    fn monomials(&self, x: &[f64], m: &mut [f64]) {
        for (mi, t) in m.iter_mut().zip(&self.terms) {
            *mi = t.iter().map(|&r| x[r]).product();
        }
    }

    /// ∂ŷ/∂xᵣ for every output regressor r (into `g`, one per `out_regs`).
    fn output_gradient(&self, theta: &[f64], x: &[f64], g: &mut [f64]) {
        g.fill(0.0);
        for (t, th) in self.terms.iter().zip(theta) {
            for (p, &r) in t.iter().enumerate() {
                let Some(o) = self.out_regs.iter().position(|&(i, _)| i == r) else {
                    continue;
                };
                let others: f64 = t
                    .iter()
                    .enumerate()
                    .filter(|&(q, _)| q != p)
                    .map(|(_, &s)| x[s])
                    .product();
                g[o] += th * others;
            }
        }
    }

    /// Free-run simulation (normalised) from `k0` on; `y[..k0]` is the
    /// history. With `sens`, also the sensitivities ∂ŷ(k)/∂θ (row-major
    /// n × p). False when it diverges.
    fn simulate(
        &self,
        theta: &[f64],
        u: &[Vec<f64>],
        y: &mut [f64],
        k0: usize,
        mut sens: Option<&mut Vec<f64>>,
    ) -> bool {
        let n = y.len();
        let p = self.terms.len();
        let mut x = vec![0.0; self.taps.len()];
        let mut m = vec![0.0; p];
        let mut g = vec![0.0; self.out_regs.len()];
        if let Some(s) = sens.as_deref_mut() {
            s.clear();
            s.resize(n * p, 0.0);
        }
        for k in k0..n {
            self.fill(k, y, u, &mut x);
            self.monomials(&x, &mut m);
            let v: f64 = m.iter().zip(theta).map(|(a, b)| a * b).sum();
            if !v.is_finite() || v.abs() > DIVERGED {
                return false;
            }
            y[k] = v;
            if let Some(s) = sens.as_deref_mut() {
                self.output_gradient(theta, &x, &mut g);
                let (past, cur) = s.split_at_mut(k * p);
                let row = &mut cur[..p];
                row.copy_from_slice(&m);
                for (&(_, d), &gr) in self.out_regs.iter().zip(&g) {
                    if gr != 0.0 && k - d >= k0 {
                        let prev = &past[(k - d) * p..(k - d + 1) * p];
                        for (a, b) in row.iter_mut().zip(prev) {
                            *a += gr * b;
                        }
                    }
                }
            }
        }
        true
    }
}

/// One record in normalised units.
#[derive(Debug, Clone)]
struct NormRec {
    u: Vec<Vec<f64>>,
    y: Vec<f64>,
}

impl NormRec {
    fn slice(&self, r: std::ops::Range<usize>) -> Self {
        Self {
            u: self.u.iter().map(|s| s[r.clone()].to_vec()).collect(),
            y: self.y[r].to_vec(),
        }
    }
}

/// Parameters of a polynomial NARX / NOE fit (see the module docs for the
/// defaults); validate with [`check`](Self::check).
#[derive(Debug, Clone, PartialEq)]
pub struct PolyParams {
    /// Output lags 1..=na.
    pub na: usize,
    /// Input lags per input (empty: `na` for every input).
    pub nb: Vec<usize>,
    /// Dead time per input (empty: 1 for every input).
    pub nk: Vec<usize>,
    /// Highest degree of a term (1..=3).
    pub degree: usize,
    /// Most terms.
    pub max_terms: usize,
    /// Simulation: refine for the simulation error; prediction: least squares.
    pub focus: Focus,
    /// Fraction of every record held out to choose the number of terms.
    pub holdout: f64,
    /// Levenberg–Marquardt iterations of each refinement.
    pub lm_iterations: usize,
}

impl PolyParams {
    /// Order `na` (= n_b per input), dead time 1, degree 3, the defaults.
    pub fn new(na: usize) -> Self {
        Self {
            na,
            nb: vec![],
            nk: vec![],
            degree: 3,
            max_terms: 15,
            focus: Focus::Simulation,
            holdout: 0.25,
            lm_iterations: 40,
        }
    }
    /// Highest degree.
    pub fn degree(mut self, d: usize) -> Self {
        self.degree = d;
        self
    }
    /// Input lags per input.
    pub fn input_lags(mut self, nb: Vec<usize>) -> Self {
        self.nb = nb;
        self
    }
    /// Dead times per input.
    pub fn dead_time(mut self, nk: Vec<usize>) -> Self {
        self.nk = nk;
        self
    }
    /// Most terms.
    pub fn max_terms(mut self, t: usize) -> Self {
        self.max_terms = t;
        self
    }
    /// Focus.
    pub fn focus(mut self, f: Focus) -> Self {
        self.focus = f;
        self
    }

    /// Validate once; the result fits.
    pub fn check(&self) -> Result<ValidPolyParams, LmnError> {
        let bad = |m: String| Err(LmnError::InvalidArgument(m));
        if self.na > 64 || self.nb.iter().chain(&self.nk).any(|&v| v > 64) {
            return bad("lags and dead times of at most 64 samples".into());
        }
        if !(1..=3).contains(&self.degree) {
            return bad(format!("degree must be 1..=3, got {}", self.degree));
        }
        if !(1..=200).contains(&self.max_terms) || !(1..=1000).contains(&self.lm_iterations) {
            return bad("max_terms in 1..=200 and lm_iterations in 1..=1000".into());
        }
        if !(0.0..0.5).contains(&self.holdout) {
            return bad("holdout in [0, 0.5)".into());
        }
        if !self.nb.is_empty() && !self.nk.is_empty() && self.nb.len() != self.nk.len() {
            return bad("as many input lags as dead times".into());
        }
        Ok(ValidPolyParams(self.clone()))
    }
}

/// Validated [`PolyParams`].
#[derive(Debug, Clone, PartialEq)]
pub struct ValidPolyParams(PolyParams);

/// All monomials of degree ≤ `degree` in `nr` regressors (constant first).
fn candidates(nr: usize, degree: usize) -> Vec<Vec<u16>> {
    let mut out = vec![vec![]];
    let mut last: Vec<Vec<u16>> = vec![vec![]];
    for _ in 0..degree {
        let mut next = vec![];
        for t in &last {
            let from = t.last().map_or(0, |&r| r as usize);
            for r in from..nr {
                let mut m = t.clone();
                m.push(r as u16);
                next.push(m);
            }
        }
        out.extend(next.iter().cloned());
        last = next;
    }
    out
}

/// Forward orthogonal least squares: the terms in the order of their error
/// reduction ratio and the least-squares coefficients of every prefix.
struct Frols {
    order: Vec<usize>,
    /// `coef[k]`: coefficients of the first k + 1 terms.
    coef: Vec<Vec<f64>>,
}

/// FROLS (modified Gram–Schmidt) on columns `cols` and target `y`.
fn frols(mut cols: Vec<Vec<f64>>, y: &[f64], max_terms: usize) -> Frols {
    let m = cols.len();
    let sigma: f64 = y.iter().map(|v| v * v).sum::<f64>().max(1e-300);
    let norm0: Vec<f64> = cols.iter().map(|c| c.iter().map(|v| v * v).sum()).collect();
    let mut free: Vec<bool> = vec![true; m];
    let mut order = vec![];
    let mut g = vec![];
    // alpha[s][j]: projection coefficient of candidate j on the s-th chosen
    let mut alpha: Vec<Vec<f64>> = vec![];
    let mut err_sum = 0.0;
    for _ in 0..max_terms.min(m) {
        let mut best: Option<(usize, f64, f64, f64)> = None;
        for (j, c) in cols.iter().enumerate() {
            if !free[j] {
                continue;
            }
            let ww: f64 = c.iter().map(|v| v * v).sum();
            if ww <= 1e-10 * norm0[j].max(1e-300) {
                continue;
            }
            let wy: f64 = c.iter().zip(y).map(|(a, b)| a * b).sum();
            let err = wy * wy / (ww * sigma);
            if best.is_none_or(|b| err > b.1) {
                best = Some((j, err, wy, ww));
            }
        }
        let Some((j, err, wy, ww)) = best else {
            break;
        };
        free[j] = false;
        order.push(j);
        g.push(wy / ww);
        err_sum += err;
        let w = cols[j].clone();
        let mut a = vec![0.0; m];
        for (i, c) in cols.iter_mut().enumerate() {
            if !free[i] {
                continue;
            }
            let al = c.iter().zip(&w).map(|(a, b)| a * b).sum::<f64>() / ww;
            a[i] = al;
            for (v, wv) in c.iter_mut().zip(&w) {
                *v -= al * wv;
            }
        }
        alpha.push(a);
        if 1.0 - err_sum < 1e-12 {
            break;
        }
    }
    // back substitution of the unit upper-triangular system per prefix
    let coef = (1..=order.len())
        .map(|k| {
            let mut th = vec![0.0; k];
            for s in (0..k).rev() {
                let mut v = g[s];
                for q in s + 1..k {
                    v -= alpha[s][order[q]] * th[q];
                }
                th[s] = v;
            }
            th
        })
        .collect();
    Frols { order, coef }
}

/// The simulation error of polynomial terms as a least-squares problem.
struct NoeProblem<'a> {
    s: &'a Structure,
    recs: &'a [NormRec],
    sens: Vec<f64>,
    y: Vec<f64>,
}

impl NoeProblem<'_> {
    fn run(&mut self, theta: &[f64], mut lin: Option<(&mut [f64], &mut [f64])>) -> Option<f64> {
        let p = theta.len();
        let k0 = self.s.max_lag();
        let mut cost = 0.0;
        if let Some((gram, grad)) = lin.as_mut() {
            gram.fill(0.0);
            grad.fill(0.0);
        }
        for r in self.recs {
            self.y.clear();
            self.y.extend_from_slice(&r.y);
            let sens = lin.is_some().then_some(&mut self.sens);
            if !self.s.simulate(theta, &r.u, &mut self.y, k0, sens) {
                return None;
            }
            let n = r.y.len();
            for k in k0..n {
                let e = r.y[k] - self.y[k];
                cost += e * e;
                if let Some((_, grad)) = lin.as_mut() {
                    let row = &self.sens[k * p..(k + 1) * p];
                    for (g, rp) in grad.iter_mut().zip(row) {
                        *g += rp * e;
                    }
                }
            }
            if let Some((gram, _)) = lin.as_mut() {
                if n > k0 {
                    add_gram(gram, p, &self.sens[k0 * p..n * p], n - k0);
                }
            }
        }
        if let Some((gram, _)) = lin {
            mirror_upper(gram, p);
        }
        cost.is_finite().then_some(cost)
    }
}

impl LeastSquaresProblem for NoeProblem<'_> {
    fn n_params(&self) -> usize {
        self.s.terms.len()
    }
    fn cost(&mut self, theta: &[f64]) -> Option<f64> {
        self.run(theta, None)
    }
    fn linearize(&mut self, theta: &[f64], gram: &mut [f64], grad: &mut [f64]) -> Option<f64> {
        self.run(theta, Some((gram, grad)))
    }
}

/// Refine `theta0` for the simulation error on `recs`; `None` when the start
/// diverges.
fn refine(s: &Structure, recs: &[NormRec], theta0: &[f64], iters: usize) -> Option<Vec<f64>> {
    let lm = LmParams::default().max_iter(iters).tol(1e-9).check().ok()?;
    let mut prob = NoeProblem {
        s,
        recs,
        sens: vec![],
        y: vec![],
    };
    lm.minimize(&mut prob, theta0, &gb_core::Silent)
        .ok()
        .map(|st| st.theta)
}

/// Free-run RMS error (normalised) on `recs`; infinite when it diverges.
fn sim_rms(s: &Structure, theta: &[f64], recs: &[NormRec]) -> f64 {
    let k0 = s.max_lag();
    let (mut sse, mut n) = (0.0, 0usize);
    for r in recs {
        let mut y = r.y.clone();
        if !s.simulate(theta, &r.u, &mut y, k0, None) {
            return f64::INFINITY;
        }
        sse += (k0..y.len()).map(|k| (r.y[k] - y[k]).powi(2)).sum::<f64>();
        n += y.len().saturating_sub(k0);
    }
    (sse / n.max(1) as f64).sqrt()
}

/// One-step (NARX) RMS error on `recs`.
fn pred_rms(s: &Structure, theta: &[f64], recs: &[NormRec]) -> f64 {
    let k0 = s.max_lag();
    let mut x = vec![0.0; s.taps.len()];
    let mut m = vec![0.0; theta.len()];
    let (mut sse, mut n) = (0.0, 0usize);
    for r in recs {
        for k in k0..r.y.len() {
            s.fill(k, &r.y, &r.u, &mut x);
            s.monomials(&x, &mut m);
            let v: f64 = m.iter().zip(theta).map(|(a, b)| a * b).sum();
            sse += (r.y[k] - v).powi(2);
            n += 1;
        }
    }
    (sse / n.max(1) as f64).sqrt()
}

impl ValidPolyParams {
    /// The parameters.
    pub fn params(&self) -> &PolyParams {
        &self.0
    }

    fn taps(&self, n_inputs: usize) -> Result<Vec<Tap>, LmnError> {
        let p = &self.0;
        let nb = if p.nb.is_empty() {
            vec![p.na; n_inputs]
        } else {
            p.nb.clone()
        };
        let nk = if p.nk.is_empty() {
            vec![1; n_inputs]
        } else {
            p.nk.clone()
        };
        if nb.len() != n_inputs || nk.len() != n_inputs {
            return Err(LmnError::InvalidArgument(format!(
                "input lags and dead times for {} inputs, the data have {n_inputs}",
                nb.len().max(nk.len())
            )));
        }
        let mut taps: Vec<Tap> = (1..=p.na)
            .map(|d| Tap {
                signal: Signal::Output,
                delay: d,
            })
            .collect();
        for j in 0..n_inputs {
            taps.extend((nk[j]..nk[j] + nb[j]).map(|d| Tap {
                signal: Signal::Input(j),
                delay: d,
            }));
        }
        if taps.is_empty() {
            return Err(LmnError::InvalidArgument("no regressors".into()));
        }
        Ok(taps)
    }

    /// Fit on records of the same signals (see the module docs).
    pub fn fit(&self, data: &Records) -> Result<PolyNarx, LmnError> {
        let p = &self.0;
        let ni = data.first().n_inputs();
        let taps = self.taps(ni)?;
        let cands = candidates(taps.len(), p.degree);
        if cands.len() > MAX_CANDIDATES {
            return Err(LmnError::InvalidArgument(format!(
                "{} candidate terms (at most {MAX_CANDIDATES}): fewer lags or a lower degree",
                cands.len()
            )));
        }
        let all_y: Vec<f64> = data.iter().flat_map(|r| r.output.iter().copied()).collect();
        let output_scaling = Scaling::of(&all_y);
        let input_scaling: Vec<Scaling> = (0..ni)
            .map(|j| {
                Scaling::of(
                    &data
                        .iter()
                        .flat_map(|r| r.inputs[j].clone())
                        .collect::<Vec<_>>(),
                )
            })
            .collect();
        let recs: Vec<NormRec> = data
            .iter()
            .map(|r| NormRec {
                u: r.inputs
                    .iter()
                    .zip(&input_scaling)
                    .map(|(s, sc)| s.iter().map(|&v| sc.to_norm(v)).collect())
                    .collect(),
                y: r.output
                    .iter()
                    .map(|&v| output_scaling.to_norm(v))
                    .collect(),
            })
            .collect();
        let k0 = taps.iter().map(|t| t.delay).max().unwrap_or(0);
        let needed = k0 + 2 * p.max_terms.min(cands.len()) + 20;
        if recs
            .iter()
            .map(|r| r.y.len().saturating_sub(k0))
            .sum::<usize>()
            < needed
        {
            return Err(LmnError::TooShort {
                needed,
                got: data.total_samples(),
            });
        }
        // inner fit / hold-out split of every record long enough
        let (mut inner, mut hold) = (vec![], vec![]);
        for r in &recs {
            let n = r.y.len();
            let h = (p.holdout * n as f64) as usize;
            if h >= 50 + k0 && n - h > 2 * k0 + 20 {
                inner.push(r.slice(0..n - h));
                hold.push(r.slice(n - h - k0..n));
            } else {
                inner.push(r.clone());
            }
        }
        let (terms, theta) = self.select(&taps, &cands, &inner, &hold)?;
        let s = Structure::new(&taps, &terms);
        let theta = match p.focus {
            Focus::Simulation => refine(&s, &recs, &theta, p.lm_iterations).unwrap_or(theta),
            _ => theta,
        };
        let m = PolyNarx {
            regressors: taps,
            terms,
            theta,
            output_scaling,
            input_scaling,
        };
        if p.focus == Focus::Simulation && !sim_rms(&Structure::of(&m), &m.theta, &recs).is_finite()
        {
            return Err(LmnError::Unstable(
                "no polynomial model simulated stably on the training data".into(),
            ));
        }
        Ok(m)
    }

    /// FROLS ordering on `inner`, the number of terms on `hold`: the chosen
    /// terms and their coefficients (refined on `inner` with simulation focus).
    fn select(
        &self,
        taps: &[Tap],
        cands: &[Vec<u16>],
        inner: &[NormRec],
        hold: &[NormRec],
    ) -> Result<(Vec<Vec<u16>>, Vec<f64>), LmnError> {
        let p = &self.0;
        let all = Structure::new(taps, cands);
        let k0 = all.max_lag();
        let rows: usize = inner.iter().map(|r| r.y.len().saturating_sub(k0)).sum();
        let mut cols = vec![Vec::with_capacity(rows); cands.len()];
        let mut target = Vec::with_capacity(rows);
        let mut x = vec![0.0; taps.len()];
        let mut m = vec![0.0; cands.len()];
        for r in inner {
            for k in k0..r.y.len() {
                all.fill(k, &r.y, &r.u, &mut x);
                all.monomials(&x, &mut m);
                for (c, v) in cols.iter_mut().zip(&m) {
                    c.push(*v);
                }
                target.push(r.y[k]);
            }
        }
        let fr = frols(cols, &target, p.max_terms);
        if fr.order.is_empty() {
            return Err(LmnError::Numerical("no term could be selected".into()));
        }
        let prefix = |k: usize| -> (Vec<Vec<u16>>, Vec<f64>) {
            (
                fr.order[..k].iter().map(|&j| cands[j].clone()).collect(),
                fr.coef[k - 1].clone(),
            )
        };
        let sim = p.focus == Focus::Simulation;
        let score = |k: usize, th: &[f64], recs: &[NormRec]| {
            let s = Structure::new(taps, &prefix(k).0);
            if sim {
                sim_rms(&s, th, recs)
            } else {
                pred_rms(&s, th, recs)
            }
        };
        let kmax = fr.order.len();
        if hold.is_empty() {
            // no hold-out: BIC of the one-step error
            let n = rows.max(1) as f64;
            let k = (1..=kmax)
                .min_by(|&a, &b| {
                    let bic = |k: usize| {
                        let (t, th) = prefix(k);
                        let e = pred_rms(&Structure::new(taps, &t), &th, inner);
                        n * (e * e).max(1e-300).ln() + k as f64 * n.ln()
                    };
                    bic(a).total_cmp(&bic(b))
                })
                .unwrap_or(1);
            return Ok(prefix(k));
        }
        let mut ranked: Vec<(usize, f64)> = (1..=kmax)
            .map(|k| (k, score(k, &fr.coef[k - 1], hold)))
            .collect();
        if !sim {
            let best = ranked.iter().map(|r| r.1).fold(f64::INFINITY, f64::min);
            let k = ranked
                .iter()
                .find(|r| r.1 <= 1.01 * best)
                .map_or(1, |r| r.0);
            return Ok(prefix(k));
        }
        // refine the best prefix and the smallest ones near it (parsimony)
        let best = ranked.iter().map(|r| r.1).fold(f64::INFINITY, f64::min);
        let mut picks: Vec<usize> = [1.0, 1.05, 1.2]
            .iter()
            .filter_map(|tol| ranked.iter().find(|r| r.1 <= tol * best).map(|r| r.0))
            .collect();
        picks.sort_unstable();
        picks.dedup();
        ranked.retain(|r| picks.contains(&r.0));
        let mut refined: Vec<(usize, f64, Vec<f64>)> = ranked
            .iter()
            .map(|&(k, _)| {
                let (t, th) = prefix(k);
                let s = Structure::new(taps, &t);
                let th = refine(&s, inner, &th, p.lm_iterations).unwrap_or(th);
                let e = sim_rms(&s, &th, hold);
                (k, e, th)
            })
            .filter(|r| r.1.is_finite())
            .collect();
        if refined.is_empty() {
            return Err(LmnError::Unstable(
                "no polynomial model simulated stably on the hold-out".into(),
            ));
        }
        let best = refined.iter().map(|r| r.1).fold(f64::INFINITY, f64::min);
        refined.sort_by_key(|r| r.0);
        let (k, e, th) = refined
            .into_iter()
            .find(|r| r.1 <= 1.01 * best)
            .expect("the best is in");
        Ok(self.prune(taps, prefix(k).0, th, e, inner, hold))
    }

    /// Backward elimination: drop the term of smallest contribution while
    /// the refined model without it simulates the hold-out within 0.5 % of
    /// the error `e` (forward selection on one-step regressors can take a
    /// term that only stands in for a later one).
    fn prune(
        &self,
        taps: &[Tap],
        mut terms: Vec<Vec<u16>>,
        mut theta: Vec<f64>,
        e: f64,
        inner: &[NormRec],
        hold: &[NormRec],
    ) -> (Vec<Vec<u16>>, Vec<f64>) {
        let iters = self.0.lm_iterations.div_ceil(2);
        while terms.len() > 1 {
            // contribution of each term: rms of θₜ mₜ on the inner records
            let s = Structure::new(taps, &terms);
            let k0 = s.max_lag();
            let mut x = vec![0.0; taps.len()];
            let mut m = vec![0.0; terms.len()];
            let mut c = vec![0.0; terms.len()];
            for r in inner {
                for k in k0..r.y.len() {
                    s.fill(k, &r.y, &r.u, &mut x);
                    s.monomials(&x, &mut m);
                    for ((ci, mi), th) in c.iter_mut().zip(&m).zip(&theta) {
                        *ci += (mi * th).powi(2);
                    }
                }
            }
            let j = (0..terms.len())
                .min_by(|&a, &b| c[a].total_cmp(&c[b]))
                .expect("terms");
            let mut t2 = terms.clone();
            let mut th2 = theta.clone();
            t2.remove(j);
            th2.remove(j);
            let s2 = Structure::new(taps, &t2);
            let th2 = refine(&s2, inner, &th2, iters).unwrap_or(th2);
            if sim_rms(&s2, &th2, hold) > 1.005 * e {
                break;
            }
            terms = t2;
            theta = th2;
        }
        (terms, theta)
    }
}

impl Identify for ValidPolyParams {
    type Model = PolyNarx;
    type Error = LmnError;
    fn identify(&self, data: &Records, _observer: &dyn Observer) -> Result<PolyNarx, LmnError> {
        self.fit(data)
    }
}

impl DynamicModel for PolyNarx {
    fn class(&self) -> &'static str {
        "poly-narx"
    }
    fn n_inputs(&self) -> usize {
        PolyNarx::n_inputs(self)
    }
    fn n_states(&self) -> usize {
        self.max_lag()
    }
    fn history_len(&self) -> usize {
        self.max_lag()
    }
    fn describe(&self) -> String {
        let deg = self.terms.iter().map(Vec::len).max().unwrap_or(0);
        let na = self
            .regressors
            .iter()
            .filter(|t| t.signal == Signal::Output)
            .count();
        format!(
            "polynomial NOE (FROLS terms, simulation-error refined): {} terms of degree <= {deg} in {} regressors ({na} output lags)",
            self.terms.len(),
            self.regressors.len()
        )
    }
    fn n_parameters(&self) -> usize {
        self.theta.len()
    }
    fn simulate_into(
        &self,
        u: &[Vec<f64>],
        init: Init<'_>,
        y: &mut [f64],
        _ws: &mut Workspace,
    ) -> Result<(), CoreError> {
        check_inputs(self.n_inputs(), u)?;
        let mean = self.output_scaling.offset;
        let sim = match init {
            Init::Window(h) | Init::History(h) | Init::State(h) => self.simulate_signals(u, h)?,
            Init::Stored => self.simulate_signals(u, &vec![mean; self.max_lag()])?,
            _ => self.simulate_signals(u, &vec![0.0; self.max_lag()])?,
        };
        if sim.len() != y.len() {
            return Err(CoreError::Dimension(format!(
                "output buffer of {} samples for a simulation of {}",
                y.len(),
                sim.len()
            )));
        }
        y.copy_from_slice(&sim);
        Ok(())
    }
    /// From every start `simulate` takes but [`Init::Periodic`]: the first
    /// `max_lag` outputs are the history (measured, zero at rest, the
    /// training mean from the stored start); stepping gives the batch
    /// simulation's outputs bit for bit.
    fn stepper(&self, init: Init<'_>) -> Result<Box<dyn Stepper + '_>, CoreError> {
        let k0 = self.max_lag();
        let sc = self.output_scaling;
        let physical: Vec<f64> = match init {
            Init::Window(h) | Init::History(h) | Init::State(h) => h.iter().take(k0).copied().collect(),
            Init::Stored => vec![sc.offset; k0],
            Init::Rest => vec![0.0; k0],
            other => {
                return Err(CoreError::Unsupported(format!(
                    "poly-narx: stepping starts at rest, from the stored start or from measured outputs, not {other:?}"
                )))
            }
        };
        Ok(Box::new(PolyStepper {
            model: self,
            structure: Structure::of(self),
            hist: physical.iter().map(|&v| sc.to_norm(v)).collect(),
            t: 0,
            y: vec![0.0; k0 + 1],
            u: vec![vec![0.0; k0 + 1]; self.n_inputs()],
            x: vec![0.0; self.regressors.len()],
            m: vec![0.0; self.terms.len()],
        }))
    }
    fn encode(&self) -> Result<Vec<u8>, CoreError> {
        crate::dynamic::encode(self)
    }
    fn views(&self, input_names: &[String], output_names: &[String]) -> Vec<ModelView> {
        let out = output_names.first().map_or("y", String::as_str);
        let rows = self
            .term_names(out, input_names)
            .into_iter()
            .zip(&self.theta)
            .map(|(t, c)| vec![t, format!("{c:+.4e}")])
            .collect();
        vec![ModelView {
            key: "poly-terms".into(),
            title: "Polynomial terms (chosen by FROLS)".into(),
            caption: "Each term is a product of normalised lagged signals (zero mean, unit variance over the training data); the coefficient is in those units.".into(),
            data: ViewData::Table {
                header: vec!["term".into(), "coefficient".into()],
                rows,
            },
        }]
    }
    fn clone_box(&self) -> Box<dyn DynamicModel> {
        Box::new(self.clone())
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// The options of a `poly` model spec.
pub const SPEC_OPTIONS: [&str; 6] = [
    "order",
    "input_lags",
    "delay",
    "degree",
    "max_terms",
    "focus",
];

/// `greybox fit --model poly[:order=N,delay=D,degree=3,max_terms=15,focus=simulation]`:
/// the fitted model (Gaussian noise of its training simulation residuals)
/// and a line on the chosen terms.
pub fn fit_spec(
    spec: &ModelSpec,
    data: &Records,
    obs: &dyn Observer,
) -> Result<(FittedModel, Vec<String>), CoreError> {
    let mut o = spec.options();
    let d = data.first();
    let na = o.usize("order", 2, 0, 64)?;
    let nb = o.usize_list("input_lags", d.n_inputs(), na.max(1), 0, 64)?;
    let nk = o.usize_list("delay", d.n_inputs(), 1, 0, 64)?;
    let degree = o.usize("degree", 3, 1, 3)?;
    let max_terms = o.usize("max_terms", 15, 1, 200)?;
    let focus = match o.choice("focus", "simulation", &["simulation", "prediction"])? {
        "prediction" => Focus::Prediction,
        _ => Focus::Simulation,
    };
    o.finish(&SPEC_OPTIONS)?;
    for (i, r) in data.iter().enumerate() {
        r.check_identifiable(&format!("record {}", i + 1), 50 + 4 * max_terms)?;
    }
    let m = PolyParams {
        nb,
        nk,
        degree,
        max_terms,
        focus,
        ..PolyParams::new(na)
    }
    .check()?
    .identify(data, obs)?;
    let mut res = vec![];
    for r in data.iter() {
        let k0 = m.max_lag().min(r.len());
        let sim = m.simulate_signals(&r.inputs, &r.output[..k0])?;
        res.extend(r.output[k0..].iter().zip(&sim[k0..]).map(|(a, b)| a - b));
    }
    let note = format!(
        "terms: {}",
        m.term_names(&d.output_name, &d.input_names).join(" + ")
    );
    let mut model = FittedModel::new(
        d.input_names.clone(),
        vec![d.output_name.clone()],
        Box::new(m),
        NoiseModel::gaussian(&res),
    )?;
    model.sample_time = d.sample_time;
    Ok((model, vec![note]))
}

/// A [`PolyNarx`] stepped one sample at a time (the operations of the
/// batch simulation in the same order): the last outputs and inputs
/// (normalised), newest first — `y[d − 1] = ŷ(t − d)`, `u[j][d] = u_j(t − d)`.
struct PolyStepper<'m> {
    model: &'m PolyNarx,
    structure: Structure,
    hist: Vec<f64>,
    t: usize,
    y: Vec<f64>,
    u: Vec<Vec<f64>>,
    x: Vec<f64>,
    m: Vec<f64>,
}

impl Stepper for PolyStepper<'_> {
    fn step(&mut self, u: &[f64], y: &mut [f64]) -> Result<(), CoreError> {
        let md = self.model;
        if u.len() != self.u.len() || y.len() != 1 {
            return Err(CoreError::Dimension(format!(
                "step: {} inputs and {} outputs for a model with {} and 1",
                u.len(),
                y.len(),
                self.u.len()
            )));
        }
        for ((ring, &v), sc) in self.u.iter_mut().zip(u).zip(&md.input_scaling) {
            ring.rotate_right(1);
            ring[0] = sc.to_norm(v);
        }
        let v = match self.hist.get(self.t) {
            Some(&h) => h,
            None if self.t < md.max_lag() => 0.0,
            None => {
                for (xi, tap) in self.x.iter_mut().zip(&self.structure.taps) {
                    *xi = match tap.signal {
                        Signal::Output => self.y[tap.delay - 1],
                        Signal::Input(j) => self.u[j][tap.delay],
                    };
                }
                self.structure.monomials(&self.x, &mut self.m);
                let v: f64 = self.m.iter().zip(&md.theta).map(|(a, b)| a * b).sum();
                if !v.is_finite() || v.abs() > DIVERGED {
                    return Err(CoreError::Unstable(format!(
                        "poly-narx: the simulation diverged at step {}",
                        self.t
                    )));
                }
                v
            }
        };
        self.y.rotate_right(1);
        self.y[0] = v;
        self.t += 1;
        y[0] = md.output_scaling.from_norm(v);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gb_core::Record;

    /// Stepping gives the batch simulation bit for bit from every start
    /// (an output or input lag off by one differs).
    #[test]
    fn stepping_is_bit_identical_to_the_simulation() {
        let (rec, _) = record(2000, 0.02, 5);
        let m = PolyParams::new(2)
            .check()
            .unwrap()
            .identify(&Records::single(rec.clone()), &gb_core::Silent)
            .unwrap();
        let u = vec![rec.inputs[0][..500].to_vec()];
        let y = &rec.output;
        for init in [
            Init::Rest,
            Init::Stored,
            Init::History(&y[..1]),
            Init::Window(&y[..5]),
            Init::State(&y[..2]),
        ] {
            let batch = DynamicModel::simulate(&m, &u, init).unwrap();
            let mut st = m.stepper(init).unwrap();
            let mut out = [0.0];
            for (k, b) in batch.iter().enumerate() {
                st.step(&[u[0][k]], &mut out).unwrap();
                assert_eq!(out[0], *b, "from {init:?}, sample {k}");
            }
        }
        assert!(m.stepper(Init::Periodic { periods: 3 }).is_err());
    }
    use rand::{Rng, SeedableRng};

    /// y₀(k) = 0.6 y₀(k−1) − 0.25 y₀(k−2) + 0.8 u(k−1) + 0.3 u(k−1)² − 0.2 y₀(k−1) u(k−1),
    /// measured with output noise.
    fn system(u: &[f64]) -> Vec<f64> {
        let mut y = vec![0.0; u.len()];
        for k in 2..u.len() {
            y[k] = 0.6 * y[k - 1] - 0.25 * y[k - 2] + 0.8 * u[k - 1] + 0.3 * u[k - 1] * u[k - 1]
                - 0.2 * y[k - 1] * u[k - 1];
        }
        y
    }

    fn record(n: usize, noise: f64, seed: u64) -> (Record, Vec<f64>) {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed);
        let u: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let y0 = system(&u);
        let y: Vec<f64> = y0
            .iter()
            .map(|v| v + noise * rng.sample::<f64, _>(rand_distr::StandardNormal))
            .collect();
        (
            Record::new(vec!["u".into()], "y".into(), vec![u], y).unwrap(),
            y0,
        )
    }

    #[test]
    fn candidates_are_every_monomial_once() {
        // C(r + d, d) monomials of degree <= d in r variables
        assert_eq!(candidates(4, 3).len(), 35);
        assert_eq!(candidates(3, 2).len(), 10);
        let c = candidates(2, 2);
        assert_eq!(
            c,
            vec![vec![], vec![0], vec![1], vec![0, 0], vec![0, 1], vec![1, 1]]
        );
    }

    /// FROLS on the noise-free regression recovers the true terms exactly
    /// (and no other), the simulation-focused fit on noisy data recovers
    /// them with their coefficients and simulates fresh data at the noise
    /// floor.
    #[test]
    fn recovers_a_known_polynomial_system() {
        let sd = 0.02;
        let (rec, _) = record(3000, sd, 11);
        let m = PolyParams::new(2)
            .check()
            .unwrap()
            .identify(&Records::single(rec.clone()), &gb_core::Silent)
            .unwrap();
        let mut names = m.term_names("y", &["u".to_string()]);
        names.sort();
        // in normalised (centred) signals the physical terms bring a constant
        let mut want: Vec<String> = [
            "1",
            "y(k-1)",
            "y(k-2)",
            "u(k-1)",
            "u(k-1)*u(k-1)",
            "y(k-1)*u(k-1)",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        want.sort();
        assert_eq!(names, want, "{:?}", m.theta);
        // coefficients back in physical units: the y(k-2) coefficient is
        // scale-free (output to output)
        let i2 = m
            .term_names("y", &["u".to_string()])
            .iter()
            .position(|t| t == "y(k-2)")
            .unwrap();
        assert!((m.theta[i2] + 0.25).abs() < 0.02, "{}", m.theta[i2]);
        let iu2 = m
            .term_names("y", &["u".to_string()])
            .iter()
            .position(|t| t == "u(k-1)*u(k-1)")
            .unwrap();
        let su = m.input_scaling[0].scale;
        let phys = m.theta[iu2] * m.output_scaling.scale / (su * su);
        assert!((phys - 0.3).abs() < 0.03, "u^2 coefficient {phys}");
        // fresh data: the simulation error is the noise
        let (fresh, y0) = record(2000, sd, 12);
        let sim = m
            .simulate(&fresh.inputs, Init::History(&fresh.output[..2]))
            .unwrap();
        let e: Vec<f64> = (50..2000).map(|k| fresh.output[k] - sim[k]).collect();
        let floor = sd;
        let rms = gb_core::metrics::rms(&e);
        assert!(
            rms < 1.1 * floor && rms > 0.9 * floor,
            "rms {rms}, noise {floor}"
        );
        let e0: Vec<f64> = (50..2000).map(|k| y0[k] - sim[k]).collect();
        assert!(gb_core::metrics::rms(&e0) < 0.3 * floor);
    }

    /// A linear model of degree 1 cannot have terms of degree 2; the
    /// least-squares (prediction) fit of a linear system is exact.
    #[test]
    fn prediction_focus_and_degree_one() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(3);
        let u: Vec<f64> = (0..800).map(|_| rng.random_range(-1.0..1.0)).collect();
        let mut y = vec![0.0; 800];
        for k in 1..800 {
            y[k] = 0.7 * y[k - 1] + 0.5 * u[k - 1];
        }
        let rec = Record::new(vec!["u".into()], "y".into(), vec![u.clone()], y.clone()).unwrap();
        let m = PolyParams::new(1)
            .degree(1)
            .focus(Focus::Prediction)
            .check()
            .unwrap()
            .fit(&Records::single(rec))
            .unwrap();
        assert!(m.terms.iter().all(|t| t.len() <= 1));
        let sim = m.simulate(&[u], Init::History(&y[..1])).unwrap();
        assert!(gb_core::metrics::nrmse(&y, &sim).unwrap() < 1e-8);
    }

    #[test]
    fn bad_parameters_and_inconsistent_bodies_are_refused() {
        assert!(PolyParams::new(2).degree(4).check().is_err());
        assert!(PolyParams::new(2).max_terms(0).check().is_err());
        assert!(PolyParams::new(65).check().is_err());
        let (rec, _) = record(600, 0.01, 5);
        let m = PolyParams::new(1)
            .degree(2)
            .check()
            .unwrap()
            .fit(&Records::single(rec))
            .unwrap();
        let body = m.encode().unwrap();
        assert_eq!(PolyNarx::decode(&body, 1).unwrap(), m);
        assert!(PolyNarx::decode(&body, 2).is_err());
        assert!(PolyNarx::decode(&body[..body.len() / 2], 1).is_err());
        let mut bad = m.clone();
        bad.terms[0] = vec![99];
        let e = PolyNarx::decode(&bad.encode().unwrap(), 1)
            .unwrap_err()
            .to_string();
        assert!(e.contains("inconsistent"), "{e}");
        // two inputs for a one-input model
        assert!(m
            .simulate(&[vec![0.0; 5], vec![0.0; 5]], Init::Rest)
            .is_err());
    }
}
