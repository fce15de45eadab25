//! Hidden-state estimates of a noisy [`SparseStateSpace`]: the bootstrap
//! particle filter's `p(x_t | y_{0:t})` and, optionally, backward-simulation
//! smoothing `p(x_t | y_{0:T-1})` (Godsill, Doucet & West 2004), summarised
//! per state and sample by the mean, the variance and a 95 % band (the
//! weighted 2.5 % and 97.5 % quantiles).
use crate::error::{ModelError, Result};
use crate::model::SparseStateSpace;
use crate::smc::{NoisyModel, Smc};
use gb_smc::smoothing::{backward_simulation, BackwardMethod};
use gb_smc::{FilterConfig, Observations, StepSummary};
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
    fn from_summaries(s: &[StepSummary], n: usize) -> Self {
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
