//! `nonlinearity` in the engineer's own equations: a black-box term added
//! to one state equation of a physics model, the physical parameters
//! re-estimated with it.
use crate::evaluate::Lineage;
use crate::extension::{Context, Extension, Proposal};
use crate::physics::{fit_physics, parameters_text, physics_of};
use crate::{Cause, DiagnoseError};
use gb_core::{FittedModel, Init};
use gb_model::physics::{Parameter, PhysicsModel, PhysicsSpec, TermTarget};

/// For every state equation `ẋᵢ = fᵢ(x, u, θ)` with a free parameter (a
/// definition such as `ẋ = v` is left alone) and every state `x_s`, three
/// candidates, each with new free parameters started at 0 and every
/// physical parameter refitted from the current estimates:
///
/// * `poly`: `ẋᵢ += a2·s² + a3·s³` with `s = x_s/h` scaled by the largest
///   |x_s| of the simulated state (a smooth nonlinear spring, damper or
///   flow law; no constant or linear part, which the physical parameters
///   own);
/// * `centred`: `ẋᵢ += c2·w² + c3·w³` with `w = (x_s − mid)/half` centred
///   on the simulated range (a law whose offset and slope come with it,
///   e.g. a flow that changes with the level);
/// * `hinge`: `ẋᵢ += b_hi·max(x_s − q₉₀, 0) + b_lo·max(q₁₀ − x_s, 0)` with
///   the 10 % and 90 % quantiles of the simulated state (a limit: an
///   overflow, an end stop, a saturation).
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
}

impl Kind {
    const ALL: [Kind; 3] = [Kind::Poly, Kind::Centred, Kind::Hinge];

    fn name(self) -> &'static str {
        match self {
            Kind::Poly => "poly",
            Kind::Centred => "centred",
            Kind::Hinge => "hinge",
        }
    }
    /// The new parameters' names for equation `eq` and variable `var`.
    fn parameters(self, eq: &str, var: &str) -> [String; 2] {
        match self {
            Kind::Poly => [format!("a2_{eq}_{var}"), format!("a3_{eq}_{var}")],
            Kind::Centred => [format!("c2_{eq}_{var}"), format!("c3_{eq}_{var}")],
            Kind::Hinge => [format!("b_hi_{eq}_{var}"), format!("b_lo_{eq}_{var}")],
        }
    }
}

/// The marker of an added term in a lineage spec: ` + poly(x) in dv/dt`.
fn marker(kind: Kind, eq: &str, var: &str) -> String {
    format!(" + {}({var}) in d{eq}/dt", kind.name())
}

/// The kind, equation and variable of a proposal, from its lineage spec.
fn target(p: &Proposal) -> Option<(Kind, String, String)> {
    let Lineage::Other { spec, .. } = &p.lineage else {
        return None;
    };
    let last = spec.rsplit(" + ").next()?;
    let (kind, rest) = last.split_once('(')?;
    let kind = Kind::ALL.into_iter().find(|k| k.name() == kind)?;
    let (var, rest) = rest.split_once(") in d")?;
    let eq = rest.strip_suffix("/dt")?;
    Some((kind, eq.to_string(), var.to_string()))
}

/// Whether `spec` can take the terms: their parameters are new, and the
/// equation of `eq` has a free parameter (an equation without one, such as
/// `ẋ = v`, is a definition, not a law the data could correct).
fn applies(spec: &PhysicsSpec, kind: Kind, eq: &str, var: &str) -> bool {
    let names = kind.parameters(eq, var);
    if spec.parameters.iter().any(|p| names.contains(&p.name)) {
        return false;
    }
    let Some(i) = spec.states.iter().position(|s| s.name == eq) else {
        return false;
    };
    let symbols: Vec<&str> = spec.equations[i]
        .iter()
        .flat_map(|t| t.split(|c: char| !(c.is_alphanumeric() || c == '_')))
        .collect();
    spec.parameters
        .iter()
        .any(|p| !p.fixed && symbols.contains(&p.name.as_str()))
}

/// The value at quantile `q` of `v` (sorted copy, nearest rank).
fn quantile(v: &[f64], q: f64) -> f64 {
    let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    s.sort_by(f64::total_cmp);
    if s.is_empty() {
        return 0.0;
    }
    s[((q * (s.len() - 1) as f64).round() as usize).min(s.len() - 1)]
}

/// The terms of `kind` in the state trajectory `x` (of `var`), as
/// expressions of the new parameters.
fn terms(kind: Kind, names: &[String; 2], var: &str, x: &[f64]) -> [String; 2] {
    match kind {
        Kind::Poly => {
            let h = x
                .iter()
                .filter(|v| v.is_finite())
                .fold(0.0_f64, |m, v| m.max(v.abs()))
                .max(1e-300);
            let s = format!("({var}/{h})");
            [format!("{}*{s}^2", names[0]), format!("{}*{s}^3", names[1])]
        }
        Kind::Centred => {
            let (lo, hi) = (quantile(x, 0.0), quantile(x, 1.0));
            let c = 0.5 * (lo + hi);
            let h = (0.5 * (hi - lo)).max(1e-12 * c.abs().max(1.0));
            let w = format!("(({var}-({c}))/{h})");
            [format!("{}*{w}^2", names[0]), format!("{}*{w}^3", names[1])]
        }
        Kind::Hinge => {
            let (q10, q90) = (quantile(x, 0.1), quantile(x, 0.9));
            [
                format!("{}*max({var}-({q90}),0)", names[0]),
                format!("{}*max(({q10})-{var},0)", names[1]),
            ]
        }
    }
}

/// `cur`'s spec started at its estimates with the terms of `kind` in the
/// equation of `eq`, normalised on `cur`'s simulation of `fit`.
fn extended(
    cur: &PhysicsModel,
    fit: &gb_core::Record,
    kind: Kind,
    eq: &str,
    var: &str,
) -> Result<PhysicsSpec, DiagnoseError> {
    let bad = |m: String| DiagnoseError::InvalidArgument(format!("physics-terms: {m}"));
    let spec = cur.spec();
    let i = spec
        .states
        .iter()
        .position(|s| s.name == eq)
        .ok_or_else(|| bad(format!("no state '{eq}'")))?;
    let j = spec
        .states
        .iter()
        .position(|s| s.name == var)
        .ok_or_else(|| bad(format!("no state '{var}'")))?;
    let x = cur
        .state_trajectory(&fit.inputs, Init::Stored)
        .map_err(gb_core::CoreError::from)?;
    let mut s = cur
        .with_start_at_values()
        .map_err(gb_core::CoreError::from)?
        .spec()
        .clone();
    let names = kind.parameters(eq, var);
    for (n, t) in names.iter().zip(terms(kind, &names, var, &x[j])) {
        s.parameters.push(Parameter::new(n, 0.0));
        s.add_term(TermTarget::State(i), &t)
            .map_err(gb_core::CoreError::from)?;
    }
    Ok(s)
}

impl Extension for PhysicsTerms {
    fn name(&self) -> &'static str {
        "physics-terms"
    }
    fn cause(&self) -> Cause {
        Cause::Nonlinearity
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        let Some(m) = physics_of(&ctx.current.model) else {
            return vec![];
        };
        let Lineage::Other { spec: base, .. } = &ctx.current.lineage else {
            return vec![];
        };
        let spec = m.spec();
        let mut out = vec![];
        for kind in Kind::ALL {
            for eq in &spec.states {
                for var in &spec.states {
                    let (e, v) = (eq.name.as_str(), var.name.as_str());
                    if !applies(spec, kind, e, v) {
                        continue;
                    }
                    let [p1, p2] = kind.parameters(e, v);
                    let text = match kind {
                        Kind::Poly => format!(
                            "d{e}/dt += {p1}·s² + {p2}·s³, s = {v}/max|{v}| of its simulation"
                        ),
                        Kind::Centred => format!(
                            "d{e}/dt += {p1}·w² + {p2}·w³, w = ({v} − mid)/half-range of its simulation"
                        ),
                        Kind::Hinge => format!(
                            "d{e}/dt += {p1}·max({v} − q90, 0) + {p2}·max(q10 − {v}, 0) at the quantiles of the simulated {v}"
                        ),
                    };
                    out.push(Proposal {
                        cause: Cause::Nonlinearity,
                        lineage: Lineage::Other {
                            spec: format!("{base}{}", marker(kind, e, v)),
                            order: spec.states.len(),
                        },
                        text: format!("{text} in the user's model, every parameter refitted"),
                    });
                }
            }
        }
        out
    }
    /// Started from the current model's estimates (of this fold under
    /// cross-validation) with the new coefficients at 0.
    fn fit(&self, p: &Proposal, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
        let bad = |m: &str| DiagnoseError::InvalidArgument(format!("physics-terms: {m}"));
        let cur = physics_of(&ctx.current.model).ok_or_else(|| bad("not a physics model"))?;
        let (kind, eq, var) = target(p).ok_or_else(|| bad("no target in the proposal"))?;
        let s = extended(cur, ctx.fit, kind, &eq, &var)?;
        fit_physics(&s, ctx.fit, ctx.observer)
    }
    fn evidence(&self, _p: &Proposal, ctx: &Context) -> String {
        ctx.evidence.nonlinearity_text()
    }
    fn row_text(&self, p: &Proposal, fitted: &FittedModel) -> String {
        let params = physics_of(fitted).map_or(String::new(), parameters_text);
        format!("{} -> {params}", p.text)
    }
}
