//! A model of several outputs: a stack of one-output (MISO) models, one per
//! output, sharing the inputs. No part sees another output (a measured
//! output is never an input of another), so each part is fitted, stepped and
//! diagnosed on its own.
//!
//! Starting a simulation: [`Init::History`] and [`Init::Window`] hold the
//! measured outputs output-major (the same number of samples of each
//! output); [`Init::State`] the parts' states one after the other; the other
//! starts go to every part unchanged.
use crate::registry::StoredPart;
use gb_core::{
    check_inputs, CoreError, DynamicModel, Init, ModelView, NoiseModel, Stepper, Workspace,
};
use serde::{Deserialize, Serialize};
use std::any::Any;

/// Tag of the class in model files.
pub const MULTI_OUTPUT_CLASS: &str = "multi-output";

/// One one-output model per output, sharing the inputs (see the module docs).
#[derive(Debug, Clone)]
pub struct MultiOutputModel {
    parts: Vec<Box<dyn DynamicModel>>,
    noise: Vec<NoiseModel>,
}

#[derive(Serialize, Deserialize)]
struct Part {
    model: StoredPart,
    noise: NoiseModel,
}

impl MultiOutputModel {
    /// Stack `parts` (one-output models of the same inputs), each with the
    /// noise model of its output error.
    pub fn new(parts: Vec<(Box<dyn DynamicModel>, NoiseModel)>) -> Result<Self, CoreError> {
        let bad = |m: String| Err(CoreError::InvalidArgument(m));
        let Some(first) = parts.first() else {
            return bad("a multi-output model needs at least one output".into());
        };
        let ni = first.0.n_inputs();
        for (o, (p, noise)) in parts.iter().enumerate() {
            if p.n_outputs() != 1 || p.class() == MULTI_OUTPUT_CLASS {
                return bad(format!("output {}: each part has one output", o + 1));
            }
            if p.n_inputs() != ni {
                return bad(format!(
                    "output {}: {} inputs, output 1 has {ni}",
                    o + 1,
                    p.n_inputs()
                ));
            }
            if !noise.is_valid() {
                return bad(format!("output {}: invalid noise model", o + 1));
            }
        }
        let (parts, noise) = parts.into_iter().unzip();
        Ok(Self { parts, noise })
    }

    /// The model of output `o`.
    pub fn part(&self, o: usize) -> Option<&dyn DynamicModel> {
        self.parts.get(o).map(|p| p.as_ref())
    }

    /// The noise model of output `o`.
    pub fn noise(&self, o: usize) -> Option<&NoiseModel> {
        self.noise.get(o)
    }

    /// Decode a model-file body of class `multi-output` (the parts are
    /// decoded through the registry).
    pub fn decode(body: &[u8], version: u32) -> Result<Self, CoreError> {
        let b: Vec<Part> = gb_core::decode_postcard(MULTI_OUTPUT_CLASS, version, 1, body)?;
        let parts = b
            .into_iter()
            .map(|p| {
                let m = p
                    .model
                    .decode(MULTI_OUTPUT_CLASS, "with a part of unknown class")?;
                Ok((m, p.noise))
            })
            .collect::<Result<Vec<_>, CoreError>>()?;
        Self::new(parts)
            .map_err(|e| CoreError::ModelFile(format!("corrupt 'multi-output' model ({e})")))
    }

    /// `init` of part `o` of `k` (see the module docs).
    fn part_init<'a>(&self, init: Init<'a>, o: usize, offset: usize) -> Init<'a> {
        let k = self.parts.len();
        let share = |h: &'a [f64]| {
            let l = h.len() / k;
            &h[o * l..(o + 1) * l]
        };
        match init {
            Init::History(h) => Init::History(share(h)),
            Init::Window(w) => Init::Window(share(w)),
            Init::State(x) => Init::State(&x[offset..offset + self.parts[o].n_states()]),
            other => other,
        }
    }

    /// The lengths an `init` must have.
    fn check_init(&self, init: Init<'_>) -> Result<(), CoreError> {
        let k = self.parts.len();
        match init {
            Init::History(h) | Init::Window(h) if h.len() % k != 0 => {
                Err(CoreError::Dimension(format!(
                    "{} measured output samples for {k} outputs (output-major, the same number of each)",
                    h.len()
                )))
            }
            Init::State(x) if x.len() != self.n_states() => Err(CoreError::Dimension(format!(
                "{} state values for a model with {} states",
                x.len(),
                self.n_states()
            ))),
            _ => Ok(()),
        }
    }
}

impl DynamicModel for MultiOutputModel {
    fn class(&self) -> &'static str {
        MULTI_OUTPUT_CLASS
    }
    fn n_inputs(&self) -> usize {
        self.parts[0].n_inputs()
    }
    fn n_outputs(&self) -> usize {
        self.parts.len()
    }
    fn n_states(&self) -> usize {
        self.parts.iter().map(|p| p.n_states()).sum()
    }
    /// The longest history a part takes (per output).
    fn history_len(&self) -> usize {
        self.parts
            .iter()
            .map(|p| p.history_len())
            .max()
            .unwrap_or(0)
    }
    fn describe(&self) -> String {
        let each: Vec<String> = self
            .parts
            .iter()
            .enumerate()
            .map(|(o, p)| format!("output {}: {}", o + 1, p.describe()))
            .collect();
        format!(
            "{} outputs, one model each ({})",
            self.parts.len(),
            each.join("; ")
        )
    }
    fn n_parameters(&self) -> usize {
        self.parts.iter().map(|p| p.n_parameters()).sum()
    }
    fn simulate_into(
        &self,
        u: &[Vec<f64>],
        init: Init<'_>,
        y: &mut [f64],
        ws: &mut Workspace,
    ) -> Result<(), CoreError> {
        check_inputs(self.n_inputs(), u)?;
        self.check_init(init)?;
        let n = u.first().map_or(0, Vec::len);
        if y.len() != n * self.parts.len() {
            return Err(CoreError::Dimension(format!(
                "output buffer of {} values for {} outputs of {n} samples",
                y.len(),
                self.parts.len()
            )));
        }
        let mut offset = 0;
        for (o, (p, yo)) in self.parts.iter().zip(y.chunks_mut(n.max(1))).enumerate() {
            p.simulate_into(u, self.part_init(init, o, offset), yo, ws)?;
            offset += p.n_states();
        }
        Ok(())
    }
    /// Every part's stepper, started as `init` says for it.
    fn stepper(&self, init: Init<'_>) -> Result<Box<dyn Stepper + '_>, CoreError> {
        self.check_init(init)?;
        let mut offset = 0;
        let mut parts = Vec::with_capacity(self.parts.len());
        for (o, p) in self.parts.iter().enumerate() {
            parts.push(p.stepper(self.part_init(init, o, offset))?);
            offset += p.n_states();
        }
        Ok(Box::new(StackStepper { parts }))
    }
    fn encode(&self) -> Result<Vec<u8>, CoreError> {
        let b = self
            .parts
            .iter()
            .zip(&self.noise)
            .map(|(p, noise)| {
                Ok(Part {
                    model: StoredPart::of(p.as_ref())?,
                    noise: noise.clone(),
                })
            })
            .collect::<Result<Vec<_>, CoreError>>()?;
        postcard::to_allocvec(&b)
            .map_err(|e| CoreError::ModelFile(format!("cannot encode model: {e}")))
    }
    /// Every part's views, keys and titles marked with the output.
    fn views(&self, input_names: &[String], output_names: &[String]) -> Vec<ModelView> {
        let mut out = vec![];
        for (o, p) in self.parts.iter().enumerate() {
            let name = output_names
                .get(o)
                .cloned()
                .unwrap_or_else(|| format!("output {}", o + 1));
            for mut v in p.views(input_names, std::slice::from_ref(&name)) {
                v.key = format!("{}-{}", v.key, o + 1);
                v.title = format!("{} ({name})", v.title);
                out.push(v);
            }
        }
        out
    }
    fn clone_box(&self) -> Box<dyn DynamicModel> {
        Box::new(self.clone())
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

struct StackStepper<'a> {
    parts: Vec<Box<dyn Stepper + 'a>>,
}

impl Stepper for StackStepper<'_> {
    fn step(&mut self, u: &[f64], y: &mut [f64]) -> Result<(), CoreError> {
        if y.len() != self.parts.len() {
            return Err(CoreError::Dimension(format!(
                "{} output values for {} outputs",
                y.len(),
                self.parts.len()
            )));
        }
        for (p, yo) in self.parts.iter_mut().zip(y.chunks_mut(1)) {
            p.step(u, yo)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::SparseStateSpace;

    fn part(a: f64, c: f64) -> Box<dyn DynamicModel> {
        // x⁺ = a x + u, y = c x
        Box::new(SparseStateSpace::linear(vec![a], vec![1.0], vec![c], vec![0.0]).unwrap())
    }

    fn stack() -> MultiOutputModel {
        MultiOutputModel::new(vec![
            (part(0.5, 1.0), NoiseModel::Gaussian { sd: 0.1 }),
            (part(-0.3, 2.0), NoiseModel::Gaussian { sd: 0.2 }),
        ])
        .unwrap()
    }

    #[test]
    fn each_output_is_its_part_and_the_file_round_trips() {
        let m = stack();
        let u = vec![vec![1.0, 0.0, -1.0, 2.0, 0.5]];
        let y = m.simulate(&u, Init::Rest).unwrap();
        let y1 = part(0.5, 1.0).simulate(&u, Init::Rest).unwrap();
        let y2 = part(-0.3, 2.0).simulate(&u, Init::Rest).unwrap();
        assert_eq!(y, [y1.clone(), y2.clone()].concat());
        // stepping gives the same values
        {
            let mut s = m.stepper(Init::Rest).unwrap();
            for k in 0..5 {
                let mut yk = [0.0; 2];
                s.step(&[u[0][k]], &mut yk).unwrap();
                assert_eq!(yk, [y1[k], y2[k]], "{k}");
            }
        }
        // an explicit state: the parts' states one after the other
        let x = m.simulate(&u, Init::State(&[1.0, -1.0])).unwrap();
        let x2 = part(-0.3, 2.0).simulate(&u, Init::State(&[-1.0])).unwrap();
        assert_eq!(&x[5..], &x2[..]);
        let fm = gb_core::FittedModel::new(
            vec!["u".into()],
            vec!["y1".into(), "y2".into()],
            Box::new(m),
            NoiseModel::Gaussian { sd: 0.1 },
        )
        .unwrap();
        let back = crate::registry::from_bytes(&fm.to_bytes().unwrap(), "m.gbm").unwrap();
        assert_eq!(back.dynamics.class(), MULTI_OUTPUT_CLASS);
        assert_eq!(back.dynamics.n_outputs(), 2);
        assert_eq!(back.simulate(&u, Init::Rest).unwrap(), y);
        let mo = back
            .dynamics
            .as_any()
            .downcast_ref::<MultiOutputModel>()
            .unwrap();
        assert_eq!(mo.noise(1), Some(&NoiseModel::Gaussian { sd: 0.2 }));
    }

    #[test]
    fn parts_must_fit_together() {
        assert!(MultiOutputModel::new(vec![]).is_err());
        let two_inputs: Box<dyn DynamicModel> = Box::new(
            SparseStateSpace::linear(vec![0.5], vec![1.0, 1.0], vec![1.0], vec![0.0, 0.0]).unwrap(),
        );
        let g = NoiseModel::Gaussian { sd: 0.1 };
        assert!(
            MultiOutputModel::new(vec![(part(0.5, 1.0), g.clone()), (two_inputs, g.clone())])
                .is_err()
        );
        let nested = Box::new(stack()) as Box<dyn DynamicModel>;
        assert!(MultiOutputModel::new(vec![(nested, g.clone())]).is_err());
        // a history must hold the same number of samples of each output
        let u = vec![vec![1.0, 0.0]];
        assert!(stack()
            .simulate(&u, Init::History(&[1.0, 2.0, 3.0]))
            .is_err());
        // a corrupt body is an error, not a panic
        assert!(MultiOutputModel::decode(&[1, 2, 3], 1).is_err());
    }
}
