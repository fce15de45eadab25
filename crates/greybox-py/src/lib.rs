//! The compiled core of the `greybox` Python package (`greybox._greybox`).
//!
//! The Python layer (`python/greybox/`) turns numpy arrays, lists and
//! pandas columns into contiguous float64 columns and calls the functions
//! here, which make the same library calls as the CLI, so results are
//! identical. Every error is a Python exception (`ValueError`, `OSError`)
//! carrying the CLI's message; long fits release the GIL.
use gb_core::{CoreError, Record};
use numpy::PyReadonlyArray1;
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;

mod diagnosis;
mod model;
mod wavelet;

/// A Python exception for a greybox error: `OSError` for I/O, else
/// `ValueError`, with the message the CLI prints.
pub(crate) fn py_err(e: CoreError) -> PyErr {
    match e {
        CoreError::Io { .. } => PyOSError::new_err(e.to_string()),
        e => PyValueError::new_err(e.to_string()),
    }
}

/// A `ValueError` with `message`.
pub(crate) fn value_err(message: impl Into<String>) -> PyErr {
    PyValueError::new_err(message.into())
}

/// The values of a contiguous float64 array.
pub(crate) fn values(a: &PyReadonlyArray1<'_, f64>, what: &str) -> PyResult<Vec<f64>> {
    a.as_slice()
        .map(<[f64]>::to_vec)
        .map_err(|e| value_err(format!("{what}: {e}")))
}

/// A record of named input columns and an output (checked by
/// [`Record::new`]: equal lengths, finite values).
pub(crate) fn record(
    inputs: &[PyReadonlyArray1<'_, f64>],
    output: &PyReadonlyArray1<'_, f64>,
    input_names: Vec<String>,
    output_name: String,
    sample_time: Option<f64>,
) -> PyResult<Record> {
    let u = inputs
        .iter()
        .map(|a| values(a, "input"))
        .collect::<PyResult<Vec<_>>>()?;
    let y = values(output, "output")?;
    let mut r = Record::new(input_names, output_name, u, y).map_err(py_err)?;
    if let Some(ts) = sample_time {
        if !(ts > 0.0 && ts.is_finite()) {
            return Err(value_err(format!(
                "sample_time must be positive and finite, got {ts}"
            )));
        }
        r = r.with_sample_time(ts);
    }
    Ok(r)
}

/// The extension module.
#[pymodule]
fn _greybox(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    model::register(m)?;
    diagnosis::register(m)?;
    wavelet::register(m)?;
    Ok(())
}
