//! The escalation: the thesis' wavelet-sparse state space with hidden
//! states (gb-model), when a named cause stays unexplained.
use crate::evaluate::Lineage;
use crate::extension::{Context, Extension, Proposal, Role};
use crate::{Cause, DiagnoseError};
use gb_core::{FittedModel, NoiseModel};

/// The hidden-state model, tried once per diagnosis when a structural cause
/// (`hysteresis` or `dynamics`) is named and addressed by its simple
/// extension, no new cause pays in this iteration, and the residuals are
/// still not white (Ljung–Box or the direction-of-motion memory test at the
/// policy's `unexplained_p`).
pub struct HiddenState;

impl Extension for HiddenState {
    fn fit_cost(&self) -> u8 {
        3
    }
    fn name(&self) -> &'static str {
        "hidden-state"
    }
    fn screen_tier(&self) -> u8 {
        2
    }
    fn cause(&self) -> Cause {
        Cause::Hysteresis
    }
    fn role(&self) -> Role {
        Role::Escalation
    }
    fn once(&self) -> bool {
        true
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        let Some(p) = ctx.current.lineage.io() else {
            return vec![];
        };
        let ev = ctx.evidence;
        let lim = ctx.policy().unexplained_p;
        if !(ev.ljung_box.1 < lim || ev.memory.1 < lim) {
            return vec![];
        }
        if ctx.named(Cause::Hysteresis) && p.hysteresis {
            return vec![Proposal {
                cause: Cause::Hysteresis,
                lineage: Lineage::HiddenState {
                    order: p.order,
                    hysteresis: true,
                    detail: 0,
                },
                text: "hidden-state model (gb-model): a hidden hysteretic state with a sparse wavelet law (mechanical structure with restoring force z, ż = f(v, z), when the linear model oscillates; else hidden states with f(x₁, u₁) and a Preisach component with a wavelet Everett function), trained output-error".into(),
            }];
        }
        if ctx.named(Cause::Dynamics) {
            return vec![Proposal {
                cause: Cause::Dynamics,
                lineage: Lineage::HiddenState {
                    order: p.order,
                    hysteresis: p.hysteresis,
                    detail: 0,
                },
                text: format!(
                    "hidden-state model (gb-model): {} hidden states with a sparse wavelet term f(x₁, u₁), trained output-error",
                    p.order
                ),
            }];
        }
        vec![]
    }
    /// Fitted on at most the policy's `hidden_state_fit_samples` of the fit
    /// block (its output-error fit is the costliest; the select block judges
    /// it as usual).
    fn fit(&self, p: &Proposal, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
        let Lineage::HiddenState {
            order, hysteresis, ..
        } = p.lineage
        else {
            return Err(DiagnoseError::InvalidArgument(
                "not a hidden-state proposal".into(),
            ));
        };
        let n = ctx.fit.len().min(ctx.policy().hidden_state_fit_samples);
        let sub = ctx.fit.slice(0..n);
        let names: Vec<String> = sub
            .input_names
            .iter()
            .chain(std::iter::once(&sub.output_name))
            .cloned()
            .collect();
        let ss = gb_model::recipes::fit_hidden_state(
            &sub.inputs,
            &sub.output,
            order,
            hysteresis,
            names,
        )?;
        state_space_model(ss, &sub)
    }
    fn evidence(&self, p: &Proposal, ctx: &Context) -> String {
        let ev = ctx.evidence;
        format!(
            "the simple extension for the named {} leaves the residuals non-white (Ljung-Box Q={:.0}, p={:.1e}; memory F={:.1}, p={:.1e}) and no new cause pays",
            p.cause, ev.ljung_box.0, ev.ljung_box.1, ev.memory.0, ev.memory.1
        )
    }
    fn row_text(&self, p: &Proposal, fitted: &FittedModel) -> String {
        format!("{} -> {}", p.text, fitted.dynamics.describe())
    }
}

/// The fitted model of a hidden-state model `ss` fitted on `rec`, with the
/// Gaussian noise model of its free-run residual there.
pub(crate) fn state_space_model(
    ss: gb_model::SparseStateSpace,
    rec: &gb_core::Record,
) -> Result<FittedModel, DiagnoseError> {
    let sim = ss.simulate(&rec.inputs)?;
    let res: Vec<f64> = rec.output.iter().zip(&sim).map(|(a, b)| a - b).collect();
    Ok(FittedModel::new(
        rec.input_names.clone(),
        vec![rec.output_name.clone()],
        Box::new(ss),
        NoiseModel::gaussian(&res),
    )?)
}
