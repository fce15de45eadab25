//! Speed of the physics model class (issue 17): fitting
//! `examples/models/msd.toml` on 10 000 samples (goal ≤ 1 s) and simulating
//! the fitted 2-state model (goal ≥ 5 M samples/s; the file's 4 RK4
//! sub-steps per sample, and 1 sub-step for the cost of one RK4 step).
//!
//! The record is generated with a fixed seed: the msd truth (m = 1,
//! c = 0.4, k = 4, 20 RK4 sub-steps per sample, 20 Hz) driven by random
//! force steps, plus white noise of 0.01.
//!
//! `physics_fit/bouc_wen_5iter/4000`: five Levenberg–Marquardt iterations
//! of `examples/models/bouc_wen.toml` (3 states, 6 free parameters and 3
//! free initial states: 9 sensitivity lanes, 4 RK4 sub-steps) on 4000
//! samples its truth generates from random force steps — the cost of the
//! sensitivity simulations that dominate the blind diagnosis' mechanical
//! templates.
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use gb_core::{DynamicModel, Identify, Init, Record, Records, Silent};
use gb_model::physics::{ModelFile, PhysicsFitParams, PhysicsModel};
use rand::Rng;
use rand_distr::{Distribution, Normal};
use std::hint::black_box;
use std::path::PathBuf;

const TS: f64 = 0.05;
/// m, c, k of the truth.
const TRUTH: [f64; 3] = [1.0, 0.4, 4.0];

fn model_file() -> ModelFile {
    example_file("msd.toml")
}

fn example_file(name: &str) -> ModelFile {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../examples/models")
        .join(name);
    ModelFile::read(&path).expect("an example model file")
}

/// The Bouc–Wen file's truth (m = 2, c = 10, k = 5e4, α = 5e4, β = 1e3,
/// γ = 0.8, δ = −1.1, no input delay) on 4000 samples of random force
/// steps (amplitude 50 N), plus white noise of 1e-6 m; the fit starts
/// from the file's values.
fn bouc_wen_record(mf: &ModelFile) -> Record {
    let mut rng = gb_core::rng::seeded(19);
    let u: Vec<f64> = force_steps(4000, &mut rng)
        .iter()
        .map(|v| 50.0 * v)
        .collect();
    let truth = PhysicsModel::new(mf.spec.clone())
        .expect("the truth compiles")
        .with_values(
            vec![2.0, 10.0, 5e4, 5e4, 1e3, 0.8, -1.1, 0.0],
            vec![0.0, 0.0, 0.0],
        )
        .expect("the truth's values fit");
    let clean = truth
        .simulate(std::slice::from_ref(&u), Init::Stored)
        .expect("the truth simulates");
    let noise = Normal::new(0.0, 1e-6).expect("valid normal");
    let y: Vec<f64> = clean.iter().map(|v| v + noise.sample(&mut rng)).collect();
    let mut rec = Record::new(vec!["u".into()], "y".into(), vec![u], y).expect("consistent record");
    rec.sample_time = mf.spec.sample_time;
    rec
}

/// Random force steps held 5–40 samples.
fn force_steps(n: usize, rng: &mut impl Rng) -> Vec<f64> {
    let level = Normal::new(0.0, 1.0).expect("valid normal");
    let mut u = Vec::with_capacity(n);
    while u.len() < n {
        let hold = rng.random_range(5..40);
        u.extend(std::iter::repeat_n(level.sample(rng), hold));
    }
    u.truncate(n);
    u
}

/// The generated msd record of `n` samples (seed 17).
fn msd_record(mf: &ModelFile, n: usize) -> Record {
    let mut rng = gb_core::rng::seeded(17);
    let u = force_steps(n, &mut rng);
    let mut spec = mf.spec.clone();
    spec.substeps = 20;
    spec.sample_time = Some(TS);
    let truth = PhysicsModel::new(spec)
        .expect("the truth compiles")
        .with_values(TRUTH.to_vec(), vec![0.0, 0.0])
        .expect("the truth's values fit");
    let clean = truth
        .simulate(std::slice::from_ref(&u), Init::Stored)
        .expect("the truth simulates");
    let noise = Normal::new(0.0, 0.01).expect("valid normal");
    let y: Vec<f64> = clean.iter().map(|v| v + noise.sample(&mut rng)).collect();
    let mut rec = Record::new(vec!["F".into()], "y".into(), vec![u], y).expect("consistent record");
    rec.sample_time = Some(TS);
    rec
}

fn bench(c: &mut Criterion) {
    let mut mf = model_file();
    mf.spec.sample_time = Some(TS);
    let data = Records::single(msd_record(&mf, 10_000));

    let mut g = c.benchmark_group("physics_fit");
    g.sample_size(10);
    g.bench_function("msd/10000", |b| {
        b.iter(|| black_box(mf.fit(&data, &Silent).expect("fit")))
    });
    g.bench_function("msd_growing/10000", |b| {
        b.iter(|| black_box(mf.fit_growing(&data, &Silent).expect("fit")))
    });
    let bw = example_file("bouc_wen.toml");
    let bw_data = Records::single(bouc_wen_record(&bw));
    let bw_fit = PhysicsFitParams::new(bw.spec.clone())
        .max_iter(5)
        .check()
        .expect("valid fit settings");
    g.bench_function("bouc_wen_5iter/4000", |b| {
        b.iter(|| black_box(bw_fit.identify(&bw_data, &Silent).expect("fit")))
    });
    g.finish();

    let fitted = mf.fit(&data, &Silent).expect("fit");
    let n = 1 << 20;
    let mut rng = gb_core::rng::seeded(18);
    let u = vec![force_steps(n, &mut rng)];
    let mut g = c.benchmark_group("physics_simulate");
    g.throughput(Throughput::Elements(n as u64));
    g.sample_size(10);
    g.bench_function(format!("msd_4substeps/{n}"), |b| {
        b.iter(|| black_box(fitted.simulate(&u, Init::Stored).expect("simulate")))
    });
    // the same model with one RK4 step per sample: the cost per step
    let mut spec = fitted.spec().clone();
    spec.substeps = 1;
    let one_step = PhysicsModel::new(spec)
        .expect("the fitted model compiles")
        .with_values(
            fitted.parameters().to_vec(),
            fitted.initial_state().to_vec(),
        )
        .expect("the fitted values fit");
    g.bench_function(format!("msd_1substep/{n}"), |b| {
        b.iter(|| black_box(one_step.simulate(&u, Init::Stored).expect("simulate")))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
