//! The search for a cause runs only where the residual shows one: on a
//! clean linear system the baseline's residuals pass the verdict's tests,
//! and no extension is fitted (policy `stop_when_adequate`); the same data
//! searched anyway name no cause either.
use gb_diagnose::generator::draw;
use gb_diagnose::{diagnose, DecisionPolicy, DiagnoseData, DiagnoseOptions, OrderChoice, Report};

fn diagnosed(family: &str, seed: u64, stop: bool) -> Report {
    let c = draw(family, seed).unwrap();
    let d = DiagnoseData::with_validation(c.train.clone(), c.validate.clone()).unwrap();
    let o = DiagnoseOptions {
        order: OrderChoice::Fixed(c.model_order),
        policy: DecisionPolicy {
            stop_when_adequate: stop,
            ..DecisionPolicy::default()
        },
        ..DiagnoseOptions::default()
    };
    diagnose(&d, &o, None).unwrap().report
}

/// `linear` seed 5 (a clean second-order system): the baseline is
/// adequate, nothing is fitted after it.
#[test]
fn clean_linear_data_are_not_searched() {
    let r = diagnosed("linear", 5, true);
    assert!(
        r.steps.is_empty() && r.causes.is_empty(),
        "{} steps, causes {:?}",
        r.steps.len(),
        r.cause_names()
    );
    assert!(
        r.structure.decision.contains("no extension was searched"),
        "{}",
        r.structure.decision
    );
    assert_eq!(
        r.verdict.kind,
        gb_diagnose::VerdictKind::Adequate,
        "{}",
        r.verdict.text
    );
    // searched anyway: candidates are fitted and none pays
    let all = diagnosed("linear", 5, false);
    assert!(
        !all.steps.is_empty() && all.causes.is_empty(),
        "{} steps, causes {:?}",
        all.steps.len(),
        all.cause_names()
    );
    assert!((all.final_model.nrmse - r.final_model.nrmse).abs() < 1e-12);
}

/// A hidden effect leaves the baseline's residual failing the tests, so
/// the search runs: `hammerstein-odd` seed 1 is named `nonlinearity`.
#[test]
fn an_effect_is_still_searched() {
    let r = diagnosed("hammerstein-odd", 1, true);
    assert!(
        !r.steps.is_empty() && r.cause_names().contains(&"nonlinearity"),
        "{} steps, causes {:?}",
        r.steps.len(),
        r.cause_names()
    );
}
