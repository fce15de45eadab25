//! `dynamics`: a higher linear order.
use crate::curves::{periodogram, smooth};
use crate::evaluate::{Lineage, Residuals};
use crate::extension::{Context, Extension, Proposal};
use crate::{Cause, DiagnoseError};
use gb_core::{FittedModel, ModelView, Series, ViewData};

/// Raise the dynamic order by one and by two, and for a linear model also
/// double it (n → 2n when 2n > n + 2): a structure with several resonant
/// modes reaches a high order in a few steps, and only when the training
/// data pay for it (up to the policy's `max_order`). For a plain linear
/// model with a dead time of more than one sample, the orders n + 1 and
/// n + 2 also with the delay of the ARX scan at that order when it is
/// shorter (a lag the low order absorbed as a dead time is a pole of the
/// higher one).
pub struct LinearOrder;

impl Extension for LinearOrder {
    fn fit_cost(&self) -> u8 {
        0
    }
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
        let mut orders = vec![p.order + 1, p.order + 2];
        if !p.network && !p.hysteresis && 2 * p.order > p.order + 2 {
            orders.push(2 * p.order);
        }
        let pol = ctx.policy();
        let mut props: Vec<Proposal> = orders
            .iter()
            .filter(|&&n| n <= pol.max_order)
            .map(|&n| Proposal {
                cause: Cause::Dynamics,
                lineage: Lineage::Io(gb_lmn::IoNetworkParams {
                    order: n,
                    ..p.clone()
                }),
                text: format!("order {} -> {n}", p.order),
            })
            .collect();
        // a dead time of the plain linear model may stand in for a lag that
        // a higher order models as a pole: the delay scanned again
        let longest = p.delay.iter().copied().max().unwrap_or(0);
        if !p.network && !p.hysteresis && longest > 1 {
            for &n in orders.iter().filter(|&&n| n <= pol.max_order).take(2) {
                let found = crate::structure::scan(
                    std::slice::from_ref(ctx.fit),
                    n,
                    longest,
                    pol.structure_scan_samples,
                )
                .best;
                let shorter = found.iter().zip(&p.delay).all(|(a, b)| a <= b);
                if found != p.delay && shorter {
                    props.push(Proposal {
                        cause: Cause::Dynamics,
                        text: format!(
                            "order {} -> {n}, input delay {:?} -> {found:?} (scanned again at the new order)",
                            p.order, p.delay
                        ),
                        lineage: Lineage::Io(gb_lmn::IoNetworkParams {
                            order: n,
                            delay: found,
                            ..p.clone()
                        }),
                    });
                }
            }
        }
        props
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
