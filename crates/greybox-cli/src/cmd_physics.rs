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

/// The record of `data` for the model of `mf`: the model's input and output
/// names are the CSV columns (or `--input`/`--output` name the columns that
/// play them, in the model's order); the record carries the model's names
/// and the sample time of a uniform `t` column. Prints the roles.
pub fn load_for_model(data: &Path, s: &SignalArgs, mf: &ModelFile) -> Result<Record> {
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
    let model_output = spec
        .outputs
        .first()
        .map(|o| o.name.clone())
        .ok_or_else(|| format!("{}: the model has no output", mf.name))?;
    let output = s
        .output()?
        .map_or_else(|| model_output.clone(), str::to_string);
    for (role, c) in inputs
        .iter()
        .map(|c| ("input", c))
        .chain(std::iter::once(("output", &output)))
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
    let mut r = Record::from_table(&t, &inputs, Some(&output)).map_err(|e| e.to_string())?;
    r.input_names = spec.inputs.clone();
    r.output_name = model_output;
    if let Some((_, dt)) = sample_time(&t)? {
        r = r.with_sample_time(dt);
    }
    println!(
        "{}: inputs {} -> output {} ({} samples)",
        data.display(),
        inputs.join(","),
        output,
        r.len()
    );
    Ok(r)
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
    let first = load_for_model(&a.train, &a.signals, &mf)?;
    let (ts, from) = sample_time_of(&mf, &first, &a.train)?;
    let mut records = vec![first];
    for f in &a.experiments {
        let e = load_for_model(f, &a.signals, &mf)?;
        e.check_identifiable(&f.display().to_string(), 20)
            .map_err(|e| e.to_string())?;
        records.push(e);
    }
    let data = Records::new(records).map_err(|e| e.to_string())?;
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
        .fit_growing(&data, &bar)
        .map_err(|e| format!("{}: {e}", a.train.display()))?;
    bar.finish();
    let fitted = model.to_fitted().map_err(|e| e.to_string())?;
    println!("model: {}", fitted.describe());
    if let Some(rep) = model.fit_report() {
        for l in rep.lines() {
            println!("{l}");
        }
        println!(
            "training NRMSE (free-run simulation): {:.4}; fit took {:.2} s",
            rep.nrmse,
            t0.elapsed().as_secs_f64()
        );
    }
    fitted.save(&a.out).map_err(|e| e.to_string())?;
    println!("saved to {}", a.out.display());
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
    let tr = load_for_model(train, s, &mf)?;
    let (ts, from) = sample_time_of(&mf, &tr, train)?;
    println!(
        "the baseline is the model file {} (sample time {ts:.6e} s, {from})",
        mf.name
    );
    let val = validate
        .map(|v| load_for_model(v, s, &mf).map(|r| r.with_sample_time(ts)))
        .transpose()?;
    let mut spec = mf.spec;
    spec.sample_time = Some(ts);
    Ok((spec, tr.with_sample_time(ts), val))
}
