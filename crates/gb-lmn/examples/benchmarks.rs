//! Free-run simulation RMSE of `LmnModel` on the standard real-data
//! benchmarks in `../shared/data` (or `$GREYBOX_DATA`): trains on the
//! standard training set, simulates the standard test set with the standard
//! init window (the first 50 test samples initialise the output lags; the
//! RMSE is computed on the samples after it), and the 2-D static test
//! (oblique tree vs axis LOLIMOT at equal numbers of leaves).
//!
//! ```sh
//! cargo run --release -p gb-lmn --example benchmarks               # all
//! cargo run --release -p gb-lmn --example benchmarks -- silverbox  # one
//! cargo run --release -p gb-lmn --example benchmarks -- tanks leaves=8 na=2
//! cargo run --release -p gb-lmn --example benchmarks -- speed      # speed figures
//! cargo run --release -p gb-lmn --example benchmarks -- tanks-ss   # state-space LMN
//! ```
//! Options (key=value) override the data set's default structure: `na`,
//! `nb`, `nk` (x delays), `zy`, `zu` (z: output delays 1..zy, input delays
//! nk..nk+zu−1), `degree`, `leaves`, `weights` (gauss|tree), `splits`
//! (axis|oblique), `lm` (LM iterations), `ntrain` (first samples only),
//! `smooth`, `crit` (aicc|bic|val), `prune` (0|1), `focus` (sim|pred),
//! `noe` (0|1: output-error construction), `patience`, `guard` (0|1:
//! stability guard of the NOE training).
use gb_core::{CsvTable, Record, Records};
use gb_lmn::{Criterion, Focus, LmnParams, RegressorSpec, SplitKind, WeightKind};
use std::collections::HashMap;
use std::path::PathBuf;
use std::time::Instant;

fn data_dir() -> Option<PathBuf> {
    let d = std::env::var_os("GREYBOX_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    d.is_dir().then_some(d)
}

fn load(p: PathBuf) -> Result<Record, String> {
    let t = CsvTable::read(&p).map_err(|e| e.to_string())?;
    Record::from_table(&t, &["u".into()], Some("y")).map_err(|e| e.to_string())
}

/// A record of input signals u1, u2, … and output y.
fn record(inputs: Vec<Vec<f64>>, y: Vec<f64>) -> Records {
    let names = (1..=inputs.len()).map(|j| format!("u{j}")).collect();
    Records::single(Record::new(names, "y".into(), inputs, y).expect("finite signals"))
}

struct Setup {
    name: &'static str,
    train: &'static str,
    test: &'static str,
    init: usize,
    unit: (&'static str, f64),
    published: &'static str,
    target: f64,
    defaults: &'static [(&'static str, &'static str)],
}

const SETUPS: &[Setup] = &[
    Setup {
        name: "silverbox",
        train: "silverbox/train_multisine.csv",
        test: "silverbox/test_multisine.csv",
        init: 50,
        unit: ("mV", 1e3),
        published: "LTI 6.96; pNARX 0.64; SOTA 0.36 mV",
        target: 0.5e-3,
        defaults: &[
            ("na", "4"),
            ("nb", "4"),
            ("nk", "0"),
            ("zy", "1"),
            ("zu", "0"),
            ("degree", "3"),
            ("leaves", "1"),
            ("lm", "30"),
        ],
    },
    Setup {
        name: "silverbox-lmn",
        train: "silverbox/train_multisine.csv",
        test: "silverbox/test_multisine.csv",
        init: 50,
        unit: ("mV", 1e3),
        published: "LTI 6.96; pNARX 0.64; SOTA 0.36 mV",
        target: 0.5e-3,
        defaults: &[
            ("na", "4"),
            ("nb", "4"),
            ("nk", "0"),
            ("zy", "1"),
            ("zu", "0"),
            ("degree", "1"),
            ("leaves", "12"),
            ("lm", "40"),
        ],
    },
    Setup {
        name: "tanks",
        train: "cascaded_tanks/train.csv",
        test: "cascaded_tanks/test.csv",
        init: 50,
        unit: ("V", 1.0),
        published: "pNARX 0.413; SOTA grey-box 0.191 V",
        target: 0.35,
        defaults: &[
            ("na", "2"),
            ("nb", "2"),
            ("nk", "1"),
            ("zy", "1"),
            ("zu", "0"),
            ("degree", "1"),
            ("leaves", "4"),
            ("smooth", "0.3"),
            ("lm", "60"),
        ],
    },
    Setup {
        name: "wh2009",
        train: "wiener_hammerstein_2009/train.csv",
        test: "wiener_hammerstein_2009/test.csv",
        init: 50,
        unit: ("mV", 1e3),
        published: "pNARX 27.3; LSTM 4.45 mV",
        target: 2e-3,
        defaults: &[
            ("na", "5"),
            ("nb", "7"),
            ("nk", "0"),
            ("zy", "1"),
            ("zu", "0"),
            ("degree", "3"),
            ("leaves", "1"),
            ("lm", "40"),
        ],
    },
];

fn run(dir: &std::path::Path, s: &Setup, over: &HashMap<String, String>) -> Result<(), String> {
    let mut o: HashMap<String, String> = s
        .defaults
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    o.extend(over.clone());
    let g = |k: &str, d: &str| o.get(k).cloned().unwrap_or_else(|| d.to_string());
    let num = |k: &str, d: &str| -> Result<usize, String> {
        g(k, d).parse().map_err(|_| format!("{k}: not a number"))
    };
    let mut train = load(dir.join(s.train))?;
    let test = load(dir.join(s.test))?;
    let ntrain = num("ntrain", "0")?;
    if ntrain > 0 && ntrain < train.len() {
        train = train.slice(0..ntrain);
    }
    let (na, nb, nk) = (num("na", "2")?, num("nb", "2")?, num("nk", "1")?);
    let (zy, zu) = (num("zy", "1")?, num("zu", "0")?);
    let reg = RegressorSpec::arx(na, &[nb], &[nk])
        .with_z((1..=zy).collect(), vec![(nk..nk + zu).collect()])
        .with_degree(num("degree", "1")?);
    let weights = match g("weights", "tree").as_str() {
        "gauss" => WeightKind::Gaussian,
        _ => WeightKind::Tree,
    };
    let splits = match g("splits", "axis").as_str() {
        "oblique" => SplitKind::Oblique,
        _ => SplitKind::Axis,
    };
    let crit = match g("crit", "aicc").as_str() {
        "bic" => Criterion::Bic,
        "val" => Criterion::Validation,
        _ => Criterion::Aicc,
    };
    let focus = match g("focus", "sim").as_str() {
        "pred" => Focus::Prediction,
        _ => Focus::Simulation,
    };
    let smooth: f64 = g("smooth", "0.1").parse().map_err(|_| "smooth")?;
    let params = LmnParams::new(reg)
        .weights(weights)
        .splits(splits)
        .max_leaves(num("leaves", "8")?)
        .criterion(crit)
        .prune(g("prune", "0") == "1")
        .focus(focus)
        .smoothness(smooth)
        .patience(num("patience", "3")?)
        .noe_construction(g("noe", "0") == "1")
        .stability_guard(g("guard", "1") == "1")
        .lm_iterations(num("lm", "30")?);
    let t0 = Instant::now();
    let model = if crit == Criterion::Validation {
        // validation: the last 20 % of the training record
        let n = train.len();
        let cut = n * 4 / 5;
        let (fit, val) = (train.slice(0..cut), train.slice(cut..n));
        params
            .check()
            .map_err(|e| e.to_string())?
            .fit(&Records::single(fit), Some(&Records::single(val)))
    } else {
        params.fit(&Records::single(train.clone()))
    }
    .map_err(|e| e.to_string())?;
    let secs = t0.elapsed().as_secs_f64();
    let sim = model.simulate(&test, s.init).map_err(|e| e.to_string())?;
    let rmse = gb_core::metrics::rmse(&test.output[s.init..], &sim[s.init..])
        .map_err(|e| e.to_string())?;
    let tr_sim = model.simulate(&train, s.init).map_err(|e| e.to_string())?;
    let tr_rmse = gb_core::metrics::rmse(&train.output[s.init..], &tr_sim[s.init..])
        .map_err(|e| e.to_string())?;
    let (u, f) = s.unit;
    println!(
        "{}: test free-run RMSE {:.4} {u} (target <= {:.3} {u}; published {}), train {:.4} {u}, fit {:.1} s",
        s.name,
        rmse * f,
        s.target * f,
        s.published,
        tr_rmse * f,
        secs
    );
    println!(
        "  options {:?}\n  model: {}\n  leaves {}, parameters {}, effective {:.1}, LM {} it, rms {:.4} -> {:.4}",
        {
            let mut v: Vec<_> = o.iter().collect();
            v.sort();
            v
        },
        model.describe(),
        model.n_leaves(),
        model.n_parameters(),
        model.effective_parameters(),
        model.summary.lm_iterations,
        model.summary.rms_before_lm,
        model.summary.rms_after_lm
    );
    Ok(())
}

/// 2-D static test: y = sum of Gaussian bumps + noise, 2000 points; RMSE of
/// axis LOLIMOT (normalised Gaussians) vs oblique tree at equal leaves,
/// against the noise-free function on a 100 x 100 grid.
fn static_2d(smooth: f64) {
    use rand::{Rng, SeedableRng};
    use rand_distr::{Distribution, StandardNormal};
    let mut r = rand::rngs::SmallRng::seed_from_u64(2026);
    let bumps = [
        (0.3, 0.3, 1.0, 0.15),
        (-0.4, 0.2, -0.8, 0.25),
        (0.0, -0.5, 0.7, 0.2),
        (-0.5, -0.6, 0.5, 0.1),
    ];
    let f = |a: f64, b: f64| -> f64 {
        bumps
            .iter()
            .map(|(x, y, h, s)| h * (-((a - x).powi(2) + (b - y).powi(2)) / (2.0 * s * s)).exp())
            .sum()
    };
    let n = 2000;
    let noise = 0.05;
    let (mut u1, mut u2, mut y) = (vec![], vec![], vec![]);
    for _ in 0..n {
        let a: f64 = r.random_range(-1.0..1.0);
        let b: f64 = r.random_range(-1.0..1.0);
        let e: f64 = StandardNormal.sample(&mut r);
        u1.push(a);
        u2.push(b);
        y.push(f(a, b) + noise * e);
    }
    let train = record(vec![u1, u2], y);
    let (mut g1, mut g2, mut gy) = (vec![], vec![], vec![]);
    for i in 0..100 {
        for j in 0..100 {
            let a = -0.99 + 0.02 * i as f64;
            let b = -0.99 + 0.02 * j as f64;
            g1.push(a);
            g2.push(b);
            gy.push(f(a, b));
        }
    }
    let grid = record(vec![g1, g2], gy);
    println!("2-D static test (4 Gaussian bumps, {n} points, noise sd {noise}): RMSE vs the true function on a 100x100 grid");
    println!("  leaves | axis LOLIMOT (Gaussian) | axis tree | oblique tree (HILOMOT) | Gauss+LM | oblique+LM");
    for leaves in [4, 8, 12, 16, 24] {
        let fit = |w: WeightKind, s: SplitKind, lm: usize| -> f64 {
            let t0 = Instant::now();
            let m = LmnParams::new(RegressorSpec::arx(0, &[1, 1], &[0, 0]))
                .weights(w)
                .splits(s)
                .max_leaves(leaves)
                .patience(1000)
                .criterion(Criterion::Validation)
                .focus(Focus::Prediction)
                .lm_iterations(lm)
                .smoothness(smooth)
                .check()
                .and_then(|p| {
                    // grow to exactly `leaves` (validation on the training data never stops early)
                    p.fit(&train, Some(&train))
                });
            let _ = t0;
            match m {
                Ok(m) if m.n_leaves() == leaves => m
                    .predict(grid.first())
                    .ok()
                    .and_then(|p| gb_core::metrics::rmse(&grid.first().output, &p).ok())
                    .unwrap_or(f64::NAN),
                _ => f64::NAN,
            }
        };
        println!(
            "  {leaves:>6} | {:>23.4} | {:>9.4} | {:>22.4} | {:>9.4} | {:>14.4}",
            fit(WeightKind::Gaussian, SplitKind::Axis, 0),
            fit(WeightKind::Tree, SplitKind::Axis, 0),
            fit(WeightKind::Tree, SplitKind::Oblique, 0),
            fit(WeightKind::Gaussian, SplitKind::Axis, 30),
            fit(WeightKind::Tree, SplitKind::Oblique, 30)
        );
    }
}

/// CPU time of this thread (ns), from /proc/thread-self/schedstat (0 if unavailable).
fn thread_cpu_ns() -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| {
            s.split_whitespace()
                .next()
                .and_then(|v| v.parse::<f64>().ok())
        })
        .unwrap_or(0.0)
}

/// CPU time of the process (s), from /proc/self/stat (utime + stime).
fn process_cpu_s() -> f64 {
    std::fs::read_to_string("/proc/self/stat")
        .ok()
        .and_then(|s| {
            let f: Vec<&str> = s.rsplit(')').next()?.split_whitespace().collect();
            let u: f64 = f.get(11)?.parse().ok()?;
            let k: f64 = f.get(12)?.parse().ok()?;
            Some((u + k) / 100.0)
        })
        .unwrap_or(0.0)
}

/// The two speed figures of issue 3 with wall and CPU time (the shared
/// machine is loaded, so CPU time is the fairer figure); the criterion
/// bench `cargo bench -p gb-lmn --bench lmn` measures the same work.
fn speed() {
    use rand::{Rng, SeedableRng};
    let mut r = rand::rngs::SmallRng::seed_from_u64(2026);
    let n = 100_000;
    let u: Vec<Vec<f64>> = (0..8)
        .map(|_| (0..n).map(|_| r.random_range(-1.0..1.0)).collect())
        .collect();
    let y: Vec<f64> = (0..n)
        .map(|k| {
            let x: Vec<f64> = u.iter().map(|c| c[k]).collect();
            (2.0 * x[0]).tanh() * x[1] + (3.0 * x[2] * x[3]).sin() + x[4] * x[4] - 0.5 * x[5]
                + 0.3 * x[6] * x[7]
                + 0.01 * r.random_range(-1.0..1.0)
        })
        .collect();
    let d = record(u, y);
    let fits = std::env::var_os("SPEED_NO_FIT").is_none();
    for (name, w) in [("tree", WeightKind::Tree), ("gauss", WeightKind::Gaussian)] {
        let p = LmnParams::new(RegressorSpec::arx(0, &[1; 8], &[0; 8]))
            .weights(w)
            .max_leaves(20)
            .patience(100)
            .lm_iterations(0);
        if !fits {
            continue;
        }
        let (t0, c0) = (Instant::now(), process_cpu_s());
        let m = p.fit(&d);
        let (wall, cpu) = (t0.elapsed().as_secs_f64(), process_cpu_s() - c0);
        println!(
            "lolimot fit ({name} weights, axis) 100000 x 8 to {} leaves: wall {wall:.2} s, CPU {cpu:.2} s (threads {})",
            m.map(|m| m.summary.history.len()).unwrap_or(0),
            rayon::current_num_threads()
        );
    }
    let gen = |n: usize, seed: u64| {
        let mut r = rand::rngs::SmallRng::seed_from_u64(seed);
        let u: Vec<f64> = (0..n).map(|_| r.random_range(-1.0..1.0)).collect();
        let mut y = vec![0.0; n];
        for k in 2..n {
            y[k] = 0.5 * y[k - 1]
                + 0.2 * y[k - 2]
                + 0.6 * (1.5 * u[k - 1]).tanh()
                + 0.2 * (2.0 * y[k - 1]).tanh() * u[k - 2];
        }
        record(vec![u], y)
    };
    let train = gen(20_000, 7);
    let leaves: usize = std::env::var("SPEED_LEAVES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20);
    let m = LmnParams::new(RegressorSpec::arx(2, &[2], &[1]).with_z(vec![1], vec![vec![1]]))
        .max_leaves(leaves)
        .patience(100)
        .criterion(Criterion::Validation)
        .focus(Focus::Prediction)
        .lm_iterations(0)
        .check()
        .and_then(|p| p.fit(&train, Some(&train)));
    let Ok(m) = m else { return };
    let test = gen(1_000_000, 8);
    let mut best_wall = f64::INFINITY;
    let mut best_cpu = f64::INFINITY;
    for _ in 0..5 {
        let (t0, c0) = (Instant::now(), thread_cpu_ns());
        let s = m.simulate(test.first(), 2);
        let (wall, cpu) = (t0.elapsed().as_secs_f64(), (thread_cpu_ns() - c0) * 1e-9);
        if s.is_ok() {
            best_wall = best_wall.min(wall);
            best_cpu = best_cpu.min(cpu);
        }
    }
    println!(
        "NOE simulation, {} leaves, 1e6 samples: {:.1} M samples/s wall, {:.1} M samples/s CPU",
        m.n_leaves(),
        1.0 / best_wall,
        1.0 / best_cpu
    );
}

/// Cascaded tanks with the local-model state-space network (`gb_lmn::ssnet`):
/// options `nx` (states), `leaves` (comma list of candidates, chosen on the validation tail
/// of the training data), `sched` (x0|x1|u), `sqrt` (0|1), `sat` (0|1),
/// `ymax` (sensor limit, `none` to drop), `nonneg` (0|1: clamp states at 0),
/// `lm` (LM iterations), `rates`.
fn tanks_ss(dir: &std::path::Path, over: &HashMap<String, String>) -> Result<(), String> {
    use gb_lmn::{fit_ss_lmn, Scheduling, SsLmnParams};
    let tr = load(dir.join("cascaded_tanks/train.csv"))?;
    let te = load(dir.join("cascaded_tanks/test.csv"))?;
    let get = |k: &str, d: &str| over.get(k).cloned().unwrap_or_else(|| d.to_string());
    let list = |k: &str, d: &str| -> Result<Vec<f64>, String> {
        get(k, d)
            .split(',')
            .map(|v| v.parse::<f64>().map_err(|e| format!("{k}: {e}")))
            .collect()
    };
    let p = SsLmnParams {
        n_states: vec![get("nx", "2").parse().map_err(|e| format!("nx: {e}"))?],
        leaves: list("leaves", "1,2")?.iter().map(|&v| v as usize).collect(),
        scheduling: match get("sched", "x0").as_str() {
            "x1" => Scheduling::State(1),
            "u" => Scheduling::Input(0),
            _ => Scheduling::State(0),
        },
        sqrt_basis: get("sqrt", "1") == "1",
        state_saturation: get("sat", "1") == "1",
        output_upper: get("ymax", "10").parse().ok(),
        nonnegative_states: get("nonneg", "0") == "1",
        init_rates: list("rates", "0.1,0.2,0.4")?,
        max_iter: get("lm", "200").parse().map_err(|e| format!("lm: {e}"))?,
        ..SsLmnParams::default()
    };
    let t0 = Instant::now();
    let fit = fit_ss_lmn(&p, &tr.inputs, &tr.output).map_err(|e| e.to_string())?;
    let secs = t0.elapsed().as_secs_f64();
    let sim = fit
        .model
        .simulate_with_init_window(&te.inputs, &te.output, 50)
        .map_err(|e| e.to_string())?;
    let n = te.output.len() - 50;
    let e = (sim[50..]
        .iter()
        .zip(&te.output[50..])
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>()
        / n as f64)
        .sqrt();
    println!(
        "tanks-ss: {} | validation {:?} | train {:.4} V | test {:.4} V (target 0.35) | fit {:.1} s",
        fit.model.describe(),
        fit.validation,
        fit.train_rmse,
        e,
        secs
    );
    Ok(())
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let which: Vec<&str> = args
        .iter()
        .filter(|a| !a.contains('='))
        .map(String::as_str)
        .collect();
    let over: HashMap<String, String> = args
        .iter()
        .filter_map(|a| a.split_once('='))
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    let all = which.is_empty();
    if which.contains(&"speed") {
        speed();
        return;
    }
    if all || which.contains(&"static2d") {
        static_2d(
            over.get("smooth")
                .and_then(|s| s.parse().ok())
                .unwrap_or(0.1),
        );
    }
    let Some(dir) = data_dir() else {
        eprintln!("real-data benchmarks skipped: ../shared/data not found (set GREYBOX_DATA)");
        return;
    };
    if all || which.contains(&"tanks-ss") {
        if let Err(e) = tanks_ss(&dir, &over) {
            eprintln!("tanks-ss: error: {e}");
        }
    }
    for s in SETUPS {
        if all || which.contains(&s.name) {
            if let Err(e) = run(&dir, s, &over) {
                eprintln!("{}: error: {e}", s.name);
            }
        }
    }
}
