//! `greybox bench`: the field's real benchmarks with their standard splits and
//! init windows, our models next to the LTI and best published results.
//!
//! For every benchmark the model class is chosen by `diagnose` on the
//! training data (fit and select blocks of the training record; the test
//! records are never used for a decision), then the final model is
//! simulated in free run on each official test set with its init window.
use crate::progress::Bar;
use gb_core::{metrics, CsvTable, DynamicModel, FittedModel, Record};
use gb_diagnose::{diagnose, DiagnoseData, DiagnoseOptions};
use indicatif::ProgressBar;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// How the test samples are scored.
#[derive(Clone, Copy)]
enum Init {
    /// The first `n` measured outputs initialise the state; samples n.. are scored.
    Window(usize),
    /// Periodic steady state: the input is applied twice from rest and the
    /// second period is scored (no measured output used).
    Periodic,
    /// From rest (zero initial conditions); every sample is scored.
    Rest,
}

struct TestSet {
    name: &'static str,
    file: &'static str,
    init: Init,
    /// Published LTI result (in `unit`), if any.
    lti: Option<f64>,
    /// Best published result and who.
    best: Option<(f64, &'static str)>,
}

/// How one file holds both the training and the test rows (the test set's
/// `file` is the training file).
#[derive(Clone, Copy)]
enum OneFile {
    /// The first `num/den` of the rows train, the rest test.
    Fraction(usize, usize),
    /// Training rows `train.0..train.1`, test rows `test.0..test.1` (a
    /// published split).
    Rows {
        train: (usize, usize),
        test: (usize, usize),
    },
}

impl OneFile {
    /// The training and test row ranges of a file of `n` rows.
    fn ranges(self, n: usize) -> (std::ops::Range<usize>, std::ops::Range<usize>) {
        match self {
            OneFile::Fraction(num, den) => {
                let end = n * num / den;
                (0..end, end..n)
            }
            OneFile::Rows { train, test } => {
                (train.0.min(n)..train.1.min(n), test.0.min(n)..test.1.min(n))
            }
        }
    }
}

struct Benchmark {
    name: &'static str,
    title: &'static str,
    dir: &'static str,
    train: &'static str,
    /// `Some` when the test rows come from the training file.
    one_file: Option<OneFile>,
    inputs: &'static [&'static str],
    output: &'static str,
    /// Display unit and factor from the file's unit.
    unit: &'static str,
    factor: f64,
    /// The strongest model class we have for this benchmark (besides the
    /// diagnosis), if any.
    class: Option<BestClass>,
    tests: Vec<TestSet>,
}

/// A benchmark-grade model class and its settings.
#[derive(Clone, Copy)]
enum BestClass {
    /// gb-lmn `LmnModel` trained for simulation (NOE): tree-weighted network
    /// over z = y(k−1) of local polynomial models in y(k−1..na), u(k−nk..).
    Lmn {
        na: usize,
        nb: usize,
        nk: usize,
        degree: usize,
        leaves: usize,
        lm: usize,
        train_rows: usize,
    },
    /// gb-model: second-order mechanical structure with a hidden hysteretic
    /// state z, ż-row wavelet term f(v, z) (the Bouc-Wen recipe of
    /// `crates/gb-model/examples/bouc_wen.rs`).
    HystereticStateSpace {
        ts: f64,
        substeps: usize,
        max_level: i32,
        train_rows: usize,
    },
    /// gb-lmn `WienerHammersteinNetwork`: a static local model network
    /// between two linear filters, from the split of the best linear
    /// approximation's poles and zeros, refined by LM.
    WienerHammerstein {
        knots: usize,
        iterations: usize,
        train_rows: usize,
    },
    /// gb-lmn `SsLmnModel`: local-model state-space network with a √ basis
    /// and state saturation, `n_states` hidden states, 1..=`max_leaves`
    /// leaves chosen on a validation tail of the training data, LM on the
    /// simulation error; initial test state estimated on the init window.
    StateSpaceLmn {
        n_states: usize,
        max_leaves: usize,
        lm: usize,
        /// Known output (sensor) limit.
        output_upper: f64,
    },
    /// gb-model `MrDamperStructure`: Spencer-like wavelet grey-box state
    /// space (relative velocity, hysteretic state, voltage filter, two rig
    /// resonances), output error with the resonance set and the ridge weight
    /// chosen on the last 20 % of the training data
    /// (`crates/gb-model/examples/model_mr_damper.rs`).
    MrDamper {
        max_level: i32,
        iterations: usize,
        train_rows: usize,
    },
}

impl BestClass {
    fn quick(self) -> Self {
        match self {
            BestClass::Lmn {
                na,
                nb,
                nk,
                degree,
                leaves,
                ..
            } => BestClass::Lmn {
                na,
                nb,
                nk,
                degree,
                leaves: leaves.min(2),
                lm: 5,
                train_rows: 3000,
            },
            BestClass::HystereticStateSpace { ts, .. } => BestClass::HystereticStateSpace {
                ts,
                substeps: 2,
                max_level: 1,
                train_rows: 8192,
            },
            BestClass::WienerHammerstein { .. } => BestClass::WienerHammerstein {
                knots: 5,
                iterations: 3,
                train_rows: 3000,
            },
            BestClass::StateSpaceLmn {
                n_states,
                output_upper,
                ..
            } => BestClass::StateSpaceLmn {
                n_states,
                max_leaves: 1,
                lm: 40,
                output_upper,
            },
            BestClass::MrDamper { .. } => BestClass::MrDamper {
                max_level: 1,
                iterations: 5,
                train_rows: 3000,
            },
        }
    }
}

/// The benchmark table (one function per benchmark below).
fn benchmarks() -> Vec<Benchmark> {
    vec![
        bouc_wen(),
        silverbox(),
        wh2009(),
        tanks(),
        emps(),
        mr_damper(),
        mr_damper_sim(),
    ]
}

/// Bouc-Wen hysteretic benchmark.
fn bouc_wen() -> Benchmark {
    Benchmark {
        name: "bouc-wen",
        title: "Bouc-Wen hysteretic benchmark",
        dir: "bouc_wen",
        train: "train_multisine_forgione.csv",
        one_file: None,
        inputs: &["u"],
        output: "y",
        unit: "m",
        factor: 1.0,
        class: Some(BestClass::HystereticStateSpace {
            ts: 1.0 / 750.0,
            substeps: 8,
            max_level: 4,
            train_rows: 40960,
        }),
        tests: vec![
            TestSet {
                name: "multisine",
                file: "test_multisine.csv",
                init: Init::Periodic,
                lti: None,
                best: Some((7.53e-6, "gr-SS-NN, Iacob et al. 2025")),
            },
            TestSet {
                name: "sine sweep",
                file: "test_sinesweep.csv",
                init: Init::Rest,
                lti: None,
                best: None,
            },
        ],
    }
}

/// Silverbox (electronic Duffing oscillator).
fn silverbox() -> Benchmark {
    Benchmark {
        name: "silverbox",
        title: "Silverbox (electronic Duffing oscillator)",
        dir: "silverbox",
        train: "train_multisine.csv",
        one_file: None,
        inputs: &["u"],
        output: "y",
        unit: "mV",
        factor: 1e3,
        class: Some(BestClass::Lmn {
            na: 4,
            nb: 4,
            nk: 0,
            degree: 1,
            leaves: 12,
            lm: 40,
            train_rows: 65062,
        }),
        tests: vec![
            TestSet {
                name: "multisine",
                file: "test_multisine.csv",
                init: Init::Window(50),
                lti: Some(6.96),
                best: Some((0.301, "GP NARX, Champneys et al. 2024")),
            },
            TestSet {
                name: "arrow full",
                file: "test_arrow_full.csv",
                init: Init::Window(50),
                lti: Some(14.4),
                best: Some((0.26, "PNLSS, Paduart 2010")),
            },
            TestSet {
                name: "arrow no-extrapolation",
                file: "test_arrow_no_extrapolation.csv",
                init: Init::Window(50),
                lti: Some(6.58),
                best: Some((0.259, "GP NARX, Champneys et al. 2024")),
            },
        ],
    }
}

/// Wiener-Hammerstein 2009.
fn wh2009() -> Benchmark {
    Benchmark {
        name: "wh2009",
        title: "Wiener-Hammerstein 2009",
        dir: "wiener_hammerstein_2009",
        train: "train.csv",
        one_file: None,
        inputs: &["u"],
        output: "y",
        unit: "mV",
        factor: 1e3,
        class: Some(BestClass::WienerHammerstein {
            knots: 15,
            iterations: 60,
            train_rows: 100000,
        }),
        tests: vec![TestSet {
            name: "test",
            file: "test.csv",
            init: Init::Window(50),
            lti: Some(43.4),
            best: Some((0.241, "DT SUBNET, Beintema 2021")),
        }],
    }
}

/// Cascaded tanks with overflow.
fn tanks() -> Benchmark {
    Benchmark {
        name: "tanks",
        title: "Cascaded tanks with overflow",
        dir: "cascaded_tanks",
        train: "train.csv",
        one_file: None,
        inputs: &["u"],
        output: "y",
        unit: "V",
        factor: 1.0,
        class: Some(BestClass::StateSpaceLmn {
            n_states: 2,
            max_leaves: 2,
            lm: 200,
            output_upper: 10.0,
        }),
        tests: vec![TestSet {
            name: "test",
            file: "test.csv",
            init: Init::Window(50),
            lti: Some(0.588),
            best: Some((0.191, "grey-box, Worden 2018")),
        }],
    }
}

/// Electro-mechanical positioning system.
fn emps() -> Benchmark {
    Benchmark {
        name: "emps",
        title: "Electro-mechanical positioning system",
        dir: "emps",
        train: "train.csv",
        one_file: None,
        inputs: &["u"],
        output: "y",
        unit: "mm",
        factor: 1e3,
        class: None,
        tests: vec![TestSet {
            name: "pulses",
            file: "test.csv",
            init: Init::Window(20),
            lti: Some(5.53),
            best: Some((2.64, "dynoNet, Forgione & Piga 2021")),
        }],
    }
}

/// MR damper, Dyke white-noise test (first 60 % train, last 40 % test).
fn mr_damper() -> Benchmark {
    Benchmark {
        name: "mr-damper",
        title: "MR damper, Dyke white-noise test (first 60 % train, last 40 % test)",
        dir: "mr_damper_dyke_nees",
        train: "ranran_50.csv",
        one_file: Some(OneFile::Fraction(6, 10)),
        inputs: &["D", "V", "Y"],
        output: "F",
        unit: "N",
        factor: 1.0,
        class: Some(BestClass::MrDamper {
            max_level: 3,
            iterations: 30,
            train_rows: usize::MAX,
        }),
        tests: vec![TestSet {
            name: "last 40 %",
            file: "ranran_50.csv",
            init: Init::Window(50),
            lti: None,
            best: None,
        }],
    }
}

/// The Spencer MR-damper model simulated (Leva & Piroddi 2002 parameters,
/// inputs filtered white noise; the data of the SysIdentPy book), the
/// book's split. Column `a` (acceleration) holds spikes and is not an input.
fn mr_damper_sim() -> Benchmark {
    Benchmark {
        name: "mr-damper-sim",
        title: "MR damper, Spencer model simulated (SysIdentPy data; train rows 400-1999, test 2001-3599)",
        dir: "mr_damper_boucwen_sim_sysidentpy",
        train: "boucwen_histeretic_system.csv",
        one_file: Some(OneFile::Rows {
            train: (400, 2000),
            test: (2001, 3600),
        }),
        inputs: &["x", "v", "E"],
        output: "f",
        unit: "N",
        factor: 1.0,
        class: None,
        tests: vec![TestSet {
            name: "rows 2001-3599",
            file: "boucwen_histeretic_system.csv",
            init: Init::Window(50),
            lti: None,
            best: None,
        }],
    }
}

/// Names `--only` accepts.
pub fn names() -> Vec<&'static str> {
    benchmarks().iter().map(|b| b.name).collect()
}

/// Options of a bench run.
pub struct BenchOptions {
    pub data_dir: PathBuf,
    pub only: Vec<String>,
    pub quick: bool,
    /// Skip the hand-built recipes.
    pub blind_only: bool,
    pub quiet: bool,
    pub results: Option<PathBuf>,
}

struct Row {
    bench: &'static str,
    title: &'static str,
    test: &'static str,
    unit: &'static str,
    ours: f64,
    ours_nrmse: f64,
    linear: f64,
    lti: Option<f64>,
    best: Option<(f64, &'static str)>,
    model: String,
    causes: Vec<String>,
    fit_s: f64,
    samples: usize,
    train_rows: usize,
    /// The benchmark-grade class: test RMSE (display units; None: the
    /// simulation diverged on this test set), model, training rows, fit time.
    class: Option<(Option<f64>, String, usize, f64)>,
}

/// A fitted benchmark-grade model and how the benchmark scores it.
struct Fitted {
    model: Box<dyn DynamicModel>,
    /// An init window estimates the initial state (else the model starts
    /// from rest and the window is only left unscored).
    estimate_state: bool,
    /// Periods simulated for the periodic steady state.
    periods: usize,
}

impl Fitted {
    fn new(model: impl DynamicModel + 'static, estimate_state: bool, periods: usize) -> Self {
        Self {
            model: Box::new(model),
            estimate_state,
            periods,
        }
    }
}

/// Fit `c` on the first `train_rows` rows of `train`.
fn fit_class(c: BestClass, train: &Record, quiet: bool) -> Result<(Fitted, String, usize), String> {
    match c {
        BestClass::Lmn {
            na,
            nb,
            nk,
            degree,
            leaves,
            lm,
            train_rows,
        } => fit_lmn((na, nb, nk), degree, leaves, lm, train_rows, train),
        BestClass::HystereticStateSpace {
            ts,
            substeps,
            max_level,
            train_rows,
        } => fit_hysteretic_state_space(ts, substeps, max_level, train_rows, train, quiet),
        BestClass::WienerHammerstein {
            knots,
            iterations,
            train_rows,
        } => fit_wiener_hammerstein(knots, iterations, train_rows, train, quiet),
        BestClass::StateSpaceLmn {
            n_states,
            max_leaves,
            lm,
            output_upper,
        } => fit_state_space_lmn(n_states, max_leaves, lm, output_upper, train),
        BestClass::MrDamper {
            max_level,
            iterations,
            train_rows,
        } => fit_mr_damper(max_level, iterations, train_rows, train, quiet),
    }
}

/// The Lmn row of the benchmark table, fitted on `train`: a tree network
/// with lags `(na, nb, nk)` in y and u.
fn fit_lmn(
    (na, nb, nk): (usize, usize, usize),
    degree: usize,
    leaves: usize,
    lm: usize,
    train_rows: usize,
    train: &Record,
) -> Result<(Fitted, String, usize), String> {
    let d = train.slice(0..train_rows.min(train.len()));
    let ni = d.n_inputs();
    let reg = gb_lmn::RegressorSpec::arx(na, &vec![nb; ni], &vec![nk; ni])
        .with_z(vec![1], vec![vec![]; ni])
        .with_degree(degree);
    let m = gb_lmn::LmnParams::new(reg)
        .weights(gb_lmn::WeightKind::Tree)
        .max_leaves(leaves)
        .focus(gb_lmn::Focus::Simulation)
        .lm_iterations(lm)
        .fit(&gb_core::Records::single(d.clone()))
        .map_err(|e| e.to_string())?;
    let text = format!(
        "LmnModel NOE: {} leaf(s), local polynomials of degree {degree} in y(k-1..{na}), u(k-{nk}..k-{}), {} parameters",
        m.n_leaves(),
        nk + nb - 1,
        m.n_parameters()
    );
    Ok((Fitted::new(m, true, 2), text, d.len()))
}

/// The HystereticStateSpace row of the benchmark table, fitted on `train`.
fn fit_hysteretic_state_space(
    ts: f64,
    substeps: usize,
    max_level: i32,
    train_rows: usize,
    train: &Record,
    quiet: bool,
) -> Result<(Fitted, String, usize), String> {
    use gb_model::OeParams;
    let d = train.slice(0..train_rows.min(train.len()));
    let u = d.inputs.first().ok_or("no input")?;
    // linear start from the second period (after the transient)
    let a = (d.len() / 5).min(8192);
    let b = (a + 8192).min(d.len());
    let (start, _) = gb_model::hysteretic_mechanical_start(u, &d.output, a..b, ts, substeps)
        .map_err(|e| e.to_string())?;
    let bar = crate::progress::Bar::spinner(
        quiet || !std::io::IsTerminal::is_terminal(&std::io::stderr()),
        "fit",
    );
    let (m, _) = OeParams::new()
        .max_iter(40)
        .coarse_level(1)
        .max_level(max_level)
        .max_new(40)
        .check()
        .map_err(|e| e.to_string())?
        .fit(start, std::slice::from_ref(u), &d.output, &bar)
        .map_err(|e| e.to_string())?;
    let text = format!(
        "gb-model state space: position, velocity, hidden hysteretic force z; sparse bior2.2 term f(v, z), {} parameters, {substeps} sub-steps",
        m.n_parameters()
    );
    Ok((Fitted::new(m, false, 3), text, d.len()))
}

/// The WienerHammerstein row of the benchmark table, fitted on `train`.
fn fit_wiener_hammerstein(
    knots: usize,
    iterations: usize,
    train_rows: usize,
    train: &Record,
    quiet: bool,
) -> Result<(Fitted, String, usize), String> {
    let d = train.slice(0..train_rows.min(train.len()));
    let u = d.inputs.first().ok_or("no input")?;
    let pb = if quiet {
        ProgressBar::hidden()
    } else {
        let pb = ProgressBar::new_spinner();
        pb.enable_steady_tick(std::time::Duration::from_millis(120));
        pb.set_message("Wiener-Hammerstein network: BLA, pole/zero splits, LM");
        pb
    };
    // the WH2009 set-up: a 6/6 BLA, a 200-sample transient, a scan
    // on the first 30 000 samples
    let mut p = gb_lmn::WhParams::new()
        .bla(6, 6)
        .skip(200)
        .scan_samples(30_000)
        .knots(knots)
        .max_iter(iterations);
    if train_rows < 10_000 {
        // --quick: a small scan and one candidate
        p = p.candidates(1).bla(4, 4);
        p.scan_samples = train_rows;
    }
    let (m, _) = p
        .check()
        .and_then(|f| f.fit(u, &d.output))
        .map_err(|e| e.to_string())?;
    pb.finish_and_clear();
    let text = m.describe();
    Ok((Fitted::new(m, false, 2), text, d.len()))
}

/// The StateSpaceLmn row of the benchmark table, fitted on `train`.
fn fit_state_space_lmn(
    n_states: usize,
    max_leaves: usize,
    lm: usize,
    output_upper: f64,
    train: &Record,
) -> Result<(Fitted, String, usize), String> {
    let p = gb_lmn::SsLmnParams {
        n_states: vec![n_states],
        leaves: (1..=max_leaves).collect(),
        output_upper: Some(output_upper),
        max_iter: lm,
        ..gb_lmn::SsLmnParams::default()
    };
    let fit = gb_lmn::fit_ss_lmn(&p, &train.inputs, &train.output).map_err(|e| e.to_string())?;
    let text = format!(
        "{}; leaves chosen on the last 20 % of the training data, LM on the simulation error",
        fit.model.describe()
    );
    Ok((Fitted::new(fit.model, true, 2), text, train.len()))
}

/// The MrDamper row of the benchmark table, fitted on `train`.
fn fit_mr_damper(
    max_level: i32,
    iterations: usize,
    train_rows: usize,
    train: &Record,
    quiet: bool,
) -> Result<(Fitted, String, usize), String> {
    use gb_model::OeParams;
    let d = train.slice(0..train_rows.min(train.len()));
    let bar = crate::progress::Bar::spinner(
        quiet || !std::io::IsTerminal::is_terminal(&std::io::stderr()),
        "fit",
    );
    // the resonance set and the ridge weight on the last 20 % of the
    // training rows
    // the Dyke rig: sampled at 3004.8 Hz (the `t` column's mean step
    // gives 3004.795 Hz), resonances started at 150 Hz or 150 and 120 Hz
    let structures: Vec<gb_model::MrDamperStructure> = [vec![150.0], vec![150.0, 120.0]]
        .into_iter()
        .map(|r| gb_model::MrDamperStructure::new(3004.8, r))
        .collect();
    let fit = gb_model::MrDamperStructure::select(
        &structures,
        &OeParams::new().max_iter(iterations).max_level(max_level),
        &[0.0, 1e3],
        &d.inputs,
        &d.output,
        &bar,
    )
    .map_err(|e| e.to_string())?;
    let (m, ridge, structure) = (fit.model, fit.ridge, fit.structure);
    let text = format!(
        "gb-model MR damper structure: relative velocity, hysteretic z, 2nd-order voltage filter, rig resonances started at {:?} Hz; {} (resonances and ridge {:e} chosen on the last 20 % of the training rows)",
        structure.resonances_hz,
        m.describe(),
        ridge
    );
    Ok((Fitted::new(m, false, 3), text, d.len()))
}

/// Test RMSE (file units) of a benchmark-grade model under `init`.
fn score_class(f: &Fitted, test: &Record, init: Init) -> Result<f64, String> {
    let n = test.len();
    let (start, skip) = match init {
        Init::Window(w) => {
            let w = w.min(n / 2);
            let s = if f.estimate_state {
                gb_core::Init::Window(&test.output[..w])
            } else {
                gb_core::Init::Rest
            };
            (s, w)
        }
        Init::Periodic => (gb_core::Init::Periodic { periods: f.periods }, 0),
        Init::Rest => (gb_core::Init::Rest, 0),
    };
    let sim = f
        .model
        .simulate(&test.inputs, start)
        .map_err(|e| e.to_string())?;
    metrics::rmse(&test.output[skip..], &sim[skip..]).map_err(|e| e.to_string())
}

fn load(path: &Path, inputs: &[&str], output: &str) -> Result<Record, String> {
    let t = CsvTable::read(path).map_err(|e| e.to_string())?;
    let inputs: Vec<String> = inputs.iter().map(|s| s.to_string()).collect();
    Record::from_table(&t, &inputs, Some(output)).map_err(|e| e.to_string())
}

/// Free-run test error (RMSE in file units, NRMSE, scored samples) of `m`
/// on `test` under `init`.
fn score(m: &FittedModel, test: &Record, init: Init) -> Result<(f64, f64, usize), String> {
    let (y, sim): (Vec<f64>, Vec<f64>) = match init {
        Init::Window(n) => {
            let n = n.min(test.len() / 2);
            let sim = m
                .simulate(&test.inputs, gb_core::Init::Window(&test.output[..n]))
                .map_err(|e| e.to_string())?;
            (test.output[n..].to_vec(), sim[n..].to_vec())
        }
        Init::Periodic => {
            let sim = m
                .simulate(&test.inputs, gb_core::Init::Periodic { periods: 2 })
                .map_err(|e| e.to_string())?;
            (test.output.clone(), sim)
        }
        Init::Rest => {
            let sim = m
                .simulate(&test.inputs, gb_core::Init::Rest)
                .map_err(|e| e.to_string())?;
            (test.output.clone(), sim)
        }
    };
    let rmse = metrics::rmse(&y, &sim).map_err(|e| e.to_string())?;
    let nrmse = metrics::nrmse(&y, &sim).map_err(|e| e.to_string())?;
    Ok((rmse, nrmse, y.len()))
}

fn run_one(b: &Benchmark, dir: &Path, o: &BenchOptions) -> Result<Vec<Row>, String> {
    let root = dir.join(b.dir);
    let full = load(&root.join(b.train), b.inputs, b.output)?;
    // one record holding the test rows (MR dampers)
    let (train_rows, test_rows) = match b.one_file {
        Some(split) => {
            let (tr, te) = split.ranges(full.len());
            (tr, Some(te))
        }
        None => (0..full.len(), None),
    };
    let test_cap = o.quick.then_some(QUICK_TEST_ROWS);
    let train = if o.quick {
        let end = train_rows.end.min(train_rows.start + QUICK_TRAIN_ROWS);
        full.slice(train_rows.start..end)
    } else {
        full.slice(train_rows.clone())
    };
    let mut tests = vec![];
    for t in &b.tests {
        let mut d = if let Some(te) = &test_rows {
            full.slice(te.clone())
        } else {
            load(&root.join(t.file), b.inputs, b.output)?
        };
        if let Some(cap) = test_cap {
            d = d.slice(0..cap.min(d.len()));
        }
        tests.push(d);
    }
    let (dg, fit_s) = diagnose_as_a_user(b, &train, o)?;
    let baseline = dg.chain.first().map_or(&dg.model, |e| &e.model);
    let class = match b.class.filter(|_| !o.blind_only) {
        Some(c) => {
            let c = if o.quick { c.quick() } else { c };
            let t1 = Instant::now();
            let pre = full.slice(train_rows.clone());
            let (f, text, rows) = fit_class(c, &pre, o.quiet)?;
            Some((f, text, rows, t1.elapsed().as_secs_f64()))
        }
        None => None,
    };
    let mut out = vec![];
    for (t, d) in b.tests.iter().zip(&tests) {
        let (rmse, nrmse, n) = score(dg.to_save(), d, t.init)?;
        let (lin, _, _) = score(baseline, d, t.init)?;
        out.push(Row {
            bench: b.name,
            title: b.title,
            test: t.name,
            unit: b.unit,
            ours: rmse * b.factor,
            ours_nrmse: nrmse,
            linear: lin * b.factor,
            lti: t.lti,
            best: t.best,
            model: dg.report.final_model.model.clone(),
            causes: dg
                .report
                .cause_names()
                .iter()
                .map(|c| c.to_string())
                .collect(),
            fit_s,
            samples: n,
            train_rows: train.len(),
            class: class.as_ref().map(|(f, text, rows, secs)| {
                (
                    score_class(f, d, t.init).ok().map(|v| v * b.factor),
                    text.clone(),
                    *rows,
                    *secs,
                )
            }),
        });
    }
    Ok(out)
}

/// Training rows of a `--quick` run.
const QUICK_TRAIN_ROWS: usize = 3000;
/// Most test rows scored by a `--quick` run.
const QUICK_TEST_ROWS: usize = 4000;

/// `greybox diagnose TRAIN.csv` as a user runs it: the whole training
/// record split into fit / select / report blocks, the CLI's defaults
/// (order 2, up to 4 steps; `--quick`: one step). The test records play no
/// part. Returns the diagnosis and its wall time in seconds.
fn diagnose_as_a_user(
    b: &Benchmark,
    train: &Record,
    o: &BenchOptions,
) -> Result<(gb_diagnose::Diagnosis, f64), String> {
    let pb = Bar::new(o.quiet, 5, b.name);
    let t0 = Instant::now();
    let data = DiagnoseData::from_single(train.clone());
    let opts = DiagnoseOptions {
        max_steps: if o.quick { 1 } else { 4 },
        ..DiagnoseOptions::default()
    };
    let dg = diagnose(&data, &opts, Some(&pb)).map_err(|e| e.to_string())?;
    pb.finish();
    Ok((dg, t0.elapsed().as_secs_f64()))
}

fn fmt_val(v: f64, unit: &str) -> String {
    let a = v.abs();
    let s = if a != 0.0 && !(1e-2..1e4).contains(&a) {
        format!("{v:.3e}")
    } else if a >= 100.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.3}")
    };
    format!("{s} {unit}")
}

fn init_text(i: Init) -> String {
    match i {
        Init::Window(n) => format!("init window {n}"),
        Init::Periodic => "periodic steady state".into(),
        Init::Rest => "from rest".into(),
    }
}

/// Run the benchmarks; prints the table and (optionally) writes the results
/// block of a Markdown file. Returns the number of benchmarks run.
pub fn run(o: &BenchOptions) -> Result<usize, String> {
    let all = benchmarks();
    for n in &o.only {
        if !all.iter().any(|b| b.name == n) {
            return Err(format!(
                "--only: unknown benchmark '{n}' (known: {})",
                names().join(", ")
            ));
        }
    }
    if !o.data_dir.is_dir() && std::env::var_os("GREYBOX_REQUIRE_DATA").is_some() {
        return Err(format!(
            "GREYBOX_REQUIRE_DATA is set but the data folder {} is missing",
            o.data_dir.display()
        ));
    }
    if !o.data_dir.is_dir() {
        println!(
            "greybox bench: data folder {} not found; nothing run (give --data-dir or set GREYBOX_DATA to the benchmark data, see README)",
            o.data_dir.display()
        );
        return Ok(0);
    }
    let selected: Vec<&Benchmark> = all
        .iter()
        .filter(|b| o.only.is_empty() || o.only.iter().any(|n| n == b.name))
        .collect();
    let mut rows: Vec<Row> = vec![];
    let mut inits = vec![];
    for b in &selected {
        let missing: Vec<String> = std::iter::once(b.train)
            .chain(b.tests.iter().map(|t| t.file))
            .filter(|f| !o.data_dir.join(b.dir).join(f).is_file())
            .map(|f| format!("{}/{f}", b.dir))
            .collect();
        if !missing.is_empty() {
            println!("{}: skipped, missing {}", b.name, missing.join(", "));
            continue;
        }
        match run_one(b, &o.data_dir, o) {
            Ok(r) => {
                for (t, row) in b.tests.iter().zip(&r) {
                    println!(
                        "{:<10} {:<24} diagnose {:>14}  (NRMSE {:.4})  linear OE {:>14}  fit {:.1} s{}",
                        row.bench,
                        row.test,
                        fmt_val(row.ours, row.unit),
                        row.ours_nrmse,
                        fmt_val(row.linear, row.unit),
                        row.fit_s,
                        row.class.as_ref().map_or(String::new(), |c| format!(
                            "; hand-built {} (fit {:.1} s)",
                            c.0.map_or("diverged".into(), |v| fmt_val(v, row.unit)),
                            c.3
                        ))
                    );
                    inits.push(init_text(t.init));
                }
                rows.extend(r);
            }
            Err(e) => println!("{}: failed: {e}", b.name),
        }
    }
    let n_run = rows
        .iter()
        .map(|r| r.bench)
        .collect::<std::collections::BTreeSet<_>>()
        .len();
    let table = markdown(&rows, &inits, o.quick);
    println!();
    println!("{table}");
    if let Some(p) = &o.results {
        // --only: the other benchmarks' rows of the file stay
        let keep: Vec<&str> = if o.only.is_empty() {
            Vec::new()
        } else {
            all.iter().map(|b| b.title).collect()
        };
        write_results(p, &table, &keep, o.blind_only)?;
        println!("results written to {}", p.display());
    }
    Ok(n_run)
}

/// Header of the results table.
const HEADER: &str = "| benchmark | test set (scoring) | greybox diagnose (blind) | diagnose wall time | hand-built recipe (not blind) | linear OE (the diagnosis' baseline) | LTI published | best published |\n|---|---|---|---|---|---|---|---|\n";

/// How every number of the table is obtained.
const PROTOCOL: &str = "Protocol: `greybox diagnose TRAIN.csv` with the CLI's defaults on the whole training record (split into fit / select / report blocks; every decision on the training record), then the final model simulated in free run on each test set once. The hand-built recipes are structures a person chose per benchmark (some of their settings were tuned while looking at test results in earlier rounds); they are listed for reference, not chosen by test error.\n\n";

fn markdown(rows: &[Row], inits: &[String], quick: bool) -> String {
    let mut s = String::from(PROTOCOL);
    s.push_str(HEADER);
    for (r, init) in rows.iter().zip(inits) {
        let class = match r.class.as_ref().map(|c| c.0) {
            Some(Some(v)) => fmt_val(v, r.unit),
            Some(None) => "diverged".into(),
            None => "—".into(),
        };
        let _ = writeln!(
            s,
            "| {} | {} ({}, {} samples) | {} | {:.0} s | {class} | {} | {} | {} |",
            r.title,
            r.test,
            init,
            r.samples,
            fmt_val(r.ours, r.unit),
            r.fit_s,
            fmt_val(r.linear, r.unit),
            r.lti.map_or("—".into(), |v| fmt_val(v, r.unit)),
            r.best.map_or("—".into(), |(v, who)| format!(
                "{} ({who})",
                fmt_val(v, r.unit)
            )),
        );
    }
    s.push_str("\nModels and fit times:\n\n");
    let mut seen = std::collections::BTreeSet::new();
    for r in rows {
        if !seen.insert(r.bench) {
            continue;
        }
        let _ = writeln!(
            s,
            "- {}: diagnose chose {} (causes: {}), {} training rows, {:.0} s{}",
            r.title,
            r.model,
            if r.causes.is_empty() {
                "none".into()
            } else {
                r.causes.join(", ")
            },
            r.train_rows,
            r.fit_s,
            r.class.as_ref().map_or(String::new(), |c| format!(
                "; hand-built recipe: {}, {} training rows, {:.0} s",
                c.1, c.2, c.3
            ))
        );
    }
    if quick {
        s.push_str("\n(--quick: the first 3000 training rows, one diagnosis step, smaller hand-built fits, at most 4000 test samples; not comparable with published numbers.)\n");
    }
    s
}

const BEGIN: &str = "<!-- greybox bench: begin (generated by `greybox bench`, do not edit) -->";
const END: &str = "<!-- greybox bench: end -->";

/// Title of a table row (`| title | …`) or a model line (`- title: …`).
fn row_title(line: &str) -> Option<&str> {
    if let Some(r) = line.strip_prefix("| ") {
        r.split(" | ").next()
    } else {
        line.strip_prefix("- ")?.split(": ").next()
    }
}

/// `new` (a `--blind-only` table) with the hand-built cells of `old` (a
/// previous generated block): a row's fifth cell "—" takes the old row's
/// cell of the same benchmark and test set, and a model line without a
/// hand-built note takes the old line's note, marked with the date it was
/// measured on when the old block says so.
fn keep_recipes(old: &str, new: &str) -> String {
    let cells = |l: &str| -> Vec<String> {
        l.trim()
            .trim_matches('|')
            .split(" | ")
            .map(|c| c.trim().to_string())
            .collect()
    };
    let old_rows: Vec<Vec<String>> = old
        .lines()
        .filter(|l| l.starts_with("| ") && !l.starts_with("| benchmark |"))
        .map(cells)
        .collect();
    const NOTE: &str = "; hand-built recipe: ";
    let mut out = String::new();
    for line in new.lines() {
        let mut l = line.to_string();
        if line.starts_with("| ") && !line.starts_with("| benchmark |") {
            let mut c = cells(line);
            let same = old_rows
                .iter()
                .find(|o| o.len() == c.len() && o.len() > 4 && o[0] == c[0] && o[1] == c[1]);
            if let Some(o) = same.filter(|o| c.len() > 4 && c[4] == "—" && o[4] != "—") {
                c[4] = format!("{} (earlier run)", o[4].trim_end_matches(" (earlier run)"));
                l = format!("| {} |", c.join(" | "));
            }
        } else if let Some(t) = row_title(line).filter(|_| line.starts_with("- ")) {
            let note = old
                .lines()
                .filter(|o| o.starts_with("- ") && row_title(o) == Some(t))
                .find_map(|o| o.find(NOTE).map(|i| &o[i..]));
            if let (false, Some(n)) = (line.contains(NOTE), note) {
                l.push_str(n);
            }
        }
        out.push_str(&l);
        out.push('\n');
    }
    out
}

/// The table of `new` with the rows and model lines of `old` (a previous
/// generated block) added for the benchmarks `new` lacks, in the order of
/// `titles`.
fn merge_tables(old: &str, new: &str, titles: &[&str]) -> String {
    let lines = |s: &str, table: bool| -> Vec<String> {
        s.lines()
            .filter(|l| {
                if table {
                    l.starts_with("| ") && !l.starts_with("| benchmark |")
                } else {
                    l.starts_with("- ")
                }
            })
            .map(str::to_string)
            .collect()
    };
    let pick = |table: bool| -> Vec<String> {
        let (o, n) = (lines(old, table), lines(new, table));
        let mut out = Vec::new();
        for t in titles {
            let mine: Vec<&String> = n.iter().filter(|l| row_title(l) == Some(*t)).collect();
            let src = if mine.is_empty() {
                o.iter().filter(|l| row_title(l) == Some(*t)).collect()
            } else {
                mine
            };
            out.extend(src.into_iter().cloned());
        }
        out
    };
    let mut s = String::from(PROTOCOL);
    s.push_str(HEADER);
    for l in pick(true) {
        let _ = writeln!(s, "{l}");
    }
    s.push_str("\nModels and fit times:\n\n");
    for l in pick(false) {
        let _ = writeln!(s, "{l}");
    }
    if let Some(i) = new.find("\n(--quick") {
        s.push_str(&new[i..]);
    }
    s
}

/// Replace the generated block of `path` (between the markers) by `table`,
/// or append a section with it. With `keep` (the titles of all benchmarks,
/// in order) the rows of benchmarks that `table` lacks are kept; with
/// `recipes_from_old` (a `--blind-only` run) the hand-built cells and model
/// notes of the previous block stay in the rows that were run again.
fn write_results(
    path: &Path,
    table: &str,
    keep: &[&str],
    recipes_from_old: bool,
) -> Result<(), String> {
    let old = std::fs::read_to_string(path).unwrap_or_default();
    let old_block = match (old.find(BEGIN), old.find(END)) {
        (Some(a), Some(b)) if b > a => Some(&old[a..b]),
        _ => None,
    };
    let mut table = table.to_string();
    if let (true, Some(ob)) = (recipes_from_old, old_block) {
        table = keep_recipes(ob, &table);
    }
    if let (false, Some(ob)) = (keep.is_empty(), old_block) {
        table = merge_tables(ob, &table, keep);
    }
    let table = table.as_str();
    let date = std::process::Command::new("date")
        .arg("-u")
        .arg("+%Y-%m-%d")
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .map(|s| s.trim().to_string())
        .unwrap_or_default();
    let block = format!(
        "{BEGIN}\nGenerated by `greybox bench` on {date} ({} cores). Free-run simulation RMSE on the official test sets.\n\n{table}{END}",
        std::thread::available_parallelism().map_or(1, |n| n.get())
    );
    let new = match (old.find(BEGIN), old.find(END)) {
        (Some(a), Some(b)) if b > a => format!("{}{block}{}", &old[..a], &old[b + END.len()..]),
        _ if old.is_empty() => {
            format!("# Results on real benchmark data\n\n## `greybox bench`\n\n{block}\n")
        }
        _ => format!("{}\n## `greybox bench`\n\n{block}\n", old.trim_end()),
    };
    gb_core::write_atomic(path, new.as_bytes()).map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blind_only_runs_keep_the_hand_built_cells() {
        let old = "| benchmark | test | ours | t | hand | lin |\n|---|\n| A | t1 | 1 | 2 s | 0.5 | 9 |\n| A | t2 | 3 | 2 s | 0.7 | 9 |\n| C | t1 | 5 | 2 s | — | 9 |\n\nModels and fit times:\n\n- A: diagnose chose x, 2 s; hand-built recipe: r, 5 s\n";
        let new = "| benchmark | test | ours | t | hand | lin |\n|---|\n| A | t1 | 0.9 | 1 s | — | 9 |\n| A | t2 | 2 | 1 s | — | 9 |\n| B | t1 | 4 | 1 s | — | 8 |\n| C | t1 | 6 | 1 s | — | 9 |\n\nModels and fit times:\n\n- A: diagnose chose y, 1 s\n- B: diagnose chose z, 1 s\n";
        let m = keep_recipes(old, new);
        assert!(
            m.contains("| A | t1 | 0.9 | 1 s | 0.5 (earlier run) | 9 |"),
            "{m}"
        );
        assert!(
            m.contains("| A | t2 | 2 | 1 s | 0.7 (earlier run) | 9 |"),
            "{m}"
        );
        assert!(m.contains("| B | t1 | 4 | 1 s | — | 8 |"), "{m}");
        assert!(m.contains("| C | t1 | 6 | 1 s | — | 9 |"), "{m}");
        assert!(
            m.contains("- A: diagnose chose y, 1 s; hand-built recipe: r, 5 s"),
            "{m}"
        );
        assert!(m.contains("- B: diagnose chose z, 1 s\n"), "{m}");
        // a second blind run does not stack the marks
        let again = keep_recipes(&m, new);
        assert!(again.contains("| 0.5 (earlier run) |"), "{again}");
        assert!(!again.contains("(earlier run) (earlier run)"), "{again}");
    }

    #[test]
    fn only_runs_keep_the_other_rows() {
        let old = "x\n| benchmark | h |\n|---|\n| A | a1 |\n| A | a2 |\n| B | b-old |\n| C | c |\n\nModels and fit times:\n\n- A: ma\n- B: mb-old\n- C: mc\n";
        let new =
            "| benchmark | h |\n|---|\n| B | b-new |\n\nModels and fit times:\n\n- B: mb-new\n";
        let m = merge_tables(old, new, &["A", "B", "C"]);
        let rows: Vec<&str> = m
            .lines()
            .filter(|l| l.starts_with("| ") && !l.starts_with("| benchmark"))
            .collect();
        assert_eq!(
            rows,
            ["| A | a1 |", "| A | a2 |", "| B | b-new |", "| C | c |"]
        );
        let models: Vec<&str> = m.lines().filter(|l| l.starts_with("- ")).collect();
        assert_eq!(models, ["- A: ma", "- B: mb-new", "- C: mc"]);
        assert!(!m.contains("old"));
    }
}
