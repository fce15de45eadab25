//! `hysteresis` inside the engineer's equations: a hysteretic internal
//! state driven by one state, added to a law, every parameter refitted.
use super::physics_terms::{is_law, quantile, sum_text};
use crate::evaluate::Lineage;
use crate::extension::{Context, Extension, Proposal};
use crate::physics::physics_row_text;
use crate::physics::{best_of_starts, current_physics, physics_fit_record, physics_of};
use crate::{Cause, DiagnoseError};
use gb_core::{FittedModel, Init};
use gb_model::physics::{Parameter, PhysicsModel, PhysicsSpec, State, TermTarget};

/// A hysteretic state `ζ` (the Bouc–Wen law with exponent 1) driven by
/// the rate of a kinematic state `x_s` (its equation has no free
/// parameter, e.g. a position with `ẋ = v`), entering a law `ẋᵢ` with a
/// free weight:
///
/// ```text
/// ζ̇ = ẋ_s − (b/h)·|ẋ_s|·ζ − (c/h)·ẋ_s·|ζ|,   ẋᵢ += w·ζ,   ζ(0) = 0
/// ```
///
/// `ẋ_s` is the right-hand side of `x_s`'s own equation and `h` the half
/// range of `x_s` in the current model's simulation, so `ζ` is in the
/// units of `x_s` and `b`, `c` are dimensionless: for `b + c > 0` the loop
/// saturates at `|ζ| = h/(b + c)` (a yielding spring, friction), for
/// `b + c < 0` it hardens (the Bouc–Wen benchmark: `b/h = βγ`,
/// `c/h = βδ`, `w` the ratio `α`). New free parameters `w` (start 0), `b`
/// (starts 2 and 8, the better fit kept) and `c` (start 0), `b, c` in
/// `[−1000, 1000]`. Proposed only when the direction-of-motion memory test
/// rejects on the current residuals at the policy's `memory_priority_p`.
/// A spring or damper force that depends on the direction of motion (the
/// thesis' hysteresis inside the dynamics, chapter 4).
pub struct PhysicsHysteresis;

const KIND: &str = "hysteresis";

/// Starts of `b` (saturations over the half range, with `c = 0`).
pub(super) const B_STARTS: [f64; 2] = [2.0, 8.0];

/// Names of the new state and parameters for law `eq` and driver `var`.
fn names(eq: &str, var: &str) -> [String; 4] {
    [
        format!("zh_{eq}_{var}"),
        format!("w_h_{eq}_{var}"),
        format!("b_h_{eq}_{var}"),
        format!("c_h_{eq}_{var}"),
    ]
}

/// Whether state `name` is a hysteretic state this extension added (not a
/// law or driver of another one).
pub(super) fn is_added_state(name: &str) -> bool {
    name.starts_with("zh_")
}

/// `(law i, driver s)` pairs: a law with a free parameter and a kinematic
/// state (one whose equation has no free parameter, such as `ẋ = v`: the
/// position behind a spring or friction force), neither an added
/// hysteretic state, whose names are new. Hysteresis is rate-independent
/// memory of a displacement: driven by a velocity or a level (EMPS: a
/// state driven by `v` gains +0.65 on the select block and triples the
/// test error; cascaded tanks: one driven by the upper level pays under
/// cross-validation and loses on the report block), it acts as a generic
/// extra dynamic state.
fn pairs(spec: &PhysicsSpec) -> Vec<(usize, usize)> {
    let used = |n: &str| {
        spec.parameters.iter().any(|p| p.name == n) || spec.states.iter().any(|x| x.name == n)
    };
    let mut out = vec![];
    for (i, eq) in spec.states.iter().enumerate() {
        if !is_law(spec, i) || is_added_state(&eq.name) {
            continue;
        }
        for (s, var) in spec.states.iter().enumerate() {
            if !is_law(spec, s)
                && !is_added_state(&var.name)
                && !names(&eq.name, &var.name).iter().any(|n| used(n))
            {
                out.push((i, s));
            }
        }
    }
    out
}

fn marker(eq: &str, var: &str) -> String {
    format!(" + {KIND}({var}) in d{eq}/dt")
}

/// The law and driver of a proposal, from its lineage spec.
fn target(p: &Proposal) -> Option<(String, String)> {
    let Lineage::Other { spec, .. } = &p.lineage else {
        return None;
    };
    let last = spec.rsplit(" + ").next()?;
    let rest = last.strip_prefix(KIND)?.strip_prefix('(')?;
    let (var, at) = rest.split_once(") in d")?;
    Some((at.strip_suffix("/dt")?.to_string(), var.to_string()))
}

/// `cur`'s spec at its estimates with the hysteretic state of law `eq`
/// driven by `var`, `b` started at `b0`.
pub(super) fn extended(
    cur: &PhysicsModel,
    fit: &gb_core::Record,
    (eq, var): (&str, &str),
    b0: f64,
) -> Result<PhysicsSpec, DiagnoseError> {
    let bad = |m: String| DiagnoseError::InvalidArgument(format!("physics-hysteresis: {m}"));
    let core =
        |e: gb_model::physics::PhysicsError| DiagnoseError::from(gb_core::CoreError::from(e));
    let mut s = cur.with_start_at_values().map_err(core)?.spec().clone();
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
    let h = (0.5 * (quantile(&x[j], 1.0) - quantile(&x[j], 0.0))).max(1e-300);
    let [z, w, b, c] = names(eq, var);
    let rate = sum_text(&s.equations[j]);
    let law = format!("({rate})-{b}/{h}*abs({rate})*{z}-{c}/{h}*({rate})*abs({z})");
    s.parameters.push(Parameter::new(&w, 0.0));
    s.parameters
        .push(Parameter::new(&b, b0).bounds(-1000.0, 1000.0));
    s.parameters
        .push(Parameter::new(&c, 0.0).bounds(-1000.0, 1000.0));
    s.states.push(State::new(&z, 0.0));
    s.equations.push(vec![law]);
    s.add_term(TermTarget::State(i), &format!("{w}*{z}"))
        .map_err(core)?;
    Ok(s)
}

/// `cur` with the hysteretic state of law `eq` driven by `var`, fitted on
/// `rec` from each start of `b` ([`B_STARTS`]), the best fit kept, and the
/// index of its start; in a fold of cross-validation only the start the
/// whole fit block chose (`ctx.start_choice`).
pub(super) fn fit_state(
    cur: &PhysicsModel,
    rec: &gb_core::Record,
    (eq, var): (&str, &str),
    ctx: &Context,
) -> Result<(FittedModel, Option<usize>), DiagnoseError> {
    best_of_starts(
        B_STARTS.len(),
        ctx.start_choice,
        |i| extended(cur, rec, (eq, var), B_STARTS[i]),
        rec,
        ctx.observer,
        None,
    )
}

impl Extension for PhysicsHysteresis {
    fn fit_cost(&self) -> u8 {
        2
    }
    fn name(&self) -> &'static str {
        "physics-hysteresis"
    }
    fn cause(&self) -> Cause {
        Cause::Hysteresis
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        let Some((m, base)) = current_physics(ctx) else {
            return vec![];
        };
        // no loop in the residual, no hysteresis: an extra state with three
        // parameters otherwise also pays as a generic dynamic correction
        // (cascaded tanks: +0.23 under cross-validation, worse on the
        // report block and the test set)
        if ctx.evidence.memory.1 >= ctx.policy().memory_priority_p {
            return vec![];
        }
        let spec = m.spec();
        pairs(spec)
            .into_iter()
            .map(|(i, s)| {
                let (eq, var) = (&spec.states[i].name, &spec.states[s].name);
                let [z, w, b, c] = names(eq, var);
                Proposal {
                    cause: Cause::Hysteresis,
                    lineage: Lineage::Other {
                        spec: format!("{base}{}", marker(eq, var)),
                        order: spec.states.len() + 1,
                    },
                    text: format!(
                        "d{eq}/dt += {w}·{z}, a hysteretic state driven by {var}: d{z}/dt = ẋ − {b}/h·|ẋ|·{z} − {c}/h·ẋ·|{z}|, ẋ = d{var}/dt, h its half range (Bouc–Wen) in the model '{}', every parameter refitted",
                        spec.name
                    ),
                }
            })
            .collect()
    }
    /// Started from the current model's estimates with `w = 0`, `c = 0` and
    /// each start of `b` (a fold: the one the whole block chose); the
    /// lowest training RMSE is kept.
    fn fit_choosing(
        &self,
        p: &Proposal,
        ctx: &Context,
    ) -> Result<(FittedModel, Option<usize>), DiagnoseError> {
        let bad = |m: &str| DiagnoseError::InvalidArgument(format!("physics-hysteresis: {m}"));
        let cur = physics_of(&ctx.current.model).ok_or_else(|| bad("not a physics model"))?;
        let (eq, var) = target(p).ok_or_else(|| bad("no target in the proposal"))?;
        let rec = physics_fit_record(ctx, cur);
        fit_state(cur, &rec, (&eq, &var), ctx)
    }
    fn evidence(&self, _p: &Proposal, ctx: &Context) -> String {
        ctx.evidence.hysteresis_text()
    }
    fn row_text(&self, p: &Proposal, fitted: &FittedModel) -> String {
        physics_row_text(p, fitted)
    }
}
