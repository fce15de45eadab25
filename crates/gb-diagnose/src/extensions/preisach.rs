//! `hysteresis`: play operators and a discrete Preisach operator on the
//! simulated output, play operators on every input.
use crate::curves::direction_means;
use crate::evaluate::{Lineage, Residuals};
use crate::extension::{Context, Extension, Proposal};
use crate::{Cause, DiagnoseError};
use gb_core::{FittedModel, ModelView, Series, ViewData};
use gb_lmn::HysteresisOn;

/// The hysteresis columns of a candidate, in words.
fn columns_text(on: HysteresisOn) -> &'static str {
    match on {
        HysteresisOn::Both => "Preisach component on the simulated output (6 play operators + a discrete Preisach operator of 21 cells, each a uniform density of 4x4 relays) and up to 8 play operators per input (thresholds within its range)",
        HysteresisOn::Output => "6 play operators on the simulated output alone (a Prandtl-Ishlinskii operator: a hysteretic force on the state that depends on the motion, not on the absolute position)",
        HysteresisOn::Inputs => "up to 8 play operators per input alone (thresholds within its range: hysteresis before the dynamics)",
    }
}

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
    /// At the current order and one more: the full set of columns and the
    /// output plays alone (a Prandtl–Ishlinskii force on the state), and at
    /// the current order the input plays alone (hysteresis before the
    /// dynamics). The one-sided candidates have a fraction of the columns,
    /// and the output-side weights are trained as one force through one lag
    /// filter (β[l, i] = c_l wᵢ): on short records a weight per column and
    /// lag overfits.
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        let Some(p) = ctx.current.lineage.io().filter(|p| !p.hysteresis) else {
            return vec![];
        };
        // a hysteretic force inside continuous dynamics reaches the
        // sampled output through one lag more than the linear part
        let max = ctx.policy().max_order;
        let mut variants = vec![];
        for order in [p.order, p.order + 1] {
            if order > max {
                continue;
            }
            variants.push((order, HysteresisOn::Both));
            variants.push((order, HysteresisOn::Output));
            if order == p.order {
                variants.push((order, HysteresisOn::Inputs));
            }
        }
        variants
            .into_iter()
            .map(|(order, on)| Proposal {
                cause: Cause::Hysteresis,
                lineage: Lineage::Io(gb_lmn::IoNetworkParams {
                    hysteresis: true,
                    hysteresis_on: on,
                    // the output block's many columns as one force
                    // through one lag filter; the few input plays keep a
                    // weight per lag
                    separable_hysteresis: on != HysteresisOn::Inputs,
                    order,
                    ..p.clone()
                }),
                text: format!(
                    "{}, at lags 1..{}, weights linear, regressor order {order}, trained output-error",
                    columns_text(on),
                    order + 1
                ),
            })
            .collect()
    }
    /// On one training record longer than the policy's
    /// `nonlinear_fit_samples`, fitted on that many leading samples of the
    /// fit block (each relay column is stepped per sample and fit).
    fn fit(&self, p: &Proposal, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
        let io = p.lineage.io().ok_or_else(|| {
            DiagnoseError::InvalidArgument("preisach-columns: not an input-output proposal".into())
        })?;
        super::on_leading(ctx, ctx.policy().nonlinear_fit_samples, |c| {
            super::fit_io(io, c)
        })
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
