//! The one Levenberg–Marquardt solver of the workspace.
//!
//! Every class that trains by nonlinear least squares (output-error /
//! simulation-error fits, initial-state estimation, block-oriented models)
//! describes its problem through [`LeastSquaresProblem`] — the cost
//! `V(θ) = Σₜ wₜ eₜ²` (plus any penalty) and, at a point, the Gram matrix
//! `G = JᵀWJ` and the gradient `g = JᵀWe` with `e = y − ŷ(θ)`, `J = ∂ŷ/∂θ` —
//! and [`LevenbergMarquardt::minimize`] owns the loop, the damping, the
//! termination and the observer calls (argmin's executor/solver split).
//!
//! One iteration solves
//!
//! ```text
//! (G + D_λ) δ = g,   D_λ,ii = λ·(max(Gᵢᵢ, ρ·maxⱼ Gⱼⱼ, ρ₀) + a) + ε·maxⱼ Gⱼⱼ + ε₀
//! ```
//!
//! (Marquardt's scaling with a relative floor ρ, an absolute floor ρ₀, an
//! additive term a and a relative / absolute jitter ε / ε₀), maps θ + δ
//! through [`LeastSquaresProblem::project`] and accepts it when it is
//! admissible and lowers the cost (with a Tikhonov penalty `Σ rᵢθᵢ²`,
//! [`LeastSquaresProblem::tikhonov`], the system is
//! `(G + D_λ + diag r) δ = g − r∘θ`); then `λ ← max(λ·down, λ_min)` (for
//! `down = 1/m` with an integer m this is computed as λ/m, one rounding).
//! A rejected step raises `λ ← λ·up` (by `up_singular` when `G + D_λ` is
//! not positive definite, see [`LeastSquaresProblem::solve_damped`]) and
//! tries again, up to
//! `max_trials` times. It stops when the relative decrease of an accepted
//! step falls below `tol`, when no trial lowers the cost, when `λ > λ_max`,
//! or after `max_iter` iterations.
//!
//! ```
//! use gb_core::solver::{LeastSquaresProblem, LmParams, Termination};
//! /// Fit y = a·exp(b·t) to data of a = 2, b = −0.5 with a small disturbance.
//! struct Exp { t: Vec<f64>, y: Vec<f64> }
//! impl LeastSquaresProblem for Exp {
//!     fn n_params(&self) -> usize { 2 }
//!     fn cost(&mut self, p: &[f64]) -> Option<f64> {
//!         Some(self.t.iter().zip(&self.y).map(|(t, y)| (y - p[0] * (p[1] * t).exp()).powi(2)).sum())
//!     }
//!     fn linearize(&mut self, p: &[f64], gram: &mut [f64], grad: &mut [f64]) -> Option<f64> {
//!         gram.fill(0.0); grad.fill(0.0);
//!         let mut c = 0.0;
//!         for (t, y) in self.t.iter().zip(&self.y) {
//!             let f = (p[1] * t).exp();
//!             let e = y - p[0] * f;
//!             let j = [f, p[0] * t * f];
//!             for a in 0..2 { grad[a] += j[a] * e; for b in 0..2 { gram[a * 2 + b] += j[a] * j[b]; } }
//!             c += e * e;
//!         }
//!         Some(c)
//!     }
//! }
//! let t: Vec<f64> = (0..20).map(|k| k as f64 * 0.2).collect();
//! let y = t.iter().enumerate().map(|(k, t)| 2.0 * (-0.5 * t).exp() + 1e-3 * (7.0 * k as f64).sin()).collect();
//! let lm = LmParams::default().check().unwrap();
//! let s = lm.minimize(&mut Exp { t, y }, &[1.0, 0.0], &gb_core::Silent).unwrap();
//! assert!((s.theta[0] - 2.0).abs() < 1e-2 && (s.theta[1] + 0.5).abs() < 1e-2);
//! assert_eq!(s.termination, Some(Termination::Converged));
//! ```
use crate::observe::{IterationInfo, Observer};
use crate::CoreError;
use nalgebra::{DMatrix, DVector};

/// A nonlinear least-squares problem in normal-equation form.
pub trait LeastSquaresProblem {
    /// Number of parameters θ.
    fn n_params(&self) -> usize;

    /// Cost `V(θ)`; `None` where θ is infeasible (the simulation diverges).
    fn cost(&mut self, theta: &[f64]) -> Option<f64>;

    /// Cost, Gram matrix `G = JᵀWJ` (n×n, row-major, both triangles) and
    /// gradient `g = JᵀWe` (`e = y − ŷ`) at θ; `None` where θ is infeasible.
    /// The returned cost must equal [`cost`](Self::cost) at the same θ.
    fn linearize(&mut self, theta: &[f64], gram: &mut [f64], grad: &mut [f64]) -> Option<f64>;

    /// Whether a trial point may be evaluated at all (stability, bounds).
    /// Checked before [`cost`](Self::cost) on every trial.
    fn admissible(&mut self, theta: &[f64]) -> bool {
        let _ = theta;
        true
    }

    /// Map a trial point onto the feasible set before it is checked and
    /// evaluated (e.g. cap a norm); the accepted point is the projected one.
    /// Default: unchanged.
    fn project(&mut self, theta: &mut [f64]) {
        let _ = theta;
    }

    /// Solve the damped normal equations `A δ = g` into `delta`; `a` is the
    /// symmetric positive definite n×n matrix `G + D_λ`, column-major, and
    /// may be overwritten. `false` where `A` is not positive definite. The
    /// default is [`cholesky_solve`]; a problem may supply a faster or
    /// structured factorisation.
    fn solve_damped(&mut self, a: &mut [f64], g: &[f64], delta: &mut [f64]) -> bool {
        cholesky_solve(a, g, delta)
    }

    /// Weights `ρᵢ ≥ 0` (one per parameter) of a Tikhonov penalty
    /// `Σᵢ ρᵢ θᵢ²` that [`cost`](Self::cost) includes but
    /// [`linearize`](Self::linearize) leaves out of the Gram matrix and the
    /// gradient (they describe the data term alone). The solver adds `ρᵢ` to
    /// the diagonal of the damped system and `−ρᵢ θᵢ` to the gradient, outside
    /// the Marquardt scaling, so the damping scales with the data term only.
    /// `None` (the default): no penalty.
    fn tikhonov(&self) -> Option<&[f64]> {
        None
    }
}

/// Solve `A δ = g` for a symmetric positive definite `A` (n×n, column-major)
/// by a Cholesky factorisation; `false` where `A` is not positive definite.
pub fn cholesky_solve(a: &[f64], g: &[f64], delta: &mut [f64]) -> bool {
    let n = g.len();
    let Some(chol) = DMatrix::from_column_slice(n, n, a).cholesky() else {
        return false;
    };
    delta.copy_from_slice(chol.solve(&DVector::from_column_slice(g)).as_slice());
    true
}

/// Why the solver stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Termination {
    /// An accepted step lowered the cost by less than `tol` (relative).
    Converged,
    /// `max_iter` iterations ran.
    MaxIterations,
    /// No trial step lowered the cost.
    NoImprovement,
    /// The damping exceeded `lambda_max`.
    DampingOverflow,
    /// The problem could not be linearised at the current point.
    Infeasible,
    /// The last `stall_window` iterations together lowered the cost by
    /// less than `stall_tol` (relative): a crawl along a flat valley.
    Stalled,
    /// After `futile_after` iterations the cost was still above
    /// `futile_ratio` times the start cost: a screen gave up on a fit that
    /// could not reach the gain it needs.
    Futile,
}

/// Settings of [`LevenbergMarquardt`]; validate with [`check`](Self::check).
///
/// | field | default | meaning |
/// |---|---|---|
/// | `max_iter` | 100 | iterations (each one linearisation) |
/// | `tol` | 1e-8 | relative cost decrease that counts as converged |
/// | `lambda_init` | 1e-3 | initial damping λ |
/// | `lambda_up` | 4 | factor on λ after a rejected step |
/// | `lambda_up_singular` | 10 | factor on λ when `G + D_λ` is singular |
/// | `lambda_down` | 1/3 | factor on λ after an accepted step |
/// | `lambda_min` | 1e-12 | smallest λ |
/// | `lambda_max` | 1e12 | λ above which the solver gives up |
/// | `max_trials` | 12 | trial steps per iteration |
/// | `diag_floor` | 1e-9 | ρ: floor of the scaling, relative to `max Gⱼⱼ` |
/// | `diag_floor_abs` | 0 | ρ₀: absolute floor of the scaling |
/// | `diag_add` | 0 | a: added to the scaling (absolute) |
/// | `jitter` | 1e-12 | ε: added to the diagonal, relative to `max Gⱼⱼ` |
/// | `jitter_abs` | 0 | ε₀: added to the diagonal (absolute) |
/// | `stall_window` | 0 | W: iterations over which progress is judged (0: never) |
/// | `stall_tol` | 0 | stop when `(S_{k−W} − S_k)/S_k < stall_tol` after iteration k |
/// | `futile_after` | 0 | K: the iteration of the futility check (0: never) |
/// | `futile_ratio` | 0 | stop after iteration K when `S_K > futile_ratio · S_0` |
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmParams {
    /// Most iterations.
    pub max_iter: usize,
    /// Relative cost decrease below which an accepted step ends the run.
    pub tol: f64,
    /// Initial damping.
    pub lambda_init: f64,
    /// Damping factor after a rejected step.
    pub lambda_up: f64,
    /// Damping factor when the damped system is not positive definite.
    pub lambda_up_singular: f64,
    /// Damping factor after an accepted step.
    pub lambda_down: f64,
    /// Smallest damping.
    pub lambda_min: f64,
    /// Damping at which the solver gives up.
    pub lambda_max: f64,
    /// Trial steps per iteration.
    pub max_trials: usize,
    /// Floor ρ of the Marquardt scaling, relative to the largest diagonal.
    pub diag_floor: f64,
    /// Absolute floor ρ₀ of the Marquardt scaling.
    pub diag_floor_abs: f64,
    /// Absolute term a added to the Marquardt scaling.
    pub diag_add: f64,
    /// Jitter ε added to the diagonal, relative to the largest diagonal.
    pub jitter: f64,
    /// Absolute jitter ε₀ added to the diagonal.
    pub jitter_abs: f64,
    /// Iterations over which progress is judged by `stall_tol` (0: never).
    pub stall_window: usize,
    /// Relative cost decrease over `stall_window` iterations below which the
    /// run stops ([`Termination::Stalled`]).
    pub stall_tol: f64,
    /// The iteration after which [`futile_ratio`](Self::futile_ratio) is
    /// checked once (0: never).
    pub futile_after: usize,
    /// The largest cost ratio `S_K/S_0` at iteration `futile_after` that
    /// lets the run go on ([`Termination::Futile`]).
    pub futile_ratio: f64,
}

impl Default for LmParams {
    fn default() -> Self {
        Self {
            max_iter: 100,
            tol: 1e-8,
            lambda_init: 1e-3,
            lambda_up: 4.0,
            lambda_up_singular: 10.0,
            lambda_down: 1.0 / 3.0,
            lambda_min: 1e-12,
            lambda_max: 1e12,
            max_trials: 12,
            diag_floor: 1e-9,
            diag_floor_abs: 0.0,
            diag_add: 0.0,
            jitter: 1e-12,
            jitter_abs: 0.0,
            stall_window: 0,
            stall_tol: 0.0,
            futile_after: 0,
            futile_ratio: 0.0,
        }
    }
}

impl LmParams {
    /// Most iterations.
    pub fn max_iter(mut self, n: usize) -> Self {
        self.max_iter = n;
        self
    }
    /// Convergence tolerance (relative cost decrease).
    pub fn tol(mut self, t: f64) -> Self {
        self.tol = t;
        self
    }
    /// Initial damping.
    pub fn lambda_init(mut self, l: f64) -> Self {
        self.lambda_init = l;
        self
    }
    /// Stop when `window` iterations together lower the cost by less than
    /// `tol` (relative): `(S_{k−W} − S_k)/S_k < tol`. Cheap insurance
    /// against crawling along a flat valley until `max_iter`.
    pub fn stall(mut self, window: usize, tol: f64) -> Self {
        self.stall_window = window;
        self.stall_tol = tol;
        self
    }

    /// Give up after iteration `after` when the cost is still above
    /// `ratio` times the start cost, `S_K > ratio·S_0`
    /// ([`Termination::Futile`]): a screen for fits that only count when
    /// they gain a stated fraction (an extension that must lower the RMSE by
    /// `g` needs `S ≤ (1 − g)²·S_0`). The run is otherwise unchanged, so a
    /// fit that passes the check ends where it would without it.
    pub fn futile(mut self, after: usize, ratio: f64) -> Self {
        self.futile_after = after;
        self.futile_ratio = ratio;
        self
    }

    /// Validate once; the result runs fits.
    pub fn check(self) -> Result<LevenbergMarquardt, CoreError> {
        let pos = |name: &str, v: f64| -> Result<(), CoreError> {
            if v > 0.0 && v.is_finite() {
                Ok(())
            } else {
                Err(CoreError::InvalidArgument(format!(
                    "Levenberg-Marquardt: {name} must be positive and finite, got {v}"
                )))
            }
        };
        pos("lambda_init", self.lambda_init)?;
        pos("lambda_min", self.lambda_min)?;
        pos("lambda_max", self.lambda_max)?;
        if !(self.lambda_up > 1.0 && self.lambda_up_singular > 1.0) {
            return Err(CoreError::InvalidArgument(
                "Levenberg-Marquardt: lambda_up and lambda_up_singular must exceed 1".into(),
            ));
        }
        if !(self.lambda_down > 0.0 && self.lambda_down < 1.0) {
            return Err(CoreError::InvalidArgument(
                "Levenberg-Marquardt: lambda_down must be in (0, 1)".into(),
            ));
        }
        if self.lambda_min > self.lambda_max || self.max_trials == 0 {
            return Err(CoreError::InvalidArgument(
                "Levenberg-Marquardt: lambda_min <= lambda_max and max_trials >= 1".into(),
            ));
        }
        let nonneg = [
            self.tol,
            self.diag_floor,
            self.diag_floor_abs,
            self.diag_add,
            self.jitter,
            self.jitter_abs,
            self.stall_tol,
            self.futile_ratio,
        ];
        if nonneg.iter().any(|v| !(*v >= 0.0 && v.is_finite())) {
            return Err(CoreError::InvalidArgument(
                "Levenberg-Marquardt: tol, diag_floor(_abs), diag_add, jitter(_abs), stall_tol and futile_ratio must be >= 0"
                    .into(),
            ));
        }
        Ok(LevenbergMarquardt { p: self })
    }
}

/// `λ·down`, computed as `λ/m` when `down = 1/m` for an integer m (one
/// rounding instead of two: a down factor of 1/3 divides by 3 exactly).
fn shrink(lambda: f64, down: f64) -> f64 {
    let m = 1.0 / down;
    if m == m.round() {
        lambda / m
    } else {
        lambda * down
    }
}

/// A validated Levenberg–Marquardt solver (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LevenbergMarquardt {
    p: LmParams,
}

/// The solver's state between iterations.
#[derive(Debug, Clone, PartialEq)]
pub struct LmState {
    /// Current parameters.
    pub theta: Vec<f64>,
    /// Cost at `theta`.
    pub cost: f64,
    /// Cost at the start.
    pub initial_cost: f64,
    /// Current damping.
    pub lambda: f64,
    /// Iterations run.
    pub iterations: usize,
    /// Cost evaluations (linearisations included).
    pub evaluations: usize,
    /// Set when the solver has stopped.
    pub termination: Option<Termination>,
}

/// Buffers of one run, allocated once.
#[derive(Debug, Clone)]
pub struct LmWorkspace {
    gram: Vec<f64>,
    grad: Vec<f64>,
    rhs: Vec<f64>,
    ridge: Vec<f64>,
    trial: Vec<f64>,
    delta: Vec<f64>,
    a: DMatrix<f64>,
}

impl LmWorkspace {
    /// Buffers for `n` parameters.
    pub fn new(n: usize) -> Self {
        Self {
            gram: vec![0.0; n * n],
            grad: vec![0.0; n],
            rhs: vec![0.0; n],
            ridge: Vec::with_capacity(n),
            trial: vec![0.0; n],
            delta: vec![0.0; n],
            a: DMatrix::zeros(n, n),
        }
    }
    /// The Gram matrix of the last linearisation (row-major n×n).
    pub fn gram(&self) -> &[f64] {
        &self.gram
    }
}

impl LevenbergMarquardt {
    /// The settings.
    pub fn params(&self) -> &LmParams {
        &self.p
    }

    /// Start state at `theta0`; an error when the problem is infeasible there.
    pub fn init<P: LeastSquaresProblem + ?Sized>(
        &self,
        problem: &mut P,
        theta0: &[f64],
    ) -> Result<LmState, CoreError> {
        let n = problem.n_params();
        if theta0.len() != n {
            return Err(CoreError::Dimension(format!(
                "{} start values for {n} parameters",
                theta0.len()
            )));
        }
        let cost = problem
            .cost(theta0)
            .filter(|c| c.is_finite())
            .ok_or_else(|| {
                CoreError::InvalidArgument(
                    "the start point is infeasible (the simulation diverges)".into(),
                )
            })?;
        Ok(LmState {
            theta: theta0.to_vec(),
            cost,
            initial_cost: cost,
            lambda: self.p.lambda_init,
            iterations: 0,
            evaluations: 1,
            termination: if n == 0 {
                Some(Termination::Converged)
            } else {
                None
            },
        })
    }

    /// One iteration: linearise at `state.theta`, then try damped steps until
    /// one is accepted or the damping runs out. Sets `state.termination`
    /// when the run should stop.
    pub fn next_iter<P: LeastSquaresProblem + ?Sized>(
        &self,
        problem: &mut P,
        state: &mut LmState,
        ws: &mut LmWorkspace,
    ) {
        let n = state.theta.len();
        state.iterations += 1;
        state.evaluations += 1;
        let Some(cost) = problem
            .linearize(&state.theta, &mut ws.gram, &mut ws.grad)
            .filter(|c| c.is_finite())
        else {
            state.termination = Some(Termination::Infeasible);
            return;
        };
        state.cost = cost;
        let dmax = (0..n)
            .map(|i| ws.gram[i * n + i])
            .fold(0.0, f64::max)
            .max(1e-300);
        let p = &self.p;
        let ridge = match problem.tikhonov() {
            Some(r) if r.len() == n => {
                ws.ridge.clear();
                ws.ridge.extend_from_slice(r);
                true
            }
            _ => false,
        };
        ws.rhs.copy_from_slice(&ws.grad);
        if ridge {
            for i in 0..n {
                ws.rhs[i] -= ws.ridge[i] * state.theta[i];
            }
        }
        for _ in 0..p.max_trials {
            let lambda = state.lambda;
            for i in 0..n {
                for j in 0..n {
                    ws.a[(i, j)] = ws.gram[i * n + j];
                }
                let g = ws.gram[i * n + i];
                ws.a[(i, i)] += lambda
                    * (g.max(p.diag_floor * dmax).max(p.diag_floor_abs) + p.diag_add)
                    + p.jitter * dmax
                    + p.jitter_abs;
                if ridge {
                    ws.a[(i, i)] += ws.ridge[i];
                }
            }
            let solved = problem.solve_damped(ws.a.as_mut_slice(), &ws.rhs, &mut ws.delta);
            if !solved || !ws.delta.iter().all(|d| d.is_finite()) {
                state.lambda *= p.lambda_up_singular;
                if state.lambda > p.lambda_max {
                    state.termination = Some(Termination::DampingOverflow);
                    return;
                }
                continue;
            };
            for i in 0..n {
                ws.trial[i] = state.theta[i] + ws.delta[i];
            }
            problem.project(&mut ws.trial);
            if problem.admissible(&ws.trial) {
                state.evaluations += 1;
                if let Some(c) = problem.cost(&ws.trial).filter(|c| c.is_finite()) {
                    if c < cost {
                        let rel = (cost - c) / cost.max(1e-300);
                        state.theta.copy_from_slice(&ws.trial);
                        state.cost = c;
                        state.lambda = shrink(state.lambda, p.lambda_down).max(p.lambda_min);
                        if rel < p.tol {
                            state.termination = Some(Termination::Converged);
                        }
                        return;
                    }
                }
            }
            state.lambda *= p.lambda_up;
            if state.lambda > p.lambda_max {
                state.termination = Some(Termination::DampingOverflow);
                return;
            }
        }
        state.termination = Some(Termination::NoImprovement);
    }

    /// Run from `theta0` until a termination criterion holds, reporting
    /// every iteration to `observer`.
    pub fn minimize<P: LeastSquaresProblem + ?Sized>(
        &self,
        problem: &mut P,
        theta0: &[f64],
        observer: &dyn Observer,
    ) -> Result<LmState, CoreError> {
        let mut state = self.init(problem, theta0)?;
        let mut ws = LmWorkspace::new(theta0.len());
        self.run(problem, &mut state, &mut ws, observer);
        Ok(state)
    }

    /// Continue `state` until a termination criterion holds (the executor).
    pub fn run<P: LeastSquaresProblem + ?Sized>(
        &self,
        problem: &mut P,
        state: &mut LmState,
        ws: &mut LmWorkspace,
        observer: &dyn Observer,
    ) {
        let w = self.p.stall_window;
        let mut costs = Vec::with_capacity(if w > 0 { self.p.max_iter + 1 } else { 0 });
        if w > 0 {
            costs.push(state.cost);
        }
        while state.termination.is_none() {
            if state.iterations >= self.p.max_iter {
                state.termination = Some(Termination::MaxIterations);
                break;
            }
            self.next_iter(problem, state, ws);
            if w > 0 {
                costs.push(state.cost);
                let k = costs.len() - 1;
                if state.termination.is_none()
                    && k >= w
                    && costs[k - w] - state.cost < self.p.stall_tol * state.cost.max(1e-300)
                {
                    state.termination = Some(Termination::Stalled);
                }
            }
            if state.termination.is_none()
                && self.p.futile_after > 0
                && state.iterations == self.p.futile_after
                && state.cost > self.p.futile_ratio * state.initial_cost
            {
                state.termination = Some(Termination::Futile);
            }
            observer.iteration(&IterationInfo {
                solver: "levenberg-marquardt",
                iteration: state.iterations,
                cost: state.cost,
                lambda: state.lambda,
                evaluations: state.evaluations,
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rosenbrock as least squares: r = (10(θ₁ − θ₀²), 1 − θ₀).
    struct Rosenbrock {
        admissible_calls: usize,
        /// Reject trial points with θ₀ > this bound.
        bound: f64,
    }
    impl LeastSquaresProblem for Rosenbrock {
        fn n_params(&self) -> usize {
            2
        }
        fn cost(&mut self, t: &[f64]) -> Option<f64> {
            let r = [10.0 * (t[1] - t[0] * t[0]), 1.0 - t[0]];
            Some(r[0] * r[0] + r[1] * r[1])
        }
        fn linearize(&mut self, t: &[f64], g: &mut [f64], grad: &mut [f64]) -> Option<f64> {
            // ŷ = −r (so e = y − ŷ = r with y = 0); J = ∂ŷ/∂θ = −∂r/∂θ
            let r = [10.0 * (t[1] - t[0] * t[0]), 1.0 - t[0]];
            let j = [[20.0 * t[0], -10.0], [1.0, 0.0]];
            g.fill(0.0);
            grad.fill(0.0);
            for k in 0..2 {
                for a in 0..2 {
                    grad[a] += j[k][a] * r[k];
                    for b in 0..2 {
                        g[a * 2 + b] += j[k][a] * j[k][b];
                    }
                }
            }
            Some(r[0] * r[0] + r[1] * r[1])
        }
        fn admissible(&mut self, t: &[f64]) -> bool {
            self.admissible_calls += 1;
            t[0] <= self.bound
        }
    }

    /// S(θ) = 1 + e^(−θ) with a Gram matrix 10⁶ times too large: every
    /// step is accepted but lowers the cost by about 10⁻⁷ (relative), above
    /// `tol`, so only the iteration limit or the stall rule stops it.
    struct Crawl;
    impl LeastSquaresProblem for Crawl {
        fn n_params(&self) -> usize {
            1
        }
        fn cost(&mut self, t: &[f64]) -> Option<f64> {
            Some(1.0 + (-t[0]).exp())
        }
        fn linearize(&mut self, t: &[f64], g: &mut [f64], grad: &mut [f64]) -> Option<f64> {
            g[0] = 1e6;
            grad[0] = 0.5 * (-t[0]).exp();
            Some(1.0 + (-t[0]).exp())
        }
    }

    #[test]
    fn a_crawl_stops_after_the_stall_window() {
        let plain = LmParams::default().max_iter(100).check().unwrap();
        let s = plain.minimize(&mut Crawl, &[0.0], &crate::Silent).unwrap();
        assert_eq!(s.termination, Some(Termination::MaxIterations));
        let stalled = LmParams::default()
            .max_iter(100)
            .stall(10, 1e-4)
            .check()
            .unwrap();
        let t = stalled
            .minimize(&mut Crawl, &[0.0], &crate::Silent)
            .unwrap();
        assert_eq!(t.termination, Some(Termination::Stalled));
        assert_eq!(t.iterations, 10);
        assert!(t.cost < t.initial_cost);
        // a run that makes progress is not cut short by the same rule
        let lm = LmParams::default()
            .tol(1e-14)
            .stall(10, 1e-4)
            .check()
            .unwrap();
        let mut p = Rosenbrock {
            admissible_calls: 0,
            bound: f64::INFINITY,
        };
        let r = lm.minimize(&mut p, &[-1.2, 1.0], &crate::Silent).unwrap();
        assert!(
            (r.theta[0] - 1.0).abs() < 1e-6,
            "{:?} {:?}",
            r.theta,
            r.termination
        );
        assert!(LmParams::default().stall(5, -1.0).check().is_err());
    }

    #[test]
    fn a_futile_run_stops_at_its_check_and_a_progressing_one_is_unchanged() {
        // the crawl lowers its cost by far less than half in 3 iterations
        let lm = LmParams::default().max_iter(100).futile(3, 0.5);
        let s = lm
            .check()
            .unwrap()
            .minimize(&mut Crawl, &[0.0], &crate::Silent)
            .unwrap();
        assert_eq!(s.termination, Some(Termination::Futile));
        assert_eq!(s.iterations, 3);
        assert!(s.cost > 0.5 * s.initial_cost && s.cost < s.initial_cost);
        // Rosenbrock falls to 5 % of its start cost in 4 iterations: a rule
        // at 10 % passes it and the path is the plain one
        let rosenbrock = || Rosenbrock {
            admissible_calls: 0,
            bound: f64::INFINITY,
        };
        let plain = LmParams::default().tol(1e-14);
        let a = plain
            .check()
            .unwrap()
            .minimize(&mut rosenbrock(), &[-1.2, 1.0], &crate::Silent)
            .unwrap();
        let b = plain
            .futile(4, 0.1)
            .check()
            .unwrap()
            .minimize(&mut rosenbrock(), &[-1.2, 1.0], &crate::Silent)
            .unwrap();
        assert_eq!(a, b);
        assert!((b.theta[0] - 1.0).abs() < 1e-6, "{:?}", b.theta);
        // a rule at 1 % stops the same run at its check
        let c = plain
            .futile(4, 0.01)
            .check()
            .unwrap()
            .minimize(&mut rosenbrock(), &[-1.2, 1.0], &crate::Silent)
            .unwrap();
        assert_eq!(c.termination, Some(Termination::Futile));
        assert_eq!(c.iterations, 4);
        assert!(LmParams::default().futile(4, -0.1).check().is_err());
    }

    #[test]
    fn finds_the_rosenbrock_minimum() {
        let lm = LmParams::default().tol(1e-14).check().unwrap();
        let mut p = Rosenbrock {
            admissible_calls: 0,
            bound: f64::INFINITY,
        };
        let s = lm.minimize(&mut p, &[-1.2, 1.0], &crate::Silent).unwrap();
        assert!((s.theta[0] - 1.0).abs() < 1e-6, "{:?}", s.theta);
        assert!((s.theta[1] - 1.0).abs() < 1e-6, "{:?}", s.theta);
        assert!(s.cost < 1e-12 && s.cost < s.initial_cost);
        assert!(p.admissible_calls > 0);
    }

    #[test]
    fn inadmissible_trials_are_never_accepted() {
        let lm = LmParams::default().check().unwrap();
        let mut p = Rosenbrock {
            admissible_calls: 0,
            bound: 0.5,
        };
        let s = lm.minimize(&mut p, &[-1.2, 1.0], &crate::Silent).unwrap();
        assert!(s.theta[0] <= 0.5);
        // the constrained optimum lies on the bound θ₀ = 0.5
        assert!(s.theta[0] > 0.3, "{:?}", s.theta);
    }

    /// Linear least squares `y ≈ Xθ` with a Tikhonov penalty `Σ rᵢθᵢ²`
    /// (the Gram matrix and gradient of the data term only).
    struct Ridge {
        x: Vec<[f64; 2]>,
        y: Vec<f64>,
        r: [f64; 2],
    }
    impl LeastSquaresProblem for Ridge {
        fn n_params(&self) -> usize {
            2
        }
        fn cost(&mut self, t: &[f64]) -> Option<f64> {
            let sse: f64 = self
                .x
                .iter()
                .zip(&self.y)
                .map(|(x, y)| (y - x[0] * t[0] - x[1] * t[1]).powi(2))
                .sum();
            Some(sse + self.r[0] * t[0] * t[0] + self.r[1] * t[1] * t[1])
        }
        fn linearize(&mut self, t: &[f64], g: &mut [f64], grad: &mut [f64]) -> Option<f64> {
            g.fill(0.0);
            grad.fill(0.0);
            for (x, y) in self.x.iter().zip(&self.y) {
                let e = y - x[0] * t[0] - x[1] * t[1];
                for a in 0..2 {
                    grad[a] += x[a] * e;
                    for b in 0..2 {
                        g[a * 2 + b] += x[a] * x[b];
                    }
                }
            }
            self.cost(t)
        }
        fn tikhonov(&self) -> Option<&[f64]> {
            Some(&self.r)
        }
    }

    #[test]
    fn tikhonov_penalty_gives_the_ridge_solution() {
        let x: Vec<[f64; 2]> = (0..30).map(|k| [1.0, (k as f64 * 0.7).sin()]).collect();
        let y: Vec<f64> = x
            .iter()
            .enumerate()
            .map(|(k, x)| 0.5 + 2.0 * x[1] + 0.1 * (k as f64 * 1.3).cos())
            .collect();
        let r = [0.0, 5.0];
        // closed form: (XᵀX + diag r) θ = Xᵀy
        let mut a = nalgebra::Matrix2::<f64>::zeros();
        let mut b = nalgebra::Vector2::<f64>::zeros();
        for (xi, yi) in x.iter().zip(&y) {
            for i in 0..2 {
                b[i] += xi[i] * yi;
                for j in 0..2 {
                    a[(i, j)] += xi[i] * xi[j];
                }
            }
        }
        a[(1, 1)] += r[1];
        let exact = a.lu().solve(&b).unwrap();
        let lm = LmParams::default().tol(1e-15).check().unwrap();
        let s = lm
            .minimize(&mut Ridge { x, y, r }, &[0.0, 0.0], &crate::Silent)
            .unwrap();
        assert!((s.theta[0] - exact[0]).abs() < 1e-9, "{:?}", s.theta);
        assert!((s.theta[1] - exact[1]).abs() < 1e-9, "{:?}", s.theta);
        // the penalty shrinks the slope below the unpenalised 2
        assert!(s.theta[1] < 1.9);
    }

    /// Counts the damped solves and caps θ₀ by projection.
    struct Capped {
        inner: Rosenbrock,
        cap: f64,
        solves: usize,
    }
    impl LeastSquaresProblem for Capped {
        fn n_params(&self) -> usize {
            2
        }
        fn cost(&mut self, t: &[f64]) -> Option<f64> {
            self.inner.cost(t)
        }
        fn linearize(&mut self, t: &[f64], g: &mut [f64], grad: &mut [f64]) -> Option<f64> {
            self.inner.linearize(t, g, grad)
        }
        fn project(&mut self, t: &mut [f64]) {
            t[0] = t[0].min(self.cap);
        }
        fn solve_damped(&mut self, a: &mut [f64], g: &[f64], d: &mut [f64]) -> bool {
            self.solves += 1;
            cholesky_solve(a, g, d)
        }
    }

    #[test]
    fn projection_and_custom_solve_are_used() {
        let lm = LmParams {
            diag_floor_abs: 1e-12,
            jitter_abs: 1e-12,
            ..LmParams::default()
        }
        .check()
        .unwrap();
        let mut p = Capped {
            inner: Rosenbrock {
                admissible_calls: 0,
                bound: f64::INFINITY,
            },
            cap: 0.5,
            solves: 0,
        };
        let s = lm.minimize(&mut p, &[-1.2, 1.0], &crate::Silent).unwrap();
        // every accepted point is a projected one; the optimum lies on the cap
        assert!(s.theta[0] <= 0.5 && s.theta[0] > 0.3, "{:?}", s.theta);
        assert!(p.solves >= s.iterations);
    }

    #[test]
    fn a_reciprocal_integer_down_factor_divides() {
        for l in [1e-3, 7.1e-5, 0.37, 123.456] {
            assert_eq!(shrink(l, 1.0 / 3.0), l / 3.0);
            assert_eq!(shrink(l, 0.3), l * 0.3);
            assert_eq!(shrink(l, 0.5), l / 2.0);
        }
    }

    #[test]
    fn max_iterations_and_bad_params() {
        let lm = LmParams::default().max_iter(2).check().unwrap();
        let mut p = Rosenbrock {
            admissible_calls: 0,
            bound: f64::INFINITY,
        };
        let s = lm.minimize(&mut p, &[-1.2, 1.0], &crate::Silent).unwrap();
        assert_eq!(s.iterations, 2);
        assert_eq!(s.termination, Some(Termination::MaxIterations));
        assert!(LmParams {
            lambda_down: 2.0,
            ..LmParams::default()
        }
        .check()
        .is_err());
        assert!(lm.minimize(&mut p, &[1.0], &crate::Silent).is_err());
    }
}
