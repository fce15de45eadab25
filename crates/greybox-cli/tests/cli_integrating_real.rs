//! An integrating real system diagnosed as a user would (`$GREYBOX_DATA`,
//! default `../shared/data`; skipped with a notice when the folder is
//! absent unless `GREYBOX_REQUIRE_DATA` is set): the EMPS positioning rig
//! (motor force → position), its training file diagnosed, the saved model
//! simulated once on the official test file.
mod common;
use common::{run, scratch, simulated, text};
use std::path::{Path, PathBuf};

/// EMPS' training and test files (`None`, with a notice, when the data
/// folder is absent and not required) and a model and a simulation path
/// in a scratch folder named `tag`.
struct Emps {
    train: String,
    test: PathBuf,
    model: String,
    sim: PathBuf,
}

fn emps(tag: &str) -> Option<Emps> {
    let default = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    let dir = gb_core::benchmark_data_dir(&default, "emps")?;
    let d = scratch("greybox-cli", tag);
    let s = |p: &Path| p.to_str().unwrap().to_string();
    Some(Emps {
        train: s(&dir.join("emps/train.csv")),
        test: dir.join("emps/test.csv"),
        model: s(&d.join("m.gbm")),
        sim: d.join("sim.csv"),
    })
}

/// The first step on EMPS' increments (a velocity): the fed-back map of
/// the simulated output — a friction law of the velocity inside the loop —
/// is chosen on the training record alone, and the one-step model
/// simulates the pulses test at 1.64 mm (published LTI 5.53 mm, dynoNet
/// 2.64 mm; 1.94 mm while the increments models were trained for the
/// increments' error, before policy `integrated_criterion`). The bound is
/// dynoNet's. While the select block was simulated
/// on from the fit block, the integrator's accumulated drift made a
/// Hammerstein model win the step by a hair (select gains +0.829 against
/// +0.819): 5.86 mm, which fails it.
///
/// With the default four steps (as a user runs it) nothing is accepted
/// after it: the training record repeats one trajectory, and the network
/// the held-out runs prefer next parts from the friction law off the
/// trajectory (policy `repeat_shift_ratio`), so it no longer pays and no
/// other candidate of step 2 does. Before that rule the search accepted it
/// and order 3, and the pulses test came out at 16.4 mm.
#[test]
fn emps_diagnosis_keeps_the_friction_law_and_stops_before_the_trajectory_network() {
    let Some(Emps {
        train,
        test,
        model,
        sim,
    }) = emps("emps-first-step")
    else {
        return;
    };
    let o = run(&[
        "diagnose", &train, "--input", "u", "--output", "y", "--quiet", "--save", &model,
    ]);
    let (out, err) = text(&o);
    assert!(o.status.success(), "{out}\n{err}");
    let step = out
        .lines()
        .find(|l| l.starts_with("1 ") && l.contains(" yes "))
        .unwrap_or_else(|| panic!("no accepted step\n{out}"));
    assert!(
        step.contains("static map of the simulated output fed back"),
        "{step}"
    );
    // the training record is four runs of one trajectory: the decisions
    // line says that its held-out blocks repeat the fit block's input
    let dec = out
        .lines()
        .find(|l| l.starts_with("decisions:"))
        .unwrap_or("");
    assert!(
        dec.contains("the select block repeats the fit block's input"),
        "{dec}"
    );
    assert!(
        dec.contains("step 2: lolimot")
            && dec.contains("was not accepted: simulated on the fit block's input"),
        "{dec}"
    );
    assert!(
        !out.lines()
            .any(|l| l.starts_with("2 ") && l.contains(" yes ")),
        "{out}"
    );
    let fin = out.lines().find(|l| l.starts_with("final:")).unwrap_or("");
    assert!(fin.contains("integrating (pole at 1)"), "{fin}");
    assert!(!fin.contains("local model network"), "{fin}");
    let got = simulated(Path::new(&model), &test, &sim, 20, "RMSE ");
    eprintln!("EMPS, diagnosed: test RMSE {:.3} mm", 1e3 * got);
    assert!(got <= 2.64e-3, "test RMSE {got:.4e}\n{out}");
}

/// `greybox fit` without expert flags on EMPS: the order and delay chosen
/// on the training record as the diagnosis chooses its baseline's, and
/// the integrator with them — `linear+feedback` models the increments
/// (a friction law of the velocity fed back) and sums them
/// (`integrating=true`), which simulates the pulses test at 3.54 mm,
/// within the published linear model's 5.53 mm. Fitted to the position
/// itself (`integrating=false`, what `fit` did before) the plain linear
/// model gave 63.5 mm.
#[test]
fn emps_fit_without_flags_models_the_integrator() {
    let Some(Emps {
        train,
        test,
        model,
        sim,
    }) = emps("emps-fit")
    else {
        return;
    };
    let o = run(&[
        "fit",
        &train,
        "--input",
        "u",
        "--output",
        "y",
        "--model",
        "linear+feedback",
        "--quiet",
        "-o",
        &model,
    ]);
    let (out, err) = text(&o);
    assert!(o.status.success(), "{out}\n{err}");
    assert!(
        out.contains("the output integrates: the increments are modelled and summed")
            && out.contains("class: integrating"),
        "{out}"
    );
    let got = simulated(Path::new(&model), &test, &sim, 20, "RMSE ");
    eprintln!("EMPS, fit linear+feedback: test RMSE {:.3} mm", 1e3 * got);
    assert!(got <= 5.53e-3, "test RMSE {got:.4e}\n{out}");
}
