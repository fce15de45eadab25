//! Wavelet transforms and denoising on numpy arrays (the CLI's `wavelet`
//! and `denoise`).
use crate::{value_err, values};
use gb_wavelet::{Mode, ThresholdRule, Wavelet};
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::prelude::*;

fn setup(wavelet: &str, mode: &str) -> PyResult<(Wavelet, Mode)> {
    let w = Wavelet::new(wavelet).map_err(|e| value_err(format!("wavelet: {e}")))?;
    let m: Mode = mode.parse().map_err(|e| value_err(format!("mode: {e}")))?;
    Ok((w, m))
}

/// `[a_J, d_J, …, d₁]` like `pywt.wavedec`.
#[pyfunction]
#[pyo3(signature = (x, wavelet, level, mode))]
fn wavedec<'py>(
    py: Python<'py>,
    x: PyReadonlyArray1<'py, f64>,
    wavelet: &str,
    level: Option<usize>,
    mode: &str,
) -> PyResult<Vec<Bound<'py, PyArray1<f64>>>> {
    let (w, m) = setup(wavelet, mode)?;
    let x = values(&x, "x")?;
    if x.iter().any(|v| !v.is_finite()) {
        return Err(value_err("x contains NaN or infinity"));
    }
    let bands = gb_wavelet::wavedec(&x, &w, m, level).map_err(|e| value_err(e.to_string()))?;
    Ok(bands
        .into_iter()
        .map(|b| PyArray1::from_vec(py, b))
        .collect())
}

/// The signal of `[a_J, d_J, …, d₁]` like `pywt.waverec`.
#[pyfunction]
#[pyo3(signature = (coeffs, wavelet, mode))]
fn waverec<'py>(
    py: Python<'py>,
    coeffs: Vec<PyReadonlyArray1<'py, f64>>,
    wavelet: &str,
    mode: &str,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let (w, m) = setup(wavelet, mode)?;
    let c = coeffs
        .iter()
        .map(|a| values(a, "coefficients"))
        .collect::<PyResult<Vec<_>>>()?;
    let x = gb_wavelet::waverec(&c, &w, m).map_err(|e| value_err(e.to_string()))?;
    Ok(PyArray1::from_vec(py, x))
}

/// Wavelet denoising (soft thresholds by `threshold`); the signal and the
/// noise level used.
#[pyfunction]
#[pyo3(signature = (x, wavelet, threshold, mode))]
fn denoise<'py>(
    py: Python<'py>,
    x: PyReadonlyArray1<'py, f64>,
    wavelet: &str,
    threshold: &str,
    mode: &str,
) -> PyResult<(Bound<'py, PyArray1<f64>>, f64)> {
    let (w, m) = setup(wavelet, mode)?;
    let rule: ThresholdRule = threshold
        .parse()
        .map_err(|e| value_err(format!("threshold: {e}")))?;
    let x = values(&x, "x")?;
    let d = gb_wavelet::denoise_with(&x, &w, &gb_wavelet::DenoiseOptions::new(rule, m))
        .map_err(|e| value_err(e.to_string()))?;
    Ok((PyArray1::from_vec(py, d.signal), d.sigma))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(wavedec, m)?)?;
    m.add_function(wrap_pyfunction!(waverec, m)?)?;
    m.add_function(wrap_pyfunction!(denoise, m)?)?;
    Ok(())
}
