//! The vocabulary every model class shares: [`DynamicModel`] (simulate,
//! step, describe, encode), [`Init`] (how a simulation starts), [`Identify`]
//! (fit validated parameters to records) and [`ModelView`] (data a report
//! can draw). Crates implement these; consumers (the diagnosis, the CLI, the
//! benchmarks, the reports) use nothing else.
use crate::observe::Observer;
use crate::{CoreError, Records};
use std::any::Any;
use std::fmt::Debug;

/// How a free-run simulation starts.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub enum Init<'a> {
    /// At rest: the zero state, a zero output history.
    Rest,
    /// The first `y.len()` outputs are these measurements: input–output
    /// models take them as their output history (and return them
    /// unchanged); state-space models estimate their state from them.
    History(&'a [f64]),
    /// An init window of measured outputs: the model estimates its initial
    /// state from them as well as it can (the benchmark convention); the
    /// window's samples are not meant to be scored.
    Window(&'a [f64]),
    /// The start the model stores: the initial state a state-space model
    /// was fitted with, the training operating point of an input–output
    /// model; [`Init::Rest`] for classes that store none.
    Stored,
    /// An explicit initial state in the model's own coordinates
    /// ([`DynamicModel::n_states`] values).
    State(&'a [f64]),
    /// Periodic steady state: the input is one period of a periodic signal.
    /// [`DynamicModel::simulate`] repeats it `periods` times from rest and
    /// returns the last period; implementations of
    /// [`DynamicModel::simulate_into`] never see this variant.
    Periodic {
        /// Periods simulated (at least 2).
        periods: usize,
    },
}

/// Scratch memory a simulation may use (allocated by the caller, reused
/// across calls).
#[derive(Debug, Clone, Default)]
pub struct Workspace {
    buf: Vec<f64>,
}

impl Workspace {
    /// A zeroed slice of `len` values (grows the buffer when needed).
    pub fn take(&mut self, len: usize) -> &mut [f64] {
        if self.buf.len() < len {
            self.buf.resize(len, 0.0);
        }
        let s = &mut self.buf[..len];
        s.fill(0.0);
        s
    }
}

/// A model running one sample at a time (online use). Stepping through a
/// record gives the same outputs as [`DynamicModel::simulate`].
pub trait Stepper {
    /// Advance one sample with the inputs `u` (one value per input) and
    /// write the outputs (one per output) into `y`.
    fn step(&mut self, u: &[f64], y: &mut [f64]) -> Result<(), CoreError>;
}

/// Data a report can draw for a model (its structure: a partition, a
/// density, a nonlinear term), independent of any plotting library.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelView {
    /// Short machine name, unique per model (`partition`, `preisach-density`).
    pub key: String,
    /// Title above the plot.
    pub title: String,
    /// One or two sentences saying how to read it.
    pub caption: String,
    /// What to draw.
    pub data: ViewData,
}

/// The drawable content of a [`ModelView`].
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum ViewData {
    /// Rectangular cells `[x0, y0, x1, y1, value]`: a heat map (signed
    /// values on a diverging scale, red positive, blue negative) or, with
    /// `outline`, a partition drawn as cell borders.
    Cells {
        /// Label of the horizontal axis.
        x_label: String,
        /// Label of the vertical axis.
        y_label: String,
        /// The cells.
        cells: Vec<[f64; 5]>,
        /// Draw borders only (a partition) instead of filled values.
        outline: bool,
    },
    /// Curves `y(x)`.
    Curves {
        /// Label of the horizontal axis.
        x_label: String,
        /// Label of the vertical axis.
        y_label: String,
        /// The series.
        series: Vec<Series>,
        /// Logarithmic vertical axis.
        log_y: bool,
    },
    /// A table of text.
    Table {
        /// Column names.
        header: Vec<String>,
        /// Rows.
        rows: Vec<Vec<String>>,
    },
}

/// One series of a [`ViewData::Curves`].
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Legend name.
    pub name: String,
    /// Points `(x, y)`.
    pub points: Vec<(f64, f64)>,
    /// Draw as markers rather than a line.
    pub markers: bool,
}

/// A fitted dynamic model of any class: the one interface of simulation.
///
/// Inputs are passed as one slice per input signal, all of the same length
/// N; outputs are written output-major (`y[o * N + k]`), so a one-output
/// model writes a plain length-N slice.
pub trait DynamicModel: Debug + Send + Sync {
    /// The class tag under which the model registry knows this class (also
    /// stored in model files), e.g. `"io-network"`.
    fn class(&self) -> &'static str;

    /// Version of this class's encoding ([`encode`](Self::encode)); bump it
    /// whenever the encoded layout changes.
    fn class_version(&self) -> u32 {
        1
    }

    /// Number of input signals.
    fn n_inputs(&self) -> usize;

    /// Number of output signals.
    fn n_outputs(&self) -> usize {
        1
    }

    /// Number of states (for [`Init::State`]); for input–output models, the
    /// length of the output history they use.
    fn n_states(&self) -> usize;

    /// Leading samples an input–output model takes from the measured output
    /// as history ([`Init::History`]); 0 for state-space models.
    fn history_len(&self) -> usize {
        0
    }

    /// Whether the model integrates: an output is the running sum (the
    /// integral) of a signal that does not depend on it — a pole at 1 in
    /// discrete time, at 0 in continuous time (force → position). Its
    /// simulation error drifts like a random walk, so a later block is met
    /// from a fresh start rather than simulated on. `false` by default.
    fn integrates(&self) -> bool {
        false
    }

    /// One-line description, e.g. `linear output-error, order 2`.
    fn describe(&self) -> String;

    /// Number of estimated parameters (for information criteria).
    fn n_parameters(&self) -> usize;

    /// Free-run simulation of `u` (each of length N) into `y`
    /// (`n_outputs · N` values), starting as `init` says.
    fn simulate_into(
        &self,
        u: &[Vec<f64>],
        init: Init<'_>,
        y: &mut [f64],
        ws: &mut Workspace,
    ) -> Result<(), CoreError>;

    /// Free-run simulation (allocating), resolving [`Init::Periodic`].
    fn simulate(&self, u: &[Vec<f64>], init: Init<'_>) -> Result<Vec<f64>, CoreError> {
        check_inputs(self.n_inputs(), u)?;
        let n = u.first().map_or(0, Vec::len);
        let mut ws = Workspace::default();
        if let Init::Periodic { periods } = init {
            let p = periods.max(2);
            let long: Vec<Vec<f64>> = u.iter().map(|s| s.repeat(p)).collect();
            let mut y = vec![0.0; self.n_outputs() * n * p];
            self.simulate_into(&long, Init::Rest, &mut y, &mut ws)?;
            let mut out = Vec::with_capacity(self.n_outputs() * n);
            for o in 0..self.n_outputs() {
                let base = o * n * p + (p - 1) * n;
                out.extend_from_slice(&y[base..base + n]);
            }
            return Ok(out);
        }
        let mut y = vec![0.0; self.n_outputs() * n];
        self.simulate_into(u, init, &mut y, &mut ws)?;
        Ok(y)
    }

    /// A stepper for online use, starting as `init` says (only
    /// [`Init::Rest`] and [`Init::State`] need be supported).
    fn stepper(&self, init: Init<'_>) -> Result<Box<dyn Stepper + '_>, CoreError> {
        let _ = init;
        Err(CoreError::Unsupported(format!(
            "{}: stepping one sample at a time is not implemented for this class",
            self.class()
        )))
    }

    /// The model's parameters encoded for a model file (postcard).
    fn encode(&self) -> Result<Vec<u8>, CoreError>;

    /// Data a report can draw (partition, densities, wavelet terms);
    /// the names label the axes.
    fn views(&self, input_names: &[String], output_names: &[String]) -> Vec<ModelView> {
        let _ = (input_names, output_names);
        vec![]
    }

    /// A boxed copy.
    fn clone_box(&self) -> Box<dyn DynamicModel>;

    /// The concrete type (for warm starts of the same class).
    fn as_any(&self) -> &dyn Any;
}

impl Clone for Box<dyn DynamicModel> {
    fn clone(&self) -> Self {
        self.clone_box()
    }
}

/// Check that `u` holds `n_inputs` signals of one length.
pub fn check_inputs(n_inputs: usize, u: &[Vec<f64>]) -> Result<(), CoreError> {
    if u.len() != n_inputs {
        return Err(CoreError::Dimension(format!(
            "the model has {n_inputs} inputs, {} signals were given",
            u.len()
        )));
    }
    if let Some(first) = u.first() {
        if u.iter().any(|s| s.len() != first.len()) {
            return Err(CoreError::Dimension(
                "input signals of different lengths".into(),
            ));
        }
    }
    Ok(())
}

/// Identification of a model class from records (linfa's `Fit`): implemented
/// by the *validated* parameters of a class, which a `check()` on its
/// parameter builder returns.
pub trait Identify {
    /// The fitted model.
    type Model: DynamicModel;
    /// The class's error.
    type Error: std::error::Error + Send + Sync + 'static;
    /// Fit to `data` (every record a separate experiment; no regressor spans
    /// two records), reporting progress to `observer`.
    fn identify(&self, data: &Records, observer: &dyn Observer)
        -> Result<Self::Model, Self::Error>;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// y(k) = a·y(k−1) + u(k−1): the smallest model to exercise the trait.
    #[derive(Debug, Clone)]
    struct Ar1 {
        a: f64,
    }
    impl DynamicModel for Ar1 {
        fn class(&self) -> &'static str {
            "test-ar1"
        }
        fn n_inputs(&self) -> usize {
            1
        }
        fn n_states(&self) -> usize {
            1
        }
        fn history_len(&self) -> usize {
            1
        }
        fn describe(&self) -> String {
            format!("ar1 a={}", self.a)
        }
        fn n_parameters(&self) -> usize {
            1
        }
        fn simulate_into(
            &self,
            u: &[Vec<f64>],
            init: Init<'_>,
            y: &mut [f64],
            _: &mut Workspace,
        ) -> Result<(), CoreError> {
            let mut s = match init {
                Init::State(x) | Init::History(x) | Init::Window(x) => {
                    x.first().copied().unwrap_or(0.0)
                }
                _ => 0.0,
            };
            for (k, yk) in y.iter_mut().enumerate() {
                *yk = s;
                s = self.a * s + u[0][k];
            }
            Ok(())
        }
        fn encode(&self) -> Result<Vec<u8>, CoreError> {
            Ok(self.a.to_le_bytes().to_vec())
        }
        fn clone_box(&self) -> Box<dyn DynamicModel> {
            Box::new(self.clone())
        }
        fn as_any(&self) -> &dyn Any {
            self
        }
    }

    #[test]
    fn periodic_start_reaches_the_steady_state() {
        let m = Ar1 { a: 0.5 };
        // one period of a square wave; the steady state of y(k)=0.5y(k-1)+u(k-1)
        let u = vec![vec![1.0, 1.0, -1.0, -1.0]];
        let y = m.simulate(&u, Init::Periodic { periods: 60 }).unwrap();
        // periodic solution: y₀ = 0.5⁴ y₀ + (0.5³ + 0.5² − 0.5 − 1) ⇒ closed form
        let y0 = (0.125 + 0.25 - 0.5 - 1.0) / (1.0 - 0.0625);
        assert!((y[0] - y0).abs() < 1e-12, "{} vs {y0}", y[0]);
        let y1 = 0.5 * y0 + 1.0;
        assert!((y[1] - y1).abs() < 1e-12);
        // from rest the first sample is 0, not the periodic value
        let r = m.simulate(&u, Init::Rest).unwrap();
        assert_eq!(r[0], 0.0);
    }

    #[test]
    fn wrong_inputs_and_unsupported_stepping_are_errors() {
        let m = Ar1 { a: 0.5 };
        assert!(m.simulate(&[vec![1.0], vec![2.0]], Init::Rest).is_err());
        let e = m.stepper(Init::Rest).err().unwrap().to_string();
        assert!(e.contains("test-ar1"), "{e}");
        let b: Box<dyn DynamicModel> = Box::new(m);
        let c = b.clone();
        assert_eq!(c.describe(), "ar1 a=0.5");
        assert!(c.as_any().downcast_ref::<Ar1>().is_some());
    }
}
