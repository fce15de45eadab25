use crate::{metrics, CoreError, CsvTable};
use serde::{Deserialize, Serialize};

/// Columns recognised as time or sample index (case-insensitive): never an
/// input or output unless named.
pub const INDEX_COLUMNS: [&str; 7] = ["t", "time", "timestamp", "k", "sample", "ts", "index"];

/// Whether a column name looks like an output: `y`, `y1`, `y_2`, `output`,
/// `out` (case-sensitive: `Y` is often a voltage).
pub fn output_like(name: &str) -> bool {
    let rest = name.strip_prefix('y').map(|r| r.trim_start_matches('_'));
    matches!(name, "output" | "out") || rest.is_some_and(|r| r.chars().all(|c| c.is_ascii_digit()))
}

/// Whether a column name is a time or sample index.
pub fn index_like(name: &str) -> bool {
    INDEX_COLUMNS.contains(&name.to_lowercase().as_str())
}

/// One record (experiment) of measured or simulated data: named input
/// signals and one output, equidistantly sampled.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Record {
    /// Names of the input signals.
    pub input_names: Vec<String>,
    /// Name of the output signal.
    pub output_name: String,
    /// Input signals, `inputs[j][k]` = input j at sample k.
    pub inputs: Vec<Vec<f64>>,
    /// Output samples.
    pub output: Vec<f64>,
    /// Sample time in seconds, when known (from a uniform `t` column or the
    /// user).
    #[serde(default)]
    pub sample_time: Option<f64>,
}

/// Three contiguous blocks of a record: fit, select (model choice) and report.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct BlockSplit {
    /// End (exclusive) of the fit block, which starts at 0.
    pub fit_end: usize,
    /// End (exclusive) of the select block.
    pub select_end: usize,
    /// Total length (end of the report block).
    pub len: usize,
}

impl Record {
    /// Build a data set, checking that all signals have the same length.
    pub fn new(
        input_names: Vec<String>,
        output_name: String,
        inputs: Vec<Vec<f64>>,
        output: Vec<f64>,
    ) -> Result<Self, CoreError> {
        if input_names.len() != inputs.len() {
            return Err(CoreError::Dimension(format!(
                "{} input names for {} input signals",
                input_names.len(),
                inputs.len()
            )));
        }
        if let Some((j, u)) = inputs
            .iter()
            .enumerate()
            .find(|(_, u)| u.len() != output.len())
        {
            return Err(CoreError::Dimension(format!(
                "input '{}' has {} samples, output has {}",
                input_names[j],
                u.len(),
                output.len()
            )));
        }
        if output
            .iter()
            .chain(inputs.iter().flatten())
            .any(|v| !v.is_finite())
        {
            return Err(CoreError::InvalidArgument(
                "signals contain NaN or infinity".into(),
            ));
        }
        Ok(Self {
            input_names,
            output_name,
            inputs,
            output,
            sample_time: None,
        })
    }

    /// Select signals from a CSV table, never guessing silently:
    ///
    /// * the output is `output`, else the one output-like column
    ///   ([`output_like`]: `y`, `y1`, `output`, …); none or several is an
    ///   error listing the columns;
    /// * the inputs are `inputs`, else every column that is neither the
    ///   output nor a time/index column ([`INDEX_COLUMNS`]) — an error when
    ///   another output-like column would become an input (a measured output
    ///   used as an input is a data leak).
    pub fn from_table(
        table: &CsvTable,
        inputs: &[String],
        output: Option<&str>,
    ) -> Result<Self, CoreError> {
        let file = table.path.display();
        let cols = table.names.join(",");
        let output_name = match output {
            Some(o) => o.to_string(),
            None => {
                let like: Vec<&String> = table.names.iter().filter(|n| output_like(n)).collect();
                match like.as_slice() {
                    [one] => one.to_string(),
                    [] => {
                        return Err(CoreError::InvalidArgument(format!(
                            "{file}: which column is the output? none is named y (columns: {cols}); give --output NAME"
                        )))
                    }
                    many => {
                        return Err(CoreError::InvalidArgument(format!(
                            "{file}: several output-like columns ({}); give --output NAME (and --input for the inputs)",
                            many.iter().map(|s| s.as_str()).collect::<Vec<_>>().join(", ")
                        )))
                    }
                }
            }
        };
        let y = table.column(&output_name)?.to_vec();
        let input_names: Vec<String> = if inputs.is_empty() {
            let v: Vec<String> = table
                .names
                .iter()
                .filter(|n| **n != output_name && !index_like(n))
                .cloned()
                .collect();
            if let Some(o) = v.iter().find(|n| output_like(n)) {
                return Err(CoreError::InvalidArgument(format!(
                    "{file}: column '{o}' looks like an output and would become an input; name the inputs with --input (columns: {cols})"
                )));
            }
            v
        } else {
            inputs.to_vec()
        };
        if input_names.is_empty() {
            return Err(CoreError::InvalidArgument(format!(
                "{file}: no input column (columns: {cols})"
            )));
        }
        if let Some(n) = input_names.iter().find(|n| **n == output_name) {
            return Err(CoreError::InvalidArgument(format!(
                "{file}: column '{n}' is both input and output"
            )));
        }
        let u = input_names
            .iter()
            .map(|n| table.column(n).map(<[f64]>::to_vec))
            .collect::<Result<Vec<_>, _>>()?;
        Self::new(input_names, output_name, u, y)
    }

    /// The same record with a known sample time (seconds).
    pub fn with_sample_time(mut self, ts: f64) -> Self {
        self.sample_time = Some(ts).filter(|t| *t > 0.0 && t.is_finite());
        self
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.output.len()
    }

    /// True when there are no samples.
    pub fn is_empty(&self) -> bool {
        self.output.is_empty()
    }

    /// Number of input signals.
    pub fn n_inputs(&self) -> usize {
        self.inputs.len()
    }

    /// Samples `range` of every signal.
    pub fn slice(&self, range: std::ops::Range<usize>) -> Self {
        Self {
            input_names: self.input_names.clone(),
            output_name: self.output_name.clone(),
            inputs: self
                .inputs
                .iter()
                .map(|u| u[range.clone()].to_vec())
                .collect(),
            output: self.output[range].to_vec(),
            sample_time: self.sample_time,
        }
    }

    /// Check the data can identify a dynamic model: at least `min_len`
    /// samples and no constant signal. `context` names the source in errors.
    pub fn check_identifiable(&self, context: &str, min_len: usize) -> Result<(), CoreError> {
        if self.len() < min_len {
            return Err(CoreError::TooShort {
                context: context.to_string(),
                needed: min_len,
                got: self.len(),
            });
        }
        for (name, u) in self.input_names.iter().zip(&self.inputs) {
            if metrics::std(u) <= f64::EPSILON * (1.0 + metrics::mean(u).abs()) {
                return Err(CoreError::Constant {
                    context: context.to_string(),
                    name: name.clone(),
                });
            }
        }
        if metrics::std(&self.output) <= f64::EPSILON * (1.0 + metrics::mean(&self.output).abs()) {
            return Err(CoreError::Constant {
                context: context.to_string(),
                name: self.output_name.clone(),
            });
        }
        Ok(())
    }

    /// Split into contiguous blocks with the given fractions for fit and
    /// select (the rest is the report block).
    ///
    /// ```
    /// # use gb_core::Record;
    /// let ds = Record::new(vec!["u".into()], "y".into(), vec![vec![0.0; 100]], vec![0.0; 100]).unwrap();
    /// let s = ds.split_blocks(0.5, 0.25);
    /// assert_eq!((s.fit_end, s.select_end, s.len), (50, 75, 100));
    /// ```
    pub fn split_blocks(&self, fit: f64, select: f64) -> BlockSplit {
        let n = self.len();
        let fit_end = ((n as f64) * fit.clamp(0.0, 1.0)).round() as usize;
        let select_end =
            (((n as f64) * (fit + select).clamp(0.0, 1.0)).round() as usize).max(fit_end);
        BlockSplit {
            fit_end,
            select_end: select_end.min(n),
            len: n,
        }
    }
}

/// Several records of the same signals (separate experiments): a model is
/// fitted on all of them, and no regressor or state spans two records.
///
/// ```
/// use gb_core::{Record, Records};
/// let a = Record::new(vec!["u".into()], "y".into(), vec![vec![0.0, 1.0]], vec![1.0, 2.0]).unwrap();
/// let b = Record::new(vec!["u".into()], "y".into(), vec![vec![2.0]], vec![3.0]).unwrap();
/// let r = Records::new(vec![a.clone(), b]).unwrap();
/// assert_eq!((r.len(), r.total_samples()), (2, 3));
/// let c = Record::new(vec!["v".into()], "y".into(), vec![vec![0.0]], vec![0.0]).unwrap();
/// assert!(Records::new(vec![a, c]).is_err());
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Records {
    records: Vec<Record>,
}

impl Records {
    /// At least one record; all with the same input and output names.
    pub fn new(records: Vec<Record>) -> Result<Self, CoreError> {
        let first = records
            .first()
            .ok_or_else(|| CoreError::InvalidArgument("no record given".into()))?;
        if let Some(r) = records
            .iter()
            .find(|r| r.input_names != first.input_names || r.output_name != first.output_name)
        {
            return Err(CoreError::InvalidArgument(format!(
                "records hold different signals: {} -> {} and {} -> {}",
                first.input_names.join(","),
                first.output_name,
                r.input_names.join(","),
                r.output_name
            )));
        }
        Ok(Self { records })
    }

    /// One record.
    pub fn single(record: Record) -> Self {
        Self {
            records: vec![record],
        }
    }

    /// The records.
    pub fn as_slice(&self) -> &[Record] {
        &self.records
    }

    /// Iterate over the records.
    pub fn iter(&self) -> std::slice::Iter<'_, Record> {
        self.records.iter()
    }

    /// The first record (there is always one).
    pub fn first(&self) -> &Record {
        &self.records[0]
    }

    /// Number of records.
    pub fn len(&self) -> usize {
        self.records.len()
    }

    /// Always false (there is at least one record).
    pub fn is_empty(&self) -> bool {
        self.records.is_empty()
    }

    /// Samples over all records.
    pub fn total_samples(&self) -> usize {
        self.records.iter().map(Record::len).sum()
    }

    /// Input names (shared by all records).
    pub fn input_names(&self) -> &[String] {
        &self.first().input_names
    }

    /// Output name (shared by all records).
    pub fn output_name(&self) -> &str {
        &self.first().output_name
    }

    /// The records, consumed.
    pub fn into_vec(self) -> Vec<Record> {
        self.records
    }
}

impl<'a> IntoIterator for &'a Records {
    type Item = &'a Record;
    type IntoIter = std::slice::Iter<'a, Record>;
    fn into_iter(self) -> Self::IntoIter {
        self.records.iter()
    }
}

/// The folder of real benchmark data: `$GREYBOX_DATA` if set, else
/// `default` (by convention `../shared/data` beside the checkout). `None`,
/// with a one-line notice on stderr naming the folder, when it (or its
/// `needs` sub-folder) is absent — how tests and examples skip without data.
///
/// # Panics
/// When the folder is absent and `GREYBOX_REQUIRE_DATA` is set (CI sets it,
/// so that real-data tests cannot pass by skipping).
///
/// ```
/// if std::env::var_os("GREYBOX_REQUIRE_DATA").is_none() {
///     let d = gb_core::benchmark_data_dir(std::path::Path::new("/nonexistent"), "");
///     assert!(d.is_none() || std::env::var_os("GREYBOX_DATA").is_some());
/// }
/// ```
pub fn benchmark_data_dir(default: &std::path::Path, needs: &str) -> Option<std::path::PathBuf> {
    let d = std::env::var_os("GREYBOX_DATA")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| default.to_path_buf());
    if d.join(needs).is_dir() {
        Some(d)
    } else if std::env::var_os("GREYBOX_REQUIRE_DATA").is_some() {
        panic!(
            "GREYBOX_REQUIRE_DATA is set but {} is missing",
            d.join(needs).display()
        );
    } else {
        eprintln!(
            "notice: real-data run skipped: {} not found (set GREYBOX_DATA)",
            d.join(needs).display()
        );
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    fn table(text: &str) -> CsvTable {
        CsvTable::from_reader(text.as_bytes(), PathBuf::from("d.csv")).unwrap()
    }

    #[test]
    fn defaults_skip_time_and_take_last_as_output() {
        let t = table("t,u1,u2,y\n0,1,2,3\n1,2,3,4\n");
        let d = Record::from_table(&t, &[], None).unwrap();
        assert_eq!(d.input_names, ["u1", "u2"]);
        assert_eq!(d.output_name, "y");
        assert_eq!(d.output, [3.0, 4.0]);
    }

    #[test]
    fn roles_are_never_guessed_silently() {
        // the measured y is the output even when it is not the last column
        let d = Record::from_table(&table("t,y,u1,u2\n0,1,2,3\n1,2,3,4\n"), &[], None).unwrap();
        assert_eq!(
            (d.output_name.as_str(), d.input_names.clone()),
            ("y", vec!["u1".to_string(), "u2".into()])
        );
        // two outputs: refuse rather than use y1 as an input of y2
        let e =
            Record::from_table(&table("u1,u2,y1,y2\n0,1,2,3\n1,2,3,4\n"), &[], None).unwrap_err();
        assert!(
            e.to_string()
                .contains("several output-like columns (y1, y2)"),
            "{e}"
        );
        let e = Record::from_table(&table("u1,u2,y1,y2\n0,1,2,3\n1,2,3,4\n"), &[], Some("y2"))
            .unwrap_err();
        assert!(e.to_string().contains("'y1' looks like an output"), "{e}");
        // no output-like name: say which flag to use; timestamp is an index
        let e = Record::from_table(&table("timestamp,D,F\n0,1,2\n1,2,3\n"), &[], None).unwrap_err();
        assert!(
            e.to_string().contains("give --output") && e.to_string().contains("timestamp,D,F"),
            "{e}"
        );
        let d =
            Record::from_table(&table("timestamp,D,F\n0,1,2\n1,2,3\n"), &[], Some("F")).unwrap();
        assert_eq!(d.input_names, ["D"]);
    }

    #[test]
    fn constant_input_is_refused() {
        let t = table("u,y\n1,1\n1,2\n1,3\n");
        let d = Record::from_table(&t, &[], None).unwrap();
        let e = d.check_identifiable("d.csv", 2).unwrap_err().to_string();
        assert!(e.contains("'u' is constant"), "{e}");
        let e = d.check_identifiable("d.csv", 10).unwrap_err().to_string();
        assert!(e.contains("3 samples, at least 10"), "{e}");
    }

    #[test]
    fn explicit_columns_and_missing() {
        let t = table("a,b,c\n0,1,2\n1,2,4\n");
        let d = Record::from_table(&t, &["c".into()], Some("a")).unwrap();
        assert_eq!(d.inputs, vec![vec![2.0, 4.0]]);
        assert!(Record::from_table(&t, &["zz".into()], Some("a")).is_err());
        assert!(Record::from_table(&t, &["a".into()], Some("a")).is_err());
    }
}
