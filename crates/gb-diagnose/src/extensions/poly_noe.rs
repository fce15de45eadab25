//! `nonlinearity`: a polynomial NOE model (gb-lmn `poly`) on the current
//! input–output model's regressors.
use super::{fit_spec, slash_list};
use crate::evaluate::Lineage;
use crate::extension::{Context, Extension, Proposal};
use crate::{Cause, DiagnoseError};
use gb_core::FittedModel;
use gb_lmn::IoNetworkParams;

/// Replace the linear model by a polynomial of degree ≤ 3 in the same
/// lagged outputs and inputs (terms by FROLS, their number on a hold-out of
/// the fit block, refined for the simulation error).
pub struct PolyNoe;

/// Most terms of a candidate polynomial (their number is chosen on a
/// hold-out of the fit block).
const MAX_TERMS: usize = 30;

/// The polynomial's model spec on the regressors of the plain
/// input–output model `p` with `n_inputs` inputs: `n_a` output lags, and
/// per input its dead time and its number of lags (`n + 1` at dead time 0
/// or behind a direct feedthrough, as the linear model has them).
pub(crate) fn poly_spec(p: &IoNetworkParams, n_inputs: usize) -> String {
    let s = p.network_spec(n_inputs);
    format!(
        "poly:order={},delay={},input_lags={},degree=3,max_terms={MAX_TERMS}",
        s.na,
        slash_list(&s.nk),
        slash_list(&s.nb)
    )
}

impl Extension for PolyNoe {
    fn fit_cost(&self) -> u8 {
        0
    }
    fn name(&self) -> &'static str {
        "poly-noe"
    }
    fn cause(&self) -> Cause {
        Cause::Nonlinearity
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        let Some(p) = ctx
            .current
            .lineage
            .io()
            .filter(|p| !p.network && !p.hysteresis)
        else {
            return vec![];
        };
        vec![Proposal {
            cause: Cause::Nonlinearity,
            lineage: Lineage::Other {
                spec: poly_spec(p, ctx.fit.n_inputs()),
                order: p.order,
            },
            text: "polynomial NOE on the same regressors (degree <= 3, terms by FROLS on the error reduction ratio, their number on a hold-out of the fit block, refined for the simulation error)".into(),
        }]
    }
    fn fit(&self, p: &Proposal, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
        fit_spec(&p.lineage, ctx, ctx.policy().nonlinear_fit_samples)
    }
    fn evidence(&self, _p: &Proposal, ctx: &Context) -> String {
        ctx.evidence.nonlinearity_text()
    }
    fn row_text(&self, p: &Proposal, fitted: &FittedModel) -> String {
        format!("{} -> {}", p.text, fitted.dynamics.describe())
    }
}

#[cfg(test)]
mod tests {
    use super::poly_spec;
    use gb_core::{metrics, Init, ModelSpec, Record, Records};
    use gb_lmn::IoNetworkParams;
    use rand::Rng;

    /// A record whose output needs the last numerator lag of a linear
    /// model with direct feedthrough, u(k−2) at order 2, and a cubic term.
    fn record() -> Record {
        let n = 800;
        let mut rng = gb_core::rng::seeded(777);
        let u: Vec<f64> = (0..n).map(|_| rng.random::<f64>() - 0.5).collect();
        let mut y = vec![0.0; n];
        for k in 2..n {
            y[k] = 0.6 * y[k - 1] - 0.2 * y[k - 2] + u[k] + 0.6 * u[k - 2] + 0.1 * y[k - 1].powi(3);
        }
        Record::new(vec!["u".into()], "y".into(), vec![u], y).unwrap()
    }

    /// At dead time 0 the polynomial gets the n + 1 input lags the linear
    /// model has: it reaches the noise-free record exactly, which it could
    /// not with n lags (u(k−2) missing: NRMSE above 0.1).
    #[test]
    fn the_polynomial_uses_the_linear_models_input_lags() {
        let d = record();
        let p = IoNetworkParams {
            delay: vec![0],
            ..IoNetworkParams::linear(2)
        };
        let nrmse = |spec: &str| {
            let spec: ModelSpec = spec.parse().unwrap();
            let f = gb_model::recipes::fit(&spec, &Records::single(d.clone()), &gb_core::Silent)
                .unwrap();
            let sim = f
                .model
                .dynamics
                .simulate(&d.inputs, Init::History(&d.output[..2]))
                .unwrap();
            metrics::nrmse(&d.output, &sim).unwrap()
        };
        assert!(nrmse(&poly_spec(&p, 1)) < 1e-3);
        assert!(nrmse("poly:order=2,delay=0,input_lags=2,degree=3") > 0.1);
    }
}
