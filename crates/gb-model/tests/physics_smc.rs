//! The SMC path of a user's model file: the mass–spring–damper of
//! `examples/models/msd.toml` with a random force disturbance (process
//! noise on the velocity) and white measurement noise, known truth.
use gb_core::{Record, Records, Silent};
use gb_model::physics::ModelFile;
use gb_model::SmcParams;
use rand_distr::{Distribution, Normal};
use std::path::PathBuf;

mod common;

const TS: f64 = 0.05;
const M: f64 = 1.0;
const C: f64 = 0.4;
const K: f64 = 4.0;

/// `x'' = (F − c x' − k x)/m` by RK4 (20 steps per sample, F held), then
/// `v += N(0, sd_v²)` per sample; `y = x + N(0, sd_w²)`.
fn disturbed_msd(n: usize, seed: u64, sd_v: f64, sd_w: f64) -> Record {
    let mut rng = gb_core::rng::seeded(seed);
    let u = common::steps(n, &mut rng);
    let f = |x: f64, v: f64, force: f64| (v, (force - C * v - K * x) / M);
    let (mut x, mut v) = (0.0, 0.0);
    let h = TS / 20.0;
    let (nv, nw) = (
        Normal::new(0.0, sd_v).unwrap(),
        Normal::new(0.0, sd_w).unwrap(),
    );
    let mut y = Vec::with_capacity(n);
    for &force in &u {
        y.push(x + nw.sample(&mut rng));
        for _ in 0..20 {
            let k1 = f(x, v, force);
            let k2 = f(x + 0.5 * h * k1.0, v + 0.5 * h * k1.1, force);
            let k3 = f(x + 0.5 * h * k2.0, v + 0.5 * h * k2.1, force);
            let k4 = f(x + h * k3.0, v + h * k3.1, force);
            x += h / 6.0 * (k1.0 + 2.0 * (k2.0 + k3.0) + k4.0);
            v += h / 6.0 * (k1.1 + 2.0 * (k2.1 + k3.1) + k4.1);
        }
        v += nv.sample(&mut rng);
    }
    Record::new(vec!["F".into()], "y".into(), vec![u], y)
        .unwrap()
        .with_sample_time(TS)
}

fn msd_file() -> ModelFile {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../examples/models/msd.toml");
    ModelFile::read(&p).unwrap()
}

/// PMMH from the output-error fit, on data with a known force disturbance
/// (process noise on the velocity, sd 0.02 per sample) and measurement
/// noise (sd 0.01):
/// - the kinematic state (`x = "v"`) takes no process noise;
/// - the velocity's process sd is found: its 95 % interval covers the
///   truth and lies above half of it (an estimator that ignored the
///   disturbance, or put it into the measurement noise, misses);
/// - the measurement sd is within 20 % of the truth;
/// - the stiffness-to-mass ratio k/m is within 8 %, m, c, k within 12, 30, 12 %;
/// - the posterior mean's particle likelihood beats the start's (process
///   noise at 5 % of the state increments) by more than 5 nats.
///
/// The chain is short for a test (3000 iterations, ESS 10–80): its 95 %
/// intervals of m, c and k do not reliably cover the truth, which is why
/// they are not asserted (docs/smc.md).
#[test]
fn pmmh_recovers_the_force_disturbance_of_a_model_file() {
    let (sd_v, sd_w) = (0.02, 0.01);
    let d = disturbed_msd(300, 5, sd_v, sd_w);
    let mf = msd_file();
    let oe = mf
        .fit_growing(&Records::single(d.clone()), &Silent)
        .unwrap();
    let smc = SmcParams::new()
        .particles(200)
        .iterations(3000, 750)
        .seed(3)
        .check()
        .unwrap();
    let rep = smc.fit_physics(&oe, &d, &Silent).unwrap();
    let get = |name: &str| rep.parameters.iter().find(|p| p.name == name).unwrap();
    for p in &rep.parameters {
        eprintln!(
            "{:<18} {:.5} [{:.5}, {:.5}] ESS {:.0} R̂ {:.3}",
            p.name, p.mean, p.lo, p.hi, p.ess, p.rhat
        );
    }
    assert!(rep.parameters.iter().all(|p| p.name != "process_sd[x]"));
    let v = get("process_sd[v]");
    assert!(v.lo <= sd_v && sd_v <= v.hi && v.lo > 0.5 * sd_v, "{v:?}");
    let w = get("measurement_sd");
    assert!((w.mean / sd_w - 1.0).abs() < 0.2, "{w:?}");
    let (m, c, k) = (get("m").mean, get("c").mean, get("k").mean);
    // 300 disturbed samples pin k/m to about 5 % (the output-error fit of
    // this record gives 3.82)
    assert!(((k / m) / (K / M) - 1.0).abs() < 0.08, "k/m = {}", k / m);
    // the posterior means of a short, poorly mixed chain wander: on this
    // record c came out 0.31–0.35 over settings (output-error 0.33), m
    // 1.04–1.10; the bounds catch a sampler that drifts off, not noise
    for (name, est, truth, tol) in [("m", m, M, 0.12), ("c", c, C, 0.3), ("k", k, K, 0.12)] {
        assert!((est / truth - 1.0).abs() < tol, "{name} = {est}");
    }
    assert!(
        rep.log_likelihood_smc > rep.log_likelihood_oe + 5.0,
        "{} vs {}",
        rep.log_likelihood_smc,
        rep.log_likelihood_oe
    );
    assert!(rep.acceptance_rate > 0.03 && rep.acceptance_rate < 0.8);
}
