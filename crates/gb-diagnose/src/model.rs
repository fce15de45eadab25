//! The grey-box model the diagnosis builds: a linear output-error model or a
//! local model network, optionally with Preisach-type (play-operator)
//! hysteresis columns and a Student-t noise model.
use crate::DiagnoseError;
use gb_core::{CoreError, DataSet, Model, Simulate};
use gb_lmn::{
    fit_linear_oe_warm, fit_lmn_oe, Experiment, FitOptions, LmnModel, LmnParams, LocalModelNetwork,
    LolimotOptions, NetworkSpec,
};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Magic bytes at the start of a model file.
const MAGIC: &[u8; 4] = b"GBM\x01";
/// Version of the model-file format (2: optional tree/oblique network
/// [`GreyBoxModel::lmn`]; version-1 files are still read).
pub const MODEL_FORMAT_VERSION: u32 = 2;
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
    /// The fitted network (one leaf when linear). For a model with
    /// [`lmn`](Self::lmn) it is a one-leaf placeholder that carries the noise
    /// model fitted on the network's simulation residuals.
    pub network: LocalModelNetwork,
    /// The full local model network of `greybox fit --model lmn` with
    /// `--weights/--splits/--prune/--focus/--max-leaves` (issue 3). When
    /// present it is what simulates.
    pub lmn: Option<LmnModel>,
}

/// The model-file layout of format version 1 (no `lmn`).
#[derive(Deserialize)]
struct GreyBoxModelV1 {
    format_version: u32,
    input_names: Vec<String>,
    output_name: String,
    structure: Structure,
    network: LocalModelNetwork,
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
            lmn: None,
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
        let exp = Experiment::from(data);
        let lmn = params.fit(std::slice::from_ref(&exp))?;
        let k0 = lmn.max_lag().min(data.len());
        let sim = lmn.simulate(&exp, k0)?;
        let res: Vec<f64> = data.output[k0..]
            .iter()
            .zip(&sim[k0..])
            .map(|(a, b)| a - b)
            .collect();
        let spec = NetworkSpec::order(structure.order, data.n_inputs());
        let mut network = gb_lmn::zero_linear_network(&spec, &data.inputs, &data.output);
        network.noise = gb_lmn::NoiseFit::gaussian(&res);
        Ok(Self {
            format_version: MODEL_FORMAT_VERSION,
            input_names: data.input_names.clone(),
            output_name: data.output_name.clone(),
            structure,
            network,
            lmn: Some(lmn),
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
        if let Some(l) = &self.lmn {
            let e = Experiment::new(inputs.to_vec(), y_window.to_vec());
            return Ok(l.simulate(&e, y_window.len())?);
        }
        Ok(self.network.simulate_with_init_window(inputs, y_window)?)
    }

    /// Number of initial samples the simulation takes from measurements.
    pub fn max_lag(&self) -> usize {
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
                    structure: o.structure,
                    network: o.network,
                    lmn: None,
                }
            }
            _ => {
                return Err(DiagnoseError::ModelFile(format!(
                    "{name}: model format version {v}, this greybox reads versions 1 and {MODEL_FORMAT_VERSION}"
                )))
            }
        };
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

impl Simulate for GreyBoxModel {
    fn n_inputs(&self) -> usize {
        self.input_names.len()
    }
    fn simulate(&self, inputs: &[Vec<f64>], init: &[f64]) -> Result<Vec<f64>, CoreError> {
        if let Some(l) = &self.lmn {
            let e = Experiment::new(inputs.to_vec(), init.to_vec());
            return Ok(l.simulate(&e, init.len())?);
        }
        Ok(self.network.simulate_signals(inputs, init)?)
    }
}

impl Model for GreyBoxModel {
    fn describe(&self) -> String {
        match &self.lmn {
            Some(l) => format!("{}, {} noise", l.describe(), self.network.noise.describe()),
            None => self.network.describe(),
        }
    }
    fn n_parameters(&self) -> usize {
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
        // a version-1 file: the same fields without `lmn`
        #[derive(Serialize)]
        struct V1<'a> {
            format_version: u32,
            input_names: &'a [String],
            output_name: &'a str,
            structure: Structure,
            network: &'a LocalModelNetwork,
        }
        let mut bytes = MAGIC.to_vec();
        bytes.extend_from_slice(&1u32.to_le_bytes());
        bytes.extend(
            postcard::to_allocvec(&V1 {
                format_version: 1,
                input_names: &m.input_names,
                output_name: &m.output_name,
                structure: m.structure,
                network: &m.network,
            })
            .unwrap(),
        );
        let back = GreyBoxModel::from_bytes(&bytes, "v1").unwrap();
        assert_eq!(back.network, m.network);
        assert!(back.lmn.is_none());
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
}
