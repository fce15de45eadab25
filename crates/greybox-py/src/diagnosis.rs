//! The diagnosis: the same calls as `greybox diagnose`.
use crate::model::PyModel;
use crate::{py_err, record, value_err};
use gb_diagnose::{diagnose, DiagnoseData, DiagnoseOptions, Diagnosis, OrderChoice};
use numpy::PyReadonlyArray1;
use pyo3::prelude::*;
use std::path::PathBuf;

/// A diagnosis with its data (the HTML report draws both).
#[pyclass(name = "_Diagnosis", module = "greybox._greybox", frozen)]
pub struct PyDiagnosis {
    diagnosis: Diagnosis,
    data: DiagnoseData,
}

/// The order as the CLI parses `--order`: `1..=max` or `auto`.
fn parse_order(s: &str, max: usize) -> PyResult<OrderChoice> {
    if s == "auto" {
        return Ok(OrderChoice::Auto);
    }
    match s.parse::<usize>() {
        Ok(n) if (1..=max).contains(&n) => Ok(OrderChoice::Fixed(n)),
        _ => Err(value_err(format!(
            "order must be 1..={max} or auto, got '{s}'"
        ))),
    }
}

/// The signals of one record as Python hands them over.
type Signals<'py> = (Vec<PyReadonlyArray1<'py, f64>>, PyReadonlyArray1<'py, f64>);

/// Diagnose the training record (with a validation record, or split into
/// blocks as the CLI does without `--validate`); `more`: further training
/// records, each a separate experiment (`greybox diagnose --train a.csv
/// --train b.csv`: without a validation record the last is the report
/// data, held out whole, and the model kept is refitted on every record).
#[pyfunction]
#[pyo3(signature = (train, validate, input_names, output_name, sample_time, order, max_steps, more=vec![]))]
#[allow(clippy::too_many_arguments)]
fn diagnose_records(
    py: Python<'_>,
    train: Signals<'_>,
    validate: Option<Signals<'_>>,
    input_names: Vec<String>,
    output_name: String,
    sample_time: Option<f64>,
    order: &str,
    max_steps: usize,
    more: Vec<Signals<'_>>,
) -> PyResult<PyDiagnosis> {
    let defaults = DiagnoseOptions::default();
    let order = parse_order(order, defaults.policy.max_order)?;
    if max_steps == 0 || max_steps > 4 {
        return Err(value_err(format!(
            "max_steps must be 1..=4, got {max_steps}"
        )));
    }
    let tr = record(
        &train.0,
        &train.1,
        input_names.clone(),
        output_name.clone(),
        sample_time,
    )?;
    let rec =
        |(u, y): &Signals<'_>| record(u, y, input_names.clone(), output_name.clone(), sample_time);
    let data = match (validate, more.is_empty()) {
        (Some(v), true) => {
            DiagnoseData::with_validation(tr, rec(&v)?).map_err(|e| value_err(e.to_string()))?
        }
        (None, true) => DiagnoseData::from_single(tr),
        (v, false) => {
            let mut recs = vec![("record 1".to_string(), tr)];
            for (i, m) in more.iter().enumerate() {
                recs.push((format!("record {}", i + 2), rec(m)?));
            }
            let v = v
                .map(|v| rec(&v).map(|r| ("validation".to_string(), r)))
                .transpose()?;
            DiagnoseData::from_records(recs, v).map_err(|e| value_err(e.to_string()))?
        }
    };
    let opts = DiagnoseOptions {
        order,
        max_steps,
        ..defaults
    };
    let diagnosis = py
        .detach(|| diagnose(&data, &opts, None))
        .map_err(|e| value_err(e.to_string()))?;
    Ok(PyDiagnosis { diagnosis, data })
}

#[pymethods]
impl PyDiagnosis {
    /// The report as the CLI's `--json` writes it.
    fn to_json(&self) -> PyResult<String> {
        serde_json::to_string_pretty(&self.diagnosis.report).map_err(|e| value_err(e.to_string()))
    }

    /// The report as `greybox diagnose` prints it.
    fn to_text(&self) -> String {
        self.diagnosis.report.to_text()
    }

    /// The accepted causes, in order.
    #[getter]
    fn causes(&self) -> Vec<&'static str> {
        self.diagnosis.report.cause_names()
    }

    /// The final (possibly extended) model: with one training record and
    /// no validation data, refitted on all of the record once the report
    /// block has scored it; with several training records, refitted on
    /// every record whole (when that refit is not worse over the data).
    #[getter]
    fn final_model(&self) -> PyModel {
        PyModel::new(self.diagnosis.to_save().clone(), vec![])
    }

    /// Split text of the data (fit, select and report blocks).
    fn split_text(&self) -> String {
        self.data.split_text()
    }

    /// Render the HTML report (the CLI's `--report`) and write it atomically.
    fn report_html(&self, py: Python<'_>, path: PathBuf, title: &str) -> PyResult<()> {
        let (d, data) = (&self.diagnosis, &self.data);
        let html = py
            .detach(|| gb_diagnose::render_html(d, data, title))
            .map_err(|e| value_err(e.to_string()))?;
        gb_core::write_atomic(&path, html.as_bytes()).map_err(py_err)
    }
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyDiagnosis>()?;
    m.add_function(wrap_pyfunction!(diagnose_records, m)?)?;
    Ok(())
}
