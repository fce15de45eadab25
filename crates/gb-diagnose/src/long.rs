//! Long records (the policy's `long_record` training samples or more): the
//! structure is searched on a subsample within a time budget, then the
//! baseline and the final structure are refitted on the whole fit block
//! (Levenberg–Marquardt started from the subsample's models) and every
//! model of the chain is scored on the whole select and report blocks.
use crate::diagnose::{assemble, search, Diagnosis};
use crate::evaluate::{evaluate_on, Evaluated};
use crate::plan::{core, Plan};
use crate::{DiagnoseData, DiagnoseError, DiagnoseOptions};
use gb_core::{FittedModel, Observer};
use std::time::{Duration, Instant};

/// The subsample the structure is searched on: the first `n` training
/// samples (fit/select 75/25) and at most `n / 2` report samples.
pub(crate) fn subsample(d: &DiagnoseData, n: usize) -> DiagnoseData {
    let start = d.fit.start;
    let train = d.train.slice(start..start + n);
    let fit_end = n * 3 / 4;
    let report = if d.single_record {
        d.report.slice(d.report_range.clone())
    } else {
        d.report.clone()
    };
    let r = report.len().min((n / 2).max(1));
    DiagnoseData {
        train,
        fit: 0..fit_end,
        select: fit_end..n,
        report: report.slice(0..r),
        report_range: 0..r,
        single_record: false,
        more: vec![],
        names: vec![],
        listed: false,
        report_is_training: false,
    }
}

/// Refit an input–output model on the plan's (whole) fit record, started
/// from `m`; `None` when it is of another class or the refit fails.
fn refit(m: &FittedModel, plan: &Plan, opts: &DiagnoseOptions) -> Option<FittedModel> {
    let net = core(m)
        .as_any()
        .downcast_ref::<gb_lmn::LocalModelNetwork>()?;
    let fit = &plan.fit;
    let o = gb_lmn::FitOptions {
        max_iter: opts.policy.refit_iterations,
        ..opts.fit.clone()
    };
    let (net, _) = gb_lmn::refine_output_error(net, &fit.inputs, &fit.output, &o).ok()?;
    let m = crate::extension::io_model(net, fit).ok()?;
    plan.finish(m, None).ok()
}

/// The diagnosis of a long record (see the module docs).
pub(crate) fn diagnose_long(
    d: &DiagnoseData,
    opts: &DiagnoseOptions,
    obs: &dyn Observer,
) -> Result<Diagnosis, DiagnoseError> {
    let pol = &opts.policy;
    let sub = subsample(d, pol.search_samples);
    let deadline = Instant::now() + Duration::from_secs_f64(pol.search_budget_s);
    let found = search(&sub, opts, obs, Some(deadline), false)?;
    let integrating = found.report.baseline.integrating;
    let plan = Plan::new(d, pol).integrating(integrating);
    let last = found.chain.len() - 1;
    let mut chain: Vec<Evaluated> = Vec::with_capacity(found.chain.len());
    for (i, e) in found.chain.into_iter().enumerate() {
        let finding = e.finding.clone();
        let mut sub_model = evaluate_on(e.model, e.lineage.clone(), d, plan.w, None)?;
        sub_model.finding = finding;
        let refitted = if i == 0 || i == last {
            refit(&sub_model.model, &plan, opts)
                .and_then(|m| evaluate_on(m, e.lineage.clone(), d, plan.w, None).ok())
        } else {
            None
        };
        chain.push(match refitted {
            Some(r) if r.scores.nrmse_select <= sub_model.scores.nrmse_select => r,
            _ => sub_model,
        });
    }
    let mut structure = found.report.structure;
    structure.decision = format!(
        "{}; structure searched on the first {} training samples ({} s budget), baseline and final structure refitted on all {} fit samples",
        sub_decision(&structure.decision),
        pol.search_samples,
        pol.search_budget_s,
        plan.fit.len()
    );
    let mut dg = assemble(
        d,
        &plan,
        (chain, None),
        found.report.steps,
        found.report.causes,
        structure,
        pol,
    );
    dg.report.data.decision = dg.report.structure.decision.clone();
    Ok(dg)
}

fn sub_decision(s: &str) -> String {
    format!("subsample: {s}")
}
