//! `nonlinearity` inside the loop: a static map of the simulated output
//! fed back into the linear dynamics (`greybox fit --model
//! linear+feedback`).
use super::{delay_variants, io_structure, plain_linear, Lolimot};
use crate::evaluate::{Evaluated, Lineage, Residuals};
use crate::extension::{Context, Extension, Proposal};
use crate::{Cause, DiagnoseError};
use gb_core::{FittedModel, Init, ModelView};

/// The number of intervals of the fed-back map (knots at quantiles of the
/// output).
const INTERVALS: usize = 8;

/// The current plain linear model with a static piecewise-linear map
/// `g(ŷ)` of its simulated output fed back at lags 1..n+1 (gb-lmn's
/// `output_map`, linear in its ramp columns):
///
/// ```text
/// y(k) = Σᵢ aᵢ y(k−i) + Σⱼ bⱼ u(k−d−j) + Σᵢ₌₁ⁿ⁺¹ Σₘ cᵢₘ (ŷ(k−i) − κₘ)₊
/// ```
///
/// A nonlinear spring when the output is a position, a friction law when
/// it is a velocity (an integrating system's increments: the EMPS
/// positioning rig's force → velocity), a nonlinear outflow of a level:
/// the static nonlinearity on the state inside the loop that neither a
/// map of the input (Hammerstein) nor of the output (Wiener) expresses.
/// Its dead time: the current one or, when it fits the fit block better,
/// one sample either side or the plain one-sample delay
/// ([`delay_variants`]); a fold of a cross-validation keeps the one the
/// whole fit block chose ([`Context::start_choice`]).
pub struct FeedbackMap;

impl FeedbackMap {
    /// The proposal's structure with dead time `delay` (`a/b`).
    fn with_delay(p: &gb_lmn::IoNetworkParams, delay: &str) -> Option<gb_lmn::IoNetworkParams> {
        let delay: Option<Vec<usize>> = delay.split('/').map(|v| v.parse().ok()).collect();
        Some(gb_lmn::IoNetworkParams {
            delay: delay?,
            ..p.clone()
        })
    }
}

/// The structure `p` fitted without a warm start (the full output-error
/// fit of gb-lmn, its staged lower orders included) on every fit record:
/// from the current linear model, the fed-back map's Levenberg–Marquardt
/// fit stays in the linear model's basin.
pub(crate) fn cold_fit(
    p: &gb_lmn::IoNetworkParams,
    ctx: &Context,
) -> Result<FittedModel, DiagnoseError> {
    let net = p
        .check()?
        .fit_records(ctx.fits, gb_lmn::WarmStart::default(), &gb_core::Silent)?;
    crate::extension::io_model(net, ctx.fit)
}

/// The free-run squared error of `m` over the record `rec` (its first
/// `lags` outputs as the history).
fn fit_error(m: &FittedModel, rec: &gb_core::Record, lags: usize) -> f64 {
    let w = lags.min(rec.len());
    match m.simulate(&rec.inputs, Init::History(&rec.output[..w])) {
        Ok(s) => s
            .iter()
            .zip(&rec.output)
            .skip(w)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>(),
        Err(_) => f64::INFINITY,
    }
}

impl Extension for FeedbackMap {
    fn fit_cost(&self) -> u8 {
        1
    }
    fn name(&self) -> &'static str {
        "feedback-map"
    }
    fn cause(&self) -> Cause {
        Cause::Nonlinearity
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        let Some(p) = ctx.current.lineage.io().filter(|p| plain_linear(p)) else {
            return vec![];
        };
        let (order, delay) = io_structure(p, ctx.fit.n_inputs());
        let others = delay_variants(&delay)[1..].join(" or ");
        vec![Proposal {
            cause: Cause::Nonlinearity,
            lineage: Lineage::Io(gb_lmn::IoNetworkParams {
                output_map: INTERVALS,
                ..p.clone()
            }),
            text: format!(
                "a static map of the simulated output fed back into the linear dynamics of order {order} (piecewise linear, {INTERVALS} intervals, knots at quantiles of the output, at lags 1..{}: a nonlinear spring of a position, friction of a velocity), input delay {delay}{}, trained output-error",
                order + 1,
                if others.is_empty() { String::new() } else { format!(", or {others} if that fits the fit block better") }
            ),
        }]
    }
    fn fit_choosing(
        &self,
        p: &Proposal,
        ctx: &Context,
    ) -> Result<(FittedModel, Option<usize>), DiagnoseError> {
        let io = p.lineage.io().expect("an input-output proposal");
        let (_, delay) = io_structure(io, ctx.fit.n_inputs());
        let variants = delay_variants(&delay);
        let lags = io.order + 1 + io.delay.iter().copied().max().unwrap_or(1);
        let mut best: Option<(f64, usize, FittedModel)> = None;
        let mut last_err = None;
        for (i, d) in variants.iter().enumerate() {
            if ctx.start_choice.is_some_and(|c| c != i) {
                continue;
            }
            let Some(params) = Self::with_delay(io, d) else {
                continue;
            };
            match cold_fit(&params, ctx) {
                Ok(m) => {
                    let e = fit_error(&m, ctx.fit, lags);
                    if best.as_ref().is_none_or(|(b, _, _)| e < *b) {
                        best = Some((e, i, m));
                    }
                }
                Err(e) => last_err = Some(e),
            }
        }
        match (best, last_err) {
            (Some((_, i, m)), _) => Ok((m, Some(i))),
            (None, Some(e)) => Err(e),
            (None, None) => Err(DiagnoseError::InvalidArgument(
                "feedback map: no dead time to fit".into(),
            )),
        }
    }
    /// The candidate's lineage names the dead time its fit chose (the next
    /// step's extensions start from it); the proposal keeps the list the
    /// choice indexes, for the refits.
    fn rescore(&self, ctx: &Context, c: &mut Evaluated) -> Result<(), DiagnoseError> {
        let Some(i) = c.start_choice else {
            return Ok(());
        };
        if let Lineage::Io(io) = &c.lineage {
            let (_, delay) = io_structure(io, ctx.fit.n_inputs());
            if let Some(p) = delay_variants(&delay)
                .get(i)
                .and_then(|d| Self::with_delay(io, d))
            {
                c.lineage = Lineage::Io(p);
            }
        }
        Ok(())
    }
    fn evidence(&self, _p: &Proposal, ctx: &Context) -> String {
        ctx.evidence.nonlinearity_text()
    }
    fn evidence_view(&self, b: &Residuals, a: &Residuals, output: &str) -> Option<ModelView> {
        Lolimot.evidence_view(b, a, output)
    }
    fn row_text(&self, p: &Proposal, fitted: &FittedModel) -> String {
        format!("{} -> {}", p.text, fitted.dynamics.describe())
    }
}
