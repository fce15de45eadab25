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
    let m = fit_params(spec.clone(), rec)
        .check()
        .map_err(CoreError::from)?
        .identify_growing(&Records::single(rec.clone()), obs)
        .map_err(CoreError::from)?;
    Ok(m.to_fitted().map_err(CoreError::from)?)
}

/// [`fit_physics`] of an extension started from a fitted model's
/// estimates (its new terms at their start values): for the blind
/// mechanical template one Levenberg–Marquardt path from that start. The
/// growing prefixes and the direct path beside them guard a cold start
/// against the phase drift of distant parameters; from a fitted model they
/// refit the same neighbourhood five times (on a Preisach-spring case of
/// 8000 samples, 12 extension fits of 0.6–2.9 s each in one step). The
/// engineer's model keeps [`fit_physics`]: its extensions may move a
/// limit that binds for real (the tanks' overflow) far from its start.
pub(crate) fn fit_physics_warm(
    spec: &PhysicsSpec,
    rec: &Record,
    obs: &dyn Observer,
) -> Result<FittedModel, DiagnoseError> {
    if !spec_is_template(&spec.name) {
        return fit_physics(spec, rec, obs);
    }
    refit_physics_direct(spec, rec, obs)
}

/// [`fit_physics_warm`] of an extension of the blind template that must
/// lower the training RMSE by `gain` to count: the fit stops after
/// [`FUTILE_AFTER`] iterations when it has not come within
/// `(1 − gain)²` of its start cost (its new terms start at 0, so the start
/// is the current model); otherwise it ends where the plain fit would.
/// The engineer's model and `None` fit in full.
pub(crate) fn fit_physics_screened(
    spec: &PhysicsSpec,
    rec: &Record,
    obs: &dyn Observer,
    gain: Option<f64>,
) -> Result<FittedModel, DiagnoseError> {
    let Some(g) = gain.filter(|_| spec_is_template(&spec.name)) else {
        return fit_physics_warm(spec, rec, obs);
    };
    let params = fit_params(spec.clone(), rec).futile(FUTILE_AFTER, (1.0 - g) * (1.0 - g));
    direct_fit(params, rec, obs)
}

/// The iteration of the futility check of [`fit_physics_screened`].
pub(crate) const FUTILE_AFTER: usize = 4;

/// One Levenberg–Marquardt path on all of `rec` from `spec`'s start values
/// (no growing prefixes): the refit of a fitted model of the engineer's
/// equations on more data, started at its estimates. The growing prefixes
/// of [`fit_physics`] guard a cold start; from an optimum on part of the
/// record they can leave it (EMPS' rigid body, an integrating system: the
/// growing refit on the whole training record ended at a free-run RMSE
/// over the record of 5.19e-3 m, its start was at 3.93e-3 m).
pub(crate) fn refit_physics_direct(
    spec: &PhysicsSpec,
    rec: &Record,
    obs: &dyn Observer,
) -> Result<FittedModel, DiagnoseError> {
    direct_fit(fit_params(spec.clone(), rec), rec, obs)
}

/// [`refit_physics_direct`] for the error of the outputs' running sum
/// (`PhysicsFitParams::integrated`): a model of an integrating system's
/// increments, refitted from its estimates for the position it predicts
/// (the criterion of the plan's linear and network models,
/// `DecisionPolicy::integrated_criterion`).
pub(crate) fn refit_physics_integrated(
    spec: &PhysicsSpec,
    rec: &Record,
    obs: &dyn Observer,
) -> Result<FittedModel, DiagnoseError> {
    direct_fit(fit_params(spec.clone(), rec).integrated(true), rec, obs)
}

/// Whether the fits of `ctx` model an integrator's increments for the
/// error of their running sum (an integrating plan under
/// `DecisionPolicy::integrated_criterion`).
pub(crate) fn integrated_fits(ctx: &crate::extension::Context) -> bool {
    ctx.plan.integrating && ctx.policy().integrated_criterion
}

/// One Levenberg–Marquardt path of `params` on all of `rec`.
fn direct_fit(
    params: PhysicsFitParams,
    rec: &Record,
    obs: &dyn Observer,
) -> Result<FittedModel, DiagnoseError> {
    let m = params
        .check()
        .map_err(CoreError::from)?
        .identify_outputs(&[Records::single(rec.clone())], obs)
        .map_err(CoreError::from)?;
    Ok(m.to_fitted().map_err(CoreError::from)?)
}

/// The fit settings of `spec` on `rec`: the record's sample time when the
/// spec has none, the template's stall rule for the blind template.
fn fit_params(mut spec: PhysicsSpec, rec: &Record) -> PhysicsFitParams {
    if spec.sample_time.is_none() {
        spec.sample_time = rec.sample_time;
    }
    let template = spec_is_template(&spec.name);
    let params = PhysicsFitParams::new(spec);
    if template {
        params
            .stall(10, TEMPLATE_STALL_TOL)
            .direct_max_iter(TEMPLATE_DIRECT_ITERATIONS)
    } else {
        params
    }
}

/// The stall rule of the fits of the blind mechanical template and its
/// extensions: stop when 10 Levenberg–Marquardt iterations together lower
/// the cost by less than 0.01 % (the library's default for the user's
/// model files, 0.001 %, lets these fits crawl: on process-noise 9 of the
/// sweep 178 of 737 fits ran ≥ 100 iterations, 129 of 183 CPU seconds,
/// most within 0.3–1 % of their final cost after 10–20; 0.01 % on the
/// user's files stops a tank's overflow limit in its slow stretch).
const TEMPLATE_STALL_TOL: f64 = 1e-4;

/// Most iterations of the template fits' direct path (from the start
/// values, beside the growing prefixes; the library's default is the
/// whole `max_iter` of 200). On the sweep the direct path won with at
/// most 29 iterations (backlash 4, bouc-wen 3: where the prefixes lead
/// astray) and otherwise crawled to 200 beside a growing path that had
/// converged within 20 (preisach 2: the spring and friction laws, 2 s
/// each of the step's 4.4 s).
const TEMPLATE_DIRECT_ITERATIONS: usize = 40;

/// Whether a physics spec is the blind mechanical template (or one of its
/// extensions), not the user's model.
pub(crate) fn spec_is_template(name: &str) -> bool {
    name == TEMPLATE_NAME
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
/// A physics candidate's row in the report: the proposal's text and the
/// fitted parameters with their standard errors.
pub(crate) fn physics_row_text(
    p: &crate::extension::Proposal,
    fitted: &gb_core::FittedModel,
) -> String {
    let params = physics_of(fitted).map_or(String::new(), parameters_text);
    format!("{} -> {params}", p.text)
}

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

/// The engineer's model with what two extensions of `cur` added: `a`'s
/// model (at its estimates) plus the parameters (at `b`'s estimates) and
/// terms that `b` appended to `cur`'s equations and outputs. Both must be
/// physics models grown from `cur` by appending (parameters, terms, new
/// states at the end); the merged spec starts at both estimates.
pub(crate) fn merged_spec(
    cur: &PhysicsModel,
    a: &PhysicsModel,
    b: &PhysicsModel,
) -> Result<PhysicsSpec, DiagnoseError> {
    let bad = |m: &str| DiagnoseError::InvalidArgument(format!("merge of two extensions: {m}"));
    let (c, bs) = (cur.spec(), b.spec());
    if bs.states.len() != c.states.len()
        || bs.parameters.len() < c.parameters.len()
        || bs.outputs.len() != c.outputs.len()
    {
        return Err(bad(
            "the second extension adds states or removes parameters",
        ));
    }
    let mut s = a
        .with_start_at_values()
        .map_err(CoreError::from)?
        .spec()
        .clone();
    for (p, v) in bs.parameters[c.parameters.len()..]
        .iter()
        .zip(&b.parameters()[c.parameters.len()..])
    {
        if s.parameters.iter().any(|q| q.name == p.name) {
            return Err(bad("both add the same parameter"));
        }
        let mut p = p.clone();
        p.value = v.clamp(p.lower, p.upper);
        s.parameters.push(p);
    }
    for (i, eq) in bs.equations.iter().enumerate() {
        let old = c.equations[i].len();
        for t in eq.get(old..).unwrap_or_default() {
            s.add_term(gb_model::physics::TermTarget::State(i), t)
                .map_err(CoreError::from)?;
        }
    }
    for (o, out) in bs.outputs.iter().enumerate() {
        let old = c.outputs[o].terms.len();
        for t in out.terms.get(old..).unwrap_or_default() {
            s.add_term(gb_model::physics::TermTarget::Output(o), t)
                .map_err(CoreError::from)?;
        }
    }
    Ok(s)
}

/// The name of the mechanical template the blind diagnosis builds
/// ([`crate::extensions::MechanicalHysteresis`]).
pub(crate) const TEMPLATE_NAME: &str = "mechanical-template";

/// The record a physics extension of `cur` is fitted on: the whole fit
/// block for the engineer's model (its parameters are the point), the
/// leading [`template_fit_len`] samples of it for the blind mechanical
/// template (its fits, with RK4 sensitivities and several starts, are the
/// costliest; the select block judges as usual).
pub(crate) fn physics_fit_record(
    ctx: &crate::extension::Context<'_>,
    cur: &PhysicsModel,
) -> Record {
    if cur.spec().name == TEMPLATE_NAME {
        ctx.fit.slice(0..template_fit_len(ctx.fit, ctx.policy()))
    } else {
        ctx.fit.clone()
    }
}

/// How many leading samples of the fit record `fit` the blind mechanical
/// template is fitted on: `n = template_fit_samples`, doubled while the
/// rest `fit[n..]` is not represented by `fit[..n]` (the level, pace or
/// range test of the select block, [`crate::plan::record_shift`]: a sweep
/// that the leading samples see only the start of, a changing amplitude),
/// up to `template_fit_max`; never more than the record.
pub(crate) fn template_fit_len(fit: &Record, pol: &crate::DecisionPolicy) -> usize {
    let cap = fit.len().min(pol.template_fit_max);
    let mut n = fit.len().min(pol.template_fit_samples);
    while n < cap && crate::plan::record_shift(fit, 0..n, n..fit.len(), pol).is_some() {
        n = (2 * n).min(cap);
    }
    n
}

/// Levenberg–Marquardt iterations of each start in [`raced`]: 8 for the
/// engineer's model, 4 for the blind template, whose leader goes on from
/// its raced estimates ([`best_of_starts`]; on preisach 4 of the 8000 +
/// 4000 sweep the race of four starts was 15 of a limit's 17 s).
fn race_iterations(template: bool) -> usize {
    if template {
        4
    } else {
        8
    }
}

/// How many of the raced starts are fitted in full: one for the blind
/// mechanical template, two for the engineer's model (its limits bind
/// for real — the tanks' overflow — and the start that leads after a few
/// iterations is not always the one that ends lowest).
fn race_survivors(template: bool) -> usize {
    if template {
        1
    } else {
        2
    }
}

/// A start that survived the race of [`raced`]: its index, its training
/// RMSE after the race and, for the blind template, the raced fit (its
/// survivor goes on from there).
struct Survivor {
    start: usize,
    rmse: f64,
    fit: Option<PhysicsModel>,
}

/// The starts of `0..n` whose plain fit on `rec` has the lowest training
/// RMSE after [`race_iterations`] iterations, best first
/// ([`race_survivors`] of them), for the template each with its raced fit;
/// only those are then fitted in full. On the sweep the
/// template's starts of one limit ended within 0.01 % of each other's RMSE
/// (the limit does not bind), and the four full fits were the slowest
/// candidates of a step; in the engineer's model the eight full fits of
/// each limit (four quantiles, warm and cold) were half of the CPU time of
/// a diagnosis of the Bouc–Wen record from a linear file. `None` for one
/// start (or no more starts than survivors), or when no start fits.
fn raced(
    n: usize,
    spec_of: &(impl Fn(usize) -> Result<PhysicsSpec, DiagnoseError> + Sync),
    rec: &Record,
    obs: &dyn Observer,
) -> Option<Vec<Survivor>> {
    let template = spec_of(0).ok().is_some_and(|s| spec_is_template(&s.name));
    let keep = race_survivors(template);
    if n <= keep {
        return None;
    }
    use rayon::prelude::*;
    let data = [Records::single(rec.clone())];
    let mut raced: Vec<Survivor> = (0..n)
        .into_par_iter()
        .map(|i| {
            let m = spec_of(i)
                .ok()
                .and_then(|spec| {
                    fit_params(spec, rec)
                        .max_iter(race_iterations(template))
                        .check()
                        .ok()
                })
                .and_then(|f| f.identify_outputs(&data, obs).ok());
            let rmse = m
                .as_ref()
                .and_then(|m| m.fit_report().map(|r| r.rmse))
                .unwrap_or(f64::INFINITY);
            // the template's survivor goes on from here (`best_of_starts`)
            let fit = m.filter(|_| template);
            Survivor {
                start: i,
                rmse,
                fit,
            }
        })
        .collect();
    raced.retain(|r| r.rmse.is_finite());
    raced.sort_by(|a, b| a.rmse.total_cmp(&b.rmse).then(a.start.cmp(&b.start)));
    raced.truncate(keep);
    (!raced.is_empty()).then_some(raced)
}

/// Of the starts `0..n` of one model (`spec_of(i)`; only `choice` when it
/// is one of them: a fold of cross-validation refitting the start its
/// whole fit block chose), each fitted on `rec`, the fit with the lowest
/// training RMSE and the index of its start; the last error when none fits.
/// The blind template's survivor of the race ([`raced`]) goes on from its
/// raced estimates on one Levenberg–Marquardt path (on preisach 4 of the
/// sweep the leader was at its optimum after eight raced iterations, and
/// the refit from its start took ten more, 5.5 s of the limit's 20 s); the
/// engineer's survivors are fitted from their starts, as unraced ones.
/// With `futile = Some((rmse, g))` (the current model's training RMSE on
/// `rec` and the gain the candidate needs), a template survivor whose
/// raced RMSE is not `g` below `rmse` is kept as raced, not fitted on: it
/// could not pay.
pub(crate) fn best_of_starts(
    n: usize,
    choice: Option<usize>,
    spec_of: impl Fn(usize) -> Result<PhysicsSpec, DiagnoseError> + Sync,
    rec: &Record,
    obs: &dyn Observer,
    futile: Option<(f64, f64)>,
) -> Result<(FittedModel, Option<usize>), DiagnoseError> {
    let chosen: Vec<(usize, Option<PhysicsModel>)> = match choice {
        Some(i) if i < n => vec![(i, None)],
        _ => match raced(n, &spec_of, rec, obs) {
            Some(mut survivors) => {
                if let (Some((base, g)), Some(lead)) = (futile, survivors.first_mut()) {
                    if lead.rmse > (1.0 - g) * base {
                        if let Some(m) = lead.fit.take() {
                            return Ok((m.to_fitted().map_err(CoreError::from)?, Some(lead.start)));
                        }
                    }
                }
                survivors.into_iter().map(|s| (s.start, s.fit)).collect()
            }
            None => (0..n).map(|i| (i, None)).collect(),
        },
    };
    // the starts are independent: fitted side by side, chosen in order
    let fits: Vec<Result<FittedModel, DiagnoseError>> = {
        use rayon::prelude::*;
        chosen
            .par_iter()
            .map(|(i, at)| match at {
                Some(m) => m
                    .with_start_at_values()
                    .map_err(|e| DiagnoseError::from(CoreError::from(e)))
                    .and_then(|m| refit_physics_direct(m.spec(), rec, obs)),
                _ => spec_of(*i).and_then(|s| fit_physics_warm(&s, rec, obs)),
            })
            .collect()
    };
    let mut best: Option<(f64, FittedModel, usize)> = None;
    let mut last_err = None;
    for ((i, _), fit) in chosen.iter().zip(fits) {
        match fit {
            Ok(m) => {
                let rmse = physics_of(&m)
                    .and_then(PhysicsModel::fit_report)
                    .map_or(f64::INFINITY, |r| r.rmse);
                if best.as_ref().is_none_or(|(b, _, _)| rmse < *b) {
                    best = Some((rmse, m, *i));
                }
            }
            Err(e) => last_err = Some(e),
        }
    }
    match (best, last_err) {
        (Some((_, m, i)), _) => Ok((m, Some(i))),
        (None, Some(e)) => Err(e),
        (None, None) => Err(DiagnoseError::InvalidArgument("no start to fit".into())),
    }
}

/// The training RMSE of `m`'s free-run simulation on `rec` (from its
/// stored initial state), `None` when it fails.
pub(crate) fn rmse_on(m: &PhysicsModel, rec: &Record) -> Option<f64> {
    use gb_core::DynamicModel;
    let y = m.simulate(&rec.inputs, gb_core::Init::Stored).ok()?;
    gb_core::metrics::rmse(&rec.output, &y)
        .ok()
        .filter(|r| r.is_finite() && *r > 0.0)
}

/// The current model of `ctx` when it is a physics model, with its lineage
/// spec (the base the physics extensions append their markers to).
pub(crate) fn current_physics<'a>(
    ctx: &crate::extension::Context<'a>,
) -> Option<(&'a PhysicsModel, &'a str)> {
    let m = physics_of(&ctx.current.model)?;
    match &ctx.current.lineage {
        Lineage::Other { spec, .. } => Some((m, spec.as_str())),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gb_core::DynamicModel;
    use gb_model::physics::{Parameter, State, TermTarget};
    use rand_distr::{Distribution, Normal};

    /// `ẋ = g·u − c·x (+ a2·x³)`, `y = x`, as the blind template (the
    /// futility check applies to it only).
    fn first_order(c: f64, a2: Option<f64>) -> PhysicsSpec {
        let mut s = PhysicsSpec::new(TEMPLATE_NAME)
            .input("u")
            .parameter(Parameter::new("c", c))
            .parameter(Parameter::new("g", 1.0))
            .state(State::new("x", 0.0), "g*u-c*x")
            .output("y", "x")
            .substeps(2)
            .sample_time(0.1);
        if let Some(a) = a2 {
            s = s.parameter(Parameter::new("a2", a));
            s.add_term(TermTarget::State(0), "a2*x^3").unwrap();
        }
        s
    }

    /// 2000 samples of `truth` driven by a random-phase multisine, with
    /// white noise of 2 % of the output's spread.
    fn record(truth: &PhysicsSpec) -> Record {
        let mut rng = gb_core::rng::seeded(7);
        let n = 2000;
        let phases: Vec<f64> = (0..8)
            .map(|_| rand::Rng::random::<f64>(&mut rng) * std::f64::consts::TAU)
            .collect();
        let u: Vec<f64> = (0..n)
            .map(|k| {
                phases
                    .iter()
                    .enumerate()
                    .map(|(j, p)| (0.01 * (j + 1) as f64 * k as f64 + p).sin())
                    .sum::<f64>()
                    / 3.0
            })
            .collect();
        let m = PhysicsModel::new(truth.clone()).unwrap();
        let y = m
            .simulate(std::slice::from_ref(&u), gb_core::Init::Stored)
            .unwrap();
        let sd = gb_core::metrics::rms(&y) * 0.02;
        let noise = Normal::new(0.0, sd).unwrap();
        let y = y.iter().map(|v| v + noise.sample(&mut rng)).collect();
        let mut r = Record::new(vec!["u".into()], "y".into(), vec![u], y).unwrap();
        r.sample_time = Some(0.1);
        r
    }

    /// The plain first-order model fitted on `rec`, its training RMSE,
    /// and its spec at the estimates with the parameters `new` (start, lower
    /// bound) and the term `term` added to its equation.
    fn plain_and_extended(
        rec: &Record,
        new: &[(&str, f64, f64)],
        term: &str,
    ) -> (f64, PhysicsSpec) {
        let plain = fit_physics_warm(&first_order(0.4, None), rec, &gb_core::Silent).unwrap();
        let base = rmse_on(physics_of(&plain).unwrap(), rec).unwrap();
        let start = physics_of(&plain).unwrap().with_start_at_values().unwrap();
        let mut extended = start.spec().clone();
        for &(name, value, lower) in new {
            extended
                .parameters
                .push(Parameter::new(name, value).bounds(lower, f64::INFINITY));
        }
        extended.add_term(TermTarget::State(0), term).unwrap();
        (base, extended)
    }

    fn fit_of(m: &FittedModel) -> &gb_model::physics::FitReport {
        physics_of(m).and_then(PhysicsModel::fit_report).unwrap()
    }

    #[test]
    fn a_term_the_data_do_not_need_stops_at_the_check_and_one_they_need_is_fitted_in_full() {
        let obs = gb_core::Silent;
        // the data have no dry-friction law: the term `−f·tanh(x/ε)`
        // started at f = 0 on the fitted plain model, its width free,
        // cannot lower the RMSE by 2.5 %; its full fit crawls along ε
        let rec = record(&first_order(0.5, None));
        let new = [("f", 0.0, f64::NEG_INFINITY), ("eps", 0.01, 1e-6)];
        let (base, extended) = plain_and_extended(&rec, &new, "-f*tanh(x/eps)");
        let screened = fit_physics_screened(&extended, &rec, &obs, Some(0.025)).unwrap();
        let full = fit_physics_warm(&extended, &rec, &obs).unwrap();
        let (s, f) = (fit_of(&screened), fit_of(&full));
        assert_eq!(s.iterations, FUTILE_AFTER);
        assert!(
            s.termination.contains("too little progress"),
            "{}",
            s.termination
        );
        assert!(
            s.rmse > 0.975 * base && f.rmse > 0.975 * base,
            "{base} {} {}",
            s.rmse,
            f.rmse
        );
        assert!(
            f.iterations > s.iterations,
            "{} {}",
            f.iterations,
            s.iterations
        );
        // the data have one: the screened fit passes the check and ends
        // where the plain fit ends
        let rec = record(&first_order(0.5, Some(-0.8)));
        let new = [("a2", 0.0, f64::NEG_INFINITY)];
        let (base, extended) = plain_and_extended(&rec, &new, "a2*x^3");
        let screened = fit_physics_screened(&extended, &rec, &obs, Some(0.025)).unwrap();
        let full = fit_physics_warm(&extended, &rec, &obs).unwrap();
        let (s, f) = (fit_of(&screened), fit_of(&full));
        assert!(s.rmse < 0.9 * base, "{base} {}", s.rmse);
        assert_eq!(s.rmse.to_bits(), f.rmse.to_bits());
        assert_eq!(s.iterations, f.iterations);
        assert_eq!(
            physics_of(&screened).unwrap().parameters(),
            physics_of(&full).unwrap().parameters()
        );
    }
}
