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
    /// What the input–output models are fitted on, one record per
    /// experiment (increments when integrating): `[fit]` with one training
    /// record, all other training records whole under leave-one-record-out.
    pub fits: Vec<Record>,
    /// The same records with the measured output.
    pub fits_y: Vec<Record>,
    /// The training record the held-out samples are in (index of
    /// [`DiagnoseData::parts`]; 0 with one training record).
    pub record: usize,
    /// The held-out samples (in that training record).
    pub test: Range<usize>,
    /// Which held-out samples are scored (`keep[i]` for sample
    /// `test.start + i`): those after the init window whose signals lie in
    /// the range the fold's fit record covers ([`covered`]).
    pub keep: Vec<bool>,
}

impl Fold {
    /// The scored samples (indices of the fold's training record).
    pub fn scored(&self) -> impl Iterator<Item = usize> + '_ {
        self.keep
            .iter()
            .enumerate()
            .filter(|(_, &k)| k)
            .map(move |(i, _)| self.test.start + i)
    }
}

/// What the residual tests read ([`Plan::tested`]).
#[derive(Debug, Clone)]
pub(crate) struct Tested {
    /// The model's residuals over the decision samples.
    pub whole: Residuals,
    /// The inputs over the same samples.
    pub inputs: Vec<Vec<f64>>,
    /// Under cross-validation: each fold's held-out residuals (its own
    /// refit) with their inputs; empty otherwise.
    pub folds: Vec<(Residuals, Vec<Vec<f64>>)>,
    /// Where `whole` restarts after a gap (indices into it; empty: one
    /// contiguous run): the folds' blocks, and the held-out samples left
    /// out inside a block. The tests take lag products inside a run only.
    pub whole_starts: Vec<usize>,
    /// The same for each fold's held-out residuals.
    pub fold_starts: Vec<Vec<usize>>,
}

/// The indices of `idx` (increasing sample numbers) where a new contiguous
/// run starts.
fn run_starts(idx: impl Iterator<Item = usize>) -> Vec<usize> {
    let mut out = vec![];
    let mut prev: Option<usize> = None;
    for (i, k) in idx.enumerate() {
        if prev.is_some_and(|p| k != p + 1) {
            out.push(i);
        }
        prev = Some(k);
    }
    out
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
    /// What the input–output models (the baseline, its delay and order
    /// scans, linear and LOLIMOT extensions) are fitted on, one record per
    /// experiment: `[fit]` with one training record, the fit parts of all
    /// training records with several (increments when integrating).
    pub fits: Vec<Record>,
    /// The same records with the measured output.
    pub fits_y: Vec<Record>,
    /// The folds (empty: decisions on the select block).
    pub folds: Vec<Fold>,
    /// Why decisions use cross-validation although the select block is
    /// long enough for the bootstrap (it is not representative of the
    /// training record).
    pub shift: Option<String>,
    /// The cross-validation spans the report block too (one training
    /// record too short for the bootstrap, the policy's
    /// `cv_whole_short_record`): the models are fitted on the whole
    /// record and their figures on the report block are in-sample.
    pub spans_report: bool,
}

/// A fit for the plan's record (`None`) or for fold `k` (`Some(k)`).
pub(crate) type FitFn<'a> = dyn Fn(Option<usize>) -> Result<FittedModel, DiagnoseError> + Sync + 'a;

/// A fitted model and, for a multi-start fit, the index of the start that
/// won.
pub(crate) type Chosen = (FittedModel, Option<usize>);

/// A fit for the plan's record (`None`) or for fold `k` given the fit on
/// the plan's record and the start it chose (`Some((k, whole))`).
pub(crate) type FoldFitFn<'a> =
    dyn Fn(Option<(usize, &Chosen)>) -> Result<Chosen, DiagnoseError> + Sync + 'a;

impl Plan {
    /// The plan of `d`: cross-validation when the select block has fewer
    /// than the policy's `bootstrap_min_samples`, or when it is not
    /// representative of the training record ([`block_shift`]: a sweep, a
    /// drifting level).
    pub fn new(d: &DiagnoseData, pol: &DecisionPolicy) -> Self {
        if d.multi() {
            return Self::multi(d, pol);
        }
        let shift = block_shift(d, pol);
        if d.select.len() >= pol.bootstrap_min_samples && shift.is_none() {
            let fit_y = d.fit_record();
            return Self {
                w: pol.init_window_for(d.select.len().min(d.report_range.len())),
                integrating: false,
                fit: fit_y.clone(),
                fits: vec![fit_y.clone()],
                fits_y: vec![fit_y.clone()],
                fit_y,
                folds: vec![],
                shift: None,
                spans_report: false,
            };
        }
        let spans_report = spans_report(d, pol);
        let end = if spans_report {
            d.report_range.end
        } else {
            d.select.end
        };
        let train = d.fit.start..end;
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
                    fits: vec![fit_y.clone()],
                    fits_y: vec![fit_y.clone()],
                    fit_y,
                    record: 0,
                    test,
                    keep: vec![],
                }
            })
            .collect();
        let w = pol.init_window_for(
            folds
                .iter()
                .map(|f| f.test.len())
                .min()
                .unwrap_or(0)
                .min(d.report_range.len()),
        );
        let folds: Vec<Fold> = folds
            .into_iter()
            .map(|f| Fold {
                keep: covered(&f.fit_y, &d.train, &f.test, w, pol),
                ..f
            })
            .collect();
        let fit_y = d.train.slice(train);
        Self {
            w,
            integrating: false,
            fit: fit_y.clone(),
            fits: vec![fit_y.clone()],
            fits_y: vec![fit_y.clone()],
            fit_y,
            folds,
            shift: shift.filter(|_| d.select.len() >= pol.bootstrap_min_samples),
            spans_report,
        }
    }

    /// The plan of several training records. The input–output models (the
    /// baseline, its ARX and output-error delay scans and order scan, the
    /// extensions fitting linear models or LOLIMOT networks) are fitted on
    /// the fit parts of all records as separate experiments (`fits`); the
    /// other classes (block-oriented, polynomial NOE, Wiener–Hammerstein,
    /// state-space and physics models) on one record, the longest fit part
    /// (`fit`). With at
    /// least the policy's `bootstrap_min_samples` select samples in all,
    /// decisions use the select blocks of all records (each simulated from
    /// its own start, residuals concatenated in record order); with fewer,
    /// leave-one-record-out cross-validation ([`Plan::leave_one_record_out`]).
    fn multi(d: &DiagnoseData, pol: &DecisionPolicy) -> Self {
        if d.select_samples() < pol.bootstrap_min_samples {
            return Self::leave_one_record_out(d, pol);
        }
        let fit_y = d.longest_fit_record();
        let fits: Vec<Record> = d
            .parts()
            .iter()
            .map(|p| p.record.slice(p.fit.clone()))
            .collect();
        Self {
            w: pol.init_window_for(d.shortest_select().min(d.report_range.len())),
            integrating: false,
            fit: fit_y.clone(),
            fits: fits.clone(),
            fits_y: fits,
            fit_y,
            folds: vec![],
            shift: None,
            spans_report: false,
        }
    }

    /// Leave-one-record-out cross-validation: fold `i` holds out training
    /// record `i` whole (simulated from its start, scored after the init
    /// window on the samples its fit covers, [`covered`]) and is fitted on
    /// the longest other training record, whole (a single-record class;
    /// the input–output models on all other training records, whole);
    /// the final models on the longest training record, whole (the
    /// input–output ones on all training records).
    fn leave_one_record_out(d: &DiagnoseData, pol: &DecisionPolicy) -> Self {
        let parts = d.parts();
        let whole = |i: usize| parts[i].record.slice(0..parts[i].select.end);
        let longest = |skip: Option<usize>| {
            (0..parts.len())
                .filter(|&i| Some(i) != skip)
                .fold(None, |best: Option<usize>, i| match best {
                    Some(b) if parts[b].select.end >= parts[i].select.end => Some(b),
                    _ => Some(i),
                })
                .unwrap_or(0)
        };
        let shortest = parts.iter().map(|p| p.select.end).min().unwrap_or(0);
        let w = pol.init_window_for(shortest.min(d.report_range.len()));
        let others = |skip: Option<usize>| -> Vec<Record> {
            (0..parts.len())
                .filter(|&i| Some(i) != skip)
                .map(whole)
                .collect()
        };
        let folds = (0..parts.len())
            .map(|i| {
                let fit_y = whole(longest(Some(i)));
                let test = 0..parts[i].select.end;
                Fold {
                    keep: covered(&fit_y, parts[i].record, &test, w, pol),
                    fit: fit_y.clone(),
                    fits: others(Some(i)),
                    fits_y: others(Some(i)),
                    fit_y,
                    record: i,
                    test,
                }
            })
            .collect();
        let fit_y = whole(longest(None));
        Self {
            w,
            integrating: false,
            fit: fit_y.clone(),
            fits: others(None),
            fits_y: others(None),
            fit_y,
            folds,
            shift: None,
            spans_report: false,
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
            fits: self.fits_y.iter().map(target).collect(),
            fits_y: self.fits_y.clone(),
            folds: self
                .folds
                .iter()
                .map(|f| Fold {
                    fit: target(&f.fit_y),
                    fit_y: f.fit_y.clone(),
                    fits: f.fits_y.iter().map(target).collect(),
                    fits_y: f.fits_y.clone(),
                    record: f.record,
                    test: f.test.clone(),
                    keep: f.keep.clone(),
                })
                .collect(),
            shift: self.shift.clone(),
            spans_report: self.spans_report,
        }
    }

    /// The same plan with every held-out sample after the init window
    /// scored (no range rule, [`covered`]): for the engineer's equations,
    /// whose added laws are meant to hold beyond the range a fold was
    /// fitted on (the overflow of a tank), extrapolation is part of what
    /// the folds judge.
    pub fn whole_folds(mut self) -> Self {
        let w = self.w;
        for f in &mut self.folds {
            f.keep = (0..f.test.len()).map(|i| i >= w).collect();
        }
        self
    }

    /// Whether decisions use cross-validation.
    pub fn cv(&self) -> bool {
        !self.folds.is_empty()
    }

    /// The record fits of target `t` are made on.
    pub fn fit_of(&self, t: Option<usize>) -> &Record {
        t.map_or(&self.fit, |k| &self.folds[k].fit)
    }

    /// The records (experiments) input–output fits of target `t`
    /// are made on.
    pub fn fits_of(&self, t: Option<usize>) -> &[Record] {
        t.map_or(&self.fits, |k| &self.folds[k].fits)
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
                        let rec = d.record(f.record);
                        f.scored().map(move |k| rec.inputs[j][k])
                    })
                    .collect()
            })
            .collect()
    }

    /// The residuals the residual tests read for `ev` (the verdict, and the
    /// `noise` extension's "coloured noise only" rule), with their inputs:
    /// its decision residuals; under blocked cross-validation of one record,
    /// `ev`'s own free-run residuals on the folds' scored samples (the model
    /// fitted on the whole training range) and, apart, each fold's held-out
    /// residuals (that fold's refit). See [`crate::verdict::verdict_tested`].
    pub fn tested(&self, ev: &Evaluated, d: &DiagnoseData) -> Tested {
        let inputs = self.decision_inputs(d);
        let plain = |inputs| Tested {
            whole: ev.select.clone(),
            inputs,
            folds: vec![],
            whole_starts: vec![],
            fold_starts: vec![],
        };
        if !self.cv() || d.multi() || ev.folds.len() != self.folds.len() {
            return plain(inputs);
        }
        let counts: Vec<usize> = self.folds.iter().map(|f| f.scored().count()).collect();
        let fits = ev
            .folds
            .iter()
            .zip(&counts)
            .all(|(f, &n)| f.select.e.len() == n);
        let Some(whole) = self.in_sample(&ev.model, d).filter(|_| fits) else {
            return plain(inputs);
        };
        let mut start = 0;
        let folds = ev
            .folds
            .iter()
            .zip(&counts)
            .map(|(f, &n)| {
                let u = inputs
                    .iter()
                    .map(|u| u[start..start + n].to_vec())
                    .collect();
                start += n;
                (f.select.clone(), u)
            })
            .collect();
        Tested {
            whole,
            inputs,
            folds,
            whole_starts: run_starts(self.folds.iter().flat_map(|f| f.scored())),
            fold_starts: self.folds.iter().map(|f| run_starts(f.scored())).collect(),
        }
    }

    /// Under cross-validation of one record: the free-run residuals of
    /// `model` (fitted on the whole training range) on the folds' scored
    /// samples, in fold order (aligned with [`Plan::decision_inputs`]),
    /// an integrating model's segments each simulated from its start as
    /// the fold refits are scored, any other model in one free run over the
    /// record. (One free run let an integrating model's drift accumulate
    /// over four folds' length: on the sweep's `integrator` seed 2 the
    /// dry-friction model that gained 42 % on the validation record gained
    /// 2 % there and was screened out. A model that does not integrate
    /// keeps the one run: its residual is then the model's own, without
    /// four init windows' transients, which the verdict's tests read.)
    pub fn in_sample(&self, model: &FittedModel, d: &DiagnoseData) -> Option<Residuals> {
        if !self.cv() || d.multi() {
            return None;
        }
        if !model.dynamics.integrates() {
            return self.in_sample_one_run(model, d);
        }
        let mut out = Residuals::default();
        for f in &self.folds {
            let r = segment_residuals(model, d, f, self.w).ok()?;
            if r.e.len() != f.scored().count() {
                return None;
            }
            out.e.extend(r.e);
            out.yhat.extend(r.yhat);
        }
        Some(out)
    }

    /// [`Plan::in_sample`] from one free run over the training record.
    fn in_sample_one_run(&self, model: &FittedModel, d: &DiagnoseData) -> Option<Residuals> {
        let end = self.folds.iter().map(|f| f.test.end).max().unwrap_or(0);
        let all = residuals_on(model, &d.train, &(0..end), self.w).ok()?;
        // `all` starts at the init window
        let idx: Vec<usize> = self
            .folds
            .iter()
            .flat_map(|f| f.scored())
            .filter_map(|k| k.checked_sub(self.w).filter(|&i| i < all.e.len()))
            .collect();
        let n: usize = self.folds.iter().map(|f| f.scored().count()).sum();
        (idx.len() == n).then(|| Residuals {
            e: idx.iter().map(|&i| all.e[i]).collect(),
            yhat: idx.iter().map(|&i| all.yhat[i]).collect(),
            nll: vec![],
        })
    }

    /// The decision data in words.
    pub fn describe(&self, d: &DiagnoseData) -> String {
        if self.cv() {
            let why = self.shift.as_ref().map_or(String::new(), |s| {
                format!(" (the select block is not representative of the training record: {s})")
            });
            let (held, scored) = self.folds.iter().fold((0, 0), |(h, s), f| {
                (
                    h + f.test.len().saturating_sub(self.w),
                    s + f.scored().count(),
                )
            });
            let outside = if scored < held {
                format!(
                    "; {} of {held} held-out samples lie outside the signal range of their fold's fit and are not scored",
                    held - scored
                )
            } else {
                String::new()
            };
            if d.multi() {
                return format!(
                    "leave-one-record-out cross-validation: {} folds, each training record held out whole and scored by the structure refitted on the other records (input-output models on all of them, the other classes on the longest) (the {} select samples are too few for the bootstrap), init window {}; input-output models fitted on all training records, the other classes on the longest, {} samples{outside}",
                    self.folds.len(),
                    d.select_samples(),
                    self.w,
                    self.fit_y.len()
                );
            }
            let spans = if self.spans_report {
                format!(
                    ", the report block included: the {}-sample select block is too short for the bootstrap, and a quarter of a short record held out of every decision costs more than a held-out figure is worth (the models are fitted on all {} samples; their figures on the report block are in-sample, the held-out figure is the cross-validated NRMSE)",
                    d.select.len(),
                    self.fit_y.len()
                )
            } else {
                String::new()
            };
            format!(
                "blocked cross-validation: {} contiguous folds over the {} training samples (each scored by the structure refitted on the longer contiguous rest){spans}, init window {}{outside}{why}",
                self.folds.len(),
                self.fit_y.len(),
                self.w
            )
        } else {
            if d.multi() {
                return format!(
                    "moving-block bootstrap on the {} select samples of {} training records (each record simulated from its own start, its first {} samples the init window; input-output models fitted on the fit parts of all records, {} samples, the other classes on the longest fit part, {} samples)",
                    d.select_samples(),
                    d.parts().len(),
                    self.w,
                    self.fits_y.iter().map(Record::len).sum::<usize>(),
                    self.fit_y.len()
                );
            }
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

/// Whether the cross-validation of `d` spans its report block: one
/// training record without a validation record (its report block the
/// record's tail, right after the select block), whose select block is
/// too short for the bootstrap, under the policy's `cv_whole_short_record`,
/// and at least `cv_whole_min_samples` long. A quarter held out of every
/// decision costs a short record more than a held-out figure for the
/// report is worth: the user's own test data give that. Folds of fewer
/// than about 200 held-out samples are too variable for the quarter more
/// to help (a clean linear record of 400 samples: its baseline's fold
/// refits scored NRMSE 5.6 to 0.31).
fn spans_report(d: &DiagnoseData, pol: &DecisionPolicy) -> bool {
    pol.cv_whole_short_record
        && d.single_record
        && !d.multi()
        && d.select.len() < pol.bootstrap_min_samples
        && d.report_range.start == d.select.end
        && !d.report_range.is_empty()
        && d.report_range.end - d.fit.start >= pol.cv_whole_min_samples
}

/// How the select block differs from the fit block, when it differs enough
/// that a decision on it would not speak for the training record: for the
/// output and each input `x`, with `m`, `s` the mean and standard deviation
/// of `x` over the fit block,
///
/// - the level ratio `rms(x_S − m) / s`,
/// - the pace ratio `(rms(Δx_S)/rms(x_S − m_S)) / (rms(Δx_F)/s)` (a sweep
///   moves its frequency, the ratio of the rms increment to the rms value
///   follows it),
/// - the share of select samples outside the fit block's range widened by
///   a tenth of its width (a drifting level leaves it).
///
/// A ratio beyond `block_shift_ratio` (either way) or a share above
/// `block_shift_outside` names the signal and the figure.
pub(crate) fn block_shift(d: &DiagnoseData, pol: &DecisionPolicy) -> Option<String> {
    record_shift(&d.train, d.fit.clone(), d.select.clone(), pol)
}

/// [`block_shift`] of the samples `s` of `rec` against its samples `f`
/// (`f` plays the fit block).
pub(crate) fn record_shift(
    rec: &gb_core::Record,
    f: std::ops::Range<usize>,
    s: std::ops::Range<usize>,
    pol: &DecisionPolicy,
) -> Option<String> {
    if f.len() < 20 || s.len() < 20 || f.end > rec.len() || s.end > rec.len() {
        return None;
    }
    let names = rec
        .input_names
        .iter()
        .chain(std::iter::once(&rec.output_name));
    let signals = rec.inputs.iter().chain(std::iter::once(&rec.output));
    for (name, x) in names.zip(signals) {
        let (xf, xs) = (&x[f.clone()], &x[s.clone()]);
        let (mf, sf) = (metrics::mean(xf), metrics::std(xf));
        if !(sf > 0.0 && sf.is_finite()) {
            continue;
        }
        let level =
            (xs.iter().map(|v| (v - mf).powi(2)).sum::<f64>() / xs.len() as f64).sqrt() / sf;
        let pace = |v: &[f64], sd: f64| {
            let d2 = v.windows(2).map(|w| (w[1] - w[0]).powi(2)).sum::<f64>();
            (d2 / (v.len() - 1) as f64).sqrt() / sd.max(1e-300)
        };
        let pace_ratio = pace(xs, metrics::std(xs)) / pace(xf, sf).max(1e-300);
        let (lo, hi) = metrics::min_max(xf);
        let pad = 0.1 * (hi - lo);
        let outside =
            xs.iter().filter(|&&v| v < lo - pad || v > hi + pad).count() as f64 / xs.len() as f64;
        let r = pol.block_shift_ratio;
        let off = |q: f64| !(q.is_finite() && q <= r && q >= 1.0 / r);
        if off(level) {
            return Some(format!("'{name}' level ratio {level:.2}"));
        }
        if off(pace_ratio) {
            return Some(format!("'{name}' pace ratio {pace_ratio:.2}"));
        }
        if outside > pol.block_shift_outside {
            return Some(format!(
                "{:.0} % of '{name}' outside the fit block's range",
                100.0 * outside
            ));
        }
    }
    None
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
    assess_from(plan, d, lineage, &|t| {
        fit(t.map(|(k, _)| k)).map(|m| (m, None))
    })
}

/// The in-sample gain of cross-validation's screen: `m`, fitted on the
/// whole training range, and the current model `cur`, compared by their
/// free-run residuals over the folds' samples, `1 − rms(e_m)/rms(e_cur)`,
/// with `m`'s residuals there. `None` when either simulation fails.
pub(crate) fn in_sample_gain(
    plan: &Plan,
    d: &DiagnoseData,
    m: &FittedModel,
    cur: &Evaluated,
) -> Option<(f64, Residuals)> {
    let after = plan.in_sample(m, d)?;
    let before = plan.in_sample(&cur.model, d)?;
    let gain = 1.0 - metrics::rms(&after.e) / metrics::rms(&before.e).max(f64::MIN_POSITIVE);
    Some((gain, after))
}

/// `m` scored on its in-sample residuals `after` (gain `gain` over the
/// current model there), marked `screened`: its folds are not fitted and
/// it does not pay. The in-sample screen of cross-validation: a candidate
/// that gains less than `min_gain` there is not expected to gain it on
/// held-out data (what it must reach to pay), and its fold fits (four of
/// its five fits) are skipped.
pub(crate) fn scored_in_sample(
    plan: &Plan,
    d: &DiagnoseData,
    (m, lineage): (&FittedModel, &Lineage),
    (gain, after): (f64, Residuals),
) -> Option<Evaluated> {
    let y: Vec<f64> = after
        .yhat
        .iter()
        .zip(&after.e)
        .map(|(a, b)| a + b)
        .collect();
    let sd = metrics::std(&y);
    let mut e = evaluate_on(m.clone(), lineage.clone(), d, plan.w, Some((after, sd))).ok()?;
    e.screened = Some(gain);
    Some(e)
}

/// [`assess`] where the fit on the plan's record may say which of several
/// starts won, and each fold's fit gets that choice (a multi-start fit
/// then refits only that start per fold).
pub(crate) fn assess_from(
    plan: &Plan,
    d: &DiagnoseData,
    lineage: Lineage,
    fit: &FoldFitFn,
) -> Result<Evaluated, DiagnoseError> {
    let whole = fit(None)?;
    let start = whole.1;
    if !plan.cv() {
        let m = plan.finish(whole.0, None)?;
        let mut e = evaluate_on(m, lineage, d, plan.w, None)?;
        e.start_choice = start;
        return Ok(e);
    }
    let m = plan.finish(whole.0.clone(), None)?;
    let folds: Vec<Evaluated> = (0..plan.folds.len())
        .into_par_iter()
        .map(|k| {
            let mk = plan.finish(fit(Some((k, &whole)))?.0, Some(k))?;
            fold_scores(mk, lineage.clone(), d, plan, k)
        })
        .collect::<Result<_, _>>()?;
    let mut pooled = Residuals::default();
    let mut y = vec![];
    for (f, fold) in folds.iter().zip(&plan.folds) {
        pooled.e.extend_from_slice(&f.select.e);
        pooled.yhat.extend_from_slice(&f.select.yhat);
        let rec = d.record(fold.record);
        y.extend(fold.scored().map(|k| rec.output[k]));
    }
    let sd = metrics::std(&y);
    let mut e = evaluate_on(m, lineage, d, plan.w, Some((pooled, sd)))?;
    e.folds = folds;
    e.start_choice = start;
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
    let fold = &plan.folds[k];
    let held = d.record(fold.record);
    let r = segment_residuals(&m, d, fold, plan.w)?;
    let y: Vec<f64> = fold.scored().map(|i| held.output[i]).collect();
    let sd = metrics::std(&y);
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
        finding: None,
        start_choice: None,
        screened: None,
        screened_by_rival: None,
        screened_by_bound: None,
    })
}

/// The free-run residuals of `m` on `fold`'s held-out samples, simulated
/// from the segment's start (its init window `w` not scored), at the
/// fold's scored samples.
fn segment_residuals(
    m: &FittedModel,
    d: &DiagnoseData,
    fold: &Fold,
    w: usize,
) -> Result<Residuals, DiagnoseError> {
    let rec = d.record(fold.record).slice(fold.test.clone());
    let all = residuals_on(m, &rec, &(0..rec.len()), w)?;
    let s = w.min(rec.len());
    let keep = |i: &usize| fold.keep.get(s + i).copied().unwrap_or(false);
    Ok(Residuals {
        e: (0..all.e.len()).filter(keep).map(|i| all.e[i]).collect(),
        yhat: (0..all.yhat.len())
            .filter(keep)
            .map(|i| all.yhat[i])
            .collect(),
        nll: vec![],
    })
}

/// Which samples of `test` (in `train`) a fold scores: those after the
/// init window `w` whose output and inputs lie in the range of the fold's
/// fit record `fit`, widened by the policy's `cv_cover_pad` of that range
/// on either side. A fold fitted on one side of a drifting record (a slow
/// excitation component, a changing level) otherwise extrapolates there,
/// which the model fitted on the whole record does not have to do; the
/// current model and a candidate are scored on the same samples. When
/// fewer than `cv_cover_min` of the fold's samples are covered, the whole
/// fold is scored (it cannot be judged by interpolation alone).
fn covered(
    fit: &Record,
    train: &Record,
    test: &Range<usize>,
    w: usize,
    pol: &DecisionPolicy,
) -> Vec<bool> {
    let s = w.min(test.len());
    let signals = |r: &Record| -> Vec<Vec<f64>> {
        r.inputs
            .iter()
            .cloned()
            .chain(std::iter::once(r.output.clone()))
            .collect()
    };
    let bounds: Vec<(f64, f64)> = signals(fit)
        .iter()
        .map(|x| {
            let (lo, hi) = metrics::min_max(x);
            let pad = pol.cv_cover_pad * (hi - lo);
            (lo - pad, hi + pad)
        })
        .collect();
    let all = signals(train);
    let inside = |k: usize| {
        all.iter()
            .zip(&bounds)
            .all(|(x, &(lo, hi))| (lo..=hi).contains(&x[k]))
    };
    let mut keep: Vec<bool> = (0..test.len())
        .map(|i| i >= s && inside(test.start + i))
        .collect();
    let n = test.len() - s;
    let kept = keep.iter().filter(|&&k| k).count();
    if (kept as f64) < pol.cv_cover_min * n as f64 {
        keep = (0..test.len()).map(|i| i >= s).collect();
    }
    keep
}

#[cfg(test)]
mod tests {
    use super::{block_shift, covered, Plan};
    use crate::{DecisionPolicy, DiagnoseData};
    use gb_core::Record;
    use rand::Rng;

    /// Fit/select/report 50/25/25 of `u`, with the output a smoothed `u`.
    fn data(u: Vec<f64>) -> DiagnoseData {
        let mut y = vec![0.0; u.len()];
        for k in 1..u.len() {
            y[k] = 0.8 * y[k - 1] + 0.2 * u[k - 1];
        }
        let rec = Record::new(vec!["u".into()], "y".into(), vec![u], y).expect("record");
        DiagnoseData::from_single(rec)
    }

    #[test]
    fn a_stationary_record_is_representative_and_a_sweep_or_a_drift_is_not() {
        let pol = DecisionPolicy::default();
        let mut rng = gb_core::rng::seeded(3);
        let n = 4000;
        let noise: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        assert_eq!(block_shift(&data(noise.clone()), &pol), None);
        // a linear chirp 0.002 -> 0.2 cycles/sample: the select block is
        // much faster than the fit block
        let sweep: Vec<f64> = (0..n)
            .map(|k| {
                let t = k as f64;
                (2.0 * std::f64::consts::PI * (0.002 * t + 0.099 * t * t / n as f64)).sin()
            })
            .collect();
        let why = block_shift(&data(sweep), &pol).expect("a sweep shifts");
        assert!(why.contains("pace"), "{why}");
        // the same noise on a ramp: the select block leaves the fit range
        let drift: Vec<f64> = noise
            .iter()
            .enumerate()
            .map(|(k, v)| v + 4.0 * k as f64 / n as f64)
            .collect();
        let why = block_shift(&data(drift), &pol).expect("a drift shifts");
        assert!(why.contains("level") || why.contains("outside"), "{why}");
    }

    #[test]
    fn the_template_sees_more_of_a_sweep_than_of_a_stationary_record() {
        let pol = DecisionPolicy::default();
        let mut rng = gb_core::rng::seeded(4);
        let n = 15_000;
        let rec = |u: Vec<f64>| data(u).train.slice(0..n);
        let noise: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let len = crate::physics::template_fit_len(&rec(noise), &pol);
        assert_eq!(len, pol.template_fit_samples);
        // a chirp 0.002 -> 0.2 cycles/sample over the record: no leading
        // part but the whole record represents it
        let sweep: Vec<f64> = (0..n)
            .map(|k| {
                let t = k as f64;
                (2.0 * std::f64::consts::PI * (0.002 * t + 0.099 * t * t / n as f64)).sin()
            })
            .collect();
        assert_eq!(
            crate::physics::template_fit_len(&rec(sweep.clone()), &pol),
            n
        );
        let capped = DecisionPolicy {
            template_fit_max: 10_000,
            ..pol.clone()
        };
        assert_eq!(
            crate::physics::template_fit_len(&rec(sweep), &capped),
            10_000
        );
    }

    #[test]
    fn a_fold_scores_only_the_samples_inside_its_fits_range() {
        let pol = DecisionPolicy::default();
        // output in [0, 1] on the fit side; the held-out block has 30 samples
        // at 0.5 and 20 at 5 (outside [-0.1, 1.1])
        let mut y: Vec<f64> = (0..100).map(|k| (k % 10) as f64 / 9.0).collect();
        y.extend((0..50).map(|k| if k < 30 { 0.5 } else { 5.0 }));
        let u: Vec<f64> = y.iter().map(|v| v * 0.1).collect();
        let train =
            Record::new(vec!["u".into()], "y".into(), vec![u.clone()], y.clone()).expect("record");
        // (the input, u = y / 10, leaves its range with the output)
        let fit = train.slice(0..100);
        let keep = covered(&fit, &train, &(100..150), 10, &pol);
        assert_eq!(keep.len(), 50);
        assert!(
            keep[..10].iter().all(|&k| !k),
            "the init window is not scored"
        );
        assert!(keep[10..30].iter().all(|&k| k));
        assert!(keep[30..].iter().all(|&k| !k));
        // a block almost entirely outside: scored whole
        let mut y2 = y.clone();
        for v in &mut y2[100..] {
            *v = 5.0;
        }
        let train2 = Record::new(vec!["u".into()], "y".into(), vec![u], y2).expect("record");
        let keep = covered(&train2.slice(0..100), &train2, &(100..150), 10, &pol);
        assert!(keep[10..].iter().all(|&k| k) && keep[..10].iter().all(|&k| !k));
        // the plan of a drifting short record scores fewer samples than it holds
        let n = 400;
        let mut rng = gb_core::rng::seeded(5);
        let noise: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let ramp: Vec<f64> = noise
            .iter()
            .enumerate()
            .map(|(k, v)| v + 6.0 * k as f64 / n as f64)
            .collect();
        let plan = Plan::new(&data(ramp), &pol);
        assert!(plan.cv());
        let held: usize = plan.folds.iter().map(|f| f.test.len() - plan.w).sum();
        let scored: usize = plan.folds.iter().map(|f| f.scored().count()).sum();
        assert!(scored < held, "scored {scored} of {held}");
    }

    /// A single record too short for the bootstrap cross-validates over all
    /// of it, its report block included; with the policy's
    /// `cv_whole_short_record` off the folds end at the select block, as
    /// they do for a record below `cv_whole_min_samples`, and a record long
    /// enough for the bootstrap keeps its select block.
    #[test]
    fn a_short_single_record_cross_validates_over_its_report_block_too() {
        let mut rng = gb_core::rng::seeded(11);
        let mut u =
            |n: usize| -> Vec<f64> { (0..n).map(|_| rng.random_range(-1.0..1.0)).collect() };
        let short = data(u(1000));
        let pol = DecisionPolicy::default();
        let plan = Plan::new(&short, &pol);
        assert!(plan.spans_report && plan.cv());
        assert_eq!(plan.fit_y.len(), 1000);
        assert_eq!(plan.folds.first().map(|f| f.test.start), Some(0));
        assert_eq!(plan.folds.last().map(|f| f.test.end), Some(1000));
        assert!(plan.describe(&short).contains("the report block included"));
        let off = DecisionPolicy {
            cv_whole_short_record: false,
            ..DecisionPolicy::default()
        };
        let plan = Plan::new(&short, &off);
        assert!(!plan.spans_report && plan.cv());
        assert_eq!(plan.folds.last().map(|f| f.test.end), Some(750));
        assert_eq!(plan.fit_y.len(), 750);
        let long = data(u(4000));
        let plan = Plan::new(&long, &pol);
        assert!(!plan.spans_report && !plan.cv());
        // below `cv_whole_min_samples` the report block stays held out
        let tiny = data(u(400));
        let plan = Plan::new(&tiny, &pol);
        assert!(!plan.spans_report && plan.cv());
        assert_eq!(plan.folds.last().map(|f| f.test.end), Some(300));
    }

    /// Under cross-validation every fold's fit is given the fit on the
    /// whole training record and the start it chose (a warm start for the
    /// fits that can use one), and each fold is fitted on its own record.
    #[test]
    fn each_fold_fit_is_given_the_whole_records_fit() {
        use gb_core::Records;
        let mut rng = gb_core::rng::seeded(5);
        let u: Vec<f64> = (0..600).map(|_| rng.random_range(-1.0..1.0)).collect();
        let d = data(u);
        let plan = Plan::new(&d, &DecisionPolicy::default());
        assert!(plan.cv(), "600 samples: cross-validation");
        let spec: gb_core::ModelSpec = "linear:order=1".parse().expect("spec");
        let fit_on = |rec: &Record| {
            gb_model::recipes::fit(&spec, &Records::single(rec.clone()), &gb_core::Silent)
                .map(|f| f.model)
                .map_err(crate::DiagnoseError::from)
        };
        // the free-run simulation of a model on the whole record: the
        // whole record's fit and a fold's fit differ in their parameters
        let simulated = |m: &gb_core::FittedModel| {
            let out = &plan.fit.output[..10];
            m.dynamics
                .simulate(&plan.fit.inputs, gb_core::Init::Window(out))
                .expect("simulated")
        };
        let whole = fit_on(&plan.fit).expect("whole fit");
        let folds_differ = (0..plan.folds.len())
            .map(|k| fit_on(plan.fit_of(Some(k))).expect("fold fit"))
            .all(|m| simulated(&m) != simulated(&whole));
        assert!(
            folds_differ,
            "a fold's fit is told apart from the whole record's"
        );
        let seen = std::sync::Mutex::new(vec![]);
        let lineage = crate::evaluate::Lineage::Other {
            spec: "linear:order=1".into(),
            order: 1,
        };
        let e = super::assess_from(&plan, &d, lineage, &|t| match t {
            None => Ok((whole.clone(), Some(3))),
            Some((k, (w, start))) => {
                let same = simulated(w) == simulated(&whole);
                seen.lock().expect("lock").push((k, *start, same));
                fit_on(plan.fit_of(Some(k))).map(|m| (m, None))
            }
        })
        .expect("assessed");
        let mut seen = seen.into_inner().expect("lock");
        seen.sort_by_key(|s| s.0);
        let want: Vec<_> = (0..plan.folds.len()).map(|k| (k, Some(3), true)).collect();
        assert_eq!(seen, want);
        assert_eq!(e.folds.len(), plan.folds.len());
        assert_eq!(e.start_choice, Some(3));
    }
}
