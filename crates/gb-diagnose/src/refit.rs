//! The final refit: the search chooses every structure on the fit block
//! and judges it on the held-out select block; the model a user keeps is
//! that structure fitted on the whole training record (fit and select
//! blocks: the usual hold-out protocol — choose on held-out data, then fit
//! the choice on everything the training record holds). On a short record
//! the fit block alone may not cover the input range the select block
//! reaches (a cubic input map then extrapolates linearly), or hold too few
//! periods of the slowest mode.
//!
//! The chain is refitted in order: the baseline (input–output models and
//! the engineer's equations), then each accepted extension fitted by its
//! own [`Extension`] on the refitted model before it, with the start or
//! map structure its fit on the fit block chose (the structure judged on
//! the select block is the one refitted). The refitted chain
//! replaces the fit-block fits only when every refit succeeded and the
//! final model's free-run squared error over the whole training record is
//! not larger,
//!
//! ```text
//! Σₖ (y_k − ŷ_k^refit)² ≤ Σₖ (y_k − ŷ_k^fit block)²,   k over fit ∪ select (after the init window),
//! ```
//!
//! which a refit that converged always satisfies (it minimises the left
//! side, the fit-block model is one of its candidates' neighbours) and a
//! refit that fell into a worse local minimum does not: a training-data
//! rule, the report block is not read. A chain with a noise model
//! (process noise, Student-t) is kept as fitted: that model's criterion is
//! not the squared simulation error.
use crate::evaluate::{evaluate_on, residuals_on, Evaluated, Lineage};
use crate::evidence::Evidence;
use crate::extension::{Context, Extension, Proposal};
use crate::plan::Plan;
use crate::{Cause, DiagnoseData, DiagnoseOptions};
use gb_core::{FittedModel, Observer};

/// An accepted step of the search: its cause, the extension and the
/// proposal it fitted.
pub(crate) type Pick = (Cause, &'static dyn Extension, Proposal);

/// The chain refitted on the whole training record (`None` inside when it
/// was not kept) and a sentence for the report's decisions line; `None`
/// when the refit does not apply (the policy turns it off, decisions used
/// cross-validation, which already fits on the whole record, there are
/// several training records, or the chain holds a noise model).
pub(crate) fn refit_chain(
    d: &DiagnoseData,
    plan: &Plan,
    chain: &[Evaluated],
    picks: &[Pick],
    opts: &DiagnoseOptions,
    obs: &dyn Observer,
) -> Option<(Option<Vec<Evaluated>>, String)> {
    if !opts.policy.refit_on_training || plan.cv() || d.multi() || d.select.is_empty() {
        return None;
    }
    let whole_y = d.train.slice(d.fit.start..d.select.end);
    let whole = plan_on(&whole_y, plan);
    let sse = |m: &FittedModel| free_run_sse(m, &whole_y, plan.w);
    let kept = |why: &str| {
        Some((
            None,
            format!(
                "; the chain refitted on the whole training record ({} samples: fit and select blocks) was not kept ({why}): the final model is the fit-block fit",
                whole_y.len()
            ),
        ))
    };
    if picks.iter().any(|(c, _, _)| *c == Cause::Noise) {
        // a noise model's criterion is not the squared simulation error
        return None;
    }
    let inputs = plan.decision_inputs(d);
    let out = match refit_over(&whole, (d, &inputs), chain, picks, opts, obs) {
        Ok(out) => out,
        Err(why) => return kept(&why),
    };
    let n = chain.len();
    let (before, after) = (sse(&chain[n - 1].model), sse(&out[n - 1].model));
    let scored = whole_y.len() - plan.w.min(whole_y.len());
    if after > before {
        return kept(&format!(
            "its free-run RMSE over the record {:.4e} exceeds the fit-block fit's {:.4e}",
            rms_of(after, scored),
            rms_of(before, scored)
        ));
    }
    let note = format!(
        "; the chosen structure refitted on the whole training record ({} samples: fit and select blocks, each extension within its own sample cap), the baseline and each accepted step in turn (free-run RMSE of the final model over the record {:.4e} -> {:.4e}); the decisions and the verdict use the fit-block fits' held-out residuals",
        whole_y.len(),
        rms_of(before, scored),
        rms_of(after, scored),
    );
    Some((Some(out), note))
}

/// The chain refitted on `whole`'s fit record: the baseline, then each
/// accepted step in turn on the refitted model before it (with the start
/// its search fit chose); `Err` says which refit failed.
fn refit_over(
    whole: &Plan,
    (d, inputs): (&DiagnoseData, &[Vec<f64>]),
    chain: &[Evaluated],
    picks: &[Pick],
    opts: &DiagnoseOptions,
    obs: &dyn Observer,
) -> Result<Vec<Evaluated>, String> {
    let base = refit_baseline(&chain[0], whole, (d, inputs), opts, obs)
        .ok_or_else(|| "the baseline's refit failed".to_string())?;
    let mut out: Vec<Evaluated> = vec![base];
    let mut causes: Vec<Cause> = vec![];
    for (i, (cause, ext, p)) in picks.iter().enumerate() {
        let run = Refit {
            whole,
            d,
            inputs,
            causes: &causes,
            opts,
            obs,
        };
        let choice = chain.get(i + 1).and_then(|e| e.start_choice);
        let next = run
            .step(*ext, p, &out[i], &chain[i], choice)
            .ok_or_else(|| format!("the refit of step {} failed", i + 1))?;
        out.push(next);
        if !causes.contains(cause) {
            causes.push(*cause);
        }
    }
    Ok(out)
}

/// The model a user saves from one training file diagnosed without a
/// validation record: the chosen structure refitted on **all** of the
/// record, its report block included (the report block held the scores
/// back; once every decision is made and the held-out gain is measured,
/// the model is fitted on everything the user gave — the usual refit after
/// model selection). The refit is kept only when its free-run squared
/// error over the whole record is not larger than the reported model's
/// (`Σₖ (y_k − ŷ_k)²`, `k` over the record after the init window);
/// otherwise the reported model is saved. Several training records (or
/// a held-out last one): [`refit_on_all_records`]. `None` when it does
/// not apply (one training record with a validation record, whose report
/// data are not training data; a noise model; the policy's
/// `refit_on_all_samples` off; a cross-validation spanning the whole
/// record, whose models are fitted on all of it already). The scores, the
/// decisions and the verdict of the report stay those of the model fitted
/// without the report block.
pub(crate) fn refit_on_all_samples(
    d: &DiagnoseData,
    plan: &Plan,
    chain: &[Evaluated],
    picks: &[Pick],
    opts: &DiagnoseOptions,
    obs: &dyn Observer,
) -> Option<(Option<FittedModel>, String)> {
    if opts.policy.refit_on_all_samples && (d.multi() || d.report_is_training) {
        return refit_on_all_records(d, plan, chain, picks, opts, obs);
    }
    let applies = opts.policy.refit_on_all_samples
        && d.single_record
        && !d.multi()
        && !d.report_range.is_empty()
        && !plan.spans_report
        && !picks.iter().any(|(c, _, _)| *c == Cause::Noise);
    if !applies {
        return None;
    }
    let all = d.train.slice(0..d.train.len());
    let whole = plan_on(&all, plan);
    let n = all.len();
    let not_kept = |why: &str| {
        format!(
            "; the model saved is the one scored here: the chosen structure refitted on all {n} samples of the training record was not kept ({why})"
        )
    };
    let scored_model = &chain[chain.len() - 1].model;
    let refitted = match physics_warm_refit(&whole, chain, obs) {
        Some(found) => found,
        None => {
            let inputs = plan.decision_inputs(d);
            refit_over(&whole, (d, &inputs), chain, picks, opts, obs)
                .map(|out| out[out.len() - 1].model.clone())
        }
    };
    let kept = |before: f64, after: f64| {
        format!(
            "; the model saved: the chosen structure refitted on all {n} samples of the training record, its report block included (free-run RMSE over the record {before:.4e} -> {after:.4e}); the scores, decisions and verdict here are those of the model fitted without the report block"
        )
    };
    Some(saved_if_no_worse(
        refitted,
        (scored_model, &[all], plan.w, "record"),
        &not_kept,
        &kept,
    ))
}

/// [`refit_on_all_samples`] with several training records: the model a
/// user saves is the chosen chain refitted on every training record whole
/// (fit and select parts; without a validation record also the last
/// record, which was held out whole for the report), each record a separate
/// experiment (input–output models on all records, the other classes on
/// the longest). Kept only when its free-run squared error summed over
/// those records, each simulated from its own start, is not larger than
/// the reported model's:
///
/// ```text
/// Σᵢ Σₖ (yᵢ(k) − ŷᵢ(k))² (refit) ≤ Σᵢ Σₖ (yᵢ(k) − ŷᵢ(k))² (reported),   k ≥ w in every record i.
/// ```
///
/// `None` when the chain holds a noise model (its criterion is not the
/// squared simulation error) or does not start from the linear baseline
/// (the engineer's equations fit one record).
fn refit_on_all_records(
    d: &DiagnoseData,
    plan: &Plan,
    chain: &[Evaluated],
    picks: &[Pick],
    opts: &DiagnoseOptions,
    obs: &dyn Observer,
) -> Option<(Option<FittedModel>, String)> {
    if picks.iter().any(|(c, _, _)| *c == Cause::Noise)
        || !matches!(chain[0].lineage, Lineage::Io(_))
    {
        return None;
    }
    let mut recs: Vec<gb_core::Record> = d
        .parts()
        .iter()
        .map(|p| p.record.slice(0..p.select.end))
        .collect();
    if d.report_is_training {
        recs.push(d.report.clone());
    }
    let whole = plan_on_records(&recs, plan);
    let n: usize = recs.iter().map(gb_core::Record::len).sum();
    let what = format!(
        "{} training records whole ({n} samples{})",
        recs.len(),
        if d.report_is_training {
            ", the held-out last record included"
        } else {
            ""
        }
    );
    let not_kept = |why: &str| {
        format!("; the model saved is the one scored here: the chosen structure refitted on all {what} was not kept ({why})")
    };
    let inputs = plan.decision_inputs(d);
    let refitted = refit_over(&whole, (d, &inputs), chain, picks, opts, obs)
        .map(|out| out[out.len() - 1].model.clone());
    let kept = |before: f64, after: f64| {
        format!(
            "; the model saved: the chosen structure refitted on all {what}, each simulated from its own start (free-run RMSE over the records {before:.4e} -> {after:.4e}); the scores, decisions and verdict here are those of the model before this refit"
        )
    };
    let scored_model = &chain[chain.len() - 1].model;
    Some(saved_if_no_worse(
        refitted,
        (scored_model, &recs, plan.w, "records"),
        &not_kept,
        &kept,
    ))
}

/// The final model of a chain that started from the engineer's equations,
/// refitted on `whole`'s record by one Levenberg–Marquardt path from its
/// estimates ([`crate::physics::refit_physics_direct`]: the physical
/// parameters and every added term together, warm); `None` for other
/// chains (refitted step by step).
fn physics_warm_refit(
    whole: &Plan,
    chain: &[Evaluated],
    obs: &dyn Observer,
) -> Option<Result<FittedModel, String>> {
    if !matches!(chain[0].lineage, Lineage::Other { .. }) {
        return None;
    }
    let phys = crate::physics::physics_of(&chain[chain.len() - 1].model)?;
    let fitted = phys
        .with_start_at_values()
        .map_err(|e| e.to_string())
        .and_then(|m| {
            crate::physics::refit_physics_direct(m.spec(), &whole.fit, obs)
                .map_err(|e| e.to_string())
        })
        .and_then(|m| whole.finish(m, None).map_err(|e| e.to_string()))
        .map_err(|e| format!("the refit of the final model failed: {e}"));
    Some(fitted)
}

/// A plan without folds whose fit record is `rec` (`plan`'s init window
/// and integrator).
fn plan_on(rec: &gb_core::Record, plan: &Plan) -> Plan {
    Plan {
        w: plan.w,
        integrating: false,
        fit: rec.clone(),
        fit_y: rec.clone(),
        fits: vec![rec.clone()],
        fits_y: vec![rec.clone()],
        folds: vec![],
        shift: None,
        spans_report: false,
    }
    .integrating(plan.integrating)
}

/// A plan without folds whose input–output models are fitted on the
/// records `recs` (separate experiments) and the other classes on the
/// longest of them (`plan`'s init window and integrator).
fn plan_on_records(recs: &[gb_core::Record], plan: &Plan) -> Plan {
    let longest = recs
        .iter()
        .fold(&recs[0], |a, r| if r.len() > a.len() { r } else { a });
    Plan {
        fits: recs.to_vec(),
        fits_y: recs.to_vec(),
        ..plan_on(longest, plan)
    }
    .integrating(plan.integrating)
}

/// The refitted model to save and the decisions line's sentence: kept
/// when its free-run squared error summed over the records `recs` (each
/// from the state of its first `w` outputs) is not larger than that of
/// the `scored` model (`kept(rms before, rms after)`), else `None` with
/// `not_kept(why)` (also when the refit failed). `over` names the records.
fn saved_if_no_worse(
    refitted: Result<FittedModel, String>,
    (scored, recs, w, over): (&FittedModel, &[gb_core::Record], usize, &str),
    not_kept: &dyn Fn(&str) -> String,
    kept: &dyn Fn(f64, f64) -> String,
) -> (Option<FittedModel>, String) {
    let refitted = match refitted {
        Ok(m) => m,
        Err(why) => return (None, not_kept(&why)),
    };
    let sse = |m: &FittedModel| -> f64 { recs.iter().map(|r| free_run_sse(m, r, w)).sum() };
    let (before, after) = (sse(scored), sse(&refitted));
    let n: usize = recs.iter().map(|r| r.len() - w.min(r.len())).sum();
    let (b, a) = (rms_of(before, n), rms_of(after, n));
    if after.is_nan() || after > before {
        let why = format!(
            "its free-run RMSE over the {over} {a:.4e} exceeds that of the model scored here, {b:.4e}"
        );
        return (None, not_kept(&why));
    }
    (Some(refitted), kept(b, a))
}

/// `Σₖ (y_k − ŷ_k)²` of `m`'s free run over `rec` from the state of its
/// first `w` outputs, `k ≥ w` (∞ when it does not simulate).
fn free_run_sse(m: &FittedModel, rec: &gb_core::Record, w: usize) -> f64 {
    residuals_on(m, rec, &(0..rec.len()), w)
        .map_or(f64::INFINITY, |r| r.e.iter().map(|e| e * e).sum())
}

/// `√(sse / n)`.
fn rms_of(sse: f64, n: usize) -> f64 {
    (sse / n.max(1) as f64).sqrt()
}

/// The baseline refitted on the whole plan's record: an input–output
/// network by its own parameters (warm-started from itself), the
/// engineer's equations from their estimates; `None` for other classes.
fn refit_baseline(
    base: &Evaluated,
    whole: &Plan,
    (d, inputs): (&DiagnoseData, &[Vec<f64>]),
    opts: &DiagnoseOptions,
    obs: &dyn Observer,
) -> Option<Evaluated> {
    let m = match &base.lineage {
        Lineage::Io(p) => {
            let ev = Evidence::compute(&base.select.e, &base.select.yhat, inputs);
            let sims = crate::diagnose::simulated_on(&base.model, &whole.fit);
            let run = Refit {
                whole,
                d,
                inputs,
                causes: &[],
                opts,
                obs,
            };
            crate::extensions::fit_io(p, &run.context(base, &ev, sims.as_deref())).ok()?
        }
        Lineage::Other { .. } => {
            let phys = crate::physics::physics_of(&base.model)?;
            let spec = phys.with_start_at_values().ok()?.spec().clone();
            crate::physics::fit_physics(&spec, &whole.fit, obs).ok()?
        }
        Lineage::HiddenState { .. } => return None,
    };
    let m = whole.finish(m, None).ok()?;
    let mut e = evaluate_on(m, base.lineage.clone(), d, whole.w, None).ok()?;
    e.finding = base.finding.clone();
    Some(e)
}

/// What the refits of one chain share.
struct Refit<'a> {
    /// The plan whose fit record is the whole training record.
    whole: &'a Plan,
    d: &'a DiagnoseData,
    /// The inputs over the decision data (aligned with the search fits'
    /// held-out residuals, which the extensions' evidence reads).
    inputs: &'a [Vec<f64>],
    /// Causes named before the step.
    causes: &'a [Cause],
    opts: &'a DiagnoseOptions,
    obs: &'a dyn Observer,
}

impl<'a> Refit<'a> {
    /// Step `p` of extension `ext` refitted on the whole record on top of
    /// the refitted model `prev` (`judged`: the model before the step as
    /// the search fitted it, whose held-out residuals the extension's
    /// evidence reads; `choice`: the start or map structure the search's
    /// fit chose, refitted alone).
    fn step(
        &self,
        ext: &'static dyn Extension,
        p: &Proposal,
        prev: &Evaluated,
        judged: &Evaluated,
        choice: Option<usize>,
    ) -> Option<Evaluated> {
        let ev = Evidence::compute(&judged.select.e, &judged.select.yhat, self.inputs);
        let sims = crate::diagnose::simulated_on(&prev.model, &self.whole.fit);
        let ctx = Context {
            start_choice: choice,
            // a template law goes on from where its fit-block fit ended
            whole_fit: Some(&judged.model),
            ..self.context(prev, &ev, sims.as_deref())
        };
        let (m, _) = ext.fit_choosing(p, &ctx).ok()?;
        let m = self.whole.finish(m, None).ok()?;
        let mut e = evaluate_on(m, p.lineage.clone(), self.d, self.whole.w, None).ok()?;
        ext.rescore(&ctx, &mut e).ok()?;
        Some(e)
    }

    /// The context of a refit on the whole record.
    fn context<'b>(
        &'b self,
        current: &'b Evaluated,
        evidence: &'b Evidence,
        simulated_fit: Option<&'b [f64]>,
    ) -> Context<'b> {
        Context {
            data: self.d,
            fit: &self.whole.fit,
            fits: &self.whole.fits,
            current,
            causes: self.causes,
            evidence,
            options: self.opts,
            simulated_fit,
            simulated_fits: None,
            observer: self.obs,
            plan: self.whole,
            fold_sims: &[],
            fold_sims_all: &[],
            start_choice: None,
            whole_fit: None,
            rival_of: None,
            templates: None,
            futile_gain: None,
        }
    }
}
