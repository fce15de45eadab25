//! The sensitivities measured against finite differences of the whole
//! simulation.
use super::fit::{coordinates, lanes_of};
use super::simulate::{simulate, simulate_dual};
use super::spec::{Parameter, PhysicsSpec, State};

/// A Bouc–Wen oscillator: `abs` in the law, free initial states.
fn bouc_wen() -> PhysicsSpec {
    PhysicsSpec::new("bw")
        .input("u")
        .parameter(Parameter::new("m", 2.0))
        .parameter(Parameter::new("c", 10.0))
        .parameter(Parameter::new("k", 5e4))
        .parameter(Parameter::new("alpha", 5e4))
        .parameter(Parameter::new("beta", 1e3).fixed())
        .parameter(Parameter::new("gamma", 0.8))
        .parameter(Parameter::new("delta", -1.1))
        .state(State::new("q", 1e-4).free(), "v")
        .state(State::new("v", 0.0).free(), "u/m - k/m*q - c/m*v - z/m")
        .state(
            State::new("z", 0.0),
            "alpha*v - beta*(gamma*abs(v)*z + delta*v*abs(z))",
        )
        .output("y", "q + 0.001*tanh(v)")
        .sample_time(1.0 / 750.0)
        .substeps(4)
}

fn input(n: usize) -> Vec<f64> {
    (0..n)
        .map(|k| {
            let t = k as f64 / 750.0;
            40.0 * (2.0 * std::f64::consts::PI * 31.0 * t).sin()
                + 25.0 * (2.0 * std::f64::consts::PI * 7.3 * t + 1.0).sin()
        })
        .collect()
}

#[test]
fn sensitivities_match_finite_differences_of_the_simulation() {
    let spec = bouc_wen();
    let c = spec.compile().unwrap();
    let (theta, x0) = (spec.theta0(), spec.x0());
    let coords = coordinates(&spec, &theta, &x0, false);
    let lanes = lanes_of(&coords, c.np, c.n);
    assert_eq!(lanes.n, 8); // 6 free parameters, 2 free initial states
    let n = 400;
    let u = input(n);
    let us: Vec<&[f64]> = vec![&u];
    let ts = 1.0 / 750.0;
    let mut dy = vec![0.0; n * lanes.n];
    simulate_dual(&c, &theta, &x0, &us, ts, 4, n, &lanes, |t, _, d| {
        dy[t * lanes.n..(t + 1) * lanes.n].copy_from_slice(d);
    })
    .unwrap();
    let sim = |th: &[f64], x: &[f64]| {
        let mut y = vec![0.0; n];
        simulate(&c, th, x, &us, ts, 4, &mut y).unwrap();
        y
    };
    let mut worst: f64 = 0.0;
    for (l, co) in coords.iter().enumerate() {
        let h = 1e-6 * co.scale.max(1e-4);
        let (mut tp, mut tm, mut xp, mut xm) =
            (theta.clone(), theta.clone(), x0.clone(), x0.clone());
        match co.what {
            super::fit::Coordinate::Parameter(i) => {
                tp[i] += h;
                tm[i] -= h;
            }
            super::fit::Coordinate::InitialState(i) => {
                xp[i] += h;
                xm[i] -= h;
            }
        }
        let (yp, ym) = (sim(&tp, &xp), sim(&tm, &xm));
        let fd: Vec<f64> = yp
            .iter()
            .zip(&ym)
            .map(|(a, b)| (a - b) / (2.0 * h))
            .collect();
        let norm = fd.iter().map(|v| v * v).sum::<f64>().sqrt();
        let err = (0..n)
            .map(|t| (dy[t * lanes.n + l] - fd[t]).powi(2))
            .sum::<f64>()
            .sqrt();
        let rel = err / norm;
        worst = worst.max(rel);
        assert!(rel < 1e-5, "{:?}: relative error {rel:e}", co.what);
    }
    eprintln!("sensitivities vs central differences: worst relative error {worst:.2e}");
}

/// The value-only RK4 (stage points written straight into the tape's
/// state slots) gives the same bits as the dual RK4 without lanes (stage
/// points in their own buffer, copied in).
#[test]
fn value_simulation_is_bit_identical_to_the_dual_one() {
    let spec = bouc_wen();
    let c = spec.compile().unwrap();
    let (theta, x0) = (spec.theta0(), spec.x0());
    let n = 2000;
    let u = input(n);
    let us: Vec<&[f64]> = vec![&u];
    let ts = 1.0 / 750.0;
    let mut y = vec![0.0; n];
    simulate(&c, &theta, &x0, &us, ts, 4, &mut y).unwrap();
    let mut y_dual = vec![0.0; n];
    let lanes = super::simulate::Lanes::default();
    simulate_dual(&c, &theta, &x0, &us, ts, 4, n, &lanes, |t, yk, _| {
        y_dual[t] = yk[0];
    })
    .unwrap();
    for (t, (a, b)) in y.iter().zip(&y_dual).enumerate() {
        assert_eq!(a.to_bits(), b.to_bits(), "sample {t}: {a:e} vs {b:e}");
    }
}

/// The state noise survives the model file; a version-1 body (before the
/// state noise) still loads, without noise.
#[test]
fn state_noise_round_trips_and_version_1_files_load() {
    use super::{PhysicsModel, StateNoise};
    use gb_core::DynamicModel;
    let m = PhysicsModel::new(bouc_wen())
        .unwrap()
        .with_state_noise(StateNoise {
            process_sd: vec![None, Some(0.5), Some(2.0)],
            measurement_sd: 1e-5,
        })
        .unwrap();
    let back = PhysicsModel::decode(&m.encode().unwrap(), m.class_version()).unwrap();
    assert_eq!(back.state_noise(), m.state_noise());
    let v1 = postcard::to_allocvec(&(
        m.spec(),
        m.parameters(),
        m.initial_state(),
        None::<super::FitReport>,
        None::<String>,
    ))
    .unwrap();
    let old = PhysicsModel::decode(&v1, 1).unwrap();
    assert!(old.state_noise().is_none());
    assert_eq!(old.parameters(), m.parameters());
    // malformed levels are refused
    for bad in [vec![None, None, None], vec![Some(-1.0), None, None]] {
        let r = PhysicsModel::new(bouc_wen())
            .unwrap()
            .with_state_noise(StateNoise {
                process_sd: bad,
                measurement_sd: 1.0,
            });
        assert!(r.is_err());
    }
}
