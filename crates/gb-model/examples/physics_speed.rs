//! Simulation of the physics model `examples/models/msd.toml` (issue 17:
//! ≥ 5 M samples/s with its 4 RK4 sub-steps per sample) for instruction
//! counts: it simulates `N` samples once, so the difference of two runs
//! under `valgrind --tool=cachegrind` divided by the difference of `N` is
//! the cost of one simulated sample, free of start-up.
//!
//! ```sh
//! cargo build --release -p gb-model --example physics_speed
//! GB_ONE_RUN=1 valgrind --tool=cachegrind --cache-sim=no \
//!     target/release/examples/physics_speed 131072
//! GB_ONE_RUN=1 valgrind --tool=cachegrind --cache-sim=no \
//!     target/release/examples/physics_speed 262144
//! ```
//!
//! It prints the wall time (best of 5 simulations; one with `GB_ONE_RUN`)
//! and the sum of the outputs (a bit-exact check between versions).
use gb_core::{DynamicModel, Init};
use gb_model::physics::{ModelFile, PhysicsModel};
use std::path::PathBuf;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let n: usize = match std::env::args().nth(1) {
        Some(a) => a.parse()?,
        None => 1 << 17,
    };
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../examples/models/msd.toml");
    let mut spec = ModelFile::read(&path)?.spec;
    spec.sample_time = Some(0.05);
    // the truth of the bench record: m = 1, c = 0.4, k = 4
    let model = PhysicsModel::new(spec)?.with_values(vec![1.0, 0.4, 4.0], vec![0.0, 0.0])?;
    let u = vec![(0..n)
        .map(|t| ((t / 17 * 7919) % 1000) as f64 / 500.0 - 1.0)
        .collect::<Vec<f64>>()];
    let runs = if std::env::var_os("GB_ONE_RUN").is_some() {
        1
    } else {
        5
    };
    let mut best = f64::INFINITY;
    let mut check = 0.0;
    for _ in 0..runs {
        let t0 = Instant::now();
        let y = model.simulate(&u, Init::Stored)?;
        best = best.min(t0.elapsed().as_secs_f64());
        check = y.iter().sum::<f64>();
    }
    println!(
        "{n} samples: {:.3} ms = {:.2} M samples/s (Σy = {check:e})",
        best * 1e3,
        n as f64 / best / 1e6
    );
    Ok(())
}
