//! `greybox generate`, `denoise`, `wavelet` and `bench`.
use crate::bench;
use crate::{BenchArgs, DenoiseArgs, GenerateArgs, Result, WaveletArgs};
use gb_core::{CsvTable, Record};
use gb_diagnose::systems;
use std::path::PathBuf;

pub fn generate(a: GenerateArgs) -> Result<()> {
    let g = systems::generate(&a.system, a.seed, a.samples, a.validate_samples)
        .map_err(|e| e.to_string())?;
    std::fs::create_dir_all(&a.out).map_err(|e| format!("{}: {e}", a.out.display()))?;
    let t_tr: Vec<f64> = (0..g.train.len()).map(|k| k as f64 * g.ts).collect();
    let t_va: Vec<f64> = (0..g.validate.len()).map(|k| k as f64 * g.ts).collect();
    let w = |name: &str, t: &[f64], d: &Record| {
        gb_core::write_csv_atomic(
            a.out.join(name),
            &["t", "u", "y"],
            &[t, &d.inputs[0], &d.output],
        )
        .map_err(|e| e.to_string())
    };
    w("train.csv", &t_tr, &g.train)?;
    w("validate.csv", &t_va, &g.validate)?;
    let truth = serde_json::json!({
        "system": g.system,
        "seed": g.seed,
        "expected_cause": g.expected_cause,
        "noise_std": g.noise_std,
        "noise_floor_nrmse": g.noise_floor_nrmse,
        "snr_db": g.snr_db,
        "ts": g.ts,
        "parameters": g.parameters.iter().map(|(k, v)| (k.clone(), *v)).collect::<std::collections::BTreeMap<_, _>>(),
    });
    let text = serde_json::to_string_pretty(&truth).map_err(|e| e.to_string())?;
    gb_core::write_atomic(a.out.join("truth.json"), text.as_bytes()).map_err(|e| e.to_string())?;
    println!(
        "{}: wrote {}/train.csv ({} samples), validate.csv ({}), truth.json; hidden effect: {}; noise floor NRMSE {:.4}",
        g.system,
        a.out.display(),
        g.train.len(),
        g.validate.len(),
        g.expected_cause.as_deref().unwrap_or("none"),
        g.noise_floor_nrmse
    );
    Ok(())
}

fn wavelet_setup(name: &str, mode: &str) -> Result<(gb_wavelet::Wavelet, gb_wavelet::Mode)> {
    let w = gb_wavelet::Wavelet::new(name).map_err(|e| format!("--wavelet: {e}"))?;
    let m: gb_wavelet::Mode = mode.parse().map_err(|e| format!("--mode: {e}"))?;
    Ok((w, m))
}

pub fn denoise(a: DenoiseArgs) -> Result<()> {
    let (w, mode) = wavelet_setup(&a.wavelet, &a.mode)?;
    let rule: gb_wavelet::ThresholdRule = a
        .threshold
        .parse()
        .map_err(|e| format!("--threshold: {e}"))?;
    let t = CsvTable::read(&a.data).map_err(|e| e.to_string())?;
    let x = t.column(&a.column).map_err(|e| e.to_string())?;
    let d = gb_wavelet::denoise_with(x, &w, &gb_wavelet::DenoiseOptions::new(rule, mode))
        .map_err(|e| format!("{}: column '{}': {e}", a.data.display(), a.column))?;
    let names: Vec<&str> = t.names.iter().map(String::as_str).collect();
    let cols: Vec<&[f64]> = t
        .names
        .iter()
        .zip(&t.columns)
        .map(|(n, c)| {
            if *n == a.column {
                d.signal.as_slice()
            } else {
                c.as_slice()
            }
        })
        .collect();
    gb_core::write_csv_atomic(&a.out, &names, &cols).map_err(|e| e.to_string())?;
    let removed = gb_core::metrics::rms(
        &x.iter()
            .zip(&d.signal)
            .map(|(p, q)| p - q)
            .collect::<Vec<_>>(),
    );
    println!(
        "{}: denoised '{}' with {} / {} thresholds (noise sigma {:.4e}, removed rms {:.4e}) -> {}",
        a.data.display(),
        a.column,
        a.wavelet,
        rule,
        d.sigma,
        removed,
        a.out.display()
    );
    Ok(())
}

pub fn wavelet(a: WaveletArgs) -> Result<()> {
    let (w, mode) = wavelet_setup(&a.wavelet, &a.mode)?;
    let t = CsvTable::read(&a.data).map_err(|e| e.to_string())?;
    let x = t.column(&a.column).map_err(|e| e.to_string())?;
    let bands = gb_wavelet::wavedec(x, &w, mode, a.level)
        .map_err(|e| format!("{}: column '{}': {e}", a.data.display(), a.column))?;
    let rows = gb_wavelet::coefficient_rows(&bands);
    let level: Vec<f64> = rows.iter().map(|r| r.0 as f64).collect();
    let index: Vec<f64> = rows.iter().map(|r| r.1 as f64).collect();
    let value: Vec<f64> = rows.iter().map(|r| r.2).collect();
    gb_core::write_csv_atomic(
        &a.out,
        &["level", "index", "value"],
        &[&level, &index, &value],
    )
    .map_err(|e| e.to_string())?;
    println!(
        "{}: {} coefficients in {} bands ({} levels, {}, {}) -> {}",
        a.data.display(),
        rows.len(),
        bands.len(),
        bands.len() - 1,
        a.wavelet,
        a.mode,
        a.out.display()
    );
    Ok(())
}

pub fn bench(a: BenchArgs, quiet: bool) -> Result<()> {
    let data_dir = a
        .data_dir
        .or_else(|| std::env::var_os("GREYBOX_DATA").map(PathBuf::from))
        .unwrap_or_else(|| PathBuf::from("../shared/data"));
    let results = if a.no_results {
        None
    } else {
        a.results
            .or_else(|| (!a.quick).then(|| PathBuf::from("docs/results.md")))
    };
    bench::run(&bench::BenchOptions {
        data_dir,
        only: a.only,
        quick: a.quick,
        blind_only: a.blind_only,
        quiet,
        results,
    })
    .map(|_| ())
}
