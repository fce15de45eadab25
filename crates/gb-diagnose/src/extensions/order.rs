//! `dynamics`: a higher linear order.
use crate::curves::{periodogram, smooth};
use crate::evaluate::{Lineage, Residuals};
use crate::extension::{Context, Extension, Proposal};
use crate::{Cause, DiagnoseError};
use gb_core::{FittedModel, ModelView, Series, ViewData};

/// Raise the dynamic order by one and by two.
pub struct LinearOrder;

impl Extension for LinearOrder {
    fn name(&self) -> &'static str {
        "linear-order"
    }
    fn cause(&self) -> Cause {
        Cause::Dynamics
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        let Some(p) = ctx.current.lineage.io() else {
            return vec![];
        };
        [1, 2]
            .into_iter()
            .filter(|add| p.order + add <= ctx.policy().max_order)
            .map(|add| Proposal {
                cause: Cause::Dynamics,
                lineage: Lineage::Io(gb_lmn::IoNetworkParams {
                    order: p.order + add,
                    ..p.clone()
                }),
                text: format!("order {} -> {}", p.order, p.order + add),
            })
            .collect()
    }
    fn fit(&self, p: &Proposal, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
        super::fit_io(p.lineage.io().expect("an input-output proposal"), ctx)
    }
    fn evidence(&self, _p: &Proposal, ctx: &Context) -> String {
        ctx.evidence.dynamics_text()
    }
    fn evidence_view(&self, b: &Residuals, a: &Residuals, _output: &str) -> Option<ModelView> {
        let line = |name: &str, e: &[f64]| Series {
            name: name.into(),
            points: smooth(&periodogram(e, 400), 3),
            markers: false,
        };
        Some(ModelView {
            key: "dynamics".into(),
            title: "Residual spectrum (smoothed periodogram): peaks are unmodelled modes".into(),
            caption: String::new(),
            data: ViewData::Curves {
                x_label: "frequency [cycles/sample]".into(),
                y_label: "power".into(),
                series: vec![line("before", &b.e), line("after", &a.e)],
                log_y: true,
            },
        })
    }
}
