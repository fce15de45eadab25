//! PMMH: 512 particles, T = 2000 observations, 2000 iterations — one sample
//! is one whole chain (about 2 · 10⁹ particle-steps). Model: the AR(1) of
//! `tests/estimation.rs`, `x_t = φ x_{t-1} + N(0, σ_x²)`, `y_t = x_t + N(0, 0.5²)`,
//! unknown `θ = (φ, σ_x)` with a flat prior on `(−1, 1) × (0, 5)`, data from
//! `φ = 0.8`, `σ_x = 1`, the chain started at `(0.5, 1.5)`; bootstrap filter
//! with the library's default (adaptive systematic) resampling, adaptive
//! random-walk proposals from iteration 500.
//!
//! Run: `cargo bench -p gb-smc --bench pmmh` (10 samples, ≈ 10 chains), or
//! `cargo bench -p gb-smc --bench pmmh -- --quick` for a short estimate.
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use gb_smc::estimation::{ParametricModel, Pmmh, PmmhConfig, Silent};
use gb_smc::{LinearGaussian, Observations};
use std::hint::black_box;
use std::time::Duration;

struct Ar1Params;
impl ParametricModel for Ar1Params {
    type Model = LinearGaussian;
    fn dim(&self) -> usize {
        2
    }
    fn build(&self, th: &[f64]) -> Option<LinearGaussian> {
        LinearGaussian::ar1(th[0], th[1], 0.5).ok()
    }
    fn log_prior(&self, th: &[f64]) -> f64 {
        if th[0].abs() < 1.0 && th[1] > 0.0 && th[1] < 5.0 {
            0.0
        } else {
            f64::NEG_INFINITY
        }
    }
}

fn bench_pmmh(c: &mut Criterion) {
    let (particles, t_len, iterations) = (512, 2000, 2000);
    let truth = LinearGaussian::ar1(0.8, 1.0, 0.5).expect("valid model");
    let (_, y) = truth.simulate(t_len, 1);
    let obs = Observations::new(&y);
    let mut cfg = PmmhConfig::new(particles, iterations, vec![0.02, 0.03]);
    cfg.burn_in = 500;
    cfg.adapt_start = 500;
    cfg.seed = 7;
    let pmmh = Pmmh::new(cfg).expect("valid config");
    let mut group = c.benchmark_group("pmmh_ar1");
    group.sample_size(10);
    group.warm_up_time(Duration::from_millis(1));
    group.measurement_time(Duration::from_secs(60));
    group.throughput(Throughput::Elements(
        (particles * t_len * iterations) as u64,
    ));
    group.bench_function("512x2000x2000", |b| {
        b.iter(|| {
            let res = pmmh
                .run(&Ar1Params, &obs, &[0.5, 1.5], &Silent)
                .expect("chain runs");
            black_box((res.acceptance_rate, res.summary[0].mean))
        })
    });
    group.finish();
}

criterion_group!(benches, bench_pmmh);
criterion_main!(benches);
