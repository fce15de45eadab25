//! The candidate extensions, one file each (see [`crate::Extension`]).
mod backlash;
mod capacity;
mod feedback;
mod hammerstein;
mod hidden_state;
mod hidden_state_detail;
mod kalman;
mod lolimot;
mod mechanical;
mod operator_poly;
mod order;
mod physics_delay;
mod physics_hysteresis;
mod physics_terms;
mod poly_noe;
mod preisach;
mod process_noise;
mod state_network;
mod student_t;
mod tree_lmn;
mod wiener;
mod wiener_hammerstein;

pub use backlash::Backlash;
pub use capacity::Capacity;
pub use feedback::FeedbackMap;
pub use hammerstein::Hammerstein;
pub use hidden_state::HiddenState;
pub use hidden_state_detail::HiddenStateDetail;
pub use lolimot::Lolimot;
pub(crate) use mechanical::TemplateCache;
pub use mechanical::{MechanicalHysteresis, MechanicalNonlinearity};
pub use operator_poly::OperatorPoly;
pub use order::LinearOrder;
pub use physics_delay::PhysicsInputDelay;
pub use physics_hysteresis::PhysicsHysteresis;
pub use physics_terms::PhysicsTerms;
pub use poly_noe::{PolyNoe, PolySimpler};
pub use preisach::PreisachColumns;
pub use process_noise::ProcessNoise;
pub use state_network::StateNetwork;
pub use student_t::StudentTNoise;
pub use tree_lmn::TreeLmn;
pub use wiener::Wiener;
pub use wiener_hammerstein::WienerHammerstein;

use crate::evaluate::Lineage;
use crate::extension::{io_model, Context};
use crate::DiagnoseError;
use gb_core::{FittedModel, ModelSpec, Records};
use gb_lmn::{IoNetworkParams, WarmStart};

/// A list of per-input numbers as a model spec writes it: `4/0/1`.
pub(crate) fn slash_list(v: &[usize]) -> String {
    v.iter().map(usize::to_string).collect::<Vec<_>>().join("/")
}

/// The order and the dead times (`1/1`) of an input–output model.
pub(crate) fn io_structure(p: &IoNetworkParams, n_inputs: usize) -> (usize, String) {
    if p.delay.len() == n_inputs {
        (p.order, slash_list(&p.delay))
    } else {
        (p.order, slash_list(&vec![1; n_inputs]))
    }
}

/// The order and delay list (`a/b`) of the current model when it is a
/// plain linear input–output model (no network, no hysteresis columns):
/// the structure the static-map and polynomial extensions start from.
pub(crate) fn plain_linear_structure(ctx: &Context) -> Option<(usize, String)> {
    let p = ctx.current.lineage.io()?;
    if p.network || p.hysteresis {
        return None;
    }
    Some(io_structure(p, ctx.fit.n_inputs()))
}

/// The delay list `d` (`a/b`, one per input), the same list shifted by
/// one sample either way (every input together; no negative delay), and
/// the plain delay of one sample on every input when the list is further
/// from it: the block-oriented candidates re-check the baseline's delay,
/// which a linear fit can misjudge when the nonlinearity dominates the
/// response — by more than a sample when the linear model explains little
/// (a hard saturation), and the one-sample delay is the structure the
/// baseline's scan always weighs too.
pub(crate) fn delay_variants(d: &str) -> Vec<String> {
    let parsed: Option<Vec<usize>> = d.split('/').map(|v| v.parse().ok()).collect();
    let Some(v) = parsed else {
        return vec![d.to_string()];
    };
    let join = |w: Vec<usize>| slash_list(&w);
    let mut out = vec![d.to_string()];
    if v.iter().all(|&x| x >= 1) {
        out.push(join(v.iter().map(|x| x - 1).collect()));
    }
    out.push(join(v.iter().map(|x| x + 1).collect()));
    let plain = join(vec![1; v.len()]);
    if !out.contains(&plain) {
        out.push(plain);
    }
    out
}

/// The `delay=` values of the block candidates at delay `d`, with their
/// words for a report row: one candidate trying every variant of
/// [`delay_variants`] (`1|0|2`, the dead time chosen on the fit block);
/// under cross-validation one candidate per variant, the folds judging
/// each (a short record's fit block can prefer a dead time the folds
/// reject: backlash 2 of the sweep, 805 samples, 1.06× the floor with the
/// folds' choice, 5.6× with the fit block's).
pub(crate) fn delay_choices(ctx: &Context, d: &str) -> Vec<(String, String)> {
    let v = delay_variants(d);
    if ctx.plan.cv() || v.len() == 1 {
        return v
            .into_iter()
            .map(|x| {
                let words = format!("input delay {x}");
                (x, words)
            })
            .collect();
    }
    let words = format!(
        "input delay {d}, or {} if that fits the fit block better",
        v[1..].join(" or ")
    );
    vec![(v.join("|"), words)]
}

/// `f` on the context whose fit block is the first `n` samples of `ctx`'s
/// when there is one training record longer than `n` (the fits whose cost
/// is linear in the samples, capped by the policy), else on `ctx` itself.
pub(crate) fn on_leading<T>(ctx: &Context, n: usize, f: impl FnOnce(&Context) -> T) -> T {
    if ctx.fits.len() > 1 || ctx.fit.len() <= n {
        return f(ctx);
    }
    let rec = ctx.fit.slice(0..n);
    let sub = Context {
        fit: &rec,
        fits: std::slice::from_ref(&rec),
        simulated_fit: ctx.simulated_fit.map(|s| &s[..n.min(s.len())]),
        ..*ctx
    };
    f(&sub)
}

/// Fit the recipe of a proposal's spec (`greybox fit --model SPEC`) on at
/// most `cap` samples of the fit block (the recipes the diagnosis proposes
/// are single-record: with several training records, the longest fit
/// part, see [`Context::fit`]).
pub(crate) fn fit_spec(
    lineage: &Lineage,
    ctx: &Context,
    cap: usize,
) -> Result<FittedModel, DiagnoseError> {
    let Lineage::Other { spec, .. } = lineage else {
        return Err(DiagnoseError::InvalidArgument(
            "not a model-spec proposal".into(),
        ));
    };
    let spec: ModelSpec = spec.parse()?;
    let sub = ctx.fit.slice(0..ctx.fit.len().min(cap));
    let f = gb_model::recipes::fit(&spec, &Records::single(sub), ctx.observer)?;
    Ok(f.model)
}

/// A block-oriented (Hammerstein, Wiener) proposal fitted by
/// [`fit_spec`], and the structure it chose on the fit block — its dead
/// time among the spec's alternatives (`delay=1|0|2`) and its map
/// structure among gb-lmn's default structures, as one index
/// `delay index · structures + map index`: the final refit on the whole
/// training record ([`Context::start_choice`]) refits that structure only,
/// the one the select block judged. The folds of a cross-validation keep
/// the dead time and choose their own map (given the whole fit block's
/// map, a fold fitted on three quarters of a short record extrapolates a
/// cubic or a spline the others would not have chosen: hammerstein-odd 5
/// and wiener 8 lost their cause; choosing their own dead time as well, a
/// fold on a slow excitation takes the wrong one: hammerstein-odd 5
/// again).
pub(crate) fn fit_block_choosing(
    lineage: &Lineage,
    ctx: &Context,
) -> Result<(FittedModel, Option<usize>), DiagnoseError> {
    let structures = gb_lmn::BlockParams::linear(1).maps;
    let cap = ctx.policy().nonlinear_fit_samples;
    let Lineage::Other { spec, order } = lineage else {
        return Ok((fit_spec(lineage, ctx, cap)?, None));
    };
    let delays = spec_delays(spec);
    let fixed = ctx.start_choice.and_then(|c| {
        let (basis, knots) = structures.get(c % structures.len())?;
        let delay = with_option(spec, "delay", delays.get(c / structures.len())?);
        let spec = if ctx.plan.cv() {
            delay
        } else {
            format!("{delay},map={}", basis.structure_name(*knots))
        };
        Some(Lineage::Other {
            spec,
            order: *order,
        })
    });
    let m = on_every_record(
        fit_spec(fixed.as_ref().unwrap_or(lineage), ctx, cap)?,
        ctx,
        cap,
    );
    let block = m.dynamics.as_any().downcast_ref::<gb_lmn::BlockModel>();
    let map = block
        .and_then(gb_lmn::BlockModel::map_structure)
        .and_then(|s| structures.iter().position(|&t| t == s));
    let delay = block.and_then(|b| {
        delays.iter().position(|d| {
            let v: Vec<usize> = d.split('/').filter_map(|x| x.parse().ok()).collect();
            v == b.nk || (v.len() == 1 && b.nk.iter().all(|&k| k == v[0]))
        })
    });
    let chosen = map.map(|s| delay.unwrap_or(0) * structures.len() + s);
    Ok((m, chosen))
}

/// With several training records, a block-oriented model `m` (fitted with
/// its structure choice on one record, the longest) trained further on
/// every record's first `cap` samples together, each a separate experiment
/// ([`gb_lmn::ValidBlockParams::refine_records`]: the summed simulation
/// error never grows); `m` unchanged with one record, for other classes,
/// or when that fit fails.
fn on_every_record(mut m: FittedModel, ctx: &Context, cap: usize) -> FittedModel {
    if ctx.fits.len() < 2 {
        return m;
    }
    let Some(block) = m.dynamics.as_any().downcast_ref::<gb_lmn::BlockModel>() else {
        return m;
    };
    let recs: Vec<gb_core::Record> = ctx
        .fits
        .iter()
        .map(|r| r.slice(0..r.len().min(cap)))
        .collect();
    let refined = gb_lmn::BlockParams::linear(1)
        .check()
        .ok()
        .and_then(|p| p.refine_records(block, &recs));
    if let Some(b) = refined {
        m.dynamics = Box::new(b);
    }
    m
}

/// The dead-time alternatives of a block spec's `delay=` option (`1|0|2`
/// gives `1`, `0`, `2`); `1` when it has none.
fn spec_delays(spec: &str) -> Vec<String> {
    spec.split_once(':')
        .map(|(_, o)| o)
        .unwrap_or("")
        .split(',')
        .find_map(|kv| kv.strip_prefix("delay="))
        .map_or_else(
            || vec!["1".to_string()],
            |d| d.split('|').map(str::to_string).collect(),
        )
}

/// A block or input–output proposal's structure without its input delay
/// ([`Extension::delay_rivals_key`]): a spec without its `delay=` option,
/// an input–output structure with its delays cleared.
pub(crate) fn delay_free_key(lineage: &Lineage) -> Option<String> {
    match lineage {
        Lineage::Other { spec, order } => {
            let (head, opts) = spec.split_once(':').unwrap_or((spec, ""));
            let rest: Vec<&str> = opts
                .split(',')
                .filter(|kv| !kv.starts_with("delay="))
                .collect();
            Some(format!("{head}:{}|{order}", rest.join(",")))
        }
        Lineage::Io(p) => Some(format!(
            "{:?}",
            IoNetworkParams {
                delay: vec![],
                ..p.clone()
            }
        )),
        _ => None,
    }
}

/// `spec` with option `key` set to `value` (replaced, or appended).
pub(crate) fn with_option(spec: &str, key: &str, value: &str) -> String {
    let (head, opts) = spec.split_once(':').unwrap_or((spec, ""));
    let prefix = format!("{key}=");
    let mut parts: Vec<String> = opts
        .split(',')
        .filter(|kv| !kv.is_empty())
        .map(|kv| {
            if kv.starts_with(&prefix) {
                format!("{prefix}{value}")
            } else {
                kv.to_string()
            }
        })
        .collect();
    if !parts.iter().any(|kv| kv.starts_with(&prefix)) {
        parts.push(format!("{prefix}{value}"));
    }
    format!("{head}:{}", parts.join(","))
}

/// Fit an input–output model on the fit block, warm-started from the
/// current model (its network for linear fits, its simulated output for
/// LOLIMOT's output-error construction; with hysteresis columns under
/// cross-validation also from the cold start,
/// `FitOptions::cold_with_hysteresis`). With several training records the
/// model (linear or a LOLIMOT network) is fitted on the fit parts of
/// all of them as separate experiments ([`Context::fits`]).
pub(crate) fn fit_io(p: &IoNetworkParams, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
    let mut p = p.clone();
    // an equation-error (ARX) estimate stays one for a plain linear model
    let arx = p.fit.equation_error && plain_linear(&p);
    p.fit = ctx.options.fit.clone();
    p.fit.equation_error = arx;
    // under cross-validation (short or unrepresentative records) a
    // hysteresis structure is also fitted from the cold start: a fold's
    // warm fit can stay in a poorer basin
    p.fit.cold_with_hysteresis |= ctx.plan.cv();
    p.lolimot = ctx.options.lolimot.clone();
    let warm_net = crate::plan::core(&ctx.current.model)
        .as_any()
        .downcast_ref::<gb_lmn::LocalModelNetwork>();
    let net = if ctx.fits.len() < 2 {
        let warm = WarmStart {
            simulated_output: ctx.simulated_fit,
            network: warm_net,
            ..WarmStart::default()
        };
        p.check()?.fit(ctx.fit, warm)?
    } else {
        let warm = WarmStart {
            network: warm_net,
            simulated_outputs: ctx.simulated_fits,
            ..WarmStart::default()
        };
        p.check()?.fit_records(ctx.fits, warm, &gb_core::Silent)?
    };
    io_model(net, ctx.fit)
}

/// A linear model without a network, hysteresis columns, an output map
/// or a robust fit.
pub(crate) fn plain_linear(p: &IoNetworkParams) -> bool {
    !p.network && !p.hysteresis && p.output_map == 0 && !p.robust && p.input_play_at.is_none()
}

#[cfg(test)]
mod tests {
    use super::delay_variants;

    #[test]
    fn a_block_spec_names_its_dead_times_and_one_can_be_fixed() {
        let s = "hammerstein:order=2,delay=4/0|5/1|1/1,maps=1/1";
        assert_eq!(super::spec_delays(s), vec!["4/0", "5/1", "1/1"]);
        assert_eq!(super::spec_delays("wiener:order=3"), vec!["1"]);
        assert_eq!(
            super::with_option(s, "delay", "5/1"),
            "hammerstein:order=2,delay=5/1,maps=1/1"
        );
        assert_eq!(
            super::with_option("wiener:order=3", "delay", "2"),
            "wiener:order=3,delay=2"
        );
    }

    #[test]
    fn the_delay_variants_are_the_delay_its_neighbours_and_the_plain_delay() {
        assert_eq!(delay_variants("1"), vec!["1", "0", "2"]);
        assert_eq!(delay_variants("0"), vec!["0", "1"]);
        assert_eq!(delay_variants("2"), vec!["2", "1", "3"]);
        assert_eq!(delay_variants("6"), vec!["6", "5", "7", "1"]);
        assert_eq!(delay_variants("4/0"), vec!["4/0", "5/1", "1/1"]);
        assert_eq!(delay_variants("x"), vec!["x"]);
    }
}
