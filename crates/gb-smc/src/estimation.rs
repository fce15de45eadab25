//! Parameter estimation: particle marginal Metropolis–Hastings (PMMH) and
//! iterated filtering (IF2).
//!
//! Both follow the solver / state / observer shape: a validated solver
//! configuration, an explicit state advanced one iteration at a time, and
//! the workspace's one progress [`Observer`] (`gb_core::Observer`) told
//! after every iteration, so one progress bar can follow a PMMH run as well
//! as a diagnosis or a deterministic fit. `run_with` also hands every
//! iteration's typed state (`PmmhState`, `If2State`) to a callback, for
//! users that need the chain itself (trace plots, diagnostics).
//!
//! * **PMMH** (Andrieu, Doucet & Holenstein 2010): Metropolis–Hastings on `θ`
//!   with the particle estimate `p̂_θ(y)` in place of the likelihood; because
//!   `p̂` is unbiased the chain targets the exact posterior `p(θ | y)`. Proposals
//!   are Gaussian random walks, adapted after `adapt_start` iterations to
//!   `(2.38² / d) (Σ̂ + εI)` with `Σ̂` the running covariance of the chain (Haario et al. 2001);
//!   optionally `Σ̂` forgets the draws before `adapt_restart` (the transient from
//!   the start) and the proposal is frozen after `adapt_end` (adaptive burn-in,
//!   then a plain Metropolis–Hastings chain). The particle number can be chosen
//!   during burn-in by the rule of Pitt, Silva, Giordani & Kohn (2012) and
//!   Doucet, Pitt, Deligiannidis & Kohn (2015): `N` such that the standard
//!   deviation of `log p̂_θ(y)` at a central `θ` is about 1.2
//!   ([`ParticleTuning`]). With too few particles the estimate of the current
//!   point is sometimes far too high and the chain sticks there.
//! * **IF2** (Ionides et al. 2015): a particle filter on the extended state
//!   `(x_t, θ_t)` with `θ_t = θ_{t-1} + σ_m ε_t`, repeated with random-walk
//!   scales `σ_m = σ_0 c^m` shrinking geometrically; the swarm of `θ` converges to the MLE.
use crate::error::{Result, SmcError};
use crate::filter::{FilterConfig, FilterKind, FilterWorkspace, ParticleFilter};
use crate::model::{Observations, StateSpaceModel};
use crate::resampling::{resample_unchecked, Resampling};
use crate::rng::{derive_seed, domain, standard_normal, stream, SmcRng, CHUNK, PAR_MIN};
use rand::Rng;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// A family of state-space models indexed by a parameter vector `θ ∈ R^d`, with a prior.
pub trait ParametricModel: Sync {
    /// The model type.
    type Model: StateSpaceModel;
    /// Dimension `d` of `θ`.
    fn dim(&self) -> usize;
    /// The model at `θ`, or `None` where `θ` is invalid.
    fn build(&self, theta: &[f64]) -> Option<Self::Model>;
    /// `log p(θ)` up to a constant; `-inf` outside the support (not used by IF2).
    fn log_prior(&self, theta: &[f64]) -> f64;
}

pub use gb_core::{Observer, Silent};

/// Posterior summary of one parameter.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ParamSummary {
    /// Posterior mean.
    pub mean: f64,
    /// Posterior standard deviation.
    pub sd: f64,
    /// 2.5 % quantile.
    pub q025: f64,
    /// Median.
    pub median: f64,
    /// 97.5 % quantile.
    pub q975: f64,
}

/// PMMH settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PmmhConfig {
    /// Particles of the inner filter.
    pub n_particles: usize,
    /// MCMC iterations (including burn-in).
    pub n_iter: usize,
    /// Iterations discarded from the summaries.
    pub burn_in: usize,
    /// Seed.
    pub seed: u64,
    /// Initial random-walk standard deviations (one per parameter).
    pub initial_step: Vec<f64>,
    /// Adapt the proposal covariance.
    pub adapt: bool,
    /// Iteration at which adaptation starts.
    pub adapt_start: usize,
    /// Resampling of the inner filter.
    pub resampling: Resampling,
    /// Kind of the inner filter.
    pub kind: FilterKind,
    /// Iteration from which the running covariance `Σ̂` starts afresh (the
    /// draws before it, a transient from the start, are forgotten); `None`:
    /// the whole chain.
    #[serde(default)]
    pub adapt_restart: Option<usize>,
    /// Last iteration whose proposal is adapted; later the proposal is
    /// frozen (`None`: adapted to the end). Freezing at the end of burn-in
    /// makes the kept draws an ordinary Metropolis–Hastings chain.
    #[serde(default)]
    pub adapt_end: Option<usize>,
    /// Choice of the particle number during burn-in (`None`: `n_particles` throughout).
    #[serde(default)]
    pub particle_tuning: Option<ParticleTuning>,
    /// Target acceptance rate of the global proposal scale, adapted from
    /// `adapt_start` to `adapt_end` (`None`: scale `2.38²/d` only).
    #[serde(default)]
    pub target_acceptance: Option<f64>,
}

/// The particle number by the rule of Pitt et al. (2012) and Doucet et al.
/// (2015): after iteration `at`, `runs` filters at the current `θ` with the
/// current `N₀` estimate the standard deviation `s₀` of `log p̂_θ(y)`; since
/// `Var(log p̂) ≈ c / N`, the chain continues with
///
/// ```text
/// N = clamp(⌈N₀ (s₀ / target_sd)²⌉, min_particles, max_particles)
/// ```
///
/// and a fresh estimate `log p̂` of the current point at `N` (the old one may
/// be one of the lucky overestimates that make a chain stick). Doucet et al.
/// find the computing time per effective draw smallest near `s ≈ 1.2`
/// (1.0–1.7). `at` should lie inside burn-in, after the transient from the
/// start: far from the posterior the filter's variance is much larger.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ParticleTuning {
    /// Iteration after which `N` is chosen.
    pub at: usize,
    /// Filter runs for the standard deviation (≥ 3).
    pub runs: usize,
    /// Target standard deviation of `log p̂`.
    pub target_sd: f64,
    /// Smallest `N`.
    pub min_particles: usize,
    /// Largest `N`.
    pub max_particles: usize,
}

impl ParticleTuning {
    /// Target sd 1.2 from 10 runs after iteration `at`, `N` in `[min, max]`.
    pub fn new(at: usize, min_particles: usize, max_particles: usize) -> Self {
        Self {
            at,
            runs: 10,
            target_sd: 1.2,
            min_particles,
            max_particles,
        }
    }
}

/// What [`ParticleTuning`] measured and chose.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ParticleChoice {
    /// Particles before the choice.
    pub before: usize,
    /// Standard deviation of `log p̂` with `before` particles.
    pub sd_before: f64,
    /// Particles chosen.
    pub chosen: usize,
    /// Standard deviation of `log p̂` with `chosen` particles (a second set of runs).
    pub sd_chosen: f64,
}

impl PmmhConfig {
    /// Defaults: bootstrap filter, systematic resampling, adaptation from iteration 200.
    pub fn new(n_particles: usize, n_iter: usize, initial_step: Vec<f64>) -> Self {
        Self {
            n_particles,
            n_iter,
            burn_in: n_iter / 5,
            seed: 0,
            initial_step,
            adapt: true,
            adapt_start: 200,
            resampling: Resampling::Systematic,
            kind: FilterKind::Bootstrap,
            adapt_restart: None,
            adapt_end: None,
            particle_tuning: None,
            target_acceptance: None,
        }
    }
}

/// State of a PMMH chain.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PmmhState {
    /// Completed iterations.
    pub iter: usize,
    /// Current `θ`.
    pub theta: Vec<f64>,
    /// `log p̂_θ(y)` at the current `θ`.
    pub log_likelihood: f64,
    /// `log p(θ)` at the current `θ`.
    pub log_prior: f64,
    /// Accepted proposals so far.
    pub accepted: usize,
    /// Whether the last proposal was accepted.
    pub last_accepted: bool,
    /// Running mean of the chain.
    pub running_mean: Vec<f64>,
    /// Running covariance of the chain (row-major `d × d`, sums of squares).
    running_m2: Vec<f64>,
    /// Draws in the running mean and covariance.
    #[serde(default)]
    running_n: usize,
    /// `ln λ`, the global proposal scale (`target_acceptance`).
    #[serde(default)]
    pub log_scale: f64,
    /// Cholesky factor of the proposal covariance (row-major lower triangle).
    pub proposal_chol: Vec<f64>,
    /// Particles of the filter now.
    #[serde(default)]
    pub n_particles: usize,
    /// The particle choice, once made ([`ParticleTuning`]).
    #[serde(default)]
    pub particle_choice: Option<ParticleChoice>,
}

impl PmmhState {
    /// Acceptance rate so far.
    pub fn acceptance_rate(&self) -> f64 {
        if self.iter == 0 {
            0.0
        } else {
            self.accepted as f64 / self.iter as f64
        }
    }
}

/// Result of a PMMH run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PmmhResult {
    /// Parameter dimension `d`.
    pub dim: usize,
    /// Chain, row-major `n_iter × d`.
    pub chain: Vec<f64>,
    /// `log p̂(y)` along the chain.
    pub log_likelihoods: Vec<f64>,
    /// Fraction of accepted proposals.
    pub acceptance_rate: f64,
    /// Posterior summaries after burn-in, one per parameter.
    pub summary: Vec<ParamSummary>,
    /// Particles of the filter at the end of the chain.
    #[serde(default)]
    pub n_particles: usize,
    /// The particle choice of [`ParticleTuning`], if configured and reached.
    #[serde(default)]
    pub particle_choice: Option<ParticleChoice>,
}

impl PmmhResult {
    /// Draw `k` of the chain.
    pub fn draw(&self, k: usize) -> &[f64] {
        &self.chain[k * self.dim..(k + 1) * self.dim]
    }
}

/// Summaries of the rows `burn_in..` of a row-major `n × d` chain (all rows if
/// `burn_in ≥ n`; empty for an empty chain).
pub fn posterior_summary(chain: &[f64], dim: usize, burn_in: usize) -> Vec<ParamSummary> {
    let rows = chain.len() / dim.max(1);
    if rows == 0 {
        return Vec::new();
    }
    let start = burn_in.min(rows - 1);
    (0..dim)
        .map(|j| {
            let mut v: Vec<f64> = (start..rows).map(|k| chain[k * dim + j]).collect();
            let n = v.len() as f64;
            let mean = v.iter().sum::<f64>() / n;
            let var = v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (n - 1.0).max(1.0);
            v.sort_unstable_by(f64::total_cmp);
            let q = |p: f64| {
                let pos = p * (v.len() - 1) as f64;
                let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
                v[lo] + (pos - lo as f64) * (v[hi] - v[lo])
            };
            ParamSummary {
                mean,
                sd: var.sqrt(),
                q025: q(0.025),
                median: q(0.5),
                q975: q(0.975),
            }
        })
        .collect()
}

/// Lower Cholesky factor of a row-major SPD matrix, `None` if not positive definite.
fn cholesky(a: &[f64], d: usize) -> Option<Vec<f64>> {
    let mut l = vec![0.0; d * d];
    for i in 0..d {
        for j in 0..=i {
            let mut s = a[i * d + j];
            for k in 0..j {
                s -= l[i * d + k] * l[j * d + k];
            }
            if i == j {
                if !(s > 0.0 && s.is_finite()) {
                    return None;
                }
                l[i * d + i] = s.sqrt();
            } else {
                l[i * d + j] = s / l[j * d + j];
            }
        }
    }
    Some(l)
}

/// Particle marginal Metropolis–Hastings.
///
/// ```
/// use gb_smc::estimation::{ParametricModel, Pmmh, PmmhConfig, Silent};
/// use gb_smc::{LinearGaussian, Observations};
/// /// Unknown AR coefficient φ with a uniform prior on (−1, 1).
/// struct Phi;
/// impl ParametricModel for Phi {
///     type Model = LinearGaussian;
///     fn dim(&self) -> usize { 1 }
///     fn build(&self, th: &[f64]) -> Option<LinearGaussian> { LinearGaussian::ar1(th[0], 1.0, 0.5).ok() }
///     fn log_prior(&self, th: &[f64]) -> f64 { if th[0].abs() < 1.0 { 0.0 } else { f64::NEG_INFINITY } }
/// }
/// let (_, y) = LinearGaussian::ar1(0.8, 1.0, 0.5).unwrap().simulate(100, 1);
/// let mut cfg = PmmhConfig::new(300, 400, vec![0.05]);
/// cfg.burn_in = 100;
/// let res = Pmmh::new(cfg).unwrap().run(&Phi, &Observations::new(&y), &[0.5], &Silent).unwrap();
/// assert!(res.acceptance_rate > 0.05);
/// assert!((res.summary[0].mean - 0.8).abs() < 0.3);
/// ```
#[derive(Debug, Clone)]
pub struct Pmmh {
    config: PmmhConfig,
    filter: FilterConfig,
}

impl Pmmh {
    /// Validates the settings.
    pub fn new(config: PmmhConfig) -> Result<Self> {
        if config.n_iter == 0 {
            return Err(SmcError::InvalidParameter {
                name: "n_iter",
                value: 0.0,
                reason: "need at least one iteration",
            });
        }
        for &s in &config.initial_step {
            crate::error::check(
                "initial_step",
                s,
                s > 0.0 && s.is_finite(),
                "must be positive",
            )?;
        }
        if let Some(t) = &config.particle_tuning {
            let ok = t.runs >= 3
                && t.min_particles >= 1
                && t.min_particles <= t.max_particles
                && t.target_sd > 0.0
                && t.target_sd.is_finite();
            if !ok {
                return Err(SmcError::InvalidParameter {
                    name: "particle_tuning",
                    value: t.target_sd,
                    reason: "need runs >= 3, 1 <= min_particles <= max_particles and target_sd > 0",
                });
            }
        }
        let filter = FilterConfig::new(config.n_particles)
            .kind(config.kind)
            .resampling(config.resampling);
        ParticleFilter::new(filter.clone())?;
        Ok(Self { config, filter })
    }

    /// `log p̂_θ(y)` with `n` particles and the filter seed of `(domain, iter)`;
    /// `None` where the model cannot be built at `theta`.
    fn loglik_n<P: ParametricModel>(
        &self,
        problem: &P,
        obs: &Observations<'_, <P::Model as StateSpaceModel>::Obs>,
        theta: &[f64],
        (dom, iter): (u64, u64),
        n: usize,
        ws: &mut FilterWorkspace<<P::Model as StateSpaceModel>::State>,
    ) -> Option<Result<f64>> {
        let model = problem.build(theta)?;
        let seed = derive_seed(self.config.seed, dom, iter);
        let mut config = self.filter.clone().seed(seed);
        config.n_particles = n;
        let pf = ParticleFilter { config };
        Some(
            pf.run_with(&model, obs, ws, |_| {})
                .map(|o| o.log_likelihood),
        )
    }

    /// The standard deviation of `log p̂_θ(y)` over `runs` filters with `n`
    /// particles (tuning streams `first..first + runs`), and the first
    /// estimate. A failed run (all weights zero) counts as `−∞`: the
    /// standard deviation is then infinite.
    #[allow(clippy::too_many_arguments)]
    fn loglik_sd<P: ParametricModel>(
        &self,
        problem: &P,
        obs: &Observations<'_, <P::Model as StateSpaceModel>::Obs>,
        theta: &[f64],
        n: usize,
        runs: usize,
        first: u64,
        ws: &mut FilterWorkspace<<P::Model as StateSpaceModel>::State>,
    ) -> (f64, f64) {
        let lls: Vec<f64> = (0..runs as u64)
            .map(|k| {
                match self.loglik_n(problem, obs, theta, (domain::PMMH_TUNE, first + k), n, ws) {
                    Some(Ok(ll)) if ll.is_finite() => ll,
                    _ => f64::NEG_INFINITY,
                }
            })
            .collect();
        if lls.iter().any(|v| !v.is_finite()) {
            return (f64::INFINITY, lls[0]);
        }
        let m = lls.iter().sum::<f64>() / runs as f64;
        let var = lls.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (runs - 1) as f64;
        (var.sqrt(), lls[0])
    }

    /// Chooses the particle number at the current `θ` ([`ParticleTuning`])
    /// and re-estimates the current `log p̂` with it.
    fn tune_particles<P: ParametricModel>(
        &self,
        problem: &P,
        obs: &Observations<'_, <P::Model as StateSpaceModel>::Obs>,
        state: &mut PmmhState,
        t: &ParticleTuning,
        ws: &mut FilterWorkspace<<P::Model as StateSpaceModel>::State>,
    ) {
        let before = state.n_particles;
        let (sd_before, _) = self.loglik_sd(problem, obs, &state.theta, before, t.runs, 0, ws);
        // Var(log p̂) ≈ c / N
        let want = before as f64 * (sd_before / t.target_sd).powi(2);
        let chosen = if want.is_finite() {
            (want.ceil() as usize).clamp(t.min_particles, t.max_particles)
        } else {
            t.max_particles
        };
        let (sd_chosen, ll) = self.loglik_sd(
            problem,
            obs,
            &state.theta,
            chosen,
            t.runs,
            t.runs as u64,
            ws,
        );
        state.n_particles = chosen;
        if ll.is_finite() {
            state.log_likelihood = ll;
        }
        state.particle_choice = Some(ParticleChoice {
            before,
            sd_before,
            chosen,
            sd_chosen,
        });
    }

    fn loglik<P: ParametricModel>(
        &self,
        problem: &P,
        obs: &Observations<'_, <P::Model as StateSpaceModel>::Obs>,
        theta: &[f64],
        iter: usize,
        n: usize,
        ws: &mut FilterWorkspace<<P::Model as StateSpaceModel>::State>,
    ) -> Option<Result<f64>> {
        self.loglik_n(
            problem,
            obs,
            theta,
            (domain::PMMH_FILTER, iter as u64),
            n,
            ws,
        )
    }

    /// Initial state at `theta0`.
    pub fn init<P: ParametricModel>(
        &self,
        problem: &P,
        obs: &Observations<'_, <P::Model as StateSpaceModel>::Obs>,
        theta0: &[f64],
        ws: &mut FilterWorkspace<<P::Model as StateSpaceModel>::State>,
    ) -> Result<PmmhState> {
        let d = problem.dim();
        if theta0.len() != d || self.config.initial_step.len() != d {
            return Err(SmcError::LengthMismatch {
                what: "theta0 / initial_step vs dim",
                expected: d,
                got: if theta0.len() != d {
                    theta0.len()
                } else {
                    self.config.initial_step.len()
                },
            });
        }
        let lp = problem.log_prior(theta0);
        if lp.is_nan() || lp == f64::NEG_INFINITY {
            return Err(SmcError::InvalidInitialParameter);
        }
        let n = self.config.n_particles;
        let ll = self
            .loglik(problem, obs, theta0, 0, n, ws)
            .ok_or(SmcError::InvalidInitialParameter)??;
        let mut chol = vec![0.0; d * d];
        for (i, s) in self.config.initial_step.iter().enumerate() {
            chol[i * d + i] = *s;
        }
        Ok(PmmhState {
            iter: 0,
            theta: theta0.to_vec(),
            log_likelihood: ll,
            log_prior: lp,
            accepted: 0,
            last_accepted: false,
            running_mean: theta0.to_vec(),
            running_m2: vec![0.0; d * d],
            running_n: 1,
            log_scale: 0.0,
            proposal_chol: chol,
            n_particles: n,
            particle_choice: None,
        })
    }

    /// One Metropolis–Hastings iteration.
    pub fn step<P: ParametricModel>(
        &self,
        problem: &P,
        obs: &Observations<'_, <P::Model as StateSpaceModel>::Obs>,
        state: &mut PmmhState,
        ws: &mut FilterWorkspace<<P::Model as StateSpaceModel>::State>,
    ) -> Result<()> {
        let d = state.theta.len();
        if let Some(t) = &self.config.particle_tuning {
            if state.iter == t.at && state.particle_choice.is_none() {
                self.tune_particles(problem, obs, state, t, ws);
            }
        }
        let it = state.iter + 1;
        let mut rng = stream(self.config.seed, domain::PMMH_MH, it as u64, 0);
        let z: Vec<f64> = (0..d).map(|_| standard_normal(&mut rng)).collect();
        let prop: Vec<f64> = (0..d)
            .map(|i| {
                state.theta[i]
                    + (0..=i)
                        .map(|k| state.proposal_chol[i * d + k] * z[k])
                        .sum::<f64>()
            })
            .collect();
        let lp = problem.log_prior(&prop);
        let mut accepted = false;
        let mut alpha = 0.0;
        if lp > f64::NEG_INFINITY && !lp.is_nan() {
            if let Some(Ok(ll)) = self.loglik(problem, obs, &prop, it, state.n_particles, ws) {
                let log_alpha = ll + lp - state.log_likelihood - state.log_prior;
                alpha = log_alpha.min(0.0).exp();
                let u: f64 = rng.random();
                if u.ln() < log_alpha {
                    state.theta = prop;
                    state.log_likelihood = ll;
                    state.log_prior = lp;
                    accepted = true;
                }
            }
        }
        state.iter = it;
        state.last_accepted = accepted;
        state.accepted += accepted as usize;
        self.adapt(state, if alpha.is_nan() { 0.0 } else { alpha });
        Ok(())
    }

    /// Welford update of the running mean and covariance with the current
    /// draw (the initial point counts as draw 0; at `adapt_restart` the
    /// statistics start afresh from the current draw), then the adapted
    /// proposal `(2.38²/d)(Σ̂ + εI)` with `ε = 10⁻⁶ σ_0²` from `adapt_start`
    /// to `adapt_end`. After a restart `Σ̂` is used once it holds
    /// `max(20 d, 100)` draws (a covariance of a few draws of a sticky chain
    /// is degenerate). With `target_acceptance = α*` the proposal factor is
    /// also scaled by `λ` (Andrieu & Thoms 2008, global adaptive scaling):
    /// `ln λ_k = ln λ_{k−1} + k^{−2/3} (α_k − α*)`, `α_k` the Metropolis–Hastings
    /// acceptance probability of iteration `k` after `adapt_start` (after a
    /// restart: `λ = 1` again, and `k` counted from the first use of the new
    /// `Σ̂`), `λ ∈ [1/3, 3]`; this undoes a `Σ̂` that came out too small (a chain that
    /// then accepts almost every tiny step) or too large.
    fn adapt(&self, state: &mut PmmhState, alpha: f64) {
        let d = state.theta.len();
        let it = state.iter;
        let restarted = self.config.adapt_restart.is_some_and(|r| it >= r);
        if self.config.adapt_restart == Some(it) {
            state.running_mean.copy_from_slice(&state.theta);
            state.running_m2.fill(0.0);
            state.running_n = 1;
            // the scale learnt on the transient starts afresh too
            let f = (-state.log_scale).exp();
            state.proposal_chol.iter_mut().for_each(|v| *v *= f);
            state.log_scale = 0.0;
        } else {
            state.running_n += 1;
            let n = state.running_n as f64;
            let delta: Vec<f64> = (0..d)
                .map(|i| state.theta[i] - state.running_mean[i])
                .collect();
            for (m, dl) in state.running_mean.iter_mut().zip(&delta) {
                *m += dl / n;
            }
            for (row, dl) in state.running_m2.chunks_mut(d).zip(&delta) {
                for ((r, th), m) in row.iter_mut().zip(&state.theta).zip(&state.running_mean) {
                    *r += dl * (th - m);
                }
            }
        }
        let min_window = (20 * d).max(100);
        let enough = if restarted {
            state.running_n >= min_window
        } else {
            it > d
        };
        let active = self.config.adapt
            && it >= self.config.adapt_start
            && self.config.adapt_end.is_none_or(|e| it <= e);
        if let (true, true, Some(target)) =
            (active, enough || !restarted, self.config.target_acceptance)
        {
            // k = 1 at adapt_start, or where the restarted Σ̂ is first used
            let from = match self.config.adapt_restart {
                Some(r) if restarted => (r + min_window - 1).max(self.config.adapt_start),
                _ => self.config.adapt_start,
            };
            let k = (it + 1 - from) as f64;
            let old = state.log_scale;
            state.log_scale =
                (old + k.powf(-2.0 / 3.0) * (alpha - target)).clamp(-3f64.ln(), 3f64.ln());
            let f = (state.log_scale - old).exp();
            state.proposal_chol.iter_mut().for_each(|v| *v *= f);
        }
        if active && enough {
            let n = state.running_n as f64;
            let sd2 = 2.38 * 2.38 / d as f64;
            let cov: Vec<f64> = (0..d * d)
                .map(|k| {
                    let (i, j) = (k / d, k % d);
                    let eps = if i == j {
                        1e-6 * self.config.initial_step[i].powi(2)
                    } else {
                        0.0
                    };
                    sd2 * (state.running_m2[k] / (n - 1.0) + eps) * (2.0 * state.log_scale).exp()
                })
                .collect();
            if let Some(l) = cholesky(&cov, d) {
                state.proposal_chol = l;
            }
        }
    }

    /// Runs the chain from `theta0`, reporting each iteration to `observer`
    /// (`progress(iteration, n_iter, "PMMH: log p̂ …")`).
    pub fn run<P: ParametricModel>(
        &self,
        problem: &P,
        obs: &Observations<'_, <P::Model as StateSpaceModel>::Obs>,
        theta0: &[f64],
        observer: &dyn Observer,
    ) -> Result<PmmhResult> {
        self.run_with(problem, obs, theta0, observer, |_| {})
    }

    /// [`run`](Self::run), also handing the chain state after every
    /// iteration to `on_state`.
    pub fn run_with<P: ParametricModel, F: FnMut(&PmmhState)>(
        &self,
        problem: &P,
        obs: &Observations<'_, <P::Model as StateSpaceModel>::Obs>,
        theta0: &[f64],
        observer: &dyn Observer,
        mut on_state: F,
    ) -> Result<PmmhResult> {
        let mut ws = FilterWorkspace::new();
        let mut state = self.init(problem, obs, theta0, &mut ws)?;
        let d = theta0.len();
        let mut chain = Vec::with_capacity(self.config.n_iter * d);
        let mut lls = Vec::with_capacity(self.config.n_iter);
        for _ in 0..self.config.n_iter {
            self.step(problem, obs, &mut state, &mut ws)?;
            chain.extend_from_slice(&state.theta);
            lls.push(state.log_likelihood);
            on_state(&state);
            observer.progress(
                state.iter,
                self.config.n_iter,
                &format!("PMMH: log p̂ {:.1}", state.log_likelihood),
            );
        }
        Ok(PmmhResult {
            dim: d,
            summary: posterior_summary(&chain, d, self.config.burn_in),
            chain,
            log_likelihoods: lls,
            acceptance_rate: state.acceptance_rate(),
            n_particles: state.n_particles,
            particle_choice: state.particle_choice,
        })
    }
}

/// Several PMMH chains, one per configuration (each with its own seed,
/// length, burn-in and schedule), run in parallel on rayon's pool and
/// pooled: `chain` and `log_likelihoods` hold every chain's draws *after
/// its burn-in*, chain after chain; `summary` summarises them;
/// `acceptance_rate` is the chains' mean, `n_particles` the largest and
/// `particle_choice` the first chain's. The first chain reports its
/// iterations to `observer`. The result does not depend on the number of
/// threads (each chain is seeded by its configuration). With equal
/// configurations but the seed, split-R̂ over the halves of the pooled
/// draws ([`crate::diagnostics::split_rhat`]) is the multi-chain statistic.
///
/// ```
/// use gb_smc::estimation::{run_chains, ParametricModel, PmmhConfig, Silent};
/// use gb_smc::{LinearGaussian, Observations};
/// struct Phi;
/// impl ParametricModel for Phi {
///     type Model = LinearGaussian;
///     fn dim(&self) -> usize { 1 }
///     fn build(&self, th: &[f64]) -> Option<LinearGaussian> { LinearGaussian::ar1(th[0], 1.0, 0.5).ok() }
///     fn log_prior(&self, th: &[f64]) -> f64 { if th[0].abs() < 1.0 { 0.0 } else { f64::NEG_INFINITY } }
/// }
/// let (_, y) = LinearGaussian::ar1(0.8, 1.0, 0.5).unwrap().simulate(100, 1);
/// let cfgs: Vec<PmmhConfig> = (0..2).map(|c| {
///     let mut cfg = PmmhConfig::new(200, 300, vec![0.05]);
///     cfg.burn_in = 100;
///     cfg.seed = 7 + c;
///     cfg
/// }).collect();
/// let res = run_chains(&cfgs, &Phi, &Observations::new(&y), &[0.5], &Silent).unwrap();
/// assert_eq!(res.chain.len(), 2 * 200); // two chains of 200 draws after burn-in
/// assert!((res.summary[0].mean - 0.8).abs() < 0.3);
/// ```
pub fn run_chains<P>(
    configs: &[PmmhConfig],
    problem: &P,
    obs: &Observations<'_, <P::Model as StateSpaceModel>::Obs>,
    theta0: &[f64],
    observer: &dyn Observer,
) -> Result<PmmhResult>
where
    P: ParametricModel,
    <P::Model as StateSpaceModel>::Obs: Sync,
{
    if configs.is_empty() {
        return Err(SmcError::InvalidParameter {
            name: "chains",
            value: 0.0,
            reason: "at least one chain is needed",
        });
    }
    let results: Vec<PmmhResult> = configs
        .par_iter()
        .enumerate()
        .map(|(c, cfg)| {
            let silent = Silent;
            let o: &dyn Observer = if c == 0 { observer } else { &silent };
            Pmmh::new(cfg.clone())?.run(problem, obs, theta0, o)
        })
        .collect::<Result<_>>()?;
    let d = theta0.len();
    let (mut chain, mut lls) = (vec![], vec![]);
    for (r, cfg) in results.iter().zip(configs) {
        let rows = r.log_likelihoods.len();
        let start = cfg.burn_in.min(rows.saturating_sub(1));
        chain.extend_from_slice(&r.chain[start * d..]);
        lls.extend_from_slice(&r.log_likelihoods[start..]);
    }
    Ok(PmmhResult {
        dim: d,
        summary: posterior_summary(&chain, d, 0),
        chain,
        log_likelihoods: lls,
        acceptance_rate: results.iter().map(|r| r.acceptance_rate).sum::<f64>()
            / results.len() as f64,
        n_particles: results.iter().map(|r| r.n_particles).max().unwrap_or(0),
        particle_choice: results[0].particle_choice,
    })
}

/// IF2 settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct If2Config {
    /// Particles.
    pub n_particles: usize,
    /// Filtering iterations `M`.
    pub n_iter: usize,
    /// Random-walk standard deviations `σ_0` per parameter and time step.
    pub rw_sd: Vec<f64>,
    /// Geometric cooling factor `c` per iteration (`σ_m = σ_0 c^m`); the
    /// classical choice is `0.05^{1/50}`, i.e. 5 % of `σ_0` after 50 iterations.
    pub cooling: f64,
    /// Seed.
    pub seed: u64,
    /// Use rayon over particle chunks (results do not depend on it).
    pub parallel: bool,
}

impl If2Config {
    /// Defaults: cooling `0.05^{1/50}`.
    pub fn new(n_particles: usize, n_iter: usize, rw_sd: Vec<f64>) -> Self {
        Self {
            n_particles,
            n_iter,
            rw_sd,
            cooling: 0.05f64.powf(1.0 / 50.0),
            seed: 0,
            parallel: true,
        }
    }
}

/// State of IF2 after an iteration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct If2State {
    /// Completed iterations.
    pub iter: usize,
    /// Mean of the parameter swarm.
    pub theta: Vec<f64>,
    /// Log-likelihood estimate of the perturbed filter in this iteration.
    pub log_likelihood: f64,
    /// Current random-walk scale factor `c^m`.
    pub scale: f64,
}

/// Result of IF2.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct If2Result {
    /// Final estimate (mean of the final swarm).
    pub theta: Vec<f64>,
    /// Swarm mean after each iteration.
    pub trace: Vec<Vec<f64>>,
    /// Perturbed-filter log-likelihood per iteration.
    pub log_likelihoods: Vec<f64>,
}

type If2Item<'a, S> = (
    usize,
    (((&'a mut [S], &'a mut [f64]), &'a mut [f64]), &'a mut [f64]),
);

/// Iterated filtering (IF2) for maximum-likelihood estimation.
///
/// ```
/// use gb_smc::estimation::{If2, If2Config, ParametricModel, Silent};
/// use gb_smc::{LinearGaussian, Observations};
/// struct Phi;
/// impl ParametricModel for Phi {
///     type Model = LinearGaussian;
///     fn dim(&self) -> usize { 1 }
///     fn build(&self, th: &[f64]) -> Option<LinearGaussian> { LinearGaussian::ar1(th[0], 1.0, 0.5).ok() }
///     fn log_prior(&self, _: &[f64]) -> f64 { 0.0 }
/// }
/// let (_, y) = LinearGaussian::ar1(0.8, 1.0, 0.5).unwrap().simulate(200, 1);
/// let res = If2::new(If2Config::new(300, 30, vec![0.02])).unwrap()
///     .run(&Phi, &Observations::new(&y), &[0.3], &Silent).unwrap();
/// assert!((res.theta[0] - 0.8).abs() < 0.15);
/// ```
#[derive(Debug, Clone)]
pub struct If2 {
    config: If2Config,
}

impl If2 {
    /// Validates the settings.
    pub fn new(config: If2Config) -> Result<Self> {
        if config.n_particles == 0 || config.n_iter == 0 {
            return Err(SmcError::InvalidParameter {
                name: "n_particles / n_iter",
                value: 0.0,
                reason: "must be positive",
            });
        }
        for &s in &config.rw_sd {
            crate::error::check(
                "rw_sd",
                s,
                s >= 0.0 && s.is_finite(),
                "must be non-negative",
            )?;
        }
        crate::error::check(
            "cooling",
            config.cooling,
            config.cooling > 0.0 && config.cooling <= 1.0,
            "must lie in (0, 1]",
        )?;
        Ok(Self { config })
    }

    /// Runs IF2 from `theta0`, reporting each iteration to `observer`
    /// (`progress(iteration, n_iter, "IF2: log p̂ …")`).
    pub fn run<P: ParametricModel>(
        &self,
        problem: &P,
        obs: &Observations<'_, <P::Model as StateSpaceModel>::Obs>,
        theta0: &[f64],
        observer: &dyn Observer,
    ) -> Result<If2Result> {
        self.run_with(problem, obs, theta0, observer, |_| {})
    }

    /// [`run`](Self::run), also handing the state after every iteration to
    /// `on_state`.
    pub fn run_with<P: ParametricModel, F: FnMut(&If2State)>(
        &self,
        problem: &P,
        obs: &Observations<'_, <P::Model as StateSpaceModel>::Obs>,
        theta0: &[f64],
        observer: &dyn Observer,
        mut on_state: F,
    ) -> Result<If2Result> {
        let cfg = &self.config;
        let d = problem.dim();
        if theta0.len() != d || cfg.rw_sd.len() != d {
            return Err(SmcError::LengthMismatch {
                what: "theta0 / rw_sd vs dim",
                expected: d,
                got: theta0.len().min(cfg.rw_sd.len()),
            });
        }
        if obs.is_empty() {
            return Err(SmcError::EmptyData);
        }
        let n = cfg.n_particles;
        let tt = obs.len();
        let model0 = problem
            .build(theta0)
            .ok_or(SmcError::InvalidInitialParameter)?;
        let fill = model0.sample_initial(obs.input(0), &mut stream(cfg.seed, domain::FILL, 0, 0));
        let mut swarm = If2Swarm::<P::Model>::new(fill, theta0, n);
        let mut trace = Vec::with_capacity(cfg.n_iter);
        let mut lls = Vec::with_capacity(cfg.n_iter);
        let ln_n = (n as f64).ln();
        for m in 0..cfg.n_iter {
            let scale = cfg.cooling.powi(m as i32);
            let seed = derive_seed(cfg.seed, domain::IF2, m as u64);
            let mut loglik = 0.0;
            for t in 0..tt {
                let step = If2Step {
                    t,
                    y: obs.y(t),
                    u: obs.input(t),
                    seed,
                    scale,
                    rw_sd: &cfg.rw_sd,
                };
                swarm.perturb_and_weight(problem, &step, cfg.parallel);
                loglik += swarm.normalise_and_resample(t, seed, ln_n)?;
            }
            let mean = swarm.resampled_mean(d);
            let state = If2State {
                iter: m + 1,
                theta: mean.clone(),
                log_likelihood: loglik,
                scale,
            };
            on_state(&state);
            observer.progress(
                state.iter,
                cfg.n_iter,
                &format!("IF2: log p̂ {:.1}", state.log_likelihood),
            );
            trace.push(mean);
            lls.push(loglik);
        }
        Ok(If2Result {
            theta: trace.last().cloned().unwrap_or_else(|| theta0.to_vec()),
            trace,
            log_likelihoods: lls,
        })
    }
}

/// One time step of an IF2 iteration: observation, input, the iteration's
/// seed, the random-walk scale `c^m` and standard deviations.
struct If2Step<'a, O: ?Sized> {
    t: usize,
    y: &'a O,
    u: &'a [f64],
    seed: u64,
    scale: f64,
    rw_sd: &'a [f64],
}

/// The IF2 swarm: states and parameter vectors (`n × d`, row-major),
/// current and next, log-weights, weights, ancestors, and scratch.
struct If2Swarm<M: StateSpaceModel> {
    x: Vec<M::State>,
    x_new: Vec<M::State>,
    th: Vec<f64>,
    th_new: Vec<f64>,
    lw: Vec<f64>,
    w: Vec<f64>,
    anc: Vec<usize>,
    counts: Vec<u32>,
    /// Per chunk: (max log-weight, Σ exp(ℓ − max), any invalid log-weight).
    stats: Vec<(f64, f64, bool)>,
}

impl<M: StateSpaceModel> If2Swarm<M> {
    /// `n` particles at `fill`, every parameter vector at `theta0`.
    fn new(fill: M::State, theta0: &[f64], n: usize) -> Self {
        let d = theta0.len();
        let th: Vec<f64> = theta0.iter().copied().cycle().take(n * d).collect();
        Self {
            x: vec![fill.clone(); n],
            x_new: vec![fill; n],
            th_new: th.clone(),
            th,
            lw: vec![0.0; n],
            w: vec![0.0; n],
            anc: (0..n).collect(),
            counts: Vec::new(),
            stats: Vec::new(),
        }
    }

    /// Move of step t, chunk by chunk: θ_i = θ_{a_i} + c^m σ ∘ z
    /// (z ~ N(0, I)), x_i ~ f_θi(· | x_{a_i}) (or the initial law at t = 0),
    /// ℓ_i = log g_θi(y_t | x_i) (−∞ where θ_i is invalid), and unnormalised
    /// chunk weights exp(ℓ_i − max_chunk ℓ) with their chunk statistics.
    fn perturb_and_weight<P: ParametricModel<Model = M>>(
        &mut self,
        problem: &P,
        step: &If2Step<'_, M::Obs>,
        parallel: bool,
    ) {
        let n = self.x.len();
        let d = problem.dim();
        let &If2Step {
            t,
            y,
            u,
            seed,
            scale,
            rw_sd: rw,
        } = step;
        let (x_old, th_old, anc_ref) = (&self.x, &self.th, &self.anc);
        let body = |(k, (((xc, tc), lc), wc)): If2Item<'_, _>| {
            let mut rng: SmcRng = stream(seed, domain::MOVE, t as u64, k as u64);
            let mut max = f64::NEG_INFINITY;
            let mut bad = false;
            for j in 0..xc.len() {
                let i = k * CHUNK + j;
                let a = if t == 0 { i } else { anc_ref[i] };
                let ti = &mut tc[j * d..(j + 1) * d];
                for q in 0..d {
                    let z = standard_normal(&mut rng);
                    ti[q] = th_old[a * d + q] + scale * rw[q] * z;
                }
                let l = match problem.build(ti) {
                    Some(model) => {
                        let xi = if t == 0 {
                            model.sample_initial(u, &mut rng)
                        } else {
                            model.sample_transition(t, &x_old[a], u, &mut rng)
                        };
                        let l = model.log_observation(t, &xi, y, u);
                        xc[j] = xi;
                        l
                    }
                    None => f64::NEG_INFINITY,
                };
                bad |= l.is_nan() || l == f64::INFINITY;
                lc[j] = l;
                max = max.max(l);
            }
            let mut s = 0.0;
            if max > f64::NEG_INFINITY && !bad {
                for (wi, &l) in wc.iter_mut().zip(lc.iter()) {
                    *wi = crate::filter::exp_nonpos(l - max);
                    s += *wi;
                }
            } else {
                wc.iter_mut().for_each(|v| *v = 0.0);
            }
            (max, s, bad)
        };
        if parallel && n >= PAR_MIN {
            self.x_new
                .par_chunks_mut(CHUNK)
                .zip(self.th_new.par_chunks_mut(CHUNK * d))
                .zip(self.lw.par_chunks_mut(CHUNK))
                .zip(self.w.par_chunks_mut(CHUNK))
                .enumerate()
                .map(body)
                .collect_into_vec(&mut self.stats);
        } else {
            self.stats.clear();
            self.stats.extend(
                self.x_new
                    .chunks_mut(CHUNK)
                    .zip(self.th_new.chunks_mut(CHUNK * d))
                    .zip(self.lw.chunks_mut(CHUNK))
                    .zip(self.w.chunks_mut(CHUNK))
                    .enumerate()
                    .map(body),
            );
        }
    }

    /// Weights of step t on the common scale exp(ℓ − max ℓ), the moved
    /// swarm made current, and systematic resampling of the ancestors.
    /// Returns the log-likelihood increment max ℓ + ln Σ w − ln n.
    fn normalise_and_resample(&mut self, t: usize, seed: u64, ln_n: f64) -> Result<f64> {
        let stats = &self.stats;
        if stats.iter().any(|s| s.2) {
            return Err(SmcError::InvalidLogWeight { t });
        }
        let max = stats.iter().map(|s| s.0).fold(f64::NEG_INFINITY, f64::max);
        if max == f64::NEG_INFINITY {
            return Err(SmcError::AllWeightsZero { t });
        }
        let mut total = 0.0;
        for (wc, s) in self.w.chunks_mut(CHUNK).zip(stats) {
            let f = if s.0 > f64::NEG_INFINITY {
                (s.0 - max).exp()
            } else {
                0.0
            };
            wc.iter_mut().for_each(|v| *v *= f);
            total += s.1 * f;
        }
        let inc = max + total.ln() - ln_n;
        std::mem::swap(&mut self.x, &mut self.x_new);
        std::mem::swap(&mut self.th, &mut self.th_new);
        let mut rng = stream(seed, domain::RESAMPLE, t as u64, 0);
        resample_unchecked(
            Resampling::Systematic,
            &self.w,
            total,
            &mut rng,
            &mut self.anc,
            &mut self.counts,
        );
        Ok(inc)
    }

    /// End of an iteration: the parameters of the resampled ancestors become
    /// the swarm (identity ancestors for the next iteration); returns their
    /// mean (1/n) Σ θ_i.
    fn resampled_mean(&mut self, d: usize) -> Vec<f64> {
        let n = self.anc.len();
        // final swarm: resampled parameters
        for (i, &a) in self.anc.iter().enumerate() {
            self.th_new[i * d..(i + 1) * d].copy_from_slice(&self.th[a * d..(a + 1) * d]);
        }
        std::mem::swap(&mut self.th, &mut self.th_new);
        let mut mean = vec![0.0; d];
        for p in self.th.chunks(d) {
            for (m_, v) in mean.iter_mut().zip(p) {
                *m_ += v / n as f64;
            }
        }
        // the next iteration starts from the final swarm (identity ancestors)
        for (i, a) in self.anc.iter_mut().enumerate() {
            *a = i;
        }
        mean
    }
}
