//! Input operators: further input channels computed from the measured
//! inputs — stop (elastic–plastic) operators, the rate-independent memory
//! of a Prandtl–Ishlinskii hysteresis (Hauth 2008, §3.2), and first-order
//! low-pass filters — in front of a model of any class, which sees the
//! measured inputs followed by the operator channels.
//!
//! ```text
//! stop of half-width h on u:  s(k) = clamp(s(k−1) + u(k) − u(k−1), −h, h),  s(0) = 0
//! low-pass of gain a on u:    f(k) = f(k−1) + a·(u(k) − f(k−1)),          f(0) = u(0)
//! ```
//!
//! A hysteretic force of a displacement (a magnetorheological damper, a
//! yielding spring, dry friction) is a function of the stop operators of
//! that displacement; the force of a damper whose field follows its
//! command voltage with a lag is a function of the low-passed voltage.
//! With the channels as inputs, a polynomial NARX / NOE model (gb-lmn)
//! forms products such as `low-pass(V)·stop(x)`.
//!
//! ```
//! use gb_model::operators::{operator_channels, InputOperator};
//! let u = vec![vec![0.0, 1.0, 3.0, 2.0]];
//! let ch = operator_channels(&[InputOperator::Stop { input: 0, half_width: 1.5 }], &u);
//! // s = 0, clamp(1) = 1, clamp(1 + 2) = 1.5, 1.5 − 1 = 0.5
//! assert_eq!(ch[0], vec![0.0, 1.0, 1.5, 0.5]);
//! ```
use crate::registry::StoredPart;
use gb_core::{check_inputs, CoreError, DynamicModel, Init, ModelView, Stepper, Workspace};
use serde::{Deserialize, Serialize};
use std::any::Any;

/// Tag of the class in model files.
pub const OPERATORS_CLASS: &str = "input-operators";

/// One operator channel computed from one measured input.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum InputOperator {
    /// The stop operator of half-width `half_width` (> 0, the input's
    /// units) on input `input`.
    Stop {
        /// Index of the measured input.
        input: usize,
        /// Half-width h.
        half_width: f64,
    },
    /// A first-order low-pass filter of gain `gain` (in (0, 1]; time
    /// constant −1/ln(1 − a) samples) on input `input`.
    LowPass {
        /// Index of the measured input.
        input: usize,
        /// Gain a.
        gain: f64,
    },
}

impl InputOperator {
    /// The measured input it reads.
    pub fn input(&self) -> usize {
        match *self {
            Self::Stop { input, .. } | Self::LowPass { input, .. } => input,
        }
    }

    /// The channel's name from the input's name, e.g. `stop(x, 0.012)`.
    pub fn name(&self, inputs: &[String]) -> String {
        let u = inputs
            .get(self.input())
            .cloned()
            .unwrap_or_else(|| format!("u{}", self.input() + 1));
        match *self {
            Self::Stop { half_width, .. } => format!("stop({u}, {half_width:.4})"),
            Self::LowPass { gain, .. } => {
                format!("lowpass({u}, {:.1} samples)", -1.0 / (1.0 - gain).ln())
            }
        }
    }

    /// Checked: a finite positive half-width, a gain in (0, 1], an input
    /// index below `n_inputs`.
    pub fn check(&self, n_inputs: usize) -> Result<(), CoreError> {
        let ok = match *self {
            Self::Stop { input, half_width } => {
                input < n_inputs && half_width.is_finite() && half_width > 0.0
            }
            Self::LowPass { input, gain } => input < n_inputs && gain > 0.0 && gain <= 1.0,
        };
        if ok {
            Ok(())
        } else {
            Err(CoreError::InvalidArgument(format!(
                "input operator {self:?}: a half-width > 0, a gain in (0, 1] and one of {n_inputs} inputs"
            )))
        }
    }

    /// The state before the first sample.
    fn start(&self) -> OperatorState {
        OperatorState {
            last: 0.0,
            value: 0.0,
            first: true,
        }
    }

    /// The channel's value at input sample `u` (the operator's input).
    fn step(&self, st: &mut OperatorState, u: f64) -> f64 {
        let first = std::mem::replace(&mut st.first, false);
        match *self {
            Self::Stop { half_width: h, .. } => {
                if !first {
                    st.value = (st.value + u - st.last).clamp(-h, h);
                }
                st.last = u;
            }
            Self::LowPass { gain, .. } => {
                st.value = if first {
                    u
                } else {
                    st.value + gain * (u - st.value)
                };
            }
        }
        st.value
    }
}

/// The running state of one operator.
#[derive(Debug, Clone, Copy)]
struct OperatorState {
    last: f64,
    value: f64,
    first: bool,
}

/// The operator channels of the measured inputs `u` (one per operator).
/// An operator naming an input `u` lacks gives an empty channel; the
/// model checks its operators when it is built.
pub fn operator_channels(ops: &[InputOperator], u: &[Vec<f64>]) -> Vec<Vec<f64>> {
    ops.iter()
        .map(|op| {
            let mut st = op.start();
            u.get(op.input())
                .map(|x| x.iter().map(|&v| op.step(&mut st, v)).collect())
                .unwrap_or_default()
        })
        .collect()
}

/// A model of any class behind input operators (see the module docs).
#[derive(Debug, Clone)]
pub struct OperatorInputsModel {
    operators: Vec<InputOperator>,
    n_measured: usize,
    inner: Box<dyn DynamicModel>,
}

#[derive(Serialize, Deserialize)]
struct Body {
    operators: Vec<InputOperator>,
    n_measured: usize,
    inner: StoredPart,
}

impl OperatorInputsModel {
    /// `inner` sees the `n_measured` measured inputs followed by one
    /// channel per operator.
    pub fn new(
        operators: Vec<InputOperator>,
        n_measured: usize,
        inner: Box<dyn DynamicModel>,
    ) -> Result<Self, CoreError> {
        for op in &operators {
            op.check(n_measured)?;
        }
        if operators.is_empty() || inner.n_inputs() != n_measured + operators.len() {
            return Err(CoreError::InvalidArgument(format!(
                "input operators: a model of {} inputs behind {n_measured} measured inputs and {} operators",
                inner.n_inputs(),
                operators.len()
            )));
        }
        if inner.class() == OPERATORS_CLASS {
            return Err(CoreError::InvalidArgument(
                "input operators in front of input operators".into(),
            ));
        }
        Ok(Self {
            operators,
            n_measured,
            inner,
        })
    }

    /// The operators.
    pub fn operators(&self) -> &[InputOperator] {
        &self.operators
    }

    /// Whether the model behind the operators reads an operator channel
    /// (known for a polynomial, whose terms say which inputs they read;
    /// `true` for any other class).
    pub fn reads_a_channel(&self) -> bool {
        match self.inner.as_any().downcast_ref::<gb_lmn::PolyNarx>() {
            Some(p) => {
                (self.n_measured..self.n_measured + self.operators.len()).any(|j| p.reads_input(j))
            }
            None => true,
        }
    }

    /// The model behind the operators.
    pub fn inner(&self) -> &dyn DynamicModel {
        self.inner.as_ref()
    }

    /// Decode a model-file body of class `input-operators` (the inner
    /// model through the registry).
    pub fn decode(body: &[u8], version: u32) -> Result<Self, CoreError> {
        let b: Body = gb_core::decode_postcard(OPERATORS_CLASS, version, 1, body)?;
        let inner = b.inner.decode(OPERATORS_CLASS, "of an unknown class")?;
        Self::new(b.operators, b.n_measured, inner)
            .map_err(|e| CoreError::ModelFile(format!("corrupt '{OPERATORS_CLASS}' model ({e})")))
    }

    /// The measured inputs followed by the operator channels.
    pub fn augmented(&self, u: &[Vec<f64>]) -> Result<Vec<Vec<f64>>, CoreError> {
        check_inputs(self.n_measured, u)?;
        let mut all = u.to_vec();
        all.extend(operator_channels(&self.operators, u));
        Ok(all)
    }

    /// The input names the inner model sees.
    pub fn augmented_names(&self, input_names: &[String]) -> Vec<String> {
        let mut names = input_names.to_vec();
        names.extend(self.operators.iter().map(|op| op.name(input_names)));
        names
    }
}

impl DynamicModel for OperatorInputsModel {
    fn class(&self) -> &'static str {
        OPERATORS_CLASS
    }
    fn n_inputs(&self) -> usize {
        self.n_measured
    }
    fn n_states(&self) -> usize {
        self.inner.n_states()
    }
    fn history_len(&self) -> usize {
        self.inner.history_len()
    }
    fn describe(&self) -> String {
        let stops = self
            .operators
            .iter()
            .filter(|o| matches!(o, InputOperator::Stop { .. }))
            .count();
        let lowpass = self.operators.len() - stops;
        format!(
            "{} on the inputs and {stops} stop operator(s), {lowpass} low-pass filter(s) of them",
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
        let all = self.augmented(u)?;
        self.inner.simulate_into(&all, init, y, ws)
    }
    fn stepper(&self, init: Init<'_>) -> Result<Box<dyn Stepper + '_>, CoreError> {
        Ok(Box::new(OperatorStepper {
            model: self,
            states: self.operators.iter().map(InputOperator::start).collect(),
            inner: self.inner.stepper(init)?,
            all: vec![0.0; self.n_measured + self.operators.len()],
        }))
    }
    fn encode(&self) -> Result<Vec<u8>, CoreError> {
        let b = Body {
            operators: self.operators.clone(),
            n_measured: self.n_measured,
            inner: StoredPart::of(self.inner.as_ref())?,
        };
        postcard::to_allocvec(&b)
            .map_err(|e| CoreError::ModelFile(format!("cannot encode model: {e}")))
    }
    fn views(&self, input_names: &[String], output_names: &[String]) -> Vec<ModelView> {
        self.inner
            .views(&self.augmented_names(input_names), output_names)
    }
    fn clone_box(&self) -> Box<dyn DynamicModel> {
        Box::new(self.clone())
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// Steps the operators, then the inner model on the augmented inputs.
struct OperatorStepper<'a> {
    model: &'a OperatorInputsModel,
    states: Vec<OperatorState>,
    inner: Box<dyn Stepper + 'a>,
    all: Vec<f64>,
}

impl Stepper for OperatorStepper<'_> {
    fn step(&mut self, u: &[f64], y: &mut [f64]) -> Result<(), CoreError> {
        let m = self.model;
        if u.len() != m.n_measured {
            return Err(CoreError::Dimension(format!(
                "step: {} inputs for a model with {}",
                u.len(),
                m.n_measured
            )));
        }
        self.all[..u.len()].copy_from_slice(u);
        for (i, (op, st)) in m.operators.iter().zip(&mut self.states).enumerate() {
            self.all[m.n_measured + i] = op.step(st, u[op.input()]);
        }
        self.inner.step(&self.all, y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::SparseStateSpace;

    fn model() -> OperatorInputsModel {
        // x⁺ = 0.5 x + u + 2 s + f, y = x
        let inner =
            SparseStateSpace::linear(vec![0.5], vec![1.0, 2.0, 1.0], vec![1.0], vec![0.0; 3])
                .unwrap();
        OperatorInputsModel::new(
            vec![
                InputOperator::Stop {
                    input: 0,
                    half_width: 0.4,
                },
                InputOperator::LowPass {
                    input: 0,
                    gain: 0.3,
                },
            ],
            1,
            Box::new(inner),
        )
        .unwrap()
    }

    /// The stop stays within ±h and follows the input's increments while
    /// inside; the low-pass obeys its recursion; the inner model sees the
    /// channels; stepping gives the batch simulation; the file reads back.
    #[test]
    fn channels_follow_their_recursions_and_the_model_reads_back() {
        let u: Vec<f64> = (0..50).map(|k| (0.3 * k as f64).sin() * 2.0).collect();
        let ops = model().operators().to_vec();
        let ch = operator_channels(&ops, std::slice::from_ref(&u));
        for k in 1..u.len() {
            let s = ch[0][k];
            assert!(s.abs() <= 0.4 + 1e-12);
            if s.abs() < 0.4 - 1e-12 {
                assert!((s - ch[0][k - 1] - (u[k] - u[k - 1])).abs() < 1e-12);
            }
            let f = ch[1][k - 1] + 0.3 * (u[k] - ch[1][k - 1]);
            assert!((ch[1][k] - f).abs() < 1e-12);
        }
        let m = model();
        let y = m.simulate(std::slice::from_ref(&u), Init::Rest).unwrap();
        let direct = m
            .inner()
            .simulate(&[u.clone(), ch[0].clone(), ch[1].clone()], Init::Rest)
            .unwrap();
        assert_eq!(y, direct);
        {
            let mut st = m.stepper(Init::Rest).unwrap();
            for (k, &v) in u.iter().enumerate() {
                let mut out = [0.0];
                st.step(&[v], &mut out).unwrap();
                assert!((out[0] - y[k]).abs() < 1e-12, "{k}");
            }
        }
        let fm = gb_core::FittedModel::new(
            vec!["x".into()],
            vec!["y".into()],
            Box::new(m),
            gb_core::NoiseModel::Gaussian { sd: 0.1 },
        )
        .unwrap();
        let back = crate::registry::from_bytes(&fm.to_bytes().unwrap(), "m.gbm").unwrap();
        assert_eq!(back.dynamics.class(), OPERATORS_CLASS);
        assert_eq!(
            back.simulate(std::slice::from_ref(&u), Init::Rest).unwrap(),
            y
        );
        assert!(back.describe().contains("1 stop operator(s)"));
    }

    #[test]
    fn bad_operators_are_refused() {
        let inner = || -> Box<dyn DynamicModel> {
            Box::new(
                SparseStateSpace::linear(vec![0.5], vec![1.0, 1.0], vec![1.0], vec![0.0; 2])
                    .unwrap(),
            )
        };
        let stop = |input, half_width| InputOperator::Stop { input, half_width };
        assert!(OperatorInputsModel::new(vec![stop(1, 0.1)], 1, inner()).is_err());
        assert!(OperatorInputsModel::new(vec![stop(0, 0.0)], 1, inner()).is_err());
        assert!(OperatorInputsModel::new(vec![stop(0, 0.1), stop(0, 0.2)], 1, inner()).is_err());
        assert!(OperatorInputsModel::new(vec![stop(0, 0.1)], 1, inner()).is_ok());
    }
}
