//! The state-space model trait and data containers.
use crate::error::{Result, SmcError};
use crate::rng::SmcRng;

/// A (possibly nonlinear, non-Gaussian) state-space model
///
/// ```text
/// x_0 ~ p_0(x_0 | u_0),   x_t ~ f_t(x_t | x_{t-1}, u_t),   y_t ~ g_t(y_t | x_t, u_t).
/// ```
///
/// Only sampling from `p_0`, `f_t` and evaluating `log g_t` are required
/// (bootstrap filter). The optional methods add a proposal
/// `q_t(x_t | x_{t-1}, y_t)` (guided filter) and auxiliary weights
/// `η_t(x_{t-1}) ≈ p(y_t | x_{t-1})` (auxiliary filter). The defaults are the
/// bootstrap choices `q_t = f_t`, `η_t = 1`.
///
/// `u` is the input row `u_t` (empty when the data has no inputs). States of a
/// `Copy` type (`f64`, `[f64; D]`) are stored contiguously and updated in place:
/// that is the fast path.
///
/// ```
/// use gb_smc::{rng::standard_normal, StateSpaceModel, SmcRng};
/// /// x_t = 0.9 x_{t-1} + v_t,  y_t = x_t + 0.5 e_t.
/// struct Ar1;
/// impl StateSpaceModel for Ar1 {
///     type State = f64;
///     type Obs = f64;
///     fn sample_initial(&self, _u: &[f64], rng: &mut SmcRng) -> f64 {
///         standard_normal(rng) * 2.29
///     }
///     fn sample_transition(&self, _t: usize, x: &f64, _u: &[f64], rng: &mut SmcRng) -> f64 {
///         0.9 * x + standard_normal(rng)
///     }
///     fn log_observation(&self, _t: usize, x: &f64, y: &f64, _u: &[f64]) -> f64 {
///         let e = (y - x) / 0.5;
///         -0.5 * e * e - (0.5f64 * (2.0 * std::f64::consts::PI).sqrt()).ln()
///     }
/// }
/// ```
pub trait StateSpaceModel: Sync {
    /// Hidden state type.
    type State: Clone + Send + Sync;
    /// Observation type.
    type Obs: Sync;

    /// Draws `x_0 ~ p_0(· | u_0)`.
    fn sample_initial(&self, u: &[f64], rng: &mut SmcRng) -> Self::State;
    /// Draws `x_t ~ f_t(· | x_{t-1}, u_t)` for `t ≥ 1`.
    fn sample_transition(
        &self,
        t: usize,
        prev: &Self::State,
        u: &[f64],
        rng: &mut SmcRng,
    ) -> Self::State;
    /// `log g_t(y_t | x_t, u_t)`; `-inf` where the density is zero.
    fn log_observation(&self, t: usize, x: &Self::State, y: &Self::Obs, u: &[f64]) -> f64;

    /// Moves a block of particles in place, `x_i ← draw from f_t(· | x_i, u_t)`,
    /// all from one stream (used by the bootstrap filter, block by block).
    /// Default: [`sample_transition`](Self::sample_transition) for each particle in
    /// order. Override it to vectorise the transition (e.g. with
    /// [`fill_standard_normal`](crate::rng::fill_standard_normal)); any
    /// deterministic use of `rng` keeps the filter reproducible.
    #[inline]
    fn sample_transition_batch(
        &self,
        t: usize,
        x: &mut [Self::State],
        u: &[f64],
        rng: &mut SmcRng,
    ) {
        for xi in x.iter_mut() {
            *xi = self.sample_transition(t, xi, u, rng);
        }
    }
    /// `out_i = log g_t(y_t | x_i, u_t)` for a block of particles. Default:
    /// [`log_observation`](Self::log_observation) for each particle.
    #[inline]
    fn log_observation_batch(
        &self,
        t: usize,
        x: &[Self::State],
        y: &Self::Obs,
        u: &[f64],
        out: &mut [f64],
    ) {
        for (o, xi) in out.iter_mut().zip(x) {
            *o = self.log_observation(t, xi, y, u);
        }
    }

    /// Draws `x_0 ~ q_0(· | y_0, u_0)` (guided/auxiliary filters). Default: `p_0`.
    fn sample_initial_proposal(&self, _y: &Self::Obs, u: &[f64], rng: &mut SmcRng) -> Self::State {
        self.sample_initial(u, rng)
    }
    /// `log p_0(x_0) − log q_0(x_0 | y_0)`. Default `0` (matching the default proposal).
    fn log_initial_proposal_ratio(&self, _x: &Self::State, _y: &Self::Obs, _u: &[f64]) -> f64 {
        0.0
    }
    /// Draws `x_t ~ q_t(· | x_{t-1}, y_t, u_t)` (guided/auxiliary filters). Default: `f_t`.
    fn sample_proposal(
        &self,
        t: usize,
        prev: &Self::State,
        _y: &Self::Obs,
        u: &[f64],
        rng: &mut SmcRng,
    ) -> Self::State {
        self.sample_transition(t, prev, u, rng)
    }
    /// `log f_t(x_t | x_{t-1}) − log q_t(x_t | x_{t-1}, y_t)`. Default `0`.
    fn log_proposal_ratio(
        &self,
        _t: usize,
        _prev: &Self::State,
        _x: &Self::State,
        _y: &Self::Obs,
        _u: &[f64],
    ) -> f64 {
        0.0
    }
    /// Auxiliary log-weight `log η_t(x_{t-1})`, a look-ahead approximation of
    /// `log p(y_t | x_{t-1})` (auxiliary filter). Default `0`.
    fn log_auxiliary(&self, _t: usize, _prev: &Self::State, _y: &Self::Obs, _u: &[f64]) -> f64 {
        0.0
    }
}

/// Models whose transition density can be evaluated (needed by smoothers).
pub trait TransitionDensity: StateSpaceModel {
    /// `log f_t(x_t | x_{t-1}, u_t)` for `t ≥ 1`.
    fn log_transition_density(
        &self,
        t: usize,
        prev: &Self::State,
        x: &Self::State,
        u: &[f64],
    ) -> f64;
    /// An upper bound of `log f_t(· | ·)` over both arguments, if one exists;
    /// enables the O(N) rejection sampler of backward simulation.
    fn log_transition_bound(&self, _t: usize, _u: &[f64]) -> Option<f64> {
        None
    }
}

/// States that can be viewed as a vector of reals (for moments, quantiles and smoothers).
pub trait StateVector {
    /// The components.
    fn components(&self) -> &[f64];
}

impl StateVector for f64 {
    fn components(&self) -> &[f64] {
        std::slice::from_ref(self)
    }
}
impl<const D: usize> StateVector for [f64; D] {
    fn components(&self) -> &[f64] {
        self
    }
}
impl StateVector for Vec<f64> {
    fn components(&self) -> &[f64] {
        self
    }
}

/// Observations `y_0..y_{T-1}` and optional inputs `u_t ∈ R^{n_u}` (row-major).
///
/// ```
/// use gb_smc::Observations;
/// let y = [0.1, 0.3, -0.2];
/// let u = [1.0, 0.0, 1.0];
/// let obs = Observations::with_inputs(&y, &u, 1).unwrap();
/// assert_eq!(obs.len(), 3);
/// assert_eq!(obs.input(2), &[1.0]);
/// ```
#[derive(Debug, Clone, Copy)]
pub struct Observations<'a, O> {
    y: &'a [O],
    u: &'a [f64],
    nu: usize,
}

impl<'a, O> Observations<'a, O> {
    /// Observations without inputs.
    pub fn new(y: &'a [O]) -> Self {
        Self { y, u: &[], nu: 0 }
    }
    /// Observations with `nu` inputs per step, `u.len() == y.len() * nu`.
    pub fn with_inputs(y: &'a [O], u: &'a [f64], nu: usize) -> Result<Self> {
        if u.len() != y.len() * nu {
            return Err(SmcError::LengthMismatch {
                what: "inputs (T * nu)",
                expected: y.len() * nu,
                got: u.len(),
            });
        }
        Ok(Self { y, u, nu })
    }
    /// Number of time steps `T`.
    pub fn len(&self) -> usize {
        self.y.len()
    }
    /// `true` when there is no observation.
    pub fn is_empty(&self) -> bool {
        self.y.is_empty()
    }
    /// Observation `y_t`.
    pub fn y(&self, t: usize) -> &'a O {
        &self.y[t]
    }
    /// All observations.
    pub fn ys(&self) -> &'a [O] {
        self.y
    }
    /// Input row `u_t` (empty without inputs).
    #[inline]
    pub fn input(&self, t: usize) -> &'a [f64] {
        &self.u[t * self.nu..(t + 1) * self.nu]
    }
    /// Number of inputs per step.
    pub fn n_inputs(&self) -> usize {
        self.nu
    }
}
