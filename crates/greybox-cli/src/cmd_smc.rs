//! The sequential Monte Carlo commands of the wavelet-sparse state-space
//! class: `greybox filter` (hidden-state estimates with 95 % bands) and
//! `greybox fit --method smc` (PMMH posterior of the noise scales and the
//! largest coefficients, with chain diagnostics).
use crate::io::load;
use crate::progress::Bar;
use crate::{FitArgs, Result};
use clap::Args;
use gb_core::{CsvTable, Records};
use gb_model::physics::PhysicsModel;
use gb_model::{SmcParams, SparseStateSpace};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Largest acceptable split-R̂ before the fit warns that the chain has not mixed.
const MAX_RHAT: f64 = 1.1;
/// Smallest acceptable effective sample size of every sampled quantity.
const MIN_ESS: f64 = 100.0;

#[derive(Args)]
pub(crate) struct FilterArgs {
    /// Model with process noise: the state-space class (`greybox fit --model state-space --method smc`) or a physics model (`greybox fit --model-file m.toml --method smc`; batch only, no --smooth).
    pub(crate) model: PathBuf,
    /// Data with the model's input columns and its output column; `-` reads rows from standard input (header first) and writes each filtered row to standard output as it arrives.
    pub(crate) data: PathBuf,
    /// Output CSV: the inputs, the output, then x1_mean,x1_lo,x1_hi,... (95 % band of the filter), and with --smooth x1_smooth_mean,x1_smooth_lo,x1_smooth_hi,...
    #[arg(short = 'o', long = "out", value_name = "FILE")]
    pub(crate) out: Option<PathBuf>,
    /// Also smooth: p(x_t | all data) by backward simulation (up to 200 trajectories).
    #[arg(long)]
    pub(crate) smooth: bool,
    /// Particles of the filter.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u64).range(1..=10_000_000))]
    pub(crate) particles: u64,
    /// Random seed (same seed, same result).
    #[arg(long, default_value_t = 1)]
    pub(crate) seed: u64,
    /// Output column (default: the model's output name).
    #[arg(long, value_name = "COLUMN")]
    pub(crate) output: Option<String>,
}

/// The `fit` options of the SMC path (flattened into `fit`).
#[derive(Args, Default)]
pub(crate) struct SmcArgs {
    /// Identification method: oe (output error, the default) or smc (PMMH from the output-error fit: `--model state-space` samples the noise scales and the largest wavelet coefficients, `--model-file` the free parameters, a process-noise level per non-kinematic state and the measurement noise).
    #[arg(long, value_name = "oe|smc", default_value = "oe")]
    pub(crate) method: String,
    /// `--method smc`: particles of the filter [default: 200].
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..=1_000_000))]
    pub(crate) particles: Option<u64>,
    /// `--method smc`: PMMH iterations, the first quarter burn-in [default: 2000].
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(8..=10_000_000))]
    pub(crate) iterations: Option<u64>,
    /// `--method smc`: random seed [default: 1].
    #[arg(long, value_name = "S")]
    pub(crate) seed: Option<u64>,
    /// `--method smc`: the tuned sampler — the particle number chosen in burn-in so that the sd of the log-likelihood estimate is about 1.2 (between --particles and this bound), the proposal adapted in burn-in only, then frozen [default: off, fixed particles].
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..=1_000_000))]
    pub(crate) max_particles: Option<u64>,
    /// `--method smc`: independent chains, run in parallel and pooled; the --iterations and burn-in are shared among them, and split-R̂ compares the chains [default: 2].
    #[arg(long, value_name = "K", value_parser = clap::value_parser!(u64).range(1..=64))]
    pub(crate) chains: Option<u64>,
}

impl SmcArgs {
    /// The validated PMMH settings (defaults 200 particles, 2000
    /// iterations, a quarter burn-in, 2 chains, seed 1), the particles and
    /// iterations.
    fn sampler(&self) -> Result<(gb_model::Smc, usize, usize)> {
        let iterations =
            usize::try_from(self.iterations.unwrap_or(2000)).map_err(|e| e.to_string())?;
        let particles =
            usize::try_from(self.particles.unwrap_or(200)).map_err(|e| e.to_string())?;
        let chains = self.chain_count();
        let mut smc = SmcParams::new()
            .particles(particles)
            .iterations(iterations, iterations / 4)
            .chains(chains)
            .seed(self.seed.unwrap_or(1));
        if let Some(max) = self.max_particles {
            smc = smc.tuned(usize::try_from(max).map_err(|e| e.to_string())?);
        }
        let smc = smc.check().map_err(|e| e.to_string())?;
        Ok((smc, particles, iterations))
    }

    /// The number of chains (default 2).
    fn chain_count(&self) -> usize {
        usize::try_from(self.chains.unwrap_or(2)).unwrap_or(2)
    }

    /// `--method smc` (an unknown method is an error).
    /// `--particles`, `--iterations` and `--seed` belong to `--method smc`:
    /// with the output-error method they are an error, not ignored.
    pub(crate) fn is_smc(&self) -> Result<bool> {
        match self.method.as_str() {
            "oe" => {
                let given = [
                    ("--particles", self.particles.is_some()),
                    ("--iterations", self.iterations.is_some()),
                    ("--seed", self.seed.is_some()),
                    ("--max-particles", self.max_particles.is_some()),
                    ("--chains", self.chains.is_some()),
                ];
                match given.iter().find(|(_, g)| *g) {
                    Some((flag, _)) => Err(format!(
                        "{flag} applies to --method smc only (the output-error fit is deterministic)"
                    )),
                    None => Ok(false),
                }
            }
            "smc" => Ok(true),
            m => Err(format!("--method '{m}': expected oe or smc")),
        }
    }
}

/// The state-space model of a model file, or an error naming its class.
fn state_space<'a>(path: &Path, m: &'a gb_core::FittedModel) -> Result<&'a SparseStateSpace> {
    m.dynamics
        .as_any()
        .downcast_ref::<SparseStateSpace>()
        .ok_or_else(|| {
            format!(
                "{}: `filter` needs a model of the state-space class (greybox fit --model state-space --method smc), this one is '{}'",
                path.display(),
                m.dynamics.class()
            )
        })
}

/// `greybox filter`: filtered (and smoothed) states with 95 % bands, and the
/// particle log-likelihood of the data. A physics model fitted by
/// `--method smc` is filtered from a file (no smoothing, no streaming).
pub fn filter(a: FilterArgs, quiet: bool) -> Result<()> {
    let m = gb_model::registry::load(&a.model).map_err(|e| e.to_string())?;
    let physics = m.dynamics.as_any().downcast_ref::<PhysicsModel>();
    let ss = match physics {
        Some(_) if a.smooth || a.data.as_os_str() == "-" => {
            return Err(format!(
                "{}: a physics model is filtered from a file, without --smooth (smoothing and streaming take state-space models)",
                a.model.display()
            ))
        }
        Some(_) => None,
        None => Some(state_space(&a.model, &m)?),
    };
    if ss.is_some_and(|ss| !ss.process_noise.iter().all(|n| n.is_valid())) {
        return Err(format!(
            "{}: the model has no process noise (an output-error fit), so the filter would only repeat the simulation; fit it with `greybox fit --model state-space --method smc`",
            a.model.display()
        ));
    }
    let out_name = a.output.clone().unwrap_or_else(|| m.output_name().into());
    let particles = usize::try_from(a.particles).map_err(|e| e.to_string())?;
    let smc = SmcParams::new()
        .particles(particles)
        .seed(a.seed)
        .check()
        .map_err(|e| e.to_string())?;
    if let (Some(ss), true) = (ss, a.data.as_os_str() == "-") {
        if a.out.is_some() || a.smooth {
            return Err(
                "filter MODEL - streams to standard output: no -o or --smooth (smoothing needs the whole record)"
                    .into(),
            );
        }
        return stream(&smc, ss, &m.input_names, &out_name);
    }
    let out = a
        .out
        .as_ref()
        .ok_or("-o FILE is needed (or `-` as DATA to stream rows from standard input)")?;
    let t = CsvTable::read(&a.data).map_err(|e| e.to_string())?;
    let inputs = crate::io::columns(&t, &m.input_names)?;
    let y = t.column(&out_name).map_err(|e| e.to_string())?.to_vec();
    let bar = Bar::spinner(quiet, &format!("filtering with {particles} particles"));
    let (est, states) = match (physics, ss) {
        (Some(pm), _) => (
            smc.filter_physics(pm, &inputs, &y)
                .map_err(|e| format!("{}: {e}", a.model.display()))?,
            pm.spec().states.iter().map(|s| s.name.clone()).collect(),
        ),
        (None, Some(ss)) => (
            smc.filter_states(ss, &inputs, &y, a.smooth)
                .map_err(|e| format!("{}: {e}", a.data.display()))?,
            (1..=ss.n_states)
                .map(|i| format!("x{i}"))
                .collect::<Vec<_>>(),
        ),
        (None, None) => return Err("no model to filter".into()),
    };
    bar.finish();
    let mut cols: Vec<&[f64]> = inputs.iter().map(Vec::as_slice).collect();
    cols.push(&y);
    let mut bands = vec![("", &est.filtered)];
    if let Some(s) = &est.smoothed {
        bands.push(("smooth_", s));
    }
    let mut names: Vec<String> = m.input_names.clone();
    names.push(out_name.clone());
    for (tag, b) in &bands {
        for (i, s) in states.iter().enumerate() {
            names.extend(["mean", "lo", "hi"].map(|k| format!("{s}_{tag}{k}")));
            cols.extend([&b.mean[i], &b.lo[i], &b.hi[i]].map(Vec::as_slice));
        }
    }
    let refs: Vec<&str> = names.iter().map(String::as_str).collect();
    gb_core::write_csv_atomic(out, &refs, &cols).map_err(|e| e.to_string())?;
    let mean_ess = est.ess.iter().sum::<f64>() / est.ess.len().max(1) as f64;
    println!(
        "{} samples, {} states, {particles} particles (mean ESS {mean_ess:.0}){}",
        y.len(),
        states.len(),
        if a.smooth { ", smoothed" } else { "" }
    );
    println!("log-likelihood: {:.4}", est.log_likelihood);
    println!("states written to {}", out.display());
    Ok(())
}

/// The band columns of the filter output: `x{i}_{tag}mean`,
/// `x{i}_{tag}lo`, `x{i}_{tag}hi` per state.
fn band_columns(n: usize, tag: &str) -> Vec<String> {
    (1..=n)
        .flat_map(|i| ["mean", "lo", "hi"].map(|k| format!("x{i}_{tag}{k}")))
        .collect()
}

/// `filter MODEL -`: rows from standard input, one at a time through the
/// online particle filter (the batch filter's particles, seed and random
/// streams, so the rows equal the batch output's); each row's inputs,
/// output and filtered states are written to standard output and flushed
/// at once, in the columns and number format of the batch output file.
fn stream(
    smc: &gb_model::Smc,
    ss: &SparseStateSpace,
    input_names: &[String],
    output: &str,
) -> Result<()> {
    let mut rows = crate::io::RowReader::new(std::io::stdin().lock(), "stdin")?;
    let ui: Vec<usize> = input_names
        .iter()
        .map(|n| rows.column(n))
        .collect::<Result<_>>()?;
    let yi = rows.column(output)?;
    let sm = gb_model::StreamingModel::new(ss).map_err(|e| e.to_string())?;
    let mut online = smc.online_states(&sm).map_err(|e| e.to_string())?;
    let mut names = input_names.to_vec();
    names.push(output.to_string());
    names.extend(band_columns(ss.n_states, ""));
    let mut out = std::io::stdout().lock();
    let io_err = |e: std::io::Error| format!("stdout: {e}");
    let (mut row, mut u) = (vec![], vec![0.0; ui.len()]);
    while rows.next_row(&mut row)? {
        for (v, &j) in u.iter_mut().zip(&ui) {
            *v = row[j];
        }
        let s = online
            .push(&u, row[yi])
            .map_err(|e| format!("stdin: row {}: {e}", rows.row()))?;
        if online.len() == 1 {
            writeln!(out, "{}", names.join(",")).map_err(io_err)?;
        }
        let mut line: Vec<String> = u.iter().map(f64::to_string).collect();
        line.push(row[yi].to_string());
        for i in 0..ss.n_states {
            line.extend([s.mean[i], s.lo[i], s.hi[i]].map(|v| v.to_string()));
        }
        writeln!(out, "{}", line.join(",")).map_err(io_err)?;
        out.flush().map_err(io_err)?;
    }
    if online.is_empty() {
        return Err(gb_core::CoreError::Empty {
            path: "stdin".into(),
        }
        .to_string());
    }
    Ok(())
}

/// `greybox fit --model state-space --method smc`: the output-error fit of
/// the recipe, then PMMH from it; prints the posterior of every sampled
/// quantity with its 95 % interval, ESS and split-R̂, and warns when the
/// chain has not mixed.
pub fn fit(a: &FitArgs, quiet: bool) -> Result<()> {
    if let Some(path) = &a.model_file {
        return fit_model_file(a, path, quiet);
    }
    let spec = crate::cmd_fit::spec_of(a)?;
    if spec.name != "state-space" || spec.has("damper") {
        return Err(format!(
            "--method smc needs --model state-space (or state-space+preisach, state-space+hysteresis), got '{spec}'"
        ));
    }
    gb_model::recipes::check_spec(&spec).map_err(|e| e.to_string())?;
    let d = load(&a.train, &a.signals)?;
    let data = Records::new(vec![d]).map_err(|e| e.to_string())?;
    let d = data.first();
    let bar = Bar::spinner(quiet, &format!("fitting {spec} (output error)"));
    let mut fitted = gb_model::recipes::fit(&spec, &data, &bar)
        .map_err(|e| format!("{}: {e}", a.train.display()))?
        .model;
    bar.finish();
    let oe = state_space(&a.train, &fitted)?.clone();
    let (smc, particles, iterations) = a.smc.sampler()?;
    let bar = Bar::new(quiet, iterations + 1, "PMMH");
    let (model, rep) = smc
        .fit(&oe, &d.inputs, &d.output, &bar)
        .map_err(|e| format!("{}: {e}", a.train.display()))?;
    bar.finish();
    fitted.dynamics = Box::new(model);
    fitted.save(&a.out).map_err(|e| e.to_string())?;
    println!("model: {}", fitted.describe());
    print_posterior(&rep, particles, iterations, a.smc.chain_count());
    println!("kept: {:?}", rep.path);
    println!("saved to {}", a.out.display());
    Ok(())
}

/// The printed posterior: every sampled quantity with its 95 % interval,
/// ESS and split-R̂, and a warning when the chain has not mixed.
fn print_posterior(rep: &gb_model::SmcReport, particles: usize, iterations: usize, chains: usize) {
    let chains_text = if chains > 1 {
        format!(
            " in {chains} parallel chains of {} (burn-in {} each)",
            iterations.div_ceil(chains),
            iterations / 4 / chains
        )
    } else {
        format!(" (burn-in {})", iterations / 4)
    };
    println!(
        "SMC: {particles} particles, {iterations} PMMH iterations{chains_text}, acceptance rate {:.3}",
        rep.acceptance_rate
    );
    if let Some(c) = rep.particle_choice {
        println!(
            "particles chosen at mid-burn-in: {} (sd of log p̂ {:.2} with {}, {:.2} with {}; target 1.2)",
            c.chosen, c.sd_before, c.before, c.sd_chosen, c.chosen
        );
    }
    println!(
        "log-likelihood (particle filter): output-error start {:.2}, posterior mean {:.2}",
        rep.log_likelihood_oe, rep.log_likelihood_smc
    );
    println!("posterior (mean, 95 % interval, effective sample size, split-R̂):");
    for p in &rep.parameters {
        println!(
            "  {:<22} {:>12.5e}  [{:.5e}, {:.5e}]  ESS {:>6.0}  R̂ {:.3}",
            p.name, p.mean, p.lo, p.hi, p.ess, p.rhat
        );
    }
    if !rep.mixed(MAX_RHAT, MIN_ESS) {
        let rhat = rep.parameters.iter().map(|p| p.rhat).fold(0.0, f64::max);
        let ess = rep
            .parameters
            .iter()
            .map(|p| p.ess)
            .fold(f64::INFINITY, f64::min);
        println!(
            "warning: the chain has not mixed (largest split-R̂ {rhat:.2}, limit {MAX_RHAT}; smallest ESS {ess:.0}, limit {MIN_ESS:.0}): the intervals are not reliable; run more --iterations"
        );
    }
}

/// `greybox fit --model-file m.toml --method smc`: the output-error fit of
/// the file (printed as `fit --model-file` prints it), then PMMH from it on
/// the training record (at most `SMC_SAMPLES` samples); prints the
/// posterior and saves the identified stochastic model (its parameters and
/// noise levels: `simulate` runs the deterministic part, `filter` the
/// particle filter).
fn fit_model_file(a: &FitArgs, path: &Path, quiet: bool) -> Result<()> {
    let mf = crate::cmd_physics::read_model_file(path)?;
    let d = crate::cmd_physics::load_for_model(&a.train, &a.signals, &mf, "--method smc")?;
    let (ts, _) = crate::cmd_physics::sample_time_of(&mf, &d, &a.train)?;
    let mut mf = mf;
    mf.spec.sample_time = Some(ts);
    let d = d.with_sample_time(ts);
    let bar = Bar::spinner(quiet, &format!("fitting {} (output error)", mf.name));
    let oe = mf
        .fit_growing(&Records::single(d.clone()), &bar)
        .map_err(|e| format!("{}: {e}", a.train.display()))?;
    bar.finish();
    if let Some(rep) = oe.fit_report() {
        for l in rep.lines() {
            println!("{l}");
        }
    }
    let n = d.len().min(SMC_SAMPLES);
    if n < d.len() {
        println!(
            "PMMH on the first {n} of {} samples (each iteration runs a particle filter over them)",
            d.len()
        );
    }
    let part = d.slice(0..n);
    let (smc, particles, iterations) = a.smc.sampler()?;
    let bar = Bar::new(quiet, iterations + 1, "PMMH");
    let (rep, model) = smc
        .fit_physics_model(&oe, &part, &bar)
        .map_err(|e| format!("{}: {e}", a.train.display()))?;
    bar.finish();
    print_posterior(&rep, particles, iterations, a.smc.chain_count());
    let levels = model.state_noise().map_or(String::new(), |n| {
        let mut v: Vec<String> = n
            .process_sd
            .iter()
            .zip(&model.spec().states)
            .filter_map(|(sd, s)| sd.map(|sd| format!("process sd [{}] {sd:.4e}", s.name)))
            .collect();
        v.push(format!("measurement sd {:.4e}", n.measurement_sd));
        v.join(", ")
    });
    let fitted = model.to_fitted().map_err(|e| e.to_string())?;
    fitted.save(&a.out).map_err(|e| e.to_string())?;
    println!(
        "saved to {} (parameters of the {:?} path; {levels}; `greybox filter` estimates the states with them)",
        a.out.display(),
        rep.path
    );
    Ok(())
}

/// Most training samples the PMMH of a model file runs on.
const SMC_SAMPLES: usize = 2000;
