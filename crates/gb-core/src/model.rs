use crate::CoreError;

/// A dynamic model that can be run in **free-run simulation**: the output is
/// computed from the inputs alone, never from measured outputs (except the
/// first few, which may initialise the state).
pub trait Simulate {
    /// Number of input signals the model expects.
    fn n_inputs(&self) -> usize;

    /// Simulate the output for `inputs` (one `Vec` per input signal, all of the
    /// same length N). `init` holds measured outputs that may initialise the
    /// state: a model uses at most its own number of output lags from it and
    /// returns those samples unchanged; an empty `init` starts from rest at the
    /// model's operating point.
    fn simulate(&self, inputs: &[Vec<f64>], init: &[f64]) -> Result<Vec<f64>, CoreError>;
}

/// A fitted model: simulatable, describable, with a parameter count.
pub trait Model: Simulate {
    /// One-line human-readable description, e.g. `linear output-error, order 2`.
    fn describe(&self) -> String;
    /// Number of estimated parameters (for information criteria).
    fn n_parameters(&self) -> usize;
}
