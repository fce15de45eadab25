//! A simulated magnetorheological damper from the data folder diagnosed as
//! a user would (`$GREYBOX_DATA`, default `../shared/data`; skipped with a
//! notice when the folder is absent unless `GREYBOX_REQUIRE_DATA` is set):
//! SysIdentPy's Spencer-model record (inputs displacement x, velocity v,
//! voltage E; output force f), the book's split — training rows 400–1999,
//! test rows 2001–3599 — the test scored once by `greybox simulate`.
mod common;
use common::{csv_rows, run, scratch, simulated, text};
use std::path::{Path, PathBuf};

/// Rows `rows` of `from` (after its header), columns x, v, E, f, written to
/// `to` (the record's column `a` holds spikes and is left out).
fn rows(from: &Path, to: &Path, rows: std::ops::Range<usize>) {
    csv_rows(from, to, rows, Some(&["x", "v", "E", "f"]));
}

/// The force is a voltage-scaled Bouc–Wen loop of the displacement: the
/// diagnosis names `hysteresis` (the static polynomial with the stop
/// operators of x) and the test NRMSE falls below 0.12 (0.080 measured).
/// Until session 65 no extension paid and the linear model stayed (0.508):
/// the static hysteresis was found but refused because, on this repeated
/// excitation, time-reversing the samples paired x with a velocity of the
/// opposite sign.
#[test]
fn a_simulated_damper_is_named_hysteresis_and_its_loop_modelled() {
    let default = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    let Some(dir) = gb_core::benchmark_data_dir(&default, "mr_damper_boucwen_sim_sysidentpy")
    else {
        return;
    };
    let src = dir
        .join("mr_damper_boucwen_sim_sysidentpy")
        .join("boucwen_histeretic_system.csv");
    let d = scratch("greybox-cli", "mr-damper-sim");
    let (train, test, model, sim) = (
        d.join("train.csv"),
        d.join("test.csv"),
        d.join("m.gbm"),
        d.join("sim.csv"),
    );
    rows(&src, &train, 400..2000);
    rows(&src, &test, 2001..3600);
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let o = run(&[
        "diagnose",
        &s(&train),
        "--output",
        "f",
        "--quiet",
        "--save",
        &s(&model),
    ]);
    let (out, err) = text(&o);
    assert!(o.status.success(), "{out}\n{err}");
    assert!(out.contains("causes: hysteresis"), "{out}");
    let got = simulated(&model, &test, &sim, 50, "NRMSE ");
    eprintln!("simulated MR damper: test NRMSE {got:.4} (linear 0.508)");
    assert!(got < 0.12, "test NRMSE {got:.4}\n{out}");
}
