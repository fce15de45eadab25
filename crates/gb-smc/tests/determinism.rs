//! Bit-identical results for a given seed on 1 and 2 rayon threads.
use gb_smc::{FilterConfig, FilterKind, LinearGaussian, Observations, Resampling};

fn pool(n: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .unwrap()
}

#[test]
fn filter_is_thread_count_invariant() {
    let model = LinearGaussian::ar1(0.9, 1.0, 0.5).unwrap();
    let (_, y) = model.simulate(60, 5);
    let obs = Observations::new(&y);
    for kind in [
        FilterKind::Bootstrap,
        FilterKind::Guided,
        FilterKind::Auxiliary,
    ] {
        for rs in [Resampling::Systematic, Resampling::Multinomial] {
            // above FILTER_PAR_MIN: the steps run on rayon
            let cfg = FilterConfig::new(17_000)
                .kind(kind)
                .resampling(rs)
                .seed(9)
                .store_history(true);
            let pf = cfg.clone().build().unwrap();
            let a = pool(1).install(|| pf.run(&model, &obs).unwrap());
            let b = pool(2).install(|| pf.run(&model, &obs).unwrap());
            let c = cfg
                .parallel(false)
                .build()
                .unwrap()
                .run(&model, &obs)
                .unwrap();
            for o in [&b, &c] {
                assert_eq!(a.log_likelihood.to_bits(), o.log_likelihood.to_bits());
                assert_eq!(a.ess, o.ess);
                let (ha, ho) = (a.history.as_ref().unwrap(), o.history.as_ref().unwrap());
                assert_eq!(ha.states, ho.states);
                assert_eq!(ha.weights, ho.weights);
            }
            // a different seed gives a different estimate
            let d = FilterConfig::new(17_000)
                .kind(kind)
                .resampling(rs)
                .seed(10)
                .build()
                .unwrap()
                .run(&model, &obs)
                .unwrap();
            assert_ne!(a.log_likelihood, d.log_likelihood);
        }
    }
}

#[test]
fn bootstrap_fast_path_is_thread_count_invariant() {
    // The benchmark configuration (bootstrap, systematic resampling at every
    // step, no history): batch moves, resampling inside the chunk tasks, on
    // rayon (N ≥ FILTER_PAR_MIN) or serially (N = 10 000, the benchmark size,
    // runs its steps on the calling thread; `parallel(false)` is compared too).
    // Also N not a multiple of the chunk size, and adaptive resampling.
    let model = LinearGaussian::ar1(0.9, 1.0, 0.5).unwrap();
    let (_, y) = model.simulate(60, 11);
    let obs = Observations::new(&y);
    const { assert!(16_500 >= gb_smc::rng::FILTER_PAR_MIN) };
    for (n, tau) in [
        (20_000usize, 1.0),
        (17_001, 1.0),
        (16_500, 0.5),
        (10_000, 1.0),
    ] {
        let cfg = FilterConfig::new(n)
            .resampling(Resampling::Systematic)
            .ess_threshold(tau)
            .seed(3);
        let pf = cfg.clone().build().unwrap();
        let a = pool(1).install(|| pf.run(&model, &obs).unwrap());
        let b = pool(2).install(|| pf.run(&model, &obs).unwrap());
        let c = pool(3).install(|| pf.run(&model, &obs).unwrap());
        let d = cfg
            .clone()
            .parallel(false)
            .build()
            .unwrap()
            .run(&model, &obs)
            .unwrap();
        for o in [&b, &c, &d] {
            assert_eq!(a.log_likelihood.to_bits(), o.log_likelihood.to_bits());
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(
                bits(&a.log_likelihood_increments),
                bits(&o.log_likelihood_increments)
            );
            assert_eq!(bits(&a.ess), bits(&o.ess));
        }
        // and the estimate is sensible (T = 60: within a few nats of the exact value)
        let exact = gb_smc::KalmanFilter::new(&model)
            .filter(&y)
            .unwrap()
            .log_likelihood;
        assert!(
            (a.log_likelihood - exact).abs() < 2.0,
            "{} vs {exact}",
            a.log_likelihood
        );
        let e = cfg.seed(4).build().unwrap().run(&model, &obs).unwrap();
        assert_ne!(a.log_likelihood, e.log_likelihood);
    }
}

#[test]
fn large_n_parallel_passes_are_thread_count_invariant() {
    // N above PAR_MIN_LIGHT: normalisation and resampling also run in parallel.
    let model = LinearGaussian::ar1(0.9, 1.0, 0.5).unwrap();
    let (_, y) = model.simulate(12, 6);
    let obs = Observations::new(&y);
    let pf = FilterConfig::new(70_000)
        .ess_threshold(1.0)
        .seed(2)
        .build()
        .unwrap();
    let a = pool(1).install(|| pf.run(&model, &obs).unwrap());
    let b = pool(2).install(|| pf.run(&model, &obs).unwrap());
    assert_eq!(a.log_likelihood.to_bits(), b.log_likelihood.to_bits());
    assert_eq!(a.ess, b.ess);
}

#[test]
fn reused_workspace_gives_identical_results() {
    use gb_smc::FilterWorkspace;
    let model = LinearGaussian::ar1(0.9, 1.0, 0.5).unwrap();
    let (_, y) = model.simulate(30, 8);
    let obs = Observations::new(&y);
    let mut ws = FilterWorkspace::new();
    for kind in [FilterKind::Bootstrap, FilterKind::Auxiliary] {
        for seed in [1u64, 2] {
            let pf = FilterConfig::new(700)
                .kind(kind)
                .seed(seed)
                .build()
                .unwrap();
            let fresh = pf.run(&model, &obs).unwrap();
            let reused = pf.run_with(&model, &obs, &mut ws, |_| {}).unwrap();
            assert_eq!(
                fresh.log_likelihood.to_bits(),
                reused.log_likelihood.to_bits()
            );
            assert_eq!(fresh.ess, reused.ess);
        }
    }
}

#[test]
fn default_proposal_reduces_guided_and_auxiliary_to_bootstrap() {
    use gb_smc::models::NonlinearGrowth;
    let model = NonlinearGrowth::classic();
    let (_, y) = model.simulate(40, 4);
    let obs = Observations::new(&y);
    let run = |kind| {
        FilterConfig::new(600)
            .kind(kind)
            .ess_threshold(1.0)
            .seed(12)
            .build()
            .unwrap()
            .run(&model, &obs)
            .unwrap()
    };
    let b = run(FilterKind::Bootstrap);
    let g = run(FilterKind::Guided);
    let a = run(FilterKind::Auxiliary);
    assert_eq!(b.log_likelihood.to_bits(), g.log_likelihood.to_bits());
    assert_eq!(b.ess, g.ess);
    // η ≡ 1: the APF equals the bootstrap filter up to rounding of Σ W_i = 1
    assert!((a.log_likelihood - b.log_likelihood).abs() < 1e-9);
}

/// Pushing the observations one at a time (`ParticleFilter::online`) gives
/// the batch filter's log-likelihood, increments, ESS and final particles,
/// bit for bit, for every filter kind and resampling scheme, serial and
/// parallel (17 000 particles), and for a model whose transition depends on
/// the time index.
#[test]
fn online_push_equals_the_batch_filter() {
    let model = LinearGaussian::ar1(0.9, 1.0, 0.5).unwrap();
    let (_, y) = model.simulate(80, 6);
    let obs = Observations::new(&y);
    for n in [1_000, 17_000] {
        for kind in [
            FilterKind::Bootstrap,
            FilterKind::Guided,
            FilterKind::Auxiliary,
        ] {
            for rs in [Resampling::Systematic, Resampling::Multinomial] {
                let pf = FilterConfig::new(n)
                    .kind(kind)
                    .resampling(rs)
                    .seed(4)
                    .build()
                    .unwrap();
                let mut steps = Vec::new();
                let batch = pf
                    .run_with(&model, &obs, &mut gb_smc::FilterWorkspace::new(), |s| {
                        if s.t + 1 == y.len() {
                            steps.extend_from_slice(s.particles);
                        }
                    })
                    .unwrap();
                let mut online = pf.online(&model);
                assert!(online.is_empty() && online.particles().is_empty());
                for (t, yt) in y.iter().enumerate() {
                    let inc = online.push(yt, &[]).unwrap();
                    assert_eq!(
                        inc.to_bits(),
                        batch.log_likelihood_increments[t].to_bits(),
                        "{kind:?} {rs:?} N {n} t {t}"
                    );
                    assert_eq!(online.ess().to_bits(), batch.ess[t].to_bits());
                }
                assert_eq!(online.len(), y.len());
                assert_eq!(
                    online.log_likelihood().to_bits(),
                    batch.log_likelihood.to_bits(),
                    "{kind:?} {rs:?} N {n}"
                );
                assert_eq!(online.particles(), &steps[..]);
            }
        }
    }
    // a model whose transition depends on the time index
    let growth = gb_smc::models::NonlinearGrowth::classic();
    let (_, y) = growth.simulate(60, 3);
    let pf = FilterConfig::new(2_000).seed(7).build().unwrap();
    let batch = pf.run(&growth, &Observations::new(&y)).unwrap();
    let mut online = pf.online(&growth);
    for yt in &y {
        online.push(yt, &[]).unwrap();
    }
    assert_eq!(
        online.log_likelihood().to_bits(),
        batch.log_likelihood.to_bits()
    );
}

/// Several PMMH chains give the same pooled draws on 1 and 2 threads, each
/// chain equals the same configuration run alone, and the pool holds each
/// chain's draws after its burn-in in order.
#[test]
fn parallel_chains_are_thread_count_invariant_and_pool_after_burn_in() {
    use gb_smc::estimation::{run_chains, ParametricModel, Pmmh, PmmhConfig, Silent};
    struct Phi;
    impl ParametricModel for Phi {
        type Model = LinearGaussian;
        fn dim(&self) -> usize {
            1
        }
        fn build(&self, th: &[f64]) -> Option<LinearGaussian> {
            LinearGaussian::ar1(th[0], 1.0, 0.5).ok()
        }
        fn log_prior(&self, th: &[f64]) -> f64 {
            if th[0].abs() < 1.0 {
                0.0
            } else {
                f64::NEG_INFINITY
            }
        }
    }
    let (_, y) = LinearGaussian::ar1(0.7, 1.0, 0.5).unwrap().simulate(80, 3);
    let obs = Observations::new(&y);
    let cfgs: Vec<PmmhConfig> = (0..3)
        .map(|c| {
            let mut cfg = PmmhConfig::new(64, 60 + 10 * c, vec![0.1]);
            cfg.burn_in = 20;
            cfg.seed = 11 + c as u64;
            cfg
        })
        .collect();
    let a = pool(1).install(|| run_chains(&cfgs, &Phi, &obs, &[0.3], &Silent).unwrap());
    let b = pool(2).install(|| run_chains(&cfgs, &Phi, &obs, &[0.3], &Silent).unwrap());
    assert_eq!(a, b);
    let mut expected = vec![];
    for cfg in &cfgs {
        let one = Pmmh::new(cfg.clone())
            .unwrap()
            .run(&Phi, &obs, &[0.3], &Silent)
            .unwrap();
        expected.extend_from_slice(&one.chain[cfg.burn_in..]);
    }
    assert_eq!(a.chain.len(), 40 + 50 + 60);
    assert_eq!(a.chain, expected);
}
