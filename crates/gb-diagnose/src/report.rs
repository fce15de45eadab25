//! The report of a diagnosis (its JSON form) and the plain-text renderer.
use crate::evaluate::Evaluated;
use crate::verdict::Verdict;
use crate::{Cause, Evidence};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;

/// Version of the report format.
pub const REPORT_VERSION: u32 = 3;

/// One row of the diagnosis: a candidate extension and whether it paid.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Step {
    /// Iteration (1-based).
    pub iteration: usize,
    /// Cause tested.
    pub cause: Cause,
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
    /// The noise a `noise` candidate found.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise: Option<NoiseFound>,
}

/// Which noise a `noise` candidate found, and what its noise model
/// predicts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NoiseFound {
    /// `process` (a disturbance inside the dynamics) or `measurement`
    /// (white, or heavy-tailed).
    pub kind: String,
    /// In words, with the fitted noise levels.
    pub text: String,
    /// `(k, before, after)`: report-block RMSE of the k-step prediction of
    /// the model before (an output-error model predicts by its simulation)
    /// and with the noise model (empty for a white noise model).
    #[serde(default)]
    pub prediction: Vec<(usize, f64, f64)>,
}

impl NoiseFound {
    /// One line for the text report.
    pub fn line(&self) -> String {
        let mut s = self.text.clone();
        if !self.prediction.is_empty() {
            let p: Vec<String> = self
                .prediction
                .iter()
                .map(|(k, b, a)| format!("{k}-step {b:.3e} -> {a:.3e}"))
                .collect();
            s.push_str(&format!(
                "; prediction RMSE (report block) {}",
                p.join(", ")
            ));
        }
        s
    }
}

/// Summary of a model in the report.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ModelSummary {
    /// Description.
    pub model: String,
    /// Model class tag (the registry's).
    pub class: String,
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
    /// Input delay per input in samples (0: direct feedthrough; empty for
    /// the hidden-state model).
    #[serde(default)]
    pub delay: Vec<usize>,
    /// The model integrates its output (models the increments, a pole at 1).
    #[serde(default)]
    pub integrating: bool,
    /// A physics model's parameters with their standard errors, in words
    /// (empty for the other classes).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub parameter_values: String,
}

impl ModelSummary {
    pub(crate) fn of(e: &Evaluated) -> Self {
        // an equation-error estimate is simulated like an output-error
        // model but not trained as one
        let arx = e
            .lineage
            .io()
            .is_some_and(|p| p.fit.equation_error && crate::extensions::plain_linear(p));
        let model = match e.model.describe() {
            d if arx => d.replacen(
                "linear output-error",
                "linear model estimated by least squares on the measured output lags (ARX, equation error)",
                1,
            ),
            d => d,
        };
        Self {
            model,
            class: e.model.dynamics.class().to_string(),
            spec: e.lineage.spec(),
            order: e.lineage.order(),
            nrmse: e.scores.nrmse,
            nll: e.scores.nll,
            nrmse_select: e.scores.nrmse_select,
            parameters: e.model.dynamics.n_parameters(),
            delay: e
                .lineage
                .io()
                .map(|p| {
                    if p.delay.is_empty() {
                        vec![1; e.model.input_names.len()]
                    } else {
                        p.delay.clone()
                    }
                })
                .unwrap_or_default(),
            integrating: e.model.dynamics.class() == gb_model::INTEGRATING_CLASS,
            parameter_values: crate::physics::physics_of(&e.model)
                .map_or(String::new(), crate::physics::parameters_text),
        }
    }
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
    /// Init window of the evaluated records (not scored).
    #[serde(default)]
    pub init_window: usize,
    /// How decisions are made (select-block bootstrap or blocked
    /// cross-validation).
    #[serde(default)]
    pub decision: String,
    /// The records of a multi-record diagnosis (training records, then the
    /// report record); empty with one training record.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub records: Vec<RecordSummary>,
    /// The report block was part of the cross-validation (a short record
    /// without a validation record, the policy's `cv_whole_short_record`):
    /// the figures on it are in-sample.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub report_in_sample: bool,
}

/// One record of a multi-record diagnosis and how its samples are used.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RecordSummary {
    /// File name (or `record i`).
    pub name: String,
    /// Samples of the record.
    pub samples: usize,
    /// Samples of its fit part (0 for the report record).
    pub fit: usize,
    /// Samples of its select part (0 for the report record).
    pub select: usize,
    /// Samples of its report block (0 for a training record).
    pub report: usize,
}

impl RecordSummary {
    /// `a.csv: fit 750 / select 250` or `v.csv: report 1000`.
    pub fn text(&self) -> String {
        if self.report > 0 {
            format!("{}: report {}", self.name, self.report)
        } else {
            format!("{}: fit {} / select {}", self.name, self.fit, self.select)
        }
    }
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
    /// How the baseline's structure (delay, integrator, order) was chosen.
    #[serde(default)]
    pub structure: crate::StructureChoice,
    /// Candidate extensions, per iteration.
    pub steps: Vec<Step>,
    /// Accepted causes in order (`[]`: no extension paid).
    pub causes: Vec<Cause>,
    /// The final model.
    #[serde(rename = "final")]
    pub final_model: ModelSummary,
    /// Residual evidence of the baseline (select block).
    pub evidence: Evidence,
    /// Residual evidence of the final model.
    pub final_evidence: Evidence,
    /// What the residual tests say about the final model.
    pub verdict: Verdict,
    /// The noise found by an accepted `noise` step (process or
    /// measurement noise).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise: Option<NoiseFound>,
}

impl Report {
    /// The causes as names.
    pub fn cause_names(&self) -> Vec<&'static str> {
        self.causes.iter().map(|c| c.name()).collect()
    }

    /// Why no cause was named: no candidate paid, or none was tried (the
    /// search budget ended the search first, or no extension applied).
    pub fn no_cause_reason(&self) -> &'static str {
        if self.steps.is_empty() {
            "no extension was tried; see the decisions line"
        } else {
            "no extension paid on held-out data"
        }
    }

    /// The step table and verdict as plain text (what `greybox diagnose`
    /// prints).
    pub fn to_text(&self) -> String {
        let mut s = String::new();
        let r = self;
        let _ = writeln!(
            s,
            "data: inputs {} -> output {}; fit {} / select {} / report {} samples{}",
            r.data.inputs.join(","),
            r.data.output,
            r.data.samples_fit,
            r.data.samples_select,
            r.data.samples_validate,
            if r.data.report_in_sample {
                " (the report block in-sample: the short record is cross-validated whole)"
            } else {
                ""
            }
        );
        if !r.data.records.is_empty() {
            let recs: Vec<String> = r.data.records.iter().map(|x| x.text()).collect();
            let _ = writeln!(s, "records: {}", recs.join("; "));
        }
        let _ = writeln!(s, "decisions: {}", r.data.decision);
        let _ = writeln!(
            s,
            "baseline: {}  NRMSE {:.4}  nll {:.3}",
            r.baseline.model, r.baseline.nrmse, r.baseline.nll
        );
        let _ = writeln!(s, "          {}\n", r.structure.text());
        if !r.steps.is_empty() {
            let _ = writeln!(
                s,
                "{:<4} {:<14} {:>8} {:>8} {:>8} {:>25} {:<8} extension / evidence",
                "step", "cause", "NRMSE", "->", "gain", "select gain [95%]", "accepted"
            );
        }
        for st in &r.steps {
            let gain = if st.gain_metric == "nll" {
                format!("{:+.3}nll", st.gain)
            } else {
                format!("{:+.1}%", 100.0 * st.gain)
            };
            let _ = writeln!(
                s,
                "{:<4} {:<14} {:>8.4} {:>8.4} {:>8} {:>+7.3} [{:+.2},{:+.2}] {:<8} {}",
                st.iteration,
                st.cause.name(),
                st.nrmse_before,
                st.nrmse_after,
                gain,
                st.gain_select,
                st.gain_ci[0],
                st.gain_ci[1],
                if st.accepted { "yes" } else { "no" },
                st.extension
            );
            if st.accepted {
                let _ = writeln!(s, "               evidence: {}", st.evidence);
                if let Some(n) = &st.noise {
                    let _ = writeln!(s, "               noise found: {}", n.line());
                }
            }
        }
        let causes = if r.causes.is_empty() {
            format!("none ({})", r.no_cause_reason())
        } else {
            r.cause_names().join(", ")
        };
        let _ = writeln!(s, "\ncauses: {causes}");
        if let Some(n) = &r.noise {
            let _ = writeln!(s, "noise: {} noise found", n.kind);
        }
        let _ = writeln!(s, "verdict: {}", r.verdict.text);
        let _ = writeln!(
            s,
            "final: {}  NRMSE {:.4}  nll {:.3}",
            r.final_model.model, r.final_model.nrmse, r.final_model.nll
        );
        if !r.final_model.parameter_values.is_empty() {
            let _ = writeln!(s, "       {}", r.final_model.parameter_values);
        }
        s
    }
}
