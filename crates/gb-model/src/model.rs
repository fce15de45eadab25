//! The model class: wavelet-sparse grey-box state space with hidden states.
use crate::basis::{EvalScratch, FastEval, SparseExpansion, MAX_DIMS};
use crate::error::{ModelError, Result};
use crate::everett::WaveletEverett;
use gb_preisach::{InitialState, Preisach, PreisachState};
use serde::{Deserialize, Serialize};

/// Magic bytes of a model file (`GBS\x01`), followed by a little-endian `u32`
/// format version and the postcard body.
pub const MAGIC: &[u8; 4] = b"GBS\x01";
/// Current model file format version.
pub const FORMAT_VERSION: u32 = 1;

/// An argument of a nonlinear term.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Signal {
    /// Hidden state `x_i`.
    State(usize),
    /// Input `u_j`.
    Input(usize),
}

/// Where a nonlinear or hysteresis term is added.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Target {
    /// Row `i` of the state update (a component of `f`).
    State(usize),
    /// The output (`g`).
    Output,
}

/// One component of `f` or `g`: `target += E(args)` with a sparse wavelet
/// expansion `E`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NonlinearTerm {
    /// Where the term is added.
    pub target: Target,
    /// The arguments, one per dimension of the expansion.
    pub args: Vec<Signal>,
    /// The function.
    pub expansion: SparseExpansion,
}

/// A Preisach component `target += P[u_input](t)` with a wavelet Everett
/// function, starting from negative saturation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HysteresisTerm {
    /// Where the operator's output is added.
    pub target: Target,
    /// The input that drives the operator.
    pub input: usize,
    /// The Everett function.
    pub everett: WaveletEverett,
}

pub use gb_core::NoiseModel;

/// Which entries of `A, B, C, D, x₀` identification may change (the rest is
/// known physics). Row-major masks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Structure {
    /// Free entries of `A` (n×n).
    pub a: Vec<bool>,
    /// Free entries of `B` (n×m).
    pub b: Vec<bool>,
    /// Free entries of `C` (n).
    pub c: Vec<bool>,
    /// Free entries of `D` (m).
    pub d: Vec<bool>,
    /// Free entries of the initial state.
    pub x0: Vec<bool>,
    /// Whether the output offset is free.
    pub y_offset: bool,
}

/// The thesis' model class (Hauth 2008, ch. 5), for one output:
///
/// ```text
/// x_{t+1} = A x_t + B u_t + f(x_t, u_t) + h_x(t) + v_t,
/// y_t     = C x_t + D u_t + g(x_t, u_t) + h_y(t) + w_t,
/// ```
///
/// with hidden states `x`, sparse wavelet expansions `f` (per state row) and
/// `g` ([`NonlinearTerm`]), Preisach components `h` with wavelet Everett
/// functions ([`HysteresisTerm`]) and noise `v, w` ([`NoiseModel`]). With
/// `substeps = M > 1` the state map is applied `M` times per sample with the
/// input held (a continuous-time structure discretised on a finer grid; the
/// hysteresis terms enter every sub-step). Known physics is stated through
/// fixed entries ([`Structure`]).
///
/// ```
/// use gb_model::SparseStateSpace;
/// // x_{t+1} = 0.5 x_t + u_t, y = x
/// let m = SparseStateSpace::linear(vec![0.5], vec![1.0], vec![1.0], vec![0.0])?;
/// let y = m.simulate(&[vec![1.0, 1.0, 1.0]])?;
/// assert_eq!(y, vec![0.0, 1.0, 1.5]);
/// let back = SparseStateSpace::from_bytes(&m.to_bytes()?)?;
/// assert_eq!(back, m);
/// # Ok::<(), gb_model::ModelError>(())
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SparseStateSpace {
    /// Number of states n.
    pub n_states: usize,
    /// Number of inputs m.
    pub n_inputs: usize,
    /// `A`, row-major n×n.
    pub a: Vec<f64>,
    /// `B`, row-major n×m.
    pub b: Vec<f64>,
    /// `C` (n).
    pub c: Vec<f64>,
    /// `D` (m).
    pub d: Vec<f64>,
    /// Initial state.
    pub x0: Vec<f64>,
    /// Output offset `y₀` (`ŷ += y₀`).
    pub y_offset: f64,
    /// Sub-steps per sample (≥ 1).
    pub substeps: usize,
    /// Components of `f` and `g`.
    pub terms: Vec<NonlinearTerm>,
    /// Preisach components.
    pub hysteresis: Vec<HysteresisTerm>,
    /// Free / fixed entries.
    pub structure: Structure,
    /// Process noise per state.
    pub process_noise: Vec<NoiseModel>,
    /// Measurement noise.
    pub measurement_noise: NoiseModel,
    /// Names of the inputs and then the output (empty: unnamed).
    pub signal_names: Vec<String>,
}

/// Scratch of the simulation loop.
#[derive(Debug, Clone, Default)]
pub(crate) struct SimScratch {
    pub x: Vec<f64>,
    pub xn: Vec<f64>,
    pub args: [f64; MAX_DIMS],
    pub eval: EvalScratch,
}

impl SparseStateSpace {
    /// A linear model with all entries free, `x₀ = 0`, one sub-step, no
    /// nonlinear terms and Gaussian noise of unit scale (`a` n×n, `b` n×m, `c` n, `d` m).
    pub fn linear(a: Vec<f64>, b: Vec<f64>, c: Vec<f64>, d: Vec<f64>) -> Result<Self> {
        let n = c.len();
        let m = d.len();
        let model = Self {
            n_states: n,
            n_inputs: m,
            structure: Structure {
                a: vec![true; a.len()],
                b: vec![true; b.len()],
                c: vec![true; n],
                d: vec![true; m],
                x0: vec![false; n],
                y_offset: false,
            },
            a,
            b,
            c,
            d,
            x0: vec![0.0; n],
            y_offset: 0.0,
            substeps: 1,
            terms: Vec::new(),
            hysteresis: Vec::new(),
            process_noise: vec![NoiseModel::Gaussian { sd: 0.0 }; n],
            measurement_noise: NoiseModel::Gaussian { sd: 1.0 },
            signal_names: Vec::new(),
        };
        model.check()?;
        Ok(model)
    }

    /// Checks the internal consistency (sizes, indices, finiteness).
    pub fn check(&self) -> Result<()> {
        let n = self.n_states;
        let m = self.n_inputs;
        let dim = |what: &str, got: usize, want: usize| -> Result<()> {
            if got != want {
                return Err(ModelError::Dimension(format!(
                    "{what} has {got} entries, expected {want}"
                )));
            }
            Ok(())
        };
        if n == 0 {
            return Err(ModelError::InvalidArgument("at least one state".into()));
        }
        // A corrupt file can name any sizes: the products must not overflow.
        let (Some(nn), Some(nm)) = (n.checked_mul(n), n.checked_mul(m)) else {
            return Err(ModelError::Dimension(format!(
                "{n} states and {m} inputs are too many"
            )));
        };
        dim("A", self.a.len(), nn)?;
        dim("B", self.b.len(), nm)?;
        dim("C", self.c.len(), n)?;
        dim("D", self.d.len(), m)?;
        dim("x0", self.x0.len(), n)?;
        dim("structure A", self.structure.a.len(), nn)?;
        dim("structure B", self.structure.b.len(), nm)?;
        dim("structure C", self.structure.c.len(), n)?;
        dim("structure D", self.structure.d.len(), m)?;
        dim("structure x0", self.structure.x0.len(), n)?;
        dim("process noise", self.process_noise.len(), n)?;
        if !self.signal_names.is_empty() && self.signal_names.len() != m.saturating_add(1) {
            return Err(ModelError::Dimension(format!(
                "{} signal names for {m} inputs and one output",
                self.signal_names.len()
            )));
        }
        if self.substeps == 0 || self.substeps > 1000 {
            return Err(ModelError::InvalidArgument(
                "substeps must be in 1..=1000".into(),
            ));
        }
        let all = self
            .a
            .iter()
            .chain(&self.b)
            .chain(&self.c)
            .chain(&self.d)
            .chain(&self.x0)
            .chain(std::iter::once(&self.y_offset));
        if all.into_iter().any(|v| !v.is_finite()) {
            return Err(ModelError::InvalidArgument(
                "matrices must be finite".into(),
            ));
        }
        let target_ok = |t: &Target| match t {
            Target::State(i) => *i < n,
            Target::Output => true,
        };
        for (k, t) in self.terms.iter().enumerate() {
            if !target_ok(&t.target)
                || t.args.len() != t.expansion.dims()
                || t.args.iter().any(|a| match a {
                    Signal::State(i) => *i >= n,
                    Signal::Input(j) => *j >= m,
                })
            {
                return Err(ModelError::InvalidArgument(format!(
                    "nonlinear term {k}: target or arguments out of range"
                )));
            }
        }
        for (k, h) in self.hysteresis.iter().enumerate() {
            if !target_ok(&h.target) || h.input >= m {
                return Err(ModelError::InvalidArgument(format!(
                    "hysteresis term {k}: target or input out of range"
                )));
            }
        }
        Ok(())
    }

    /// Number of free parameters (free matrix entries and stored coefficients).
    pub fn n_parameters(&self) -> usize {
        let s = &self.structure;
        let free = |v: &[bool]| v.iter().filter(|&&b| b).count();
        free(&s.a)
            + free(&s.b)
            + free(&s.c)
            + free(&s.d)
            + free(&s.x0)
            + usize::from(s.y_offset)
            + self.terms.iter().map(|t| t.expansion.len()).sum::<usize>()
            + self
                .hysteresis
                .iter()
                .map(|h| h.everett.expansion().len())
                .sum::<usize>()
    }

    /// Number of non-zero wavelet coefficients over all terms.
    pub fn n_coefficients(&self) -> usize {
        self.terms.iter().map(|t| t.expansion.nnz()).sum::<usize>()
            + self
                .hysteresis
                .iter()
                .map(|h| h.everett.expansion().nnz())
                .sum::<usize>()
    }

    /// One-line description.
    pub fn describe(&self) -> String {
        format!(
            "{}, {} measurement noise",
            self.describe_structure(),
            self.measurement_noise.describe()
        )
    }

    /// The description without the noise model.
    pub fn describe_structure(&self) -> String {
        let mut s = format!(
            "sparse wavelet state space, {} states{}",
            self.n_states,
            if self.substeps > 1 {
                format!(" ({} sub-steps)", self.substeps)
            } else {
                String::new()
            }
        );
        if !self.terms.is_empty() {
            s += &format!(
                ", {} nonlinear terms ({} non-zero coefficients)",
                self.terms.len(),
                self.terms.iter().map(|t| t.expansion.nnz()).sum::<usize>()
            );
        }
        if !self.hysteresis.is_empty() {
            s += &format!(", {} Preisach components", self.hysteresis.len());
        }
        s
    }

    pub(crate) fn check_inputs(&self, inputs: &[Vec<f64>]) -> Result<usize> {
        if inputs.len() != self.n_inputs {
            return Err(ModelError::Dimension(format!(
                "model has {} inputs, got {}",
                self.n_inputs,
                inputs.len()
            )));
        }
        let n = inputs.first().map_or(0, Vec::len);
        if inputs.iter().any(|u| u.len() != n) {
            return Err(ModelError::Dimension(
                "input signals of different lengths".into(),
            ));
        }
        Ok(n)
    }

    /// Outputs of the Preisach components, `h[k][t]`.
    pub fn hysteresis_outputs(&self, inputs: &[Vec<f64>]) -> Result<Vec<Vec<f64>>> {
        self.hysteresis
            .iter()
            .map(|h| {
                Preisach::new(h.everett.clone())
                    .simulate(&inputs[h.input], &InitialState::NegativeSaturation)
                    .map_err(ModelError::from)
            })
            .collect()
    }

    /// Free-run simulation from `x₀` (no noise): the output `ŷ_t`.
    pub fn simulate(&self, inputs: &[Vec<f64>]) -> Result<Vec<f64>> {
        self.simulate_from(inputs, &self.x0).map(|(y, _)| y)
    }

    /// Free-run simulation from `x0`: outputs and the final state.
    pub fn simulate_from(&self, inputs: &[Vec<f64>], x0: &[f64]) -> Result<(Vec<f64>, Vec<f64>)> {
        let len = self.check_inputs(inputs)?;
        if x0.len() != self.n_states {
            return Err(ModelError::Dimension(format!(
                "initial state has {} entries, model has {} states",
                x0.len(),
                self.n_states
            )));
        }
        let h = self.hysteresis_outputs(inputs)?;
        let mut y = vec![0.0; len];
        let mut s = SimScratch {
            x: x0.to_vec(),
            xn: vec![0.0; self.n_states],
            ..Default::default()
        };
        let mut u = vec![0.0; self.n_inputs];
        let mut hk = vec![0.0; h.len()];
        let fast = self.fast_terms();
        for t in 0..len {
            for (j, uj) in u.iter_mut().enumerate() {
                *uj = inputs[j][t];
            }
            for (k, v) in hk.iter_mut().enumerate() {
                *v = h[k][t];
            }
            y[t] = self.output(&s.x, &u, &hk, &mut s.eval, &mut s.args);
            self.advance_with(&u, &hk, &mut s, &fast);
            if !s.x.iter().all(|v| v.is_finite() && v.abs() < 1e150) {
                return Err(ModelError::Diverged(t));
            }
        }
        Ok((y, s.x))
    }

    /// Simulated hidden states `x_t` (row-major N×n) and outputs.
    pub fn simulate_states(&self, inputs: &[Vec<f64>]) -> Result<(Vec<f64>, Vec<f64>)> {
        let len = self.check_inputs(inputs)?;
        let h = self.hysteresis_outputs(inputs)?;
        let n = self.n_states;
        let mut y = vec![0.0; len];
        let mut xs = vec![0.0; len * n];
        let mut s = SimScratch {
            x: self.x0.clone(),
            xn: vec![0.0; n],
            ..Default::default()
        };
        let mut u = vec![0.0; self.n_inputs];
        let mut hk = vec![0.0; h.len()];
        let fast = self.fast_terms();
        for t in 0..len {
            for (j, uj) in u.iter_mut().enumerate() {
                *uj = inputs[j][t];
            }
            for (k, v) in hk.iter_mut().enumerate() {
                *v = h[k][t];
            }
            xs[t * n..(t + 1) * n].copy_from_slice(&s.x);
            y[t] = self.output(&s.x, &u, &hk, &mut s.eval, &mut s.args);
            self.advance_with(&u, &hk, &mut s, &fast);
            if !s.x.iter().all(|v| v.is_finite() && v.abs() < 1e150) {
                return Err(ModelError::Diverged(t));
            }
        }
        Ok((y, xs))
    }

    #[inline]
    pub(crate) fn gather(args: &[Signal], x: &[f64], u: &[f64], out: &mut [f64; MAX_DIMS]) {
        for (o, a) in out.iter_mut().zip(args) {
            *o = match *a {
                Signal::State(i) => x[i],
                Signal::Input(j) => u[j],
            };
        }
    }

    /// `ŷ = C x + D u + g(x, u) + h_y`.
    #[inline]
    pub(crate) fn output(
        &self,
        x: &[f64],
        u: &[f64],
        h: &[f64],
        ev: &mut EvalScratch,
        args: &mut [f64; MAX_DIMS],
    ) -> f64 {
        let mut y = self.y_offset;
        for (c, xi) in self.c.iter().zip(x) {
            y += c * xi;
        }
        for (d, uj) in self.d.iter().zip(u) {
            y += d * uj;
        }
        for t in &self.terms {
            if t.target == Target::Output {
                Self::gather(&t.args, x, u, args);
                y += t
                    .expansion
                    .eval_with(&args[..t.args.len()], None, false, ev);
            }
        }
        for (k, hy) in self.hysteresis.iter().enumerate() {
            if hy.target == Target::Output {
                y += h[k];
            }
        }
        y
    }

    /// Grid evaluators of the state terms (`None`: atom evaluation).
    pub(crate) fn fast_terms(&self) -> Vec<Option<FastEval<'_>>> {
        self.terms.iter().map(|t| t.expansion.fast()).collect()
    }

    /// All sub-steps of one sample: `s.x ← map^M(s.x)`.
    #[inline]
    pub(crate) fn advance(&self, u: &[f64], h: &[f64], s: &mut SimScratch) {
        self.advance_with(u, h, s, &[]);
    }

    /// [`advance`](Self::advance) with precomputed grid evaluators.
    #[inline]
    pub(crate) fn advance_with(
        &self,
        u: &[f64],
        h: &[f64],
        s: &mut SimScratch,
        fast: &[Option<FastEval<'_>>],
    ) {
        let n = self.n_states;
        let m = self.n_inputs;
        for _ in 0..self.substeps {
            for i in 0..n {
                let mut v = 0.0;
                let row = &self.a[i * n..(i + 1) * n];
                for (a, xj) in row.iter().zip(&s.x) {
                    v += a * xj;
                }
                let brow = &self.b[i * m..(i + 1) * m];
                for (b, uj) in brow.iter().zip(u) {
                    v += b * uj;
                }
                s.xn[i] = v;
            }
            for (k, t) in self.terms.iter().enumerate() {
                if let Target::State(i) = t.target {
                    Self::gather(&t.args, &s.x, u, &mut s.args);
                    let d = t.args.len();
                    s.xn[i] += match fast.get(k) {
                        Some(Some(f)) => f.eval(&s.args, d),
                        _ => t
                            .expansion
                            .eval_with(&s.args[..d], None, false, &mut s.eval),
                    };
                }
            }
            for (k, hy) in self.hysteresis.iter().enumerate() {
                if let Target::State(i) = hy.target {
                    s.xn[i] += h[k];
                }
            }
            std::mem::swap(&mut s.x, &mut s.xn);
        }
    }

    /// The model file: magic, format version, postcard body.
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        let mut out = MAGIC.to_vec();
        out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
        out.extend(postcard::to_allocvec(self).map_err(|e| ModelError::Format(e.to_string()))?);
        Ok(out)
    }

    /// Reads a model file written by [`to_bytes`](Self::to_bytes) and checks it.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self> {
        if bytes.len() < 8 || &bytes[..4] != MAGIC {
            return Err(ModelError::Format(
                "not a greybox state-space model (bad magic)".into(),
            ));
        }
        let mut v = [0u8; 4];
        v.copy_from_slice(&bytes[4..8]);
        let version = u32::from_le_bytes(v);
        if version != FORMAT_VERSION {
            return Err(ModelError::Format(format!(
                "format version {version}, this build reads {FORMAT_VERSION}"
            )));
        }
        let m: Self =
            postcard::from_bytes(&bytes[8..]).map_err(|e| ModelError::Format(e.to_string()))?;
        m.check()?;
        Ok(m)
    }
}

impl SparseStateSpace {
    /// Decode a model-file body of class `state-space` (checked).
    pub fn decode(body: &[u8], version: u32) -> std::result::Result<Self, gb_core::CoreError> {
        let m: Self = gb_core::decode_postcard("state-space", version, 1, body)?;
        m.check().map_err(|e| {
            gb_core::CoreError::ModelFile(format!("inconsistent 'state-space' model ({e})"))
        })?;
        Ok(m)
    }
}

impl gb_core::DynamicModel for SparseStateSpace {
    fn class(&self) -> &'static str {
        "state-space"
    }
    fn n_inputs(&self) -> usize {
        self.n_inputs
    }
    fn n_states(&self) -> usize {
        self.n_states
    }
    fn describe(&self) -> String {
        self.describe_structure()
    }
    fn n_parameters(&self) -> usize {
        SparseStateSpace::n_parameters(self)
    }
    /// `Rest` starts from the zero state, `Stored` from the fitted `x₀`,
    /// `State` from the given one, `History`/`Window` from the state
    /// estimated on the measured outputs.
    fn simulate_into(
        &self,
        u: &[Vec<f64>],
        init: gb_core::Init<'_>,
        y: &mut [f64],
        _ws: &mut gb_core::Workspace,
    ) -> std::result::Result<(), gb_core::CoreError> {
        use gb_core::Init;
        gb_core::check_inputs(self.n_inputs, u)?;
        let sim = match init {
            Init::State(x0) => self.simulate_from(u, x0)?.0,
            Init::Stored => self.simulate(u)?,
            Init::Window(w) | Init::History(w) if !w.is_empty() => {
                self.simulate_init_window(u, w)?
            }
            _ => self.simulate_from(u, &vec![0.0; self.n_states])?.0,
        };
        if sim.len() != y.len() {
            return Err(gb_core::CoreError::Dimension(format!(
                "output buffer of {} samples for a simulation of {}",
                y.len(),
                sim.len()
            )));
        }
        y.copy_from_slice(&sim);
        Ok(())
    }
    /// `Rest` starts from the zero state (as [`simulate_into`](gb_core::DynamicModel::simulate_into)),
    /// `Stored` from the fitted `x₀`, `State` from the given one; the
    /// Preisach components start from negative saturation.
    fn stepper(
        &self,
        init: gb_core::Init<'_>,
    ) -> std::result::Result<Box<dyn gb_core::Stepper + '_>, gb_core::CoreError> {
        use gb_core::Init;
        let x0 = match init {
            Init::Rest => vec![0.0; self.n_states],
            Init::Stored => self.x0.clone(),
            Init::State(x) if x.len() == self.n_states => x.to_vec(),
            Init::State(x) => {
                return Err(gb_core::CoreError::Dimension(format!(
                    "initial state has {} entries, model has {} states",
                    x.len(),
                    self.n_states
                )))
            }
            _ => {
                return Err(gb_core::CoreError::Unsupported(
                    "state-space: a stepper starts at rest, stored or given state".into(),
                ))
            }
        };
        Ok(Box::new(StateSpaceStepper::new(self, x0)?))
    }
    fn encode(&self) -> std::result::Result<Vec<u8>, gb_core::CoreError> {
        postcard::to_allocvec(self)
            .map_err(|e| gb_core::CoreError::ModelFile(format!("cannot encode model: {e}")))
    }
    fn views(&self, input_names: &[String], _outputs: &[String]) -> Vec<gb_core::ModelView> {
        crate::views::state_space_views(self, input_names)
    }
    fn clone_box(&self) -> Box<dyn gb_core::DynamicModel> {
        Box::new(self.clone())
    }
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

/// [`SparseStateSpace`] one sample at a time (`DynamicModel::stepper`):
/// the same operations in the same order as the free-run simulation, so a
/// record stepped through gives bit-identical outputs.
pub struct StateSpaceStepper<'a> {
    model: &'a SparseStateSpace,
    preisach: Vec<(Preisach<WaveletEverett>, PreisachState<f64>)>,
    fast: Vec<Option<FastEval<'a>>>,
    s: SimScratch,
    h: Vec<f64>,
    t: usize,
}

impl<'a> StateSpaceStepper<'a> {
    /// A stepper of `model` from the state `x0`.
    pub fn new(model: &'a SparseStateSpace, x0: Vec<f64>) -> Result<Self> {
        if x0.len() != model.n_states {
            return Err(ModelError::Dimension(format!(
                "initial state has {} entries, model has {} states",
                x0.len(),
                model.n_states
            )));
        }
        let preisach = model
            .hysteresis
            .iter()
            .map(|h| {
                let p = Preisach::new(h.everett.clone());
                let st = p.state(&InitialState::NegativeSaturation)?;
                Ok((p, st))
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            model,
            preisach,
            fast: model.fast_terms(),
            s: SimScratch {
                xn: vec![0.0; x0.len()],
                x: x0,
                ..Default::default()
            },
            h: vec![0.0; model.hysteresis.len()],
            t: 0,
        })
    }

    /// The current state `x_t` (before the next step).
    pub fn state(&self) -> &[f64] {
        &self.s.x
    }
}

impl gb_core::Stepper for StateSpaceStepper<'_> {
    fn step(&mut self, u: &[f64], y: &mut [f64]) -> std::result::Result<(), gb_core::CoreError> {
        let m = self.model;
        if u.len() != m.n_inputs || y.len() != 1 {
            return Err(gb_core::CoreError::Dimension(format!(
                "a step takes {} inputs and gives 1 output, got {} and {}",
                m.n_inputs,
                u.len(),
                y.len()
            )));
        }
        if u.iter().any(|v| !v.is_finite()) {
            return Err(gb_core::CoreError::InvalidArgument(format!(
                "input at step {} is not finite",
                self.t
            )));
        }
        for ((hk, (p, st)), term) in self.h.iter_mut().zip(&mut self.preisach).zip(&m.hysteresis) {
            *hk = p.step(st, u[term.input]);
        }
        let s = &mut self.s;
        y[0] = m.output(&s.x, u, &self.h, &mut s.eval, &mut s.args);
        m.advance_with(u, &self.h, s, &self.fast);
        if !s.x.iter().all(|v| v.is_finite() && v.abs() < 1e150) {
            return Err(ModelError::Diverged(self.t).into());
        }
        self.t += 1;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gb_core::{DynamicModel, Init};

    /// Two states, 3 sub-steps, a grid-evaluated 2-D term on a state row, an
    /// atom-evaluated (db2) term on the output and a Preisach component.
    fn model() -> SparseStateSpace {
        let mut m = SparseStateSpace::linear(
            vec![0.9, 0.1, -0.2, 0.7],
            vec![0.0, 0.5],
            vec![1.0, 0.0],
            vec![0.1],
        )
        .unwrap();
        m.substeps = 3;
        m.y_offset = 0.2;
        let mut e = SparseExpansion::new("bior2.2", vec![-2.0, -2.0], vec![2.0, 2.0]).unwrap();
        e.add_coarse_grid(2).unwrap();
        let n = e.len();
        e.set_values(&(0..n).map(|i| 0.01 * (i as f64 - 7.0)).collect::<Vec<_>>())
            .unwrap();
        m.terms.push(NonlinearTerm {
            target: Target::State(1),
            args: vec![Signal::State(0), Signal::Input(0)],
            expansion: e,
        });
        let mut g = SparseExpansion::new("db2", vec![-2.0], vec![2.0]).unwrap();
        g.add_coarse_grid(1).unwrap();
        let n = g.len();
        g.set_values(&(0..n).map(|i| 0.02 * i as f64).collect::<Vec<_>>())
            .unwrap();
        m.terms.push(NonlinearTerm {
            target: Target::Output,
            args: vec![Signal::State(1)],
            expansion: g,
        });
        let mut h = SparseExpansion::new("bior2.2", vec![-1.5, -1.5], vec![1.5, 1.5]).unwrap();
        h.add_coarse_grid(1).unwrap();
        let n = h.len();
        h.set_values(&(0..n).map(|i| 0.03 * (i as f64).sin()).collect::<Vec<_>>())
            .unwrap();
        m.hysteresis.push(HysteresisTerm {
            target: Target::State(0),
            input: 0,
            everett: WaveletEverett::new(h).unwrap(),
        });
        m.check().unwrap();
        m
    }

    #[test]
    fn stepping_through_a_record_is_bit_identical_to_the_simulation() {
        let m = model();
        let n = 1500;
        let u = vec![(0..n)
            .map(|t| (t as f64 * 0.031).sin() * 1.2 + 0.3 * (t as f64 * 0.17).cos())
            .collect::<Vec<f64>>()];
        for x0 in [None, Some(vec![0.4, -0.3])] {
            let init = match &x0 {
                None => Init::Rest,
                Some(x) => Init::State(x),
            };
            let batch = DynamicModel::simulate(&m, &u, init).unwrap();
            let mut st = m.stepper(init).unwrap();
            let mut y = [0.0];
            for (t, yb) in batch.iter().enumerate() {
                st.step(&[u[0][t]], &mut y).unwrap();
                assert_eq!(y[0].to_bits(), yb.to_bits(), "sample {t}, start {x0:?}");
            }
        }
        // sizes and unsupported starts are errors
        let mut st = m.stepper(Init::Rest).unwrap();
        assert!(st.step(&[1.0, 2.0], &mut [0.0]).is_err());
        assert!(st.step(&[f64::NAN], &mut [0.0]).is_err());
        assert!(m.stepper(Init::State(&[1.0])).is_err());
        assert!(m.stepper(Init::Window(&[1.0])).is_err());
    }

    #[test]
    fn stepping_reports_divergence_where_the_simulation_does() {
        let m = SparseStateSpace::linear(vec![3.0], vec![1.0], vec![1.0], vec![0.0]).unwrap();
        let u = vec![vec![1.0; 2000]];
        let Err(ModelError::Diverged(t)) = m.simulate_from(&u, &[0.0]) else {
            panic!("the simulation must diverge");
        };
        let mut st = StateSpaceStepper::new(&m, vec![0.0]).unwrap();
        let mut y = [0.0];
        let first_err =
            (0..2000).find(|_| gb_core::Stepper::step(&mut st, &[1.0], &mut y).is_err());
        assert_eq!(first_err, Some(t));
    }
}
