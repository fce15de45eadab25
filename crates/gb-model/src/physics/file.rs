//! Model files: the engineer's model in TOML (read with the `toml` crate
//! and serde; expressions parsed by exmex). Errors name the file, the line
//! (from toml's spans), the expression and the symbol.
//!
//! ```toml
//! name = "mass-spring-damper"
//! inputs = ["F"]             # data columns, in order
//! substeps = 4               # RK4 steps per sample (input held: zero-order hold)
//! sample_time = 0.05         # s; optional when the data have a uniform t column
//! # input_delay = "td"       # optional: the parameter that is the input delay [s]
//!
//! [states]                   # in order; initial value fixed, or free = estimated
//! x = { initial = 0.0 }
//! v = { initial = 0.0, free = true }
//!
//! [parameters]               # start value, bounds, fixed, Gaussian prior
//! m = { value = 1.5, min = 0.1, max = 10.0 }
//! c = { value = 0.3, min = 0.0 }
//! k = { value = 2.0, min = 0.0, prior = { mean = 4.0, sd = 1.0 } }
//!
//! [equations]                # dx/dt: an expression or a list of additive terms
//! x = "v"
//! v = ["F/m", "-c/m*v", "-k/m*x"]
//!
//! [outputs]                  # data column = g(x, u, θ)
//! y = "x"
//!
//! # optional: a Preisach operator on a state (cells P0, P1, … in the
//! # equations); with `into`, free weights w0, w1, … (start 0, with
//! # `prior_sd` a Gaussian prior N(0, prior_sd²) each) and the force
//! # w0*P0 + w1*P1 + … are added to the equation of that state
//! # [preisach]
//! # P = { state = "x", min = -0.1, max = 0.1, levels = 6, sub = 4, into = "v", weights = "w" }
//! ```
use super::error::{Item, Location, PhysicsError, PhysicsResult};
use super::identify::PhysicsFitParams;
use super::model::PhysicsModel;
use super::spec::{Output, Parameter, PhysicsSpec, Prior, State, StateHysteresis};
use gb_core::{Identify, Observer, Records};
use serde::de::{self, Deserializer, MapAccess, SeqAccess, Visitor};
use serde::Deserialize;
use std::fmt;
use std::marker::PhantomData;
use std::path::Path;
use toml::Spanned;

/// A TOML table in document order.
struct Ordered<V>(Vec<(String, V)>);

impl<'de, V: Deserialize<'de>> Deserialize<'de> for Ordered<V> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Vis<V>(PhantomData<V>);
        impl<'de, V: Deserialize<'de>> Visitor<'de> for Vis<V> {
            type Value = Ordered<V>;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("a table")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut m: A) -> Result<Self::Value, A::Error> {
                let mut v = vec![];
                while let Some(e) = m.next_entry::<String, V>()? {
                    v.push(e);
                }
                Ok(Ordered(v))
            }
        }
        d.deserialize_map(Vis(PhantomData))
    }
}

/// An expression or a list of additive terms.
struct Terms(Vec<String>);

impl<'de> Deserialize<'de> for Terms {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Vis;
        impl<'de> Visitor<'de> for Vis {
            type Value = Terms;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("an expression (string) or a list of expressions (additive terms)")
            }
            fn visit_str<E: de::Error>(self, s: &str) -> Result<Terms, E> {
                Ok(Terms(vec![s.to_string()]))
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut a: A) -> Result<Terms, A::Error> {
                let mut v = vec![];
                while let Some(s) = a.next_element::<String>()? {
                    v.push(s);
                }
                Ok(Terms(v))
            }
        }
        d.deserialize_any(Vis)
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct StateDoc {
    initial: Option<f64>,
    free: Option<bool>,
    min: Option<f64>,
    max: Option<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PriorDoc {
    mean: f64,
    sd: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PreisachDoc {
    state: String,
    min: f64,
    max: f64,
    levels: Option<usize>,
    sub: Option<usize>,
    into: Option<String>,
    weights: Option<String>,
    prior_sd: Option<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ParamDoc {
    value: f64,
    min: Option<f64>,
    max: Option<f64>,
    fixed: Option<bool>,
    prior: Option<PriorDoc>,
}

type Table<V> = Spanned<Ordered<Spanned<V>>>;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Doc {
    name: Option<String>,
    inputs: Option<Vec<String>>,
    substeps: Option<Spanned<i64>>,
    sample_time: Option<Spanned<f64>>,
    input_delay: Option<Spanned<String>>,
    states: Option<Table<StateDoc>>,
    parameters: Option<Table<ParamDoc>>,
    equations: Option<Table<Terms>>,
    outputs: Option<Table<Terms>>,
    preisach: Option<Table<PreisachDoc>>,
}

/// Lines of the items of a model file.
#[derive(Debug, Clone, Default, PartialEq)]
struct Lines {
    model: Option<usize>,
    states: Vec<usize>,
    equations: Vec<usize>,
    outputs: Vec<usize>,
    parameters: Vec<usize>,
}

/// A model file: its name, text, the model and where each item is.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelFile {
    /// The file name (labels errors).
    pub name: String,
    /// The file's text.
    pub text: String,
    /// The model it defines.
    pub spec: PhysicsSpec,
    lines: Lines,
}

fn line_of(text: &str, offset: usize) -> usize {
    text.as_bytes()[..offset.min(text.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

impl ModelFile {
    /// Read and check a model file.
    pub fn read(path: &Path) -> PhysicsResult<Self> {
        let text = std::fs::read_to_string(path).map_err(|source| gb_core::CoreError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Parse and check a model file's text (names, values, and every
    /// expression compiles); `name` labels errors.
    pub fn parse(text: &str, name: &str) -> PhysicsResult<Self> {
        let doc: Doc = toml::from_str(text).map_err(|e| PhysicsError::Toml {
            file: name.into(),
            line: e.span().map_or(1, |s| line_of(text, s.start)),
            message: e.message().trim().to_string(),
        })?;
        let at = |offset: usize, item: Item, what: String| Location {
            file: Some(name.into()),
            line: Some(line_of(text, offset)),
            item,
            what,
        };
        let missing = |table: &str| PhysicsError::Dimension {
            at: Location {
                file: Some(name.into()),
                line: None,
                item: Item::Model,
                what: "model".into(),
            },
            message: format!("no [{table}] table"),
        };
        let mut lines = Lines::default();
        let mut spec = PhysicsSpec::new(doc.name.as_deref().unwrap_or("model"));
        spec.inputs = doc.inputs.unwrap_or_default();
        if let Some(s) = doc.substeps {
            lines.model = Some(line_of(text, s.span().start));
            spec.substeps = usize::try_from(*s.get_ref()).unwrap_or(0);
        }
        spec.sample_time = doc.sample_time.map(|s| *s.get_ref());
        let states = doc.states.ok_or_else(|| missing("states"))?;
        for (n, s) in &states.get_ref().0 {
            lines.states.push(line_of(text, s.span().start));
            let d = s.get_ref();
            spec.states.push(State {
                name: n.clone(),
                initial: d.initial.unwrap_or(0.0),
                free: d.free.unwrap_or(false),
                lower: d.min.unwrap_or(f64::NEG_INFINITY),
                upper: d.max.unwrap_or(f64::INFINITY),
            });
        }
        for (n, p) in doc.parameters.map(|t| t.into_inner().0).unwrap_or_default() {
            lines.parameters.push(line_of(text, p.span().start));
            let d = p.into_inner();
            spec.parameters.push(Parameter {
                name: n,
                value: d.value,
                lower: d.min.unwrap_or(f64::NEG_INFINITY),
                upper: d.max.unwrap_or(f64::INFINITY),
                fixed: d.fixed.unwrap_or(false),
                prior: d.prior.map(|p| Prior {
                    mean: p.mean,
                    sd: p.sd,
                }),
            });
        }
        let eqs = doc
            .equations
            .ok_or_else(|| missing("equations"))?
            .into_inner()
            .0;
        for (n, e) in &eqs {
            if !spec.states.iter().any(|s| &s.name == n) {
                return Err(PhysicsError::Dimension {
                    at: at(e.span().start, Item::Model, format!("equation for '{n}'")),
                    message: format!("no state named '{n}' in [states]"),
                });
            }
        }
        for (i, s) in spec.states.iter().enumerate() {
            let Some((_, e)) = eqs.iter().find(|(n, _)| *n == s.name) else {
                return Err(PhysicsError::Dimension {
                    at: at(
                        states.get_ref().0[i].1.span().start,
                        Item::State(i),
                        format!("state '{}'", s.name),
                    ),
                    message: "the state has no equation in [equations]".into(),
                });
            };
            lines.equations.push(line_of(text, e.span().start));
            spec.equations.push(e.get_ref().0.clone());
        }
        for (n, o) in doc
            .outputs
            .ok_or_else(|| missing("outputs"))?
            .into_inner()
            .0
        {
            lines.outputs.push(line_of(text, o.span().start));
            spec.outputs.push(Output {
                name: n,
                terms: o.into_inner().0,
            });
        }
        for (prefix, h) in doc.preisach.map(|t| t.into_inner().0).unwrap_or_default() {
            let start = h.span().start;
            let d = h.into_inner();
            let bad = |message: String| PhysicsError::Dimension {
                at: at(start, Item::Model, format!("Preisach operator '{prefix}'")),
                message,
            };
            if !(d.min.is_finite() && d.max.is_finite() && d.max > d.min) {
                return Err(bad(format!("needs min < max, got {} and {}", d.min, d.max)));
            }
            let op = StateHysteresis {
                driver: d.state.clone(),
                prefix: prefix.clone(),
                levels: d.levels.unwrap_or(6),
                sub: d.sub.unwrap_or(4),
                center: 0.5 * (d.min + d.max),
                half_range: 0.5 * (d.max - d.min),
            };
            if let Some(into) = &d.into {
                let i = spec
                    .states
                    .iter()
                    .position(|x| &x.name == into)
                    .ok_or_else(|| bad(format!("into = '{into}' is not a state")))?;
                let w = d.weights.clone().unwrap_or_else(|| format!("w{prefix}"));
                for j in 0..op.n_cells() {
                    lines.parameters.push(line_of(text, start));
                    let mut p = Parameter::new(&format!("{w}{j}"), 0.0);
                    if let Some(sd) = d.prior_sd {
                        p = p.prior(0.0, sd);
                    }
                    spec.parameters.push(p);
                    spec.equations[i].push(format!("{w}{j}*{}", op.cell_name(j)));
                }
            } else if d.weights.is_some() || d.prior_sd.is_some() {
                return Err(bad(
                    "weights and prior_sd need into = the state whose equation gets the force"
                        .into(),
                ));
            }
            spec.hysteresis.push(op);
        }
        if let Some(d) = doc.input_delay {
            let name_ = d.get_ref().clone();
            if !spec.parameters.iter().any(|p| p.name == name_) {
                return Err(PhysicsError::Dimension {
                    at: at(d.span().start, Item::Model, "input_delay".into()),
                    message: format!("input_delay names '{name_}', which is not in [parameters]"),
                });
            }
            spec.input_delay = Some(name_);
        }
        let f = Self {
            name: name.into(),
            text: text.into(),
            spec,
            lines,
        };
        // names, values and every expression (exmex), located
        f.spec.compile().map_err(|e| f.locate(e))?;
        Ok(f)
    }

    /// Put the file and line on an error about an item of this file.
    pub fn locate(&self, mut e: PhysicsError) -> PhysicsError {
        if let Some(at) = e.location_mut() {
            let l = &self.lines;
            let line = match at.item {
                Item::Model => l.model,
                Item::State(i) => l.states.get(i).copied(),
                Item::Equation(i) => l.equations.get(i).copied(),
                Item::Output(i) => l.outputs.get(i).copied(),
                Item::Parameter(i) => l.parameters.get(i).copied(),
            };
            at.file = Some(self.name.clone());
            at.line = at.line.or(line);
        }
        e
    }

    /// The model with its start values (compiled; errors located).
    pub fn model(&self) -> PhysicsResult<PhysicsModel> {
        PhysicsModel::new(self.spec.clone())
            .map(|m| m.with_source(self.text.clone()))
            .map_err(|e| self.locate(e))
    }

    /// Fit the model to `data` (whose inputs and output are the model's);
    /// errors name the file and line.
    pub fn fit(&self, data: &Records, obs: &dyn Observer) -> PhysicsResult<PhysicsModel> {
        PhysicsFitParams::new(self.spec.clone())
            .source(self.text.clone())
            .check()
            .map_err(|e| self.locate(e))?
            .identify(data, obs)
            .map_err(|e| self.locate(e))
    }

    /// As [`fit`](Self::fit), keeping the better of the direct fit and the
    /// fit continued over growing prefixes
    /// ([`PhysicsFit::identify_growing`]).
    pub fn fit_growing(&self, data: &Records, obs: &dyn Observer) -> PhysicsResult<PhysicsModel> {
        self.fit_growing_outputs(std::slice::from_ref(data), obs)
    }

    /// As [`fit_growing`](Self::fit_growing) for a model of several
    /// outputs: `data[o]` holds the records of output `o` (the file's
    /// `[outputs]` order), fitted jointly
    /// ([`PhysicsFit::identify_outputs`](super::PhysicsFit::identify_outputs)).
    pub fn fit_growing_outputs(
        &self,
        data: &[Records],
        obs: &dyn Observer,
    ) -> PhysicsResult<PhysicsModel> {
        PhysicsFitParams::new(self.spec.clone())
            .source(self.text.clone())
            .check()
            .map_err(|e| self.locate(e))?
            .identify_growing_outputs(data, obs)
            .map_err(|e| self.locate(e))
    }
}
