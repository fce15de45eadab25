//! Bootstrap filter on the scalar AR(1) model of issue 5:
//! x_t = 0.9 x_{t-1} + N(0, 1), y_t = x_t + N(0, 0.5²), N = 10 000, T = 1000,
//! systematic resampling at every step, log-likelihood computed.
//!
//! Run: `cargo bench -p gb-smc --bench filter` (`RAYON_NUM_THREADS=1` for the
//! single-thread figure). Throughput is reported in particle-steps
//! ("elements") per second. The filter is the library's public API
//! (`ParticleFilter::run_with` with a reused `FilterWorkspace`); the model is
//! the library's `LinearGaussian`, monomorphised.
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use gb_smc::{FilterConfig, FilterWorkspace, LinearGaussian, Observations, Resampling};
use std::hint::black_box;

fn bench_filter(c: &mut Criterion) {
    let model = LinearGaussian::ar1(0.9, 1.0, 0.5).expect("valid model");
    let t_len = 1000;
    let (_, y) = model.simulate(t_len, 1);
    let obs = Observations::new(&y);
    let mut group = c.benchmark_group("bootstrap_ar1");
    group.sample_size(20);
    for &n in &[1_000usize, 10_000] {
        let pf = FilterConfig::new(n)
            .resampling(Resampling::Systematic)
            .ess_threshold(1.0)
            .seed(3)
            .build()
            .expect("valid config");
        let mut ws = FilterWorkspace::new();
        group.throughput(Throughput::Elements((n * t_len) as u64));
        group.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| {
                let out = pf
                    .run_with(&model, &obs, &mut ws, |_| {})
                    .expect("filter runs");
                black_box(out.log_likelihood)
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench_filter);
criterion_main!(benches);
