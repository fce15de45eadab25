//! `nonlinearity`: a Hammerstein model (static maps of the inputs before
//! the linear dynamics); with several inputs, a map of one input at a time
//! says which input the nonlinearity lives on.
use super::{delay_choices, fit_block_choosing, plain_linear_structure};
use crate::evaluate::Lineage;
use crate::extension::{Context, Extension, Proposal};
use crate::{Cause, DiagnoseError};
use gb_core::FittedModel;

/// Static maps of the inputs (cubic polynomial, cubic spline or piecewise linear, knots at
/// quantiles, the structure chosen on a hold-out of the fit block) before
/// the current linear dynamics, trained output-error, with the current
/// input delay or, when it fits the fit block better, one sample either
/// side or the plain one-sample delay (under cross-validation one candidate
/// per delay: [`delay_choices`]). With several inputs: one candidate per
/// input (only that path nonlinear, the current delay) and the every-input
/// candidates.
pub struct Hammerstein;

/// The maps of a proposal (`maps=0/1/…`) as flags.
fn maps(p: &Proposal) -> Vec<bool> {
    let Lineage::Other { spec, .. } = &p.lineage else {
        return vec![];
    };
    spec.split("maps=")
        .nth(1)
        .map(|m| {
            m.split([',', ' '])
                .next()
                .unwrap_or("")
                .split('/')
                .map(|f| f == "1")
                .collect()
        })
        .unwrap_or_default()
}

impl Extension for Hammerstein {
    fn fit_cost(&self) -> u8 {
        3
    }
    fn name(&self) -> &'static str {
        "hammerstein"
    }
    fn cause(&self) -> Cause {
        Cause::Nonlinearity
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        let Some((order, delay)) = plain_linear_structure(ctx) else {
            return vec![];
        };
        let ni = ctx.fit.n_inputs();
        let names = &ctx.fit.input_names;
        let proposal = |flags: &[bool], delay: &str, text: String| {
            let m: Vec<&str> = flags.iter().map(|&f| if f { "1" } else { "0" }).collect();
            Proposal {
                cause: Cause::Nonlinearity,
                lineage: Lineage::Other {
                    spec: format!(
                        "hammerstein:order={order},delay={delay},maps={}",
                        m.join("/")
                    ),
                    order,
                },
                text,
            }
        };
        let tail = |d: &str| {
            format!(
                "(cubic polynomial, cubic spline or piecewise linear, knots at quantiles, chosen on a hold-out of the fit block), then the linear dynamics of order {order} ({d}), trained output-error"
            )
        };
        let choices = delay_choices(ctx, &delay);
        if ni == 1 {
            return choices
                .iter()
                .map(|(d, words)| {
                    proposal(
                        &[true],
                        d,
                        format!(
                            "Hammerstein: a static map of the input '{}' {}",
                            names[0],
                            tail(words)
                        ),
                    )
                })
                .collect();
        }
        let mut out: Vec<Proposal> = (0..ni)
            .map(|j| {
                let flags: Vec<bool> = (0..ni).map(|i| i == j).collect();
                proposal(
                    &flags,
                    &delay,
                    format!(
                        "Hammerstein on input '{}' only: a static map of '{}' {}; the other inputs stay linear",
                        names[j],
                        names[j],
                        tail(&format!("input delay {delay}"))
                    ),
                )
            })
            .collect();
        out.extend(choices.iter().map(|(d, words)| {
            proposal(
                &vec![true; ni],
                d,
                format!("Hammerstein: a static map of every input {}", tail(words)),
            )
        }));
        out
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
    fn input(&self, p: &Proposal, ctx: &Context) -> Option<String> {
        let m = maps(p);
        (m.len() > 1 && m.iter().filter(|&&f| f).count() == 1)
            .then(|| m.iter().position(|&f| f))
            .flatten()
            .and_then(|j| ctx.fit.input_names.get(j).cloned())
    }
}
