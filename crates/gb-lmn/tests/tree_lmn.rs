//! Known-answer tests of the issue-3 network (tree/Gaussian weights, oblique
//! splits, pruning, NOE gradients, Duffing).
use gb_core::{Record, Records};
use gb_lmn::{Criterion, Focus, LmnModel, LmnParams, RegressorSpec, SplitKind, WeightKind};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, StandardNormal};

/// A record of input signals u1, u2, … and output y (a struct literal, so
/// that tests can build inconsistent records on purpose).
fn rec(inputs: Vec<Vec<f64>>, output: Vec<f64>) -> Record {
    Record {
        input_names: (1..=inputs.len()).map(|j| format!("u{j}")).collect(),
        output_name: "y".into(),
        inputs,
        output,
        sample_time: None,
    }
}

/// One record as a training set.
fn one(r: &Record) -> Records {
    Records::single(r.clone())
}

fn rng(seed: u64) -> rand::rngs::SmallRng {
    rand::rngs::SmallRng::seed_from_u64(seed)
}

/// Static experiment with two inputs and output f(u1, u2) + noise.
fn static_2d(n: usize, noise: f64, seed: u64, f: impl Fn(f64, f64) -> f64) -> Record {
    let mut r = rng(seed);
    let mut u1 = Vec::with_capacity(n);
    let mut u2 = Vec::with_capacity(n);
    let mut y = Vec::with_capacity(n);
    for i in 0..n {
        // u1 on a grid symmetric about 0 (cell midpoint exactly 0, no sample on it)
        let a = -0.99 + 0.02 * (i % 100) as f64;
        let b: f64 = r.random_range(-1.0..1.0);
        let e: f64 = StandardNormal.sample(&mut r);
        u1.push(a);
        u2.push(b);
        y.push(f(a, b) + noise * e);
    }
    rec(vec![u1, u2], y)
}

#[test]
fn piecewise_affine_function_is_recovered_by_the_right_split() {
    let f = |a: f64, b: f64| {
        if a < 0.0 {
            1.0 + 2.0 * a - b
        } else {
            -1.0 + 0.5 * a + 3.0 * b
        }
    };
    let e = static_2d(2000, 0.01, 1, f);
    let m = LmnParams::new(RegressorSpec::arx(0, &[1, 1], &[0, 0]))
        .smoothness(1e-4)
        .max_leaves(6)
        .lm_iterations(0)
        .fit(&one(&e))
        .unwrap();
    assert_eq!(m.n_leaves(), 2, "{}", m.describe());
    let s = &m.splits()[0];
    assert_eq!(s.axis, Some(0));
    // back to physical units: position in normalised u1
    let pos = m.input_scaling[0].from_norm(s.position * s.direction[0].signum());
    assert!(pos.abs() < 1e-9, "split at {pos}");
    // local models in physical units: y = c + a u1 + b u2
    let ys = m.output_scaling;
    for th in m.local_parameters() {
        let (s1, s2) = (m.input_scaling[0], m.input_scaling[1]);
        let a = th[1] * ys.scale / s1.scale;
        let b = th[2] * ys.scale / s2.scale;
        let c = ys.offset + ys.scale * th[0] - a * s1.offset - b * s2.offset;
        let ok_left = (a - 2.0).abs() < 0.01 && (b + 1.0).abs() < 0.01 && (c - 1.0).abs() < 0.01;
        let ok_right = (a - 0.5).abs() < 0.01 && (b - 3.0).abs() < 0.01 && (c + 1.0).abs() < 0.01;
        assert!(ok_left || ok_right, "local model c {c} a {a} b {b}");
    }
    let p = m.predict(&e).unwrap();
    let rmse = gb_core::metrics::rmse(&e.output, &p).unwrap();
    assert!(rmse < 0.0105, "rmse {rmse}");
}

#[test]
fn oblique_tree_beats_axis_lolimot_on_an_oblique_function() {
    // a ridge along the diagonal: axis splits need a staircase
    let f = |a: f64, b: f64| (3.0 * (a + b)).tanh();
    let e = static_2d(2000, 0.02, 2, f);
    let reg = RegressorSpec::arx(0, &[1, 1], &[0, 0]);
    let fit = |w: WeightKind, s: SplitKind| {
        let m = LmnParams::new(reg.clone())
            .weights(w)
            .splits(s)
            .max_leaves(4)
            .patience(10)
            .criterion(Criterion::Validation)
            .focus(Focus::Prediction)
            .lm_iterations(0)
            .check()
            .unwrap()
            .fit(&one(&e), Some(&one(&e)))
            .unwrap();
        let p = m.predict(&e).unwrap();
        (m.n_leaves(), gb_core::metrics::rmse(&e.output, &p).unwrap())
    };
    let (la, ea) = fit(WeightKind::Gaussian, SplitKind::Axis);
    let (lo, eo) = fit(WeightKind::Tree, SplitKind::Oblique);
    assert_eq!((la, lo), (4, 4));
    assert!(eo < 0.7 * ea, "oblique {eo} vs axis {ea}");
}

#[test]
fn pruning_removes_a_split_added_on_pure_noise() {
    let mut r = rng(3);
    let u: Vec<f64> = (0..1500).map(|_| r.random_range(-1.0..1.0)).collect();
    let y: Vec<f64> = u
        .iter()
        .map(|v| {
            let e: f64 = StandardNormal.sample(&mut r);
            1.0 + 2.0 * v + 0.3 * e
        })
        .collect();
    let e = one(&rec(vec![u], y));
    // choosing by the (same) data always keeps a split on the noise
    let mut m = LmnParams::new(RegressorSpec::arx(0, &[1], &[0]))
        .max_leaves(2)
        .criterion(Criterion::Validation)
        .focus(Focus::Prediction)
        .lm_iterations(0)
        .check()
        .unwrap()
        .fit(&e, Some(&e))
        .unwrap();
    assert_eq!(m.n_leaves(), 2);
    let removed = m.prune(&e, Criterion::Aicc).unwrap();
    assert_eq!((removed, m.n_leaves()), (1, 1));
    // and the pruning option of the builder gives one leaf directly
    let m = LmnParams::new(RegressorSpec::arx(0, &[1], &[0]))
        .max_leaves(6)
        .patience(10)
        .prune(true)
        .lm_iterations(0)
        .fit(&e)
        .unwrap();
    assert_eq!(m.n_leaves(), 1, "{:?}", m.summary);
}

/// A mildly nonlinear second-order system (bounded by the tanh terms).
fn nl_system(n: usize, noise: f64, seed: u64) -> Record {
    nl_system_with_truth(n, noise, seed).0
}

/// [`nl_system`] and the same record without the measurement noise (the
/// truth a simulation should reproduce).
fn nl_system_with_truth(n: usize, noise: f64, seed: u64) -> (Record, Record) {
    let mut r = rng(seed);
    let u: Vec<f64> = (0..n).map(|_| r.random_range(-1.0..1.0)).collect();
    let mut y0 = vec![0.0; n];
    for k in 2..n {
        y0[k] = 0.3 * y0[k - 1]
            + 0.2 * y0[k - 2]
            + 0.5 * (1.5 * u[k - 1]).tanh()
            + 0.3 * (2.0 * y0[k - 1]).tanh();
    }
    let y = y0
        .iter()
        .map(|v| {
            let e: f64 = StandardNormal.sample(&mut r);
            v + noise * e
        })
        .collect();
    (rec(vec![u.clone()], y), rec(vec![u], y0))
}

fn check_gradient(m: &LmnModel, e: &Records, focus: Focus) {
    let (_, g) = m.cost_gradient(e, focus).unwrap();
    let th = m.parameters();
    for q in 0..th.len() {
        let h = 1e-6 * (1.0 + th[q].abs());
        let mut a = m.clone();
        let mut t = th.clone();
        t[q] += h;
        a.set_parameters(&t).unwrap();
        let cp = a.cost_gradient(e, focus).unwrap().0;
        t[q] -= 2.0 * h;
        a.set_parameters(&t).unwrap();
        let cm = a.cost_gradient(e, focus).unwrap().0;
        let fd = (cp - cm) / (2.0 * h);
        assert!(
            (fd - g[q]).abs() <= 1e-4 * (1.0 + g[q].abs()),
            "{focus:?} param {q}: fd {fd} analytic {}",
            g[q]
        );
    }
}

#[test]
fn noe_gradient_matches_finite_differences() {
    let e = Records::new(vec![nl_system(400, 0.02, 4), nl_system(300, 0.02, 5)]).unwrap();
    let reg = RegressorSpec::arx(2, &[2], &[1])
        .with_z(vec![1], vec![vec![1]])
        .with_degree(2);
    for (w, s) in [
        (WeightKind::Tree, SplitKind::Oblique),
        (WeightKind::Gaussian, SplitKind::Axis),
    ] {
        let m = LmnParams::new(reg.clone())
            .weights(w)
            .splits(s)
            .smoothness(0.3)
            .max_leaves(3)
            .patience(5)
            .criterion(Criterion::Validation)
            .focus(Focus::Prediction)
            .lm_iterations(0)
            .check()
            .unwrap()
            .fit(&e, Some(&e))
            .unwrap();
        assert_eq!(m.n_leaves(), 3);
        check_gradient(&m, &e, Focus::Simulation);
        check_gradient(&m, &e, Focus::Prediction);
    }
}

/// Duffing oscillator x'' + 0.3 x' + x + 2 x³ = u, sampled at 0.2 with RK4 (zero-order hold).
fn duffing(n: usize, noise: f64, seed: u64) -> (Record, Vec<f64>) {
    let mut r = rng(seed);
    let mut u = Vec::with_capacity(n);
    let mut level = 0.0;
    for k in 0..n {
        if k % 8 == 0 {
            level = r.random_range(-1.5..1.5);
        }
        u.push(level);
    }
    let f = |x: f64, v: f64, u: f64| (v, u - 0.3 * v - x - 2.0 * x * x * x);
    let (mut x, mut v) = (0.0, 0.0);
    let h = 0.2;
    let mut y0 = Vec::with_capacity(n);
    for &uk in &u {
        y0.push(x);
        let (k1x, k1v) = f(x, v, uk);
        let (k2x, k2v) = f(x + 0.5 * h * k1x, v + 0.5 * h * k1v, uk);
        let (k3x, k3v) = f(x + 0.5 * h * k2x, v + 0.5 * h * k2v, uk);
        let (k4x, k4v) = f(x + h * k3x, v + h * k3v, uk);
        x += h / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x);
        v += h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
    }
    let y = y0
        .iter()
        .map(|v| {
            let e: f64 = StandardNormal.sample(&mut r);
            v + noise * e
        })
        .collect();
    (rec(vec![u], y), y0)
}

#[test]
fn duffing_free_run_reaches_twice_the_noise_floor() {
    let noise = 0.01;
    let (train, _) = duffing(3000, noise, 6);
    let (val, truth) = duffing(2000, noise, 7);
    let reg = RegressorSpec::arx(2, &[2], &[1]).with_z(vec![1], vec![vec![]]);
    let m = LmnParams::new(reg)
        .weights(WeightKind::Tree)
        .max_leaves(8)
        .focus(Focus::Simulation)
        .lm_iterations(25)
        .fit(&one(&train))
        .unwrap();
    let sim = m.simulate(&val, 0).unwrap();
    let k0 = m.max_lag();
    let nrmse = gb_core::metrics::nrmse(&val.output[k0..], &sim[k0..]).unwrap();
    let floor = noise / gb_core::metrics::std(&truth[k0..]);
    println!(
        "duffing: {} ; NRMSE {nrmse:.4}, noise floor {floor:.4}",
        m.describe()
    );
    assert!(nrmse < 2.0 * floor, "NRMSE {nrmse} vs floor {floor}");
}

#[test]
fn several_experiments_and_user_columns_round_trip() {
    let e1 = nl_system(500, 0.01, 8);
    let e2 = nl_system(400, 0.01, 9);
    // a user column (the last input signal): the square of the input,
    // entering the local models linearly
    let add = |mut e: Record| {
        let c: Vec<f64> = e.inputs[0].iter().map(|v| v * v).collect();
        e.inputs.push(c);
        e.input_names.push("u1_squared".into());
        e
    };
    let e = Records::new(vec![add(e1), add(e2)]).unwrap();
    let reg = RegressorSpec::arx(2, &[1], &[1]).with_extra(1);
    let m = LmnParams::new(reg)
        .max_leaves(3)
        .lm_iterations(5)
        .fit(&e)
        .unwrap();
    let bytes = postcard::to_allocvec(&m).unwrap();
    let back: LmnModel = postcard::from_bytes(&bytes).unwrap();
    assert_eq!(m, back);
    back.check_consistency().unwrap();
    let e1 = &e.as_slice()[1];
    assert_eq!(m.simulate(e1, 10).unwrap(), back.simulate(e1, 10).unwrap());
    // the user columns are inputs of the model as a DynamicModel too
    use gb_core::{DynamicModel, Init};
    assert_eq!(DynamicModel::n_inputs(&m), 2);
    let dm = DynamicModel::simulate(&m, &e1.inputs, Init::History(&e1.output[..10])).unwrap();
    assert_eq!(dm[10..], m.simulate(e1, 10).unwrap()[10..]);
    assert!(m.effective_parameters() > 0.0);
    // bad data is an error, not a panic
    assert!(m.simulate(&rec(vec![], vec![0.0; 10]), 0).is_err());
    assert!(LmnParams::new(RegressorSpec::arx(1, &[1], &[1]))
        .fit(&one(&rec(vec![vec![0.0; 5]], vec![0.0; 5])))
        .is_err());
}

#[test]
fn fast_tree_simulation_agrees_with_the_generic_evaluation() {
    let e = nl_system(800, 0.02, 10);
    let reg = RegressorSpec::arx(2, &[2], &[1]).with_z(vec![1], vec![vec![1]]);
    let m = LmnParams::new(reg)
        .splits(SplitKind::Oblique)
        .max_leaves(6)
        .patience(10)
        .criterion(Criterion::Validation)
        .focus(Focus::Prediction)
        .lm_iterations(0)
        .check()
        .unwrap()
        .fit(&one(&e), Some(&one(&e)))
        .unwrap();
    assert_eq!(m.n_leaves(), 6);
    let sim = m.simulate(&e, 0).unwrap();
    // one-step predictions with the simulated output as "measurement" reproduce it
    let again = m.predict(&rec(e.inputs.clone(), sim.clone())).unwrap();
    for k in m.max_lag()..sim.len() {
        assert!(
            (sim[k] - again[k]).abs() < 1e-12 * (1.0 + sim[k].abs()),
            "k {k}"
        );
    }
}

/// The output-error construction grows a second network on simulated output
/// lags and keeps it only if it simulates the TRAINING data better — so
/// checking the training data again proves nothing. Judged instead on a
/// fresh record of the same system against its noise-free truth: the kept
/// network never simulates worse than the plain one, and where the
/// construction switched networks (seed 13) it simulates clearly better.
#[test]
fn output_error_construction_does_not_simulate_fresh_data_worse() {
    let reg = RegressorSpec::arx(2, &[2], &[1]).with_z(vec![1], vec![vec![1]]);
    let p = LmnParams::new(reg).max_leaves(6).lm_iterations(10);
    // truth RMSE of the simulation (from the true initial outputs)
    let rms = |m: &LmnModel, truth: &Record| {
        let s = m.simulate(truth, 0).unwrap();
        gb_core::metrics::rmse(&truth.output[2..], &s[2..]).unwrap()
    };
    for (seed, noise, switches) in [
        (11, 0.02, false),
        (11, 0.05, false),
        (12, 0.02, false),
        (13, 0.05, true),
    ] {
        let e = nl_system(1500, noise, seed);
        let (_, truth) = nl_system_with_truth(3000, noise, seed + 100);
        let plain = p.clone().fit(&one(&e)).unwrap();
        let noe = p.clone().noe_construction(true).fit(&one(&e)).unwrap();
        let (a, b) = (rms(&plain, &truth), rms(&noe, &truth));
        eprintln!("seed {seed}, noise {noise}: fresh-data truth RMSE plain {a:.5}, NOE construction {b:.5}");
        // measured: 0.0831/0.0831, 0.0633/0.0633, 0.0821/0.0821, 0.0905/0.0716;
        // keeping the second network regardless would give 0.0931, 0.0919, 0.0878
        assert!(
            b <= 1.02 * a,
            "seed {seed}: construction {b} vs plain {a} on fresh data"
        );
        if switches {
            assert!(
                b < 0.9 * a,
                "seed {seed}: construction {b} vs plain {a} on fresh data"
            );
        }
    }
}

#[test]
fn mismatched_lengths_are_errors_not_panics() {
    let e = nl_system(300, 0.02, 12);
    let m = LmnParams::new(RegressorSpec::arx(2, &[2], &[1]))
        .max_leaves(2)
        .lm_iterations(2)
        .fit(&one(&e))
        .unwrap();
    let mut long = e.clone();
    long.output.extend_from_slice(&[0.0; 10]);
    assert!(m.predict(&long).is_err());
    assert!(m.clone().prune(&one(&long), Criterion::Bic).is_err());
    assert!(LmnParams::new(RegressorSpec::arx(2, &[2], &[1]))
        .fit(&one(&long))
        .is_err());
    // simulation needs only the inputs; the output may be just the init window
    assert_eq!(
        m.simulate_signals(&e.inputs, &e.output[..5]).unwrap().len(),
        300
    );
    let mut nan = e.clone();
    nan.output[7] = f64::NAN;
    assert!(LmnParams::new(RegressorSpec::arx(2, &[2], &[1]))
        .fit(&one(&nan))
        .is_err());
}
