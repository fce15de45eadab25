//! The baseline reads its structure from the training data: the input delay,
//! an integrator, and short records decided by cross-validation.
use gb_core::Record;
use gb_diagnose::generator::{draw_with, Knobs};
use gb_diagnose::{diagnose, DecisionPolicy, DiagnoseData, DiagnoseOptions, OrderChoice};
use rand_distr::{Distribution, StandardNormal};

fn options(order: usize, max_steps: usize) -> DiagnoseOptions {
    DiagnoseOptions {
        order: OrderChoice::Fixed(order),
        max_steps,
        ..DiagnoseOptions::default()
    }
}

/// `linear` seed 48: 2nd order, input delay 2 besides the sample of ZOH
/// sampling, no feedthrough, so y(k) first responds to u(k − 3).
#[test]
fn a_dead_time_of_three_samples_is_found() {
    let knobs = Knobs::lengths(2000, 1000);
    let c = draw_with("linear", 48, &knobs).unwrap();
    assert_eq!(
        (c.input_delay, c.feedthrough),
        (2, false),
        "{}",
        c.description
    );
    let d = DiagnoseData::with_validation(c.train, c.validate).unwrap();
    let dg = diagnose(&d, &options(c.model_order, 0), None).unwrap();
    assert_eq!(
        dg.report.structure.delay,
        vec![3],
        "{}",
        dg.report.to_text()
    );
    assert_eq!(dg.report.baseline.delay, vec![3]);
}

/// The output of a generated linear system summed (an integrator after it),
/// plus white measurement noise at 1 % of the summed output's spread.
fn integrated(r: &Record, seed: u64) -> Record {
    let mut s = 0.0;
    let y: Vec<f64> = r
        .output
        .iter()
        .map(|v| {
            s += v;
            s
        })
        .collect();
    let sd = gb_core::metrics::std(&y);
    let mut rng = gb_core::rng::seeded(seed);
    let y = y
        .iter()
        .map(|v| {
            let e: f64 = StandardNormal.sample(&mut rng);
            v + 0.01 * sd * e
        })
        .collect();
    Record::new(
        r.input_names.clone(),
        r.output_name.clone(),
        r.inputs.clone(),
        y,
    )
    .unwrap()
}

#[test]
fn an_integrating_system_gets_the_integrating_baseline_and_it_predicts_better() {
    let knobs = Knobs {
        n_train: Some(3000),
        n_validate: Some(1500),
        noise_free: true,
        ..Knobs::default()
    };
    let c = draw_with("linear", 48, &knobs).unwrap();
    let d =
        DiagnoseData::with_validation(integrated(&c.train, 1), integrated(&c.validate, 2)).unwrap();
    let o = options(c.model_order, 0);
    let with = diagnose(&d, &o, None).unwrap().report;
    assert!(with.structure.integrating, "{}", with.to_text());
    assert!(with.baseline.integrating);
    assert_eq!(with.baseline.class, gb_model::INTEGRATING_CLASS);
    // the plain baseline: no ARX pole is ever this close to 1
    let plain_opts = DiagnoseOptions {
        policy: DecisionPolicy {
            integrator_pole: 1e-12,
            ..DecisionPolicy::default()
        },
        ..o
    };
    let plain = diagnose(&d, &plain_opts, None).unwrap().report;
    assert!(!plain.baseline.integrating);
    assert!(
        with.baseline.nrmse < 0.8 * plain.baseline.nrmse,
        "held-out NRMSE: integrating {} vs plain {}",
        with.baseline.nrmse,
        plain.baseline.nrmse
    );
}

/// 500 samples, 400 to train and 100 held out: the select block is too short
/// for the bootstrap, so decisions are made by blocked cross-validation over
/// the training record, and the diagnosis runs to a verdict.
#[test]
fn a_500_sample_record_is_diagnosed_by_cross_validation() {
    let knobs = Knobs::lengths(400, 100);
    let c = draw_with("hammerstein-odd", 3, &knobs).unwrap();
    assert_eq!((c.train.len(), c.validate.len()), (400, 100));
    let d = DiagnoseData::with_validation(c.train, c.validate).unwrap();
    let dg = diagnose(&d, &options(c.model_order, 2), None).unwrap();
    let r = &dg.report;
    assert!(
        r.data.decision.contains("cross-validation"),
        "{}",
        r.data.decision
    );
    assert_eq!(r.data.samples_validate + r.data.init_window, 100);
    assert!(!r.verdict.text.is_empty());
    assert!(r.final_model.nrmse.is_finite() && r.final_model.nrmse <= r.baseline.nrmse * 1.5);
}

/// Records of 200–300 training samples, decided by cross-validation: when
/// the diagnosis names a cause, its final model is not the baseline. (A
/// structure chosen inside the fit — LOLIMOT's number of leaves — once came
/// out as the linear baseline on the whole record after paying on the
/// folds: `nonlinearity` was named for a final model identical to the
/// baseline, saturation seed 5 at 200 samples.)
#[test]
fn a_cause_named_on_a_short_record_changes_the_model() {
    let mut named = 0;
    for (system, seed, n) in [
        ("saturation", 5, 200),
        ("duffing", 5, 200),
        ("saturation", 2, 300),
        ("backlash", 3, 300),
    ] {
        let g = gb_diagnose::systems::generate(system, seed, n, 400).unwrap();
        let d = DiagnoseData::with_validation(g.train, g.validate).unwrap();
        let dg = diagnose(&d, &options(2, 2), None).unwrap();
        let r = &dg.report;
        assert!(r.data.decision.contains("cross-validation"));
        if r.causes.is_empty() {
            continue;
        }
        named += 1;
        let (b, f) = (&r.baseline, &r.final_model);
        assert!(
            f.model != b.model && (f.nrmse - b.nrmse).abs() > 1e-4 * b.nrmse,
            "{system} {seed}: causes {:?} but the final model is the baseline\n{}",
            r.causes,
            r.to_text()
        );
    }
    assert!(named >= 2, "only {named} of 4 records got a cause");
}
