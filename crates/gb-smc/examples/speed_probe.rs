//! Throughput probe of the bootstrap filter (AR(1), N particles (default
//! 10 000), T = 1000, systematic resampling at every step): best and median of
//! `REPS` runs (default 11), with `parallel(false)` ("serial") and the default
//! `parallel(true)` (rayon from `rng::FILTER_PAR_MIN` = 16 384 particles up,
//! so N = 10 000 runs its steps on the calling thread either way).
//!
//! `cargo run --release -p gb-smc --example speed_probe -- [serial|parallel] [REPS] [N]`
use gb_smc::{FilterConfig, FilterWorkspace, LinearGaussian, Observations, Resampling};
use std::time::Instant;

fn main() {
    let mode = std::env::args().nth(1);
    let reps: usize = std::env::args()
        .nth(2)
        .and_then(|s| s.parse().ok())
        .unwrap_or(11);
    let n: usize = std::env::args()
        .nth(3)
        .and_then(|s| s.parse().ok())
        .unwrap_or(10_000);
    let model = LinearGaussian::ar1(0.9, 1.0, 0.5).expect("valid model");
    let (_, y) = model.simulate(1000, 1);
    let obs = Observations::new(&y);
    let modes: Vec<bool> = match mode.as_deref() {
        Some("serial") => vec![false],
        Some("parallel") => vec![true],
        _ => vec![false, true],
    };
    for parallel in modes {
        let pf = FilterConfig::new(n)
            .resampling(Resampling::Systematic)
            .ess_threshold(1.0)
            .seed(3)
            .parallel(parallel)
            .build()
            .expect("valid config");
        let mut ws = FilterWorkspace::new();
        let mut times = Vec::with_capacity(reps);
        for _ in 0..reps {
            let t0 = Instant::now();
            let out = pf.run_with(&model, &obs, &mut ws, |_| {}).expect("runs");
            std::hint::black_box(out.log_likelihood);
            times.push(t0.elapsed().as_secs_f64());
        }
        times.sort_by(f64::total_cmp);
        let (best, med) = (times[0], times[times.len() / 2]);
        let steps = (n * y.len()) as f64;
        println!(
            "N={n} parallel={parallel}: best {:.1} ms = {:.1} M particle-steps/s, median {:.1} ms ({} rayon threads, {reps} runs)",
            best * 1e3,
            steps / best / 1e6,
            med * 1e3,
            rayon::current_num_threads(),
        );
    }
}
