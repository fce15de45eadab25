//! Fitted models: fit (any registry recipe or a physics model file),
//! load, save, simulate, and step one sample at a time.
use crate::{py_err, record, value_err, values};
use gb_core::{DynamicModel, FittedModel, Init, ModelSpec, Records, Silent, Stepper};
use gb_model::physics::ModelFile;
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::prelude::*;
use std::mem::ManuallyDrop;
use std::path::PathBuf;

/// A fitted model of any class (the CLI's `.gbm` model), with the notes of
/// its fit.
#[pyclass(name = "_Model", module = "greybox._greybox", frozen)]
pub struct PyModel {
    pub(crate) model: FittedModel,
    notes: Vec<String>,
}

impl PyModel {
    pub(crate) fn new(model: FittedModel, notes: Vec<String>) -> Self {
        Self { model, notes }
    }
}

/// How a simulation starts: `"stored"` (as `greybox simulate` without
/// `--init-window`), `"rest"`, `"window"` (an init window of measured
/// outputs, as `--init-window N`) or `"state"`.
fn init_of<'a>(kind: &str, values: &'a [f64]) -> PyResult<Init<'a>> {
    Ok(match kind {
        "stored" => Init::Stored,
        "rest" => Init::Rest,
        "window" => Init::Window(values),
        "history" => Init::History(values),
        "state" => Init::State(values),
        other => {
            return Err(value_err(format!(
                "init must be stored, rest, window, history or state, got '{other}'"
            )))
        }
    })
}

#[pymethods]
impl PyModel {
    /// Free-run simulation of the input columns; `init_kind` says how it
    /// starts (see `init_of`), `init_values` are its measured outputs or
    /// state. Returns the outputs output-major (`n_outputs · N` values).
    #[pyo3(signature = (inputs, init_kind="stored", init_values=None))]
    fn simulate<'py>(
        &self,
        py: Python<'py>,
        inputs: Vec<PyReadonlyArray1<'py, f64>>,
        init_kind: &str,
        init_values: Option<PyReadonlyArray1<'py, f64>>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let u = inputs
            .iter()
            .map(|a| values(a, "input"))
            .collect::<PyResult<Vec<_>>>()?;
        if u.iter().flatten().any(|v| !v.is_finite()) {
            return Err(value_err("signals contain NaN or infinity"));
        }
        let w = match &init_values {
            Some(a) => values(a, "init")?,
            None => vec![],
        };
        let n = u.first().map_or(0, Vec::len);
        if kind_needs_values(init_kind) && w.len() > n {
            return Err(value_err(format!(
                "the init window of {} samples exceeds the {n} samples of the inputs",
                w.len()
            )));
        }
        let init = init_of(init_kind, &w)?;
        let model = &self.model;
        let y = py.detach(|| model.simulate(&u, init)).map_err(py_err)?;
        Ok(PyArray1::from_vec(py, y))
    }

    /// A stepper for online use from rest or from `state` (an output
    /// history for input–output models, a state for state-space models).
    #[pyo3(signature = (state=None))]
    fn stepper(&self, state: Option<PyReadonlyArray1<'_, f64>>) -> PyResult<PyStepper> {
        let s = match &state {
            Some(a) => Some(values(a, "state")?),
            None => None,
        };
        PyStepper::new(&self.model, s.as_deref())
    }

    /// Write the model file (the CLI's format) atomically.
    fn save(&self, path: PathBuf) -> PyResult<()> {
        self.model.save(&path).map_err(py_err)
    }

    /// `"<dynamics>, <noise> noise"`.
    fn describe(&self) -> String {
        self.model.describe()
    }

    /// The registry's class tag.
    #[getter]
    fn class_name(&self) -> &'static str {
        self.model.dynamics.class()
    }

    #[getter]
    fn input_names(&self) -> Vec<String> {
        self.model.input_names.clone()
    }

    #[getter]
    fn output_names(&self) -> Vec<String> {
        self.model.output_names.clone()
    }

    #[getter]
    fn sample_time(&self) -> Option<f64> {
        self.model.sample_time
    }

    #[getter]
    fn n_parameters(&self) -> usize {
        self.model.dynamics.n_parameters()
    }

    #[getter]
    fn n_states(&self) -> usize {
        self.model.dynamics.n_states()
    }

    #[getter]
    fn history_len(&self) -> usize {
        self.model.dynamics.history_len()
    }

    #[getter]
    fn notes(&self) -> Vec<String> {
        self.notes.clone()
    }
}

fn kind_needs_values(kind: &str) -> bool {
    matches!(kind, "window" | "history")
}

/// A model running one sample at a time. It owns a copy of the model's
/// dynamics, which its stepper borrows.
#[pyclass(name = "_Stepper", module = "greybox._greybox", unsendable)]
pub struct PyStepper {
    stepper: ManuallyDrop<Box<dyn Stepper + 'static>>,
    dynamics: *mut dyn DynamicModel,
    n_inputs: usize,
    n_outputs: usize,
}

impl PyStepper {
    fn new(model: &FittedModel, state: Option<&[f64]>) -> PyResult<Self> {
        let dynamics: *mut dyn DynamicModel = Box::into_raw(model.dynamics.clone_box());
        // SAFETY: `dynamics` is a heap allocation owned by this value, never
        // moved or mutated, and freed in `drop` only after the stepper that
        // borrows it.
        let borrowed: &'static dyn DynamicModel = unsafe { &*dynamics };
        let init = state.map_or(Init::Rest, Init::State);
        match borrowed.stepper(init) {
            Ok(stepper) => Ok(Self {
                stepper: ManuallyDrop::new(stepper),
                dynamics,
                n_inputs: borrowed.n_inputs(),
                n_outputs: borrowed.n_outputs(),
            }),
            Err(e) => {
                // SAFETY: nothing borrows `dynamics` any more.
                drop(unsafe { Box::from_raw(dynamics) });
                Err(py_err(e))
            }
        }
    }
}

impl Drop for PyStepper {
    fn drop(&mut self) {
        // SAFETY: the stepper goes first, then the dynamics it borrowed;
        // neither is used again.
        unsafe {
            ManuallyDrop::drop(&mut self.stepper);
            drop(Box::from_raw(self.dynamics));
        }
    }
}

#[pymethods]
impl PyStepper {
    /// Advance one sample with one value per input; the outputs.
    fn step(&mut self, u: Vec<f64>) -> PyResult<Vec<f64>> {
        if u.len() != self.n_inputs {
            return Err(value_err(format!(
                "the model has {} inputs, {} values were given",
                self.n_inputs,
                u.len()
            )));
        }
        if u.iter().any(|v| !v.is_finite()) {
            return Err(value_err("signals contain NaN or infinity"));
        }
        let mut y = vec![0.0; self.n_outputs];
        self.stepper.step(&u, &mut y).map_err(py_err)?;
        Ok(y)
    }
}

/// Fit the registry recipe `spec` (the CLI's `--model SPEC`) on one record.
#[pyfunction]
#[pyo3(signature = (inputs, output, input_names, output_name, sample_time, spec))]
fn fit(
    py: Python<'_>,
    inputs: Vec<PyReadonlyArray1<'_, f64>>,
    output: PyReadonlyArray1<'_, f64>,
    input_names: Vec<String>,
    output_name: String,
    sample_time: Option<f64>,
    spec: &str,
) -> PyResult<PyModel> {
    let spec: ModelSpec = spec.parse().map_err(py_err)?;
    gb_model::recipes::check_spec(&spec).map_err(py_err)?;
    let r = record(&inputs, &output, input_names, output_name, sample_time)?;
    let data = Records::new(vec![r]).map_err(py_err)?;
    let fitted = py
        .detach(|| gb_model::recipes::fit(&spec, &data, &Silent))
        .map_err(py_err)?;
    Ok(PyModel::new(fitted.model, fitted.notes))
}

/// Fit the physics model of a TOML model file; the signal names default to
/// the file's.
#[pyfunction]
#[pyo3(signature = (path, inputs, output, input_names, output_name, sample_time))]
fn fit_model_file(
    py: Python<'_>,
    path: PathBuf,
    inputs: Vec<PyReadonlyArray1<'_, f64>>,
    output: PyReadonlyArray1<'_, f64>,
    input_names: Option<Vec<String>>,
    output_name: Option<String>,
    sample_time: Option<f64>,
) -> PyResult<PyModel> {
    let file = ModelFile::read(&path).map_err(|e| value_err(e.to_string()))?;
    let input_names = input_names.unwrap_or_else(|| file.spec.inputs.clone());
    let output_name = output_name
        .or_else(|| file.spec.outputs.first().map(|o| o.name.clone()))
        .unwrap_or_else(|| "y".into());
    let r = record(&inputs, &output, input_names, output_name, sample_time)?;
    let data = Records::new(vec![r]).map_err(py_err)?;
    let fitted = py
        .detach(|| file.fit(&data, &Silent).map_err(|e| e.to_string()))
        .map_err(value_err)?;
    let notes = fitted.fit_report().map(|f| f.lines()).unwrap_or_default();
    let model = fitted.to_fitted().map_err(|e| value_err(e.to_string()))?;
    Ok(PyModel::new(model, notes))
}

/// Read a model file of any class (the CLI's `.gbm`).
#[pyfunction]
fn load(path: PathBuf) -> PyResult<PyModel> {
    let m = gb_model::registry::load(&path).map_err(py_err)?;
    Ok(PyModel::new(m, vec![]))
}

/// The recipes and their options (`greybox fit --help`).
#[pyfunction]
fn recipes_help() -> String {
    gb_model::recipes::help()
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyModel>()?;
    m.add_class::<PyStepper>()?;
    m.add_function(wrap_pyfunction!(fit, m)?)?;
    m.add_function(wrap_pyfunction!(fit_model_file, m)?)?;
    m.add_function(wrap_pyfunction!(load, m)?)?;
    m.add_function(wrap_pyfunction!(recipes_help, m)?)?;
    Ok(())
}
