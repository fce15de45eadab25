//! Initial-state estimation from an init window of measured outputs.
use crate::error::{ModelError, Result};
use crate::model::SparseStateSpace;
use nalgebra::{DMatrix, DVector};

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
        let resid = |x: &[f64]| -> Option<Vec<f64>> {
            let (y, _) = self.simulate_from(&win, x).ok()?;
            let r: Vec<f64> = y_window[..w].iter().zip(&y).map(|(a, b)| a - b).collect();
            r.iter().all(|v| v.is_finite()).then_some(r)
        };
        let cost = |r: &[f64]| r.iter().map(|v| v * v).sum::<f64>();
        let Some(mut r) = resid(&x) else {
            return Ok(x);
        };
        let mut c = cost(&r);
        let mut lambda = 1e-3;
        for _ in 0..20 {
            let mut jac = DMatrix::<f64>::zeros(w, n);
            for i in 0..n {
                let h = 1e-6 * scale[i];
                let mut xp = x.clone();
                xp[i] += h;
                let Some(rp) = resid(&xp) else {
                    return Ok(x);
                };
                // J = ∂ŷ/∂x = −∂r/∂x
                for t in 0..w {
                    jac[(t, i)] = (r[t] - rp[t]) / h;
                }
            }
            let jtj = jac.transpose() * &jac;
            let jtr = jac.transpose() * DVector::from_column_slice(&r);
            let mut improved = false;
            for _ in 0..8 {
                let mut a = jtj.clone();
                for i in 0..n {
                    a[(i, i)] += lambda * (jtj[(i, i)] + 1e-12);
                }
                let Some(dx) = a.cholesky().map(|ch| ch.solve(&jtr)) else {
                    lambda *= 10.0;
                    continue;
                };
                let xn: Vec<f64> = x.iter().zip(dx.iter()).map(|(a, b)| a + b).collect();
                if let Some(rn) = resid(&xn) {
                    let cn = cost(&rn);
                    if cn < c {
                        let done = c - cn <= 1e-12 * c.max(1e-300);
                        x = xn;
                        r = rn;
                        c = cn;
                        lambda = (lambda * 0.3).max(1e-9);
                        improved = !done;
                        break;
                    }
                }
                lambda *= 10.0;
            }
            if !improved {
                break;
            }
        }
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
