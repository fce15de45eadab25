//! Regressors of a local model network with separate local-model space x and
//! partition space z (Nelles 2020, ch. 14.1 and 19.2).
//!
//! Both spaces are built from tapped delays of the output and of every input,
//! each signal with its own list of delays:
//!
//! x(k) = [y(k−i) for i in `x_output`, u_j(k−d) for d in `x_inputs[j]`]
//! z(k) = [y(k−i) for i in `z_output`, u_j(k−d) for d in `z_inputs[j]`]
//!
//! In the NARX (series-parallel) form y are the measured outputs, in the NOE
//! (parallel) form the model's own simulated outputs. A local model is a
//! polynomial of degree 1..=3 in x (all monomials), optionally plus
//! user-supplied columns e(k) that enter linearly (e.g. Preisach or other basis
//! terms from other crates):
//!
//! Lᵢ(k) = θᵢᵀ φ(k),  φ = [1, x, x_a x_b (a ≤ b), x_a x_b x_c, e].
use crate::LmnError;
use serde::{Deserialize, Serialize};

/// One record split for the regressors: the dynamic inputs, the output and
/// the user columns (the last `n_extra` input signals of a record). Internal:
/// the public API takes [`gb_core::Record`] / [`gb_core::Records`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Experiment<'a> {
    /// `inputs[j][k]`: input j at sample k.
    pub inputs: &'a [Vec<f64>],
    /// Measured output (for simulation, possibly only an init window).
    pub output: &'a [f64],
    /// User-supplied columns (at time k) entering the local models linearly.
    pub extra: &'a [Vec<f64>],
}

impl<'a> Experiment<'a> {
    /// Split `signals` into `n_inputs` dynamic inputs and the user columns
    /// after them (borrowed, no copy).
    pub fn split(
        signals: &'a [Vec<f64>],
        output: &'a [f64],
        n_inputs: usize,
        n_extra: usize,
    ) -> Result<Self, LmnError> {
        if signals.len() != n_inputs + n_extra {
            return Err(LmnError::Dimension(format!(
                "the structure has {n_inputs} inputs and {n_extra} user columns (the last input signals), the data has {} input signals",
                signals.len()
            )));
        }
        Ok(Self {
            inputs: &signals[..n_inputs],
            output,
            extra: &signals[n_inputs..],
        })
    }

    /// A record split for `spec`.
    pub fn of_record(r: &'a gb_core::Record, spec: &RegressorSpec) -> Result<Self, LmnError> {
        Self::split(&r.inputs, &r.output, spec.n_inputs(), spec.n_extra)
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.output.len()
    }
}

/// Which signal a tap reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Signal {
    /// The (measured or simulated) output.
    Output,
    /// Input j.
    Input(usize),
}

/// One tapped delay: `signal(k − delay)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Tap {
    /// The signal.
    pub signal: Signal,
    /// Delay in samples (≥ 1 for the output).
    pub delay: usize,
}

/// Regressor structure: per-signal delays of x and z, polynomial degree of the
/// local models and the number of user columns.
///
/// ```
/// use gb_lmn::RegressorSpec;
/// // x: y(k-1), y(k-2), u(k-1), u(k-2); z: y(k-1), u(k-1)
/// let r = RegressorSpec::arx(2, &[2], &[1]).with_z(vec![1], vec![vec![1]]);
/// assert_eq!((r.nx(), r.nz(), r.max_lag()), (4, 2, 2));
/// assert!(r.check().is_ok());
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RegressorSpec {
    /// Output delays in x.
    pub x_output: Vec<usize>,
    /// Delays of each input in x.
    pub x_inputs: Vec<Vec<usize>>,
    /// Output delays in z.
    pub z_output: Vec<usize>,
    /// Delays of each input in z.
    pub z_inputs: Vec<Vec<usize>>,
    /// Polynomial degree of the local models (1 = affine / ARX).
    pub degree: usize,
    /// Number of user columns in the local models.
    pub n_extra: usize,
}

impl RegressorSpec {
    /// ARX-type structure: output delays 1..=na, input j delays
    /// nk_j..nk_j+nb_j−1; z = x.
    pub fn arx(na: usize, nb: &[usize], nk: &[usize]) -> Self {
        let x_output: Vec<usize> = (1..=na).collect();
        let x_inputs: Vec<Vec<usize>> = nb
            .iter()
            .enumerate()
            .map(|(j, &b)| {
                let k = nk.get(j).copied().unwrap_or(1);
                (k..k + b).collect()
            })
            .collect();
        Self {
            z_output: x_output.clone(),
            z_inputs: x_inputs.clone(),
            x_output,
            x_inputs,
            degree: 1,
            n_extra: 0,
        }
    }

    /// Set the partition space delays.
    pub fn with_z(mut self, z_output: Vec<usize>, z_inputs: Vec<Vec<usize>>) -> Self {
        self.z_output = z_output;
        self.z_inputs = z_inputs;
        self
    }

    /// Set the polynomial degree of the local models.
    pub fn with_degree(mut self, degree: usize) -> Self {
        self.degree = degree;
        self
    }

    /// Set the number of user columns: the last `n_extra` input signals of
    /// every record enter the local models linearly at time k (not as
    /// tapped delays), e.g. Preisach or other basis terms computed by other
    /// crates.
    pub fn with_extra(mut self, n_extra: usize) -> Self {
        self.n_extra = n_extra;
        self
    }

    /// Number of (dynamic) inputs.
    pub fn n_inputs(&self) -> usize {
        self.x_inputs.len()
    }

    /// Number of input signals a record needs: the inputs, then the user
    /// columns.
    pub fn n_signals(&self) -> usize {
        self.n_inputs() + self.n_extra
    }

    /// Taps of x in order.
    pub fn x_taps(&self) -> Vec<Tap> {
        taps(&self.x_output, &self.x_inputs)
    }

    /// Taps of z in order.
    pub fn z_taps(&self) -> Vec<Tap> {
        taps(&self.z_output, &self.z_inputs)
    }

    /// Dimension of x.
    pub fn nx(&self) -> usize {
        self.x_output.len() + self.x_inputs.iter().map(Vec::len).sum::<usize>()
    }

    /// Dimension of z.
    pub fn nz(&self) -> usize {
        self.z_output.len() + self.z_inputs.iter().map(Vec::len).sum::<usize>()
    }

    /// Largest delay (samples needed before the first regressor row).
    pub fn max_lag(&self) -> usize {
        self.x_taps()
            .iter()
            .chain(self.z_taps().iter())
            .map(|t| t.delay)
            .max()
            .unwrap_or(0)
            .max(1)
    }

    /// Largest output delay (0: no output feedback, a NFIR model).
    pub fn max_output_lag(&self) -> usize {
        self.x_output
            .iter()
            .chain(&self.z_output)
            .copied()
            .max()
            .unwrap_or(0)
    }

    /// Monomials of degree ≥ 2 (indices into x).
    pub fn monomials(&self) -> Vec<Vec<usize>> {
        let nx = self.nx();
        let mut out = Vec::new();
        if self.degree >= 2 {
            for a in 0..nx {
                for b in a..nx {
                    out.push(vec![a, b]);
                }
            }
        }
        if self.degree >= 3 {
            for a in 0..nx {
                for b in a..nx {
                    for c in b..nx {
                        out.push(vec![a, b, c]);
                    }
                }
            }
        }
        out
    }

    /// Number of local parameters: 1 + nx + monomials + user columns.
    pub fn n_local(&self) -> usize {
        1 + self.nx() + self.monomials().len() + self.n_extra
    }

    /// Validate.
    pub fn check(&self) -> Result<(), LmnError> {
        if self.x_inputs.len() != self.z_inputs.len() {
            return Err(LmnError::InvalidArgument(format!(
                "x has delays for {} inputs, z for {}",
                self.x_inputs.len(),
                self.z_inputs.len()
            )));
        }
        if !(1..=3).contains(&self.degree) {
            return Err(LmnError::InvalidArgument(format!(
                "local model degree must be 1..=3, got {}",
                self.degree
            )));
        }
        if self.x_output.iter().chain(&self.z_output).any(|&d| d == 0) {
            return Err(LmnError::InvalidArgument(
                "output delays must be >= 1".into(),
            ));
        }
        if self.max_lag() > 1000 {
            return Err(LmnError::InvalidArgument("delays must be <= 1000".into()));
        }
        if self.nx() + self.n_extra == 0 {
            return Err(LmnError::InvalidArgument(
                "the local models have no regressors".into(),
            ));
        }
        if self.n_local() > 2000 {
            return Err(LmnError::InvalidArgument(format!(
                "{} local parameters (degree {} over {} regressors): too many",
                self.n_local(),
                self.degree,
                self.nx()
            )));
        }
        Ok(())
    }
}

fn taps(out: &[usize], inp: &[Vec<usize>]) -> Vec<Tap> {
    let mut v: Vec<Tap> = out
        .iter()
        .map(|&d| Tap {
            signal: Signal::Output,
            delay: d,
        })
        .collect();
    for (j, ds) in inp.iter().enumerate() {
        v.extend(ds.iter().map(|&d| Tap {
            signal: Signal::Input(j),
            delay: d,
        }));
    }
    v
}

/// Precomputed tap layout used by the hot loops.
#[derive(Debug, Clone)]
pub(crate) struct Layout {
    pub x: Vec<Tap>,
    pub z: Vec<Tap>,
    pub mono: Vec<Vec<usize>>,
    pub p: usize,
    pub max_lag: usize,
}

impl Layout {
    pub fn new(r: &RegressorSpec) -> Self {
        let mono = r.monomials();
        Self {
            x: r.x_taps(),
            z: r.z_taps(),
            p: 1 + r.nx() + mono.len() + r.n_extra,
            mono,
            max_lag: r.max_lag(),
        }
    }

    /// Fill x and z at time k with outputs from `y` (measured or simulated).
    #[inline]
    pub fn fill(&self, k: usize, y: &[f64], u: &[Vec<f64>], x: &mut [f64], z: &mut [f64]) {
        for (v, t) in x.iter_mut().zip(&self.x) {
            *v = match t.signal {
                Signal::Output => y[k - t.delay],
                Signal::Input(j) => u[j][k - t.delay],
            };
        }
        for (v, t) in z.iter_mut().zip(&self.z) {
            *v = match t.signal {
                Signal::Output => y[k - t.delay],
                Signal::Input(j) => u[j][k - t.delay],
            };
        }
    }

    /// Basis φ = [1, x, monomials, extra(k)].
    #[inline]
    pub fn basis(&self, x: &[f64], extra: &[Vec<f64>], k: usize, phi: &mut [f64]) {
        phi[0] = 1.0;
        let nx = x.len();
        phi[1..=nx].copy_from_slice(x);
        let c = 1 + nx;
        for (dst, m) in phi[c..].iter_mut().zip(&self.mono) {
            *dst = m.iter().map(|&i| x[i]).product();
        }
        let c = c + self.mono.len();
        for (dst, e) in phi[c..].iter_mut().zip(extra) {
            *dst = e[k];
        }
    }

    /// Add w·∂(θᵀφ)/∂x to `gx`.
    #[inline]
    pub fn add_local_grad(&self, theta: &[f64], x: &[f64], w: f64, gx: &mut [f64]) {
        let nx = x.len();
        for j in 0..nx {
            gx[j] += w * theta[1 + j];
        }
        for (m, th) in self.mono.iter().zip(&theta[1 + nx..]) {
            let t = th * w;
            if t == 0.0 {
                continue;
            }
            if m.len() == 2 {
                gx[m[0]] += t * x[m[1]];
                gx[m[1]] += t * x[m[0]];
            } else {
                gx[m[0]] += t * x[m[1]] * x[m[2]];
                gx[m[1]] += t * x[m[0]] * x[m[2]];
                gx[m[2]] += t * x[m[0]] * x[m[1]];
            }
        }
    }
}

/// Normalised signals of one experiment.
#[derive(Debug, Clone)]
pub(crate) struct NormExp {
    pub u: Vec<Vec<f64>>,
    pub y: Vec<f64>,
    pub e: Vec<Vec<f64>>,
}
