//! Named recipes that build and fit a gb-model structure from data alone
//! (every number comes from the data or the caller).
use crate::error::Result as ModelResult;
use crate::identify::OeParams;
use crate::SparseStateSpace;
use gb_core::metrics;

/// The hidden-state model the diagnosis offers when input–output
/// extensions leave a named cause unexplained:
///
/// * `hysteresis` with one input and an oscillating best linear model: the
///   mechanical structure with a hidden restoring force z (`ż = f(v, z)`,
///   Bouc-Wen shape; [`hysteretic_mechanical_start`](crate::hysteretic_mechanical_start)),
///   4 sub-steps per sample, 8 when the fit with 4 improves on the linear
///   model by less than 10 % (symplectic Euler needs sub-steps to follow
///   the linear model), wavelet levels 1–2;
/// * otherwise the black-box start of [`fit_state_space`](crate::fit_state_space)
///   with `order` states and, with `hysteresis`, a Preisach component of
///   the first input with a wavelet Everett function.
///
/// `names`: the inputs' and the output's names.
pub fn fit_hidden_state(
    inputs: &[Vec<f64>],
    y: &[f64],
    order: usize,
    hysteresis: bool,
    names: Vec<String>,
) -> ModelResult<SparseStateSpace> {
    let silent = crate::Silent;
    if hysteresis && inputs.len() == 1 {
        if let Some(m) = mechanical(inputs, y, &names) {
            return Ok(m);
        }
    }
    Ok(crate::fit_state_space(inputs, y, order, hysteresis, names, &silent)?.0)
}

/// The mechanical hysteretic structure with the sub-step retry; `None` when
/// it cannot be built or fitted.
fn mechanical(inputs: &[Vec<f64>], y: &[f64], names: &[String]) -> Option<SparseStateSpace> {
    let silent = crate::Silent;
    let u = &inputs[0];
    let err = |m: &SparseStateSpace| -> f64 {
        m.simulate(inputs)
            .ok()
            .and_then(|s| metrics::nrmse(y, &s).ok())
            .filter(|e| e.is_finite())
            .unwrap_or(f64::INFINITY)
    };
    let mut best: Option<(SparseStateSpace, f64)> = None;
    for substeps in [4, 8] {
        let Ok((mut s0, lin)) = crate::hysteretic_mechanical_start(u, y, 0..y.len(), 1.0, substeps)
        else {
            break;
        };
        s0.signal_names = names.to_vec();
        let e_lin = err(&lin);
        let Ok((m, _)) = OeParams::new()
            .max_iter(30)
            .coarse_level(1)
            .max_level(2)
            .max_new(24)
            .check()
            .and_then(|p| p.fit(s0, inputs, y, &silent))
        else {
            break;
        };
        let e = err(&m);
        // retry with 8 sub-steps only when stuck near the linear model
        // (less than 10 % better; not when it is not better at all)
        let retry = e < e_lin && e >= 0.9 * e_lin;
        if best.as_ref().is_none_or(|b| e < b.1) {
            best = Some((m, e));
        }
        if !retry {
            break;
        }
    }
    best.map(|(m, _)| m)
}

/// A finer fit of a hidden-state model `current` found by
/// [`fit_hidden_state`] (more capacity for the cause it answered):
///
/// * the mechanical structure (`hysteresis`, one input, 3 states): fitted
///   again from its linear start with 8 sub-steps per sample (the symplectic
///   Euler step of a lightly damped resonance is accurate to a few 10⁻⁶ of
///   the response only on a finer grid) and wavelet levels 1–4, up to 40
///   new coefficients per level, 40 Levenberg–Marquardt iterations per
///   stage;
/// * otherwise `current` refined from its own coefficients with one more
///   wavelet level (1–4).
///
/// Errors when the fit fails; the caller judges the result on held-out
/// data.
pub fn refine_hidden_state(
    current: &SparseStateSpace,
    inputs: &[Vec<f64>],
    y: &[f64],
    hysteresis: bool,
) -> ModelResult<SparseStateSpace> {
    let silent = crate::Silent;
    if hysteresis && inputs.len() == 1 && current.n_states == 3 {
        let (mut s0, _) = crate::hysteretic_mechanical_start(&inputs[0], y, 0..y.len(), 1.0, 8)?;
        s0.signal_names = current.signal_names.clone();
        let (m, _) = OeParams::new()
            .max_iter(40)
            .coarse_level(1)
            .max_level(4)
            .max_new(40)
            .check()?
            .fit(s0, inputs, y, &silent)?;
        return Ok(m);
    }
    let (m, _) = OeParams::new().coarse_level(1).max_level(4).check()?.fit(
        current.clone(),
        inputs,
        y,
        &silent,
    )?;
    Ok(m)
}

use crate::operators::{operator_channels, InputOperator, OperatorInputsModel};
use gb_core::{CoreError, FittedModel, ModelSpec, NoiseModel, Observer, Options, Record, Records};

/// What a recipe fitted, with lines worth printing.
#[derive(Debug, Clone)]
pub struct Fitted {
    /// The model.
    pub model: FittedModel,
    /// Facts about the fit (chosen structure, scores), one per line.
    pub notes: Vec<String>,
}

/// Fits one recipe's spec on records.
pub type RecipeFit = fn(&ModelSpec, &Records, &dyn Observer) -> Result<Fitted, CoreError>;

/// A named way to fit a model class from data: `greybox fit --model SPEC`.
#[derive(Debug, Clone, Copy)]
pub struct Recipe {
    /// The spec name.
    pub name: &'static str,
    /// The components it accepts.
    pub components: &'static [&'static str],
    /// One line for `--help`.
    pub summary: &'static str,
    /// Its options: `key=default: meaning`.
    pub options: &'static [&'static str],
    /// The fit.
    pub fit: RecipeFit,
}

/// Every recipe, in the order `--help` lists them.
pub static RECIPES: &[Recipe] = &[
    Recipe {
        name: "linear",
        components: &["preisach", "feedback", "student-t"],
        summary: "linear output-error model of order n (+preisach: play-operator and discrete Preisach columns; +feedback: a static piecewise-linear map of the simulated output fed back into the dynamics, a nonlinear spring or friction; +student-t: heavy-tailed noise, robust fit)",
        options: &[
            "order=2: n = n_a = n_b",
            "delay=1: input dead time, one or one per input (a/b)",
            "integrating=false: model the increments of an integrating output (a pole at 1: force -> position), trained for the error of their sum",
        ],
        fit: fit_io_network,
    },
    Recipe {
        name: "lmn",
        components: &["preisach", "feedback", "student-t"],
        summary: "LOLIMOT local model network on the order-n regressors; any tree option selects the full tree network (HILOMOT/oblique, several records allowed)",
        options: &[
            "order=2", "delay=1", "integrating=false: the increments summed (not with tree options)", "weights=tree: gauss|tree", "splits=axis: axis|oblique",
            "prune=false", "focus=simulation: simulation|prediction", "max_leaves=20",
            "degree=1: 1..3", "dead_time=1 (list)", "input_lags=order (list)", "output_lags=order",
            "criterion=aicc: aicc|bic", "partition=all: all|y1",
        ],
        fit: fit_lmn,
    },
    Recipe {
        name: "wiener-hammerstein",
        components: &[],
        summary: "static local model network between two linear filters, from the best linear approximation (one input)",
        options: &["max_leaves=16: local models of the static network"],
        fit: fit_wiener_hammerstein,
    },
    Recipe {
        name: "lmn-state-space",
        components: &[],
        summary: "state-space local model network: hidden states, square-root basis, learned state bounds",
        options: &["order=2: states", "max_leaves=2: most local models (1..=8, chosen on a hold-out)", "output_max: known upper limit of the output"],
        fit: fit_ss_lmn,
    },
    Recipe {
        name: "state-space",
        components: &["preisach", "hysteresis", "damper"],
        summary: "wavelet-sparse state space (gb-model): +preisach a Preisach component with a wavelet Everett function; +hysteresis a hidden hysteretic state with a wavelet law; +damper the Spencer-like MR damper structure (inputs displacement, velocity, voltage [, acceleration])",
        options: &["order=2: states", "resonances: +damper, start frequencies of rig resonances in Hz (a/b)", "sample_rate: +damper, Hz (default: the record's)", "ridge: +damper, Tikhonov weight (default: 0 or 1000, chosen on the last 20 %)"],
        fit: fit_sparse_state_space,
    },
    Recipe {
        name: "hammerstein",
        components: &[],
        summary: "Hammerstein: static maps of the inputs (cubic polynomial, cubic spline or piecewise linear, knots at quantiles, chosen on a hold-out) before linear dynamics of order n, trained output-error",
        options: &["order=2", DELAY_CHOICES, "maps=1: which inputs get a map, 0 or 1 per input (list)", MAP_OPTION],
        fit: fit_block,
    },
    Recipe {
        name: "wiener",
        components: &[],
        summary: "Wiener: linear dynamics of order n, then a static map of the output (cubic polynomial, cubic spline or piecewise linear, chosen on a hold-out), trained output-error",
        options: &["order=2", DELAY_CHOICES, MAP_OPTION],
        fit: fit_block,
    },
    Recipe {
        name: "poly",
        components: &[],
        summary: "polynomial NARX/NOE: terms of degree <= 3 in lagged outputs and inputs chosen by FROLS (error reduction ratio), the number of terms on a hold-out, refined for the simulation error",
        options: &["order=2: output lags", "input_lags=order (list; the operator channels follow the inputs)", "delay=1 (list)", "degree=3: 1..3", "max_terms=15", "focus=simulation: simulation|prediction", "stops: inputs (1-based, list) whose stop operators (hysteresis) are further inputs", "stop_widths=0.03/0.1/0.3: their half-widths in standard deviations of the input", "lowpass: inputs (1-based, list) whose first-order low-pass is a further input", "lowpass_samples=10: its time constants in samples (list)"],
        fit: fit_poly,
    },
];

/// The recipe of `name`.
pub fn recipe(name: &str) -> Option<&'static Recipe> {
    RECIPES.iter().find(|r| r.name == name)
}

/// The recipe of `spec`, after checking its name and components (before any
/// data is read).
pub fn check_spec(spec: &ModelSpec) -> Result<&'static Recipe, CoreError> {
    let r = recipe(&spec.name).ok_or_else(|| {
        CoreError::Unsupported(format!(
            "unknown model spec '{spec}' (known models: {})",
            RECIPES
                .iter()
                .map(|r| r.name)
                .collect::<Vec<_>>()
                .join(", ")
        ))
    })?;
    if let Some(c) = spec
        .components
        .iter()
        .find(|c| !r.components.contains(&c.as_str()))
    {
        return Err(CoreError::Unsupported(format!(
            "unknown model spec '{spec}': no component '{c}' for {} (known: {})",
            r.name,
            if r.components.is_empty() {
                "none".to_string()
            } else {
                r.components.join(", ")
            }
        )));
    }
    Ok(r)
}

/// Fit `spec` on `data`: the recipe of its name, after checking its
/// components.
pub fn fit(spec: &ModelSpec, data: &Records, obs: &dyn Observer) -> Result<Fitted, CoreError> {
    (check_spec(spec)?.fit)(spec, data, obs)
}

/// The recipes as help text.
pub fn help() -> String {
    let mut s = String::from("Model SPEC = NAME[+COMPONENT...][:KEY=VALUE,...] (lists: a/b/c)\n");
    for r in RECIPES {
        let comps = r
            .components
            .iter()
            .map(|c| format!("[+{c}]"))
            .collect::<String>();
        s.push_str(&format!(
            "  {}{comps}: {}\n      options: {}\n",
            r.name,
            r.summary,
            r.options.join("; ")
        ));
    }
    s
}

fn one_record<'a>(data: &'a Records, what: &str) -> Result<&'a Record, CoreError> {
    if data.len() != 1 {
        return Err(CoreError::InvalidArgument(format!(
            "{what} is fitted on one record, got {}",
            data.len()
        )));
    }
    Ok(data.first())
}

/// Gaussian noise of the free-run residuals `y − ŷ` from sample `k0` on.
fn residual_noise(y: &[f64], sim: &[f64], k0: usize) -> NoiseModel {
    let k0 = k0.min(y.len());
    let res: Vec<f64> = y[k0..].iter().zip(&sim[k0..]).map(|(a, b)| a - b).collect();
    NoiseModel::gaussian(&res)
}

fn wrap(
    data: &Record,
    dynamics: Box<dyn gb_core::DynamicModel>,
    noise: NoiseModel,
    notes: Vec<String>,
) -> Result<Fitted, CoreError> {
    let mut model = FittedModel::new(
        data.input_names.clone(),
        vec![data.output_name.clone()],
        dynamics,
        noise,
    )?;
    model.sample_time = data.sample_time;
    Ok(Fitted { model, notes })
}

/// The input operators a spec names (`stops`, `stop_widths`, `lowpass`,
/// `lowpass_samples`; half-widths in standard deviations of the input over
/// `data`) and the spec without those options.
fn input_operators(
    spec: &ModelSpec,
    data: &Records,
) -> Result<(Vec<InputOperator>, ModelSpec), CoreError> {
    const KEYS: [&str; 4] = ["stops", "stop_widths", "lowpass", "lowpass_samples"];
    const POLY_KEYS: [&str; 6] = gb_lmn::poly::SPEC_OPTIONS;
    if let Some((k, _)) = spec
        .options
        .iter()
        .find(|(k, _)| !KEYS.contains(&k.as_str()) && !POLY_KEYS.contains(&k.as_str()))
    {
        return Err(CoreError::InvalidArgument(format!(
            "model spec '{spec}': unknown option '{k}' (options here: {}, {})",
            POLY_KEYS.join(", "),
            KEYS.join(", ")
        )));
    }
    let mut o = spec.options();
    let ni = data.first().n_inputs();
    let indices = |key: &str| -> Result<Vec<usize>, CoreError> {
        let Some(v) = spec.option(key) else {
            return Ok(vec![]);
        };
        v.split('/')
            .map(|x| {
                x.trim()
                    .parse::<usize>()
                    .ok()
                    .filter(|j| (1..=ni).contains(j))
            })
            .map(|j| j.map(|j| j - 1))
            .collect::<Option<Vec<usize>>>()
            .ok_or_else(|| {
                CoreError::InvalidArgument(format!(
                    "model spec '{spec}': {key}={v}: input numbers in 1..={ni}, separated by /"
                ))
            })
    };
    let stops = indices("stops")?;
    let lowpass = indices("lowpass")?;
    let mut widths = o.f64_list("stop_widths")?;
    if widths.is_empty() {
        widths = vec![0.03, 0.1, 0.3];
    }
    let mut taus = o.f64_list("lowpass_samples")?;
    if taus.is_empty() {
        taus = vec![10.0];
    }
    let mut ops = vec![];
    for &j in &stops {
        let all: Vec<f64> = data.iter().flat_map(|r| r.inputs[j].clone()).collect();
        let sd = metrics::std(&all);
        if !(sd > 0.0 && sd.is_finite()) {
            return Err(CoreError::InvalidArgument(format!(
                "model spec '{spec}': stops on input '{}', which is constant",
                data.first().input_names[j]
            )));
        }
        ops.extend(widths.iter().map(|w| InputOperator::Stop {
            input: j,
            half_width: w * sd,
        }));
    }
    for &j in &lowpass {
        ops.extend(taus.iter().map(|t| InputOperator::LowPass {
            input: j,
            gain: 1.0 - (-1.0 / t).exp(),
        }));
    }
    let rest = ModelSpec {
        options: spec
            .options
            .iter()
            .filter(|(k, _)| !KEYS.contains(&k.as_str()))
            .cloned()
            .collect(),
        ..spec.clone()
    };
    Ok((ops, rest))
}

/// `poly`, with input operators when the spec names some: the polynomial
/// on the measured inputs followed by the operator channels, behind an
/// [`OperatorInputsModel`].
fn fit_poly(spec: &ModelSpec, data: &Records, obs: &dyn Observer) -> Result<Fitted, CoreError> {
    let (ops, rest) = input_operators(spec, data)?;
    if ops.is_empty() {
        return gb_lmn::poly::fit_spec(spec, data, obs)
            .map(|(model, notes)| Fitted { model, notes });
    }
    let augmented = data
        .iter()
        .map(|r| {
            let mut a = r.clone();
            a.inputs.extend(operator_channels(&ops, &r.inputs));
            a.input_names
                .extend(ops.iter().map(|op| op.name(&r.input_names)));
            a
        })
        .collect();
    let (fitted, notes) = gb_lmn::poly::fit_spec(&rest, &Records::new(augmented)?, obs)?;
    let d = data.first();
    let dynamics = OperatorInputsModel::new(ops, d.n_inputs(), fitted.dynamics)?;
    let mut model = FittedModel::new(
        d.input_names.clone(),
        fitted.output_names,
        Box::new(dynamics),
        fitted.noise,
    )?;
    model.sample_time = fitted.sample_time;
    Ok(Fitted { model, notes })
}

/// `linear` and `lmn` without tree options: the input–output network.
fn fit_io_network(
    spec: &ModelSpec,
    data: &Records,
    _obs: &dyn Observer,
) -> Result<Fitted, CoreError> {
    let mut o = spec.options();
    let d = one_record(data, "an input-output network")?;
    let order = o.usize("order", 2, 1, gb_lmn::MAX_IO_ORDER)?;
    let delay = o.usize_list("delay", d.n_inputs(), 1, 0, 64)?;
    let integrating = o.flag("integrating", false)?;
    o.finish(&["order", "delay", "integrating"])?;
    d.check_identifiable("training record", io_min_samples(spec, order, d.n_inputs()))?;
    let p = gb_lmn::IoNetworkParams {
        delay,
        network: spec.name == "lmn",
        hysteresis: spec.has("preisach"),
        output_map: if spec.has("feedback") { 8 } else { 0 },
        robust: spec.has("student-t"),
        ..gb_lmn::IoNetworkParams::linear(order)
    };
    if integrating {
        return fit_integrating(p, d);
    }
    let net = p.check()?.fit(d, gb_lmn::WarmStart::default())?;
    let noise = net.noise.clone();
    wrap(d, Box::new(net), noise, vec![])
}

/// `integrating=true`: the network models the increments Δy(k) =
/// y(k) − y(k−1) of `d`'s output, trained for the error of their running
/// sum (gb-lmn's `FitOptions::integrated_error`), and the output is that
/// sum ([`crate::IntegratingModel`]: a pole at 1); the noise model from
/// the summed free-run residuals, the state from an init window of 50
/// samples (a tenth of a short record).
fn fit_integrating(mut p: gb_lmn::IoNetworkParams, d: &Record) -> Result<Fitted, CoreError> {
    p.fit.integrated_error = true;
    let mut inc = d.clone();
    inc.output = crate::integrating::output_increments(&d.output);
    let net = p.check()?.fit(&inc, gb_lmn::WarmStart::default())?;
    let dynamics = crate::IntegratingModel::new(Box::new(net))?;
    let w = 50.min(d.len() / 10).max(1);
    let sim = gb_core::DynamicModel::simulate(
        &dynamics,
        &d.inputs,
        gb_core::Init::Window(&d.output[..w]),
    )?;
    let noise = residual_noise(&d.output, &sim, w);
    let note = "note: the output integrates (integrating=true): the network models its increments, trained for the error of their sum, and the output is their running sum".to_string();
    wrap(d, Box::new(dynamics), noise, vec![note])
}

/// Fewest training samples of an input–output network of `order` with
/// `ni` inputs. A plain linear output-error model has
/// p = n(1 + nᵢ) + 1 parameters; it needs 10 samples per parameter and the
/// 2n + 10 samples its lags and start take, `10 p + 2n + 10` (order 6 with
/// one input: 152 samples, so that a record of 200 samples can be fitted
/// at the orders a vibrating structure needs). A LOLIMOT network or a
/// linear model with play-operator columns or an output map fits many
/// more columns: `20 (n + 1)(nᵢ + 1) + 50`.
fn io_min_samples(spec: &ModelSpec, order: usize, ni: usize) -> usize {
    if spec.name == "linear" && spec.components.iter().all(|c| c == "student-t") {
        10 * (order * (ni + 1) + 1) + 2 * order + 10
    } else {
        20 * (order + 1) * (ni + 1) + 50
    }
}

/// Options of `lmn` that select the tree network (as do several records).
pub const TREE_KEYS: [&str; 11] = [
    "weights",
    "splits",
    "prune",
    "focus",
    "max_leaves",
    "degree",
    "dead_time",
    "input_lags",
    "output_lags",
    "criterion",
    "partition",
];

/// `lmn`: the tree network when a tree option is given or there are several
/// records, else the LOLIMOT input–output network.
fn fit_lmn(spec: &ModelSpec, data: &Records, obs: &dyn Observer) -> Result<Fitted, CoreError> {
    let o = spec.options();
    if !TREE_KEYS.iter().any(|k| o.given(k)) && data.len() == 1 {
        return fit_io_network(spec, data, obs);
    }
    if !spec.components.is_empty() {
        return Err(CoreError::InvalidArgument(format!(
            "model spec '{spec}': the tree options and several records need plain lmn (no components)"
        )));
    }
    let (p, order) = tree_params(spec, data.first().n_inputs())?;
    for (i, r) in data.iter().enumerate() {
        let min = if i == 0 {
            20 * (order + 1) * (r.n_inputs() + 1) + 50
        } else {
            20
        };
        r.check_identifiable(&format!("record {}", i + 1), min)?;
    }
    let lmn = p.check()?.fit_with_observer(data, None, obs)?;
    let mut res = vec![];
    for d in data.iter() {
        let k0 = lmn.max_lag().min(d.len());
        let sim = lmn.simulate(d, k0)?;
        res.extend(d.output[k0..].iter().zip(&sim[k0..]).map(|(a, b)| a - b));
    }
    let notes = vec![format!(
        "leaves: {}, effective parameters {:.1}, chosen by {:?} ({:.4e}), pruned splits {}",
        lmn.n_leaves(),
        lmn.effective_parameters(),
        lmn.summary.criterion,
        lmn.summary.criterion_value,
        lmn.summary.pruned
    )];
    wrap(
        data.first(),
        Box::new(lmn),
        NoiseModel::gaussian(&res),
        notes,
    )
}

/// The tree network's parameters from the options.
fn tree_params(spec: &ModelSpec, n_inputs: usize) -> Result<(gb_lmn::LmnParams, usize), CoreError> {
    use gb_lmn::{Criterion, Focus, LmnParams, RegressorSpec, SplitKind, WeightKind};
    let mut o: Options = spec.options();
    let order = o.usize("order", 2, 1, 64)?;
    let degree = o.usize("degree", 1, 1, 3)?;
    let nk = o.usize_list("dead_time", n_inputs, 1, 0, 64)?;
    let nb = o.usize_list("input_lags", n_inputs, order, 0, 64)?;
    let na = o.usize("output_lags", order, 0, 64)?;
    let criterion = match o.choice("criterion", "aicc", &["aicc", "bic"])? {
        "bic" => Criterion::Bic,
        _ => Criterion::Aicc,
    };
    let weights = match o.choice("weights", "tree", &["tree", "gauss"])? {
        "gauss" => WeightKind::Gaussian,
        _ => WeightKind::Tree,
    };
    let splits = match o.choice("splits", "axis", &["axis", "oblique"])? {
        "oblique" => SplitKind::Oblique,
        _ => SplitKind::Axis,
    };
    let focus = match o.choice("focus", "simulation", &["simulation", "prediction"])? {
        "prediction" => Focus::Prediction,
        _ => Focus::Simulation,
    };
    let prune = o.flag("prune", false)?;
    let max_leaves = o.usize("max_leaves", 20, 1, 256)?;
    let mut reg = RegressorSpec::arx(na, &nb, &nk);
    if o.choice("partition", "all", &["all", "y1"])? == "y1" {
        reg = reg.with_z(vec![1], vec![vec![]; n_inputs]);
    }
    let mut known = vec!["order"];
    known.extend(TREE_KEYS);
    o.finish(&known)?;
    let p = LmnParams::new(reg.with_degree(degree))
        .weights(weights)
        .splits(splits)
        .prune(prune)
        .focus(focus)
        .criterion(criterion)
        .max_leaves(max_leaves);
    p.check()?;
    Ok((p, order))
}

/// `hammerstein` and `wiener`: the block-oriented class.
fn fit_block(spec: &ModelSpec, data: &Records, _obs: &dyn Observer) -> Result<Fitted, CoreError> {
    let mut o = spec.options();
    let d = one_record(data, "a block-oriented model")?;
    let ni = d.n_inputs();
    let order = o.usize("order", 2, 1, 30)?;
    let mut delays = o.usize_list_choices("delay", ni, 1, 0, 64)?;
    let delay = delays.remove(0);
    let mut p = gb_lmn::BlockParams {
        delay,
        other_delays: delays,
        ..gb_lmn::BlockParams::linear(order)
    };
    let map = o.choice("map", "auto", &MAP_STRUCTURES)?;
    if map != "auto" {
        p.maps.retain(|&(b, k)| b.structure_name(k) == map);
    }
    if spec.name == "wiener" {
        o.finish(&["order", "delay", "map"])?;
        p.output_map = true;
    } else {
        p.input_maps = o
            .usize_list("maps", ni, 1, 0, 1)?
            .iter()
            .map(|&m| m == 1)
            .collect();
        o.finish(&["order", "delay", "maps", "map"])?;
    }
    d.check_identifiable("training record", 20 * (order + 1) * (ni + 1) + 50)?;
    let m = p.check()?.fit(d)?;
    let k0 = m.max_lag().min(d.len());
    let sim = m.simulate_signals(&d.inputs, &d.output[..k0])?;
    let noise = residual_noise(&d.output, &sim, k0);
    wrap(d, Box::new(m), noise, vec![])
}

/// `wiener-hammerstein`.
fn fit_wiener_hammerstein(
    spec: &ModelSpec,
    data: &Records,
    _obs: &dyn Observer,
) -> Result<Fitted, CoreError> {
    let mut o = spec.options();
    let d = one_record(data, "a Wiener-Hammerstein network")?;
    let leaves = o.usize("max_leaves", 16, 1, 61)?;
    o.finish(&["max_leaves"])?;
    if d.n_inputs() != 1 {
        return Err(CoreError::InvalidArgument(format!(
            "a Wiener-Hammerstein network needs exactly one input, got {} ({})",
            d.n_inputs(),
            d.input_names.join(", ")
        )));
    }
    d.check_identifiable("training record", 1000)?;
    let (w, rep) = gb_lmn::WhParams::new()
        .knots(leaves - 1)
        .check()?
        .fit(&d.inputs[0], &d.output)?;
    let sim = w.simulate(&d.inputs[0]);
    // past the transient of the zero state
    let noise = residual_noise(&d.output, &sim, 200.min(d.len() / 4));
    let notes = vec![format!(
        "best linear approximation RMSE {:.4e}; {} pole/zero splits scanned, best {:.4e}; after LM {:.4e}",
        rep.bla_rmse, rep.splits_tried, rep.best_split_rmse, rep.rmse
    )];
    wrap(d, Box::new(w), noise, notes)
}

/// A Wiener–Hammerstein network `start` (as the `wiener-hammerstein`
/// recipe fits it) refined on `data` with its structure kept
/// ([`gb_lmn::WhFitter::refit_from`]): the same network fitted on other
/// data of the same system, a fold of a cross-validation or a longer
/// record, without scanning the pole/zero splits again. `None` when
/// `start` is not such a network.
pub fn refit_wiener_hammerstein(
    start: &FittedModel,
    data: &Records,
) -> Result<Option<Fitted>, CoreError> {
    let Some(w0) = start
        .dynamics
        .as_any()
        .downcast_ref::<gb_lmn::WienerHammersteinNetwork>()
    else {
        return Ok(None);
    };
    let d = one_record(data, "a Wiener-Hammerstein network")?;
    if d.n_inputs() != 1 {
        return Err(CoreError::InvalidArgument(format!(
            "a Wiener-Hammerstein network needs exactly one input, got {}",
            d.n_inputs()
        )));
    }
    d.check_identifiable("training record", 1000)?;
    let (w, rmse, iterations) =
        gb_lmn::WhParams::new()
            .check()?
            .refit_from(w0, &d.inputs[0], &d.output)?;
    let sim = w.simulate(&d.inputs[0]);
    let noise = residual_noise(&d.output, &sim, 200.min(d.len() / 4));
    let notes = vec![format!(
        "refined from a fitted network ({iterations} iterations): RMSE {rmse:.4e}"
    )];
    wrap(d, Box::new(w), noise, notes).map(Some)
}

/// The help line of the block-oriented recipes' `delay` option.
const DELAY_CHOICES: &str = "delay=1: dead time, one or one per input (a/b); alternatives separated by | (delay=1|0|2) are compared by their fit error at the map structure chosen at the first";

/// The help line of the block-oriented recipes' `map` option.
const MAP_OPTION: &str = "map=auto: the static maps' structure, cubic, spline4/8/16 or pwl2/4/8/16 (piecewise linear, free knots); auto chooses among them on a hold-out";

/// The `map` option of the block-oriented recipes: `auto` (chosen on a
/// hold-out among the others) or one of gb-lmn's default map structures.
const MAP_STRUCTURES: [&str; 9] = [
    "auto", "cubic", "pwl2", "pwl4", "spline4", "spline8", "pwl8", "spline16", "pwl16",
];

/// `lmn-state-space`.
fn fit_ss_lmn(spec: &ModelSpec, data: &Records, _obs: &dyn Observer) -> Result<Fitted, CoreError> {
    let mut o = spec.options();
    let d = one_record(data, "a state-space network")?;
    let n_states = o.usize("order", 2, 1, 8)?;
    let leaves = o.usize("max_leaves", 2, 1, 8)?;
    let output_upper = o.f64_opt("output_max", f64::MIN, f64::MAX)?;
    o.finish(&["order", "max_leaves", "output_max"])?;
    let params = gb_lmn::SsLmnParams {
        n_states: vec![n_states],
        leaves: (1..=leaves).collect(),
        output_upper,
        ..gb_lmn::SsLmnParams::default()
    };
    params.check(d.n_inputs())?;
    d.check_identifiable("training record", 100)?;
    let fit = gb_lmn::fit_ss_lmn(&params, &d.inputs, &d.output)?;
    let w = params.init_window.min(d.len());
    let sim = fit
        .model
        .simulate_with_init_window(&d.inputs, &d.output, w)?;
    let noise = residual_noise(&d.output, &sim, w);
    wrap(d, Box::new(fit.model), noise, vec![])
}

/// `state-space[+preisach|+hysteresis|+damper]`.
fn fit_sparse_state_space(
    spec: &ModelSpec,
    data: &Records,
    _obs: &dyn Observer,
) -> Result<Fitted, CoreError> {
    let d = one_record(data, "a state-space model")?;
    if spec.components.len() > 1 {
        return Err(CoreError::InvalidArgument(format!(
            "model spec '{spec}': at most one of +preisach, +hysteresis, +damper"
        )));
    }
    if spec.has("damper") {
        return fit_damper(spec, d);
    }
    let mut o = spec.options();
    let order = o.usize("order", 2, 1, 8)?;
    o.finish(&["order"])?;
    d.check_identifiable("training record", 20 * (order + 1) + 50)?;
    let names: Vec<String> = d
        .input_names
        .iter()
        .chain(std::iter::once(&d.output_name))
        .cloned()
        .collect();
    let (m, notes) = if spec.has("hysteresis") {
        (
            fit_hidden_state(&d.inputs, &d.output, order, true, names)?,
            vec![],
        )
    } else {
        let silent = crate::Silent;
        let (m, rep) = crate::fit_state_space(
            &d.inputs,
            &d.output,
            order,
            spec.has("preisach"),
            names,
            &silent,
        )?;
        let note = format!(
            "path {:?}, log-likelihood {:.1}",
            rep.path, rep.log_likelihood
        );
        (m, vec![note])
    };
    let sim = m.simulate(&d.inputs)?;
    let noise = residual_noise(&d.output, &sim, 0);
    wrap(d, Box::new(m), noise, notes)
}

/// `state-space+damper`.
fn fit_damper(spec: &ModelSpec, d: &Record) -> Result<Fitted, CoreError> {
    let mut o = spec.options();
    let resonances_hz = o.f64_list("resonances")?;
    let sample_rate = o.f64_opt("sample_rate", 1e-9, 1e12)?;
    let ridge = o.f64_opt("ridge", 0.0, 1e300)?;
    o.finish(&["resonances", "sample_rate", "ridge"])?;
    if !(3..=4).contains(&d.n_inputs()) {
        return Err(CoreError::InvalidArgument(format!(
            "state-space+damper takes 3 or 4 inputs (displacement, velocity, voltage [, acceleration], in that order), got {} ({})",
            d.n_inputs(),
            d.input_names.join(", ")
        )));
    }
    d.check_identifiable("training record", 500)?;
    let sample_rate = match (sample_rate, d.sample_time) {
        (Some(f), _) => f,
        (None, Some(ts)) => 1.0 / ts,
        (None, None) if resonances_hz.is_empty() => 1.0,
        (None, None) => {
            return Err(CoreError::InvalidArgument(
                "state-space+damper with resonances needs the sample rate: a `t` column or the option sample_rate".into(),
            ))
        }
    };
    let structure = crate::MrDamperStructure::new(sample_rate, resonances_hz);
    // without a ridge: 0 or 10³, chosen on the last 20 % of the record
    let ridges = ridge.map_or(vec![0.0, 1e3], |r| vec![r]);
    let fit = structure.fit_validated(
        &OeParams::new(),
        &ridges,
        &d.inputs,
        &d.output,
        &crate::Silent,
    )?;
    let notes = fit
        .scores
        .iter()
        .map(|(_, r, e)| {
            format!("ridge {r:e}: NRMSE {e:.4} on the last 20 % (fitted on the first 80 %)")
        })
        .collect();
    let mut m = fit.model;
    m.signal_names = d
        .input_names
        .iter()
        .chain(std::iter::once(&d.output_name))
        .cloned()
        .collect();
    let sim = m.simulate(&d.inputs)?;
    let noise = residual_noise(&d.output, &sim, 0);
    wrap(d, Box::new(m), noise, notes)
}

#[cfg(test)]
mod tests {
    use super::MAP_STRUCTURES;
    use crate::operators::{operator_channels, InputOperator};
    use gb_core::{Init, ModelSpec, Record, Records};

    /// `y = x + 3·s_h[x]·w + 0.5·w` with `w` a slow second input and `h`
    /// 0.1 standard deviations of `x`: the static polynomial with the
    /// stops of input 1 (0.1 among the widths) and the low-pass of input 2
    /// (a time constant of one sample passes it nearly whole) reaches it
    /// closely, a polynomial of the inputs alone does not; the model file
    /// reads back; options out of range and unknown options are refused
    /// with the spec named.
    #[test]
    fn a_poly_spec_with_stops_fits_a_static_hysteresis() {
        let n = 1500;
        let mut r = gb_core::rng::seeded(4);
        let mut x = vec![0.0; n];
        for k in 1..n {
            x[k] = 0.97 * x[k - 1] + rand::Rng::random::<f64>(&mut r) - 0.5;
        }
        let w: Vec<f64> = (0..n).map(|k| 1.0 + (k as f64 / 150.0).sin()).collect();
        let h = 0.1 * gb_core::metrics::std(&x);
        let s = &operator_channels(
            &[InputOperator::Stop {
                input: 0,
                half_width: h,
            }],
            std::slice::from_ref(&x),
        )[0];
        let y: Vec<f64> = (0..n)
            .map(|k| x[k] + 3.0 * s[k] * w[k] + 0.5 * w[k])
            .collect();
        let rec = Record::new(
            vec!["x".into(), "w".into()],
            "y".into(),
            vec![x.clone(), w.clone()],
            y.clone(),
        )
        .unwrap();
        let data = Records::single(rec);
        let nrmse = |spec: &str| {
            let spec: ModelSpec = spec.parse().unwrap();
            let f = super::fit(&spec, &data, &gb_core::Silent).unwrap();
            let bytes = f.model.to_bytes().unwrap();
            let back = crate::registry::from_bytes(&bytes, "m.gbm").unwrap();
            let sim = back.simulate(&[x.clone(), w.clone()], Init::Rest).unwrap();
            gb_core::metrics::nrmse(&y, &sim).unwrap()
        };
        let with = nrmse(
            "poly:order=0,delay=0,stops=1,stop_widths=0.03/0.1/0.3,lowpass=2,lowpass_samples=1",
        );
        let without = nrmse("poly:order=0,delay=0");
        assert!(with < 0.02 && without > 0.1, "{with} {without}");
        for (bad, says) in [
            ("poly:stops=3", "stops=3: input numbers in 1..=2"),
            ("poly:stops=1,stop_widths=0", "stop_widths=0"),
            ("poly:stops=1,bogus=2", "unknown option 'bogus'"),
        ] {
            let spec: ModelSpec = bad.parse().unwrap();
            let e = super::fit(&spec, &data, &gb_core::Silent)
                .unwrap_err()
                .to_string();
            assert!(e.contains(says) && e.contains("model spec"), "{bad}: {e}");
        }
    }

    #[test]
    fn the_map_option_names_every_default_map_structure() {
        let names: Vec<String> = gb_lmn::BlockParams::linear(2)
            .maps
            .iter()
            .map(|&(b, k)| b.structure_name(k))
            .collect();
        let listed: Vec<&str> = MAP_STRUCTURES[1..].to_vec();
        assert_eq!(names, listed);
        assert_eq!(MAP_STRUCTURES[0], "auto");
    }

    #[test]
    fn the_map_option_fixes_the_structure_of_the_static_map() {
        // a Hammerstein system: tanh of the input, then a second-order filter
        let u: Vec<f64> = (0..1500)
            .map(|k| ((k as f64 * 0.37).sin() + (k as f64 * 0.113).cos()) * 1.2)
            .collect();
        let mut y = vec![0.0; u.len()];
        for k in 2..u.len() {
            y[k] = 1.2 * y[k - 1] - 0.5 * y[k - 2] + 0.4 * u[k - 1].tanh();
        }
        let rec = gb_core::Record::new(vec!["u".into()], "y".into(), vec![u], y).unwrap();
        let data = gb_core::Records::single(rec);
        for (name, want) in [
            ("cubic", (gb_lmn::MapBasis::Cubic, 0)),
            ("pwl4", (gb_lmn::MapBasis::Hinge, 4)),
            ("spline8", (gb_lmn::MapBasis::Spline, 8)),
        ] {
            for recipe in ["hammerstein", "wiener"] {
                let m = fitted_block(&format!("{recipe}:order=2,map={name}"), &data);
                assert_eq!(m.map_structure(), Some(want), "{recipe} map={name}");
            }
        }
        let bad = "hammerstein:map=spline5".parse().unwrap();
        let err = super::fit(&bad, &data, &crate::Silent).unwrap_err();
        assert!(err.to_string().contains("spline5"), "{err}");
    }

    /// An integrator (velocity v(k) = 0.9 v(k−1) + 0.1 u(k−1) of a slow
    /// random input, its position measured with 1 % noise): with
    /// `integrating=true` the fitted model integrates (its class; a pole
    /// at one) and simulates the noise-free position of a fresh input far
    /// closer than the output-error model of the position itself, which a
    /// stable fit cannot make drift; a tree option with it is refused.
    #[test]
    fn integrating_true_models_the_increments_and_sums_them() {
        use rand::Rng;
        let plant = |u: &[f64]| {
            let (mut v, mut q) = (0.0, 0.0);
            let mut y = vec![0.0; u.len()];
            for k in 1..u.len() {
                v = 0.9 * v + 0.1 * u[k - 1];
                q += v;
                y[k] = q;
            }
            y
        };
        let slow = |seed: u64, n: usize| {
            let mut r = gb_core::rng::seeded(seed);
            let mut l = 0.0;
            (0..n)
                .map(|_| {
                    l = 0.97 * l + 0.3 * r.random_range(-1.0..1.0);
                    l
                })
                .collect::<Vec<f64>>()
        };
        let u = slow(1, 3000);
        let pos = plant(&u);
        let sd = gb_core::metrics::std(&pos);
        let mut r = gb_core::rng::seeded(2);
        let y: Vec<f64> = pos
            .iter()
            .map(|p| p + 0.01 * sd * r.random_range(-1.7..1.7))
            .collect();
        let rec = gb_core::Record::new(vec!["u".into()], "y".into(), vec![u], y).unwrap();
        let data = gb_core::Records::single(rec);
        let fit = |spec: &str| super::fit(&spec.parse().unwrap(), &data, &crate::Silent);
        let summed = fit("linear:order=1,delay=1,integrating=true").unwrap();
        let plain = fit("linear:order=2,delay=1").unwrap();
        assert_eq!(summed.model.dynamics.class(), crate::INTEGRATING_CLASS);
        assert!(summed.model.dynamics.integrates());
        let uv = slow(7, 2000);
        let truth = plant(&uv);
        let err = |m: &gb_core::FittedModel| {
            let sim = m
                .simulate(
                    std::slice::from_ref(&uv),
                    gb_core::Init::Window(&truth[..20]),
                )
                .unwrap();
            let e: Vec<f64> = truth.iter().zip(&sim).map(|(a, b)| a - b).collect();
            gb_core::metrics::rms(&e[20..]) / gb_core::metrics::std(&truth)
        };
        let (es, ep) = (err(&summed.model), err(&plain.model));
        eprintln!("position error: summed {es:.4}, the position's own {ep:.4}");
        assert!(
            es < 0.05 && es < 0.2 * ep,
            "summed {es}, the position's own {ep}"
        );
        assert!(fit("lmn:integrating=true,max_leaves=3").is_err());
    }

    /// A sixth-order system (three lightly damped modes) on 200 samples:
    /// `linear:order=6` is fitted (the network rule would ask for 330
    /// samples) and simulates a fresh record far better than order 2;
    /// `lmn:order=6` still asks for 330.
    #[test]
    fn a_high_order_linear_model_is_fitted_on_a_short_record() {
        use rand::Rng;
        let system = |n: usize, seed: u64| {
            let mut rng = gb_core::rng::seeded(seed);
            let u: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
            // three resonances in series, poles 0.9·e^{±0.3i}, 0.92·e^{±1.0i}, 0.9·e^{±2.0i}
            let mut x = u.clone();
            for (r, w) in [(0.9f64, 0.3f64), (0.92, 1.0), (0.9, 2.0)] {
                let (a1, a2) = (2.0 * r * w.cos(), -r * r);
                let mut z = vec![0.0; n];
                for k in 2..n {
                    z[k] = a1 * z[k - 1] + a2 * z[k - 2] + x[k - 1];
                }
                x = z;
            }
            let y = x
                .iter()
                .map(|v| v + 0.01 * rng.random_range(-1.0..1.0))
                .collect();
            gb_core::Record::new(vec!["u".into()], "y".into(), vec![u], y).unwrap()
        };
        let data = gb_core::Records::single(system(200, 1));
        let fresh = system(1000, 2);
        let nrmse = |spec: &str| {
            let f = super::fit(&spec.parse().unwrap(), &data, &crate::Silent).unwrap();
            let sim = f
                .model
                .simulate(&fresh.inputs, gb_core::Init::Window(&fresh.output[..20]))
                .unwrap();
            let e: Vec<f64> = (20..fresh.len())
                .map(|k| fresh.output[k] - sim[k])
                .collect();
            gb_core::metrics::rms(&e) / gb_core::metrics::std(&fresh.output[20..])
        };
        let (six, two) = (nrmse("linear:order=6"), nrmse("linear:order=2"));
        eprintln!("fresh-record NRMSE: order 6 {six:.4}, order 2 {two:.4}");
        assert!(six < 0.2 * two, "order 6: {six:.4}, order 2: {two:.4}");
        let err = super::fit(&"lmn:order=6".parse().unwrap(), &data, &crate::Silent).unwrap_err();
        assert!(err.to_string().contains("at least 330"), "{err}");
    }

    /// The block-oriented model a recipe spec fits on `data`.
    fn fitted_block(spec: &str, data: &gb_core::Records) -> gb_lmn::BlockModel {
        let spec = spec.parse().unwrap();
        let f = super::fit(&spec, data, &crate::Silent).unwrap();
        f.model
            .dynamics
            .as_any()
            .downcast_ref::<gb_lmn::BlockModel>()
            .unwrap()
            .clone()
    }

    #[test]
    fn the_block_recipes_choose_among_alternative_dead_times() {
        // a second-order filter of the input three samples late, with tanh
        // before it (Hammerstein) or after it (Wiener)
        let u: Vec<f64> = (0..1500)
            .map(|k| ((k as f64 * 0.37).sin() + (k as f64 * 0.113).cos()) * 1.2)
            .collect();
        for recipe in ["hammerstein", "wiener"] {
            let before = |v: f64| if recipe == "hammerstein" { v.tanh() } else { v };
            let mut x = vec![0.0; u.len()];
            for k in 3..u.len() {
                x[k] = 1.2 * x[k - 1] - 0.5 * x[k - 2] + 0.4 * before(u[k - 3]);
            }
            let y = if recipe == "wiener" {
                x.iter().map(|v| (2.0 * v).tanh()).collect()
            } else {
                x
            };
            let rec =
                gb_core::Record::new(vec!["u".into()], "y".into(), vec![u.clone()], y).unwrap();
            let data = gb_core::Records::single(rec);
            for (delay, want) in [("4|3|5", 3), ("5|4|3", 3), ("4", 4)] {
                let m = fitted_block(&format!("{recipe}:order=2,delay={delay}"), &data);
                assert_eq!(m.nk, vec![want], "{recipe} delay={delay}");
            }
        }
    }
}
