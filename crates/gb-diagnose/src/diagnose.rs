//! The diagnosis loop: simulate the engineer's model, compute residual
//! evidence, fit every candidate extension of the registry, keep the one
//! whose gain on held-out data is significant, repeat.
use crate::decide::{choose, relative_gain_ci, score, Candidate};
use crate::evaluate::{evaluate, Evaluated, Lineage};
use crate::extension::{io_model, Context, Extension, Proposal, Role, EXTENSIONS};
use crate::report::{DataSummary, ModelSummary, Report, Step, REPORT_VERSION};
use crate::{Cause, DecisionPolicy, DiagnoseData, DiagnoseError, Evidence};
use gb_core::{FittedModel, Init, Observer, Record, Silent};
use gb_lmn::{FitOptions, IoNetworkParams, LolimotOptions, WarmStart};
use rayon::prelude::*;
use std::collections::HashSet;

/// How the baseline order is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OrderChoice {
    /// The engineer's order.
    Fixed(usize),
    /// The lowest order of the policy's `auto_orders` within its tolerance
    /// of the best select-block NRMSE.
    Auto,
}

/// Options of [`diagnose`]; validate with [`check`](Self::check).
#[derive(Debug, Clone)]
pub struct DiagnoseOptions {
    /// Baseline order.
    pub order: OrderChoice,
    /// Most extension steps.
    pub max_steps: usize,
    /// Every decision threshold.
    pub policy: DecisionPolicy,
    /// Output-error training options of the input–output networks.
    pub fit: FitOptions,
    /// LOLIMOT options.
    pub lolimot: LolimotOptions,
}

impl Default for DiagnoseOptions {
    fn default() -> Self {
        Self {
            order: OrderChoice::Fixed(2),
            max_steps: 4,
            policy: DecisionPolicy::default(),
            fit: FitOptions::default(),
            lolimot: LolimotOptions::default(),
        }
    }
}

impl DiagnoseOptions {
    /// Validate.
    pub fn check(&self) -> Result<(), DiagnoseError> {
        self.policy.check()?;
        if let OrderChoice::Fixed(n) = self.order {
            if n == 0 || n > self.policy.max_order {
                return Err(DiagnoseError::InvalidArgument(format!(
                    "order must be in 1..={}, got {n}",
                    self.policy.max_order
                )));
            }
        }
        if self.max_steps > 4 {
            return Err(DiagnoseError::InvalidArgument(
                "at most 4 extension steps".into(),
            ));
        }
        self.fit.check()?;
        self.lolimot.check()?;
        Ok(())
    }
}

/// Result of [`diagnose`]: the report, the final model and every model of
/// the accepted chain with its residuals (reports render from these).
pub struct Diagnosis {
    /// The report.
    pub report: Report,
    /// The final (possibly extended) model.
    pub model: FittedModel,
    /// The baseline and the model after each accepted step, in order, with
    /// lineage, scores and select/report residuals (`chain[0]` is the
    /// baseline, the last entry is the final model).
    pub chain: Vec<Evaluated>,
}

/// Fit the input–output baseline of order `order` on the fit block.
fn fit_baseline(
    order: usize,
    d: &DiagnoseData,
    fit: &Record,
    opts: &DiagnoseOptions,
) -> Result<Evaluated, DiagnoseError> {
    let p = IoNetworkParams {
        fit: opts.fit.clone(),
        lolimot: opts.lolimot.clone(),
        ..IoNetworkParams::linear(order)
    };
    let net = p.check()?.fit(fit, WarmStart::default())?;
    evaluate(io_model(net, fit)?, Lineage::Io(p), d, &opts.policy)
}

/// The engineer's baseline, or the order chosen on the select block.
fn baseline(
    d: &DiagnoseData,
    fit: &Record,
    opts: &DiagnoseOptions,
) -> Result<Evaluated, DiagnoseError> {
    match opts.order {
        OrderChoice::Fixed(n) => fit_baseline(n, d, fit, opts),
        OrderChoice::Auto => {
            let fits: Vec<Evaluated> = opts
                .policy
                .auto_orders
                .clone()
                .into_par_iter()
                .filter_map(|n| fit_baseline(n, d, fit, opts).ok())
                .collect();
            let best = fits
                .iter()
                .map(|e| e.scores.nrmse_select)
                .fold(f64::INFINITY, f64::min);
            fits.into_iter()
                .find(|e| e.scores.nrmse_select <= best * opts.policy.auto_order_tolerance + 1e-12)
                .ok_or_else(|| {
                    DiagnoseError::Core(gb_core::CoreError::Unstable(
                        "no order gave a stable model".into(),
                    ))
                })
        }
    }
}

/// What one iteration decided.
struct Iteration {
    rows: Vec<Step>,
    chosen: Option<(Cause, Evaluated)>,
}

/// The proposals of the regular extensions (not the escalation).
fn proposals(
    ctx: &Context,
    tried: &HashSet<&'static str>,
) -> Vec<(&'static dyn Extension, Proposal)> {
    EXTENSIONS
        .iter()
        .filter(|e| e.role() != Role::Escalation && !(e.once() && tried.contains(e.name())))
        .flat_map(|e| e.propose(ctx).into_iter().map(move |p| (*e, p)))
        .collect()
}

/// Fit and score the proposals in parallel; seeds follow the proposal order.
fn fit_candidates(
    ctx: &Context,
    proposals: Vec<(&'static dyn Extension, Proposal)>,
    it: usize,
) -> Vec<Candidate> {
    let pol = ctx.policy();
    let fitted: Vec<Option<Evaluated>> = proposals
        .par_iter()
        .map(|(e, p)| {
            let m = e.fit(p, ctx).ok()?;
            evaluate(m, p.lineage.clone(), ctx.data, pol).ok()
        })
        .collect();
    proposals
        .into_iter()
        .zip(fitted)
        .enumerate()
        .filter_map(|(i, ((e, p), f))| {
            let seed = pol.seed.wrapping_add(1000 * it as u64 + i as u64);
            f.map(|f| score(e, p, f, ctx, seed))
        })
        .collect()
}

/// The escalation (tried once per diagnosis) when no new cause was chosen:
/// it must pay against the current model and against the simple choice.
fn escalate(
    ctx: &Context,
    (ext, p): (&'static dyn Extension, Proposal),
    cands: &mut Vec<Candidate>,
    chosen: Option<usize>,
    it: usize,
) -> Option<usize> {
    let pol = ctx.policy();
    ctx.observer
        .progress(it, it + 1, "fitting the hidden-state model");
    let f = ext
        .fit(&p, ctx)
        .and_then(|m| evaluate(m, p.lineage.clone(), ctx.data, pol))
        .ok()?;
    let seed = pol.seed.wrapping_add(1000 * it as u64 + 999);
    let mut c = score(ext, p, f, ctx, seed);
    if let Some(simple) = chosen.map(|i| &cands[i].fitted) {
        let (g2, ci2) = relative_gain_ci(
            &simple.select.e,
            &c.fitted.select.e,
            pol.block(simple.select.e.len()),
            pol.bootstrap,
            seed + 1,
        );
        c.pays = c.pays && ci2[0] > 0.0 && g2 >= pol.min_gain;
    }
    let pays = c.pays;
    cands.push(c);
    pays.then_some(cands.len() - 1)
}

/// The report rows of an iteration: every candidate, of the plain order
/// increases only the best (or the chosen), accepted first.
fn rows(
    cands: &[Candidate],
    chosen: Option<usize>,
    note: Option<&str>,
    ctx: &Context,
    it: usize,
) -> Vec<Step> {
    let cur = ctx.current;
    let best_dyn = cands
        .iter()
        .enumerate()
        .filter(|(_, c)| c.cause() == Cause::Dynamics && c.role() == Role::NewCause)
        .max_by(|a, b| a.1.gain.total_cmp(&b.1.gain))
        .map(|(i, _)| i);
    let mut out = vec![];
    for (i, c) in cands.iter().enumerate() {
        let accepted = Some(i) == chosen;
        if c.cause() == Cause::Dynamics
            && c.role() == Role::NewCause
            && Some(i) != best_dyn
            && !accepted
        {
            continue;
        }
        let f = &c.fitted;
        let (gain, metric) = match c.ext.metric() {
            crate::extension::GainMetric::Nll => (cur.scores.nll - f.scores.nll, "nll"),
            crate::extension::GainMetric::Nrmse => {
                (1.0 - f.scores.nrmse / cur.scores.nrmse.max(1e-300), "nrmse")
            }
        };
        let mut evidence = c.ext.evidence(&c.proposal, ctx);
        if let (Some(n), true) = (note, accepted) {
            evidence.push_str(n);
        }
        out.push(Step {
            iteration: it,
            cause: c.cause(),
            evidence,
            extension: c.ext.row_text(&c.proposal, &f.model),
            nrmse_before: cur.scores.nrmse,
            nrmse_after: f.scores.nrmse,
            gain,
            gain_metric: metric.to_string(),
            gain_select: c.gain,
            gain_ci: c.ci,
            nll_before: cur.scores.nll,
            nll_after: f.scores.nll,
            accepted,
        });
    }
    out.sort_by_key(|r| !r.accepted);
    out
}

/// What every iteration of one diagnosis shares.
struct Run<'a> {
    d: &'a DiagnoseData,
    fit: &'a Record,
    opts: &'a DiagnoseOptions,
    obs: &'a dyn Observer,
}

/// One iteration: evidence, candidates, choice, escalation, rows.
fn iterate(
    run: &Run,
    cur: &Evaluated,
    causes: &[Cause],
    tried: &mut HashSet<&'static str>,
    it: usize,
) -> Option<Iteration> {
    let Run { d, fit, opts, obs } = *run;
    let w = opts.policy.init_window;
    let ev = Evidence::compute(&cur.select.e, &cur.select.yhat, &d.select_inputs(w));
    let hist = cur.model.dynamics.history_len().min(fit.len());
    let simulated_fit = cur
        .model
        .simulate(&fit.inputs, Init::History(&fit.output[..hist]))
        .ok();
    let ctx = Context {
        data: d,
        fit,
        current: cur,
        causes,
        evidence: &ev,
        options: opts,
        simulated_fit: simulated_fit.as_deref(),
        observer: obs,
    };
    let props = proposals(&ctx, tried);
    if props.is_empty() {
        return None;
    }
    let mut cands = fit_candidates(&ctx, props, it);
    let (mut chosen, note) = choose(&mut cands, &ctx, it);
    let new_cause = chosen
        .is_some_and(|i| cands[i].role() == Role::NewCause && !causes.contains(&cands[i].cause()));
    if !new_cause {
        let escalation = EXTENSIONS
            .iter()
            .filter(|e| e.role() == Role::Escalation && !tried.contains(e.name()))
            .find_map(|e| e.propose(&ctx).into_iter().next().map(|p| (*e, p)));
        if let Some(esc) = escalation {
            tried.insert(esc.0.name());
            if let Some(i) = escalate(&ctx, esc, &mut cands, chosen, it) {
                chosen = Some(i);
            }
        }
    }
    for c in &cands {
        if c.ext.once() {
            tried.insert(c.ext.name());
        }
    }
    let rows = rows(&cands, chosen, note.as_deref(), &ctx, it);
    let chosen = chosen.map(|i| {
        let c = cands.swap_remove(i);
        (c.cause(), c.fitted)
    });
    Some(Iteration { rows, chosen })
}

/// What was tried, per cause: `nonlinearity (2 candidates, 1 accepted)`.
fn tried_summary(steps: &[Step]) -> Vec<String> {
    Cause::ALL
        .iter()
        .filter_map(|c| {
            let n = steps.iter().filter(|s| s.cause == *c).count();
            let acc = steps.iter().filter(|s| s.cause == *c && s.accepted).count();
            (n > 0).then(|| {
                format!(
                    "{c} ({n} candidate{}, {acc} accepted)",
                    if n == 1 { "" } else { "s" }
                )
            })
        })
        .collect()
}

/// Run the diagnosis on `d`, reporting progress to `obs`.
pub fn diagnose(
    d: &DiagnoseData,
    opts: &DiagnoseOptions,
    obs: Option<&dyn Observer>,
) -> Result<Diagnosis, DiagnoseError> {
    opts.check()?;
    let pol = &opts.policy;
    d.check(pol.min_fit, pol.min_block)?;
    let obs: &dyn Observer = obs.unwrap_or(&Silent);
    let fit = d.fit_record();
    let total = 1 + opts.max_steps;
    obs.progress(0, total, "fitting the baseline");
    let base = baseline(d, &fit, opts)?;
    let w = pol.init_window;
    let baseline_evidence =
        Evidence::compute(&base.select.e, &base.select.yhat, &d.select_inputs(w));
    let mut chain = vec![base];
    let mut steps = vec![];
    let mut causes: Vec<Cause> = vec![];
    let mut tried = HashSet::new();
    for it in 1..=opts.max_steps {
        obs.progress(
            it,
            total,
            &format!("step {it}: fitting candidate extensions"),
        );
        let cur = chain.last().expect("the chain holds the baseline");
        let run = Run {
            d,
            fit: &fit,
            opts,
            obs,
        };
        let Some(step) = iterate(&run, cur, &causes, &mut tried, it) else {
            break;
        };
        steps.extend(step.rows);
        match step.chosen {
            Some((cause, model)) => {
                if !causes.contains(&cause) {
                    causes.push(cause);
                }
                chain.push(model);
            }
            None => break,
        }
    }
    obs.progress(total, total, "done");
    let last = chain.last().expect("the chain holds the baseline");
    let final_evidence = Evidence::compute(&last.select.e, &last.select.yhat, &d.select_inputs(w));
    let verdict = crate::verdict::verdict(
        &last.select.e,
        &last.select.yhat,
        &d.select_inputs(w),
        pol.verdict_level,
        &tried_summary(&steps),
    );
    let report = Report {
        version: REPORT_VERSION,
        data: DataSummary {
            inputs: d.train.input_names.clone(),
            output: d.train.output_name.clone(),
            samples_fit: d.fit.len(),
            samples_select: d.select.len(),
            samples_validate: d.report_scored(w).len(),
            split: d.split_text(),
        },
        baseline: ModelSummary::of(&chain[0]),
        steps,
        causes,
        final_model: ModelSummary::of(last),
        evidence: baseline_evidence,
        final_evidence,
        verdict,
    };
    Ok(Diagnosis {
        report,
        model: last.model.clone(),
        chain,
    })
}
