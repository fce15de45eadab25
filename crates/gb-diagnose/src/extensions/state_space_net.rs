//! `nonlinearity`: a state-space local model network (hidden states whose
//! update is a local model network of the states and inputs).
use super::{fit_spec, plain_linear_structure};
use crate::evaluate::Lineage;
use crate::extension::{Context, Extension, Proposal};
use crate::{Cause, DiagnoseError};
use gb_core::FittedModel;

/// Most hidden states of the network (the recipe's limit).
const MAX_STATES: usize = 8;

/// `x(k+1) = Σᵢ Φᵢ(x(k)) (Aᵢ x(k) + Bᵢ ψ(u(k)) + cᵢ)`, `y = C x` with a
/// square-root basis and learned state bounds (gb-lmn's `SsLmnModel`), as
/// many states as the current linear order, 1 or 2 local models chosen on a
/// hold-out of the fit block, trained on the simulation error. Proposed
/// while the current model is plain linear.
pub struct StateSpaceNetwork;

impl Extension for StateSpaceNetwork {
    fn name(&self) -> &'static str {
        "state-space-network"
    }
    fn cause(&self) -> Cause {
        Cause::Nonlinearity
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        let Some((order, _)) = plain_linear_structure(ctx) else {
            return vec![];
        };
        let states = order.clamp(1, MAX_STATES);
        vec![Proposal {
            cause: Cause::Nonlinearity,
            lineage: Lineage::Other {
                spec: format!("lmn-state-space:order={states}"),
                order: states,
            },
            text: format!(
                "state-space local model network: {states} hidden states, square-root basis, learned state bounds, 1 or 2 local models chosen on a hold-out of the fit block, trained on the simulation error"
            ),
        }]
    }
    fn fit(&self, p: &Proposal, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
        fit_spec(&p.lineage, ctx, ctx.policy().expensive_fit_samples)
    }
    fn evidence(&self, _p: &Proposal, ctx: &Context) -> String {
        ctx.evidence.nonlinearity_text()
    }
    fn row_text(&self, p: &Proposal, fitted: &FittedModel) -> String {
        format!("{} -> {}", p.text, fitted.dynamics.describe())
    }
}
