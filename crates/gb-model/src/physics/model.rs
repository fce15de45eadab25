//! The physics model as a [`gb_core::DynamicModel`]: simulation from any
//! [`Init`], a stepper, the model-file body (the model text, the fitted
//! values and the covariance) and a parameter table for reports.
use super::error::{PhysicsError, PhysicsResult};
use super::fit::{coordinates, FitReport, OeProblem, Segment};
use super::simulate::{simulate, Integrator, Lanes};
use super::spec::{Compiled, PhysicsSpec, StateHysteresis};
use gb_core::solver::LmParams;
use gb_core::{CoreError, DynamicModel, Init, ModelView, Stepper, ViewData, Workspace};
use serde::{Deserialize, Serialize};
use std::any::Any;

/// The class tag of physics models in model files.
pub const CLASS: &str = "physics";
/// The encoding version of the class (2: the state noise of the SMC path;
/// 3: the input delay).
const CLASS_VERSION: u32 = 4;

/// The noise of the stochastic model `x_t = Φ_θ(x_{t−1}, u_{t−1}) + v_t`,
/// `y_t = g(x_t, u_t, θ) + w_t` that the SMC path identifies
/// ([`crate::Smc::fit_physics_model`]): Gaussian `v_{t,i} ~ N(0, σ_{p,i}²)`
/// per state (`None`: a kinematic state, no noise) and
/// `w_t ~ N(0, σ_m²)`. `greybox filter` runs the particle filter with it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StateNoise {
    /// `σ_{p,i}` per state.
    pub process_sd: Vec<Option<f64>>,
    /// `σ_m`.
    pub measurement_sd: f64,
}

/// The engineer's continuous-time model with its (fitted) parameter
/// values, initial state and, after a fit, the uncertainty.
#[derive(Debug, Clone)]
pub struct PhysicsModel {
    spec: PhysicsSpec,
    theta: Vec<f64>,
    x0: Vec<f64>,
    fit: Option<FitReport>,
    source: Option<String>,
    noise: Option<StateNoise>,
    compiled: Compiled,
}

/// What every model-file version stores first (version 1 stores only
/// this).
#[derive(Serialize, Deserialize)]
struct StoredBase {
    spec: PhysicsSpec,
    theta: Vec<f64>,
    x0: Vec<f64>,
    fit: Option<FitReport>,
    source: Option<String>,
}

/// What a model file stores (postcard): the base, then the state noise
/// (version 2), the input delay (version 3) and the Preisach operators on
/// states (version 4). Postcard writes a nested struct or tuple as its
/// fields in order, so an older version is the base followed by a
/// shorter tail.
#[derive(Serialize, Deserialize)]
struct Stored {
    base: StoredBase,
    noise: Option<StateNoise>,
    input_delay: Option<String>,
    hysteresis: Vec<StateHysteresis>,
}

impl PhysicsModel {
    /// Compile `spec` (checked) with its start values.
    pub fn new(spec: PhysicsSpec) -> PhysicsResult<Self> {
        let compiled = spec.compile()?;
        Ok(Self {
            theta: spec.theta0(),
            x0: spec.x0(),
            spec,
            fit: None,
            source: None,
            noise: None,
            compiled,
        })
    }

    /// Keep the model file's text (stored in the model file).
    pub fn with_source(mut self, text: String) -> Self {
        self.source = Some(text);
        self
    }

    /// Set parameter values and initial state (e.g. a known truth); checks
    /// lengths and finiteness.
    pub fn with_values(mut self, theta: Vec<f64>, x0: Vec<f64>) -> PhysicsResult<Self> {
        if theta.len() != self.theta.len() || x0.len() != self.x0.len() {
            return Err(PhysicsError::Data(format!(
                "{} parameter values and {} initial states for a model with {} and {}",
                theta.len(),
                x0.len(),
                self.theta.len(),
                self.x0.len()
            )));
        }
        if !theta.iter().chain(&x0).all(|v| v.is_finite()) {
            return Err(PhysicsError::Data("parameter values must be finite".into()));
        }
        self.theta = theta;
        self.x0 = x0;
        Ok(self)
    }

    /// The model definition.
    pub fn spec(&self) -> &PhysicsSpec {
        &self.spec
    }
    /// All parameter values, in the spec's order.
    pub fn parameters(&self) -> &[f64] {
        &self.theta
    }
    /// The value of the parameter `name`.
    pub fn parameter(&self, name: &str) -> Option<f64> {
        let i = self.spec.parameters.iter().position(|p| p.name == name)?;
        Some(self.theta[i])
    }
    /// The stored initial state.
    pub fn initial_state(&self) -> &[f64] {
        &self.x0
    }
    /// The fit's estimates and uncertainty (after a fit).
    pub fn fit_report(&self) -> Option<&FitReport> {
        self.fit.as_ref()
    }
    /// The model file's text, when the model came from one.
    pub fn source(&self) -> Option<&str> {
        self.source.as_deref()
    }
    pub(crate) fn compiled(&self) -> &Compiled {
        &self.compiled
    }

    pub(crate) fn set_fitted(&mut self, theta: Vec<f64>, x0: Vec<f64>, ts: f64, report: FitReport) {
        self.theta = theta;
        self.x0 = x0;
        self.spec.sample_time = Some(ts);
        self.fit = Some(report);
        self.noise = None;
    }

    /// The state noise identified by the SMC path, if any.
    pub fn state_noise(&self) -> Option<&StateNoise> {
        self.noise.as_ref()
    }

    /// With state noise (one entry per state, every level finite and
    /// positive, at least one state with process noise).
    pub fn with_state_noise(mut self, noise: StateNoise) -> PhysicsResult<Self> {
        let ok = |v: f64| v.is_finite() && v > 0.0;
        if noise.process_sd.len() != self.x0.len()
            || !noise.process_sd.iter().flatten().all(|&v| ok(v))
            || noise.process_sd.iter().all(Option::is_none)
            || !ok(noise.measurement_sd)
        {
            return Err(PhysicsError::Data(format!(
                "state noise: {} process levels (finite, positive, at least one) and a positive measurement level are needed for {} states",
                noise.process_sd.len(),
                self.x0.len()
            )));
        }
        self.noise = Some(noise);
        Ok(self)
    }

    /// The sample time (from the model file or the fit's data).
    pub fn sample_time(&self) -> PhysicsResult<f64> {
        self.spec.sample_time.ok_or_else(|| {
            PhysicsError::Data(format!(
                "model '{}': the sample time is unknown (give sample_time in the model file or fit on data with a t column)",
                self.spec.name
            ))
        })
    }

    /// Free-run simulation from `x0` with parameters `theta` (first output
    /// or all: output-major).
    pub(crate) fn run(
        &self,
        theta: &[f64],
        x0: &[f64],
        u: &[&[f64]],
        y: &mut [f64],
    ) -> PhysicsResult<()> {
        let ts = self.sample_time()?;
        simulate(&self.compiled, theta, x0, u, ts, self.spec.substeps, y)
            .map_err(PhysicsError::Diverged)
    }

    /// The state trajectory of a free-run simulation on inputs `u` started
    /// as `init` says: `x[i][t]`, state `i` at the start of sample `t`.
    pub fn state_trajectory(&self, u: &[Vec<f64>], init: Init<'_>) -> PhysicsResult<Vec<Vec<f64>>> {
        let us: Vec<&[f64]> = u.iter().map(Vec::as_slice).collect();
        let x0 = self.resolve_init(&us, init)?;
        let ts = self.sample_time()?;
        let lanes = Lanes::default();
        let mut it = Integrator::new(&self.compiled, &self.theta, ts, self.spec.substeps, &lanes);
        it.reset(&x0, &lanes);
        let len = u.first().map_or(0, Vec::len);
        let mut x = vec![Vec::with_capacity(len); x0.len()];
        for t in 0..len {
            for (xi, v) in x.iter_mut().zip(it.state()) {
                xi.push(*v);
            }
            it.set_input(us.iter().map(|s| s[t]));
            if !it.step() {
                return Err(PhysicsError::Diverged(t));
            }
        }
        Ok(x)
    }

    /// The initial state that best explains the measured outputs `y` of an
    /// init window (least squares over every state's initial value, the
    /// parameters fixed; the stored state is the start).
    /// With several outputs `y` holds each output's window, output-major.
    pub fn estimate_initial_state(&self, u: &[&[f64]], y: &[f64]) -> PhysicsResult<Vec<f64>> {
        let ny = self.spec.outputs.len().max(1);
        if y.len() % ny != 0 {
            return Err(PhysicsError::Data(format!(
                "an init window of {} values for {ny} outputs",
                y.len()
            )));
        }
        let w = y.len() / ny;
        if w == 0 {
            return Ok(self.x0.clone());
        }
        if u.iter().any(|s| s.len() < w) {
            return Err(PhysicsError::Data(format!(
                "an init window of {w} samples is longer than the inputs"
            )));
        }
        let ts = self.sample_time()?;
        let coords = coordinates(&self.spec, &self.theta, &self.x0, true);
        let seg = Segment {
            u: u.iter().map(|s| &s[..w]).collect(),
            y: y.chunks(w).collect(),
        };
        let mut p = OeProblem::new(
            &self.compiled,
            ts,
            self.spec.substeps,
            vec![seg],
            coords,
            self.theta.clone(),
            self.x0.clone(),
        );
        let lm = LmParams::default().max_iter(100).tol(1e-12).check()?;
        let phi0 = p.phi();
        let Ok(st) = lm.minimize(&mut p, &phi0, &gb_core::Silent) else {
            return Ok(self.x0.clone());
        };
        p.unpack(&st.theta);
        Ok(p.x0)
    }

    /// The initial state `init` asks for.
    pub(crate) fn resolve_init(&self, u: &[&[f64]], init: Init<'_>) -> PhysicsResult<Vec<f64>> {
        let n = self.x0.len();
        match init {
            Init::Rest => Ok(vec![0.0; n]),
            Init::Stored => Ok(self.x0.clone()),
            Init::State(x) if x.len() == n => Ok(x.to_vec()),
            Init::State(x) => Err(PhysicsError::Data(format!(
                "{} initial values for a model with {n} states",
                x.len()
            ))),
            Init::Window(y) | Init::History(y) => self.estimate_initial_state(u, y),
            _ => Err(PhysicsError::Data(
                "this start is resolved by DynamicModel::simulate".into(),
            )),
        }
    }

    /// Decode a model-file body (checked).
    pub fn decode(body: &[u8], version: u32) -> Result<Self, CoreError> {
        let s: Stored = match version {
            0 | 1 => Stored {
                base: gb_core::decode_postcard(CLASS, version, CLASS_VERSION, body)?,
                noise: None,
                input_delay: None,
                hysteresis: vec![],
            },
            2 | 3 => {
                let (base, noise, input_delay): (StoredBase, _, Option<String>) = if version == 2 {
                    let (b, n) = gb_core::decode_postcard(CLASS, version, CLASS_VERSION, body)?;
                    (b, n, None)
                } else {
                    gb_core::decode_postcard(CLASS, version, CLASS_VERSION, body)?
                };
                Stored {
                    base,
                    noise,
                    input_delay,
                    hysteresis: vec![],
                }
            }
            _ => gb_core::decode_postcard(CLASS, version, CLASS_VERSION, body)?,
        };
        let bad = |m: String| CoreError::ModelFile(format!("inconsistent '{CLASS}' model ({m})"));
        let b = s.base;
        let mut spec = b.spec;
        spec.input_delay = s.input_delay;
        spec.hysteresis = s.hysteresis;
        let mut m = Self::new(spec).map_err(|e| bad(e.to_string()))?;
        m = m
            .with_values(b.theta, b.x0)
            .map_err(|e| bad(e.to_string()))?;
        if let Some(f) = &b.fit {
            let l = f.free.len();
            if f.covariance.len() != l * l
                || f.free.iter().any(|c| match *c {
                    super::fit::Coordinate::Parameter(i) => i >= m.theta.len(),
                    super::fit::Coordinate::InitialState(i) => i >= m.x0.len(),
                })
            {
                return Err(bad("covariance of the wrong size".into()));
            }
        }
        m.fit = b.fit;
        m.source = b.source;
        if let Some(n) = s.noise {
            m = m.with_state_noise(n).map_err(|e| bad(e.to_string()))?;
        }
        Ok(m)
    }

    fn parameter_table(&self) -> ViewData {
        let header = ["parameter", "value", "std. error", "95 % interval", "note"]
            .map(String::from)
            .to_vec();
        let rows = match &self.fit {
            Some(f) => f
                .estimates
                .iter()
                .map(|e| {
                    let fixed = e.fixed;
                    vec![
                        e.name.clone(),
                        format!("{:.6e}", e.value),
                        if fixed {
                            "—".into()
                        } else {
                            format!("{:.3e}", e.std_error)
                        },
                        if fixed {
                            "—".into()
                        } else {
                            format!("[{:.6e}, {:.6e}]", e.interval.0, e.interval.1)
                        },
                        if fixed {
                            "fixed".into()
                        } else if e.at_bound {
                            "at a bound".into()
                        } else if !e.std_error.is_finite() {
                            "not identifiable".into()
                        } else {
                            String::new()
                        },
                    ]
                })
                .collect(),
            None => self
                .spec
                .parameters
                .iter()
                .zip(&self.theta)
                .map(|(p, v)| {
                    let note = if p.fixed { "fixed" } else { "not fitted" };
                    vec![
                        p.name.clone(),
                        format!("{v:.6e}"),
                        "—".into(),
                        "—".into(),
                        note.into(),
                    ]
                })
                .collect(),
        };
        ViewData::Table { header, rows }
    }
}

impl DynamicModel for PhysicsModel {
    fn class(&self) -> &'static str {
        CLASS
    }
    /// A state that an output reads and that no state equation, no
    /// Preisach operator and not its own equation uses (`q̇ = v` with `q`
    /// nowhere else): the output sums the rest of the model.
    fn integrates(&self) -> bool {
        let c = &self.compiled;
        (0..c.n).any(|s| {
            c.g_used.iter().any(|g| g.contains(&s))
                && !c.f_used.iter().any(|f| f.contains(&s))
                && !c.ops.iter().any(|o| o.driver == s)
        })
    }
    fn class_version(&self) -> u32 {
        CLASS_VERSION
    }
    fn n_inputs(&self) -> usize {
        self.spec.inputs.len()
    }
    fn n_outputs(&self) -> usize {
        self.spec.outputs.len()
    }
    fn n_states(&self) -> usize {
        self.spec.states.len()
    }
    fn describe(&self) -> String {
        let delay = match self.spec.input_delay_index() {
            Some(p) => format!(
                ", input delay {} = {:.4e} s",
                self.spec.parameters[p].name, self.theta[p]
            ),
            None => String::new(),
        };
        format!(
            "physics model '{}': {} states ({}), {} free parameters, RK4 with {} sub-step{} per sample{delay}",
            self.spec.name,
            self.spec.states.len(),
            self.spec
                .states
                .iter()
                .map(|s| s.name.as_str())
                .collect::<Vec<_>>()
                .join(", "),
            self.spec.parameters.iter().filter(|p| !p.fixed).count(),
            self.spec.substeps,
            if self.spec.substeps == 1 { "" } else { "s" },
        )
    }
    fn n_parameters(&self) -> usize {
        self.spec.parameters.iter().filter(|p| !p.fixed).count()
            + self.spec.states.iter().filter(|s| s.free).count()
    }

    /// `Rest` starts from the zero state, `Stored` from the fitted `x(0)`,
    /// `Window`/`History` from the least-squares initial state of the
    /// window, `State` from the given one.
    fn simulate_into(
        &self,
        u: &[Vec<f64>],
        init: Init<'_>,
        y: &mut [f64],
        _ws: &mut Workspace,
    ) -> Result<(), CoreError> {
        gb_core::check_inputs(self.n_inputs(), u)?;
        let len = u
            .first()
            .map_or(y.len() / self.n_outputs().max(1), Vec::len);
        if y.len() != len * self.n_outputs() {
            return Err(CoreError::Dimension(format!(
                "{} output values for {len} samples of {} outputs",
                y.len(),
                self.n_outputs()
            )));
        }
        let us: Vec<&[f64]> = u.iter().map(Vec::as_slice).collect();
        let x0 = self.resolve_init(&us, init)?;
        Ok(self.run(&self.theta, &x0, &us, y)?)
    }

    fn stepper(&self, init: Init<'_>) -> Result<Box<dyn Stepper + '_>, CoreError> {
        let x0 = self.resolve_init(&[], init)?;
        let ts = self.sample_time()?;
        let lanes = Lanes::default();
        let mut it = Integrator::new(&self.compiled, &self.theta, ts, self.spec.substeps, &lanes);
        it.reset(&x0, &lanes);
        Ok(Box::new(PhysicsStepper {
            it,
            nu: self.n_inputs(),
            ny: self.n_outputs(),
            delayed: std::collections::VecDeque::new(),
            first: vec![],
            k: 0,
        }))
    }

    fn encode(&self) -> Result<Vec<u8>, CoreError> {
        let s = Stored {
            base: StoredBase {
                spec: self.spec.clone(),
                theta: self.theta.clone(),
                x0: self.x0.clone(),
                fit: self.fit.clone(),
                source: self.source.clone(),
            },
            noise: self.noise.clone(),
            input_delay: self.spec.input_delay.clone(),
            hysteresis: self.spec.hysteresis.clone(),
        };
        postcard::to_allocvec(&s)
            .map_err(|e| CoreError::ModelFile(format!("cannot encode the physics model: {e}")))
    }

    fn views(&self, _inputs: &[String], _outputs: &[String]) -> Vec<ModelView> {
        let caption = match &self.fit {
            Some(f) => format!(
                "Estimates with standard errors from σ̂²(JᵀJ)⁻¹ at the optimum (σ̂ = {:.3e}, {} samples) and 95 % intervals (t quantile {:.3}); condition number of the scaled JᵀJ {:.1e}.",
                f.sigma, f.samples, f.t_quantile, f.condition
            ),
            None => "Parameter values of the model file (not fitted).".into(),
        };
        vec![ModelView {
            key: "physics-parameters".into(),
            title: format!("Parameters of the physics model '{}'", self.spec.name),
            caption,
            data: self.parameter_table(),
        }]
    }

    fn clone_box(&self) -> Box<dyn DynamicModel> {
        Box::new(self.clone())
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// One sample at a time (the same RK4 steps as the simulation; under an
/// input delay of `D` samples the outputs `ỹ_{k−D..k}` wait in a queue).
struct PhysicsStepper<'m> {
    it: Integrator<'m>,
    nu: usize,
    ny: usize,
    delayed: std::collections::VecDeque<Vec<f64>>,
    /// `g(x₀, u₀)`, the output of the first `D` samples.
    first: Vec<f64>,
    /// Samples stepped.
    k: usize,
}

impl Stepper for PhysicsStepper<'_> {
    fn step(&mut self, u: &[f64], y: &mut [f64]) -> Result<(), CoreError> {
        if u.len() != self.nu || y.len() != self.ny {
            return Err(CoreError::Dimension(format!(
                "step: {} inputs and {} outputs for a model with {} and {}",
                u.len(),
                y.len(),
                self.nu,
                self.ny
            )));
        }
        self.it.set_input(u.iter().copied());
        let shift = self.it.shift();
        if self.k == 0 && shift > 0 {
            self.first = vec![0.0; y.len()];
            self.it.output_now(&mut self.first);
        }
        self.it.output(y);
        if !self.it.step() || !y.iter().all(|v| v.is_finite()) {
            return Err(CoreError::Unstable(
                "the physics model's state left the finite numbers".into(),
            ));
        }
        if shift > 0 {
            self.delayed.push_back(y.to_vec());
            if self.k >= shift {
                if let Some(old) = self.delayed.pop_front() {
                    y.copy_from_slice(&old);
                }
            } else {
                y.copy_from_slice(&self.first);
            }
        }
        self.k += 1;
        Ok(())
    }
}
