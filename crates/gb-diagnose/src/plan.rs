//! How a diagnosis fits and judges its models, decided once from the data:
//! the init window, the decision data (the select block, or blocked
//! cross-validation over the training record when the select block is too
//! short for the bootstrap), and whether models describe the output or its
//! increments (an integrating baseline).
use crate::evaluate::{evaluate_on, residuals_on, Evaluated, Lineage, Residuals};
use crate::structure::increments;
use crate::{DecisionPolicy, DiagnoseData, DiagnoseError};
use gb_core::{metrics, DynamicModel, FittedModel, Init, NoiseModel, Record};
use gb_model::IntegratingModel;
use rayon::prelude::*;
use std::ops::Range;

/// One fold of the blocked cross-validation.
#[derive(Debug, Clone)]
pub(crate) struct Fold {
    /// What models are fitted on for this fold (increments when integrating).
    pub fit: Record,
    /// The same samples with the measured output.
    pub fit_y: Record,
    /// The held-out samples (in the training record).
    pub test: Range<usize>,
}

/// The plan of a diagnosis (see the module docs).
#[derive(Debug, Clone)]
pub(crate) struct Plan {
    /// Init window of every evaluated record.
    pub w: usize,
    /// Models describe the increments of the output, summed.
    pub integrating: bool,
    /// What the models of the chain are fitted on (increments when
    /// integrating): the fit block, or under cross-validation the whole
    /// training record.
    pub fit: Record,
    /// The same samples with the measured output.
    pub fit_y: Record,
    /// The folds (empty: decisions on the select block).
    pub folds: Vec<Fold>,
}

/// A fit for the plan's record (`None`) or for fold `k` (`Some(k)`).
pub(crate) type FitFn<'a> = dyn Fn(Option<usize>) -> Result<FittedModel, DiagnoseError> + Sync + 'a;

impl Plan {
    /// The plan of `d`: cross-validation when the select block has fewer
    /// than the policy's `bootstrap_min_samples`.
    pub fn new(d: &DiagnoseData, pol: &DecisionPolicy) -> Self {
        if d.select.len() >= pol.bootstrap_min_samples {
            let fit_y = d.fit_record();
            return Self {
                w: pol.init_window_for(d.select.len().min(d.report_range.len())),
                integrating: false,
                fit: fit_y.clone(),
                fit_y,
                folds: vec![],
            };
        }
        let train = d.fit.start..d.select.end;
        let (n, k) = (train.len(), pol.cv_folds);
        let bound = |i: usize| train.start + i * n / k;
        let folds: Vec<Fold> = (0..k)
            .map(|i| {
                let test = bound(i)..bound(i + 1);
                let before = train.start..test.start;
                let after = test.end..train.end;
                let rest = if before.len() >= after.len() {
                    before
                } else {
                    after
                };
                let fit_y = d.train.slice(rest);
                Fold {
                    fit: fit_y.clone(),
                    fit_y,
                    test,
                }
            })
            .collect();
        let shortest = folds
            .iter()
            .map(|f| f.test.len())
            .min()
            .unwrap_or(0)
            .min(d.report_range.len());
        let fit_y = d.train.slice(train);
        Self {
            w: pol.init_window_for(shortest),
            integrating: false,
            fit: fit_y.clone(),
            fit_y,
            folds,
        }
    }

    /// The same plan for models of the output (`false`) or of its
    /// increments (`true`).
    pub fn integrating(&self, on: bool) -> Self {
        let target = |r: &Record| if on { increments(r) } else { r.clone() };
        Self {
            w: self.w,
            integrating: on,
            fit: target(&self.fit_y),
            fit_y: self.fit_y.clone(),
            folds: self
                .folds
                .iter()
                .map(|f| Fold {
                    fit: target(&f.fit_y),
                    fit_y: f.fit_y.clone(),
                    test: f.test.clone(),
                })
                .collect(),
        }
    }

    /// Whether decisions use cross-validation.
    pub fn cv(&self) -> bool {
        !self.folds.is_empty()
    }

    /// The record fits of target `t` are made on.
    pub fn fit_of(&self, t: Option<usize>) -> &Record {
        t.map_or(&self.fit, |k| &self.folds[k].fit)
    }

    /// The inputs over the decision samples (aligned with `select`
    /// residuals).
    pub fn decision_inputs(&self, d: &DiagnoseData) -> Vec<Vec<f64>> {
        if !self.cv() {
            return d.select_inputs(self.w);
        }
        (0..d.train.n_inputs())
            .map(|j| {
                self.folds
                    .iter()
                    .flat_map(|f| {
                        let s = (f.test.start + self.w).min(f.test.end);
                        d.train.inputs[j][s..f.test.end].iter().copied()
                    })
                    .collect()
            })
            .collect()
    }

    /// The decision data in words.
    pub fn describe(&self, d: &DiagnoseData) -> String {
        if self.cv() {
            format!(
                "blocked cross-validation: {} contiguous folds over the {} training samples (each scored by the structure refitted on the longer contiguous rest), init window {}",
                self.folds.len(),
                self.fit_y.len(),
                self.w
            )
        } else {
            format!(
                "moving-block bootstrap on the {}-sample select block, init window {}",
                d.select.len(),
                self.w
            )
        }
    }

    /// A fitted model as the diagnosis keeps it: an increments model is
    /// wrapped to integrate, with the noise model of its output error on
    /// the measured output of its fit record.
    pub fn finish(&self, m: FittedModel, t: Option<usize>) -> Result<FittedModel, DiagnoseError> {
        if !self.integrating {
            return Ok(m);
        }
        let fit_y = t.map_or(&self.fit_y, |k| &self.folds[k].fit_y);
        let robust = matches!(m.noise, NoiseModel::StudentT { .. });
        let dynamics: Box<dyn DynamicModel> = Box::new(IntegratingModel::new(m.dynamics)?);
        let w = self.w.min(fit_y.len());
        let sim = dynamics.simulate(&fit_y.inputs, Init::Window(&fit_y.output[..w]))?;
        let e: Vec<f64> = fit_y.output[w..]
            .iter()
            .zip(&sim[w..])
            .map(|(a, b)| a - b)
            .collect();
        let noise = if robust {
            NoiseModel::student_t(&e)
        } else {
            NoiseModel::gaussian(&e)
        };
        Ok(FittedModel::new(
            m.input_names,
            m.output_names,
            dynamics,
            noise,
        )?)
    }
}

/// The dynamics a model extends: the increments model of an integrating
/// model, else the model itself.
pub(crate) fn core(m: &FittedModel) -> &dyn DynamicModel {
    match m.dynamics.as_any().downcast_ref::<IntegratingModel>() {
        Some(i) => i.inner(),
        None => m.dynamics.as_ref(),
    }
}

/// Fit with `fit` and score: on the select block, or under
/// cross-validation refitted on every fold and scored on the pooled
/// held-out residuals. Fold fits run in parallel.
pub(crate) fn assess(
    plan: &Plan,
    d: &DiagnoseData,
    lineage: Lineage,
    fit: &FitFn,
) -> Result<Evaluated, DiagnoseError> {
    let m = plan.finish(fit(None)?, None)?;
    if !plan.cv() {
        return evaluate_on(m, lineage, d, plan.w, None);
    }
    let folds: Vec<Evaluated> = (0..plan.folds.len())
        .into_par_iter()
        .map(|k| {
            let mk = plan.finish(fit(Some(k))?, Some(k))?;
            fold_scores(mk, lineage.clone(), d, plan, k)
        })
        .collect::<Result<_, _>>()?;
    let mut pooled = Residuals::default();
    let mut y = vec![];
    for (f, fold) in folds.iter().zip(&plan.folds) {
        pooled.e.extend_from_slice(&f.select.e);
        pooled.yhat.extend_from_slice(&f.select.yhat);
        let s = (fold.test.start + plan.w).min(fold.test.end);
        y.extend_from_slice(&d.train.output[s..fold.test.end]);
    }
    let sd = metrics::std(&y);
    let mut e = evaluate_on(m, lineage, d, plan.w, Some((pooled, sd)))?;
    e.folds = folds;
    Ok(e)
}

/// A fold model scored on its held-out samples (simulated from the fold's
/// start, the init window not scored).
fn fold_scores(
    m: FittedModel,
    lineage: Lineage,
    d: &DiagnoseData,
    plan: &Plan,
    k: usize,
) -> Result<Evaluated, DiagnoseError> {
    let test = &plan.folds[k].test;
    let rec = d.train.slice(test.clone());
    let r = residuals_on(&m, &rec, &(0..rec.len()), plan.w)?;
    let s = plan.w.min(rec.len());
    let sd = metrics::std(&rec.output[s..]);
    let nrmse = metrics::rms(&r.e) / sd;
    let nll = m.noise.mean_nll(&r.e);
    if !(nrmse.is_finite() && nll.is_finite()) {
        return Err(DiagnoseError::Core(gb_core::CoreError::Unstable(
            "non-finite fold score".into(),
        )));
    }
    Ok(Evaluated {
        model: m,
        lineage,
        scores: crate::Scores {
            nrmse_select: nrmse,
            nrmse,
            nll_select: nll,
            nll,
        },
        select: r,
        report: Residuals::default(),
        folds: vec![],
    })
}
