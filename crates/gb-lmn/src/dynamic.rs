//! The gb-lmn classes as [`DynamicModel`]s: the input–output network
//! ([`LocalModelNetwork`]: linear OE, LOLIMOT, play-operator hysteresis),
//! the tree network ([`LmnModel`]), the Wiener–Hammerstein network and the
//! state-space network ([`SsLmnModel`]).
use crate::regressors::Experiment;
use crate::{LmnError, LmnModel, LocalModelNetwork, SsLmnModel, WienerHammersteinNetwork};
use gb_core::{check_inputs, CoreError, DynamicModel, Init, ModelView, Workspace};
use std::any::Any;

/// Encode a serde value with postcard for a model file.
pub(crate) fn encode<T: serde::Serialize>(v: &T) -> Result<Vec<u8>, CoreError> {
    postcard::to_allocvec(v).map_err(|e| CoreError::ModelFile(format!("cannot encode model: {e}")))
}

/// The measured outputs `y` padded with zeros to `n` samples.
fn padded(y: &[f64], n: usize) -> Vec<f64> {
    let mut v = y[..y.len().min(n)].to_vec();
    v.resize(n, 0.0);
    v
}

fn copy_out(src: &[f64], y: &mut [f64]) -> Result<(), CoreError> {
    if src.len() != y.len() {
        return Err(CoreError::Dimension(format!(
            "output buffer of {} samples for a simulation of {}",
            y.len(),
            src.len()
        )));
    }
    y.copy_from_slice(src);
    Ok(())
}

impl DynamicModel for LocalModelNetwork {
    fn class(&self) -> &'static str {
        "io-network"
    }
    fn n_inputs(&self) -> usize {
        self.input_scaling.len()
    }
    fn n_states(&self) -> usize {
        self.spec.max_lag()
    }
    fn history_len(&self) -> usize {
        self.spec.max_lag()
    }
    fn describe(&self) -> String {
        LocalModelNetwork::describe(self)
    }
    fn n_parameters(&self) -> usize {
        LocalModelNetwork::n_parameters(self)
    }
    fn simulate_into(
        &self,
        u: &[Vec<f64>],
        init: Init<'_>,
        y: &mut [f64],
        _ws: &mut Workspace,
    ) -> Result<(), CoreError> {
        check_inputs(self.n_inputs(), u)?;
        let sim = match init {
            Init::Window(w) => self.simulate_with_init_window(u, w)?,
            Init::History(h) | Init::State(h) => self.simulate_signals(u, h)?,
            _ => self.simulate_signals(u, &vec![0.0; self.spec.max_lag()])?,
        };
        copy_out(&sim, y)
    }
    fn encode(&self) -> Result<Vec<u8>, CoreError> {
        encode(self)
    }
    fn views(&self) -> Vec<ModelView> {
        vec![]
    }
    fn clone_box(&self) -> Box<dyn DynamicModel> {
        Box::new(self.clone())
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

impl DynamicModel for LmnModel {
    fn class(&self) -> &'static str {
        "lmn-tree"
    }
    /// The inputs, then the user columns (the last input signals).
    fn n_inputs(&self) -> usize {
        self.regressors.n_signals()
    }
    fn n_states(&self) -> usize {
        self.max_lag()
    }
    fn history_len(&self) -> usize {
        self.max_lag()
    }
    fn describe(&self) -> String {
        LmnModel::describe(self)
    }
    fn n_parameters(&self) -> usize {
        LmnModel::n_parameters(self)
    }
    fn simulate_into(
        &self,
        u: &[Vec<f64>],
        init: Init<'_>,
        y: &mut [f64],
        _ws: &mut Workspace,
    ) -> Result<(), CoreError> {
        check_inputs(self.n_inputs(), u)?;
        let n = u.first().map_or(0, Vec::len);
        let (history, used) = match init {
            Init::Window(h) | Init::History(h) | Init::State(h) => (padded(h, n), h.len().min(n)),
            _ => (vec![0.0; n], 0),
        };
        let r = &self.regressors;
        let e = Experiment::split(u, history, r.n_inputs(), r.n_extra)?;
        let sim = self.simulate_experiment(&e, used)?;
        copy_out(&sim, y)
    }
    fn encode(&self) -> Result<Vec<u8>, CoreError> {
        encode(self)
    }
    fn clone_box(&self) -> Box<dyn DynamicModel> {
        Box::new(self.clone())
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

impl DynamicModel for WienerHammersteinNetwork {
    fn class(&self) -> &'static str {
        "wiener-hammerstein"
    }
    fn n_inputs(&self) -> usize {
        1
    }
    fn n_states(&self) -> usize {
        self.a1.len() - 1 + self.a2.len() - 1
    }
    fn describe(&self) -> String {
        WienerHammersteinNetwork::describe(self)
    }
    fn n_parameters(&self) -> usize {
        WienerHammersteinNetwork::n_parameters(self)
    }
    /// The filters start from the zero state whatever `init` says (an init
    /// window is the transient a caller does not score).
    fn simulate_into(
        &self,
        u: &[Vec<f64>],
        _init: Init<'_>,
        y: &mut [f64],
        _ws: &mut Workspace,
    ) -> Result<(), CoreError> {
        check_inputs(1, u)?;
        copy_out(&self.simulate(&u[0]), y)
    }
    fn encode(&self) -> Result<Vec<u8>, CoreError> {
        encode(self)
    }
    fn clone_box(&self) -> Box<dyn DynamicModel> {
        Box::new(self.clone())
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

impl DynamicModel for SsLmnModel {
    fn class(&self) -> &'static str {
        "lmn-state-space"
    }
    fn n_inputs(&self) -> usize {
        SsLmnModel::n_inputs(self)
    }
    fn n_states(&self) -> usize {
        SsLmnModel::n_states(self)
    }
    fn describe(&self) -> String {
        SsLmnModel::describe(self)
    }
    fn n_parameters(&self) -> usize {
        self.parameters().len()
    }
    fn simulate_into(
        &self,
        u: &[Vec<f64>],
        init: Init<'_>,
        y: &mut [f64],
        _ws: &mut Workspace,
    ) -> Result<(), CoreError> {
        check_inputs(self.n_inputs(), u)?;
        let n = u.first().map_or(0, Vec::len);
        let nx = SsLmnModel::n_states(self);
        let sim = match init {
            Init::State(x0) => self.simulate_from(u, x0)?,
            Init::Window(w) | Init::History(w) if w.len().min(n) >= nx && nx > 0 => {
                self.simulate_with_init_window(u, &padded(w, n), w.len().min(n))?
            }
            _ => self.simulate_from(u, &vec![0.0; nx])?,
        };
        copy_out(&sim, y)
    }
    fn encode(&self) -> Result<Vec<u8>, CoreError> {
        encode(self)
    }
    fn clone_box(&self) -> Box<dyn DynamicModel> {
        Box::new(self.clone())
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// Decode a class body and check it, for the model registry.
fn decode_checked<T: serde::de::DeserializeOwned>(
    class: &str,
    version: u32,
    body: &[u8],
    check: impl FnOnce(&T) -> Result<(), String>,
) -> Result<T, CoreError> {
    let m: T = gb_core::decode_postcard(class, version, 1, body)?;
    check(&m).map_err(|e| CoreError::ModelFile(format!("inconsistent '{class}' model ({e})")))?;
    Ok(m)
}

impl LocalModelNetwork {
    /// Sizes of the parameters agree with the structure.
    pub fn check_consistency(&self) -> Result<(), LmnError> {
        self.spec.check(self.input_scaling.len())?;
        if self
            .leaves
            .iter()
            .any(|l| l.theta.len() != 1 + self.spec.n_dynamic())
            || self.beta.len() != self.spec.n_hysteresis()
            || self.leaves.is_empty()
        {
            return Err(LmnError::Dimension(
                "parameters do not match the structure".into(),
            ));
        }
        Ok(())
    }

    /// Decode a model-file body of class `io-network`.
    pub fn decode(body: &[u8], version: u32) -> Result<Self, CoreError> {
        decode_checked("io-network", version, body, |m: &Self| {
            m.check_consistency().map_err(|e| e.to_string())
        })
    }
}

impl LmnModel {
    /// Decode a model-file body of class `lmn-tree`.
    pub fn decode(body: &[u8], version: u32) -> Result<Self, CoreError> {
        decode_checked("lmn-tree", version, body, |m: &Self| {
            m.check_consistency().map_err(|e| e.to_string())
        })
    }
}

impl WienerHammersteinNetwork {
    /// Decode a model-file body of class `wiener-hammerstein`.
    pub fn decode(body: &[u8], version: u32) -> Result<Self, CoreError> {
        decode_checked("wiener-hammerstein", version, body, |m: &Self| {
            m.check().map_err(|e| e.to_string())
        })
    }
}

impl SsLmnModel {
    /// Decode a model-file body of class `lmn-state-space`.
    pub fn decode(body: &[u8], version: u32) -> Result<Self, CoreError> {
        decode_checked("lmn-state-space", version, body, |m: &Self| {
            m.check_consistency().map_err(|e| e.to_string())
        })
    }
}
