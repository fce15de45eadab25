//! `--model-file` on real benchmarks (`$GREYBOX_DATA`, default
//! `../shared/data`; skipped with a notice when the folder is absent unless
//! `GREYBOX_REQUIRE_DATA` is set): the plain Torricelli model of
//! `examples/models/cascaded_tanks.toml`, then its diagnosis on the
//! training record only, the test set scored once, init window 50, and the
//! blind diagnosis of the same record (no model file); the
//! Bouc–Wen benchmark's own ODE with an estimated input delay
//! (`examples/models/bouc_wen.toml`), and the diagnosis of a linear
//! mass–spring–damper on the same data (`bouc_wen_linear.toml`), each
//! scored on the multisine test period in periodic steady state.
use std::path::{Path, PathBuf};
use std::process::Command;

fn data_dir() -> Option<PathBuf> {
    data_dir_of("cascaded_tanks")
}

fn data_dir_of(benchmark: &str) -> Option<PathBuf> {
    let default = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    gb_core::benchmark_data_dir(&default, benchmark)
}

fn greybox(args: &[&str]) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_greybox"))
        .args(args)
        .output()
        .expect("run greybox");
    let (so, se) = (
        String::from_utf8_lossy(&o.stdout).to_string(),
        String::from_utf8_lossy(&o.stderr).to_string(),
    );
    assert_eq!(o.status.code(), Some(0), "{args:?}\n{so}\n{se}");
    so
}

/// The RMSE printed by `simulate`.
fn rmse(out: &str) -> f64 {
    out.lines()
        .find_map(|l| l.split("RMSE ").nth(1))
        .and_then(|r| r.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no RMSE in\n{out}"))
}

/// The test RMSE of `model` simulated by `greybox simulate` on `test`
/// (init window 50), the simulation written to `sim`.
fn tanks_test_rmse(model: &Path, test: &Path, sim: &Path) -> f64 {
    let s = |p: &Path| p.to_str().unwrap().to_string();
    rmse(&greybox(&[
        "simulate",
        &s(model),
        &s(test),
        "-o",
        &s(sim),
        "--init-window",
        "50",
    ]))
}

#[test]
fn tanks_physics_file_and_its_diagnosis_on_the_test_set() {
    let Some(dir) = data_dir() else { return };
    let tanks = dir.join("cascaded_tanks");
    let (train, test) = (tanks.join("train.csv"), tanks.join("test.csv"));
    let file =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../examples/models/cascaded_tanks.toml");
    let out = std::env::temp_dir().join(format!("greybox-tanks-{}", std::process::id()));
    std::fs::create_dir_all(&out).unwrap();
    let (fit, diag, sim) = (
        out.join("fit.gbm"),
        out.join("diag.gbm"),
        out.join("sim.csv"),
    );
    let s = |p: &PathBuf| p.to_str().unwrap().to_string();
    let fo = greybox(&["fit", &s(&train), "--model-file", &s(&file), "-o", &s(&fit)]);
    // the scaling symmetry of the unmeasured upper level is reported
    assert!(fo.contains("not identifiable"), "{fo}");
    let plain = tanks_test_rmse(&fit, &test, &sim);
    let d = greybox(&[
        "diagnose",
        &s(&train),
        "--model-file",
        &s(&file),
        "--save",
        &s(&diag),
        "--quiet",
    ]);
    assert!(d.contains("causes: nonlinearity"), "{d}");
    let diagnosed = tanks_test_rmse(&diag, &test, &sim);
    // measured 2026-11-24: 0.686 V plain, 0.532 V diagnosed; 2026-11-29:
    // 0.491 V diagnosed (the saved model refitted on all training samples)
    assert!(plain < 0.75, "plain physics test RMSE {plain}");
    assert!(
        diagnosed < 0.9 * plain,
        "diagnosed {diagnosed} vs plain {plain}"
    );
    let _ = std::fs::remove_dir_all(&out);
}

/// The blind diagnosis of the cascaded tanks' 1024 training samples (no
/// model file, no validation record): too short for the bootstrap, its
/// decisions cross-validate over the whole record, report block included,
/// and there the state-space network with a square-root basis and learned
/// state bounds pays; held out of the folds, the last quarter left them
/// unable to tell it from the linear model (+0.12 [−0.37, +0.52]) and the
/// diagnosis kept the linear baseline, 0.604 V on the test set.
#[test]
fn tanks_blind_diagnosis_cross_validates_over_the_whole_short_record() {
    let Some(dir) = data_dir() else { return };
    let tanks = dir.join("cascaded_tanks");
    let (train, test) = (tanks.join("train.csv"), tanks.join("test.csv"));
    let out = std::env::temp_dir().join(format!("greybox-tanks-blind-{}", std::process::id()));
    std::fs::create_dir_all(&out).unwrap();
    let (diag, sim) = (out.join("diag.gbm"), out.join("sim.csv"));
    let s = |p: &PathBuf| p.to_str().unwrap().to_string();
    let d = greybox(&["diagnose", &s(&train), "--save", &s(&diag), "--quiet"]);
    assert!(
        d.contains("folds over the 1024 training samples")
            && d.contains("the report block included"),
        "{d}"
    );
    // the figures on the report block are labelled in-sample
    assert!(d.contains("(the report block in-sample"), "{d}");
    assert!(d.contains("causes: nonlinearity"), "{d}");
    assert!(d.contains("final: state-space LMN"), "{d}");
    let cv = |key: &str| -> f64 {
        d.rsplit("cross-validated NRMSE (")
            .next()
            .and_then(|t| t.split(key).nth(1))
            .and_then(|t| t.split([',', ';', '\n']).next())
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or_else(|| panic!("no cross-validated {key} in\n{d}"))
    };
    // measured 2026-11-30: 0.336 -> 0.103
    assert!(cv("final") < 0.5 * cv("baseline"), "{d}");
    let diagnosed = tanks_test_rmse(&diag, &test, &sim);
    // measured 2026-11-30: 0.206 V (the linear baseline 0.604 V, the
    // published LTI 0.588 V, the best published 0.191 V)
    assert!(diagnosed < 0.3, "blind diagnosis test RMSE {diagnosed} V");
    let _ = std::fs::remove_dir_all(&out);
}

/// The RMSE of `model` on the second of the two test periods in `test2`
/// (the periodic steady state).
fn periodic_test_rmse(model: &Path, test2: &Path, sim: &Path, period: usize) -> f64 {
    let s = |p: &Path| p.to_str().unwrap().to_string();
    greybox(&["simulate", &s(model), &s(test2), "-o", &s(sim)]);
    let csv = std::fs::read_to_string(sim).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |n: &str| header.iter().position(|h| *h == n).unwrap();
    let (iy, is) = (col("y"), col("y_sim"));
    let err: Vec<f64> = lines
        .skip(period)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            v[iy] - v[is]
        })
        .collect();
    assert_eq!(err.len(), period);
    (err.iter().map(|e| e * e).sum::<f64>() / period as f64).sqrt()
}

/// The multisine test period twice (header once) in `dir`: its path and
/// the period.
fn test_twice(bw: &Path, dir: &Path) -> (PathBuf, usize) {
    let test = std::fs::read_to_string(bw.join("test_multisine.csv")).unwrap();
    let body = test.split_once('\n').unwrap().1;
    let test2 = dir.join("test2.csv");
    std::fs::write(&test2, format!("{test}{body}")).unwrap();
    (test2, body.lines().count())
}

fn example(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../examples/models")
        .join(name)
}

/// The benchmark's ODE with a free input delay started at 0: the delay
/// comes out at half a sample early (the data's output is read mid-way
/// through each held input) and the multisine test period, simulated
/// twice from the stored state and the second period scored, is below
/// 5e-6 m (issue 17's goal; without the delay 7.1e-5 m).
#[test]
fn bouc_wen_physics_file_with_an_input_delay_on_the_test_set() {
    let Some(dir) = data_dir_of("bouc_wen") else {
        return;
    };
    let bw = dir.join("bouc_wen");
    let train = bw.join("train_multisine_forgione.csv");
    let file = example("bouc_wen.toml");
    let out = std::env::temp_dir().join(format!("greybox-bw-physics-{}", std::process::id()));
    std::fs::create_dir_all(&out).unwrap();
    let (fit, sim) = (out.join("fit.gbm"), out.join("sim.csv"));
    let s = |p: &PathBuf| p.to_str().unwrap().to_string();
    let (test2, period) = test_twice(&bw, &out);
    let fo = greybox(&["fit", &s(&train), "--model-file", &s(&file), "-o", &s(&fit)]);
    let td: f64 = fo
        .lines()
        .find(|l| l.split_whitespace().next() == Some("td"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no td in\n{fo}"));
    let ts = 1.0 / 750.0;
    assert!(
        (td / ts + 0.5).abs() < 0.1,
        "td = {td} ({} samples)",
        td / ts
    );
    let rmse = periodic_test_rmse(&fit, &test2, &sim, period);
    println!(
        "Bouc-Wen physics with input delay: td = {td:.4e} s, multisine test RMSE {rmse:.3e} m"
    );
    assert!(rmse < 5e-6, "test RMSE {rmse:e}");
    let _ = std::fs::remove_dir_all(&out);
}

/// A linear mass–spring–damper file on the Bouc–Wen data: the diagnosis
/// adds the hysteretic state (driven by the displacement) and the input
/// delay, and the multisine test RMSE falls from the linear model's level
/// (1.7e-4 m) below 5e-6 m. Run with `--max-steps 2`: the two steps are
/// what this test claims; the third step's search (none of its candidates
/// pays; 90 of the diagnosis' 250 s in release, measured 2026-11-30) is
/// left to the documented run of docs/results.md.
#[test]
fn bouc_wen_from_a_linear_file_the_diagnosis_finds_hysteresis_and_timing() {
    let Some(dir) = data_dir_of("bouc_wen") else {
        return;
    };
    let bw = dir.join("bouc_wen");
    let train = bw.join("train_multisine_forgione.csv");
    let file = example("bouc_wen_linear.toml");
    let out = std::env::temp_dir().join(format!("greybox-bw-linear-{}", std::process::id()));
    std::fs::create_dir_all(&out).unwrap();
    let (fit, diag, sim) = (
        out.join("fit.gbm"),
        out.join("diag.gbm"),
        out.join("sim.csv"),
    );
    let s = |p: &PathBuf| p.to_str().unwrap().to_string();
    let (test2, period) = test_twice(&bw, &out);
    greybox(&["fit", &s(&train), "--model-file", &s(&file), "-o", &s(&fit)]);
    let plain = periodic_test_rmse(&fit, &test2, &sim, period);
    let d = greybox(&[
        "diagnose",
        &s(&train),
        "--model-file",
        &s(&file),
        "--save",
        &s(&diag),
        "--quiet",
        "--max-steps",
        "2",
    ]);
    assert!(d.contains("causes: hysteresis, dynamics"), "{d}");
    assert!(d.contains("input delay t_delay"), "{d}");
    let diagnosed = periodic_test_rmse(&diag, &test2, &sim, period);
    println!("Bouc-Wen from a linear file: test RMSE {plain:.3e} -> {diagnosed:.3e} m");
    assert!(plain > 1e-4, "plain linear {plain:e}");
    assert!(diagnosed < 5e-6, "diagnosed {diagnosed:e}");
    let _ = std::fs::remove_dir_all(&out);
}

/// EMPS' rigid body (`examples/models/emps.toml`), an integrating system:
/// fitted with its initial state free, the fit puts the start where it
/// cancels the integrator's drift (3.1 mm and −26 mm/s while the record
/// starts at rest), and `fit` says so; the file as shipped states the
/// start (at rest) and scores 5.46 mm on the pulses test set (init window
/// 20; 9.24 mm with the start fitted, measured 2026-11-29; published LTI
/// 5.53 mm).
#[test]
fn emps_physics_file_states_its_start_and_a_free_start_is_flagged() {
    let Some(dir) = data_dir_of("emps") else {
        return;
    };
    let emps = dir.join("emps");
    let (train, test) = (emps.join("train.csv"), emps.join("test.csv"));
    let file = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../examples/models/emps.toml");
    let out = std::env::temp_dir().join(format!("greybox-emps-{}", std::process::id()));
    std::fs::create_dir_all(&out).unwrap();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let text = std::fs::read_to_string(&file).unwrap();
    let free = out.join("emps_free.toml");
    std::fs::write(&free, text.replace("free = false", "free = true")).unwrap();
    let (stated, fitted) = (out.join("stated.gbm"), out.join("free.gbm"));
    let fo = greybox(&[
        "fit",
        &s(&train),
        "--model-file",
        &s(&free),
        "-o",
        &s(&fitted),
    ]);
    assert!(
        fo.contains("the fit leans on its fitted initial state"),
        "{fo}"
    );
    let so = greybox(&[
        "fit",
        &s(&train),
        "--model-file",
        &s(&file),
        "-o",
        &s(&stated),
    ]);
    assert!(!so.contains("leans on"), "{so}");
    let sim = out.join("sim.csv");
    let score = |m: &Path| {
        rmse(&greybox(&[
            "simulate",
            &s(m),
            &s(&test),
            "-o",
            &s(&sim),
            "--init-window",
            "20",
        ]))
    };
    let (with_start, free_start) = (score(&stated), score(&fitted));
    assert!(
        with_start < 6.0e-3 && with_start < 0.7 * free_start,
        "test RMSE: start stated {with_start:.3e} m, start fitted {free_start:.3e} m"
    );
    let _ = std::fs::remove_dir_all(&out);
}
