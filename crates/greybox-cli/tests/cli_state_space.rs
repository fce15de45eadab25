//! `greybox fit --model state-space[+preisach]` and `simulate` of the
//! gb-model file, and its bad-input cases.
use std::path::PathBuf;
use std::process::{Command, Output};

fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_greybox"))
        .args(args)
        .output()
        .expect("run greybox")
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("greybox-ss-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
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
