//! Silverbox with the tree network on the real data in `../shared/data` (or
//! `$GREYBOX_DATA`); skipped with a notice when the folder is absent. The
//! full benchmark runs are `cargo run --release -p gb-lmn --example benchmarks`.
use gb_core::CsvTable;
use gb_core::{Record, Records};
use gb_lmn::{Focus, LmnParams, RegressorSpec, WeightKind};
use std::path::PathBuf;

fn data_dir() -> Option<PathBuf> {
    let default = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    gb_core::benchmark_data_dir(&default, "")
}

fn load(p: PathBuf) -> Record {
    let t = CsvTable::read(&p).expect("read");
    Record::from_table(&t, &["u".into()], Some("y")).expect("u, y")
}

/// Silverbox multisine test (init window 50): a 12-leaf affine tree network
/// over z = y(k−1), trained for simulation on the first 20 000 training
/// samples, simulates below the 0.5 mV.
#[test]
fn silverbox_tree_network_beats_half_a_millivolt() {
    let Some(dir) = data_dir() else { return };
    let train = load(dir.join("silverbox/train_multisine.csv")).slice(0..20_000);
    let test = load(dir.join("silverbox/test_multisine.csv"));
    let reg = RegressorSpec::arx(4, &[4], &[0]).with_z(vec![1], vec![vec![]]);
    let m = LmnParams::new(reg)
        .weights(WeightKind::Tree)
        .max_leaves(12)
        .focus(Focus::Simulation)
        .lm_iterations(15)
        .fit(&Records::single(train))
        .unwrap();
    let sim = m.simulate(&test, 50).unwrap();
    let rmse = gb_core::metrics::rmse(&test.output[50..], &sim[50..]).unwrap();
    eprintln!(
        "Silverbox: {} leaves, test RMSE {:.4} mV",
        m.n_leaves(),
        rmse * 1e3
    );
    assert!(rmse < 0.5e-3, "RMSE {rmse}");
}
