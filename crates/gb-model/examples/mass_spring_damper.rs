//! The thesis' examples (Hauth 2008, ch. 5), reproduced: a mass-spring-damper
//! `m ẍ + c ẋ + r(x) = F(t)` where only the position x is measured (the
//! velocity is a hidden state), in three variants:
//!
//! 1. linear: `r(x) = k x`, `F = u`;
//! 2. nonlinear (hardening spring): `r(x) = k x + k₃ x³`, `F = u`;
//! 3. hysteresis: `r(x) = k x`, `F = P[u]`, a Preisach operator of the input
//!    (Gaussian Everett function).
//!
//! Data: RK4 at 10 sub-steps per sample (input held), 4000 training and 2000
//! validation samples, measurement noise 1 % of the output's standard
//! deviation. Model: the grey-box second-order structure `p⁺ = p + h v`
//! (known kinematics), `v⁺ = a₂₁ p + a₂₂ v + b₂ u + f(p)` (+ `h[u]`), 4
//! sub-steps per sample, f a sparse `bior2.2` expansion, `h` a Preisach
//! component with a 2-D wavelet Everett function; identified by output error.
//!
//! ```sh
//! cargo run --release -p gb-model --example mass_spring_damper [-- OUT_DIR]
//! ```
use gb_core::metrics;
use gb_model::{
    HysteresisTerm, NonlinearTerm, OeParams, Signal, Silent, SparseExpansion, SparseStateSpace,
    Structure, Target, WaveletEverett,
};
use gb_preisach::{Everett, InitialState, ParametricEverett, Preisach};
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};
use std::path::PathBuf;

const TS: f64 = 0.05;
const M: f64 = 1.0;
const C: f64 = 0.6;
const K: f64 = 4.0;
const K3: f64 = 6.0;

/// Band-limited random input (sum of 40 random-phase sines below 1 Hz).
fn input(n: usize, seed: u64, amp: f64) -> Vec<f64> {
    let mut r = gb_core::rng::seeded(seed);
    let comps: Vec<(f64, f64)> = (1..=40)
        .map(|k| (k as f64 * 0.025, r.random::<f64>() * std::f64::consts::TAU))
        .collect();
    let raw: Vec<f64> = (0..n)
        .map(|t| {
            comps
                .iter()
                .map(|(f, ph)| (std::f64::consts::TAU * f * t as f64 * TS + ph).sin())
                .sum::<f64>()
        })
        .collect();
    let s = metrics::std(&raw);
    raw.iter().map(|v| amp * v / s).collect()
}

/// RK4 simulation of `m ẍ + c ẋ + r(x) = force(t)` (force held over the sample).
fn simulate_truth(force: &[f64], r: impl Fn(f64) -> f64) -> Vec<f64> {
    let sub = 10;
    let h = TS / sub as f64;
    let (mut p, mut v) = (0.0f64, 0.0f64);
    let mut y = Vec::with_capacity(force.len());
    let acc = |p: f64, v: f64, f: f64| (f - C * v - r(p)) / M;
    for &f in force {
        y.push(p);
        for _ in 0..sub {
            let (k1p, k1v) = (v, acc(p, v, f));
            let (k2p, k2v) = (
                v + 0.5 * h * k1v,
                acc(p + 0.5 * h * k1p, v + 0.5 * h * k1v, f),
            );
            let (k3p, k3v) = (
                v + 0.5 * h * k2v,
                acc(p + 0.5 * h * k2p, v + 0.5 * h * k2v, f),
            );
            let (k4p, k4v) = (v + h * k3v, acc(p + h * k3p, v + h * k3v, f));
            p += h / 6.0 * (k1p + 2.0 * k2p + 2.0 * k3p + k4p);
            v += h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
        }
    }
    y
}

fn noisy(y: &[f64], seed: u64) -> Vec<f64> {
    let mut r = gb_core::rng::seeded(seed);
    let s = 0.01 * metrics::std(y);
    y.iter()
        .map(|v| {
            let e: f64 = StandardNormal.sample(&mut r);
            v + s * e
        })
        .collect()
}

/// The grey-box start: p⁺ = p + h v fixed, v-row from a rough guess.
fn mechanical_start(substeps: usize) -> Result<SparseStateSpace, gb_model::ModelError> {
    let h = TS / substeps as f64;
    // a deliberately wrong start (k/m = 2, c/m = 1, 1/m = 0.5)
    let mut m = SparseStateSpace::linear(
        vec![1.0, h, -h * 2.0, 1.0 - h * 1.0],
        vec![0.0, h * 0.5],
        vec![1.0, 0.0],
        vec![0.0],
    )?;
    m.substeps = substeps;
    m.structure = Structure {
        a: vec![false, false, true, true],
        b: vec![false, true],
        c: vec![false, false],
        d: vec![false],
        x0: vec![false, false],
        y_offset: false,
    };
    Ok(m)
}

/// Continuous-time k/m, c/m, 1/m of the identified second-order part, from
/// the eigenvalues of the sub-step matrix (s = ln λ / h) and its static gain,
/// so that the (explicit Euler) discretisation does not bias them.
fn physical(m: &SparseStateSpace, h: f64) -> (f64, f64, f64) {
    let a = &m.a;
    let tr = a[0] + a[3];
    let det = a[0] * a[3] - a[1] * a[2];
    let re = 0.5 * tr;
    let im = (det - re * re).max(0.0).sqrt();
    let s_re = (re * re + im * im).sqrt().ln() / h;
    let s_im = im.atan2(re) / h;
    let w2 = s_re * s_re + s_im * s_im;
    // static gain C (I − A)^{-1} B
    let (i11, i12, i21, i22) = (1.0 - a[0], -a[1], -a[2], 1.0 - a[3]);
    let idet = i11 * i22 - i12 * i21;
    let x1 = (i22 * m.b[0] - i12 * m.b[1]) / idet;
    (w2, -2.0 * s_re, w2 * x1)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::args().nth(1).map(PathBuf::from);
    if let Some(d) = &out {
        std::fs::create_dir_all(d)?;
    }
    let (n_fit, n_val) = (4000, 2000);
    let substeps = 4;
    let h = TS / substeps as f64;
    let fit = OeParams::new()
        .max_iter(40)
        .coarse_level(1)
        .max_level(3)
        .check()?;

    // ---- 1. linear ----
    let u = input(n_fit + n_val, 1, 1.0);
    let y0 = simulate_truth(&u, |p| K * p);
    let y = noisy(&y0, 2);
    let (uf, yf) = (vec![u[..n_fit].to_vec()], &y[..n_fit]);
    let uv = vec![u[n_fit..].to_vec()];
    let (m1, r1) = fit.fit(mechanical_start(substeps)?, &uf, yf, &Silent)?;
    let sim = m1.simulate(std::slice::from_ref(&u))?;
    println!("1. linear mass-spring-damper (position measured, velocity hidden)");
    let (km, cm, im) = physical(&m1, h);
    println!(
        "   identified k/m = {km:.4} (true {:.4}), c/m = {cm:.4} (true {:.4}), 1/m = {im:.4} (true {:.4})",
        K / M,
        C / M,
        1.0 / M
    );
    println!(
        "   training RMSE {:.3e}; validation NRMSE vs noise-free output {:.4}",
        r1.rmse,
        metrics::nrmse(&y0[n_fit..], &sim[n_fit..])?
    );

    // ---- 2. nonlinear: hardening spring ----
    let y0 = simulate_truth(&u, |p| K * p + K3 * p * p * p);
    let y = noisy(&y0, 3);
    let yf = &y[..n_fit];
    let pmax = y0.iter().fold(0.0f64, |a, v| a.max(v.abs())) * 1.1;
    let mut start = mechanical_start(substeps)?;
    start.terms.push(NonlinearTerm {
        target: Target::State(1),
        args: vec![Signal::State(0)],
        expansion: SparseExpansion::new("bior2.2", vec![-pmax], vec![pmax])?,
    });
    let (m2, r2) = fit.fit(start, &uf, yf, &Silent)?;
    let sim = m2.simulate(std::slice::from_ref(&u))?;
    let lin_only = {
        let (ml, _) = fit.fit(mechanical_start(substeps)?, &uf, yf, &Silent)?;
        ml.simulate(&uv)?
    };
    println!("2. nonlinear mass-spring-damper r(x) = k x + k3 x^3 (hidden velocity)");
    for s in &r2.stages {
        println!(
            "   stage {:<16} coefficients {:>3}  train RMSE {:.3e}  {}",
            s.stage,
            s.coefficients,
            s.rmse,
            if s.accepted { "kept" } else { "rejected" }
        );
    }
    println!(
        "   validation NRMSE: linear model {:.4}, wavelet model {:.4}",
        metrics::nrmse(&y0[n_fit..], &lin_only)?,
        metrics::nrmse(&y0[n_fit..], &sim[n_fit..])?
    );
    println!("   identified restoring force r(x)/m = -(a21 x + f(x))/h against the true one:");
    println!("   {:>8} {:>10} {:>10}", "x", "true", "identified");
    let f = &m2.terms[0].expansion;
    let prange = pmax / 1.1;
    // the range where 95 % of the training positions lie
    let mut sorted: Vec<f64> = y0[..n_fit].iter().map(|v| v.abs()).collect();
    sorted.sort_by(f64::total_cmp);
    let p95 = sorted[(0.95 * n_fit as f64) as usize];
    let mut worst95 = 0.0f64;
    let mut worst = 0.0f64;
    let mut rows = Vec::new();
    for i in 0..=20 {
        let p = -prange + 2.0 * prange * i as f64 / 20.0;
        let truth = (K * p + K3 * p * p * p) / M;
        let ident = -(m2.a[2] * p + f.eval(&[p])) / h;
        worst = worst.max((ident - truth).abs());
        if p.abs() <= p95 {
            worst95 = worst95.max((ident - truth).abs());
        }
        rows.push(format!("{p},{truth},{ident}"));
        if i % 4 == 0 {
            println!("   {p:>8.3} {truth:>10.4} {ident:>10.4}");
        }
    }
    let scale = (K * prange + K3 * prange.powi(3)) / M;
    println!(
        "   max |error| {:.4} = {:.2} % of the range over |x| <= {p95:.3} (95 % of the data), {:.2} % up to the extremes; {} non-zero coefficients",
        worst95,
        100.0 * worst95 / scale,
        100.0 * worst / scale,
        f.nnz()
    );
    if let Some(d) = &out {
        gb_core::write_atomic(
            d.join("msd_restoring_force.csv"),
            format!("x,true,identified\n{}\n", rows.join("\n")).as_bytes(),
        )?;
    }

    // ---- 3. Preisach hysteresis in the actuator ----
    let everett = ParametricEverett::gaussian(1.5, 0.3, 0.25, -0.3, 0.25)?;
    let preisach = Preisach::new(everett);
    let uh = input(n_fit + n_val, 4, 0.5);
    let force = preisach.simulate(&uh, &InitialState::NegativeSaturation)?;
    let y0 = simulate_truth(&force, |p| K * p);
    let y = noisy(&y0, 5);
    let (uf, yf) = (vec![uh[..n_fit].to_vec()], &y[..n_fit]);
    let umax = uh.iter().fold(0.0f64, |a, v| a.max(v.abs())) * 1.05;
    let mut start = mechanical_start(substeps)?;
    start.hysteresis.push(HysteresisTerm {
        target: Target::State(1),
        input: 0,
        everett: WaveletEverett::new(SparseExpansion::new(
            "bior2.2",
            vec![-umax, -umax],
            vec![umax, umax],
        )?)?,
    });
    let fit_h = OeParams::new()
        .max_iter(40)
        .coarse_level(2)
        .max_level(3)
        .check()?;
    let (m3, r3) = fit_h.fit(start, &uf, yf, &Silent)?;
    let sim = m3.simulate(std::slice::from_ref(&uh))?;
    let lin_only = {
        let (ml, _) = fit_h.fit(mechanical_start(substeps)?, &uf, yf, &Silent)?;
        ml.simulate(&[uh[n_fit..].to_vec()])?
    };
    println!("3. Preisach hysteresis in the actuator force, F = P[u] (hidden velocity)");
    for s in &r3.stages {
        println!(
            "   stage {:<16} coefficients {:>3}  train RMSE {:.3e}  {}",
            s.stage,
            s.coefficients,
            s.rmse,
            if s.accepted { "kept" } else { "rejected" }
        );
    }
    println!(
        "   validation NRMSE: linear model {:.4}, model with wavelet-Everett Preisach {:.4}",
        metrics::nrmse(&y0[n_fit..], &lin_only)?,
        metrics::nrmse(&y0[n_fit..], &sim[n_fit..])?
    );
    // identified force (b u + P̂[u]) / (h/m) against the true P[u]
    let hid = m3.hysteresis_outputs(std::slice::from_ref(&uh))?;
    let gain = m3.b[1];
    let ident: Vec<f64> = (0..uh.len())
        .map(|t| (gain * uh[t] + hid[0][t]) / h * M)
        .collect();
    // the force is identified up to its mean (an offset is a rest position)
    let off = metrics::mean(&force[n_fit..]) - metrics::mean(&ident[n_fit..]);
    let ident: Vec<f64> = ident.iter().map(|v| v + off).collect();
    println!(
        "   identified hysteretic force vs true P[u] on validation: NRMSE {:.4} ({} non-zero Everett coefficients; true Everett mass {:.2})",
        metrics::nrmse(&force[n_fit..], &ident[n_fit..])?,
        m3.hysteresis[0].everett.expansion().nnz(),
        everett.total()
    );
    if let Some(d) = &out {
        let rows: Vec<String> = (n_fit..uh.len())
            .map(|t| format!("{},{},{}", uh[t], force[t], ident[t]))
            .collect();
        gb_core::write_atomic(
            d.join("msd_hysteresis_loop.csv"),
            format!("u,true_force,identified_force\n{}\n", rows.join("\n")).as_bytes(),
        )?;
        gb_core::write_atomic(d.join("msd_hysteresis.gbs"), &m3.to_bytes()?)?;
    }

    // ---- 4. SMC path: the cubic spring under heavy-tailed noise ----
    let n_smc = 600;
    let us = input(n_smc, 6, 1.0);
    let y0 = simulate_truth(&us, |p| K * p + K3 * p * p * p);
    let s = 0.02 * metrics::std(&y0);
    // Student-t(3) measurement noise: outliers an output-error fit is pulled by
    let t3 =
        gb_smc::noise::Noise::from_model(&gb_model::NoiseModel::StudentT { nu: 3.0, scale: s })?;
    let mut rs = gb_core::rng::seeded(7);
    let y: Vec<f64> = y0.iter().map(|v| v + t3.sample(&mut rs)).collect();
    let mut start = mechanical_start(substeps)?;
    start.terms.push(NonlinearTerm {
        target: Target::State(1),
        args: vec![Signal::State(0)],
        expansion: SparseExpansion::new("bior2.2", vec![-pmax], vec![pmax])?,
    });
    let (oe, _) = fit.fit(start, std::slice::from_ref(&us), &y, &Silent)?;
    let smc = gb_model::SmcParams::new()
        .particles(200)
        .iterations(300, 100)
        .coefficients(4)
        .measurement(gb_model::NoiseModel::StudentT {
            nu: 3.0,
            scale: 1.0,
        })
        .seed(11)
        .check()?;
    let t0 = std::time::Instant::now();
    let (ms, rep) = smc.fit(&oe, std::slice::from_ref(&us), &y, &Silent)?;
    println!("4. SMC path (PMMH, 200 particles, 300 iterations, Student-t(3) measurement noise, Laplace prior on the 4 largest coefficients)");
    println!(
        "   particle log-likelihood: output-error model {:.1}, posterior-mean model {:.1}; acceptance {:.2}; final model from the {:?} path ({:.1} s)",
        rep.log_likelihood_oe,
        rep.log_likelihood_smc,
        rep.acceptance_rate,
        rep.path,
        t0.elapsed().as_secs_f64()
    );
    println!(
        "   noise: process scale x{:.3}, measurement scale x{:.3} of the OE start; final {}",
        rep.posterior_mean[0].exp(),
        rep.posterior_mean[1].exp(),
        ms.measurement_noise.describe()
    );
    Ok(())
}
