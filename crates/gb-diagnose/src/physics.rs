//! The engineer's own equations as the baseline of a diagnosis (a model
//! file of gb-model's `physics` class): fitted by output error on the
//! plan's record (and every fold), scored on its residuals like any
//! baseline; [`crate::extensions::PhysicsTerms`] extends its equations.
use crate::baseline::{Baseline, StructureChoice};
use crate::evaluate::Lineage;
use crate::plan::{assess, Plan};
use crate::{DiagnoseData, DiagnoseError};
use gb_core::{CoreError, FittedModel, Observer, Record, Records};
use gb_model::physics::{PhysicsFitParams, PhysicsModel, PhysicsSpec};

/// The lineage spec of a physics model: `physics 'NAME'` and its added
/// terms.
pub(crate) fn lineage_of(spec: &PhysicsSpec, added: &str) -> Lineage {
    Lineage::Other {
        spec: format!("physics '{}'{added}", spec.name),
        order: spec.states.len(),
    }
}

/// Output-error fit of `spec` on `rec` (its start values are the start),
/// as a fitted model with the Gaussian noise of σ̂.
pub(crate) fn fit_physics(
    spec: &PhysicsSpec,
    rec: &Record,
    obs: &dyn Observer,
) -> Result<FittedModel, DiagnoseError> {
    let mut spec = spec.clone();
    if spec.sample_time.is_none() {
        spec.sample_time = rec.sample_time;
    }
    let m = PhysicsFitParams::new(spec)
        .check()
        .map_err(CoreError::from)?
        .identify_growing(&Records::single(rec.clone()), obs)
        .map_err(CoreError::from)?;
    Ok(m.to_fitted().map_err(CoreError::from)?)
}

/// The physics model of a fitted model, if it is one.
pub(crate) fn physics_of(m: &FittedModel) -> Option<&PhysicsModel> {
    m.dynamics.as_any().downcast_ref::<PhysicsModel>()
}

/// The parameters of a fitted physics model in words:
/// `m = 1.002 ± 0.004, c = …` (± one standard error; fixed ones marked).
pub(crate) fn parameters_text(m: &PhysicsModel) -> String {
    match m.fit_report() {
        Some(r) => r
            .estimates
            .iter()
            .filter(|e| matches!(e.what, gb_model::physics::Coordinate::Parameter(_)))
            .map(|e| {
                if e.fixed {
                    format!("{} = {:.4e} (fixed)", e.name, e.value)
                } else {
                    format!("{} = {:.4e} ± {:.2e}", e.name, e.value, e.std_error)
                }
            })
            .collect::<Vec<_>>()
            .join(", "),
        None => m
            .spec()
            .parameters
            .iter()
            .zip(m.parameters())
            .map(|(p, v)| format!("{} = {v:.4e}", p.name))
            .collect::<Vec<_>>()
            .join(", "),
    }
}

/// The baseline: the engineer's model file fitted on the plan's record
/// (and refitted on every fold under cross-validation).
pub(crate) fn physics_baseline(
    d: &DiagnoseData,
    plan: &Plan,
    spec: &PhysicsSpec,
    obs: &dyn Observer,
) -> Result<Baseline, DiagnoseError> {
    let eval = assess(plan, d, lineage_of(spec, ""), &|t| {
        fit_physics(spec, plan.fit_of(t), obs)
    })?;
    let params = physics_of(&eval.model).map_or(String::new(), parameters_text);
    let choice = StructureChoice {
        user_model: Some(format!(
            "the user's model file '{}' ({} states: {}), fitted by output error: {params}",
            spec.name,
            spec.states.len(),
            spec.states
                .iter()
                .map(|s| s.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        )),
        ..StructureChoice::default()
    };
    Ok(Baseline {
        eval,
        plan: plan.clone(),
        choice,
    })
}
