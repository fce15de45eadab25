//! The `greybox` command-line tool.
use clap::{Args, Parser, Subcommand};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

mod bench;
mod cmd_diagnose;
mod cmd_fit;
mod cmd_physics;
mod cmd_simulate;
mod cmd_smc;
mod cmd_tools;
mod io;
mod progress;

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

CSV files need a header row. A uniform `t` (or `time`) column gives the
sample time; t/time/timestamp/k/sample/ts/index columns are never inputs.
Without --output the column `y` is the output (else an error lists the
columns). Errors name the file, row and column and exit with code 2.";

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
        after_help = "Examples:\n  greybox diagnose --example shock-absorber\n  greybox diagnose train.csv --validate val.csv --input u --output y --json report.json --report report.html\n  greybox diagnose data.csv --order auto --save model.gbm\n  greybox diagnose train.csv --validate val.csv --model-file examples/models/msd.toml\n  greybox diagnose long.csv --budget 120 --save model.gbm\n  greybox diagnose --train run1.csv --train run2.csv --validate run3.csv --json report.json\n\nSeveral records (the positional TRAIN and each --train FILE, same columns): no regressor and no simulated state spans two records. With --validate each training record is split into fit (first 75 %) and select (last 25 %) parts and the validation record is the report data; without it the last training record is the report data (held out whole) and the others are split 75/25; the model --save writes is then refitted on every training record whole, the held-out one included (kept when its free-run error over the records is not larger). Every record is simulated from its own start (its first samples are the init window); the select residuals of all records, concatenated in record order, make the decisions (moving-block bootstrap); with fewer than 300 select samples in all, leave-one-record-out cross-validation (each record held out whole, scored by the structure refitted on the other records). The input-output models (the linear baseline, its delay and order scans, the order, noise and hysteresis variants, the LOLIMOT networks) are fitted on the fit parts of all records (under cross-validation the records whole), each simulated from its own start; the block-oriented (Hammerstein, Wiener, Wiener-Hammerstein), polynomial NOE, state-space and physics models on one record, the longest fit part (under cross-validation the longest record); a Hammerstein or Wiener model is then trained on every record's fit part (its structure kept). The report lists the records and their fit/select samples. Not with --model-file or several --output.\n\nTime: records shorter than 100 000 training samples are searched whole (with fewer than 300 select samples, decisions use 4-fold blocked cross-validation — without --validate, on a record of 800 samples or more, over the whole record, its report block included, whose figures are then in-sample; the decisions line gives the cross-validated NRMSE — so every candidate is fitted five times, except a nonlinear or hysteresis candidate that gains less than 5 % on the training data in-sample, fitted once). No extension step starts after the --budget (300 s by default). Longer records are searched on their first 20 000 samples (fit/select 75/25) within it, then the baseline and the final structure are refitted on the whole fit block and every model is scored on the whole select and report blocks. Measured on 2 cores (docs/benchmarks.md, docs/results.md): a median of about 5 s for the generated systems of 600-13 000 samples, 4-240 s for the real benchmarks. A progress bar shows on a terminal (--quiet, or a pipe, hides it)."
    )]
    Diagnose(DiagnoseArgs),
    /// Fit a model of a given structure (a SPEC of the model registry).
    #[command(after_help = cmd_fit::help())]
    Fit(Box<FitArgs>),
    /// Simulate a saved model on the inputs of a CSV file (free run).
    #[command(
        after_help = "Examples:\n  greybox simulate model.gbm test.csv -o sim.csv --init-window 50\n  greybox simulate msd.gbm test.csv -o sim.csv --bands   # 95 % prediction band of a --model-file fit\n  sensor | greybox simulate model.gbm -                   # online: CSV rows on stdin (header first), one simulated row out per row in"
    )]
    Simulate(SimulateArgs),
    /// Estimate the hidden states of a saved state-space model by a particle filter (95 % bands).
    #[command(
        after_help = "Examples:\n  greybox fit train.csv --model state-space --method smc -o ss.gbm\n  greybox filter ss.gbm test.csv -o states.csv --smooth --particles 2000 --seed 3\n  sensor | greybox filter ss.gbm -                        # online: CSV rows on stdin (header first), one filtered row out per row in"
    )]
    Filter(cmd_smc::FilterArgs),
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
    /// Run the real benchmarks (Bouc-Wen, Silverbox, WH2009, tanks, EMPS, MR damper measured and simulated) and print the results table.
    #[command(
        after_help = "Benchmarks: bouc-wen, silverbox, wh2009, tanks, emps, mr-damper, mr-damper-sim\n\nEach benchmark, as a user would run it: `greybox diagnose TRAIN.csv` with the CLI's defaults on the whole training record (fit / select / report blocks of the training record; every decision on training data), then the final model is simulated in free run once on each official test set with its init window. The table shows that RMSE and the diagnosis' wall time next to the diagnosis' linear baseline, the hand-built recipe of the benchmark (a structure a person chose; not blind), the published LTI result and the best published result.\n\nExamples:\n  greybox bench --quick                       # a few minutes, subsets (CI)\n  greybox bench --only silverbox --only tanks\n  greybox bench --blind-only                  # skip the hand-built recipes\n  greybox bench --data-dir ../shared/data --results docs/results.md\n\nA missing data folder prints a notice and exits 0."
    )]
    Bench(BenchArgs),
}

#[derive(Args)]
pub(crate) struct BenchArgs {
    /// Folder with the benchmark data (default: $GREYBOX_DATA, else ../shared/data).
    #[arg(long, value_name = "DIR")]
    pub(crate) data_dir: Option<PathBuf>,
    /// Run only this benchmark (repeatable).
    #[arg(long, value_name = "NAME")]
    pub(crate) only: Vec<String>,
    /// Small subsets and one diagnosis step: minutes, for CI; not comparable with published numbers.
    #[arg(long)]
    pub(crate) quick: bool,
    /// Only the blind diagnosis: the hand-built recipes are not fitted (their column shows —; with --results the cells of the earlier run stay, marked "(earlier run)").
    #[arg(long)]
    pub(crate) blind_only: bool,
    /// Markdown file whose generated results block is replaced (default: docs/results.md for a full run, none for --quick); with --only, the rows of the other benchmarks stay.
    #[arg(long, value_name = "FILE")]
    pub(crate) results: Option<PathBuf>,
    /// Do not write a results file.
    #[arg(long, conflicts_with = "results")]
    pub(crate) no_results: bool,
}

#[derive(Args)]
pub(crate) struct DenoiseArgs {
    /// Input CSV.
    pub(crate) data: PathBuf,
    /// Column to denoise.
    #[arg(long)]
    pub(crate) column: String,
    /// Wavelet (haar, dbN, symN, coifN, biorX.Y, cdf53, cdf97).
    #[arg(long, default_value = "db8")]
    pub(crate) wavelet: String,
    /// Threshold rule: sure, universal, bayes (BayesShrink), ebayes (empirical Bayes).
    #[arg(long, default_value = "sure")]
    pub(crate) threshold: String,
    /// Signal extension mode: periodization, symmetric, zero, constant, periodic.
    #[arg(long, default_value = "symmetric")]
    pub(crate) mode: String,
    /// Output CSV.
    #[arg(short = 'o', long = "out", value_name = "FILE")]
    pub(crate) out: PathBuf,
}

#[derive(Args)]
pub(crate) struct WaveletArgs {
    /// Input CSV.
    pub(crate) data: PathBuf,
    /// Column to transform.
    #[arg(long)]
    pub(crate) column: String,
    /// Wavelet (haar, dbN, symN, coifN, biorX.Y, cdf53, cdf97).
    #[arg(long, default_value = "db4")]
    pub(crate) wavelet: String,
    /// Decomposition levels (default: the maximum useful level).
    #[arg(long)]
    pub(crate) level: Option<usize>,
    /// Signal extension mode: periodization, symmetric, zero, constant, periodic.
    #[arg(long, default_value = "symmetric")]
    pub(crate) mode: String,
    /// Output CSV with columns level,index,value.
    #[arg(short = 'o', long = "out", value_name = "FILE")]
    pub(crate) out: PathBuf,
}

#[derive(Args)]
pub(crate) struct SignalArgs {
    /// Input column (repeat for several inputs). Default: every column except the output, index/time columns and other output-like columns (y1, out, ...).
    #[arg(long = "input", value_name = "COLUMN")]
    pub(crate) inputs: Vec<String>,
    /// Output column; repeat it for several outputs (`fit`, `diagnose`: one model per output, sharing the inputs; no output is an input of another). Default: the column named `y` (an error listing the columns when there is none).
    #[arg(long = "output", value_name = "COLUMN")]
    pub(crate) outputs: Vec<String>,
}

impl SignalArgs {
    /// The one output column named (`None`: the default); an error when
    /// several are named where one is modelled.
    pub(crate) fn output(&self) -> Result<Option<&str>> {
        match self.outputs.as_slice() {
            [] => Ok(None),
            [one] => Ok(Some(one)),
            many => Err(format!(
                "{} --output columns where one output is modelled ({})",
                many.len(),
                many.join(", ")
            )),
        }
    }
}

#[derive(Args)]
pub(crate) struct DiagnoseArgs {
    /// Training data (CSV). Without --validate it is split into fit/select/report blocks.
    #[arg(required_unless_present_any = ["example", "more_train"])]
    pub(crate) train: Option<PathBuf>,
    /// A further training record (CSV, same columns; repeatable): each record is a separate experiment (see "Several records" below).
    #[arg(long = "train", value_name = "FILE", conflicts_with = "example")]
    pub(crate) more_train: Vec<PathBuf>,
    /// Validation data (CSV) on which the NRMSE is reported.
    #[arg(long)]
    pub(crate) validate: Option<PathBuf>,
    #[command(flatten)]
    pub(crate) signals: SignalArgs,
    /// Order of the engineer's linear output-error model, or `auto`.
    #[arg(long, default_value = "2")]
    pub(crate) order: String,
    /// Your own equations (TOML model file, docs/physics.md) as the baseline instead of the linear output-error model; extensions add terms to its state equations.
    #[arg(long, value_name = "FILE.toml", conflicts_with = "example")]
    pub(crate) model_file: Option<PathBuf>,
    /// Write the report as JSON.
    #[arg(long, value_name = "FILE")]
    pub(crate) json: Option<PathBuf>,
    /// Save the final model (postcard).
    #[arg(long, value_name = "FILE")]
    pub(crate) save: Option<PathBuf>,
    /// Write a self-contained HTML report with plots (measured vs simulated, residual tests, evidence per cause, the extension).
    #[arg(long, value_name = "FILE")]
    pub(crate) report: Option<PathBuf>,
    /// Run on a generated example instead of files: shock-absorber, or any `generate` system.
    #[arg(long, value_name = "NAME", conflicts_with = "train")]
    pub(crate) example: Option<String>,
    /// Most extension steps (1..=4).
    #[arg(long, default_value_t = 4)]
    pub(crate) max_steps: usize,
    /// Search budget of a long record in seconds (default 300): no new extension step starts after it; the structure found so far is refitted on the whole record and reported.
    #[arg(long, value_name = "SECONDS")]
    pub(crate) budget: Option<f64>,
}

#[derive(Args)]
pub(crate) struct FitArgs {
    /// Training data (CSV).
    pub(crate) train: PathBuf,
    /// Model SPEC: NAME[+COMPONENT...][:KEY=VALUE,...] (see below).
    #[arg(long, default_value = "linear")]
    pub(crate) model: String,
    /// Your own equations: a TOML model file (states, parameters, equations, outputs; see docs/physics.md), fitted with standard errors and 95 % intervals.
    #[arg(long, value_name = "FILE.toml", conflicts_with = "model")]
    pub(crate) model_file: Option<PathBuf>,
    /// Dynamic order n (the option order=N of the SPEC), or `auto`: order and input delay chosen on the training data as `diagnose --order auto` chooses its baseline's. Default: `auto` when neither this flag nor order= in the SPEC is given (for recipes with an order option).
    #[arg(long, value_name = "N|auto")]
    pub(crate) order: Option<String>,
    #[command(flatten)]
    pub(crate) signals: SignalArgs,
    /// Model file to write.
    #[arg(short = 'o', long = "out", value_name = "FILE")]
    pub(crate) out: PathBuf,
    /// `--model lmn` only: validity functions, gauss (normalised Gaussians, LOLIMOT) or tree (decision-tree sigmoids). Any of --weights/--splits/--prune/--focus/--max-leaves selects the full local model network (x = z = the order-n regressors).
    #[arg(long, value_name = "gauss|tree")]
    pub(crate) weights: Option<String>,
    /// `--model lmn` only: axis (LOLIMOT) or oblique (HILOMOT, tree weights) splits.
    #[arg(long, value_name = "axis|oblique")]
    pub(crate) splits: Option<String>,
    /// `--model lmn` only: remove splits that do not pay by AICc after growing.
    #[arg(long)]
    pub(crate) prune: bool,
    /// `--model lmn` only: train for free-run simulation (NOE) or one-step prediction (NARX).
    #[arg(long, value_name = "simulation|prediction")]
    pub(crate) focus: Option<String>,
    /// `--model lmn` only: largest number of local models.
    #[arg(long, value_name = "N")]
    pub(crate) max_leaves: Option<usize>,
    /// `--model lmn` only: degree of the local models, 1 (affine) to 3 (polynomial).
    #[arg(long, value_name = "D")]
    pub(crate) degree: Option<usize>,
    /// `--model lmn` only: input dead time (delays k-d..k-d-n+1; 0 = direct feed-through); one value for every input or one per input (`1,0,2`).
    #[arg(long, value_name = "D[,D..]")]
    pub(crate) dead_time: Option<String>,
    /// `--model lmn` only: number of lags of each input (default: the order); one value or one per input (`4,2`).
    #[arg(long, value_name = "N[,N..]")]
    pub(crate) input_lags: Option<String>,
    /// `--model lmn` only: number of output lags y(k-1..k-N) (default: the order).
    #[arg(long, value_name = "N")]
    pub(crate) output_lags: Option<usize>,
    /// `--model lmn-state-space` only: known upper limit of the output (sensor range), e.g. 10.
    #[arg(long, value_name = "Y")]
    pub(crate) output_max: Option<f64>,
    /// `--model lmn` and `--model-file` only: a further training record, fitted as a separate experiment (no regressor spans two records); repeatable.
    #[arg(long = "experiment", value_name = "FILE")]
    pub(crate) experiments: Vec<PathBuf>,
    /// `--model lmn` only: growth criterion, aicc or bic.
    #[arg(long, value_name = "aicc|bic")]
    pub(crate) criterion: Option<String>,
    /// `--model lmn` only: partition space, all (every regressor) or y1 (the last output only).
    #[arg(long, value_name = "all|y1")]
    pub(crate) partition: Option<String>,
    /// `--model state-space+damper` only: start frequencies (Hz) of test-rig resonances seen in the force, one 2-state block each (`150,120`; default none).
    #[arg(long, value_name = "HZ[,HZ..]")]
    pub(crate) resonances: Option<String>,
    /// `--model state-space+damper` only: sample rate in Hz (default: from a `t` column of the training file).
    #[arg(long, value_name = "HZ")]
    pub(crate) sample_rate: Option<f64>,
    #[command(flatten)]
    pub(crate) smc: cmd_smc::SmcArgs,
    /// `--model state-space+damper` only: Tikhonov weight on the wavelet coefficients (output units squared per squared coefficient; default: 0 or 1000, chosen on the last 20 % of the training record).
    #[arg(long, value_name = "RHO")]
    pub(crate) ridge: Option<f64>,
}

#[derive(Args)]
pub(crate) struct SimulateArgs {
    /// Model file written by `fit` or `diagnose --save`.
    pub(crate) model: PathBuf,
    /// Data with the model's input columns (and optionally its output column); `-` streams rows from standard input: each simulated row is written to standard output as soon as it is computed.
    pub(crate) data: PathBuf,
    /// Output CSV: the inputs, the measured output if present, and y_sim (not with `-`: rows go to standard output).
    #[arg(short = 'o', long = "out", value_name = "FILE")]
    pub(crate) out: Option<PathBuf>,
    /// The first N measured outputs initialise the state (estimated by least squares when N exceeds the model's lags); errors are reported on samples N.. only.
    #[arg(long, default_value_t = 0)]
    pub(crate) init_window: usize,
    /// Add y_sim_lo and y_sim_hi: the 95 % prediction band (parameter uncertainty propagated plus noise); models fitted with --model-file only.
    #[arg(long)]
    pub(crate) bands: bool,
}

#[derive(Args)]
pub(crate) struct GenerateArgs {
    /// System name (see below).
    pub(crate) system: String,
    /// Output directory (created if missing).
    #[arg(short = 'o', long = "out", value_name = "DIR")]
    pub(crate) out: PathBuf,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    pub(crate) seed: u64,
    /// Training samples.
    #[arg(long, default_value_t = 8000)]
    pub(crate) samples: usize,
    /// Validation samples.
    #[arg(long, default_value_t = 4000)]
    pub(crate) validate_samples: usize,
}

pub(crate) type Result<T> = std::result::Result<T, String>;

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
        Command::Diagnose(a) => cmd_diagnose::run(a, quiet),
        Command::Fit(a) => cmd_fit::run(*a, quiet),
        Command::Simulate(a) => cmd_simulate::run(a),
        Command::Filter(a) => cmd_smc::filter(a, quiet),
        Command::Generate(a) => cmd_tools::generate(a),
        Command::Denoise(a) => cmd_tools::denoise(a),
        Command::Wavelet(a) => cmd_tools::wavelet(a),
        Command::Bench(a) => cmd_tools::bench(a, quiet),
    };
    match r {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("greybox: error: {e}");
            ExitCode::from(2)
        }
    }
}
