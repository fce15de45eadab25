//! Fast wavelet transform benchmarks. Ids `dwt/db4/1048576` and
//! `wavedec/db4/1048576` are the ones issue 4 checks (periodization mode).
//!
//! Run: `cargo bench -p gb-wavelet --bench fwt`

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use gb_wavelet::{DecompositionPlan, Mode, Wavelet};
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

fn random_signal(n: usize) -> Vec<f64> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(42);
    (0..n).map(|_| rng.random::<f64>() - 0.5).collect()
}

fn bench_fwt(c: &mut Criterion) {
    let n = 1 << 20;
    let x = random_signal(n);
    for name in ["db4", "sym8"] {
        let w = Wavelet::new(name).expect("known wavelet");
        let mut group = c.benchmark_group("dwt");
        group.throughput(Throughput::Elements(n as u64));
        let half = w.dwt_len(n, Mode::Periodization);
        let (mut a, mut d) = (vec![0.0; half], vec![0.0; half]);
        group.bench_function(BenchmarkId::new(name, n), |b| {
            b.iter(|| {
                w.dwt_into(&x, Mode::Periodization, &mut a, &mut d)
                    .expect("buffers sized by plan")
            })
        });
        group.finish();

        let plan = DecompositionPlan::new(&w, n, Mode::Periodization, None).expect("valid plan");
        let mut coeffs = vec![0.0; plan.coeff_len()];
        let mut scratch = vec![0.0; plan.scratch_len()];
        let mut group = c.benchmark_group("wavedec");
        group.throughput(Throughput::Elements(n as u64));
        group.bench_function(BenchmarkId::new(name, n), |b| {
            b.iter(|| {
                plan.decompose(&x, &mut coeffs, &mut scratch)
                    .expect("buffers sized by plan")
            })
        });
        group.finish();

        let mut y = vec![0.0; plan.output_len()];
        let mut group = c.benchmark_group("waverec");
        group.throughput(Throughput::Elements(n as u64));
        group.bench_function(BenchmarkId::new(name, n), |b| {
            b.iter(|| {
                plan.reconstruct(&coeffs, &mut y, &mut scratch)
                    .expect("buffers sized by plan")
            })
        });
        group.finish();
    }
}

criterion_group!(benches, bench_fwt);
criterion_main!(benches);
