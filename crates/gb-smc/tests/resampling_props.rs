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
