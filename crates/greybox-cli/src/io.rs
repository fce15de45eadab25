//! Reading records and writing simulations.
use crate::{Result, SignalArgs};
use gb_core::{CsvTable, Record};
use std::path::Path;

/// A record of `path` with the columns `s` names (or the unambiguous
/// defaults), its sample time from a uniform time column; prints the roles.
pub fn load(path: &Path, s: &SignalArgs) -> Result<Record> {
    let t = CsvTable::read(path).map_err(|e| e.to_string())?;
    let mut r = Record::from_table(&t, &s.inputs, s.output()?).map_err(|e| e.to_string())?;
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

/// One record of `path` per output column of `s` (at least two), all with
/// the same inputs: `--input`, else every column but the outputs and the
/// index/time columns (no output is an input of another); prints the roles.
pub fn load_outputs(path: &Path, s: &SignalArgs) -> Result<Vec<Record>> {
    if let Some(o) = (1..s.outputs.len()).find(|&i| s.outputs[..i].contains(&s.outputs[i])) {
        return Err(format!("--output '{}' is given twice", s.outputs[o]));
    }
    let t = CsvTable::read(path).map_err(|e| e.to_string())?;
    let ts = sample_time(&t)?;
    let mut out = vec![];
    for o in &s.outputs {
        // the table without the other outputs
        let (names, columns) = t
            .names
            .iter()
            .zip(&t.columns)
            .filter(|(n, _)| *n == o || !s.outputs.contains(n))
            .map(|(n, c)| (n.clone(), c.clone()))
            .unzip();
        let own = CsvTable {
            path: t.path.clone(),
            names,
            columns,
        };
        let mut r = Record::from_table(&own, &s.inputs, Some(o)).map_err(|e| e.to_string())?;
        if let Some((_, dt)) = ts {
            r = r.with_sample_time(dt);
        }
        out.push(r);
    }
    println!(
        "{}: inputs {} -> outputs {} (one model each){}",
        path.display(),
        out[0].input_names.join(","),
        s.outputs.join(","),
        ts.map_or(String::new(), |(c, dt)| format!(
            "; sample time {dt:.6e} s (column {c})"
        ))
    );
    Ok(out)
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

/// The columns of `t` named by `names` (a model's inputs), in that order;
/// a missing column is an error naming the file and the column.
pub fn columns(t: &CsvTable, names: &[String]) -> Result<Vec<Vec<f64>>> {
    names
        .iter()
        .map(|n| t.column(n).map(<[f64]>::to_vec))
        .collect::<std::result::Result<_, _>>()
        .map_err(|e| e.to_string())
}

/// The columns of a simulation's output: the inputs, the measured outputs
/// present, the simulated outputs (`y`, `y_sim` for one output; `NAME`,
/// `NAME_sim` for each of several).
pub fn simulation_columns(
    inputs: &[String],
    outputs: &[String],
    measured: &[Option<usize>],
) -> Vec<String> {
    let one = outputs.len() == 1;
    let mut names = inputs.to_vec();
    for (o, m) in outputs.iter().zip(measured) {
        if m.is_some() {
            names.push(if one { "y".into() } else { o.clone() });
        }
    }
    for o in outputs {
        names.push(if one {
            "y_sim".into()
        } else {
            format!("{o}_sim")
        });
    }
    names
}

/// One output of a simulation: its name, its measured values (when the
/// data have them) and its simulation.
pub struct SimOutput<'a> {
    /// The output's name.
    pub name: &'a str,
    /// Measured values, if present.
    pub measured: Option<&'a [f64]>,
    /// Simulated values.
    pub sim: &'a [f64],
}

/// Writes the inputs, the measured outputs (if any), the simulated outputs
/// (see [`simulation_columns`]) and the `extra` columns to `out`
/// (atomically), then prints the errors of each measured output over
/// samples `n0..`.
pub fn write_simulation(
    out: &Path,
    in_names: &[String],
    inputs: &[Vec<f64>],
    outputs: &[SimOutput<'_>],
    extra: &[(&str, &[f64])],
    n0: usize,
) -> Result<()> {
    let out_names: Vec<String> = outputs.iter().map(|o| o.name.to_string()).collect();
    let present: Vec<Option<usize>> = outputs.iter().map(|o| o.measured.map(|_| 0)).collect();
    let names = simulation_columns(in_names, &out_names, &present);
    let mut names: Vec<&str> = names.iter().map(String::as_str).collect();
    let mut cols: Vec<&[f64]> = inputs.iter().map(Vec::as_slice).collect();
    cols.extend(outputs.iter().filter_map(|o| o.measured));
    cols.extend(outputs.iter().map(|o| o.sim));
    for (n, c) in extra {
        names.push(n);
        cols.push(c);
    }
    gb_core::write_csv_atomic(out, &names, &cols).map_err(|e| e.to_string())?;
    for o in outputs {
        let (Some(y), sim) = (o.measured, o.sim) else {
            continue;
        };
        let n0 = n0.min(y.len().saturating_sub(1));
        let rmse = gb_core::metrics::rmse(&y[n0..], &sim[n0..]).map_err(|e| e.to_string())?;
        let nrmse = gb_core::metrics::nrmse(&y[n0..], &sim[n0..]).map_err(|e| e.to_string())?;
        println!(
            "{}samples {}..{}: RMSE {rmse:.6e}  NRMSE {nrmse:.4}  fit {:.2}%",
            if outputs.len() > 1 {
                format!("{}: ", o.name)
            } else {
                String::new()
            },
            n0,
            y.len(),
            100.0 * (1.0 - nrmse)
        );
    }
    println!("simulation written to {}", out.display());
    Ok(())
}

/// Rows of numeric CSV read one line at a time (`simulate MODEL -`): the
/// first non-blank line names the columns, as in CSV files; every cell is
/// checked as [`CsvTable`] checks it, and errors name the source, the
/// 1-based line (the header is row 1) and the column.
pub struct RowReader<R> {
    reader: R,
    path: std::path::PathBuf,
    /// Column names, in order.
    pub names: Vec<String>,
    line: usize,
    buf: String,
}

impl<R: std::io::BufRead> RowReader<R> {
    /// Read the header line of `reader`; `label` names the source in errors.
    pub fn new(reader: R, label: &str) -> Result<Self> {
        let mut s = Self {
            reader,
            path: label.into(),
            names: vec![],
            line: 0,
            buf: String::new(),
        };
        if !s.next_line()? {
            return Err(gb_core::CoreError::Empty { path: s.path }.to_string());
        }
        let names: Vec<String> = s.buf.split(',').map(|f| f.trim().to_string()).collect();
        let bad = |message: String| gb_core::CoreError::Csv {
            path: s.path.clone(),
            row: s.line,
            message,
        };
        if let Some(j) = names.iter().position(String::is_empty) {
            return Err(bad(format!("header field {} is empty", j + 1)).to_string());
        }
        if let Some(j) = names.iter().position(|n| n.parse::<f64>().is_ok()) {
            return Err(bad(format!(
                "header field {} is the number '{}': the first row must name the columns",
                j + 1,
                names[j]
            ))
            .to_string());
        }
        s.names = names;
        Ok(s)
    }

    /// The next non-blank line into `buf` (false at the end).
    fn next_line(&mut self) -> Result<bool> {
        loop {
            self.buf.clear();
            let n = self
                .reader
                .read_line(&mut self.buf)
                .map_err(|e| format!("{}: {e}", self.path.display()))?;
            if n == 0 {
                return Ok(false);
            }
            self.line += 1;
            if !self.buf.trim().is_empty() {
                return Ok(true);
            }
        }
    }

    /// The index of column `name`, or an error listing the columns.
    pub fn column(&self, name: &str) -> Result<usize> {
        self.names.iter().position(|n| n == name).ok_or_else(|| {
            gb_core::CoreError::MissingColumn {
                path: self.path.clone(),
                column: name.to_string(),
                available: self.names.join(","),
            }
            .to_string()
        })
    }

    /// The row number of the last row read (1-based; the header is row 1).
    pub fn row(&self) -> usize {
        self.line
    }

    /// The next row's values into `out`; false at the end of the input.
    pub fn next_row(&mut self, out: &mut Vec<f64>) -> Result<bool> {
        if !self.next_line()? {
            return Ok(false);
        }
        let (path, row) = (self.path.clone(), self.line);
        let fields: Vec<&str> = self.buf.split(',').map(str::trim).collect();
        if fields.len() != self.names.len() {
            return Err(gb_core::CoreError::Ragged {
                path,
                row,
                expected: self.names.len(),
                found: fields.len(),
            }
            .to_string());
        }
        out.clear();
        for (j, f) in fields.iter().enumerate() {
            let column = self.names[j].clone();
            let value = f.to_string();
            let v: f64 = f.parse().map_err(|_| {
                gb_core::CoreError::NonNumeric {
                    path: path.clone(),
                    row,
                    column: column.clone(),
                    value: value.clone(),
                }
                .to_string()
            })?;
            if !v.is_finite() {
                return Err(gb_core::CoreError::NonFinite {
                    path,
                    row,
                    column,
                    value,
                }
                .to_string());
            }
            out.push(v);
        }
        Ok(true)
    }
}
