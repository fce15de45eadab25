//! Model files written before format 4, converted on load.
//!
//! * Formats 1–3 stored one fixed struct: the signal names, a structure
//!   summary, an input–output network (a one-leaf placeholder carrying the
//!   noise model when another class simulates) and, from format 2 on, the
//!   other classes as optional fields. Format 3 gained `wiener_hammerstein`
//!   and then `ss_lmn` without a version bump, so three format-3 layouts
//!   exist; each is tried, longest first, and must consume the whole body.
//! * `GBS\x01` files were written by `greybox fit --model state-space` before
//!   the formats were unified.
use crate::SparseStateSpace;
use gb_core::{CoreError, DynamicModel, FittedModel, NoiseModel};
use gb_lmn::{LmnModel, LocalModelNetwork, SsLmnModel, WienerHammersteinNetwork};
use serde::de::DeserializeOwned;
use serde::Deserialize;

/// The structure summary of formats 1 and 2.
#[derive(Deserialize)]
#[allow(dead_code)]
struct StructureV2 {
    order: usize,
    network: bool,
    hysteresis: bool,
    robust_noise: bool,
    detail: u8,
}

/// The structure summary of format 3.
#[derive(Deserialize)]
#[allow(dead_code)]
struct StructureV3 {
    order: usize,
    network: bool,
    hysteresis: bool,
    robust_noise: bool,
    detail: u8,
    state_space: bool,
}

#[derive(Deserialize)]
struct V1 {
    _format_version: u32,
    input_names: Vec<String>,
    output_name: String,
    _structure: StructureV2,
    network: LocalModelNetwork,
}

#[derive(Deserialize)]
struct V2 {
    _format_version: u32,
    input_names: Vec<String>,
    output_name: String,
    _structure: StructureV2,
    network: LocalModelNetwork,
    lmn: Option<LmnModel>,
}

/// Format 3 as first written (the hidden-state model only).
#[derive(Deserialize)]
struct V3Early {
    _format_version: u32,
    input_names: Vec<String>,
    output_name: String,
    _structure: StructureV3,
    network: LocalModelNetwork,
    lmn: Option<LmnModel>,
    state_space: Option<SparseStateSpace>,
}

/// Format 3 with the Wiener–Hammerstein network.
#[derive(Deserialize)]
struct V3Wh {
    _format_version: u32,
    input_names: Vec<String>,
    output_name: String,
    _structure: StructureV3,
    network: LocalModelNetwork,
    lmn: Option<LmnModel>,
    state_space: Option<SparseStateSpace>,
    wiener_hammerstein: Option<WienerHammersteinNetwork>,
}

/// Format 3 as last written.
#[derive(Deserialize)]
struct V3 {
    _format_version: u32,
    input_names: Vec<String>,
    output_name: String,
    _structure: StructureV3,
    network: LocalModelNetwork,
    lmn: Option<LmnModel>,
    state_space: Option<SparseStateSpace>,
    wiener_hammerstein: Option<WienerHammersteinNetwork>,
    ss_lmn: Option<SsLmnModel>,
}

/// Decode `body` as `T`, requiring every byte to be used.
fn exact<T: DeserializeOwned>(body: &[u8]) -> Option<T> {
    match postcard::take_from_bytes::<T>(body) {
        Ok((v, [])) => Some(v),
        _ => None,
    }
}

/// The common fields of every layout, the class that simulates first.
struct Parts {
    input_names: Vec<String>,
    output_name: String,
    network: LocalModelNetwork,
    dynamics: Option<Box<dyn DynamicModel>>,
}

fn parts(version: u32, body: &[u8]) -> Option<Parts> {
    fn some<T: DynamicModel + 'static>(m: Option<T>) -> Option<Box<dyn DynamicModel>> {
        m.map(|m| Box::new(m) as Box<dyn DynamicModel>)
    }
    match version {
        1 => exact::<V1>(body).map(|o| Parts {
            input_names: o.input_names,
            output_name: o.output_name,
            network: o.network,
            dynamics: None,
        }),
        2 => exact::<V2>(body).map(|o| Parts {
            input_names: o.input_names,
            output_name: o.output_name,
            network: o.network,
            dynamics: some(o.lmn),
        }),
        _ => {
            if let Some(o) = exact::<V3>(body) {
                let d = some(o.state_space)
                    .or(some(o.wiener_hammerstein))
                    .or(some(o.ss_lmn))
                    .or(some(o.lmn));
                return Some(Parts {
                    input_names: o.input_names,
                    output_name: o.output_name,
                    network: o.network,
                    dynamics: d,
                });
            }
            if let Some(o) = exact::<V3Wh>(body) {
                let d = some(o.state_space)
                    .or(some(o.wiener_hammerstein))
                    .or(some(o.lmn));
                return Some(Parts {
                    input_names: o.input_names,
                    output_name: o.output_name,
                    network: o.network,
                    dynamics: d,
                });
            }
            exact::<V3Early>(body).map(|o| Parts {
                input_names: o.input_names,
                output_name: o.output_name,
                network: o.network,
                dynamics: some(o.state_space).or(some(o.lmn)),
            })
        }
    }
}

/// A model file of format 1, 2 or 3 (`body` after the 8-byte header).
pub(crate) fn from_format_1_to_3(
    version: u32,
    body: &[u8],
    name: &str,
) -> Result<FittedModel, CoreError> {
    let p = parts(version, body).ok_or_else(|| {
        CoreError::ModelFile(format!(
            "{name}: model file of format {version} that this greybox cannot decode (truncated or corrupt, or written by an unreleased older greybox); re-fit the model"
        ))
    })?;
    let inconsistent =
        |e: String| CoreError::ModelFile(format!("{name}: inconsistent model ({e})"));
    p.network
        .check_consistency()
        .map_err(|e| inconsistent(e.to_string()))?;
    let noise = p.network.noise.clone();
    let dynamics: Box<dyn DynamicModel> = match p.dynamics {
        Some(d) => {
            check_class(d.as_ref()).map_err(inconsistent)?;
            d
        }
        None => Box::new(p.network),
    };
    if !noise.is_valid() {
        return Err(inconsistent("noise model".into()));
    }
    FittedModel::new(p.input_names, vec![p.output_name], dynamics, noise)
        .map_err(|e| inconsistent(e.to_string()))
}

/// The consistency check a class's `decode` would run.
fn check_class(d: &dyn DynamicModel) -> Result<(), String> {
    let a = d.as_any();
    if let Some(m) = a.downcast_ref::<SparseStateSpace>() {
        return m.check().map_err(|e| e.to_string());
    }
    if let Some(m) = a.downcast_ref::<LmnModel>() {
        return m.check_consistency().map_err(|e| e.to_string());
    }
    if let Some(m) = a.downcast_ref::<WienerHammersteinNetwork>() {
        return m.check().map_err(|e| e.to_string());
    }
    if let Some(m) = a.downcast_ref::<SsLmnModel>() {
        return m.check_consistency().map_err(|e| e.to_string());
    }
    Ok(())
}

/// A `GBS\x01` state-space model file.
pub(crate) fn from_state_space_file(bytes: &[u8], name: &str) -> Result<FittedModel, CoreError> {
    let ss = SparseStateSpace::from_bytes(bytes)
        .map_err(|e| CoreError::ModelFile(format!("{name}: {e}")))?;
    let m = ss.n_inputs;
    let (inputs, output) = if ss.signal_names.len() == m + 1 {
        (ss.signal_names[..m].to_vec(), ss.signal_names[m].clone())
    } else {
        ((1..=m).map(|j| format!("u{j}")).collect(), "y".to_string())
    };
    let noise = match &ss.measurement_noise {
        n if n.is_valid() => n.clone(),
        _ => NoiseModel::Gaussian { sd: 1.0 },
    };
    FittedModel::new(inputs, vec![output], Box::new(ss), noise)
        .map_err(|e| CoreError::ModelFile(format!("{name}: inconsistent model ({e})")))
}
