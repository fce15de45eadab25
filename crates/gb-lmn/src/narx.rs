//! Global Levenberg–Marquardt over all local-model and split parameters
//! (Nelles 2020, sec. 14.6 and ch. 19): NARX (one-step prediction error,
//! measured output lags) or NOE (simulation error).
//!
//! For NOE the sensitivities S(k) = ∂ŷ(k)/∂p follow the recursion
//!
//! S(k) = ∂f/∂p + Σ_{x taps y(k−i)} ∂f/∂x_j · S(k−i) + Σ_{z taps y(k−i)} ∂f/∂z_d · S(k−i)
//!
//! with ∂f/∂z from the weight-function derivatives (see [`crate::tree`]);
//! samples of the init window have S = 0. JᵀJ is accumulated in blocks of
//! rows ([`gb_core::gram::GramAccumulator`]), J is never stored. A step solves
//! (JᵀJ + λ diag JᵀJ) δ = Jᵀe and is accepted only if the cost falls, the
//! simulation stays bounded and (stability guard, affine local models) every
//! local model's autoregressive part has spectral radius < 0.9995.
use crate::lmn::{Eval, Focus, LmnModel, DIVERGED};
use crate::regressors::Experiment;
use crate::regressors::{NormExp, Signal};
use crate::LmnError;
use gb_core::gram::GramAccumulator;
use gb_core::solver::{LeastSquaresProblem, LmParams};
use gb_core::Records;
use gb_core::{Observer, Silent};
use rayon::prelude::*;

const MAX_RADIUS: f64 = 0.9995;

/// Cost Σ e² and, with `jac`, JᵀJ and Jᵀe over the first `nact` parameters,
/// for one experiment. `None` if the simulation diverged.
/// (JᵀJ column-major `nact × nact`, Jᵀe of length `nact`; both empty
/// without `jac`.)
type Part = (f64, Vec<f64>, Vec<f64>);

fn accumulate(m: &LmnModel, e: &NormExp, focus: Focus, nact: usize, jac: bool) -> Option<Part> {
    let mut ev: Eval = m.eval_scratch();
    let np = m.parameters().len();
    let n = e.y.len();
    let k0 = m.max_lag().min(n);
    let sim = focus == Focus::Simulation && m.regressors.max_output_lag() > 0;
    let d = if jac { nact } else { 0 };
    let mut jtj = vec![0.0; d * d];
    let mut jte = vec![0.0; d];
    let mut acc = GramAccumulator::new(d);
    let mut out = e.y.clone();
    let ring = m.regressors.max_output_lag().max(1);
    let mut sy = if jac && sim {
        vec![0.0; ring * nact]
    } else {
        vec![]
    };
    let mut gp = vec![0.0; if jac { np } else { 0 }];
    let mut snew = vec![0.0; nact];
    let mut cost = 0.0;
    let xt = ev.lay.x.clone();
    let zt = ev.lay.z.clone();
    for k in k0..n {
        ev.lay
            .fill(k, if sim { &out } else { &e.y }, &e.u, &mut ev.x, &mut ev.z);
        ev.lay.basis(&ev.x, &e.e, k, &mut ev.phi);
        let v = if jac {
            m.eval(&mut ev, Some(&mut gp), sim)
        } else {
            m.eval(&mut ev, None, false)
        };
        if !v.is_finite() || v.abs() > DIVERGED {
            return None;
        }
        out[k] = v;
        let err = e.y[k] - v;
        cost += err * err;
        if !jac {
            continue;
        }
        snew.copy_from_slice(&gp[..nact]);
        if sim {
            for (j, t) in xt.iter().enumerate() {
                if t.signal == Signal::Output && k >= k0 + t.delay {
                    let g = ev.gx[j];
                    if g != 0.0 {
                        let b = ((k - t.delay) % ring) * nact;
                        for (s, o) in snew.iter_mut().zip(&sy[b..b + nact]) {
                            *s += g * o;
                        }
                    }
                }
            }
            for (d, t) in zt.iter().enumerate() {
                if t.signal == Signal::Output && k >= k0 + t.delay {
                    let g = ev.gz[d];
                    if g != 0.0 {
                        let b = ((k - t.delay) % ring) * nact;
                        for (s, o) in snew.iter_mut().zip(&sy[b..b + nact]) {
                            *s += g * o;
                        }
                    }
                }
            }
            let slot = (k % ring) * nact;
            sy[slot..slot + nact].copy_from_slice(&snew);
        }
        for (g, s) in jte.iter_mut().zip(&snew) {
            *g += s * err;
        }
        acc.push(&mut jtj, &snew);
    }
    if jac {
        acc.finish(&mut jtj);
    }
    Some((cost, jtj, jte))
}

/// Chunks for parallel accumulation: NARX rows are independent, so long
/// experiments are cut (with `max_lag` samples of overlap as history).
fn chunks(m: &LmnModel, exps: &[NormExp], focus: Focus) -> Vec<NormExp> {
    let sim = focus == Focus::Simulation && m.regressors.max_output_lag() > 0;
    if sim {
        return exps.to_vec();
    }
    let k0 = m.max_lag();
    let len = 8192;
    let mut out = Vec::new();
    for e in exps {
        let n = e.y.len();
        let mut s = 0;
        while s + k0 < n {
            let end = (s + k0 + len).min(n);
            out.push(NormExp {
                u: e.u.iter().map(|u| u[s..end].to_vec()).collect(),
                y: e.y[s..end].to_vec(),
                e: e.e.iter().map(|u| u[s..end].to_vec()).collect(),
            });
            s += len;
        }
    }
    out
}

type Acc = (f64, Vec<f64>, Vec<f64>, usize);

fn total(m: &LmnModel, parts: &[NormExp], focus: Focus, nact: usize, jac: bool) -> Option<Acc> {
    let res: Vec<Option<Part>> = parts
        .par_iter()
        .map(|e| accumulate(m, e, focus, nact, jac))
        .collect();
    let mut cost = 0.0;
    let d = if jac { nact } else { 0 };
    let mut jtj = vec![0.0; d * d];
    let mut jte = vec![0.0; d];
    let mut cnt = 0;
    for (r, e) in res.into_iter().zip(parts) {
        let (c, a, b) = r?;
        cost += c;
        cnt += e.y.len().saturating_sub(m.max_lag());
        for (t, v) in jtj.iter_mut().zip(&a) {
            *t += v;
        }
        for (t, v) in jte.iter_mut().zip(&b) {
            *t += v;
        }
    }
    Some((cost, jtj, jte, cnt))
}

/// The global optimisation as a least-squares problem over the first
/// `nact` parameters (all, or the local models only): cost and Gram matrix
/// accumulated over the (chunked) experiments in parallel; with the
/// stability guard, trial points whose affine local models are unstable are
/// inadmissible.
struct GlobalProblem<'a> {
    /// Scratch copy of the model, its first `nact` parameters set to θ.
    model: LmnModel,
    full: Vec<f64>,
    parts: &'a [NormExp],
    focus: Focus,
    nact: usize,
    guard: Option<f64>,
}

impl GlobalProblem<'_> {
    fn set(&mut self, theta: &[f64]) -> bool {
        self.full[..self.nact].copy_from_slice(theta);
        self.model.set_parameters(&self.full).is_ok()
    }
}

impl LeastSquaresProblem for GlobalProblem<'_> {
    fn n_params(&self) -> usize {
        self.nact
    }
    fn cost(&mut self, theta: &[f64]) -> Option<f64> {
        if !self.set(theta) {
            return None;
        }
        total(&self.model, self.parts, self.focus, self.nact, false).map(|t| t.0)
    }
    fn linearize(&mut self, theta: &[f64], gram: &mut [f64], grad: &mut [f64]) -> Option<f64> {
        if !self.set(theta) {
            return None;
        }
        let (c, jtj, jte, _) = total(&self.model, self.parts, self.focus, self.nact, true)?;
        // symmetric: the column-major layout is the row-major one
        gram.copy_from_slice(&jtj);
        grad.copy_from_slice(&jte);
        Some(c)
    }
    fn admissible(&mut self, theta: &[f64]) -> bool {
        if !self.set(theta) {
            return false;
        }
        self.guard
            .is_none_or(|start| self.model.max_spectral_radius() < MAX_RADIUS.max(start))
    }
}

/// Global LM; returns (iterations, rms before, rms after) in normalised units.
/// Solver settings: the workspace defaults (λ from 1e-3, ×4 / ÷3, floor
/// 1e-12, Marquardt scaling with floor 1e-9·max Gᵢᵢ and jitter
/// 1e-12·max Gᵢᵢ, 12 trials, give up above 1e12), tolerance 1e-8.
pub(crate) fn optimise(
    m: &mut LmnModel,
    exps: &[NormExp],
    focus: Focus,
    max_iter: usize,
    guard: bool,
    splits: bool,
    observer: &dyn Observer,
) -> Result<(usize, f64, f64), LmnError> {
    let np = m.parameters().len();
    let nact = if splits {
        np
    } else {
        m.n_leaves() * m.regressors.n_local()
    };
    let parts = chunks(m, exps, focus);
    let use_guard = guard
        && focus == Focus::Simulation
        && m.regressors.degree == 1
        && !m.regressors.x_output.is_empty();
    let full = m.parameters();
    let cnt: usize = parts
        .iter()
        .map(|e| e.y.len().saturating_sub(m.max_lag()))
        .sum();
    let mut problem = GlobalProblem {
        model: m.clone(),
        full: full.clone(),
        parts: &parts,
        focus,
        nact,
        guard: use_guard.then(|| m.max_spectral_radius()),
    };
    let lm = LmParams::default()
        .max_iter(max_iter)
        .tol(1e-8)
        .check()
        .map_err(|e| LmnError::InvalidArgument(e.to_string()))?;
    let state = lm
        .minimize(&mut problem, &full[..nact], observer)
        .map_err(|_| LmnError::Unstable("the grown network diverges in simulation".into()))?;
    if problem.set(&state.theta) {
        *m = problem.model;
    }
    let rms = |c: f64| (c / cnt.max(1) as f64).sqrt();
    Ok((state.iterations, rms(state.initial_cost), rms(state.cost)))
}

/// What [`LmnModel::refine`] did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefineReport {
    /// LM iterations.
    pub iterations: usize,
    /// RMS error (normalised) before.
    pub rms_before: f64,
    /// RMS error (normalised) after.
    pub rms_after: f64,
}

impl LmnModel {
    /// Global Levenberg–Marquardt over all parameters (local models and, for
    /// tree weights, the splits) on the one-step (`Focus::Prediction`, NARX)
    /// or simulation (`Focus::Simulation`, NOE) error of the experiments.
    pub fn refine(
        &mut self,
        train: &Records,
        focus: Focus,
        max_iter: usize,
    ) -> Result<RefineReport, LmnError> {
        self.refine_with_observer(train, focus, max_iter, &Silent)
    }

    /// [`refine`](Self::refine), reporting every iteration to `observer`.
    pub fn refine_with_observer(
        &mut self,
        train: &Records,
        focus: Focus,
        max_iter: usize,
        observer: &dyn Observer,
    ) -> Result<RefineReport, LmnError> {
        let nexps = self.normalise_records(train)?;
        let (iterations, rms_before, rms_after) =
            optimise(self, &nexps, focus, max_iter, true, true, observer)?;
        self.summary.focus = focus;
        self.summary.lm_iterations += iterations;
        self.summary.rms_after_lm = rms_after;
        Ok(RefineReport {
            iterations,
            rms_before,
            rms_after,
        })
    }

    /// Cost Σ e² (normalised) and its gradient −2 Jᵀe w.r.t. all parameters
    /// (simulation error for `Focus::Simulation`), for checks against finite
    /// differences.
    pub fn cost_gradient(
        &self,
        train: &Records,
        focus: Focus,
    ) -> Result<(f64, Vec<f64>), LmnError> {
        let nexps = self.normalise_records(train)?;
        let np = self.parameters().len();
        let (c, _, g, _) = total(self, &nexps, focus, np, true)
            .ok_or_else(|| LmnError::Unstable("the simulation diverged".into()))?;
        Ok((c, g.iter().map(|v| -2.0 * v).collect()))
    }
}

impl LmnModel {
    /// Every record split for the regressors and normalised (the output as
    /// long as the inputs).
    pub(crate) fn normalise_records(&self, data: &Records) -> Result<Vec<NormExp>, LmnError> {
        data.iter()
            .map(|d| self.normalise_full(&Experiment::of_record(d, &self.regressors)?))
            .collect()
    }
}
