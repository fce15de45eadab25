//! `--model-file` end to end on generated data with a known truth (fixed
//! seeds): the printed intervals cover the truth, the bands cover held-out
//! noisy samples, the diagnosis of a linear msd file on data with a cubic
//! spring names the cause and gains on held-out data, and bad model files
//! fail with `file:line` and exit 2.
mod common;
use common::{run, text};
use gb_core::{DynamicModel, Init};
use gb_model::physics::{ModelFile, PhysicsModel};
use rand::Rng;
use rand_distr::{Distribution, Normal};
use std::path::{Path, PathBuf};
use std::process::Output;

const TS: f64 = 0.05;
/// m, c, k of the truth.
const TRUTH: [f64; 3] = [1.0, 0.4, 4.0];

fn example(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../examples/models")
        .join(name)
}

fn tmp(name: &str) -> PathBuf {
    common::scratch("greybox-physics", name)
}

/// Random force steps held 5–40 samples.
fn steps(n: usize, rng: &mut impl Rng) -> Vec<f64> {
    let mut u = Vec::with_capacity(n);
    while u.len() < n {
        let level: f64 = Normal::new(0.0, 1.0).unwrap().sample(rng);
        let hold = rng.random_range(5..40);
        u.extend(std::iter::repeat_n(level, hold));
    }
    u.truncate(n);
    u
}

/// The msd truth (with `cubic`·x³ added to the spring force when
/// nonzero), simulated with 20 RK4 steps per sample, plus white noise of
/// standard deviation `sd`; written as `t,F,y` to `path`. Returns the
/// noise-free output.
fn msd_csv(path: &Path, n: usize, seed: u64, sd: f64, cubic: f64) -> Vec<f64> {
    msd_delayed_csv(path, n, seed, sd, cubic, 0.0)
}

/// [`msd_csv`] with the force acting `delay` seconds after its sample
/// instant (none when 0).
fn msd_delayed_csv(path: &Path, n: usize, seed: u64, sd: f64, cubic: f64, delay: f64) -> Vec<f64> {
    msd_truth_csv(path, n, seed, sd, (cubic, delay, false))
}

/// The msd truth with a cubic spring, an input delay and (when
/// `hysteretic`) a Bouc–Wen spring force `z` in the force balance:
/// `ż = 2·ẋ − 8·|ẋ|·z − 2·ẋ·|z|` (saturating at |z| = 0.2 N).
fn msd_truth_csv(
    path: &Path,
    n: usize,
    seed: u64,
    sd: f64,
    (cubic, delay, hysteretic): (f64, f64, bool),
) -> Vec<f64> {
    let mut rng = gb_core::rng::seeded(seed);
    let u = steps(n, &mut rng);
    let mut spec = ModelFile::read(&example("msd.toml")).unwrap().spec;
    spec.substeps = 20;
    spec.sample_time = Some(TS);
    let mut theta = TRUTH.to_vec();
    if cubic != 0.0 {
        spec.parameters
            .push(gb_model::physics::Parameter::new("k3", cubic));
        spec.add_term(gb_model::physics::TermTarget::State(1), "-k3/m*x^3")
            .unwrap();
        theta.push(cubic);
    }
    if delay != 0.0 {
        spec.parameters
            .push(gb_model::physics::Parameter::new("td", delay));
        spec.input_delay = Some("td".into());
        theta.push(delay);
    }
    let mut x0 = vec![0.0, 0.0];
    if hysteretic {
        spec.states.push(gb_model::physics::State::new("z", 0.0));
        spec.equations
            .push(vec!["2*v - 8*abs(v)*z - 2*v*abs(z)".into()]);
        spec.add_term(gb_model::physics::TermTarget::State(1), "-z/m")
            .unwrap();
        x0.push(0.0);
    }
    let truth = PhysicsModel::new(spec)
        .unwrap()
        .with_values(theta, x0)
        .unwrap();
    let clean = truth
        .simulate(std::slice::from_ref(&u), Init::Stored)
        .unwrap();
    let noise = Normal::new(0.0, sd).unwrap();
    let mut s = String::from("t,F,y\n");
    for (k, (f, y)) in u.iter().zip(&clean).enumerate() {
        let v = y + noise.sample(&mut rng);
        s.push_str(&format!("{},{f},{v}\n", k as f64 * TS));
    }
    std::fs::write(path, s).unwrap();
    clean
}

/// `greybox fit DATA --model-file MODEL -o OUT`, which must succeed: its
/// standard output.
fn fit_ok(data: &Path, model: &Path, out: &Path) -> String {
    let o = run(&[
        "fit",
        data.to_str().unwrap(),
        "--model-file",
        model.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    let (so, se) = text(&o);
    assert_eq!(o.status.code(), Some(0), "{so}\n{se}");
    so
}

/// The estimate and 95 % interval of parameter `name` in `fit`'s output.
fn interval_of(out: &str, name: &str) -> (f64, f64, f64) {
    let line = out
        .lines()
        .find(|l| l.split_whitespace().next() == Some(name))
        .unwrap_or_else(|| panic!("no line for {name} in\n{out}"));
    let nums: Vec<f64> = line
        .replace(['[', ']', ','], " ")
        .split_whitespace()
        .filter_map(|w| w.parse().ok())
        .collect();
    assert!(nums.len() >= 4, "{line}");
    (nums[0], nums[2], nums[3])
}

#[test]
fn fit_model_file_prints_intervals_that_cover_the_truth() {
    let d = tmp("fit");
    let data = d.join("train.csv");
    msd_csv(&data, 2000, 3, 0.02, 0.0);
    let out = d.join("msd.gbm");
    let so = fit_ok(&data, &example("msd.toml"), &out);
    assert!(
        so.contains("sample time: 5.000000e-2 s (from the t column"),
        "{so}"
    );
    for (name, truth) in ["m", "c", "k"].iter().zip(TRUTH) {
        let (v, lo, hi) = interval_of(&so, name);
        assert!(lo < v && v < hi, "{name}: {v} not in [{lo}, {hi}]");
        assert!(
            lo <= truth && truth <= hi,
            "{name}: truth {truth} not in [{lo}, {hi}]\n{so}"
        );
        // informative: the interval is narrow
        assert!(hi - lo < 0.1 * truth, "{name}: [{lo}, {hi}] too wide");
    }
    assert!(so.contains("training NRMSE"), "{so}");
    assert!(out.exists());
    // the saved model simulates
    let sim = d.join("sim.csv");
    let o = run(&[
        "simulate",
        out.to_str().unwrap(),
        data.to_str().unwrap(),
        "-o",
        sim.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(0), "{:?}", text(&o));
}

/// A model file that states every parameter and initial state (nothing
/// left to estimate) is scored, not refused: `fit` exits 0, says there
/// were no free parameters, and the stated truth simulates the training
/// record at the noise level (RMSE within 10 % of the noise's standard
/// deviation). Until 2026-12-06 the empty covariance panicked.
#[test]
fn fit_model_file_with_every_parameter_fixed_scores_the_stated_model() {
    let d = tmp("fixed");
    let data = d.join("train.csv");
    let sd = 0.02;
    msd_csv(&data, 2000, 5, sd, 0.0);
    let file = d.join("msd_fixed.toml");
    let text_of = std::fs::read_to_string(example("msd.toml")).unwrap();
    let stated = text_of
        .replace(
            "x = { initial = 0.0 }",
            "x = { initial = 0.0, free = false }",
        )
        .replace(
            "v = { initial = 0.0 }",
            "v = { initial = 0.0, free = false }",
        )
        .replace(
            "m = { value = 1.5, min = 0.01, max = 100.0 }",
            "m = { value = 1.0, fixed = true }",
        )
        .replace(
            "c = { value = 0.3, min = 0.0, max = 100.0 }",
            "c = { value = 0.4, fixed = true }",
        )
        .replace(
            "k = { value = 2.0, min = 0.0, max = 1000.0 }",
            "k = { value = 4.0, fixed = true }",
        );
    assert_eq!(stated.matches("fixed = true").count(), 3, "{stated}");
    std::fs::write(&file, stated).unwrap();
    let out = d.join("msd.gbm");
    let so = fit_ok(&data, &file, &out);
    assert!(so.contains("0 free parameters"), "{so}");
    assert!(so.contains("(no free parameters)"), "{so}");
    let line = so
        .lines()
        .find(|l| l.starts_with("training fit"))
        .unwrap_or_else(|| panic!("no training fit line in {so}"));
    let rmse: f64 = line
        .split_whitespace()
        .skip_while(|w| *w != "RMSE")
        .nth(1)
        .and_then(|w| w.parse().ok())
        .unwrap_or_else(|| panic!("no RMSE in {line}"));
    assert!(
        (0.9 * sd..1.1 * sd).contains(&rmse),
        "the stated truth should simulate at the noise level {sd}: {line}"
    );
    assert!(out.exists());
}

/// A model file with a free input delay, started at 0, estimates a dead
/// time of 2.4 samples (the interval covers it) and the physical
/// parameters with it.
#[test]
fn fit_model_file_estimates_an_input_delay() {
    let d = tmp("delay");
    let data = d.join("train.csv");
    let delay = 2.4 * TS;
    msd_delayed_csv(&data, 2000, 5, 0.02, 0.0, delay);
    let text_ = std::fs::read_to_string(example("msd.toml"))
        .unwrap()
        .replace("[states]", "input_delay = \"td\"\n\n[states]")
        .replace(
            "[equations]",
            "td = { value = 0.0, min = -0.05, max = 0.5 }\n\n[equations]",
        );
    let file = d.join("msd_delay.toml");
    std::fs::write(&file, text_).unwrap();
    let out = d.join("msd.gbm");
    let so = fit_ok(&data, &file, &out);
    assert!(so.contains("input delay td = "), "{so}");
    for (name, truth) in ["m", "c", "k", "td"]
        .iter()
        .zip(TRUTH.iter().chain(&[delay]))
    {
        let (v, lo, hi) = interval_of(&so, name);
        assert!(
            lo <= *truth && *truth <= hi,
            "{name}: truth {truth} not in [{lo}, {hi}]\n{so}"
        );
        assert!(
            (v - truth).abs() < 0.05 * truth,
            "{name} = {v}, truth {truth}"
        );
    }
    // the plain file (no delay) fits this record clearly worse
    let o = run(&[
        "fit",
        data.to_str().unwrap(),
        "--model-file",
        example("msd.toml").to_str().unwrap(),
        "-o",
        d.join("plain.gbm").to_str().unwrap(),
    ]);
    let (plain, _) = text(&o);
    let nrmse = |s: &str| -> f64 {
        let l = s
            .lines()
            .find(|l| l.starts_with("training NRMSE"))
            .unwrap_or_else(|| panic!("no NRMSE in {s}"));
        l.split_whitespace()
            .find_map(|w| w.trim_end_matches(';').parse().ok())
            .unwrap()
    };
    let (with, without) = (nrmse(&so), nrmse(&plain));
    assert!(with < 0.5 * without, "with delay {with}, without {without}");
}

/// Two sensors (examples/models/msd_two_outputs.toml): position `y` and a
/// tachometer `tach = 2.5·v`, each with white noise at 1 % of its RMS;
/// written as `t,F,y,tach`.
fn two_sensor_csv(path: &Path, n: usize, seed: u64) {
    let mut rng = gb_core::rng::seeded(seed);
    let u = steps(n, &mut rng);
    let mut spec = ModelFile::read(&example("msd_two_outputs.toml"))
        .unwrap()
        .spec;
    spec.substeps = 20;
    spec.sample_time = Some(TS);
    let mut theta = TRUTH.to_vec();
    theta.push(2.5);
    let truth = PhysicsModel::new(spec)
        .unwrap()
        .with_values(theta, vec![0.0, 0.0])
        .unwrap();
    let clean = truth
        .simulate(std::slice::from_ref(&u), Init::Stored)
        .unwrap();
    let mut noisy = vec![];
    for o in 0..2 {
        let c = &clean[o * n..(o + 1) * n];
        let rms = (c.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
        let noise = Normal::new(0.0, 0.01 * rms).unwrap();
        noisy.push(
            c.iter()
                .map(|v| v + noise.sample(&mut rng))
                .collect::<Vec<_>>(),
        );
    }
    let mut s = String::from("t,F,y,tach\n");
    for k in 0..n {
        s.push_str(&format!(
            "{},{},{},{}\n",
            k as f64 * TS,
            u[k],
            noisy[0][k],
            noisy[1][k]
        ));
    }
    std::fs::write(path, s).unwrap();
}

/// `fit --model-file` with a model of two outputs fits them jointly: the
/// tachometer gain (seen only in the second output) and m, c, k lie in
/// their printed 95 % intervals, each output's training NRMSE is printed
/// near its 1 % noise level, `simulate` writes both outputs, and
/// `diagnose --model-file` says it handles one output (exit 2).
#[test]
fn fit_model_file_with_two_outputs() {
    let d = tmp("two-outputs");
    let data = d.join("train.csv");
    two_sensor_csv(&data, 2000, 8);
    let out = d.join("msd2.gbm");
    let model = example("msd_two_outputs.toml");
    let so = fit_ok(&data, &model, &out);
    assert!(so.contains("-> outputs y,tach"), "{so}");
    for (name, truth) in [("m", 1.0), ("c", 0.4), ("k", 4.0), ("g", 2.5)] {
        let (_, lo, hi) = interval_of(&so, name);
        assert!(
            lo <= truth && truth <= hi,
            "{name}: {truth} not in [{lo}, {hi}]\n{so}"
        );
    }
    for name in ["y", "tach"] {
        let nrmse: f64 = so
            .lines()
            .find_map(|l| {
                l.trim()
                    .strip_prefix(&format!("output {name}: training NRMSE "))
            })
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or_else(|| panic!("no NRMSE of {name} in\n{so}"));
        assert!(nrmse < 0.02, "{name}: {nrmse}");
    }
    let sim = d.join("sim.csv");
    let o = run(&[
        "simulate",
        out.to_str().unwrap(),
        data.to_str().unwrap(),
        "-o",
        sim.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(0), "{:?}", text(&o));
    let header = std::fs::read_to_string(&sim).unwrap();
    let header = header.lines().next().unwrap().to_string();
    assert!(
        header.contains("y_sim") && header.contains("tach_sim"),
        "{header}"
    );
    let banded = d.join("banded.csv");
    let o = run(&[
        "simulate",
        out.to_str().unwrap(),
        data.to_str().unwrap(),
        "-o",
        banded.to_str().unwrap(),
        "--bands",
    ]);
    let (_, se) = text(&o);
    assert_eq!(o.status.code(), Some(2), "{se}");
    assert!(se.contains("--bands handles models of one output"), "{se}");
    assert!(!banded.exists());
    let o = run(&[
        "diagnose",
        data.to_str().unwrap(),
        "--model-file",
        model.to_str().unwrap(),
    ]);
    let (_, se) = text(&o);
    assert_eq!(o.status.code(), Some(2), "{se}");
    assert!(
        se.contains("handles models of one output") && se.trim_end().lines().count() == 1,
        "{se}"
    );
}

/// `fit --model-file --method smc`: the output-error fit, then PMMH; the
/// posterior lines of the velocity's process noise, the measurement noise
/// and m, c, k are printed with intervals, ESS and R̂; the measurement sd
/// is near the data's (0.02) and k near the truth; the kinematic state x
/// gets no process noise; the saved model simulates.
#[test]
fn fit_model_file_by_smc_prints_the_posterior() {
    let d = tmp("smc");
    let data = d.join("train.csv");
    msd_csv(&data, 400, 6, 0.02, 0.0);
    let out = d.join("msd.gbm");
    let o = fit_msd_by_smc(&data, &out, "2");
    let (so, se) = text(&o);
    assert_eq!(o.status.code(), Some(0), "{so}\n{se}");
    let mean_of = |name: &str| -> f64 {
        so.lines()
            .find(|l| l.split_whitespace().next() == Some(name))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("no posterior line for {name} in\n{so}"))
    };
    let w = mean_of("measurement_sd");
    assert!((w / 0.02 - 1.0).abs() < 0.25, "measurement_sd {w}\n{so}");
    let k = mean_of("k");
    assert!((k / TRUTH[2] - 1.0).abs() < 0.1, "k {k}\n{so}");
    mean_of("process_sd[v]");
    assert!(!so.contains("process_sd[x]"), "{so}");
    assert!(so.contains("acceptance rate") && so.contains("R̂"), "{so}");
    let sim = d.join("sim.csv");
    let o = run(&[
        "simulate",
        out.to_str().unwrap(),
        data.to_str().unwrap(),
        "-o",
        sim.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(0), "{:?}", text(&o));
}

/// `greybox fit DATA --model-file msd.toml --method smc` with 100
/// particles and 400 iterations, saved to `out`.
fn fit_msd_by_smc(data: &Path, out: &Path, seed: &str) -> Output {
    run(&[
        "fit",
        data.to_str().unwrap(),
        "--model-file",
        example("msd.toml").to_str().unwrap(),
        "--method",
        "smc",
        "--particles",
        "100",
        "--iterations",
        "400",
        "--seed",
        seed,
        "-o",
        out.to_str().unwrap(),
    ])
}

/// A failing call: exit 2, one line on stderr containing `needle`, no
/// output file.
fn assert_bad(args: &[&str], needle: &str, out: &Path) {
    let o = run(args);
    let (_, e) = text(&o);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {e}");
    assert!(!e.contains("panicked"), "{e}");
    assert!(e.contains(needle), "expected '{needle}' in: {e}");
    assert_eq!(e.trim_end().lines().count(), 1, "not one line: {e}");
    assert!(!out.exists(), "output {} written", out.display());
}

#[test]
fn bad_model_files_and_columns_exit_2_with_file_and_line() {
    let d = tmp("bad");
    let data = d.join("train.csv");
    msd_csv(&data, 300, 1, 0.02, 0.0);
    let good = std::fs::read_to_string(example("msd.toml")).unwrap();
    let out = d.join("m.gbm");
    let (ds, os) = (data.to_str().unwrap(), out.to_str().unwrap());
    // an unknown symbol in the equation of v (line of `v = [...]`)
    let line = good.lines().position(|l| l.starts_with("v = [")).unwrap() + 1;
    let bad = d.join("bad.toml");
    std::fs::write(&bad, good.replace("-c/m*v", "-cc/m*v")).unwrap();
    let bs = bad.to_str().unwrap();
    assert_bad(
        &["fit", ds, "--model-file", bs, "-o", os],
        &format!("bad.toml:{line}:"),
        &out,
    );
    assert_bad(&["fit", ds, "--model-file", bs, "-o", os], "'cc'", &out);
    // a syntax error
    std::fs::write(&bad, good.replace("-c/m*v", "-c/m*(v")).unwrap();
    assert_bad(
        &["fit", ds, "--model-file", bs, "-o", os],
        &format!("bad.toml:{line}:"),
        &out,
    );
    // the model's input is not a column
    std::fs::write(
        &bad,
        good.replace("inputs = [\"F\"]", "inputs = [\"force\"]")
            .replace("\"F/m\"", "\"force/m\""),
    )
    .unwrap();
    assert_bad(
        &["fit", ds, "--model-file", bs, "-o", os],
        "input 'force' is not a column",
        &out,
    );
    // no sample time anywhere
    let no_t = d.join("no_t.csv");
    let csv = std::fs::read_to_string(&data).unwrap();
    let stripped: String = csv
        .lines()
        .map(|l| l.split_once(',').map_or(l, |(_, r)| r).to_string() + "\n")
        .collect();
    std::fs::write(&no_t, stripped).unwrap();
    assert_bad(
        &[
            "fit",
            no_t.to_str().unwrap(),
            "--model-file",
            example("msd.toml").to_str().unwrap(),
            "-o",
            os,
        ],
        "no sample_time",
        &out,
    );
    // --model and --model-file exclude each other
    let o = run(&["fit", ds, "--model", "linear", "--model-file", bs, "-o", os]);
    assert_eq!(o.status.code(), Some(2));
    assert!(!out.exists());
}

/// The column `name` of a CSV written by `simulate`.
fn column(csv: &str, name: &str) -> Vec<f64> {
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let j = header.iter().position(|h| *h == name).unwrap();
    lines
        .map(|l| l.split(',').nth(j).unwrap().parse().unwrap())
        .collect()
}

#[test]
fn bands_cover_about_95_percent_of_held_out_noisy_samples() {
    let d = tmp("bands");
    let (train, test) = (d.join("train.csv"), d.join("test.csv"));
    msd_csv(&train, 1500, 11, 0.02, 0.0);
    msd_csv(&test, 3000, 12, 0.02, 0.0);
    let model = d.join("msd.gbm");
    let o = run(&[
        "fit",
        train.to_str().unwrap(),
        "--model-file",
        example("msd.toml").to_str().unwrap(),
        "-o",
        model.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(0), "{:?}", text(&o));
    let sim = d.join("sim.csv");
    let o = run(&[
        "simulate",
        model.to_str().unwrap(),
        test.to_str().unwrap(),
        "-o",
        sim.to_str().unwrap(),
        "--bands",
    ]);
    let (so, se) = text(&o);
    assert_eq!(o.status.code(), Some(0), "{so}\n{se}");
    assert!(so.contains("band covers"), "{so}");
    let csv = std::fs::read_to_string(&sim).unwrap();
    let (y, lo, hi, ys) = (
        column(&csv, "y"),
        column(&csv, "y_sim_lo"),
        column(&csv, "y_sim_hi"),
        column(&csv, "y_sim"),
    );
    let inside = (0..y.len())
        .filter(|&t| lo[t] <= y[t] && y[t] <= hi[t])
        .count();
    let share = inside as f64 / y.len() as f64;
    assert!(
        (0.85..=0.995).contains(&share),
        "band covers {:.1} % of held-out samples",
        100.0 * share
    );
    assert!((0..y.len()).all(|t| lo[t] < ys[t] && ys[t] < hi[t]));
    // the band is no wider than noise and parameter spread need
    let width = (0..y.len()).map(|t| hi[t] - lo[t]).sum::<f64>() / y.len() as f64;
    assert!(width < 4.0 * 1.96 * 0.02, "mean width {width}");

    // a model without a covariance: one-line error, no output
    let lin = d.join("lin.gbm");
    let o = run(&[
        "fit",
        train.to_str().unwrap(),
        "--input",
        "F",
        "-o",
        lin.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(0), "{:?}", text(&o));
    let out = d.join("lin_sim.csv");
    assert_bad(
        &[
            "simulate",
            lin.to_str().unwrap(),
            test.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--bands",
        ],
        "--bands needs a physics model",
        &out,
    );
}

/// `greybox diagnose TRAIN --validate VAL --model-file examples/models/FILE
/// EXTRA…`, which must succeed: its standard output.
fn diagnose_ok(train: &Path, val: &Path, file: &str, extra: &[&str]) -> String {
    let model = example(file);
    let mut args = vec![
        "diagnose",
        train.to_str().unwrap(),
        "--validate",
        val.to_str().unwrap(),
        "--model-file",
        model.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let o = run(&args);
    let (so, se) = text(&o);
    assert_eq!(o.status.code(), Some(0), "{so}\n{se}");
    so
}

/// The NRMSE of a `baseline:` or `final:` line of the diagnosis.
fn nrmse_of(out: &str, prefix: &str) -> f64 {
    let line = out
        .lines()
        .find(|l| l.starts_with(prefix))
        .unwrap_or_else(|| panic!("no '{prefix}' line in\n{out}"));
    let w: Vec<&str> = line.split_whitespace().collect();
    let i = w.iter().position(|x| *x == "NRMSE").unwrap();
    w[i + 1].parse().unwrap()
}

#[test]
fn diagnose_model_file_names_a_missing_cubic_spring_and_gains_on_held_out_data() {
    let d = tmp("diagnose");
    let (train, val) = (d.join("train.csv"), d.join("validate.csv"));
    // a hardening spring k3·x³ the linear msd file lacks
    msd_csv(&train, 3000, 21, 0.01, 6.0);
    msd_csv(&val, 2000, 22, 0.01, 6.0);
    let json = d.join("report.json");
    let so = diagnose_ok(
        &train,
        &val,
        "msd.toml",
        &["--json", json.to_str().unwrap()],
    );
    println!("{so}");
    assert!(
        so.contains("the user's model file 'mass-spring-damper'"),
        "{so}"
    );
    assert!(so.contains("causes: nonlinearity"), "{so}");
    // the extension is in the equation of v, the physical parameters named
    let accepted = so
        .lines()
        .find(|l| l.contains(" yes "))
        .unwrap_or_else(|| panic!("no accepted step\n{so}"));
    assert!(accepted.contains("dv/dt +="), "{accepted}");
    let (base, fin) = (nrmse_of(&so, "baseline:"), nrmse_of(&so, "final:"));
    assert!(
        fin < 0.5 * base,
        "held-out NRMSE {base:.4} -> {fin:.4}: less than the stated 50 % gain"
    );
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(r["baseline"]["class"], "physics");
    assert!(r["baseline"]["parameter_values"]
        .as_str()
        .unwrap()
        .contains("k = "));
    // the added term is in dv/dt and in x; the physical parameters stay
    // named, k close to the linear stiffness of the truth
    let fin_params = r["final"]["parameter_values"].as_str().unwrap();
    assert!(fin_params.contains("3_v_x = "), "{fin_params}");
    let k: f64 = fin_params
        .split(", ")
        .find_map(|p| p.strip_prefix("k = "))
        .and_then(|v| v.split(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no k in {fin_params}"));
    assert!((k - TRUTH[2]).abs() < 0.05 * TRUTH[2], "k = {k}");
}

/// The msd file without a delay, on data whose force acts 2.4 samples
/// late: the diagnosis names `dynamics`, adds an input delay to the
/// user's model (estimated within 5 % of the truth) and gains on held-out
/// data.
#[test]
fn diagnose_model_file_finds_an_input_delay() {
    let d = tmp("diagnose-delay");
    let (train, val) = (d.join("train.csv"), d.join("validate.csv"));
    let delay = 2.4 * TS;
    msd_delayed_csv(&train, 3000, 31, 0.01, 0.0, delay);
    msd_delayed_csv(&val, 2000, 32, 0.01, 0.0, delay);
    let json = d.join("report.json");
    let so = diagnose_ok(
        &train,
        &val,
        "msd.toml",
        &["--json", json.to_str().unwrap()],
    );
    println!("{so}");
    assert!(so.contains("causes: dynamics"), "{so}");
    let accepted = so
        .lines()
        .find(|l| l.contains(" yes "))
        .unwrap_or_else(|| panic!("no accepted step\n{so}"));
    assert!(accepted.contains("an input delay"), "{accepted}");
    let (base, fin) = (nrmse_of(&so, "baseline:"), nrmse_of(&so, "final:"));
    assert!(fin < 0.5 * base, "held-out NRMSE {base:.4} -> {fin:.4}");
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let fin_params = r["final"]["parameter_values"].as_str().unwrap();
    let td: f64 = fin_params
        .split(", ")
        .find_map(|p| p.strip_prefix("t_delay = "))
        .and_then(|v| v.split(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no t_delay in {fin_params}"));
    assert!(
        (td - delay).abs() < 0.05 * delay,
        "t_delay = {td}, truth {delay}"
    );
}

/// The msd file on data whose spring has a Bouc–Wen hysteretic part: the
/// diagnosis names `hysteresis`, adds a hysteretic state to the force
/// balance and reaches the noise floor on held-out data.
#[test]
fn diagnose_model_file_finds_a_hysteretic_spring() {
    let d = tmp("diagnose-hysteresis");
    let (train, val) = (d.join("train.csv"), d.join("validate.csv"));
    let clean = msd_truth_csv(&train, 3000, 41, 0.005, (0.0, 0.0, true));
    msd_truth_csv(&val, 2000, 42, 0.005, (0.0, 0.0, true));
    let sd_y = {
        let m = clean.iter().sum::<f64>() / clean.len() as f64;
        (clean.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / clean.len() as f64).sqrt()
    };
    let floor = 0.005 / sd_y;
    let so = diagnose_ok(&train, &val, "msd.toml", &[]);
    println!("{so}\nnoise floor {floor:.4}");
    assert!(so.contains("causes: hysteresis"), "{so}");
    let accepted = so
        .lines()
        .find(|l| l.contains(" yes "))
        .unwrap_or_else(|| panic!("no accepted step\n{so}"));
    assert!(
        accepted.contains("a hysteretic state driven by x"),
        "{accepted}"
    );
    let fin = nrmse_of(&so, "final:");
    assert!(
        fin < 1.5 * floor,
        "held-out NRMSE {fin:.4}, floor {floor:.4}"
    );
}

/// Two tanks (`cascaded_tanks.toml`) whose upper tank overflows at
/// `level` (the truth adds the ceiling `ẋ₁ = min(f₁, (level − x₁)/h)` that
/// the file lacks; the fraction `spill` of what it cuts off runs into the
/// lower tank), pump voltage in random steps, written as `t,u,y` with
/// white noise `sd`. Returns the clean output's standard deviation and the
/// fraction of samples at the ceiling.
fn overflow_csv(
    path: &Path,
    n: usize,
    seed: u64,
    sd: f64,
    (level, spill): (f64, f64),
) -> (f64, f64) {
    let mut rng = gb_core::rng::seeded(seed);
    let mut u = Vec::with_capacity(n);
    while u.len() < n {
        let v: f64 = rng.random_range(1.0..6.0);
        u.extend(std::iter::repeat_n(v, rng.random_range(20..80)));
    }
    u.truncate(n);
    let mut spec = ModelFile::read(&example("cascaded_tanks.toml"))
        .unwrap()
        .spec;
    spec.substeps = 8;
    spec.parameters
        .push(gb_model::physics::Parameter::new("level", level));
    let rate = spec.substeps as f64 / 4.0;
    let z = format!("(level-x1)*{rate}-(-k1*sqrt(x1)+k2*u)");
    spec.add_term(
        gb_model::physics::TermTarget::State(0),
        &format!("(({z})-abs({z}))/2"),
    )
    .unwrap();
    if spill > 0.0 {
        spec.add_term(
            gb_model::physics::TermTarget::State(1),
            &format!("{spill}*((abs({z}))-({z}))/2"),
        )
        .unwrap();
    }
    let truth = PhysicsModel::new(spec)
        .unwrap()
        .with_values(vec![0.1, 0.08, 0.1, 0.08, level], vec![1.0, 1.0])
        .unwrap();
    let us = [u.clone()];
    let x = truth.state_trajectory(&us, Init::Stored).unwrap();
    let clean = truth.simulate(&us, Init::Stored).unwrap();
    let at_limit = x[0].iter().filter(|v| **v > level - 1e-3).count() as f64 / n as f64;
    let noise = Normal::new(0.0, sd).unwrap();
    let mut s = String::from("t,u,y\n");
    for (k, (f, y)) in u.iter().zip(&clean).enumerate() {
        let v = y + noise.sample(&mut rng);
        s.push_str(&format!("{},{f},{v}\n", k as f64 * 4.0));
    }
    std::fs::write(path, s).unwrap();
    let mean = clean.iter().sum::<f64>() / n as f64;
    let var = clean.iter().map(|y| (y - mean).powi(2)).sum::<f64>() / n as f64;
    (var.sqrt(), at_limit)
}

/// One step of the diagnosis of `cascaded_tanks.toml` on tanks that
/// overflow at level 10 and spill the fraction `spill` (1500 training and
/// 1000 validation samples, noise sd 0.01, seeds `seed` and `seed + 1`):
/// the printed report, the noise sd and the clean output's sd.
fn diagnose_overflow(name: &str, seed: u64, spill: f64) -> (String, f64, f64) {
    let d = tmp(name);
    let (train, val) = (d.join("train.csv"), d.join("validate.csv"));
    let sd = 0.01;
    let (sy, at) = overflow_csv(&train, 1500, seed, sd, (10.0, spill));
    overflow_csv(&val, 1000, seed + 1, sd, (10.0, spill));
    println!(
        "output sd {sy:.3}, {:.0} % of the samples at the ceiling",
        100.0 * at
    );
    assert!((0.1..0.6).contains(&at), "the ceiling binds {at}");
    let so = diagnose_ok(&train, &val, "cascaded_tanks.toml", &["--max-steps", "1"]);
    println!("{so}");
    (so, sd, sy)
}

#[test]
fn diagnose_model_file_finds_the_overflow_of_a_tank() {
    let (so, sd, sy) = diagnose_overflow("overflow", 31, 0.0);
    let accepted: Vec<&str> = so.lines().filter(|l| l.contains(" yes ")).collect();
    assert!(
        accepted
            .first()
            .is_some_and(|l| l.contains("an upper limit L_hi_x1 on x1")),
        "the first accepted step is not the overflow of x1:\n{so}"
    );
    let (base, fin) = (nrmse_of(&so, "baseline:"), nrmse_of(&so, "final:"));
    let floor = sd / sy;
    assert!(
        fin < 1.3 * floor,
        "held-out NRMSE {base:.4} -> {fin:.4}, noise floor {floor:.4}"
    );
}

/// The upper tank overflows and half of what runs over falls into the
/// lower tank: a limit on `x1` alone leaves that inflow out (the lower
/// level then stays too low while the upper tank is full), the overflow
/// candidate (the limit and its spill into `x2`, one step) brings it back.
#[test]
fn diagnose_model_file_finds_an_overflow_into_the_lower_tank() {
    let (so, sd, sy) = diagnose_overflow("overflow-spill", 33, 0.5);
    let accepted = so.lines().find(|l| l.contains(" yes ")).unwrap_or("");
    assert!(
        accepted.contains("an upper limit L_hi_x1 on x1") && accepted.contains("runs into x2"),
        "the first accepted step is not the overflow of x1 into x2:\n{so}"
    );
    // the truth runs 8 RK4 sub-steps, the file 2: measured 1.4× the floor
    // (the plain model 0.28, a limit on x1 alone 0.22)
    let fin = nrmse_of(&so, "final:");
    assert!(
        fin < 1.6 * sd / sy,
        "held-out NRMSE {fin:.4}, floor {:.4}",
        sd / sy
    );
}

/// The msd truth driven by `F` and a hidden force disturbance `d ~ N(0,
/// sd_d²)` held over each sample, position measured with noise `sd`;
/// written as `t,F,y`. Returns the true velocity and the velocity of the
/// same truth without the disturbance (the best any deterministic
/// simulation can do).
fn disturbed_msd_csv(path: &Path, n: usize, seed: u64, sd: f64, sd_d: f64) -> [Vec<f64>; 2] {
    let mut rng = gb_core::rng::seeded(seed);
    let u = steps(n, &mut rng);
    let dist = Normal::new(0.0, sd_d).unwrap();
    let d: Vec<f64> = (0..n).map(|_| dist.sample(&mut rng)).collect();
    let mut spec = ModelFile::read(&example("msd.toml")).unwrap().spec;
    spec.substeps = 20;
    spec.sample_time = Some(TS);
    spec.inputs.push("d".into());
    spec.add_term(gb_model::physics::TermTarget::State(1), "d/m")
        .unwrap();
    let truth = PhysicsModel::new(spec)
        .unwrap()
        .with_values(TRUTH.to_vec(), vec![0.0, 0.0])
        .unwrap();
    let x = truth
        .state_trajectory(&[u.clone(), d], Init::Stored)
        .unwrap();
    let x_det = truth
        .state_trajectory(&[u.clone(), vec![0.0; n]], Init::Stored)
        .unwrap();
    let noise = Normal::new(0.0, sd).unwrap();
    let mut s = String::from("t,F,y\n");
    for (k, (f, p)) in u.iter().zip(&x[0]).enumerate() {
        let v = p + noise.sample(&mut rng);
        s.push_str(&format!("{},{f},{v}\n", k as f64 * TS));
    }
    std::fs::write(path, s).unwrap();
    [x[1].clone(), x_det[1].clone()]
}

/// `fit --method smc` saves the stochastic model, and `filter` estimates
/// the hidden velocity of held-out data under the force disturbance that
/// no deterministic simulation can follow: the filtered mean is closer to
/// the true velocity than the undisturbed truth's, and the 95 % band covers
/// most of it.
#[test]
fn filter_estimates_the_hidden_velocity_of_a_disturbed_physics_model() {
    let d = tmp("filter");
    let (train, val) = (d.join("train.csv"), d.join("val.csv"));
    disturbed_msd_csv(&train, 400, 41, 0.01, 0.5);
    let [v_true, v_det] = disturbed_msd_csv(&val, 400, 42, 0.01, 0.5);
    let model = d.join("msd.gbm");
    let o = fit_msd_by_smc(&train, &model, "3");
    let (so, se) = text(&o);
    assert_eq!(o.status.code(), Some(0), "{so}\n{se}");
    assert!(so.contains("process sd [v]"), "{so}");
    let states = d.join("states.csv");
    let o = run(&[
        "filter",
        model.to_str().unwrap(),
        val.to_str().unwrap(),
        "-o",
        states.to_str().unwrap(),
        "--particles",
        "500",
    ]);
    let (so, se) = text(&o);
    assert_eq!(o.status.code(), Some(0), "{so}\n{se}");
    let csv = std::fs::read_to_string(&states).unwrap();
    let (mean, lo, hi) = (
        column(&csv, "v_mean"),
        column(&csv, "v_lo"),
        column(&csv, "v_hi"),
    );
    let rms = |a: &[f64], b: &[f64]| {
        (a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / a.len() as f64).sqrt()
    };
    let (e_filter, e_det) = (rms(&mean, &v_true), rms(&v_det, &v_true));
    let covered = v_true
        .iter()
        .zip(lo.iter().zip(&hi))
        .filter(|(v, (l, h))| *l <= *v && *v <= *h)
        .count() as f64
        / v_true.len() as f64;
    println!("velocity RMS error: filter {e_filter:.4}, undisturbed truth {e_det:.4}; band covers {covered:.3}");
    assert!(e_filter < 0.5 * e_det, "filter {e_filter} vs {e_det}");
    assert!(covered > 0.8, "the 95 % band covers {covered}");
    // a model without state noise is refused with a one-line error
    let oe = d.join("oe.gbm");
    let o = run(&[
        "fit",
        train.to_str().unwrap(),
        "--model-file",
        example("msd.toml").to_str().unwrap(),
        "-o",
        oe.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(0), "{:?}", text(&o));
    let o = run(&[
        "filter",
        oe.to_str().unwrap(),
        val.to_str().unwrap(),
        "-o",
        d.join("x.csv").to_str().unwrap(),
    ]);
    let (_, se) = text(&o);
    assert_eq!(o.status.code(), Some(2), "{se}");
    assert!(se.contains("no state noise"), "{se}");
    assert!(!d.join("x.csv").exists());
}
