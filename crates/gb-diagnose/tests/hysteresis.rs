//! Hysteresis before and inside the dynamics: a generated input backlash
//! (a play operator of half-width ρ·σ_u before linear dynamics) and a
//! Bouc–Wen restoring force are named `hysteresis` and reach the noise
//! floor; the backlash's half-width comes back from the training data.
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
