//! `nonlinearity`: a polynomial NOE model (gb-lmn `poly`) on the current
//! input–output model's regressors.
use super::{fit_spec, plain_linear_structure};
use crate::evaluate::Lineage;
use crate::extension::{Context, Extension, Proposal};
use crate::{Cause, DiagnoseError};
use gb_core::FittedModel;

/// Replace the linear model by a polynomial of degree ≤ 3 in the same
/// lagged outputs and inputs (terms by FROLS, their number on a hold-out of
/// the fit block, refined for the simulation error).
pub struct PolyNoe;

impl Extension for PolyNoe {
    fn fit_cost(&self) -> u8 {
        0
    }
    fn name(&self) -> &'static str {
        "poly-noe"
    }
    fn cause(&self) -> Cause {
        Cause::Nonlinearity
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        let Some((order, delay)) = plain_linear_structure(ctx) else {
            return vec![];
        };
        vec![Proposal {
            cause: Cause::Nonlinearity,
            lineage: Lineage::Other {
                spec: format!("poly:order={order},delay={delay},degree=3,max_terms=15"),
                order,
            },
            text: "polynomial NOE on the same regressors (degree <= 3, terms by FROLS on the error reduction ratio, their number on a hold-out of the fit block, refined for the simulation error)".into(),
        }]
    }
    fn fit(&self, p: &Proposal, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
        fit_spec(&p.lineage, ctx, ctx.policy().nonlinear_fit_samples)
    }
    fn evidence(&self, _p: &Proposal, ctx: &Context) -> String {
        ctx.evidence.nonlinearity_text()
    }
    fn row_text(&self, p: &Proposal, fitted: &FittedModel) -> String {
        format!("{} -> {}", p.text, fitted.dynamics.describe())
    }
}
