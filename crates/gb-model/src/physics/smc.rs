//! The SMC path of the physics class (Hauth 2008, ch. 5, for the
//! engineer's own equations): the discretised model with process noise on
//! every state and measurement noise,
//!
//! ```text
//! x_t = Φ_θ(x_{t−1}, u_{t−1}) + v_t,   v_{t,i} ~ N(0, (κ_p,i s_i)²),
//! y_t = g(x_t, u_t, θ) + w_t,           w_t ~ N(0, (κ_m σ̂_OE)²),
//! ```
//!
//! `Φ_θ` the RK4 map of one sample, `s_i` the standard deviation of the
//! output-error simulation's increments of state i times
//! `SmcParams::process_fraction`, `σ̂_OE` the output-error RMSE. A
//! kinematic state — one whose equation is another state, `x = "v"` — gets
//! no process noise: a disturbance enters where forces (or flows) do, and
//! the kinematic identity is exact. Particle
//! marginal Metropolis–Hastings (Andrieu, Doucet & Holenstein 2010) samples
//! `(ln κ_p,1 … ln κ_p,n, ln κ_m, θ_free)` — a process level per state —
//! from the output-error estimate, with the bootstrap filter's unbiased
//! likelihood, uniform priors on the bounds (the file's Gaussian priors
//! where given) and N(0, 3²) on the log-levels. The free parameters are
//! sampled in the coordinates `z` of `θ_free = θ̂ + L z`, `L Lᵀ` the
//! output-error covariance inflated by 4 (process noise widens it): the
//! strongly coupled pairs of a physical model (mass and stiffness) become
//! unit-scale and uncorrelated for the random walk.
use super::error::{PhysicsError, PhysicsResult};
use super::model::PhysicsModel;
use super::simulate::{Integrator, Lanes};
use crate::smc::{posterior_parameter, Smc, SmcReport, SMC_MAX_STATES};
use crate::IdentificationPath;
use gb_core::{Init, Observer, Record, SubTask};
use gb_smc::estimation::{run_chains, ParametricModel};
use gb_smc::noise::Noise;
use gb_smc::{FilterConfig, Observations, SmcRng, StateSpaceModel};
use std::sync::Mutex;

/// The physics model with process and measurement noise, as a
/// `gb_smc::StateSpaceModel` (one output).
struct NoisyPhysics<'a> {
    n: usize,
    inputs: &'a [Vec<f64>],
    x0: Vec<f64>,
    /// Process noise per state (`None`: a kinematic state, none).
    process: Vec<Option<Noise>>,
    measurement: Noise,
    /// The integrator at this θ (the filter runs particles one by one below
    /// its parallel threshold, so the lock is uncontended).
    rk4: Mutex<Integrator<'a>>,
}

impl NoisyPhysics<'_> {
    fn with_rk4<T>(&self, f: impl FnOnce(&mut Integrator<'_>) -> T) -> T {
        let mut g = self
            .rk4
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        f(&mut g)
    }

    fn input(&self, t: usize) -> impl Iterator<Item = f64> + '_ {
        self.inputs.iter().map(move |u| u[t])
    }
}

impl StateSpaceModel for NoisyPhysics<'_> {
    type State = [f64; SMC_MAX_STATES];
    type Obs = f64;

    fn sample_initial(&self, _u: &[f64], rng: &mut SmcRng) -> Self::State {
        let mut x = [0.0; SMC_MAX_STATES];
        for (i, xi) in x.iter_mut().take(self.n).enumerate() {
            *xi = self.x0[i] + self.process[i].as_ref().map_or(0.0, |v| v.sample(rng));
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
        let mut x = [0.0; SMC_MAX_STATES];
        let ok = self.with_rk4(|it| {
            it.reset(&prev[..self.n], &Lanes::default());
            it.set_input(self.input(t - 1));
            let ok = it.step();
            x[..self.n].copy_from_slice(it.state());
            ok
        });
        if !ok {
            // a diverged particle gets no weight (its output is NaN)
            x[..self.n].fill(f64::NAN);
            return x;
        }
        for (xi, v) in x.iter_mut().zip(&self.process) {
            if let Some(v) = v {
                *xi += v.sample(rng);
            }
        }
        x
    }

    fn log_observation(&self, t: usize, x: &Self::State, y: &f64, _u: &[f64]) -> f64 {
        if x[..self.n].iter().any(|v| !v.is_finite()) {
            return f64::NEG_INFINITY;
        }
        let mut yk = [0.0];
        self.with_rk4(|it| {
            it.reset(&x[..self.n], &Lanes::default());
            it.set_input(self.input(t));
            it.output(&mut yk);
        });
        if yk[0].is_finite() {
            self.measurement.log_pdf(y - yk[0])
        } else {
            f64::NEG_INFINITY
        }
    }
}

/// The PMMH target: `θ = (ln κ_p,1 … ln κ_p,n, ln κ_m, free parameters)`.
struct Problem<'a> {
    model: &'a PhysicsModel,
    inputs: &'a [Vec<f64>],
    /// Indices of the free parameters.
    free: Vec<usize>,
    /// The states with process noise (not kinematic), in state order.
    noisy: Vec<usize>,
    /// Their output-error estimate θ̂ and the factor L (row-major).
    centre: Vec<f64>,
    chol: Vec<f64>,
    proc_scale: Vec<f64>,
    meas_scale: f64,
    ts: f64,
}

impl<'a> Problem<'a> {
    /// The free parameters `θ̂ + L z` of the sampled coordinates `z`.
    fn natural(&self, z: &[f64]) -> Vec<f64> {
        let m = self.free.len();
        (0..m)
            .map(|a| self.centre[a] + (0..=a).map(|b| self.chol[a * m + b] * z[b]).sum::<f64>())
            .collect()
    }

    /// Number of log-levels (one per state with process noise, then the
    /// measurement).
    fn levels(&self) -> usize {
        self.noisy.len() + 1
    }

    /// The full parameter vector at `theta`, `None` outside the bounds.
    fn parameters_at(&self, theta: &[f64]) -> Option<Vec<f64>> {
        let spec = self.model.spec();
        let mut p = self.model.parameters().to_vec();
        for (&i, v) in self.free.iter().zip(self.natural(&theta[self.levels()..])) {
            let q = &spec.parameters[i];
            if !(v.is_finite() && v >= q.lower && v <= q.upper) {
                return None;
            }
            p[i] = v;
        }
        Some(p)
    }

    /// The noisy model at `theta` with the full parameter vector `params`
    /// (the integrator copies them).
    fn noisy(&self, theta: &[f64], params: &[f64]) -> Option<NoisyPhysics<'a>> {
        let gauss = |sd: f64| Noise::from_model(&gb_core::NoiseModel::Gaussian { sd }).ok();
        let mut process: Vec<Option<Noise>> = vec![None; self.proc_scale.len()];
        for (k, &i) in self.noisy.iter().enumerate() {
            process[i] = Some(gauss(self.proc_scale[i] * theta[k].exp())?);
        }
        let km = theta[self.noisy.len()].exp();
        let spec = self.model.spec();
        Some(NoisyPhysics {
            n: spec.states.len(),
            inputs: self.inputs,
            x0: self.model.initial_state().to_vec(),
            process,
            measurement: gauss(self.meas_scale * km)?,
            rk4: Mutex::new(Integrator::new(
                self.model.compiled(),
                params,
                self.ts,
                spec.substeps,
                &Lanes::default(),
            )),
        })
    }
}

impl<'a> ParametricModel for Problem<'a> {
    type Model = NoisyPhysics<'a>;
    fn dim(&self) -> usize {
        self.levels() + self.free.len()
    }
    fn build(&self, theta: &[f64]) -> Option<NoisyPhysics<'a>> {
        if !theta[..self.levels()].iter().all(|l| l.abs() <= 20.0) {
            return None;
        }
        let params = self.parameters_at(theta)?;
        self.noisy(theta, &params)
    }
    fn log_prior(&self, theta: &[f64]) -> f64 {
        let spec = self.model.spec();
        let nl = self.levels();
        let mut lp: f64 = theta[..nl].iter().map(|l| -0.5 * (l / 3.0).powi(2)).sum();
        for (&i, v) in self.free.iter().zip(self.natural(&theta[nl..])) {
            if let Some(p) = spec.parameters[i].prior {
                lp -= 0.5 * ((v - p.mean) / p.sd).powi(2);
            }
        }
        lp
    }
}

impl Problem<'_> {
    /// The draws after `burn_in` in natural units: each state's process
    /// scale, the measurement scale, the free parameters.
    fn posterior(&self, chain: &[f64], burn_in: usize) -> Vec<crate::PosteriorParameter> {
        let nl = self.levels();
        let d = nl + self.free.len();
        let rows = chain.len() / d;
        let start = burn_in.min(rows.saturating_sub(1));
        let draws = |j: usize, f: &dyn Fn(f64) -> f64| -> Vec<f64> {
            (start..rows).map(|k| f(chain[k * d + j])).collect()
        };
        let spec = self.model.spec();
        let mut out: Vec<_> = self
            .noisy
            .iter()
            .enumerate()
            .map(|(k, &i)| {
                let s = self.proc_scale[i];
                posterior_parameter(
                    format!("process_sd[{}]", spec.states[i].name),
                    &draws(k, &|v| s * v.exp()),
                )
            })
            .collect();
        out.push(posterior_parameter(
            "measurement_sd".into(),
            &draws(nl - 1, &|v| self.meas_scale * v.exp()),
        ));
        let natural: Vec<Vec<f64>> = (start..rows)
            .map(|k| self.natural(&chain[k * d + nl..(k + 1) * d]))
            .collect();
        for (j, &i) in self.free.iter().enumerate() {
            let x: Vec<f64> = natural.iter().map(|p| p[j]).collect();
            out.push(posterior_parameter(spec.parameters[i].name.clone(), &x));
        }
        out
    }
}

impl Smc {
    /// PMMH of the fitted one-output physics model `oe` (an output-error
    /// fit: its standard errors scale the proposal) on `data`: the
    /// posterior of the free parameters, a process-noise level per state
    /// and the measurement noise (see the module docs). The report's
    /// `path` says whether the posterior mean's particle likelihood beats
    /// the output-error start's (process noise at `process_fraction`).
    pub fn fit_physics(
        &self,
        oe: &PhysicsModel,
        data: &Record,
        obs: &dyn Observer,
    ) -> PhysicsResult<SmcReport> {
        Ok(self.fit_physics_model(oe, data, obs)?.0)
    }

    /// [`fit_physics`](Self::fit_physics), and the identified stochastic
    /// model: the parameters of the report's `path` (posterior mean, or the
    /// output-error estimate when the posterior mean's likelihood does not
    /// beat it) with the process and measurement noise levels at that point
    /// ([`PhysicsModel::state_noise`]); its fit report (standard errors)
    /// stays the output-error one.
    pub fn fit_physics_model(
        &self,
        oe: &PhysicsModel,
        data: &Record,
        obs: &dyn Observer,
    ) -> PhysicsResult<(SmcReport, PhysicsModel)> {
        let p = self.params();
        let spec = oe.spec();
        let bad = |m: String| Err(PhysicsError::Data(m));
        if let Some(d) = &spec.input_delay {
            return bad(format!(
                "the SMC path does not handle an input delay yet ('{}' has input_delay = \"{d}\"); fit it output-error",
                spec.name
            ));
        }
        if spec.outputs.len() != 1 || spec.states.len() > SMC_MAX_STATES {
            return bad(format!(
                "the SMC path handles models of one output and at most {SMC_MAX_STATES} states; '{}' has {} and {}",
                spec.name,
                spec.outputs.len(),
                spec.states.len()
            ));
        }
        if !spec.hysteresis.is_empty() {
            return bad(format!(
                "the SMC path does not carry the relay states of Preisach operators on states ('{}' has {})",
                spec.name,
                spec.hysteresis.len()
            ));
        }
        let Some(fit) = oe.fit_report() else {
            return bad("the SMC path starts from an output-error fit".into());
        };
        if data.inputs.len() != spec.inputs.len() || data.output.iter().any(|v| !v.is_finite()) {
            return bad("the data's inputs are not the model's, or an output is not finite".into());
        }
        let ts = oe.sample_time()?;
        let u = &data.inputs;
        let yhat = gb_core::DynamicModel::simulate(oe, u, Init::Stored)
            .map_err(|e| PhysicsError::Numerical(e.to_string()))?;
        let rmse = gb_core::metrics::rmse(&data.output, &yhat)
            .map_err(|e| PhysicsError::Data(e.to_string()))?
            .max(1e-12);
        let xs = oe.state_trajectory(u, Init::Stored)?;
        let proc_scale: Vec<f64> = xs
            .iter()
            .map(|x| {
                let d: Vec<f64> = x.windows(2).map(|w| w[1] - w[0]).collect();
                (p.process_fraction * gb_core::metrics::std(&d)).max(1e-12)
            })
            .collect();
        let free: Vec<usize> = (0..spec.parameters.len())
            .filter(|&i| !spec.parameters[i].fixed)
            .collect();
        let chol = proposal_factor(fit, &free, oe.parameters());
        let noisy: Vec<usize> = (0..spec.states.len())
            .filter(|&i| !kinematic(&spec.equations[i], spec))
            .collect();
        if noisy.is_empty() {
            return bad(format!(
                "'{}': every state is kinematic (its equation is another state), so no state takes process noise",
                spec.name
            ));
        }
        let problem = Problem {
            noisy,
            model: oe,
            inputs: u,
            centre: free.iter().map(|&i| oe.parameters()[i]).collect(),
            chol,
            free,
            proc_scale,
            meas_scale: rmse * p.measurement_fraction,
            ts,
        };
        let nl = problem.levels();
        let theta0 = vec![0.0; nl + problem.free.len()];
        // about 2.38/√d of the posterior sd per coordinate (Roberts &
        // Rosenthal 2001): z has sd about ½ (the covariance is inflated 4×)
        let d = (nl + problem.free.len()) as f64;
        let mut step = vec![0.1; nl];
        step[nl - 1] = 0.05;
        step.extend(std::iter::repeat_n(
            0.5 * 2.38 / d.sqrt(),
            problem.free.len(),
        ));
        let configs = crate::smc::chain_configs(p, &step);
        let observations = Observations::new(&data.output);
        let total = p.iterations;
        let chain = SubTask {
            outer: obs,
            offset: 0,
            span: total,
            total: total + 1,
        };
        let res = run_chains(&configs, &problem, &observations, &theta0, &chain)
            .map_err(|e| PhysicsError::Numerical(e.to_string()))?;
        let mean: Vec<f64> = res.summary.iter().map(|s| s.mean).collect();
        let sd: Vec<f64> = res.summary.iter().map(|s| s.sd).collect();
        // the pooled draws are after burn-in
        let parameters = problem.posterior(&res.chain, 0);
        let ll = |theta: &[f64]| -> f64 {
            let Some(m) = problem.build(theta) else {
                return f64::NEG_INFINITY;
            };
            FilterConfig::new(p.particles)
                .seed(p.seed)
                .build()
                .and_then(|pf| pf.run(&m, &observations))
                .map_or(f64::NEG_INFINITY, |o| o.log_likelihood)
        };
        let (ll_oe, ll_smc) = (ll(&theta0), ll(&mean));
        obs.progress(total + 1, total + 1, "done");
        let (path, best, at) = if ll_smc > ll_oe {
            (IdentificationPath::Smc, ll_smc, &mean)
        } else {
            (IdentificationPath::OutputError, ll_oe, &theta0)
        };
        let model = problem.stochastic_model(at)?;
        let report = SmcReport {
            path,
            log_likelihood_oe: ll_oe,
            log_likelihood_smc: ll_smc,
            log_likelihood: best,
            acceptance_rate: res.acceptance_rate,
            posterior_mean: mean,
            posterior_sd: sd,
            parameters,
            particles: res.n_particles,
            particle_choice: res.particle_choice,
        };
        Ok((report, model))
    }
}

impl Problem<'_> {
    /// The physics model at the sampled point `theta` with its noise levels.
    fn stochastic_model(&self, theta: &[f64]) -> PhysicsResult<PhysicsModel> {
        let params = self
            .parameters_at(theta)
            .unwrap_or_else(|| self.model.parameters().to_vec());
        let mut process_sd = vec![None; self.proc_scale.len()];
        for (k, &i) in self.noisy.iter().enumerate() {
            process_sd[i] = Some(self.proc_scale[i] * theta[k].exp());
        }
        self.model
            .clone()
            .with_values(params, self.model.initial_state().to_vec())?
            .with_state_noise(super::StateNoise {
                process_sd,
                measurement_sd: self.meas_scale * theta[self.noisy.len()].exp(),
            })
    }
}

/// The factor `L` (row-major, lower) of 4 × the output-error covariance of
/// the free parameters `free`; where that covariance is not usable (a
/// parameter not identifiable, not positive definite) the diagonal of
/// 2 × the standard errors, or 10⁻³ |θ̂|.
fn proposal_factor(fit: &super::FitReport, free: &[usize], theta: &[f64]) -> Vec<f64> {
    let m = free.len();
    let pos: Vec<Option<usize>> = free
        .iter()
        .map(|&i| {
            fit.free
                .iter()
                .position(|c| *c == super::Coordinate::Parameter(i))
        })
        .collect();
    let cov = nalgebra::DMatrix::from_fn(m, m, |a, b| match (pos[a], pos[b]) {
        (Some(ka), Some(kb)) => 4.0 * fit.cov(ka, kb),
        _ => f64::NAN,
    });
    if cov.iter().all(|v| v.is_finite()) {
        if let Some(c) = cov.clone().cholesky() {
            let l = c.l();
            return (0..m * m).map(|k| l[(k / m, k % m)]).collect();
        }
    }
    let mut l = vec![0.0; m * m];
    for a in 0..m {
        let v = cov[(a, a)];
        l[a * m + a] = if v.is_finite() && v > 0.0 {
            v.sqrt()
        } else {
            1e-3 * theta[free[a]].abs().max(1e-6)
        };
    }
    l
}

/// A kinematic equation: one term that is the name of a state.
fn kinematic(terms: &[String], spec: &super::PhysicsSpec) -> bool {
    matches!(terms, [t] if spec.states.iter().any(|s| s.name == t.trim()))
}

impl Smc {
    /// Filtered states `p(x_t | y_{0:t})` of a physics model identified by
    /// the SMC path (its [`PhysicsModel::state_noise`]), by the bootstrap
    /// particle filter from the stored initial state: mean, variance and
    /// 95 % band per state and sample, the ESS and the particle
    /// log-likelihood. Smoothing is not offered: a kinematic state has no
    /// transition density for backward simulation.
    pub fn filter_physics(
        &self,
        m: &PhysicsModel,
        inputs: &[Vec<f64>],
        y: &[f64],
    ) -> PhysicsResult<crate::StateEstimate> {
        let spec = m.spec();
        let noise = m.state_noise().ok_or_else(|| {
            PhysicsError::Data(format!(
                "'{}' has no state noise (an output-error fit), so the filter would only repeat the simulation; fit it with `greybox fit --model-file … --method smc`",
                spec.name
            ))
        })?;
        let n = spec.states.len();
        if spec.input_delay.is_some() {
            return Err(PhysicsError::Data(format!(
                "the filter does not handle an input delay yet ('{}')",
                spec.name
            )));
        }
        if !spec.hysteresis.is_empty() {
            return Err(PhysicsError::Data(format!(
                "the filter does not carry the relay states of Preisach operators on states ('{}' has {})",
                spec.name,
                spec.hysteresis.len()
            )));
        }
        if spec.outputs.len() != 1 || n > SMC_MAX_STATES {
            return Err(PhysicsError::Data(format!(
                "the filter handles models of one output and at most {SMC_MAX_STATES} states; '{}' has {} and {n}",
                spec.name,
                spec.outputs.len()
            )));
        }
        if inputs.len() != spec.inputs.len()
            || inputs.iter().any(|u| u.len() != y.len())
            || y.iter().any(|v| !v.is_finite())
        {
            return Err(PhysicsError::Data(
                "the data's inputs are not the model's, or an output is not finite".into(),
            ));
        }
        let gauss = |sd: f64| {
            Noise::from_model(&gb_core::NoiseModel::Gaussian { sd })
                .map_err(|e| PhysicsError::Numerical(e.to_string()))
        };
        let process = noise
            .process_sd
            .iter()
            .map(|v| v.map(gauss).transpose())
            .collect::<PhysicsResult<Vec<_>>>()?;
        let model = NoisyPhysics {
            n,
            inputs,
            x0: m.initial_state().to_vec(),
            process,
            measurement: gauss(noise.measurement_sd)?,
            rk4: Mutex::new(Integrator::new(
                m.compiled(),
                m.parameters(),
                m.sample_time()?,
                spec.substeps,
                &Lanes::default(),
            )),
        };
        let p = self.params();
        let num = |e: gb_smc::SmcError| PhysicsError::Numerical(e.to_string());
        let pf = FilterConfig::new(p.particles)
            .seed(p.seed)
            .build()
            .map_err(num)?;
        let (out, sums) = pf
            .run_summaries(&model, &Observations::new(y), &[0.025, 0.975])
            .map_err(num)?;
        Ok(crate::StateEstimate {
            log_likelihood: out.log_likelihood,
            increments: out.log_likelihood_increments,
            ess: out.ess,
            filtered: crate::StateBand::from_summaries(&sums, n),
            smoothed: None,
        })
    }
}
