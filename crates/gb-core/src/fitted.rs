//! A fitted model with its signal names and noise model, and the one model
//! file format.
//!
//! A model file is the 4-byte magic [`MODEL_FILE_MAGIC`], a little-endian
//! `u32` format version and a postcard body. Format 4 (this module) stores
//! an envelope: the class tag and the class's own encoding version, the
//! signal names, the sample time, the noise model and the class's encoded
//! parameters ([`DynamicModel::encode`]). A class changes its layout by
//! bumping its [`DynamicModel::class_version`], never the file format.
//! Formats 1–3 (one fixed struct) are read by the model registry, which
//! knows the classes.
use crate::{CoreError, DynamicModel, Init, NoiseModel};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Magic bytes at the start of every greybox model file.
pub const MODEL_FILE_MAGIC: &[u8; 4] = b"GBM\x01";
/// The model file format written by [`FittedModel::to_bytes`].
pub const MODEL_FORMAT_VERSION: u32 = 4;

/// Turns a class tag and encoded parameters back into a model (the model
/// registry implements it).
pub trait ClassDecoder {
    /// `None` when `class` is unknown; else the decoded model or an error
    /// (for example a `class_version` newer than this build reads).
    fn decode(
        &self,
        class: &str,
        class_version: u32,
        body: &[u8],
    ) -> Option<Result<Box<dyn DynamicModel>, CoreError>>;
}

/// A fitted model: its dynamics (any class), the names of its signals, the
/// sample time it was fitted at and the noise model of its output error.
#[derive(Debug, Clone)]
pub struct FittedModel {
    /// Input signal names, in order.
    pub input_names: Vec<String>,
    /// Output signal names, in order.
    pub output_names: Vec<String>,
    /// Sample time in seconds, when known.
    pub sample_time: Option<f64>,
    /// Noise model of the simulation error (one output).
    pub noise: NoiseModel,
    /// The dynamics.
    pub dynamics: Box<dyn DynamicModel>,
}

#[derive(Serialize, Deserialize)]
struct EnvelopeV4 {
    class: String,
    class_version: u32,
    input_names: Vec<String>,
    output_names: Vec<String>,
    sample_time: Option<f64>,
    noise: NoiseModel,
    body: Vec<u8>,
}

impl FittedModel {
    /// Wrap `dynamics`; the names must match its inputs and outputs.
    pub fn new(
        input_names: Vec<String>,
        output_names: Vec<String>,
        dynamics: Box<dyn DynamicModel>,
        noise: NoiseModel,
    ) -> Result<Self, CoreError> {
        if input_names.len() != dynamics.n_inputs() || output_names.len() != dynamics.n_outputs() {
            return Err(CoreError::Dimension(format!(
                "{} input and {} output names for a model with {} inputs and {} outputs",
                input_names.len(),
                output_names.len(),
                dynamics.n_inputs(),
                dynamics.n_outputs()
            )));
        }
        Ok(Self {
            input_names,
            output_names,
            sample_time: None,
            noise,
            dynamics,
        })
    }

    /// The output name (first output).
    pub fn output_name(&self) -> &str {
        self.output_names.first().map_or("", String::as_str)
    }

    /// `"<dynamics>, <noise> noise"`.
    pub fn describe(&self) -> String {
        format!(
            "{}, {} noise",
            self.dynamics.describe(),
            self.noise.describe()
        )
    }

    /// Free-run simulation (see [`DynamicModel::simulate`]).
    pub fn simulate(&self, u: &[Vec<f64>], init: Init<'_>) -> Result<Vec<f64>, CoreError> {
        self.dynamics.simulate(u, init)
    }

    /// The model file (format [`MODEL_FORMAT_VERSION`]).
    pub fn to_bytes(&self) -> Result<Vec<u8>, CoreError> {
        let env = EnvelopeV4 {
            class: self.dynamics.class().to_string(),
            class_version: self.dynamics.class_version(),
            input_names: self.input_names.clone(),
            output_names: self.output_names.clone(),
            sample_time: self.sample_time,
            noise: self.noise.clone(),
            body: self.dynamics.encode()?,
        };
        let mut out = MODEL_FILE_MAGIC.to_vec();
        out.extend_from_slice(&MODEL_FORMAT_VERSION.to_le_bytes());
        let body = postcard::to_allocvec(&env)
            .map_err(|e| CoreError::ModelFile(format!("cannot encode model: {e}")))?;
        out.extend_from_slice(&body);
        Ok(out)
    }

    /// The format version of a model file's bytes; an error naming `name`
    /// when they are not a greybox model file.
    pub fn format_version(bytes: &[u8], name: &str) -> Result<u32, CoreError> {
        if bytes.len() < 8 || &bytes[..4] != MODEL_FILE_MAGIC {
            return Err(CoreError::ModelFile(format!(
                "{name}: not a greybox model file"
            )));
        }
        Ok(u32::from_le_bytes([bytes[4], bytes[5], bytes[6], bytes[7]]))
    }

    /// Read a format-4 model file; `name` labels errors.
    pub fn from_bytes(
        bytes: &[u8],
        name: &str,
        classes: &dyn ClassDecoder,
    ) -> Result<Self, CoreError> {
        let v = Self::format_version(bytes, name)?;
        if v != MODEL_FORMAT_VERSION {
            return Err(CoreError::ModelFile(format!(
                "{name}: model format version {v}, this reader handles version {MODEL_FORMAT_VERSION}"
            )));
        }
        let env: EnvelopeV4 = postcard::from_bytes(&bytes[8..]).map_err(|e| {
            CoreError::ModelFile(format!("{name}: truncated or corrupt model file ({e})"))
        })?;
        let dynamics = classes
            .decode(&env.class, env.class_version, &env.body)
            .ok_or_else(|| {
                CoreError::ModelFile(format!(
                    "{name}: model class '{}' is unknown to this greybox (written by a newer version?)",
                    env.class
                ))
            })?
            .map_err(|e| CoreError::ModelFile(format!("{name}: {e}")))?;
        if !env.noise.is_valid() {
            return Err(CoreError::ModelFile(format!(
                "{name}: inconsistent model (noise model)"
            )));
        }
        let mut m = Self::new(env.input_names, env.output_names, dynamics, env.noise)
            .map_err(|e| CoreError::ModelFile(format!("{name}: inconsistent model ({e})")))?;
        m.sample_time = env.sample_time;
        Ok(m)
    }

    /// Write the model file atomically (no partial file on error).
    pub fn save(&self, path: &Path) -> Result<(), CoreError> {
        crate::write_atomic(path, &self.to_bytes()?)
    }
}

/// Decode a class body written with postcard, refusing class versions newer
/// than `max_version` with a clear message.
pub fn decode_postcard<T: serde::de::DeserializeOwned>(
    class: &str,
    class_version: u32,
    max_version: u32,
    body: &[u8],
) -> Result<T, CoreError> {
    if class_version > max_version {
        return Err(CoreError::ModelFile(format!(
            "model class '{class}' version {class_version} was written by a newer greybox (this one reads up to {max_version})"
        )));
    }
    postcard::from_bytes(body)
        .map_err(|e| CoreError::ModelFile(format!("truncated or corrupt '{class}' model ({e})")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Workspace;
    use std::any::Any;

    #[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
    struct Gain {
        k: f64,
    }
    impl DynamicModel for Gain {
        fn class(&self) -> &'static str {
            "test-gain"
        }
        fn n_inputs(&self) -> usize {
            1
        }
        fn n_states(&self) -> usize {
            0
        }
        fn describe(&self) -> String {
            format!("gain {}", self.k)
        }
        fn n_parameters(&self) -> usize {
            1
        }
        fn simulate_into(
            &self,
            u: &[Vec<f64>],
            _: Init<'_>,
            y: &mut [f64],
            _: &mut Workspace,
        ) -> Result<(), CoreError> {
            for (o, i) in y.iter_mut().zip(&u[0]) {
                *o = self.k * i;
            }
            Ok(())
        }
        fn encode(&self) -> Result<Vec<u8>, CoreError> {
            postcard::to_allocvec(self).map_err(|e| CoreError::ModelFile(e.to_string()))
        }
        fn clone_box(&self) -> Box<dyn DynamicModel> {
            Box::new(self.clone())
        }
        fn as_any(&self) -> &dyn Any {
            self
        }
    }
    struct Classes;
    impl ClassDecoder for Classes {
        fn decode(
            &self,
            class: &str,
            v: u32,
            body: &[u8],
        ) -> Option<Result<Box<dyn DynamicModel>, CoreError>> {
            (class == "test-gain").then(|| {
                decode_postcard::<Gain>(class, v, 1, body)
                    .map(|g| Box::new(g) as Box<dyn DynamicModel>)
            })
        }
    }

    #[test]
    fn round_trip_and_clear_errors() {
        let m = FittedModel::new(
            vec!["u".into()],
            vec!["y".into()],
            Box::new(Gain { k: 2.5 }),
            NoiseModel::Gaussian { sd: 0.1 },
        )
        .unwrap();
        let bytes = m.to_bytes().unwrap();
        let back = FittedModel::from_bytes(&bytes, "m.gbm", &Classes).unwrap();
        assert_eq!(back.describe(), m.describe());
        assert_eq!(
            back.simulate(&[vec![1.0, 2.0]], Init::Rest).unwrap(),
            [2.5, 5.0]
        );
        // truncated
        let e = FittedModel::from_bytes(&bytes[..bytes.len() - 3], "m.gbm", &Classes)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("m.gbm: ") && e.contains("corrupt"), "{e}");
        // not a model file, other version
        let e = FittedModel::from_bytes(b"hello world", "x", &Classes).unwrap_err();
        assert!(e.to_string().contains("not a greybox model file"));
        let mut v9 = bytes.clone();
        v9[4] = 9;
        assert!(FittedModel::from_bytes(&v9, "x", &Classes).is_err());
        // unknown class
        struct None_;
        impl ClassDecoder for None_ {
            fn decode(
                &self,
                _: &str,
                _: u32,
                _: &[u8],
            ) -> Option<Result<Box<dyn DynamicModel>, CoreError>> {
                None
            }
        }
        let e = FittedModel::from_bytes(&bytes, "x", &None_)
            .unwrap_err()
            .to_string();
        assert!(e.contains("'test-gain' is unknown"), "{e}");
        // newer class version
        let e = decode_postcard::<Gain>("test-gain", 2, 1, &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains("newer greybox"), "{e}");
        // names must match the dynamics
        assert!(FittedModel::new(
            vec![],
            vec!["y".into()],
            Box::new(Gain { k: 1.0 }),
            NoiseModel::Gaussian { sd: 1.0 }
        )
        .is_err());
    }
}
