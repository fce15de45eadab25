//! The model registry: every model class the workspace has, by the tag it
//! is stored under, and the one reader of model files.
//!
//! A class joins by implementing [`gb_core::DynamicModel`] and a checked
//! `decode(body, version)`, then one line in [`CLASSES`]. Files of format 4
//! name their class; files of formats 1–3 (a fixed struct holding every
//! class as an optional field) and the early state-space format (`GBS\x01`)
//! are converted on load ([`legacy`](crate::legacy)).
use crate::SparseStateSpace;
use gb_core::{ClassDecoder, CoreError, DynamicModel, FittedModel, MODEL_FORMAT_VERSION};
use gb_lmn::{LmnModel, LocalModelNetwork, SsLmnModel, WienerHammersteinNetwork};
use std::path::Path;

/// Decodes (and checks) a model-file body of a class version.
pub type DecodeFn = fn(&[u8], u32) -> Result<Box<dyn DynamicModel>, CoreError>;

/// A registered model class.
#[derive(Debug, Clone, Copy)]
pub struct ModelClass {
    /// Tag stored in model files ([`DynamicModel::class`]).
    pub tag: &'static str,
    /// One line for `--help` and the docs.
    pub summary: &'static str,
    /// Decodes (and checks) a model-file body of a class version.
    pub decode: DecodeFn,
}

fn boxed<T: DynamicModel + 'static>(
    r: Result<T, CoreError>,
) -> Result<Box<dyn DynamicModel>, CoreError> {
    r.map(|m| Box::new(m) as Box<dyn DynamicModel>)
}

/// Every model class, in the order `--help` lists them.
pub static CLASSES: &[ModelClass] = &[
    ModelClass {
        tag: "io-network",
        summary: "input-output model: linear output-error or LOLIMOT local model network, optional play-operator/Preisach columns (gb-lmn)",
        decode: |b, v| boxed(LocalModelNetwork::decode(b, v)),
    },
    ModelClass {
        tag: "lmn-tree",
        summary: "local model network with tree (HILOMOT) or Gaussian weights, oblique splits, pruning, NARX/NOE training (gb-lmn)",
        decode: |b, v| boxed(LmnModel::decode(b, v)),
    },
    ModelClass {
        tag: "wiener-hammerstein",
        summary: "Wiener-Hammerstein network: linear filter, static local model network, linear filter (gb-lmn)",
        decode: |b, v| boxed(WienerHammersteinNetwork::decode(b, v)),
    },
    ModelClass {
        tag: "lmn-state-space",
        summary: "state-space local model network with square-root basis and state bounds (gb-lmn)",
        decode: |b, v| boxed(SsLmnModel::decode(b, v)),
    },
    ModelClass {
        tag: "state-space",
        summary: "wavelet-sparse grey-box state space with hidden states and Preisach terms (gb-model)",
        decode: |b, v| boxed(SparseStateSpace::decode(b, v)),
    },
    ModelClass {
        tag: "block",
        summary: "block-oriented model: static spline or piecewise-linear maps of the inputs (Hammerstein) and/or the output (Wiener) around linear dynamics (gb-lmn)",
        decode: |b, v| boxed(gb_lmn::BlockModel::decode(b, v)),
    },
    ModelClass {
        tag: "poly-narx",
        summary: "polynomial NARX/NOE: terms of degree <= 3 in lagged outputs and inputs chosen by FROLS, refined for the simulation error (gb-lmn)",
        decode: |b, v| boxed(gb_lmn::PolyNarx::decode(b, v)),
    },
    ModelClass {
        tag: "integrating",
        summary: "integrating model: a model of any class simulates the output increments, which are summed (a pole at 1; gb-model)",
        decode: |b, v| boxed(crate::IntegratingModel::decode(b, v)),
    },
    ModelClass {
        tag: "input-operators",
        summary: "input operators: stop operators (hysteresis) and low-pass filters of the inputs as further inputs of a model of any class (gb-model)",
        decode: |b, v| boxed(crate::operators::OperatorInputsModel::decode(b, v)),
    },
    ModelClass {
        tag: "multi-output",
        summary: "several outputs: one one-output model of any class per output, sharing the inputs (no output is an input of another; gb-model)",
        decode: |b, v| boxed(crate::MultiOutputModel::decode(b, v)),
    },
    ModelClass {
        tag: "physics",
        summary: "the engineer's continuous-time equations from a model file (TOML), RK4, fitted with standard errors and intervals (gb-model)",
        decode: |b, v| boxed(crate::physics::PhysicsModel::decode(b, v)),
    },
];

/// The registry as a [`ClassDecoder`] for [`FittedModel::from_bytes`].
#[derive(Debug, Clone, Copy, Default)]
pub struct Registry;

impl ClassDecoder for Registry {
    fn decode(
        &self,
        class: &str,
        class_version: u32,
        body: &[u8],
    ) -> Option<Result<Box<dyn DynamicModel>, CoreError>> {
        CLASSES
            .iter()
            .find(|c| c.tag == class)
            .map(|c| (c.decode)(body, class_version))
    }
}

/// A model stored inside a wrapper class (`integrating`, `multi-output`,
/// `input-operators`): its class tag, class version and body. Postcard
/// writes a nested struct as its fields in order, so a wrapper body that
/// holds one is byte for byte the body that listed the three fields.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub(crate) struct StoredPart {
    class: String,
    class_version: u32,
    body: Vec<u8>,
}

impl StoredPart {
    /// The stored form of `m`.
    pub(crate) fn of(m: &dyn DynamicModel) -> Result<Self, CoreError> {
        Ok(Self {
            class: m.class().to_string(),
            class_version: m.class_version(),
            body: m.encode()?,
        })
    }

    /// The model, decoded through the registry: a part of the wrapper's own
    /// class (a nesting no writer produces) or of an unknown class is a
    /// model-file error; `unknown` says what the part is in that message.
    pub(crate) fn decode(
        &self,
        wrapper: &str,
        unknown: &str,
    ) -> Result<Box<dyn DynamicModel>, CoreError> {
        let class = self.class.as_str();
        if class == wrapper {
            return Err(CoreError::ModelFile(format!(
                "corrupt '{wrapper}' model (nested)"
            )));
        }
        Registry
            .decode(class, self.class_version, &self.body)
            .ok_or_else(|| CoreError::ModelFile(format!("'{wrapper}' model {unknown} '{class}'")))?
    }
}

/// Read a model file of any format greybox ever wrote; `name` labels errors.
pub fn from_bytes(bytes: &[u8], name: &str) -> Result<FittedModel, CoreError> {
    if bytes.len() >= 4 && &bytes[..4] == crate::model::MAGIC {
        return crate::legacy::from_state_space_file(bytes, name);
    }
    match FittedModel::format_version(bytes, name)? {
        MODEL_FORMAT_VERSION => FittedModel::from_bytes(bytes, name, &Registry),
        v @ 1..=3 => crate::legacy::from_format_1_to_3(v, &bytes[8..], name),
        v => Err(CoreError::ModelFile(format!(
            "{name}: model format version {v} was written by a newer greybox (this one reads versions 1 to {MODEL_FORMAT_VERSION})"
        ))),
    }
}

/// Read a model file.
pub fn load(path: &Path) -> Result<FittedModel, CoreError> {
    let bytes = std::fs::read(path).map_err(|source| CoreError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    from_bytes(&bytes, &path.display().to_string())
}

/// The registered class of `tag`.
pub fn class(tag: &str) -> Option<&'static ModelClass> {
    CLASSES.iter().find(|c| c.tag == tag)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Wrapper bodies written before `StoredPart` listed the part's three
    /// fields inline (`integrating`: class, version, body; `multi-output`:
    /// those and the noise per part): the bytes are the same, both ways.
    #[test]
    fn a_stored_part_keeps_the_inline_layout_of_earlier_files() {
        #[derive(serde::Serialize, serde::Deserialize)]
        struct Inline {
            class: String,
            class_version: u32,
            body: Vec<u8>,
            noise: gb_core::NoiseModel,
        }
        #[derive(serde::Serialize, serde::Deserialize)]
        struct Nested {
            part: StoredPart,
            noise: gb_core::NoiseModel,
        }
        let ss = SparseStateSpace::linear(vec![0.5], vec![1.0], vec![1.0], vec![0.0]).unwrap();
        let noise = gb_core::NoiseModel::Gaussian { sd: 0.25 };
        let inline = Inline {
            class: "state-space".into(),
            class_version: DynamicModel::class_version(&ss),
            body: ss.encode().unwrap(),
            noise: noise.clone(),
        };
        let old = postcard::to_allocvec(&inline).unwrap();
        let nested = Nested {
            part: StoredPart::of(&ss).unwrap(),
            noise,
        };
        assert_eq!(postcard::to_allocvec(&nested).unwrap(), old);
        let back: Nested = postcard::from_bytes(&old).unwrap();
        let m = back
            .part
            .decode("multi-output", "of an unknown class")
            .unwrap();
        assert_eq!(m.class(), "state-space");
        assert!(back.part.decode("state-space", "x").is_err());
    }

    #[test]
    fn tags_are_unique_and_match_the_models() {
        for (i, c) in CLASSES.iter().enumerate() {
            assert!(CLASSES[i + 1..].iter().all(|d| d.tag != c.tag), "{}", c.tag);
        }
        let ss = SparseStateSpace::linear(vec![0.5], vec![1.0], vec![1.0], vec![0.0]).unwrap();
        assert_eq!(DynamicModel::class(&ss), "state-space");
        assert!(class("state-space").is_some() && class("nope").is_none());
    }

    #[test]
    fn format_4_round_trip_and_errors() {
        let ss = SparseStateSpace::linear(
            vec![0.5, 0.1, -0.2, 0.3],
            vec![1.0, 0.0],
            vec![1.0, 0.0],
            vec![0.0],
        )
        .unwrap();
        let m = FittedModel::new(
            vec!["u".into()],
            vec!["y".into()],
            Box::new(ss),
            gb_core::NoiseModel::Gaussian { sd: 0.01 },
        )
        .unwrap();
        let bytes = m.to_bytes().unwrap();
        let back = from_bytes(&bytes, "m.gbm").unwrap();
        let u = vec![vec![1.0, 0.0, -1.0, 2.0]];
        assert_eq!(
            back.simulate(&u, gb_core::Init::Rest).unwrap(),
            m.simulate(&u, gb_core::Init::Rest).unwrap()
        );
        let mut v7 = bytes.clone();
        v7[4] = 7;
        let e = from_bytes(&v7, "m.gbm").unwrap_err().to_string();
        assert!(e.contains("newer greybox"), "{e}");
        let e = from_bytes(&bytes[..bytes.len() / 2], "m.gbm")
            .unwrap_err()
            .to_string();
        assert!(e.contains("m.gbm") && e.contains("corrupt"), "{e}");
    }

    /// A polynomial model fitted by its recipe is written and read back by
    /// the registry and simulates identically.
    #[test]
    fn poly_narx_file_round_trip() {
        let u: Vec<f64> = (0..800)
            .map(|k| ((k * 7919) % 23) as f64 / 11.0 - 1.0)
            .collect();
        let mut y = vec![0.0; 800];
        for k in 2..800 {
            y[k] = 0.5 * y[k - 1] - 0.2 * y[k - 2] + u[k - 1] + 0.4 * u[k - 1].powi(3);
        }
        let rec = gb_core::Record::new(vec!["u".into()], "y".into(), vec![u.clone()], y).unwrap();
        let spec: gb_core::ModelSpec = "poly:order=2,degree=3".parse().unwrap();
        let f =
            crate::recipes::fit(&spec, &gb_core::Records::single(rec), &gb_core::Silent).unwrap();
        assert_eq!(f.model.dynamics.class(), "poly-narx");
        let back = from_bytes(&f.model.to_bytes().unwrap(), "p.gbm").unwrap();
        assert_eq!(back.dynamics.class(), "poly-narx");
        let init = gb_core::Init::History(&[0.1, -0.2]);
        assert_eq!(
            back.simulate(std::slice::from_ref(&u), init).unwrap(),
            f.model.simulate(&[u], init).unwrap()
        );
        assert_eq!(back.describe(), f.model.describe());
    }

    /// Hammerstein and Wiener models fitted by their recipes are written and
    /// read back by the registry and simulate bit-identically.
    #[test]
    fn block_file_round_trip() {
        let u: Vec<f64> = (0..900)
            .map(|k| ((k * 7919) % 23) as f64 / 11.0 - 1.0)
            .collect();
        let mut y = vec![0.0; 900];
        for k in 2..900 {
            y[k] = 1.2 * y[k - 1] - 0.5 * y[k - 2] + 0.3 * u[k - 1].clamp(-0.6, 0.6);
        }
        let rec = gb_core::Record::new(vec!["u".into()], "y".into(), vec![u.clone()], y).unwrap();
        for name in ["hammerstein:order=2", "wiener:order=2"] {
            let spec: gb_core::ModelSpec = name.parse().unwrap();
            let f = crate::recipes::fit(
                &spec,
                &gb_core::Records::single(rec.clone()),
                &gb_core::Silent,
            )
            .unwrap();
            assert_eq!(f.model.dynamics.class(), "block", "{name}");
            let back = from_bytes(&f.model.to_bytes().unwrap(), "b.gbm").unwrap();
            assert_eq!(back.dynamics.class(), "block");
            let init = gb_core::Init::History(&[0.1, -0.2]);
            let (a, b) = (
                back.simulate(std::slice::from_ref(&u), init).unwrap(),
                f.model.simulate(std::slice::from_ref(&u), init).unwrap(),
            );
            assert!(
                a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()),
                "{name}"
            );
            assert_eq!(back.describe(), f.model.describe());
        }
    }
}
