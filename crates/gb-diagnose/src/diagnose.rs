//! The diagnosis loop: simulate the engineer's model, compute residual
//! evidence, fit every candidate extension, keep the one whose gain on
//! held-out data is significant (moving-block bootstrap), repeat.
use crate::evidence::Evidence;
use crate::model::{GreyBoxModel, ModelFitOptions, Structure, MAX_ORDER};
use crate::{stats, DiagnoseError};
use gb_core::{metrics, DataSet};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::ops::Range;

/// Samples at the start of every evaluated record that form the init
/// window: the initial state is estimated from them by least squares, and
/// they are not scored (the benchmark convention).
pub const EVAL_SKIP: usize = 50;

/// The fixed vocabulary of causes.
pub const CAUSES: [&str; 4] = ["nonlinearity", "hysteresis", "dynamics", "noise"];

/// How the baseline order is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OrderChoice {
    /// The engineer's order.
    Fixed(usize),
    /// Select 1..=6 on the select block.
    Auto,
}

/// A progress observer (a progress bar plugs in here).
pub trait Observer: Sync {
    /// `done` of `total` units of work finished; `message` says what runs now.
    fn progress(&self, done: usize, total: usize, message: &str);
}

/// Options of [`diagnose`].
#[derive(Clone)]
pub struct DiagnoseOptions {
    /// Baseline order.
    pub order: OrderChoice,
    /// Most extension steps.
    pub max_steps: usize,
    /// Smallest relative NRMSE gain on the select block that counts.
    pub min_gain: f64,
    /// Smallest nll gain per sample (nats) that counts for `noise`.
    pub min_nll_gain: f64,
    /// Bootstrap replicates.
    pub bootstrap: usize,
    /// Seed of the bootstrap.
    pub seed: u64,
    /// Fitting options.
    pub fit: ModelFitOptions,
}

impl Default for DiagnoseOptions {
    fn default() -> Self {
        Self {
            order: OrderChoice::Fixed(2),
            max_steps: 4,
            min_gain: 0.05,
            min_nll_gain: 0.02,
            bootstrap: 400,
            seed: 1,
            fit: ModelFitOptions::default(),
        }
    }
}

impl DiagnoseOptions {
    /// Validate.
    pub fn check(&self) -> Result<(), DiagnoseError> {
        if let OrderChoice::Fixed(n) = self.order {
            if n == 0 || n > MAX_ORDER {
                return Err(DiagnoseError::InvalidArgument(format!(
                    "order must be in 1..={MAX_ORDER}, got {n}"
                )));
            }
        }
        if self.max_steps > 4 {
            return Err(DiagnoseError::InvalidArgument(
                "at most 4 extension steps".into(),
            ));
        }
        if !(0.0..1.0).contains(&self.min_gain) || self.bootstrap < 50 {
            return Err(DiagnoseError::InvalidArgument(
                "min_gain in [0,1), bootstrap >= 50".into(),
            ));
        }
        Ok(())
    }
}

/// The data of a diagnosis: one record holding the fit and select blocks
/// (contiguous) and the report data (a separate record, or the tail of the
/// same one).
#[derive(Debug, Clone)]
pub struct DiagnoseData {
    /// Record with the fit and select blocks.
    pub train: DataSet,
    /// Fit block range in `train`.
    pub fit: Range<usize>,
    /// Select block range in `train`.
    pub select: Range<usize>,
    /// Record holding the report block.
    pub report: DataSet,
    /// Report block range in `report`.
    pub report_range: Range<usize>,
}

impl DiagnoseData {
    /// Train file split 75/25 into fit/select; the validation file is the report data.
    pub fn with_validation(train: DataSet, validate: DataSet) -> Result<Self, DiagnoseError> {
        check_same_signals(&train, &validate)?;
        let s = train.split_blocks(0.75, 0.25);
        let n = validate.len();
        Ok(Self {
            fit: 0..s.fit_end,
            select: s.fit_end..s.len,
            report_range: EVAL_SKIP.min(n)..n,
            report: validate,
            train,
        })
    }

    /// One record split into contiguous fit (50 %), select (25 %) and report (25 %) blocks.
    pub fn from_single(data: DataSet) -> Self {
        let s = data.split_blocks(0.5, 0.25);
        Self {
            fit: 0..s.fit_end,
            select: s.fit_end..s.select_end,
            report_range: s.select_end..s.len,
            report: data.clone(),
            train: data,
        }
    }

    fn check(&self, min_fit: usize) -> Result<(), DiagnoseError> {
        let fit = self.train.slice(self.fit.clone());
        fit.check_identifiable("fit block", min_fit)?;
        if self.select.len() < 100 || self.report_range.len() < 100 {
            return Err(DiagnoseError::Core(gb_core::CoreError::TooShort {
                context: "select/report blocks".into(),
                needed: 100,
                got: self.select.len().min(self.report_range.len()),
            }));
        }
        Ok(())
    }
}

fn check_same_signals(a: &DataSet, b: &DataSet) -> Result<(), DiagnoseError> {
    if a.input_names != b.input_names || a.output_name != b.output_name {
        return Err(DiagnoseError::InvalidArgument(format!(
            "training signals ({} -> {}) differ from validation signals ({} -> {})",
            a.input_names.join(","),
            a.output_name,
            b.input_names.join(","),
            b.output_name
        )));
    }
    Ok(())
}

/// Residuals and simulated output of `model` on `range` of `data`,
/// simulating from the record's start (initialised with measured outputs).
pub fn residuals_on(
    model: &GreyBoxModel,
    data: &DataSet,
    range: &Range<usize>,
) -> Result<(Vec<f64>, Vec<f64>), DiagnoseError> {
    let end = range.end;
    let inputs: Vec<Vec<f64>> = data.inputs.iter().map(|u| u[..end].to_vec()).collect();
    // initial state estimated from the first EVAL_SKIP measured outputs
    let sim = model.simulate_init_window(&inputs, &data.output[..EVAL_SKIP.min(end)])?;
    let start = range.start.max(EVAL_SKIP);
    let e = (start..end).map(|k| data.output[k] - sim[k]).collect();
    Ok((e, sim[start..end].to_vec()))
}

/// Scores of one model.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Scores {
    /// NRMSE on the select block.
    pub nrmse_select: f64,
    /// NRMSE on the report block.
    pub nrmse: f64,
    /// Mean nll per sample on the select block.
    pub nll_select: f64,
    /// Mean nll per sample on the report block.
    pub nll: f64,
}

struct Evaluated {
    model: GreyBoxModel,
    scores: Scores,
    e_select: Vec<f64>,
    yhat_select: Vec<f64>,
}

fn evaluate(model: GreyBoxModel, d: &DiagnoseData) -> Result<Evaluated, DiagnoseError> {
    let (es, ys) = residuals_on(&model, &d.train, &d.select)?;
    let (er, _) = residuals_on(&model, &d.report, &d.report_range)?;
    let start_s = d.select.start.max(EVAL_SKIP);
    let start_r = d.report_range.start.max(EVAL_SKIP);
    let sd_s = metrics::std(&d.train.output[start_s..d.select.end]);
    let sd_r = metrics::std(&d.report.output[start_r..d.report_range.end]);
    let noise = model.network.noise.clone();
    let scores = Scores {
        nrmse_select: metrics::rms(&es) / sd_s,
        nrmse: metrics::rms(&er) / sd_r,
        nll_select: noise.mean_nll(&es),
        nll: noise.mean_nll(&er),
    };
    if !(scores.nrmse.is_finite() && scores.nrmse_select.is_finite() && scores.nll.is_finite()) {
        return Err(DiagnoseError::Lmn(gb_lmn::LmnError::Unstable(
            "non-finite score".into(),
        )));
    }
    Ok(Evaluated {
        model,
        scores,
        e_select: es,
        yhat_select: ys,
    })
}

/// One row of the diagnosis: a candidate extension and whether it paid.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Step {
    /// Iteration (1-based).
    pub iteration: usize,
    /// Cause from the fixed vocabulary.
    pub cause: String,
    /// Residual evidence for the cause.
    pub evidence: String,
    /// The extension fitted.
    pub extension: String,
    /// Report-block NRMSE before.
    pub nrmse_before: f64,
    /// Report-block NRMSE after.
    pub nrmse_after: f64,
    /// Gain on the report block: relative NRMSE reduction (structural causes)
    /// or nll reduction per sample (noise).
    pub gain: f64,
    /// Which metric `gain` is: "nrmse" or "nll".
    pub gain_metric: String,
    /// Gain on the select block (the decision's data).
    pub gain_select: f64,
    /// 95 % moving-block-bootstrap interval of the select-block gain.
    pub gain_ci: [f64; 2],
    /// Report-block nll per sample before.
    pub nll_before: f64,
    /// Report-block nll per sample after.
    pub nll_after: f64,
    /// Whether the extension was kept.
    pub accepted: bool,
}

/// Summary of a model in the report.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ModelSummary {
    /// Description.
    pub model: String,
    /// SPEC string (`greybox fit --model`).
    pub spec: String,
    /// Order.
    pub order: usize,
    /// Report-block NRMSE (free-run simulation).
    pub nrmse: f64,
    /// Report-block nll per sample.
    pub nll: f64,
    /// Select-block NRMSE.
    pub nrmse_select: f64,
    /// Parameters.
    pub parameters: usize,
}

/// Data description in the report.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DataSummary {
    /// Input names.
    pub inputs: Vec<String>,
    /// Output name.
    pub output: String,
    /// Samples used for fitting.
    pub samples_fit: usize,
    /// Samples of the select block.
    pub samples_select: usize,
    /// Samples the report NRMSE is computed on.
    pub samples_validate: usize,
    /// How the data were split.
    pub split: String,
}

/// The diagnosis (the `--json` report).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Report {
    /// Report format version.
    pub version: u32,
    /// Data description.
    pub data: DataSummary,
    /// The engineer's model.
    pub baseline: ModelSummary,
    /// Candidate extensions, per iteration.
    pub steps: Vec<Step>,
    /// Accepted causes in order (`[]`: the model is adequate).
    pub causes: Vec<String>,
    /// The final model.
    #[serde(rename = "final")]
    pub final_model: ModelSummary,
    /// Residual evidence of the baseline (select block).
    pub evidence: Evidence,
    /// Residual evidence of the final model.
    pub final_evidence: Evidence,
}

fn summary(e: &Evaluated) -> ModelSummary {
    ModelSummary {
        model: e.model.describe(),
        spec: e.model.structure.spec(),
        order: e.model.structure.order,
        nrmse: e.scores.nrmse,
        nll: e.scores.nll,
        nrmse_select: e.scores.nrmse_select,
        parameters: e.model.n_parameters(),
    }
}

/// Result of [`diagnose`]: the report and the final model.
pub struct Diagnosis {
    /// The report.
    pub report: Report,
    /// The final (possibly extended) model.
    pub model: GreyBoxModel,
    /// The baseline and the model after each accepted step, in order
    /// (`chain[0]` is the baseline, the last entry equals `model`).
    pub chain: Vec<GreyBoxModel>,
}

/// The model with both a network and hysteresis for a tie: the network with
/// zero-weight hysteresis columns trained further by LM, or the hysteresis
/// model itself (a one-leaf network), whichever simulates the fit data better.
fn fit_combined(
    both: Structure,
    lmn: &GreyBoxModel,
    hyst: &GreyBoxModel,
    fit: &DataSet,
    o: &ModelFitOptions,
) -> Result<GreyBoxModel, DiagnoseError> {
    let spec = both.network_spec(fit.n_inputs());
    let mut best = GreyBoxModel {
        structure: both,
        ..hyst.clone()
    };
    let res = |m: &GreyBoxModel| -> f64 {
        m.network
            .simulation_residuals(&fit.inputs, &fit.output)
            .map_or(f64::INFINITY, |e| metrics::rms(&e))
    };
    let mut best_cost = res(&best);
    if let Some(start) = gb_lmn::embed_hysteresis(&lmn.network, &spec) {
        if let Ok((net, _)) = gb_lmn::refine_output_error(&start, &fit.inputs, &fit.output, &o.fit)
        {
            let cand = GreyBoxModel {
                network: net,
                structure: both,
                ..lmn.clone()
            };
            let c = res(&cand);
            if c < best_cost {
                best_cost = c;
                best = cand;
            }
        }
    }
    let _ = best_cost;
    Ok(best)
}

fn fit_eval(
    s: Structure,
    d: &DiagnoseData,
    fit: &DataSet,
    yreg: Option<&[f64]>,
    warm: Option<&GreyBoxModel>,
    o: &ModelFitOptions,
) -> Result<Evaluated, DiagnoseError> {
    let t0 = std::time::Instant::now();
    let m = GreyBoxModel::fit(s, fit, yreg, warm, o)?;
    if std::env::var_os("GREYBOX_TIMING").is_some() {
        eprintln!(
            "fit {} order {}: {:.2}s",
            s.spec(),
            s.order,
            t0.elapsed().as_secs_f64()
        );
    }
    evaluate(m, d)
}

struct Candidate {
    cause: &'static str,
    structure: Structure,
    extension: String,
    /// More capacity for an already named cause (names nothing new).
    refine: bool,
}

/// p-value below which the residual evidence for a cause that the model's
/// simple extension already addresses still counts as unexplained.
const STILL_FLAGGED_P: f64 = 1e-3;
/// Most fit-block samples the hidden-state model is fitted on (its
/// output-error fit is the costliest; the select block judges it as usual).
const SS_FIT_SAMPLES: usize = 4000;

fn candidates(cur: Structure, causes: &[String], tried_noise: bool) -> Vec<Candidate> {
    let mut v = vec![];
    if cur.state_space {
        // the hidden-state model is the last extension the diagnosis offers
        return v;
    }
    // "more of what we have": a new cause must beat it
    let last_structural = causes
        .iter()
        .rev()
        .find(|c| *c == "nonlinearity" || *c == "hysteresis");
    if let Some(c) = last_structural {
        if cur.detail < 2 {
            // more local models / operators, and one more lag of every
            // regressor: a nonlinear force inside continuous dynamics reaches
            // the sampled output through more lags than the linear part needs
            let s = Structure {
                detail: cur.detail + 1,
                order: (cur.order + 1).min(MAX_ORDER),
                ..cur
            };
            let cause = if c == "nonlinearity" {
                "nonlinearity"
            } else {
                "hysteresis"
            };
            v.push(Candidate {
                cause,
                structure: s,
                extension: if s.network && cause == "nonlinearity" {
                    format!(
                        "more capacity for the named nonlinearity: up to {} local models, regressor lags {}",
                        s.max_leaves(),
                        s.order
                    )
                } else {
                    format!(
                        "more capacity for the named hysteresis: {} play operators and {} relays on the output, regressor lags {}",
                        6 * (1 + s.detail as usize),
                        {
                            let l = 6 + 2 * s.detail as usize;
                            l * (l + 1) / 2
                        },
                        s.order
                    )
                },
                refine: true,
            });
        }
    }
    if !cur.network {
        v.push(Candidate {
            cause: "nonlinearity",
            structure: Structure { network: true, ..cur },
            extension: "local model network (LOLIMOT, normalised Gaussian validity functions) on the same regressors, trained output-error".into(),
            refine: false,
        });
    }
    if !cur.hysteresis {
        v.push(Candidate {
            cause: "hysteresis",
            structure: Structure { hysteresis: true, ..cur },
            extension: "Preisach component on the simulated output (6 play operators + a 21-relay discrete Preisach operator) and 8 play operators per input, at lags 1..n+1, weights linear, trained output-error".into(),
            refine: false,
        });
    }
    for add in [1, 2] {
        if cur.order + add <= MAX_ORDER {
            v.push(Candidate {
                cause: "dynamics",
                structure: Structure {
                    order: cur.order + add,
                    ..cur
                },
                extension: format!("order {} -> {}", cur.order, cur.order + add),
                refine: false,
            });
        }
    }
    if !cur.robust_noise && !tried_noise {
        v.push(Candidate {
            cause: "noise",
            structure: Structure {
                robust_noise: true,
                ..cur
            },
            extension: "Student-t noise model, robust (IRLS) output-error fit".into(),
            refine: false,
        });
    }
    v
}

/// The hidden-state model of `gb-model`, offered when the simpler
/// extensions do not suffice: a structural cause (`hysteresis` or
/// `dynamics`) is already named and addressed by its simple extension, no
/// new cause pays in this iteration, and the residuals are still not white
/// (Ljung–Box or the direction-of-motion memory test at p < 10⁻³).
fn state_space_candidate(cur: Structure, causes: &[String], ev: &Evidence) -> Option<Candidate> {
    if cur.state_space {
        return None;
    }
    let named = |c: &str| causes.iter().any(|x| x == c);
    let unexplained = ev.ljung_box.1 < STILL_FLAGGED_P || ev.memory.1 < STILL_FLAGGED_P;
    if !unexplained {
        return None;
    }
    if named("hysteresis") && cur.hysteresis {
        return Some(Candidate {
            cause: "hysteresis",
            structure: Structure {
                state_space: true,
                network: false,
                detail: 0,
                ..cur
            },
            extension: "hidden-state model (gb-model): a hidden hysteretic state with a sparse wavelet law (mechanical structure with restoring force z, ż = f(v, z), when the linear model oscillates; else hidden states with f(x₁, u₁) and a Preisach component with a wavelet Everett function), trained output-error".into(),
            refine: false,
        });
    }
    if named("dynamics") {
        return Some(Candidate {
            cause: "dynamics",
            structure: Structure {
                state_space: true,
                network: false,
                detail: 0,
                ..cur
            },
            extension: format!(
                "hidden-state model (gb-model): {} hidden states with a sparse wavelet term f(x₁, u₁), trained output-error",
                cur.order
            ),
            refine: false,
        });
    }
    None
}

fn relative_gain_ci(
    before: &[f64],
    after: &[f64],
    block: usize,
    reps: usize,
    seed: u64,
) -> (f64, [f64; 2]) {
    let sb: f64 = before.iter().map(|v| v * v).sum();
    let sa: f64 = after.iter().map(|v| v * v).sum();
    let g = 1.0 - (sa / sb.max(1e-300)).sqrt();
    let (lo, hi) = stats::block_bootstrap(before.len(), block, reps, seed, |idx| {
        let (mut b, mut a) = (0.0, 0.0);
        for &i in idx {
            b += before[i] * before[i];
            a += after[i] * after[i];
        }
        1.0 - (a / b.max(1e-300)).sqrt()
    });
    (g, [lo, hi])
}

fn nll_gain_ci(nb: &[f64], na: &[f64], block: usize, reps: usize, seed: u64) -> (f64, [f64; 2]) {
    let d: Vec<f64> = nb.iter().zip(na).map(|(a, b)| a - b).collect();
    let g = metrics::mean(&d);
    let (lo, hi) = stats::block_bootstrap(d.len(), block, reps, seed, |idx| {
        idx.iter().map(|&i| d[i]).sum::<f64>() / idx.len() as f64
    });
    (g, [lo, hi])
}

/// Run the diagnosis.
pub fn diagnose(
    d: &DiagnoseData,
    opts: &DiagnoseOptions,
    obs: Option<&dyn Observer>,
) -> Result<Diagnosis, DiagnoseError> {
    opts.check()?;
    d.check(60)?;
    let fit = d.train.slice(d.fit.clone());
    let progress = |done: usize, total: usize, msg: &str| {
        if let Some(o) = obs {
            o.progress(done, total, msg);
        }
    };
    let total = 1 + opts.max_steps;
    progress(0, total, "fitting the baseline");
    let base = match opts.order {
        OrderChoice::Fixed(n) => fit_eval(Structure::linear(n), d, &fit, None, None, &opts.fit)?,
        OrderChoice::Auto => {
            let fits: Vec<Evaluated> = (1..=6usize)
                .into_par_iter()
                .filter_map(|n| fit_eval(Structure::linear(n), d, &fit, None, None, &opts.fit).ok())
                .collect();
            let best = fits
                .iter()
                .map(|e| e.scores.nrmse_select)
                .fold(f64::INFINITY, f64::min);
            fits.into_iter()
                .find(|e| e.scores.nrmse_select <= best * 1.02 + 1e-12)
                .ok_or_else(|| {
                    DiagnoseError::Lmn(gb_lmn::LmnError::Unstable(
                        "no order gave a stable model".into(),
                    ))
                })?
        }
    };
    let baseline_summary = summary(&base);
    let baseline_evidence = Evidence::compute(&base.e_select, &base.yhat_select, &select_inputs(d));
    let mut chain = vec![base.model.clone()];
    let mut cur = base;
    let mut steps = vec![];
    let mut causes: Vec<String> = vec![];
    let n_sel = cur.e_select.len();
    let block = (n_sel / 40).clamp(25, 200);
    let mut tried_noise = false;
    let mut tried_state_space = false;
    for it in 1..=opts.max_steps {
        progress(
            it,
            total,
            &format!("step {it}: fitting candidate extensions"),
        );
        let ev = Evidence::compute(&cur.e_select, &cur.yhat_select, &select_inputs(d));
        let mut cands = candidates(cur.model.structure, &causes, tried_noise);
        if cands.is_empty() {
            break;
        }
        // simulated output of the current model on the fit block: output lags for LOLIMOT
        let yreg = cur
            .model
            .simulate(
                &fit.inputs,
                &fit.output[..cur.model.max_lag().min(fit.len())],
            )
            .ok();
        let mut fitted: Vec<Option<Evaluated>> = cands
            .par_iter()
            .map(|c| {
                fit_eval(
                    c.structure,
                    d,
                    &fit,
                    yreg.as_deref(),
                    Some(&cur.model),
                    &opts.fit,
                )
                .ok()
            })
            .collect();
        // score each candidate on the select block
        #[derive(Clone, Copy)]
        struct Scored {
            idx: usize,
            gain: f64,
            ci: [f64; 2],
            pays: bool,
        }
        let mut scored = vec![];
        for (i, (c, f)) in cands.iter().zip(&fitted).enumerate() {
            let Some(f) = f else { continue };
            let seed = opts.seed.wrapping_add(1000 * it as u64 + i as u64);
            let (gain, ci, pays) = if c.cause == "noise" {
                let nb: Vec<f64> = cur
                    .e_select
                    .iter()
                    .map(|&e| cur.model.network.noise.nll(e))
                    .collect();
                let na: Vec<f64> = f
                    .e_select
                    .iter()
                    .map(|&e| f.model.network.noise.nll(e))
                    .collect();
                let (g, ci) = nll_gain_ci(&nb, &na, block, opts.bootstrap, seed);
                let heavy = ev.normality.3 < 1e-3 && ev.normality.1 > 0.5;
                let nrmse_ok = f.scores.nrmse_select <= cur.scores.nrmse_select * 1.02;
                (
                    g,
                    ci,
                    heavy && nrmse_ok && ci[0] > 0.0 && g >= opts.min_nll_gain,
                )
            } else {
                let (g, ci) =
                    relative_gain_ci(&cur.e_select, &f.e_select, block, opts.bootstrap, seed);
                (g, ci, ci[0] > 0.0 && g >= opts.min_gain)
            };
            scored.push(Scored {
                idx: i,
                gain,
                ci,
                pays,
            });
        }
        // a new structural cause must also beat "more of what we have"
        let refine = scored
            .iter()
            .find(|s| s.pays && cands[s.idx].refine)
            .map(|s| s.idx);
        if let Some(r) = refine {
            let rf = fitted[r].as_ref().expect("scored candidates were fitted");
            for s in scored.iter_mut() {
                let c = &cands[s.idx];
                if s.pays && !c.refine && c.cause != "noise" {
                    let f = fitted[s.idx]
                        .as_ref()
                        .expect("scored candidates were fitted");
                    let seed = opts.seed.wrapping_add(5000 + s.idx as u64);
                    let (g, ci) =
                        relative_gain_ci(&rf.e_select, &f.e_select, block, opts.bootstrap, seed);
                    s.pays = ci[0] > 0.0 && g >= opts.min_gain;
                }
            }
        }
        // choose: the new structural cause with the largest gain, else the
        // refinement, else noise
        let structural_best = scored
            .iter()
            .filter(|s| s.pays && !cands[s.idx].refine && cands[s.idx].cause != "noise")
            .max_by(|a, b| a.gain.total_cmp(&b.gain))
            .map(|s| s.idx);
        let mut chosen = structural_best;
        // Hysteresis and nonlinearity both pay and their intervals overlap:
        // fit the model with both and keep the cause with the larger unique
        // contribution (the gain of adding it to the other one).
        let mut tie_note: Option<String> = None;
        if let Some(ci) = chosen.filter(|&ci| !cands[ci].structure.state_space) {
            let other = match cands[ci].cause {
                "nonlinearity" => "hysteresis",
                "hysteresis" => "nonlinearity",
                _ => "",
            };
            if let Some(o) = scored.iter().find(|s| {
                s.pays
                    && !cands[s.idx].refine
                    && !cands[s.idx].structure.state_space
                    && cands[s.idx].cause == other
            }) {
                let best = scored
                    .iter()
                    .find(|s| s.idx == ci)
                    .map_or([0.0, 0.0], |s| s.ci);
                if o.ci[1] >= best[0] && best[1] >= o.ci[0] {
                    let (ni, hi) = if cands[ci].cause == "nonlinearity" {
                        (ci, o.idx)
                    } else {
                        (o.idx, ci)
                    };
                    let both = Structure {
                        network: true,
                        hysteresis: true,
                        ..cur.model.structure
                    };
                    let lmn = &fitted[ni].as_ref().expect("fitted").model;
                    let hyst = &fitted[hi].as_ref().expect("fitted").model;
                    if let Ok(comb) =
                        fit_combined(both, lmn, hyst, &fit, &opts.fit).and_then(|m| evaluate(m, d))
                    {
                        let en = &fitted[ni].as_ref().expect("fitted").e_select;
                        let eh = &fitted[hi].as_ref().expect("fitted").e_select;
                        let (g_h, _) = relative_gain_ci(en, &comb.e_select, block, 50, 0);
                        let (g_n, _) = relative_gain_ci(eh, &comb.e_select, block, 50, 0);
                        chosen = Some(if g_h > g_n { hi } else { ni });
                        tie_note = Some(format!(
                            "; tie with {other} resolved by unique contributions: hysteresis adds {:+.1}% to a network, a network adds {:+.1}% to hysteresis",
                            100.0 * g_h,
                            100.0 * g_n
                        ));
                    }
                }
            }
        }
        if chosen.is_none() {
            chosen = refine;
        }
        if chosen.is_none() {
            chosen = scored
                .iter()
                .find(|s| s.pays && cands[s.idx].cause == "noise")
                .map(|s| s.idx);
        }
        // No new cause this iteration (nothing pays, or only more of what
        // we have): if a named cause is still unexplained, the hidden-state
        // model of gb-model (tried once per diagnosis: it is fitted from
        // scratch, on at most SS_FIT_SAMPLES samples of the fit block). It
        // must pay against the current model and beat the simple choice.
        let new_cause = chosen
            .is_some_and(|ci| !cands[ci].refine && !causes.iter().any(|c| c == cands[ci].cause));
        let ss = if new_cause || tried_state_space {
            None
        } else {
            state_space_candidate(cur.model.structure, &causes, &ev)
        };
        if let Some(c) = ss {
            tried_state_space = true;
            progress(
                it,
                total,
                &format!("step {it}: fitting the hidden-state model"),
            );
            let sub = fit.slice(0..fit.len().min(SS_FIT_SAMPLES));
            if let Ok(f) = fit_eval(c.structure, d, &sub, None, None, &opts.fit) {
                let seed = opts.seed.wrapping_add(1000 * it as u64 + 999);
                let (gain, ci) =
                    relative_gain_ci(&cur.e_select, &f.e_select, block, opts.bootstrap, seed);
                let mut pays = ci[0] > 0.0 && gain >= opts.min_gain;
                if let Some(simple) = chosen.and_then(|i| fitted[i].as_ref()) {
                    let (g2, ci2) = relative_gain_ci(
                        &simple.e_select,
                        &f.e_select,
                        block,
                        opts.bootstrap,
                        seed + 1,
                    );
                    pays = pays && ci2[0] > 0.0 && g2 >= opts.min_gain;
                }
                let idx = cands.len();
                cands.push(c);
                fitted.push(Some(f));
                scored.push(Scored {
                    idx,
                    gain,
                    ci,
                    pays,
                });
                if pays {
                    chosen = Some(idx);
                }
            }
        }
        if scored.iter().any(|s| cands[s.idx].cause == "noise") {
            tried_noise = true;
        }
        // rows: every candidate of this iteration (best dynamics order only)
        let best_dyn = scored
            .iter()
            .filter(|s| cands[s.idx].cause == "dynamics" && !cands[s.idx].structure.state_space)
            .max_by(|a, b| a.gain.total_cmp(&b.gain))
            .map(|s| s.idx);
        let mut rows = vec![];
        for s in &scored {
            let c = &cands[s.idx];
            if c.cause == "dynamics"
                && !c.structure.state_space
                && Some(s.idx) != best_dyn
                && Some(s.idx) != chosen
            {
                continue;
            }
            let f = fitted[s.idx]
                .as_ref()
                .expect("scored candidates were fitted");
            let (gain, metric) = if c.cause == "noise" {
                (cur.scores.nll - f.scores.nll, "nll")
            } else {
                (1.0 - f.scores.nrmse / cur.scores.nrmse.max(1e-300), "nrmse")
            };
            let evidence = if c.refine {
                format!("the named {} pays further with more capacity", c.cause)
            } else if c.structure.state_space {
                format!(
                    "the simple extension for the named {} leaves the residuals non-white (Ljung-Box Q={:.0}, p={:.1e}; memory F={:.1}, p={:.1e}) and no new cause pays",
                    c.cause, ev.ljung_box.0, ev.ljung_box.1, ev.memory.0, ev.memory.1
                )
            } else {
                match c.cause {
                    "nonlinearity" => ev.nonlinearity_text(),
                    "hysteresis" => ev.hysteresis_text(),
                    "dynamics" => ev.dynamics_text(),
                    _ => ev.noise_text(),
                }
            };
            let evidence = match (&tie_note, Some(s.idx) == chosen) {
                (Some(t), true) => format!("{evidence}{t}"),
                _ => evidence,
            };
            let extension = if c.structure.state_space {
                format!("{} -> {}", c.extension, f.model.describe())
            } else {
                c.extension.clone()
            };
            rows.push(Step {
                iteration: it,
                cause: c.cause.to_string(),
                evidence,
                extension,
                nrmse_before: cur.scores.nrmse,
                nrmse_after: f.scores.nrmse,
                gain,
                gain_metric: metric.to_string(),
                gain_select: s.gain,
                gain_ci: s.ci,
                nll_before: cur.scores.nll,
                nll_after: f.scores.nll,
                accepted: Some(s.idx) == chosen,
            });
        }
        rows.sort_by_key(|r| !r.accepted);
        steps.extend(rows);
        match chosen {
            Some(ci) => {
                if !causes.iter().any(|c| c == cands[ci].cause) {
                    causes.push(cands[ci].cause.to_string());
                }
                let mut fitted = fitted;
                cur = fitted[ci].take().expect("chosen candidate was fitted");
                chain.push(cur.model.clone());
            }
            None => break,
        }
    }
    progress(total, total, "done");
    let final_evidence = Evidence::compute(&cur.e_select, &cur.yhat_select, &select_inputs(d));
    let split = if std::ptr::eq(&d.train, &d.report)
        || d.report_range.start > 0
            && d.report.len() == d.train.len()
            && d.report.output == d.train.output
    {
        format!(
            "one record split into contiguous blocks: fit {}..{}, select {}..{}, report {}..{}",
            d.fit.start,
            d.fit.end,
            d.select.start,
            d.select.end,
            d.report_range.start,
            d.report_range.end
        )
    } else {
        format!(
            "training record: fit {}..{}, select {}..{}; validation record: report {}..{}",
            d.fit.start,
            d.fit.end,
            d.select.start,
            d.select.end,
            d.report_range.start,
            d.report_range.end
        )
    };
    let report = Report {
        version: 1,
        data: DataSummary {
            inputs: d.train.input_names.clone(),
            output: d.train.output_name.clone(),
            samples_fit: d.fit.len(),
            samples_select: d.select.len(),
            samples_validate: d.report_range.len(),
            split,
        },
        baseline: baseline_summary,
        steps,
        causes,
        final_model: summary(&cur),
        evidence: baseline_evidence,
        final_evidence,
    };
    Ok(Diagnosis {
        report,
        model: cur.model,
        chain,
    })
}

fn select_inputs(d: &DiagnoseData) -> Vec<Vec<f64>> {
    let start = d.select.start.max(EVAL_SKIP);
    d.train
        .inputs
        .iter()
        .map(|u| u[start..d.select.end].to_vec())
        .collect()
}
