//! The gb-lmn classes as [`DynamicModel`]s: the input–output network
//! ([`LocalModelNetwork`]: linear OE, LOLIMOT, play-operator hysteresis),
//! the tree network ([`LmnModel`]), the Wiener–Hammerstein network and the
//! state-space network ([`SsLmnModel`]).
use crate::lmn::LmnStepper;
use crate::noe::NetworkStepper;
use crate::regressors::Experiment;
use crate::ssnet::SsStepper;
use crate::wiener_hammerstein::WhStepper;
use crate::{LmnError, LmnModel, LocalModelNetwork, SsLmnModel, WienerHammersteinNetwork};
use gb_core::{check_inputs, CoreError, DynamicModel, Init, ModelView, Stepper, Workspace};
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

/// The one output slot of a single-output stepper.
fn one_output(y: &mut [f64]) -> Result<&mut f64, CoreError> {
    match y {
        [v] => Ok(v),
        _ => Err(CoreError::Dimension(format!(
            "one output per step, a buffer of {} was given",
            y.len()
        ))),
    }
}

fn unsupported(class: &str, init: &Init<'_>) -> CoreError {
    CoreError::Unsupported(format!(
        "{class}: stepping starts at rest or from an explicit state/history, not {init:?}"
    ))
}

impl Stepper for NetworkStepper<'_> {
    fn step(&mut self, u: &[f64], y: &mut [f64]) -> Result<(), CoreError> {
        let out = one_output(y)?;
        *out = NetworkStepper::step(self, u)?;
        Ok(())
    }
}

impl Stepper for LmnStepper<'_> {
    fn step(&mut self, u: &[f64], y: &mut [f64]) -> Result<(), CoreError> {
        let out = one_output(y)?;
        *out = LmnStepper::step(self, u)?;
        Ok(())
    }
}

impl Stepper for SsStepper<'_> {
    fn step(&mut self, u: &[f64], y: &mut [f64]) -> Result<(), CoreError> {
        let out = one_output(y)?;
        *out = SsStepper::step(self, u)?;
        Ok(())
    }
}

impl Stepper for WhStepper<'_> {
    fn step(&mut self, u: &[f64], y: &mut [f64]) -> Result<(), CoreError> {
        let out = one_output(y)?;
        let [uk] = u else {
            return Err(CoreError::Dimension(format!(
                "the network has one input, {} values were given",
                u.len()
            )));
        };
        *out = WhStepper::step(self, *uk);
        Ok(())
    }
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
    /// Version 2 appends the relays per cell side of the output relay grid
    /// and the knots of the output map to the version-1 body.
    fn class_version(&self) -> u32 {
        2
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
        self.describe_structure()
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
            Init::Stored => self.simulate_signals(u, &[])?,
            _ => self.simulate_signals(u, &vec![0.0; self.spec.max_lag()])?,
        };
        copy_out(&sim, y)
    }
    /// From [`Init::Rest`] (a zero output history), the measured output
    /// history ([`Init::History`] / [`Init::State`], as in
    /// [`LocalModelNetwork::simulate_signals`]) or [`Init::Stored`] (no
    /// history: the training operating point, as `simulate` starts).
    fn stepper(&self, init: Init<'_>) -> Result<Box<dyn Stepper + '_>, CoreError> {
        let zeros = vec![0.0; self.spec.max_lag()];
        let h = match init {
            Init::Rest => &zeros[..],
            Init::Stored => &[][..],
            Init::History(h) | Init::State(h) => h,
            other => return Err(unsupported(self.class(), &other)),
        };
        Ok(Box::new(NetworkStepper::new(self, h)?))
    }
    fn encode(&self) -> Result<Vec<u8>, CoreError> {
        encode(&(self, self.spec.relay_sub as u32, &self.spec.output_knots))
    }
    fn views(&self, input_names: &[String], output_names: &[String]) -> Vec<ModelView> {
        crate::views::network_views(self, input_names, output_names)
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
            Init::Stored => (vec![], 0),
            _ => (vec![0.0; n], 0),
        };
        let r = &self.regressors;
        let e = Experiment::split(u, &history, r.n_inputs(), r.n_extra)?;
        let sim = self.simulate_experiment(&e, used)?;
        copy_out(&sim, y)
    }
    /// From [`Init::Rest`] (a zero output history), [`Init::Stored`] (the
    /// training mean) or the output history ([`Init::History`] /
    /// [`Init::State`]; padded with zeros to `max_lag` samples, as
    /// [`simulate`](DynamicModel::simulate) does).
    fn stepper(&self, init: Init<'_>) -> Result<Box<dyn Stepper + '_>, CoreError> {
        // the stored start: the training mean as the output history
        let mean = vec![self.output_scaling.offset; self.max_lag()];
        let h = match init {
            Init::Rest => &[][..],
            Init::Stored => &mean[..],
            Init::History(h) | Init::State(h) => h,
            other => return Err(unsupported(self.class(), &other)),
        };
        let mut history = h.to_vec();
        history.resize(h.len().max(self.max_lag()), 0.0);
        Ok(Box::new(LmnStepper::new(self, &history)?))
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
    /// Version 2 appends the static map's training support to the
    /// version-1 body.
    fn class_version(&self) -> u32 {
        2
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
    /// The filters start from the zero state ([`Init::Rest`],
    /// [`Init::Stored`], [`Init::State`]), or, given measured outputs
    /// ([`Init::Window`], [`Init::History`]), from the steady state of the
    /// first input held before the start (the record began in motion: the
    /// zero state would add a step from zero to `u(0)`).
    fn simulate_into(
        &self,
        u: &[Vec<f64>],
        init: Init<'_>,
        y: &mut [f64],
        _ws: &mut Workspace,
    ) -> Result<(), CoreError> {
        check_inputs(1, u)?;
        match init {
            Init::Window(_) | Init::History(_) => copy_out(&self.simulate_from_steady(&u[0]), y),
            _ => copy_out(&self.simulate(&u[0]), y),
        }
    }
    /// From the zero state ([`Init::Rest`], [`Init::Stored`] or an all-zero
    /// [`Init::State`]).
    fn stepper(&self, init: Init<'_>) -> Result<Box<dyn Stepper + '_>, CoreError> {
        match init {
            Init::Rest | Init::Stored => {}
            Init::State(x) if x.iter().all(|v| *v == 0.0) => {}
            other => return Err(unsupported(self.class(), &other)),
        }
        Ok(Box::new(WhStepper::new(self)))
    }
    fn encode(&self) -> Result<Vec<u8>, CoreError> {
        encode(&(self, self.nonlinearity.support))
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
    /// From [`Init::Rest`] or [`Init::Stored`] (the zero state, as
    /// `simulate` starts both) or [`Init::State`].
    fn stepper(&self, init: Init<'_>) -> Result<Box<dyn Stepper + '_>, CoreError> {
        let zeros = vec![0.0; SsLmnModel::n_states(self)];
        let x0 = match init {
            Init::Rest | Init::Stored => &zeros[..],
            Init::State(x) => x,
            other => return Err(unsupported(self.class(), &other)),
        };
        Ok(Box::new(self.step_from(x0)?))
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
        let nz = self.z_index.len();
        if self.z_lower.len() != nz
            || self.z_upper.len() != nz
            || self.z_index.iter().any(|&i| i >= self.spec.n_dynamic())
            || self
                .leaves
                .iter()
                .any(|l| l.lower.len() != nz || l.upper.len() != nz)
        {
            return Err(LmnError::Dimension(
                "parameters do not match the structure".into(),
            ));
        }
        Ok(())
    }

    /// Decode a model-file body of class `io-network` (version 1: hard
    /// relays, no output map; version 2: the relays per cell side and the
    /// output map's knots follow the network).
    pub fn decode(body: &[u8], version: u32) -> Result<Self, CoreError> {
        let check = |m: &Self| m.check_consistency().map_err(|e| e.to_string());
        if version < 2 {
            return decode_checked("io-network", version, body, check);
        }
        let (mut m, sub, knots): (Self, u32, Vec<f64>) =
            gb_core::decode_postcard("io-network", version, 2, body)?;
        // a count out of range fails the consistency check below
        m.spec.relay_sub = usize::try_from(sub).unwrap_or(usize::MAX);
        m.spec.output_knots = knots;
        check(&m)
            .map_err(|e| CoreError::ModelFile(format!("inconsistent 'io-network' model ({e})")))?;
        Ok(m)
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
    /// Decode a model-file body of class `wiener-hammerstein` (version 1:
    /// the network alone, extrapolated by its outermost local models;
    /// version 2: the static map's training support follows).
    pub fn decode(body: &[u8], version: u32) -> Result<Self, CoreError> {
        let check = |m: &Self| m.check().map_err(|e| e.to_string());
        if version < 2 {
            return decode_checked("wiener-hammerstein", version, body, check);
        }
        let (mut m, support): (Self, Option<[f64; 2]>) =
            gb_core::decode_postcard("wiener-hammerstein", version, 2, body)?;
        m.nonlinearity.support = support;
        check(&m).map_err(|e| {
            CoreError::ModelFile(format!("inconsistent 'wiener-hammerstein' model ({e})"))
        })?;
        Ok(m)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{
        fit_lmn_oe, FitOptions, IoNetworkParams, LolimotOptions, NetworkSpec, SsLmnParams,
        StaticNetwork, WarmStart,
    };
    use rand::{Rng, SeedableRng};
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// Step through `u` (one input) from `init`.
    fn stepped(m: &dyn DynamicModel, u: &[f64], init: Init<'_>) -> Vec<f64> {
        let mut s = m.stepper(init).unwrap();
        let mut y = [0.0];
        u.iter()
            .map(|&v| {
                s.step(&[v], &mut y).unwrap();
                y[0]
            })
            .collect()
    }

    /// The linear model of order 2 with the default Preisach component,
    /// fitted on (u, y).
    fn preisach_network(u: &[f64], y: &[f64]) -> LocalModelNetwork {
        let rec = gb_core::Record::new(vec!["u".into()], "y".into(), vec![u.to_vec()], y.to_vec())
            .unwrap();
        IoNetworkParams {
            hysteresis: true,
            ..IoNetworkParams::linear(2)
        }
        .check()
        .unwrap()
        .fit(&rec, WarmStart::default())
        .unwrap()
    }

    fn hysteretic(n: usize, seed: u64) -> (Vec<f64>, Vec<f64>) {
        let mut r = Xoshiro256PlusPlus::seed_from_u64(seed);
        let u: Vec<f64> = (0..n)
            .map(|k| (k as f64 * 0.01).sin() + 0.3 * r.random_range(-1.0..1.0))
            .collect();
        let mut y = vec![0.0; n];
        let mut p = 0.0f64;
        for k in 1..n {
            p = p.max(u[k - 1] - 0.3).min(u[k - 1] + 0.3);
            y[k] = 0.7 * y[k - 1]
                + 0.3 * p
                + 0.3 * (2.0 * y[k - 1]).tanh()
                + 0.01 * r.random_range(-1.0..1.0);
        }
        (u, y)
    }

    #[test]
    fn stepping_an_io_network_is_bit_identical_to_simulate() {
        let (u, y) = hysteretic(2500, 1);
        // play operators and relay cells on the output and the input, lags 1..3
        let hyst = preisach_network(&u, &y);
        // a LOLIMOT network (several leaves)
        let spec = NetworkSpec::order(2, 1);
        let lopts = LolimotOptions {
            max_leaves: 4,
            ..LolimotOptions::default()
        };
        let net = fit_lmn_oe(
            &spec,
            std::slice::from_ref(&u),
            &y,
            None,
            &lopts,
            &FitOptions::default(),
        )
        .unwrap();
        assert!(net.n_leaves() > 1);
        for m in [&hyst, &net] {
            let uu = [u.clone()];
            for init in [Init::Rest, Init::History(&y[..3]), Init::History(&y[..1])] {
                let sim = DynamicModel::simulate(m, &uu, init).unwrap();
                assert_eq!(stepped(m, &u, init), sim, "{init:?}");
            }
        }
        assert!(hyst.stepper(Init::Window(&y[..50])).is_err());
    }

    /// The relays per cell side travel in the model file (version 2); a
    /// version-1 body (before them) reads as hard relays, and a model of
    /// cells simulates differently from one of hard relays.
    #[test]
    fn a_model_file_keeps_the_relay_cells() {
        let (u, y) = hysteretic(1500, 4);
        let m = preisach_network(&u, &y);
        assert_eq!(m.spec.relay_sub, 4);
        assert_eq!(m.class_version(), 2);
        let back = LocalModelNetwork::decode(&m.encode().unwrap(), 2).unwrap();
        assert_eq!(back.spec.relay_sub, 4);
        let uu = [u];
        let sim = DynamicModel::simulate(&m, &uu, Init::Rest).unwrap();
        assert_eq!(DynamicModel::simulate(&back, &uu, Init::Rest).unwrap(), sim);
        let v1 = LocalModelNetwork::decode(&encode(&m).unwrap(), 1).unwrap();
        assert_eq!(v1.spec.relay_sub, 1);
        let hard = DynamicModel::simulate(&v1, &uu, Init::Rest).unwrap();
        assert!(hard.iter().zip(&sim).any(|(a, b)| (a - b).abs() > 1e-9));
        // a count out of range and a truncated body are model-file errors
        let zero = encode(&(&m, 0u32, &m.spec.output_knots)).unwrap();
        let e = LocalModelNetwork::decode(&zero, 2).unwrap_err().to_string();
        assert!(e.contains("relays per cell side"), "{e}");
        let mut cut = encode(&m).unwrap();
        cut.push(4);
        assert!(LocalModelNetwork::decode(&cut, 2).is_err());
    }

    #[test]
    fn stepping_a_state_space_network_is_bit_identical_to_simulate() {
        let mut r = Xoshiro256PlusPlus::seed_from_u64(3);
        let n = 400;
        let u: Vec<f64> = (0..n)
            .map(|k| 3.0 + 2.0 * ((k / 40) as f64 * 1.7).sin())
            .collect();
        let mut x = [4.0f64, 4.0];
        let y: Vec<f64> = u
            .iter()
            .map(|&uk| {
                let yk = x[1] + 0.02 * r.random_range(-1.0..1.0);
                let x1 = (x[0] + 0.2 * uk - 0.25 * x[0].max(0.0).sqrt()).min(9.0);
                x[1] += 0.25 * x[0].max(0.0).sqrt() - 0.22 * x[1].max(0.0).sqrt();
                x[0] = x1;
                yk
            })
            .collect();
        let p = SsLmnParams {
            n_states: vec![2],
            leaves: vec![2],
            max_iter: 10,
            init_window: 20,
            ..SsLmnParams::default()
        };
        let m = crate::fit_ss_lmn(&p, std::slice::from_ref(&u), &y)
            .unwrap()
            .model;
        let uu = [u.clone()];
        for init in [Init::Rest, Init::State(&[3.5, 4.2])] {
            let sim = DynamicModel::simulate(&m, &uu, init).unwrap();
            assert_eq!(stepped(&m, &u, init), sim, "{init:?}");
        }
        assert!(m.stepper(Init::State(&[1.0])).is_err());
    }

    /// The static map's support travels in the model file (version 2); a
    /// version-1 body reads without it (the outermost local models
    /// extrapolate), and the two simulate differently beyond the support.
    #[test]
    fn a_wiener_hammerstein_file_keeps_the_support() {
        let mut m = WienerHammersteinNetwork {
            b1: vec![1.0],
            a1: vec![1.0],
            b2: vec![1.0],
            a2: vec![1.0],
            nonlinearity: StaticNetwork {
                knots: vec![0.0, 1.5],
                width: 0.05,
                coefficients: vec![0.0, 1.0, 0.0, 1.0, 0.0, 20.0],
                support: Some([-1.0, 1.0]),
            },
        };
        assert_eq!(m.class_version(), 2);
        let back = WienerHammersteinNetwork::decode(&m.encode().unwrap(), 2).unwrap();
        assert_eq!(back, m);
        let v1 = WienerHammersteinNetwork::decode(&encode(&m).unwrap(), 1).unwrap();
        assert_eq!(v1.nonlinearity.support, None);
        let u = [vec![0.5, 2.0]];
        let (a, b) = (
            DynamicModel::simulate(&m, &u, Init::Rest).unwrap(),
            DynamicModel::simulate(&v1, &u, Init::Rest).unwrap(),
        );
        assert!((a[0] - b[0]).abs() < 1e-9);
        // v = 2 is beyond the support: the outer trend (slope 1) continues
        // there, not the outermost model (slope 20, no data in its region)
        assert!(b[1] > 20.0 && (a[1] - 2.0).abs() < 0.05, "{a:?} {b:?}");
        m.nonlinearity.support = Some([1.0, -1.0]);
        assert!(WienerHammersteinNetwork::decode(&m.encode().unwrap(), 2).is_err());
    }

    #[test]
    fn stepping_a_wiener_hammerstein_network_is_bit_identical_to_simulate() {
        let m = WienerHammersteinNetwork {
            b1: vec![0.3, 0.2, -0.05],
            a1: vec![1.0, -0.9, 0.4],
            b2: vec![0.0, 0.4, -0.1],
            a2: vec![1.0, -1.3, 0.55],
            nonlinearity: StaticNetwork {
                knots: vec![-0.5, 0.0, 0.5],
                width: 0.1,
                coefficients: vec![0.1, 0.5, 0.0, 1.0, 0.2, 0.8, -0.1, 0.3],
                support: None,
            },
        };
        let mut r = Xoshiro256PlusPlus::seed_from_u64(5);
        let u: Vec<f64> = (0..500).map(|_| r.random_range(-1.0..1.0)).collect();
        let sim = DynamicModel::simulate(&m, std::slice::from_ref(&u), Init::Rest).unwrap();
        assert_eq!(stepped(&m, &u, Init::Rest), sim);
        assert_eq!(stepped(&m, &u, Init::State(&[0.0; 4])), sim);
        assert!(m.stepper(Init::State(&[1.0, 0.0, 0.0, 0.0])).is_err());
        let mut s = m.stepper(Init::Rest).unwrap();
        assert!(s.step(&[1.0, 2.0], &mut [0.0]).is_err());
        assert!(s.step(&[1.0], &mut [0.0, 0.0]).is_err());
    }

    #[test]
    fn stepping_a_tree_network_is_bit_identical_to_simulate() {
        use crate::{Focus, LmnParams, RegressorSpec, SplitKind, WeightKind};
        let (u, y) = hysteretic(1500, 2);
        let sq: Vec<f64> = u.iter().map(|v| v * v).collect();
        let rec = |inputs: Vec<Vec<f64>>| {
            let names = (0..inputs.len()).map(|j| format!("u{j}")).collect();
            gb_core::Records::single(
                gb_core::Record::new(names, "y".into(), inputs, y.clone()).unwrap(),
            )
        };
        let reg = RegressorSpec::arx(2, &[2], &[1]).with_z(vec![1], vec![vec![1]]);
        let cases = [
            (reg.clone(), WeightKind::Tree, SplitKind::Axis, false),
            (reg.clone(), WeightKind::Tree, SplitKind::Oblique, false),
            (reg.clone(), WeightKind::Gaussian, SplitKind::Axis, false),
            (
                reg.clone().with_degree(2),
                WeightKind::Tree,
                SplitKind::Axis,
                false,
            ),
            (
                reg.clone().with_extra(1),
                WeightKind::Tree,
                SplitKind::Axis,
                true,
            ),
        ];
        for (r, w, sp, extra) in cases {
            let inputs = if extra {
                vec![u.clone(), sq.clone()]
            } else {
                vec![u.clone()]
            };
            let m = LmnParams::new(r)
                .weights(w)
                .splits(sp)
                .max_leaves(4)
                .focus(Focus::Simulation)
                .lm_iterations(3)
                .fit(&rec(inputs.clone()))
                .unwrap();
            for init in [
                Init::Rest,
                Init::Stored,
                Init::History(&y[..2]),
                Init::History(&y[..7]),
            ] {
                let sim = DynamicModel::simulate(&m, &inputs, init).unwrap();
                let mut s = m.stepper(init).unwrap();
                let mut out = [0.0];
                let stepped: Vec<f64> = (0..y.len())
                    .map(|k| {
                        let uk: Vec<f64> = inputs.iter().map(|c| c[k]).collect();
                        s.step(&uk, &mut out).unwrap();
                        out[0]
                    })
                    .collect();
                assert_eq!(stepped, sim, "{w:?} {sp:?} extra {extra} {init:?}");
            }
        }
    }

    /// Counts the observer calls.
    #[derive(Default)]
    struct Count {
        progress: std::sync::atomic::AtomicUsize,
        iterations: std::sync::atomic::AtomicUsize,
    }
    impl gb_core::Observer for Count {
        fn progress(&self, _: usize, _: usize, _: &str) {
            self.progress
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
        fn iteration(&self, _: &gb_core::IterationInfo) {
            self.iterations
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
    }

    #[test]
    fn identify_reports_to_the_observer() {
        use crate::{LmnParams, RegressorSpec};
        use gb_core::Identify;
        use std::sync::atomic::Ordering::Relaxed;
        let (u, y) = hysteretic(1500, 4);
        let recs = gb_core::Records::single(
            gb_core::Record::new(vec!["u".into()], "y".into(), vec![u], y).unwrap(),
        );
        let c = Count::default();
        let m = IoNetworkParams::linear(2)
            .check()
            .unwrap()
            .identify(&recs, &c)
            .unwrap();
        assert!(c.iterations.load(Relaxed) > 0);
        // the same model as without an observer
        let quiet = IoNetworkParams::linear(2)
            .check()
            .unwrap()
            .identify(&recs, &gb_core::Silent)
            .unwrap();
        assert_eq!(m, quiet);
        let c = Count::default();
        LmnParams::new(RegressorSpec::arx(2, &[2], &[1]))
            .max_leaves(3)
            .lm_iterations(5)
            .check()
            .unwrap()
            .identify(&recs, &c)
            .unwrap();
        assert!(c.progress.load(Relaxed) > 0 && c.iterations.load(Relaxed) > 0);
    }
}
