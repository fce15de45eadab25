//! Least-squares ARX models: the generator's measure of how far a case is
//! from linear (the free-run error of the best equation-error linear model
//! fitted on noise-free data), and a tool for tests.
//!
//! y(k) = θ₀ + Σᵢ aᵢ y(k−i) + Σⱼ Σ_{l ∈ lagsⱼ} bⱼₗ uⱼ(k−l), all signals
//! normalised to zero mean and unit standard deviation for the fit.
use gb_core::{metrics, CoreError};
use nalgebra::{DMatrix, DVector};

/// A fitted ARX model.
#[derive(Debug, Clone, PartialEq)]
pub struct Arx {
    /// Output lags 1..=na.
    pub na: usize,
    /// Input lags per input.
    pub lags: Vec<Vec<usize>>,
    /// [θ₀, a₁..a_na, b…] in normalised units.
    pub theta: Vec<f64>,
    /// (mean, std) of each input, then of the output.
    scale: Vec<(f64, f64)>,
}

fn norm(x: &[f64]) -> (f64, f64) {
    let s = metrics::std(x);
    (metrics::mean(x), if s > 0.0 { s } else { 1.0 })
}

impl Arx {
    fn start(na: usize, lags: &[Vec<usize>]) -> usize {
        lags.iter().flatten().copied().max().unwrap_or(0).max(na)
    }

    fn regressor(&self, u: &[Vec<f64>], y: &[f64], k: usize, phi: &mut Vec<f64>) {
        phi.clear();
        phi.push(1.0);
        let (my, sy) = self.scale[u.len()];
        for i in 1..=self.na {
            phi.push((y[k - i] - my) / sy);
        }
        for (j, l) in self.lags.iter().enumerate() {
            let (m, s) = self.scale[j];
            for &d in l {
                phi.push((u[j][k - d] - m) / s);
            }
        }
    }

    /// Least-squares fit on inputs `u` (`u[j][k]`) and output `y`.
    pub fn fit(
        u: &[Vec<f64>],
        y: &[f64],
        na: usize,
        lags: &[Vec<usize>],
    ) -> Result<Self, CoreError> {
        if u.len() != lags.len() || u.iter().any(|x| x.len() != y.len()) {
            return Err(CoreError::Dimension(
                "ARX: inputs, lags and output differ".into(),
            ));
        }
        let start = Self::start(na, lags);
        let p = 1 + na + lags.iter().map(Vec::len).sum::<usize>();
        if y.len() < start + 2 * p {
            return Err(CoreError::TooShort {
                context: "ARX fit".into(),
                needed: start + 2 * p,
                got: y.len(),
            });
        }
        let mut scale: Vec<(f64, f64)> = u.iter().map(|x| norm(x)).collect();
        scale.push(norm(y));
        let mut m = Self {
            na,
            lags: lags.to_vec(),
            theta: vec![],
            scale,
        };
        let rows = y.len() - start;
        let mut a = DMatrix::<f64>::zeros(rows, p);
        let mut b = DVector::<f64>::zeros(rows);
        let mut phi = Vec::with_capacity(p);
        let (my, sy) = m.scale[u.len()];
        for k in start..y.len() {
            m.regressor(u, y, k, &mut phi);
            for (c, v) in phi.iter().enumerate() {
                a[(k - start, c)] = *v;
            }
            b[k - start] = (y[k] - my) / sy;
        }
        // SVD: the regressors of slow, noise-free systems are nearly collinear
        let svd = a.svd(true, true);
        let tol = 1e-12 * svd.singular_values.max();
        let theta = svd
            .solve(&b, tol)
            .map_err(|e| CoreError::InvalidArgument(format!("ARX: {e}")))?;
        m.theta = theta.iter().copied().collect();
        Ok(m)
    }

    /// Free-run simulation; the first samples (up to the largest lag) are
    /// taken from the measured `y`. Stops growing at 1e6 output std (the
    /// rest is held) so that an unstable fit gives a large, finite error.
    pub fn simulate(&self, u: &[Vec<f64>], y: &[f64]) -> Vec<f64> {
        let start = Self::start(self.na, &self.lags).min(y.len());
        let (my, sy) = self.scale[u.len()];
        let mut yh: Vec<f64> = y[..start].to_vec();
        let mut phi = Vec::with_capacity(self.theta.len());
        for k in start..y.len() {
            self.regressor(u, &yh, k, &mut phi);
            let t: f64 = phi.iter().zip(&self.theta).map(|(a, b)| a * b).sum();
            let t = if t.is_finite() {
                t.clamp(-1e6, 1e6)
            } else {
                1e6
            };
            yh.push(my + sy * t);
        }
        yh
    }

    /// Free-run NRMSE on (u, y), scored after the start-up samples, at most 10.
    pub fn free_run_nrmse(&self, u: &[Vec<f64>], y: &[f64]) -> Result<f64, CoreError> {
        let start = Self::start(self.na, &self.lags).min(y.len());
        let yh = self.simulate(u, y);
        let e = metrics::nrmse(&y[start..], &yh[start..])?;
        Ok(if e.is_finite() { e.min(10.0) } else { 10.0 })
    }
}

impl Arx {
    /// One-step-ahead prediction NRMSE on (u, y) (measured outputs in the
    /// regressors), scored after the start-up samples.
    pub fn one_step_nrmse(&self, u: &[Vec<f64>], y: &[f64]) -> Result<f64, CoreError> {
        let start = Self::start(self.na, &self.lags).min(y.len());
        let (my, sy) = self.scale[u.len()];
        let mut phi = Vec::with_capacity(self.theta.len());
        let yh: Vec<f64> = (start..y.len())
            .map(|k| {
                self.regressor(u, y, k, &mut phi);
                my + sy * phi.iter().zip(&self.theta).map(|(a, b)| a * b).sum::<f64>()
            })
            .collect();
        metrics::nrmse(&y[start..], &yh)
    }
}

/// Fit an ARX model on the training pair, return its free-run NRMSE on the
/// validation pair.
pub fn arx_misfit(
    train: (&[Vec<f64>], &[f64]),
    validate: (&[Vec<f64>], &[f64]),
    na: usize,
    lags: &[Vec<usize>],
) -> Result<f64, CoreError> {
    Arx::fit(train.0, train.1, na, lags)?.free_run_nrmse(validate.0, validate.1)
}
