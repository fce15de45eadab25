//! Smoothing from a stored filter history.
//!
//! * **FFBSm** (forward filtering, backward smoothing; marginal smoother, O(N²T)):
//!   `W_{t|T}^i = W_t^i Σ_j W_{t+1|T}^j f(x_{t+1}^j | x_t^i) / Σ_k W_t^k f(x_{t+1}^j | x_t^k)`.
//! * **Backward simulation** (FFBSi): draw `J_{T-1} ~ W_{T-1}`, then
//!   `J_t = i` with probability `∝ W_t^i f(x_{t+1}^{J_{t+1}} | x_t^i)`; each draw is a
//!   trajectory from the smoothing distribution. O(NT) per trajectory exactly,
//!   or O(T) expected with the rejection sampler of Douc et al. (2011) when
//!   `f ≤ exp(bound)`: propose `i ~ W_t`, accept with probability `f / exp(bound)`.
//! * **Fixed-lag**: `E[x_t | y_{0:t+L}] ≈ Σ_i W_{t+L}^i x_t^{(i)}`, tracing each particle's
//!   ancestral line back `L` steps (reduced path degeneracy compared with full genealogies).
use crate::error::{Result, SmcError};
use crate::filter::{FilterHistory, StepSummary};
use crate::model::{Observations, StateVector, TransitionDensity};
use crate::rng::{domain, stream};
use rand::Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

fn check_lengths<S, O>(h: &FilterHistory<S>, obs: &Observations<'_, O>) -> Result<()> {
    if h.is_empty() {
        return Err(SmcError::MissingHistory);
    }
    if h.len() != obs.len() {
        return Err(SmcError::LengthMismatch {
            what: "history vs observations",
            expected: obs.len(),
            got: h.len(),
        });
    }
    Ok(())
}

/// Online log-sum-exp accumulator.
#[derive(Clone, Copy)]
struct Lse {
    max: f64,
    sum: f64,
}
impl Lse {
    fn new() -> Self {
        Self {
            max: f64::NEG_INFINITY,
            sum: 0.0,
        }
    }
    #[inline]
    fn add(&mut self, v: f64) {
        if v <= self.max {
            if v > f64::NEG_INFINITY {
                self.sum += (v - self.max).exp();
            }
        } else {
            self.sum = self.sum * (self.max - v).exp() + 1.0;
            self.max = v;
        }
    }
    fn value(&self) -> f64 {
        self.max + self.sum.ln()
    }
}

/// FFBSm marginal smoothing weights `W_{t|T}^i` (flat, `[t * N + i]`).
///
/// ```
/// use gb_smc::{FilterConfig, LinearGaussian, Observations, smoothing};
/// let m = LinearGaussian::ar1(0.9, 1.0, 0.5).unwrap();
/// let (_, y) = m.simulate(20, 1);
/// let obs = Observations::new(&y);
/// let out = FilterConfig::new(100).store_history(true).build().unwrap().run(&m, &obs).unwrap();
/// let h = out.history.unwrap();
/// let w = smoothing::ffbsm_weights(&m, &h, &obs).unwrap();
/// let s = smoothing::weighted_moments(&h, &w);
/// assert_eq!(s.len(), 20);
/// ```
pub fn ffbsm_weights<M: TransitionDensity>(
    model: &M,
    h: &FilterHistory<M::State>,
    obs: &Observations<'_, M::Obs>,
) -> Result<Vec<f64>> {
    check_lengths(h, obs)?;
    let n = h.n;
    let tt = h.len();
    let mut ws = vec![0.0; n * tt];
    ws[(tt - 1) * n..].copy_from_slice(h.weights_at(tt - 1));
    let mut logden = vec![0.0; n];
    for t in (0..tt - 1).rev() {
        let (xt, wt, xn) = (h.states_at(t), h.weights_at(t), h.states_at(t + 1));
        let u = obs.input(t + 1);
        let (head, tail) = ws.split_at_mut((t + 1) * n);
        let wnext = &tail[..n];
        let wcur = &mut head[t * n..];
        logden.par_iter_mut().enumerate().for_each(|(j, d)| {
            if wnext[j] > 0.0 {
                let mut acc = Lse::new();
                for (xi, &wi) in xt.iter().zip(wt) {
                    if wi > 0.0 {
                        acc.add(wi.ln() + model.log_transition_density(t + 1, xi, &xn[j], u));
                    }
                }
                *d = acc.value();
            } else {
                *d = f64::INFINITY;
            }
        });
        wcur.par_iter_mut().enumerate().for_each(|(i, w)| {
            *w = if wt[i] > 0.0 {
                let mut s = 0.0;
                for j in 0..n {
                    if wnext[j] > 0.0 && logden[j] < f64::INFINITY {
                        let lf = model.log_transition_density(t + 1, &xt[i], &xn[j], u);
                        s += wnext[j] * (lf - logden[j]).exp();
                    }
                }
                wt[i] * s
            } else {
                0.0
            };
        });
        let total: f64 = wcur.iter().sum();
        if !(total > 0.0 && total.is_finite()) {
            return Err(SmcError::AllWeightsZero { t });
        }
        wcur.iter_mut().for_each(|w| *w /= total);
    }
    Ok(ws)
}

/// Weighted mean and variance per step of history particles with weights `w` (flat `[t * N + i]`).
pub fn weighted_moments<S: StateVector>(h: &FilterHistory<S>, w: &[f64]) -> Vec<StepSummary> {
    let n = h.n;
    let mut buf = Vec::new();
    (0..h.len())
        .map(|t| crate::filter::summarise(h.states_at(t), &w[t * n..(t + 1) * n], &[], &mut buf))
        .collect()
}

/// How backward simulation draws ancestors.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum BackwardMethod {
    /// Exact O(N) categorical draw per step and trajectory.
    Exact,
    /// Rejection sampling with the bound of [`TransitionDensity::log_transition_bound`]
    /// (O(1) expected per draw); falls back to `Exact` after `max_tries` rejections
    /// or when the model has no bound.
    Rejection {
        /// Proposals before falling back to the exact draw.
        max_tries: usize,
    },
}

/// Trajectories drawn from the smoothing distribution, `states[t * M + m]`.
#[derive(Debug, Clone)]
pub struct Trajectories<S> {
    /// Number of trajectories `M`.
    pub m: usize,
    /// States, time-major.
    pub states: Vec<S>,
    /// Fraction of draws accepted by the rejection sampler (1 for `Exact`).
    pub acceptance_rate: f64,
}

impl<S: StateVector> Trajectories<S> {
    /// Sample mean and variance of the trajectories at each step.
    pub fn moments(&self) -> Vec<StepSummary> {
        let w = vec![1.0 / self.m as f64; self.m];
        let mut buf = Vec::new();
        self.states
            .chunks(self.m)
            .map(|c| crate::filter::summarise(c, &w, &[], &mut buf))
            .collect()
    }
}

/// Backward simulation of `n_traj` smoothing trajectories.
///
/// ```
/// use gb_smc::{FilterConfig, LinearGaussian, Observations, smoothing::{backward_simulation, BackwardMethod}};
/// let m = LinearGaussian::ar1(0.9, 1.0, 0.5).unwrap();
/// let (_, y) = m.simulate(20, 1);
/// let obs = Observations::new(&y);
/// let h = FilterConfig::new(200).store_history(true).build().unwrap().run(&m, &obs).unwrap().history.unwrap();
/// let tr = backward_simulation(&m, &h, &obs, 50, 3, BackwardMethod::Rejection { max_tries: 50 }).unwrap();
/// assert_eq!(tr.states.len(), 20 * 50);
/// ```
pub fn backward_simulation<M: TransitionDensity>(
    model: &M,
    h: &FilterHistory<M::State>,
    obs: &Observations<'_, M::Obs>,
    n_traj: usize,
    seed: u64,
    method: BackwardMethod,
) -> Result<Trajectories<M::State>> {
    check_lengths(h, obs)?;
    if n_traj == 0 {
        return Err(SmcError::InvalidParameter {
            name: "n_traj",
            value: 0.0,
            reason: "need at least one trajectory",
        });
    }
    let n = h.n;
    let tt = h.len();
    let mut idx = vec![0usize; n_traj * tt];
    let mut cum = vec![0.0; n];
    let cumulate = |w: &[f64], cum: &mut [f64]| {
        let mut s = 0.0;
        for (c, &x) in cum.iter_mut().zip(w) {
            s += x;
            *c = s;
        }
        s
    };
    let pick = |cum: &[f64], u: f64| cum.partition_point(|&c| c <= u).min(cum.len() - 1);
    let total = cumulate(h.weights_at(tt - 1), &mut cum);
    for (m, j) in idx[(tt - 1) * n_traj..].iter_mut().enumerate() {
        let mut rng = stream(seed, domain::BACKWARD, (tt - 1) as u64, m as u64);
        *j = pick(&cum, rng.random::<f64>() * total);
    }
    let mut accepted = 0usize;
    let mut proposals = 0usize;
    for t in (0..tt - 1).rev() {
        let (xt, wt, xn) = (h.states_at(t), h.weights_at(t), h.states_at(t + 1));
        let u = obs.input(t + 1);
        let total = cumulate(wt, &mut cum);
        let bound = match method {
            BackwardMethod::Rejection { max_tries } => {
                model.log_transition_bound(t + 1, u).map(|b| (b, max_tries))
            }
            BackwardMethod::Exact => None,
        };
        let (head, tail) = idx.split_at_mut((t + 1) * n_traj);
        let next = &tail[..n_traj];
        let cur = &mut head[t * n_traj..];
        let cum_ref = &cum;
        let counts: (usize, usize) = cur
            .par_iter_mut()
            .enumerate()
            .map_init(Vec::new, |buf: &mut Vec<f64>, (m, j)| {
                let mut rng = stream(seed, domain::BACKWARD, t as u64, m as u64);
                let target = &xn[next[m]];
                let mut tries = 0;
                if let Some((b, max_tries)) = bound {
                    while tries < max_tries {
                        tries += 1;
                        let i = pick(cum_ref, rng.random::<f64>() * total);
                        let lf = model.log_transition_density(t + 1, &xt[i], target, u);
                        if rng.random::<f64>().ln() < lf - b {
                            *j = i;
                            return (1, tries);
                        }
                    }
                }
                // exact categorical draw
                buf.clear();
                let mut max = f64::NEG_INFINITY;
                for (xi, &wi) in xt.iter().zip(wt) {
                    let v = if wi > 0.0 {
                        wi.ln() + model.log_transition_density(t + 1, xi, target, u)
                    } else {
                        f64::NEG_INFINITY
                    };
                    max = max.max(v);
                    buf.push(v);
                }
                let mut s = 0.0;
                for v in buf.iter_mut() {
                    s += (*v - max).exp();
                    *v = s;
                }
                *j = pick(buf, rng.random::<f64>() * s);
                (0, tries)
            })
            .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
        accepted += counts.0;
        proposals += counts.1;
    }
    let states = idx
        .chunks(n_traj)
        .enumerate()
        .flat_map(|(t, c)| c.iter().map(move |&i| h.states_at(t)[i].clone()))
        .collect();
    Ok(Trajectories {
        m: n_traj,
        states,
        acceptance_rate: if proposals == 0 {
            1.0
        } else {
            accepted as f64 / proposals as f64
        },
    })
}

/// Fixed-lag smoother `E[x_t | y_{0:min(t+L, T-1)}]` (mean and variance per step)
/// from the genealogy stored in the history.
///
/// ```
/// use gb_smc::{FilterConfig, LinearGaussian, Observations, smoothing::fixed_lag};
/// let m = LinearGaussian::ar1(0.9, 1.0, 0.5).unwrap();
/// let (_, y) = m.simulate(30, 1);
/// let obs = Observations::new(&y);
/// let h = FilterConfig::new(300).store_history(true).build().unwrap().run(&m, &obs).unwrap().history.unwrap();
/// let s = fixed_lag(&h, 5).unwrap();
/// assert_eq!(s.len(), 30);
/// ```
pub fn fixed_lag<S: StateVector + Sync>(
    h: &FilterHistory<S>,
    lag: usize,
) -> Result<Vec<StepSummary>> {
    if h.is_empty() {
        return Err(SmcError::MissingHistory);
    }
    let n = h.n;
    let tt = h.len();
    Ok((0..tt)
        .into_par_iter()
        .map(|t| {
            let s = (t + lag).min(tt - 1);
            let w = h.weights_at(s);
            let xs = h.states_at(t);
            let mut line: Vec<usize> = (0..n).collect();
            for tau in (t + 1..=s).rev() {
                let anc = h.ancestors_at(tau);
                line.iter_mut().for_each(|j| *j = anc[*j]);
            }
            let particles: Vec<&S> = line.iter().map(|&j| &xs[j]).collect();
            let d = xs[0].components().len();
            let mut mean = vec![0.0; d];
            let mut var = vec![0.0; d];
            for (p, &wi) in particles.iter().zip(w) {
                for (m, &c) in mean.iter_mut().zip(p.components()) {
                    *m += wi * c;
                }
            }
            for (p, &wi) in particles.iter().zip(w) {
                for ((v, &m), &c) in var.iter_mut().zip(&mean).zip(p.components()) {
                    *v += wi * (c - m) * (c - m);
                }
            }
            StepSummary {
                mean,
                var,
                quantiles: Vec::new(),
            }
        })
        .collect())
}
