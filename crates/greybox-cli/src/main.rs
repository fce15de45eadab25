//! The `greybox` command-line tool.
use clap::{Args, Parser, Subcommand};
use gb_core::{CsvTable, DataSet};
use gb_diagnose::{
    diagnose, systems, DiagnoseData, DiagnoseOptions, GreyBoxModel, ModelFitOptions, OrderChoice,
    Report, Structure,
};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

mod bench;

const ABOUT: &str =
    "greybox: identify nonlinear dynamical systems and see what your model gets wrong";

const LONG_ABOUT: &str = "\
greybox identifies models of dynamical systems from measured data and tells
you what your model gets wrong: it simulates your model (free run), names the
cause of the misfit (nonlinearity, hysteresis, dynamics, noise), extends the
model and measures the gain on held-out data.

Workflow:
  greybox diagnose --example shock-absorber          # a demo on generated data
  greybox generate bouc-wen -o data/                 # write train.csv, validate.csv
  greybox diagnose data/train.csv --validate data/validate.csv --json report.json --save model.gbm
  greybox simulate model.gbm data/validate.csv -o sim.csv
  greybox fit data/train.csv --model linear+preisach -o model.gbm

CSV files need a header row; a `t` column is ignored. Errors name the file,
row and column and exit with code 2.";

#[derive(Parser)]
#[command(name = "greybox", version, about = ABOUT, long_about = LONG_ABOUT)]
struct Cli {
    /// No progress bars.
    #[arg(long, global = true)]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Show what the simulation gets wrong, name the cause, extend the model, measure the gain.
    #[command(
        after_help = "Examples:\n  greybox diagnose --example shock-absorber\n  greybox diagnose train.csv --validate val.csv --input u --output y --json report.json --report report.html\n  greybox diagnose data.csv --order auto --save model.gbm"
    )]
    Diagnose(DiagnoseArgs),
    /// Fit a model of a given structure by output-error identification.
    #[command(
        after_help = "Model SPEC: linear, lmn, linear+preisach, lmn+preisach (append +student-t for a robust heavy-tailed noise model); lmn-state-space (a local model network in state-space form: hidden states, sqrt basis, learned state bounds; --order states, --max-leaves, --output-max); wiener-hammerstein (a static local model network between two linear filters, from the best linear approximation; one input; --max-leaves sets its local models); state-space, state-space+preisach, state-space+hysteresis (the wavelet-sparse state-space class of gb-model; +hysteresis: a hidden hysteretic state z with a wavelet law, the model diagnose chooses when the simple extensions do not suffice); state-space+damper (a Spencer-like MR damper: inputs displacement, velocity, voltage [, acceleration] in that order; --resonances for test-rig modes, --ridge).\n\nExamples:\n  greybox fit train.csv --model lmn --order 2 --input u --output y -o model.gbm\n  greybox fit train.csv --model lmn --weights tree --splits oblique --prune --focus simulation --max-leaves 10 -o model.gbm\n  greybox fit silverbox_train.csv --model lmn --order 4 --dead-time 0 --partition y1 --max-leaves 12 -o sb.gbm   # 0.28 mV on the Silverbox multisine test\n  greybox fit run1.csv --experiment run2.csv --model lmn --input a --input b --dead-time 2,0 --input-lags 3,1 --output-lags 2 -o m.gbm   # per-input delays, two experiments\n  greybox fit train.csv --model state-space+hysteresis -o m.gbs   # hidden hysteretic force, as diagnose chooses it\n  greybox fit mr.csv --model state-space+damper --input D --input V --input Y --input A --output F --resonances 150,120 -o mr.gbs"
    )]
    Fit(Box<FitArgs>),
    /// Simulate a saved model on the inputs of a CSV file (free run).
    #[command(
        after_help = "Example:\n  greybox simulate model.gbm test.csv -o sim.csv --init-window 50"
    )]
    Simulate(SimulateArgs),
    /// Write train.csv and validate.csv for a generated system (fixed seed = same files).
    #[command(
        after_help = "Systems: linear, msd-linear, msd-nonlinear, duffing, saturation, deadzone, preisach, bouc-wen, backlash, two-mass, student-t, shock-absorber\n\nExample:\n  greybox generate duffing -o duffing/ --seed 3"
    )]
    Generate(GenerateArgs),
    /// Denoise one column by wavelet thresholding (soft, all levels).
    #[command(
        after_help = "Example:\n  greybox denoise data.csv --column y --wavelet db8 --threshold sure -o clean.csv\n\nThe output has every input column and the denoised column in place of the original."
    )]
    Denoise(DenoiseArgs),
    /// Multilevel wavelet decomposition of one column, one row per coefficient.
    #[command(
        after_help = "Example:\n  greybox wavelet data.csv --column y --wavelet db4 --level 5 --mode periodization -o coeffs.csv\n\nColumns: level,index,value; level 0 is the approximation, then details coarse to fine (PyWavelets' wavedec order)."
    )]
    Wavelet(WaveletArgs),
    /// Run the real benchmarks (Bouc-Wen, Silverbox, WH2009, tanks, EMPS, MR damper) and print the results table.
    #[command(
        after_help = "Benchmarks: bouc-wen, silverbox, wh2009, tanks, emps, mr-damper\n\nEach benchmark: `diagnose` on the training record chooses the model, which is then simulated in free run on the official test sets with their init windows. The table shows our RMSE next to our linear OE model, the published LTI result and the best published result.\n\nExamples:\n  greybox bench --quick                       # a few minutes, subsets (CI)\n  greybox bench --only silverbox --only tanks\n  greybox bench --data-dir ../shared/data --results docs/results.md\n\nA missing data folder prints a notice and exits 0."
    )]
    Bench(BenchArgs),
}

#[derive(Args)]
struct BenchArgs {
    /// Folder with the benchmark data (default: $GREYBOX_DATA, else ../shared/data).
    #[arg(long, value_name = "DIR")]
    data_dir: Option<PathBuf>,
    /// Run only this benchmark (repeatable).
    #[arg(long, value_name = "NAME")]
    only: Vec<String>,
    /// Small subsets and one diagnosis step: minutes, for CI; not comparable with published numbers.
    #[arg(long)]
    quick: bool,
    /// Markdown file whose generated results block is replaced (default: docs/results.md for a full run, none for --quick); with --only, the rows of the other benchmarks stay.
    #[arg(long, value_name = "FILE")]
    results: Option<PathBuf>,
    /// Do not write a results file.
    #[arg(long, conflicts_with = "results")]
    no_results: bool,
}

#[derive(Args)]
struct DenoiseArgs {
    /// Input CSV.
    data: PathBuf,
    /// Column to denoise.
    #[arg(long)]
    column: String,
    /// Wavelet (haar, dbN, symN, coifN, biorX.Y, cdf53, cdf97).
    #[arg(long, default_value = "db8")]
    wavelet: String,
    /// Threshold rule: sure, universal, bayes (BayesShrink), ebayes (empirical Bayes).
    #[arg(long, default_value = "sure")]
    threshold: String,
    /// Signal extension mode: periodization, symmetric, zero, constant, periodic.
    #[arg(long, default_value = "symmetric")]
    mode: String,
    /// Output CSV.
    #[arg(short = 'o', long = "out", value_name = "FILE")]
    out: PathBuf,
}

#[derive(Args)]
struct WaveletArgs {
    /// Input CSV.
    data: PathBuf,
    /// Column to transform.
    #[arg(long)]
    column: String,
    /// Wavelet (haar, dbN, symN, coifN, biorX.Y, cdf53, cdf97).
    #[arg(long, default_value = "db4")]
    wavelet: String,
    /// Decomposition levels (default: the maximum useful level).
    #[arg(long)]
    level: Option<usize>,
    /// Signal extension mode: periodization, symmetric, zero, constant, periodic.
    #[arg(long, default_value = "symmetric")]
    mode: String,
    /// Output CSV with columns level,index,value.
    #[arg(short = 'o', long = "out", value_name = "FILE")]
    out: PathBuf,
}

#[derive(Args)]
struct SignalArgs {
    /// Input column (repeat for several inputs). Default: every column except the output and `t`.
    #[arg(long = "input", value_name = "COLUMN")]
    inputs: Vec<String>,
    /// Output column. Default: the last column.
    #[arg(long, value_name = "COLUMN")]
    output: Option<String>,
}

#[derive(Args)]
struct DiagnoseArgs {
    /// Training data (CSV). Without --validate it is split into fit/select/report blocks.
    #[arg(required_unless_present = "example")]
    train: Option<PathBuf>,
    /// Validation data (CSV) on which the NRMSE is reported.
    #[arg(long)]
    validate: Option<PathBuf>,
    #[command(flatten)]
    signals: SignalArgs,
    /// Order of the engineer's linear output-error model, or `auto`.
    #[arg(long, default_value = "2")]
    order: String,
    /// Write the report as JSON.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// Save the final model (postcard).
    #[arg(long, value_name = "FILE")]
    save: Option<PathBuf>,
    /// Write a self-contained HTML report with plots (measured vs simulated, residual tests, evidence per cause, the extension).
    #[arg(long, value_name = "FILE")]
    report: Option<PathBuf>,
    /// Run on a generated example instead of files: shock-absorber, or any `generate` system.
    #[arg(long, value_name = "NAME", conflicts_with = "train")]
    example: Option<String>,
    /// Most extension steps (1..=4).
    #[arg(long, default_value_t = 4)]
    max_steps: usize,
}

#[derive(Args)]
struct FitArgs {
    /// Training data (CSV).
    train: PathBuf,
    /// Model structure SPEC.
    #[arg(long, default_value = "linear")]
    model: String,
    /// Dynamic order n.
    #[arg(long, default_value_t = 2)]
    order: usize,
    #[command(flatten)]
    signals: SignalArgs,
    /// Model file to write.
    #[arg(short = 'o', long = "out", value_name = "FILE")]
    out: PathBuf,
    /// `--model lmn` only: validity functions, gauss (normalised Gaussians, LOLIMOT) or tree (decision-tree sigmoids). Any of --weights/--splits/--prune/--focus/--max-leaves selects the full local model network (x = z = the order-n regressors).
    #[arg(long, value_name = "gauss|tree")]
    weights: Option<String>,
    /// `--model lmn` only: axis (LOLIMOT) or oblique (HILOMOT, tree weights) splits.
    #[arg(long, value_name = "axis|oblique")]
    splits: Option<String>,
    /// `--model lmn` only: remove splits that do not pay by AICc after growing.
    #[arg(long)]
    prune: bool,
    /// `--model lmn` only: train for free-run simulation (NOE) or one-step prediction (NARX).
    #[arg(long, value_name = "simulation|prediction")]
    focus: Option<String>,
    /// `--model lmn` only: largest number of local models.
    #[arg(long, value_name = "N")]
    max_leaves: Option<usize>,
    /// `--model lmn` only: degree of the local models, 1 (affine) to 3 (polynomial).
    #[arg(long, value_name = "D")]
    degree: Option<usize>,
    /// `--model lmn` only: input dead time (delays k-d..k-d-n+1; 0 = direct feed-through); one value for every input or one per input (`1,0,2`).
    #[arg(long, value_name = "D[,D..]")]
    dead_time: Option<String>,
    /// `--model lmn` only: number of lags of each input (default: the order); one value or one per input (`4,2`).
    #[arg(long, value_name = "N[,N..]")]
    input_lags: Option<String>,
    /// `--model lmn` only: number of output lags y(k-1..k-N) (default: the order).
    #[arg(long, value_name = "N")]
    output_lags: Option<usize>,
    /// `--model lmn-state-space` only: known upper limit of the output (sensor range), e.g. 10.
    #[arg(long, value_name = "Y")]
    output_max: Option<f64>,
    /// `--model lmn` only: a further training record, fitted as a separate experiment (no regressor spans two records); repeatable.
    #[arg(long = "experiment", value_name = "FILE")]
    experiments: Vec<PathBuf>,
    /// `--model lmn` only: growth criterion, aicc or bic.
    #[arg(long, value_name = "aicc|bic")]
    criterion: Option<String>,
    /// `--model lmn` only: partition space, all (every regressor) or y1 (the last output only).
    #[arg(long, value_name = "all|y1")]
    partition: Option<String>,
    /// `--model state-space+damper` only: start frequencies (Hz) of test-rig resonances seen in the force, one 2-state block each (`150,120`; default none).
    #[arg(long, value_name = "HZ[,HZ..]")]
    resonances: Option<String>,
    /// `--model state-space+damper` only: sample rate in Hz (default: from a `t` column of the training file).
    #[arg(long, value_name = "HZ")]
    sample_rate: Option<f64>,
    /// `--model state-space+damper` only: Tikhonov weight on the wavelet coefficients (output units squared per squared coefficient; default: 0 or 1000, chosen on the last 20 % of the training record).
    #[arg(long, value_name = "RHO")]
    ridge: Option<f64>,
}

/// A per-input list flag: one value for every input or one per input, each
/// in `lo..=hi`; `default` when absent.
fn per_input(
    flag: &str,
    v: Option<&str>,
    default: usize,
    n_inputs: usize,
    lo: usize,
    hi: usize,
) -> Result<Vec<usize>> {
    let Some(v) = v else {
        return Ok(vec![default; n_inputs]);
    };
    let vals: Vec<usize> = v
        .split(',')
        .map(|x| {
            x.trim()
                .parse::<usize>()
                .ok()
                .filter(|n| (lo..=hi).contains(n))
                .ok_or_else(|| format!("{flag}: '{x}' is not a whole number in {lo}..={hi}"))
        })
        .collect::<Result<_>>()?;
    match vals.len() {
        1 => Ok(vec![vals[0]; n_inputs]),
        n if n == n_inputs => Ok(vals),
        n => Err(format!(
            "{flag}: {n} values for {n_inputs} inputs (give one, or one per input)"
        )),
    }
}

/// The full local model network of `fit --model lmn` when any of its flags is given.
fn lmn_params(a: &FitArgs, s: &Structure, n_inputs: usize) -> Result<Option<gb_lmn::LmnParams>> {
    use gb_lmn::{Focus, LmnParams, RegressorSpec, SplitKind, WeightKind};
    if a.weights.is_none()
        && a.splits.is_none()
        && !a.prune
        && a.focus.is_none()
        && a.max_leaves.is_none()
        && a.degree.is_none()
        && a.dead_time.is_none()
        && a.input_lags.is_none()
        && a.output_lags.is_none()
        && a.experiments.is_empty()
        && a.criterion.is_none()
        && a.partition.is_none()
    {
        return Ok(None);
    }
    if !s.network || s.hysteresis || s.robust_noise {
        return Err(format!(
            "--weights/--splits/--prune/--focus/--max-leaves/--degree/--dead-time/--input-lags/--output-lags/--experiment/--criterion/--partition need --model lmn, got '{}'",
            a.model
        ));
    }
    let degree = a.degree.unwrap_or(1);
    if !(1..=3).contains(&degree) {
        return Err(format!("--degree must be 1, 2 or 3, got {degree}"));
    }
    let nk = per_input("--dead-time", a.dead_time.as_deref(), 1, n_inputs, 0, 64)?;
    let nb = per_input(
        "--input-lags",
        a.input_lags.as_deref(),
        a.order,
        n_inputs,
        0,
        64,
    )?;
    let na = a.output_lags.unwrap_or(a.order);
    if na > 64 {
        return Err(format!("--output-lags must be at most 64, got {na}"));
    }
    let criterion = match a.criterion.as_deref() {
        None | Some("aicc") => gb_lmn::Criterion::Aicc,
        Some("bic") => gb_lmn::Criterion::Bic,
        Some(w) => return Err(format!("--criterion must be aicc or bic, got '{w}'")),
    };
    let weights = match a.weights.as_deref() {
        None | Some("tree") => WeightKind::Tree,
        Some("gauss") => WeightKind::Gaussian,
        Some(w) => return Err(format!("--weights must be gauss or tree, got '{w}'")),
    };
    let splits = match a.splits.as_deref() {
        None | Some("axis") => SplitKind::Axis,
        Some("oblique") => SplitKind::Oblique,
        Some(w) => return Err(format!("--splits must be axis or oblique, got '{w}'")),
    };
    let focus = match a.focus.as_deref() {
        None | Some("simulation") => Focus::Simulation,
        Some("prediction") => Focus::Prediction,
        Some(w) => {
            return Err(format!(
                "--focus must be simulation or prediction, got '{w}'"
            ))
        }
    };
    let mut reg = RegressorSpec::arx(na, &nb, &nk);
    match a.partition.as_deref() {
        None | Some("all") => {}
        Some("y1") => reg = reg.with_z(vec![1], vec![vec![]; n_inputs]),
        Some(w) => return Err(format!("--partition must be all or y1, got '{w}'")),
    }
    let p = LmnParams::new(reg.with_degree(degree))
        .weights(weights)
        .splits(splits)
        .prune(a.prune)
        .focus(focus)
        .criterion(criterion)
        .max_leaves(a.max_leaves.unwrap_or(20));
    p.check().map_err(|e| e.to_string())?;
    Ok(Some(p))
}

#[derive(Args)]
struct SimulateArgs {
    /// Model file written by `fit` or `diagnose --save`.
    model: PathBuf,
    /// Data with the model's input columns (and optionally its output column).
    data: PathBuf,
    /// Output CSV: the inputs, the measured output if present, and y_sim.
    #[arg(short = 'o', long = "out", value_name = "FILE")]
    out: PathBuf,
    /// The first N measured outputs initialise the state (estimated by least squares when N exceeds the model's lags); errors are reported on samples N.. only.
    #[arg(long, default_value_t = 0)]
    init_window: usize,
}

#[derive(Args)]
struct GenerateArgs {
    /// System name (see below).
    system: String,
    /// Output directory (created if missing).
    #[arg(short = 'o', long = "out", value_name = "DIR")]
    out: PathBuf,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Training samples.
    #[arg(long, default_value_t = 8000)]
    samples: usize,
    /// Validation samples.
    #[arg(long, default_value_t = 4000)]
    validate_samples: usize,
}

type Result<T> = std::result::Result<T, String>;

/// A closed stdout (`greybox … | head -1`) ends the program quietly, as
/// Unix tools do, instead of with println!'s panic message.
fn quiet_on_broken_pipe() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let msg = info
            .payload()
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| info.payload().downcast_ref::<&str>().copied())
            .unwrap_or("");
        if msg.contains("failed printing to stdout") && msg.contains("Broken pipe") {
            std::process::exit(141);
        }
        default(info);
    }));
}

fn main() -> ExitCode {
    quiet_on_broken_pipe();
    let cli = Cli::parse();
    // progress bars only for a person watching: silent when piped
    let quiet = cli.quiet || !std::io::stdout().is_terminal() || !std::io::stderr().is_terminal();
    let r = match cli.command {
        Command::Diagnose(a) => run_diagnose(a, quiet),
        Command::Fit(a) => run_fit(*a, quiet),
        Command::Simulate(a) => run_simulate(a),
        Command::Generate(a) => run_generate(a),
        Command::Denoise(a) => run_denoise(a),
        Command::Wavelet(a) => run_wavelet(a),
        Command::Bench(a) => run_bench(a, quiet),
    };
    match r {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("greybox: error: {e}");
            ExitCode::from(2)
        }
    }
}

fn load(path: &Path, s: &SignalArgs) -> Result<DataSet> {
    let t = CsvTable::read(path).map_err(|e| e.to_string())?;
    DataSet::from_table(&t, &s.inputs, s.output.as_deref()).map_err(|e| e.to_string())
}

fn spinner(quiet: bool, msg: &str) -> ProgressBar {
    let pb = ProgressBar::new_spinner();
    if quiet {
        pb.set_draw_target(ProgressDrawTarget::hidden());
    } else {
        pb.enable_steady_tick(std::time::Duration::from_millis(120));
    }
    pb.set_message(msg.to_string());
    pb
}

struct BarObserver(ProgressBar);

impl gb_diagnose::Observer for BarObserver {
    fn progress(&self, done: usize, total: usize, message: &str) {
        self.0.set_length(total as u64);
        self.0.set_position(done as u64);
        self.0.set_message(message.to_string());
    }
}

/// A `gb_core::Observer` drawing an indicatif bar on stderr for a fit of
/// the numerical crates (stage and training RMSE); hidden with `--quiet` or
/// when stderr is not a terminal, cleared when the work is done.
pub(crate) struct FitBar(ProgressBar);

impl FitBar {
    pub(crate) fn new(quiet: bool) -> Self {
        let bar = if quiet || !std::io::stderr().is_terminal() {
            ProgressBar::hidden()
        } else {
            let b = ProgressBar::new(1);
            if let Ok(style) =
                ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} {msg}")
            {
                b.set_style(style);
            }
            b
        };
        Self(bar)
    }
}

impl gb_core::Observer for FitBar {
    fn progress(&self, done: usize, total: usize, message: &str) {
        self.0.set_length(total as u64);
        self.0.set_position(done as u64);
        self.0.set_message(message.to_string());
        if done >= total {
            self.0.finish_and_clear();
        }
    }
}

fn parse_order(s: &str) -> Result<OrderChoice> {
    if s == "auto" {
        return Ok(OrderChoice::Auto);
    }
    match s.parse::<usize>() {
        Ok(n) if (1..=gb_diagnose::MAX_ORDER).contains(&n) => Ok(OrderChoice::Fixed(n)),
        _ => Err(format!(
            "--order must be 1..={} or auto, got '{s}'",
            gb_diagnose::MAX_ORDER
        )),
    }
}

fn run_diagnose(a: DiagnoseArgs, quiet: bool) -> Result<()> {
    let order = parse_order(&a.order)?;
    if a.max_steps == 0 || a.max_steps > 4 {
        return Err(format!("--max-steps must be 1..=4, got {}", a.max_steps));
    }
    let data = if let Some(ex) = &a.example {
        let name = if ex == "shock-absorber" {
            "shock-absorber"
        } else {
            ex.as_str()
        };
        let g = systems::generate(name, 1, 8000, 4000).map_err(|e| e.to_string())?;
        println!(
            "example '{name}': generated {} training + {} validation samples (seed 1, SNR {:.1} dB, noise floor NRMSE {:.4})",
            g.train.len(),
            g.validate.len(),
            g.snr_db,
            g.noise_floor_nrmse
        );
        DiagnoseData::with_validation(g.train, g.validate).map_err(|e| e.to_string())?
    } else {
        let train_path = a
            .train
            .as_ref()
            .ok_or("a training CSV or --example is needed")?;
        let train = load(train_path, &a.signals)?;
        match &a.validate {
            Some(v) => {
                let val = load(v, &a.signals)?;
                DiagnoseData::with_validation(train, val)
                    .map_err(|e| format!("{}: {e}", v.display()))?
            }
            None => {
                let d = DiagnoseData::from_single(train);
                println!(
                    "no --validate: {} split into contiguous blocks fit {}..{}, select {}..{}, report {}..{}",
                    train_path.display(),
                    d.fit.start,
                    d.fit.end,
                    d.select.start,
                    d.select.end,
                    d.report_range.start,
                    d.report_range.end
                );
                d
            }
        }
    };
    let opts = DiagnoseOptions {
        order,
        max_steps: a.max_steps,
        ..DiagnoseOptions::default()
    };
    let pb = ProgressBar::new(1 + a.max_steps as u64);
    if quiet {
        pb.set_draw_target(ProgressDrawTarget::hidden());
    } else {
        pb.set_style(
            ProgressStyle::with_template("{spinner} [{bar:20}] {pos}/{len} {msg} ({elapsed})")
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        pb.enable_steady_tick(std::time::Duration::from_millis(120));
    }
    let obs = BarObserver(pb.clone());
    let d = diagnose(&data, &opts, Some(&obs)).map_err(|e| e.to_string())?;
    pb.finish_and_clear();
    print_report(&d.report);
    // render before writing anything: a failure leaves no output file behind
    let html = match &a.report {
        Some(_) => {
            let title = match (&a.example, &a.train) {
                (Some(ex), _) => format!("greybox diagnosis: example {ex}"),
                (None, Some(p)) => format!("greybox diagnosis: {}", p.display()),
                _ => "greybox diagnosis".to_string(),
            };
            Some(gb_diagnose::render_html(&d, &data, &title).map_err(|e| e.to_string())?)
        }
        None => None,
    };
    // write outputs only after everything succeeded (each write is atomic)
    if let (Some(p), Some(h)) = (&a.report, &html) {
        gb_core::write_atomic(p, h.as_bytes()).map_err(|e| e.to_string())?;
        println!("HTML report written to {}", p.display());
    }
    if let Some(j) = &a.json {
        let text = serde_json::to_string_pretty(&d.report).map_err(|e| e.to_string())?;
        gb_core::write_atomic(j, text.as_bytes()).map_err(|e| e.to_string())?;
        println!("report written to {}", j.display());
    }
    if let Some(s) = &a.save {
        d.model.save(s).map_err(|e| e.to_string())?;
        println!("final model saved to {}", s.display());
    }
    Ok(())
}

fn print_report(r: &Report) {
    println!();
    println!(
        "data: inputs {} -> output {}; fit {} / select {} / report {} samples",
        r.data.inputs.join(","),
        r.data.output,
        r.data.samples_fit,
        r.data.samples_select,
        r.data.samples_validate
    );
    println!(
        "baseline: {}  NRMSE {:.4}  nll {:.3}",
        r.baseline.model, r.baseline.nrmse, r.baseline.nll
    );
    println!();
    println!(
        "{:<4} {:<13} {:>8} {:>8} {:>8} {:>17} {:<8} extension / evidence",
        "step", "cause", "NRMSE", "->", "gain", "select gain [95%]", "accepted"
    );
    for s in &r.steps {
        let gain = if s.gain_metric == "nll" {
            format!("{:+.3}nll", s.gain)
        } else {
            format!("{:+.1}%", 100.0 * s.gain)
        };
        println!(
            "{:<4} {:<13} {:>8.4} {:>8.4} {:>8} {:>+6.3} [{:+.2},{:+.2}] {:<8} {}",
            s.iteration,
            s.cause,
            s.nrmse_before,
            s.nrmse_after,
            gain,
            s.gain_select,
            s.gain_ci[0],
            s.gain_ci[1],
            if s.accepted { "yes" } else { "no" },
            s.extension
        );
        if s.accepted {
            println!("{:<14} evidence: {}", "", s.evidence);
        }
    }
    println!();
    if r.causes.is_empty() {
        println!("causes: none - the model is adequate (no extension pays on held-out data)");
    } else {
        println!("causes: {}", r.causes.join(", "));
    }
    println!(
        "final: {}  NRMSE {:.4}  nll {:.3}",
        r.final_model.model, r.final_model.nrmse, r.final_model.nll
    );
}

fn run_fit(a: FitArgs, quiet: bool) -> Result<()> {
    if a.model != "state-space+damper"
        && (a.resonances.is_some() || a.sample_rate.is_some() || a.ridge.is_some())
    {
        return Err(
            "--resonances, --sample-rate and --ridge need --model state-space+damper".into(),
        );
    }
    if a.model.starts_with("state-space") {
        return run_fit_state_space(a.clone_for_state_space(), quiet);
    }
    if a.model == "wiener-hammerstein" {
        return run_fit_wiener_hammerstein(a, quiet);
    }
    if a.model == "lmn-state-space" {
        return run_fit_ss_lmn(a, quiet);
    }
    if a.output_max.is_some() {
        return Err("--output-max needs --model lmn-state-space".into());
    }
    let structure = Structure::parse(&a.model, a.order).map_err(|e| e.to_string())?;
    let data = load(&a.train, &a.signals)?;
    let lmn = lmn_params(&a, &structure, data.n_inputs())?;
    let min = 20 * (a.order + 1) * (data.n_inputs() + 1) + 50;
    data.check_identifiable(&a.train.display().to_string(), min)
        .map_err(|e| e.to_string())?;
    let pb = spinner(
        quiet,
        &format!("fitting {} of order {}", structure.spec(), a.order),
    );
    let mut records = vec![data.clone()];
    for f in &a.experiments {
        let e = load(f, &a.signals)?;
        if e.input_names != data.input_names || e.output_name != data.output_name {
            return Err(format!(
                "{}: signals {:?} -> {} differ from the training record's {:?} -> {}",
                f.display(),
                e.input_names,
                e.output_name,
                data.input_names,
                data.output_name
            ));
        }
        e.check_identifiable(&f.display().to_string(), 20)
            .map_err(|e| e.to_string())?;
        records.push(e);
    }
    let m = match &lmn {
        Some(p) => GreyBoxModel::fit_lmn_experiments(structure, &records, p),
        None => GreyBoxModel::fit(structure, &data, None, None, &ModelFitOptions::default()),
    }
    .map_err(|e| e.to_string())?;
    pb.finish_and_clear();
    let sim = m
        .simulate(&data.inputs, &data.output[..m.max_lag().min(data.len())])
        .map_err(|e| e.to_string())?;
    let k0 = m.max_lag();
    let nrmse =
        gb_core::metrics::nrmse(&data.output[k0..], &sim[k0..]).map_err(|e| e.to_string())?;
    m.save(&a.out).map_err(|e| e.to_string())?;
    println!("model: {}", m.describe());
    println!("parameters: {}", m.n_parameters());
    if let Some(l) = &m.lmn {
        println!(
            "leaves: {}, effective parameters {:.1}, chosen by {:?} ({:.4e}), pruned splits {}",
            l.n_leaves(),
            l.effective_parameters(),
            l.summary.criterion,
            l.summary.criterion_value,
            l.summary.pruned
        );
    }
    println!("training NRMSE (free-run simulation): {nrmse:.4}");
    println!("saved to {}", a.out.display());
    Ok(())
}

/// `greybox fit --model state-space[+preisach|+hysteresis]`: the
/// wavelet-sparse state-space class (gb-model). `+hysteresis` is the
/// hidden-hysteretic-state model `greybox diagnose` chooses.
fn run_fit_state_space(a: StateSpaceFit, quiet: bool) -> Result<()> {
    if a.order == 0 || a.order > gb_diagnose::MAX_ORDER {
        return Err(format!(
            "--order must be in 1..={}, got {}",
            gb_diagnose::MAX_ORDER,
            a.order
        ));
    }
    let preisach = match a.rest.as_str() {
        "" => false,
        "+preisach" => true,
        "+hysteresis" => return run_fit_hysteretic_state_space(a, quiet),
        "+damper" => return run_fit_damper(a, quiet),
        _ => {
            return Err(format!(
            "unknown model '{}': use state-space, state-space+preisach, state-space+hysteresis or state-space+damper",
            a.model
        ))
        }
    };
    let data = load(&a.train, &a.signals)?;
    data.check_identifiable(&a.train.display().to_string(), 20 * (a.order + 1) + 50)
        .map_err(|e| e.to_string())?;
    let mut names = data.input_names.clone();
    names.push(data.output_name.clone());
    let bar = FitBar::new(quiet);
    let (m, report) =
        gb_model::fit_state_space(&data.inputs, &data.output, a.order, preisach, names, &bar)
            .map_err(|e| e.to_string())?;
    save_state_space(&m, &report, &data, &a.out)
}

/// Writes a gb-model file (atomically) and prints what `fit` reports for it.
fn save_state_space(
    m: &gb_model::SparseStateSpace,
    report: &gb_model::OeReport,
    data: &DataSet,
    out: &Path,
) -> Result<()> {
    let bytes = m.to_bytes().map_err(|e| e.to_string())?;
    gb_core::write_atomic(out, &bytes).map_err(|e| e.to_string())?;
    println!("model: {}", m.describe());
    println!("parameters: {}", m.n_parameters());
    let sim = m.simulate(&data.inputs).map_err(|e| e.to_string())?;
    let nrmse = gb_core::metrics::nrmse(&data.output, &sim).map_err(|e| e.to_string())?;
    println!(
        "training NRMSE (free-run simulation): {nrmse:.4}; path {:?}, log-likelihood {:.1}",
        report.path, report.log_likelihood
    );
    println!("saved to {}", out.display());
    Ok(())
}

/// `greybox fit --model state-space+damper`: the Spencer-like MR damper
/// structure of gb-model (`MrDamperStructure`) on inputs D, V, Y [, A].
fn run_fit_damper(a: StateSpaceFit, quiet: bool) -> Result<()> {
    let data = load(&a.train, &a.signals)?;
    if !(3..=4).contains(&data.n_inputs()) {
        return Err(format!(
            "{}: --model state-space+damper takes 3 or 4 inputs (displacement, velocity, voltage [, acceleration], in that order), got {} ({})",
            a.train.display(),
            data.n_inputs(),
            data.input_names.join(", ")
        ));
    }
    data.check_identifiable(&a.train.display().to_string(), 500)
        .map_err(|e| e.to_string())?;
    let resonances_hz: Vec<f64> = match &a.resonances {
        None => Vec::new(),
        Some(v) => v
            .split(',')
            .map(|x| {
                x.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|f| *f > 0.0 && f.is_finite())
                    .ok_or_else(|| format!("--resonances: '{x}' is not a frequency > 0 in Hz"))
            })
            .collect::<Result<_>>()?,
    };
    let sample_rate = match a.sample_rate {
        Some(f) if f > 0.0 && f.is_finite() => f,
        Some(f) => return Err(format!("--sample-rate must be > 0, got {f}")),
        None if resonances_hz.is_empty() => 1.0,
        None => {
            let t = CsvTable::read(&a.train).map_err(|e| e.to_string())?;
            let col = t.column("t").map_err(|_| {
                format!(
                    "{}: no `t` column to take the sample rate from; give --sample-rate",
                    a.train.display()
                )
            })?;
            let n = col.len();
            let dt = if n > 1 {
                (col[n - 1] - col[0]) / (n - 1) as f64
            } else {
                0.0
            };
            if !(dt > 0.0 && dt.is_finite()) {
                return Err(format!(
                    "{}: column t does not increase; give --sample-rate",
                    a.train.display()
                ));
            }
            1.0 / dt
        }
    };
    let structure = gb_model::MrDamperStructure::new(sample_rate, resonances_hz);
    // without --ridge: 0 or 10³, chosen on the last 20 % of the record
    let ridges = match a.ridge {
        Some(r) if r >= 0.0 && r.is_finite() => vec![r],
        Some(r) => return Err(format!("--ridge must be finite and >= 0, got {r}")),
        None => vec![0.0, 1e3],
    };
    let bar = FitBar::new(quiet);
    let fit = structure
        .fit_validated(
            &gb_model::OeParams::new(),
            &ridges,
            &data.inputs,
            &data.output,
            &bar,
        )
        .map_err(|e| format!("--model state-space+damper: {e}"))?;
    for (_, r, e) in &fit.scores {
        println!("ridge {r:e}: NRMSE {e:.4} on the last 20 % (fitted on the first 80 %)");
    }
    let (mut m, report) = (fit.model, fit.report);
    let mut names = data.input_names.clone();
    names.push(data.output_name.clone());
    m.signal_names = names;
    save_state_space(&m, &report, &data, &a.out)
}

/// `greybox fit --model state-space+hysteresis`: a hidden hysteretic state
/// with a sparse wavelet law (`GreyBoxModel::fit_state_space`), saved as a
/// gb-model file.
fn run_fit_hysteretic_state_space(a: StateSpaceFit, quiet: bool) -> Result<()> {
    let data = load(&a.train, &a.signals)?;
    data.check_identifiable(&a.train.display().to_string(), 20 * (a.order + 1) + 50)
        .map_err(|e| e.to_string())?;
    let structure = Structure {
        state_space: true,
        hysteresis: true,
        ..Structure::linear(a.order)
    };
    let pb = spinner(quiet, "fitting a hidden hysteretic state");
    let g = GreyBoxModel::fit_state_space(structure, &data).map_err(|e| e.to_string())?;
    pb.finish_and_clear();
    let m = g
        .state_space
        .ok_or("the hidden-state fit returned no state-space model")?;
    let bytes = m.to_bytes().map_err(|e| e.to_string())?;
    gb_core::write_atomic(&a.out, &bytes).map_err(|e| e.to_string())?;
    println!("model: {}", m.describe());
    println!("parameters: {}", m.n_parameters());
    let sim = m.simulate(&data.inputs).map_err(|e| e.to_string())?;
    let nrmse = gb_core::metrics::nrmse(&data.output, &sim).map_err(|e| e.to_string())?;
    println!("training NRMSE (free-run simulation): {nrmse:.4}");
    println!("saved to {}", a.out.display());
    Ok(())
}

/// `greybox fit --model wiener-hammerstein`: a static local model network
/// between two linear filters (gb-lmn), from the best linear approximation.
fn run_fit_wiener_hammerstein(a: FitArgs, quiet: bool) -> Result<()> {
    let data = load(&a.train, &a.signals)?;
    if data.n_inputs() != 1 {
        return Err(format!(
            "{}: --model wiener-hammerstein needs exactly one input, got {} ({})",
            a.train.display(),
            data.n_inputs(),
            data.input_names.join(", ")
        ));
    }
    let leaves = a.max_leaves.unwrap_or(16);
    if !(1..=61).contains(&leaves) {
        return Err(format!("--max-leaves must be in 1..=61, got {leaves}"));
    }
    let params = gb_lmn::WhParams::new().knots(leaves - 1);
    data.check_identifiable(&a.train.display().to_string(), 1000)
        .map_err(|e| e.to_string())?;
    let pb = spinner(
        quiet,
        "Wiener-Hammerstein network: best linear approximation, pole/zero splits, LM",
    );
    let (m, rep) =
        GreyBoxModel::fit_wiener_hammerstein(&data, &params).map_err(|e| e.to_string())?;
    pb.finish_and_clear();
    m.save(&a.out).map_err(|e| e.to_string())?;
    println!("model: {}", m.describe());
    println!("parameters: {}", m.n_parameters());
    println!(
        "best linear approximation RMSE {:.4e}; {} pole/zero splits scanned, best {:.4e}; after LM {:.4e}",
        rep.bla_rmse, rep.splits_tried, rep.best_split_rmse, rep.rmse
    );
    let sim = m.simulate(&data.inputs, &[]).map_err(|e| e.to_string())?;
    let nrmse = gb_core::metrics::nrmse(&data.output, &sim).map_err(|e| e.to_string())?;
    println!("training NRMSE (free-run simulation): {nrmse:.4}");
    println!("saved to {}", a.out.display());
    Ok(())
}

/// `greybox fit --model lmn-state-space`: the state-space local model network
/// (gb-lmn `SsLmnModel`: hidden states, √ basis, learned state bounds).
fn run_fit_ss_lmn(a: FitArgs, quiet: bool) -> Result<()> {
    let data = load(&a.train, &a.signals)?;
    let leaves = a.max_leaves.unwrap_or(2);
    if !(1..=8).contains(&leaves) {
        return Err(format!(
            "--max-leaves must be in 1..=8 for lmn-state-space, got {leaves}"
        ));
    }
    if let Some(v) = a.output_max {
        if !v.is_finite() {
            return Err(format!("--output-max must be finite, got {v}"));
        }
    }
    let params = gb_lmn::SsLmnParams {
        n_states: a.order,
        leaves: (1..=leaves).collect(),
        output_upper: a.output_max,
        ..gb_lmn::SsLmnParams::default()
    };
    params
        .check(data.n_inputs())
        .map_err(|e| format!("--model lmn-state-space: {e}"))?;
    data.check_identifiable(&a.train.display().to_string(), 100)
        .map_err(|e| e.to_string())?;
    let pb = spinner(
        quiet,
        "state-space local model network: LM on the simulation error",
    );
    let m = GreyBoxModel::fit_ss_lmn(&data, &params).map_err(|e| e.to_string())?;
    pb.finish_and_clear();
    m.save(&a.out).map_err(|e| e.to_string())?;
    println!("model: {}", m.describe());
    println!("parameters: {}", m.n_parameters());
    let w = params.init_window.min(data.len());
    let sim = m
        .simulate_init_window(&data.inputs, &data.output[..w])
        .map_err(|e| e.to_string())?;
    let nrmse = gb_core::metrics::nrmse(&data.output[w..], &sim[w..]).map_err(|e| e.to_string())?;
    println!("training NRMSE (free-run simulation after a {w}-sample init window): {nrmse:.4}");
    println!("saved to {}", a.out.display());
    Ok(())
}

/// The arguments `run_fit_state_space` needs.
struct StateSpaceFit {
    model: String,
    rest: String,
    train: PathBuf,
    signals: SignalArgs,
    order: usize,
    out: PathBuf,
    resonances: Option<String>,
    sample_rate: Option<f64>,
    ridge: Option<f64>,
}

impl FitArgs {
    fn clone_for_state_space(self) -> StateSpaceFit {
        StateSpaceFit {
            rest: self.model.trim_start_matches("state-space").to_string(),
            model: self.model,
            train: self.train,
            signals: self.signals,
            order: self.order,
            out: self.out,
            resonances: self.resonances,
            sample_rate: self.sample_rate,
            ridge: self.ridge,
        }
    }
}

/// `greybox simulate` of a gb-model file (magic `GBS\x01`).
fn run_simulate_state_space(a: &SimulateArgs, bytes: &[u8]) -> Result<()> {
    let m = gb_model::SparseStateSpace::from_bytes(bytes)
        .map_err(|e| format!("{}: {e}", a.model.display()))?;
    let t = CsvTable::read(&a.data).map_err(|e| e.to_string())?;
    let (in_names, out_name): (Vec<String>, String) = if m.signal_names.is_empty() {
        (
            (0..m.n_inputs).map(|j| format!("u{}", j + 1)).collect(),
            "y".into(),
        )
    } else {
        let k = m.signal_names.len() - 1;
        (m.signal_names[..k].to_vec(), m.signal_names[k].clone())
    };
    let inputs: Vec<Vec<f64>> = in_names
        .iter()
        .map(|n| t.column(n).map(<[f64]>::to_vec))
        .collect::<std::result::Result<_, _>>()
        .map_err(|e| e.to_string())?;
    let y = t.column(&out_name).ok();
    if a.init_window > t.n_rows() {
        return Err(format!(
            "--init-window {} exceeds the {} samples of {}",
            a.init_window,
            t.n_rows(),
            a.data.display()
        ));
    }
    // with measured outputs and --init-window n, the initial state is
    // estimated from the first n of them; else the model's stored x0
    let sim = match y {
        Some(y) if a.init_window > 0 => m.simulate_init_window(&inputs, &y[..a.init_window]),
        _ => m.simulate(&inputs),
    }
    .map_err(|e| e.to_string())?;
    write_simulation(&a.out, &in_names, &inputs, y, &sim, a.init_window)
}

/// Writes the inputs, the measured output (if any) and `y_sim` to `out`
/// (atomically), then prints the errors over samples `n0..`.
fn write_simulation(
    out: &Path,
    in_names: &[String],
    inputs: &[Vec<f64>],
    y: Option<&[f64]>,
    sim: &[f64],
    n0: usize,
) -> Result<()> {
    let mut names: Vec<&str> = in_names.iter().map(String::as_str).collect();
    let mut cols: Vec<&[f64]> = inputs.iter().map(Vec::as_slice).collect();
    if let Some(y) = y {
        names.push("y");
        cols.push(y);
    }
    names.push("y_sim");
    cols.push(sim);
    gb_core::write_csv_atomic(out, &names, &cols).map_err(|e| e.to_string())?;
    if let Some(y) = y {
        let n0 = n0.min(y.len().saturating_sub(1));
        let rmse = gb_core::metrics::rmse(&y[n0..], &sim[n0..]).map_err(|e| e.to_string())?;
        let nrmse = gb_core::metrics::nrmse(&y[n0..], &sim[n0..]).map_err(|e| e.to_string())?;
        println!(
            "samples {}..{}: RMSE {rmse:.6e}  NRMSE {nrmse:.4}  fit {:.2}%",
            n0,
            y.len(),
            100.0 * (1.0 - nrmse)
        );
    }
    println!("simulation written to {}", out.display());
    Ok(())
}

fn run_simulate(a: SimulateArgs) -> Result<()> {
    if let Ok(bytes) = std::fs::read(&a.model) {
        if bytes.starts_with(gb_model::MAGIC) {
            return run_simulate_state_space(&a, &bytes);
        }
    }
    let m = GreyBoxModel::load(&a.model).map_err(|e| e.to_string())?;
    let t = CsvTable::read(&a.data).map_err(|e| e.to_string())?;
    let inputs: Vec<Vec<f64>> = m
        .input_names
        .iter()
        .map(|n| t.column(n).map(<[f64]>::to_vec))
        .collect::<std::result::Result<_, _>>()
        .map_err(|e| e.to_string())?;
    let y = t.column(&m.output_name).ok().map(<[f64]>::to_vec);
    if a.init_window > t.n_rows() {
        return Err(format!(
            "--init-window {} exceeds the {} samples of {}",
            a.init_window,
            t.n_rows(),
            a.data.display()
        ));
    }
    let init: Vec<f64> = match &y {
        Some(y) => y[..a.init_window.min(m.max_lag())].to_vec(),
        None if a.init_window > 0 => {
            return Err(format!(
                "{}: --init-window needs the output column '{}'",
                a.data.display(),
                m.output_name
            ))
        }
        None => vec![],
    };
    let sim = match &y {
        Some(y) if a.init_window > m.max_lag() => {
            m.simulate_init_window(&inputs, &y[..a.init_window])
        }
        _ => m.simulate(&inputs, &init).map_err(Into::into),
    }
    .map_err(|e| e.to_string())?;
    write_simulation(
        &a.out,
        &m.input_names,
        &inputs,
        y.as_deref(),
        &sim,
        a.init_window,
    )
}

fn run_generate(a: GenerateArgs) -> Result<()> {
    let g = systems::generate(&a.system, a.seed, a.samples, a.validate_samples)
        .map_err(|e| e.to_string())?;
    std::fs::create_dir_all(&a.out).map_err(|e| format!("{}: {e}", a.out.display()))?;
    let t_tr: Vec<f64> = (0..g.train.len()).map(|k| k as f64 * g.ts).collect();
    let t_va: Vec<f64> = (0..g.validate.len()).map(|k| k as f64 * g.ts).collect();
    let w = |name: &str, t: &[f64], d: &DataSet| {
        gb_core::write_csv_atomic(
            a.out.join(name),
            &["t", "u", "y"],
            &[t, &d.inputs[0], &d.output],
        )
        .map_err(|e| e.to_string())
    };
    w("train.csv", &t_tr, &g.train)?;
    w("validate.csv", &t_va, &g.validate)?;
    let truth = serde_json::json!({
        "system": g.system,
        "seed": g.seed,
        "expected_cause": g.expected_cause,
        "noise_std": g.noise_std,
        "noise_floor_nrmse": g.noise_floor_nrmse,
        "snr_db": g.snr_db,
        "ts": g.ts,
        "parameters": g.parameters.iter().map(|(k, v)| (k.clone(), *v)).collect::<std::collections::BTreeMap<_, _>>(),
    });
    let text = serde_json::to_string_pretty(&truth).map_err(|e| e.to_string())?;
    gb_core::write_atomic(a.out.join("truth.json"), text.as_bytes()).map_err(|e| e.to_string())?;
    println!(
        "{}: wrote {}/train.csv ({} samples), validate.csv ({}), truth.json; hidden effect: {}; noise floor NRMSE {:.4}",
        g.system,
        a.out.display(),
        g.train.len(),
        g.validate.len(),
        g.expected_cause.as_deref().unwrap_or("none"),
        g.noise_floor_nrmse
    );
    Ok(())
}

fn wavelet_setup(name: &str, mode: &str) -> Result<(gb_wavelet::Wavelet, gb_wavelet::Mode)> {
    let w = gb_wavelet::Wavelet::new(name).map_err(|e| format!("--wavelet: {e}"))?;
    let m: gb_wavelet::Mode = mode.parse().map_err(|e| format!("--mode: {e}"))?;
    Ok((w, m))
}

fn run_denoise(a: DenoiseArgs) -> Result<()> {
    let (w, mode) = wavelet_setup(&a.wavelet, &a.mode)?;
    let rule: gb_wavelet::ThresholdRule = a
        .threshold
        .parse()
        .map_err(|e| format!("--threshold: {e}"))?;
    let t = CsvTable::read(&a.data).map_err(|e| e.to_string())?;
    let x = t.column(&a.column).map_err(|e| e.to_string())?;
    let d = gb_wavelet::denoise_with(x, &w, &gb_wavelet::DenoiseOptions::new(rule, mode))
        .map_err(|e| format!("{}: column '{}': {e}", a.data.display(), a.column))?;
    let names: Vec<&str> = t.names.iter().map(String::as_str).collect();
    let cols: Vec<&[f64]> = t
        .names
        .iter()
        .zip(&t.columns)
        .map(|(n, c)| {
            if *n == a.column {
                d.signal.as_slice()
            } else {
                c.as_slice()
            }
        })
        .collect();
    gb_core::write_csv_atomic(&a.out, &names, &cols).map_err(|e| e.to_string())?;
    let removed = gb_core::metrics::rms(
        &x.iter()
            .zip(&d.signal)
            .map(|(p, q)| p - q)
            .collect::<Vec<_>>(),
    );
    println!(
        "{}: denoised '{}' with {} / {} thresholds (noise sigma {:.4e}, removed rms {:.4e}) -> {}",
        a.data.display(),
        a.column,
        a.wavelet,
        rule,
        d.sigma,
        removed,
        a.out.display()
    );
    Ok(())
}

fn run_wavelet(a: WaveletArgs) -> Result<()> {
    let (w, mode) = wavelet_setup(&a.wavelet, &a.mode)?;
    let t = CsvTable::read(&a.data).map_err(|e| e.to_string())?;
    let x = t.column(&a.column).map_err(|e| e.to_string())?;
    let bands = gb_wavelet::wavedec(x, &w, mode, a.level)
        .map_err(|e| format!("{}: column '{}': {e}", a.data.display(), a.column))?;
    let rows = gb_wavelet::coefficient_rows(&bands);
    let level: Vec<f64> = rows.iter().map(|r| r.0 as f64).collect();
    let index: Vec<f64> = rows.iter().map(|r| r.1 as f64).collect();
    let value: Vec<f64> = rows.iter().map(|r| r.2).collect();
    gb_core::write_csv_atomic(
        &a.out,
        &["level", "index", "value"],
        &[&level, &index, &value],
    )
    .map_err(|e| e.to_string())?;
    println!(
        "{}: {} coefficients in {} bands ({} levels, {}, {}) -> {}",
        a.data.display(),
        rows.len(),
        bands.len(),
        bands.len() - 1,
        a.wavelet,
        a.mode,
        a.out.display()
    );
    Ok(())
}

fn run_bench(a: BenchArgs, quiet: bool) -> Result<()> {
    let data_dir = a
        .data_dir
        .or_else(|| std::env::var_os("GREYBOX_DATA").map(PathBuf::from))
        .unwrap_or_else(|| PathBuf::from("../shared/data"));
    let results = if a.no_results {
        None
    } else {
        a.results
            .or_else(|| (!a.quick).then(|| PathBuf::from("docs/results.md")))
    };
    bench::run(&bench::BenchOptions {
        data_dir,
        only: a.only,
        quick: a.quick,
        quiet,
        results,
    })
    .map(|_| ())
}
