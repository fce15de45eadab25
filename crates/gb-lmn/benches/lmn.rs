//! Speed figures of issue 3:
//! * `lolimot_fit/tree_axis/20_leaves_100000x8`: LOLIMOT growth (tree
//!   weights, axis splits) to 20 leaves on 100 000 samples × 8 regressors
//!   (target ≤ 2 s on 2 cores);
//! * `lolimot_fit/gauss_axis/20_leaves_100000x8`: the same with normalised
//!   Gaussians (classic LOLIMOT);
//! * `noe_simulate/20_leaves/1000000`: free-run simulation of a 20-leaf NOE
//!   network (x: y(k−1), y(k−2), u(k−1), u(k−2); z: y(k−1), u(k−1)),
//!   target ≥ 10 M samples/s;
//! * `block_fit/{hammerstein,wiener}_order2/8000`: a block-oriented fit
//!   with its map-structure choice on 8000 samples (the diagnosis' most
//!   frequent candidates).
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use gb_core::{Record, Records};
use gb_lmn::{BlockParams, Criterion as Crit, Focus, LmnParams, RegressorSpec, WeightKind};
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::hint::black_box;

/// A record of input signals u1, u2, … and output y.
fn record(inputs: Vec<Vec<f64>>, y: Vec<f64>) -> Record {
    let names = (1..=inputs.len()).map(|j| format!("u{j}")).collect();
    Record::new(names, "y".into(), inputs, y).expect("finite signals of one length")
}

/// 100 000 samples of 8 inputs, y = a smooth nonlinear function + noise.
fn static_data(n: usize) -> Records {
    let mut r = Xoshiro256PlusPlus::seed_from_u64(2026);
    let u: Vec<Vec<f64>> = (0..8)
        .map(|_| (0..n).map(|_| r.random_range(-1.0..1.0)).collect())
        .collect();
    let y: Vec<f64> = (0..n)
        .map(|k| {
            let x: Vec<f64> = u.iter().map(|c| c[k]).collect();
            (2.0 * x[0]).tanh() * x[1] + (3.0 * x[2] * x[3]).sin() + x[4] * x[4] - 0.5 * x[5]
                + 0.3 * x[6] * x[7]
                + 0.01 * r.random_range(-1.0..1.0)
        })
        .collect();
    Records::single(record(u, y))
}

fn dynamic_data(n: usize) -> Records {
    let mut r = Xoshiro256PlusPlus::seed_from_u64(7);
    let u: Vec<f64> = (0..n).map(|_| r.random_range(-1.0..1.0)).collect();
    let mut y = vec![0.0; n];
    for k in 2..n {
        y[k] = 0.5 * y[k - 1]
            + 0.2 * y[k - 2]
            + 0.6 * (1.5 * u[k - 1]).tanh()
            + 0.2 * (2.0 * y[k - 1]).tanh() * u[k - 2];
    }
    Records::single(record(vec![u], y))
}

fn bench(c: &mut Criterion) {
    let d = static_data(100_000);
    let reg = RegressorSpec::arx(0, &[1; 8], &[0; 8]);
    let mut g = c.benchmark_group("lolimot_fit");
    g.sample_size(10);
    for (name, w) in [
        ("tree_axis", WeightKind::Tree),
        ("gauss_axis", WeightKind::Gaussian),
    ] {
        let p = LmnParams::new(reg.clone())
            .weights(w)
            .max_leaves(20)
            .patience(100)
            .criterion(Crit::Aicc)
            .lm_iterations(0);
        let m = p.fit(&d).unwrap();
        assert_eq!(
            m.summary.history.len(),
            20,
            "{name} grew {:?}",
            m.summary.history.len()
        );
        g.bench_function(BenchmarkId::new(name, "20_leaves_100000x8"), |b| {
            b.iter(|| black_box(p.fit(&d).unwrap()))
        });
    }
    g.finish();

    let train = dynamic_data(20_000);
    let reg = RegressorSpec::arx(2, &[2], &[1]).with_z(vec![1], vec![vec![1]]);
    let m = LmnParams::new(reg)
        .max_leaves(20)
        .patience(100)
        .criterion(Crit::Validation)
        .focus(Focus::Prediction)
        .lm_iterations(0)
        .check()
        .unwrap()
        .fit(&train, Some(&train))
        .unwrap();
    assert_eq!(m.n_leaves(), 20);
    let n = 1_000_000;
    let test = dynamic_data(n);
    let mut g = c.benchmark_group("noe_simulate");
    g.throughput(Throughput::Elements(n as u64));
    g.sample_size(10);
    g.bench_function(BenchmarkId::new("20_leaves", n), |b| {
        b.iter(|| black_box(m.simulate(test.first(), 2).unwrap()))
    });
    g.finish();

    // block-oriented fits as the diagnosis runs them (every default map
    // structure fitted on 80 % and judged on the rest, then refitted):
    // their Levenberg-Marquardt Gram matrices dominate (gb_core::gram)
    let d = dynamic_data(8000);
    let one = d.first().clone();
    let mut g = c.benchmark_group("block_fit");
    g.sample_size(10);
    for (name, p) in [
        ("hammerstein_order2", BlockParams::hammerstein(2, 1)),
        ("wiener_order2", BlockParams::wiener(2)),
    ] {
        let v = p.check().unwrap();
        g.bench_function(BenchmarkId::new(name, 8000), |b| {
            b.iter(|| black_box(v.fit(&one).unwrap()))
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
