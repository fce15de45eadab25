//! Property tests of the resampling schemes.
use gb_smc::{resample, rng::stream, Resampling};
use proptest::prelude::*;
use proptest::test_runner::{Config, RngSeed};

const SCHEMES: [Resampling; 4] = [
    Resampling::Multinomial,
    Resampling::Residual,
    Resampling::Stratified,
    Resampling::Systematic,
];

fn weights() -> impl Strategy<Value = Vec<f64>> {
    prop::collection::vec(prop_oneof![3 => 0.0f64..1.0, 1 => Just(0.0)], 1..40)
        .prop_filter("some positive weight", |w| w.iter().any(|&x| x > 1e-3))
}

proptest! {
    #![proptest_config(Config { cases: 48, rng_seed: RngSeed::Fixed(12345), ..Config::default() })]

    #[test]
    fn offspring_counts_are_unbiased(w in weights(), m in 1usize..60) {
        let total: f64 = w.iter().sum();
        let reps = 300;
        for scheme in SCHEMES {
            let mut counts = vec![0.0f64; w.len()];
            let mut anc = vec![0usize; m];
            for r in 0..reps {
                let mut rng = stream(7, 0, r, 0);
                resample(scheme, &w, &mut rng, &mut anc).unwrap();
                let mut c = vec![0usize; w.len()];
                for &a in &anc {
                    prop_assert!(w[a] > 0.0, "{scheme:?} picked a zero-weight particle");
                    c[a] += 1;
                }
                for (i, &ci) in c.iter().enumerate() {
                    let e = m as f64 * w[i] / total;
                    match scheme {
                        Resampling::Systematic => prop_assert!(
                            ci as f64 >= e.floor() - 1e-9 && ci as f64 <= e.ceil() + 1e-9,
                            "systematic count {ci} vs {e}"
                        ),
                        Resampling::Residual => prop_assert!(ci as f64 >= e.floor() - 1e-9),
                        Resampling::Stratified => prop_assert!((ci as f64 - e).abs() < 2.0),
                        _ => {}
                    }
                    counts[i] += ci as f64;
                }
            }
            for (i, &ci) in counts.iter().enumerate() {
                let p = w[i] / total;
                let e = m as f64 * p;
                let sd = (m as f64 * p * (1.0 - p) / reps as f64).sqrt();
                let mean = ci / reps as f64;
                prop_assert!((mean - e).abs() <= 5.5 * sd + 1e-9,
                    "{scheme:?}: mean count {mean} vs {e} (sd {sd})");
            }
        }
    }
}

#[test]
fn invalid_weights_are_rejected() {
    let mut rng = stream(0, 0, 0, 0);
    let mut a = [0usize; 3];
    for w in [vec![], vec![0.0, 0.0], vec![1.0, -1.0], vec![f64::NAN, 1.0]] {
        assert!(resample(Resampling::Systematic, &w, &mut rng, &mut a).is_err());
    }
}

#[test]
fn filter_systematic_offspring_counts_are_floor_or_ceil() {
    // The filter's chunk-parallel systematic resampling (fused with normalisation)
    // must give every particle ⌊N W_i⌋ or ⌈N W_i⌉ children, never a zero-weight one.
    use gb_smc::{FilterConfig, LinearGaussian, Observations};
    let model = LinearGaussian::ar1(0.9, 1.0, 0.5).unwrap();
    let (_, y) = model.simulate(40, 3);
    for n in [7usize, 512, 3000, 4096, 5121] {
        let pf = FilterConfig::new(n)
            .ess_threshold(1.0)
            .store_history(true)
            .build()
            .unwrap();
        let h = pf
            .run(&model, &Observations::new(&y))
            .unwrap()
            .history
            .unwrap();
        for t in 1..y.len() {
            let w = h.weights_at(t - 1);
            let mut c = vec![0usize; n];
            for &a in h.ancestors_at(t) {
                c[a] += 1;
            }
            for (i, &ci) in c.iter().enumerate() {
                let e = n as f64 * w[i];
                assert!(
                    ci as f64 >= e.floor() - 1e-6 && ci as f64 <= e.ceil() + 1e-6,
                    "n = {n}, t = {t}, i = {i}: {ci} children for N W = {e}"
                );
                if w[i] == 0.0 {
                    assert_eq!(ci, 0);
                }
            }
        }
    }
}
