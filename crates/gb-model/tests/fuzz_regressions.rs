//! Inputs that made the fuzz targets in `fuzz/` panic or abort (see
//! docs/fuzzing.md). Each must now give an error (or load and simulate)
//! without panicking.
use gb_core::Init;

/// What the `model_file` fuzz target does with its bytes.
fn load_and_simulate(bytes: &[u8]) {
    let Ok(m) = gb_model::registry::from_bytes(bytes, "fuzz.gbm") else {
        return;
    };
    let _ = m.describe();
    let u: Vec<Vec<f64>> = (0..m.input_names.len())
        .map(|j| (0..40).map(|k| (k as f64 * 0.3 + j as f64).sin()).collect())
        .collect();
    let _ = m.simulate(&u, Init::Stored);
    let _ = m.simulate(&u, Init::Rest);
    let y: Vec<f64> = (0..10).map(|k| (k as f64 * 0.1).cos()).collect();
    let _ = m.simulate(&u, Init::Window(&y));
}

/// An `lmn-tree` partition whose node names a parent out of range
/// (index out of bounds in `LmnModel::splits`).
#[test]
fn lmn_partition_with_bad_parent_is_an_error() {
    let bytes = include_bytes!("fuzz_regressions/model_file-lmn-parent.bin");
    assert!(gb_model::registry::from_bytes(bytes, "x.gbm").is_err());
    load_and_simulate(bytes);
}

/// A wavelet expansion whose shifts span ~10^13 grid cells (allocation
/// failure, abort, while decoding).
#[test]
fn wavelet_shifts_spanning_a_huge_grid_are_an_error() {
    let bytes = include_bytes!("fuzz_regressions/model_file-basis-grid.bin");
    assert!(gb_model::registry::from_bytes(bytes, "x.gbm").is_err());
}

/// An `io-network` whose partition-variable indices point outside the
/// regressor (index out of bounds in `LocalModelNetwork::fill_z`).
#[test]
fn io_network_with_bad_partition_index_is_an_error() {
    let bytes = include_bytes!("fuzz_regressions/model_file-io-network-z-index.bin");
    assert!(gb_model::registry::from_bytes(bytes, "x.gbm").is_err());
    load_and_simulate(bytes);
}

/// A state-space file whose state count overflows `n * n` (arithmetic
/// overflow panic in `SparseStateSpace::check`).
#[test]
fn state_space_with_overflowing_size_is_an_error() {
    let bytes = include_bytes!("fuzz_regressions/model_file-state-space-overflow.bin");
    assert!(gb_model::registry::from_bytes(bytes, "x.gbs").is_err());
}

/// A crash of the forked `model_file` run (fixed by the checks above).
#[test]
fn fork_run_crash_loads_without_panic() {
    load_and_simulate(include_bytes!(
        "fuzz_regressions/model_file-fork-2bc6591e.bin"
    ));
}
