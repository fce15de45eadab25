//! `nonlinearity`: a local model network with decision-tree weights
//! (gb-lmn's tree network) on the current input–output model's regressors.
use super::{fit_spec, slash_list};
use crate::evaluate::Lineage;
use crate::extension::{Context, Extension, Proposal};
use crate::{Cause, DiagnoseError};
use gb_core::FittedModel;
use gb_lmn::IoNetworkParams;

/// Replace the linear model by a local model network whose validity
/// functions are products of sigmoids along a binary tree (the thesis'
/// decision-tree weights, [docs/lmn.md]). Unlike normalised Gaussians
/// they do not reactivate a local model far from its centre: beyond the
/// training range the outermost local models extrapolate linearly. Local
/// affine models in the same lagged outputs and inputs, the partition over
/// all of them, the number of leaves (≤ 15) by AICc, trained for the
/// simulation error.
///
/// Silverbox (65 062 training rows): the diagnosis chose the normalised
/// Gaussian network (0.301 mV on the multisine test, 56 s); with this
/// candidate it chooses the tree network (0.279 mV, 21 s: the Preisach
/// columns of the Gaussian network are no longer fitted in a second step).
pub struct TreeLmn;

/// Largest number of local models of the candidate.
const MAX_LEAVES: usize = 15;

/// The tree network's model spec on the regressors of the plain
/// input–output model `p` with `n_inputs` inputs: `n_a` output lags, and
/// per input its dead time and its number of lags (`n + 1` at dead time 0
/// or behind a direct feedthrough).
pub(crate) fn tree_spec(p: &IoNetworkParams, n_inputs: usize) -> String {
    let s = p.network_spec(n_inputs);
    format!(
        "lmn:order={},output_lags={},dead_time={},input_lags={},max_leaves={MAX_LEAVES},weights=tree",
        p.order,
        s.na,
        slash_list(&s.nk),
        slash_list(&s.nb)
    )
}

impl Extension for TreeLmn {
    fn name(&self) -> &'static str {
        "tree-lmn"
    }
    fn cause(&self) -> Cause {
        Cause::Nonlinearity
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        match ctx.current.lineage.io() {
            Some(p) if !p.network && !p.hysteresis => vec![Proposal {
                cause: Cause::Nonlinearity,
                lineage: Lineage::Other {
                    spec: tree_spec(p, ctx.fit.n_inputs()),
                    order: p.order,
                },
                text: "local model network with decision-tree (sigmoid) weights on the same regressors (local affine models, leaves by AICc, trained for the simulation error)".into(),
            }],
            _ => vec![],
        }
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
    use super::tree_spec;
    use gb_core::{ModelSpec, Record, Records};
    use gb_lmn::IoNetworkParams;

    /// A two-input record with a mild nonlinearity.
    fn record() -> Record {
        let n = 600;
        let mut s = 12345u64;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        let u: Vec<Vec<f64>> = (0..2).map(|_| (0..n).map(|_| rnd()).collect()).collect();
        let mut y = vec![0.0; n];
        for k in 2..n {
            y[k] = 0.6 * y[k - 1] - 0.1 * y[k - 2]
                + u[0][k]
                + 0.5 * u[1][k - 2]
                + 0.2 * (y[k - 1]).powi(3);
        }
        Record::new(vec!["a".into(), "b".into()], "y".into(), u, y).unwrap()
    }

    /// The tree network is fitted on the regressors the input–output
    /// network of the same structure uses (two routes: the recipe's option
    /// parser, and `IoNetworkParams::network_spec`), at dead time 0 (n + 1
    /// input lags), a feedthrough behind a dead time, and the plain delay.
    #[test]
    fn the_tree_network_uses_the_io_models_regressors() {
        let d = record();
        for (order, delay, feedthrough, expect) in [
            (2, vec![0, 2], false, "y[1, 2] u1[0, 1, 2] u2[2, 3]"),
            (2, vec![1, 2], true, "y[1, 2] u1[1, 2, 3] u2[2, 3, 4]"),
            (3, vec![], false, "y[1, 2, 3] u1[1, 2, 3] u2[1, 2, 3]"),
        ] {
            let p = IoNetworkParams {
                delay,
                feedthrough,
                ..IoNetworkParams::linear(order)
            };
            let spec: ModelSpec = tree_spec(&p, 2).parse().unwrap();
            let f = gb_model::recipes::fit(&spec, &Records::single(d.clone()), &gb_core::Silent)
                .unwrap();
            let text = f.model.dynamics.describe();
            assert!(text.contains(expect), "{spec}: {text}");
        }
    }
}
