//! The baseline's structure on its own, for `greybox fit --order auto`:
//! the same selection the diagnosis makes before its first step.
use crate::baseline::{baseline, StructureChoice};
use crate::plan::Plan;
use crate::{DiagnoseData, DiagnoseError, DiagnoseOptions};

/// The structure [`choose_structure`] chose.
#[derive(Debug, Clone)]
pub struct ChosenStructure {
    /// The chosen linear order.
    pub order: usize,
    /// The decision NRMSE of the chosen linear output-error model.
    pub nrmse_select: f64,
    /// How it was chosen: the delay per input, the integrator test and (with
    /// `OrderChoice::Auto`) every order tried with its decision NRMSE.
    pub choice: StructureChoice,
}

/// The order, input delay and integrator of the diagnosis' baseline on `d`,
/// chosen exactly as [`crate::diagnose`] chooses them (on the training
/// record's fit and select blocks; long records on the same subsample),
/// without the extension steps.
pub fn choose_structure(
    d: &DiagnoseData,
    opts: &DiagnoseOptions,
) -> Result<ChosenStructure, DiagnoseError> {
    opts.check()?;
    let pol = &opts.policy;
    d.check(pol.min_fit, pol.min_block)?;
    let long = !d.multi() && d.select.end - d.fit.start >= pol.long_record;
    let sub;
    let d = if long {
        sub = crate::long::subsample(d, pol.search_samples);
        &sub
    } else {
        d
    };
    let plan = Plan::new(d, pol);
    let b = baseline(d, &plan, opts)?;
    let mut choice = b.choice;
    choice.decision = plan.describe(d);
    if long {
        choice.decision = format!(
            "subsample of the first {} training samples: {}",
            pol.search_samples, choice.decision
        );
    }
    Ok(ChosenStructure {
        order: b.eval.lineage.order(),
        nrmse_select: b.eval.scores.nrmse_select,
        choice,
    })
}
