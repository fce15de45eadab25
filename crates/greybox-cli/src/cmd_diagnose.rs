//! `greybox diagnose`: the diagnosis on files or a generated example.
use crate::io::{load, load_outputs};
use crate::progress::Bar;
use crate::{DiagnoseArgs, Result};
use gb_diagnose::{diagnose, systems, DiagnoseData, DiagnoseOptions, OrderChoice};
use gb_model::physics::PhysicsSpec;

fn parse_order(s: &str, max: usize) -> Result<OrderChoice> {
    if s == "auto" {
        return Ok(OrderChoice::Auto);
    }
    match s.parse::<usize>() {
        Ok(n) if (1..=max).contains(&n) => Ok(OrderChoice::Fixed(n)),
        _ => Err(format!("--order must be 1..={max} or auto, got '{s}'")),
    }
}

/// The data of the diagnosis: an example, or the training file (with the
/// validation file, or split into blocks); with `--model-file` the records
/// carry the model's signal names and the spec comes along.
fn data(a: &DiagnoseArgs) -> Result<(DiagnoseData, Option<PhysicsSpec>)> {
    if !a.more_train.is_empty() {
        if a.model_file.is_some() {
            return Err(
                "several training records (--train) are not supported with --model-file yet".into(),
            );
        }
        return Ok((multi_data(a)?, None));
    }
    if let (Some(mf), Some(train)) = (&a.model_file, &a.train) {
        let (spec, tr, val) =
            crate::cmd_physics::diagnose_data(mf, train, a.validate.as_deref(), &a.signals)?;
        let d = match val {
            Some(v) => DiagnoseData::with_validation(tr, v).map_err(|e| e.to_string())?,
            None => DiagnoseData::from_single(tr),
        };
        return Ok((d, Some(spec)));
    }
    Ok((plain_data(a)?, None))
}

/// The data of a diagnosis with the linear baseline.
fn plain_data(a: &DiagnoseArgs) -> Result<DiagnoseData> {
    if let Some(name) = &a.example {
        let g = systems::generate(name, 1, 8000, 4000).map_err(|e| e.to_string())?;
        println!(
            "example '{name}': generated {} training + {} validation samples (seed 1, SNR {:.1} dB, noise floor NRMSE {:.4})",
            g.train.len(),
            g.validate.len(),
            g.snr_db,
            g.noise_floor_nrmse
        );
        return DiagnoseData::with_validation(g.train, g.validate).map_err(|e| e.to_string());
    }
    let train_path = a
        .train
        .as_ref()
        .ok_or("a training CSV or --example is needed")?;
    let train = load(train_path, &a.signals)?;
    match &a.validate {
        Some(v) => {
            let val = load(v, &a.signals)?;
            DiagnoseData::with_validation(train, val).map_err(|e| format!("{}: {e}", v.display()))
        }
        None => {
            let d = DiagnoseData::from_single(train);
            println!(
                "no --validate: {} split into contiguous blocks fit {}..{}, select {}..{}, report {}..{}",
                train_path.display(),
                d.fit.start,
                d.fit.end,
                d.select.start,
                d.select.end,
                d.report_range.start,
                d.report_range.end
            );
            Ok(d)
        }
    }
}

/// The data of several training records (the positional TRAIN, then each
/// `--train FILE`): every record must carry the first record's signals.
fn multi_data(a: &DiagnoseArgs) -> Result<DiagnoseData> {
    let paths: Vec<&std::path::PathBuf> = a.train.iter().chain(&a.more_train).collect();
    let mut records = Vec::with_capacity(paths.len());
    for p in &paths {
        records.push((p.display().to_string(), load(p, &a.signals)?));
    }
    let validate = match &a.validate {
        Some(v) => Some((v.display().to_string(), load(v, &a.signals)?)),
        None => None,
    };
    let d = DiagnoseData::from_records(records, validate).map_err(|e| e.to_string())?;
    println!("{}", d.split_text());
    Ok(d)
}

/// `--budget SECONDS`: the search budget of long records (positive).
fn set_budget(opts: &mut DiagnoseOptions, budget: Option<f64>) -> Result<()> {
    if let Some(b) = budget {
        if !(b.is_finite() && b > 0.0) {
            return Err(format!(
                "--budget must be a positive number of seconds, got {b}"
            ));
        }
        opts.policy.search_budget_s = b;
    }
    Ok(())
}

/// Run the diagnosis, print the report, then write the requested files
/// (each atomically, only after everything succeeded).
pub fn run(a: DiagnoseArgs, quiet: bool) -> Result<()> {
    let defaults = DiagnoseOptions::default();
    let order = parse_order(&a.order, defaults.policy.max_order)?;
    if a.max_steps == 0 || a.max_steps > 4 {
        return Err(format!("--max-steps must be 1..=4, got {}", a.max_steps));
    }
    if a.signals.outputs.len() > 1 {
        if !a.more_train.is_empty() {
            return Err("several training records (--train) take one --output".into());
        }
        return run_outputs(&a, order, quiet);
    }
    let (data, physics) = data(&a)?;
    let mut opts = DiagnoseOptions {
        order,
        max_steps: a.max_steps,
        physics,
        ..defaults
    };
    set_budget(&mut opts, a.budget)?;
    let bar = Bar::new(quiet, 1 + a.max_steps, "");
    let d = diagnose(&data, &opts, Some(&bar)).map_err(|e| e.to_string())?;
    bar.finish();
    println!();
    print!("{}", d.report.to_text());
    // render before writing anything: a failure leaves no output file behind
    let html = match &a.report {
        Some(_) => {
            let title = match (&a.example, &a.train) {
                (Some(ex), _) => format!("greybox diagnosis: example {ex}"),
                (None, Some(p)) if a.more_train.is_empty() => {
                    format!("greybox diagnosis: {}", p.display())
                }
                (None, _) if !a.more_train.is_empty() => format!(
                    "greybox diagnosis: {} training records",
                    a.more_train.len() + usize::from(a.train.is_some())
                ),
                _ => "greybox diagnosis".to_string(),
            };
            Some(gb_diagnose::render_html(&d, &data, &title).map_err(|e| e.to_string())?)
        }
        None => None,
    };
    let json = match &a.json {
        Some(_) => Some(serde_json::to_string_pretty(&d.report).map_err(|e| e.to_string())?),
        None => None,
    };
    if let (Some(p), Some(h)) = (&a.report, &html) {
        gb_core::write_atomic(p, h.as_bytes()).map_err(|e| e.to_string())?;
        println!("HTML report written to {}", p.display());
    }
    if let (Some(j), Some(text)) = (&a.json, &json) {
        gb_core::write_atomic(j, text.as_bytes()).map_err(|e| e.to_string())?;
        println!("report written to {}", j.display());
    }
    if let Some(s) = &a.save {
        d.to_save().save(s).map_err(|e| e.to_string())?;
        println!("final model saved to {}", s.display());
    }
    Ok(())
}

/// One diagnosis per output (`--output` repeated): each output's records
/// share the inputs; the reports are printed one after the other, the JSON
/// report has one section per output, the HTML reports are concatenated and
/// the final models are stacked into one `multi-output` model.
fn run_outputs(a: &DiagnoseArgs, order: OrderChoice, quiet: bool) -> Result<()> {
    if a.example.is_some() || a.model_file.is_some() {
        return Err(
            "several --output columns need a training CSV (no --example or --model-file)".into(),
        );
    }
    let train_path = a.train.as_ref().ok_or("a training CSV is needed")?;
    let train = load_outputs(train_path, &a.signals)?;
    let (inputs, sample_time) = (train[0].input_names.clone(), train[0].sample_time);
    let val = a
        .validate
        .as_ref()
        .map(|v| load_outputs(v, &a.signals))
        .transpose()?;
    let mut opts = DiagnoseOptions {
        order,
        max_steps: a.max_steps,
        ..DiagnoseOptions::default()
    };
    set_budget(&mut opts, a.budget)?;
    let (mut sections, mut reported, mut parts) = (vec![], vec![], vec![]);
    for (o, tr) in train.into_iter().enumerate() {
        let name = a.signals.outputs[o].clone();
        let data = match &val {
            Some(v) => {
                DiagnoseData::with_validation(tr, v[o].clone()).map_err(|e| e.to_string())?
            }
            None => DiagnoseData::from_single(tr),
        };
        let bar = Bar::new(quiet, 1 + a.max_steps, "");
        let d = diagnose(&data, &opts, Some(&bar)).map_err(|e| format!("output {name}: {e}"))?;
        bar.finish();
        println!("\n== output {name} ==");
        print!("{}", d.report.to_text());
        let report = serde_json::to_value(&d.report).map_err(|e| e.to_string())?;
        sections.push(serde_json::json!({"output": name, "report": report}));
        let kept = d.to_save();
        parts.push((kept.dynamics.clone(), kept.noise.clone()));
        if a.report.is_some() {
            reported.push((name, d, data));
        }
    }
    let html = if a.report.is_some() {
        let title = format!(
            "greybox diagnosis: {} (outputs {})",
            train_path.display(),
            a.signals.outputs.join(", ")
        );
        let refs: Vec<(&str, &gb_diagnose::Diagnosis, &DiagnoseData)> = reported
            .iter()
            .map(|(n, d, data)| (n.as_str(), d, data))
            .collect();
        gb_diagnose::render_html_outputs(&refs, &title).map_err(|e| e.to_string())?
    } else {
        String::new()
    };
    println!();
    for (s, name) in sections.iter().zip(&a.signals.outputs) {
        let causes = s["report"]["causes"]
            .as_array()
            .map(|c| {
                c.iter()
                    .filter_map(|v| v.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            })
            .filter(|c| !c.is_empty())
            .unwrap_or_else(|| "none".into());
        println!("output {name}: causes: {causes}");
    }
    let json = serde_json::to_string_pretty(&serde_json::json!({ "outputs": sections }))
        .map_err(|e| e.to_string())?;
    let noise = parts[0].1.clone();
    let stack = gb_model::MultiOutputModel::new(parts).map_err(|e| e.to_string())?;
    let mut model =
        gb_core::FittedModel::new(inputs, a.signals.outputs.clone(), Box::new(stack), noise)
            .map_err(|e| e.to_string())?;
    model.sample_time = sample_time;
    if let Some(p) = &a.report {
        gb_core::write_atomic(p, html.as_bytes()).map_err(|e| e.to_string())?;
        println!("HTML report written to {}", p.display());
    }
    if let Some(j) = &a.json {
        gb_core::write_atomic(j, json.as_bytes()).map_err(|e| e.to_string())?;
        println!("report written to {}", j.display());
    }
    if let Some(s) = &a.save {
        model.save(s).map_err(|e| e.to_string())?;
        println!("final model saved to {}", s.display());
    }
    Ok(())
}
