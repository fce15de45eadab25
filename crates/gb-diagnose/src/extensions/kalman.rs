//! The exact filter of the linear-Gaussian state space with process noise
//! (the `noise` extension's likelihood when the model is linear and the
//! noise Gaussian) and the maximum-likelihood noise levels.
//!
//! The model is the one the particle filter of `gb_model::Smc` runs
//! (`NoisyModel`): `x_0 ~ N(x₀, Q)`, `x_t = A x_{t−1} + B u_{t−1} + v_t`,
//! `y_t = C x_t + D u_t + y₀ + w_t`, `v_t ~ N(0, Q)` with diagonal
//! `Q = diag(q_i²)`, `w_t ~ N(0, r²)`. For it the Kalman filter's
//! increments `log N(y_t; ŷ_{t|t−1}, S_t)` are the exact predictive
//! log-likelihood the bootstrap particle filter estimates (tested).
use gb_model::{NoiseModel, SparseStateSpace};

const LN_2PI: f64 = 1.837_877_066_409_345_3;

/// The linear-Gaussian form of a linear [`SparseStateSpace`] (one sub-step,
/// no wavelet or Preisach terms, Gaussian noise), or `None`.
pub(crate) struct Lgss<'a> {
    m: &'a SparseStateSpace,
    q: Vec<f64>,
    r: f64,
}

impl<'a> Lgss<'a> {
    /// `m` with its own noise, when it is linear and Gaussian.
    pub(crate) fn of(m: &'a SparseStateSpace) -> Option<Self> {
        let sd = |n: &NoiseModel| match n {
            NoiseModel::Gaussian { sd } if sd.is_finite() && *sd >= 0.0 => Some(*sd),
            _ => None,
        };
        let q: Option<Vec<f64>> = m
            .process_noise
            .iter()
            .map(|n| sd(n).map(|s| s * s))
            .collect();
        let r = sd(&m.measurement_noise)?;
        (m.substeps == 1 && m.terms.is_empty() && m.hysteresis.is_empty() && r > 0.0)
            .then_some(Self { m, q: q?, r: r * r })
    }

    /// With process standard deviations `q` and measurement sd `r`.
    pub(crate) fn with(m: &'a SparseStateSpace, q: &[f64], r: f64) -> Self {
        Self {
            m,
            q: q.iter().map(|s| s * s).collect(),
            r: r * r,
        }
    }

    /// The Kalman filter over `y` from `m.x0`: the increments
    /// `log p(y_t | y_{0:t−1})` and, with `keep`, the filtered means
    /// `x_{t|t}` (row-major, N×n). Returns `None` when a variance stops
    /// being positive or a value is not finite.
    pub(crate) fn filter(
        &self,
        u: &[Vec<f64>],
        y: &[f64],
        keep: bool,
    ) -> Option<(Vec<f64>, Vec<f64>)> {
        let (n, nu) = (self.m.n_states, self.m.n_inputs);
        let (a, b, c) = (&self.m.a, &self.m.b, &self.m.c);
        let mut x = self.m.x0.clone();
        let mut p = vec![0.0; n * n];
        for i in 0..n {
            p[i * n + i] = self.q[i];
        }
        let (mut xn, mut ap, mut pc) = (vec![0.0; n], vec![0.0; n * n], vec![0.0; n]);
        let mut inc = Vec::with_capacity(y.len());
        let mut means = Vec::with_capacity(if keep { y.len() * n } else { 0 });
        for t in 0..y.len() {
            if t > 0 {
                // x ← A x + B u_{t−1};  P ← A P Aᵀ + Q
                for i in 0..n {
                    let mut v = 0.0;
                    for j in 0..n {
                        v += a[i * n + j] * x[j];
                    }
                    for j in 0..nu {
                        v += b[i * nu + j] * u[j][t - 1];
                    }
                    xn[i] = v;
                }
                std::mem::swap(&mut x, &mut xn);
                for i in 0..n {
                    for j in 0..n {
                        ap[i * n + j] = (0..n).map(|k| a[i * n + k] * p[k * n + j]).sum();
                    }
                }
                for i in 0..n {
                    for j in 0..n {
                        p[i * n + j] = (0..n).map(|k| ap[i * n + k] * a[j * n + k]).sum();
                    }
                    p[i * n + i] += self.q[i];
                }
            }
            // innovation ν = y − C x − D u − y₀, S = C P Cᵀ + r
            let mut yh = self.m.y_offset;
            for i in 0..n {
                yh += c[i] * x[i];
            }
            for j in 0..nu {
                yh += self.m.d[j] * u[j][t];
            }
            for i in 0..n {
                pc[i] = (0..n).map(|k| p[i * n + k] * c[k]).sum();
            }
            let s = self.r + (0..n).map(|i| c[i] * pc[i]).sum::<f64>();
            let nu_t = y[t] - yh;
            if !(s > 0.0 && s.is_finite() && nu_t.is_finite()) {
                return None;
            }
            inc.push(-0.5 * (LN_2PI + s.ln() + nu_t * nu_t / s));
            // K = P Cᵀ / S;  x ← x + K ν;  P ← P − K S Kᵀ (kept symmetric)
            for i in 0..n {
                x[i] += pc[i] / s * nu_t;
            }
            for i in 0..n {
                for j in 0..n {
                    p[i * n + j] -= pc[i] * pc[j] / s;
                }
            }
            for i in 0..n {
                for j in 0..i {
                    let v = 0.5 * (p[i * n + j] + p[j * n + i]);
                    p[i * n + j] = v;
                    p[j * n + i] = v;
                }
            }
            if keep {
                means.extend_from_slice(&x);
            }
        }
        Some((inc, means))
    }

    /// `Σ_t log p(y_t | y_{0:t−1})`, `−∞` when the filter fails.
    pub(crate) fn log_likelihood(&self, u: &[Vec<f64>], y: &[f64]) -> f64 {
        self.filter(u, y, false)
            .map_or(f64::NEG_INFINITY, |(inc, _)| inc.iter().sum())
    }
}

/// Maximum-likelihood noise levels of `m` on `(u, y)`: process standard
/// deviations `κ_p s_i` (`s_i`, the standard deviation of state `i`'s
/// simulated increments, fixes their ratios) and measurement sd `κ_m σ`
/// (`σ` the output-error RMSE), `(κ_p, κ_m)` maximising the exact
/// likelihood: a grid over `log₁₀ κ_p ∈ {−∞, −3, −2.75, …, 0}`,
/// `log₁₀ κ_m ∈ {−1.5, …, 0.25}`, then a pattern search in the logs.
/// Returns `(κ_p, κ_m, log-likelihood)`.
pub(crate) fn ml_levels(
    m: &SparseStateSpace,
    s: &[f64],
    sigma: f64,
    u: &[Vec<f64>],
    y: &[f64],
) -> (f64, f64, f64) {
    let ll = |lp: f64, lm: f64| -> f64 {
        let kp = if lp <= -30.0 { 0.0 } else { lp.exp() };
        let q: Vec<f64> = s.iter().map(|v| kp * v).collect();
        Lgss::with(m, &q, sigma * lm.exp()).log_likelihood(u, y)
    };
    let ln10 = std::f64::consts::LN_10;
    let mut best = (-31.0, 0.0, f64::NEG_INFINITY);
    let kps = std::iter::once(-31.0).chain((0..=12).map(|i| (-3.0 + 0.25 * i as f64) * ln10));
    for lp in kps {
        for j in 0..=14 {
            let lm = (-1.5 + 0.125 * j as f64) * ln10;
            let v = ll(lp, lm);
            if v > best.2 {
                best = (lp, lm, v);
            }
        }
    }
    let mut step = 0.25;
    while step > 0.01 {
        let mut moved = false;
        for (dp, dm) in [(step, 0.0), (-step, 0.0), (0.0, step), (0.0, -step)] {
            if best.0 <= -30.0 && dp != 0.0 {
                continue;
            }
            let v = ll(best.0 + dp, best.1 + dm);
            if v > best.2 {
                best = (best.0 + dp, best.1 + dm, v);
                moved = true;
            }
        }
        if !moved {
            step *= 0.5;
        }
    }
    let kp = if best.0 <= -30.0 { 0.0 } else { best.0.exp() };
    (kp, best.1.exp(), best.2)
}

#[cfg(test)]
pub(in crate::extensions) mod tests {
    use super::*;
    use gb_model::SmcParams;
    use rand_distr::{Distribution, StandardNormal};

    /// The resonant second-order observer-form model of the noise tests.
    pub(in crate::extensions) fn resonant() -> SparseStateSpace {
        SparseStateSpace::linear(
            vec![1.6, 1.0, -0.8, 0.0],
            vec![0.5, 0.3],
            vec![1.0, 0.0],
            vec![0.0],
        )
        .expect("model")
    }

    /// A resonant second-order system driven by `u` and by a white force
    /// disturbance `v` (entering both states), measured with white noise.
    fn data(n: usize, q: f64, r: f64, seed: u64) -> (SparseStateSpace, Vec<Vec<f64>>, Vec<f64>) {
        let m = resonant();
        let mut rng = gb_core::rng::seeded(seed);
        let mut g = || -> f64 { StandardNormal.sample(&mut rng) };
        let u: Vec<f64> = (0..n).map(|_| g()).collect();
        let (mut x, mut y) = ([0.0f64; 2], vec![0.0; n]);
        for t in 0..n {
            y[t] = x[0] + r * g();
            let x0 = 1.6 * x[0] + x[1] + 0.5 * u[t] + q * g();
            let x1 = -0.8 * x[0] + 0.3 * u[t] + q * g();
            x = [x0, x1];
        }
        (m, vec![u], y)
    }

    #[test]
    fn the_kalman_likelihood_is_the_one_the_particle_filter_estimates() {
        let (mut m, u, y) = data(300, 0.2, 0.3, 5);
        m.process_noise = vec![NoiseModel::Gaussian { sd: 0.2 }; 2];
        m.measurement_noise = NoiseModel::Gaussian { sd: 0.3 };
        let exact = Lgss::of(&m)
            .expect("linear Gaussian")
            .log_likelihood(&u, &y);
        // the particle estimate's Monte Carlo error at 80 000 particles
        // (300 samples) is about 0.3 nats: the mean of two seeds lies within
        // 0.5 nats of the exact value (20 000 particles: errors up to 0.9)
        let runs: Vec<_> = [1, 2]
            .iter()
            .map(|&seed| {
                let smc = SmcParams::new()
                    .particles(80_000)
                    .seed(seed)
                    .check()
                    .expect("params");
                smc.filter_states(&m, &u, &y, false).expect("filter")
            })
            .collect();
        let mean = runs.iter().map(|e| e.log_likelihood).sum::<f64>() / 2.0;
        assert!(
            (mean - exact).abs() < 0.5,
            "particle {mean} vs Kalman {exact}"
        );
        let est = &runs[0];
        let sum: f64 = est.increments.iter().sum();
        assert!((sum - est.log_likelihood).abs() < 1e-6);
    }

    #[test]
    fn maximum_likelihood_finds_process_noise_where_there_is_some_and_none_where_there_is_none() {
        let s = [0.2, 0.2];
        let (m, u, y) = data(3000, 0.2, 0.3, 7);
        let (kp, km, _) = ml_levels(&m, &s, 0.3, &u, &y);
        // true levels: κ_p = 1, κ_m = 1
        assert!((0.7..1.4).contains(&kp), "κ_p {kp}");
        assert!((0.8..1.2).contains(&km), "κ_m {km}");
        let (m, u, y) = data(3000, 0.0, 0.3, 8);
        let (kp, _, _) = ml_levels(&m, &s, 0.3, &u, &y);
        assert!(kp < 0.05, "κ_p {kp} without process noise");
    }
}
