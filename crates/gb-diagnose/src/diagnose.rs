//! The diagnosis loop: simulate the engineer's model, compute residual
//! evidence, fit every candidate extension of the registry, keep the one
//! whose gain on held-out data is significant, repeat.
use crate::baseline::{baseline, StructureChoice};
use crate::decide::{choose, relative_gain_ci, score, Candidate};
use crate::evaluate::{Evaluated, Lineage};
use crate::extension::{Context, Extension, GainMetric, Proposal, Role, EXTENSIONS};
use crate::plan::{assess_from, core, Plan};
use crate::report::{DataSummary, ModelSummary, Report, Step, REPORT_VERSION};
use crate::{Cause, DecisionPolicy, DiagnoseData, DiagnoseError, Evidence};
use gb_core::{metrics, FittedModel, Init, Observer, Silent};
use gb_lmn::{FitOptions, LolimotOptions};
use std::collections::HashSet;
use std::time::{Duration, Instant};

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
    /// The engineer's own equations (a model file): the baseline instead
    /// of the linear output-error model; its records' signal names must be
    /// the model's.
    pub physics: Option<gb_model::physics::PhysicsSpec>,
}

impl Default for DiagnoseOptions {
    fn default() -> Self {
        Self {
            order: OrderChoice::Fixed(2),
            max_steps: 4,
            policy: DecisionPolicy::default(),
            fit: FitOptions::default(),
            lolimot: LolimotOptions::default(),
            physics: None,
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

    /// The options for fitting on `plan`: for an integrating plan (models
    /// of the increments) the output-error fits minimise the error of the
    /// increments' running sum ([`FitOptions::integrated_error`]) when the
    /// policy says so.
    pub(crate) fn for_plan(&self, plan: &crate::plan::Plan) -> std::borrow::Cow<'_, Self> {
        let on = plan.integrating && self.policy.integrated_criterion;
        if on == self.fit.integrated_error {
            return std::borrow::Cow::Borrowed(self);
        }
        let mut o = self.clone();
        o.fit.integrated_error = on;
        std::borrow::Cow::Owned(o)
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
    /// The final structure refitted on all of a single training file, its
    /// report block included, or on every training record whole, a
    /// held-out last record included (the policy's
    /// `refit_on_all_samples`); `None` when that does not apply or was not
    /// kept. See [`Diagnosis::to_save`].
    pub saved: Option<FittedModel>,
}

impl Diagnosis {
    /// The model a user keeps: the final structure refitted on all of the
    /// training data when that was done and kept, else the final model
    /// (the one the report scores).
    pub fn to_save(&self) -> &FittedModel {
        self.saved.as_ref().unwrap_or(&self.model)
    }
}

/// What one iteration decided.
struct Iteration {
    rows: Vec<Step>,
    chosen: Option<(Evaluated, crate::refit::Pick)>,
    /// The candidates that did not pay (extension, proposal text), and
    /// those the screen held back because a noise model explained the rest.
    lost: HashSet<Lost>,
    /// The extensions whose every candidate lost decisively (the whole
    /// 95 % interval of its select gain below zero).
    beaten: HashSet<&'static str>,
    /// For the decisions line: what the screening of the costly candidates
    /// left out, which candidates diverged.
    notes: Option<String>,
    /// The chosen candidate was checked for carrying over a repeated
    /// excitation ([`carried_over_choice`]).
    carry_checked: bool,
}

/// A candidate that did not pay at a step: its extension and proposal text.
type Lost = (&'static str, String);

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

/// Fit and score the proposals in parallel; seeds follow the proposal
/// order (`i` of each pair, its index among the step's proposals). First
/// each proposal's fit on the whole fit block ([`first_fit`]), then the
/// in-sample screen among rivals of one structure at different delays
/// ([`screen_delay_rivals`]), then the folds of those left: first of the
/// ones near the best in-sample error, then of the others unless their
/// in-sample error is far above the smallest cross-validated error of the
/// step so far, `bound`, which the folds lower ([`bound_phases`],
/// [`screen_by_bound`]). A proposal whose fit fails is left out; its
/// extension and error are returned for the decisions line.
fn fit_candidates(
    ctx: &Context,
    proposals: Vec<(usize, (&'static dyn Extension, Proposal))>,
    (it, bound): (usize, &mut Option<f64>),
) -> (Vec<(usize, Candidate)>, Vec<String>) {
    let pol = ctx.policy();
    let cost = |k: usize| proposals[k].1 .0.fit_cost();
    let after = rival_siblings(ctx, &proposals);
    let mut firsts: Vec<Result<FirstFit, DiagnoseError>> =
        longest_first_after(proposals.len(), cost, &after, |k, sibling| {
            let (e, p) = &proposals[k].1;
            let rival_of = sibling
                .and_then(|f: &Result<FirstFit, DiagnoseError>| f.as_ref().ok())
                .map(FirstFit::whole);
            let c = Context { rival_of, ..*ctx };
            timed(e.name(), &p.lineage, || first_fit(*e, p, &c))
        });
    screen_delay_rivals(ctx, &proposals, &mut firsts);
    let fold = |firsts: &[Result<FirstFit, DiagnoseError>], k: usize| {
        let (e, p) = &proposals[k].1;
        match &firsts[k] {
            Ok(FirstFit::Whole(w)) => timed(e.name(), &p.lineage, || {
                fold_fits(*e, p, ctx, (&w.raw, w.start))
            }),
            _ => Err(DiagnoseError::InvalidArgument(
                "no fit waits for its folds".into(),
            )),
        }
    };
    for (k, f) in firsts.iter().enumerate() {
        if let Ok(FirstFit::Done(c)) = f {
            *bound = lower_bound(*bound, &proposals[k].1, Some(c));
        }
    }
    let (lead, rest) = bound_phases(ctx, &firsts, *bound);
    let mut folded: Vec<Option<Result<Evaluated, DiagnoseError>>> =
        (0..firsts.len()).map(|_| None).collect();
    for (k, r) in lead.iter().zip(longest_first(
        lead.len(),
        |j| cost(lead[j]),
        |j| fold(&firsts, lead[j]),
    )) {
        *bound = lower_bound(*bound, &proposals[*k].1, r.as_ref().ok());
        folded[*k] = Some(r);
    }
    let rest = screen_by_bound(ctx, &proposals, &mut firsts, rest, *bound);
    for (k, r) in rest.iter().zip(longest_first(
        rest.len(),
        |j| cost(rest[j]),
        |j| fold(&firsts, rest[j]),
    )) {
        *bound = lower_bound(*bound, &proposals[*k].1, r.as_ref().ok());
        folded[*k] = Some(r);
    }
    let mut failed = vec![];
    let mut cands = vec![];
    for (((i, (e, p)), first), fold) in proposals.into_iter().zip(firsts).zip(folded) {
        let f = match first {
            Ok(FirstFit::Done(c)) => Ok(*c),
            Ok(FirstFit::Whole(_)) => fold.unwrap_or_else(|| {
                Err(DiagnoseError::InvalidArgument(
                    "a fold fit is missing".into(),
                ))
            }),
            Err(err) => Err(err),
        };
        match f {
            Ok(f) => {
                let seed = pol.seed.wrapping_add(1000 * it as u64 + i as u64);
                cands.push((i, score(e, p, f, ctx, seed)));
            }
            Err(err) => failed.push(failure(e, &err)),
        }
    }
    (cands, failed)
}

/// The in-sample RMS residual over the folds' samples of a fit waiting for
/// its folds (`None`: no reading, or not waiting).
fn in_sample_rms(f: &Result<FirstFit, DiagnoseError>) -> Option<f64> {
    match f {
        Ok(FirstFit::Whole(w)) if !w.in_sample.1.e.is_empty() => {
            Some(metrics::rms(&w.in_sample.1.e)).filter(|r| r.is_finite())
        }
        _ => None,
    }
}

/// The fits waiting for their folds in two phases (policy
/// `cv_bound_ratio`): first those within the factor of the smallest
/// in-sample RMS residual among them (and those without a reading), which
/// set the bound; then the others, each cross-validated unless
/// [`screen_by_bound`] scores it in-sample. Without cross-validation or
/// with the screen off, every waiting fit in the first phase. The step's
/// bound so far (earlier tiers) moves a fit above it to the second phase.
fn bound_phases(
    ctx: &Context,
    firsts: &[Result<FirstFit, DiagnoseError>],
    bound: Option<f64>,
) -> (Vec<usize>, Vec<usize>) {
    let waiting = (0..firsts.len()).filter(|&k| matches!(firsts[k], Ok(FirstFit::Whole(_))));
    let ratio = ctx.policy().cv_bound_ratio;
    if ratio < 1.0 || !ctx.plan.cv() {
        return (waiting.collect(), vec![]);
    }
    let best = (0..firsts.len())
        .filter_map(|k| in_sample_rms(&firsts[k]))
        .min_by(f64::total_cmp);
    waiting.partition(|&k| match (in_sample_rms(&firsts[k]), best) {
        (Some(r), Some(b)) => r <= ratio * b && bound.is_none_or(|c| r <= ratio * c),
        _ => true,
    })
}

/// `bound` lowered to the cross-validated RMS residual of `c` when it is a
/// reading of the decision data (not scored in-sample) of a candidate that
/// competes on the NRMSE for a new or the named cause (nonlinearity,
/// hysteresis, dynamics).
fn lower_bound(
    bound: Option<f64>,
    (e, p): &(&'static dyn Extension, Proposal),
    c: Option<&Evaluated>,
) -> Option<f64> {
    let competes = matches!(
        p.cause,
        Cause::Nonlinearity | Cause::Hysteresis | Cause::Dynamics
    ) && matches!(e.role(), Role::NewCause | Role::Refinement)
        && e.metric() == crate::extension::GainMetric::Nrmse;
    let r = c
        .filter(|c| competes && c.screened.is_none() && !c.select.e.is_empty())
        .map(|c| metrics::rms(&c.select.e))
        .filter(|r| r.is_finite());
    match (bound, r) {
        (Some(b), Some(r)) => Some(b.min(r)),
        (b, r) => b.or(r),
    }
}

/// Of the fits `rest` waiting for their folds, those whose in-sample RMS
/// residual exceeds the policy's `cv_bound_ratio` times `bound` are scored
/// in-sample ([`crate::plan::scored_in_sample`]) and do not pay; the
/// others are returned to be cross-validated.
fn screen_by_bound(
    ctx: &Context,
    proposals: &[(usize, (&'static dyn Extension, Proposal))],
    firsts: &mut [Result<FirstFit, DiagnoseError>],
    rest: Vec<usize>,
    bound: Option<f64>,
) -> Vec<usize> {
    let ratio = ctx.policy().cv_bound_ratio;
    let mut left = vec![];
    for k in rest {
        let (Some(r), Some(b)) = (in_sample_rms(&firsts[k]), bound) else {
            left.push(k);
            continue;
        };
        let scored = match &firsts[k] {
            Ok(FirstFit::Whole(w)) if r > ratio * b => crate::plan::scored_in_sample(
                ctx.plan,
                ctx.data,
                (&w.finished, &proposals[k].1 .1.lineage),
                w.in_sample.clone(),
            ),
            _ => None,
        };
        match scored {
            Some(mut c) => {
                c.screened_by_bound = Some(r / b);
                firsts[k] = Ok(FirstFit::Done(Box::new(c)));
            }
            None => left.push(k),
        }
    }
    left
}

/// Of the proposals whose fit on the whole fit block waits for its folds,
/// those that share [`Extension::delay_rivals_key`] (one structure at
/// different input delays) with a rival whose in-sample RMS residual is
/// more than the policy's `rival_screen_ratio` times smaller are scored
/// in-sample and not cross-validated (the same structure and number of
/// parameters: the in-sample error compares them) — except the first of
/// them, the structure at the current model's delay: the folds judge it
/// beside the best (backlash 2 of the sweep at 805 samples: the best
/// in-sample delay fails its folds, −0.31, the current delay's pass,
/// +0.53, and only the latter carries the cause).
fn screen_delay_rivals(
    ctx: &Context,
    proposals: &[(usize, (&'static dyn Extension, Proposal))],
    firsts: &mut [Result<FirstFit, DiagnoseError>],
) {
    let ratio = ctx.policy().rival_screen_ratio;
    if ratio < 1.0 {
        return;
    }
    let keys = rival_keys(proposals, false);
    let rms = |f: &Result<FirstFit, DiagnoseError>| match f {
        Ok(FirstFit::Whole(w)) if w.in_sample.0.is_finite() && !w.in_sample.1.e.is_empty() => {
            Some(metrics::rms(&w.in_sample.1.e))
        }
        _ => None,
    };
    let best: Vec<Option<f64>> = keys
        .iter()
        .map(|key| {
            let key = key.as_ref()?;
            (0..firsts.len())
                .filter(|&j| keys[j].as_ref() == Some(key))
                .filter_map(|j| rms(&firsts[j]))
                .filter(|r| r.is_finite())
                .min_by(f64::total_cmp)
        })
        .collect();
    // the first of a key is the structure at the current model's delay
    let incumbent = |k: usize| keys[..k].iter().all(|o| o != &keys[k]);
    for (k, first) in firsts.iter_mut().enumerate() {
        let (Some(r), Some(b)) = (rms(first), best[k]) else {
            continue;
        };
        if incumbent(k) {
            continue;
        }
        if r.is_nan() || r <= ratio * b {
            continue;
        }
        let Ok(FirstFit::Whole(w)) = first else {
            continue;
        };
        let p = &proposals[k].1 .1;
        let scored = crate::plan::scored_in_sample(
            ctx.plan,
            ctx.data,
            (&w.finished, &p.lineage),
            w.in_sample.clone(),
        );
        if let Some(mut c) = scored {
            c.screened_by_rival = Some(r / b);
            *first = Ok(FirstFit::Done(Box::new(c)));
        }
    }
}

/// Each proposal's [`Extension::delay_rivals_key`] with its extension's
/// name (`None`: no rivals); with `starting`, only of the extensions that
/// [`starts_from_rival`](Extension::starts_from_rival).
fn rival_keys(
    proposals: &[(usize, (&'static dyn Extension, Proposal))],
    starting: bool,
) -> Vec<Option<String>> {
    proposals
        .iter()
        .map(|(_, (e, p))| {
            e.delay_rivals_key(p)
                .filter(|_| !starting || e.starts_from_rival())
                .map(|k| format!("{}|{k}", e.name()))
        })
        .collect()
}

/// For each proposal under cross-validation of an extension that
/// [`starts_from_rival`](Extension::starts_from_rival), the delay rival's
/// sibling: the first proposal of the step with the same
/// [`Extension::delay_rivals_key`] (the structure at the current model's
/// delay), whose whole fit the rival's starts from; `None` for that first
/// one and for every other proposal.
fn rival_siblings(
    ctx: &Context,
    proposals: &[(usize, (&'static dyn Extension, Proposal))],
) -> Vec<Option<usize>> {
    if !ctx.plan.cv() {
        return vec![None; proposals.len()];
    }
    let keys = rival_keys(proposals, true);
    (0..keys.len())
        .map(|k| {
            let key = keys[k].as_ref()?;
            (0..k).find(|&j| keys[j].as_ref() == Some(key))
        })
        .collect()
}

/// `run(k)` for `k` in `0..n`, in order, computed by one worker per thread
/// of the pool, each taking the next job of the largest `cost` first (a
/// step's costly fit started last ran alone at its end); the jobs' own
/// parallel work is helped by idle workers.
fn longest_first<T: Send + Sync>(
    n: usize,
    cost: impl Fn(usize) -> u8,
    run: impl Fn(usize) -> T + Sync,
) -> Vec<T> {
    longest_first_after(n, cost, &vec![None; n], |k, _| run(k))
}

/// [`longest_first`] where job `k` with `after[k] = Some(j)` waits for job
/// `j` (which waits for none) and runs with its result, `run(k, Some(&r_j))`;
/// a job becomes ready when its sibling is done and joins the queue by its
/// cost (behind the ready jobs of the same cost).
fn longest_first_after<T: Send + Sync>(
    n: usize,
    cost: impl Fn(usize) -> u8,
    after: &[Option<usize>],
    run: impl Fn(usize, Option<&T>) -> T + Sync,
) -> Vec<T> {
    use std::sync::{Condvar, Mutex, OnceLock};
    let costs: Vec<u8> = (0..n).map(cost).collect();
    let waits = |k: usize| after.get(k).copied().flatten().filter(|&j| j < n && j != k);
    let mut ready: Vec<usize> = (0..n).filter(|&k| waits(k).is_none()).collect();
    ready.sort_by_key(|&k| std::cmp::Reverse(costs[k]));
    // the ready queue, how many jobs have started, whether a job panicked
    let state = Mutex::new((ready, 0usize, false));
    let woken = Condvar::new();
    let out: Vec<OnceLock<T>> = (0..n).map(|_| OnceLock::new()).collect();
    let lock = || state.lock().unwrap_or_else(|e| e.into_inner());
    let next = || {
        let mut g = lock();
        loop {
            if g.2 {
                return None;
            }
            if !g.0.is_empty() {
                g.1 += 1;
                return Some(g.0.remove(0));
            }
            if g.1 >= n {
                return None;
            }
            g = woken.wait(g).unwrap_or_else(|e| e.into_inner());
        }
    };
    // a job that panics wakes the waiting workers, which stop (the scope
    // then raises the panic) instead of waiting for its rivals forever
    struct Abandon<'s>(&'s Mutex<(Vec<usize>, usize, bool)>, &'s Condvar);
    impl Drop for Abandon<'_> {
        fn drop(&mut self) {
            if std::thread::panicking() {
                self.0.lock().unwrap_or_else(|e| e.into_inner()).2 = true;
                self.1.notify_all();
            }
        }
    }
    let work = || {
        let _abandon = Abandon(&state, &woken);
        while let Some(k) = next() {
            let sibling = waits(k).and_then(|j| out[j].get());
            let _ = out[k].set(run(k, sibling));
            let mut g = lock();
            for d in (0..n).filter(|&d| waits(d) == Some(k)) {
                let at = g.0.iter().position(|&x| costs[x] < costs[d]);
                let at = at.unwrap_or(g.0.len());
                g.0.insert(at, d);
            }
            drop(g);
            woken.notify_all();
        }
        woken.notify_all();
    };
    rayon::scope(|s| {
        for _ in 1..rayon::current_num_threads().min(n) {
            s.spawn(|_| work());
        }
        work();
    });
    out.into_iter()
        .map(|c| c.into_inner().expect("every job ran"))
        .collect()
}

/// `note` with `more` appended (each a `; …` clause of the decisions line).
fn appended(note: Option<String>, more: Option<String>) -> Option<String> {
    match more {
        Some(m) => Some(note.unwrap_or_default() + &m),
        None => note,
    }
}

/// A failed fit of extension `e` for the decisions line: `name (error)`.
fn failure(e: &dyn Extension, err: &DiagnoseError) -> String {
    format!("{} ({})", e.name(), kind_once(err.to_string()))
}

/// `text` with a leading error kind said once: an error passed up through
/// the crates' error types repeats it ("invalid argument: invalid
/// argument: …").
fn kind_once(mut text: String) -> String {
    while let Some((kind, rest)) = text.split_once(": ") {
        if !rest.starts_with(&format!("{kind}: ")) {
            break;
        }
        text = rest.to_string();
    }
    text
}

/// The decisions line's note on the proposals of step `it` whose fit
/// failed, `None` when none did.
fn failed_note(failed: &[String], it: usize) -> Option<String> {
    (!failed.is_empty()).then(|| {
        format!(
            "; step {it}: {} candidate{} could not be fitted and {} left out of the table: {}",
            failed.len(),
            if failed.len() == 1 { "" } else { "s" },
            if failed.len() == 1 { "is" } else { "are" },
            failed.join(", ")
        )
    })
}

/// The candidates of one step in proposal order. With the policy's
/// `screen_costly`, the proposals are fitted tier by tier
/// ([`Extension::screen_tier`]: the cheap ones, then the static
/// mechanical laws, then the hysteretic template, the Wiener–Hammerstein
/// network and the hidden-state model), and a tier only when no candidate
/// of the tiers before that pays leaves a quiet residual on the decision
/// data (the one with the largest gain: [`residual_quiet`] within
/// `screen_noise_ratio` × the white-noise level) and, when none pays, the
/// current model's residual is not quiet either ([`quiet_after_tier`]);
/// then the note says what was not fitted.
fn screened_candidates(
    ctx: &Context,
    props: Vec<(&'static dyn Extension, Proposal)>,
    it: usize,
) -> Screened {
    let pol = ctx.policy();
    let tier = |e: &dyn Extension| {
        if pol.screen_costly {
            e.screen_tier()
        } else {
            0
        }
    };
    let mut left: Vec<_> = props.into_iter().enumerate().collect();
    let mut cands = vec![];
    let mut failed = vec![];
    let mut note = None;
    let mut held = HashSet::new();
    // whether the current model reads quiet at the screen's reading (asked
    // once, when a tier paid nothing)
    let mut current_quiet: Option<bool> = None;
    // the smallest cross-validated RMS residual of the step's candidates
    // so far (policy `cv_bound_ratio`)
    let mut bound: Option<f64> = None;
    while let Some(t) = left.iter().map(|(_, (e, _))| tier(*e)).min() {
        let quiet = (!cands.is_empty())
            .then(|| quiet_after_tier(&cands, ctx, &mut current_quiet))
            .flatten();
        if let Some((who, noise_only)) = quiet {
            if noise_only {
                held.extend(left.iter().map(|(_, (e, p))| (e.name(), p.text.clone())));
            }
            let names: Vec<&str> = left.iter().map(|(_, (e, _))| e.name()).collect();
            let mut unique = names.clone();
            unique.sort_unstable();
            unique.dedup();
            note = Some(format!(
                "; step {it}: {who}: {} costly candidate{} ({}) not fitted",
                names.len(),
                if names.len() == 1 { "" } else { "s" },
                unique.join(", ")
            ));
            break;
        }
        let (now, later): (Vec<_>, Vec<_>) =
            left.into_iter().partition(|(_, (e, _))| tier(*e) == t);
        left = later;
        prepare_tier(ctx, &now);
        let (fitted, f) = fit_candidates(ctx, now, (it, &mut bound));
        cands.extend(fitted);
        failed.extend(f);
    }
    cands.sort_by_key(|(i, _)| *i);
    Screened {
        cands: cands.into_iter().map(|(_, c)| c).collect(),
        note: appended(note, failed_note(&failed, it)),
        held,
    }
}

/// [`Extension::prepare`] of each extension with proposals in a tier,
/// once, in proposal order.
fn prepare_tier(ctx: &Context, now: &[(usize, (&'static dyn Extension, Proposal))]) {
    let mut done: Vec<&str> = vec![];
    for (_, (e, _)) in now {
        if !done.contains(&e.name()) {
            done.push(e.name());
            e.prepare(ctx);
        }
    }
}

/// A step's candidates after the screen ([`screened_candidates`]).
struct Screened {
    /// The candidates fitted, in proposal order.
    cands: Vec<Candidate>,
    /// For the decisions line: what was not fitted, which fits failed.
    note: Option<String>,
    /// The proposals left out because only noise models paid and the input
    /// tests passed: after a step that changed only the noise model they
    /// stay out, as the candidates that did not pay do.
    held: HashSet<Lost>,
}

/// What leaves a quiet residual at the screen's reading after the tiers
/// fitted so far, in words: the paying candidate with the largest gain
/// when one pays (its residual decides; when only noise models pay and
/// no structural candidate reaches `min_gain`, on the input tests alone,
/// [`input_quiet`], and the flag is true), else the current model (no
/// candidate paid: its own residual decides, read once into `current`).
/// A residual the cheap candidates leave quiet, or that none of them could
/// improve and that is quiet already, leaves no structure a costly one
/// could gain on significantly (a clean linear record of 8000 samples whose
/// residual failed one test at the search stop's lenient 5 % reading
/// fitted the mechanical templates and the Wiener–Hammerstein network for
/// no gain: the whole diagnosis took 4.5 s, now 3.0 s).
fn quiet_after_tier(
    cands: &[(usize, Candidate)],
    ctx: &Context,
    current: &mut Option<bool>,
) -> Option<(String, bool)> {
    let (at, pol) = ((ctx.plan, ctx.data), ctx.policy());
    let r = Reading::screen(pol);
    let paying = || cands.iter().filter(|(_, c)| c.pays);
    let best = paying().max_by(|a, b| a.1.gain.total_cmp(&b.1.gain));
    // a structural candidate at `min_gain` (its point estimate), though it
    // does not pay, says the deterministic part may hold more
    let only_noise = paying().all(|(_, c)| c.ext.metric() == GainMetric::Nll)
        && !cands.iter().any(|(_, c)| {
            c.ext.metric() == GainMetric::Nrmse && c.gain_counts() && c.gain >= pol.min_gain
        });
    match best {
        Some((_, c)) if only_noise => input_quiet(&c.fitted, at, r).then(|| {
            format!(
                "only noise models paid, no structural candidate gained {} % (point estimate), and the {} candidate's residual passed every input test (cross-correlation, higher-order, static nonlinearity, memory) at the {} % level, {}: its noise model explains the rest",
                100.0 * pol.min_gain,
                c.ext.name(),
                100.0 * r.level,
                r.reading_text()
            )
        })
        .map(|w| (w, true)),
        Some((_, c)) => residual_quiet(&c.fitted, at, r)
            .then(|| (quiet_words(&format!("the {} candidate", c.ext.name()), r), false)),
        None => current
            .get_or_insert_with(|| residual_quiet(ctx.current, at, r))
            .then(|| (quiet_words("no candidate paid and the current model", r), false)),
    }
}

/// `who left a quiet residual (…)`: the screen's reading in words.
fn quiet_words(who: &str, r: Reading) -> String {
    format!(
        "{who} left a quiet residual (every test passed at the {} % level, {}; within {}× the white-noise level)",
        100.0 * r.level,
        r.reading_text(),
        r.noise_ratio
    )
}

/// `f()`, and with the environment variable `GREYBOX_TIMING` set, one
/// line on stderr with its wall time, the extension and the candidate.
fn timed<T>(extension: &str, lineage: &Lineage, f: impl FnOnce() -> T) -> T {
    timed_line("timing", || format!("{extension}  {}", lineage.spec()), f)
}

/// `f()`, and with `GREYBOX_TIMING` set, one line on stderr with the wall
/// time of the phase `name`.
pub(crate) fn timed_phase<T>(name: &str, f: impl FnOnce() -> T) -> T {
    timed_line("phase", || name.to_string(), f)
}

/// `f()`, and with `GREYBOX_TIMING` set, the line `kind: seconds  label
/// (from start)` on stderr, the start counted from the first timed call.
fn timed_line<T>(kind: &str, label: impl FnOnce() -> String, f: impl FnOnce() -> T) -> T {
    if std::env::var_os("GREYBOX_TIMING").is_none() {
        return f();
    }
    static FIRST: std::sync::OnceLock<Instant> = std::sync::OnceLock::new();
    let t0 = Instant::now();
    let since = t0.duration_since(*FIRST.get_or_init(|| t0)).as_secs_f64();
    let r = f();
    eprintln!(
        "{kind}: {:8.3} s  {}  (from {since:.3} s)",
        t0.elapsed().as_secs_f64(),
        label()
    );
    r
}

/// Fit a proposal on the plan's record (and its folds) and score it.
pub(crate) fn fit_proposal(
    e: &'static dyn Extension,
    p: &Proposal,
    ctx: &Context,
) -> Result<Evaluated, DiagnoseError> {
    match first_fit(e, p, ctx)? {
        FirstFit::Done(c) => Ok(*c),
        FirstFit::Whole(w) => fold_fits(e, p, ctx, (&w.raw, w.start)),
    }
}

/// A proposal after its fit on the plan's record: scored already, or, under
/// cross-validation past the in-sample screen, waiting for its folds.
enum FirstFit {
    /// Scored (not cross-validated, screened out, or with its folds).
    Done(Box<Evaluated>),
    /// The fit on the whole fit block, waiting for its folds.
    Whole(Box<Waiting>),
}

impl FirstFit {
    /// The fit on the whole fit block and the start it chose.
    fn whole(&self) -> (&FittedModel, Option<usize>) {
        match self {
            FirstFit::Done(c) => (&c.model, c.start_choice),
            FirstFit::Whole(w) => (&w.raw, w.start),
        }
    }
}

/// A proposal's fit on the whole fit block, waiting for its folds.
struct Waiting {
    /// The fit as the extension returned it.
    raw: FittedModel,
    /// The start it chose, for the folds.
    start: Option<usize>,
    /// The fit as the plan finishes it.
    finished: FittedModel,
    /// Its in-sample gain over the current model and residuals
    /// ([`crate::plan::in_sample_gain`]).
    in_sample: (f64, crate::evaluate::Residuals),
}

/// The fit of a proposal on the plan's record. Under cross-validation a
/// `nonlinearity` or `hysteresis` candidate that gains less than
/// `min_gain` in-sample is scored there ([`crate::plan::scored_in_sample`]); one
/// that gains more waits for its folds ([`fold_fits`]). Other proposals
/// are fitted and scored in full.
fn first_fit(
    e: &'static dyn Extension,
    p: &Proposal,
    ctx: &Context,
) -> Result<FirstFit, DiagnoseError> {
    // (a simplification is not screened: it need not gain in-sample)
    let screened = matches!(p.cause, Cause::Nonlinearity | Cause::Hysteresis)
        && e.role() != Role::Simplification
        && e.metric() == crate::extension::GainMetric::Nrmse
        && ctx.plan.cv()
        && !ctx.data.multi()
        && ctx.policy().cv_in_sample_screen;
    if !screened {
        let mut c = assess_from(ctx.plan, ctx.data, p.lineage.clone(), &|t| {
            e.fit_choosing(p, &ctx.at_fold(t))
        })?;
        e.rescore(ctx, &mut c)?;
        return Ok(FirstFit::Done(Box::new(c)));
    }
    let (raw, start) = e.fit_choosing(p, &ctx.at_fold(None))?;
    let finished = ctx.plan.finish(raw.clone(), None)?;
    let min_gain = ctx.policy().min_gain;
    let read = crate::plan::in_sample_gain(ctx.plan, ctx.data, &finished, ctx.current);
    let in_sample = match read {
        Some((gain, after)) if gain < min_gain && gain.is_finite() => {
            let lineage = &p.lineage;
            let c = crate::plan::scored_in_sample(
                ctx.plan,
                ctx.data,
                (&finished, lineage),
                (gain, after),
            );
            match c {
                Some(c) => return Ok(FirstFit::Done(Box::new(c))),
                None => None,
            }
        }
        other => other,
    };
    // without an in-sample reading it is judged by its folds alone
    let in_sample = in_sample.unwrap_or_else(|| (f64::NAN, crate::evaluate::Residuals::default()));
    Ok(FirstFit::Whole(Box::new(Waiting {
        raw,
        start,
        finished,
        in_sample,
    })))
}

/// The folds of a proposal fitted on the plan's record (`raw` and the
/// start it chose), and its score over them.
fn fold_fits(
    e: &'static dyn Extension,
    p: &Proposal,
    ctx: &Context,
    (raw, start): (&FittedModel, Option<usize>),
) -> Result<Evaluated, DiagnoseError> {
    let mut c = assess_from(ctx.plan, ctx.data, p.lineage.clone(), &|t| match t {
        None => Ok((raw.clone(), start)),
        Some(_) => e.fit_choosing(p, &ctx.at_fold(t)),
    })?;
    e.rescore(ctx, &mut c)?;
    Ok(c)
}

/// The escalation (tried once per diagnosis) when no new cause was chosen:
/// it must pay against the current model and against the simple choice.
/// A failed fit comes back as its extension and error (for the decisions
/// line).
fn escalate(
    ctx: &Context,
    (ext, p): (&'static dyn Extension, Proposal),
    cands: &mut Vec<Candidate>,
    chosen: Option<usize>,
    it: usize,
) -> Result<Option<usize>, String> {
    let pol = ctx.policy();
    ctx.observer
        .progress(it, it + 1, "fitting the hidden-state model");
    let f = fit_proposal(ext, &p, ctx).map_err(|e| failure(ext, &e))?;
    let seed = pol.seed.wrapping_add(1000 * it as u64 + 999);
    let mut c = score(ext, p, f, ctx, seed);
    if let Some(simple) = chosen.map(|i| &cands[i].fitted) {
        let (g2, ci2) = relative_gain_ci(
            &simple.select.e,
            &c.fitted.select.e,
            pol.block_for(&simple.select.e),
            pol.bootstrap,
            seed + 1,
        );
        c.pays = c.pays && ci2[0] > 0.0 && g2 >= pol.min_gain;
    }
    let pays = c.pays;
    cands.push(c);
    Ok(pays.then_some(cands.len() - 1))
}

/// The report rows of an iteration: every candidate but those that
/// diverged, of the plain order increases only the best (or the chosen),
/// accepted first.
fn rows(
    cands: &[Candidate],
    (chosen, diverged): (Option<usize>, &[usize]),
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
        if diverged.contains(&i) {
            continue;
        }
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
            extension: match (f.screened, f.screened_by_rival, f.screened_by_bound) {
                (Some(_), _, Some(r)) => format!(
                    "{} (select gain: on the training data in-sample; its in-sample error is {r:.2}× the smallest cross-validated error of the step, so not cross-validated)",
                    c.ext.row_text(&c.proposal, &f.model)
                ),
                (Some(_), Some(r), None) => format!(
                    "{} (select gain: on the training data in-sample; its in-sample error is {r:.2}× that of the same structure at another input delay, so not cross-validated)",
                    c.ext.row_text(&c.proposal, &f.model)
                ),
                (Some(_), None, None) => format!(
                    "{} (select gain: on the training data in-sample, below min_gain, so not cross-validated)",
                    c.ext.row_text(&c.proposal, &f.model)
                ),
                _ => c.ext.row_text(&c.proposal, &f.model),
            },
            nrmse_before: cur.scores.nrmse,
            nrmse_after: f.scores.nrmse,
            gain,
            gain_metric: metric.to_string(),
            gain_select: c.gain,
            gain_ci: c.ci,
            nll_before: cur.scores.nll,
            nll_after: f.scores.nll,
            accepted,
            noise: f.finding.clone(),
        });
    }
    out.sort_by_key(|r| !r.accepted);
    out
}

/// What every iteration of one diagnosis shares.
struct Run<'a> {
    d: &'a DiagnoseData,
    plan: &'a Plan,
    opts: &'a DiagnoseOptions,
    obs: &'a dyn Observer,
    /// The select block repeats the fit block's input: a chosen step must
    /// carry over ([`carried_over_choice`]).
    repeated: bool,
}

/// Free-run simulation of the dynamics `m` extends on `rec`, started from
/// its measured history (the warm start of output-error constructions).
pub(crate) fn simulated_on(m: &FittedModel, rec: &gb_core::Record) -> Option<Vec<f64>> {
    let c = core(m);
    let hist = c.history_len().min(rec.len());
    c.simulate(&rec.inputs, Init::History(&rec.output[..hist]))
        .ok()
}

/// Free-run simulations of `m` on every record of `recs`, each from its own
/// start; `None` with fewer than two records or when one fails.
fn simulated_on_all(m: &FittedModel, recs: &[gb_core::Record]) -> Option<Vec<Vec<f64>>> {
    if recs.len() < 2 {
        return None;
    }
    recs.iter().map(|r| simulated_on(m, r)).collect()
}

/// One iteration: evidence, candidates, choice, escalation, rows.
fn iterate(
    run: &Run,
    cur: &Evaluated,
    causes: &[Cause],
    (tried, skip): (&mut HashSet<&'static str>, &Skip),
    it: usize,
) -> Option<Iteration> {
    let Run {
        d, plan, opts, obs, ..
    } = *run;
    let ev = Evidence::compute(&cur.select.e, &cur.select.yhat, &plan.decision_inputs(d));
    let simulated_fit = simulated_on(&cur.model, &plan.fit);
    let fold_sims: Vec<Option<Vec<f64>>> = cur
        .folds
        .iter()
        .zip(&plan.folds)
        .map(|(e, f)| simulated_on(&e.model, &f.fit))
        .collect();
    let simulated_fits = simulated_on_all(&cur.model, &plan.fits);
    let fold_sims_all: Vec<Option<Vec<Vec<f64>>>> = cur
        .folds
        .iter()
        .zip(&plan.folds)
        .map(|(e, f)| simulated_on_all(&e.model, &f.fits))
        .collect();
    let templates = crate::extensions::TemplateCache::default();
    let ctx = Context {
        data: d,
        fit: &plan.fit,
        fits: &plan.fits,
        current: cur,
        causes,
        evidence: &ev,
        options: opts,
        simulated_fit: simulated_fit.as_deref(),
        simulated_fits: simulated_fits.as_deref(),
        observer: obs,
        plan,
        fold_sims: &fold_sims,
        fold_sims_all: &fold_sims_all,
        start_choice: None,
        whole_fit: None,
        rival_of: None,
        templates: Some(&templates),
        futile_gain: (opts.policy.futile_gain > 0.0).then_some(opts.policy.futile_gain),
    };
    let props: Vec<_> = proposals(&ctx, tried)
        .into_iter()
        .filter(|(e, p)| {
            !skip.lost.contains(&(e.name(), p.text.clone())) && !skip.beaten.contains(e.name())
        })
        .collect();
    if props.is_empty() {
        return None;
    }
    let Screened {
        mut cands,
        note: mut screened,
        held,
    } = timed_phase("candidates", || screened_candidates(&ctx, props, it));
    let (mut chosen, mut note) = timed_phase("choose", || choose(&mut cands, &ctx, it));
    let mut carry = CarryOver::default();
    if run.repeated {
        (chosen, note) = carried_over_choice(&mut cands, (chosen, note), &ctx, it, &mut carry);
    }
    let new_cause = chosen
        .is_some_and(|i| cands[i].role() == Role::NewCause && !causes.contains(&cands[i].cause()));
    // an order increase after a named hysteresis may only stand in for the
    // hysteresis the simple extension missed: the escalation competes
    // with it (and must beat it)
    let order_after_hysteresis = chosen.is_some_and(|i| {
        new_cause && cands[i].cause() == Cause::Dynamics && causes.contains(&Cause::Hysteresis)
    });
    if !new_cause || order_after_hysteresis {
        let escalation = EXTENSIONS
            .iter()
            .filter(|e| e.role() == Role::Escalation && !tried.contains(e.name()))
            .find_map(|e| e.propose(&ctx).into_iter().next().map(|p| (*e, p)));
        if let Some(esc) = escalation {
            tried.insert(esc.0.name());
            match escalate(&ctx, esc, &mut cands, chosen, it) {
                Ok(Some(i)) => chosen = Some(i),
                Ok(None) => {}
                Err(f) => screened = appended(screened, failed_note(&[f], it)),
            }
        }
    }
    for c in &cands {
        if c.ext.once() {
            tried.insert(c.ext.name());
        }
    }
    let diverged: Vec<usize> = (0..cands.len())
        .filter(|&i| Some(i) != chosen && diverged(&cands[i], cur, ctx.policy()))
        .collect();
    let rows = rows(&cands, (chosen, &diverged), note.as_deref(), &ctx, it);
    let notes = appended(
        appended(screened, carry.note),
        diverged_note(&cands, &diverged, cur, ctx.policy(), it),
    );
    let carry_checked = chosen.is_some() && chosen == carry.checked;
    let lost = cands
        .iter()
        .filter(|c| !c.pays)
        .map(|c| (c.ext.name(), c.proposal.text.clone()))
        .chain(held)
        .collect();
    let beaten = beaten_extensions(&cands);
    let chosen = chosen.map(|i| {
        let c = cands.swap_remove(i);
        (c.fitted, (c.proposal.cause, c.ext, c.proposal))
    });
    Some(Iteration {
        rows,
        chosen,
        lost,
        beaten,
        notes,
        carry_checked,
    })
}

/// The training record's inputs over its fit block (what the carry-over
/// check of a repeated excitation simulates).
fn fit_block_inputs(d: &DiagnoseData) -> Vec<Vec<f64>> {
    d.train
        .inputs
        .iter()
        .map(|s| s[d.fit.clone()].to_vec())
        .collect()
}

/// What [`carried_over_choice`] found: the decisions line's text and the
/// candidate it checked last and kept.
#[derive(Default)]
struct CarryOver {
    note: Option<String>,
    checked: Option<usize>,
}

/// On a repeated excitation, the step's choice (and its note) among
/// candidates that carry over: a structural choice that parts from the current model on
/// shifted inputs more than `repeat_shift_ratio` times as much as on the
/// fit block's input ([`crate::repeat::shift_disagreement`]) no longer
/// pays, and the step chooses again among the rest (duffing 5 of the
/// sweep at its own length, 635 samples of a periodic PRBS: the nonlinear
/// spring parts 3.8× as much time-reversed from a linear model 32× the
/// noise floor; the search stopped there with no cause). A choice that a
/// paying rival of another class agrees with off the trajectory
/// ([`crate::repeat::shift_witness`]) carries over: the current model is
/// what the trajectory tuned (duffing 5: the nonlinear spring and the
/// polynomial NOE 4.9e-4 apart time-reversed, each 9.9e-3 from the linear
/// model there and 2.6e-3 on the input itself; 32 → 1.06× the floor). A
/// noise step is not checked, nor are models that cannot be compared.
fn carried_over_choice(
    cands: &mut [Candidate],
    (mut chosen, mut note): (Option<usize>, Option<String>),
    ctx: &Context,
    it: usize,
    out: &mut CarryOver,
) -> (Option<usize>, Option<String>) {
    let d = ctx.data;
    let u = fit_block_inputs(d);
    let max = ctx.policy().repeat_shift_ratio;
    let mut texts = vec![];
    while let Some(i) = chosen {
        if cands[i].cause() == Cause::Noise {
            break;
        }
        let Some((r, how)) =
            crate::repeat::shift_disagreement(&ctx.current.model, &cands[i].fitted.model, &u)
        else {
            break;
        };
        if r <= max {
            texts.push(format!(
                "step {it}'s choice carries over the repeated excitation (on the fit block's input {how} it parts from the current model {r:.2}× as much as on the input itself; at most {max}×)"
            ));
            out.checked = Some(i);
            break;
        }
        let rivals: Vec<usize> = (0..cands.len())
            .filter(|&j| {
                let c = &cands[j];
                j != i && c.pays && c.structural_new() && c.ext.name() != cands[i].ext.name()
            })
            .collect();
        let witness = crate::repeat::shift_witness(
            &cands[i].fitted.model,
            &ctx.current.model,
            rivals.iter().map(|&j| &cands[j].fitted.model),
            &u,
            how,
        );
        if let Some((j, gap)) = witness.map(|(k, gap)| (rivals[k], gap)) {
            texts.push(format!(
                "step {it}'s choice parts from the current model {r:.1}× as much on the fit block's input {how} as on the input itself (more than {max}×), but {} agrees with it there to {gap:.2}× its departure on the input itself: the current model, not the choice, is what the trajectory tuned",
                short_label(&cands[j])
            ));
            out.checked = Some(i);
            break;
        }
        texts.push(format!(
            "step {it}: {} was not accepted: simulated on the fit block's input {how} it parts from the current model {r:.1}× as much as on the input itself (at most {max}×) — it reproduces the repeated trajectory, not what carries over to other inputs",
            short_label(&cands[i])
        ));
        cands[i].pays = false;
        (chosen, note) = choose(cands, ctx, it);
    }
    if !texts.is_empty() {
        out.note = Some(format!("; {}", texts.join("; ")));
    }
    (chosen, note)
}

/// The extensions of the step whose every candidate lost decisively: the
/// whole 95 % interval of its select gain below zero.
fn beaten_extensions(cands: &[Candidate]) -> HashSet<&'static str> {
    beaten(cands.iter().map(|c| (c.ext.name(), c.pays, c.ci[1])))
}

/// Of the candidates `(extension, pays, upper end of the gain interval)`,
/// the extensions none of whose candidates pays or reaches a gain of 0.
fn beaten<'a>(cands: impl Iterator<Item = (&'a str, bool, f64)> + Clone) -> HashSet<&'a str> {
    let mut out: HashSet<&'a str> = cands.clone().map(|c| c.0).collect();
    for (name, pays, hi) in cands {
        if pays || hi >= 0.0 || hi.is_nan() {
            out.remove(name);
        }
    }
    out
}

/// Candidates the next step does not fit again: after a step that changed
/// only the noise model, those that did not pay (`retry_after_noise_step`
/// false); after a refinement (more capacity for a named cause, policy
/// `retry_after_refinement` false), the extensions whose every candidate
/// lost decisively.
#[derive(Default)]
struct Skip {
    lost: HashSet<Lost>,
    beaten: HashSet<&'static str>,
}

/// After step `it`: when it was a refinement (and the policy does not
/// retry), the extensions it beat join those skipped since the last
/// non-refinement step (the decisions line names the new ones); after any
/// other step none is skipped.
fn skip_beaten(
    skip: &mut Skip,
    (refined, beaten): (bool, HashSet<&'static str>),
    opts: &DiagnoseOptions,
    it: usize,
    decision: &mut String,
) {
    if !refined || opts.policy.retry_after_refinement {
        skip.beaten.clear();
        return;
    }
    if !beaten.is_empty() {
        let mut names: Vec<&str> = beaten.iter().copied().collect();
        names.sort_unstable();
        decision.push_str(&format!(
            "; step {it} added capacity to a named cause: the extensions whose every candidate lost decisively there ({}) were not fitted again",
            names.join(", ")
        ));
    }
    skip.beaten.extend(beaten);
}

/// Whether candidate `c` diverged: its RMS error on the decision data is
/// above `diverged_ratio` × the current model's and its NRMSE there above
/// `diverged_nrmse`.
fn diverged(c: &Candidate, cur: &Evaluated, pol: &DecisionPolicy) -> bool {
    let (after, before) = (c.fitted.scores.nrmse_select, cur.scores.nrmse_select);
    !after.is_finite() || (after > pol.diverged_ratio * before && after > pol.diverged_nrmse)
}

/// A candidate in a few words: its extension's name and, where that
/// extension proposes several, what it adds (its proposal's text up to the
/// model it extends, at most 90 characters).
fn short_label(c: &Candidate) -> String {
    let text = c.proposal.text.as_str();
    let head = text.split(" in the model").next().unwrap_or(text);
    if head.is_empty() || head == c.ext.name() {
        return c.ext.name().to_string();
    }
    let mut short: String = head.chars().take(90).collect();
    if short.len() < head.len() {
        short.push('…');
    }
    format!("{}: {short}", c.ext.name())
}

/// The decisions line's note on the candidates of step `it` that diverged
/// (indices `which` of `cands`), `None` when none did.
fn diverged_note(
    cands: &[Candidate],
    which: &[usize],
    cur: &Evaluated,
    pol: &DecisionPolicy,
    it: usize,
) -> Option<String> {
    if which.is_empty() {
        return None;
    }
    let names: Vec<String> = which
        .iter()
        .map(|&i| {
            let c = &cands[i];
            format!(
                "{} (NRMSE {:.3e})",
                short_label(c),
                c.fitted.scores.nrmse_select
            )
        })
        .collect();
    Some(format!(
        "; step {it}: {} candidate{} diverged on the decision data (NRMSE above {}× the current model's {:.4} and above {}) and {} left out of the table: {}",
        which.len(),
        if which.len() == 1 { "" } else { "s" },
        pol.diverged_ratio,
        cur.scores.nrmse_select,
        pol.diverged_nrmse,
        if which.len() == 1 { "is" } else { "are" },
        names.join(", ")
    ))
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
///
/// No extension step starts after `search_budget_s` (the report's
/// decision line says when the budget ended the search). Training records
/// of the policy's `long_record` samples or more are searched on a
/// subsample of `search_samples` within that budget,
/// and the chosen baseline and final structures are refitted on the whole
/// fit block (see [`DecisionPolicy`]).
pub fn diagnose(
    d: &DiagnoseData,
    opts: &DiagnoseOptions,
    obs: Option<&dyn Observer>,
) -> Result<Diagnosis, DiagnoseError> {
    opts.check()?;
    let pol = &opts.policy;
    d.check(pol.min_fit, pol.min_block)?;
    let obs: &dyn Observer = obs.unwrap_or(&Silent);
    if d.multi() && opts.physics.is_some() {
        return Err(DiagnoseError::InvalidArgument(
            "several training records are not supported with your own equations (--model-file) yet"
                .into(),
        ));
    }
    // the physics baseline fits long records whole (its fits are cheap);
    // several records are searched whole (no subsample)
    if opts.physics.is_none() && !d.multi() && d.select.end - d.fit.start >= pol.long_record {
        return crate::long::diagnose_long(d, opts, obs);
    }
    let budget = Duration::from_secs_f64(pol.search_budget_s);
    search(d, opts, obs, Some(Instant::now() + budget), true)
}

/// Whether the residuals of `cur` on the decision data show no hint of
/// structure at the reading `r`: no test of the verdict
/// ([`crate::verdict::verdict_tested`]) rejects at its level (each test at it, or
/// Bonferroni over the tests), the residual is within its noise ratio
/// times the white-noise level, and the Jarque–Bera test does not reject
/// normality at the level either (heavy tails are the `noise` cause's
/// evidence). Before a step ([`Reading::search_stop`]): the search for a
/// cause runs where the residual shows one.
fn residual_quiet(cur: &Evaluated, (plan, d): (&Plan, &DiagnoseData), r: Reading) -> bool {
    quiet_at(&plan.tested(cur, d), r)
}

/// Whether the residual of `cur` on the decision data passes every test
/// that involves the inputs (cross-correlation, higher-order
/// correlations, static nonlinearity, memory) at reading `r` — whiteness,
/// normality and the size are not read: a noise model that paid explains
/// the colour, the tails and the excess over the white-noise level.
fn input_quiet(cur: &Evaluated, (plan, d): (&Plan, &DiagnoseData), r: Reading) -> bool {
    crate::verdict::input_quiet(&plan.tested(cur, d), (r.level, r.corrected))
}

/// [`residual_quiet`] on what [`Plan::tested`] gave.
fn quiet_at(t: &crate::plan::Tested, r: Reading) -> bool {
    let normal = crate::stats::jarque_bera(&t.whole.e).3 >= r.level;
    normal && crate::verdict::quiet(t, (r.level, r.corrected), r.noise_ratio)
}

/// How [`residual_quiet`] reads a residual: the level of the residual
/// tests, whether it is Bonferroni-corrected over the verdict's tests, and
/// the largest residual RMS in units of the white-noise level.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Reading {
    level: f64,
    corrected: bool,
    noise_ratio: f64,
}

impl Reading {
    /// The search stop's reading (`search_stop_level`, uncorrected,
    /// `verdict_noise_ratio`).
    fn search_stop(pol: &DecisionPolicy) -> Self {
        Self {
            level: pol.search_stop_level,
            corrected: false,
            noise_ratio: pol.verdict_noise_ratio,
        }
    }
    /// The screen's reading (`screen_level`, Bonferroni-corrected when
    /// `screen_bonferroni`, `screen_noise_ratio`).
    fn screen(pol: &DecisionPolicy) -> Self {
        Self {
            level: pol.screen_level,
            corrected: pol.screen_bonferroni,
            noise_ratio: pol.screen_noise_ratio,
        }
    }
    /// How the level applies, in words.
    fn reading_text(&self) -> &'static str {
        if self.corrected {
            "Bonferroni over the tests"
        } else {
            "each test, uncorrected"
        }
    }
}

/// The reading at which the current model's residual is quiet before
/// step `it`, when it is (policy `stop_when_adequate`): the search-stop
/// reading before every step, and after an accepted step also the
/// screen's ([`Reading::screen`]: a stricter noise ratio), which already
/// decides that the costly candidates of a step are not needed.
fn stop_reading(
    cur: &Evaluated,
    at: (&Plan, &DiagnoseData),
    pol: &DecisionPolicy,
    it: usize,
) -> Option<Reading> {
    if !pol.stop_when_adequate {
        return None;
    }
    let screen = (it > 1 && pol.screen_costly).then(|| Reading::screen(pol));
    // one in-sample simulation for both readings
    let tested = at.0.tested(cur, at.1);
    [Reading::search_stop(pol)]
        .into_iter()
        .chain(screen)
        .find(|&r| quiet_at(&tested, r))
}

/// The plan of the search: [`Plan::new`]; for the engineer's equations
/// with every held-out sample scored ([`Plan::whole_folds`]: their laws
/// are judged beyond their folds' range too) and the report block kept out
/// of the folds (a record's tail that leaves the training range would
/// judge extrapolation only).
fn decision_plan(d: &DiagnoseData, opts: &DiagnoseOptions) -> Plan {
    match &opts.physics {
        Some(_) => Plan::new(
            d,
            &DecisionPolicy {
                cv_whole_short_record: false,
                ..opts.policy.clone()
            },
        )
        .whole_folds(),
        None => Plan::new(d, &opts.policy),
    }
}

/// The held-out figure of a record cross-validated whole: the pooled fold
/// NRMSE of the baseline and of the final model of `chain`.
fn cross_validated_text(chain: &[Evaluated]) -> String {
    let (b, f) = (&chain[0], &chain[chain.len() - 1]);
    format!(
        "; cross-validated NRMSE (each fold's held-out samples, scored by its refit): baseline {:.4}, final {:.4}",
        b.scores.nrmse_select, f.scores.nrmse_select
    )
}

/// The diagnosis loop; with a `deadline`, no step starts after it. With
/// `refit`, the chosen chain is refitted on the whole training record
/// ([`crate::refit`]).
pub(crate) fn search(
    d: &DiagnoseData,
    opts: &DiagnoseOptions,
    obs: &dyn Observer,
    deadline: Option<Instant>,
    refit: bool,
) -> Result<Diagnosis, DiagnoseError> {
    let total = 1 + opts.max_steps;
    obs.progress(0, total, "fitting the baseline");
    let plan0 = decision_plan(d, opts);
    let base = match &opts.physics {
        Some(spec) => crate::physics::physics_baseline(d, &plan0, spec, obs)?,
        None => timed_phase("baseline", || baseline(d, &plan0, opts))?,
    };
    let plan = base.plan;
    let opts = &*opts.for_plan(&plan);
    let mut choice = base.choice;
    choice.decision = plan.describe(d);
    let mut repeated = false;
    if let Some(note) = crate::repeat::repeated_note(
        &d.train,
        d.fit.clone(),
        d.select.clone(),
        opts.policy.repeat_correlation,
    ) {
        choice.decision.push_str(&note);
        repeated = true;
    }
    let mut chain = vec![base.eval];
    let mut steps = vec![];
    let mut causes: Vec<Cause> = vec![];
    let mut tried = HashSet::new();
    // after a step that changed only the noise model: the candidates that
    // did not pay there (`retry_after_noise_step`)
    let mut skip = Skip::default();
    let mut picks: Vec<crate::refit::Pick> = vec![];
    for it in 1..=opts.max_steps {
        if deadline.is_some_and(|t| Instant::now() > t) {
            choice.decision.push_str(&format!(
                "; the search budget of {} s ended the search before step {it}",
                opts.policy.search_budget_s
            ));
            break;
        }
        obs.progress(
            it,
            total,
            &format!("step {it}: fitting candidate extensions"),
        );
        let cur = chain.last().expect("the chain holds the baseline");
        if let Some(r) = stop_reading(cur, (&plan, d), &opts.policy, it) {
            choice.decision.push_str(&format!(
                "; before step {it} every residual test passed at the {} % level ({}; normality at {} %) and the residual was within {}× the white-noise level: no extension was searched",
                100.0 * r.level,
                r.reading_text(),
                100.0 * r.level,
                r.noise_ratio
            ));
            break;
        }
        let run = Run {
            d,
            plan: &plan,
            opts,
            obs,
            repeated,
        };
        let Some(step) = timed_phase("step", || {
            iterate(&run, cur, &causes, (&mut tried, &skip), it)
        }) else {
            choice.decision.push_str(&format!(
                "; before step {it} no candidate extension applies to the current model ({}) that was not tried already: the search ended there",
                cur.model.dynamics.describe()
            ));
            break;
        };
        if let Some(note) = &step.notes {
            choice.decision.push_str(note);
        }
        let mut rows = step.rows;
        let stop = repeated
            && !step.carry_checked
            && step.chosen.as_ref().is_some_and(|(model, pick)| {
                carry_over_stop(
                    d,
                    (cur, model, pick),
                    opts,
                    it,
                    (&mut rows, &mut choice.decision),
                )
            });
        steps.extend(rows);
        if stop {
            break;
        }
        match step.chosen {
            Some((model, pick)) => {
                if pick.0 == Cause::Noise && !opts.policy.retry_after_noise_step {
                    choice.decision.push_str(&format!(
                        "; step {it} changed only the noise model: its {} candidates that did not pay or were not fitted are not fitted again",
                        step.lost.len()
                    ));
                    skip.lost.extend(step.lost);
                } else {
                    skip.lost.clear();
                }
                let refined = pick.1.role() == Role::Refinement;
                skip_beaten(
                    &mut skip,
                    (refined, step.beaten),
                    opts,
                    it,
                    &mut choice.decision,
                );
                if !causes.contains(&pick.0) {
                    causes.push(pick.0);
                }
                chain.push(model);
                picks.push(pick);
            }
            None => break,
        }
    }
    Ok(finish(
        d,
        &plan,
        (chain, picks),
        (steps, causes, choice),
        opts,
        obs,
        (refit, total),
    ))
}

/// After the search: the chain refitted on the whole training record (with
/// `refit`), the cross-validated figure of a record that the folds span,
/// the model saved refitted on all samples, and the assembled diagnosis.
fn finish(
    d: &DiagnoseData,
    plan: &Plan,
    (chain, picks): (Vec<Evaluated>, Vec<crate::refit::Pick>),
    (steps, causes, mut choice): (Vec<Step>, Vec<Cause>, StructureChoice),
    opts: &DiagnoseOptions,
    obs: &dyn Observer,
    (refit, total): (bool, usize),
) -> Diagnosis {
    let refitted = refit
        .then(|| {
            timed_phase("refit", || {
                crate::refit::refit_chain(d, plan, &chain, &picks, opts, obs)
            })
        })
        .flatten();
    obs.progress(total, total, "done");
    let refitted = refitted.and_then(|(r, note)| {
        choice.decision.push_str(&note);
        r
    });
    let (reported, judged) = match refitted {
        Some(r) => (r, Some(chain)),
        None => (chain, None),
    };
    if plan.spans_report {
        choice.decision.push_str(&cross_validated_text(&reported));
    }
    let saved = refit
        .then(|| {
            timed_phase("refit on all samples", || {
                crate::refit::refit_on_all_samples(d, plan, &reported, &picks, opts, obs)
            })
        })
        .flatten()
        .and_then(|(m, note)| {
            choice.decision.push_str(&note);
            m
        });
    let mut diagnosis = assemble(
        d,
        plan,
        (reported, judged.as_deref()),
        steps,
        causes,
        choice,
        &opts.policy,
    );
    diagnosis.saved = saved;
    diagnosis
}

/// On a repeated excitation, whether step `it`'s chosen structural model
/// fails to carry over: it parts from the current one on shifted inputs
/// more than `repeat_shift_ratio` times as much as on the fit block's
/// input ([`crate::repeat::shift_disagreement`]). The decisions line gets
/// the ratio either way; a step that does not carry over has its rows
/// unmarked and the search stops. A noise step changes how the residual is
/// read, not the response to the input, and is not checked; nor are models
/// that cannot be compared.
fn carry_over_stop(
    d: &DiagnoseData,
    (cur, chosen, pick): (&Evaluated, &Evaluated, &crate::refit::Pick),
    opts: &DiagnoseOptions,
    it: usize,
    (rows, decision): (&mut [Step], &mut String),
) -> bool {
    if pick.0 == Cause::Noise {
        return false;
    }
    let u = fit_block_inputs(d);
    let Some((r, how)) = crate::repeat::shift_disagreement(&cur.model, &chosen.model, &u) else {
        return false;
    };
    let max = opts.policy.repeat_shift_ratio;
    if r <= max {
        decision.push_str(&format!(
            "; step {it}'s choice carries over the repeated excitation (on the fit block's input {how} it parts from the current model {r:.2}× as much as on the input itself; at most {max}×)"
        ));
        return false;
    }
    decision.push_str(&format!(
        "; step {it}'s choice ({}: {}) was not accepted and the search stopped: simulated on the fit block's input {how} it parts from the current model {r:.1}× as much as on the input itself (at most {max}×) — it reproduces the repeated trajectory, not what carries over to other inputs",
        pick.0.name(),
        chosen.model.describe()
    ));
    for row in rows.iter_mut().filter(|row| row.iteration == it) {
        row.accepted = false;
    }
    true
}

/// The diagnosis from its chain of models and its rows: `(chain, judged)`,
/// the models reported and, when they were refitted on the whole training
/// record, the chain as the search fitted it, whose held-out residuals the
/// evidence and the verdict read.
pub(crate) fn assemble(
    d: &DiagnoseData,
    plan: &Plan,
    (chain, judged): (Vec<Evaluated>, Option<&[Evaluated]>),
    steps: Vec<Step>,
    causes: Vec<Cause>,
    structure: StructureChoice,
    pol: &DecisionPolicy,
) -> Diagnosis {
    let inputs = plan.decision_inputs(d);
    let held = judged.unwrap_or(&chain);
    let (base, last) = (&held[0], &held[held.len() - 1]);
    let (base_model, final_model) = (&chain[0], &chain[chain.len() - 1]);
    let final_evidence = Evidence::compute(&last.select.e, &last.select.yhat, &inputs);
    let noise = chain.iter().rev().find_map(|e| e.finding.clone());
    // a noise model that paid on held-out data explains the residual's
    // size: only the correlation tests judge then
    let ratio = if noise.is_some() {
        f64::INFINITY
    } else {
        pol.verdict_noise_ratio
    };
    let coloured = if noise.is_some() {
        f64::INFINITY
    } else {
        pol.coloured_noise_ratio
    };
    let mut verdict = crate::verdict::verdict_tested(
        &plan.tested(last, d),
        (pol.verdict_level, ratio, coloured),
        &tried_summary(&steps),
    );
    if let Some(n) = &noise {
        verdict
            .text
            .push_str(&format!("; the noise model found {}", n.text));
    }
    let scored = d.report_scored(plan.w);
    let report_inputs: Vec<&[f64]> = d.report.inputs.iter().map(|u| &u[scored.clone()]).collect();
    // a report block inside the cross-validation is not held out
    let carry = (!plan.spans_report).then(|| {
        crate::verdict::report_carry_over(
            (&last.select.e, &final_model.report.e),
            (&plan.fit_y, &report_inputs),
            pol.report_carry_ratio,
        )
    });
    if let Some(note) = carry.flatten() {
        verdict.not_carried_over(&note);
    }
    let report = Report {
        version: REPORT_VERSION,
        data: DataSummary {
            inputs: d.train.input_names.clone(),
            output: d.train.output_name.clone(),
            samples_fit: plan.fit.len(),
            samples_select: d.select_samples(),
            samples_validate: d.report_scored(plan.w).len(),
            split: d.split_text(),
            init_window: plan.w,
            decision: structure.decision.clone(),
            records: d.record_summaries(),
            report_in_sample: plan.spans_report,
        },
        baseline: ModelSummary::of(base_model),
        structure,
        steps,
        causes,
        final_model: ModelSummary::of(final_model),
        evidence: Evidence::compute(&base.select.e, &base.select.yhat, &inputs),
        final_evidence,
        verdict,
        noise,
    };
    Diagnosis {
        report,
        model: final_model.model.clone(),
        chain,
        saved: None,
    }
}

#[cfg(test)]
mod tests {
    use super::{beaten, kind_once, longest_first, longest_first_after};

    /// A failed candidate's error says its kind once, and a message that
    /// merely contains a colon is left whole.
    #[test]
    fn a_failed_candidates_error_says_its_kind_once() {
        let nested =
            "invalid argument: invalid argument: invalid argument: the poles 0.93 and -0.97";
        assert_eq!(
            kind_once(nested.into()),
            "invalid argument: the poles 0.93 and -0.97"
        );
        let plain = "unstable: the simulation diverged: at sample 12";
        assert_eq!(kind_once(plain.into()), plain);
    }

    /// An extension is beaten only when every candidate of it lost
    /// decisively: one candidate whose interval reaches 0, or that pays,
    /// keeps it.
    #[test]
    fn an_extension_is_beaten_only_when_every_candidate_lost_decisively() {
        let rows = [
            ("preisach-columns", false, -0.12),
            ("preisach-columns", false, -1.08),
            ("linear-order", false, -0.2),
            ("linear-order", false, 0.10),
            ("capacity", true, 0.13),
            ("lolimot", false, 0.0),
            ("wiener", false, f64::NAN),
        ];
        let b = beaten(rows.iter().copied());
        assert_eq!(b.len(), 1, "{b:?}");
        assert!(b.contains("preisach-columns"));
        assert!(beaten([("x", true, -1.0)].iter().copied()).is_empty());
        assert!(beaten(std::iter::empty()).is_empty());
    }

    /// `f()` on a pool of one worker thread.
    fn on_one_thread<T: Send>(f: impl FnOnce() -> T + Send) -> T {
        rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .expect("a one-thread pool")
            .install(f)
    }

    /// The parallel fits of a step come back in proposal order, each run
    /// once, and a single worker starts them costliest first (stable among
    /// equal costs).
    #[test]
    fn fits_run_once_each_costliest_first_and_come_back_in_order() {
        use std::sync::Mutex;
        let cost = [1u8, 3, 0, 3, 2, 1];
        let started = Mutex::new(vec![]);
        let out = on_one_thread(|| {
            longest_first(
                cost.len(),
                |k| cost[k],
                |k| {
                    started.lock().expect("not poisoned").push(k);
                    10 * k
                },
            )
        });
        assert_eq!(out, vec![0, 10, 20, 30, 40, 50]);
        assert_eq!(
            *started.lock().expect("not poisoned"),
            vec![1, 3, 4, 0, 5, 2]
        );
        // on the global pool too, every job exactly once, results in order
        let ran = Mutex::new(vec![]);
        let out = longest_first(
            40,
            |k| (k % 4) as u8,
            |k| {
                ran.lock().expect("not poisoned").push(k);
                k * k
            },
        );
        assert_eq!(out, (0..40).map(|k| k * k).collect::<Vec<_>>());
        let mut ran = ran.into_inner().expect("not poisoned");
        ran.sort_unstable();
        assert_eq!(ran, (0..40).collect::<Vec<_>>());
        assert!(longest_first(0, |_| 0, |k| k).is_empty());
    }

    /// A job that waits for a sibling runs after it, with its result, and
    /// joins the queue by its cost once the sibling is done; a single
    /// worker runs them all (no job waits forever).
    #[test]
    fn delay_rivals_run_after_their_sibling_with_its_result() {
        use std::sync::Mutex;
        let cost = [3u8, 3, 1, 0, 2, 3];
        let after = [None, Some(0), None, Some(2), Some(0), None];
        // a job's result: 100 + its sibling's, or its own index
        let run = |k: usize, sibling: Option<&usize>| sibling.map_or(k, |s| 100 + s);
        let expected = vec![0, 100, 2, 102, 100, 5];
        let started = Mutex::new(vec![]);
        let out = on_one_thread(|| {
            longest_first_after(
                cost.len(),
                |k| cost[k],
                &after,
                |k, s| {
                    started.lock().expect("not poisoned").push(k);
                    run(k, s)
                },
            )
        });
        assert_eq!(out, expected);
        // 0 and 5 (cost 3) first; 0's rivals 1 (cost 3) and 4 (cost 2)
        // join behind 5, before 2 (cost 1); 2's rival 3 last
        assert_eq!(
            *started.lock().expect("not poisoned"),
            vec![0, 5, 1, 4, 2, 3]
        );
        // on the global pool, many rivals of few siblings
        let n = 60;
        let after: Vec<Option<usize>> = (0..n).map(|k| (k >= 3).then_some(k % 3)).collect();
        let out = longest_first_after(
            n,
            |k| (k % 4) as u8,
            &after,
            |k, s| s.map_or(k, |s| 100 + s),
        );
        let want: Vec<usize> = (0..n)
            .map(|k| if k < 3 { k } else { 100 + k % 3 })
            .collect();
        assert_eq!(out, want);
        // a job that panics: the panic comes back, no worker waits forever
        // for its rivals
        let two = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .expect("a two-thread pool");
        let caught = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            two.install(|| {
                longest_first_after(
                    4,
                    |_| 1,
                    &[None, Some(0), Some(0), None],
                    |k, _| {
                        if k == 0 {
                            std::thread::sleep(std::time::Duration::from_millis(50));
                            panic!("job 0 fails");
                        }
                        k
                    },
                )
            })
        }));
        assert!(caught.is_err());
    }
}
