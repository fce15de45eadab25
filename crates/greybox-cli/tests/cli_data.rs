//! The binary on data questions: `fit --order auto` (order and input delay
//! read from the training data), streaming `simulate` from standard input,
//! and several outputs (`--output` repeated: one model per output).
mod common;
use common::{bin, run};
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};
use std::path::{Path, PathBuf};

fn tmp(name: &str) -> PathBuf {
    common::scratch("greybox-data", name)
}

fn ok(args: &[&str]) -> String {
    let o = run(args);
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(
        o.status.success(),
        "args {args:?}: {}\n{out}",
        String::from_utf8_lossy(&o.stderr)
    );
    out
}

/// Input held for 1..=8 samples at normal levels (seeded), length `n`.
fn steps_input(n: usize, seed: u64) -> Vec<f64> {
    let mut r = gb_core::rng::seeded(seed);
    let mut u = Vec::with_capacity(n);
    while u.len() < n {
        let v: f64 = StandardNormal.sample(&mut r);
        let hold = r.random_range(1..=8);
        u.extend(std::iter::repeat_n(v, hold));
    }
    u.truncate(n);
    u
}

/// y(k) = 2.3031 y(k−1) − 1.9853 y(k−2) + 0.6503 y(k−3)
///        + u(k−3) + 0.5 u(k−4) + 0.25 u(k−5) + white noise (1 % of y's
/// spread): poles 0.9 and 0.85·e^{±0.6i}, the input acts after 3 samples.
fn third_order_delay_3(path: &Path, n: usize, seed: u64) {
    let u = steps_input(n, seed);
    let mut y = vec![0.0; n];
    let a = [2.303071, -1.985264, 0.65025];
    let b = [1.0, 0.5, 0.25];
    for k in 5..n {
        y[k] = a[0] * y[k - 1] + a[1] * y[k - 2] + a[2] * y[k - 3];
        for (j, bj) in b.iter().enumerate() {
            y[k] += bj * u[k - 3 - j];
        }
    }
    let sd = std_of(&y);
    let mut r = gb_core::rng::seeded(seed + 100);
    let mut text = String::from("u,y\n");
    for k in 0..n {
        let e: f64 = StandardNormal.sample(&mut r);
        text.push_str(&format!("{},{}\n", u[k], y[k] + 0.01 * sd * e));
    }
    std::fs::write(path, text).unwrap();
}

fn std_of(x: &[f64]) -> f64 {
    let m = x.iter().sum::<f64>() / x.len() as f64;
    (x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / x.len() as f64).sqrt()
}

/// The order and delay of the `order auto:` line of `fit`'s output.
fn chosen(out: &str) -> (usize, String) {
    let line = out
        .lines()
        .find(|l| l.starts_with("order auto:"))
        .unwrap_or_else(|| panic!("no 'order auto:' line in\n{out}"));
    let order = line
        .split("order ")
        .nth(2)
        .and_then(|s| s.split(',').next())
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or_else(|| panic!("{line}"));
    let delay = line
        .split("delay ")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .unwrap_or_else(|| panic!("{line}"))
        .to_string();
    (order, delay)
}

#[test]
fn fit_order_auto_finds_order_and_delay() {
    let d = tmp("auto");
    let f = d.join("third.csv");
    third_order_delay_3(&f, 3000, 7);
    let m = d.join("m.gbm");
    let out = ok(&[
        "fit",
        f.to_str().unwrap(),
        "--order",
        "auto",
        "-o",
        m.to_str().unwrap(),
    ]);
    assert_eq!(chosen(&out), (3, "[3]".to_string()), "{out}");
    // the candidates' scores are printed, and the fit used the choice
    assert!(
        out.contains("order chosen on the training data (1: "),
        "{out}"
    );
    assert!(out.contains("spec: linear:order=3,delay=3"), "{out}");
    assert!(m.exists());

    // the two-mass system is of order 4
    let ds = d.to_str().unwrap();
    ok(&[
        "generate",
        "two-mass",
        "-o",
        ds,
        "--seed",
        "4",
        "--samples",
        "3000",
        "--validate-samples",
        "500",
    ]);
    let out = ok(&[
        "fit",
        d.join("train.csv").to_str().unwrap(),
        "--order",
        "auto",
        "--input",
        "u",
        "--output",
        "y",
        "-o",
        m.to_str().unwrap(),
    ]);
    assert_eq!(chosen(&out).0, 4, "{out}");
    // a spec without an order option is refused before any fit
    let o = run(&[
        "fit",
        f.to_str().unwrap(),
        "--model",
        "wiener-hammerstein",
        "--order",
        "auto",
        "-o",
        d.join("wh.gbm").to_str().unwrap(),
    ]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(
        e.contains("no order option") && e.lines().count() == 1,
        "{e}"
    );
    assert!(!d.join("wh.gbm").exists());
}

/// `simulate MODEL -` with `input` on standard input: exit code, stdout
/// and stderr.
fn stream(model: &Path, input: &str) -> (Option<i32>, String, String) {
    use std::io::Write;
    let mut c = bin()
        .args(["simulate", model.to_str().unwrap(), "-"])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = c.stdin.take().unwrap();
    // written beside the reading (a long input would fill both pipes); a
    // closed pipe (the binary stopped at an error) is no test failure
    let input = input.to_string();
    let writer = std::thread::spawn(move || {
        let _ = stdin.write_all(input.as_bytes());
    });
    let o = c.wait_with_output().unwrap();
    writer.join().unwrap();
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stdout).to_string(),
        String::from_utf8_lossy(&o.stderr).to_string(),
    )
}

#[test]
fn simulate_streams_stdin_rows_as_the_batch_simulation() {
    use std::io::{BufRead, BufReader, Write};
    let d = tmp("stream");
    let f = d.join("third.csv");
    third_order_delay_3(&f, 1500, 3);
    let m = d.join("m.gbm");
    ok(&[
        "fit",
        f.to_str().unwrap(),
        "--order",
        "3",
        "--model",
        "linear:delay=3",
        "-o",
        m.to_str().unwrap(),
    ]);
    // the batch simulation of the first 300 rows
    let text = std::fs::read_to_string(&f).unwrap();
    let part: Vec<&str> = text.lines().take(301).collect();
    let pf = d.join("part.csv");
    std::fs::write(&pf, part.join("\n") + "\n").unwrap();
    let sim = d.join("sim.csv");
    ok(&[
        "simulate",
        m.to_str().unwrap(),
        pf.to_str().unwrap(),
        "-o",
        sim.to_str().unwrap(),
    ]);
    let batch = std::fs::read_to_string(&sim).unwrap();
    let batch: Vec<&str> = batch.lines().collect();
    assert_eq!(batch.len(), 301);

    // streamed: one row in, then its simulated row must come out before
    // the next row is written (a reader thread; a 120 s watchdog turns a
    // missing flush into a failure instead of a hang)
    let mut c = bin()
        .args(["simulate", m.to_str().unwrap(), "-"])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = c.stdin.take().unwrap();
    let stdout = c.stdout.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    let reader = std::thread::spawn(move || {
        for l in BufReader::new(stdout).lines() {
            if tx.send(l.unwrap()).is_err() {
                break;
            }
        }
    });
    let wait = std::time::Duration::from_secs(120);
    writeln!(stdin, "{}", part[0]).unwrap();
    for (k, row) in part[1..].iter().enumerate() {
        writeln!(stdin, "{row}").unwrap();
        stdin.flush().unwrap();
        if k == 0 {
            let header = rx.recv_timeout(wait).expect("header after the first row");
            assert_eq!(header, batch[0]);
        }
        let line = rx
            .recv_timeout(wait)
            .unwrap_or_else(|_| panic!("no output for row {} before the next row", k + 2));
        assert_eq!(line, batch[k + 1], "row {}", k + 2);
    }
    drop(stdin);
    assert!(c.wait().unwrap().success());
    reader.join().unwrap();
    // bad input keeps the contract: one line naming row and column, exit 2
    for (input, needle) in [
        (
            "u,y\n1,2\n0.5,1\nabc,1\n",
            "stdin: row 4, column 'u': 'abc' is not a number",
        ),
        (
            "u,y\n1,2\n1\n",
            "stdin: row 3 has 1 fields, the header has 2",
        ),
        ("x,y\n1,2\n", "stdin: no column named 'u' (columns: x,y)"),
        (
            "u,y\n1,inf\n",
            "stdin: row 2, column 'y': value inf is not finite",
        ),
        ("", "stdin: file is empty"),
        (
            "1,2\n3,4\n",
            "stdin: row 1: header field 1 is the number '1'",
        ),
    ] {
        let (code, _, e) = stream(&m, input);
        assert_eq!(code, Some(2), "{input:?}: {e}");
        assert!(!e.contains("panicked"), "{e}");
        assert!(e.contains(needle), "{input:?}: expected '{needle}' in {e}");
        assert_eq!(e.trim_end().lines().count(), 1, "{e}");
    }
    // the rows before a bad one were already written
    let (_, out, _) = stream(&m, "u,y\n1,2\n0.5,1\nabc,1\n");
    assert_eq!(out.lines().count(), 3, "{out}");
    // the block and polynomial classes stream as they simulate
    for spec in ["hammerstein:order=3,delay=3", "wiener-hammerstein"] {
        let mb = d.join("block.gbm");
        ok(&[
            "fit",
            f.to_str().unwrap(),
            "--model",
            spec,
            "-o",
            mb.to_str().unwrap(),
        ]);
        ok(&[
            "simulate",
            mb.to_str().unwrap(),
            pf.to_str().unwrap(),
            "-o",
            sim.to_str().unwrap(),
        ]);
        let (code, streamed, e) = stream(&mb, &(part.join("\n") + "\n"));
        assert_eq!(code, Some(0), "{spec}: {e}");
        assert_eq!(streamed, std::fs::read_to_string(&sim).unwrap(), "{spec}");
    }
}

/// One input, two outputs: `y_lin` a linear second-order response, `y_sat`
/// the same kind of dynamics behind a saturation of the input
/// (tanh(1.5 u)); white noise at 1 % of each output's spread.
fn two_outputs(path: &Path, n: usize, seed: u64) {
    let u = steps_input(n, seed);
    let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
    for k in 2..n {
        a[k] = 1.5 * a[k - 1] - 0.7 * a[k - 2] + 0.5 * u[k - 1] + 0.3 * u[k - 2];
        let s = |x: f64| (1.5 * x).tanh();
        b[k] = 1.2 * b[k - 1] - 0.5 * b[k - 2] + s(u[k - 1]) + 0.5 * s(u[k - 2]);
    }
    let (sa, sb) = (std_of(&a), std_of(&b));
    let mut r = gb_core::rng::seeded(seed + 100);
    let mut text = String::from("u,y_lin,y_sat\n");
    for k in 0..n {
        let (ea, eb): (f64, f64) = (StandardNormal.sample(&mut r), StandardNormal.sample(&mut r));
        text.push_str(&format!(
            "{},{},{}\n",
            u[k],
            a[k] + 0.01 * sa * ea,
            b[k] + 0.01 * sb * eb
        ));
    }
    std::fs::write(path, text).unwrap();
}

/// The values of column `name` of a CSV text, as printed.
fn column<'a>(csv: &'a str, name: &str) -> Vec<&'a str> {
    let mut lines = csv.lines();
    let j = lines
        .next()
        .unwrap()
        .split(',')
        .position(|c| c == name)
        .unwrap_or_else(|| panic!("no column {name}"));
    lines.map(|l| l.split(',').nth(j).unwrap()).collect()
}

#[test]
fn two_outputs_are_fitted_simulated_and_diagnosed_one_model_each() {
    let d = tmp("mimo");
    let f = d.join("two.csv");
    two_outputs(&f, 3000, 11);
    let fs = f.to_str().unwrap();
    let path = |n: &str| d.join(n).to_str().unwrap().to_string();
    // fit: one linear model per output; the other output is no input
    let out = ok(&[
        "fit",
        fs,
        "--output",
        "y_lin",
        "--output",
        "y_sat",
        "-o",
        &path("m.gbm"),
    ]);
    assert!(out.contains("inputs u -> outputs y_lin,y_sat"), "{out}");
    for (o, file) in [("y_lin", "lin.gbm"), ("y_sat", "sat.gbm")] {
        ok(&["fit", fs, "--input", "u", "--output", o, "-o", &path(file)]);
    }
    // simulate writes one column per output, each the per-output model's
    ok(&["simulate", &path("m.gbm"), fs, "-o", &path("sim.csv")]);
    let sim = std::fs::read_to_string(d.join("sim.csv")).unwrap();
    assert_eq!(
        sim.lines().next().unwrap(),
        "u,y_lin,y_sat,y_lin_sim,y_sat_sim"
    );
    for (o, file) in [("y_lin", "lin.gbm"), ("y_sat", "sat.gbm")] {
        let one = path(&format!("{o}.csv"));
        ok(&["simulate", &path(file), fs, "-o", &one]);
        let one = std::fs::read_to_string(&one).unwrap();
        assert_eq!(
            column(&sim, &format!("{o}_sim")),
            column(&one, "y_sim"),
            "{o}"
        );
    }
    // streamed, the two-output model gives the batch file
    let (code, streamed, e) = stream(&d.join("m.gbm"), &std::fs::read_to_string(&f).unwrap());
    assert_eq!(code, Some(0), "{e}");
    assert_eq!(streamed, sim);

    // diagnose: the linear output gets no cause, the saturating one
    // `nonlinearity`; per-output JSON sections, one stacked model
    let out = ok(&[
        "diagnose",
        fs,
        "--output",
        "y_lin",
        "--output",
        "y_sat",
        "--max-steps",
        "1",
        "--json",
        &path("r.json"),
        "--report",
        &path("r.html"),
        "--save",
        &path("final.gbm"),
    ]);
    // one HTML document: a summary table linking each output's section,
    // every figure id once
    let html = std::fs::read_to_string(d.join("r.html")).unwrap();
    assert_eq!(html.matches("<!DOCTYPE html>").count(), 1);
    assert_eq!(html.matches("</html>").count(), 1);
    for (o, name) in [(1, "y_lin"), (2, "y_sat")] {
        assert!(
            html.contains(&format!("<a href=\"#output-{o}\">{name}</a>")),
            "{name}"
        );
        assert!(html.contains(&format!("<section id=\"output-{o}\">")));
    }
    let ids: Vec<&str> = html
        .split("id=\"")
        .skip(1)
        .filter_map(|s| s.split('"').next())
        .collect();
    let unique: std::collections::HashSet<&&str> = ids.iter().collect();
    assert!(ids.len() > 4, "{ids:?}");
    assert_eq!(unique.len(), ids.len(), "duplicate ids: {ids:?}");
    assert!(
        out.contains("== output y_lin ==") && out.contains("== output y_sat =="),
        "{out}"
    );
    assert!(out.contains("output y_lin: causes: none"), "{out}");
    assert!(out.contains("output y_sat: causes: nonlinearity"), "{out}");
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("r.json")).unwrap()).unwrap();
    let s = j["outputs"].as_array().unwrap();
    assert_eq!(s.len(), 2);
    assert_eq!(s[0]["output"], "y_lin");
    assert_eq!(s[0]["report"]["causes"], serde_json::json!([]));
    assert_eq!(s[1]["output"], "y_sat");
    assert_eq!(
        s[1]["report"]["causes"],
        serde_json::json!(["nonlinearity"])
    );
    ok(&["simulate", &path("final.gbm"), fs, "-o", &path("final.csv")]);
    let fin = std::fs::read_to_string(d.join("final.csv")).unwrap();
    assert!(fin.starts_with("u,y_lin,y_sat,y_lin_sim,y_sat_sim\n"));

    // a repeated output and a model file with several outputs are errors
    for (args, needle) in [
        (
            vec!["fit", fs, "--output", "y_lin", "--output", "y_lin", "-o"],
            "given twice",
        ),
        (
            vec!["fit", fs, "--output", "nope", "--output", "y_lin", "-o"],
            "no column named 'nope'",
        ),
    ] {
        let mut args = args.clone();
        let bad = path("bad.gbm");
        args.push(&bad);
        let o = run(&args);
        let e = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{e}");
        assert!(
            e.contains(needle) && e.trim_end().lines().count() == 1,
            "{e}"
        );
        assert!(!d.join("bad.gbm").exists());
    }
}
