//! Initial-state estimation from an init window of measured outputs.
use crate::error::{ModelError, Result};
use crate::model::SparseStateSpace;
use gb_core::solver::{LeastSquaresProblem, LmParams};
use gb_core::Silent;
use nalgebra::{DMatrix, DVector};

/// `min_x Σ_{t<w} (y_t − ŷ_t(x))²` for the workspace's Levenberg–Marquardt
/// solver, with a forward-difference Jacobian.
struct InitProblem<'a> {
    model: &'a SparseStateSpace,
    win: &'a [Vec<f64>],
    y: &'a [f64],
    /// State scales for the difference steps.
    scale: Vec<f64>,
    /// The lowest-cost point evaluated so far (x, residual, cost): the
    /// solver's current point, whose residual the Jacobian reuses.
    best: Option<(Vec<f64>, Vec<f64>, f64)>,
}

impl InitProblem<'_> {
    fn residual(&self, x: &[f64]) -> Option<Vec<f64>> {
        let (y, _) = self.model.simulate_from(self.win, x).ok()?;
        let r: Vec<f64> = self.y.iter().zip(&y).map(|(a, b)| a - b).collect();
        r.iter().all(|v| v.is_finite()).then_some(r)
    }
}

impl LeastSquaresProblem for InitProblem<'_> {
    fn n_params(&self) -> usize {
        self.model.n_states
    }
    fn cost(&mut self, x: &[f64]) -> Option<f64> {
        let r = self.residual(x)?;
        let c = r.iter().map(|v| v * v).sum::<f64>();
        if self.best.as_ref().is_none_or(|b| c < b.2) {
            self.best = Some((x.to_vec(), r, c));
        }
        Some(c)
    }
    fn linearize(&mut self, x: &[f64], gram: &mut [f64], grad: &mut [f64]) -> Option<f64> {
        let hit = self
            .best
            .as_ref()
            .is_some_and(|b| b.0.iter().zip(x).all(|(a, b)| a.to_bits() == b.to_bits()));
        if !hit {
            self.cost(x)?;
        }
        let (_, r, c) = self.best.clone()?;
        let (w, n) = (self.y.len(), self.model.n_states);
        let mut jac = DMatrix::<f64>::zeros(w, n);
        for i in 0..n {
            let h = 1e-6 * self.scale[i];
            let mut xp = x.to_vec();
            xp[i] += h;
            let rp = self.residual(&xp)?;
            // J = ∂ŷ/∂x = −∂r/∂x
            for t in 0..w {
                jac[(t, i)] = (r[t] - rp[t]) / h;
            }
        }
        let jtj = jac.transpose() * &jac;
        let jtr = jac.transpose() * DVector::from_column_slice(&r);
        for i in 0..n {
            for j in 0..n {
                gram[i * n + j] = jtj[(i, j)];
            }
            grad[i] = jtr[i];
        }
        Some(c)
    }
}

impl SparseStateSpace {
    /// Initial state `x̂₀` that makes the free-run simulation match the
    /// measured outputs `y_window` (the first `w` samples of the record):
    ///
    /// `x̂₀ = argmin_x Σ_{t<w} (y_t − ŷ_t(x))²`, by Levenberg–Marquardt from
    /// the model's own `x₀`, with a finite-difference Jacobian (one
    /// simulation of `w` samples per state) and a damping that keeps
    /// unobservable directions at `x₀`. Preisach components start from
    /// negative saturation as in [`simulate`](Self::simulate).
    ///
    /// ```
    /// use gb_model::SparseStateSpace;
    /// let m = SparseStateSpace::linear(vec![0.9], vec![0.1], vec![1.0], vec![0.0])?;
    /// let u = vec![vec![0.0; 40]];
    /// let y: Vec<f64> = (0..40).map(|t| 2.0 * 0.9f64.powi(t)).collect();
    /// let x0 = m.estimate_initial_state(&u, &y[..20])?;
    /// assert!((x0[0] - 2.0).abs() < 1e-6);
    /// # Ok::<(), gb_model::ModelError>(())
    /// ```
    pub fn estimate_initial_state(
        &self,
        inputs: &[Vec<f64>],
        y_window: &[f64],
    ) -> Result<Vec<f64>> {
        let len = self.check_inputs(inputs)?;
        let w = y_window.len().min(len);
        let mut x = self.x0.clone();
        if w == 0 {
            return Ok(x);
        }
        if y_window[..w].iter().any(|v| !v.is_finite()) {
            return Err(ModelError::InvalidArgument(
                "init window has non-finite outputs".into(),
            ));
        }
        let win: Vec<Vec<f64>> = inputs.iter().map(|u| u[..w].to_vec()).collect();
        let n = self.n_states;
        // state scales from the simulation over the window, for the FD steps
        let scale: Vec<f64> = match self.simulate_states(&win) {
            Ok((_, xs)) => (0..n)
                .map(|i| {
                    let m = xs.chunks(n).map(|r| r[i].abs()).fold(0.0, f64::max);
                    m.max(x[i].abs()).max(1e-8)
                })
                .collect(),
            Err(_) => vec![1.0; n],
        };
        let mut problem = InitProblem {
            model: self,
            win: &win,
            y: &y_window[..w],
            scale,
            best: None,
        };
        let Some(c0) = problem.cost(&x) else {
            return Ok(x);
        };
        if !c0.is_finite() {
            return Ok(x);
        }
        // λ from 1e-3, ×10 after a rejected step, ×0.3 after an accepted one
        // (≥ 1e-9), 8 trials, 20 iterations, damping λ·(Gᵢᵢ + 1e-12), done
        // when a step lowers the cost by less than 1e-12 (relative)
        let solver = LmParams {
            max_iter: 20,
            tol: 1e-12,
            lambda_init: 1e-3,
            lambda_up: 10.0,
            lambda_up_singular: 10.0,
            lambda_down: 0.3,
            lambda_min: 1e-9,
            lambda_max: f64::MAX,
            max_trials: 8,
            diag_floor: 0.0,
            diag_add: 1e-12,
            jitter: 0.0,
            diag_floor_abs: 0.0,
            jitter_abs: 0.0,
            stall_window: 0,
            stall_tol: 0.0,
            ..LmParams::default()
        }
        .check()?;
        x = solver.minimize(&mut problem, &x, &Silent)?.theta;
        Ok(x)
    }

    /// Free-run simulation whose initial state is estimated from the
    /// measured outputs `y_window` ([`estimate_initial_state`](Self::estimate_initial_state)).
    pub fn simulate_init_window(&self, inputs: &[Vec<f64>], y_window: &[f64]) -> Result<Vec<f64>> {
        let x0 = self.estimate_initial_state(inputs, y_window)?;
        self.simulate_from(inputs, &x0).map(|(y, _)| y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_the_initial_state_of_an_oscillator() {
        // x⁺ = A x + b u, y = x₁; true x₀ = (0.7, −0.3)
        let m = SparseStateSpace::linear(
            vec![1.5, -0.7, 1.0, 0.0],
            vec![0.5, 0.0],
            vec![1.0, 0.0],
            vec![0.0],
        )
        .unwrap();
        let u: Vec<f64> = (0..300)
            .map(|t| ((t * 7 % 11) as f64 - 5.0) / 5.0)
            .collect();
        let truth = vec![0.7, -0.3];
        let (y, _) = m.simulate_from(std::slice::from_ref(&u), &truth).unwrap();
        let x0 = m
            .estimate_initial_state(std::slice::from_ref(&u), &y[..30])
            .unwrap();
        assert!(
            (x0[0] - 0.7).abs() < 1e-6 && (x0[1] + 0.3).abs() < 1e-6,
            "{x0:?}"
        );
        let sim = m.simulate_init_window(&[u], &y[..30]).unwrap();
        let e = sim
            .iter()
            .zip(&y)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(e < 1e-6, "{e}");
        // the stored x₀ (zero) would be off
        assert!(m.simulate(&[vec![0.0; 5]]).unwrap()[0].abs() < 1e-12);
    }
}
