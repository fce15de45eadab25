//! `nonlinearity`: a polynomial NOE model (gb-lmn `poly`) on the current
//! input–output model's regressors.
use super::{fit_spec, slash_list};
use crate::evaluate::{Evaluated, Lineage};
use crate::extension::{Context, Extension, Proposal, Role};
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
    poly_spec_on(s.na, &s.nk, &s.nb)
}

/// The polynomial's model spec on `na` output lags and, per input, the
/// dead time `nk` and `nb` lags.
fn poly_spec_on(na: usize, nk: &[usize], nb: &[usize]) -> String {
    format!(
        "poly:order={na},delay={},input_lags={},degree=3,max_terms={MAX_TERMS}",
        slash_list(nk),
        slash_list(nb)
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

/// A simpler model of a nonlinearity already named: when the current
/// model is a local model network (LOLIMOT or tree weights, chosen for
/// `nonlinearity`), a polynomial NOE of degree ≤ 3 on one more lag of the
/// output and of each input than the network's regressors
/// (`n_a + 1`, `n_b + 1`, the same dead times; terms by FROLS, up to
/// [`MAX_TERMS`]). It replaces the network when the data cannot tell them
/// apart ([`Role::Simplification`]: the decision data's gain within
/// `min_gain` of 0 and its 95 % interval reaching 0) and it has at most
/// half the network's parameters. A network's outermost local models go
/// on linearly beyond the training amplitudes, where a polynomial's cubic
/// terms hold (the Silverbox arrow); fewer parameters are the better bet
/// when held-out data cannot choose.
pub struct PolySimpler;

/// The regressors `(n_a, dead times, input lags)` of the current network
/// `lineage`: LOLIMOT (an input–output lineage) or a network of an `lmn:`
/// spec (the tree network's); `None` for any other model.
fn network_regressors(
    lineage: &Lineage,
    n_inputs: usize,
) -> Option<(usize, Vec<usize>, Vec<usize>)> {
    match lineage {
        Lineage::Io(p) if p.network && !p.hysteresis => {
            let s = p.network_spec(n_inputs);
            Some((s.na, s.nk, s.nb))
        }
        Lineage::Other { spec, .. } if spec.starts_with("lmn:") => {
            let spec: gb_core::ModelSpec = spec.parse().ok()?;
            let na = spec.option("output_lags")?.parse().ok()?;
            let mut opts = spec.options();
            // one value per input (the tree network's spec names each)
            let mut list = |key: &str| -> Option<Vec<usize>> {
                (spec.option(key)?.split('/').count() == n_inputs).then_some(())?;
                opts.usize_list(key, n_inputs, 0, 0, usize::MAX).ok()
            };
            Some((na, list("dead_time")?, list("input_lags")?))
        }
        _ => None,
    }
}

impl Extension for PolySimpler {
    fn fit_cost(&self) -> u8 {
        0
    }
    fn name(&self) -> &'static str {
        "poly-simpler"
    }
    fn cause(&self) -> Cause {
        Cause::Nonlinearity
    }
    fn role(&self) -> Role {
        Role::Simplification
    }
    fn once(&self) -> bool {
        true
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        if !ctx.named(Cause::Nonlinearity) {
            return vec![];
        }
        let Some((na, nk, nb)) = network_regressors(&ctx.current.lineage, ctx.fit.n_inputs())
        else {
            return vec![];
        };
        let nb: Vec<usize> = nb.iter().map(|b| b + 1).collect();
        vec![Proposal {
            cause: Cause::Nonlinearity,
            lineage: Lineage::Other {
                spec: poly_spec_on(na + 1, &nk, &nb),
                order: ctx.current.lineage.order(),
            },
            text: "a simpler model of the named nonlinearity: polynomial NOE on one more lag of the output and of each input than the network (degree <= 3, terms by FROLS, their number on a hold-out of the fit block, refined for the simulation error), kept when the data cannot tell it from the network and it has at most half its parameters".into(),
        }]
    }
    fn fit(&self, p: &Proposal, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
        fit_spec(&p.lineage, ctx, ctx.policy().nonlinear_fit_samples)
    }
    /// At most half the current model's parameters.
    fn admits(&self, ctx: &Context, candidate: &Evaluated) -> bool {
        2 * candidate.model.dynamics.n_parameters() <= ctx.current.model.dynamics.n_parameters()
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
    use super::{network_regressors, poly_spec};
    use crate::evaluate::Lineage;
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

    /// The regressors a simpler polynomial starts from: a tree network's
    /// from its spec, LOLIMOT's from its parameters (n + 1 input lags at
    /// dead time 0); none for a model that is not a network.
    #[test]
    fn a_networks_regressors_are_read_from_its_lineage() {
        let tree = Lineage::Other {
            spec:
                "lmn:order=2,output_lags=2,dead_time=0/3,input_lags=3/2,max_leaves=15,weights=tree"
                    .into(),
            order: 2,
        };
        assert_eq!(
            network_regressors(&tree, 2),
            Some((2, vec![0, 3], vec![3, 2]))
        );
        assert_eq!(network_regressors(&tree, 1), None);
        let lolimot = IoNetworkParams {
            delay: vec![0],
            network: true,
            ..IoNetworkParams::linear(3)
        };
        assert_eq!(
            network_regressors(&Lineage::Io(lolimot.clone()), 1),
            Some((3, vec![0], vec![4]))
        );
        let linear = IoNetworkParams {
            network: false,
            ..lolimot
        };
        assert_eq!(network_regressors(&Lineage::Io(linear), 1), None);
        let poly = Lineage::Other {
            spec: "poly:order=2,delay=1,input_lags=2,degree=3".into(),
            order: 2,
        };
        assert_eq!(network_regressors(&poly, 1), None);
    }
}
