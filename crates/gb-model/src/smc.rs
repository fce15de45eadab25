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
use gb_smc::estimation::{run_chains, ParametricModel, ParticleChoice, ParticleTuning, PmmhConfig};
use gb_smc::noise::Noise;
use gb_smc::{FilterConfig, Observations, SmcRng, StateSpaceModel, TransitionDensity};
use serde::{Deserialize, Serialize};
use std::borrow::Cow;
use std::cell::RefCell;

/// Largest state dimension of the SMC path (states are `[f64; 8]`, the fast
/// `Copy` path of `gb-smc`).
pub const SMC_MAX_STATES: usize = 8;

thread_local! {
    static SCRATCH: RefCell<SimScratch> = RefCell::new(SimScratch::default());
}

/// A [`SparseStateSpace`] with its noise, as a `gb_smc::StateSpaceModel`.
pub(crate) struct NoisyModel<'a> {
    pub(crate) model: SparseStateSpace,
    rows: Rows<'a>,
    process: Vec<Noise>,
    measurement: Noise,
}

/// Where the inputs `u_t` and Preisach outputs `h_t` of sample `t` come from.
enum Rows<'a> {
    /// A whole record (`[input][t]`, `[component][t]`).
    Batch {
        inputs: &'a [Vec<f64>],
        hyst: Cow<'a, [Vec<f64>]>,
    },
    /// Online use: the rows of samples `t − 1` and `t`, in slots `t mod 2`
    /// (set by [`NoisyModel::set_row`] before the filter sees sample `t`).
    Stream(Box<std::sync::RwLock<[StreamRow; 2]>>),
}

/// One sample's inputs and Preisach outputs (online use).
#[derive(Clone, Copy, Default)]
pub(crate) struct StreamRow {
    u: [f64; 8],
    h: [f64; 8],
}

impl<'a> NoisyModel<'a> {
    /// `model` with its own noise on `inputs` (`hyst`: its Preisach outputs).
    pub(crate) fn new(
        model: &SparseStateSpace,
        inputs: &'a [Vec<f64>],
        hyst: &'a [Vec<f64>],
    ) -> Result<Self> {
        Self::with_rows(
            model,
            Rows::Batch {
                inputs,
                hyst: Cow::Borrowed(hyst),
            },
        )
    }

    /// `model` with its own noise for online use: the rows come one at a
    /// time through [`set_row`](Self::set_row).
    pub(crate) fn streaming(model: &SparseStateSpace) -> Result<NoisyModel<'static>> {
        NoisyModel::with_rows(model, Rows::Stream(Default::default()))
    }

    fn with_rows(model: &SparseStateSpace, rows: Rows<'a>) -> Result<Self> {
        check_size(model)?;
        Ok(NoisyModel {
            model: model.clone(),
            rows,
            process: model
                .process_noise
                .iter()
                .map(Noise::from_model)
                .collect::<std::result::Result<Vec<_>, _>>()?,
            measurement: Noise::from_model(&model.measurement_noise)?,
        })
    }

    /// The noise-free transition `F(x_{t-1}, u_{t-1})` (the state at `t` before `v_t`).
    fn predict(&self, t: usize, prev: &[f64; SMC_MAX_STATES]) -> [f64; SMC_MAX_STATES] {
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
            x[..n].copy_from_slice(&s.x[..n]);
            x
        })
    }

    fn row(&self, t: usize, u: &mut [f64], h: &mut [f64]) {
        match &self.rows {
            Rows::Batch { inputs, hyst } => {
                for (j, v) in u.iter_mut().enumerate() {
                    *v = inputs[j][t];
                }
                for (k, v) in h.iter_mut().enumerate() {
                    *v = hyst[k][t];
                }
            }
            Rows::Stream(rows) => {
                let rows = rows
                    .read()
                    .unwrap_or_else(std::sync::PoisonError::into_inner);
                let r = &rows[t & 1];
                u.copy_from_slice(&r.u[..u.len()]);
                h.copy_from_slice(&r.h[..h.len()]);
            }
        }
    }

    /// Online use: the inputs `u` and Preisach outputs `h` of sample `t`
    /// (a no-op for a whole-record model).
    pub(crate) fn set_row(&self, t: usize, u: &[f64], h: &[f64]) {
        if let Rows::Stream(rows) = &self.rows {
            let mut rows = rows
                .write()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            let r = &mut rows[t & 1];
            r.u[..u.len()].copy_from_slice(u);
            r.h[..h.len()].copy_from_slice(h);
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
        let mut x = self.predict(t, prev);
        for (xi, v) in x.iter_mut().zip(&self.process) {
            *xi += v.sample(rng);
        }
        x
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

/// `log f(x_t | x_{t-1}) = Σ_i log p_{v_i}(x_{t,i} − F_i(x_{t-1}, u_{t-1}))`, bounded
/// by `Σ_i log p_{v_i}(0)` for the unimodal families centred at 0 (Gaussian,
/// Student-t, Laplace): the rejection backward sampler of the smoother.
impl TransitionDensity for NoisyModel<'_> {
    fn log_transition_density(
        &self,
        t: usize,
        prev: &Self::State,
        x: &Self::State,
        _u: &[f64],
    ) -> f64 {
        let m = self.predict(t, prev);
        self.process
            .iter()
            .enumerate()
            .map(|(i, v)| v.log_pdf(x[i] - m[i]))
            .sum()
    }

    fn log_transition_bound(&self, _t: usize, _u: &[f64]) -> Option<f64> {
        self.process
            .iter()
            .map(|v| match v {
                Noise::Gaussian { .. } | Noise::StudentT { .. } | Noise::Laplace { .. } => {
                    Some(v.log_pdf(0.0))
                }
                _ => None,
            })
            .sum()
    }
}

fn check_size(model: &SparseStateSpace) -> Result<()> {
    if model.n_states > SMC_MAX_STATES || model.n_inputs > 8 || model.hysteresis.len() > 8 {
        return Err(ModelError::InvalidArgument(format!(
            "the SMC path supports up to {SMC_MAX_STATES} states, 8 inputs and 8 Preisach components"
        )));
    }
    Ok(())
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
    /// Initial measurement-noise level relative to the output-error RMSE
    /// (1: the chain starts with all of the misfit as measurement noise).
    #[serde(default = "one")]
    pub measurement_fraction: f64,
    /// Seed.
    pub seed: u64,
    /// Also sample the free entries of `A` and `B` (flat prior), so that
    /// the noise scales' intervals take their uncertainty into account
    /// (otherwise they stay at the output-error estimate).
    #[serde(default)]
    pub sample_linear: bool,
    /// The tuned sampler when set (`None`: the fixed one): the particle
    /// number chosen at mid-burn-in so that the standard deviation of
    /// `log p̂` is about 1.2 (Pitt et al. 2012; Doucet et al. 2015), between
    /// `particles` and this bound, and the proposal covariance adapted on
    /// the second half of burn-in only, then frozen ([`tuned_schedule`]).
    #[serde(default)]
    pub max_particles: Option<usize>,
    /// Independent PMMH chains run in parallel (`iterations` and
    /// `burn_in` are shared among them; chain `c` has seed `seed + c`),
    /// pooled after each chain's burn-in. 1: one chain.
    #[serde(default = "one_chain")]
    pub chains: usize,
}

fn one_chain() -> usize {
    1
}

/// The PMMH configurations of the chains of `p`: chain `c` has
/// `⌈iterations/chains⌉` iterations, `⌊burn_in/chains⌋` burn-in, its own
/// schedule ([`tuned_schedule`]) and seed `seed + c`.
pub(crate) fn chain_configs(p: &SmcParams, step: &[f64]) -> Vec<PmmhConfig> {
    let k = p.chains.max(1);
    let (iters, burn) = (p.iterations.div_ceil(k), p.burn_in / k);
    (0..k)
        .map(|c| {
            let pc = SmcParams {
                iterations: iters,
                burn_in: burn,
                ..p.clone()
            };
            let mut cfg = PmmhConfig::new(p.particles, iters, step.to_vec());
            cfg.burn_in = burn;
            cfg.seed = p.seed.wrapping_add(c as u64);
            tuned_schedule(&mut cfg, &pc);
            cfg
        })
        .collect()
}

/// The PMMH schedule of the tuned sampler, with burn-in `B`:
///
/// * iterations `B/5 … B/2`: adaptive random walk `(2.38²/d) Σ̂` on the
///   chain so far (it leaves the start quickly);
/// * after iteration `B/2`: `N` chosen by [`gb_smc::estimation::ParticleTuning`]
///   (target sd of `log p̂` 1.2, `N ∈ [particles, max_particles]`), and `Σ̂`
///   restarted, so that the transient from the start does not inflate it;
/// * up to iteration `B`: `Σ̂` from the draws since `B/2` (once it holds
///   `max(20 d, 100)`), and from `B/5` on a global scale `λ` of the
///   proposal adapted towards an acceptance rate of 0.2 (`λ ∈ [1/3, 3]`);
/// * after `B`: proposal and `N` frozen — the kept draws are an ordinary
///   (pseudo-marginal) Metropolis–Hastings chain.
///
/// Without `max_particles` the fixed schedule: `N = particles` and the
/// proposal adapted from `max(iterations/3, 50)` on, to the end.
/// Acceptance rate the tuned sampler's proposal scale aims at during
/// burn-in: near the optimum of a pseudo-marginal random walk whose
/// log-likelihood noise has sd ≈ 1.2 (Sherlock, Thiery, Roberts &
/// Rosenthal 2015 find 7–15 % in high dimension; low dimensions accept more).
const TARGET_ACCEPTANCE: f64 = 0.2;

pub(crate) fn tuned_schedule(cfg: &mut PmmhConfig, p: &SmcParams) {
    let b = p.burn_in;
    match p.max_particles {
        Some(max) => {
            cfg.adapt_start = b / 5;
            cfg.adapt_restart = Some(b / 2);
            cfg.adapt_end = Some(b);
            cfg.target_acceptance = Some(TARGET_ACCEPTANCE);
            cfg.particle_tuning = Some(ParticleTuning::new(
                b / 2,
                p.particles,
                max.max(p.particles),
            ));
        }
        None => cfg.adapt_start = (p.iterations / 3).max(50),
    }
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
            measurement_fraction: 1.0,
            seed: 1,
            sample_linear: false,
            max_particles: None,
            chains: 1,
        }
    }
}

fn one() -> f64 {
    1.0
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
    /// Sets the initial process- and measurement-noise levels (relative to
    /// the state increments and to the output-error RMSE).
    pub fn start_levels(mut self, process: f64, measurement: f64) -> Self {
        self.process_fraction = process;
        self.measurement_fraction = measurement;
        self
    }
    /// Sets the seed.
    pub fn seed(mut self, s: u64) -> Self {
        self.seed = s;
        self
    }
    /// Samples the free entries of `A` and `B` too.
    pub fn sample_linear(mut self, yes: bool) -> Self {
        self.sample_linear = yes;
        self
    }
    /// The tuned sampler (see [`SmcParams::max_particles`]): the particle
    /// number chosen in burn-in, at most `max_particles`.
    pub fn tuned(mut self, max_particles: usize) -> Self {
        self.max_particles = Some(max_particles);
        self
    }
    /// Independent chains run in parallel (see [`SmcParams::chains`]).
    pub fn chains(mut self, k: usize) -> Self {
        self.chains = k;
        self
    }
    /// Validates the options once.
    pub fn check(self) -> Result<Smc> {
        if !(1..=64).contains(&self.chains)
            || self.iterations / self.chains <= self.burn_in / self.chains
        {
            return Err(ModelError::InvalidArgument(format!(
                "chains must be 1..=64 with more iterations than burn-in per chain, got {} chains of {} iterations, burn-in {}",
                self.chains, self.iterations, self.burn_in
            )));
        }
        if self.particles == 0 || self.iterations == 0 || self.burn_in >= self.iterations {
            return Err(ModelError::InvalidArgument(
                "particles >= 1, iterations >= 1 and burn_in < iterations are needed".into(),
            ));
        }
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(self.process_fraction) || !positive(self.measurement_fraction) {
            return Err(ModelError::InvalidArgument(
                "process_fraction and measurement_fraction must be > 0".into(),
            ));
        }
        Noise::from_model(&self.measurement)?;
        Noise::from_model(&self.process)?;
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
    /// Posterior summaries in natural units (process and measurement noise
    /// scales, the sampled coefficients), from the draws after burn-in.
    #[serde(default)]
    pub parameters: Vec<PosteriorParameter>,
    /// Particles of the filter after burn-in.
    #[serde(default)]
    pub particles: usize,
    /// The particle choice of the tuned sampler (standard deviations of
    /// `log p̂` before and after).
    #[serde(default)]
    pub particle_choice: Option<ParticleChoice>,
}

/// Posterior summary of one sampled quantity, with its chain diagnostics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PosteriorParameter {
    /// `process_scale[x1]`, …, `measurement_scale`, `coef[k]`.
    pub name: String,
    /// Posterior mean.
    pub mean: f64,
    /// 2.5 % quantile.
    pub lo: f64,
    /// 97.5 % quantile.
    pub hi: f64,
    /// Effective sample size of the draws after burn-in (Geyer).
    pub ess: f64,
    /// Split-R̂ of the draws after burn-in (four quarters of the one chain).
    pub rhat: f64,
}

impl SmcReport {
    /// True when every sampled quantity has split-R̂ ≤ `max_rhat` and
    /// ESS ≥ `min_ess`.
    pub fn mixed(&self, max_rhat: f64, min_ess: f64) -> bool {
        self.parameters
            .iter()
            .all(|p| p.rhat <= max_rhat && p.ess >= min_ess)
    }
}

/// Summary and diagnostics of draws `x` (after burn-in) of one quantity.
/// Split-R̂ treats the four quarters as chains: each is halved again, so the
/// statistic compares eight segments (a drift or a stuck start shows).
pub(crate) fn posterior_parameter(name: String, x: &[f64]) -> PosteriorParameter {
    let n = x.len().max(1) as f64;
    let mean = x.iter().sum::<f64>() / n;
    let mut v = x.to_vec();
    v.sort_unstable_by(f64::total_cmp);
    let q = |p: f64| {
        if v.is_empty() {
            return f64::NAN;
        }
        let pos = p * (v.len() - 1) as f64;
        let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
        v[lo] + (pos - lo as f64) * (v[hi] - v[lo])
    };
    let k = x.len() / 4;
    let quarters: Vec<&[f64]> = (0..4).map(|i| &x[i * k..(i + 1) * k]).collect();
    PosteriorParameter {
        name,
        mean,
        lo: q(0.025),
        hi: q(0.975),
        ess: gb_smc::diagnostics::effective_sample_size(x),
        rhat: gb_smc::diagnostics::split_rhat(&quarters),
    }
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
    /// The draws after `burn_in` in natural units: each state's process
    /// scale `s_i e^{θ_0}`, the measurement scale `s_w e^{θ_1}`, the coefficients.
    fn posterior_parameters(&self, chain: &[f64], burn_in: usize) -> Vec<PosteriorParameter> {
        let d = 2 + self.cols.len();
        let rows = chain.len() / d;
        let start = burn_in.min(rows.saturating_sub(1));
        let draws = |j: usize, scale: f64| -> Vec<f64> {
            (start..rows)
                .map(|k| {
                    let v = chain[k * d + j];
                    if j < 2 {
                        scale * v.exp()
                    } else {
                        v
                    }
                })
                .collect()
        };
        let mut out: Vec<PosteriorParameter> = self
            .proc_scale
            .iter()
            .enumerate()
            .map(|(i, s)| posterior_parameter(format!("process_scale[x{}]", i + 1), &draws(0, *s)))
            .collect();
        out.push(posterior_parameter(
            "measurement_scale".into(),
            &draws(1, self.meas_scale),
        ));
        let n = self.base.n_states;
        let mut k = 0;
        for (j, c) in self.cols.iter().enumerate() {
            let name = match c {
                Param::A(i) => format!("A[{},{}]", i / n + 1, i % n + 1),
                Param::B(i) => format!("B[{}]", i + 1),
                _ => {
                    k += 1;
                    format!("coef[{k}]")
                }
            };
            out.push(posterior_parameter(name, &draws(2 + j, 1.0)));
        }
        out
    }

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
            .map(Noise::from_model)
            .collect::<std::result::Result<Vec<_>, _>>()
            .ok()?;
        let measurement = Noise::from_model(&m.measurement_noise).ok()?;
        // sampled Everett coefficients change the Preisach outputs
        let hyst = if self.cols.iter().any(|c| matches!(c, Param::Hyst(..))) {
            Cow::Owned(m.hysteresis_outputs(self.inputs).ok()?)
        } else {
            Cow::Borrowed(self.hyst)
        };
        Some(NoisyModel {
            model: m,
            rows: Rows::Batch {
                inputs: self.inputs,
                hyst,
            },
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
        check_size(model)?;
        let hyst = model.hysteresis_outputs(inputs)?;
        let nm = NoisyModel::new(model, inputs, &hyst)?;
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
        check_size(oe)?;
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
        let mean_abs = coef.iter().map(|c| c.0).sum::<f64>() / coef.len().max(1) as f64;
        // the free entries of A and B (flat prior: an infinite Laplace width), then the coefficients
        let mut cols: Vec<Param> = if p.sample_linear {
            all.iter()
                .copied()
                .filter(|c| matches!(c, Param::A(..) | Param::B(..)))
                .collect()
        } else {
            Vec::new()
        };
        let mut laplace = vec![f64::INFINITY; cols.len()];
        laplace.resize(cols.len() + coef.len(), mean_abs.max(1e-12));
        cols.extend(coef.iter().map(|c| c.1));
        let hyst = oe.hysteresis_outputs(inputs)?;
        let problem = Problem {
            base: oe.clone(),
            laplace,
            cols,
            inputs,
            hyst: &hyst,
            proc_scale,
            meas_scale: rmse * p.measurement_fraction,
            process: p.process.clone(),
            measurement: p.measurement.clone(),
        };
        let mut theta0 = vec![0.0, 0.0];
        theta0.extend(get_params(oe, &problem.cols));
        let mut step = vec![0.1, 0.05];
        step.extend(
            theta0[2..]
                .iter()
                .zip(&problem.laplace)
                .map(|(c, b)| match b.is_finite() {
                    true => 0.01 * c.abs().max(mean_abs * 0.1),
                    false => 0.005 * c.abs().max(0.1),
                }),
        );
        let configs = chain_configs(p, &step);
        let observations = Observations::new(y);
        let total = p.iterations;
        // PMMH reports its iterations into 0..total of total + 1 steps
        let chain = SubTask {
            outer: obs,
            offset: 0,
            span: total,
            total: total + 1,
        };
        let res = run_chains(&configs, &problem, &observations, &theta0, &chain)?;
        let mean: Vec<f64> = res.summary.iter().map(|s| s.mean).collect();
        let sd: Vec<f64> = res.summary.iter().map(|s| s.sd).collect();
        let start = problem
            .model_at(&theta0)
            .ok_or_else(|| ModelError::Numerical("start model".into()))?;
        let post = problem
            .model_at(&mean)
            .ok_or_else(|| ModelError::Numerical("posterior mean model".into()))?;
        // the pooled draws are after burn-in
        let parameters = problem.posterior_parameters(&res.chain, 0);
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
                parameters,
                particles: res.n_particles,
                particle_choice: res.particle_choice,
            },
        ))
    }
}
