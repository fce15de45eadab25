//! `nonlinearity` in the engineer's own equations: a black-box term added
//! to one state equation of a physics model, the physical parameters
//! re-estimated with it.
use crate::evaluate::Lineage;
use crate::extension::{Context, Extension, Proposal};
use crate::physics::{fit_physics, parameters_text, physics_of};
use crate::{Cause, DiagnoseError};
use gb_core::FittedModel;
use gb_model::physics::{Parameter, PhysicsSpec, TermTarget};

/// For every state equation `ẋᵢ = fᵢ(x, u, θ)` and every state `x_s`, the
/// candidate `ẋᵢ = fᵢ + aᵢₛ₂ x_s² + aᵢₛ₃ x_s³` (new free parameters
/// `a2_i_s`, `a3_i_s`, started at 0), refitted by output error from the
/// current estimates with every physical parameter free again. The
/// physical parameters keep their names in the extended model.
pub struct PhysicsTerms;

/// The marker of an added term in a lineage spec: `+ poly(s) in d(i)/dt`.
fn marker(eq: &str, var: &str) -> String {
    format!(" + poly({var}) in d{eq}/dt")
}

/// The equation and variable of a proposal, from its lineage spec.
fn target(p: &Proposal) -> Option<(String, String)> {
    let Lineage::Other { spec, .. } = &p.lineage else {
        return None;
    };
    let last = spec.rsplit(" + poly(").next()?;
    let (var, rest) = last.split_once(") in d")?;
    let eq = rest.strip_suffix("/dt")?;
    Some((eq.to_string(), var.to_string()))
}

/// `spec` with `a2·var² + a3·var³` added to the equation of `eq`; `None`
/// when those parameters exist already.
fn extended(spec: &PhysicsSpec, eq: &str, var: &str) -> Option<PhysicsSpec> {
    let i = spec.states.iter().position(|s| s.name == eq)?;
    let (a2, a3) = (format!("a2_{eq}_{var}"), format!("a3_{eq}_{var}"));
    if spec.parameters.iter().any(|p| p.name == a2 || p.name == a3) {
        return None;
    }
    let mut s = spec.clone();
    s.parameters.push(Parameter::new(&a2, 0.0));
    s.parameters.push(Parameter::new(&a3, 0.0));
    s.add_term(TermTarget::State(i), &format!("{a2}*{var}^2"))
        .ok()?;
    s.add_term(TermTarget::State(i), &format!("{a3}*{var}^3"))
        .ok()?;
    Some(s)
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
        for eq in &spec.states {
            for var in &spec.states {
                if extended(spec, &eq.name, &var.name).is_none() {
                    continue;
                }
                let mark = marker(&eq.name, &var.name);
                out.push(Proposal {
                    cause: Cause::Nonlinearity,
                    lineage: Lineage::Other {
                        spec: format!("{base}{mark}"),
                        order: spec.states.len(),
                    },
                    text: format!(
                        "d{0}/dt += a2_{0}_{1}·{1}² + a3_{0}_{1}·{1}³ in the user's model, every parameter refitted",
                        eq.name, var.name
                    ),
                });
            }
        }
        out
    }
    /// Started from the current model's estimates (of this fold under
    /// cross-validation) with the new coefficients at 0.
    fn fit(&self, p: &Proposal, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
        let bad = |m: &str| DiagnoseError::InvalidArgument(format!("physics-terms: {m}"));
        let cur = physics_of(&ctx.current.model).ok_or_else(|| bad("not a physics model"))?;
        let (eq, var) = target(p).ok_or_else(|| bad("no target in the proposal"))?;
        let mut start = cur.spec().clone();
        for (par, v) in start.parameters.iter_mut().zip(cur.parameters()) {
            par.value = v.clamp(par.lower, par.upper);
        }
        for (st, v) in start.states.iter_mut().zip(cur.initial_state()) {
            st.initial = v.clamp(st.lower, st.upper);
        }
        let s = extended(&start, &eq, &var).ok_or_else(|| bad("the terms exist already"))?;
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
