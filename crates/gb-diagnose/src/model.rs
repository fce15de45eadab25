//! The grey-box model the diagnosis builds: a linear output-error model or a
//! local model network, optionally with Preisach-type (play-operator)
//! hysteresis columns and a Student-t noise model — or, when those do not
//! suffice, the wavelet-sparse state space with hidden states of `gb-model`.
use crate::DiagnoseError;
use gb_core::{CoreError, DataSet};
use gb_lmn::{
    fit_linear_oe_warm, fit_lmn_oe, Experiment, FitOptions, LmnModel, LmnParams, LocalModelNetwork,
    LolimotOptions, NetworkSpec, SsLmnModel, SsLmnParams, WhParams, WienerHammersteinNetwork,
};
use gb_model::{OeParams, SparseStateSpace};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Magic bytes at the start of a model file.
const MAGIC: &[u8; 4] = b"GBM\x01";
/// Version of the model-file format (2: optional tree/oblique network
/// [`GreyBoxModel::lmn`]; 3: optional hidden-state model
/// [`GreyBoxModel::state_space`] and Wiener–Hammerstein network
/// [`GreyBoxModel::wiener_hammerstein`]; versions 1 and 2 are still read).
pub const MODEL_FORMAT_VERSION: u32 = 3;
/// Largest model order accepted.
pub const MAX_ORDER: usize = 8;

/// Which parts a model has: the engineer's baseline plus the extensions the
/// diagnosis can add.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Structure {
    /// Dynamic order n (n_a = n_b = n).
    pub order: usize,
    /// Local model network (LOLIMOT) instead of one linear model.
    pub network: bool,
    /// Play-operator (Prandtl–Ishlinskii / discrete Preisach) hysteresis columns.
    pub hysteresis: bool,
    /// Heavy-tailed Student-t noise model, fitted robustly.
    pub robust_noise: bool,
    /// Capacity level of the nonlinear parts (0 = default): more local models
    /// and more hysteresis operators per level.
    pub detail: u8,
    /// The wavelet-sparse state space with hidden states (`gb-model`)
    /// replaces the input–output model; `order` is its number of states and
    /// `hysteresis` says that it has a hysteretic part.
    pub state_space: bool,
}

/// [`Structure`] of model-file versions 1 and 2.
#[derive(Debug, Clone, Copy, Deserialize)]
struct StructureV2 {
    order: usize,
    network: bool,
    hysteresis: bool,
    robust_noise: bool,
    detail: u8,
}

impl From<StructureV2> for Structure {
    fn from(o: StructureV2) -> Self {
        Self {
            order: o.order,
            network: o.network,
            hysteresis: o.hysteresis,
            robust_noise: o.robust_noise,
            detail: o.detail,
            state_space: false,
        }
    }
}

impl Structure {
    /// The linear output-error baseline of order `order`.
    pub fn linear(order: usize) -> Self {
        Self {
            order,
            network: false,
            hysteresis: false,
            robust_noise: false,
            detail: 0,
            state_space: false,
        }
    }

    /// Largest number of local models of a network structure.
    pub fn max_leaves(&self) -> usize {
        10 + 5 * self.detail as usize
    }

    /// Parse a model SPEC of `greybox fit`: `linear`, `lmn`, `linear+preisach`,
    /// `lmn+preisach`, each optionally `+student-t`.
    ///
    /// ```
    /// use gb_diagnose::Structure;
    /// let s = Structure::parse("lmn+preisach", 3).unwrap();
    /// assert!(s.network && s.hysteresis && s.order == 3);
    /// assert!(Structure::parse("nonsense", 2).is_err());
    /// ```
    pub fn parse(spec: &str, order: usize) -> Result<Self, DiagnoseError> {
        let mut s = Self::linear(order);
        let mut parts = spec.split('+');
        match parts.next() {
            Some("linear") => {}
            Some("lmn") => s.network = true,
            _ => return Err(DiagnoseError::UnknownSpec(spec.to_string())),
        }
        for p in parts {
            match p {
                "preisach" | "hysteresis" => s.hysteresis = true,
                "student-t" | "robust" => s.robust_noise = true,
                _ => return Err(DiagnoseError::UnknownSpec(spec.to_string())),
            }
        }
        if order == 0 || order > MAX_ORDER {
            return Err(DiagnoseError::InvalidArgument(format!(
                "order must be in 1..={MAX_ORDER}, got {order}"
            )));
        }
        Ok(s)
    }

    /// The SPEC string of this structure.
    pub fn spec(&self) -> String {
        let mut s = String::from(if self.state_space {
            "state-space"
        } else if self.network {
            "lmn"
        } else {
            "linear"
        });
        if self.hysteresis {
            s.push_str(if self.state_space {
                "+hysteresis"
            } else {
                "+preisach"
            });
        }
        if self.robust_noise {
            s.push_str("+student-t");
        }
        if self.detail > 0 {
            s.push_str(&format!(" (detail {})", self.detail));
        }
        s
    }

    /// The network structure for `n_inputs` inputs.
    pub fn network_spec(&self, n_inputs: usize) -> NetworkSpec {
        let mut spec = NetworkSpec::order(self.order, n_inputs);
        if self.hysteresis {
            // thresholds in normalised (unit-variance) output units
            let d = 1 + self.detail as usize;
            let (no, ni) = (6 * d, 8 * d);
            spec.output_play = (1..=no).map(|i| 2.4 * i as f64 / no as f64).collect();
            spec.output_relays = 6 + 2 * self.detail as usize;
            // lags 1..n+1: the hysteretic force acts inside n-th order
            // continuous dynamics and varies between samples
            spec.hysteresis_lags = self.order + 1;
            spec.input_play =
                vec![(1..=ni).map(|i| 2.4 * i as f64 / ni as f64).collect(); n_inputs];
        }
        spec
    }
}

/// A fitted grey-box model with its signal names: simulatable, serialisable.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GreyBoxModel {
    /// Format version (see [`MODEL_FORMAT_VERSION`]).
    pub format_version: u32,
    /// Input signal names, in order.
    pub input_names: Vec<String>,
    /// Output signal name.
    pub output_name: String,
    /// What the model consists of.
    pub structure: Structure,
    /// The fitted network (one leaf when linear). For a model with
    /// [`lmn`](Self::lmn) it is a one-leaf placeholder that carries the noise
    /// model fitted on the network's simulation residuals.
    pub network: LocalModelNetwork,
    /// The full local model network of `greybox fit --model lmn` with
    /// `--weights/--splits/--prune/--focus/--max-leaves` (issue 3). When
    /// present it is what simulates.
    pub lmn: Option<LmnModel>,
    /// The hidden-state model (`gb-model`) the diagnosis chose when the
    /// input–output extensions did not suffice. When present it is what
    /// simulates, and [`network`](Self::network) is a one-leaf placeholder
    /// carrying the noise model of its simulation residuals.
    pub state_space: Option<SparseStateSpace>,
    /// The Wiener–Hammerstein local model network of `greybox fit --model
    /// wiener-hammerstein` (gb-lmn). When present it is what simulates (from
    /// the zero state), and [`network`](Self::network) is a one-leaf
    /// placeholder carrying the noise model.
    pub wiener_hammerstein: Option<WienerHammersteinNetwork>,
    /// The state-space local model network of `greybox fit --model
    /// lmn-state-space` (gb-lmn `SsLmnModel`). When present it is what
    /// simulates (initial state estimated from the init window).
    pub ss_lmn: Option<SsLmnModel>,
}

/// The model-file layout of format version 1 (no `lmn`).
#[derive(Deserialize)]
struct GreyBoxModelV1 {
    format_version: u32,
    input_names: Vec<String>,
    output_name: String,
    structure: StructureV2,
    network: LocalModelNetwork,
}

/// The model-file layout of format version 2 (no `state_space`).
#[derive(Deserialize)]
struct GreyBoxModelV2 {
    format_version: u32,
    input_names: Vec<String>,
    output_name: String,
    structure: StructureV2,
    network: LocalModelNetwork,
    lmn: Option<LmnModel>,
}

/// The one-leaf placeholder network (order `order`) of a model that
/// simulates through another class: it carries the Gaussian noise model of
/// that class's simulation residuals `res`.
fn noise_placeholder(order: usize, data: &DataSet, res: &[f64]) -> LocalModelNetwork {
    let spec = NetworkSpec::order(order, data.n_inputs());
    let mut network = gb_lmn::zero_linear_network(&spec, &data.inputs, &data.output);
    network.noise = gb_core::NoiseModel::gaussian(res);
    network
}

/// Options of [`GreyBoxModel::fit`].
#[derive(Debug, Clone, Default)]
pub struct ModelFitOptions {
    /// Output-error training options.
    pub fit: FitOptions,
    /// LOLIMOT options (network structures only).
    pub lolimot: LolimotOptions,
}

impl GreyBoxModel {
    /// Fit `structure` on `data` by output-error identification. `yreg` may
    /// give the free-run simulation of a previous model, used as output lags
    /// while LOLIMOT grows the network (output-error construction).
    pub fn fit(
        structure: Structure,
        data: &DataSet,
        yreg: Option<&[f64]>,
        warm: Option<&GreyBoxModel>,
        opts: &ModelFitOptions,
    ) -> Result<Self, DiagnoseError> {
        if structure.state_space {
            return Self::fit_state_space(structure, data);
        }
        let spec = structure.network_spec(data.n_inputs());
        let mut fopts = opts.fit.clone();
        fopts.robust = structure.robust_noise;
        let network = if structure.network {
            let mut lopts = opts.lolimot.clone();
            lopts.max_leaves = lopts.max_leaves.max(structure.max_leaves());
            fit_lmn_oe(&spec, &data.inputs, &data.output, yreg, &lopts, &fopts)?
        } else {
            fit_linear_oe_warm(
                &spec,
                &data.inputs,
                &data.output,
                &fopts,
                warm.map(|w| &w.network),
            )?
        };
        Ok(Self {
            format_version: MODEL_FORMAT_VERSION,
            input_names: data.input_names.clone(),
            output_name: data.output_name.clone(),
            structure,
            network,
            lmn: None,
            state_space: None,
            wiener_hammerstein: None,
            ss_lmn: None,
        })
    }

    /// Fit the hidden-state model of `structure` (`state_space` set) on
    /// `data` by output error (`gb-model`):
    ///
    /// * with `hysteresis`, one input and an oscillating best linear model:
    ///   the mechanical structure with a hidden restoring force z
    ///   (`ż = f(v, z)`, Bouc-Wen shape; [`gb_model::hysteretic_mechanical_start`]),
    ///   4 sub-steps per sample (8 when the fit with 4 improves on the linear
    ///   model by less than 10 %), wavelet levels 1–2;
    /// * otherwise the black-box start of `greybox fit --model
    ///   state-space[+preisach]` ([`gb_model::fit_state_space`]) with
    ///   `order` states and, with `hysteresis`, a Preisach component of the
    ///   first input with a wavelet Everett function.
    ///
    /// `network` becomes a one-leaf placeholder holding the Gaussian noise
    /// model of the simulation residuals.
    pub fn fit_state_space(structure: Structure, data: &DataSet) -> Result<Self, DiagnoseError> {
        let names: Vec<String> = data
            .input_names
            .iter()
            .chain(std::iter::once(&data.output_name))
            .cloned()
            .collect();
        let silent = gb_model::Silent;
        let mech = if structure.hysteresis && data.n_inputs() == 1 {
            let (u, y) = (&data.inputs[0], &data.output);
            let err = |m: &SparseStateSpace| -> f64 {
                m.simulate(&data.inputs)
                    .ok()
                    .and_then(|s| gb_core::metrics::nrmse(y, &s).ok())
                    .filter(|e| e.is_finite())
                    .unwrap_or(f64::INFINITY)
            };
            // symplectic Euler needs sub-steps for the start to follow the
            // linear model: 4, and 8 when the fit with 4 is stuck near the
            // linear model (less than 10 % better; no retry when it is not
            // better at all: the structure does not fit the data)
            let mut best: Option<(SparseStateSpace, gb_model::OeReport, f64)> = None;
            for substeps in [4, 8] {
                let Ok((mut s0, lin)) =
                    gb_model::hysteretic_mechanical_start(u, y, 0..data.len(), 1.0, substeps)
                else {
                    break;
                };
                s0.signal_names = names.clone();
                let e_lin = err(&lin);
                let Ok((m, rep)) = OeParams::new()
                    .max_iter(30)
                    .coarse_level(1)
                    .max_level(2)
                    .max_new(24)
                    .check()
                    .and_then(|p| p.fit(s0, &data.inputs, y, &silent))
                else {
                    break;
                };
                let e = err(&m);
                let retry = e < e_lin && e >= 0.9 * e_lin;
                if best.as_ref().is_none_or(|b| e < b.2) {
                    best = Some((m, rep, e));
                }
                if !retry {
                    break;
                }
            }
            best.map(|(m, r, _)| (m, r))
        } else {
            None
        };
        let (ss, _) = match mech {
            Some(m) => m,
            None => gb_model::fit_state_space(
                &data.inputs,
                &data.output,
                structure.order,
                structure.hysteresis,
                names,
                &silent,
            )?,
        };
        let sim = ss.simulate(&data.inputs)?;
        let res: Vec<f64> = data.output.iter().zip(&sim).map(|(a, b)| a - b).collect();
        let network = noise_placeholder(structure.order.min(MAX_ORDER), data, &res);
        Ok(Self {
            format_version: MODEL_FORMAT_VERSION,
            input_names: data.input_names.clone(),
            output_name: data.output_name.clone(),
            structure: Structure {
                order: ss.n_states,
                ..structure
            },
            network,
            lmn: None,
            state_space: Some(ss),
            wiener_hammerstein: None,
            ss_lmn: None,
        })
    }

    /// Fit the Wiener–Hammerstein local model network ([`WhParams`]) on a
    /// one-input `data`; `network` becomes a one-leaf placeholder holding the
    /// Gaussian noise model of the simulation residuals.
    pub fn fit_wiener_hammerstein(
        data: &DataSet,
        params: &WhParams,
    ) -> Result<(Self, gb_lmn::WhReport), DiagnoseError> {
        if data.n_inputs() != 1 {
            return Err(DiagnoseError::InvalidArgument(format!(
                "a Wiener-Hammerstein network has one input, got {}",
                data.n_inputs()
            )));
        }
        let (w, rep) = params.clone().check()?.fit(&data.inputs[0], &data.output)?;
        let sim = w.simulate(&data.inputs[0]);
        // past the transient of the zero state
        let k0 = 200.min(data.len() / 4);
        let res: Vec<f64> = data.output[k0..]
            .iter()
            .zip(&sim[k0..])
            .map(|(a, b)| a - b)
            .collect();
        let network = noise_placeholder(1, data, &res);
        let structure = Structure::linear(w.a1.len() - 1 + w.a2.len() - 1);
        Ok((
            Self {
                format_version: MODEL_FORMAT_VERSION,
                input_names: data.input_names.clone(),
                output_name: data.output_name.clone(),
                structure,
                network,
                lmn: None,
                state_space: None,
                wiener_hammerstein: Some(w),
                ss_lmn: None,
            },
            rep,
        ))
    }

    /// Fit the state-space local model network ([`SsLmnParams`], gb-lmn
    /// `fit_ss_lmn`) on `data`; `network` becomes a one-leaf placeholder
    /// holding the Gaussian noise model of the simulation residuals.
    pub fn fit_ss_lmn(data: &DataSet, params: &SsLmnParams) -> Result<Self, DiagnoseError> {
        params.check(data.n_inputs())?;
        let fit = gb_lmn::fit_ss_lmn(params, &data.inputs, &data.output)?;
        let w = params.init_window.min(data.len());
        let sim = fit
            .model
            .simulate_with_init_window(&data.inputs, &data.output, w)?;
        let res: Vec<f64> = data.output[w..]
            .iter()
            .zip(&sim[w..])
            .map(|(a, b)| a - b)
            .collect();
        let network = noise_placeholder(1, data, &res);
        Ok(Self {
            format_version: MODEL_FORMAT_VERSION,
            input_names: data.input_names.clone(),
            output_name: data.output_name.clone(),
            structure: Structure::linear(params.n_states),
            network,
            lmn: None,
            state_space: None,
            wiener_hammerstein: None,
            ss_lmn: Some(fit.model),
        })
    }

    /// Fit the full local model network ([`LmnModel`], issue 3) with
    /// `params` on `data`; `network` becomes a one-leaf placeholder holding
    /// the Gaussian noise model of the simulation residuals.
    pub fn fit_lmn(
        structure: Structure,
        data: &DataSet,
        params: &LmnParams,
    ) -> Result<Self, DiagnoseError> {
        Self::fit_lmn_experiments(structure, std::slice::from_ref(data), params)
    }

    /// [`fit_lmn`](Self::fit_lmn) on several records of the same signals,
    /// each a separate experiment (no regressor spans two records); the
    /// names come from the first.
    pub fn fit_lmn_experiments(
        structure: Structure,
        records: &[DataSet],
        params: &LmnParams,
    ) -> Result<Self, DiagnoseError> {
        let data = records
            .first()
            .ok_or_else(|| DiagnoseError::InvalidArgument("at least one training record".into()))?;
        let exps: Vec<Experiment> = records.iter().map(Experiment::from).collect();
        let lmn = params.fit(&exps)?;
        let mut res = vec![];
        for (e, d) in exps.iter().zip(records) {
            let k0 = lmn.max_lag().min(d.len());
            let sim = lmn.simulate(e, k0)?;
            res.extend(d.output[k0..].iter().zip(&sim[k0..]).map(|(a, b)| a - b));
        }
        let network = noise_placeholder(structure.order, data, &res);
        Ok(Self {
            format_version: MODEL_FORMAT_VERSION,
            input_names: data.input_names.clone(),
            output_name: data.output_name.clone(),
            structure,
            network,
            lmn: Some(lmn),
            state_space: None,
            wiener_hammerstein: None,
            ss_lmn: None,
        })
    }

    /// Free-run simulation whose initial state is estimated by least squares
    /// from the measured outputs `y_window` (see
    /// `LocalModelNetwork::simulate_with_init_window`).
    pub fn simulate_init_window(
        &self,
        inputs: &[Vec<f64>],
        y_window: &[f64],
    ) -> Result<Vec<f64>, DiagnoseError> {
        if let Some(ss) = &self.state_space {
            return Ok(ss.simulate_init_window(inputs, y_window)?);
        }
        if let Some(w) = &self.wiener_hammerstein {
            // filters start from the zero state; the window's samples are
            // the transient the caller does not score
            return Ok(w.simulate(&inputs[0]));
        }
        if let Some(m) = &self.ss_lmn {
            if y_window.len() >= m.n_states() {
                let n = inputs.first().map_or(0, Vec::len);
                let mut y = y_window.to_vec();
                y.resize(n.max(y.len()), 0.0);
                return Ok(m.simulate_with_init_window(inputs, &y, y_window.len())?);
            }
            return Ok(m.simulate_from(inputs, &vec![0.0; m.n_states()])?);
        }
        if let Some(l) = &self.lmn {
            let e = Experiment::new(inputs.to_vec(), y_window.to_vec());
            return Ok(l.simulate(&e, y_window.len())?);
        }
        Ok(self.network.simulate_with_init_window(inputs, y_window)?)
    }

    /// Free-run simulation from rest: zero output history for the
    /// input–output models, the zero state for the hidden-state model.
    pub fn simulate_from_rest(&self, inputs: &[Vec<f64>]) -> Result<Vec<f64>, DiagnoseError> {
        if let Some(ss) = &self.state_space {
            return Ok(ss.simulate_from(inputs, &vec![0.0; ss.n_states])?.0);
        }
        if let Some(w) = &self.wiener_hammerstein {
            return Ok(w.simulate(&inputs[0]));
        }
        if let Some(m) = &self.ss_lmn {
            return Ok(m.simulate_from(inputs, &vec![0.0; m.n_states()])?);
        }
        Ok(self.simulate(inputs, &vec![0.0; self.max_lag()])?)
    }

    /// Number of initial samples the simulation takes from measurements.
    pub fn max_lag(&self) -> usize {
        if self.state_space.is_some() || self.wiener_hammerstein.is_some() || self.ss_lmn.is_some()
        {
            return 0;
        }
        match &self.lmn {
            Some(l) => l.max_lag(),
            None => self.network.spec.max_lag(),
        }
    }

    /// Serialise (postcard, with a magic header and format version).
    pub fn to_bytes(&self) -> Result<Vec<u8>, DiagnoseError> {
        let mut out = MAGIC.to_vec();
        out.extend_from_slice(&MODEL_FORMAT_VERSION.to_le_bytes());
        let body = postcard::to_allocvec(self)
            .map_err(|e| DiagnoseError::ModelFile(format!("cannot encode model: {e}")))?;
        out.extend_from_slice(&body);
        Ok(out)
    }

    /// Deserialise from [`to_bytes`](Self::to_bytes) output; `name` labels errors.
    pub fn from_bytes(bytes: &[u8], name: &str) -> Result<Self, DiagnoseError> {
        if bytes.len() < 8 || &bytes[..4] != MAGIC {
            return Err(DiagnoseError::ModelFile(format!(
                "{name}: not a greybox model file"
            )));
        }
        let v = u32::from_le_bytes([bytes[4], bytes[5], bytes[6], bytes[7]]);
        let corrupt = |e: postcard::Error| {
            DiagnoseError::ModelFile(format!("{name}: truncated or corrupt model file ({e})"))
        };
        let m: Self = match v {
            MODEL_FORMAT_VERSION => postcard::from_bytes(&bytes[8..]).map_err(corrupt)?,
            1 => {
                let o: GreyBoxModelV1 = postcard::from_bytes(&bytes[8..]).map_err(corrupt)?;
                Self {
                    format_version: o.format_version,
                    input_names: o.input_names,
                    output_name: o.output_name,
                    structure: o.structure.into(),
                    network: o.network,
                    lmn: None,
                    state_space: None,
                    wiener_hammerstein: None,
                    ss_lmn: None,
                }
            }
            2 => {
                let o: GreyBoxModelV2 = postcard::from_bytes(&bytes[8..]).map_err(corrupt)?;
                Self {
                    format_version: o.format_version,
                    input_names: o.input_names,
                    output_name: o.output_name,
                    structure: o.structure.into(),
                    network: o.network,
                    lmn: o.lmn,
                    state_space: None,
                    wiener_hammerstein: None,
                    ss_lmn: None,
                }
            }
            _ => {
                return Err(DiagnoseError::ModelFile(format!(
                    "{name}: model format version {v}, this greybox reads versions 1 to {MODEL_FORMAT_VERSION}"
                )))
            }
        };
        if let Some(ss) = &m.state_space {
            ss.check().map_err(|e| {
                DiagnoseError::ModelFile(format!("{name}: inconsistent model ({e})"))
            })?;
            if ss.n_inputs != m.input_names.len() {
                return Err(DiagnoseError::ModelFile(format!(
                    "{name}: inconsistent model (state-space inputs)"
                )));
            }
        }
        if let Some(s) = &m.ss_lmn {
            s.check_consistency().map_err(|e| {
                DiagnoseError::ModelFile(format!("{name}: inconsistent model ({e})"))
            })?;
            if s.n_inputs() != m.input_names.len() {
                return Err(DiagnoseError::ModelFile(format!(
                    "{name}: inconsistent model (state-space network inputs)"
                )));
            }
        }
        if let Some(w) = &m.wiener_hammerstein {
            w.check().map_err(|e| {
                DiagnoseError::ModelFile(format!("{name}: inconsistent model ({e})"))
            })?;
            if m.input_names.len() != 1 {
                return Err(DiagnoseError::ModelFile(format!(
                    "{name}: inconsistent model (a Wiener-Hammerstein network has one input)"
                )));
            }
        }
        if let Some(l) = &m.lmn {
            if l.regressors.n_inputs() != m.input_names.len() {
                return Err(DiagnoseError::ModelFile(format!(
                    "{name}: inconsistent model (network inputs)"
                )));
            }
            l.check_consistency().map_err(|e| {
                DiagnoseError::ModelFile(format!("{name}: inconsistent model ({e})"))
            })?;
        }
        m.network
            .spec
            .check(m.input_names.len())
            .map_err(|e| DiagnoseError::ModelFile(format!("{name}: inconsistent model ({e})")))?;
        if m.network
            .leaves
            .iter()
            .any(|l| l.theta.len() != 1 + m.network.spec.n_dynamic())
            || m.network.beta.len() != m.network.spec.n_hysteresis()
            || m.network.input_scaling.len() != m.input_names.len()
        {
            return Err(DiagnoseError::ModelFile(format!(
                "{name}: inconsistent model parameters"
            )));
        }
        Ok(m)
    }

    /// Write the model file atomically.
    pub fn save(&self, path: &Path) -> Result<(), DiagnoseError> {
        gb_core::write_atomic(path, &self.to_bytes()?)?;
        Ok(())
    }

    /// Read a model file.
    pub fn load(path: &Path) -> Result<Self, DiagnoseError> {
        let bytes = std::fs::read(path).map_err(|source| CoreError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_bytes(&bytes, &path.display().to_string())
    }
}

impl GreyBoxModel {
    /// Number of inputs.
    pub fn n_inputs(&self) -> usize {
        self.input_names.len()
    }
    /// Free-run simulation; `init` holds measured outputs for the output lags.
    pub fn simulate(&self, inputs: &[Vec<f64>], init: &[f64]) -> Result<Vec<f64>, CoreError> {
        if let Some(ss) = &self.state_space {
            // the state space starts from its stored x₀; `init` (output
            // history of the input-output models) is not used
            return ss
                .simulate(inputs)
                .map_err(|e| CoreError::InvalidArgument(e.to_string()));
        }
        if let Some(m) = &self.ss_lmn {
            return Ok(m.simulate_from(inputs, &vec![0.0; m.n_states()])?);
        }
        if let Some(w) = &self.wiener_hammerstein {
            let u = inputs.first().ok_or_else(|| {
                CoreError::InvalidArgument("a Wiener-Hammerstein network needs its input".into())
            })?;
            return Ok(w.simulate(u));
        }
        if let Some(l) = &self.lmn {
            let e = Experiment::new(inputs.to_vec(), init.to_vec());
            return Ok(l.simulate(&e, init.len())?);
        }
        Ok(self.network.simulate_signals(inputs, init)?)
    }
}

impl GreyBoxModel {
    /// One-line description.
    pub fn describe(&self) -> String {
        if let Some(ss) = &self.state_space {
            return ss.describe();
        }
        if let Some(w) = &self.wiener_hammerstein {
            return format!("{}, {} noise", w.describe(), self.network.noise.describe());
        }
        if let Some(m) = &self.ss_lmn {
            return format!("{}, {} noise", m.describe(), self.network.noise.describe());
        }
        match &self.lmn {
            Some(l) => format!("{}, {} noise", l.describe(), self.network.noise.describe()),
            None => self.network.describe(),
        }
    }
    /// Number of estimated parameters.
    pub fn n_parameters(&self) -> usize {
        if let Some(ss) = &self.state_space {
            return ss.n_parameters();
        }
        if let Some(w) = &self.wiener_hammerstein {
            return w.n_parameters();
        }
        if let Some(m) = &self.ss_lmn {
            return m.parameters().len();
        }
        match &self.lmn {
            Some(l) => l.n_parameters(),
            None => self.network.n_parameters(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data() -> DataSet {
        let u: Vec<f64> = (0..600).map(|k| ((k * 7919) % 13) as f64 - 6.0).collect();
        let mut y = vec![0.0; 600];
        for k in 1..600 {
            y[k] = 0.5 * y[k - 1] + u[k - 1] + 0.05 * (u[k - 1]).powi(2);
        }
        DataSet::new(vec!["u".into()], "y".into(), vec![u], y).unwrap()
    }

    #[test]
    fn version_1_files_still_load_and_lmn_models_round_trip() {
        let d = data();
        let m =
            GreyBoxModel::fit(Structure::linear(1), &d, None, None, &Default::default()).unwrap();
        // versions 1 and 2: the structure without `state_space`, the model
        // without `lmn` (1) or without `state_space` (2)
        #[derive(Serialize)]
        struct S2 {
            order: usize,
            network: bool,
            hysteresis: bool,
            robust_noise: bool,
            detail: u8,
        }
        #[derive(Serialize)]
        struct V1<'a> {
            format_version: u32,
            input_names: &'a [String],
            output_name: &'a str,
            structure: S2,
            network: &'a LocalModelNetwork,
        }
        #[derive(Serialize)]
        struct V2<'a> {
            format_version: u32,
            input_names: &'a [String],
            output_name: &'a str,
            structure: S2,
            network: &'a LocalModelNetwork,
            lmn: Option<LmnModel>,
        }
        let s2 = || S2 {
            order: m.structure.order,
            network: m.structure.network,
            hysteresis: m.structure.hysteresis,
            robust_noise: m.structure.robust_noise,
            detail: m.structure.detail,
        };
        let mut bytes = MAGIC.to_vec();
        bytes.extend_from_slice(&1u32.to_le_bytes());
        bytes.extend(
            postcard::to_allocvec(&V1 {
                format_version: 1,
                input_names: &m.input_names,
                output_name: &m.output_name,
                structure: s2(),
                network: &m.network,
            })
            .unwrap(),
        );
        let back = GreyBoxModel::from_bytes(&bytes, "v1").unwrap();
        assert_eq!(back.network, m.network);
        assert_eq!(back.structure, m.structure);
        assert!(back.lmn.is_none() && back.state_space.is_none());
        let mut b2bytes = MAGIC.to_vec();
        b2bytes.extend_from_slice(&2u32.to_le_bytes());
        b2bytes.extend(
            postcard::to_allocvec(&V2 {
                format_version: 2,
                input_names: &m.input_names,
                output_name: &m.output_name,
                structure: s2(),
                network: &m.network,
                lmn: None,
            })
            .unwrap(),
        );
        let back2 = GreyBoxModel::from_bytes(&b2bytes, "v2").unwrap();
        assert_eq!(back2.network, m.network);
        assert_eq!(back2.structure, m.structure);
        // the full network: saved, reloaded, simulates identically
        let s = Structure::parse("lmn", 1).unwrap();
        let p = LmnParams::new(gb_lmn::RegressorSpec::arx(1, &[1], &[1])).max_leaves(3);
        let l = GreyBoxModel::fit_lmn(s, &d, &p).unwrap();
        let b2 = GreyBoxModel::from_bytes(&l.to_bytes().unwrap(), "lmn").unwrap();
        assert_eq!(b2, l);
        let sim = b2.simulate(&d.inputs, &d.output[..1]).unwrap();
        let e = gb_core::metrics::nrmse(&d.output[1..], &sim[1..]).unwrap();
        assert!(e < 0.05, "nrmse {e}");
        let mut bad = bytes.clone();
        bad[4] = 7;
        assert!(GreyBoxModel::from_bytes(&bad, "x").is_err());
    }

    /// A mass-spring system with a Bouc-Wen restoring force, sampled at 100 Hz.
    fn bouc_wen(n: usize) -> DataSet {
        let (k, c, a, b, g) = (400.0, 2.0, 300.0, 40.0, 30.0);
        let h = 0.01 / 20.0;
        let (mut x, mut v, mut z) = (0.0f64, 0.0f64, 0.0f64);
        let mut u = vec![0.0; n];
        let mut y = vec![0.0; n];
        for t in 0..n {
            // a deterministic multisine
            u[t] = (0..8)
                .map(|i| {
                    let f = 0.3 + 0.6 * i as f64;
                    (2.0 * std::f64::consts::PI * f * t as f64 * 0.01 + i as f64 * i as f64).sin()
                })
                .sum::<f64>()
                * 8.0;
            y[t] = x;
            for _ in 0..20 {
                let acc = u[t] - k * x - c * v - z;
                let dz = a * v - b * v.abs() * z - g * v * z.abs();
                x += h * v;
                v += h * acc;
                z += h * dz;
            }
        }
        DataSet::new(vec!["u".into()], "y".into(), vec![u], y).unwrap()
    }

    #[test]
    fn the_hidden_state_model_fits_bouc_wen_and_round_trips() {
        let d = bouc_wen(4000);
        let (train, test) = (d.slice(0..3000), d.slice(3000..4000));
        let lin = GreyBoxModel::fit(
            Structure::linear(2),
            &train,
            None,
            None,
            &Default::default(),
        )
        .unwrap();
        let s = Structure {
            state_space: true,
            hysteresis: true,
            ..Structure::linear(2)
        };
        let m = GreyBoxModel::fit_state_space(s, &train).unwrap();
        assert!(m.state_space.is_some());
        assert_eq!(m.structure.spec(), "state-space+hysteresis");
        let err = |g: &GreyBoxModel| {
            let sim = g
                .simulate_init_window(&test.inputs, &test.output[..50])
                .unwrap();
            gb_core::metrics::nrmse(&test.output[50..], &sim[50..]).unwrap()
        };
        let (e_lin, e_ss) = (err(&lin), err(&m));
        eprintln!("linear {e_lin:.4}, hidden state {e_ss:.4}");
        assert!(e_ss < 0.5 * e_lin, "hidden state {e_ss} vs linear {e_lin}");
        // model file version 3: reloads and simulates identically
        let back = GreyBoxModel::from_bytes(&m.to_bytes().unwrap(), "ss").unwrap();
        assert_eq!(back, m);
        assert_eq!(err(&back), e_ss);
    }
}
