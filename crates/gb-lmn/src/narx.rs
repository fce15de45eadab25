//! Global Levenberg–Marquardt over all local-model and split parameters
//! (Nelles 2020, sec. 14.6 and ch. 19): NARX (one-step prediction error,
//! measured output lags) or NOE (simulation error).
//!
//! For NOE the sensitivities S(k) = ∂ŷ(k)/∂p follow the recursion
//!
//! S(k) = ∂f/∂p + Σ_{x taps y(k−i)} ∂f/∂x_j · S(k−i) + Σ_{z taps y(k−i)} ∂f/∂z_d · S(k−i)
//!
//! with ∂f/∂z from the weight-function derivatives (see [`crate::tree`]);
//! samples of the init window have S = 0. JᵀJ and Jᵀe are accumulated in
//! blocks of 64 rows (one GEMM per block), J is never stored. A step solves
//! (JᵀJ + λ diag JᵀJ) δ = Jᵀe and is accepted only if the cost falls, the
//! simulation stays bounded and (stability guard, affine local models) every
//! local model's autoregressive part has spectral radius < 0.9995.
use crate::lmn::{Eval, Focus, LmnModel, DIVERGED};
use crate::regressors::{NormExp, Signal};
use crate::{Experiment, LmnError};
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

const MAX_RADIUS: f64 = 0.9995;

/// Cost Σ e² and, with `jac`, JᵀJ and Jᵀe over the first `nact` parameters,
/// for one experiment. `None` if the simulation diverged.
type Part = (f64, DMatrix<f64>, DVector<f64>);

fn accumulate(m: &LmnModel, e: &NormExp, focus: Focus, nact: usize, jac: bool) -> Option<Part> {
    let mut ev: Eval = m.eval_scratch();
    let np = m.parameters().len();
    let n = e.y.len();
    let k0 = m.max_lag().min(n);
    let sim = focus == Focus::Simulation && m.regressors.max_output_lag() > 0;
    let mut jtj = DMatrix::<f64>::zeros(if jac { nact } else { 0 }, if jac { nact } else { 0 });
    let mut jte = DVector::<f64>::zeros(if jac { nact } else { 0 });
    let mut out = e.y.clone();
    let ring = m.regressors.max_output_lag().max(1);
    let mut sy = if jac && sim {
        vec![0.0; ring * nact]
    } else {
        vec![]
    };
    let mut gp = vec![0.0; if jac { np } else { 0 }];
    let mut snew = vec![0.0; nact];
    const BLOCK: usize = 64;
    let mut blk = DMatrix::<f64>::zeros(if jac { BLOCK } else { 0 }, nact);
    let mut nb = 0;
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
        for (a, s) in snew.iter().enumerate() {
            jte[a] += s * err;
            blk[(nb, a)] = *s;
        }
        nb += 1;
        if nb == BLOCK {
            jtj.gemm_tr(1.0, &blk, &blk, 1.0);
            nb = 0;
        }
    }
    if jac && nb > 0 {
        let part = blk.rows(0, nb);
        jtj.gemm_tr(1.0, &part, &part, 1.0);
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

type Acc = (f64, DMatrix<f64>, DVector<f64>, usize);

fn total(m: &LmnModel, parts: &[NormExp], focus: Focus, nact: usize, jac: bool) -> Option<Acc> {
    let res: Vec<Option<Part>> = parts
        .par_iter()
        .map(|e| accumulate(m, e, focus, nact, jac))
        .collect();
    let mut cost = 0.0;
    let d = if jac { nact } else { 0 };
    let mut jtj = DMatrix::<f64>::zeros(d, d);
    let mut jte = DVector::<f64>::zeros(d);
    let mut cnt = 0;
    for (r, e) in res.into_iter().zip(parts) {
        let (c, a, b) = r?;
        cost += c;
        cnt += e.y.len().saturating_sub(m.max_lag());
        if jac {
            jtj += a;
            jte += b;
        }
    }
    Some((cost, jtj, jte, cnt))
}

/// Global LM; returns (iterations, rms before, rms after) in normalised units.
pub(crate) fn optimise(
    m: &mut LmnModel,
    exps: &[NormExp],
    focus: Focus,
    max_iter: usize,
    guard: bool,
    splits: bool,
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
    let radius_ok = |c: &LmnModel, start: f64| -> bool {
        !use_guard || c.max_spectral_radius() < MAX_RADIUS.max(start)
    };
    let start_radius = if use_guard {
        m.max_spectral_radius()
    } else {
        0.0
    };
    let Some((c0, _, _, cnt)) = total(m, &parts, focus, nact, false) else {
        return Err(LmnError::Unstable(
            "the grown network diverges in simulation".into(),
        ));
    };
    let rms0 = (c0 / cnt.max(1) as f64).sqrt();
    let mut cost = c0;
    let mut lambda = 1e-3;
    let mut it = 0;
    while it < max_iter {
        it += 1;
        let Some((c, jtj, jte, _)) = total(m, &parts, focus, nact, true) else {
            break;
        };
        cost = c;
        let theta = m.parameters();
        let diag: Vec<f64> = (0..nact).map(|i| jtj[(i, i)]).collect();
        let dmax = diag.iter().copied().fold(0.0, f64::max).max(1e-300);
        let mut improved = false;
        let mut converged = false;
        for _ in 0..12 {
            let mut a = jtj.clone();
            for i in 0..nact {
                a[(i, i)] += lambda * diag[i].max(1e-9 * dmax) + 1e-12 * dmax;
            }
            let Some(ch) = a.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let delta = ch.solve(&jte);
            let mut trial = theta.clone();
            for (t, d) in trial.iter_mut().zip(delta.iter()) {
                *t += d;
            }
            let mut cand = m.clone();
            cand.set_parameters(&trial)?;
            if radius_ok(&cand, start_radius) {
                if let Some((ct, _, _, _)) = total(&cand, &parts, focus, nact, false) {
                    if ct < cost {
                        converged = (cost - ct) / cost.max(1e-300) < 1e-8;
                        *m = cand;
                        cost = ct;
                        lambda = (lambda / 3.0).max(1e-12);
                        improved = true;
                        break;
                    }
                }
            }
            lambda *= 4.0;
            if lambda > 1e12 {
                break;
            }
        }
        if !improved || converged {
            break;
        }
    }
    Ok((it, rms0, (cost / cnt.max(1) as f64).sqrt()))
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
        train: &[Experiment],
        focus: Focus,
        max_iter: usize,
    ) -> Result<RefineReport, LmnError> {
        let nexps = train
            .iter()
            .map(|e| self.normalise_full(e))
            .collect::<Result<Vec<_>, _>>()?;
        let (iterations, rms_before, rms_after) =
            optimise(self, &nexps, focus, max_iter, true, true)?;
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
        train: &[Experiment],
        focus: Focus,
    ) -> Result<(f64, Vec<f64>), LmnError> {
        let nexps = train
            .iter()
            .map(|e| self.normalise_full(e))
            .collect::<Result<Vec<_>, _>>()?;
        let np = self.parameters().len();
        let (c, _, g, _) = total(self, &nexps, focus, np, true)
            .ok_or_else(|| LmnError::Unstable("the simulation diverged".into()))?;
        Ok((c, g.iter().map(|v| -2.0 * v).collect()))
    }
}
