//! Diagnoses on the real benchmark data in `../shared/data` (or
//! `$GREYBOX_DATA`). Skipped with a notice when the folder is absent.
use gb_core::{CsvTable, Record};
use gb_diagnose::{diagnose, DiagnoseData, DiagnoseOptions};
use std::path::PathBuf;

fn data_dir() -> Option<PathBuf> {
    let default = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    gb_core::benchmark_data_dir(&default, "")
}

fn load(p: PathBuf) -> Record {
    let t = CsvTable::read(&p).expect("read");
    Record::from_table(&t, &["u".into()], Some("y")).expect("columns")
}

/// Diagnose `train` against `val` (`max_steps` steps) and require
/// `expected` as the first cause and a final NRMSE below 0.6x the baseline.
fn check(
    name: &str,
    train: Record,
    val: Record,
    expected: &str,
    max_steps: usize,
) -> gb_diagnose::Diagnosis {
    let data = DiagnoseData::with_validation(train, val).unwrap();
    let d = diagnose(
        &data,
        &DiagnoseOptions {
            max_steps,
            ..Default::default()
        },
        None,
    )
    .unwrap();
    eprintln!(
        "{name}: causes {:?}, NRMSE {:.4} -> {:.4}",
        d.report.causes, d.report.baseline.nrmse, d.report.final_model.nrmse
    );
    assert_eq!(d.report.cause_names().first().copied(), Some(expected));
    assert!(d.report.final_model.nrmse < 0.6 * d.report.baseline.nrmse);
    d
}

/// Bouc-Wen: the hysteretic benchmark must be diagnosed as `hysteresis`,
/// and with the default four steps the diagnosis must go on from the
/// Preisach extension to the hidden-state model (gb-model) and cut the
/// baseline error at least fivefold.
#[test]
fn bouc_wen_benchmark_is_hysteresis() {
    let Some(dir) = data_dir() else { return };
    let train = load(dir.join("bouc_wen/train_multisine_forgione.csv"));
    // drop the first period (transient) and keep two periods to bound the run time
    let train = train.slice(8192..8192 * 3);
    let val = load(dir.join("bouc_wen/test_multisine.csv"));
    let d = check("Bouc-Wen", train, val, "hysteresis", 4);
    assert_eq!(d.report.cause_names(), ["hysteresis"]);
    assert_eq!(
        d.model.dynamics.class(),
        "state-space",
        "no hidden-state model"
    );
    assert!(d.report.final_model.nrmse < 0.2 * d.report.baseline.nrmse);
    // the refined hidden-state model (8 sub-steps, levels 1-4) is kept:
    // 0.0128 without it, 0.0080 with it
    assert!(
        d.report.steps.iter().any(|s| s.accepted
            && s.extension
                .contains("more capacity for the hidden-state model")),
        "the hidden-state refinement was not kept"
    );
    assert!(
        d.report.final_model.nrmse < 0.0105,
        "validation NRMSE {}",
        d.report.final_model.nrmse
    );
}

/// Silverbox: the electronic Duffing oscillator must be diagnosed as
/// `nonlinearity`. Step 1 chooses the network with decision-tree weights;
/// step 2 replaces it by the polynomial on one more lag, which the
/// decision data cannot tell from it and which has at most half its
/// parameters (`poly-simpler`). Measured (20 000 training samples): the
/// tree network 0.0051 on the multisine test, 1.624 mV on the arrow (full,
/// init window 50: beyond the training amplitudes); the polynomial 0.0046
/// and 0.317 mV — its cubic terms hold where the network's outermost local
/// models go on linearly (issue 15's goal: 0.40 mV).
#[test]
fn silverbox_is_nonlinearity() {
    let Some(dir) = data_dir() else { return };
    let train = load(dir.join("silverbox/train_multisine.csv")).slice(0..20000);
    let val = load(dir.join("silverbox/test_multisine.csv"));
    let d = check("Silverbox", train, val, "nonlinearity", 2);
    let model = d.model.dynamics.describe();
    assert!(model.contains("polynomial NOE"), "{model}");
    assert!(
        d.report
            .steps
            .iter()
            .any(|s| s.accepted && s.iteration == 2 && s.extension.contains("simpler model")),
        "no simplification in step 2"
    );
    let arrow = load(dir.join("silverbox/test_arrow_full.csv"));
    let w = 50;
    let sim = d
        .model
        .dynamics
        .simulate(&arrow.inputs, gb_core::Init::Window(&arrow.output[..w]))
        .unwrap();
    let rmse = gb_core::metrics::rmse(&arrow.output[w..], &sim[w..]).unwrap();
    assert!(rmse < 4e-4, "arrow full RMSE {rmse:.3e} V");
    assert!(
        d.report.final_model.nrmse < 0.0049,
        "test NRMSE {}",
        d.report.final_model.nrmse
    );
}
