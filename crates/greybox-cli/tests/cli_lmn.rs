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

/// Polynomial local models, dead time, partition on y(k−1) and BIC from the
/// command line (the Silverbox models of docs/results.md are fitted this way),
/// and their bad values rejected with one line and exit code 2.
#[test]
fn fit_lmn_degree_dead_time_partition_criterion() {
    let d: PathBuf = std::env::temp_dir().join(format!("gb-cli-lmn2-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    let ds = d.to_str().unwrap();
    let o = run(&["generate", "duffing", "-o", ds, "--samples", "2000"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let train = d.join("train.csv");
    let model = d.join("p.gbm");
    let args = |extra: &[&str]| -> Vec<String> {
        let mut v: Vec<String> = ["fit", train.to_str().unwrap(), "--model", "lmn"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        v.extend(extra.iter().map(|s| s.to_string()));
        v.extend(["-o".to_string(), model.to_str().unwrap().to_string()]);
        v
    };
    let ok = args(&[
        "--degree",
        "3",
        "--dead-time",
        "0",
        "--partition",
        "y1",
        "--criterion",
        "bic",
        "--max-leaves",
        "2",
    ]);
    let o = run(&ok.iter().map(String::as_str).collect::<Vec<_>>());
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.contains("degree 3"), "{out}");
    assert!(out.contains("u1[0, 1]"), "dead time 0: {out}");
    assert!(out.contains("z = 1 regressors"), "partition y1: {out}");
    assert!(out.contains("Bic"), "criterion: {out}");
    std::fs::remove_file(&model).unwrap();
    for (flag, value, needle) in [
        ("--degree", "4", "--degree must be 1, 2 or 3"),
        ("--criterion", "magic", "--criterion must be aicc or bic"),
        ("--partition", "z9", "--partition must be all or y1"),
        ("--dead-time", "100", "--dead-time must be at most 64"),
    ] {
        let bad = args(&[flag, value]);
        let o = run(&bad.iter().map(String::as_str).collect::<Vec<_>>());
        let e = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{flag} {value}: {e}");
        assert!(
            e.contains(needle) && e.trim_end().lines().count() == 1,
            "{e}"
        );
        assert!(!model.exists(), "no model file after a bad flag");
    }
    let _ = std::fs::remove_dir_all(&d);
}
