//! Example models: stochastic volatility and the univariate nonlinear growth
//! benchmark, with configurable (non-Gaussian) noise.
use crate::error::{check, Result};
use crate::kalman::log_normal;
use crate::model::{StateSpaceModel, TransitionDensity};
use crate::noise::Noise;
use crate::rng::SmcRng;

/// Stochastic volatility model
///
/// ```text
/// x_0 ~ N(μ, σ²/(1−φ²)),  x_t = μ + φ (x_{t-1} − μ) + σ v_t,  y_t = exp(x_t / 2) e_t,
/// ```
///
/// `v_t ~ N(0, 1)`, `e_t` from a [`Noise`] (Gaussian or heavy-tailed Student-t).
///
/// ```
/// use gb_smc::models::StochasticVolatility;
/// use gb_smc::{FilterConfig, Observations};
/// let m = StochasticVolatility::new(-1.0, 0.95, 0.3).unwrap();
/// let (_, y) = m.simulate(100, 1);
/// let out = FilterConfig::new(500).build().unwrap().run(&m, &Observations::new(&y)).unwrap();
/// assert!(out.log_likelihood.is_finite());
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct StochasticVolatility {
    /// Mean log-volatility μ.
    pub mu: f64,
    /// Persistence φ, `|φ| < 1`.
    pub phi: f64,
    /// Volatility of log-volatility σ > 0.
    pub sigma: f64,
    /// Distribution of `e_t`.
    pub obs_noise: Noise,
}

impl StochasticVolatility {
    /// SV model with Gaussian `e_t`.
    pub fn new(mu: f64, phi: f64, sigma: f64) -> Result<Self> {
        Self::with_noise(mu, phi, sigma, Noise::gaussian(0.0, 1.0)?)
    }
    /// SV model with a given observation noise.
    pub fn with_noise(mu: f64, phi: f64, sigma: f64, obs_noise: Noise) -> Result<Self> {
        check("mu", mu, mu.is_finite(), "must be finite")?;
        check("phi", phi, phi.abs() < 1.0, "must satisfy |phi| < 1")?;
        check(
            "sigma",
            sigma,
            sigma > 0.0 && sigma.is_finite(),
            "must be positive",
        )?;
        Ok(Self {
            mu,
            phi,
            sigma,
            obs_noise,
        })
    }
    /// Simulates `(x, y)` of length `t`.
    pub fn simulate(&self, t: usize, seed: u64) -> (Vec<f64>, Vec<f64>) {
        simulate(self, t, seed, |m, x, rng| {
            (x / 2.0).exp() * m.obs_noise.sample(rng)
        })
    }
}

fn simulate<M: StateSpaceModel<State = f64>>(
    m: &M,
    t: usize,
    seed: u64,
    obs: impl Fn(&M, f64, &mut SmcRng) -> f64,
) -> (Vec<f64>, Vec<f64>) {
    let mut rng = crate::rng::stream(seed, 98, 0, 0);
    let mut xs: Vec<f64> = Vec::with_capacity(t);
    let mut ys = Vec::with_capacity(t);
    for k in 0..t {
        let x = if k == 0 {
            m.sample_initial(&[], &mut rng)
        } else {
            m.sample_transition(k, &xs[k - 1], &[], &mut rng)
        };
        ys.push(obs(m, x, &mut rng));
        xs.push(x);
    }
    (xs, ys)
}

impl StateSpaceModel for StochasticVolatility {
    type State = f64;
    type Obs = f64;
    fn sample_initial(&self, _u: &[f64], rng: &mut SmcRng) -> f64 {
        let sd = self.sigma / (1.0 - self.phi * self.phi).sqrt();
        self.mu + sd * crate::rng::standard_normal(rng)
    }
    fn sample_transition(&self, _t: usize, x: &f64, _u: &[f64], rng: &mut SmcRng) -> f64 {
        self.mu + self.phi * (x - self.mu) + self.sigma * crate::rng::standard_normal(rng)
    }
    fn log_observation(&self, _t: usize, x: &f64, y: &f64, _u: &[f64]) -> f64 {
        self.obs_noise.log_pdf(y * (-0.5 * x).exp()) - 0.5 * x
    }
}

impl TransitionDensity for StochasticVolatility {
    fn log_transition_density(&self, _t: usize, prev: &f64, x: &f64, _u: &[f64]) -> f64 {
        log_normal(
            *x,
            self.mu + self.phi * (prev - self.mu),
            self.sigma * self.sigma,
        )
    }
    fn log_transition_bound(&self, _t: usize, _u: &[f64]) -> Option<f64> {
        Some(log_normal(0.0, 0.0, self.sigma * self.sigma))
    }
}

/// Univariate nonlinear growth model (Kitagawa 1996; Gordon, Salmond & Smith 1993),
/// the standard nonlinear, bimodal filtering benchmark:
///
/// ```text
/// x_0 ~ N(0, 5),  x_t = x_{t-1}/2 + 25 x_{t-1}/(1 + x_{t-1}²) + 8 cos(1.2 t) + v_t,
/// y_t = x_t² / 20 + w_t,
/// ```
///
/// with `v_t`, `w_t` from [`Noise`] (classically `N(0, 10)` and `N(0, 1)`).
///
/// ```
/// use gb_smc::models::NonlinearGrowth;
/// use gb_smc::{FilterConfig, Observations};
/// let m = NonlinearGrowth::classic();
/// let (_, y) = m.simulate(50, 2);
/// let out = FilterConfig::new(1000).build().unwrap().run(&m, &Observations::new(&y)).unwrap();
/// assert!(out.log_likelihood.is_finite());
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct NonlinearGrowth {
    /// State noise `v_t`.
    pub state_noise: Noise,
    /// Observation noise `w_t`.
    pub obs_noise: Noise,
}

impl NonlinearGrowth {
    /// The classical setting `v_t ~ N(0, 10)`, `w_t ~ N(0, 1)`.
    pub fn classic() -> Self {
        Self {
            state_noise: Noise::Gaussian {
                mean: 0.0,
                sd: 10f64.sqrt(),
            },
            obs_noise: Noise::Gaussian { mean: 0.0, sd: 1.0 },
        }
    }
    /// Mean of the transition.
    #[inline]
    pub fn drift(t: usize, x: f64) -> f64 {
        0.5 * x + 25.0 * x / (1.0 + x * x) + 8.0 * (1.2 * t as f64).cos()
    }
    /// Simulates `(x, y)` of length `t`.
    pub fn simulate(&self, t: usize, seed: u64) -> (Vec<f64>, Vec<f64>) {
        simulate(self, t, seed, |m, x, rng| {
            x * x / 20.0 + m.obs_noise.sample(rng)
        })
    }
}

impl StateSpaceModel for NonlinearGrowth {
    type State = f64;
    type Obs = f64;
    fn sample_initial(&self, _u: &[f64], rng: &mut SmcRng) -> f64 {
        5f64.sqrt() * crate::rng::standard_normal(rng)
    }
    fn sample_transition(&self, t: usize, x: &f64, _u: &[f64], rng: &mut SmcRng) -> f64 {
        Self::drift(t, *x) + self.state_noise.sample(rng)
    }
    fn log_observation(&self, _t: usize, x: &f64, y: &f64, _u: &[f64]) -> f64 {
        self.obs_noise.log_pdf(y - x * x / 20.0)
    }
}

impl TransitionDensity for NonlinearGrowth {
    fn log_transition_density(&self, t: usize, prev: &f64, x: &f64, _u: &[f64]) -> f64 {
        self.state_noise.log_pdf(x - Self::drift(t, *prev))
    }
}
