//! `greybox fit --model-file model.toml`: the engineer's own equations
//! (the `physics` class of gb-model), fitted by output error with standard
//! errors, 95 % intervals, correlations and identifiability warnings.
use crate::io::sample_time;
use crate::progress::Bar;
use crate::{FitArgs, Result, SignalArgs};
use gb_core::{CsvTable, Record, Records};
use gb_model::physics::ModelFile;
use std::path::Path;

/// Read and check a model file; errors are one line `file:line: …`.
pub fn read_model_file(path: &Path) -> Result<ModelFile> {
    ModelFile::read(path).map_err(|e| e.to_string())
}

/// The records of `data` for the model of `mf`, one per model output (in
/// the file's `[outputs]` order): the model's input and output names are
/// the CSV columns (or `--input`/`--output` name the columns that play
/// them, in the model's order); each record carries the model's names and
/// the sample time of a uniform `t` column. Prints the roles.
pub fn load_outputs_for_model(data: &Path, s: &SignalArgs, mf: &ModelFile) -> Result<Vec<Record>> {
    let spec = &mf.spec;
    let t = CsvTable::read(data).map_err(|e| e.to_string())?;
    let inputs: Vec<String> = if s.inputs.is_empty() {
        spec.inputs.clone()
    } else if s.inputs.len() == spec.inputs.len() {
        s.inputs.clone()
    } else {
        return Err(format!(
            "{}: {} --input columns for the model's {} inputs [{}]",
            mf.name,
            s.inputs.len(),
            spec.inputs.len(),
            spec.inputs.join(", ")
        ));
    };
    let model_outputs: Vec<String> = spec.outputs.iter().map(|o| o.name.clone()).collect();
    if model_outputs.is_empty() {
        return Err(format!("{}: the model has no output", mf.name));
    }
    let outputs: Vec<String> = if s.outputs.is_empty() {
        model_outputs.clone()
    } else if s.outputs.len() == model_outputs.len() {
        s.outputs.clone()
    } else {
        return Err(format!(
            "{}: {} --output columns for the model's {} outputs [{}]",
            mf.name,
            s.outputs.len(),
            model_outputs.len(),
            model_outputs.join(", ")
        ));
    };
    for (role, c) in inputs
        .iter()
        .map(|c| ("input", c))
        .chain(outputs.iter().map(|c| ("output", c)))
    {
        if !t.names.iter().any(|n| n == c) {
            return Err(format!(
                "{}: {role} '{c}' is not a column of {} (columns: {}); rename it in the model file or pass --{role} COLUMN",
                mf.name,
                data.display(),
                t.names.join(", ")
            ));
        }
    }
    let dt = sample_time(&t)?.map(|(_, dt)| dt);
    let mut records = vec![];
    for (column, name) in outputs.iter().zip(&model_outputs) {
        let mut r = Record::from_table(&t, &inputs, Some(column)).map_err(|e| e.to_string())?;
        r.input_names = spec.inputs.clone();
        r.output_name = name.clone();
        if let Some(dt) = dt {
            r = r.with_sample_time(dt);
        }
        records.push(r);
    }
    println!(
        "{}: inputs {} -> output{} {} ({} samples)",
        data.display(),
        inputs.join(","),
        if outputs.len() > 1 { "s" } else { "" },
        outputs.join(","),
        records[0].len()
    );
    Ok(records)
}

/// The record of `data` for a model of one output (see
/// [`load_outputs_for_model`]); a model of several outputs is an error
/// naming `what` cannot handle it.
pub fn load_for_model(data: &Path, s: &SignalArgs, mf: &ModelFile, what: &str) -> Result<Record> {
    if mf.spec.outputs.len() > 1 {
        return Err(format!(
            "{}: {what} handles models of one output; this one has {} ({})",
            mf.name,
            mf.spec.outputs.len(),
            mf.spec
                .outputs
                .iter()
                .map(|o| o.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    let mut r = load_outputs_for_model(data, s, mf)?;
    Ok(r.remove(0))
}

/// The sample time of the fit and where it comes from: the model file's
/// `sample_time`, else the data's `t` column, else an error saying so.
pub fn sample_time_of(mf: &ModelFile, r: &Record, data: &Path) -> Result<(f64, String)> {
    match (mf.spec.sample_time, r.sample_time) {
        (Some(ts), _) => Ok((ts, format!("from {}", mf.name))),
        (None, Some(ts)) => Ok((ts, format!("from the t column of {}", data.display()))),
        (None, None) => Err(format!(
            "{}: no sample_time in the model file and no uniform t column in {}; add `sample_time = …` to the model file",
            mf.name,
            data.display()
        )),
    }
}

/// Fit the model file on the training file (and `--experiment` files),
/// print the estimates with their uncertainty, save the model.
pub fn fit(a: &FitArgs, path: &Path, quiet: bool) -> Result<()> {
    let mf = read_model_file(path)?;
    // per file, one record per model output
    let first = load_outputs_for_model(&a.train, &a.signals, &mf)?;
    let (ts, from) = sample_time_of(&mf, &first[0], &a.train)?;
    let mut files = vec![first];
    for f in &a.experiments {
        let e = load_outputs_for_model(f, &a.signals, &mf)?;
        for r in &e {
            r.check_identifiable(&f.display().to_string(), 20)
                .map_err(|e| e.to_string())?;
        }
        files.push(e);
    }
    // per output, the records of every file
    let data: Vec<Records> = (0..mf.spec.outputs.len())
        .map(|o| Records::new(files.iter().map(|f| f[o].clone()).collect()))
        .collect::<std::result::Result<_, _>>()
        .map_err(|e| e.to_string())?;
    let mut mf = mf;
    mf.spec.sample_time = Some(ts);
    println!(
        "sample time: {ts:.6e} s ({from}); RK4 with {} sub-step{} per sample",
        mf.spec.substeps,
        if mf.spec.substeps == 1 { "" } else { "s" }
    );
    let bar = Bar::spinner(quiet, &format!("fitting {}", mf.name));
    let t0 = std::time::Instant::now();
    let model = mf
        .fit_growing_outputs(&data, &bar)
        .map_err(|e| format!("{}: {e}", a.train.display()))?;
    bar.finish();
    let fitted = model.to_fitted().map_err(|e| e.to_string())?;
    println!("model: {}", fitted.describe());
    if let Some(rep) = model.fit_report() {
        for l in rep.lines() {
            println!("{l}");
        }
        println!(
            "training NRMSE (free-run simulation): {:.4}{}; fit took {:.2} s",
            rep.nrmse,
            if data.len() > 1 {
                " (RMS over the outputs)"
            } else {
                ""
            },
            t0.elapsed().as_secs_f64()
        );
        if data.len() > 1 {
            print_output_errors(&model, &data)?;
        }
        if let Some(w) = initial_state_warning(&model, &data[0])? {
            println!("warning: {w}");
        }
    }
    fitted.save(&a.out).map_err(|e| e.to_string())?;
    println!("saved to {}", a.out.display());
    Ok(())
}

/// Whether the fit leans on a free initial state that the start of the
/// record does not show: the first record simulated from the state its
/// first `w` measured outputs give (`w` = 50, at most a tenth of the
/// record; as `simulate --init-window w` scores a test set) against the
/// fitted start, both scored on samples `w..`. More than 1.5 times the
/// error says that the fitted start absorbs something the equations do not
/// (a drift of an integrating state): EMPS' rigid body fitted with `q(0)`
/// and `v(0)` free starts at 3.1 mm and −26 mm/s while the record starts at
/// rest, 2.4e-3 m over the record from there, 7.8e-3 m from the state the
/// first 50 samples give. The first output only.
fn initial_state_warning(
    model: &gb_model::physics::PhysicsModel,
    data: &Records,
) -> Result<Option<String>> {
    use gb_core::DynamicModel;
    let spec = model.spec();
    let free: Vec<String> = spec
        .states
        .iter()
        .zip(model.initial_state())
        .filter(|(s, _)| s.free)
        .map(|(s, v)| format!("{}(0) = {v:.4e}", s.name))
        .collect();
    let Some(rec) = data.iter().next() else {
        return Ok(None);
    };
    let w = 50.min(rec.len() / 10);
    if free.is_empty() || w < spec.states.len() || spec.outputs.len() != 1 {
        return Ok(None);
    }
    let rms_after = |init| -> Result<f64> {
        let sim = model
            .simulate(&rec.inputs, init)
            .map_err(|e| e.to_string())?;
        let e: Vec<f64> = (w..rec.len()).map(|k| rec.output[k] - sim[k]).collect();
        Ok(gb_core::metrics::rms(&e))
    };
    let fitted = rms_after(gb_core::Init::Stored)?;
    let from_data = rms_after(gb_core::Init::Window(&rec.output[..w]))?;
    if from_data.is_nan() || from_data <= 1.5 * fitted {
        return Ok(None);
    }
    Ok(Some(format!(
        "the fit leans on its fitted initial state ({}): simulated from the state the first {w} measured outputs give (as `simulate --init-window {w}` scores new data), the training RMSE is {from_data:.4e}, not {fitted:.4e}. The fitted start absorbs what the equations miss (the drift of an integrating state, a slow transient); when the experiment starts from a known state (at rest), state it in the model file (`initial = …, free = false`)",
        free.join(", ")
    )))
}

/// The training NRMSE of each output (free run from the fitted start,
/// every record of the output together).
fn print_output_errors(model: &gb_model::physics::PhysicsModel, data: &[Records]) -> Result<()> {
    use gb_core::DynamicModel;
    let ny = data.len();
    let (mut sse, mut n) = (vec![0.0; ny], 0usize);
    for r in 0..data[0].len() {
        let u = &data[0].iter().nth(r).ok_or("record")?.inputs;
        let sim = model
            .simulate(u, gb_core::Init::Stored)
            .map_err(|e| e.to_string())?;
        let len = u.first().map_or(0, Vec::len);
        n += len;
        for (o, d) in data.iter().enumerate() {
            let y = &d.iter().nth(r).ok_or("record")?.output;
            sse[o] += y
                .iter()
                .zip(&sim[o * len..(o + 1) * len])
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>();
        }
    }
    for (o, d) in data.iter().enumerate() {
        let all: Vec<f64> = d.iter().flat_map(|r| r.output.iter().copied()).collect();
        let sd = gb_core::metrics::std(&all);
        println!(
            "  output {}: training NRMSE {:.4}",
            d.output_name(),
            (sse[o] / n.max(1) as f64).sqrt() / sd
        );
    }
    Ok(())
}

/// The training (and validation) records of `diagnose --model-file` with
/// the model file's spec, its sample time set (file, else data).
pub fn diagnose_data(
    path: &Path,
    train: &Path,
    validate: Option<&Path>,
    s: &SignalArgs,
) -> Result<(gb_model::physics::PhysicsSpec, Record, Option<Record>)> {
    let mf = read_model_file(path)?;
    let tr = load_for_model(train, s, &mf, "diagnose --model-file")?;
    let (ts, from) = sample_time_of(&mf, &tr, train)?;
    println!(
        "the baseline is the model file {} (sample time {ts:.6e} s, {from})",
        mf.name
    );
    let val = validate
        .map(|v| load_for_model(v, s, &mf, "diagnose --model-file").map(|r| r.with_sample_time(ts)))
        .transpose()?;
    let mut spec = mf.spec;
    spec.sample_time = Some(ts);
    Ok((spec, tr.with_sample_time(ts), val))
}
