//! Hysteresis before and inside the dynamics: a generated input backlash
//! (a play operator of half-width ρ·σ_u before linear dynamics) and a
//! Bouc–Wen restoring force are named `hysteresis` and reach the noise
//! floor; the backlash's half-width comes back from the training data.
use gb_core::Record;
use gb_diagnose::generator::{draw, Case};
use gb_diagnose::{diagnose, DiagnoseData, DiagnoseOptions, OrderChoice, Report};

/// The diagnosis of case `c` with the engineer's order.
fn diagnosed(c: &Case) -> Report {
    let d = DiagnoseData::with_validation(c.train.clone(), c.validate.clone()).unwrap();
    let o = DiagnoseOptions {
        order: OrderChoice::Fixed(c.model_order),
        ..DiagnoseOptions::default()
    };
    diagnose(&d, &o, None).unwrap().report
}

/// `bouc-wen` seed 7 (540 training samples, 5.4 samples per period): the
/// continuous-time mass–spring–damper template with a Bouc–Wen state has
/// the true structure. While it was proposed only when the
/// direction-of-motion memory test rejected, the columns of play operators
/// were chosen and the diagnosis ended at 7.2× the floor.
#[test]
fn a_bouc_wen_force_is_fitted_by_the_mechanical_template() {
    let c = draw("bouc-wen", 7).unwrap();
    let r = diagnosed(&c);
    let causes: Vec<String> = r.cause_names().iter().map(|s| s.to_string()).collect();
    let ratio = r.final_model.nrmse / c.noise_floor_nrmse;
    let template = r
        .steps
        .iter()
        .any(|s| s.accepted && s.extension.starts_with("a mechanical grey-box model"));
    assert!(
        c.causes_right(&causes) && ratio <= 1.2 && template,
        "{causes:?}, final/floor {ratio:.2}, template accepted: {template}"
    );
}

/// `backlash` seeds 2 (805 samples, a sweep with a slow component, judged
/// by cross-validation) and 8 (1469 samples, noise with a slow component).
/// Before the half-width was fitted, the grid of input plays (0.3 σ apart)
/// only approximated it: seed 2 ended with no cause at 5.6× the floor
/// (every candidate lost under cross-validation), seed 8 at 1.8× after a
/// spurious order increase. Seed 2 also guards the tie rule: a degenerate
/// dry-friction template paid +0.31 [+0.03, +0.58] against the backlash's
/// +0.53 [+0.41, +0.69], and "no loop in the residual" gave the tie to the
/// static law (4.9× the floor) until a tie needed the static candidate's
/// gain inside the hysteretic one's interval.
#[test]
fn a_backlash_half_width_is_recovered_and_the_floor_reached() {
    for seed in [2, 8] {
        let c = draw("backlash", seed).unwrap();
        let truth = c
            .parameters
            .iter()
            .find(|(n, _)| n == "level_quantile")
            .map(|p| p.1)
            .unwrap();
        let r = diagnosed(&c);
        let causes: Vec<String> = r.cause_names().iter().map(|s| s.to_string()).collect();
        let ratio = r.final_model.nrmse / c.noise_floor_nrmse;
        assert!(
            c.causes_right(&causes) && ratio <= 1.2,
            "seed {seed}: {causes:?}, final/floor {ratio:.2}"
        );
        let step = r
            .steps
            .iter()
            .find(|s| s.accepted && s.extension.starts_with("a backlash on input 'u'"))
            .unwrap_or_else(|| panic!("seed {seed}: the backlash candidate was not accepted"));
        let width: f64 = step
            .extension
            .split("-> half-width ")
            .nth(1)
            .and_then(|t| t.split_whitespace().next())
            .and_then(|t| t.parse().ok())
            .unwrap();
        assert!(
            (width / truth - 1.0).abs() < 0.15,
            "seed {seed}: half-width {width} sd, true {truth} u_rms"
        );
    }
}

/// `preisach` seed 2 (a relay-grid Preisach spring on the position inside
/// the loop, 2089 training samples, multisine, 45 dB): a map of the
/// simulated output fed back (+0.789 [+0.75, +0.84] on the select block)
/// and a Preisach component on the output (+0.782 [+0.75, +0.83]) tie,
/// and the model with both is no better than either, so the unique
/// contributions cannot tell. The static map's residual keeps the loop
/// (direction-of-motion memory p ≈ 6e-7) and the Preisach component's does
/// not: hysteresis. Until the loop spoke, the map with fewer parameters was
/// chosen and the diagnosis ended with `nonlinearity` at 5.2× the floor
/// (now 4.1×: the relay grid's hard steps are not reached).
#[test]
fn a_loop_the_static_map_leaves_names_hysteresis() {
    let c = draw("preisach", 2).unwrap();
    let r = diagnosed(&c);
    let causes: Vec<String> = r.cause_names().iter().map(|s| s.to_string()).collect();
    let ratio = r.final_model.nrmse / c.noise_floor_nrmse;
    let rule = r.steps.iter().any(|s| {
        s.accepted
            && s.evidence
                .contains("resolved for hysteresis: the static candidate's residual keeps the loop")
    });
    assert!(
        causes == ["hysteresis"] && rule && ratio < 5.0,
        "{causes:?}, final/floor {ratio:.2}, rule named: {rule}"
    );
}

/// A magnetorheological damper after Spencer et al. (1997), without the
/// inner dashpot: the force `F = α(w)·z + c₀(w)·v + k₀·x` of a Bouc–Wen
/// state `ż = −γ|v|z|z| − β v z² + A v` (n = 2) driven by the piston
/// velocity `v = ẋ`, its field `w` the command voltage `E` through a
/// first-order lag (time constant `tau` s); `α = αa + αb·w`, `c₀ = c₀a +
/// c₀b·w`. Sampled at `dt` with 20 Euler sub-steps; the displacement is
/// white noise through two first-order lags, the voltage held at random
/// levels in [0, 2.25] V for 0.1–0.4 s; measurement noise on `F` at
/// `snr_db`. The record's inputs are `x`, `v` (the sampled derivative of
/// `x`, as a rig computes it) and `E`; the noise-free force is returned
/// as well.
fn mr_damper(n: usize, dt: f64, tau: f64, snr_db: f64, seed: u64) -> (Record, Vec<f64>) {
    use rand::Rng;
    use rand_distr::{Distribution, StandardNormal};
    let mut rng = gb_core::rng::seeded(seed);
    let (a1, a2) = ((-dt / 0.02f64).exp(), (-dt / 0.05f64).exp());
    let (mut p, mut x) = (0.0, vec![0.0; n]);
    for k in 1..n {
        let e: f64 = StandardNormal.sample(&mut rng);
        p = a1 * p + (1.0 - a1) * e;
        x[k] = a2 * x[k - 1] + (1.0 - a2) * p * 8.0;
    }
    let v: Vec<f64> = (0..n)
        .map(|k| (x[(k + 1).min(n - 1)] - x[k.saturating_sub(1)]) / (2.0 * dt))
        .collect();
    let (mut volt, mut level, mut hold) = (vec![0.0; n], 0.0, 0usize);
    for e in &mut volt {
        if hold == 0 {
            level = 2.25 * rng.random::<f64>();
            hold = ((0.1 + 0.3 * rng.random::<f64>()) / dt) as usize;
        }
        hold -= 1;
        *e = level;
    }
    let (beta, gamma, big_a) = (12.5, 12.5, 1.0);
    let (mut z, mut w, sub) = (0.0f64, 0.0f64, 20);
    let h = dt / sub as f64;
    let mut f = vec![0.0; n];
    for k in 0..n {
        for _ in 0..sub {
            let vk = v[k];
            z += h * (-gamma * vk.abs() * z * z.abs() - beta * vk * z * z + big_a * vk);
            w += h * (volt[k] - w) / tau;
        }
        f[k] = (1000.0 + 5000.0 * w) * z + (21.0 + 3.5 * w) * v[k] + 46.9 * x[k];
    }
    let sd = gb_core::metrics::std(&f) * 10f64.powf(-snr_db / 20.0);
    let y: Vec<f64> = f
        .iter()
        .map(|fk| {
            let e: f64 = StandardNormal.sample(&mut rng);
            fk + sd * e
        })
        .collect();
    let rec = Record::new(
        vec!["x".into(), "v".into(), "E".into()],
        "F".into(),
        vec![x, v, volt],
        y,
    )
    .unwrap();
    (rec, f)
}

/// A generated magnetorheological damper (three inputs: displacement,
/// velocity, command voltage; 4000 training samples at 1 kHz, a fresh
/// excitation of 3000 for validation, 40 dB; the loop saturates at 0.3
/// standard deviations of the displacement): the force is a hysteretic
/// function of the displacement whose level the lagged voltage sets. The
/// static polynomial of the inputs, the stop operators of `x` and the
/// low-pass channels of `v` and `E` is accepted for `hysteresis` on `x`:
/// the validation NRMSE falls from 0.447 (linear) to 0.067, 6.6× the noise
/// floor (a few stops approximate the smooth Bouc–Wen loop). Before the
/// input operators (the extension left out) `nonlinearity` was named and
/// the diagnosis ended at 0.091, 9.0× the floor.
#[test]
fn a_damper_force_is_a_polynomial_of_stop_operators_and_a_lagged_voltage() {
    let (train, _) = mr_damper(4000, 1e-3, 0.02, 40.0, 11);
    let (validate, clean) = mr_damper(3000, 1e-3, 0.02, 40.0, 12);
    let floor = gb_core::metrics::nrmse(&validate.output, &clean).unwrap();
    let d = DiagnoseData::with_validation(train, validate).unwrap();
    let r = diagnose(&d, &DiagnoseOptions::default(), None)
        .unwrap()
        .report;
    let causes: Vec<&str> = r.cause_names();
    let ratio = r.final_model.nrmse / floor;
    let on_x = r.steps.iter().any(|s| {
        s.accepted
            && s.cause == gb_diagnose::Cause::Hysteresis
            && s.extension.contains("stop operators of 'x'")
    });
    let gain = r.final_model.nrmse / r.baseline.nrmse;
    assert!(
        causes == ["hysteresis"] && on_x && ratio <= 8.0 && gain < 0.2,
        "{causes:?}, stops of x accepted: {on_x}, final/floor {ratio:.2}, final/baseline {gain:.3}"
    );
}
