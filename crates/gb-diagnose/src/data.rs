//! The data of a diagnosis: fit, select and report blocks, on one training
//! record or on several (separate experiments: no regressor and no
//! simulated state spans two records).
use crate::DiagnoseError;
use gb_core::Record;
use std::ops::Range;

/// A further training record of a multi-record diagnosis, with its
/// contiguous fit and select ranges.
#[derive(Debug, Clone)]
pub struct TrainPart {
    /// The record.
    pub record: Record,
    /// Fit block range in `record`.
    pub fit: Range<usize>,
    /// Select block range in `record`.
    pub select: Range<usize>,
}

/// One training record's view: the record, its fit and its select range.
#[derive(Debug, Clone, Copy)]
pub struct Part<'a> {
    /// The record.
    pub record: &'a Record,
    /// Fit block range in `record`.
    pub fit: &'a Range<usize>,
    /// Select block range in `record`.
    pub select: &'a Range<usize>,
}

/// The data of a diagnosis: one record holding the fit and select blocks
/// (contiguous) and the report data (a separate record, or the tail of the
/// same one). Decisions use the fit and select blocks only; the report
/// block is scored once per model, for the report.
#[derive(Debug, Clone)]
pub struct DiagnoseData {
    /// Record with the fit and select blocks.
    pub train: Record,
    /// Fit block range in `train`.
    pub fit: Range<usize>,
    /// Select block range in `train`.
    pub select: Range<usize>,
    /// Record holding the report block.
    pub report: Record,
    /// Report block range in `report`.
    pub report_range: Range<usize>,
    /// Whether `report` is the training record itself.
    pub single_record: bool,
    /// Further training records after `train` (empty: one training record).
    pub more: Vec<TrainPart>,
    /// Names of the training records, then of the report record (file
    /// names, for the report; empty when not given).
    pub names: Vec<String>,
    /// Whether the report lists the records ([`from_records`](Self::from_records)
    /// with several training records, the last possibly the report data).
    pub listed: bool,
    /// Whether the report record is one of the user's training records
    /// (several training records and no validation record: the last is
    /// held out whole for the report), so that the model saved may be
    /// refitted on it once the report is scored.
    pub report_is_training: bool,
}

impl DiagnoseData {
    /// Train file split 75/25 into fit/select; the validation file is the
    /// report data (scored after its init window of `init_window` samples).
    pub fn with_validation(train: Record, validate: Record) -> Result<Self, DiagnoseError> {
        check_same_signals(&train, &validate)?;
        let s = train.split_blocks(0.75, 0.25);
        let n = validate.len();
        Ok(Self {
            fit: 0..s.fit_end,
            select: s.fit_end..s.len,
            report_range: 0..n,
            report: validate,
            train,
            single_record: false,
            more: vec![],
            names: vec![],
            listed: false,
            report_is_training: false,
        })
    }

    /// Several training records (`records`, at least one, same signals),
    /// each `(name, record)`. One record: [`with_validation`](Self::with_validation)
    /// or [`from_single`](Self::from_single), unchanged. `K ≥ 2` records:
    /// with a validation record every training record is split 75/25 into
    /// fit/select and the validation record is the report data; without
    /// one the last training record is the report data (held out whole,
    /// scored after its init window) and the others are split 75/25.
    pub fn from_records(
        mut records: Vec<(String, Record)>,
        validate: Option<(String, Record)>,
    ) -> Result<Self, DiagnoseError> {
        if records.is_empty() {
            return Err(DiagnoseError::InvalidArgument("no training record".into()));
        }
        let first = &records[0].1;
        for (name, r) in records.iter().skip(1).chain(validate.as_ref()) {
            if r.input_names != first.input_names || r.output_name != first.output_name {
                return Err(DiagnoseError::InvalidArgument(format!(
                    "{name}: signals ({} -> {}) differ from those of {} ({} -> {})",
                    r.input_names.join(","),
                    r.output_name,
                    records[0].0,
                    first.input_names.join(","),
                    first.output_name
                )));
            }
        }
        if records.len() == 1 {
            let (name, r) = records.pop().expect("one record");
            let mut d = match validate {
                Some((vname, v)) => Self {
                    names: vec![name.clone(), vname],
                    ..Self::with_validation(r, v)?
                },
                None => Self::from_single(r),
            };
            if d.names.is_empty() {
                d.names = vec![name];
            }
            return Ok(d);
        }
        let report_is_training = validate.is_none();
        let report = match validate {
            Some(v) => v,
            None => records.pop().expect("two records"),
        };
        let mut parts = records.into_iter().map(|(name, r)| {
            let s = r.split_blocks(0.75, 0.25);
            let part = TrainPart {
                fit: 0..s.fit_end,
                select: s.fit_end..s.len,
                record: r,
            };
            (name, part)
        });
        let (name0, first) = parts.next().expect("a training record");
        let (mut names, more): (Vec<String>, Vec<TrainPart>) = parts.unzip();
        names.insert(0, name0);
        names.push(report.0);
        let n = report.1.len();
        Ok(Self {
            train: first.record,
            fit: first.fit,
            select: first.select,
            report: report.1,
            report_range: 0..n,
            single_record: false,
            more,
            names,
            listed: true,
            report_is_training,
        })
    }

    /// Whether there are several training records.
    pub fn multi(&self) -> bool {
        !self.more.is_empty()
    }

    /// The training records in order, with their fit and select ranges.
    pub fn parts(&self) -> Vec<Part<'_>> {
        std::iter::once(Part {
            record: &self.train,
            fit: &self.fit,
            select: &self.select,
        })
        .chain(self.more.iter().map(|p| Part {
            record: &p.record,
            fit: &p.fit,
            select: &p.select,
        }))
        .collect()
    }

    /// Training record `i` (0: `train`, then `more` in order).
    pub fn record(&self, i: usize) -> &Record {
        match i.checked_sub(1) {
            Some(j) => &self.more[j].record,
            None => &self.train,
        }
    }

    /// The fit block a single-record model class is fitted on: the fit
    /// block of one record, or with several records the longest fit part
    /// (the first of equal length).
    pub fn longest_fit_record(&self) -> Record {
        let parts = self.parts();
        let mut best = parts[0];
        for p in &parts[1..] {
            if p.fit.len() > best.fit.len() {
                best = *p;
            }
        }
        best.record.slice(best.fit.clone())
    }

    /// Samples of the shortest select block (of one record: its select
    /// block).
    pub fn shortest_select(&self) -> usize {
        self.parts()
            .iter()
            .map(|p| p.select.len())
            .min()
            .unwrap_or(0)
    }

    /// Samples of the select blocks of all training records.
    pub fn select_samples(&self) -> usize {
        self.parts().iter().map(|p| p.select.len()).sum()
    }

    /// One record split into contiguous fit (50 %), select (25 %) and
    /// report (25 %) blocks.
    pub fn from_single(data: Record) -> Self {
        let s = data.split_blocks(0.5, 0.25);
        Self {
            fit: 0..s.fit_end,
            select: s.fit_end..s.select_end,
            report_range: s.select_end..s.len,
            report: data.clone(),
            train: data,
            single_record: true,
            more: vec![],
            names: vec![],
            listed: false,
            report_is_training: false,
        }
    }

    /// The fit block as a record.
    pub fn fit_record(&self) -> Record {
        self.train.slice(self.fit.clone())
    }

    /// Scored samples of the select block (after the init window).
    pub fn select_scored(&self, init_window: usize) -> Range<usize> {
        self.select.start.max(init_window)..self.select.end
    }

    /// Scored samples of the report block (after the init window).
    pub fn report_scored(&self, init_window: usize) -> Range<usize> {
        self.report_range.start.max(init_window)..self.report_range.end
    }

    /// The inputs over the scored select samples (with several records,
    /// each record's scored select samples, concatenated in record order).
    pub fn select_inputs(&self, init_window: usize) -> Vec<Vec<f64>> {
        (0..self.train.n_inputs())
            .map(|j| {
                self.parts()
                    .iter()
                    .flat_map(|p| {
                        let r = p.select.start.max(init_window)..p.select.end;
                        p.record.inputs[j][r].iter().copied()
                    })
                    .collect()
            })
            .collect()
    }

    /// The measured output over the scored select samples (concatenated
    /// in record order).
    pub fn select_output(&self, init_window: usize) -> Vec<f64> {
        self.parts()
            .iter()
            .flat_map(|p| {
                let r = p.select.start.max(init_window)..p.select.end;
                p.record.output[r].iter().copied()
            })
            .collect()
    }

    pub(crate) fn check(&self, min_fit: usize, min_block: usize) -> Result<(), DiagnoseError> {
        for p in self.parts() {
            p.record
                .slice(p.fit.clone())
                .check_identifiable("fit block", min_fit)?;
            if p.select.len() < min_block || self.report_range.len() < min_block {
                return Err(DiagnoseError::Core(gb_core::CoreError::TooShort {
                    context: "select/report blocks".into(),
                    needed: min_block,
                    got: p.select.len().min(self.report_range.len()),
                }));
            }
        }
        Ok(())
    }

    /// The records and their fit/select (or report) sample counts, for the
    /// report (empty with one training record).
    pub fn record_summaries(&self) -> Vec<crate::report::RecordSummary> {
        if !self.listed {
            return vec![];
        }
        let name = |i: usize| {
            self.names
                .get(i)
                .cloned()
                .unwrap_or(format!("record {}", i + 1))
        };
        let mut out: Vec<crate::report::RecordSummary> = self
            .parts()
            .iter()
            .enumerate()
            .map(|(i, p)| crate::report::RecordSummary {
                name: name(i),
                samples: p.record.len(),
                fit: p.fit.len(),
                select: p.select.len(),
                report: 0,
            })
            .collect();
        out.push(crate::report::RecordSummary {
            name: name(out.len()),
            samples: self.report.len(),
            fit: 0,
            select: 0,
            report: self.report_range.len(),
        });
        out
    }

    /// How the data were split, in words.
    pub fn split_text(&self) -> String {
        let blocks = format!(
            "fit {}..{}, select {}..{}",
            self.fit.start, self.fit.end, self.select.start, self.select.end
        );
        if self.listed {
            let recs: Vec<String> = self.record_summaries().iter().map(|r| r.text()).collect();
            let k = self.parts().len();
            format!(
                "{k} training record{}, each simulated from its own start: {}",
                if k == 1 { "" } else { "s" },
                recs.join("; ")
            )
        } else if self.single_record {
            format!(
                "one record split into contiguous blocks: {blocks}, report {}..{}",
                self.report_range.start, self.report_range.end
            )
        } else {
            format!(
                "training record: {blocks}; validation record: report {}..{}",
                self.report_range.start, self.report_range.end
            )
        }
    }
}

fn check_same_signals(a: &Record, b: &Record) -> Result<(), DiagnoseError> {
    if a.input_names != b.input_names || a.output_name != b.output_name {
        return Err(DiagnoseError::InvalidArgument(format!(
            "training signals ({} -> {}) differ from validation signals ({} -> {})",
            a.input_names.join(","),
            a.output_name,
            b.input_names.join(","),
            b.output_name
        )));
    }
    Ok(())
}
