//! Scalar linear-Gaussian model and its exact Kalman filter / RTS smoother
//! (the reference against which the particle methods are tested).
use crate::error::{check, Result, SmcError};
use crate::model::{StateSpaceModel, TransitionDensity};
use crate::rng::{fill_standard_normal, standard_normal, stream, SmcRng};
use serde::{Deserialize, Serialize};

const LN_2PI: f64 = 1.837_877_066_409_345_3;

/// `log N(x; m, v)`.
#[inline]
pub(crate) fn log_normal(x: f64, m: f64, v: f64) -> f64 {
    let e = x - m;
    -0.5 * (LN_2PI + v.ln() + e * e / v)
}

/// Scalar linear-Gaussian state-space model
///
/// ```text
/// x_0 ~ N(m0, p0),  x_t = a x_{t-1} + b u_t + N(0, q),  y_t = c x_t + d u_t + N(0, r)
/// ```
///
/// (`u_t` is the first input, `0` without inputs). It provides the locally
/// optimal proposal `p(x_t | x_{t-1}, y_t)` and the exact look-ahead
/// `η_t = p(y_t | x_{t-1})`, so the guided and auxiliary filters run "fully adapted".
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LinearGaussian {
    a: f64,
    b: f64,
    c: f64,
    d: f64,
    q: f64,
    r: f64,
    m0: f64,
    p0: f64,
    // cached
    sd_q: f64,
    sd_p0: f64,
    inv_r: f64,
    obs_const: f64,
}

impl LinearGaussian {
    /// Builds the model; variances must be positive and all values finite.
    #[allow(clippy::too_many_arguments)]
    pub fn new(a: f64, b: f64, c: f64, d: f64, q: f64, r: f64, m0: f64, p0: f64) -> Result<Self> {
        for (name, v) in [("a", a), ("b", b), ("c", c), ("d", d), ("m0", m0)] {
            check(name, v, v.is_finite(), "must be finite")?;
        }
        for (name, v) in [("q", q), ("r", r), ("p0", p0)] {
            check(
                name,
                v,
                v > 0.0 && v.is_finite(),
                "variance must be positive and finite",
            )?;
        }
        Ok(Self {
            a,
            b,
            c,
            d,
            q,
            r,
            m0,
            p0,
            sd_q: q.sqrt(),
            sd_p0: p0.sqrt(),
            inv_r: 1.0 / r,
            obs_const: -0.5 * (LN_2PI + r.ln()),
        })
    }

    /// Stationary AR(1) `x_t = φ x_{t-1} + σ_x v_t`, `y_t = x_t + σ_y e_t`, `|φ| < 1`.
    ///
    /// ```
    /// let m = gb_smc::LinearGaussian::ar1(0.9, 1.0, 0.5).unwrap();
    /// assert!((m.p0() - 1.0 / (1.0 - 0.81)).abs() < 1e-12);
    /// ```
    pub fn ar1(phi: f64, sigma_x: f64, sigma_y: f64) -> Result<Self> {
        check("phi", phi, phi.abs() < 1.0, "must satisfy |phi| < 1")?;
        check(
            "sigma_x",
            sigma_x,
            sigma_x > 0.0 && sigma_x.is_finite(),
            "must be positive",
        )?;
        check(
            "sigma_y",
            sigma_y,
            sigma_y > 0.0 && sigma_y.is_finite(),
            "must be positive",
        )?;
        let q = sigma_x * sigma_x;
        Self::new(
            phi,
            0.0,
            1.0,
            0.0,
            q,
            sigma_y * sigma_y,
            0.0,
            q / (1.0 - phi * phi),
        )
    }

    /// Transition coefficient `a`.
    pub fn a(&self) -> f64 {
        self.a
    }
    /// State noise variance `q`.
    pub fn q(&self) -> f64 {
        self.q
    }
    /// Observation noise variance `r`.
    pub fn r(&self) -> f64 {
        self.r
    }
    /// Initial variance `p0`.
    pub fn p0(&self) -> f64 {
        self.p0
    }

    #[inline]
    fn u0(u: &[f64]) -> f64 {
        u.first().copied().unwrap_or(0.0)
    }

    /// Simulates `(x, y)` of length `t` without inputs.
    pub fn simulate(&self, t: usize, seed: u64) -> (Vec<f64>, Vec<f64>) {
        let mut rng = stream(seed, 99, 0, 0);
        let mut xs = Vec::with_capacity(t);
        let mut ys = Vec::with_capacity(t);
        for k in 0..t {
            let x = if k == 0 {
                self.sample_initial(&[], &mut rng)
            } else {
                self.sample_transition(k, &xs[k - 1], &[], &mut rng)
            };
            let e = standard_normal(&mut rng);
            ys.push(self.c * x + self.r.sqrt() * e);
            xs.push(x);
        }
        (xs, ys)
    }

    /// Optimal proposal `N(mean, var)` given prior `N(mu, v)` and `y_t`; plus
    /// `log p(y_t | prior)`.
    #[inline]
    fn posterior(&self, mu: f64, v: f64, y: f64, u: f64) -> (f64, f64, f64) {
        let yc = y - self.d * u;
        let s = self.c * self.c * v + self.r;
        let k = v * self.c / s;
        let mean = mu + k * (yc - self.c * mu);
        let var = v - k * self.c * v;
        (mean, var, log_normal(yc, self.c * mu, s))
    }
}

impl StateSpaceModel for LinearGaussian {
    type State = f64;
    type Obs = f64;
    #[inline]
    fn sample_initial(&self, _u: &[f64], rng: &mut SmcRng) -> f64 {
        self.m0 + self.sd_p0 * standard_normal(rng)
    }
    #[inline]
    fn sample_transition(&self, _t: usize, prev: &f64, u: &[f64], rng: &mut SmcRng) -> f64 {
        self.a * prev + self.b * Self::u0(u) + self.sd_q * standard_normal(rng)
    }
    #[inline]
    fn log_observation(&self, _t: usize, x: &f64, y: &f64, u: &[f64]) -> f64 {
        let e = y - self.c * x - self.d * Self::u0(u);
        self.obs_const - 0.5 * e * e * self.inv_r
    }
    #[inline(always)]
    fn sample_transition_batch(&self, _t: usize, x: &mut [f64], u: &[f64], rng: &mut SmcRng) {
        let bu = self.b * Self::u0(u);
        let mut z = [0.0f64; 128];
        for blk in x.chunks_mut(128) {
            let z = &mut z[..blk.len()];
            fill_standard_normal(rng, z);
            for (xi, &zi) in blk.iter_mut().zip(z.iter()) {
                *xi = self.a * *xi + bu + self.sd_q * zi;
            }
        }
    }
    #[inline(always)]
    fn log_observation_batch(&self, _t: usize, x: &[f64], y: &f64, u: &[f64], out: &mut [f64]) {
        let yc = *y;
        let du = self.d * Self::u0(u);
        for (o, &xi) in out.iter_mut().zip(x) {
            let e = yc - self.c * xi - du;
            *o = self.obs_const - 0.5 * e * e * self.inv_r;
        }
    }
    fn sample_initial_proposal(&self, y: &f64, u: &[f64], rng: &mut SmcRng) -> f64 {
        let (m, v, _) = self.posterior(self.m0, self.p0, *y, Self::u0(u));
        m + v.sqrt() * standard_normal(rng)
    }
    fn log_initial_proposal_ratio(&self, x: &f64, y: &f64, u: &[f64]) -> f64 {
        let (m, v, _) = self.posterior(self.m0, self.p0, *y, Self::u0(u));
        log_normal(*x, self.m0, self.p0) - log_normal(*x, m, v)
    }
    fn sample_proposal(&self, _t: usize, prev: &f64, y: &f64, u: &[f64], rng: &mut SmcRng) -> f64 {
        let u0 = Self::u0(u);
        let (m, v, _) = self.posterior(self.a * prev + self.b * u0, self.q, *y, u0);
        m + v.sqrt() * standard_normal(rng)
    }
    fn log_proposal_ratio(&self, _t: usize, prev: &f64, x: &f64, y: &f64, u: &[f64]) -> f64 {
        let u0 = Self::u0(u);
        let mu = self.a * prev + self.b * u0;
        let (m, v, _) = self.posterior(mu, self.q, *y, u0);
        log_normal(*x, mu, self.q) - log_normal(*x, m, v)
    }
    fn log_auxiliary(&self, _t: usize, prev: &f64, y: &f64, u: &[f64]) -> f64 {
        let u0 = Self::u0(u);
        self.posterior(self.a * prev + self.b * u0, self.q, *y, u0)
            .2
    }
}

impl TransitionDensity for LinearGaussian {
    fn log_transition_density(&self, _t: usize, prev: &f64, x: &f64, u: &[f64]) -> f64 {
        log_normal(*x, self.a * prev + self.b * Self::u0(u), self.q)
    }
    fn log_transition_bound(&self, _t: usize, _u: &[f64]) -> Option<f64> {
        Some(-0.5 * (LN_2PI + self.q.ln()))
    }
}

/// Output of the Kalman filter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KalmanOutput {
    /// Exact `log p(y_{0:T-1})`.
    pub log_likelihood: f64,
    /// Filtering means `E[x_t | y_{0:t}]`.
    pub mean: Vec<f64>,
    /// Filtering variances.
    pub var: Vec<f64>,
    /// Predictive means `E[x_t | y_{0:t-1}]`.
    pub pred_mean: Vec<f64>,
    /// Predictive variances.
    pub pred_var: Vec<f64>,
}

/// Exact Kalman filter and Rauch–Tung–Striebel smoother for [`LinearGaussian`] (no inputs).
///
/// ```
/// use gb_smc::{KalmanFilter, LinearGaussian};
/// let m = LinearGaussian::ar1(0.5, 1.0, 1.0).unwrap();
/// let out = KalmanFilter::new(&m).filter(&[0.3, -0.1]).unwrap();
/// assert_eq!(out.mean.len(), 2);
/// ```
#[derive(Debug, Clone, Copy)]
pub struct KalmanFilter<'a> {
    model: &'a LinearGaussian,
}

impl<'a> KalmanFilter<'a> {
    /// Filter for `model`.
    pub fn new(model: &'a LinearGaussian) -> Self {
        Self { model }
    }

    /// Runs the filter on `y`.
    pub fn filter(&self, y: &[f64]) -> Result<KalmanOutput> {
        if y.is_empty() {
            return Err(SmcError::EmptyData);
        }
        let m = self.model;
        let n = y.len();
        let mut out = KalmanOutput {
            log_likelihood: 0.0,
            mean: Vec::with_capacity(n),
            var: Vec::with_capacity(n),
            pred_mean: Vec::with_capacity(n),
            pred_var: Vec::with_capacity(n),
        };
        let (mut mp, mut pp) = (m.m0, m.p0);
        for (t, &yt) in y.iter().enumerate() {
            if t > 0 {
                let (mf, pf) = (out.mean[t - 1], out.var[t - 1]);
                mp = m.a * mf;
                pp = m.a * m.a * pf + m.q;
            }
            out.pred_mean.push(mp);
            out.pred_var.push(pp);
            let (mean, var, ll) = m.posterior(mp, pp, yt, 0.0);
            out.log_likelihood += ll;
            out.mean.push(mean);
            out.var.push(var);
        }
        Ok(out)
    }

    /// RTS smoother: `(E[x_t | y_{0:T-1}], Var[x_t | y_{0:T-1}])`.
    pub fn smooth(&self, y: &[f64]) -> Result<(Vec<f64>, Vec<f64>)> {
        let f = self.filter(y)?;
        let n = y.len();
        let mut ms = f.mean.clone();
        let mut ps = f.var.clone();
        for t in (0..n - 1).rev() {
            let g = f.var[t] * self.model.a / f.pred_var[t + 1];
            ms[t] = f.mean[t] + g * (ms[t + 1] - f.pred_mean[t + 1]);
            ps[t] = f.var[t] + g * g * (ps[t + 1] - f.pred_var[t + 1]);
        }
        Ok((ms, ps))
    }
}
