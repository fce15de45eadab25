//! The SMC path (Hauth 2008, ch. 5): hidden states and parameters under
//! non-Gaussian process and measurement noise, by particle marginal
//! Metropolis–Hastings (Andrieu, Doucet & Holenstein 2010) on `gb-smc`.
//!
//! The state-space model `x_{t+1} = F_θ(x_t, u_t) + v_t`, `y_t = G_θ(x_t, u_t) + w_t`
//! has no closed-form filter; the bootstrap particle filter (Doucet &
//! Johansen 2009; Chopin & Papaspiliopoulos 2020) gives an unbiased
//! likelihood estimate `p̂_θ(y)`. The parameter `θ` holds the log-scales of
//! `v` and `w` and the largest wavelet coefficients; the coefficients get
//! the **sparsity prior** `p(c) ∝ exp(−|c|/b)` (Laplace, the Bayesian form of
//! soft thresholding), the log-scales a wide Gaussian prior. The chain starts
//! at the output-error estimate; the final model is the posterior mean if its
//! particle likelihood beats the output-error model's, and the report says
//! which path won.
use crate::error::{ModelError, Result};
use crate::identify::{get_params, layout, set_params, IdentificationPath, Param};
use crate::model::{NoiseModel, SimScratch, SparseStateSpace};
use gb_core::{Observer, SubTask};
use gb_smc::estimation::{ParametricModel, Pmmh, PmmhConfig};
use gb_smc::noise::Noise;
use gb_smc::{FilterConfig, Observations, SmcRng, StateSpaceModel};
use serde::{Deserialize, Serialize};
use std::cell::RefCell;

/// Largest state dimension of the SMC path (states are `[f64; 8]`, the fast
/// `Copy` path of `gb-smc`).
pub const SMC_MAX_STATES: usize = 8;

thread_local! {
    static SCRATCH: RefCell<SimScratch> = RefCell::new(SimScratch::default());
}

/// A [`SparseStateSpace`] with its noise, as a `gb_smc::StateSpaceModel`.
pub(crate) struct NoisyModel<'a> {
    model: SparseStateSpace,
    inputs: &'a [Vec<f64>],
    hyst: &'a [Vec<f64>],
    process: Vec<Noise>,
    measurement: Noise,
}

impl NoisyModel<'_> {
    fn row(&self, t: usize, u: &mut [f64], h: &mut [f64]) {
        for (j, v) in u.iter_mut().enumerate() {
            *v = self.inputs[j][t];
        }
        for (k, v) in h.iter_mut().enumerate() {
            *v = self.hyst[k][t];
        }
    }
}

impl StateSpaceModel for NoisyModel<'_> {
    type State = [f64; SMC_MAX_STATES];
    type Obs = f64;

    fn sample_initial(&self, _u: &[f64], rng: &mut SmcRng) -> Self::State {
        let mut x = [0.0; SMC_MAX_STATES];
        for (i, xi) in x.iter_mut().take(self.model.n_states).enumerate() {
            *xi = self.model.x0[i] + self.process[i].sample(rng);
        }
        x
    }

    fn sample_transition(
        &self,
        t: usize,
        prev: &Self::State,
        _u: &[f64],
        rng: &mut SmcRng,
    ) -> Self::State {
        let n = self.model.n_states;
        let mut u = [0.0; 8];
        let mut h = [0.0; 8];
        let (nu, nh) = (self.model.n_inputs, self.model.hysteresis.len());
        self.row(t - 1, &mut u[..nu], &mut h[..nh]);
        SCRATCH.with(|s| {
            let mut s = s.borrow_mut();
            s.x.clear();
            s.x.extend_from_slice(&prev[..n]);
            s.xn.resize(n, 0.0);
            self.model.advance(&u[..nu], &h[..nh], &mut s);
            let mut x = [0.0; SMC_MAX_STATES];
            for i in 0..n {
                x[i] = s.x[i] + self.process[i].sample(rng);
            }
            x
        })
    }

    fn log_observation(&self, t: usize, x: &Self::State, y: &f64, _u: &[f64]) -> f64 {
        let n = self.model.n_states;
        let mut u = [0.0; 8];
        let mut h = [0.0; 8];
        let (nu, nh) = (self.model.n_inputs, self.model.hysteresis.len());
        self.row(t, &mut u[..nu], &mut h[..nh]);
        SCRATCH.with(|s| {
            let mut s = s.borrow_mut();
            let s = &mut *s;
            let yh = self
                .model
                .output(&x[..n], &u[..nu], &h[..nh], &mut s.eval, &mut s.args);
            self.measurement.log_pdf(y - yh)
        })
    }
}

/// Options of the SMC path (validated by [`SmcParams::check`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SmcParams {
    /// Particles of the filter.
    pub particles: usize,
    /// PMMH iterations (including burn-in).
    pub iterations: usize,
    /// Iterations discarded from the posterior mean.
    pub burn_in: usize,
    /// Largest coefficients sampled (the rest stays at the OE estimate).
    pub coefficients: usize,
    /// Measurement-noise family at unit scale (scaled by the OE RMSE).
    pub measurement: NoiseModel,
    /// Process-noise family at unit scale (scaled by `process_fraction` ×
    /// the standard deviation of each simulated state's increments).
    pub process: NoiseModel,
    /// Initial process-noise level relative to the state increments.
    pub process_fraction: f64,
    /// Seed.
    pub seed: u64,
}

impl Default for SmcParams {
    fn default() -> Self {
        Self {
            particles: 200,
            iterations: 300,
            burn_in: 100,
            coefficients: 6,
            measurement: NoiseModel::Gaussian { sd: 1.0 },
            process: NoiseModel::Gaussian { sd: 1.0 },
            process_fraction: 0.05,
            seed: 1,
        }
    }
}

/// Validated [`SmcParams`].
#[derive(Debug, Clone, PartialEq)]
pub struct Smc {
    params: SmcParams,
}

impl SmcParams {
    /// Defaults: 200 particles, 300 iterations, Gaussian noise.
    pub fn new() -> Self {
        Self::default()
    }
    /// Sets the number of particles.
    pub fn particles(mut self, n: usize) -> Self {
        self.particles = n;
        self
    }
    /// Sets the PMMH iterations and burn-in.
    pub fn iterations(mut self, n: usize, burn_in: usize) -> Self {
        self.iterations = n;
        self.burn_in = burn_in;
        self
    }
    /// Sets the measurement-noise family (unit scale).
    pub fn measurement(mut self, n: NoiseModel) -> Self {
        self.measurement = n;
        self
    }
    /// Sets the process-noise family (unit scale).
    pub fn process(mut self, n: NoiseModel) -> Self {
        self.process = n;
        self
    }
    /// Sets the number of sampled coefficients.
    pub fn coefficients(mut self, n: usize) -> Self {
        self.coefficients = n;
        self
    }
    /// Sets the seed.
    pub fn seed(mut self, s: u64) -> Self {
        self.seed = s;
        self
    }
    /// Validates the options once.
    pub fn check(self) -> Result<Smc> {
        if self.particles == 0 || self.iterations == 0 || self.burn_in >= self.iterations {
            return Err(ModelError::InvalidArgument(
                "particles >= 1, iterations >= 1 and burn_in < iterations are needed".into(),
            ));
        }
        if !(self.process_fraction.is_finite() && self.process_fraction > 0.0) {
            return Err(ModelError::InvalidArgument(
                "process_fraction must be > 0".into(),
            ));
        }
        gb_smc::noise::Noise::from_model(&self.measurement)?;
        gb_smc::noise::Noise::from_model(&self.process)?;
        Ok(Smc { params: self })
    }
}

/// What the SMC path did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SmcReport {
    /// Which path produced the returned model.
    pub path: IdentificationPath,
    /// Particle log-likelihood of the output-error model (noise at the chain start).
    pub log_likelihood_oe: f64,
    /// Particle log-likelihood of the posterior-mean model.
    pub log_likelihood_smc: f64,
    /// Log-likelihood of the returned model.
    pub log_likelihood: f64,
    /// PMMH acceptance rate.
    pub acceptance_rate: f64,
    /// Posterior means of `θ` = (ln process scale, ln measurement scale, coefficients…).
    pub posterior_mean: Vec<f64>,
    /// Posterior standard deviations of `θ`.
    pub posterior_sd: Vec<f64>,
}

struct Problem<'a> {
    base: SparseStateSpace,
    cols: Vec<Param>,
    inputs: &'a [Vec<f64>],
    hyst: &'a [Vec<f64>],
    proc_scale: Vec<f64>,
    meas_scale: f64,
    process: NoiseModel,
    measurement: NoiseModel,
    laplace: Vec<f64>,
}

impl Problem<'_> {
    fn model_at(&self, theta: &[f64]) -> Option<SparseStateSpace> {
        let mut m = self.base.clone();
        set_params(&mut m, &self.cols, &theta[2..]).ok()?;
        let kp = theta[0].exp();
        let km = theta[1].exp();
        m.process_noise = self
            .proc_scale
            .iter()
            .map(|s| self.process.scaled(s * kp))
            .collect();
        m.measurement_noise = self.measurement.scaled(self.meas_scale * km);
        Some(m)
    }
}

impl<'a> ParametricModel for Problem<'a> {
    type Model = NoisyModel<'a>;
    fn dim(&self) -> usize {
        2 + self.cols.len()
    }
    fn build(&self, theta: &[f64]) -> Option<NoisyModel<'a>> {
        if theta.iter().any(|v| !v.is_finite()) || theta[0].abs() > 20.0 || theta[1].abs() > 20.0 {
            return None;
        }
        let m = self.model_at(theta)?;
        let process = m
            .process_noise
            .iter()
            .map(gb_smc::noise::Noise::from_model)
            .collect::<std::result::Result<Vec<_>, _>>()
            .ok()?;
        let measurement = gb_smc::noise::Noise::from_model(&m.measurement_noise).ok()?;
        Some(NoisyModel {
            model: m,
            inputs: self.inputs,
            hyst: self.hyst,
            process,
            measurement,
        })
    }
    fn log_prior(&self, theta: &[f64]) -> f64 {
        let mut lp = -0.5 * (theta[0] / 3.0).powi(2) - 0.5 * (theta[1] / 3.0).powi(2);
        for (c, b) in theta[2..].iter().zip(&self.laplace) {
            lp -= c.abs() / b;
        }
        lp
    }
}

impl Smc {
    /// The options.
    pub fn params(&self) -> &SmcParams {
        &self.params
    }

    /// Particle log-likelihood `log p̂(y)` of `model` with its own noise.
    pub fn log_likelihood(
        &self,
        model: &SparseStateSpace,
        inputs: &[Vec<f64>],
        y: &[f64],
    ) -> Result<f64> {
        if model.n_states > SMC_MAX_STATES || model.n_inputs > 8 || model.hysteresis.len() > 8 {
            return Err(ModelError::InvalidArgument(format!(
                "the SMC path supports up to {SMC_MAX_STATES} states, 8 inputs and 8 Preisach components"
            )));
        }
        let hyst = model.hysteresis_outputs(inputs)?;
        let nm = NoisyModel {
            model: model.clone(),
            inputs,
            hyst: &hyst,
            process: model
                .process_noise
                .iter()
                .map(gb_smc::noise::Noise::from_model)
                .collect::<std::result::Result<Vec<_>, _>>()?,
            measurement: gb_smc::noise::Noise::from_model(&model.measurement_noise)?,
        };
        let pf = FilterConfig::new(self.params.particles)
            .seed(self.params.seed)
            .build()?;
        Ok(pf.run(&nm, &Observations::new(y))?.log_likelihood)
    }

    /// Runs PMMH from the output-error model `oe` (see the module docs) and
    /// returns the better of the two models with the report.
    pub fn fit(
        &self,
        oe: &SparseStateSpace,
        inputs: &[Vec<f64>],
        y: &[f64],
        obs: &dyn Observer,
    ) -> Result<(SparseStateSpace, SmcReport)> {
        let p = &self.params;
        let len = oe.check_inputs(inputs)?;
        if len != y.len() || y.iter().any(|v| !v.is_finite()) {
            return Err(ModelError::InvalidArgument(
                "outputs must be finite and as long as the inputs".into(),
            ));
        }
        if oe.n_states > SMC_MAX_STATES || oe.n_inputs > 8 || oe.hysteresis.len() > 8 {
            return Err(ModelError::InvalidArgument(format!(
                "the SMC path supports up to {SMC_MAX_STATES} states, 8 inputs and 8 Preisach components"
            )));
        }
        // scales from the deterministic simulation
        let (yh, xs) = oe.simulate_states(inputs)?;
        let n = oe.n_states;
        let rmse = gb_core::metrics::rmse(y, &yh)
            .map_err(|e| ModelError::InvalidArgument(e.to_string()))?
            .max(1e-12);
        let proc_scale: Vec<f64> = (0..n)
            .map(|i| {
                let d: Vec<f64> = (1..len)
                    .map(|t| xs[t * n + i] - xs[(t - 1) * n + i])
                    .collect();
                (p.process_fraction * gb_core::metrics::std(&d)).max(1e-12)
            })
            .collect();
        // the largest coefficients
        let all = layout(oe);
        let vals = get_params(oe, &all);
        let mut coef: Vec<(f64, Param)> = all
            .iter()
            .zip(&vals)
            .filter(|(p, _)| matches!(p, Param::Coef(..) | Param::Hyst(..)))
            .map(|(p, v)| (v.abs(), *p))
            .collect();
        coef.sort_by(|a, b| b.0.total_cmp(&a.0));
        coef.truncate(p.coefficients);
        let cols: Vec<Param> = coef.iter().map(|c| c.1).collect();
        let mean_abs = coef.iter().map(|c| c.0).sum::<f64>() / coef.len().max(1) as f64;
        let hyst = oe.hysteresis_outputs(inputs)?;
        let problem = Problem {
            base: oe.clone(),
            laplace: vec![mean_abs.max(1e-12); cols.len()],
            cols,
            inputs,
            hyst: &hyst,
            proc_scale,
            meas_scale: rmse,
            process: p.process.clone(),
            measurement: p.measurement.clone(),
        };
        let mut theta0 = vec![0.0, 0.0];
        theta0.extend(get_params(oe, &problem.cols));
        let mut step = vec![0.1, 0.05];
        step.extend(
            theta0[2..]
                .iter()
                .map(|c| 0.01 * c.abs().max(mean_abs * 0.1)),
        );
        let mut cfg = PmmhConfig::new(p.particles, p.iterations, step);
        cfg.burn_in = p.burn_in;
        cfg.seed = p.seed;
        cfg.adapt_start = (p.iterations / 3).max(50);
        let observations = Observations::new(y);
        let total = p.iterations;
        // PMMH reports its iterations into 0..total of total + 1 steps
        let chain = SubTask {
            outer: obs,
            offset: 0,
            span: total,
            total: total + 1,
        };
        let res = Pmmh::new(cfg)?.run(&problem, &observations, &theta0, &chain)?;
        let mean: Vec<f64> = res.summary.iter().map(|s| s.mean).collect();
        let sd: Vec<f64> = res.summary.iter().map(|s| s.sd).collect();
        let start = problem
            .model_at(&theta0)
            .ok_or_else(|| ModelError::Numerical("start model".into()))?;
        let post = problem
            .model_at(&mean)
            .ok_or_else(|| ModelError::Numerical("posterior mean model".into()))?;
        let ll_oe = self.log_likelihood(&start, inputs, y)?;
        let ll_smc = self
            .log_likelihood(&post, inputs, y)
            .unwrap_or(f64::NEG_INFINITY);
        obs.progress(total + 1, total + 1, "done");
        let (model, path, ll) = if ll_smc > ll_oe {
            (post, IdentificationPath::Smc, ll_smc)
        } else {
            (start, IdentificationPath::OutputError, ll_oe)
        };
        Ok((
            model,
            SmcReport {
                path,
                log_likelihood_oe: ll_oe,
                log_likelihood_smc: ll_smc,
                log_likelihood: ll,
                acceptance_rate: res.acceptance_rate,
                posterior_mean: mean,
                posterior_sd: sd,
            },
        ))
    }
}
