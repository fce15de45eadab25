//! `nonlinearity`: a Wiener model (the linear dynamics, then a static map
//! of the output).
use super::{delay_choices, fit_block_choosing, plain_linear_structure};
use crate::evaluate::Lineage;
use crate::extension::{Context, Extension, Proposal};
use crate::{Cause, DiagnoseError};
use gb_core::FittedModel;

/// The current linear dynamics followed by a static map of the output
/// (cubic polynomial, cubic spline or piecewise linear, knots at quantiles, the structure
/// chosen on a hold-out of the fit block), trained output-error, with the
/// current input delay or one of [`super::delay_variants`] when it fits
/// the hold-out better ([`delay_choices`]).
pub struct Wiener;

impl Extension for Wiener {
    fn fit_cost(&self) -> u8 {
        2
    }
    fn name(&self) -> &'static str {
        "wiener"
    }
    fn cause(&self) -> Cause {
        Cause::Nonlinearity
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        let Some((order, delay)) = plain_linear_structure(ctx) else {
            return vec![];
        };
        delay_choices(ctx, &delay)
            .into_iter()
            .map(|(d, words)| Proposal {
                cause: Cause::Nonlinearity,
                lineage: Lineage::Other {
                    spec: format!("wiener:order={order},delay={d}"),
                    order,
                },
                text: format!(
                    "Wiener: the linear dynamics of order {order} ({words}), then a static map of the output (cubic polynomial, cubic spline or piecewise linear, chosen on a hold-out of the fit block), trained output-error"
                ),
            })
            .collect()
    }
    fn delay_rivals_key(&self, p: &Proposal) -> Option<String> {
        super::delay_free_key(&p.lineage)
    }
    fn fit_choosing(
        &self,
        p: &Proposal,
        ctx: &Context,
    ) -> Result<(FittedModel, Option<usize>), DiagnoseError> {
        fit_block_choosing(&p.lineage, ctx)
    }
    fn evidence(&self, _p: &Proposal, ctx: &Context) -> String {
        ctx.evidence.nonlinearity_text()
    }
    fn row_text(&self, p: &Proposal, fitted: &FittedModel) -> String {
        format!("{} -> {}", p.text, fitted.dynamics.describe())
    }
}
