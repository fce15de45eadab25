//! PMMH coverage and IF2 against the exact (Kalman) maximum-likelihood estimate.
use gb_smc::estimation::{If2, If2Config, ParametricModel, Pmmh, PmmhConfig, Silent};
use gb_smc::{KalmanFilter, LinearGaussian, Observations};
use rayon::prelude::*;

/// AR(1) with unknown θ = (φ, σ_x), σ_y = 0.5 known; flat prior on (−1, 1) × (0, 5).
struct Ar1Params;
impl ParametricModel for Ar1Params {
    type Model = LinearGaussian;
    fn dim(&self) -> usize {
        2
    }
    fn build(&self, th: &[f64]) -> Option<LinearGaussian> {
        LinearGaussian::ar1(th[0], th[1], 0.5).ok()
    }
    fn log_prior(&self, th: &[f64]) -> f64 {
        if th[0].abs() < 1.0 && th[1] > 0.0 && th[1] < 5.0 {
            0.0
        } else {
            f64::NEG_INFINITY
        }
    }
}

const TRUTH: [f64; 2] = [0.8, 1.0];

fn pmmh_config(seed: u64) -> PmmhConfig {
    let mut cfg = PmmhConfig::new(150, 1200, vec![0.05, 0.08]);
    cfg.burn_in = 300;
    cfg.adapt_start = 300;
    cfg.seed = seed;
    cfg
}

#[test]
fn pmmh_intervals_cover_the_truth() {
    let truth = LinearGaussian::ar1(TRUTH[0], TRUTH[1], 0.5).unwrap();
    let results: Vec<_> = (0..20u64)
        .into_par_iter()
        .map(|r| {
            let (_, y) = truth.simulate(100, 500 + r);
            Pmmh::new(pmmh_config(r))
                .unwrap()
                .run(&Ar1Params, &Observations::new(&y), &[0.5, 1.5], &Silent)
                .unwrap()
        })
        .collect();
    for (j, &true_value) in TRUTH.iter().enumerate() {
        let covered = results
            .iter()
            .filter(|r| r.summary[j].q025 <= true_value && true_value <= r.summary[j].q975)
            .count();
        let mean_of_means =
            results.iter().map(|r| r.summary[j].mean).sum::<f64>() / results.len() as f64;
        let mean_sd = results.iter().map(|r| r.summary[j].sd).sum::<f64>() / results.len() as f64;
        println!("param {j}: covered {covered}/20, mean of posterior means {mean_of_means:.3}, mean sd {mean_sd:.3}");
        assert!(covered >= 15, "parameter {j}: covered {covered}/20");
        // the average posterior mean is near the truth (sd of the average ≈ mean_sd / √20)
        assert!((mean_of_means - true_value).abs() < 4.0 * mean_sd / 20f64.sqrt() + 0.02);
    }
    for r in &results {
        assert!(
            r.acceptance_rate > 0.05 && r.acceptance_rate < 0.7,
            "{}",
            r.acceptance_rate
        );
    }
}

#[test]
fn pmmh_observer_and_determinism() {
    let truth = LinearGaussian::ar1(TRUTH[0], TRUTH[1], 0.5).unwrap();
    let (_, y) = truth.simulate(50, 1);
    let obs = Observations::new(&y);
    // 17 000 particles: above FILTER_PAR_MIN, so the inner filter runs in parallel
    let mut cfg = PmmhConfig::new(17_000, 25, vec![0.05, 0.08]);
    cfg.adapt_start = 10;
    cfg.seed = 3;
    let pmmh = Pmmh::new(cfg).unwrap();
    let mut seen = 0;
    let mut obs_fn = |s: &gb_smc::estimation::PmmhState| {
        seen += 1;
        assert_eq!(s.iter, seen);
    };
    let pool = |n| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
    };
    let a = pool(1).install(|| {
        pmmh.run_with(&Ar1Params, &obs, &[0.5, 1.5], &Silent, &mut obs_fn)
            .unwrap()
    });
    assert_eq!(seen, 25);
    let b = pool(2).install(|| pmmh.run(&Ar1Params, &obs, &[0.5, 1.5], &Silent).unwrap());
    assert_eq!(a, b);
    // invalid starts are errors
    assert!(pmmh.run(&Ar1Params, &obs, &[1.5, 1.0], &Silent).is_err());
    assert!(pmmh.run(&Ar1Params, &obs, &[0.5], &Silent).is_err());
}

fn kalman_mle(y: &[f64]) -> ([f64; 2], f64) {
    let mut best = ([0.0, 0.0], f64::NEG_INFINITY);
    for i in 0..=100 {
        let phi = 0.5 + 0.0049 * i as f64;
        for j in 0..=100 {
            let s = 0.5 + 0.01 * j as f64;
            let m = LinearGaussian::ar1(phi, s, 0.5).unwrap();
            let ll = KalmanFilter::new(&m).filter(y).unwrap().log_likelihood;
            if ll > best.1 {
                best = ([phi, s], ll);
            }
        }
    }
    best
}

#[test]
fn if2_finds_the_kalman_mle() {
    let truth = LinearGaussian::ar1(TRUTH[0], TRUTH[1], 0.5).unwrap();
    let (_, y) = truth.simulate(300, 77);
    let (mle, ll_max) = kalman_mle(&y);
    let mut cfg = If2Config::new(1000, 40, vec![0.02, 0.02]);
    cfg.seed = 5;
    let if2 = If2::new(cfg.clone()).unwrap();
    let mut iters = 0;
    let res = if2
        .run_with(
            &Ar1Params,
            &Observations::new(&y),
            &[0.5, 1.5],
            &Silent,
            |_: &gb_smc::estimation::If2State| iters += 1,
        )
        .unwrap();
    let m = LinearGaussian::ar1(res.theta[0], res.theta[1], 0.5).unwrap();
    let ll = KalmanFilter::new(&m).filter(&y).unwrap().log_likelihood;
    println!(
        "IF2 {:?} vs MLE {:?}; loglik {ll:.3} vs {ll_max:.3}",
        res.theta, mle
    );
    assert_eq!(iters, 40);
    assert!((res.theta[0] - mle[0]).abs() < 0.05);
    assert!((res.theta[1] - mle[1]).abs() < 0.1);
    assert!(ll > ll_max - 1.5);
    // deterministic regardless of the thread count
    let pool = |n| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
    };
    let obs = Observations::new(&y[..60]);
    let mut short = cfg;
    short.n_iter = 3;
    short.n_particles = 5000; // above PAR_MIN: the parallel path runs
    let if2 = If2::new(short).unwrap();
    let a = pool(1).install(|| if2.run(&Ar1Params, &obs, &[0.5, 1.5], &Silent).unwrap());
    let b = pool(2).install(|| if2.run(&Ar1Params, &obs, &[0.5, 1.5], &Silent).unwrap());
    assert_eq!(a, b);
}

/// The particle number rule and the adaptive burn-in: from 50 particles on
/// T = 300 (sd of `log p̂` well above 1.2) the chain chooses more particles
/// after iteration 100, the standard deviation measured at the chosen `N`
/// is near the target (0.6–2.0; it is an estimate from 10 runs), and the
/// proposal and `N` stay frozen after iteration 300. A tuning with
/// `max_particles = 50` keeps 50.
#[test]
fn pmmh_chooses_the_particle_number_and_freezes_the_proposal() {
    use gb_smc::estimation::ParticleTuning;
    let truth = LinearGaussian::ar1(TRUTH[0], TRUTH[1], 0.5).unwrap();
    let (_, y) = truth.simulate(300, 11);
    let obs = Observations::new(&y);
    let mut cfg = PmmhConfig::new(50, 500, vec![0.05, 0.08]);
    cfg.burn_in = 300;
    cfg.adapt_start = 50;
    cfg.adapt_restart = Some(100);
    cfg.adapt_end = Some(300);
    cfg.target_acceptance = Some(0.2);
    cfg.particle_tuning = Some(ParticleTuning::new(100, 50, 5000));
    cfg.seed = 4;
    let mut frozen: Option<(Vec<f64>, usize)> = None;
    let res = Pmmh::new(cfg.clone())
        .unwrap()
        .run_with(&Ar1Params, &obs, &[0.7, 1.2], &Silent, |s| {
            if s.iter <= 100 {
                assert_eq!(s.n_particles, 50);
            }
            if s.iter == 300 {
                frozen = Some((s.proposal_chol.clone(), s.n_particles));
            } else if let Some((chol, n)) = &frozen {
                assert_eq!((&s.proposal_chol, s.n_particles), (chol, *n));
            }
        })
        .unwrap();
    let c = res.particle_choice.unwrap();
    println!("{c:?}, acceptance {:.2}", res.acceptance_rate);
    assert_eq!(c.before, 50);
    assert!(c.sd_before > 2.0, "{c:?}");
    assert!(
        c.chosen > 100 && c.chosen < 5000 && c.chosen == res.n_particles,
        "{c:?}"
    );
    assert!(c.sd_chosen > 0.6 && c.sd_chosen < 2.0, "{c:?}");
    assert!(frozen.is_some());
    cfg.particle_tuning = Some(ParticleTuning::new(100, 50, 50));
    let res = Pmmh::new(cfg)
        .unwrap()
        .run(&Ar1Params, &obs, &[0.7, 1.2], &Silent)
        .unwrap();
    assert_eq!(res.n_particles, 50);
    // invalid tuning is refused
    let mut bad = PmmhConfig::new(20, 10, vec![0.05, 0.08]);
    bad.particle_tuning = Some(ParticleTuning::new(5, 30, 20));
    assert!(Pmmh::new(bad).is_err());
}
