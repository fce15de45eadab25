//! A fitted model as the diagnosis sees it: how it was built, its scores and
//! its residuals on the select and report blocks (kept, so that reports are
//! pure renderers).
use crate::{DecisionPolicy, DiagnoseData, DiagnoseError};
use gb_core::{metrics, FittedModel, Init, Record};
use gb_lmn::IoNetworkParams;
use serde::{Deserialize, Serialize};
use std::ops::Range;

/// How a model was built: what the extensions can extend further.
#[derive(Debug, Clone, PartialEq)]
pub enum Lineage {
    /// An input–output network (linear OE or LOLIMOT, optional Preisach
    /// columns, optional Student-t noise) with these parameters.
    Io(IoNetworkParams),
    /// The hidden-state model of gb-model with `order` states, hysteretic
    /// or not.
    HiddenState {
        /// Number of states.
        order: usize,
        /// Whether it has a hysteretic part.
        hysteresis: bool,
        /// 0: as the escalation fits it; 1: refined (finer sub-steps and
        /// wavelet levels, more data).
        detail: u8,
    },
    /// A model of another class (a nonlinear extension's: polynomial,
    /// block-oriented, tree or Wiener–Hammerstein network); the
    /// input–output extensions do not extend it further.
    Other {
        /// The model SPEC (`greybox fit --model`) or the class in words.
        spec: String,
        /// Dynamic order of its linear part.
        order: usize,
    },
}

impl Lineage {
    /// The model SPEC (`greybox fit --model`).
    pub fn spec(&self) -> String {
        match self {
            Lineage::Io(p) => {
                let mut s = p.spec_name();
                if p.hysteresis {
                    match p.hysteresis_on {
                        gb_lmn::HysteresisOn::Both => {}
                        gb_lmn::HysteresisOn::Inputs => s.push_str(" (inputs)"),
                        gb_lmn::HysteresisOn::Output => s.push_str(" (output)"),
                    }
                }
                if p.detail > 0 {
                    s.push_str(&format!(" (detail {})", p.detail));
                }
                s
            }
            Lineage::HiddenState {
                hysteresis, detail, ..
            } => {
                let s = if *hysteresis {
                    "state-space+hysteresis"
                } else {
                    "state-space"
                };
                if *detail > 0 {
                    format!("{s} (detail {detail})")
                } else {
                    s.into()
                }
            }
            Lineage::Other { spec, .. } => spec.clone(),
        }
    }

    /// Dynamic order (states of the hidden-state model).
    pub fn order(&self) -> usize {
        match self {
            Lineage::Io(p) => p.order,
            Lineage::HiddenState { order, .. } | Lineage::Other { order, .. } => *order,
        }
    }

    /// The input–output network parameters, if that is the class.
    pub fn io(&self) -> Option<&IoNetworkParams> {
        match self {
            Lineage::Io(p) => Some(p),
            Lineage::HiddenState { .. } | Lineage::Other { .. } => None,
        }
    }
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

/// Residuals `e = y − ŷ` and the simulated output `ŷ` over the scored
/// samples of one block.
#[derive(Debug, Clone, Default)]
pub struct Residuals {
    /// Residuals.
    pub e: Vec<f64>,
    /// Simulated output.
    pub yhat: Vec<f64>,
    /// Per-sample negative log predictive density `−log p(y_t | y_{0:t−1})`
    /// when it is not the noise model's density of `e` (a model with
    /// process noise: its filter's); empty otherwise.
    pub nll: Vec<f64>,
}

impl Residuals {
    /// `−log p(y_t | y_{0:t−1})` per sample under `noise` (the model's
    /// noise of the simulation residual) unless `nll` holds the model's own.
    pub fn nll_per_sample(&self, noise: &gb_core::NoiseModel) -> Vec<f64> {
        if self.nll.len() == self.e.len() {
            self.nll.clone()
        } else {
            self.e.iter().map(|&e| noise.nll(e)).collect()
        }
    }
}

/// A model with its lineage, scores and residuals.
#[derive(Debug, Clone)]
pub struct Evaluated {
    /// The fitted model.
    pub model: FittedModel,
    /// How it was built.
    pub lineage: Lineage,
    /// Scores.
    pub scores: Scores,
    /// Residuals on the select block.
    pub select: Residuals,
    /// Residuals on the report block.
    pub report: Residuals,
    /// Under blocked cross-validation: the structure refitted for each fold
    /// (its `select` residuals are the fold's held-out residuals); empty
    /// when decisions use the select block.
    pub folds: Vec<Evaluated>,
    /// The noise a `noise` candidate found (`None` for the other models).
    pub finding: Option<crate::report::NoiseFound>,
    /// The start or map structure a multi-start fit chose on the fit block
    /// ([`crate::Extension::fit_choosing`]): the final refit on the whole
    /// training record fits that one only, and so do the folds of the
    /// cross-validation of the extensions that take it there (the physics
    /// starts, the backlash half-width; a block-oriented model's folds
    /// choose their own map).
    pub start_choice: Option<usize>,
    /// Under cross-validation, a `nonlinearity` or `hysteresis` candidate
    /// whose fit on the whole training range gains less than the policy's
    /// `min_gain` over the current model there (free-run residuals over the
    /// folds' samples): that in-sample gain; its folds are not fitted and
    /// it does not pay ([`crate::plan::scored_in_sample`]).
    pub screened: Option<f64>,
    /// Under cross-validation, a candidate screened out by a rival of the
    /// same structure at another input delay (policy
    /// `rival_screen_ratio`): its in-sample RMS residual over the best
    /// rival's; `screened` holds its in-sample gain.
    pub screened_by_rival: Option<f64>,
    /// Under cross-validation, a candidate whose in-sample RMS residual
    /// exceeds the policy's `cv_bound_ratio` times the step's smallest
    /// cross-validated one: that ratio; `screened` holds its in-sample
    /// gain.
    pub screened_by_bound: Option<f64>,
}

/// Residuals of `model` on `range` of `data`, simulating in free run from
/// the record's start with the initial state estimated from its first
/// `init_window` outputs; samples before the window's end are not scored.
pub fn residuals_on(
    model: &FittedModel,
    data: &Record,
    range: &Range<usize>,
    init_window: usize,
) -> Result<Residuals, DiagnoseError> {
    let end = range.end;
    let inputs: Vec<Vec<f64>> = data.inputs.iter().map(|u| u[..end].to_vec()).collect();
    let sim = model.simulate(&inputs, Init::Window(&data.output[..init_window.min(end)]))?;
    let start = range.start.max(init_window).min(end);
    Ok(Residuals {
        e: (start..end).map(|k| data.output[k] - sim[k]).collect(),
        yhat: sim[start..end].to_vec(),
        nll: vec![],
    })
}

/// [`residuals_on`], except that an integrating model (a pole at 1,
/// [`gb_core::DynamicModel::integrates`]: `gb_model::IntegratingModel`, or
/// the engineer's equations with a position that only integrates its
/// velocity) meets the block `range` from a fresh
/// start: simulated from `w` samples before the block, its state from
/// those measured outputs, scored on the same samples. Simulated on from
/// the record's start, an integrator's error on a later block is mostly
/// the position drift accumulated over the samples before it (a random
/// walk of the integrated error over the fit block), which ranks models by
/// how their in-sample errors happened to cancel rather than by how they
/// predict the block; new data are met from a fresh start (the benchmark
/// convention: an init window, then free run).
pub fn block_residuals(
    model: &FittedModel,
    data: &Record,
    range: &Range<usize>,
    w: usize,
) -> Result<Residuals, DiagnoseError> {
    if model.dynamics.integrates() {
        fresh_residuals(model, data, range, w)
    } else {
        residuals_on(model, data, range, w)
    }
}

/// The residuals of `model` on the block `range` of `data` simulated from
/// a fresh start `w` samples before it (its state from those measured
/// outputs), scored on the samples [`residuals_on`] scores; from the
/// record's start when the block begins within the first `w` samples.
pub fn fresh_residuals(
    model: &FittedModel,
    data: &Record,
    range: &Range<usize>,
    w: usize,
) -> Result<Residuals, DiagnoseError> {
    if range.start < w || w == 0 {
        return residuals_on(model, data, range, w);
    }
    let sub = data.slice(range.start - w..range.end);
    residuals_on(model, &sub, &(w..sub.len()), w)
}

/// The NRMSE of `model` on the select blocks of every training record,
/// each simulated from a fresh start ([`fresh_residuals`]).
pub(crate) fn fresh_select_nrmse(
    model: &FittedModel,
    d: &DiagnoseData,
    w: usize,
) -> Result<f64, DiagnoseError> {
    let mut e = vec![];
    for p in d.parts() {
        e.extend(fresh_residuals(model, p.record, p.select, w)?.e);
    }
    Ok(metrics::rms(&e) / metrics::std(&d.select_output(w)))
}

/// Residuals of `model` on the select blocks of every training record:
/// record `i` is simulated in free run from its own start with its initial
/// state from its first `w` outputs (no state carried across records) and
/// scored on its select block `S_i`; `e = [e_S1, e_S2, …]` in record order.
pub fn select_residuals(
    model: &FittedModel,
    d: &DiagnoseData,
    w: usize,
) -> Result<Residuals, DiagnoseError> {
    let mut all = Residuals::default();
    for p in d.parts() {
        let r = block_residuals(model, p.record, p.select, w)?;
        all.e.extend_from_slice(&r.e);
        all.yhat.extend_from_slice(&r.yhat);
    }
    Ok(all)
}

/// Score `model` on the select and report blocks of `d` (init window from
/// the policy and the shorter of the two blocks).
pub fn evaluate(
    model: FittedModel,
    lineage: Lineage,
    d: &DiagnoseData,
    policy: &DecisionPolicy,
) -> Result<Evaluated, DiagnoseError> {
    let w = policy.init_window_for(d.shortest_select().min(d.report_range.len()));
    evaluate_on(model, lineage, d, w, None)
}

/// Score `model` on the report block of `d` with init window `w`, and on the
/// decision data: the select block, or the given held-out residuals
/// `(residuals, std of the measured output over them)`.
pub(crate) fn evaluate_on(
    model: FittedModel,
    lineage: Lineage,
    d: &DiagnoseData,
    w: usize,
    decision: Option<(Residuals, f64)>,
) -> Result<Evaluated, DiagnoseError> {
    let (select, sd_s) = match decision {
        Some(x) => x,
        None if d.multi() => (
            select_residuals(&model, d, w)?,
            metrics::std(&d.select_output(w)),
        ),
        None => (
            block_residuals(&model, &d.train, &d.select, w)?,
            metrics::std(&d.train.output[d.select_scored(w)]),
        ),
    };
    let report = block_residuals(&model, &d.report, &d.report_range, w)?;
    let sd_r = metrics::std(&d.report.output[d.report_scored(w)]);
    let scores = Scores {
        nrmse_select: metrics::rms(&select.e) / sd_s,
        nrmse: metrics::rms(&report.e) / sd_r,
        nll_select: model.noise.mean_nll(&select.e),
        nll: model.noise.mean_nll(&report.e),
    };
    if !(scores.nrmse.is_finite() && scores.nrmse_select.is_finite() && scores.nll.is_finite()) {
        return Err(DiagnoseError::Core(gb_core::CoreError::Unstable(
            "non-finite score".into(),
        )));
    }
    Ok(Evaluated {
        model,
        lineage,
        scores,
        select,
        report,
        folds: vec![],
        finding: None,
        start_choice: None,
        screened: None,
        screened_by_rival: None,
        screened_by_bound: None,
    })
}
