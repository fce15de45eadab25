//! Hidden-state estimates of a noisy [`SparseStateSpace`]: the bootstrap
//! particle filter's `p(x_t | y_{0:t})` and, optionally, backward-simulation
//! smoothing `p(x_t | y_{0:T-1})` (Godsill, Doucet & West 2004), summarised
//! per state and sample by the mean, the variance and a 95 % band (the
//! weighted 2.5 % and 97.5 % quantiles).
use crate::error::{ModelError, Result};
use crate::everett::WaveletEverett;
use crate::model::SparseStateSpace;
use crate::smc::{NoisyModel, Smc};
use gb_preisach::{InitialState, Preisach, PreisachState};
use gb_smc::smoothing::{backward_simulation, BackwardMethod};
use gb_smc::{FilterConfig, Observations, OnlineFilter, StepSummary};
use serde::{Deserialize, Serialize};

/// Largest number of smoothing trajectories (backward simulation).
pub const SMOOTHING_TRAJECTORIES: usize = 200;

/// Mean, variance and 95 % band of every state at every sample, `[state][t]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StateBand {
    /// Posterior mean.
    pub mean: Vec<Vec<f64>>,
    /// Posterior variance.
    pub var: Vec<Vec<f64>>,
    /// 2.5 % quantile.
    pub lo: Vec<Vec<f64>>,
    /// 97.5 % quantile.
    pub hi: Vec<Vec<f64>>,
}

impl StateBand {
    pub(crate) fn from_summaries(s: &[StepSummary], n: usize) -> Self {
        let col = |f: &dyn Fn(&StepSummary, usize) -> f64| -> Vec<Vec<f64>> {
            (0..n)
                .map(|i| s.iter().map(|st| f(st, i)).collect())
                .collect()
        };
        Self {
            mean: col(&|st, i| st.mean[i]),
            var: col(&|st, i| st.var[i]),
            lo: col(&|st, i| st.quantiles[i][0]),
            hi: col(&|st, i| st.quantiles[i][1]),
        }
    }
}

/// What [`Smc::filter_states`] estimated.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StateEstimate {
    /// `log p̂(y_{0:T-1}) = Σ_t log p̂(y_t | y_{0:t-1})`.
    pub log_likelihood: f64,
    /// The increments `log p̂(y_t | y_{0:t-1})` (the per-sample predictive
    /// log-likelihood).
    #[serde(default)]
    pub increments: Vec<f64>,
    /// Effective sample size of the particles after each step.
    pub ess: Vec<f64>,
    /// Filtered states `p(x_t | y_{0:t})`.
    pub filtered: StateBand,
    /// Smoothed states `p(x_t | y_{0:T-1})`, when asked for.
    pub smoothed: Option<StateBand>,
}

impl Smc {
    /// Filters (and with `smooth`, smooths) the hidden states of `model`
    /// under its own process and measurement noise (both must be proper:
    /// an output-error model without process noise has nothing to filter).
    /// `x_0 = x₀ + v_0`, `x_t = F(x_{t-1}, u_{t-1}) + v_t`, `y_t = G(x_t, u_t) + w_t`.
    pub fn filter_states(
        &self,
        model: &SparseStateSpace,
        inputs: &[Vec<f64>],
        y: &[f64],
        smooth: bool,
    ) -> Result<StateEstimate> {
        let len = model.check_inputs(inputs)?;
        if len != y.len() || y.iter().any(|v| !v.is_finite()) {
            return Err(ModelError::InvalidArgument(
                "outputs must be finite and as long as the inputs".into(),
            ));
        }
        let hyst = model.hysteresis_outputs(inputs)?;
        let nm = NoisyModel::new(model, inputs, &hyst)?;
        let p = self.params();
        let pf = FilterConfig::new(p.particles)
            .seed(p.seed)
            .store_history(smooth)
            .build()?;
        let obs = Observations::new(y);
        let (out, sums) = pf.run_summaries(&nm, &obs, &[0.025, 0.975])?;
        let n = model.n_states;
        let filtered = StateBand::from_summaries(&sums, n);
        let smoothed = match (smooth, &out.history) {
            (true, Some(h)) => {
                let m = p.particles.clamp(1, SMOOTHING_TRAJECTORIES);
                let tr = backward_simulation(
                    &nm,
                    h,
                    &obs,
                    m,
                    p.seed ^ 0x5eed,
                    BackwardMethod::Rejection { max_tries: 32 },
                )?;
                let w = vec![1.0 / m as f64; m];
                let mut buf = Vec::new();
                let s: Vec<StepSummary> = tr
                    .states
                    .chunks(m)
                    .map(|c| gb_smc::summarise(c, &w, &[0.025, 0.975], &mut buf))
                    .collect();
                Some(StateBand::from_summaries(&s, n))
            }
            _ => None,
        };
        Ok(StateEstimate {
            log_likelihood: out.log_likelihood,
            increments: out.log_likelihood_increments,
            ess: out.ess,
            filtered,
            smoothed,
        })
    }
}

/// The model side of online filtering ([`Smc::online_states`]): a noisy
/// [`SparseStateSpace`] fed one sample at a time.
pub struct StreamingModel {
    noisy: NoisyModel<'static>,
    preisach: Vec<(usize, Preisach<WaveletEverett>)>,
}

impl StreamingModel {
    /// `model` with its own process and measurement noise (both proper).
    pub fn new(model: &SparseStateSpace) -> Result<Self> {
        Ok(Self {
            noisy: NoisyModel::streaming(model)?,
            preisach: model
                .hysteresis
                .iter()
                .map(|h| (h.input, Preisach::new(h.everett.clone())))
                .collect(),
        })
    }
}

/// Filtered states of one sample (online use): `p(x_t | y_{0:t})`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StateStep {
    /// Posterior mean of every state.
    pub mean: Vec<f64>,
    /// 2.5 % quantile of every state.
    pub lo: Vec<f64>,
    /// 97.5 % quantile of every state.
    pub hi: Vec<f64>,
    /// `log p̂(y_t | y_{0:t-1})`.
    pub log_likelihood_increment: f64,
    /// Effective sample size after the step.
    pub ess: f64,
}

/// The particle filter of [`Smc::filter_states`] fed one sample at a time:
/// pushing a record row by row gives the filtered band of the batch run,
/// bit for bit (same particles, seed and random streams).
///
/// ```
/// use gb_model::{Smc, SmcParams, SparseStateSpace, StreamingModel, NoiseModel};
/// let mut m = SparseStateSpace::linear(vec![0.9], vec![1.0], vec![1.0], vec![0.0]).unwrap();
/// m.process_noise = vec![NoiseModel::Gaussian { sd: 0.1 }];
/// m.measurement_noise = NoiseModel::Gaussian { sd: 0.2 };
/// let u: Vec<f64> = (0..50).map(|t| (t as f64 * 0.3).sin()).collect();
/// let y = m.simulate(&[u.clone()]).unwrap();
/// let smc = SmcParams::new().particles(300).check().unwrap();
/// let batch = smc.filter_states(&m, &[u.clone()], &y, false).unwrap();
/// let sm = StreamingModel::new(&m).unwrap();
/// let mut online = smc.online_states(&sm).unwrap();
/// for t in 0..u.len() {
///     let step = online.push(&[u[t]], y[t]).unwrap();
///     assert_eq!(step.mean[0], batch.filtered.mean[0][t]);
/// }
/// assert_eq!(online.log_likelihood(), batch.log_likelihood);
/// ```
pub struct OnlineStates<'m> {
    model: &'m StreamingModel,
    filter: OnlineFilter<'m, NoisyModel<'static>>,
    preisach: Vec<PreisachState<f64>>,
    h: Vec<f64>,
    buf: Vec<(f64, f64)>,
}

impl Smc {
    /// An online filter of `model` ([`OnlineStates::push`] one sample at a
    /// time), with this configuration's particles and seed.
    pub fn online_states<'m>(&self, model: &'m StreamingModel) -> Result<OnlineStates<'m>> {
        let p = self.params();
        let preisach = model
            .preisach
            .iter()
            .map(|(_, p)| p.state(&InitialState::NegativeSaturation))
            .collect::<std::result::Result<Vec<_>, _>>()?;
        let pf = FilterConfig::new(p.particles).seed(p.seed).build()?;
        Ok(OnlineStates {
            model,
            filter: pf.online(&model.noisy),
            h: vec![0.0; preisach.len()],
            preisach,
            buf: Vec::new(),
        })
    }
}

impl OnlineStates<'_> {
    /// Filter sample `t` (the pushes so far): its inputs `u` and measured
    /// output `y`; returns the filtered states with their 95 % band.
    pub fn push(&mut self, u: &[f64], y: f64) -> Result<StateStep> {
        let nm = &self.model.noisy;
        if u.len() != nm.model.n_inputs || !y.is_finite() || u.iter().any(|v| !v.is_finite()) {
            return Err(ModelError::InvalidArgument(format!(
                "a sample needs {} finite inputs and a finite output",
                nm.model.n_inputs
            )));
        }
        for ((h, st), (input, p)) in self
            .h
            .iter_mut()
            .zip(&mut self.preisach)
            .zip(&self.model.preisach)
        {
            *h = p.step(st, u[*input]);
        }
        let t = self.filter.len();
        nm.set_row(t, u, &self.h);
        let inc = self.filter.push(&y, u)?;
        let s = gb_smc::summarise(
            self.filter.particles(),
            self.filter.weights(),
            &[0.025, 0.975],
            &mut self.buf,
        );
        let n = nm.model.n_states;
        Ok(StateStep {
            mean: s.mean[..n].to_vec(),
            lo: s.quantiles[..n].iter().map(|q| q[0]).collect(),
            hi: s.quantiles[..n].iter().map(|q| q[1]).collect(),
            log_likelihood_increment: inc,
            ess: self.filter.ess(),
        })
    }

    /// `log p̂(y_{0:t-1})` of the samples pushed so far.
    pub fn log_likelihood(&self) -> f64 {
        self.filter.log_likelihood()
    }

    /// Samples pushed so far.
    pub fn len(&self) -> usize {
        self.filter.len()
    }

    /// `true` before the first push.
    pub fn is_empty(&self) -> bool {
        self.filter.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::basis::SparseExpansion;
    use crate::model::{HysteresisTerm, NoiseModel, Target};
    use crate::SmcParams;

    /// A damped oscillator with a Preisach component on the velocity and
    /// process noise on both states.
    fn hysteretic() -> SparseStateSpace {
        let mut m = SparseStateSpace::linear(
            vec![1.0, 0.1, -0.2, 0.9],
            vec![0.0, 0.1],
            vec![1.0, 0.0],
            vec![0.0],
        )
        .unwrap();
        let mut h = SparseExpansion::new("bior2.2", vec![-1.5, -1.5], vec![1.5, 1.5]).unwrap();
        h.add_coarse_grid(1).unwrap();
        let n = h.len();
        h.set_values(&(0..n).map(|i| 0.03 * (i as f64).sin()).collect::<Vec<_>>())
            .unwrap();
        m.hysteresis.push(HysteresisTerm {
            target: Target::State(1),
            input: 0,
            everett: WaveletEverett::new(h).unwrap(),
        });
        m.process_noise = vec![NoiseModel::Gaussian { sd: 0.01 }; 2];
        m.measurement_noise = NoiseModel::Gaussian { sd: 0.05 };
        m
    }

    /// Pushing a record row by row gives the batch filter's bands and
    /// log-likelihood bit for bit, Preisach memory included (a Preisach
    /// output computed from another start or one sample late would differ).
    #[test]
    fn online_filter_equals_the_batch_filter_with_hysteresis() {
        let m = hysteretic();
        let len = 300;
        let u: Vec<f64> = (0..len)
            .map(|t| 1.2 * (t as f64 * 0.05).sin() * (t as f64 * 0.007).cos())
            .collect();
        let y: Vec<f64> = m
            .simulate(std::slice::from_ref(&u))
            .unwrap()
            .iter()
            .enumerate()
            .map(|(t, v)| v + 0.05 * ((t * 7919 % 101) as f64 / 50.0 - 1.0))
            .collect();
        let smc = SmcParams::new().particles(256).seed(9).check().unwrap();
        let batch = smc
            .filter_states(&m, std::slice::from_ref(&u), &y, false)
            .unwrap();
        let sm = StreamingModel::new(&m).unwrap();
        let mut online = smc.online_states(&sm).unwrap();
        for t in 0..len {
            let s = online.push(&[u[t]], y[t]).unwrap();
            for i in 0..2 {
                assert_eq!(s.mean[i], batch.filtered.mean[i][t], "x{i} at {t}");
                assert_eq!(s.lo[i], batch.filtered.lo[i][t], "x{i} at {t}");
                assert_eq!(s.hi[i], batch.filtered.hi[i][t], "x{i} at {t}");
            }
            assert_eq!(s.ess, batch.ess[t]);
        }
        assert_eq!(online.log_likelihood(), batch.log_likelihood);
        // without the Preisach component the filter differs: the test sees it
        let mut plain = m.clone();
        plain.hysteresis.clear();
        let sm = StreamingModel::new(&plain).unwrap();
        let mut online = smc.online_states(&sm).unwrap();
        for t in 0..len {
            online.push(&[u[t]], y[t]).unwrap();
        }
        assert_ne!(online.log_likelihood(), batch.log_likelihood);
        // bad samples are errors, not panics
        assert!(online.push(&[f64::NAN], 0.0).is_err());
        assert!(online.push(&[0.0, 1.0], 0.0).is_err());
    }
}
