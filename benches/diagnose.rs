//! Whole `diagnose` on 8000 fit + 4000 validation samples, one input: two
//! systems of `gb_diagnose::systems` and three cases of the sweep's
//! generator (a Wiener system, dry friction, a Preisach spring), each at
//! seed 1 with the length fixed to 8000 + 4000.
//! `cargo bench -p greybox --bench diagnose`
use criterion::{criterion_group, criterion_main, Criterion};
use gb_diagnose::generator::{draw_with, Knobs};
use gb_diagnose::sweep::{run_diagnosis, OrderMode};
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
    let knobs = Knobs {
        n_train: Some(8000),
        n_validate: Some(4000),
        ..Knobs::default()
    };
    for family in ["wiener", "friction", "preisach"] {
        let case = draw_with(family, 1, &knobs).expect("generate");
        g.bench_function(format!("sweep-{family}-1/8000+4000"), |b| {
            b.iter(|| run_diagnosis(&case, OrderMode::Case).expect("diagnose"))
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
