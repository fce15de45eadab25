//! Whole `diagnose` on 8000 fit + 4000 validation samples, one input.
//! `cargo bench -p greybox --bench diagnose`
use criterion::{criterion_group, criterion_main, Criterion};
use gb_diagnose::{diagnose, systems, DiagnoseData, DiagnoseOptions};

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("diagnose");
    g.sample_size(10);
    for system in ["linear", "shock-absorber"] {
        let gen = systems::generate(system, 1, 8000, 4000).expect("generate");
        let data = DiagnoseData::with_validation(gen.train, gen.validate).expect("data");
        g.bench_function(format!("{system}/8000+4000"), |b| {
            b.iter(|| diagnose(&data, &DiagnoseOptions::default(), None).expect("diagnose"))
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
