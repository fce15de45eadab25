//! `hysteresis`: play operators and a discrete Preisach operator on the
//! simulated output, play operators on every input.
use crate::curves::direction_means;
use crate::evaluate::{Lineage, Residuals};
use crate::extension::{Context, Extension, Proposal};
use crate::{Cause, DiagnoseError};
use gb_core::{FittedModel, ModelView, Series, ViewData};

/// Add Preisach-type columns whose weights enter linearly (Hauth 2008,
/// ch. 3), trained output-error.
pub struct PreisachColumns;

impl Extension for PreisachColumns {
    fn name(&self) -> &'static str {
        "preisach-columns"
    }
    fn cause(&self) -> Cause {
        Cause::Hysteresis
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        match ctx.current.lineage.io() {
            Some(p) if !p.hysteresis => {
                // a hysteretic force inside continuous dynamics reaches the
                // sampled output through one lag more than the linear part
                let max = ctx.policy().max_order;
                let mut orders = vec![p.order];
                if p.order < max {
                    orders.push(p.order + 1);
                }
                orders
                    .into_iter()
                    .map(|order| Proposal {
                        cause: Cause::Hysteresis,
                        lineage: Lineage::Io(gb_lmn::IoNetworkParams {
                            hysteresis: true,
                            order,
                            ..p.clone()
                        }),
                        text: format!("Preisach component on the simulated output (6 play operators + a 21-relay discrete Preisach operator) and 8 play operators per input, at lags 1..{}, weights linear, regressor order {order}, trained output-error", order + 1),
                    })
                    .collect()
            }
            _ => vec![],
        }
    }
    fn fit(&self, p: &Proposal, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
        super::fit_io(p.lineage.io().expect("an input-output proposal"), ctx)
    }
    fn evidence(&self, _p: &Proposal, ctx: &Context) -> String {
        ctx.evidence.hysteresis_text()
    }
    fn evidence_view(&self, b: &Residuals, a: &Residuals, output: &str) -> Option<ModelView> {
        let (up, down) = direction_means(&b.yhat, &b.e, 24);
        let (up_a, down_a) = direction_means(&a.yhat, &a.e, 24);
        let line = |name: &str, points| Series {
            name: name.into(),
            points,
            markers: false,
        };
        Some(ModelView {
            key: "hysteresis".into(),
            title: "Mean residual vs simulated output, rising vs falling: two branches = a loop = hysteresis".into(),
            caption: String::new(),
            data: ViewData::Curves {
                x_label: format!("simulated {output}"),
                y_label: "mean residual".into(),
                series: vec![
                    line("before, rising", up),
                    line("before, falling", down),
                    line("after, rising", up_a),
                    line("after, falling", down_a),
                ],
                log_y: false,
            },
        })
    }
}
