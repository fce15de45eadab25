//! `nonlinearity` in the engineer's own equations: a black-box term added
//! to one state equation or to the output of a physics model, the physical
//! parameters re-estimated with it.
use crate::evaluate::Lineage;
use crate::extension::{Context, Extension, Proposal};
use crate::physics::physics_row_text;
use crate::physics::{
    best_of_starts, current_physics, fit_physics_screened, physics_fit_record, physics_of, rmse_on,
    spec_is_template,
};
use crate::{Cause, DiagnoseError};
use gb_core::{DynamicModel, FittedModel, Init};
use gb_model::physics::{Parameter, PhysicsModel, PhysicsSpec, TermTarget};

/// Candidate terms for the engineer's equations, each with new free
/// parameters and every physical parameter refitted from the current
/// estimates. For every state equation `ẋᵢ = fᵢ(x, u, θ)` with a free
/// parameter (a definition such as `ẋ = v` is left alone) and every state
/// `x_s`:
///
/// * `poly`: `ẋᵢ += a2·s² + a3·s³` with `s = x_s/h` scaled by the largest
///   |x_s| of the simulated state (a smooth nonlinear spring, damper or
///   flow law; no constant or linear part, which the physical parameters
///   own);
/// * `centred`: `ẋᵢ += c2·w² + c3·w³` with `w = (x_s − mid)/half` centred
///   on the simulated range (a law whose offset and slope come with it,
///   e.g. a flow that changes with the level);
/// * `hinge`: `ẋᵢ += b_hi·max(x_s − q₉₀, 0) + b_lo·max(q₁₀ − x_s, 0)` with
///   the 10 % and 90 % quantiles of the simulated state (a law that
///   changes beyond a level);
/// * `coulomb` (on the state's own equation, `s = i`): `ẋᵢ −= f·tanh(xᵢ/ε)`
///   with `ε > 0` free, started at 5 % of the rms of the simulated state
///   (dry friction on a velocity: a force of size `f` against the motion,
///   smoothed over `|xᵢ| ≲ ε`, which a polynomial does not approach).
///
/// On the state itself (`s = i`), a hard limit (an overflow, an end stop,
/// an empty tank), with `r = substeps/Ts` the inverse RK4 step:
///
/// * `ceiling`: `ẋᵢ = min(fᵢ, r·(L − xᵢ))`, added as the term
///   `min(0, r·(L − xᵢ) − fᵢ)`, so the state stops at `L` within about
///   one step; `L` starts at the 80, 90, 95 and 99 % quantiles of the
///   simulated `xᵢ` and the best fit is kept (only for a state without a
///   declared `max`, which the simulation already enforces);
/// * `floor`: `ẋᵢ = max(fᵢ, r·(L − xᵢ))`, `L` from the mirrored quantiles
///   (only for a state without a declared `min`);
/// * `spill` (once `xᵢ` has a ceiling): what the ceiling removes flows, by
///   a fraction `k`, into another state: `ẋⱼ += k·max(0, fᵢ − r·(L − xᵢ))`
///   (the overflow of one tank into the next).
///
/// On each output `y = g(x, u, θ)`:
///
/// * `offset`: `y += o` (a sensor bias);
/// * `clip`: `y = min(g, M)`, `M` started at the same quantiles of the
///   simulated output (a sensor range).
///
/// The normalisation comes from the current model's simulation on the fit
/// record of each fit (the fold's under cross-validation). The physical
/// parameters keep their names in the extended model.
pub struct PhysicsTerms;

/// The kinds of added terms.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Poly,
    Centred,
    Hinge,
    Coulomb,
    Ceiling,
    Floor,
    Spill,
    Overflow,
    Offset,
    Clip,
}

/// Where a term goes: a state's equation or an output, by name.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Place {
    State(String),
    Output(String),
}

impl Place {
    fn label(&self) -> String {
        match self {
            Place::State(s) => format!("d{s}/dt"),
            Place::Output(o) => o.clone(),
        }
    }
    fn parse(s: &str) -> Place {
        match s.strip_prefix('d').and_then(|r| r.strip_suffix("/dt")) {
            Some(st) => Place::State(st.to_string()),
            None => Place::Output(s.to_string()),
        }
    }
}

impl Kind {
    const ALL: [Kind; 10] = [
        Kind::Poly,
        Kind::Centred,
        Kind::Hinge,
        Kind::Coulomb,
        Kind::Ceiling,
        Kind::Floor,
        Kind::Spill,
        Kind::Overflow,
        Kind::Offset,
        Kind::Clip,
    ];

    fn name(self) -> &'static str {
        match self {
            Kind::Poly => "poly",
            Kind::Centred => "centred",
            Kind::Hinge => "hinge",
            Kind::Coulomb => "coulomb",
            Kind::Ceiling => "ceiling",
            Kind::Floor => "floor",
            Kind::Spill => "spill",
            Kind::Overflow => "overflow",
            Kind::Offset => "offset",
            Kind::Clip => "clip",
        }
    }
    /// The new parameters' names for place `at` and variable `var`.
    fn parameters(self, at: &Place, var: &str) -> Vec<String> {
        let eq = match at {
            Place::State(s) | Place::Output(s) => s,
        };
        match self {
            Kind::Poly => vec![format!("a2_{eq}_{var}"), format!("a3_{eq}_{var}")],
            Kind::Centred => vec![format!("c2_{eq}_{var}"), format!("c3_{eq}_{var}")],
            Kind::Hinge => vec![format!("b_hi_{eq}_{var}"), format!("b_lo_{eq}_{var}")],
            Kind::Coulomb => vec![format!("f_c_{eq}"), format!("eps_c_{eq}")],
            Kind::Ceiling => vec![ceiling_name(eq)],
            Kind::Floor => vec![format!("L_lo_{eq}")],
            Kind::Spill => vec![format!("k_spill_{var}_{eq}")],
            // the limit sits on `eq`, what it cuts off flows into `var`
            Kind::Overflow => vec![ceiling_name(eq), format!("k_spill_{eq}_{var}")],
            Kind::Offset => vec![format!("off_{eq}")],
            Kind::Clip => vec![format!("M_{eq}")],
        }
    }
}

/// The name of the ceiling parameter of state `s`.
fn ceiling_name(s: &str) -> String {
    format!("L_hi_{s}")
}

/// The marker of an added term in a lineage spec: ` + poly(x) in dv/dt`,
/// ` + offset() in y`.
fn marker(kind: Kind, at: &Place, var: &str) -> String {
    format!(" + {}({var}) in {}", kind.name(), at.label())
}

/// The kind, place and variable of a proposal, from its lineage spec.
fn target(p: &Proposal) -> Option<(Kind, Place, String)> {
    let Lineage::Other { spec, .. } = &p.lineage else {
        return None;
    };
    let last = spec.rsplit(" + ").next()?;
    let (kind, rest) = last.split_once('(')?;
    let kind = Kind::ALL.into_iter().find(|k| k.name() == kind)?;
    let (var, at) = rest.split_once(") in ")?;
    Some((kind, Place::parse(at), var.to_string()))
}

/// The symbols of a list of terms.
fn symbols(terms: &[String]) -> Vec<&str> {
    terms
        .iter()
        .flat_map(|t| t.split(|c: char| !(c.is_alphanumeric() || c == '_')))
        .collect()
}

/// Whether equation `i` of `spec` has a free parameter (an equation
/// without one, such as `ẋ = v`, is a definition, not a law the data could
/// correct).
pub(super) fn is_law(spec: &PhysicsSpec, i: usize) -> bool {
    let syms = symbols(&spec.equations[i]);
    spec.parameters
        .iter()
        .any(|p| !p.fixed && syms.contains(&p.name.as_str()))
}

/// Whether `spec` can take the terms of `kind` at `at` in `var`: their
/// parameters are new, a state equation is a law, a spill has a ceiling to
/// spill from and goes elsewhere, a limit sits on its own state.
fn applies(spec: &PhysicsSpec, kind: Kind, at: &Place, var: &str) -> bool {
    let names = kind.parameters(at, var);
    let has = |n: &str| spec.parameters.iter().any(|p| p.name == n);
    if names.iter().any(|n| has(n)) {
        return false;
    }
    let state = |s: &str| spec.states.iter().position(|x| x.name == s);
    match at {
        Place::Output(o) => {
            matches!(kind, Kind::Offset | Kind::Clip) && spec.outputs.iter().any(|x| &x.name == o)
        }
        Place::State(eq) => {
            let Some(i) = state(eq) else { return false };
            // an added hysteretic state is neither extended nor a variable
            let added = super::physics_hysteresis::is_added_state;
            if !is_law(spec, i) || added(eq) || added(var) {
                return false;
            }
            match kind {
                Kind::Poly | Kind::Centred | Kind::Hinge => state(var).is_some(),
                Kind::Coulomb => var == eq,
                Kind::Ceiling => var == eq && spec.states[i].upper == f64::INFINITY,
                Kind::Floor => var == eq && spec.states[i].lower == f64::NEG_INFINITY,
                Kind::Spill => var != eq && state(var).is_some() && has(&ceiling_name(var)),
                Kind::Overflow => {
                    var != eq
                        && spec.states[i].upper == f64::INFINITY
                        && state(var).is_some_and(|j| is_law(spec, j))
                }
                Kind::Offset | Kind::Clip => false,
            }
        }
    }
}

/// The value at quantile `q` of `v` (sorted copy, nearest rank).
pub(super) fn quantile(v: &[f64], q: f64) -> f64 {
    let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    s.sort_by(f64::total_cmp);
    if s.is_empty() {
        return 0.0;
    }
    s[((q * (s.len() - 1) as f64).round() as usize).min(s.len() - 1)]
}

/// `(a)+(b)+…`: a list of terms as one expression.
pub(super) fn sum_text(terms: &[String]) -> String {
    if terms.is_empty() {
        return "0".into();
    }
    terms
        .iter()
        .map(|t| format!("({t})"))
        .collect::<Vec<_>>()
        .join("+")
}

/// `min(0, z)` and `max(0, z)` as `(z ∓ |z|)/2` (the expression grammar
/// does not nest two-argument functions).
fn neg_part(z: &str) -> String {
    format!("(({z})-abs({z}))/2")
}
fn pos_part(z: &str) -> String {
    format!("(({z})+abs({z}))/2")
}

/// The terms of a smooth law (`poly`, `centred`, `hinge`) in the state
/// trajectory `x` (of `var`), as expressions of the new parameters.
fn law_terms(kind: Kind, names: &[String], var: &str, x: &[f64]) -> Vec<String> {
    match kind {
        Kind::Poly => {
            let h = x
                .iter()
                .filter(|v| v.is_finite())
                .fold(0.0_f64, |m, v| m.max(v.abs()))
                .max(1e-300);
            let s = format!("({var}/{h})");
            vec![format!("{}*{s}^2", names[0]), format!("{}*{s}^3", names[1])]
        }
        Kind::Centred => {
            let (lo, hi) = (quantile(x, 0.0), quantile(x, 1.0));
            let c = 0.5 * (lo + hi);
            let h = (0.5 * (hi - lo)).max(1e-12 * c.abs().max(1.0));
            let w = format!("(({var}-({c}))/{h})");
            vec![format!("{}*{w}^2", names[0]), format!("{}*{w}^3", names[1])]
        }
        _ => {
            let (q10, q90) = (quantile(x, 0.1), quantile(x, 0.9));
            vec![
                format!("{}*max({var}-({q90}),0)", names[0]),
                format!("{}*max(({q10})-{var},0)", names[1]),
            ]
        }
    }
}

/// The unlimited law of state `i`: its terms without the ceiling term.
fn unlimited(spec: &PhysicsSpec, i: usize) -> Vec<String> {
    let l = ceiling_name(&spec.states[i].name);
    spec.equations[i]
        .iter()
        .filter(|t| !symbols(std::slice::from_ref(t)).contains(&l.as_str()))
        .cloned()
        .collect()
}

/// A new parameter (start, bounds) and the term it brings, if any (a
/// parameter such as a smoothing width appears only inside another term).
type NewParameter = (Parameter, Option<String>);

/// The new parameters (with start values) and terms of `kind` at state
/// equation `i` in variable `j`.
fn state_terms(
    spec: &PhysicsSpec,
    kind: Kind,
    names: &[String],
    (i, j): (usize, usize),
    x: &[Vec<f64>],
    (rate, q): (f64, f64),
) -> Vec<NewParameter> {
    let (xi, var) = (&spec.states[i].name, &spec.states[j].name);
    let limit = |l: &str, own: &str| format!("({l}-{own})*{rate}");
    match kind {
        Kind::Ceiling => {
            let z = format!(
                "{}-({})",
                limit(&names[0], xi),
                sum_text(&spec.equations[i])
            );
            vec![(
                Parameter::new(&names[0], quantile(&x[i], q)),
                Some(neg_part(&z)),
            )]
        }
        Kind::Floor => {
            let z = format!(
                "{}-({})",
                limit(&names[0], xi),
                sum_text(&spec.equations[i])
            );
            vec![(
                Parameter::new(&names[0], quantile(&x[i], 1.0 - q)),
                Some(pos_part(&z)),
            )]
        }
        Kind::Coulomb => {
            // the smoothing width stays positive; it has no term of its own
            let eps = (0.05 * gb_core::metrics::rms(&x[j])).max(1e-12);
            vec![
                (
                    Parameter::new(&names[0], 0.0),
                    Some(format!("-{}*tanh({var}/{})", names[0], names[1])),
                ),
                (
                    Parameter::new(&names[1], eps).bounds(1e-6 * eps, COULOMB_WIDTH_MAX * eps),
                    None,
                ),
            ]
        }
        Kind::Spill => {
            // the overflow of the source state j (= var) into equation i
            let z = format!(
                "({})-{}",
                sum_text(&unlimited(spec, j)),
                limit(&ceiling_name(var), var)
            );
            vec![(
                Parameter::new(&names[0], 0.0),
                Some(format!("{}*{}", names[0], pos_part(&z))),
            )]
        }
        _ => law_terms(kind, names, var, &x[j])
            .into_iter()
            .zip(names)
            .map(|(t, n)| (Parameter::new(n, 0.0), Some(t)))
            .collect(),
    }
}

/// The widest smoothing width ε of a dry-friction law, in units of its
/// start (5 % of the rms of its variable): ε ≤ the rms. Unbounded, a law
/// the data do not ask for drifts along `f, ε → ∞` with `f/ε` fixed (a
/// linear term beside `c·v`): the blind template's first-order law on
/// wiener 6 of the 8000 + 4000 sweep ran 200 iterations to f = −644,
/// ε = 140 (the velocity's rms ≈ 5), its folds 130–150 each, 10.1 s of the
/// case's 24 s; bounded, 34 and 1–21 iterations, 1.5 s, every diagnosis
/// of the sweep the same.
const COULOMB_WIDTH_MAX: f64 = 20.0;

/// `cur`'s spec started at its estimates with the terms of `kind` at `at`
/// (in `var`), normalised on `cur`'s simulation of `fit`; a limit starts
/// at the quantile `q` of the simulated state or output (the upper one;
/// `1 − q` for a floor). With `Start::Cold` the model is `cur`'s spec at
/// the start values it was fitted from instead (see [`limit_starts`]).
fn extended(
    cur: &PhysicsModel,
    fit: &gb_core::Record,
    (kind, at, var): (Kind, &Place, &str),
    (q, start): (f64, Start),
) -> Result<PhysicsSpec, DiagnoseError> {
    let core =
        |e: gb_model::physics::PhysicsError| DiagnoseError::from(gb_core::CoreError::from(e));
    let cold;
    let (cur, mut s) = match start {
        Start::Warm => (
            cur,
            cur.with_start_at_values().map_err(core)?.spec().clone(),
        ),
        Start::Cold => {
            cold = PhysicsModel::new(cur.spec().clone()).map_err(core)?;
            (&cold, cur.spec().clone())
        }
    };
    let bad = |m: String| DiagnoseError::InvalidArgument(format!("physics-terms: {m}"));
    let names = kind.parameters(at, var);
    let (target, terms) = match at {
        Place::Output(o) => {
            let k = s
                .outputs
                .iter()
                .position(|x| &x.name == o)
                .ok_or_else(|| bad(format!("no output '{o}'")))?;
            let terms = if kind == Kind::Clip {
                let y = cur.simulate(&fit.inputs, Init::Stored)?;
                let z = format!("{}-({})", names[0], sum_text(&s.outputs[k].terms));
                vec![(
                    Parameter::new(&names[0], quantile(&y, q)),
                    Some(neg_part(&z)),
                )]
            } else {
                vec![(Parameter::new(&names[0], 0.0), Some(names[0].clone()))]
            };
            (TermTarget::Output(k), terms)
        }
        Place::State(eq) => {
            let pos = |n: &str| {
                s.states
                    .iter()
                    .position(|x| x.name == n)
                    .ok_or_else(|| bad(format!("no state '{n}'")))
            };
            let (i, j) = (pos(eq)?, pos(var)?);
            let x = cur
                .state_trajectory(&fit.inputs, Init::Stored)
                .map_err(core)?;
            let rate = s.substeps.max(1) as f64 / cur.sample_time().map_err(core)?;
            if kind == Kind::Overflow {
                // the limit on x_i first, then the spill of what it cuts off
                // into x_j (whose text reads the limit's parameter)
                let steps = [(Kind::Ceiling, i, i, 0), (Kind::Spill, j, i, 1)];
                for (k, to, from, n) in steps {
                    let terms = state_terms(&s, k, &names[n..=n], (to, from), &x, (rate, q));
                    push_terms(&mut s, TermTarget::State(to), terms)?;
                }
                return Ok(s);
            }
            let terms = state_terms(&s, kind, &names, (i, j), &x, (rate, q));
            (TermTarget::State(i), terms)
        }
    };
    push_terms(&mut s, target, terms)?;
    Ok(s)
}

/// Adds the new parameters to `s` and their terms to `target`.
fn push_terms(
    s: &mut PhysicsSpec,
    target: TermTarget,
    terms: Vec<NewParameter>,
) -> Result<(), DiagnoseError> {
    for (p, term) in terms {
        s.parameters.push(p);
        if let Some(t) = term {
            s.add_term(target, &t)
                .map_err(|e| DiagnoseError::from(gb_core::CoreError::from(e)))?;
        }
    }
    Ok(())
}

/// `cur`'s spec with the centred law `c2·w² + c3·w³` of state `var` added
/// to the equation of `eq` (for the blind mechanical template).
pub(super) fn with_centred_law(
    cur: &PhysicsModel,
    fit: &gb_core::Record,
    eq: &str,
    var: &str,
) -> Result<PhysicsSpec, DiagnoseError> {
    extended(
        cur,
        fit,
        (Kind::Centred, &Place::State(eq.into()), var),
        (1.0, Start::Warm),
    )
}

/// `cur`'s spec with dry friction `−f·tanh(x/ε)` of state `eq` added to
/// its own equation (for the blind templates).
pub(super) fn with_coulomb_law(
    cur: &PhysicsModel,
    fit: &gb_core::Record,
    eq: &str,
) -> Result<PhysicsSpec, DiagnoseError> {
    extended(
        cur,
        fit,
        (Kind::Coulomb, &Place::State(eq.into()), eq),
        (1.0, Start::Warm),
    )
}

/// The quantiles of the simulation a limit starts from (the starts race a
/// few iterations, the leaders are fitted in full and the lowest training
/// RMSE wins: the least-squares fit of a limit has local optima where it
/// stops binding; [`crate::physics::best_of_starts`]). Under
/// cross-validation only the fit on the whole fit block tries them all;
/// each fold refits the one that won there.
const LIMIT_STARTS: [f64; 4] = [0.8, 0.9, 0.95, 0.99];

/// Where an extension's fit starts: at the current model's estimates, or
/// at the start values the current model was fitted from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Start {
    Warm,
    Cold,
}

/// The starts of a limit's fit in the engineer's model: each quantile of
/// [`LIMIT_STARTS`] from the current estimates, then from the start values
/// they were fitted from. A direction the data do not determine (the scale
/// of an unmeasured level, `x₁ → a·x₁` with the outflow and inflow
/// coefficients rescaled) can leave the estimates where the law is steep
/// and the limit's landscape rough: two tanks whose upper one overflows
/// into the lower, fitted from the plain model's estimates (upper level
/// 0.01–0.35), reach NRMSE 0.005–0.19 depending on the limit's start;
/// from the file's start values (levels of a few units) 0.0016 from every
/// start. The blind template keeps the warm starts only. The starts race
/// (eight iterations each); the two leaders of the engineer's model, the
/// leader of the template, are fitted in full.
fn limit_starts(cur: &PhysicsModel) -> Vec<(f64, Start)> {
    let warm = LIMIT_STARTS.iter().map(|&q| (q, Start::Warm));
    if spec_is_template(&cur.spec().name) {
        return warm.collect();
    }
    warm.chain(LIMIT_STARTS.iter().map(|&q| (q, Start::Cold)))
        .collect()
}

/// What a candidate adds, in words.
fn describe(kind: Kind, at: &Place, var: &str, names: &[String]) -> String {
    let p = |k: usize| names.get(k).map_or("?", String::as_str);
    let lhs = at.label();
    match kind {
        Kind::Poly => format!(
            "{lhs} += {}·s² + {}·s³, s = {var}/max|{var}| of its simulation",
            p(0),
            p(1)
        ),
        Kind::Centred => format!(
            "{lhs} += {}·w² + {}·w³, w = ({var} − mid)/half-range of its simulation",
            p(0),
            p(1)
        ),
        Kind::Hinge => format!(
            "{lhs} += {}·max({var} − q90, 0) + {}·max(q10 − {var}, 0) at the quantiles of the simulated {var}",
            p(0),
            p(1)
        ),
        Kind::Coulomb => format!(
            "{lhs} −= {}·tanh({var}/{}) (dry friction against the motion, ε started at 5 % of the rms of the simulated {var})",
            p(0),
            p(1)
        ),
        Kind::Ceiling => format!(
            "an upper limit {} on {var} ({lhs} = min(law, (limit − {var})/step): an overflow, an end stop)",
            p(0)
        ),
        Kind::Floor => format!(
            "a lower limit {} on {var} ({lhs} = max(law, (limit − {var})/step): an empty tank, an end stop)",
            p(0)
        ),
        Kind::Spill => format!(
            "{lhs} += {}·(what the limit of {var} cuts off): the overflow of {var} flows on",
            p(0)
        ),
        Kind::Overflow => {
            let own = match at {
                Place::State(s) | Place::Output(s) => s,
            };
            format!(
                "an upper limit {} on {own} ({lhs} = min(law, (limit − {own})/step)) whose cut-off inflow runs into {var} by a fraction {}: an overflow into the next state",
                p(0),
                p(1)
            )
        }
        Kind::Offset => format!("{lhs} += {} (a sensor offset)", p(0)),
        Kind::Clip => format!("{lhs} = min(g, {}) (a sensor range)", p(0)),
    }
}

/// Every place and variable a kind can go to in `spec`.
fn places(spec: &PhysicsSpec, kind: Kind) -> Vec<(Place, String)> {
    let mut out = vec![];
    if matches!(kind, Kind::Offset | Kind::Clip) {
        for o in &spec.outputs {
            out.push((Place::Output(o.name.clone()), String::new()));
        }
        return out;
    }
    for eq in &spec.states {
        for var in &spec.states {
            out.push((Place::State(eq.name.clone()), var.name.clone()));
        }
    }
    out
}

impl Extension for PhysicsTerms {
    fn fit_cost(&self) -> u8 {
        2
    }
    fn name(&self) -> &'static str {
        "physics-terms"
    }
    fn cause(&self) -> Cause {
        Cause::Nonlinearity
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        let Some((m, base)) = current_physics(ctx) else {
            return vec![];
        };
        let spec = m.spec();
        let mut out = vec![];
        for kind in Kind::ALL {
            for (at, var) in places(spec, kind) {
                if !applies(spec, kind, &at, &var) {
                    continue;
                }
                let text = describe(kind, &at, &var, &kind.parameters(&at, &var));
                out.push(Proposal {
                    cause: Cause::Nonlinearity,
                    lineage: Lineage::Other {
                        spec: format!("{base}{}", marker(kind, &at, &var)),
                        order: spec.states.len(),
                    },
                    text: format!(
                        "{text} in the model '{}', every parameter refitted",
                        spec.name
                    ),
                });
            }
        }
        out
    }
    /// Started from the current model's estimates (of this fold under
    /// cross-validation) with the new coefficients at 0 and new limits at
    /// each quantile of [`LIMIT_STARTS`] of the simulation (in a fold only
    /// at the one the whole fit block chose). On the whole fit block of the
    /// blind template a fit that has not lowered the training RMSE by the
    /// policy's `futile_gain` after four iterations (a law) or its race (a
    /// limit) stops there: it could not pass the in-sample screen.
    fn fit_choosing(
        &self,
        p: &Proposal,
        ctx: &Context,
    ) -> Result<(FittedModel, Option<usize>), DiagnoseError> {
        let bad = |m: &str| DiagnoseError::InvalidArgument(format!("physics-terms: {m}"));
        let cur = physics_of(&ctx.current.model).ok_or_else(|| bad("not a physics model"))?;
        let (kind, at, var) = target(p).ok_or_else(|| bad("no target in the proposal"))?;
        let rec = physics_fit_record(ctx, cur);
        if !matches!(
            kind,
            Kind::Ceiling | Kind::Floor | Kind::Clip | Kind::Overflow
        ) {
            let s = extended(cur, &rec, (kind, &at, &var), (1.0, Start::Warm))?;
            let m = fit_physics_screened(&s, &rec, ctx.observer, ctx.futile_gain)?;
            return Ok((m, None));
        }
        let starts = limit_starts(cur);
        let futile = ctx
            .futile_gain
            .filter(|_| spec_is_template(&cur.spec().name))
            .and_then(|g| rmse_on(cur, &rec).map(|b| (b, g)));
        best_of_starts(
            starts.len(),
            ctx.start_choice,
            |i| extended(cur, &rec, (kind, &at, &var), starts[i]),
            &rec,
            ctx.observer,
            futile,
        )
    }
    fn evidence(&self, _p: &Proposal, ctx: &Context) -> String {
        ctx.evidence.nonlinearity_text()
    }
    fn row_text(&self, p: &Proposal, fitted: &FittedModel) -> String {
        physics_row_text(p, fitted)
    }
}
