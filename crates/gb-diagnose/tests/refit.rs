//! The final refit on the whole training record: the structure is chosen
//! on the fit block and judged on the select block, then refitted on both
//! for the model the user keeps.
use gb_diagnose::generator::{draw, Case};
use gb_diagnose::{diagnose, DiagnoseData, DiagnoseOptions, OrderChoice, Report};

/// The case `family seed` and its diagnosis with the refit policy on and
/// off (the engineer's order).
fn with_and_without_refit(family: &str, seed: u64) -> (Case, Report, Report) {
    let c = draw(family, seed).unwrap();
    let d = DiagnoseData::with_validation(c.train.clone(), c.validate.clone()).unwrap();
    let run = |refit: bool| {
        let mut o = DiagnoseOptions {
            order: OrderChoice::Fixed(c.model_order),
            ..DiagnoseOptions::default()
        };
        o.policy.refit_on_training = refit;
        diagnose(&d, &o, None).unwrap().report
    };
    let (with, without) = (run(true), run(false));
    (c, with, without)
}

/// `two-input` seed 9 (1425 training samples of filtered noise; a cubic
/// map on input 1, input 2 linear, one first-order block): the
/// Hammerstein structure chosen on the 1069-sample fit block, whose input
/// range is narrower than the validation record's, extrapolates the cubic
/// map linearly (2.6× the noise floor); refitted on all 1425 training
/// samples it reaches the floor. Without the refit (policy off) the same
/// search stays above 2× the floor, so the test fails if the refit does
/// nothing.
#[test]
fn the_chosen_structure_refitted_on_all_training_samples_reaches_the_floor() {
    let (c, with, without) = with_and_without_refit("two-input", 9);
    let ratio = |r: &Report| r.final_model.nrmse / c.noise_floor_nrmse;
    let causes: Vec<String> = with.cause_names().iter().map(|s| s.to_string()).collect();
    assert!(
        c.causes_right(&causes) && ratio(&with) <= 1.1 && ratio(&without) >= 2.0,
        "{causes:?}, final/floor with the refit {:.3}, without {:.3}",
        ratio(&with),
        ratio(&without)
    );
    // the decisions line says what was refitted; the step table is the
    // search's (the same rows either way)
    assert!(
        with.data
            .decision
            .contains("refitted on the whole training record (1425 samples:"),
        "{}",
        with.data.decision
    );
    assert_eq!(with.steps.len(), without.steps.len());
    assert_eq!(with.causes, without.causes);
}

/// Under cross-validation (`saturation` seed 1: 608 training samples, too
/// few for a select block) the models are already fitted on the whole
/// training record: the refit does not run, and the final model is the
/// same with the policy on or off.
#[test]
fn cross_validated_decisions_are_not_refitted() {
    let (_, with, without) = with_and_without_refit("saturation", 1);
    assert!(
        with.data.decision.starts_with("blocked cross-validation")
            && !with
                .data
                .decision
                .contains("refitted on the whole training record"),
        "{}",
        with.data.decision
    );
    assert_eq!(with.final_model.nrmse, without.final_model.nrmse);
    assert_eq!(with.final_model.model, without.final_model.model);
}
