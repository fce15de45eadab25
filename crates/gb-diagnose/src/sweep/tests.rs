//! Tests of the sweep runner and its tables.
use super::*;

fn result(family: &str, expected: &[&str], named: &[&str], ratio: f64) -> CaseResult {
    let v = |s: &[&str]| -> Vec<String> { s.iter().map(|x| x.to_string()).collect() };
    let spec = CaseSpec {
        family: family.into(),
        seed: 7,
        knobs: Knobs::default(),
    };
    let mut r = failed(&spec, None, String::new());
    r.error = None;
    r.expected = v(expected);
    r.named = v(named);
    r.causes_right = r.named.iter().all(|c| r.expected.contains(c))
        && r.expected.is_empty() == r.named.is_empty();
    r.ratio = ratio;
    r.floor = 0.02;
    r.final_nrmse = ratio * 0.02;
    r.right = r.causes_right && ratio <= 1.5;
    r.right_tight = r.causes_right && ratio <= 1.3;
    r.adequate_above_floor = r.named.is_empty() && ratio > 1.5;
    r.explained_above_floor = ratio > 1.5 && r.named.len() < 2;
    r.seconds = 1.0;
    r
}

#[test]
fn markdown_counts_right_foreign_and_floor() {
    let mut rs = vec![
        result("linear", &[], &[], 1.0),
        result("linear", &[], &["dynamics"], 1.0),
        result("duffing", &["nonlinearity"], &["nonlinearity"], 1.4),
        result("duffing", &["nonlinearity"], &[], 3.0),
        result("backlash", &["hysteresis"], &["nonlinearity"], 1.2),
    ];
    rs[1].foreign_named = vec!["dynamics".into()];
    rs[4].foreign_named = vec!["nonlinearity".into()];
    let md = markdown(&rs, "test");
    assert!(
        md.contains("| right (causes right, final ≤ 1.5× floor) | 2/5 (40 %) |"),
        "{md}"
    );
    assert!(
        md.contains("| right, final ≤ 1.3× floor | 1/5 (20 %) |"),
        "{md}"
    );
    assert!(
        md.contains("| no cause named on clean linear data (linear, dead-time) | 1/2 (50 %) |"),
        "{md}"
    );
    assert!(
        md.contains("| verdict \"adequate\" while final > 1.5× floor | 1/5 (20 %) |"),
        "{md}"
    );
    assert!(
        md.contains(
            "| verdict \"adequate\" or \"coloured noise\" while final > 1.5× floor | 1/5 (20 %) |"
        ),
        "{md}"
    );
    assert!(md.contains("| duffing | nonlinearity | 2 | 1/2 (50 %) | 0 | 1/2 (50 %) | 1/2 (50 %) | 0/2 (0 %) | 2.20 | 3.00 | 1 |"), "{md}");
    // confusion: expected none -> 1 none, 1 dynamics
    assert!(md.contains("| none | 1 | 0 | 0 | 1 | 0 | 0 |"), "{md}");
    assert!(
        md.contains("| hysteresis | 0 | 1 | 0 | 0 | 0 | 0 |"),
        "{md}"
    );
    assert!(md.contains("| all | 2 | 1 | 1 | 0 | 1 |"), "{md}");
    assert!(md.contains("## Failures (3 of 5)"), "{md}");
}

#[test]
fn run_one_reports_a_case() {
    let spec = CaseSpec {
        family: "linear".into(),
        seed: 3,
        knobs: Knobs {
            n_train: Some(800),
            n_validate: Some(400),
            ..Knobs::default()
        },
    };
    let r = run(std::slice::from_ref(&spec), &SweepOptions::default(), None);
    assert_eq!(r.len(), 1);
    let r = &r[0];
    assert!(r.error.is_none(), "{:?}", r.error);
    assert!(r.final_nrmse.is_finite() && r.floor > 0.0 && r.ratio.is_finite());
    assert!(r.final_nrmse <= r.baseline_nrmse + 1e-12);
    assert_eq!(r.right, r.causes_right && r.ratio <= 1.5);
    let bad = CaseSpec {
        family: "nope".into(),
        ..spec
    };
    assert!(run_one(&bad, &SweepOptions::default()).error.is_some());
}
