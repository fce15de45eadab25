//! Throughput probe of the bootstrap filter (AR(1), N = 10 000, T = 1000,
//! systematic resampling at every step): best and median of `REPS` runs
//! (default 11), serial (`parallel(false)`) and with rayon.
//!
//! `cargo run --release -p gb-smc --example speed_probe [serial|parallel] [REPS]`
use gb_smc::{FilterConfig, FilterWorkspace, LinearGaussian, Observations, Resampling};
use std::time::Instant;

fn main() {
    let mode = std::env::args().nth(1);
    let reps: usize = std::env::args()
        .nth(2)
        .and_then(|s| s.parse().ok())
        .unwrap_or(11);
    let model = LinearGaussian::ar1(0.9, 1.0, 0.5).expect("valid model");
    let (_, y) = model.simulate(1000, 1);
    let obs = Observations::new(&y);
    let modes: Vec<(bool, bool)> = match mode.as_deref() {
        Some("serial") => vec![(false, false)],
        Some("parallel") => vec![(true, false)],
        Some("inpool") => vec![(true, true)],
        _ => vec![(false, false), (true, false)],
    };
    for (parallel, inpool) in modes {
        let pf = FilterConfig::new(10_000)
            .resampling(Resampling::Systematic)
            .ess_threshold(1.0)
            .seed(3)
            .parallel(parallel)
            .build()
            .expect("valid config");
        let mut ws = FilterWorkspace::new();
        let mut times = Vec::with_capacity(reps);
        let mut body = || {
            for _ in 0..reps {
                let t0 = Instant::now();
                let out = pf.run_with(&model, &obs, &mut ws, |_| {}).expect("runs");
                std::hint::black_box(out.log_likelihood);
                times.push(t0.elapsed().as_secs_f64());
            }
        };
        if inpool {
            rayon::scope(|_| body());
        } else {
            body();
        }
        times.sort_by(f64::total_cmp);
        let (best, med) = (times[0], times[times.len() / 2]);
        println!(
            "parallel={parallel}{}: best {:.1} ms = {:.1} M particle-steps/s, median {:.1} ms ({} threads, {reps} runs)",
            if inpool { " (in pool)" } else { "" },
            best * 1e3,
            1e7 / best / 1e6,
            med * 1e3,
            if parallel { rayon::current_num_threads() } else { 1 },
        );
    }
}
