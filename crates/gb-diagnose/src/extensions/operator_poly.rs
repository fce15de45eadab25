//! `hysteresis`: a polynomial in the inputs and the stop operators of one
//! input (gb-model input operators in front of a gb-lmn polynomial).
use super::fit_spec;
use crate::evaluate::{Evaluated, Lineage};
use crate::extension::{Context, Extension, Proposal};
use crate::{Cause, DiagnoseError};
use gb_core::{FittedModel, ModelSpec};
use gb_model::operators::OperatorInputsModel;

/// Half-widths of the stop operators, in standard deviations of the input
/// (a logarithmic basis of a Prandtl–Ishlinskii operator: about 3 per
/// decade, from a loop a thirtieth of the input's spread to its whole
/// spread).
const STOP_WIDTHS: &str = "0.03/0.1/0.3/1";
/// Time constants (samples) of the low-pass channels of the other inputs
/// (a logarithmic basis).
const LOWPASS_SAMPLES: &str = "4/16/64";
/// Most terms of a candidate polynomial.
const MAX_TERMS: usize = 30;

/// A static hysteresis of one input `u_j`: `y(k) = P(u(k), s(k), f(k))`,
/// a polynomial of degree ≤ 3 (terms by FROLS) with no output lag and no
/// dead time in the inputs, the stop operators `s_h[u_j]` (half-widths
/// 0.03, 0.1, 0.3 and 1 standard deviations; Hauth 2008, §3.2: a
/// Prandtl–Ishlinskii operator is a weighted sum of stops, the polynomial
/// also forms their products with other inputs) and `f` the low-pass
/// channels of the other inputs (time constants 4, 16 and 64 samples) — a
/// hysteretic force of a displacement whose level another input sets
/// through a lag (a magnetorheological damper: displacement, velocity,
/// field voltage). Tried first and not kept (session 65): a second
/// candidate per input with the stops added to the linear model's
/// regressors (output lags, dead times), refined for the simulation error
/// — it tied with the input plays and the backlash where those fit
/// (backlash 6 at 8000 + 4000: +0.786 against +0.785 and +0.781), left
/// nothing to extend after it (1.02 → 1.27× the noise floor) and won on
/// none of the damper records.
pub struct OperatorPoly;

impl OperatorPoly {
    /// The spec of input `j` (0-based) of `n_inputs`.
    fn spec(n_inputs: usize, j: usize) -> String {
        let others: Vec<String> = (0..n_inputs)
            .filter(|&i| i != j)
            .map(|i| (i + 1).to_string())
            .collect();
        let lowpass = if others.is_empty() {
            String::new()
        } else {
            format!(
                ",lowpass={},lowpass_samples={LOWPASS_SAMPLES}",
                others.join("/")
            )
        };
        format!(
            "poly:order=0,delay=0,input_lags=1,degree=3,max_terms={MAX_TERMS},stops={},stop_widths={STOP_WIDTHS}{lowpass}",
            j + 1
        )
    }

    /// The input (0-based) whose stops a proposal adds.
    fn stop_input(p: &Proposal) -> Option<usize> {
        let Lineage::Other { spec, .. } = &p.lineage else {
            return None;
        };
        let spec: ModelSpec = spec.parse().ok()?;
        spec.option("stops")?.parse::<usize>().ok()?.checked_sub(1)
    }
}

impl Extension for OperatorPoly {
    fn name(&self) -> &'static str {
        "operator-poly"
    }
    fn cause(&self) -> Cause {
        Cause::Hysteresis
    }
    fn fit_cost(&self) -> u8 {
        1
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        if ctx
            .current
            .lineage
            .io()
            .is_none_or(|p| p.network || p.hysteresis)
        {
            return vec![];
        }
        let ni = ctx.fit.n_inputs();
        let others = if ni > 1 {
            ", and low-pass channels of the other inputs (time constants 4, 16, 64 samples)"
        } else {
            ""
        };
        ctx.fit
            .input_names
            .iter()
            .enumerate()
            .map(|(j, name)| Proposal {
                cause: Cause::Hysteresis,
                lineage: Lineage::Other {
                    spec: Self::spec(ni, j),
                    order: 0,
                },
                text: format!("a static hysteresis: a polynomial (degree <= 3, terms by FROLS) of the inputs at the same sample, the stop operators of '{name}' (half-widths 0.03, 0.1, 0.3, 1 standard deviations){others}"),
            })
            .collect()
    }
    fn fit(&self, p: &Proposal, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
        fit_spec(&p.lineage, ctx, ctx.policy().nonlinear_fit_samples)
    }
    /// A polynomial that reads no stop operator (nor low-pass channel) is
    /// the plain polynomial NOE of `nonlinearity`, not a hysteresis.
    fn admits(&self, _ctx: &Context, candidate: &Evaluated) -> bool {
        candidate
            .model
            .dynamics
            .as_any()
            .downcast_ref::<OperatorInputsModel>()
            .is_some_and(OperatorInputsModel::reads_a_channel)
    }
    fn evidence(&self, _p: &Proposal, ctx: &Context) -> String {
        ctx.evidence.hysteresis_text()
    }
    fn row_text(&self, p: &Proposal, fitted: &FittedModel) -> String {
        format!("{} -> {}", p.text, fitted.dynamics.describe())
    }
    fn input(&self, p: &Proposal, ctx: &Context) -> Option<String> {
        Self::stop_input(p).and_then(|j| ctx.fit.input_names.get(j).cloned())
    }
}

#[cfg(test)]
mod tests {
    use super::OperatorPoly;

    /// No output lag, no dead time; the stops of the input, the low-pass
    /// channels of the others (none for one input).
    #[test]
    fn the_spec_is_static_with_the_stops_of_one_input() {
        let s = OperatorPoly::spec(3, 1);
        assert!(s.starts_with("poly:order=0,delay=0,input_lags=1"));
        assert!(s.contains("stops=2,") && s.contains("lowpass=1/3,"));
        assert!(!OperatorPoly::spec(1, 0).contains("lowpass"));
    }
}
