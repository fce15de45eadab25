//! A second mode of small amplitude: the order increase gains only a few
//! per cent of NRMSE, below the policy's `min_gain`, but it is what the
//! residual tests ask for (the input is left in the residual of the
//! order-2 baseline and not in the order-4 model's), and it reaches the
//! noise floor.
use gb_diagnose::generator::{draw, draw_with, Knobs};
use gb_diagnose::{diagnose, DiagnoseData, DiagnoseOptions, OrderChoice, Report};

/// The diagnosis of a generated case from the engineer's order: the report,
/// the named causes and the final NRMSE over the noise floor.
fn diagnosed(family: &str, seed: u64) -> (Report, Vec<String>, f64) {
    diagnosed_case(draw(family, seed).unwrap())
}

/// [`diagnosed`] for a drawn case.
fn diagnosed_case(c: gb_diagnose::generator::Case) -> (Report, Vec<String>, f64) {
    let d = DiagnoseData::with_validation(c.train.clone(), c.validate.clone()).unwrap();
    let o = DiagnoseOptions {
        order: OrderChoice::Fixed(c.model_order),
        ..DiagnoseOptions::default()
    };
    let r = diagnose(&d, &o, None).unwrap().report;
    let causes: Vec<String> = r.cause_names().iter().map(|s| s.to_string()).collect();
    let ratio = r.final_model.nrmse / c.noise_floor_nrmse;
    (r, causes, ratio)
}

/// `dynamics` alone named, by an accepted order increase 2 → 4, and the
/// final model within `max_ratio` × the noise floor.
fn assert_named_by_order_2_to_4((r, causes, ratio): (Report, Vec<String>, f64), max_ratio: f64) {
    let order_step = r
        .steps
        .iter()
        .any(|s| s.accepted && s.extension.starts_with("order 2 -> 4"));
    assert!(
        causes == ["dynamics"] && ratio <= max_ratio && order_step,
        "{causes:?}, final/floor {ratio:.3}, order increase accepted: {order_step}"
    );
}

/// `two-mass` seed 9 (4425 training samples, PRBS, 18.8 dB SNR; true
/// order 4): the order increase 2 → 4 gains +1.7 % [+1 %, +2 %] on the
/// select block. Before the evidence rule the diagnosis named no cause and
/// its verdict read "unexplained misfit: input cross-correlation" at the
/// noise floor.
#[test]
fn a_small_second_mode_is_named_dynamics_when_the_residual_asks_for_it() {
    assert_named_by_order_2_to_4(diagnosed("two-mass", 9), 1.05);
}

/// `two-mass` seed 9 at 8000 + 4000 samples (the sweep's lengths): the
/// order increase 2 → 4 gains +3.2 % [+1.9 %, +4.3 %] on the select block
/// and answers the cross-correlation evidence (p = 7e-15 → 0.015). The
/// check from a fresh start of the select block asked it for the full
/// `min_gain` though the select block admitted it at
/// `evidenced_dynamics_gain`: no cause named, the order-2 model kept at
/// 1.03× the floor with its verdict "unexplained misfit".
#[test]
fn a_small_second_mode_pays_from_a_fresh_start_at_the_evidenced_gain() {
    let c = draw_with("two-mass", 9, &Knobs::lengths(8000, 4000)).unwrap();
    assert_named_by_order_2_to_4(diagnosed_case(c), 1.02);
}

/// `two-mass` seed 4 at 8000 + 4000 samples (a sweep with a slow
/// component: the select block unlike the training record, so blocked
/// cross-validation decides). A fold of a sweep holds out a band the rest
/// never excites: the order increase 2 → 4 scattered at +0.285 [−0.28,
/// +0.52] over the folds and no cause was named at 1.05× the floor.
/// Schwarz's criterion on the whole training record bears it out.
#[test]
fn an_order_increase_on_a_sweep_is_borne_out_by_the_information_criterion() {
    let c = draw_with("two-mass", 4, &Knobs::lengths(8000, 4000)).unwrap();
    assert_named_by_order_2_to_4(diagnosed_case(c), 1.04);
}

/// `linear` seed 4 at 8000 + 4000 samples (true order 4, dead time 3
/// and a feedthrough behind it; the engineer's order 4): the output-error
/// fit of the right structure from its cold start ended in a local minimum
/// at 1.037× the noise floor, its residual correlated with the input
/// (p = 5e-21), and with the fresh-start check at the evidenced gain the
/// order increase 4 → 6 named `dynamics` for a linear system of the
/// engineer's order. The baseline's fit from the reduction of its order-6
/// fit reaches the floor: no cause.
#[test]
fn a_local_minimum_of_the_right_order_is_not_named_dynamics() {
    let c = draw_with("linear", 4, &Knobs::lengths(8000, 4000)).unwrap();
    let (r, causes, ratio) = diagnosed_case(c);
    let base = r.baseline.nrmse;
    assert!(
        causes.is_empty() && ratio <= 1.01,
        "{causes:?}, final/floor {ratio:.3} (baseline NRMSE {base:.4})"
    );
}

/// `lag` seed 8 (a resonance at 8.8 samples per period behind a real pole,
/// 1350 training samples, sweep + slow excitation; the engineer's order 2):
/// the order-2 baseline absorbs the pole as a dead time of 2 samples. The
/// order increase with the delay scanned again (order 3, delay 1) reaches
/// the noise floor; before it, the order increase kept the dead time and a
/// Preisach component on the output was named `hysteresis` (0.0812 →
/// 0.0258), then a hidden-state model; with the rescanned candidate but
/// the memory rule still preferring hysteresis to any order increase, the
/// same.
#[test]
fn a_lag_absorbed_as_dead_time_is_named_dynamics() {
    let (r, causes, ratio) = diagnosed("lag", 8);
    let rescanned = r
        .steps
        .iter()
        .any(|s| s.accepted && s.extension.contains("input delay [2] -> [1]"));
    assert!(
        causes == ["dynamics"] && ratio <= 1.1 && rescanned,
        "{causes:?}, final/floor {ratio:.3}, rescanned order accepted: {rescanned}"
    );
}

/// `lag` seed 6 (949 training samples, cross-validation; the engineer's
/// order 2): after order 2 → 4, a Hammerstein model gains +0.059 on the
/// folds and order 4 → 5 +0.044. The largest gain would name
/// `nonlinearity` for a linear system; the Hammerstein model does not pay
/// against the order increase's residuals, so the order increase is
/// chosen (policy `linear_before_nonlinear`) and the step's evidence says
/// so.
#[test]
fn a_nonlinear_candidate_must_beat_the_higher_linear_order() {
    let (r, causes, ratio) = diagnosed("lag", 6);
    // the choice's note is in the accepted step's evidence line
    let rule = r.steps.iter().any(|s| {
        s.accepted
            && s.evidence
                .contains("does not pay against the higher linear order")
    });
    assert!(
        causes == ["dynamics"] && ratio <= 1.1 && rule,
        "{causes:?}, final/floor {ratio:.3}, rule named: {rule}"
    );
}

/// `lag` seed 30 (three real poles, 25 samples per period, multisine,
/// 1399 training samples; the engineer's order 2): the order increase
/// 2 → 4 gains +0.377 [+0.27, +0.48], and the lagging residual of the
/// missing poles reads as a loop to the memory test (p = 4e-7). The memory
/// rule used to prefer any overlapping hysteresis candidate, here play
/// operators on the output at order 3 (+0.182 [+0.11, +0.28]), which do
/// not nest order 4: `hysteresis` at 1.65× the floor. Only a hysteresis
/// candidate at the increased order or above may take its place.
#[test]
fn a_missing_pole_read_as_a_loop_stays_dynamics() {
    let (_, causes, ratio) = diagnosed("lag", 30);
    assert!(
        causes == ["dynamics"] && ratio <= 1.1,
        "{causes:?}, final/floor {ratio:.3}"
    );
}

/// `two-mass` seed 2 at 8000 + 4000 samples (a hidden second mass at
/// 20.8 dB, a periodic multisine): the order 2 → 4 fit warm-started from
/// the order-2 model stayed in a basin without the weak mode (0.0985 on
/// the validation record, floor 0.0913), and a Wiener–Hammerstein network
/// whose filters had found it was named `nonlinearity` at 1.71× the floor.
/// Refined from the reduction of an order-6 fit, the order increase finds
/// the mode.
#[test]
fn an_order_increase_from_a_reduction_finds_a_weak_mode_the_warm_start_misses() {
    let c = draw_with("two-mass", 2, &Knobs::lengths(8000, 4000)).unwrap();
    assert_named_by_order_2_to_4(diagnosed_case(c), 1.05);
}

/// `backlash` seed 4 (an input backlash before two first-order lags,
/// 10 847 training samples of a sweep, judged by cross-validation): once
/// the backlash is in (1.02× the floor), the order increase 2 → 4 gained
/// +0.50 on the folds — the backlash model's fold refits extrapolate badly
/// into the sweep's held-out band — but only 2.4 % on the whole training
/// record (2.6 % on the report block). An order increase must realise on
/// the whole record the gain it needs (policy `cv_dynamics_realised`):
/// `hysteresis` alone, where `hysteresis, dynamics` was named before.
#[test]
fn an_order_increase_must_realise_its_gain_on_the_whole_record() {
    let (r, causes, ratio) = diagnosed("backlash", 4);
    assert!(
        causes == ["hysteresis"] && ratio <= 1.1,
        "{causes:?}, final/floor {ratio:.3}; steps: {:?}",
        r.steps
            .iter()
            .filter(|s| s.accepted)
            .map(|s| &s.extension)
            .collect::<Vec<_>>()
    );
}
