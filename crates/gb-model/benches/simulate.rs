//! Simulation speed of the model class (issue 7: ≥ 10 M samples/s).
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use gb_model::{NonlinearTerm, Signal, SparseExpansion, SparseStateSpace, Target};
use std::hint::black_box;

fn expansion(dims: usize, max_level: i32) -> SparseExpansion {
    let mut e = SparseExpansion::new("bior2.2", vec![-1.0; dims], vec![1.0; dims]).unwrap();
    e.add_coarse_grid(1).unwrap();
    for level in 1..=max_level {
        for c in e.detail_candidates(level).into_iter().step_by(3) {
            e.push(c).unwrap();
        }
    }
    let vals: Vec<f64> = (0..e.len())
        .map(|i| 1e-4 * (((i * 7919) % 21) as f64 - 10.0))
        .collect();
    e.set_values(&vals).unwrap();
    e.drop_zeros();
    e
}

fn bench(c: &mut Criterion) {
    let n = 1 << 20;
    let u: Vec<Vec<f64>> = vec![(0..n)
        .map(|t| ((t * 7919) % 1000) as f64 / 1000.0 - 0.5)
        .collect()];
    let h = 0.0125;
    let mut msd = SparseStateSpace::linear(
        vec![1.0, h, -h * 4.0, 1.0 - h * 0.6],
        vec![0.0, h],
        vec![1.0, 0.0],
        vec![0.0],
    )
    .unwrap();
    msd.terms.push(NonlinearTerm {
        target: Target::State(1),
        args: vec![Signal::State(0)],
        expansion: expansion(1, 3),
    });
    let hs = 1.0 / 6000.0;
    let mut bw = SparseStateSpace::linear(
        vec![
            1.0,
            hs,
            0.0,
            -hs * 2.5e4,
            1.0 - hs * 20.0,
            -hs,
            0.0,
            hs * 2.5e4,
            1.0 - hs * 5.0,
        ],
        vec![0.0, hs * 0.5, 0.0],
        vec![1.0, 0.0, 0.0],
        vec![0.0],
    )
    .unwrap();
    bw.substeps = 8;
    bw.terms.push(NonlinearTerm {
        target: Target::State(2),
        args: vec![Signal::State(1), Signal::State(2)],
        expansion: expansion(2, 4),
    });
    let mut g = c.benchmark_group("model_simulate");
    g.sample_size(10);
    g.throughput(Throughput::Elements(n as u64));
    g.bench_function("mechanical_1d/1048576", |b| {
        b.iter(|| black_box(msd.simulate(black_box(&u)).unwrap()))
    });
    g.bench_function("bouc_wen_shaped_2d_8substeps/1048576", |b| {
        b.iter(|| black_box(bw.simulate(black_box(&u)).unwrap()))
    });
    // the Bouc-Wen model identified with 3 sub-steps (8.3e-6 m on the
    // multisine test, BW_SUBSTEPS=3 in examples/bouc_wen.rs)
    let mut bw3 = bw.clone();
    bw3.substeps = 3;
    g.bench_function("bouc_wen_shaped_2d_3substeps/1048576", |b| {
        b.iter(|| black_box(bw3.simulate(black_box(&u)).unwrap()))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
