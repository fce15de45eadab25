//! The physics class on generated data with known truth (fixed seeds): the
//! mass–spring–damper example file, coverage of the 95 % intervals,
//! identifiability warnings, model-file errors, model files, bands.
use gb_core::{DynamicModel, Identify, Init, Record, Records, Silent};
use gb_model::physics::*;
use rand_distr::{Distribution, Normal};
use std::path::PathBuf;

mod common;

const TS: f64 = 0.05;
const TRUTH: [f64; 3] = [1.0, 0.4, 4.0]; // m, c, k

fn example(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../examples/models")
        .join(name)
}

fn msd_file() -> ModelFile {
    ModelFile::read(&example("msd.toml")).expect("examples/models/msd.toml")
}

/// Random steps held 5–40 samples, the truth simulated with 20 RK4 steps
/// per sample, white noise at `snr_db`; also the noise-free output.
fn msd_data(n: usize, seed: u64, snr_db: f64) -> (Record, Vec<f64>) {
    msd_data_sd(n, seed, Err(snr_db))
}

/// As [`msd_data`], the noise given by its SNR (`Err`) or its sd (`Ok`).
fn msd_data_sd(n: usize, seed: u64, noise: Result<f64, f64>) -> (Record, Vec<f64>) {
    let mut rng = gb_core::rng::seeded(seed);
    let u = common::steps(n, &mut rng);
    let mut spec = msd_file().spec;
    spec.substeps = 20;
    spec.sample_time = Some(TS);
    let truth = PhysicsModel::new(spec)
        .unwrap()
        .with_values(TRUTH.to_vec(), vec![0.0, 0.0])
        .unwrap();
    let clean = truth
        .simulate(std::slice::from_ref(&u), Init::Stored)
        .unwrap();
    let rms = (clean.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
    let sd = noise.unwrap_or_else(|snr_db| rms * 10f64.powf(-snr_db / 20.0));
    let noise = Normal::new(0.0, sd).unwrap();
    let y: Vec<f64> = clean.iter().map(|v| v + noise.sample(&mut rng)).collect();
    let r = Record::new(vec!["F".into()], "y".into(), vec![u], y)
        .unwrap()
        .with_sample_time(TS);
    (r, clean)
}

fn noise_sd(y: &[f64], clean: &[f64]) -> f64 {
    (y.iter()
        .zip(clean)
        .map(|(a, b)| (a - b).powi(2))
        .sum::<f64>()
        / y.len() as f64)
        .sqrt()
}

fn fit(r: Record) -> PhysicsModel {
    msd_file().fit(&Records::single(r), &Silent).expect("fit")
}

#[test]
fn msd_parameters_come_back_within_two_percent_at_30_db() {
    let (r, _) = msd_data(2000, 1, 30.0);
    let m = fit(r);
    let rep = m.fit_report().unwrap();
    for (name, truth) in ["m", "c", "k"].iter().zip(TRUTH) {
        let v = m.parameter(name).unwrap();
        assert!(
            ((v - truth) / truth).abs() < 0.02,
            "{name} = {v}, truth {truth}\n{}",
            rep.lines().join("\n")
        );
    }
    assert!(rep.warnings.is_empty(), "{:?}", rep.warnings);
    assert_eq!(rep.termination, "converged");
    // every estimate carries a finite standard error and an interval
    for e in &rep.estimates {
        assert!(e.std_error > 0.0 && e.std_error.is_finite(), "{e:?}");
        assert!(e.interval.0 < e.value && e.value < e.interval.1);
    }
}

/// 50 seeds, 1000 samples each: the 95 % intervals must cover the truth in
/// 90–99 % of the 150 intervals (and of each parameter's 50).
#[test]
fn msd_intervals_cover_the_truth() {
    let mut covered = [0usize; 3];
    let seeds = 50;
    for seed in 0..seeds {
        let (r, _) = msd_data(1000, 100 + seed, 30.0);
        let m = fit(r);
        let rep = m.fit_report().unwrap();
        for (k, name) in ["m", "c", "k"].iter().enumerate() {
            let e = rep.estimates.iter().find(|e| e.name == *name).unwrap();
            if e.interval.0 <= TRUTH[k] && TRUTH[k] <= e.interval.1 {
                covered[k] += 1;
            }
        }
    }
    let total = covered.iter().sum::<usize>() as f64 / (3 * seeds) as f64;
    eprintln!(
        "coverage of the 95 % intervals over {seeds} seeds: m {}/50, c {}/50, k {}/50, all {:.3}",
        covered[0], covered[1], covered[2], total
    );
    assert!((0.90..=0.99).contains(&total), "coverage {total}");
    for c in covered {
        assert!(c >= 43, "a parameter covered in only {c} of 50 seeds");
    }
}

#[test]
fn redundant_and_ineffective_parameters_are_named() {
    let (r, _) = msd_data(1000, 3, 30.0);
    // c enters only as c1·c2: the pair is redundant; d has no effect
    let spec = PhysicsSpec::new("redundant")
        .input("F")
        .parameter(Parameter::new("m", 1.2).bounds(0.1, 10.0))
        .parameter(Parameter::new("c1", 0.5).bounds(0.0, 10.0))
        .parameter(Parameter::new("c2", 0.5).bounds(0.0, 10.0))
        .parameter(Parameter::new("k", 3.0).bounds(0.0, 100.0))
        .parameter(Parameter::new("d", 1.0).bounds(-10.0, 10.0))
        .state(State::new("x", 0.0), "v")
        .state(State::new("v", 0.0), "F/m - c1*c2/m*v - k/m*x + 0*d")
        .output("y", "x")
        .substeps(4);
    let m = PhysicsFitParams::new(spec)
        .check()
        .unwrap()
        .identify(&Records::single(r), &Silent)
        .unwrap();
    let rep = m.fit_report().unwrap();
    let all = rep.warnings.join("\n");
    assert!(
        all.contains("d is not identifiable") && all.contains("does not depend on it"),
        "{all}"
    );
    assert!(
        all.contains("ill-conditioned") && all.contains("c1") && all.contains("c2"),
        "{all}"
    );
    let d = rep.estimates.iter().find(|e| e.name == "d").unwrap();
    assert!(d.std_error.is_infinite());
    // the well-determined parameters keep finite errors
    let k = rep.estimates.iter().find(|e| e.name == "k").unwrap();
    assert!(
        k.std_error.is_finite() && (k.value - 4.0).abs() < 0.1,
        "{k:?}"
    );
}

#[test]
fn strongly_coupled_pairs_are_reported() {
    // a short, slow record: m and k are hard to separate
    let (r, _) = msd_data(1000, 5, 30.0);
    let m = fit(r);
    let rep = m.fit_report().unwrap();
    // correlations are consistent with the covariance
    for (a, b, rho) in &rep.correlated {
        assert!(rho.abs() > 0.9 && rho.abs() <= 1.0, "{a} {b} {rho}");
    }
    assert!(rep.condition >= 1.0 && rep.condition.is_finite());
    let lines = rep.lines().join("\n");
    assert!(
        lines.contains("95 % interval") && lines.contains("training fit"),
        "{lines}"
    );
}

#[test]
fn a_prior_pulls_an_unidentifiable_parameter_to_its_mean() {
    let (r, _) = msd_data(1000, 4, 30.0);
    let spec = PhysicsSpec::new("prior")
        .input("F")
        .parameter(Parameter::new("m", 1.2).bounds(0.1, 10.0))
        .parameter(Parameter::new("c", 0.5).bounds(0.0, 10.0))
        .parameter(Parameter::new("k", 3.0).bounds(0.0, 100.0))
        .parameter(Parameter::new("d", 1.0).prior(2.0, 0.5))
        .state(State::new("x", 0.0), "v")
        .state(State::new("v", 0.0), "F/m - c/m*v - k/m*x + 0*d")
        .output("y", "x")
        .substeps(4);
    let m = PhysicsFitParams::new(spec)
        .check()
        .unwrap()
        .identify(&Records::single(r), &Silent)
        .unwrap();
    let rep = m.fit_report().unwrap();
    let d = rep.estimates.iter().find(|e| e.name == "d").unwrap();
    assert!((d.value - 2.0).abs() < 1e-6, "{d:?}");
    assert!((d.std_error - 0.5).abs() < 1e-3, "{d:?}");
}

fn parse_err(text: &str) -> String {
    ModelFile::parse(text, "bad.toml").unwrap_err().to_string()
}

const GOOD: &str = r#"name = "t"
inputs = ["F"]
sample_time = 0.05

[states]
x = { initial = 0.0 }
v = { initial = 0.0 }

[parameters]
m = { value = 1.0, min = 0.1, max = 10.0 }
k = { value = 4.0 }

[equations]
x = "v"
v = "F/m - k/m*x"

[outputs]
y = "x"
"#;

#[test]
fn model_file_errors_name_the_file_line_expression_and_symbol() {
    assert!(ModelFile::parse(GOOD, "good.toml").is_ok());
    let e = parse_err(&GOOD.replace("F/m - k/m*x", "F/m - kk/m*x"));
    assert!(e.starts_with("bad.toml:15: equation for 'v'"), "{e}");
    assert!(
        e.contains("\"F/m - kk/m*x\"") && e.contains("unknown symbol 'kk'"),
        "{e}"
    );
    // a state without an equation
    let e = parse_err(&GOOD.replace("v = \"F/m - k/m*x\"\n", ""));
    assert!(
        e.starts_with("bad.toml:7: state 'v'") && e.contains("no equation"),
        "{e}"
    );
    // an equation for no state
    let e = parse_err(&GOOD.replace("x = \"v\"", "x = \"v\"\nw = \"x\""));
    assert!(
        e.starts_with("bad.toml:15: equation for 'w'") && e.contains("no state"),
        "{e}"
    );
    // a parameter outside its bounds
    let e = parse_err(&GOOD.replace("value = 1.0, min = 0.1", "value = 20.0, min = 0.1"));
    assert!(
        e.starts_with("bad.toml:10: parameter 'm'") && e.contains("outside its bounds"),
        "{e}"
    );
    // TOML syntax and schema errors carry toml's line
    let e = parse_err(&GOOD.replace("k = { value = 4.0 }", "k = { value = 4.0.1 }"));
    assert!(e.starts_with("bad.toml:11:"), "{e}");
    let e = parse_err(&GOOD.replace("k = { value = 4.0 }", "k = { vaule = 4.0 }"));
    assert!(e.starts_with("bad.toml:11:") && e.contains("vaule"), "{e}");
    // reserved names and syntax errors in an expression
    let e = parse_err(
        &GOOD
            .replace("k = { value", "e = { value")
            .replace("k/m", "e/m"),
    );
    assert!(e.contains("parameter 'e'") && e.contains("reserved"), "{e}");
    let e = parse_err(&GOOD.replace("F/m - k/m*x", "F/m - (k/m*x"));
    assert!(
        e.starts_with("bad.toml:15: equation for 'v'") && e.contains("(k/m*x"),
        "{e}"
    );
    // missing tables
    let e = parse_err(&GOOD.replace("[outputs]\ny = \"x\"\n", ""));
    assert!(
        e.contains("bad.toml") && e.contains("no [outputs] table"),
        "{e}"
    );
}

#[test]
fn an_equation_that_is_nan_at_the_initial_point_is_named() {
    let f = ModelFile::parse(
        &GOOD.replace("x = \"v\"", "x = \"v + sqrt(x - 1)\""),
        "nan.toml",
    )
    .unwrap();
    let (r, _) = msd_data(200, 1, 30.0);
    let e = f.fit(&Records::single(r), &Silent).unwrap_err().to_string();
    assert!(
        e.starts_with("nan.toml:14: equation for 'x'") && e.contains("is NaN at the initial point"),
        "{e}"
    );
    assert!(e.contains("x = 0") && e.contains("v = 0"), "{e}");
}

#[test]
fn fitted_models_round_trip_through_model_files() {
    let (r, _) = msd_data(1000, 7, 30.0);
    let u = r.inputs.clone();
    let m = fit(r);
    let fm = m.to_fitted().unwrap();
    assert_eq!(fm.dynamics.class(), "physics");
    assert_eq!(fm.input_names, vec!["F".to_string()]);
    let bytes = fm.to_bytes().unwrap();
    let back = gb_model::registry::from_bytes(&bytes, "m.gbm").unwrap();
    assert_eq!(
        back.simulate(&u, Init::Stored).unwrap(),
        fm.simulate(&u, Init::Stored).unwrap()
    );
    let pm = back
        .dynamics
        .as_any()
        .downcast_ref::<PhysicsModel>()
        .unwrap();
    assert_eq!(pm.fit_report(), m.fit_report());
    assert!(pm.source().unwrap().contains("mass-spring-damper"));
    // the report table
    let v = back.dynamics.views(&back.input_names, &back.output_names);
    match &v[0].data {
        gb_core::ViewData::Table { header, rows } => {
            assert_eq!(header[0], "parameter");
            assert_eq!(rows.len(), 3);
        }
        d => panic!("{d:?}"),
    }
    // a corrupt body is an error, never a panic
    let e = gb_model::registry::from_bytes(&bytes[..bytes.len() - 9], "m.gbm")
        .unwrap_err()
        .to_string();
    assert!(e.contains("m.gbm"), "{e}");
}

#[test]
fn stepping_and_init_windows_agree_with_the_simulation() {
    let (r, _) = msd_data(600, 8, 30.0);
    let m = fit(r.clone());
    let u = r.inputs.clone();
    let x0 = [0.3, -0.2];
    let y = m.simulate(&u, Init::State(&x0)).unwrap();
    let mut s = m.stepper(Init::State(&x0)).unwrap();
    for (k, yk) in y.iter().enumerate() {
        let mut o = [0.0];
        s.step(&[u[0][k]], &mut o).unwrap();
        assert_eq!(o[0], *yk);
    }
    // the init window recovers the state from 50 outputs
    let w = m.simulate(&u, Init::Window(&y[..50])).unwrap();
    let err = y
        .iter()
        .zip(&w)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(err < 1e-6, "{err}");
}

#[test]
fn prediction_bands_cover_new_measurements() {
    let (r, clean_r) = msd_data(2000, 11, 30.0);
    let true_sd = noise_sd(&r.output, &clean_r);
    let m = fit(r);
    let fm = m.to_fitted().unwrap();
    // new data with the same noise level as the training record
    let sd = true_sd;
    assert!(
        (fm.noise.sd() / sd - 1.0).abs() < 0.05,
        "σ̂ {} vs {sd}",
        fm.noise.sd()
    );
    let (v, clean) = msd_data_sd(2000, 12, Ok(sd));
    let b = prediction_bands(&fm, &v.inputs, Init::Stored, BandParams::default()).unwrap();
    assert_eq!(b.draws, 200);
    let inside = v
        .output
        .iter()
        .zip(b.lo.iter().zip(&b.hi))
        .filter(|(y, (lo, hi))| lo <= y && y <= hi)
        .count() as f64
        / v.output.len() as f64;
    eprintln!(
        "95 % prediction bands contain {:.1} % of new measurements",
        100.0 * inside
    );
    assert!((0.92..=0.98).contains(&inside), "{inside}");
    // and always the noise-free output's neighbourhood
    assert!(clean.iter().zip(&b.lo).all(|(c, lo)| lo < c));
    // a model of another class has no covariance
    let lin =
        gb_model::SparseStateSpace::linear(vec![0.5], vec![1.0], vec![1.0], vec![0.0]).unwrap();
    let other = gb_core::FittedModel::new(
        vec!["u".into()],
        vec!["y".into()],
        Box::new(lin),
        gb_core::NoiseModel::Gaussian { sd: 0.1 },
    )
    .unwrap();
    let e = prediction_bands(&other, &[vec![0.0; 10]], Init::Rest, BandParams::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("class 'state-space'"), "{e}");
}

#[test]
fn state_trajectory_is_the_simulated_state() {
    let (r, _) = msd_data(500, 7, 30.0);
    let m = fit(r.clone());
    let x = m.state_trajectory(&r.inputs, Init::Stored).unwrap();
    let y = m.simulate(&r.inputs, Init::Stored).unwrap();
    assert_eq!(x.len(), 2);
    // y = x: the output is the first state at the start of each sample
    for (t, (a, b)) in x[0].iter().zip(&y).enumerate() {
        assert!(
            (a - b).abs() <= 1e-12 * b.abs().max(1e-12),
            "sample {t}: {a} vs {b}"
        );
    }
    // v is the rate of x (central differences, TS = 0.05)
    let mid = 250;
    let dx = (x[0][mid + 1] - x[0][mid - 1]) / (2.0 * TS);
    assert!((dx - x[1][mid]).abs() < 0.05 * x[1].iter().fold(0.0_f64, |m, v| m.max(v.abs())));
}

#[test]
fn growing_fit_is_never_worse_and_finds_the_truth_on_long_records() {
    for seed in 1..=4 {
        let (r, _) = msd_data(6000, 100 + seed, 30.0);
        let data = Records::single(r);
        let direct = msd_file().fit(&data, &Silent).unwrap();
        let grown = msd_file().fit_growing(&data, &Silent).unwrap();
        let (d, g) = (
            direct.fit_report().unwrap().rmse,
            grown.fit_report().unwrap().rmse,
        );
        assert!(
            g <= d * (1.0 + 1e-12),
            "seed {seed}: growing {g} > direct {d}"
        );
        for (name, truth) in ["m", "c", "k"].iter().zip(TRUTH) {
            let v = grown.parameter(name).unwrap();
            assert!(
                ((v - truth) / truth).abs() < 0.03,
                "seed {seed}: {name} = {v}, direct RMSE {d}, grown {g}"
            );
        }
    }
}

/// The msd truth with a hardening spring `k3·x³` the file lacks, white
/// noise of sd 0.01.
fn cubic_msd_data(n: usize, seed: u64, k3: f64) -> Record {
    let mut rng = gb_core::rng::seeded(seed);
    let u = common::steps(n, &mut rng);
    let mut spec = msd_file().spec;
    spec.substeps = 20;
    spec.sample_time = Some(TS);
    spec.parameters.push(Parameter::new("k3", k3));
    spec.add_term(TermTarget::State(1), "-k3/m*x^3").unwrap();
    let mut theta = TRUTH.to_vec();
    theta.push(k3);
    let truth = PhysicsModel::new(spec)
        .unwrap()
        .with_values(theta, vec![0.0, 0.0])
        .unwrap();
    let clean = truth
        .simulate(std::slice::from_ref(&u), Init::Stored)
        .unwrap();
    let noise = Normal::new(0.0, 0.01).unwrap();
    let y: Vec<f64> = clean.iter().map(|v| v + noise.sample(&mut rng)).collect();
    Record::new(vec!["F".into()], "y".into(), vec![u], y)
        .unwrap()
        .with_sample_time(TS)
}

/// A linear file on data with a cubic spring: the direct fit from the
/// file's start values can end in a far local minimum (m ≈ 100); the fit
/// continued over growing prefixes does not.
#[test]
fn growing_fit_escapes_local_minima_of_the_output_error_cost() {
    let mut escaped = 0;
    for seed in 20..=25 {
        let data = Records::single(cubic_msd_data(3000, seed, 6.0).slice(0..2250));
        let direct = msd_file().fit(&data, &Silent).unwrap();
        let grown = msd_file().fit_growing(&data, &Silent).unwrap();
        let (d, g) = (
            direct.fit_report().unwrap().rmse,
            grown.fit_report().unwrap().rmse,
        );
        assert!(
            g <= d * (1.0 + 1e-12),
            "seed {seed}: growing {g} > direct {d}"
        );
        let m = grown.parameter("m").unwrap();
        assert!((m - 1.0).abs() < 0.2, "seed {seed}: m = {m}");
        if g < 0.5 * d {
            escaped += 1;
        }
    }
    // measured: the direct fit ends at m = 97 (seed 21) and m = 63 (seed 22)
    assert!(
        escaped >= 2,
        "{escaped} seeds where the continuation escapes"
    );
}

/// Two sensors on the msd: the position `y = x` and a tachometer
/// `tach = g·v` of gain g = 2.5 (seen only in the second output), white
/// noise at 1 % of each output's RMS; `data[o]` per output.
fn two_sensor_data(n: usize, seed: u64) -> (ModelFile, Vec<Records>, [f64; 2]) {
    let mf = ModelFile::read(&example("msd_two_outputs.toml")).unwrap();
    let mut rng = gb_core::rng::seeded(seed);
    let u = common::steps(n, &mut rng);
    let mut spec = mf.spec.clone();
    spec.substeps = 20;
    spec.sample_time = Some(TS);
    let truth = PhysicsModel::new(spec)
        .unwrap()
        .with_values(vec![1.0, 0.4, 4.0, 2.5], vec![0.0, 0.0])
        .unwrap();
    let clean = truth
        .simulate(std::slice::from_ref(&u), Init::Stored)
        .unwrap();
    let mut data = vec![];
    let mut sds = [0.0; 2];
    for (o, name) in ["y", "tach"].iter().enumerate() {
        let c = &clean[o * n..(o + 1) * n];
        let rms = (c.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
        sds[o] = 0.01 * rms;
        let noise = Normal::new(0.0, sds[o]).unwrap();
        let y: Vec<f64> = c.iter().map(|v| v + noise.sample(&mut rng)).collect();
        let r = Record::new(vec!["F".into()], name.to_string(), vec![u.clone()], y)
            .unwrap()
            .with_sample_time(TS);
        data.push(Records::single(r));
    }
    (mf, data, sds)
}

/// The joint fit of both outputs recovers m, c, k and the tachometer gain
/// (within 2 % and 4 standard errors: a gain fitted from the wrong output,
/// or one output ignored, misses), each output's free-run error sits at its
/// noise level although the outputs differ in scale, and data for the
/// wrong number of outputs is a one-line error naming the outputs.
#[test]
fn two_outputs_are_fitted_jointly() {
    let (mf, data, sds) = two_sensor_data(2000, 31);
    let m = mf.fit_growing_outputs(&data, &Silent).unwrap();
    let rep = m.fit_report().unwrap();
    for (name, truth) in [("m", 1.0), ("c", 0.4), ("k", 4.0), ("g", 2.5)] {
        let e = rep.estimates.iter().find(|e| e.name == name).unwrap();
        eprintln!("{name}: {:.5} ± {:.5}", e.value, e.std_error);
        assert!(
            (e.value - truth).abs() < 0.02 * truth,
            "{name} = {}",
            e.value
        );
        assert!(
            (e.value - truth).abs() < 4.0 * e.std_error,
            "{name} = {} ± {}",
            e.value,
            e.std_error
        );
    }
    let u = &data[0].first().inputs;
    let sim = m.simulate(u, Init::Stored).unwrap();
    let n = u[0].len();
    for o in 0..2 {
        let y = &data[o].first().output;
        let rmse = (y
            .iter()
            .zip(&sim[o * n..(o + 1) * n])
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            / n as f64)
            .sqrt();
        eprintln!("output {o}: rmse {rmse:.3e}, noise sd {:.3e}", sds[o]);
        assert!(
            rmse < 1.2 * sds[o],
            "output {o}: {rmse} vs noise {}",
            sds[o]
        );
    }
    let e = mf
        .fit_growing_outputs(&data[..1], &Silent)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("has 2 outputs [y, tach]") && e.lines().count() == 1,
        "{e}"
    );
}

/// The mass–spring–damper with a Preisach spring on the position, from a
/// model file's `[preisach]` table: relay cells over `[−h, h]`, weights
/// `w0…` added to the equation of `v`.
fn msd_preisach_file(h: f64, prior: &str) -> ModelFile {
    let text = format!(
        r#"name = "msd-preisach"
inputs = ["F"]
substeps = 4
sample_time = {TS}
[states]
x = {{ initial = 0.0 }}
v = {{ initial = 0.0 }}
[parameters]
m = {{ value = 1.2, min = 0.1, max = 10.0 }}
c = {{ value = 0.3, min = 0.0 }}
k = {{ value = 3.5, min = 0.0 }}
[equations]
x = "v"
v = ["F/m", "-c/m*v", "-k/m*x"]
[outputs]
y = "x"
[preisach]
P = {{ state = "x", min = {lo}, max = {h}, levels = 4, sub = 2, into = "v", weights = "w"{prior} }}
"#,
        lo = -h
    );
    ModelFile::parse(&text, "msd_preisach.toml").expect("the Preisach model file")
}

/// A Preisach spring inside the loop (the thesis' hysteresis in the
/// dynamics), generated by the file's own structure with known weights:
/// fitted from the file's starts (weights 0), the free-run simulation of a
/// new record is more than five times closer to the truth than the plain
/// mass–spring–damper's, and a prior on the weights (`prior_sd`) closer
/// still.
#[test]
fn a_preisach_spring_in_a_model_file_beats_the_plain_model_on_new_data() {
    let n = 3000;
    let mut rng = gb_core::rng::seeded(21);
    let (u, u_new) = (common::steps(n, &mut rng), common::steps(n, &mut rng));
    // the grid covers the linear system's positions
    let probe = msd_data(n, 21, 60.0).1;
    let h = 1.1 * probe.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    let file = msd_preisach_file(h, "");
    let cells = file.spec.hysteresis[0].n_cells();
    assert_eq!(file.spec.parameters.len(), 3 + cells);
    let mut theta = TRUTH.to_vec();
    // a restoring hysteretic force of about a fifth of the spring's
    theta.extend((0..cells).map(|j| -0.2 * TRUTH[2] * h / cells as f64 * (0.5 + (j % 3) as f64)));
    let truth = file
        .model()
        .unwrap()
        .with_values(theta, vec![0.0, 0.0])
        .unwrap();
    let clean = |u: &Vec<f64>| {
        truth
            .simulate(std::slice::from_ref(u), Init::Stored)
            .unwrap()
    };
    let (c_fit, c_new) = (clean(&u), clean(&u_new));
    let rms = (c_fit.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
    let sd = 0.01 * rms;
    let noise = Normal::new(0.0, sd).unwrap();
    let mut draws: Vec<f64> = (0..2 * n).map(|_| noise.sample(&mut rng)).collect();
    let mut record = |u: Vec<f64>, c: &[f64]| {
        let e = draws.split_off(draws.len() - c.len());
        let y: Vec<f64> = c.iter().zip(e).map(|(v, e)| v + e).collect();
        Record::new(vec!["F".into()], "y".into(), vec![u], y)
            .unwrap()
            .with_sample_time(TS)
    };
    let r = record(u, &c_fit);
    let r_new = record(u_new, &c_new);
    let free_run_rms = |m: &PhysicsModel| {
        let s = m.simulate(&r_new.inputs, Init::Stored).unwrap();
        (s.iter()
            .zip(&c_new)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            / n as f64)
            .sqrt()
    };
    let fitted = file
        .fit_growing(&Records::single(r.clone()), &Silent)
        .unwrap();
    let plain = fit(r.clone());
    let shrunk = msd_preisach_file(h, ", prior_sd = 0.05")
        .fit_growing(&Records::single(r), &Silent)
        .unwrap();
    // the error against the clean output of a new record, measured: 1.45e-2
    // (the Preisach model), 7.8e-3 (with the prior on the weights) and
    // 1.08e-1 (the plain model), the noise sd 5.2e-3. The fit does not
    // reach the noise level: the weights of cells the record rarely
    // switches are poorly determined, and the closed loop's cost jumps
    // where a relay's switching sub-step moves (the sensitivities do not
    // see it). Started from zero weights without the forced-cells start:
    // 2.6e-2.
    let (e_pre, e_lin) = (free_run_rms(&fitted), free_run_rms(&plain));
    let e_shrunk = free_run_rms(&shrunk);
    assert!(
        e_pre < 0.2 * e_lin,
        "Preisach model {e_pre:.3e}, plain {e_lin:.3e}"
    );
    assert!(
        e_shrunk < 0.7 * e_pre,
        "with the prior {e_shrunk:.3e}, without {e_pre:.3e}"
    );
    assert!(
        e_lin > 10.0 * sd,
        "plain model: {e_lin:.3e} vs noise sd {sd:.3e}"
    );
}

/// `[preisach]` errors name the file and line.
#[test]
fn preisach_table_errors_name_the_line() {
    let good = msd_preisach_file(1.0, "").text;
    let e = ModelFile::parse(&good.replace("into = \"v\"", "into = \"q\""), "bad.toml")
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("bad.toml:18:") && e.contains("'q' is not a state"),
        "{e}"
    );
    let e = ModelFile::parse(&good.replace("state = \"x\"", "state = \"z\""), "bad.toml")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("bad.toml") && e.contains("'z' is not a state"),
        "{e}"
    );
    let e = ModelFile::parse(&good.replace("min = -1", "min = 2"), "bad.toml")
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("bad.toml:18:") && e.contains("min < max"),
        "{e}"
    );
}
