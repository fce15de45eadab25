//! Preisach operator throughput: `preisach/1000000` is the figure of issue 6
//! (1e6 samples of a bounded random input, smooth parametric Everett
//! function, memory depth ≤ 32, output at every step).
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use gb_preisach::{GridEverett, InitialState, ParametricEverett, PrandtlIshlinskii, Preisach};
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::hint::black_box;

const N: usize = 1_000_000;

fn input() -> Vec<f64> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(2026);
    (0..N).map(|_| rng.random_range(-1.5..1.5)).collect()
}

fn bench(c: &mut Criterion) {
    let x = input();
    let mut y = vec![0.0; N];

    let mut g = c.benchmark_group("preisach");
    g.throughput(Throughput::Elements(N as u64));
    g.sample_size(20);
    let gauss = Preisach::new(ParametricEverett::gaussian(1.0, 0.4, 0.3, -0.4, 0.3).unwrap())
        .with_memory_cap(32)
        .unwrap();
    g.bench_with_input(BenchmarkId::from_parameter(N), &x, |b, x| {
        b.iter(|| {
            let mut st = gauss.state(&InitialState::NegativeSaturation).unwrap();
            for (yo, &xi) in y.iter_mut().zip(x.iter()) {
                *yo = gauss.step(&mut st, xi);
            }
            black_box(&y);
        })
    });
    g.finish();

    let mut g = c.benchmark_group("preisach_lorentzian");
    g.throughput(Throughput::Elements(N as u64));
    g.sample_size(10);
    let lor = Preisach::new(ParametricEverett::lorentzian(1.0, 0.4, 0.2, -0.4, 0.2).unwrap())
        .with_memory_cap(32)
        .unwrap();
    g.bench_with_input(BenchmarkId::from_parameter(N), &x, |b, x| {
        b.iter(|| {
            let mut st = lor.state(&InitialState::NegativeSaturation).unwrap();
            for (yo, &xi) in y.iter_mut().zip(x.iter()) {
                *yo = lor.step(&mut st, xi);
            }
            black_box(&y);
        })
    });
    g.finish();

    let mut g = c.benchmark_group("preisach_grid32");
    g.throughput(Throughput::Elements(N as u64));
    g.sample_size(10);
    let f = ParametricEverett::gaussian(1.0, 0.4, 0.3, -0.4, 0.3).unwrap();
    let grid = Preisach::new(GridEverett::from_everett(&f, -1.5, 1.5, 32).unwrap())
        .with_memory_cap(32)
        .unwrap();
    g.bench_with_input(BenchmarkId::from_parameter(N), &x, |b, x| {
        b.iter(|| {
            let mut st = grid.state(&InitialState::NegativeSaturation).unwrap();
            for (yo, &xi) in y.iter_mut().zip(x.iter()) {
                *yo = grid.step(&mut st, xi);
            }
            black_box(&y);
        })
    });
    g.finish();

    let mut g = c.benchmark_group("pi16");
    g.throughput(Throughput::Elements(N as u64));
    g.sample_size(10);
    let pi = PrandtlIshlinskii::new(
        1.0,
        (0..16).map(|i| 0.1 * i as f64).collect(),
        vec![0.1; 16],
    )
    .unwrap();
    g.bench_with_input(BenchmarkId::from_parameter(N), &x, |b, x| {
        b.iter(|| {
            let mut st = pi.initial_state(x[0]);
            for (yo, &xi) in y.iter_mut().zip(x.iter()) {
                *yo = pi.step(&mut st, xi);
            }
            black_box(&y);
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
