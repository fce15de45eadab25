//! Prandtl–Ishlinskii: the inverse composed with the model is the identity.
#![allow(clippy::needless_range_loop)]
use gb_preisach::{
    Envelope, GeneralizedPlay, HysteresisRegressor, PlayOperatorBank, PrandtlIshlinskii,
    StopOperatorBank,
};
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

fn random_pi(rng: &mut Xoshiro256PlusPlus, n: usize, allow_negative: bool) -> PrandtlIshlinskii {
    let mut r = 0.0;
    let thresholds: Vec<f64> = (0..n)
        .map(|i| {
            if i > 0 || rng.random_bool(0.5) {
                r += rng.random_range(0.01..0.3);
            }
            r
        })
        .collect();
    let a0 = rng.random_range(0.2..1.5);
    let weights: Vec<f64> = (0..n)
        .map(|_| {
            if allow_negative {
                rng.random_range(-0.05..0.5)
            } else {
                rng.random_range(0.0..0.5)
            }
        })
        .collect();
    PrandtlIshlinskii::new(a0, thresholds, weights).unwrap()
}

#[test]
fn pi_inverse_composed_with_pi_is_identity() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(42);
    for trial in 0..50 {
        let pi = random_pi(&mut rng, 1 + trial % 12, trial % 3 == 0);
        let inv = pi.inverse().unwrap();
        // Random start (non-relaxed memory from a random history).
        let mut st = pi.initial_state(0.0);
        for _ in 0..20 {
            pi.step(&mut st, rng.random_range(-2.0..2.0));
        }
        let mut ist = pi.inverse_state(&st).unwrap();
        let mut x: f64 = 0.0;
        for _ in 0..2000 {
            x = (x + rng.random_range(-0.3..0.3)).clamp(-3.0, 3.0);
            let y = pi.step(&mut st, x);
            let xh = inv.step(&mut ist, y);
            assert!((xh - x).abs() < 1e-12, "trial {trial}: {xh} vs {x}");
        }
        // And the other way round: PI ∘ PI⁻¹ = identity on the output side.
        let back = inv.inverse().unwrap();
        for (a, b) in back.weights().iter().zip(pi.weights()) {
            assert!((a - b).abs() < 1e-12);
        }
        for (a, b) in back.thresholds().iter().zip(pi.thresholds()) {
            assert!((a - b).abs() < 1e-12);
        }
        assert!((back.linear_gain() - pi.linear_gain()).abs() < 1e-12);
    }
}

#[test]
fn pi_inverse_breaks_with_wrong_state() {
    // The test above can fail: a mismatched inverse memory gives errors.
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
    let pi = random_pi(&mut rng, 6, false);
    let inv = pi.inverse().unwrap();
    let mut st = pi.initial_state(0.0);
    let mut ist = inv.initial_state(1.0);
    let mut worst: f64 = 0.0;
    for k in 0..100 {
        let x = (k as f64 * 0.1).sin();
        let y = pi.step(&mut st, x);
        worst = worst.max((inv.step(&mut ist, y) - x).abs());
    }
    assert!(worst > 1e-3);
}

#[test]
fn pi_rejects_bad_parameters_and_derivative_is_slope() {
    assert!(PrandtlIshlinskii::new(0.0, vec![0.1], vec![1.0]).is_err());
    assert!(PrandtlIshlinskii::new(1.0, vec![0.2, 0.1], vec![1.0, 1.0]).is_err());
    assert!(PrandtlIshlinskii::new(1.0, vec![0.1, 0.2], vec![-0.6, -0.6]).is_err());
    assert!(PrandtlIshlinskii::new(1.0, vec![0.1], vec![1.0, 2.0]).is_err());
    let ok = PrandtlIshlinskii::new(1.0, vec![0.1], vec![1.0]).unwrap();
    assert!(ok.inverse_state(&[0.0, 1.0]).is_err());
    let pi = PrandtlIshlinskii::new(0.5, vec![0.0, 0.2, 0.4], vec![0.3, 0.2, 0.1]).unwrap();
    let mut st = pi.initial_state(0.0);
    let (_, d) = pi.step_with_derivative(&mut st, 0.3); // plays 0, 0.2 move
    assert!((d - (0.5 + 0.3 + 0.2)).abs() < 1e-15);
}

#[test]
fn stop_bank_is_input_minus_play_and_generalized_play_reduces_to_play() {
    let x: Vec<f64> = (0..300).map(|k| (k as f64 * 0.07).sin() * 1.3).collect();
    let plays = PlayOperatorBank::new(vec![0.1, 0.4]).unwrap();
    let stops = StopOperatorBank::new(vec![0.1, 0.4]).unwrap();
    let p = plays.regressors(&x).unwrap();
    let s = stops.regressors(&x).unwrap();
    for c in 0..2 {
        for t in 0..x.len() {
            assert!((p.columns[c][t] + s.columns[c][t] - x[t]).abs() < 1e-15);
            assert!((p.derivatives[c][t] + s.derivatives[c][t] - 1.0).abs() < 1e-15);
            assert!(s.columns[c][t].abs() <= [0.1, 0.4][c] + 1e-15);
        }
    }
    let g = GeneralizedPlay::new(
        Envelope::Affine {
            slope: 1.0,
            offset: -0.4,
        },
        Envelope::Affine {
            slope: 1.0,
            offset: 0.4,
        },
    )
    .unwrap();
    assert_eq!(g.apply(&x, x[0]), plays.apply(&x)[1]);
    // A tanh generalised play saturates and stays between its envelopes.
    let t = GeneralizedPlay::new(
        Envelope::Tanh {
            amplitude: 1.0,
            gain: 2.0,
            center: 0.3,
            offset: 0.0,
        },
        Envelope::Tanh {
            amplitude: 1.0,
            gain: 2.0,
            center: -0.3,
            offset: 0.0,
        },
    )
    .unwrap();
    let y = t.apply(&x, 0.0);
    for (v, xi) in y.iter().zip(&x) {
        assert!(*v >= (2.0 * (xi - 0.3)).tanh() - 1e-15 && *v <= (2.0 * (xi + 0.3)).tanh() + 1e-15);
    }
    assert!(GeneralizedPlay::new(
        Envelope::Affine {
            slope: -1.0,
            offset: 0.0
        },
        Envelope::Affine {
            slope: 1.0,
            offset: 0.0
        }
    )
    .is_err());
}

#[test]
fn pi_identified_from_noisy_data_and_inverse_compensates() {
    use gb_preisach::{fit_prandtl_ishlinskii, FitOptions};
    use rand_distr::{Distribution, Normal};
    // (r = 0 would be collinear with a₀ x.)
    let thresholds = vec![0.05, 0.1, 0.2, 0.35, 0.5, 0.7];
    let truth = PrandtlIshlinskii::new(
        0.6,
        thresholds.clone(),
        vec![0.3, 0.25, 0.0, 0.2, 0.1, 0.05],
    )
    .unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(8);
    let mut x = vec![0.0];
    for _ in 0..3000 {
        let last: f64 = *x.last().unwrap();
        x.push((last + rng.random_range(-0.15..0.15)).clamp(-1.5, 1.5));
    }
    let noise = Normal::new(0.0, 0.005).unwrap();
    let y: Vec<f64> = truth
        .apply(&x)
        .unwrap()
        .into_iter()
        .map(|v| v + noise.sample(&mut rng))
        .collect();
    let fit = fit_prandtl_ishlinskii(&x, &y, thresholds, &FitOptions::default()).unwrap();
    assert!(
        (fit.model.linear_gain() - 0.6).abs() < 0.03,
        "{}",
        fit.model.linear_gain()
    );
    for (a, b) in fit.model.weights().iter().zip(truth.weights()) {
        assert!(*a >= 0.0 && (a - b).abs() < 0.03, "{a} vs {b}");
    }
    assert!(fit.rmse < 0.006);
    // Compensation: drive the true system with the identified inverse.
    let inv = fit.model.inverse().unwrap();
    let target: Vec<f64> = (0..500).map(|k| (k as f64 * 0.03).sin()).collect();
    let mut ist = inv.initial_state(target[0]);
    let u: Vec<f64> = target.iter().map(|&t| inv.step(&mut ist, t)).collect();
    let out = truth.apply(&u).unwrap();
    let err = out
        .iter()
        .zip(&target)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(err < 0.05, "compensation error {err}");
}
