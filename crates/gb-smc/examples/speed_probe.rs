//! Throughput probe of the bootstrap filter (AR(1), N = 10 000, T = 1000).
use gb_smc::{FilterConfig, FilterWorkspace, LinearGaussian, Observations, Resampling};
use std::time::Instant;

fn main() {
    if std::env::args().nth(1).as_deref() == Some("micro") {
        micro();
        return;
    }
    let model = LinearGaussian::ar1(0.9, 1.0, 0.5).expect("valid model");
    let (_, y) = model.simulate(1000, 1);
    let obs = Observations::new(&y);
    let modes: Vec<bool> = match std::env::args().nth(1).as_deref() {
        Some("serial") => vec![false],
        Some("parallel") => vec![true],
        _ => vec![false, true],
    };
    for parallel in modes {
        let pf = FilterConfig::new(10_000)
            .resampling(Resampling::Systematic)
            .ess_threshold(1.0)
            .parallel(parallel)
            .build()
            .expect("valid config");
        let mut ws = FilterWorkspace::new();
        let mut best = f64::INFINITY;
        for _ in 0..5 {
            let t0 = Instant::now();
            let out = pf.run_with(&model, &obs, &mut ws, |_| {}).expect("runs");
            std::hint::black_box(out.log_likelihood);
            best = best.min(t0.elapsed().as_secs_f64());
        }
        println!(
            "parallel={parallel}: {:.1} M particle-steps/s",
            1e7 / best / 1e6
        );
    }
}

#[allow(dead_code)]
fn micro() {
    use rand::Rng;
    use rand_distr::StandardNormal;
    let mut rng = gb_smc::rng::stream(1, 2, 3, 4);
    let n = 20_000_000;
    let t0 = Instant::now();
    let mut s = 0.0;
    for _ in 0..n {
        s += rng.sample::<f64, _>(StandardNormal);
    }
    println!(
        "rand_distr normal: {:.2} ns",
        t0.elapsed().as_secs_f64() * 1e9 / n as f64
    );
    let t0 = Instant::now();
    for _ in 0..n {
        s += gb_smc::rng::standard_normal(&mut rng);
    }
    println!(
        "gb_smc normal: {:.2} ns",
        t0.elapsed().as_secs_f64() * 1e9 / n as f64
    );
    let t0 = Instant::now();
    for _ in 0..n {
        s += rng.random::<f64>();
    }
    println!(
        "uniform: {:.2} ns",
        t0.elapsed().as_secs_f64() * 1e9 / n as f64
    );
    let v: Vec<f64> = (0..10_000).map(|i| -(i as f64) * 0.001).collect();
    let t0 = Instant::now();
    for _ in 0..(n / 10_000) {
        for &x in &v {
            s += x.exp();
        }
    }
    println!(
        "libm exp: {:.2} ns",
        t0.elapsed().as_secs_f64() * 1e9 / n as f64
    );
    std::hint::black_box(s);
}
