//! More capacity for the hidden-state model once it was chosen: finer
//! sub-steps and wavelet levels, fitted on more of the fit block.
use crate::evaluate::Lineage;
use crate::extension::{Context, Extension, Proposal, Role};
use crate::{Cause, DiagnoseError};
use gb_core::FittedModel;

/// The hidden-state model of the escalation fitted again with more
/// capacity (`gb_model::recipes::refine_hidden_state`: the mechanical
/// structure with 8 sub-steps and wavelet levels 1–4, or the black-box
/// structure with one more level), on at most the policy's
/// `nonlinear_fit_samples` of the fit block (the escalation itself sees at
/// most `hidden_state_fit_samples`). A refinement of the cause the
/// escalation answered: it must pay on the decision data like any
/// candidate, and a new cause must beat it. Tried once, and not when the
/// decisions use cross-validation (short or non-stationary records: on
/// generated bouc-wen seed 7, 540 samples, the folds said +48 % and the
/// validation record got worse, 0.31 → 0.45).
pub struct HiddenStateDetail;

impl Extension for HiddenStateDetail {
    fn name(&self) -> &'static str {
        "hidden-state-detail"
    }
    fn cause(&self) -> Cause {
        Cause::Hysteresis
    }
    fn role(&self) -> Role {
        Role::Refinement
    }
    fn once(&self) -> bool {
        true
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        // more capacity needs more data: under cross-validation the record
        // is short (a select block under `bootstrap_min_samples`) or not
        // stationary, and up to 160 more coefficients would be fitted on
        // folds of a few hundred samples
        if ctx.plan.cv() {
            return vec![];
        }
        let Lineage::HiddenState {
            order,
            hysteresis,
            detail: 0,
        } = ctx.current.lineage
        else {
            return vec![];
        };
        let cause = if hysteresis {
            Cause::Hysteresis
        } else {
            Cause::Dynamics
        };
        vec![Proposal {
            cause,
            lineage: Lineage::HiddenState {
                order,
                hysteresis,
                detail: 1,
            },
            text: format!(
                "more capacity for the hidden-state model of the named {cause}: finer sub-steps and wavelet levels 1-4, fitted on up to {} samples of the fit block",
                ctx.policy().nonlinear_fit_samples
            ),
        }]
    }
    fn fit(&self, p: &Proposal, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
        let Lineage::HiddenState { hysteresis, .. } = p.lineage else {
            return Err(DiagnoseError::InvalidArgument(
                "not a hidden-state proposal".into(),
            ));
        };
        let current = crate::plan::core(&ctx.current.model)
            .as_any()
            .downcast_ref::<gb_model::SparseStateSpace>()
            .ok_or_else(|| {
                DiagnoseError::InvalidArgument(
                    "the current model is not a hidden-state model".into(),
                )
            })?;
        let n = ctx.fit.len().min(ctx.policy().nonlinear_fit_samples);
        let sub = ctx.fit.slice(0..n);
        let ss =
            gb_model::recipes::refine_hidden_state(current, &sub.inputs, &sub.output, hysteresis)?;
        super::hidden_state::state_space_model(ss, &sub)
    }
    fn evidence(&self, _p: &Proposal, ctx: &Context) -> String {
        let ev = ctx.evidence;
        format!(
            "the hidden-state model leaves the residuals non-white (Ljung-Box Q={:.0}, p={:.1e}; memory F={:.1}, p={:.1e})",
            ev.ljung_box.0, ev.ljung_box.1, ev.memory.0, ev.memory.1
        )
    }
    fn row_text(&self, p: &Proposal, fitted: &FittedModel) -> String {
        format!("{} -> {}", p.text, fitted.dynamics.describe())
    }
}
