//! The `greybox` binary as a user runs it: the workflow, and bad input
//! giving a one-line error with exit code 2, no panic and no output file.
mod common;
use common::{bin, run};
use std::path::{Path, PathBuf};
use std::process::Output;

fn tmp(name: &str) -> PathBuf {
    common::scratch("greybox-cli", name)
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).to_string()
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).to_string()
}

/// A failing call: exit code 2, exactly one line on stderr that contains
/// `needle`, no panic, and `out` not created.
fn assert_bad(args: &[&str], needle: &str, out: &Path) {
    let o = run(args);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "args {args:?}: stderr {e}");
    assert!(!e.contains("panicked"), "panic: {e}");
    assert!(
        e.contains(needle),
        "args {args:?}: expected '{needle}' in: {e}"
    );
    assert_eq!(e.trim_end().lines().count(), 1, "not one line: {e}");
    assert!(!out.exists(), "partial output {} written", out.display());
}

fn write(path: &Path, text: &str) {
    std::fs::write(path, text).unwrap();
}

#[test]
fn generate_fit_simulate_diagnose_round_trip() {
    let d = tmp("flow");
    let ds = d.to_str().unwrap();
    let o = run(&[
        "generate",
        "two-mass",
        "-o",
        ds,
        "--seed",
        "4",
        "--samples",
        "3000",
        "--validate-samples",
        "1500",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let train = d.join("train.csv");
    let val = d.join("validate.csv");
    assert!(train.exists() && val.exists() && d.join("truth.json").exists());
    // fit order 4 (the true order) and simulate on validation data
    let model = d.join("m.gbm");
    let o = run(&[
        "fit",
        train.to_str().unwrap(),
        "--model",
        "linear",
        "--order",
        "4",
        "--input",
        "u",
        "--output",
        "y",
        "-o",
        model.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let sim = d.join("sim.csv");
    let o = run(&[
        "simulate",
        model.to_str().unwrap(),
        val.to_str().unwrap(),
        "-o",
        sim.to_str().unwrap(),
        "--init-window",
        "50",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = std::fs::read_to_string(&sim).unwrap();
    assert!(text.starts_with("u,y,y_sim\n"), "{}", &text[..40]);
    let out = stdout(&o);
    let nrmse: f64 = out
        .split("NRMSE ")
        .nth(1)
        .unwrap()
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap();
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("truth.json")).unwrap()).unwrap();
    let floor = truth["noise_floor_nrmse"].as_f64().unwrap();
    assert!(
        nrmse < 2.0 * floor,
        "order-4 model NRMSE {nrmse} vs noise floor {floor}"
    );
    // diagnose with the engineer's order 2 finds the missing dynamics
    let json = d.join("report.json");
    let saved = d.join("final.gbm");
    let o = run(&[
        "diagnose",
        train.to_str().unwrap(),
        "--validate",
        val.to_str().unwrap(),
        "--json",
        json.to_str().unwrap(),
        "--save",
        saved.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(r["version"], 3);
    assert_eq!(r["data"]["inputs"][0], "u");
    assert_eq!(r["data"]["output"], "y");
    assert_eq!(r["causes"][0], "dynamics", "{r}");
    for key in [
        "nrmse_before",
        "nrmse_after",
        "gain",
        "nll_before",
        "nll_after",
        "accepted",
        "cause",
        "evidence",
        "extension",
    ] {
        assert!(r["steps"][0].get(key).is_some(), "step lacks {key}");
    }
    assert!(r["final"]["nrmse"].as_f64().unwrap() < r["baseline"]["nrmse"].as_f64().unwrap());
    assert!(saved.exists());
    assert!(stdout(&o).contains("causes: dynamics"));
}

/// A valid record `good.csv` (t, u, y; 400 rows) in `d`.
fn good_record(d: &Path) -> PathBuf {
    let good = d.join("good.csv");
    let mut text = String::from("t,u,y\n");
    for k in 0..400 {
        text.push_str(&format!(
            "{k},{},{}\n",
            ((k * 37) % 11) as f64 - 5.0,
            ((k * 13) % 7) as f64
        ));
    }
    write(&good, &text);
    good
}

/// A record `const.csv` (u, y; 400 rows) in `d` whose input is constant.
fn constant_input_record(d: &Path) -> PathBuf {
    let f = d.join("const.csv");
    let mut c = String::from("u,y\n");
    for k in 0..400 {
        c.push_str(&format!("1.0,{}\n", (k % 5) as f64));
    }
    write(&f, &c);
    f
}

#[test]
fn bad_csv_is_one_line_exit_2_no_output() {
    let d = tmp("bad-csv");
    let out = d.join("out.gbm");
    let o_s = out.to_str().unwrap();
    let good = good_record(&d);
    let g = good.to_str().unwrap();
    // missing file
    assert_bad(
        &["fit", "/nonexistent/x.csv", "-o", o_s],
        "/nonexistent/x.csv",
        &out,
    );
    // missing column
    assert_bad(
        &["fit", g, "--input", "v", "-o", o_s],
        "no column named 'v'",
        &out,
    );
    // NaN / inf
    let f = d.join("nan.csv");
    write(&f, "u,y\n1,2\n2,NaN\n");
    assert_bad(
        &["fit", f.to_str().unwrap(), "-o", o_s],
        "row 3, column 'y'",
        &out,
    );
    let f = d.join("inf.csv");
    write(&f, "u,y\n1,2\ninf,3\n");
    assert_bad(
        &["fit", f.to_str().unwrap(), "-o", o_s],
        "row 3, column 'u'",
        &out,
    );
    // ragged row
    let f = d.join("ragged.csv");
    write(&f, "u,y\n1,2\n3\n");
    assert_bad(
        &["fit", f.to_str().unwrap(), "-o", o_s],
        "row 3 has 1 fields",
        &out,
    );
    // non-numeric cell
    let f = d.join("text.csv");
    write(&f, "u,y\n1,2\n3,abc\n");
    assert_bad(
        &["fit", f.to_str().unwrap(), "-o", o_s],
        "'abc' is not a number",
        &out,
    );
    // empty file
    let f = d.join("empty.csv");
    write(&f, "");
    assert_bad(&["fit", f.to_str().unwrap(), "-o", o_s], "empty", &out);
}

#[test]
fn unusable_data_is_one_line_exit_2_no_output() {
    let d = tmp("bad-data");
    let out = d.join("out.gbm");
    let o_s = out.to_str().unwrap();
    // too few samples
    let f = d.join("short.csv");
    write(&f, "u,y\n1,2\n2,3\n3,1\n");
    assert_bad(&["fit", f.to_str().unwrap(), "-o", o_s], "at least", &out);
    // constant input
    let f = constant_input_record(&d);
    assert_bad(
        &["fit", f.to_str().unwrap(), "-o", o_s],
        "'u' is constant",
        &out,
    );
    let rep = d.join("r.json");
    assert_bad(
        &[
            "diagnose",
            f.to_str().unwrap(),
            "--json",
            rep.to_str().unwrap(),
        ],
        "'u' is constant",
        &rep,
    );
}

#[test]
fn bad_model_spec_or_option_is_one_line_exit_2_no_output() {
    let d = tmp("bad-option");
    let out = d.join("out.gbm");
    let o_s = out.to_str().unwrap();
    let good = good_record(&d);
    let g = good.to_str().unwrap();
    // unknown model spec, absurd flags
    assert_bad(
        &["fit", g, "--model", "quantum", "-o", o_s],
        "unknown model spec 'quantum'",
        &out,
    );
    assert_bad(&["fit", g, "--order", "0", "-o", o_s], "order", &out);
    let rep = d.join("r.json");
    assert_bad(
        &[
            "diagnose",
            g,
            "--order",
            "99",
            "--json",
            rep.to_str().unwrap(),
        ],
        "--order",
        &rep,
    );
    // unknown wavelet / rule
    let den = d.join("den.csv");
    assert_bad(
        &[
            "denoise",
            g,
            "--column",
            "y",
            "--wavelet",
            "db99x",
            "-o",
            den.to_str().unwrap(),
        ],
        "--wavelet",
        &den,
    );
    assert_bad(
        &[
            "denoise",
            g,
            "--column",
            "y",
            "--threshold",
            "magic",
            "-o",
            den.to_str().unwrap(),
        ],
        "--threshold",
        &den,
    );
    let html = d.join("r.html");
    assert_bad(
        &[
            "bench",
            "--only",
            "bogus",
            "--results",
            html.to_str().unwrap(),
        ],
        "unknown benchmark 'bogus'",
        &html,
    );
    // unknown system
    let gd = d.join("gen");
    assert_bad(
        &["generate", "warp-drive", "-o", gd.to_str().unwrap()],
        "unknown system 'warp-drive'",
        &gd.join("train.csv"),
    );
}

#[test]
fn absurd_sizes_are_one_line_exit_2_no_output() {
    let d = tmp("bad-size");
    let good = good_record(&d);
    let g = good.to_str().unwrap();
    let rep = d.join("r.json");
    let gd = d.join("gen");
    assert_bad(
        &[
            "generate",
            "linear",
            "-o",
            gd.to_str().unwrap(),
            "--samples",
            "100000000000",
        ],
        "at most",
        &gd.join("train.csv"),
    );
    assert_bad(
        &[
            "diagnose",
            g,
            "--max-steps",
            "100",
            "--json",
            rep.to_str().unwrap(),
        ],
        "--max-steps",
        &rep,
    );
    let wav = d.join("w.csv");
    assert_bad(
        &[
            "wavelet",
            g,
            "--column",
            "y",
            "--level",
            "99",
            "-o",
            wav.to_str().unwrap(),
        ],
        "level 99",
        &wav,
    );
    let out2 = d.join("out2.gbm");
    assert_bad(
        &["fit", g, "--order", "1000", "-o", out2.to_str().unwrap()],
        "order=1000: a whole number in 1..=",
        &out2,
    );
}

#[test]
fn bad_model_file_is_one_line_exit_2_no_output() {
    let d = tmp("bad-model");
    let out = d.join("out.gbm");
    let o_s = out.to_str().unwrap();
    let good = good_record(&d);
    let g = good.to_str().unwrap();
    // model files: not a model, truncated
    let sim = d.join("sim.csv");
    let fake = d.join("fake.gbm");
    write(&fake, "hello");
    assert_bad(
        &[
            "simulate",
            fake.to_str().unwrap(),
            g,
            "-o",
            sim.to_str().unwrap(),
        ],
        "not a greybox model file",
        &sim,
    );
    let o = run(&["fit", g, "-o", o_s]);
    assert!(o.status.success(), "{}", stderr(&o));
    let bytes = std::fs::read(&out).unwrap();
    let trunc = d.join("trunc.gbm");
    std::fs::write(&trunc, &bytes[..bytes.len() / 2]).unwrap();
    assert_bad(
        &[
            "simulate",
            trunc.to_str().unwrap(),
            g,
            "-o",
            sim.to_str().unwrap(),
        ],
        "truncated or corrupt",
        &sim,
    );
    let mut other = bytes.clone();
    other[4] = 9;
    let ver = d.join("ver.gbm");
    std::fs::write(&ver, &other).unwrap();
    assert_bad(
        &[
            "simulate",
            ver.to_str().unwrap(),
            g,
            "-o",
            sim.to_str().unwrap(),
        ],
        "format version 9",
        &sim,
    );
}

#[test]
fn wavelet_coefficients_reconstruct_the_signal_energy() {
    let d = tmp("wav");
    let f = d.join("s.csv");
    let mut text = String::from("t,y\n");
    let mut energy = 0.0;
    for k in 0..256 {
        let v = (k as f64 * 0.2).sin() + 0.3 * (k as f64 * 1.3).cos();
        energy += v * v;
        text.push_str(&format!("{k},{v}\n"));
    }
    write(&f, &text);
    let out = d.join("c.csv");
    let o = run(&[
        "wavelet",
        f.to_str().unwrap(),
        "--column",
        "y",
        "--wavelet",
        "db4",
        "--level",
        "3",
        "--mode",
        "periodization",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let c = std::fs::read_to_string(&out).unwrap();
    let mut lines = c.lines();
    assert_eq!(lines.next(), Some("level,index,value"));
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 256);
    assert_eq!(rows.iter().filter(|r| r[0] == 0.0).count(), 32);
    // orthogonal transform with periodization preserves energy (Parseval)
    let e2: f64 = rows.iter().map(|r| r[2] * r[2]).sum();
    assert!((e2 - energy).abs() < 1e-9 * energy, "{e2} vs {energy}");
    let den = d.join("d.csv");
    let o = run(&[
        "denoise",
        f.to_str().unwrap(),
        "--column",
        "y",
        "--wavelet",
        "db8",
        "--threshold",
        "sure",
        "-o",
        den.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(std::fs::read_to_string(&den).unwrap().starts_with("t,y\n"));
}

#[test]
fn help_teaches_the_workflow() {
    let o = run(&["--help"]);
    let s = stdout(&o);
    assert!(o.status.success());
    assert!(s.contains("greybox diagnose --example shock-absorber"));
    for sub in [
        "diagnose", "fit", "simulate", "generate", "denoise", "wavelet", "bench",
    ] {
        assert!(s.contains(sub), "help lacks {sub}");
        let o = run(&[sub, "--help"]);
        assert!(o.status.success(), "{sub} --help");
        assert!(
            stdout(&o).contains("Example"),
            "{sub} help lacks an example"
        );
    }
}

#[test]
fn bench_without_data_is_a_notice_and_exit_0() {
    let d = tmp("bench-none");
    let res = d.join("results.md");
    let absent = d.join("absent");
    let args = [
        "bench",
        "--data-dir",
        absent.to_str().unwrap(),
        "--results",
        res.to_str().unwrap(),
    ];
    // A newcomer without the data: a visible notice, exit 0.
    let o = bin()
        .args(args)
        .env_remove("GREYBOX_REQUIRE_DATA")
        .output()
        .expect("run greybox");
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(stdout(&o).contains("not found; nothing run"));
    assert!(!res.exists(), "nothing run, nothing written");
    // CI (GREYBOX_REQUIRE_DATA set): a missing folder is a failure.
    let o = bin()
        .args(args)
        .env("GREYBOX_REQUIRE_DATA", "1")
        .output()
        .expect("run greybox");
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("GREYBOX_REQUIRE_DATA"));
    assert!(!res.exists(), "nothing run, nothing written");
}

/// The first number after `key` in `line` (`… key   0.689 V …`).
fn number_after(line: &str, key: &str) -> f64 {
    line.split(key)
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no number after '{key}' in: {line}"))
}

/// With the real data present: the quick bench on the smallest benchmark
/// measures our models on the test record — the hand-built recipe (state-space
/// local model network) far better than our linear OE model and than the
/// published LTI result, the diagnosis no worse than its own linear
/// baseline — prints them in the table next to the published numbers, and
/// replaces only the generated block of the results file.
#[test]
fn bench_quick_runs_a_benchmark_and_writes_its_block() {
    let data = std::env::var_os("GREYBOX_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    if !data.join("cascaded_tanks/train.csv").is_file() {
        eprintln!(
            "bench test skipped: {} not found (set GREYBOX_DATA)",
            data.display()
        );
        return;
    }
    let d = tmp("bench-quick");
    let res = d.join("results.md");
    write(&res, "# Results\n\nhand-written text stays\n");
    let args = [
        "bench",
        "--quick",
        "--only",
        "tanks",
        "--data-dir",
        data.to_str().unwrap(),
        "--results",
        res.to_str().unwrap(),
    ];
    let o = run(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let s = stdout(&o);
    assert!(
        s.contains("| Cascaded tanks with overflow | test (init window 50"),
        "{s}"
    );
    assert!(
        s.contains("0.588 V") && s.contains("0.191 V"),
        "published numbers: {s}"
    );
    // our measured RMSEs (V) on the test record
    let line = s
        .lines()
        .find(|l| l.starts_with("tanks ") && l.contains("hand-built"))
        .unwrap_or_else(|| panic!("no tanks result line: {s}"));
    let diagnose = number_after(line, "diagnose");
    let linear = number_after(line, "linear OE");
    let class = number_after(line, "hand-built");
    // --quick measured 0.689 V (diagnose = linear OE: one step, nothing
    // pays) and 0.226 V for the class; published: LTI 0.588 V, best 0.191 V
    assert!(
        linear > 0.3 && linear < 1.5,
        "linear OE {linear} V: not the tanks' linear model"
    );
    assert!(
        diagnose <= 1.05 * linear,
        "diagnose {diagnose} V worse than its linear baseline {linear} V"
    );
    assert!(
        class < 0.5 * linear && class < 0.588,
        "hand-built recipe {class} V vs our linear OE {linear} V and the published LTI 0.588 V"
    );
    // the table states its protocol, shows the measured values and bolds
    // none of them (nothing is chosen by test error)
    assert!(s.contains("Protocol: `greybox diagnose TRAIN.csv`"), "{s}");
    assert!(
        s.contains(&format!("| {class:.3} V |")),
        "hand-built recipe {class} V not in the table: {s}"
    );
    assert!(!s.contains("| **"), "a bold cell in the table: {s}");
    let text = std::fs::read_to_string(&res).unwrap();
    assert!(text.starts_with("# Results\n\nhand-written text stays\n"));
    assert_eq!(text.matches("greybox bench: begin").count(), 1);
    // a second run replaces the block instead of appending another
    let o = run(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = std::fs::read_to_string(&res).unwrap();
    assert_eq!(text.matches("greybox bench: begin").count(), 1);
    assert!(text.contains("hand-written text stays"));
}

// ---- sequential Monte Carlo: `filter` and `fit --method smc` ----

/// A mass-spring-damper (k = 4, c = 0.6, h = 0.05) with a random force:
/// `p⁺ = p + h v + v₁`, `v⁺ = v + h(u − k p − c v) + v₂`, `y = p + w`, with
/// σ = (0.002, 0.02) and σ_w = 0.01. Returns the true model (a state-space
/// model file of the class, with its noise) and a record with the true
/// hidden states, simulated in the class's convention (`x_0 = v_0`).
fn msd_with_random_force(
    n: usize,
    seed: u64,
) -> (gb_core::FittedModel, Vec<f64>, Vec<f64>, Vec<[f64; 2]>) {
    use rand_distr::{Distribution, StandardNormal};
    let (h, k, c) = (0.05, 4.0, 0.6);
    let a = [1.0, h, -h * k, 1.0 - h * c];
    let b = [0.0, h];
    let sd = [0.002, 0.02];
    let sd_w = 0.01;
    let mut m =
        gb_model::SparseStateSpace::linear(a.to_vec(), b.to_vec(), vec![1.0, 0.0], vec![0.0])
            .unwrap();
    m.process_noise = sd
        .iter()
        .map(|&sd| gb_core::NoiseModel::Gaussian { sd })
        .collect();
    m.measurement_noise = gb_core::NoiseModel::Gaussian { sd: sd_w };
    let mut r = gb_core::rng::seeded(seed);
    let mut g = || -> f64 { StandardNormal.sample(&mut r) };
    let u: Vec<f64> = (0..n)
        .map(|t| 2.0 * (0.031 * t as f64).sin() + (0.11 * t as f64).sin())
        .collect();
    let mut x = [sd[0] * g(), sd[1] * g()];
    let (mut y, mut xs) = (Vec::new(), Vec::new());
    for t in 0..n {
        if t > 0 {
            x = [
                a[0] * x[0] + a[1] * x[1] + b[0] * u[t - 1] + sd[0] * g(),
                a[2] * x[0] + a[3] * x[1] + b[1] * u[t - 1] + sd[1] * g(),
            ];
        }
        xs.push(x);
        y.push(x[0] + sd_w * g());
    }
    let fm = gb_core::FittedModel::new(
        vec!["u".into()],
        vec!["y".into()],
        Box::new(m),
        gb_core::NoiseModel::Gaussian { sd: sd_w },
    )
    .unwrap();
    (fm, u, y, xs)
}

fn write_record(path: &Path, u: &[f64], y: &[f64]) {
    let mut s = String::from("u,y\n");
    for (a, b) in u.iter().zip(y) {
        s.push_str(&format!("{a},{b}\n"));
    }
    write(path, &s);
}

/// `greybox filter` on the true model of a generated system: the CSV has
/// the input, the output and x{i}_{mean,lo,hi} (and the smoothed columns with
/// --smooth); the true position and the true hidden velocity lie inside the
/// 95 % filter and smoother bands for at least 90 % of the samples (a band
/// that ignored the process noise, or means off by a sample, fall far below);
/// the log-likelihood is printed and the same seed gives the same file.
#[test]
fn filter_bands_contain_the_true_hidden_state() {
    let d = tmp("filter");
    let (fm, u, y, xs) = msd_with_random_force(400, 11);
    let model = d.join("msd.gbm");
    fm.save(&model).unwrap();
    let data = d.join("data.csv");
    write_record(&data, &u, &y);
    let out = d.join("states.csv");
    let args = [
        "filter",
        model.to_str().unwrap(),
        data.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--smooth",
        "--particles",
        "1000",
        "--seed",
        "5",
    ];
    let o = run(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let s = stdout(&o);
    let ll = s
        .lines()
        .find_map(|l| l.strip_prefix("log-likelihood: "))
        .and_then(|v| v.trim().parse::<f64>().ok())
        .expect(&s);
    assert!(ll.is_finite(), "{s}");
    let t = gb_core::CsvTable::read(&out).unwrap();
    let want = [
        "u",
        "y",
        "x1_mean",
        "x1_lo",
        "x1_hi",
        "x2_mean",
        "x2_lo",
        "x2_hi",
        "x1_smooth_mean",
        "x1_smooth_lo",
        "x1_smooth_hi",
        "x2_smooth_mean",
        "x2_smooth_lo",
        "x2_smooth_hi",
    ];
    assert_eq!(t.names, want);
    assert_eq!(t.n_rows(), 400);
    for (state, tag) in [(0, ""), (1, ""), (0, "smooth_"), (1, "smooth_")] {
        let lo = t.column(&format!("x{}_{tag}lo", state + 1)).unwrap();
        let hi = t.column(&format!("x{}_{tag}hi", state + 1)).unwrap();
        let inside = xs
            .iter()
            .enumerate()
            .filter(|(i, x)| lo[*i] <= x[state] && x[state] <= hi[*i])
            .count();
        let share = inside as f64 / xs.len() as f64;
        eprintln!(
            "x{} {tag}band: {:.1} % of the true states inside",
            state + 1,
            100.0 * share
        );
        assert!(share >= 0.90, "x{} {tag}: {share}", state + 1);
    }
    // same seed, same file
    let first = std::fs::read(&out).unwrap();
    let o = run(&args);
    assert!(o.status.success());
    assert_eq!(std::fs::read(&out).unwrap(), first);
}

/// `filter MODEL -`: rows on standard input give, row by row, the lines of
/// the batch filter's file (same particles and seed: bit-identical bands);
/// the first filtered row comes out before the second row is written
/// (flushed per row); `-o` or `--smooth` with `-` are a one-line error.
#[test]
fn filter_streams_stdin_rows_as_the_batch_filter() {
    use std::io::{BufRead, BufReader, Write};
    let d = tmp("filter-stream");
    let (fm, u, y, _) = msd_with_random_force(200, 12);
    let model = d.join("msd.gbm");
    fm.save(&model).unwrap();
    let data = d.join("data.csv");
    write_record(&data, &u, &y);
    let out = d.join("states.csv");
    let m = model.to_str().unwrap();
    let o = run(&[
        "filter",
        m,
        data.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--particles",
        "500",
        "--seed",
        "4",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let batch = std::fs::read_to_string(&out).unwrap();
    let batch: Vec<&str> = batch.lines().collect();
    assert_eq!(batch.len(), 201);
    let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_greybox"))
        .args(["filter", m, "-", "--particles", "500", "--seed", "4"])
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
    let text = std::fs::read_to_string(&data).unwrap();
    let rows: Vec<&str> = text.lines().collect();
    writeln!(stdin, "{}\n{}", rows[0], rows[1]).unwrap();
    stdin.flush().unwrap();
    assert_eq!(rx.recv_timeout(wait).expect("header"), batch[0]);
    assert_eq!(rx.recv_timeout(wait).expect("row 2 before row 3"), batch[1]);
    for row in &rows[2..] {
        writeln!(stdin, "{row}").unwrap();
    }
    drop(stdin);
    assert!(c.wait().unwrap().success());
    reader.join().unwrap();
    let streamed: Vec<String> = rx.try_iter().collect();
    assert_eq!(streamed.len(), 199);
    for (k, (a, b)) in streamed.iter().zip(&batch[2..]).enumerate() {
        assert_eq!(a, b, "row {}", k + 3);
    }
    // bad rows: one line naming row and column, exit 2, no panic
    for (input, needle) in [
        (
            "u,y\n1,2\nabc,1\n",
            "stdin: row 3, column 'u': 'abc' is not a number",
        ),
        ("x,y\n1,2\n", "stdin: no column named 'u'"),
        (
            "u,y\n1,inf\n",
            "stdin: row 2, column 'y': value inf is not finite",
        ),
        ("", "stdin: file is empty"),
    ] {
        let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_greybox"))
            .args(["filter", m, "-"])
            .stdin(std::process::Stdio::piped())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let _ = c.stdin.take().unwrap().write_all(input.as_bytes());
        let o = c.wait_with_output().unwrap();
        let e = String::from_utf8_lossy(&o.stderr).to_string();
        assert_eq!(o.status.code(), Some(2), "{input:?}: {e}");
        assert!(
            e.contains(needle) && e.trim_end().lines().count() == 1,
            "{input:?}: {e}"
        );
    }
    for extra in [["-o", "x.csv"], ["--smooth", "--seed"]] {
        let mut args = vec!["filter", m, "-"];
        args.extend(extra);
        if extra[0] == "--smooth" {
            args.push("4");
        }
        let o = run(&args);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{e}");
        assert!(
            e.contains("streams to standard output") && e.trim_end().lines().count() == 1,
            "{e}"
        );
    }
}

/// Bad input to `filter`: one line, exit 2, no output file.
#[test]
fn filter_bad_input_is_one_line_exit_2_no_output() {
    let d = tmp("filter-bad");
    let (fm, u, y, _) = msd_with_random_force(300, 12);
    let model = d.join("msd.gbm");
    fm.save(&model).unwrap();
    let data = d.join("data.csv");
    write_record(&data, &u, &y);
    let out = d.join("states.csv");
    let (m, ds, os) = (
        model.to_str().unwrap(),
        data.to_str().unwrap(),
        out.to_str().unwrap(),
    );
    // missing files
    assert_bad(&["filter", "nope.gbm", ds, "-o", os], "nope.gbm", &out);
    assert_bad(&["filter", m, "nope.csv", "-o", os], "nope.csv", &out);
    // the model's input column is missing
    let other = d.join("other.csv");
    write(&other, "a,y\n1,2\n3,4\n");
    assert_bad(&["filter", m, other.to_str().unwrap(), "-o", os], "u", &out);
    // a non-finite output
    let nan = d.join("nan.csv");
    write(&nan, "u,y\n1,0.1\n2,nan\n3,0.2\n");
    assert_bad(
        &["filter", m, nan.to_str().unwrap(), "-o", os],
        "nan.csv",
        &out,
    );
    // a model of another class
    let lin = d.join("lin.gbm");
    let o = run(&["fit", ds, "--model", "linear", "-o", lin.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_bad(
        &["filter", lin.to_str().unwrap(), ds, "-o", os],
        "state-space class",
        &out,
    );
    // a state-space model without process noise (an output-error fit)
    let mut oe = fm.clone();
    let mut ss = oe
        .dynamics
        .as_any()
        .downcast_ref::<gb_model::SparseStateSpace>()
        .unwrap()
        .clone();
    ss.process_noise = vec![gb_core::NoiseModel::Gaussian { sd: 0.0 }; 2];
    oe.dynamics = Box::new(ss);
    let oe_path = d.join("oe.gbm");
    oe.save(&oe_path).unwrap();
    assert_bad(
        &["filter", oe_path.to_str().unwrap(), ds, "-o", os],
        "no process noise",
        &out,
    );
    // zero particles is refused by the argument parser (exit 2)
    let o = run(&["filter", m, ds, "-o", os, "--particles", "0"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(!out.exists());
    // --method smc for another class, an unknown method
    let fit_out = d.join("fit.gbm");
    let fo = fit_out.to_str().unwrap();
    assert_bad(
        &["fit", ds, "--model", "linear", "--method", "smc", "-o", fo],
        "--method smc needs --model state-space",
        &fit_out,
    );
    assert_bad(
        &["fit", ds, "--method", "mcmc", "-o", fo],
        "expected oe or smc",
        &fit_out,
    );
}

/// `fit --model state-space --method smc` prints the posterior of the noise
/// scales and coefficients with 95 % intervals, ESS and split-R̂, the
/// acceptance rate, and — for a chain of 40 iterations — the warning that it
/// has not mixed; the saved model filters.
#[test]
fn fit_method_smc_reports_the_posterior_and_warns_on_short_chains() {
    let d = tmp("fit-smc");
    let (_, u, y, _) = msd_with_random_force(400, 13);
    let data = d.join("train.csv");
    write_record(&data, &u, &y);
    let model = d.join("smc.gbm");
    let o = run(&[
        "fit",
        data.to_str().unwrap(),
        "--model",
        "state-space",
        "--method",
        "smc",
        "--particles",
        "50",
        "--iterations",
        "40",
        "-o",
        model.to_str().unwrap(),
    ]);
    let s = stdout(&o);
    assert!(o.status.success(), "{}", stderr(&o));
    for needle in [
        "acceptance rate",
        "process_scale[x1]",
        "process_scale[x2]",
        "measurement_scale",
        "ESS",
        "R̂",
        "warning: the chain has not mixed",
    ] {
        assert!(s.contains(needle), "'{needle}' missing in:\n{s}");
    }
    // every posterior line: lo <= mean <= hi
    let posterior = s.lines().filter(|l| {
        l.trim_start().starts_with("process_scale")
            || l.trim_start().starts_with("measurement_scale")
    });
    for l in posterior {
        let nums: Vec<f64> = l
            .split(|c: char| c == '[' || c == ']' || c == ',' || c.is_whitespace())
            .filter_map(|w| w.parse::<f64>().ok())
            .collect();
        assert!(
            nums.len() >= 3 && nums[1] <= nums[0] && nums[0] <= nums[2],
            "{l}"
        );
    }
    // the SMC flags with the output-error method: an error, not ignored
    let oe_model = d.join("oe.gbm");
    let o = run(&[
        "fit",
        data.to_str().unwrap(),
        "--model",
        "state-space",
        "--particles",
        "50",
        "-o",
        oe_model.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--particles applies to --method smc only"));
    assert_eq!(stderr(&o).trim().lines().count(), 1, "{}", stderr(&o));
    assert!(!oe_model.exists());
    let out = d.join("states.csv");
    let o = run(&[
        "filter",
        model.to_str().unwrap(),
        data.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--particles",
        "100",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(gb_core::CsvTable::read(&out)
        .unwrap()
        .names
        .contains(&"x2_hi".to_string()));
    // the tuned sampler reports its particle choice, within the bounds
    let tuned = d.join("tuned.gbm");
    let o = run(&[
        "fit",
        data.to_str().unwrap(),
        "--model",
        "state-space",
        "--method",
        "smc",
        "--particles",
        "50",
        "--max-particles",
        "120",
        "--iterations",
        "40",
        "-o",
        tuned.to_str().unwrap(),
    ]);
    let s = stdout(&o);
    assert!(o.status.success(), "{}", stderr(&o));
    let chosen: usize = s
        .lines()
        .find_map(|l| l.strip_prefix("particles chosen at mid-burn-in: "))
        .and_then(|l| l.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no particle choice in:\n{s}"));
    assert!((50..=120).contains(&chosen), "{s}");
    let o = run(&[
        "fit",
        data.to_str().unwrap(),
        "--model",
        "state-space",
        "--max-particles",
        "120",
        "-o",
        oe_model.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--max-particles applies to --method smc only"));
}

/// `--budget`: no extension step starts after it, the report says so and
/// names no cause it did not test; the help states the budget; a bad
/// budget is one line, exit 2, no file. Without the budget the same data
/// name their cause (the budget, not the data, stopped the search).
#[test]
fn the_search_budget_ends_the_search_and_the_report_says_so() {
    let s = stdout(&run(&["diagnose", "--help"]));
    assert!(s.contains("--budget") && s.contains("300 s"), "{s}");
    let d = tmp("budget");
    let json = d.join("r.json");
    let o = run(&[
        "diagnose",
        "--example",
        "duffing",
        "--budget",
        "0.000001",
        "--max-steps",
        "1",
        "--json",
        json.to_str().unwrap(),
    ]);
    let text = stdout(&o);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        text.contains("the search budget of 0.000001 s ended the search before step 1"),
        "{text}"
    );
    assert!(
        text.contains("causes: none (no extension was tried"),
        "{text}"
    );
    let r = std::fs::read_to_string(&json).unwrap();
    assert!(r.contains("ended the search before step 1"), "{r}");
    let o = run(&["diagnose", "--example", "duffing", "--max-steps", "1"]);
    let text = stdout(&o);
    assert!(text.contains("causes: nonlinearity"), "{text}");
    assert!(!text.contains("search budget"), "{text}");
    let out = d.join("m.gbm");
    for bad in ["0", "nan", "-1"] {
        assert_bad(
            &[
                "diagnose",
                "--example",
                "duffing",
                &format!("--budget={bad}"),
                "--save",
                out.to_str().unwrap(),
            ],
            "--budget must be a positive number of seconds",
            &out,
        );
    }
}

/// `fit --model linear` without --order chooses order and delay on the
/// training data: on the fourth-order two-mass system it reaches the noise
/// floor on held-out data, where the recipe's old default (order 2) cannot.
/// With --order 2 the flag is kept.
#[test]
fn fit_without_flags_chooses_the_structure_on_the_training_data() {
    let d = tmp("fit-auto");
    let ds = d.to_str().unwrap();
    let o = run(&[
        "generate",
        "two-mass",
        "-o",
        ds,
        "--samples",
        "2000",
        "--validate-samples",
        "1000",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let floor = number_after(&stdout(&o), "noise floor NRMSE ");
    let (train, val, m) = (d.join("train.csv"), d.join("validate.csv"), d.join("m.gbm"));
    let fit_and_score = |extra: &[&str]| -> (String, f64) {
        let mut args = vec!["fit", train.to_str().unwrap(), "--model", "linear"];
        args.extend_from_slice(extra);
        args.extend_from_slice(&["-o", m.to_str().unwrap()]);
        let o = run(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        let fit_out = stdout(&o);
        let o = run(&[
            "simulate",
            m.to_str().unwrap(),
            val.to_str().unwrap(),
            "--init-window",
            "20",
            "-o",
            d.join("sim.csv").to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        (fit_out, number_after(&stdout(&o), "NRMSE "))
    };
    let (auto_out, e_auto) = fit_and_score(&[]);
    assert!(auto_out.contains("order auto: order 4"), "{auto_out}");
    let (fixed_out, e_two) = fit_and_score(&["--order", "2"]);
    assert!(!fixed_out.contains("order auto"), "{fixed_out}");
    // measured: auto 0.0287, order 2 0.1145, noise floor 0.0291
    assert!(
        e_auto < 1.3 * floor && e_two > 2.0 * e_auto,
        "validation NRMSE: default {e_auto}, --order 2 {e_two}, floor {floor}"
    );
}
