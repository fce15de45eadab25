//! `greybox fit --model state-space[+preisach]` and `simulate` of the
//! gb-model file, and its bad-input cases.
mod common;
use common::run;
use std::path::PathBuf;

fn tmp(name: &str) -> PathBuf {
    common::scratch("greybox-ss", name)
}

#[test]
fn state_space_fit_then_simulate() {
    let d = tmp("fit");
    let ds = d.to_str().unwrap();
    let o = run(&[
        "generate",
        "shock-absorber",
        "-o",
        ds,
        "--samples",
        "2000",
        "--validate-samples",
        "800",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let model = d.join("m.gbs");
    let o = run(&[
        "fit",
        d.join("train.csv").to_str().unwrap(),
        "--model",
        "state-space+preisach",
        "-o",
        model.to_str().unwrap(),
    ]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.contains("sparse wavelet state space"), "{out}");
    assert!(out.contains("path OutputError"), "{out}");
    let sim = d.join("sim.csv");
    let o = run(&[
        "simulate",
        model.to_str().unwrap(),
        d.join("validate.csv").to_str().unwrap(),
        "-o",
        sim.to_str().unwrap(),
    ]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let nrmse: f64 = out
        .split("NRMSE ")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .expect("NRMSE printed");
    assert!(nrmse < 0.25, "validation NRMSE {nrmse}");
    assert!(std::fs::read_to_string(&sim)
        .unwrap()
        .starts_with("u,y,y_sim"));
    // an unknown variant is a one-line error with exit code 2, no file
    let bad = d.join("bad.gbs");
    let o = run(&[
        "fit",
        d.join("train.csv").to_str().unwrap(),
        "--model",
        "state-space+foo",
        "-o",
        bad.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("state-space+foo"));
    assert!(!bad.exists());
}

fn nrmse_of(out: &str) -> f64 {
    out.split("NRMSE ")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .expect("NRMSE printed")
}

/// `diagnose` ends on a Bouc-Wen spring in a model with a hidden hysteretic
/// state (the mechanical grey-box model or the hidden-state model); the
/// saved model (format 3) and the
/// `state-space+hysteresis` fit both simulate the validation record with
/// the initial state estimated from the init window, near the noise floor.
#[test]
fn diagnose_chooses_the_hidden_state_model_and_it_reloads() {
    let d = tmp("diag");
    let ds = d.to_str().unwrap();
    let o = run(&["generate", "bouc-wen", "-o", ds, "--seed", "2"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (train, val) = (d.join("train.csv"), d.join("validate.csv"));
    let gbm = d.join("m.gbm");
    let o = run(&[
        "diagnose",
        train.to_str().unwrap(),
        "--validate",
        val.to_str().unwrap(),
        "--save",
        gbm.to_str().unwrap(),
    ]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // a hidden hysteretic state inside the dynamics: gb-model's wavelet
    // state space, or the mechanical grey-box model with a Bouc–Wen state
    assert!(
        out.contains("hidden-state model (gb-model)")
            || out.contains("a mechanical grey-box model"),
        "{out}"
    );
    assert!(
        out.contains("final: sparse wavelet state space")
            || out.contains("final: physics model 'mechanical-template': 3 states"),
        "{out}"
    );
    let sim = d.join("sim.csv");
    let o = run(&[
        "simulate",
        gbm.to_str().unwrap(),
        val.to_str().unwrap(),
        "-o",
        sim.to_str().unwrap(),
        "--init-window",
        "50",
    ]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let e_diag = nrmse_of(&out);
    // the generated record's noise floor is 0.024
    assert!(e_diag < 0.03, "validation NRMSE {e_diag}");
    // the same class from `fit`, against a linear fit
    let gbs = d.join("m.gbs");
    let o = run(&[
        "fit",
        train.to_str().unwrap(),
        "--model",
        "state-space+hysteresis",
        "-o",
        gbs.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let lin = d.join("lin.gbm");
    let o = run(&[
        "fit",
        train.to_str().unwrap(),
        "--model",
        "linear",
        "-o",
        lin.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut e = vec![];
    for m in [&gbs, &lin] {
        let o = run(&[
            "simulate",
            m.to_str().unwrap(),
            val.to_str().unwrap(),
            "-o",
            sim.to_str().unwrap(),
            "--init-window",
            "50",
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        e.push(nrmse_of(&String::from_utf8_lossy(&o.stdout)));
    }
    assert!(
        e[0] < 0.03 && e[0] < 0.2 * e[1],
        "hidden state {} vs linear {}",
        e[0],
        e[1]
    );
    // --init-window longer than the record: one-line error, no output file
    let sim2 = d.join("sim2.csv");
    let o = run(&[
        "simulate",
        gbs.to_str().unwrap(),
        val.to_str().unwrap(),
        "-o",
        sim2.to_str().unwrap(),
        "--init-window",
        "99999",
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(!sim2.exists());
    // an absurd order: a one-line error, no model file
    let bad = d.join("bad.gbs");
    let o = run(&[
        "fit",
        train.to_str().unwrap(),
        "--model",
        "state-space+hysteresis",
        "--order",
        "99",
        "-o",
        bad.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("order=99: a whole number in 1..=8"));
    assert!(!bad.exists());
}

/// `--model state-space+damper` on 2 s of the Dyke MR damper test (real
/// data, skipped without it), simulated on the 2 s after the first 3 s
/// with a 50-sample init window: ≥ 4× better than the CLI's linear model
/// on the same inputs (measured NRMSE 0.102 against 0.457; trained on 3 s,
/// 0.083). Bad inputs: a one-line error, no model file.
#[test]
fn damper_fit_then_simulate_on_the_mr_damper_record() {
    let data = std::env::var_os("GREYBOX_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    let src = data.join("mr_damper_dyke_nees/ranran_50.csv");
    if !src.is_file() {
        eprintln!(
            "damper test skipped: {} not found (set GREYBOX_DATA)",
            src.display()
        );
        return;
    }
    let d = tmp("damper");
    let text = std::fs::read_to_string(&src).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let (train, test) = (d.join("train.csv"), d.join("test.csv"));
    std::fs::write(&train, lines[..6001].join("\n") + "\n").unwrap();
    std::fs::write(
        &test,
        [&[lines[0]], &lines[9001..15001]].concat().join("\n") + "\n",
    )
    .unwrap();
    let io = [
        "--input", "D", "--input", "V", "--input", "Y", "--input", "A", "--output", "F",
    ];
    let fit_sim = |spec: &[&str], file: &str| -> f64 {
        let model = d.join(file);
        let mut args = vec!["fit", train.to_str().unwrap()];
        args.extend_from_slice(spec);
        args.extend_from_slice(&io);
        args.extend_from_slice(&["-o", model.to_str().unwrap()]);
        let o = run(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let o = run(&[
            "simulate",
            model.to_str().unwrap(),
            test.to_str().unwrap(),
            "-o",
            d.join("sim.csv").to_str().unwrap(),
            "--init-window",
            "50",
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        nrmse_of(&String::from_utf8_lossy(&o.stdout))
    };
    let e = fit_sim(
        &["--model", "state-space+damper", "--resonances", "150,120"],
        "mr.gbs",
    );
    let e_lin = fit_sim(&["--model", "linear", "--order", "2"], "lin.gbm");
    assert!(e < e_lin / 4.0, "damper {e} vs linear {e_lin}");
    // bad input: two inputs, a bad frequency, a flag for another model
    let bad = d.join("bad.gbs");
    for args in [
        vec![
            "--model",
            "state-space+damper",
            "--input",
            "D",
            "--input",
            "V",
            "--output",
            "F",
        ],
        vec![
            "--model",
            "state-space+damper",
            "--input",
            "D",
            "--input",
            "V",
            "--input",
            "Y",
            "--output",
            "F",
            "--resonances",
            "150,x",
        ],
        vec![
            "--model", "lmn", "--input", "D", "--output", "F", "--ridge", "3",
        ],
    ] {
        let mut a = vec!["fit", train.to_str().unwrap()];
        a.extend_from_slice(&args);
        a.extend_from_slice(&["-o", bad.to_str().unwrap()]);
        let o = run(&a);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(!bad.exists());
    }
}
