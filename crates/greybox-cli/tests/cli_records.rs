//! `greybox diagnose` on several training records (`--train FILE`
//! repeated): the report lists the records, and records with other
//! columns are a one-line error naming the file (exit 2).
mod common;
use common::run;
use std::path::{Path, PathBuf};

fn tmp(name: &str) -> PathBuf {
    common::scratch("greybox-records", name)
}

/// Rows `rows` of the CSV `from` (header kept) written to `to`.
fn rows(from: &Path, to: &Path, rows: std::ops::Range<usize>) {
    common::csv_rows(from, to, rows, None);
}

/// `greybox diagnose --train a --train b EXTRA --json json --quiet`.
fn diagnose_two((a, b): (&Path, &Path), extra: &[&str], json: &Path) -> std::process::Output {
    let mut args = vec![
        "diagnose",
        "--train",
        a.to_str().unwrap(),
        "--train",
        b.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    args.extend(["--json", json.to_str().unwrap(), "--quiet"]);
    run(&args)
}

#[test]
fn two_training_records_are_listed_in_the_report() {
    let d = tmp("two");
    let ds = d.to_str().unwrap();
    let o = run(&[
        "generate",
        "msd-linear",
        "-o",
        ds,
        "--seed",
        "2",
        "--samples",
        "2000",
        "--validate-samples",
        "1000",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (a, b) = (d.join("a.csv"), d.join("b.csv"));
    rows(&d.join("train.csv"), &a, 0..1200);
    rows(&d.join("train.csv"), &b, 1200..2000);
    let (v, json) = (d.join("validate.csv"), d.join("r.json"));
    let o = diagnose_two(
        (&a, &b),
        &["--validate", v.to_str().unwrap(), "--max-steps", "1"],
        &json,
    );
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(
        o.status.success(),
        "{}\n{out}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(out.contains("records: "), "{out}");
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let recs = r["data"]["records"].as_array().expect("records list");
    let got: Vec<(String, u64, u64, u64)> = recs
        .iter()
        .map(|x| {
            (
                x["name"]
                    .as_str()
                    .unwrap()
                    .rsplit('/')
                    .next()
                    .unwrap()
                    .to_string(),
                x["fit"].as_u64().unwrap(),
                x["select"].as_u64().unwrap(),
                x["report"].as_u64().unwrap(),
            )
        })
        .collect();
    assert_eq!(
        got,
        vec![
            ("a.csv".to_string(), 900, 300, 0),
            ("b.csv".to_string(), 600, 200, 0),
            ("validate.csv".to_string(), 0, 0, 1000),
        ]
    );
    assert_eq!(r["data"]["samples_select"].as_u64(), Some(500));
    // without --validate the last record is the report data, held out whole
    let o = run(&[
        "diagnose",
        a.to_str().unwrap(),
        "--train",
        b.to_str().unwrap(),
        "--max-steps",
        "1",
        "--json",
        json.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let recs = r["data"]["records"].as_array().expect("records list");
    let got: Vec<(u64, u64, u64)> = recs
        .iter()
        .map(|x| {
            let n = |k: &str| x[k].as_u64().unwrap();
            (n("fit"), n("select"), n("report"))
        })
        .collect();
    assert_eq!(got, vec![(900, 300, 0), (0, 0, 800)]);
    // the model saved: the chain refitted on both records whole, the
    // held-out one included
    let decision = r["data"]["decision"].as_str().unwrap_or_default();
    assert!(
        decision.contains("refitted on all 2 training records whole (2000 samples, the held-out last record included)"),
        "{decision}"
    );
}

#[test]
fn a_record_with_other_columns_is_one_line_naming_the_file() {
    let d = tmp("bad");
    let a = d.join("a.csv");
    let b = d.join("b.csv");
    let mut ta = String::from("u,y\n");
    let mut tb = String::from("u,w,y\n");
    for k in 0..400 {
        let u = ((k * 37) % 11) as f64 - 5.0;
        ta.push_str(&format!("{u},{}\n", ((k * 13) % 7) as f64));
        tb.push_str(&format!(
            "{u},{},{}\n",
            (k % 3) as f64,
            ((k * 13) % 7) as f64
        ));
    }
    std::fs::write(&a, ta).unwrap();
    std::fs::write(&b, tb).unwrap();
    let json = d.join("r.json");
    let o = diagnose_two((&a, &b), &[], &json);
    let e = String::from_utf8_lossy(&o.stderr).to_string();
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(!e.contains("panicked"), "{e}");
    assert_eq!(e.trim_end().lines().count(), 1, "not one line: {e}");
    assert!(e.contains("b.csv"), "{e}");
    assert!(!json.exists());
}
