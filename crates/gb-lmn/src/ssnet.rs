//! Local-model **state-space** network with a square-root basis and state
//! saturation, trained on the simulation (output) error.
//!
//! With hidden states x(k) ∈ ℝⁿ, inputs u(k) ∈ ℝᵐ and L leaves:
//!
//! x(k+1) = min( Σᵢ Φᵢ(z(k)) · [Aᵢ x(k) + Gᵢ √x₊(k) + Bᵢ u(k) + cᵢ] , x̄ )
//!
//! ŷ(k) = min( Cᵀ x(k) + d , ȳ )
//!
//! where √x₊ = √max(x, 0) elementwise (the Torricelli outflow of a tank;
//! `sqrt_basis = false` drops it and gives a local-affine state-space network,
//! Verdult 2002), x̄ is a learned upper bound per state (overflow / hard
//! saturation; `state_saturation = false` drops it; `nonnegative_states`
//! adds a lower bound 0), ȳ an optional known
//! sensor range, and Φᵢ are decision-tree sigmoid weights of a chain of L−1
//! splits over the scheduling variable z (one state or one input):
//! Φ₁ = 1−σ₁, Φ₂ = σ₁(1−σ₂), …, Φ_L = σ₁⋯σ_{L−1}, σⱼ = 1/(1+e^{−sⱼ(z−tⱼ)}).
//!
//! Training: the initial state of the training record is a parameter too; all
//! parameters are fitted by Levenberg–Marquardt on the free-run simulation
//! error (finite-difference Jacobian — the models are small) from a few
//! physically motivated starts (a chain of leaky tanks: A = I,
//! G = r(−I + S) with S the sub-diagonal shift, B = b e₁, C = eₙ). The number
//! of leaves is chosen on a validation tail of the training record (initial
//! state estimated on the samples before it), then the chosen structure is
//! refitted on the whole record. At simulation time the initial state is
//! estimated from an init window of measured outputs (least squares over x(0),
//! LM from the model's equilibrium under u(0) and from a 7ⁿ grid over [0, x̄]).
//!
//! This is the model of the cascaded-tanks benchmark (Schoukens, Mattsson,
//! Wigren, Noël 2016): with one leaf it is a dense generalisation of the
//! two-tank Torricelli model.

use crate::LmnError;
use gb_core::solver::{LeastSquaresProblem, LmParams};
use gb_core::{Identify, Observer, Records, Silent, SubTask};
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

/// Which signal schedules the leaves of a [`SsLmnModel`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Scheduling {
    /// Hidden state xⱼ(k).
    State(usize),
    /// Input uⱼ(k).
    Input(usize),
}

/// Options of [`fit_ss_lmn`]. The defaults are generic: 1, 2 or 3 hidden
/// states and 1 or 2 leaves, chosen by the simulation error on the last
/// 20 % of the training record; the √ basis and the learned state bounds of
/// the class; no output limit. Benchmark set-ups (the cascaded tanks: two
/// states, a 10 V sensor limit) belong to the code that runs them.
///
/// | field | default |
/// |---|---|
/// | `n_states` | `[1, 2, 3]` (chosen on the validation tail) |
/// | `leaves` | `[1, 2]` (chosen on the validation tail) |
/// | `scheduling` | `State(0)` |
/// | `sqrt_basis`, `state_saturation` | true |
/// | `output_upper` | none |
/// | `nonnegative_states` | false |
/// | `init_rates` | `[0.1, 0.2, 0.4]` |
/// | `max_iter` | 200 |
/// | `validation_fraction` | 0.2 |
/// | `init_window` | 50 |
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SsLmnParams {
    /// Candidate numbers of hidden states n (each in 1..=8).
    pub n_states: Vec<usize>,
    /// Candidate numbers of leaves (each in 1..=8). With several
    /// (states, leaves) pairs, the one with the smallest validation
    /// simulation error is refitted on all data.
    pub leaves: Vec<usize>,
    /// Scheduling variable of the splits (ignored for one leaf).
    pub scheduling: Scheduling,
    /// Include the Gᵢ √x₊ basis.
    pub sqrt_basis: bool,
    /// Learn an upper bound x̄ per state (overflow).
    pub state_saturation: bool,
    /// Known upper limit ȳ of the output (sensor range), if any.
    pub output_upper: Option<f64>,
    /// Clamp the states at 0, x(k) ≥ 0 (off by default: the fitted states
    /// are not physical levels — A, G, C are dense and d shifts the output).
    pub nonnegative_states: bool,
    /// Leak rates r of the starting chains (one LM run per rate).
    pub init_rates: Vec<f64>,
    /// Levenberg–Marquardt iterations per run.
    pub max_iter: usize,
    /// Fraction of the training record kept for validation when several
    /// candidates are given (0 < f < 0.5).
    pub validation_fraction: f64,
    /// Measured outputs used to estimate the initial state (validation and
    /// [`SsLmnModel::simulate_with_init_window`]).
    pub init_window: usize,
}

impl Default for SsLmnParams {
    fn default() -> Self {
        Self {
            n_states: vec![1, 2, 3],
            leaves: vec![1, 2],
            scheduling: Scheduling::State(0),
            sqrt_basis: true,
            state_saturation: true,
            output_upper: None,
            nonnegative_states: false,
            init_rates: vec![0.1, 0.2, 0.4],
            max_iter: 200,
            validation_fraction: 0.2,
            init_window: 50,
        }
    }
}

impl SsLmnParams {
    /// The (states, leaves) candidates in the order they are tried.
    pub fn candidates(&self) -> Vec<(usize, usize)> {
        self.n_states
            .iter()
            .flat_map(|&n| self.leaves.iter().map(move |&l| (n, l)))
            .collect()
    }

    /// Validate the options against `n_inputs` inputs; the result fits.
    pub fn check(&self, n_inputs: usize) -> Result<ValidSsLmnParams, LmnError> {
        let bad = |m: &str| Err(LmnError::InvalidArgument(m.to_string()));
        if self.n_states.is_empty() || self.n_states.iter().any(|&n| n == 0 || n > 8) {
            return bad("n_states: candidates in 1..=8 are needed");
        }
        let (min_n, max_n) = (
            self.n_states.iter().copied().min().unwrap_or(1),
            self.n_states.iter().copied().max().unwrap_or(1),
        );
        if n_inputs == 0 {
            return bad("at least one input is needed");
        }
        if self.leaves.is_empty() || self.leaves.iter().any(|&l| l == 0 || l > 8) {
            return bad("leaves: candidates in 1..=8 are needed");
        }
        match self.scheduling {
            Scheduling::State(j) if j >= min_n => {
                return bad("scheduling state out of range (for the smallest n_states)")
            }
            Scheduling::Input(j) if j >= n_inputs => return bad("scheduling input out of range"),
            _ => {}
        }
        if self.init_rates.is_empty()
            || self.init_rates.iter().any(|r| !(r.is_finite() && *r > 0.0))
        {
            return bad("init_rates must be positive and finite");
        }
        if self.max_iter == 0 {
            return bad("max_iter must be ≥ 1");
        }
        if !(self.validation_fraction > 0.0 && self.validation_fraction < 0.5) {
            return bad("validation_fraction must be in (0, 0.5)");
        }
        if self.init_window < max_n {
            return bad("init_window must be ≥ n_states");
        }
        if let Some(v) = self.output_upper {
            if !v.is_finite() {
                return bad("output_upper must be finite");
            }
        }
        Ok(ValidSsLmnParams {
            p: self.clone(),
            n_inputs,
        })
    }
}

/// [`SsLmnParams`] validated for a number of inputs; fits with
/// [`fit`](Self::fit) or [`Identify`].
#[derive(Clone, Debug, PartialEq)]
pub struct ValidSsLmnParams {
    p: SsLmnParams,
    n_inputs: usize,
}

impl ValidSsLmnParams {
    /// The options.
    pub fn params(&self) -> &SsLmnParams {
        &self.p
    }

    /// Fit to one experiment (inputs `u[j]`, output `y`), reporting progress
    /// (one unit per structure fitted) and every Levenberg–Marquardt
    /// iteration to `observer`.
    pub fn fit(
        &self,
        u: &[Vec<f64>],
        y: &[f64],
        observer: &dyn Observer,
    ) -> Result<SsLmnFit, LmnError> {
        if u.len() != self.n_inputs {
            return Err(LmnError::Dimension(format!(
                "the parameters were checked for {} inputs, the data has {}",
                self.n_inputs,
                u.len()
            )));
        }
        fit_checked(&self.p, u, y, observer)
    }
}

impl Identify for ValidSsLmnParams {
    type Model = SsLmnModel;
    type Error = LmnError;
    /// One record (the training state x(0) is a parameter of one record).
    fn identify(&self, data: &Records, observer: &dyn Observer) -> Result<SsLmnModel, LmnError> {
        if data.len() != 1 {
            return Err(LmnError::InvalidArgument(format!(
                "a state-space network is fitted on one record, got {}",
                data.len()
            )));
        }
        let r = data.first();
        self.fit(&r.inputs, &r.output, observer).map(|f| f.model)
    }
}

/// A fitted local-model state-space network (see the module docs for the
/// equations). Parameters are stored flat; see [`SsLmnModel::parameters`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SsLmnModel {
    n_states: usize,
    n_inputs: usize,
    n_leaves: usize,
    scheduling: Scheduling,
    sqrt_basis: bool,
    state_saturation: bool,
    output_upper: Option<f64>,
    nonnegative_states: bool,
    theta: Vec<f64>,
}

/// A [`SsLmnModel`] running one sample at a time.
pub(crate) struct SsStepper<'a> {
    m: &'a SsLmnModel,
    x: [f64; 8],
    failed: bool,
}

impl SsStepper<'_> {
    /// Advance one sample with the inputs `u`; the output.
    pub fn step(&mut self, u: &[f64]) -> Result<f64, LmnError> {
        if u.len() != self.m.n_inputs {
            return Err(LmnError::Dimension(format!(
                "{} inputs expected, got {}",
                self.m.n_inputs,
                u.len()
            )));
        }
        if self.failed || u.iter().any(|v| !v.is_finite()) {
            return Err(LmnError::InvalidArgument(
                "non-finite input or a diverged state".into(),
            ));
        }
        match self.m.step_state(&self.m.theta, &mut self.x, |j| u[j]) {
            Some(y) => Ok(y),
            None => {
                self.failed = true;
                Err(LmnError::Unstable("simulation diverged".into()))
            }
        }
    }
}

/// Result of [`fit_ss_lmn`].
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SsLmnFit {
    /// The model refitted on the whole training record.
    pub model: SsLmnModel,
    /// Validation simulation RMSE per candidate (states, leaves, RMSE);
    /// empty when only one candidate was given.
    pub validation: Vec<(usize, usize, f64)>,
    /// Training simulation RMSE of the final model.
    pub train_rmse: f64,
}

impl SsLmnModel {
    fn leaf_len(&self) -> usize {
        let n = self.n_states;
        n * n + if self.sqrt_basis { n * n } else { 0 } + n * self.n_inputs + n
    }

    fn n_model_params(&self) -> usize {
        let n = self.n_states;
        self.n_leaves * self.leaf_len()
            + n
            + 1
            + if self.state_saturation { n } else { 0 }
            + 2 * (self.n_leaves - 1)
    }

    /// Checks a loaded model: sizes, scheduling index and finite parameters.
    pub fn check_consistency(&self) -> Result<(), LmnError> {
        let bad = |m: &str| Err(LmnError::InvalidArgument(m.to_string()));
        if !(1..=8).contains(&self.n_states)
            || !(1..=8).contains(&self.n_leaves)
            || self.n_inputs == 0
        {
            return bad("state-space network: states and leaves must be in 1..=8, inputs >= 1");
        }
        match self.scheduling {
            Scheduling::State(j) if j >= self.n_states => {
                return bad("scheduling state out of range")
            }
            Scheduling::Input(j) if j >= self.n_inputs => {
                return bad("scheduling input out of range")
            }
            _ => {}
        }
        if self.theta.len() != self.n_model_params() || !self.theta.iter().all(|v| v.is_finite()) {
            return bad("state-space network: wrong number of parameters or non-finite values");
        }
        Ok(())
    }

    /// Number of inputs.
    pub fn n_inputs(&self) -> usize {
        self.n_inputs
    }

    /// Number of leaves L.
    pub fn n_leaves(&self) -> usize {
        self.n_leaves
    }

    /// Number of hidden states n.
    pub fn n_states(&self) -> usize {
        self.n_states
    }

    /// Flat parameters: per leaf [A (row-major), G, B, c], then C, d, x̄ (if
    /// saturated), split positions tⱼ, log steepnesses ln sⱼ.
    pub fn parameters(&self) -> &[f64] {
        &self.theta
    }

    /// Learned state upper bounds x̄ (None without saturation).
    pub fn state_upper(&self) -> Option<&[f64]> {
        if !self.state_saturation {
            return None;
        }
        let o = self.n_leaves * self.leaf_len() + self.n_states + 1;
        Some(&self.theta[o..o + self.n_states])
    }

    /// One-line description.
    pub fn describe(&self) -> String {
        format!(
            "state-space LMN: {} states, {} leaves, {}{}{} ({} parameters)",
            self.n_states,
            self.n_leaves,
            if self.sqrt_basis {
                "sqrt basis"
            } else {
                "affine"
            },
            if self.state_saturation {
                ", state saturation"
            } else {
                ""
            },
            match self.output_upper {
                Some(v) => format!(", output ≤ {v}"),
                None => String::new(),
            },
            self.theta.len()
        )
    }

    /// Simulate from the initial state `x0`; `u[j][k]` is input j at sample k.
    /// Returns None when the simulation leaves the finite range.
    fn sim_into(&self, theta: &[f64], u: &[Vec<f64>], x0: &[f64], out: &mut [f64]) -> bool {
        self.sim_state(theta, u, x0, out).is_some()
    }

    /// State after simulating `out.len()` samples from `x0`.
    fn final_state(&self, u: &[Vec<f64>], x0: &[f64], out: &mut [f64]) -> Option<Vec<f64>> {
        self.sim_state(&self.theta, u, x0, out)
    }

    fn sim_state(
        &self,
        theta: &[f64],
        u: &[Vec<f64>],
        x0: &[f64],
        out: &mut [f64],
    ) -> Option<Vec<f64>> {
        let n = self.n_states;
        let mut x = [0.0f64; 8];
        x[..n].copy_from_slice(x0);
        for (k, o) in out.iter_mut().enumerate() {
            *o = self.step_state(theta, &mut x, |j| u[j][k])?;
        }
        Some(x[..n].to_vec())
    }

    /// One sample: the output ŷ(k) from the state x(k), then x(k+1) in
    /// place; `uk(j)` is input j at sample k. `None` when the output or the
    /// state leaves the finite range.
    #[inline(always)]
    fn step_state(
        &self,
        theta: &[f64],
        x: &mut [f64; 8],
        uk: impl Fn(usize) -> f64,
    ) -> Option<f64> {
        let n = self.n_states;
        let m = self.n_inputs;
        let ll = self.leaf_len();
        let l = self.n_leaves;
        let o_c = l * ll;
        let cvec = &theta[o_c..o_c + n];
        let d = theta[o_c + n];
        let o_up = o_c + n + 1;
        let o_split = o_up + if self.state_saturation { n } else { 0 };
        let mut s = [0.0f64; 8];
        let mut xn = [0.0f64; 8];
        let mut w = [0.0f64; 8];
        let mut yk = d;
        for i in 0..n {
            yk += cvec[i] * x[i];
        }
        if let Some(v) = self.output_upper {
            yk = yk.min(v);
        }
        if !yk.is_finite() {
            return None;
        }
        // weights
        if l == 1 {
            w[0] = 1.0;
        } else {
            let z = match self.scheduling {
                Scheduling::State(j) => x[j],
                Scheduling::Input(j) => uk(j),
            };
            let mut rem = 1.0;
            for j in 0..l - 1 {
                let t = theta[o_split + j];
                let st = theta[o_split + l - 1 + j].clamp(-30.0, 30.0).exp();
                let a = (st * (z - t)).clamp(-50.0, 50.0);
                let sig = 1.0 / (1.0 + (-a).exp());
                w[j] = rem * (1.0 - sig);
                rem *= sig;
            }
            w[l - 1] = rem;
        }
        for i in 0..n {
            s[i] = x[i].max(0.0).sqrt();
            xn[i] = 0.0;
        }
        for leaf in 0..l {
            let p = &theta[leaf * ll..(leaf + 1) * ll];
            let (a, rest) = p.split_at(n * n);
            let (g, rest) = if self.sqrt_basis {
                rest.split_at(n * n)
            } else {
                rest.split_at(0)
            };
            let (b, c) = rest.split_at(n * m);
            for i in 0..n {
                let mut v = c[i];
                for j in 0..n {
                    v += a[i * n + j] * x[j];
                }
                if self.sqrt_basis {
                    for j in 0..n {
                        v += g[i * n + j] * s[j];
                    }
                }
                for j in 0..m {
                    v += b[i * m + j] * uk(j);
                }
                xn[i] += w[leaf] * v;
            }
        }
        for i in 0..n {
            let mut v = xn[i];
            if self.state_saturation {
                v = v.min(theta[o_up + i]);
            }
            if self.nonnegative_states {
                v = v.max(0.0);
            }
            if !v.is_finite() || v.abs() > 1e6 {
                return None;
            }
            x[i] = v;
        }
        Some(yk)
    }

    /// One sample at a time from the state `x0` (see
    /// [`gb_core::DynamicModel::stepper`]): the same arithmetic as
    /// [`simulate_from`](Self::simulate_from).
    pub(crate) fn step_from(&self, x0: &[f64]) -> Result<SsStepper<'_>, LmnError> {
        if x0.len() != self.n_states {
            return Err(LmnError::Dimension(format!(
                "x0 needs {} states",
                self.n_states
            )));
        }
        let mut x = [0.0; 8];
        x[..self.n_states].copy_from_slice(x0);
        Ok(SsStepper {
            m: self,
            x,
            failed: false,
        })
    }

    fn check_inputs(&self, u: &[Vec<f64>], len: usize) -> Result<(), LmnError> {
        if u.len() != self.n_inputs {
            return Err(LmnError::Dimension(format!(
                "{} inputs expected, got {}",
                self.n_inputs,
                u.len()
            )));
        }
        if u.iter().any(|c| c.len() != len) {
            return Err(LmnError::Dimension("inputs of different lengths".into()));
        }
        if u.iter().flatten().any(|v| !v.is_finite()) {
            return Err(LmnError::InvalidArgument("non-finite input".into()));
        }
        Ok(())
    }

    /// Free-run simulation from the initial state `x0` (length n).
    pub fn simulate_from(&self, u: &[Vec<f64>], x0: &[f64]) -> Result<Vec<f64>, LmnError> {
        let len = u.first().map_or(0, Vec::len);
        self.check_inputs(u, len)?;
        if x0.len() != self.n_states {
            return Err(LmnError::Dimension(format!(
                "x0 needs {} states",
                self.n_states
            )));
        }
        let mut out = vec![0.0; len];
        if self.sim_into(&self.theta, u, x0, &mut out) {
            Ok(out)
        } else {
            Err(LmnError::Unstable("simulation diverged".into()))
        }
    }

    /// Least-squares estimate of x(0) from the first `window` measured outputs
    /// y(0…window−1): min over x(0) of Σ (ŷ(k) − y(k))², several starts.
    pub fn estimate_initial_state(
        &self,
        u: &[Vec<f64>],
        y: &[f64],
        window: usize,
    ) -> Result<Vec<f64>, LmnError> {
        if window < 1 || window > y.len() {
            return Err(LmnError::TooShort {
                needed: window.max(1),
                got: y.len(),
            });
        }
        self.check_inputs(u, y.len())?;
        let uw: Vec<Vec<f64>> = u.iter().map(|c| c[..window].to_vec()).collect();
        let yw = &y[..window];
        let theta = self.theta.clone();
        let n = self.n_states;
        let mut best: Option<(f64, Vec<f64>)> = None;
        for start in self.state_starts(&uw, yw) {
            let f = |x0: &[f64], r: &mut [f64]| -> bool {
                if !self.sim_into(&theta, &uw, x0, r) {
                    return false;
                }
                for (ri, yi) in r.iter_mut().zip(yw) {
                    *ri -= yi;
                }
                true
            };
            if let Some((x0, c)) = lm_fd(&f, &start, window, 60, &Silent) {
                if best.as_ref().is_none_or(|b| c < b.0) {
                    best = Some((c, x0));
                }
            }
        }
        best.map(|b| b.1)
            .filter(|x| x.len() == n)
            .ok_or_else(|| LmnError::Unstable("no initial state found".into()))
    }

    /// Starting guesses for x(0): the model's equilibrium under the first
    /// input sample u(0) held constant (400 steps from the output level
    /// mapped onto every state), and that equilibrium with the non-output
    /// states scaled by 0.5, 1.5 and 2.
    fn state_starts(&self, u: &[Vec<f64>], y: &[f64]) -> Vec<Vec<f64>> {
        let n = self.n_states;
        let o_c = self.n_leaves * self.leaf_len();
        let c = &self.theta[o_c..o_c + n];
        let d = self.theta[o_c + n];
        let y0 = y.first().copied().unwrap_or(0.0);
        let csum: f64 = c.iter().sum();
        let lvl = if csum.abs() > 1e-9 {
            (y0 - d) / csum
        } else {
            y0
        };
        let mut starts = vec![vec![lvl; n]];
        let hold: Vec<Vec<f64>> = u
            .iter()
            .map(|c| vec![c.first().copied().unwrap_or(0.0); 401])
            .collect();
        let mut out = vec![0.0; 401];
        if let Some(xe) = self.final_state(&hold, &vec![lvl; n], &mut out) {
            for f in [1.0, 0.5, 1.5, 2.0] {
                let mut x = xe.clone();
                for v in x.iter_mut().take(n.saturating_sub(1)) {
                    *v *= f;
                }
                starts.push(x);
            }
        }
        // coarse grid over the box [0, x̄] (or [0, 2·level]) for n ≤ 3
        if n <= 3 {
            let g = 7usize;
            let hi: Vec<f64> = match self.state_upper() {
                Some(up) => up.iter().map(|v| v.abs().max(1e-3)).collect(),
                None => vec![2.0 * lvl.abs().max(1e-3); n],
            };
            let total = g.pow(n as u32);
            for idx in 0..total {
                let mut r = idx;
                let mut x = vec![0.0; n];
                for i in 0..n {
                    x[i] = hi[i] * (r % g) as f64 / (g - 1) as f64;
                    r /= g;
                }
                starts.push(x);
            }
        }
        starts
    }

    /// Estimate x(0) on the first `window` measured outputs, then simulate
    /// the whole record in free run (the score is over samples ≥ window).
    pub fn simulate_with_init_window(
        &self,
        u: &[Vec<f64>],
        y: &[f64],
        window: usize,
    ) -> Result<Vec<f64>, LmnError> {
        let x0 = self.estimate_initial_state(u, y, window)?;
        self.simulate_from(u, &x0)
    }
}

/// A residual function `f(p, r)` (false where the model is not simulable)
/// as a least-squares problem with a forward-difference Jacobian (step
/// 1e-6·max(|pⱼ|, 1), backward where the forward point is not simulable).
struct FdProblem<'a> {
    f: &'a dyn Fn(&[f64], &mut [f64]) -> bool,
    np: usize,
    /// The last point evaluated and its residuals (the accepted point is
    /// linearised next).
    p: Vec<f64>,
    r: Vec<f64>,
    valid: bool,
    rq: Vec<f64>,
    q: Vec<f64>,
    jac: DMatrix<f64>,
}

impl FdProblem<'_> {
    fn eval(&mut self, p: &[f64]) -> Option<f64> {
        self.valid = (self.f)(p, &mut self.r);
        self.p.copy_from_slice(p);
        self.valid.then(|| self.r.iter().map(|v| v * v).sum())
    }
}

impl LeastSquaresProblem for FdProblem<'_> {
    fn n_params(&self) -> usize {
        self.np
    }
    fn cost(&mut self, p: &[f64]) -> Option<f64> {
        self.eval(p)
    }
    fn linearize(&mut self, p: &[f64], gram: &mut [f64], grad: &mut [f64]) -> Option<f64> {
        if !(self.valid && self.p.as_slice() == p) {
            self.eval(p)?;
        }
        let (np, n_res) = (self.np, self.r.len());
        for j in 0..np {
            let h = 1e-6 * p[j].abs().max(1.0);
            self.q.copy_from_slice(p);
            self.q[j] += h;
            if !(self.f)(&self.q, &mut self.rq) {
                self.q[j] = p[j] - h;
                if !(self.f)(&self.q, &mut self.rq) {
                    self.rq.copy_from_slice(&self.r);
                }
                for i in 0..n_res {
                    self.jac[(i, j)] = (self.r[i] - self.rq[i]) / h;
                }
                continue;
            }
            for i in 0..n_res {
                self.jac[(i, j)] = (self.rq[i] - self.r[i]) / h;
            }
        }
        let jt = self.jac.transpose();
        let a = &jt * &self.jac;
        let g = &jt * DVector::from_column_slice(&self.r);
        for i in 0..np {
            for j in 0..np {
                gram[i * np + j] = a[(i, j)];
            }
            // r = ŷ − y: the gradient Jᵀ(y − ŷ) is −Jᵀr
            grad[i] = -g[i];
        }
        Some(self.r.iter().map(|v| v * v).sum())
    }
}

/// Levenberg–Marquardt with a forward-difference Jacobian on the residual
/// function `f(p, r)` (returns false where the model is not simulable):
/// λ from 1e-2, ×10 after a rejected step, ÷3 after an accepted one (floor
/// 1e-9), damping λ·(Gᵢᵢ + 1e-9), 12 trials, relative tolerance 1e-8.
/// Returns the parameters and the final cost Σ r².
fn lm_fd(
    f: &dyn Fn(&[f64], &mut [f64]) -> bool,
    p0: &[f64],
    n_res: usize,
    iters: usize,
    observer: &dyn Observer,
) -> Option<(Vec<f64>, f64)> {
    let np = p0.len();
    let lm = LmParams {
        max_iter: iters,
        tol: 1e-8,
        lambda_init: 1e-2,
        lambda_up: 10.0,
        lambda_up_singular: 10.0,
        lambda_down: 1.0 / 3.0,
        lambda_min: 1e-9,
        lambda_max: 1e300,
        max_trials: 12,
        diag_floor: 0.0,
        diag_floor_abs: 0.0,
        diag_add: 1e-9,
        jitter: 0.0,
        jitter_abs: 0.0,
        stall_window: 0,
        stall_tol: 0.0,
        ..LmParams::default()
    }
    .check()
    .ok()?;
    let mut problem = FdProblem {
        f,
        np,
        p: vec![0.0; np],
        r: vec![0.0; n_res],
        valid: false,
        rq: vec![0.0; n_res],
        q: vec![0.0; np],
        jac: DMatrix::zeros(n_res, np),
    };
    let state = lm.minimize(&mut problem, p0, observer).ok()?;
    Some((state.theta, state.cost))
}

fn rmse(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().max(1) as f64;
    (a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>() / n).sqrt()
}

/// Fit one structure with `n_leaves` leaves on (u, y): LM from one start per
/// init rate; returns the best model and its training RMSE.
fn fit_structure(
    p: &SsLmnParams,
    (n, n_leaves): (usize, usize),
    u: &[Vec<f64>],
    y: &[f64],
    observer: &dyn Observer,
) -> Result<(SsLmnModel, f64), LmnError> {
    let m = u.len();
    let len = y.len();
    let proto = SsLmnModel {
        n_states: n,
        n_inputs: m,
        n_leaves,
        scheduling: p.scheduling,
        sqrt_basis: p.sqrt_basis,
        state_saturation: p.state_saturation,
        output_upper: p.output_upper,
        nonnegative_states: p.nonnegative_states,
        theta: Vec::new(),
    };
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let ybar = mean(y);
    let ymax = y.iter().copied().fold(f64::MIN, f64::max);
    let ymin = y.iter().copied().fold(f64::MAX, f64::min);
    let ubar = mean(&u[0]);
    // split positions: quantile-like spread over the range of the
    // scheduling variable (states live on the output scale)
    let (zlo, zhi) = match p.scheduling {
        Scheduling::State(_) => (ymin, ymax),
        Scheduling::Input(j) => (
            u[j].iter().copied().fold(f64::MAX, f64::min),
            u[j].iter().copied().fold(f64::MIN, f64::max),
        ),
    };
    let zr = (zhi - zlo).max(1e-9);
    let mut best: Option<(SsLmnModel, f64)> = None;
    for (i, &rate) in p.init_rates.iter().enumerate() {
        observer.progress(
            i,
            p.init_rates.len(),
            &format!("state-space network, {n} states, {n_leaves} leaves"),
        );
        let mut th = Vec::with_capacity(proto.n_model_params() + n);
        // chain of leaky tanks at steady state x ≈ ȳ: b ū = r √ȳ
        let lvl = ybar.abs().max(1e-3);
        let b0 = if ubar.abs() > 1e-9 {
            rate * lvl.sqrt() / ubar
        } else {
            rate
        };
        for _ in 0..n_leaves {
            for i in 0..n {
                for j in 0..n {
                    th.push(if i == j { 1.0 } else { 0.0 });
                }
            }
            if p.sqrt_basis {
                for i in 0..n {
                    for j in 0..n {
                        th.push(if i == j {
                            -rate
                        } else if i == j + 1 {
                            rate
                        } else {
                            0.0
                        });
                    }
                }
            }
            for i in 0..n {
                for j in 0..m {
                    th.push(if i == 0 && j == 0 { b0 } else { 0.0 });
                }
            }
            th.extend(std::iter::repeat_n(0.0, n));
        }
        if !p.sqrt_basis {
            // turn A = I into A = (1 − r')I + r' S with r' = r/(2√ȳ)
            let rr = rate / (2.0 * lvl.sqrt());
            let ll = proto.leaf_len();
            for leaf in 0..n_leaves {
                for i in 0..n {
                    th[leaf * ll + i * n + i] = 1.0 - rr;
                    if i > 0 {
                        th[leaf * ll + i * n + i - 1] = rr;
                    }
                }
            }
        }
        for i in 0..n {
            th.push(if i + 1 == n { 1.0 } else { 0.0 });
        }
        th.push(0.0);
        if p.state_saturation {
            for _ in 0..n {
                th.push(ymax + 0.5 * (ymax - ymin).abs().max(1e-3));
            }
        }
        for j in 0..n_leaves - 1 {
            th.push(zlo + zr * (j + 1) as f64 / n_leaves as f64);
        }
        for _ in 0..n_leaves - 1 {
            th.push((4.0 / zr).ln());
        }
        // initial training state
        let y0 = y[0];
        for _ in 0..n {
            th.push(y0);
        }
        let npm = proto.n_model_params();
        let f = |q: &[f64], r: &mut [f64]| -> bool {
            if !proto.sim_into(&q[..npm], u, &q[npm..], r) {
                return false;
            }
            for (ri, yi) in r.iter_mut().zip(y) {
                *ri -= yi;
            }
            true
        };
        if let Some((q, c)) = lm_fd(&f, &th, len, p.max_iter, observer) {
            let rm = (c / len as f64).sqrt();
            if best.as_ref().is_none_or(|b| rm < b.1) {
                let mut model = proto.clone();
                model.theta = q[..npm].to_vec();
                best = Some((model, rm));
            }
        }
    }
    best.ok_or_else(|| LmnError::Unstable("every start diverged".into()))
}

/// Fit a local-model state-space network to one experiment (inputs `u[j]`,
/// output `y`), choosing the number of states and leaves among
/// [`SsLmnParams::candidates`] by the free-run simulation RMSE on the last
/// `validation_fraction` of the record.
pub fn fit_ss_lmn(params: &SsLmnParams, u: &[Vec<f64>], y: &[f64]) -> Result<SsLmnFit, LmnError> {
    fit_ss_lmn_with_observer(params, u, y, &Silent)
}

/// [`fit_ss_lmn`], reporting progress (one unit per structure fitted) and
/// every Levenberg–Marquardt iteration to `observer`.
pub fn fit_ss_lmn_with_observer(
    params: &SsLmnParams,
    u: &[Vec<f64>],
    y: &[f64],
    observer: &dyn Observer,
) -> Result<SsLmnFit, LmnError> {
    params.check(u.len())?.fit(u, y, observer)
}

fn fit_checked(
    params: &SsLmnParams,
    u: &[Vec<f64>],
    y: &[f64],
    observer: &dyn Observer,
) -> Result<SsLmnFit, LmnError> {
    let len = y.len();
    let needed = 4 * params.init_window.max(10);
    if len < needed {
        return Err(LmnError::TooShort { needed, got: len });
    }
    if u.iter().any(|c| c.len() != len) {
        return Err(LmnError::Dimension(
            "inputs and output differ in length".into(),
        ));
    }
    if y.iter().chain(u.iter().flatten()).any(|v| !v.is_finite()) {
        return Err(LmnError::InvalidArgument("non-finite sample".into()));
    }
    let cands = params.candidates();
    let total = if cands.len() == 1 { 1 } else { cands.len() + 1 };
    let sub = |i: usize| SubTask {
        outer: observer,
        offset: i,
        span: 1,
        total,
    };
    let mut validation = Vec::new();
    let chosen = if cands.len() == 1 {
        cands[0]
    } else {
        let n_val = ((len as f64) * params.validation_fraction) as usize;
        let n_tr = len - n_val;
        if n_tr < 2 * params.init_window || n_val < 10 {
            return Err(LmnError::TooShort { needed, got: len });
        }
        let ut: Vec<Vec<f64>> = u.iter().map(|c| c[..n_tr].to_vec()).collect();
        // validation record starts init_window samples early to estimate x(0)
        let v0 = n_tr - params.init_window;
        let uv: Vec<Vec<f64>> = u.iter().map(|c| c[v0..].to_vec()).collect();
        let yv = &y[v0..];
        let mut best = (cands[0], f64::INFINITY);
        for (i, &c) in cands.iter().enumerate() {
            let score = fit_structure(params, c, &ut, &y[..n_tr], &sub(i))
                .and_then(|(m, _)| m.simulate_with_init_window(&uv, yv, params.init_window))
                .map(|s| rmse(&s[params.init_window..], &yv[params.init_window..]))
                .unwrap_or(f64::INFINITY);
            validation.push((c.0, c.1, score));
            if score < best.1 {
                best = (c, score);
            }
        }
        best.0
    };
    let (model, train_rmse) = fit_structure(params, chosen, u, y, &sub(total - 1))?;
    observer.progress(total, total, "state-space network fitted");
    Ok(SsLmnFit {
        model,
        validation,
        train_rmse,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// Two Torricelli tanks with overflow of the upper one, piecewise-constant
    /// random input, measurement noise (fixed seed).
    fn tanks(n: usize, seed: u64) -> (Vec<f64>, Vec<f64>) {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut u = vec![0.0; n];
        let mut level = 3.0;
        for k in 0..n {
            if k % 40 == 0 {
                level = rng.random_range(1.0..7.0);
            }
            u[k] = level;
        }
        let (mut x1, mut x2) = (4.0f64, 4.0f64);
        let mut y = vec![0.0; n];
        for k in 0..n {
            y[k] = x2 + 0.02 * rng.random_range(-1.0..1.0);
            let x1n = (x1 + 0.2 * u[k] - 0.25 * x1.max(0.0).sqrt()).min(9.0);
            x2 += 0.25 * x1.max(0.0).sqrt() - 0.22 * x2.max(0.0).sqrt();
            x1 = x1n;
        }
        (u, y)
    }

    #[test]
    fn recovers_two_tanks_in_free_run() {
        let (u, y) = tanks(800, 7);
        // the two tanks' order, given
        let p = SsLmnParams {
            n_states: vec![2],
            leaves: vec![1],
            init_window: 30,
            ..Default::default()
        };
        let fit = fit_ss_lmn(&p, std::slice::from_ref(&u), &y).unwrap();
        let (ut, yt) = tanks(600, 8);
        let sim = fit.model.simulate_with_init_window(&[ut], &yt, 30).unwrap();
        let e = rmse(&sim[30..], &yt[30..]);
        let sd = {
            let m = yt.iter().sum::<f64>() / yt.len() as f64;
            (yt.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / yt.len() as f64).sqrt()
        };
        // the noise is 0.012 rms; a linear model is far worse than 5 % of sd
        assert!(e < 0.05 * sd, "test rmse {e} vs output sd {sd}");
    }

    #[test]
    fn params_check_rejects_bad_options() {
        let ok = SsLmnParams::default();
        assert!(ok.check(1).is_ok());
        assert!(ok.check(0).is_err());
        let p = SsLmnParams {
            leaves: vec![0],
            ..Default::default()
        };
        assert!(p.check(1).is_err());
        let p = SsLmnParams {
            scheduling: Scheduling::State(2),
            ..Default::default()
        };
        assert!(p.check(1).is_err());
        let p = SsLmnParams {
            n_states: vec![],
            ..Default::default()
        };
        assert!(p.check(1).is_err());
        let p = SsLmnParams {
            validation_fraction: 0.7,
            ..Default::default()
        };
        assert!(p.check(1).is_err());
        let p = SsLmnParams {
            init_rates: vec![-1.0],
            ..Default::default()
        };
        assert!(p.check(1).is_err());
    }

    #[test]
    fn rejects_short_and_mismatched_data() {
        let p = SsLmnParams::default();
        assert!(matches!(
            fit_ss_lmn(&p, &[vec![1.0; 20]], &[0.0; 20]),
            Err(LmnError::TooShort { .. })
        ));
        assert!(fit_ss_lmn(&p, &[vec![1.0; 300]], &[0.0; 400]).is_err());
    }

    #[test]
    fn model_round_trips_through_postcard() {
        let (u, y) = tanks(300, 3);
        let p = SsLmnParams {
            n_states: vec![2],
            leaves: vec![2],
            max_iter: 5,
            init_window: 20,
            ..Default::default()
        };
        let fit = fit_ss_lmn(&p, std::slice::from_ref(&u), &y).unwrap();
        let bytes = postcard::to_allocvec(&fit.model).unwrap();
        let back: SsLmnModel = postcard::from_bytes(&bytes).unwrap();
        assert_eq!(back, fit.model);
        let a = fit
            .model
            .simulate_from(std::slice::from_ref(&u), &[4.0, 4.0])
            .unwrap();
        let b = back.simulate_from(&[u], &[4.0, 4.0]).unwrap();
        assert_eq!(a, b);
    }

    #[test]
    fn generic_defaults_choose_the_structure_on_the_hold_out() {
        let (u, y) = tanks(800, 7);
        let p = SsLmnParams {
            max_iter: 40,
            init_window: 30,
            ..Default::default()
        };
        let rec =
            gb_core::Record::new(vec!["u".into()], "y".into(), vec![u.clone()], y.clone()).unwrap();
        let v = p.check(1).unwrap();
        let m = v
            .identify(&Records::single(rec.clone()), &gb_core::Silent)
            .unwrap();
        let fit = v
            .fit(std::slice::from_ref(&u), &y, &gb_core::Silent)
            .unwrap();
        assert_eq!(m, fit.model);
        // every (states, leaves) pair was scored; the best one was refitted
        assert_eq!(fit.validation.len(), 6);
        let best = fit
            .validation
            .iter()
            .min_by(|a, b| a.2.total_cmp(&b.2))
            .unwrap();
        assert_eq!((m.n_states(), m.n_leaves()), (best.0, best.1));
        eprintln!(
            "ss-LMN generic defaults: {:?} -> {}",
            fit.validation,
            m.describe()
        );
        // one record only
        let two = Records::new(vec![rec.clone(), rec]).unwrap();
        assert!(v.identify(&two, &gb_core::Silent).is_err());
    }
}
