//! The data of a diagnosis: fit, select and report blocks.
use crate::DiagnoseError;
use gb_core::Record;
use std::ops::Range;

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
        })
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

    /// The inputs over the scored select samples.
    pub fn select_inputs(&self, init_window: usize) -> Vec<Vec<f64>> {
        let r = self.select_scored(init_window);
        self.train
            .inputs
            .iter()
            .map(|u| u[r.clone()].to_vec())
            .collect()
    }

    pub(crate) fn check(&self, min_fit: usize, min_block: usize) -> Result<(), DiagnoseError> {
        self.fit_record().check_identifiable("fit block", min_fit)?;
        if self.select.len() < min_block || self.report_range.len() < min_block {
            return Err(DiagnoseError::Core(gb_core::CoreError::TooShort {
                context: "select/report blocks".into(),
                needed: min_block,
                got: self.select.len().min(self.report_range.len()),
            }));
        }
        Ok(())
    }

    /// How the data were split, in words.
    pub fn split_text(&self) -> String {
        let blocks = format!(
            "fit {}..{}, select {}..{}",
            self.fit.start, self.fit.end, self.select.start, self.select.end
        );
        if self.single_record {
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
