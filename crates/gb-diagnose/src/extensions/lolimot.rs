//! `nonlinearity`: a LOLIMOT local model network on the same regressors.
use crate::curves::{binned_mean, thin};
use crate::evaluate::{Lineage, Residuals};
use crate::extension::{Context, Extension, Proposal};
use crate::{Cause, DiagnoseError};
use gb_core::{FittedModel, ModelView, Series, ViewData};

/// Replace the linear model by a local model network (LOLIMOT, normalised
/// Gaussian validity functions), trained output-error.
pub struct Lolimot;

impl Extension for Lolimot {
    fn fit_cost(&self) -> u8 {
        2
    }
    fn name(&self) -> &'static str {
        "lolimot"
    }
    fn cause(&self) -> Cause {
        Cause::Nonlinearity
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        match ctx.current.lineage.io() {
            Some(p) if !p.network => vec![Proposal {
                cause: Cause::Nonlinearity,
                lineage: Lineage::Io(gb_lmn::IoNetworkParams {
                    network: true,
                    ..p.clone()
                }),
                text: "local model network (LOLIMOT, normalised Gaussian validity functions) on the same regressors, trained output-error".into(),
            }],
            _ => vec![],
        }
    }
    fn fit(&self, p: &Proposal, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
        super::fit_io(p.lineage.io().expect("an input-output proposal"), ctx)
    }
    fn evidence(&self, _p: &Proposal, ctx: &Context) -> String {
        ctx.evidence.nonlinearity_text()
    }
    fn evidence_view(&self, b: &Residuals, a: &Residuals, output: &str) -> Option<ModelView> {
        Some(ModelView {
            key: "nonlinearity".into(),
            title: "Residual vs simulated output: a systematic curve is a static nonlinearity"
                .into(),
            caption: String::new(),
            data: ViewData::Curves {
                x_label: format!("simulated {output}"),
                y_label: "residual".into(),
                series: vec![
                    Series {
                        name: "before".into(),
                        points: thin(&b.yhat, &b.e, 1500),
                        markers: true,
                    },
                    Series {
                        name: "after".into(),
                        points: thin(&a.yhat, &a.e, 1500),
                        markers: true,
                    },
                    Series {
                        name: "before, binned mean".into(),
                        points: binned_mean(&b.yhat, &b.e, 30),
                        markers: false,
                    },
                ],
                log_y: false,
            },
        })
    }
}
