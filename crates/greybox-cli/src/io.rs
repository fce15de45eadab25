//! Reading records and writing simulations.
use crate::{Result, SignalArgs};
use gb_core::{CsvTable, Record};
use std::path::Path;

/// A record of `path` with the columns `s` names (or the unambiguous
/// defaults), its sample time from a uniform time column; prints the roles.
pub fn load(path: &Path, s: &SignalArgs) -> Result<Record> {
    let t = CsvTable::read(path).map_err(|e| e.to_string())?;
    let mut r =
        Record::from_table(&t, &s.inputs, s.output.as_deref()).map_err(|e| e.to_string())?;
    let ts = sample_time(&t)?;
    if let Some((_, dt)) = ts {
        r = r.with_sample_time(dt);
    }
    println!(
        "{}: inputs {} -> output {}{}",
        path.display(),
        r.input_names.join(","),
        r.output_name,
        ts.map_or(String::new(), |(c, dt)| format!(
            "; sample time {dt:.6e} s (column {c})"
        ))
    );
    Ok(r)
}

/// The sample time of the time column (`t`, `time`, `timestamp`), if there
/// is one: its mean step `dt`, when every time lies within `dt/2` of the
/// uniform grid `t₀ + k·dt` (printed times are rounded, so single steps
/// jitter; a missing sample or a jump moves the grid by a whole step). A
/// non-uniform time column is an error naming the row where it jumps.
pub fn sample_time(t: &CsvTable) -> Result<Option<(String, f64)>> {
    let Some(name) = t
        .names
        .iter()
        .find(|n| matches!(n.to_lowercase().as_str(), "t" | "time" | "timestamp"))
    else {
        return Ok(None);
    };
    let c = t.column(name).map_err(|e| e.to_string())?;
    let n = c.len();
    if n < 2 {
        return Ok(None);
    }
    let dt = (c[n - 1] - c[0]) / (n - 1) as f64;
    if !(dt > 0.0 && dt.is_finite()) {
        return Err(format!(
            "{}: column '{name}' does not increase; drop it or fix it",
            t.path.display()
        ));
    }
    if let Some(k) = (0..n).find(|&k| (c[k] - c[0] - k as f64 * dt).abs() > 0.5 * dt) {
        let j = k.max(1);
        return Err(format!(
            "{}: column '{name}' is not uniform: row {} steps from {} to {} (mean step {dt:.6e}); resample the record to a uniform grid or drop the column",
            t.path.display(),
            j + 2,
            c[j - 1],
            c[j]
        ));
    }
    Ok(Some((name.clone(), dt)))
}

/// Writes the inputs, the measured output (if any), `y_sim` and the
/// `extra` columns to `out` (atomically), then prints the errors over
/// samples `n0..`.
pub fn write_simulation(
    out: &Path,
    in_names: &[String],
    inputs: &[Vec<f64>],
    y: Option<&[f64]>,
    sim: &[f64],
    extra: &[(&str, &[f64])],
    n0: usize,
) -> Result<()> {
    let mut names: Vec<&str> = in_names.iter().map(String::as_str).collect();
    let mut cols: Vec<&[f64]> = inputs.iter().map(Vec::as_slice).collect();
    if let Some(y) = y {
        names.push("y");
        cols.push(y);
    }
    names.push("y_sim");
    cols.push(sim);
    for (n, c) in extra {
        names.push(n);
        cols.push(c);
    }
    gb_core::write_csv_atomic(out, &names, &cols).map_err(|e| e.to_string())?;
    if let Some(y) = y {
        let n0 = n0.min(y.len().saturating_sub(1));
        let rmse = gb_core::metrics::rmse(&y[n0..], &sim[n0..]).map_err(|e| e.to_string())?;
        let nrmse = gb_core::metrics::nrmse(&y[n0..], &sim[n0..]).map_err(|e| e.to_string())?;
        println!(
            "samples {}..{}: RMSE {rmse:.6e}  NRMSE {nrmse:.4}  fit {:.2}%",
            n0,
            y.len(),
            100.0 * (1.0 - nrmse)
        );
    }
    println!("simulation written to {}", out.display());
    Ok(())
}
