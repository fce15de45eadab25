//! An integrating model: a model of any class simulates the increments
//! Δy(k) = y(k) − y(k−1) of the output, and the output is their running
//! sum (a pole at 1 in front of any dynamics). For integrating plants
//! (force → position) whose output drifts like a random walk, which an
//! output-error model kept stable cannot follow.
//!
//! Starting a simulation: with an init window the increments model
//! estimates its state from the window's increments and the level is the
//! least-squares offset of the summed simulation to the window; with a
//! history the level is anchored at the last history sample; at rest the
//! level is 0; an explicit state is `[level, inner state…]`.
use gb_core::{check_inputs, CoreError, DynamicModel, Init, ModelView, Stepper, Workspace};
use serde::{Deserialize, Serialize};
use std::any::Any;

/// Tag of the class in model files.
pub const INTEGRATING_CLASS: &str = "integrating";

/// A model of the increments of the output, summed (see the module docs).
#[derive(Debug, Clone)]
pub struct IntegratingModel {
    inner: Box<dyn DynamicModel>,
}

#[derive(Serialize, Deserialize)]
struct Body {
    class: String,
    class_version: u32,
    body: Vec<u8>,
}

/// The increments of `y` (Δy(0) = Δy(1): same length, same alignment).
pub fn output_increments(y: &[f64]) -> Vec<f64> {
    let mut d: Vec<f64> = (0..y.len())
        .map(|k| if k == 0 { 0.0 } else { y[k] - y[k - 1] })
        .collect();
    if d.len() > 1 {
        d[0] = d[1];
    }
    d
}

impl IntegratingModel {
    /// Integrate the output of `inner` (a one-output model of the increments).
    pub fn new(inner: Box<dyn DynamicModel>) -> Result<Self, CoreError> {
        if inner.n_outputs() != 1 {
            return Err(CoreError::InvalidArgument(
                "an integrating model integrates one output".into(),
            ));
        }
        if inner.class() == INTEGRATING_CLASS {
            return Err(CoreError::InvalidArgument(
                "an integrating model of an integrating model".into(),
            ));
        }
        Ok(Self { inner })
    }

    /// The model of the increments.
    pub fn inner(&self) -> &dyn DynamicModel {
        self.inner.as_ref()
    }

    /// Decode a model-file body of class `integrating` (the inner model is
    /// decoded through the registry).
    pub fn decode(body: &[u8], version: u32) -> Result<Self, CoreError> {
        let b: Body = gb_core::decode_postcard(INTEGRATING_CLASS, version, 1, body)?;
        let inner = crate::registry::decode_part(
            INTEGRATING_CLASS,
            "of an unknown class",
            (&b.class, b.class_version, &b.body),
        )?;
        Self::new(inner)
    }
}

/// Running sum of the increments `d`: `y(0) = level`, `y(k) = y(k−1) + d(k)`.
fn summed(d: &[f64], level: f64, y: &mut [f64]) {
    let mut acc = level;
    for (k, v) in d.iter().enumerate() {
        if k > 0 {
            acc += v;
        }
        y[k] = acc;
    }
}

impl DynamicModel for IntegratingModel {
    fn class(&self) -> &'static str {
        INTEGRATING_CLASS
    }
    fn n_inputs(&self) -> usize {
        self.inner.n_inputs()
    }
    fn n_states(&self) -> usize {
        1 + self.inner.n_states()
    }
    fn history_len(&self) -> usize {
        1 + self.inner.history_len()
    }
    fn integrates(&self) -> bool {
        true
    }
    fn describe(&self) -> String {
        format!(
            "integrating (pole at 1): the increments by a {}",
            self.inner.describe()
        )
    }
    fn n_parameters(&self) -> usize {
        self.inner.n_parameters()
    }
    fn simulate_into(
        &self,
        u: &[Vec<f64>],
        init: Init<'_>,
        y: &mut [f64],
        ws: &mut Workspace,
    ) -> Result<(), CoreError> {
        check_inputs(self.n_inputs(), u)?;
        let n = u.first().map_or(0, Vec::len);
        if y.len() != n {
            return Err(CoreError::Dimension(format!(
                "output buffer of {} samples for a simulation of {n}",
                y.len()
            )));
        }
        let mut d = vec![0.0; n];
        let anchor: Option<(&[f64], bool)> = match init {
            Init::Window(w) => {
                let dw = output_increments(w);
                self.inner.simulate_into(u, Init::Window(&dw), &mut d, ws)?;
                Some((w, true))
            }
            Init::History(h) => {
                let dh = output_increments(h);
                self.inner
                    .simulate_into(u, Init::History(&dh), &mut d, ws)?;
                Some((h, false))
            }
            Init::State(x) => {
                if x.len() != self.n_states() {
                    return Err(CoreError::Dimension(format!(
                        "{} state values for a model with {} states",
                        x.len(),
                        self.n_states()
                    )));
                }
                self.inner
                    .simulate_into(u, Init::State(&x[1..]), &mut d, ws)?;
                summed(&d, x[0], y);
                return Ok(());
            }
            other => {
                self.inner.simulate_into(u, other, &mut d, ws)?;
                None
            }
        };
        summed(&d, 0.0, y);
        if let Some((m, window)) = anchor {
            let m = &m[..m.len().min(n)];
            let level = if m.is_empty() {
                0.0
            } else if window {
                // least-squares offset over the window
                m.iter().zip(y.iter()).map(|(a, b)| a - b).sum::<f64>() / m.len() as f64
            } else {
                m[m.len() - 1] - y[m.len() - 1]
            };
            y.iter_mut().for_each(|v| *v += level);
        }
        Ok(())
    }
    fn stepper(&self, init: Init<'_>) -> Result<Box<dyn Stepper + '_>, CoreError> {
        let (level, inner) = match init {
            Init::State(x) if x.len() == self.n_states() => {
                (x[0], self.inner.stepper(Init::State(&x[1..]))?)
            }
            Init::Rest | Init::Stored => (0.0, self.inner.stepper(init)?),
            _ => {
                return Err(CoreError::Unsupported(
                    "an integrating model steps from rest, stored or an explicit state".into(),
                ))
            }
        };
        Ok(Box::new(SumStepper {
            inner,
            acc: level,
            first: true,
        }))
    }
    fn encode(&self) -> Result<Vec<u8>, CoreError> {
        let b = Body {
            class: self.inner.class().to_string(),
            class_version: self.inner.class_version(),
            body: self.inner.encode()?,
        };
        postcard::to_allocvec(&b)
            .map_err(|e| CoreError::ModelFile(format!("cannot encode model: {e}")))
    }
    fn views(&self, input_names: &[String], output_names: &[String]) -> Vec<ModelView> {
        self.inner.views(input_names, output_names)
    }
    fn clone_box(&self) -> Box<dyn DynamicModel> {
        Box::new(self.clone())
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

struct SumStepper<'a> {
    inner: Box<dyn Stepper + 'a>,
    acc: f64,
    first: bool,
}

impl Stepper for SumStepper<'_> {
    fn step(&mut self, u: &[f64], y: &mut [f64]) -> Result<(), CoreError> {
        let mut d = [0.0];
        self.inner.step(u, &mut d)?;
        if !self.first {
            self.acc += d[0];
        }
        self.first = false;
        y[0] = self.acc;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::SparseStateSpace;

    fn inner() -> Box<dyn DynamicModel> {
        // x⁺ = 0.5 x + u, y = x: the increments
        Box::new(SparseStateSpace::linear(vec![0.5], vec![1.0], vec![1.0], vec![0.0]).unwrap())
    }

    #[test]
    fn it_sums_the_increments_and_reads_back_through_the_registry() {
        let m = IntegratingModel::new(inner()).unwrap();
        let u = vec![vec![1.0, 0.0, -1.0, 2.0, 0.5, 0.0]];
        let d = inner().simulate(&u, Init::Rest).unwrap();
        let y = m.simulate(&u, Init::Rest).unwrap();
        // y(k) = Σ_{1..k} Δ, from 0
        let mut acc = 0.0;
        for k in 0..u[0].len() {
            if k > 0 {
                acc += d[k];
            }
            assert!((y[k] - acc).abs() < 1e-12, "{k}");
        }
        let s = m.simulate(&u, Init::State(&[3.0, 0.0])).unwrap();
        assert!((s[4] - (3.0 + y[4])).abs() < 1e-12);
        let fm = gb_core::FittedModel::new(
            vec!["u".into()],
            vec!["y".into()],
            Box::new(m),
            gb_core::NoiseModel::Gaussian { sd: 0.1 },
        )
        .unwrap();
        let back = crate::registry::from_bytes(&fm.to_bytes().unwrap(), "m.gbm").unwrap();
        assert_eq!(back.dynamics.class(), "integrating");
        assert_eq!(back.simulate(&u, Init::Rest).unwrap(), y);
        assert!(back.describe().contains("integrating (pole at 1)"));
    }

    #[test]
    fn an_init_window_sets_the_level() {
        let m = IntegratingModel::new(inner()).unwrap();
        let u = vec![vec![0.0; 40]];
        // no input, a constant window: the level is the window's
        let w = [5.0; 6];
        let y = m.simulate(&u, Init::Window(&w)).unwrap();
        assert!(y.iter().all(|v| (v - 5.0).abs() < 1e-9), "{y:?}");
        let h = m.simulate(&u, Init::History(&[1.0, 2.0])).unwrap();
        assert!((h[1] - 2.0).abs() < 1e-9);
        assert!(IntegratingModel::new(Box::new(m.clone())).is_err());
    }
}
