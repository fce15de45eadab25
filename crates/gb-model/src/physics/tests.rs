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
    check_sensitivities(&bouc_wen(), 8);
}

/// With a free input delay `d` the delay's lane is the derivative of the
/// discrete map too: a negative delay (output sampled after the held
/// input acted), a fraction of a sample, and a shift of two samples plus
/// a fraction.
#[test]
fn sensitivities_match_finite_differences_under_an_input_delay() {
    let ts = 1.0 / 750.0;
    for d in [-0.5 * ts, 0.3 * ts, 2.4 * ts] {
        let spec = bouc_wen()
            .parameter(Parameter::new("td", d))
            .with_input_delay("td");
        check_sensitivities(&spec, 9);
    }
}

fn check_sensitivities(spec: &PhysicsSpec, lanes_expected: usize) {
    let c = spec.compile().unwrap();
    let (theta, x0) = (spec.theta0(), spec.x0());
    let coords = coordinates(spec, &theta, &x0, false);
    let lanes = lanes_of(&coords, c.np, c.n);
    // 6 free parameters (+ the delay), 2 free initial states
    assert_eq!(lanes.n, lanes_expected);
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

/// A chain of `n` states driven by `u` (a tank cascade when `bounded`:
/// each level clamped to `[0, 2]`), with products inside sums.
fn chain(n: usize, bounded: bool) -> PhysicsSpec {
    let mut spec = PhysicsSpec::new("chain")
        .input("u")
        .parameter(Parameter::new("a", 3.0))
        .parameter(Parameter::new("b", 0.7));
    for i in 0..n {
        let name = format!("x{i}");
        let from = if i == 0 {
            "u".to_string()
        } else {
            format!("x{}", i - 1)
        };
        let law = format!("a*{from} - b*{name}*abs({name}) - a*{name} + 0.1*u*{name}");
        let state = State::new(&name, 0.1 * i as f64);
        let state = if bounded {
            state.bounded(0.0, 2.0)
        } else {
            state
        };
        spec = spec.state(state, &law);
    }
    spec.output("y", &format!("x{} + 0.5*x0", n - 1))
        .sample_time(1.0 / 750.0)
        .substeps(4)
}

/// The value-only RK4 (stage points written straight into the tape's
/// state slots, products fused into their sums, up to 4 states in
/// arrays) gives the same bits as the dual RK4 without lanes (the plain
/// nodes, stage points in their own buffer, copied in): 1 to 6 states,
/// with and without state bounds, and the Bouc–Wen oscillator.
#[test]
fn value_simulation_is_bit_identical_to_the_dual_one() {
    let mut specs = vec![bouc_wen()];
    for n in 1..=6 {
        specs.push(chain(n, false));
        specs.push(chain(n, true));
    }
    for spec in specs {
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
        let name = format!("{} states, bounded {}", c.n, c.range[0].1.is_finite());
        for (t, (a, b)) in y.iter().zip(&y_dual).enumerate() {
            assert_eq!(
                a.to_bits(),
                b.to_bits(),
                "{name}, sample {t}: {a:e} vs {b:e}"
            );
        }
        // not a resting run (and the bounded chain's levels, driven by an
        // input of amplitude 65, run into their bounds)
        assert!(y.iter().any(|v| *v != y[0]), "{name}: constant output");
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
    // version 2: the state noise after the base
    let v2 = postcard::to_allocvec(&(
        m.spec(),
        m.parameters(),
        m.initial_state(),
        None::<super::FitReport>,
        None::<String>,
        m.state_noise(),
    ))
    .unwrap();
    let old = PhysicsModel::decode(&v2, 2).unwrap();
    assert_eq!(old.state_noise(), m.state_noise());
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

/// An input delay of exactly two samples is the undelayed simulation
/// shifted by two samples (the first outputs held at the first one).
#[test]
fn a_delay_of_whole_samples_shifts_the_output() {
    let ts = 1.0 / 750.0;
    let n = 600;
    let u = input(n);
    let us: Vec<&[f64]> = vec![&u];
    let plain = bouc_wen();
    let c = plain.compile().unwrap();
    let mut y0 = vec![0.0; n];
    simulate(&c, &plain.theta0(), &plain.x0(), &us, ts, 4, &mut y0).unwrap();
    let delayed = bouc_wen()
        .parameter(Parameter::new("td", 2.0 * ts).fixed())
        .with_input_delay("td");
    let cd = delayed.compile().unwrap();
    let mut y2 = vec![0.0; n];
    simulate(&cd, &delayed.theta0(), &delayed.x0(), &us, ts, 4, &mut y2).unwrap();
    assert_eq!(y2[0], y0[0]);
    assert_eq!(y2[1], y0[0]);
    for k in 2..n {
        assert!(
            (y2[k] - y0[k - 2]).abs() <= 1e-12 * y0[k - 2].abs().max(1e-9),
            "{k}"
        );
    }
}

/// A delay of −Ts/2 samples the output half a sample after the held
/// input started: the same model at half the sample time, each input held
/// for two half samples, gives it at its odd samples (both integrated
/// finely enough that RK4's error is below the tolerance).
#[test]
fn a_negative_half_sample_delay_samples_the_output_mid_interval() {
    let ts = 1.0 / 750.0;
    let n = 800;
    let u = input(n);
    let spec = bouc_wen()
        .parameter(Parameter::new("td", -0.5 * ts).fixed())
        .with_input_delay("td");
    let c = spec.compile().unwrap();
    let mut y = vec![0.0; n];
    simulate(&c, &spec.theta0(), &spec.x0(), &[&u], ts, 16, &mut y).unwrap();
    let plain = bouc_wen();
    let cp = plain.compile().unwrap();
    let u2: Vec<f64> = u.iter().flat_map(|&v| [v, v]).collect();
    let mut y2 = vec![0.0; 2 * n];
    simulate(
        &cp,
        &plain.theta0(),
        &plain.x0(),
        &[&u2],
        ts / 2.0,
        8,
        &mut y2,
    )
    .unwrap();
    let scale = y2.iter().map(|v| v.abs()).fold(0.0, f64::max);
    for k in 0..n - 1 {
        assert!(
            (y[k] - y2[2 * k + 1]).abs() < 1e-6 * scale,
            "sample {k}: {:e} vs {:e}",
            y[k],
            y2[2 * k + 1]
        );
    }
    // and it is not the undelayed output
    let mut y0 = vec![0.0; n];
    simulate(&cp, &plain.theta0(), &plain.x0(), &[&u], ts, 16, &mut y0).unwrap();
    let diff = y
        .iter()
        .zip(&y0)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(diff > 1e-3 * scale, "{diff:e}");
}

/// The stepper (one sample at a time) gives the batch simulation under a
/// delay of several samples; the delay survives a model file, and a
/// version-2 body (before the delay) still loads.
#[test]
fn a_delayed_model_steps_like_it_simulates_and_keeps_its_delay_in_files() {
    use super::PhysicsModel;
    use gb_core::{DynamicModel, Init};
    let ts = 1.0 / 750.0;
    let spec = bouc_wen()
        .parameter(Parameter::new("td", 2.3 * ts))
        .with_input_delay("td");
    let m = PhysicsModel::new(spec).unwrap();
    let n = 300;
    let u = vec![input(n)];
    let batch = m.simulate(&u, Init::Stored).unwrap();
    let mut st = m.stepper(Init::Stored).unwrap();
    let mut y = [0.0];
    for k in 0..n {
        st.step(&[u[0][k]], &mut y).unwrap();
        assert_eq!(y[0].to_bits(), batch[k].to_bits(), "sample {k}");
    }
    let back = PhysicsModel::decode(&m.encode().unwrap(), m.class_version()).unwrap();
    assert_eq!(back.spec().input_delay.as_deref(), Some("td"));
    assert_eq!(back.simulate(&u, Init::Stored).unwrap(), batch);
    let v2 = postcard::to_allocvec(&(
        m.spec(),
        m.parameters(),
        m.initial_state(),
        None::<super::FitReport>,
        None::<String>,
        None::<super::StateNoise>,
    ))
    .unwrap();
    let old = PhysicsModel::decode(&v2, 2).unwrap();
    assert!(old.spec().input_delay.is_none());
    assert_ne!(old.simulate(&u, Init::Stored).unwrap(), batch);
}

/// The delay's lane on a rigid body with a smooth Coulomb law (`tanh`) and
/// one RK4 step per sample, on both sides of a whole sample. (At `d = 0`
/// exactly the discrete map has a kink of the order of RK4's error: the
/// offset step from the sample before and the sample's own step differ.)
#[test]
fn sensitivities_under_an_input_delay_with_a_smooth_coulomb_law() {
    let ts = 1e-3;
    for d in [-0.3e-3, 0.4e-3, 2.5e-3] {
        let spec = PhysicsSpec::new("emps")
            .input("u")
            .parameter(Parameter::new("M", 100.0))
            .parameter(Parameter::new("Fv", 200.0))
            .parameter(Parameter::new("Fc", 20.0))
            .parameter(Parameter::new("offset", 0.5))
            .parameter(Parameter::new("td", d))
            .with_input_delay("td")
            .state(State::new("q", 0.0).free(), "v")
            .state(
                State::new("v", 0.01).free(),
                "35.15*u/M - Fv/M*v - Fc/M*tanh(v/0.001) - offset/M",
            )
            .output("y", "q")
            .sample_time(ts)
            .substeps(1);
        check_sensitivities(&spec, 7);
    }
}

/// A mass–spring–damper with a Preisach spring `Σⱼ wⱼ·Pⱼ(q)` on the
/// position: hard relays (`sub = 1`), one per cell.
fn preisach_spring(levels: usize) -> PhysicsSpec {
    use super::spec::StateHysteresis;
    let op = StateHysteresis {
        driver: "q".into(),
        prefix: "P".into(),
        levels,
        sub: 1,
        center: 0.001,
        half_range: 0.02,
    };
    let mut spec = PhysicsSpec::new("preisach spring")
        .input("u")
        .parameter(Parameter::new("k", 3948.0))
        .parameter(Parameter::new("c", 20.0))
        .state(State::new("q", 0.0).free(), "v")
        .state(State::new("v", 0.0), "u - k*q - c*v")
        .output("y", "q")
        .sample_time(1.0 / 750.0)
        .substeps(4);
    for j in 0..op.n_cells() {
        let w = format!("w{j}");
        spec = spec.parameter(Parameter::new(&w, 4.0 + 0.5 * j as f64));
        spec.add_term(super::spec::TermTarget::State(1), &format!("-{w}*P{j}"))
            .unwrap();
    }
    spec.with_hysteresis(op)
}

/// The Preisach spring simulated by hand: relays at the cell centres of
/// the grid, started demagnetised (+1 below α + β = 2q₀), switched with
/// the position before every RK4 sub-step and held within it.
#[test]
fn a_preisach_spring_simulates_like_a_hand_written_relay_loop() {
    let levels = 4;
    let spec = preisach_spring(levels);
    let c = spec.compile().unwrap();
    let (theta, x0) = (spec.theta0(), vec![0.004, 0.0]);
    let n = 600;
    let u = input(n);
    let mut y = vec![0.0; n];
    simulate(&c, &theta, &x0, &[&u], 1.0 / 750.0, 4, &mut y).unwrap();
    // the reference
    let (k, cd, w) = (theta[0], theta[1], &theta[2..]);
    let at = |i: usize| 0.001 + 0.02 * (-1.0 + 2.0 * (i as f64 + 0.5) / levels as f64);
    let mut relays = vec![];
    for i in 0..levels {
        for j in 0..=i {
            relays.push((at(i), at(j)));
        }
    }
    let mut s: Vec<f64> = relays
        .iter()
        .map(|&(a, b)| {
            if x0[0] >= a || (x0[0] > b && a + b < 2.0 * x0[0]) {
                1.0
            } else {
                -1.0
            }
        })
        .collect();
    let h = 1.0 / 750.0 / 4.0;
    let (mut q, mut v) = (x0[0], x0[1]);
    let mut moved = 0;
    for (t, &ut) in u.iter().enumerate() {
        assert!((y[t] - q).abs() <= 1e-12 * q.abs().max(1e-3), "sample {t}");
        for _ in 0..4 {
            for (si, &(a, b)) in s.iter_mut().zip(&relays) {
                let before = *si;
                if q >= a {
                    *si = 1.0;
                } else if q <= b {
                    *si = -1.0;
                }
                moved += usize::from(*si != before);
            }
            let force: f64 = w.iter().zip(&s).map(|(wj, sj)| wj * sj).sum();
            let f = |q: f64, v: f64| (v, ut - k * q - cd * v - force);
            let (a1, b1) = f(q, v);
            let (a2, b2) = f(q + 0.5 * h * a1, v + 0.5 * h * b1);
            let (a3, b3) = f(q + 0.5 * h * a2, v + 0.5 * h * b2);
            let (a4, b4) = f(q + h * a3, v + h * b3);
            q += h / 6.0 * (a1 + 2.0 * (a2 + a3) + a4);
            v += h / 6.0 * (b1 + 2.0 * (b2 + b3) + b4);
        }
    }
    // the position sweeps the grid: relays switch many times
    assert!(moved > 20, "only {moved} switches");
}

/// The cells are piecewise constant in the state, so the sensitivities of
/// the weights, the spring, the damper and the initial position are the
/// derivatives of the simulation (perturbations too small to switch a
/// relay).
#[test]
fn sensitivities_with_a_preisach_spring_match_finite_differences() {
    // 2 + 10 weights, 1 free initial state
    check_sensitivities(&preisach_spring(4), 13);
}

/// A Preisach operator survives the model file; version-3 files (no
/// operators) still load; a driver that is not a state and a cell symbol
/// that is also a parameter are refused.
#[test]
fn preisach_operators_round_trip_and_are_checked() {
    use super::PhysicsModel;
    use gb_core::DynamicModel;
    let m = PhysicsModel::new(preisach_spring(3)).unwrap();
    let back = PhysicsModel::decode(&m.encode().unwrap(), m.class_version()).unwrap();
    assert_eq!(back.spec().hysteresis, m.spec().hysteresis);
    let u = input(300);
    assert_eq!(
        back.simulate(std::slice::from_ref(&u), gb_core::Init::Stored)
            .unwrap(),
        m.simulate(&[u], gb_core::Init::Stored).unwrap()
    );
    let plain = PhysicsModel::new(bouc_wen()).unwrap();
    let v3 = postcard::to_allocvec(&(
        plain.spec(),
        plain.parameters(),
        plain.initial_state(),
        None::<super::FitReport>,
        None::<String>,
        None::<super::StateNoise>,
        None::<String>,
    ))
    .unwrap();
    let old = PhysicsModel::decode(&v3, 3).unwrap();
    assert!(old.spec().hysteresis.is_empty());
    let mut bad = preisach_spring(2);
    bad.hysteresis[0].driver = "z".into();
    assert!(bad
        .check()
        .unwrap_err()
        .to_string()
        .contains("'z' is not a state"));
    let clash = preisach_spring(2).parameter(Parameter::new("P1", 0.0));
    assert!(clash
        .check()
        .unwrap_err()
        .to_string()
        .contains("'P1' is used twice"));
}

/// A position that only integrates its velocity (`q̇ = v`, `q` in no other
/// equation: a rigid body with friction) makes the model integrate; a
/// spring on the position (`k·q` in `v̇`), a Preisach operator driven by
/// it, or an output that reads no such state does not.
#[test]
fn a_position_read_by_nothing_but_the_output_integrates() {
    use gb_core::DynamicModel;
    let body = |force: &str, out: &str| {
        PhysicsSpec::new("body")
            .input("u")
            .parameter(Parameter::new("m", 2.0))
            .parameter(Parameter::new("c", 10.0))
            .parameter(Parameter::new("k", 50.0))
            .state(State::new("q", 0.0), "v")
            .state(State::new("v", 0.0), force)
            .output("y", out)
            .sample_time(0.01)
    };
    let integrates = |s: PhysicsSpec| super::PhysicsModel::new(s).unwrap().integrates();
    assert!(integrates(body("u/m - c/m*tanh(v)", "q")));
    assert!(!integrates(body("u/m - c/m*v - k/m*q", "q")));
    assert!(!integrates(body("u/m - c/m*v", "v")));
    assert!(!integrates(bouc_wen()));
    assert!(!integrates(preisach_spring(3)));
}

/// A velocity with viscous and dry friction whose output is the increment
/// of the position over one sample (`Δq ≈ Ts·v`): a model of an
/// integrating system's increments.
fn increments_model(g: f64, c: f64, f: f64) -> PhysicsSpec {
    PhysicsSpec::new("increments")
        .input("u")
        .parameter(Parameter::new("g", g))
        .parameter(Parameter::new("c", c))
        .parameter(Parameter::new("f", f))
        .state(State::new("v", 0.0), "g*u - c*v - f*tanh(v/0.05)")
        .output("dq", "0.01*v")
        .sample_time(0.01)
        .substeps(2)
}

/// A slow random force (first-order filtered noise, fixed seed).
fn slow_force(n: usize, seed: u64) -> Vec<f64> {
    use rand::Rng;
    let mut r = gb_core::rng::seeded(seed);
    let mut f = 0.0;
    (0..n)
        .map(|_| {
            f = 0.97 * f + 0.3 * (r.random::<f64>() - 0.5);
            f
        })
        .collect()
}

/// The integrated criterion's gradient and cost (running sums, means
/// projected out) against central differences of its cost.
#[test]
fn the_integrated_criterion_gradient_matches_finite_differences() {
    use super::fit::{OeProblem, Segment};
    use gb_core::solver::LeastSquaresProblem;
    let spec = increments_model(2.0, 1.5, 0.3);
    let c = spec.compile().unwrap();
    let u = slow_force(600, 3);
    let truth = increments_model(2.4, 1.2, 0.5);
    let ct = truth.compile().unwrap();
    let mut y = vec![0.0; u.len()];
    simulate(&ct, &[2.4, 1.2, 0.5], &[0.0], &[&u], 0.01, 2, &mut y).unwrap();
    let coords = coordinates(&spec, &[2.0, 1.5, 0.3], &[0.0], false);
    let seg = || Segment {
        u: vec![u.as_slice()],
        y: vec![y.as_slice()],
    };
    let mut p = OeProblem::new(
        &c,
        0.01,
        2,
        vec![seg()],
        coords.clone(),
        vec![2.0, 1.5, 0.3],
        vec![0.0],
    );
    p.integrated = true;
    let phi = p.phi();
    let l = phi.len();
    let (mut gram, mut grad) = (vec![0.0; l * l], vec![0.0; l]);
    let sse = p.linearize(&phi, &mut gram, &mut grad).unwrap();
    let cost = p.cost(&phi).unwrap();
    assert!((sse - cost).abs() <= 1e-9 * cost, "{sse} vs {cost}");
    // the cost by hand: the running sum of the errors, centred
    let mut sim = vec![0.0; u.len()];
    simulate(&c, &[2.0, 1.5, 0.3], &[0.0], &[&u], 0.01, 2, &mut sim).unwrap();
    let mut acc = 0.0;
    let run: Vec<f64> = y
        .iter()
        .zip(&sim)
        .map(|(a, b)| {
            acc += a - b;
            acc
        })
        .collect();
    let mean = run.iter().sum::<f64>() / run.len() as f64;
    let by_hand: f64 = run.iter().map(|e| (e - mean) * (e - mean)).sum();
    assert!((cost - by_hand).abs() <= 1e-9 * by_hand);
    for k in 0..l {
        let h = 1e-6 * phi[k].abs().max(1e-3);
        let (mut a, mut b) = (phi.clone(), phi.clone());
        a[k] += h;
        b[k] -= h;
        let fd = (p.cost(&a).unwrap() - p.cost(&b).unwrap()) / (2.0 * h);
        // d cost / dφ = −2 Jᵀe
        assert!(
            (fd + 2.0 * grad[k]).abs() <= 1e-5 * fd.abs().max(1e-9),
            "coordinate {k}: {fd} vs {}",
            -2.0 * grad[k]
        );
    }
    // JᵀJ is symmetric and positive on the diagonal
    for i in 0..l {
        assert!(gram[i * l + i] > 0.0);
        for j in 0..l {
            assert!((gram[i * l + j] - gram[j * l + i]).abs() <= 1e-9 * gram[i * l + i]);
        }
    }
}

/// With white noise on the measured position, the fit of the increments
/// for the error of their running sum places the model closer to the
/// true position over the record than the fit of the increments' error
/// from the same start.
#[test]
fn the_integrated_fit_tracks_the_position_better_than_the_increments_fit() {
    use super::PhysicsFitParams;
    use gb_core::{Record, Records};
    use rand_distr::{Distribution, Normal};
    let (g, c, f) = (2.4, 1.2, 0.5);
    let u = slow_force(4000, 7);
    let ct = increments_model(g, c, f).compile().unwrap();
    let mut dq = vec![0.0; u.len()];
    simulate(&ct, &[g, c, f], &[0.0], &[&u], 0.01, 2, &mut dq).unwrap();
    let q: Vec<f64> = dq
        .iter()
        .scan(0.0, |a, d| {
            *a += d;
            Some(*a)
        })
        .collect();
    let sd = {
        let m = q.iter().sum::<f64>() / q.len() as f64;
        (q.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / q.len() as f64).sqrt()
    };
    let mut r = gb_core::rng::seeded(11);
    let noise = Normal::new(0.0, 0.03 * sd).unwrap();
    let qm: Vec<f64> = q.iter().map(|v| v + noise.sample(&mut r)).collect();
    let dqm: Vec<f64> = std::iter::once(qm[0])
        .chain(qm.windows(2).map(|w| w[1] - w[0]))
        .collect();
    let rec = Record::new(vec!["u".into()], "dq".into(), vec![u.clone()], dqm).unwrap();
    let data = Records::single(rec);
    let fit = |integrated: bool| {
        PhysicsFitParams::new(increments_model(2.0, 1.5, 0.3))
            .integrated(integrated)
            .check()
            .unwrap()
            .identify_outputs(std::slice::from_ref(&data), &gb_core::Silent)
            .unwrap()
    };
    // centred RMS of the simulated position against the true one
    let position_error = |m: &super::PhysicsModel| {
        let mut sim = vec![0.0; u.len()];
        let cm = m.spec().compile().unwrap();
        simulate(&cm, m.parameters(), &[0.0], &[&u], 0.01, 2, &mut sim).unwrap();
        let e: Vec<f64> = sim.iter().zip(&dq).map(|(a, b)| a - b).collect();
        (integrated_cost_of(&e) / e.len() as f64).sqrt() / sd
    };
    let (plain, integrated) = (fit(false), fit(true));
    let (ep, ei) = (position_error(&plain), position_error(&integrated));
    assert!(ei < 0.0015, "integrated fit: position NRMSE {ei}");
    assert!(ei < 0.5 * ep, "integrated {ei} vs increments {ep}");
    // the report stays that of the increments
    let rmse_inc = integrated.fit_report().unwrap().rmse;
    assert!(rmse_inc > 0.0 && rmse_inc < 0.1 * sd);
}

/// `Σ (Eₖ − Ē)²` of the running sums, written out.
fn integrated_cost_of(e: &[f64]) -> f64 {
    let run: Vec<f64> = e
        .iter()
        .scan(0.0, |a, v| {
            *a += v;
            Some(*a)
        })
        .collect();
    let m = run.iter().sum::<f64>() / run.len() as f64;
    run.iter().map(|v| (v - m) * (v - m)).sum()
}
