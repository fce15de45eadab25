//! Model files written by every released model-file format: real files, each
//! written by the `greybox` binary of an old commit (tests/fixtures/models,
//! see its README for the commit and command of every file).
//!
//! For every fixture, today's loader must either read it and simulate the
//! fixture's input exactly as the old binary did (its recorded `simulate`
//! output, to 1e-9 relative), or refuse it with a message that says the file
//! was written by an older greybox and must be re-fitted — never
//! "truncated or corrupt".
//!
//! Every file is read by the model registry (`gb_model::registry::load`),
//! as `greybox simulate` does: `.gbm` files of formats 1–3 (magic
//! `GBM\x01`; three format-3 layouts exist, because `wiener_hammerstein` and
//! `ss_lmn` were added without a version bump) and `.gbs` files (magic
//! `GBS\x01`, the gb-model state-space file that `greybox fit --model
//! state-space*` wrote) are converted to today's fitted model.
//!
//! Each model `NAME.gbm|gbs` has the old binary's
//! `greybox simulate NAME INPUT -o NAME.sim.csv` and
//! `… -o NAME.sim-iw50.csv --init-window 50` beside it. A sim file holds the
//! input columns, the measured output (column `y`) and the simulation
//! (`y_sim`), so it is both the input and the expected output here. The
//! simulation is redone the way today's `greybox simulate` does it: with
//! `--init-window 50` the initial state is estimated from the first 50
//! measured outputs where the model supports it; without, the model starts
//! from the state it stores (`Init::Stored`). The exceptions are listed in
//! [`OLD_SIMULATE_IGNORED_THE_WINDOW`] (old gb-model state-space files and
//! Wiener–Hammerstein networks).
use gb_core::CsvTable;
use gb_core::{FittedModel, Init};
use std::path::{Path, PathBuf};

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/models")
}

/// Relative tolerance of a re-simulation, against the largest |y_sim|.
const TOL: f64 = 1e-9;

/// Fixtures whose old `greybox simulate --init-window N` did NOT use the
/// window for the simulation: their `.sim-iw50.csv` is compared with the
/// simulation from the stored start.
///
/// * `.gbs` files (format-2-era binaries simulated gb-model files from the
///   stored x₀ and used the window only to skip samples when scoring);
///   today's binary estimates x₀ from the window instead.
/// * Wiener–Hammerstein networks (until session 15 they started every
///   simulation from the zero state); today, given measured outputs, they
///   start in the steady state of the first input.
const OLD_SIMULATE_IGNORED_THE_WINDOW: &[&str] = &[
    "v2-state-space.gbs",
    "v2-state-space-preisach.gbs",
    "v3-wiener-hammerstein.gbm",
    "v3-early-wh-wiener-hammerstein.gbm",
];

/// A model file as today's `greybox simulate` reads it (the registry).
fn load(path: &Path) -> Result<FittedModel, String> {
    gb_model::registry::load(path).map_err(|e| e.to_string())
}

/// Today's `greybox simulate MODEL DATA --init-window W` (without the file
/// output): the window estimates the initial state, no window starts from
/// the state the model stores; `use_window = false` ignores the window.
fn simulate_today(
    m: &FittedModel,
    inputs: &[Vec<f64>],
    y: &[f64],
    window: usize,
    use_window: bool,
) -> Result<Vec<f64>, String> {
    let init = if window > 0 && use_window {
        Init::Window(&y[..window])
    } else {
        Init::Stored
    };
    m.simulate(inputs, init).map_err(|e| e.to_string())
}

/// The old binary's simulations of `model`: (sim file, init window).
fn recorded_simulations(model: &str) -> Vec<(PathBuf, usize)> {
    let stem = model.rsplit_once('.').map_or(model, |(s, _)| s);
    let mut out = vec![];
    for entry in std::fs::read_dir(fixtures()).expect("fixture folder") {
        let name = entry
            .expect("entry")
            .file_name()
            .to_string_lossy()
            .to_string();
        let Some(rest) = name
            .strip_prefix(stem)
            .and_then(|r| r.strip_prefix(".sim"))
            .and_then(|r| r.strip_suffix(".csv"))
        else {
            continue;
        };
        let window = match rest {
            "" => 0,
            r => r
                .strip_prefix("-iw")
                .and_then(|n| n.parse().ok())
                .unwrap_or_else(|| panic!("{name}: expected NAME.sim.csv or NAME.sim-iwN.csv")),
        };
        out.push((fixtures().join(name), window));
    }
    out.sort();
    out
}

/// What today's loader must do with a fixture.
#[derive(Clone, Copy, PartialEq)]
enum Expect {
    /// Load, and simulate every recorded input as the old binary did.
    Loads,
    /// Load and simulate as the old binary did, or refuse with a clear
    /// message (written by an older greybox, re-fit).
    LoadsOrClearError,
}

/// Check one fixture; returns a line for the summary.
fn check(file: &str, expect: Expect) -> String {
    let path = fixtures().join(file);
    assert!(path.is_file(), "{} is missing", path.display());
    let m = match load(&path) {
        Ok(m) => m,
        Err(e) => {
            assert!(
                expect == Expect::LoadsOrClearError,
                "{file}: today's loader must read this file, got: {e}"
            );
            assert!(
                e.contains(file),
                "{file}: the error does not name the file: {e}"
            );
            assert!(
                !e.contains("truncated or corrupt"),
                "{file}: a valid file written by an older greybox is reported as \"truncated or corrupt\": {e}"
            );
            assert!(
                e.contains("written by an older greybox") && e.contains("re-fit"),
                "{file}: the error should say the file was written by an older greybox and must be re-fitted: {e}"
            );
            return format!("{file}: refused clearly ({e})");
        }
    };
    let sims = recorded_simulations(file);
    assert!(
        !sims.is_empty(),
        "{file}: no recorded simulation ({}.sim.csv) beside it",
        file.rsplit_once('.').map_or(file, |(s, _)| s)
    );
    let names = m.input_names.clone();
    let mut worst = 0.0f64;
    for (sim, window) in &sims {
        let t = CsvTable::read(sim).unwrap_or_else(|e| panic!("{e}"));
        let inputs: Vec<Vec<f64>> = names
            .iter()
            .map(|n| {
                t.column(n)
                    .unwrap_or_else(|e| panic!("{}: input {n}: {e}", sim.display()))
                    .to_vec()
            })
            .collect();
        // the old binary wrote the measured output as `y`
        let y = t.column("y").unwrap_or_else(|e| panic!("{e}"));
        let old = t.column("y_sim").unwrap_or_else(|e| panic!("{e}"));
        let use_window = !OLD_SIMULATE_IGNORED_THE_WINDOW.contains(&file);
        let now = simulate_today(&m, &inputs, y, *window, use_window)
            .unwrap_or_else(|e| panic!("{file} on {}: {e}", sim.display()));
        assert_eq!(now.len(), old.len(), "{}", sim.display());
        let scale = old.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        assert!(scale > 0.0 && scale.is_finite(), "{}", sim.display());
        let (k, dev) = now
            .iter()
            .zip(old)
            .map(|(a, b)| (a - b).abs())
            .enumerate()
            .fold(
                (0, 0.0f64),
                |(k0, d0), (k, d)| if d > d0 { (k, d) } else { (k0, d0) },
            );
        let rel = dev / scale;
        assert!(
            rel <= TOL,
            "{file} simulates {} differently from the binary that wrote it: sample {k}: {} now vs {} then (deviation {rel:.2e} of max |y_sim|, init window {window})",
            sim.display(),
            now[k],
            old[k]
        );
        worst = worst.max(rel);
    }
    format!(
        "{file}: loads, {} simulation(s) identical (largest deviation {worst:.1e} of max |y_sim|)",
        sims.len()
    )
}

/// Every model file in the folder — new fixtures are covered without a new
/// test. Each must be listed in the README table.
#[test]
fn every_model_file_in_the_folder() {
    let readme = std::fs::read_to_string(fixtures().join("README.md")).expect("README.md");
    let mut files: Vec<String> = std::fs::read_dir(fixtures())
        .expect("fixture folder")
        .map(|e| e.expect("entry").file_name().to_string_lossy().to_string())
        .filter(|n| n.ends_with(".gbm") || n.ends_with(".gbs"))
        .collect();
    files.sort();
    assert!(files.len() >= 40, "only {} model files", files.len());
    for f in &files {
        assert!(
            readme.contains(&format!("`{f}`")),
            "{f} is not in tests/fixtures/models/README.md"
        );
        eprintln!("{}", check(f, Expect::Loads));
    }
}

macro_rules! fixture_tests {
    ($($(#[$attr:meta])* $name:ident: $file:literal => $expect:ident;)*) => {
        $(
            #[test]
            $(#[$attr])*
            fn $name() {
                eprintln!("{}", check($file, Expect::$expect));
            }
        )*
    };
}

fixture_tests! {
    // format 1 (commit 746ac40)
    v1_linear: "v1-linear.gbm" => Loads;
    v1_lmn: "v1-lmn.gbm" => Loads;
    v1_linear_preisach: "v1-linear-preisach.gbm" => Loads;
    v1_lmn_preisach_student_t: "v1-lmn-preisach-student-t.gbm" => Loads;
    v1_diagnose_shock: "v1-diagnose-shock.gbm" => Loads;
    // format 2 (commit dd295ec) and its gb-model files
    v2_linear: "v2-linear.gbm" => Loads;
    v2_lmn: "v2-lmn.gbm" => Loads;
    v2_linear_preisach: "v2-linear-preisach.gbm" => Loads;
    v2_lmn_preisach_student_t: "v2-lmn-preisach-student-t.gbm" => Loads;
    v2_lmn_tree_oblique: "v2-lmn-tree-oblique.gbm" => Loads;
    v2_lmn_poly: "v2-lmn-poly.gbm" => Loads;
    v2_diagnose_shock: "v2-diagnose-shock.gbm" => Loads;
    v2_state_space: "v2-state-space.gbs" => Loads;
    v2_state_space_preisach: "v2-state-space-preisach.gbs" => Loads;
    // early format 3, state_space only (commit 7a3c1d9)
    v3_early_linear: "v3-early-linear.gbm" => LoadsOrClearError;
    v3_early_lmn: "v3-early-lmn.gbm" => LoadsOrClearError;
    v3_early_linear_preisach: "v3-early-linear-preisach.gbm" => LoadsOrClearError;
    v3_early_lmn_preisach_student_t: "v3-early-lmn-preisach-student-t.gbm" => LoadsOrClearError;
    v3_early_lmn_tree_oblique: "v3-early-lmn-tree-oblique.gbm" => LoadsOrClearError;
    v3_early_lmn_poly: "v3-early-lmn-poly.gbm" => LoadsOrClearError;
    v3_early_lmn_input_lags: "v3-early-lmn-input-lags.gbm" => LoadsOrClearError;
    v3_early_diagnose_shock: "v3-early-diagnose-shock.gbm" => LoadsOrClearError;
    v3_early_state_space: "v3-early-state-space.gbs" => Loads;
    v3_early_state_space_preisach: "v3-early-state-space-preisach.gbs" => Loads;
    v3_early_state_space_hysteresis: "v3-early-state-space-hysteresis.gbs" => Loads;
    // early format 3 with wiener_hammerstein, before ss_lmn (commit ed355e8)
    v3_early_wh_linear: "v3-early-wh-linear.gbm" => LoadsOrClearError;
    v3_early_wh_lmn: "v3-early-wh-lmn.gbm" => LoadsOrClearError;
    v3_early_wh_linear_preisach: "v3-early-wh-linear-preisach.gbm" => LoadsOrClearError;
    v3_early_wh_lmn_preisach_student_t: "v3-early-wh-lmn-preisach-student-t.gbm" => LoadsOrClearError;
    v3_early_wh_lmn_tree_oblique: "v3-early-wh-lmn-tree-oblique.gbm" => LoadsOrClearError;
    v3_early_wh_lmn_poly: "v3-early-wh-lmn-poly.gbm" => LoadsOrClearError;
    v3_early_wh_lmn_input_lags: "v3-early-wh-lmn-input-lags.gbm" => LoadsOrClearError;
    v3_early_wh_wiener_hammerstein: "v3-early-wh-wiener-hammerstein.gbm" => LoadsOrClearError;
    v3_early_wh_diagnose_shock: "v3-early-wh-diagnose-shock.gbm" => LoadsOrClearError;
    v3_early_wh_state_space: "v3-early-wh-state-space.gbs" => Loads;
    v3_early_wh_state_space_preisach: "v3-early-wh-state-space-preisach.gbs" => Loads;
    v3_early_wh_state_space_hysteresis: "v3-early-wh-state-space-hysteresis.gbs" => Loads;
    // final format 3 (commit d5e3027)
    v3_linear: "v3-linear.gbm" => Loads;
    v3_lmn: "v3-lmn.gbm" => Loads;
    v3_linear_preisach: "v3-linear-preisach.gbm" => Loads;
    v3_lmn_preisach_student_t: "v3-lmn-preisach-student-t.gbm" => Loads;
    v3_lmn_tree_oblique: "v3-lmn-tree-oblique.gbm" => Loads;
    v3_lmn_poly: "v3-lmn-poly.gbm" => Loads;
    v3_lmn_input_lags: "v3-lmn-input-lags.gbm" => Loads;
    v3_wiener_hammerstein: "v3-wiener-hammerstein.gbm" => Loads;
    v3_lmn_state_space: "v3-lmn-state-space.gbm" => Loads;
    v3_diagnose_shock: "v3-diagnose-shock.gbm" => Loads;
    v3_state_space: "v3-state-space.gbs" => Loads;
    v3_state_space_preisach: "v3-state-space-preisach.gbs" => Loads;
    v3_state_space_hysteresis: "v3-state-space-hysteresis.gbs" => Loads;
    v3_state_space_damper: "v3-state-space-damper.gbs" => Loads;
}

/// Online use: every fixture model whose class can step one sample at a
/// time, stepped from rest through its recorded input, gives bit for bit
/// the batch simulation from rest. Classes that cannot step say so with an
/// `Unsupported` error naming the class; at least half the fixtures step.
#[test]
fn stepping_sample_by_sample_equals_the_batch_simulation() {
    let mut files: Vec<String> = std::fs::read_dir(fixtures())
        .expect("fixture folder")
        .map(|e| e.expect("entry").file_name().to_string_lossy().to_string())
        .filter(|n| n.ends_with(".gbm") || n.ends_with(".gbs"))
        .collect();
    files.sort();
    let (mut stepped, mut refused) = (0, vec![]);
    for f in &files {
        let Ok(m) = load(&fixtures().join(f)) else {
            continue; // refused formats are checked by the fixture tests
        };
        let Some((sim, _)) = recorded_simulations(f).into_iter().next() else {
            continue;
        };
        let t = CsvTable::read(&sim).expect("sim file");
        let u: Vec<Vec<f64>> = m
            .input_names
            .iter()
            .map(|n| t.column(n).expect("input column").to_vec())
            .collect();
        let batch = m.dynamics.simulate(&u, Init::Rest).expect("batch");
        let mut s = match m.dynamics.stepper(Init::Rest) {
            Ok(s) => s,
            Err(e) => {
                let e = e.to_string();
                assert!(e.contains(m.dynamics.class()), "{f}: {e}");
                refused.push(f.clone());
                continue;
            }
        };
        let (mut uk, mut yk) = (vec![0.0; u.len()], [0.0]);
        for (k, b) in batch.iter().enumerate() {
            for (j, s) in u.iter().enumerate() {
                uk[j] = s[k];
            }
            s.step(&uk, &mut yk).expect("step");
            assert_eq!(yk[0].to_bits(), b.to_bits(), "{f}: sample {k}");
        }
        stepped += 1;
    }
    eprintln!("stepped {stepped} models; cannot step: {refused:?}");
    assert!(stepped * 2 >= stepped + refused.len(), "{refused:?}");
}
