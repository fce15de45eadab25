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
/// higher one). For a plain linear output-error model also the
/// equation-error (least-squares ARX) estimate at the order of smallest
/// AIC above n ([`arx_order`]), simulated in free run like every model:
/// on short records of lightly damped structures it generalises better
/// than the output-error fit (the DaISy robot arm, 600 training samples:
/// test NRMSE 0.0359 with output-error orders 2 → 4 → 6, 0.0280 with the
/// ARX estimate of order 8).
pub struct LinearOrder;

/// For the n → n + 2 proposal of a plain linear output-error model whose
/// residual the input explains in part (the verdict's `r_ue` rejects on
/// some input at `verdict_level`), its fit `m` or, when it simulates the
/// fit records with a smaller error, the fit refined from the reduction of
/// an order n + 4 fit (the baseline's rival start,
/// [`crate::baseline::reduced_or`]). The warm start from the current model
/// keeps its poles and adds small new ones, and a weak mode stays in a
/// basin the output-error cost cannot leave: the sweep's `two-mass` seed 2
/// (a hidden second mass at 20.8 dB, 8000 + 4000 samples) fitted order 4 to
/// 0.0985 on the validation record (noise floor 0.0913) where a cold order
/// 5 reaches 0.0917, and a Wiener–Hammerstein network (+0.07 on the select
/// block, its filters of orders 5 and 4) was named `nonlinearity` at
/// 1.71× the floor.
fn reduced_order_fit(io: &gb_lmn::IoNetworkParams, ctx: &Context, m: FittedModel) -> FittedModel {
    let current = ctx.current.lineage.io().map(|c| c.order);
    if !super::plain_linear(io) || io.fit.equation_error || current.map(|n| n + 2) != Some(io.order)
    {
        return m;
    }
    // only where the residual asks for linear dynamics: the current
    // model's input–residual cross-correlation (the verdict's r_ue)
    // rejects on some input
    let u = ctx.plan.decision_inputs(ctx.data);
    let level = ctx.policy().verdict_level;
    if !crate::verdict::input_cross_p(&ctx.current.select.e, &u)
        .iter()
        .any(|&p| p < level)
    {
        return m;
    }
    let Some(net) = crate::plan::core(&m)
        .as_any()
        .downcast_ref::<gb_lmn::LocalModelNetwork>()
        .cloned()
    else {
        return m;
    };
    let mut p = io.clone();
    p.fit = ctx.options.fit.clone();
    p.lolimot = ctx.options.lolimot.clone();
    let reduced = crate::baseline::reduced_or(&p, ctx.fits, net);
    crate::extension::io_model(reduced, ctx.fit).unwrap_or(m)
}

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
            return block_orders(ctx);
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
        if let Some(m) = arx_order(p, ctx) {
            props.push(Proposal {
                cause: Cause::Dynamics,
                text: format!(
                    "order {} -> {m}, estimated by least squares on the measured output lags (ARX, equation error; the order by AIC), simulated in free run",
                    p.order
                ),
                lineage: Lineage::Io(gb_lmn::IoNetworkParams {
                    order: m,
                    fit: gb_lmn::FitOptions {
                        equation_error: true,
                        ..p.fit.clone()
                    },
                    ..p.clone()
                }),
            });
        }
        props
    }
    fn fit_choosing(
        &self,
        p: &Proposal,
        ctx: &Context,
    ) -> Result<(FittedModel, Option<usize>), DiagnoseError> {
        match p.lineage.io() {
            Some(io) => {
                let m = super::fit_io(io, ctx)?;
                Ok((reduced_order_fit(io, ctx, m), None))
            }
            None => super::fit_block_choosing(&p.lineage, ctx),
        }
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

/// For a block-oriented current model (Hammerstein, Wiener: a recipe
/// spec `hammerstein:order=n,…` or `wiener:order=n,…`): the same
/// structure with the linear block of order n + 1 and n + 2 (up to the
/// policy's `max_order`), its map structure and dead time those of the
/// current model (re-chosen, a finer map paid as if it were the order:
/// saturation 1 of the generator at 608 samples named a spurious
/// `dynamics`, +5.0 % on the folds, +1.2 % on the validation record).
/// Without it a block-oriented model ended the search: no other extension
/// extends it, and a nonlinearity found at the baseline's order kept that
/// order whatever the residual spectrum said.
fn block_orders(ctx: &Context) -> Vec<Proposal> {
    let Lineage::Other { spec, order } = &ctx.current.lineage else {
        return vec![];
    };
    if !(spec.starts_with("hammerstein:") || spec.starts_with("wiener:")) {
        return vec![];
    }
    let class = spec.split(':').next().unwrap_or("");
    // the current maps and dead time, fixed: the gain is the order's
    let block = crate::plan::core(&ctx.current.model)
        .as_any()
        .downcast_ref::<gb_lmn::BlockModel>();
    let Some((basis, knots)) = block.and_then(gb_lmn::BlockModel::map_structure) else {
        return vec![];
    };
    let delay = super::slash_list(&block.map(|b| b.nk.clone()).unwrap_or_default());
    let fixed = super::with_option(
        &super::with_option(spec, "delay", &delay),
        "map",
        &basis.structure_name(knots),
    );
    [order + 1, order + 2]
        .into_iter()
        .filter(|&n| n <= ctx.policy().max_order)
        .map(|n| Proposal {
            cause: Cause::Dynamics,
            lineage: Lineage::Other {
                spec: super::with_option(&fixed, "order", &n.to_string()),
                order: n,
            },
            text: format!("order {order} -> {n} of the {class} model's linear block"),
        })
        .collect()
}

/// For a plain linear output-error model of order n: the order m > n of
/// the least-squares ARX model with the smallest AIC on the fit records,
///
/// ```text
/// AIC(m) = N ln σ̂²(m) + 2 p(m),   σ̂²: mean squared one-step error over k ≥ K,
/// ```
///
/// m in n+1 ..= min(max(2n, 8), max_order), every order scored from the
/// same sample K (the largest lag); `None` when no higher order has a
/// smaller AIC than order n's ARX model. A lightly damped structure whose
/// disturbance passes through the dynamics is often simulated better by
/// this estimate than by the output-error fit of a short record.
fn arx_order(p: &gb_lmn::IoNetworkParams, ctx: &Context) -> Option<usize> {
    if !super::plain_linear(p) || p.fit.equation_error {
        return None;
    }
    let top = (2 * p.order).max(8).min(ctx.policy().max_order);
    if top <= p.order {
        return None;
    }
    let longest = p.delay.iter().copied().max().unwrap_or(1);
    let k0 = top + longest + 1;
    let aic = |m: usize| -> Option<f64> {
        let q = gb_lmn::IoNetworkParams {
            order: m,
            fit: gb_lmn::FitOptions {
                equation_error: true,
                ..ctx.options.fit.clone()
            },
            ..p.clone()
        };
        let net = q
            .check()
            .ok()?
            .fit_records(ctx.fits, gb_lmn::WarmStart::default(), &gb_core::Silent)
            .ok()?;
        // every order scored from the same sample k0 of each record
        let (mut sse, mut n) = (0.0, 0usize);
        for r in ctx.fits {
            let e = net
                .equation_errors_records(&[gb_lmn::Experiment::of(r)])
                .ok()?;
            let skip = e.len().saturating_sub(r.len().saturating_sub(k0));
            sse += e[skip..].iter().map(|v| v * v).sum::<f64>();
            n += e.len() - skip;
        }
        (n > 0 && sse > 0.0)
            .then(|| n as f64 * (sse / n as f64).ln() + 2.0 * net.n_parameters() as f64)
    };
    let base = aic(p.order)?;
    (p.order + 1..=top)
        .filter_map(|m| aic(m).map(|a| (m, a)))
        .filter(|&(_, a)| a < base)
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(m, _)| m)
}
