//! `greybox fit --model SPEC`: any recipe of the model registry.
use crate::io::{load, load_outputs};
use crate::progress::Bar;
use crate::{FitArgs, Result};
use gb_core::{FittedModel, Init, ModelSpec, Record, Records};
use gb_diagnose::{DiagnoseData, DiagnoseOptions, OrderChoice};
use gb_model::recipes::Fitted;
use gb_model::MultiOutputModel;

/// The `--help` text of `fit`: the spec grammar, every recipe, examples.
pub fn help() -> String {
    format!(
        "{}\nExpert flags map to options: --order, --weights, --splits, --prune, --focus, --max-leaves, --degree, --dead-time, --input-lags, --output-lags, --criterion, --partition, --output-max, --resonances, --sample-rate, --ridge (comma lists become a/b).\n\nExamples:\n  greybox fit train.csv --model lmn --order 2 --input u --output y -o model.gbm\n  greybox fit train.csv --model 'lmn:weights=tree,splits=oblique,prune=true,max_leaves=10' -o model.gbm\n  greybox fit silverbox_train.csv --model lmn --order 4 --dead-time 0 --partition y1 --max-leaves 12 -o sb.gbm\n  greybox fit run1.csv --experiment run2.csv --model lmn --input a --input b --dead-time 2,0 --input-lags 3,1 --output-lags 2 -o m.gbm\n  greybox fit train.csv --model state-space+hysteresis -o m.gbm\n  greybox fit mr.csv --model state-space+damper --input D --input V --input Y --output F --resonances 150,120 -o mr.gbm\n  greybox fit train.csv --model-file examples/models/msd.toml -o msd.gbm   # your own equations (docs/physics.md)",
        gb_model::recipes::help()
    )
}

/// The spec with the expert flags added as options.
pub(crate) fn spec_of(a: &FitArgs) -> Result<ModelSpec> {
    let mut s: ModelSpec = a
        .model
        .parse()
        .map_err(|e: gb_core::CoreError| e.to_string())?;
    let list = |v: &str| v.replace(',', "/");
    let mut set = |k: &str, v: Option<String>| {
        if let Some(v) = v {
            s.set_default(k, v);
        }
    };
    set("order", a.order.clone().filter(|o| o != "auto"));
    set("weights", a.weights.clone());
    set("splits", a.splits.clone());
    set("prune", a.prune.then(|| "true".to_string()));
    set("focus", a.focus.clone());
    set("max_leaves", a.max_leaves.map(|v| v.to_string()));
    set("degree", a.degree.map(|v| v.to_string()));
    set("dead_time", a.dead_time.as_deref().map(list));
    set("input_lags", a.input_lags.as_deref().map(list));
    set("output_lags", a.output_lags.map(|v| v.to_string()));
    set("criterion", a.criterion.clone());
    set("partition", a.partition.clone());
    set("output_max", a.output_max.map(|v| v.to_string()));
    set("resonances", a.resonances.as_deref().map(list));
    set("sample_rate", a.sample_rate.map(|v| v.to_string()));
    set("ridge", a.ridge.map(|v| v.to_string()));
    Ok(s)
}

/// `--order auto`: the order, input delay and integrator of the
/// diagnosis' baseline chosen on `train` (its fit and select blocks), set
/// as the spec's `order` and, where the recipe has one, `delay` options
/// (options the spec names stay); prints the choice and the candidates'
/// decision NRMSEs.
fn auto_structure(
    mut spec: ModelSpec,
    train: &Record,
    several: bool,
    quiet: bool,
) -> Result<ModelSpec> {
    let recipe = gb_model::recipes::check_spec(&spec).map_err(|e| e.to_string())?;
    let has = |k: &str| {
        recipe
            .options
            .iter()
            .any(|o| o.split(['=', ':']).next() == Some(k))
    };
    if !has("order") {
        return Err(format!(
            "--order auto: model spec '{spec}' has no order option"
        ));
    }
    let mut opts = DiagnoseOptions {
        order: OrderChoice::Auto,
        ..DiagnoseOptions::default()
    };
    // no order the recipes cannot fit on this record: they need
    // 20 (n + 1)(inputs + 1) + 50 samples
    let per_order = 20 * (train.n_inputs() + 1);
    let fits = (train.len().saturating_sub(50) / per_order).saturating_sub(1);
    opts.policy.max_order = opts.policy.max_order.min(fits.max(1));
    let d = DiagnoseData::from_single(train.clone());
    let bar = Bar::spinner(quiet, "choosing order and delay");
    let c = gb_diagnose::choose_structure(&d, &opts).map_err(|e| e.to_string())?;
    bar.finish();
    let delay: Vec<String> = c.choice.delay.iter().map(|v| v.to_string()).collect();
    println!(
        "order auto: order {}, delay [{}] chosen on the training data ({}; NRMSE {:.4})",
        c.order,
        delay.join(","),
        c.choice.decision,
        c.nrmse_select
    );
    println!("  {}", c.choice.text());
    // an integrator: the input-output networks model the increments and
    // sum them (`integrating=true`), as the diagnosis' baseline does
    let o = spec.options();
    let tree =
        spec.name == "lmn" && (several || gb_model::recipes::TREE_KEYS.iter().any(|k| o.given(k)));
    if c.choice.integrating && (spec.name == "linear" || spec.name == "lmn") && !tree {
        spec.set_default("integrating", "true");
        println!("  the output integrates: the increments are modelled and summed (integrating=true; integrating=false fits the output itself)");
    } else if c.choice.integrating {
        println!("  note: the output integrates; `diagnose` and `linear`/`lmn` model its increments, '{spec}' fits the output itself");
    }
    spec.set_default("order", c.order.to_string());
    if spec.name == "poly" {
        poly_regressors(&mut spec, c.order, &c.choice);
    }
    // the tree network of `lmn` (a tree option or several records) names
    // its input delays `dead_time`
    if tree {
        spec.set_default("dead_time", delay.join("/"));
    } else if has("delay") {
        spec.set_default("delay", delay.join("/"));
    } else {
        println!("  note: model spec '{spec}' has no delay option; the delay is not used");
    }
    Ok(spec)
}

/// The polynomial's regressors as the diagnosis' `poly-noe` candidate
/// takes them from the linear model of `order` and `choice`: per input
/// `order + 1` lags at dead time 0 or behind a feedthrough, else `order`;
/// up to 30 terms (the recipe's defaults: `order` lags, 15 terms). Options
/// the spec names stay.
fn poly_regressors(spec: &mut ModelSpec, order: usize, choice: &gb_diagnose::StructureChoice) {
    let lags: Vec<String> = choice
        .delay
        .iter()
        .map(|&d| {
            if d == 0 || choice.feedthrough {
                order + 1
            } else {
                order
            }
            .to_string()
        })
        .collect();
    spec.set_default("input_lags", lags.join("/"));
    spec.set_default("max_terms", "30");
}

/// The polynomial `spec` on one more lag of the output and of each input
/// (what the diagnosis' `poly-simpler` fits after a network): `None`
/// without an order or input lags.
fn poly_one_more_lag(spec: &ModelSpec) -> Option<ModelSpec> {
    let order: usize = spec.option("order")?.parse().ok()?;
    let lags: Option<Vec<String>> = spec
        .option("input_lags")?
        .split('/')
        .map(|v| v.parse::<usize>().ok().map(|n| (n + 1).to_string()))
        .collect();
    let mut wider = spec.clone();
    wider
        .options
        .retain(|(k, _)| k != "order" && k != "input_lags");
    wider.set_default("order", (order + 1).to_string());
    wider.set_default("input_lags", lags?.join("/"));
    Some(wider)
}

/// The polynomial `spec` with each input one sample earlier (`delay − 1`,
/// one more lag: the lags it had and `u(k − delay + 1)`, a feedthrough
/// behind the dead time): `None` when an input's delay is already 0.
fn poly_one_sample_earlier(spec: &ModelSpec) -> Option<ModelSpec> {
    let list = |key: &str| -> Option<Vec<usize>> {
        spec.option(key)?
            .split('/')
            .map(|v| v.parse().ok())
            .collect()
    };
    let (delay, lags) = (list("delay")?, list("input_lags")?);
    if delay.contains(&0) || delay.len() != lags.len() {
        return None;
    }
    let text = |v: Vec<usize>| v.iter().map(usize::to_string).collect::<Vec<_>>().join("/");
    let mut earlier = spec.clone();
    earlier
        .options
        .retain(|(k, _)| k != "delay" && k != "input_lags");
    earlier.set_default("delay", text(delay.iter().map(|d| d - 1).collect()));
    earlier.set_default("input_lags", text(lags.iter().map(|n| n + 1).collect()));
    Some(earlier)
}

/// Whether the order (and delay) of `spec` is chosen on the training data:
/// `--order auto`, or no order given at all (neither `--order N` nor
/// `order=` in the spec) for a recipe that has an order option — a fit
/// without expert flags selects its structure as the diagnosis does.
fn order_is_auto(a: &FitArgs, spec: &ModelSpec) -> bool {
    match a.order.as_deref() {
        Some(o) => o == "auto",
        None => {
            let o = spec.options();
            let structural = ["order", "delay", "dead_time", "input_lags", "output_lags"];
            !structural.iter().any(|k| o.given(k))
                && gb_model::recipes::check_spec(spec).is_ok_and(|r| {
                    let has = |k: &str| {
                        r.options
                            .iter()
                            .any(|o| o.split(['=', ':']).next() == Some(k))
                    };
                    // the input-output recipes (an order and an input delay)
                    has("order") && has("delay")
                })
        }
    }
}

/// The structure of a nonlinear recipe: a linear model's order and delay
/// (`chosen`, from [`auto_structure`]) are often inflated by a
/// nonlinearity they stand in for, so the recipe itself is fitted with
/// them and with its defaults (`given`) on the first 75 % of `train` and
/// simulated on the last 25 % (init window 50, or a tenth of it); the
/// smaller free-run NRMSE wins. Prints both. Skipped when the chosen order
/// is the recipe's default.
fn order_by_hold_out(
    given: &ModelSpec,
    chosen: ModelSpec,
    train: &Record,
    quiet: bool,
) -> Result<ModelSpec> {
    let (head, tail) = {
        let cut = train.len() * 3 / 4;
        (train.slice(0..cut), train.slice(cut..train.len()))
    };
    let plain = given.clone();
    // the recipe's default order ("order=2: …" in its options)
    let default = gb_model::recipes::check_spec(given).ok().and_then(|r| {
        r.options.iter().find_map(|o| {
            o.strip_prefix("order=")
                .map(|v| v.split([':', ' ']).next().unwrap_or("").to_string())
        })
    });
    // a polynomial also tries one more lag (its terms are chosen inside
    // the fit: a wider regressor set costs few parameters)
    let poly = given.name == "poly" && plain.option("order").is_none();
    let wider = poly.then(|| poly_one_more_lag(&chosen)).flatten();
    let earlier = (poly && plain.option("delay").is_none())
        .then(|| poly_one_sample_earlier(&chosen))
        .flatten();
    if wider.is_none()
        && (chosen
            .option("order")
            .is_none_or(|n| Some(n) == default.as_deref())
            || plain.option("order").is_some())
    {
        return Ok(chosen);
    }
    let bar = Bar::spinner(quiet, "choosing the order on a hold-out");
    let w = 50.min(tail.len() / 10).max(1);
    let score = |s: &ModelSpec| -> f64 {
        let Ok(f) = gb_model::recipes::fit(s, &Records::single(head.clone()), &gb_core::Silent)
        else {
            return f64::INFINITY;
        };
        f.model
            .simulate(&tail.inputs, Init::Window(&tail.output[..w]))
            .ok()
            .and_then(|y| gb_core::metrics::nrmse(&tail.output[w..], &y[w..]).ok())
            .filter(|e| e.is_finite())
            .unwrap_or(f64::INFINITY)
    };
    let (e_chosen, e_plain) = (score(&chosen), score(&plain));
    let e_wider = wider.as_ref().map_or(f64::INFINITY, &score);
    let e_earlier = earlier.as_ref().map_or(f64::INFINITY, &score);
    bar.finish();
    let best = e_chosen.min(e_plain).min(e_wider).min(e_earlier);
    let pick = if e_chosen == best {
        "the chosen"
    } else if e_wider == best {
        "one more lag"
    } else if e_earlier == best {
        "one sample earlier"
    } else {
        "the defaults"
    };
    let mut more = String::new();
    if wider.is_some() {
        more.push_str(&format!(
            ", with one more lag of the output and of each input NRMSE {e_wider:.4}"
        ));
    }
    if earlier.is_some() {
        more.push_str(&format!(
            ", every input one sample earlier (one more lag) NRMSE {e_earlier:.4}"
        ));
    }
    println!(
        "  on a hold-out (the last 25 % of the training record, free run): the chosen order and delay NRMSE {e_chosen:.4}{more}, the recipe's defaults NRMSE {e_plain:.4} -> {pick}"
    );
    Ok(match pick {
        "the chosen" => chosen,
        "one more lag" => wider.unwrap_or(chosen),
        "one sample earlier" => earlier.unwrap_or(chosen),
        _ => plain,
    })
}

/// A bad option value of `spec` (`weights=cubes`, `max_leaves=0`), found
/// before the order and delay are chosen (seconds on a long record): the
/// recipes read their options before they fit, so a fit on the first 64
/// rows names the bad value; any other outcome of that fit is ignored.
fn options_valid(spec: &ModelSpec, train: &Record) -> Result<()> {
    let head = Records::single(train.slice(0..train.len().min(64)));
    match gb_model::recipes::fit(spec, &head, &gb_core::Silent) {
        Err(gb_core::CoreError::InvalidArgument(m)) if m.starts_with("model spec") => Err(m),
        _ => Ok(()),
    }
}

/// Fit `spec` (with `--order auto`, its order and delay chosen on the
/// first record) on `records`; prints the model, its notes and the training
/// NRMSE (free run; the model's lags or an init window of 50 samples set
/// the initial state).
fn fit_output(
    a: &FitArgs,
    mut spec: ModelSpec,
    records: Vec<Record>,
    quiet: bool,
) -> Result<Fitted> {
    let data = Records::new(records).map_err(|e| e.to_string())?;
    if order_is_auto(a, &spec) {
        options_valid(&spec, data.first())?;
        match auto_structure(spec.clone(), data.first(), data.len() > 1, quiet) {
            Ok(s) if spec.name == "linear" => spec = s,
            Ok(s) => spec = order_by_hold_out(&spec, s, data.first(), quiet)?,
            // the default: a record the chooser cannot handle is fitted
            // with the recipe's default order, said so
            Err(e) if a.order.is_none() => {
                println!("note: order and delay not chosen on the data ({e}); the recipe's defaults are used (--order N sets them)");
            }
            Err(e) => return Err(e),
        }
    }
    let bar = Bar::spinner(quiet, &format!("fitting {spec}"));
    let fitted = gb_model::recipes::fit(&spec, &data, &bar).map_err(|e| match e {
        // a bad option is the spec's fault, not the file's
        gb_core::CoreError::InvalidArgument(m) if m.starts_with("model spec") => m,
        e => format!("{}: {e}", a.train.display()),
    })?;
    bar.finish();
    let m = &fitted.model;
    let d = data.first();
    // the state from a window of measured outputs (least squares beyond
    // the model's lags; a tenth of the record, at most 400 samples): the
    // first lags alone start an oversampled model with a transient that is
    // no part of its fit, and a short window leaves its slow state unknown
    let w = m
        .dynamics
        .history_len()
        .max(400.min(d.len() / 10))
        .min(d.len());
    let init = Init::Window(&d.output[..w]);
    let sim = m.simulate(&d.inputs, init).map_err(|e| e.to_string())?;
    let w = w.min(d.len());
    let nrmse = gb_core::metrics::nrmse(&d.output[w..], &sim[w..]).map_err(|e| e.to_string())?;
    println!("model: {}", m.describe());
    println!("class: {}; spec: {spec}", m.dynamics.class());
    println!("parameters: {}", m.dynamics.n_parameters());
    for n in &fitted.notes {
        println!("{n}");
    }
    println!("training NRMSE (free-run simulation): {nrmse:.4}");
    Ok(fitted)
}

/// Several outputs: one model of `spec` per output on the same inputs,
/// stacked into one `multi-output` model.
fn fit_outputs(a: &FitArgs, spec: ModelSpec, quiet: bool) -> Result<FittedModel> {
    let mut per_file = vec![load_outputs(&a.train, &a.signals)?];
    for f in &a.experiments {
        per_file.push(load_outputs(f, &a.signals)?);
    }
    let mut parts = vec![];
    for (o, name) in a.signals.outputs.iter().enumerate() {
        println!("\noutput {name}:");
        let records: Vec<Record> = per_file.iter().map(|r| r[o].clone()).collect();
        for (r, f) in records.iter().skip(1).zip(&a.experiments) {
            r.check_identifiable(&f.display().to_string(), 20)
                .map_err(|e| e.to_string())?;
        }
        let fm = fit_output(a, spec.clone(), records, quiet)?.model;
        parts.push((fm.dynamics, fm.noise));
    }
    let first = &per_file[0][0];
    let noise = parts[0].1.clone();
    let stack = MultiOutputModel::new(parts).map_err(|e| e.to_string())?;
    let mut m = FittedModel::new(
        first.input_names.clone(),
        a.signals.outputs.clone(),
        Box::new(stack),
        noise,
    )
    .map_err(|e| e.to_string())?;
    m.sample_time = first.sample_time;
    println!("\nmodel: {}", m.dynamics.describe());
    Ok(m)
}

/// Fit, save, and print the model, its notes and the training NRMSE.
pub fn run(a: FitArgs, quiet: bool) -> Result<()> {
    if a.smc.is_smc()? {
        return crate::cmd_smc::fit(&a, quiet);
    }
    if let Some(path) = &a.model_file {
        return crate::cmd_physics::fit(&a, path, quiet);
    }
    let spec = spec_of(&a)?;
    gb_model::recipes::check_spec(&spec).map_err(|e| e.to_string())?;
    let m = if a.signals.outputs.len() > 1 {
        fit_outputs(&a, spec, quiet)?
    } else {
        let mut records = vec![load(&a.train, &a.signals)?];
        for f in &a.experiments {
            let e = load(f, &a.signals)?;
            e.check_identifiable(&f.display().to_string(), 20)
                .map_err(|e| e.to_string())?;
            records.push(e);
        }
        fit_output(&a, spec, records, quiet)?.model
    };
    m.save(&a.out).map_err(|e| e.to_string())?;
    println!("saved to {}", a.out.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::{poly_one_more_lag, poly_one_sample_earlier};
    use gb_core::ModelSpec;

    fn spec(s: &str) -> ModelSpec {
        s.parse().unwrap()
    }

    /// The polynomial's hold-out rivals: one more lag of the output and of
    /// each input; each input one sample earlier with one more lag (none
    /// when an input is already at dead time 0).
    #[test]
    fn the_polynomials_rivals_on_the_hold_out() {
        let chosen = spec("poly:order=2,input_lags=2/3,max_terms=30,delay=1/2");
        let wider = poly_one_more_lag(&chosen).unwrap();
        assert_eq!(wider.option("order"), Some("3"));
        assert_eq!(wider.option("input_lags"), Some("3/4"));
        assert_eq!(wider.option("delay"), Some("1/2"));
        let earlier = poly_one_sample_earlier(&chosen).unwrap();
        assert_eq!(earlier.option("order"), Some("2"));
        assert_eq!(earlier.option("delay"), Some("0/1"));
        assert_eq!(earlier.option("input_lags"), Some("3/4"));
        assert_eq!(earlier.option("max_terms"), Some("30"));
        let at_zero = spec("poly:order=2,input_lags=3/2,delay=0/1");
        assert!(poly_one_sample_earlier(&at_zero).is_none());
        assert!(poly_one_more_lag(&spec("poly:order=2")).is_none());
    }
}
