//! The best linear model as a starting point: a linear output-error model of
//! `gb-lmn` converted to state space (observer canonical form).
use crate::error::{ModelError, Result};
use crate::model::SparseStateSpace;
use gb_lmn::{fit_linear_oe, FitOptions, LocalModelNetwork, NetworkSpec};

/// Converts a linear (one-leaf, no hysteresis) network of `gb-lmn`,
/// `y(k) = κ + Σ_i a_i y(k−i) + Σ_{j,l} b_{jl} u_j(k−d_j−l)` in normalised
/// units, to the observer canonical form
/// `x_i(k+1) = a_i x_1(k) + x_{i+1}(k) + (β_i + a_i β_0) u(k)`,
/// `y(k) = s_y x_1(k) + D u(k) + y₀` (Ljung 1999, §4.3), all entries free.
pub fn linear_from_network(net: &LocalModelNetwork) -> Result<SparseStateSpace> {
    let spec = &net.spec;
    if net.leaves.len() != 1 || spec.n_hysteresis() > 0 {
        return Err(ModelError::InvalidArgument(
            "only a linear network (one leaf, no hysteresis) converts to state space".into(),
        ));
    }
    let theta = &net.leaves[0].theta;
    let m = spec.nb.len();
    let na = spec.na;
    let n = spec
        .nb
        .iter()
        .zip(&spec.nk)
        .map(|(b, d)| (b + d).saturating_sub(1))
        .max()
        .unwrap_or(0)
        .max(na)
        .max(1);
    let mut a = vec![0.0; n + 1];
    a[1..=na].copy_from_slice(&theta[1..=na]);
    // β[j][i], i = 0..=n, in units of the physical input
    let mut beta = vec![vec![0.0; n + 1]; m];
    let mut kappa = theta[0];
    let mut pos = 1 + na;
    for j in 0..m {
        let s = net.input_scaling[j];
        for l in 0..spec.nb[j] {
            let b = theta[pos];
            pos += 1;
            beta[j][spec.nk[j] + l] += b / s.scale;
            kappa -= b * s.offset / s.scale;
        }
    }
    let sum_a: f64 = a[1..].iter().sum();
    let y_ss = if (1.0 - sum_a).abs() > 1e-9 {
        kappa / (1.0 - sum_a)
    } else {
        0.0
    };
    let sy = net.output_scaling.scale;
    let mut am = vec![0.0; n * n];
    let mut bm = vec![0.0; n * m];
    for i in 0..n {
        am[i * n] = a[i + 1];
        if i + 1 < n {
            am[i * n + i + 1] = 1.0;
        }
        for j in 0..m {
            bm[i * m + j] = beta[j][i + 1] + a[i + 1] * beta[j][0];
        }
    }
    let mut c = vec![0.0; n];
    c[0] = sy;
    let d: Vec<f64> = (0..m).map(|j| sy * beta[j][0]).collect();
    let mut model = SparseStateSpace::linear(am, bm, c, d)?;
    model.y_offset = sy * y_ss + net.output_scaling.offset;
    model.structure.y_offset = true;
    Ok(model)
}

/// Fits the linear output-error model of order `order` (`gb-lmn`,
/// `n_b = order`, dead time 1) and returns it as state space.
///
/// ```
/// let u: Vec<f64> = (0..500).map(|k| ((k * 7919) % 13) as f64 - 6.0).collect();
/// let mut y = vec![0.0; 500];
/// y[1] = 0.3 * u[0];
/// for k in 2..500 { y[k] = 1.2 * y[k - 1] - 0.5 * y[k - 2] + 0.3 * u[k - 1]; }
/// let m = gb_model::linear_from_oe(&[u.clone()], &y, 2)?;
/// let sim = m.simulate(&[u])?;
/// assert!(gb_core::metrics::nrmse(&y, &sim)? < 1e-4);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn linear_from_oe(inputs: &[Vec<f64>], y: &[f64], order: usize) -> Result<SparseStateSpace> {
    let spec = NetworkSpec::order(order, inputs.len());
    // the measured starting history (as the gb-model identification paths
    // were tuned with)
    let opts = FitOptions {
        estimate_start: false,
        ..FitOptions::default()
    };
    let net = fit_linear_oe(&spec, inputs, y, &opts)?;
    linear_from_network(&net)
}
