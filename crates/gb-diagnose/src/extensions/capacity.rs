//! More capacity for a cause already named: more local models / operators
//! (a finer fed-back map) and one more lag of every regressor. A new cause must beat it.
use crate::evaluate::Lineage;
use crate::extension::{Context, Extension, Proposal, Role};
use crate::{Cause, DiagnoseError};
use gb_core::FittedModel;

/// More of what the model has, for the last named structural cause.
pub struct Capacity;

/// Highest capacity level.
const MAX_DETAIL: u8 = 2;

impl Extension for Capacity {
    fn name(&self) -> &'static str {
        "capacity"
    }
    fn cause(&self) -> Cause {
        Cause::Nonlinearity
    }
    fn role(&self) -> Role {
        Role::Refinement
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        let Some(p) = ctx.current.lineage.io() else {
            return vec![];
        };
        let last = ctx
            .causes
            .iter()
            .rev()
            .find(|c| matches!(c, Cause::Nonlinearity | Cause::Hysteresis));
        let Some(&cause) = last else {
            return vec![];
        };
        if p.detail >= MAX_DETAIL {
            return vec![];
        }
        // a nonlinear force inside continuous dynamics reaches the sampled
        // output through more lags than the linear part needs
        let s = gb_lmn::IoNetworkParams {
            detail: p.detail + 1,
            order: (p.order + 1).min(ctx.policy().max_order),
            ..p.clone()
        };
        if !(p.network || p.hysteresis || p.output_map > 0) {
            return vec![];
        }
        if !p.network && !p.hysteresis {
            // a fed-back map of the output (`FeedbackMap`): twice the
            // intervals
            return vec![Proposal {
                cause,
                text: format!(
                    "more capacity for the named nonlinearity: a fed-back map of {} intervals, regressor lags {}",
                    2 * p.output_map,
                    s.order
                ),
                lineage: Lineage::Io(gb_lmn::IoNetworkParams {
                    output_map: 2 * p.output_map,
                    ..s
                }),
            }];
        }
        let text = if s.network && cause == Cause::Nonlinearity {
            format!(
                "more capacity for the named nonlinearity: up to {} local models, regressor lags {}",
                s.max_leaves(),
                s.order
            )
        } else {
            let l = 6 + 2 * s.detail as usize;
            let d = 1 + s.detail as usize;
            let cols = match s.hysteresis_on {
                gb_lmn::HysteresisOn::Both => format!(
                    "{} play operators and {} Preisach cells on the output, up to {} play operators per input",
                    6 * d,
                    l * (l + 1) / 2,
                    8 * d
                ),
                gb_lmn::HysteresisOn::Output => format!("{} play operators on the output", 6 * d),
                gb_lmn::HysteresisOn::Inputs => {
                    format!("up to {} play operators per input", 8 * d)
                }
            };
            format!(
                "more capacity for the named hysteresis: {cols}, regressor lags {}",
                s.order
            )
        };
        vec![Proposal {
            cause,
            lineage: Lineage::Io(s),
            text,
        }]
    }
    fn fit(&self, p: &Proposal, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
        let io = p.lineage.io().expect("an input-output proposal");
        if !io.network && !io.hysteresis && io.output_map > 0 {
            return super::feedback::cold_fit(io, ctx);
        }
        super::fit_io(io, ctx)
    }
    fn evidence(&self, p: &Proposal, _ctx: &Context) -> String {
        format!("the named {} pays further with more capacity", p.cause)
    }
}
