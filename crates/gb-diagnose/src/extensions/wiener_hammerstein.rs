//! `nonlinearity`: a Wiener–Hammerstein network (a static local model
//! network between two linear filters, from the best linear approximation).
use super::{fit_spec, plain_linear_structure};
use crate::evaluate::Lineage;
use crate::extension::{Context, Extension, Proposal};
use crate::{Cause, DiagnoseError};
use gb_core::FittedModel;

/// Fewest fit samples for the best linear approximation and its pole/zero
/// splits (the recipe's own minimum).
const MIN_FIT_SAMPLES: usize = 1000;

/// `y = G₂(f(G₁ u))`: the best linear approximation's poles and zeros split
/// between the filters `G₁` and `G₂` (every split scanned, the best refined),
/// the static map `f` a local model network of `v = G₁ u`, then all of it
/// refined by Levenberg–Marquardt on the simulation error (gb-lmn's
/// `WienerHammersteinNetwork`; orders and split chosen on the fit block).
/// One input; proposed while the current model is plain linear.
pub struct WienerHammerstein;

impl Extension for WienerHammerstein {
    fn fit_cost(&self) -> u8 {
        3
    }
    fn name(&self) -> &'static str {
        "wiener-hammerstein"
    }
    fn screen_tier(&self) -> u8 {
        2
    }
    fn cause(&self) -> Cause {
        Cause::Nonlinearity
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        let Some((order, _)) = plain_linear_structure(ctx) else {
            return vec![];
        };
        if ctx.fit.n_inputs() != 1 || ctx.fit.len() < MIN_FIT_SAMPLES {
            return vec![];
        }
        vec![Proposal {
            cause: Cause::Nonlinearity,
            lineage: Lineage::Other {
                spec: "wiener-hammerstein".into(),
                order,
            },
            text: "Wiener-Hammerstein network: a static local model network between two linear filters split from the best linear approximation, refined on the simulation error".into(),
        }]
    }
    /// A fold of cross-validation (and the refit on the whole training
    /// record) refines the network fitted on the whole fit block, its
    /// orders, split and local models kept, instead of fitting one from
    /// the best linear approximation again; the full fit when that fails.
    fn fit(&self, p: &Proposal, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
        let cap = ctx.policy().expensive_fit_samples;
        if let Some(start) = ctx.whole_fit {
            let sub = ctx.fit.slice(0..ctx.fit.len().min(cap));
            let data = gb_core::Records::single(sub);
            if let Ok(Some(f)) = gb_model::recipes::refit_wiener_hammerstein(start, &data) {
                return Ok(f.model);
            }
        }
        fit_spec(&p.lineage, ctx, cap)
    }
    fn evidence(&self, _p: &Proposal, ctx: &Context) -> String {
        ctx.evidence.nonlinearity_text()
    }
    fn row_text(&self, p: &Proposal, fitted: &FittedModel) -> String {
        format!("{} -> {}", p.text, fitted.dynamics.describe())
    }
}
