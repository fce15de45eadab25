//! The engineer's model: named states, inputs, outputs and parameters and
//! the equations `ẋ = f(x, u, θ)`, `y = g(x, u, θ)` as expressions, each a
//! list of additive terms (so that a diagnosis can add a term to one state
//! equation or to an output, see [`PhysicsSpec::add_term`]).
use super::error::{Item, Location, PhysicsError, PhysicsResult};
use super::tape::{ExprError, Rec, Tape, TapeBuilder, RESERVED};
use serde::{Deserialize, Serialize};

/// A Gaussian prior `θ ~ N(mean, sd²)` on a parameter.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Prior {
    /// Prior mean.
    pub mean: f64,
    /// Prior standard deviation (> 0).
    pub sd: f64,
}

/// A parameter: start value, bounds, fixed or free, optional prior.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Parameter {
    /// Name (a symbol in the equations).
    pub name: String,
    /// Start value (the value, when fixed).
    pub value: f64,
    /// Lower bound (`-inf` for none).
    pub lower: f64,
    /// Upper bound (`inf` for none).
    pub upper: f64,
    /// Known: not estimated.
    pub fixed: bool,
    /// Gaussian prior (MAP estimate), when given.
    pub prior: Option<Prior>,
}

impl Parameter {
    /// A free, unbounded parameter.
    pub fn new(name: &str, value: f64) -> Self {
        Self {
            name: name.into(),
            value,
            lower: f64::NEG_INFINITY,
            upper: f64::INFINITY,
            fixed: false,
            prior: None,
        }
    }
    /// With bounds.
    pub fn bounds(mut self, lower: f64, upper: f64) -> Self {
        self.lower = lower;
        self.upper = upper;
        self
    }
    /// Fixed (known).
    pub fn fixed(mut self) -> Self {
        self.fixed = true;
        self
    }
    /// With a Gaussian prior.
    pub fn prior(mut self, mean: f64, sd: f64) -> Self {
        self.prior = Some(Prior { mean, sd });
        self
    }
}

/// A state: its initial value, fixed or estimated, and its optional
/// physical range `[lower, upper]` (a level that cannot be negative, an
/// end stop): the estimated initial value stays inside it, and the
/// simulation clamps the state into it after every RK4 stage and step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct State {
    /// Name (a symbol in the equations).
    pub name: String,
    /// Initial value `x(0)` (the start value when free).
    pub initial: f64,
    /// Estimate the initial value.
    pub free: bool,
    /// Lower bound of the state (and of its initial value).
    pub lower: f64,
    /// Upper bound of the state (and of its initial value).
    pub upper: f64,
}

impl State {
    /// A state with a fixed initial value.
    pub fn new(name: &str, initial: f64) -> Self {
        Self {
            name: name.into(),
            initial,
            free: false,
            lower: f64::NEG_INFINITY,
            upper: f64::INFINITY,
        }
    }
    /// With an estimated initial value.
    pub fn free(mut self) -> Self {
        self.free = true;
        self
    }
    /// With a physical range `[lower, upper]`.
    pub fn bounded(mut self, lower: f64, upper: f64) -> Self {
        self.lower = lower;
        self.upper = upper;
        self
    }
}

/// An output `y = g(x, u, θ)`, a sum of terms.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Output {
    /// Name (the data column).
    pub name: String,
    /// Additive terms.
    pub terms: Vec<String>,
}

/// A Preisach operator on a state (Hauth 2008, ch. 3): relay cells
/// ([`gb_preisach::RelayCells`], `levels` intervals per side, `sub`² relays
/// per cell) over `[center − half_range, center + half_range]` of the state
/// `driver`. Cell `j`'s output, its mean relay state in `[−1, 1]`, is the
/// symbol `{prefix}{j}` in the equations; with weights `Σⱼ wⱼ·P_j` is a
/// discrete Preisach operator whose Everett function is piecewise
/// constant over the cells. The cells switch with the state after every
/// RK4 sub-step and are held within it (a hysteretic force inside the
/// dynamics, such as a Preisach spring). In the sensitivities the cells
/// are held inputs: `∂P_j/∂θ = 0`, `∂(wⱼ·P_j)/∂wⱼ = P_j` exact.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StateHysteresis {
    /// The state the relays switch with.
    pub driver: String,
    /// The cells' symbols are `{prefix}0`, `{prefix}1`, ….
    pub prefix: String,
    /// Intervals per side of the relay grid (1..=32).
    pub levels: usize,
    /// Relays per cell side (1..=16).
    pub sub: usize,
    /// Middle of the grid, in the units of `driver`.
    pub center: f64,
    /// Half width of the grid (> 0).
    pub half_range: f64,
}

impl StateHysteresis {
    /// Number of cells: `levels·(levels + 1)/2`.
    pub fn n_cells(&self) -> usize {
        self.levels * (self.levels + 1) / 2
    }
    /// The symbol of cell `j`.
    pub fn cell_name(&self, j: usize) -> String {
        format!("{}{j}", self.prefix)
    }
}

/// Where a term goes ([`PhysicsSpec::add_term`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum TermTarget {
    /// The equation of this state.
    State(usize),
    /// This output.
    Output(usize),
}

/// The engineer's continuous-time model.
///
/// `ẋ = f(x, u, θ)` with one equation per state (`equations[i]` is the sum
/// of its terms), `y = g(x, u, θ)` per output, discretised by RK4 with
/// `substeps` steps per sample under zero-order hold of the input.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PhysicsSpec {
    /// A name for reports.
    pub name: String,
    /// States, in order.
    pub states: Vec<State>,
    /// Input names (data columns), in order.
    pub inputs: Vec<String>,
    /// Parameters, in order.
    pub parameters: Vec<Parameter>,
    /// `ẋᵢ` as additive terms, one list per state.
    pub equations: Vec<Vec<String>>,
    /// Outputs.
    pub outputs: Vec<Output>,
    /// RK4 steps per sample (≥ 1).
    pub substeps: usize,
    /// Sample time in seconds (else the data's).
    pub sample_time: Option<f64>,
    /// The parameter that is the input delay `d` in seconds, when the
    /// model has one: the input held from sample `j` acts on
    /// `[t_j + d, t_{j+1} + d)`, and `y_k` is the output at `t_k`. A dead
    /// time is `d > 0`; `−T_s < d < 0` says the output is sampled after the
    /// held input has acted for `−d` (`d = −T_s/2`: a zero-order hold
    /// centred on the sample instant). Stored after the spec in model
    /// files (class version 3).
    #[serde(skip)]
    pub input_delay: Option<String>,
    /// Preisach operators on states, their cells symbols the equations
    /// use. Stored after the spec in model files (class version 4).
    #[serde(skip)]
    pub hysteresis: Vec<StateHysteresis>,
}

impl PhysicsSpec {
    /// An empty model (add states, inputs, parameters, equations, outputs).
    pub fn new(name: &str) -> Self {
        Self {
            name: name.into(),
            states: vec![],
            inputs: vec![],
            parameters: vec![],
            equations: vec![],
            outputs: vec![],
            substeps: 1,
            sample_time: None,
            input_delay: None,
            hysteresis: vec![],
        }
    }

    /// Add a state with its equation `ẋ = expr`.
    pub fn state(mut self, state: State, expr: &str) -> Self {
        self.states.push(state);
        self.equations.push(vec![expr.into()]);
        self
    }

    /// Add an input.
    pub fn input(mut self, name: &str) -> Self {
        self.inputs.push(name.into());
        self
    }

    /// Add a parameter.
    pub fn parameter(mut self, p: Parameter) -> Self {
        self.parameters.push(p);
        self
    }

    /// Add an output `name = expr`.
    pub fn output(mut self, name: &str, expr: &str) -> Self {
        self.outputs.push(Output {
            name: name.into(),
            terms: vec![expr.into()],
        });
        self
    }

    /// RK4 steps per sample.
    pub fn substeps(mut self, n: usize) -> Self {
        self.substeps = n;
        self
    }

    /// The sample time.
    pub fn sample_time(mut self, ts: f64) -> Self {
        self.sample_time = Some(ts);
        self
    }

    /// The parameter `name` is the input delay in seconds (see
    /// [`input_delay`](Self::input_delay)).
    pub fn with_input_delay(mut self, name: &str) -> Self {
        self.input_delay = Some(name.into());
        self
    }

    /// Add a Preisach operator on a state ([`StateHysteresis`]; its cells
    /// enter the equations through terms such as `w0*P0`).
    pub fn with_hysteresis(mut self, h: StateHysteresis) -> Self {
        self.hysteresis.push(h);
        self
    }

    /// Number of cell symbols of all Preisach operators.
    pub(crate) fn n_cells(&self) -> usize {
        self.hysteresis.iter().map(StateHysteresis::n_cells).sum()
    }

    /// The index of the input-delay parameter (after [`check`](Self::check)).
    pub(crate) fn input_delay_index(&self) -> Option<usize> {
        let name = self.input_delay.as_deref()?;
        self.parameters.iter().position(|p| p.name == name)
    }

    /// Add a term to a state equation or an output (the hook a diagnosis
    /// uses to extend the engineer's model; new parameters go through
    /// [`parameter`](Self::parameter)).
    pub fn add_term(&mut self, target: TermTarget, term: &str) -> PhysicsResult<()> {
        let list = match target {
            TermTarget::State(i) => self.equations.get_mut(i),
            TermTarget::Output(i) => self.outputs.get_mut(i).map(|o| &mut o.terms),
        };
        list.ok_or_else(|| PhysicsError::Dimension {
            at: Location::new(Item::Model, "add_term"),
            message: format!("no {target:?} in the model"),
        })?
        .push(term.into());
        Ok(())
    }

    /// The index of the state, input or parameter of this name, in the
    /// variable layout `[states | inputs | parameters]`.
    pub(crate) fn var_names(&self) -> Vec<String> {
        let mut v: Vec<String> = self.states.iter().map(|s| s.name.clone()).collect();
        v.extend(self.inputs.iter().cloned());
        v.extend(self.cell_names());
        v.extend(self.parameters.iter().map(|p| p.name.clone()));
        v
    }

    /// The symbols of every Preisach cell, operator by operator.
    fn cell_names(&self) -> Vec<String> {
        self.hysteresis
            .iter()
            .flat_map(|h| (0..h.n_cells()).map(|j| h.cell_name(j)))
            .collect()
    }

    /// What an item is, in words.
    pub(crate) fn what(&self, item: Item) -> String {
        match item {
            Item::Model => format!("model '{}'", self.name),
            Item::State(i) => format!("state '{}'", self.state_name(i)),
            Item::Equation(i) => format!("equation for '{}'", self.state_name(i)),
            Item::Output(i) => format!(
                "output '{}'",
                self.outputs.get(i).map_or("?", |o| o.name.as_str())
            ),
            Item::Parameter(i) => format!(
                "parameter '{}'",
                self.parameters.get(i).map_or("?", |p| p.name.as_str())
            ),
        }
    }

    fn state_name(&self, i: usize) -> &str {
        self.states.get(i).map_or("?", |s| s.name.as_str())
    }

    fn at(&self, item: Item) -> Location {
        Location::new(item, self.what(item))
    }

    /// Check names, dimensions and values (once, before compiling).
    pub fn check(&self) -> PhysicsResult<()> {
        let dim = |item, message: String| PhysicsError::Dimension {
            at: self.at(item),
            message,
        };
        if self.states.is_empty() {
            return Err(dim(Item::Model, "the model has no states".into()));
        }
        if self.outputs.is_empty() {
            return Err(dim(Item::Model, "the model has no outputs".into()));
        }
        if self.equations.len() != self.states.len() {
            return Err(dim(
                Item::Model,
                format!(
                    "{} equations for {} states",
                    self.equations.len(),
                    self.states.len()
                ),
            ));
        }
        self.check_names()?;
        for (i, eq) in self.equations.iter().enumerate() {
            if eq.is_empty() || eq.iter().all(|t| t.trim().is_empty()) {
                return Err(dim(Item::Equation(i), "the state has no equation".into()));
            }
        }
        for (i, o) in self.outputs.iter().enumerate() {
            if o.terms.is_empty() || o.terms.iter().all(|t| t.trim().is_empty()) {
                return Err(dim(Item::Output(i), "the output has no expression".into()));
            }
        }
        self.check_values()
    }

    fn check_names(&self) -> PhysicsResult<()> {
        let mut seen: Vec<(&str, Item)> = vec![];
        let cells = self.cell_names();
        let items = self
            .states
            .iter()
            .enumerate()
            .map(|(i, s)| (s.name.as_str(), Item::State(i), "state"))
            .chain(
                self.inputs
                    .iter()
                    .map(|n| (n.as_str(), Item::Model, "input")),
            )
            .chain(
                cells
                    .iter()
                    .map(|n| (n.as_str(), Item::Model, "Preisach cell")),
            )
            .chain(
                self.parameters
                    .iter()
                    .enumerate()
                    .map(|(i, p)| (p.name.as_str(), Item::Parameter(i), "parameter")),
            );
        for (name, item, kind) in items {
            let bad = |message: String| PhysicsError::Dimension {
                at: self.at(item),
                message,
            };
            let mut chars = name.chars();
            let ok = chars.next().is_some_and(|c| c.is_alphabetic() || c == '_')
                && chars.all(|c| c.is_alphanumeric() || c == '_');
            if !ok {
                return Err(bad(format!(
                    "{kind} name '{name}' is not a symbol (letters, digits, _; not starting with a digit)"
                )));
            }
            if RESERVED.contains(&name) {
                return Err(bad(format!(
                    "{kind} name '{name}' is reserved (an operator or constant of the expression language)"
                )));
            }
            if let Some((_, other)) = seen.iter().find(|(n, _)| *n == name) {
                return Err(bad(format!(
                    "{kind} name '{name}' is used twice (also {})",
                    self.what(*other)
                )));
            }
            seen.push((name, item));
        }
        for (i, o) in self.outputs.iter().enumerate() {
            if self.outputs[..i].iter().any(|p| p.name == o.name) {
                return Err(PhysicsError::Dimension {
                    at: self.at(Item::Output(i)),
                    message: format!("output '{}' is given twice", o.name),
                });
            }
        }
        for h in &self.hysteresis {
            let bad = |message: String| PhysicsError::Dimension {
                at: self.at(Item::Model),
                message: format!("Preisach operator '{}': {message}", h.prefix),
            };
            if !self.states.iter().any(|s| s.name == h.driver) {
                return Err(bad(format!("'{}' is not a state", h.driver)));
            }
            if !(1..=32).contains(&h.levels) || !(1..=16).contains(&h.sub) {
                return Err(bad(format!(
                    "levels must be 1..=32 and sub 1..=16, got {} and {}",
                    h.levels, h.sub
                )));
            }
            if !(h.center.is_finite() && h.half_range.is_finite() && h.half_range > 0.0) {
                return Err(bad(format!(
                    "center must be finite and half_range > 0, got {} and {}",
                    h.center, h.half_range
                )));
            }
        }
        if let Some(d) = &self.input_delay {
            if self.input_delay_index().is_none() {
                return Err(PhysicsError::Dimension {
                    at: self.at(Item::Model),
                    message: format!(
                        "input_delay names '{d}', which is not a parameter (parameters: {})",
                        list(self.parameters.iter().map(|p| p.name.as_str()))
                    ),
                });
            }
        }
        Ok(())
    }

    fn check_values(&self) -> PhysicsResult<()> {
        let val = |item, message: String| PhysicsError::Value {
            at: self.at(item),
            message,
        };
        for (i, p) in self.parameters.iter().enumerate() {
            let item = Item::Parameter(i);
            if !p.value.is_finite() || p.lower.is_nan() || p.upper.is_nan() {
                return Err(val(
                    item,
                    format!("value {} is not a finite number", p.value),
                ));
            }
            if p.lower > p.upper {
                return Err(val(
                    item,
                    format!("min {} exceeds max {}", p.lower, p.upper),
                ));
            }
            if p.value < p.lower || p.value > p.upper {
                return Err(val(
                    item,
                    format!(
                        "value {} is outside its bounds [{}, {}]",
                        p.value, p.lower, p.upper
                    ),
                ));
            }
            if let Some(pr) = p.prior {
                if !(pr.sd > 0.0 && pr.sd.is_finite() && pr.mean.is_finite()) {
                    return Err(val(
                        item,
                        format!("prior needs a finite mean and sd > 0, got {pr:?}"),
                    ));
                }
            }
        }
        for (i, s) in self.states.iter().enumerate() {
            if !s.initial.is_finite() || s.initial < s.lower || s.initial > s.upper {
                return Err(val(
                    Item::State(i),
                    format!(
                        "initial value {} is not finite or outside its bounds [{}, {}]",
                        s.initial, s.lower, s.upper
                    ),
                ));
            }
        }
        if !(1..=10_000).contains(&self.substeps) {
            return Err(val(
                Item::Model,
                format!("substeps must be 1..=10000, got {}", self.substeps),
            ));
        }
        if let Some(ts) = self.sample_time {
            if !(ts > 0.0 && ts.is_finite()) {
                return Err(val(
                    Item::Model,
                    format!("sample_time must be positive, got {ts}"),
                ));
            }
        }
        Ok(())
    }

    /// Compile the equations (after [`check`](Self::check)).
    pub(crate) fn compile(&self) -> PhysicsResult<Compiled> {
        self.check()?;
        let names = self.var_names();
        // the Preisach cells are held inputs of the tapes
        let (n, nu) = (self.states.len(), self.inputs.len() + self.n_cells());
        let known = format!(
            "states: {}; inputs: {}; parameters: {}",
            list(self.states.iter().map(|s| s.name.as_str())),
            list(self.inputs.iter().map(String::as_str)),
            list(self.parameters.iter().map(|p| p.name.as_str()))
        );
        let build = |lists: Vec<(Item, &Vec<String>)>| -> PhysicsResult<(Tape, Vec<Vec<usize>>)> {
            let mut b = TapeBuilder::new(&names, n, n + nu);
            let mut outs = Vec::with_capacity(lists.len());
            let mut used = Vec::with_capacity(lists.len());
            for (item, terms) in lists {
                let mut recs: Vec<Rec> = vec![];
                let mut vars: Vec<usize> = vec![];
                for t in terms.iter().filter(|t| !t.trim().is_empty()) {
                    let (r, syms) = b.expr(t).map_err(|e| match e {
                        ExprError::Syntax(message) => PhysicsError::Syntax {
                            at: self.at(item),
                            expr: t.clone(),
                            message,
                        },
                        ExprError::Unknown(symbol) => PhysicsError::UnknownSymbol {
                            at: self.at(item),
                            expr: t.clone(),
                            symbol,
                            known: known.clone(),
                        },
                    })?;
                    recs.push(r);
                    for s in syms {
                        if let Some(i) = names.iter().position(|x| *x == s) {
                            if !vars.contains(&i) {
                                vars.push(i);
                            }
                        }
                    }
                }
                outs.push(b.sum(&recs));
                vars.sort_unstable();
                used.push(vars);
            }
            Ok((b.finish(&outs), used))
        };
        let (f, f_used) = build(
            self.equations
                .iter()
                .enumerate()
                .map(|(i, e)| (Item::Equation(i), e))
                .collect(),
        )?;
        let (g, g_used) = build(
            self.outputs
                .iter()
                .enumerate()
                .map(|(i, o)| (Item::Output(i), &o.terms))
                .collect(),
        )?;
        Ok(Compiled {
            f,
            g,
            n,
            nu,
            np: self.parameters.len(),
            f_used,
            g_used,
            range: self.states.iter().map(|s| (s.lower, s.upper)).collect(),
            delay: self.input_delay_index(),
            ops: self.compile_hysteresis()?,
        })
    }

    /// The relay cells of every Preisach operator and their input slots.
    fn compile_hysteresis(&self) -> PhysicsResult<Vec<CompiledHysteresis>> {
        let mut slot = self.states.len() + self.inputs.len();
        let mut out = vec![];
        for h in &self.hysteresis {
            let cells = gb_preisach::RelayCells::uniform(h.levels, 1.0, h.sub).map_err(|e| {
                PhysicsError::Dimension {
                    at: self.at(Item::Model),
                    message: format!("Preisach operator '{}': {e}", h.prefix),
                }
            })?;
            out.push(CompiledHysteresis {
                driver: self
                    .states
                    .iter()
                    .position(|s| s.name == h.driver)
                    .unwrap_or(0),
                slot,
                center: h.center,
                inv_half: 1.0 / h.half_range,
                cells,
            });
            slot += h.n_cells();
        }
        Ok(out)
    }

    /// The text of an equation or output (terms joined by ` + `).
    pub(crate) fn text(&self, item: Item) -> String {
        let terms = match item {
            Item::Equation(i) => self.equations.get(i),
            Item::Output(i) => self.outputs.get(i).map(|o| &o.terms),
            _ => None,
        };
        terms.map_or_else(String::new, |t| t.join(" + "))
    }

    /// The parameter values of the spec.
    pub(crate) fn theta0(&self) -> Vec<f64> {
        self.parameters.iter().map(|p| p.value).collect()
    }

    /// The initial states of the spec.
    pub(crate) fn x0(&self) -> Vec<f64> {
        self.states.iter().map(|s| s.initial).collect()
    }
}

fn list<'a>(it: impl Iterator<Item = &'a str>) -> String {
    let v: Vec<&str> = it.collect();
    if v.is_empty() {
        "none".into()
    } else {
        v.join(", ")
    }
}

/// The compiled model: the tapes of `f` (one output per state) and `g`
/// (one per output) over the slots `[states | inputs | parameters]`.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Compiled {
    pub(crate) f: Tape,
    pub(crate) g: Tape,
    pub(crate) n: usize,
    pub(crate) nu: usize,
    pub(crate) np: usize,
    /// Variables each state equation uses.
    pub(crate) f_used: Vec<Vec<usize>>,
    /// Variables each output uses.
    pub(crate) g_used: Vec<Vec<usize>>,
    /// The physical range `[min, max]` of each state: the simulation
    /// keeps the state inside it.
    pub(crate) range: Vec<(f64, f64)>,
    /// The index of the input-delay parameter, when there is one.
    pub(crate) delay: Option<usize>,
    /// The Preisach operators on states.
    pub(crate) ops: Vec<CompiledHysteresis>,
}

/// A compiled [`StateHysteresis`]: cells on the unit grid, driven by
/// `(x[driver] − center)/half_range`, their outputs in the input slots
/// from `slot`.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct CompiledHysteresis {
    pub(crate) driver: usize,
    pub(crate) slot: usize,
    pub(crate) center: f64,
    pub(crate) inv_half: f64,
    pub(crate) cells: gb_preisach::RelayCells,
}

impl CompiledHysteresis {
    /// The driver in grid units.
    #[inline]
    pub(crate) fn grid_input(&self, x: &[f64]) -> f64 {
        (x[self.driver] - self.center) * self.inv_half
    }
}
impl Compiled {
    /// Check that every equation and output is finite at `(x, u, θ)`;
    /// the error names the expression and the values of its symbols.
    pub(crate) fn check_point(
        &self,
        spec: &PhysicsSpec,
        x: &[f64],
        u: &[f64],
        theta: &[f64],
    ) -> PhysicsResult<()> {
        let names = spec.var_names();
        let mut vals = x.to_vec();
        vals.extend_from_slice(u);
        for op in &self.ops {
            let st = op.cells.relay_states(op.grid_input(x));
            let mut cols = vec![0.0; op.cells.n_cells()];
            op.cells.columns(&st, &mut cols);
            vals.extend_from_slice(&cols);
        }
        vals.extend_from_slice(theta);
        for (tape, used, is_f) in [
            (&self.f, &self.f_used, true),
            (&self.g, &self.g_used, false),
        ] {
            let mut s = tape.slots(0);
            s.v[..vals.len()].copy_from_slice(&vals);
            tape.run_pre(&mut s);
            tape.run_input(&mut s);
            tape.run(&mut s);
            for i in 0..tape.n_outputs() {
                let v = tape.out(&s, i);
                if !v.is_finite() {
                    let item = if is_f {
                        Item::Equation(i)
                    } else {
                        Item::Output(i)
                    };
                    let point = used[i]
                        .iter()
                        .map(|&k| format!("{} = {}", names[k], vals[k]))
                        .collect::<Vec<_>>()
                        .join(", ");
                    return Err(PhysicsError::NonFinite {
                        at: spec.at(item),
                        expr: spec.text(item),
                        value: v,
                        point,
                    });
                }
            }
        }
        Ok(())
    }
}
