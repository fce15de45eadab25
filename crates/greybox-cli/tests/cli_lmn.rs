//! `greybox fit --model lmn` with the options of the full local model network.
use std::path::PathBuf;
use std::process::Command;

fn run(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_greybox"))
        .args(args)
        .output()
        .expect("run greybox")
}

#[test]
fn fit_lmn_tree_oblique_pruned_then_simulate() {
    let d: PathBuf = std::env::temp_dir().join(format!("gb-cli-lmn-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    let ds = d.to_str().unwrap();
    let o = run(&[
        "generate",
        "saturation",
        "-o",
        ds,
        "--samples",
        "2000",
        "--validate-samples",
        "1000",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let train = d.join("train.csv");
    let val = d.join("validate.csv");
    let model = d.join("m.gbm");
    let o = run(&[
        "fit",
        train.to_str().unwrap(),
        "--model",
        "lmn",
        "--weights",
        "tree",
        "--splits",
        "oblique",
        "--prune",
        "--focus",
        "simulation",
        "--max-leaves",
        "4",
        "-o",
        model.to_str().unwrap(),
    ]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        out.contains("decision-tree sigmoid") && out.contains("leaves:"),
        "{out}"
    );
    let sim = d.join("sim.csv");
    let o = run(&[
        "simulate",
        model.to_str().unwrap(),
        val.to_str().unwrap(),
        "-o",
        sim.to_str().unwrap(),
        "--init-window",
        "20",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("NRMSE"));
    // bad option values: one line, exit code 2, no model written
    let bad = d.join("bad.gbm");
    for args in [
        vec!["--model", "lmn", "--weights", "cubes"],
        vec!["--model", "lmn", "--splits", "round"],
        vec!["--model", "lmn", "--focus", "everything"],
        vec!["--model", "lmn", "--max-leaves", "0"],
        vec!["--model", "linear", "--prune"],
    ] {
        let mut a = vec!["fit", train.to_str().unwrap(), "-o", bad.to_str().unwrap()];
        a.extend(args.iter());
        let o = run(&a);
        assert_eq!(o.status.code(), Some(2), "{args:?}");
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(
            e.starts_with("greybox: error:") && e.lines().count() == 1,
            "{e}"
        );
        assert!(!bad.exists());
    }
    let _ = std::fs::remove_dir_all(&d);
}
