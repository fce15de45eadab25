//! The grey-box model the diagnosis builds: a linear output-error model or a
//! local model network, optionally with Preisach-type (play-operator)
//! hysteresis columns and a Student-t noise model.
use crate::DiagnoseError;
use gb_core::{CoreError, DataSet, Model, Simulate};
use gb_lmn::{
    fit_linear_oe_warm, fit_lmn_oe, FitOptions, LocalModelNetwork, LolimotOptions, NetworkSpec,
};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Magic bytes at the start of a model file.
const MAGIC: &[u8; 4] = b"GBM\x01";
/// Version of the model-file format.
pub const MODEL_FORMAT_VERSION: u32 = 1;
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
        let mut s = String::from(if self.network { "lmn" } else { "linear" });
        if self.hysteresis {
            s.push_str("+preisach");
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
    /// The fitted network (one leaf when linear).
    pub network: LocalModelNetwork,
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
        Ok(self.network.simulate_with_init_window(inputs, y_window)?)
    }

    /// Number of initial samples the simulation takes from measurements.
    pub fn max_lag(&self) -> usize {
        self.network.spec.max_lag()
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
        if v != MODEL_FORMAT_VERSION {
            return Err(DiagnoseError::ModelFile(format!(
                "{name}: model format version {v}, this greybox reads version {MODEL_FORMAT_VERSION}"
            )));
        }
        let m: Self = postcard::from_bytes(&bytes[8..]).map_err(|e| {
            DiagnoseError::ModelFile(format!("{name}: truncated or corrupt model file ({e})"))
        })?;
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

impl Simulate for GreyBoxModel {
    fn n_inputs(&self) -> usize {
        self.input_names.len()
    }
    fn simulate(&self, inputs: &[Vec<f64>], init: &[f64]) -> Result<Vec<f64>, CoreError> {
        Ok(self.network.simulate_signals(inputs, init)?)
    }
}

impl Model for GreyBoxModel {
    fn describe(&self) -> String {
        self.network.describe()
    }
    fn n_parameters(&self) -> usize {
        self.network.n_parameters()
    }
}
