//! Wiener–Hammerstein local model network: a static local model network
//! between two linear filters,
//!
//! ```text
//! v(k) = G₁(q) u(k),    w(k) = f(v(k)) = Σᵢ Φᵢ(v(k)) (aᵢ + bᵢ v(k)),    ŷ(k) = G₂(q) w(k),
//! ```
//!
//! with `Gⱼ(q) = Bⱼ(q⁻¹)/Aⱼ(q⁻¹)` and Φᵢ the decision-tree sigmoid weights of
//! a one-dimensional chain of splits at fixed knots (a partition of unity by
//! construction: `Φ₀ = 1 − ψ₁`, `Φᵢ = ψᵢ − ψᵢ₊₁`, `Φ_M = ψ_M`,
//! `ψⱼ(v) = σ((v − κⱼ)/s)`). The nonlinearity acts on the internal signal v,
//! which is what a network on delayed outputs cannot see (Nelles 2001 §19;
//! the partition space is the output of a linear filter of the input).
//!
//! Identification ([`WhParams`] → [`WhFitter::fit`]) follows the
//! best-linear-approximation route of Sjöberg & Schoukens (2012) and
//! Schoukens & Tiels (2017):
//!
//! 1. the best linear approximation `G = B/A` by output error (ARX start,
//!    Levenberg–Marquardt);
//! 2. every split of its poles and zeros (complex pairs kept together)
//!    between G₁ and G₂ is scored: with G₁ and G₂ fixed the model is linear
//!    in the local-model parameters, `ŷ = Σ cₖ G₂(ϕₖ(v))`, so one least-squares
//!    fit per split gives its simulation error;
//! 3. the best splits, each with 1, 2, … `extra_g1` further free poles and
//!    zeros in G₁, are refined by Levenberg–Marquardt on the simulation error
//!    over all filter coefficients and local-model parameters jointly (poles
//!    kept inside |z| < 0.999), in two rounds: each for a third of the
//!    iterations, then the best `candidates` by the held-out error for the
//!    rest (successive halving); the one with the smallest error on a
//!    held-out tail of the training data is kept and trained on all of it.
//!
//! Beyond the range of v on the training record (its *support*, stored with
//! the fitted network) f continues the trend of its outer tenth linearly
//! ([`StaticNetwork::extrapolated`]): the outermost local models, whose
//! validity regions may hold no data, do not decide the extrapolation.
//!
//! The BLA orders of step 1, the splits of step 2 and the refinements of
//! each round of step 3 are independent fits: they run in parallel (rayon)
//! and are kept in their sequential order, so the result is the same on
//! any number of threads.
use crate::LmnError;
use gb_core::solver::{LeastSquaresProblem, LevenbergMarquardt, LmParams};
use gb_core::{Identify, Observer, Records, Silent};
use nalgebra::{Complex, DMatrix, DVector};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

type Result<T> = std::result::Result<T, LmnError>;

/// `y = (b/a) x`: `y(k) = Σⱼ bⱼ x(k−j) − Σ_{i≥1} aᵢ y(k−i)`, zero initial state
/// (`a[0] = 1`).
pub fn filter(b: &[f64], a: &[f64], x: &[f64], y: &mut [f64]) {
    let n = x.len().min(y.len());
    for k in 0..n {
        let mut acc = 0.0;
        for (j, bj) in b.iter().enumerate().take(k + 1) {
            acc += bj * x[k - j];
        }
        for (i, ai) in a.iter().enumerate().skip(1).take(k) {
            acc -= ai * y[k - i];
        }
        y[k] = acc;
    }
}

fn filtered(b: &[f64], a: &[f64], x: &[f64]) -> Vec<f64> {
    let mut y = vec![0.0; x.len()];
    filter(b, a, x, &mut y);
    y
}

/// `y = (b/a) x` started in the steady state of the constant input `x₀`:
/// `x(k) = x₀` and `y(k) = G(1)·x₀` for `k < 0`, `G(1) = Σb / Σa`, so that
/// only the changes of `x` after the start excite the filter. Without a
/// finite static gain (a pole at 1) the zero state is used.
fn filtered_from_steady(b: &[f64], a: &[f64], x: &[f64]) -> Vec<f64> {
    let x0 = x.first().copied().unwrap_or(0.0);
    let sa: f64 = a.iter().sum();
    let gain = b.iter().sum::<f64>() / sa;
    if !(gain.is_finite() && sa.abs() > 1e-9) {
        return filtered(b, a, x);
    }
    let y0 = gain * x0;
    let mut y = vec![0.0; x.len()];
    for k in 0..x.len() {
        let past_x = |j: usize| if j <= k { x[k - j] } else { x0 };
        let mut acc: f64 = b.iter().enumerate().map(|(j, bj)| bj * past_x(j)).sum();
        for (i, ai) in a.iter().enumerate().skip(1) {
            acc -= ai * if i <= k { y[k - i] } else { y0 };
        }
        y[k] = acc;
    }
    y
}

/// Roots in z of `c₀ zⁿ + c₁ zⁿ⁻¹ + … + cₙ` (the polynomial in q⁻¹ with
/// coefficients `c`), as eigenvalues of the companion matrix.
pub fn roots(c: &[f64]) -> Vec<Complex<f64>> {
    let mut c = c.to_vec();
    while c.len() > 1 && c[0] == 0.0 {
        c.remove(0);
    }
    let n = c.len().saturating_sub(1);
    if n == 0 || !c.iter().all(|v| v.is_finite()) {
        return vec![];
    }
    let mut m = DMatrix::<f64>::zeros(n, n);
    for j in 0..n {
        m[(0, j)] = -c[j + 1] / c[0];
    }
    for i in 1..n {
        m[(i, i - 1)] = 1.0;
    }
    m.complex_eigenvalues().iter().copied().collect()
}

/// Real coefficients (in q⁻¹, leading 1) of `Π (z − rᵢ)`.
pub fn poly_from_roots(r: &[Complex<f64>]) -> Vec<f64> {
    let mut p = vec![Complex::new(1.0, 0.0)];
    for &x in r {
        let mut q = vec![Complex::new(0.0, 0.0); p.len() + 1];
        for (i, &c) in p.iter().enumerate() {
            q[i] += c;
            q[i + 1] -= c * x;
        }
        p = q;
    }
    p.iter().map(|c| c.re).collect()
}

fn max_root_modulus(a: &[f64]) -> f64 {
    roots(a).iter().map(|z| z.norm()).fold(0.0, f64::max)
}

/// Samples until the slowest mode of the denominator `a` has decayed to
/// 10⁻³ (its zero-state transient).
fn settling_samples(a: &[f64]) -> usize {
    let r = max_root_modulus(a);
    if r > 1e-6 && r < 1.0 {
        ((1e-3f64).ln() / r.ln()).ceil() as usize
    } else {
        a.len()
    }
}

/// Groups of roots that go together: a real root, or a complex pair.
fn root_groups(r: &[Complex<f64>]) -> Vec<Vec<Complex<f64>>> {
    let mut used = vec![false; r.len()];
    let mut g = vec![];
    for i in 0..r.len() {
        if used[i] {
            continue;
        }
        used[i] = true;
        if r[i].im.abs() > 1e-9 * r[i].norm().max(1e-300) {
            let conj = r[i].conj();
            if let Some(j) = (0..r.len())
                .filter(|&j| !used[j])
                .min_by(|&a, &b| (r[a] - conj).norm().total_cmp(&(r[b] - conj).norm()))
            {
                used[j] = true;
                g.push(vec![r[i], r[j]]);
                continue;
            }
        }
        g.push(vec![Complex::new(r[i].re, 0.0)]);
    }
    g
}

/// The static one-dimensional local model network `f(v) = Σᵢ Φᵢ(v)(aᵢ + bᵢ v)`
/// with sigmoid-chain (decision-tree) weights at fixed knots.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StaticNetwork {
    /// Split positions κ₁ < … < κ_M.
    pub knots: Vec<f64>,
    /// Sigmoid width s (the smoothness).
    pub width: f64,
    /// `(a₀, b₀, a₁, b₁, …, a_M, b_M)`.
    pub coefficients: Vec<f64>,
    /// The range `[v_lo, v_hi]` of the internal signal on the training
    /// record, set once the network is fitted: beyond it [`eval`](Self::eval)
    /// extrapolates with the outer trend instead of the outermost local
    /// model (see [`extrapolated`](Self::extrapolated)). `None`: no bound
    /// (while fitting, and in files written before it existed). Travels
    /// in the model file after the network (class version 2).
    #[serde(skip)]
    pub support: Option<[f64; 2]>,
}

impl StaticNetwork {
    /// Number of local models M + 1.
    pub fn n_local_models(&self) -> usize {
        self.knots.len() + 1
    }

    /// The 2(M+1) basis values `Φᵢ(v), Φᵢ(v)·v` into `out`.
    pub fn basis(&self, v: f64, out: &mut [f64]) {
        let m = self.knots.len();
        let mut prev = 1.0; // ψ₀ = 1
        for i in 0..=m {
            let next = if i < m {
                1.0 / (1.0 + (-(v - self.knots[i]) / self.width).exp())
            } else {
                0.0
            };
            let phi = prev - next;
            out[2 * i] = phi;
            out[2 * i + 1] = phi * v;
            prev = next;
        }
    }

    /// `f(v)` and its slope `f′(v) = Σᵢ Φᵢ′(v)(cᵢ₀ + cᵢ₁v) + Φᵢ(v)cᵢ₁`,
    /// `Φᵢ = ψᵢ − ψᵢ₊₁` with `ψ′ = ψ(1 − ψ)/width` for the sigmoids. The
    /// network itself, without the support bound (what the fit's Jacobian
    /// needs; the support is set after the fit).
    pub fn eval_with_slope(&self, v: f64) -> (f64, f64) {
        let m = self.knots.len();
        let (mut prev, mut dprev) = (1.0, 0.0);
        let (mut s, mut ds) = (0.0, 0.0);
        for i in 0..=m {
            let (next, dnext) = if i < m {
                let g = 1.0 / (1.0 + (-(v - self.knots[i]) / self.width).exp());
                (g, g * (1.0 - g) / self.width)
            } else {
                (0.0, 0.0)
            };
            let (phi, dphi) = (prev - next, dprev - dnext);
            let (c0, c1) = (self.coefficients[2 * i], self.coefficients[2 * i + 1]);
            s += phi * (c0 + c1 * v);
            ds += dphi * (c0 + c1 * v) + phi * c1;
            (prev, dprev) = (next, dnext);
        }
        (s, ds)
    }

    /// `f(v)`: the network inside its [`support`](Self::support), the
    /// [`extrapolated`](Self::extrapolated) trend beyond it.
    pub fn eval(&self, v: f64) -> f64 {
        match self.support {
            Some([lo, hi]) if v > hi || v < lo => self.extrapolated(v, lo, hi),
            _ => self.eval_network(v),
        }
    }

    /// Beyond the training range: `f(e) + s·(v − e)` from the nearer edge
    /// `e`, with `s` the secant slope of the network over the outer tenth of
    /// the range, `s = (f(e) − f(e ∓ r/10)) / (±r/10)`, `r = v_hi − v_lo`.
    /// A local model whose validity region holds no training data has an
    /// arbitrary slope (measured: 19–64 where the data show 0–1 on a
    /// saturating record); the secant is set by values the data support.
    pub fn extrapolated(&self, v: f64, lo: f64, hi: f64) -> f64 {
        let (edge, inner) = if v > hi {
            (hi, hi - 0.1 * (hi - lo))
        } else {
            (lo, lo + 0.1 * (hi - lo))
        };
        let fe = self.eval_network(edge);
        let slope = if edge != inner {
            (fe - self.eval_network(inner)) / (edge - inner)
        } else {
            0.0
        };
        fe + slope * (v - edge)
    }

    /// `f(v)` of the network itself, without the support bound.
    fn eval_network(&self, v: f64) -> f64 {
        let m = self.knots.len();
        let mut prev = 1.0;
        let mut s = 0.0;
        for i in 0..=m {
            let next = if i < m {
                1.0 / (1.0 + (-(v - self.knots[i]) / self.width).exp())
            } else {
                0.0
            };
            let phi = prev - next;
            s += phi * (self.coefficients[2 * i] + self.coefficients[2 * i + 1] * v);
            prev = next;
        }
        s
    }
}

/// A fitted Wiener–Hammerstein local model network (see the module docs).
///
/// ```
/// use gb_lmn::{StaticNetwork, WienerHammersteinNetwork};
/// // G₁ = 0.5/(1 − 0.5 q⁻¹), f = identity (one local model), G₂ = q⁻¹
/// let m = WienerHammersteinNetwork {
///     b1: vec![0.5], a1: vec![1.0, -0.5], b2: vec![0.0, 1.0], a2: vec![1.0],
///     nonlinearity: StaticNetwork { knots: vec![], width: 1.0, coefficients: vec![0.0, 1.0], support: None },
/// };
/// let y = m.simulate(&[1.0, 1.0, 1.0]);
/// assert_eq!(y, vec![0.0, 0.5, 0.75]);
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WienerHammersteinNetwork {
    /// Numerator of G₁ (in q⁻¹).
    pub b1: Vec<f64>,
    /// Denominator of G₁ (`a1[0] = 1`).
    pub a1: Vec<f64>,
    /// Numerator of G₂.
    pub b2: Vec<f64>,
    /// Denominator of G₂ (`a2[0] = 1`).
    pub a2: Vec<f64>,
    /// The static local model network between them.
    pub nonlinearity: StaticNetwork,
}

impl WienerHammersteinNetwork {
    /// Free-run simulation from the zero state.
    pub fn simulate(&self, u: &[f64]) -> Vec<f64> {
        let v = filtered(&self.b1, &self.a1, u);
        let w: Vec<f64> = v.iter().map(|&x| self.nonlinearity.eval(x)).collect();
        filtered(&self.b2, &self.a2, &w)
    }

    /// Free-run simulation from the steady state of the first input
    /// `u(0)` held before the start (both filters at rest at their static
    /// response): a record that starts away from zero does not begin with
    /// the step from zero, which the zero state would add.
    pub fn simulate_from_steady(&self, u: &[f64]) -> Vec<f64> {
        let v = filtered_from_steady(&self.b1, &self.a1, u);
        let w: Vec<f64> = v.iter().map(|&x| self.nonlinearity.eval(x)).collect();
        filtered_from_steady(&self.b2, &self.a2, &w)
    }

    /// The internal signal v = G₁ u.
    pub fn internal_signal(&self, u: &[f64]) -> Vec<f64> {
        filtered(&self.b1, &self.a1, u)
    }

    /// Number of free parameters (the leading coefficient of B₁ is fixed).
    pub fn n_parameters(&self) -> usize {
        self.b1.len() - 1 + self.a1.len() - 1 + self.b2.len() + self.a2.len() - 1
            + self.nonlinearity.coefficients.len()
    }

    /// One-line description.
    pub fn describe(&self) -> String {
        format!(
            "Wiener-Hammerstein local model network: G1 {}/{}, {} local affine models in v = G1 u (sigmoid-chain tree weights), G2 {}/{}, {} parameters",
            self.b1.len() - 1,
            self.a1.len() - 1,
            self.nonlinearity.n_local_models(),
            self.b2.len() - 1,
            self.a2.len() - 1,
            self.n_parameters()
        )
    }

    /// Checks sizes, finiteness and that both filters are stable.
    pub fn check(&self) -> Result<()> {
        let all = self
            .b1
            .iter()
            .chain(&self.a1)
            .chain(&self.b2)
            .chain(&self.a2)
            .chain(&self.nonlinearity.coefficients)
            .chain(&self.nonlinearity.knots);
        if self.b1.is_empty()
            || self.b2.is_empty()
            || self.a1.first() != Some(&1.0)
            || self.a2.first() != Some(&1.0)
            || self.nonlinearity.coefficients.len() != 2 * self.nonlinearity.n_local_models()
            || self.nonlinearity.width.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater)
            || self
                .nonlinearity
                .support
                .is_some_and(|[lo, hi]| !(lo.is_finite() && hi.is_finite() && lo < hi))
        {
            return Err(LmnError::InvalidArgument(
                "inconsistent Wiener-Hammerstein network".into(),
            ));
        }
        for v in all {
            if !v.is_finite() {
                return Err(LmnError::InvalidArgument(
                    "non-finite Wiener-Hammerstein parameter".into(),
                ));
            }
        }
        if max_root_modulus(&self.a1) >= 1.0 || max_root_modulus(&self.a2) >= 1.0 {
            return Err(LmnError::Unstable(
                "a filter has a pole outside the unit circle".into(),
            ));
        }
        Ok(())
    }
}

/// One filter `b/a` in direct form run one sample at a time from the zero
/// state, with the arithmetic of [`filter`] (terms in the same order, none
/// before the first sample).
#[derive(Debug, Clone)]
struct FilterStep<'a> {
    b: &'a [f64],
    a: &'a [f64],
    /// Past inputs and outputs, most recent first.
    x: Vec<f64>,
    y: Vec<f64>,
    k: usize,
}

impl<'a> FilterStep<'a> {
    fn new(b: &'a [f64], a: &'a [f64]) -> Self {
        Self {
            b,
            a,
            x: vec![0.0; b.len()],
            y: vec![0.0; a.len()],
            k: 0,
        }
    }

    fn step(&mut self, xk: f64) -> f64 {
        if !self.x.is_empty() {
            self.x.rotate_right(1);
            self.x[0] = xk;
        }
        let k = self.k;
        let mut acc = 0.0;
        for (j, bj) in self.b.iter().enumerate().take(k + 1) {
            acc += bj * self.x[j];
        }
        for (i, ai) in self.a.iter().enumerate().skip(1).take(k) {
            acc -= ai * self.y[i - 1];
        }
        if !self.y.is_empty() {
            self.y.rotate_right(1);
            self.y[0] = acc;
        }
        self.k += 1;
        acc
    }
}

/// A [`WienerHammersteinNetwork`] running one sample at a time from the
/// zero state: bit-identical to [`WienerHammersteinNetwork::simulate`].
#[derive(Debug, Clone)]
pub(crate) struct WhStepper<'a> {
    m: &'a WienerHammersteinNetwork,
    g1: FilterStep<'a>,
    g2: FilterStep<'a>,
}

impl<'a> WhStepper<'a> {
    pub fn new(m: &'a WienerHammersteinNetwork) -> Self {
        Self {
            m,
            g1: FilterStep::new(&m.b1, &m.a1),
            g2: FilterStep::new(&m.b2, &m.a2),
        }
    }

    /// Advance one sample with the input `u`; the output.
    pub fn step(&mut self, u: f64) -> f64 {
        let v = self.g1.step(u);
        self.g2.step(self.m.nonlinearity.eval(v))
    }
}

/// Options of the Wiener–Hammerstein identification (validated by
/// [`WhParams::check`]). The defaults are generic — what depends on the data
/// is derived from it: the order of the best linear approximation is chosen
/// on the hold-out tail, the transient left out of the costs follows from its
/// slowest pole, the scan uses every sample. Benchmark set-ups (WH2009: a
/// 6/6 BLA, a 200-sample transient, a 30 000-sample scan) belong to the code
/// that runs them.
///
/// | field | default |
/// |---|---|
/// | `bla_orders` | none: n poles and n zeros, n ≤ `max_bla_order`, chosen on the hold-out |
/// | `max_bla_order` | 6 |
/// | `knots` | 15 (16 local models) |
/// | `smoothness` | 0.25 |
/// | `extra_g1` | 3 (1, 2, 3 tried, the hold-out chooses) |
/// | `candidates` | 2 |
/// | `max_iter` | 60 |
/// | `scan_samples` | all |
/// | `holdout` | 0.2 |
/// | `skip` | none: until the BLA start's slowest mode decayed to 10⁻³ |
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WhParams {
    /// Poles and zeros of the best linear approximation (its numerator has
    /// zeros + 1 taps); `None`: n poles and n zeros with n in
    /// 1..=`max_bla_order` chosen by the simulation error on the hold-out.
    pub bla_orders: Option<(usize, usize)>,
    /// Largest BLA order tried when `bla_orders` is `None`.
    pub max_bla_order: usize,
    /// Knots of the static network (local models = knots + 1), spread over
    /// ±2.5 standard deviations of the start's internal signal.
    pub knots: usize,
    /// Sigmoid width as a fraction of the knot spacing.
    pub smoothness: f64,
    /// Most further free poles and zeros given to G₁ before the joint
    /// refinement: 1..=extra_g1 are each tried, and the hold-out error
    /// chooses (0: none).
    pub extra_g1: usize,
    /// Splits refined jointly (the best by the scan).
    pub candidates: usize,
    /// Levenberg–Marquardt iterations of each refinement.
    pub max_iter: usize,
    /// Samples of the training record used by the split scan (at most;
    /// `usize::MAX`: all).
    pub scan_samples: usize,
    /// Fraction of the training record held out to choose among the refined
    /// splits (and the BLA order).
    pub holdout: f64,
    /// Leading samples left out of every cost (transient of the zero state;
    /// at most a quarter of the record); `None`: until the slowest pole of
    /// the BLA's least-squares start has decayed to 10⁻³.
    pub skip: Option<usize>,
}

impl Default for WhParams {
    fn default() -> Self {
        Self {
            bla_orders: None,
            max_bla_order: 6,
            knots: 15,
            smoothness: 0.25,
            extra_g1: 3,
            candidates: 2,
            max_iter: 60,
            scan_samples: usize::MAX,
            holdout: 0.2,
            skip: None,
        }
    }
}

impl WhParams {
    /// The defaults (see the table of [`WhParams`]).
    pub fn new() -> Self {
        Self::default()
    }
    /// Sets the number of knots of the static network.
    pub fn knots(mut self, n: usize) -> Self {
        self.knots = n;
        self
    }
    /// Sets the LM iterations per refinement.
    pub fn max_iter(mut self, n: usize) -> Self {
        self.max_iter = n;
        self
    }
    /// Sets the extra poles/zeros of G₁.
    pub fn extra_g1(mut self, n: usize) -> Self {
        self.extra_g1 = n;
        self
    }
    /// Fixes the BLA orders.
    pub fn bla(mut self, poles: usize, zeros: usize) -> Self {
        self.bla_orders = Some((poles, zeros));
        self
    }
    /// Fixes the transient left out of every cost.
    pub fn skip(mut self, samples: usize) -> Self {
        self.skip = Some(samples);
        self
    }
    /// Sets the most samples of the split scan.
    pub fn scan_samples(mut self, n: usize) -> Self {
        self.scan_samples = n;
        self
    }
    /// Poles plus zeros of the largest BLA fitted.
    fn bla_size(&self) -> usize {
        self.bla_orders
            .map_or(2 * self.max_bla_order, |(p, z)| p + z)
    }
    /// Sets the number of refined splits.
    pub fn candidates(mut self, n: usize) -> Self {
        self.candidates = n;
        self
    }
    /// Validates the options once.
    pub fn check(self) -> Result<WhFitter> {
        let bad = |m: &str| Err(LmnError::InvalidArgument(m.to_string()));
        match self.bla_orders {
            Some((p, z)) if !(1..=12).contains(&p) || z > 12 => {
                return bad("BLA orders must be 1..=12 poles and at most 12 zeros")
            }
            None if !(1..=12).contains(&self.max_bla_order) || self.holdout <= 0.0 => {
                return bad("choosing the BLA order needs max_bla_order in 1..=12 and holdout > 0")
            }
            _ => {}
        }
        if self.knots > 60 || !(self.smoothness > 0.0 && self.smoothness.is_finite()) {
            return bad("knots must be at most 60 and smoothness > 0");
        }
        if self.extra_g1 > 4 || self.candidates == 0 || self.max_iter == 0 {
            return bad("extra_g1 <= 4, candidates >= 1 and max_iter >= 1 are needed");
        }
        if !(0.0..0.5).contains(&self.holdout) || self.scan_samples < 100 {
            return bad("holdout must be in [0, 0.5) and scan_samples >= 100");
        }
        Ok(WhFitter { p: self })
    }
}

/// Validated [`WhParams`].
#[derive(Debug, Clone, PartialEq)]
pub struct WhFitter {
    p: WhParams,
}

impl Identify for WhFitter {
    type Model = WienerHammersteinNetwork;
    type Error = LmnError;
    /// One record with one input (the filters run over one record).
    fn identify(
        &self,
        data: &Records,
        observer: &dyn Observer,
    ) -> Result<WienerHammersteinNetwork> {
        let r = data.first();
        if data.len() != 1 || r.n_inputs() != 1 {
            return Err(LmnError::InvalidArgument(format!(
                "a Wiener-Hammerstein network is fitted on one record with one input, got {} record(s) with {} input(s)",
                data.len(),
                r.n_inputs()
            )));
        }
        self.fit_with_observer(&r.inputs[0], &r.output, observer)
            .map(|(m, _)| m)
    }
}

/// What the identification did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WhReport {
    /// Poles and zeros of the best linear approximation.
    pub bla_orders: (usize, usize),
    /// Hold-out RMSE per BLA order tried (empty when the orders were given).
    pub bla_holdout_rmse: Vec<(usize, f64)>,
    /// Leading samples left out of the costs.
    pub skip: usize,
    /// RMSE of the best linear approximation (training record).
    pub bla_rmse: f64,
    /// Pole/zero splits scored.
    pub splits_tried: usize,
    /// Scan RMSE of the best split (fixed filters, least-squares network).
    pub best_split_rmse: f64,
    /// Held-out RMSE of each refined candidate (split-major, then extra
    /// G₁ order 1, 2, …).
    pub holdout_rmse: Vec<f64>,
    /// Final training RMSE.
    pub rmse: f64,
    /// LM iterations of the final refinement.
    pub iterations: usize,
}

/// Parameter vector layout of a refinement: b1[1..], a1[1..], b2, a2[1..], c.
struct Layout {
    nb1: usize,
    na1: usize,
    nb2: usize,
    na2: usize,
    nc: usize,
}

impl Layout {
    fn of(m: &WienerHammersteinNetwork) -> Self {
        Self {
            nb1: m.b1.len(),
            na1: m.a1.len() - 1,
            nb2: m.b2.len(),
            na2: m.a2.len() - 1,
            nc: m.nonlinearity.coefficients.len(),
        }
    }
    fn n_filter(&self) -> usize {
        self.nb1 - 1 + self.na1 + self.nb2 + self.na2
    }
    fn pack(&self, m: &WienerHammersteinNetwork) -> Vec<f64> {
        let mut p = vec![];
        p.extend_from_slice(&m.b1[1..]);
        p.extend_from_slice(&m.a1[1..]);
        p.extend_from_slice(&m.b2);
        p.extend_from_slice(&m.a2[1..]);
        p.extend_from_slice(&m.nonlinearity.coefficients);
        p
    }
    fn unpack(&self, p: &[f64], m: &mut WienerHammersteinNetwork) {
        let mut i = 0;
        m.b1[1..].copy_from_slice(&p[i..i + self.nb1 - 1]);
        i += self.nb1 - 1;
        m.a1[1..].copy_from_slice(&p[i..i + self.na1]);
        i += self.na1;
        m.b2.copy_from_slice(&p[i..i + self.nb2]);
        i += self.nb2;
        m.a2[1..].copy_from_slice(&p[i..i + self.na2]);
        i += self.na2;
        m.nonlinearity
            .coefficients
            .copy_from_slice(&p[i..i + self.nc]);
    }
}

/// `[min, max]` of a finite, non-empty signal.
fn support_of(v: &[f64]) -> Option<[f64; 2]> {
    let (lo, hi) = gb_core::metrics::min_max(v);
    (lo.is_finite() && hi.is_finite() && hi > lo).then_some([lo, hi])
}

fn rms(e: &[f64]) -> f64 {
    (e.iter().map(|v| v * v).sum::<f64>() / e.len().max(1) as f64).sqrt()
}

/// A network with its score (an RMSE).
type ScoredNetwork = (f64, WienerHammersteinNetwork);

/// RMS of the tail error `sim[n_fit..] − y[n_fit..]`.
fn tail_rms(sim: &[f64], y: &[f64], n_fit: usize) -> f64 {
    rms(&sim[n_fit..]
        .iter()
        .zip(&y[n_fit..])
        .map(|(a, b)| a - b)
        .collect::<Vec<_>>())
}

/// Columns `G₂(ϕₖ(v))` of the model linear in the network coefficients.
fn network_columns(m: &WienerHammersteinNetwork, u: &[f64]) -> Vec<Vec<f64>> {
    let v = filtered(&m.b1, &m.a1, u);
    let nc = m.nonlinearity.coefficients.len();
    let mut cols = vec![vec![0.0; u.len()]; nc];
    let mut phi = vec![0.0; nc];
    for (k, &x) in v.iter().enumerate() {
        m.nonlinearity.basis(x, &mut phi);
        for (c, p) in cols.iter_mut().zip(&phi) {
            c[k] = *p;
        }
    }
    cols.iter().map(|c| filtered(&m.b2, &m.a2, c)).collect()
}

/// `∂ŷ/∂θ` for the free filter coefficients in [`Layout`]'s order
/// (b₁ after its first, a₁, b₂, a₂ after their first), exact, each over
/// the whole record: with `v = (B₁/A₁)u`, `w = f(v)`, `ŷ = (B₂/A₂)w`
/// (zero initial states),
/// `∂v/∂b₁ⱼ = q⁻ʲ(1/A₁)u`, `∂v/∂a₁ⱼ = −q⁻ʲ(1/A₁)v`, `∂ŷ/∂θ₁ = (B₂/A₂)(f′(v)·∂v/∂θ₁)`,
/// `∂ŷ/∂b₂ⱼ = q⁻ʲ(1/A₂)w`, `∂ŷ/∂a₂ⱼ = −q⁻ʲ(1/A₂)ŷ`.
fn filter_columns(m: &WienerHammersteinNetwork, u: &[f64]) -> Vec<Vec<f64>> {
    let n = u.len();
    let v = filtered(&m.b1, &m.a1, u);
    let (w, slope): (Vec<f64>, Vec<f64>) =
        v.iter().map(|&x| m.nonlinearity.eval_with_slope(x)).unzip();
    let yhat = filtered(&m.b2, &m.a2, &w);
    let shifted = |x: &[f64], j: usize, sign: f64| -> Vec<f64> {
        (0..n)
            .map(|k| if k >= j { sign * x[k - j] } else { 0.0 })
            .collect()
    };
    let through_g2 = |dv: Vec<f64>| -> Vec<f64> {
        let dw: Vec<f64> = dv.iter().zip(&slope).map(|(d, s)| d * s).collect();
        filtered(&m.b2, &m.a2, &dw)
    };
    let (u1, v1) = (filtered(&[1.0], &m.a1, u), filtered(&[1.0], &m.a1, &v));
    let (w2, y2) = (filtered(&[1.0], &m.a2, &w), filtered(&[1.0], &m.a2, &yhat));
    let mut cols = Vec::with_capacity(Layout::of(m).n_filter());
    cols.extend((1..m.b1.len()).map(|j| through_g2(shifted(&u1, j, 1.0))));
    cols.extend((1..m.a1.len()).map(|j| through_g2(shifted(&v1, j, -1.0))));
    cols.extend((0..m.b2.len()).map(|j| shifted(&w2, j, 1.0)));
    cols.extend((1..m.a2.len()).map(|j| shifted(&y2, j, -1.0)));
    cols
}

/// Least squares `y ≈ Σ cₖ colₖ` over samples `skip..` (small ridge).
fn solve_columns(cols: &[Vec<f64>], y: &[f64], skip: usize) -> Option<Vec<f64>> {
    let p = cols.len();
    let mut g = DMatrix::<f64>::zeros(p, p);
    let mut r = DVector::<f64>::zeros(p);
    for i in 0..p {
        for j in 0..=i {
            let s: f64 = cols[i][skip..]
                .iter()
                .zip(&cols[j][skip..])
                .map(|(a, b)| a * b)
                .sum();
            g[(i, j)] = s;
            g[(j, i)] = s;
        }
        r[i] = cols[i][skip..]
            .iter()
            .zip(&y[skip..])
            .map(|(a, b)| a * b)
            .sum();
    }
    let tr = (0..p).map(|i| g[(i, i)]).sum::<f64>() / p.max(1) as f64;
    for i in 0..p {
        g[(i, i)] += 1e-9 * tr.max(1e-300);
    }
    g.cholesky().map(|c| c.solve(&r).iter().copied().collect())
}

impl WhFitter {
    /// The options.
    pub fn params(&self) -> &WhParams {
        &self.p
    }

    /// Identify the network from input `u` and output `y`.
    pub fn fit(&self, u: &[f64], y: &[f64]) -> Result<(WienerHammersteinNetwork, WhReport)> {
        self.fit_with_observer(u, y, &Silent)
    }

    /// [`fit`](Self::fit), reporting progress (the BLA, the split scan, each
    /// refinement) and every Levenberg–Marquardt iteration to `observer`.
    pub fn fit_with_observer(
        &self,
        u: &[f64],
        y: &[f64],
        observer: &dyn Observer,
    ) -> Result<(WienerHammersteinNetwork, WhReport)> {
        let p = &self.p;
        self.check_record(u, y)?;
        let n = u.len();
        let n_fit = n - (p.holdout * n as f64) as usize;
        let extras: Vec<usize> = if p.extra_g1 == 0 {
            vec![0]
        } else {
            (1..=p.extra_g1).collect()
        };
        let total = 3 + p.candidates * extras.len();
        // 1. best linear approximation (its order chosen on the hold-out)
        observer.progress(0, total, "Wiener-Hammerstein: best linear approximation");
        let (orders, bla_holdout_rmse) = match p.bla_orders {
            Some(o) => (o, vec![]),
            None => self.bla_orders_on_holdout(u, y, n_fit),
        };
        let (bb, ab, bla_rmse, skip) = self.bla(u, y, orders, observer)?;
        // 2. split scan
        observer.progress(1, total, "Wiener-Hammerstein: pole/zero split scan");
        let ns = p.scan_samples.min(n);
        let (scored, tried) = self.scan_splits(&bb, &ab, &u[..ns], &y[..ns], skip);
        let best_split_rmse = scored.first().map_or(f64::INFINITY, |s| s.0);
        if scored.is_empty() {
            return Err(LmnError::Unstable(
                "no pole/zero split gave a finite model".into(),
            ));
        }
        // 3. refine the best splits with extra G₁ freedom; choose on the hold-out tail
        let starts: Vec<WienerHammersteinNetwork> =
            scored.into_iter().take(p.candidates).map(|s| s.1).collect();
        let (mut refined, holdout_rmse) =
            self.refine_starts(&starts, &extras, u, y, n_fit, skip, total, observer)?;
        refined.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (_, m) = refined.swap_remove(0);
        observer.progress(
            total - 1,
            total,
            "Wiener-Hammerstein: final Levenberg-Marquardt",
        );
        let (mut m, rmse, iterations) =
            self.refine(m, u, y, p.max_iter.div_ceil(3), skip, observer)?;
        m.check()?;
        m.nonlinearity.support = support_of(&filtered(&m.b1, &m.a1, u));
        observer.progress(total, total, "Wiener-Hammerstein network fitted");
        Ok((
            m,
            WhReport {
                bla_orders: orders,
                bla_holdout_rmse,
                skip,
                bla_rmse,
                splits_tried: tried,
                best_split_rmse,
                holdout_rmse,
                rmse,
                iterations,
            },
        ))
    }

    /// `m` refined on `u`, `y` with its structure kept (the orders and
    /// pole/zero split of its filters, its local models): Levenberg–Marquardt
    /// on the simulation error from `m`'s parameters, the transient skipped
    /// as given ([`WhParams::skip`]) or until the slower filter's slowest
    /// mode and then the other's decayed to 10⁻³. A fit of the same network
    /// on other data of the same system (a fold of a cross-validation, a
    /// longer record) that need not scan the splits again. Returns the
    /// network, its RMSE after the transient and the iterations.
    pub fn refit_from(
        &self,
        m: &WienerHammersteinNetwork,
        u: &[f64],
        y: &[f64],
    ) -> Result<(WienerHammersteinNetwork, f64, usize)> {
        self.check_record(u, y)?;
        m.check()?;
        let skip = self
            .p
            .skip
            .unwrap_or_else(|| settling_samples(&m.a1) + settling_samples(&m.a2));
        let (mut r, rmse, iterations) =
            self.refine(m.clone(), u, y, self.p.max_iter, skip, &Silent)?;
        r.check()?;
        r.nonlinearity.support = support_of(&filtered(&r.b1, &r.a1, u));
        Ok((r, rmse, iterations))
    }

    /// Check the record: equal lengths, at least
    /// max(500, 20·(BLA size + 2·knots + 8) + skip) samples, all finite.
    fn check_record(&self, u: &[f64], y: &[f64]) -> Result<()> {
        let p = &self.p;
        let n = u.len();
        if y.len() != n {
            return Err(LmnError::Dimension(format!(
                "input has {n} samples, output {}",
                y.len()
            )));
        }
        let needed = 20 * (p.bla_size() + 2 * p.knots + 8) + p.skip.unwrap_or(0);
        if n < needed.max(500) {
            return Err(LmnError::TooShort {
                needed: needed.max(500),
                got: n,
            });
        }
        if !u.iter().chain(y).all(|v| v.is_finite()) {
            return Err(LmnError::InvalidArgument("non-finite samples".into()));
        }
        Ok(())
    }

    /// The BLA order k (k poles, k zeros), k = 1..=max, with the smallest
    /// free-run RMSE on the hold-out tail `n_fit..` of a fit on `..n_fit`;
    /// with the hold-out RMSE of every order that could be fitted.
    fn bla_orders_on_holdout(
        &self,
        u: &[f64],
        y: &[f64],
        n_fit: usize,
    ) -> ((usize, usize), Vec<(usize, f64)>) {
        // the orders are independent fits: in parallel, kept in order
        let bla_holdout_rmse: Vec<(usize, f64)> = (1..=self.p.max_bla_order)
            .into_par_iter()
            .filter_map(|k| {
                let (b, a, _, _) = self.bla(&u[..n_fit], &y[..n_fit], (k, k), &Silent).ok()?;
                Some((k, tail_rms(&filtered(&b, &a, u), y, n_fit)))
            })
            .collect();
        let mut best = (1, f64::INFINITY);
        for &(k, e) in &bla_holdout_rmse {
            if e < best.1 {
                best = (k, e);
            }
        }
        ((best.0, best.0), bla_holdout_rmse)
    }

    /// Score every split of the BLA's pole groups (roots of `ab`) and zero
    /// groups (roots of `bb`) between G₁ and G₂ (G₁ with unit static gain,
    /// the rest of the gain in G₂) by the RMSE of its least-squares start
    /// network on `(us, ys)`. Returns the scored networks, best first, and
    /// the number of splits tried.
    fn scan_splits(
        &self,
        bb: &[f64],
        ab: &[f64],
        us: &[f64],
        ys: &[f64],
        skip: usize,
    ) -> (Vec<ScoredNetwork>, usize) {
        let pg = root_groups(&roots(ab));
        let zg = root_groups(&roots(bb));
        let lead = bb.iter().copied().find(|v| *v != 0.0).unwrap_or(1.0);
        let pick = |g: &[Vec<Complex<f64>>], mask: u32, inside: bool| {
            g.iter()
                .enumerate()
                .filter(|(i, _)| ((mask >> i) & 1 == 1) == inside)
                .flat_map(|(_, r)| r.iter().copied())
                .collect::<Vec<_>>()
        };
        // the splits with a usable G₁ (unit static gain, the rest of the
        // gain in G₂), in scan order
        let splits: Vec<[Vec<f64>; 4]> = (0u32..(1 << pg.len()))
            .flat_map(|pm| (0u32..(1 << zg.len())).map(move |zm| (pm, zm)))
            .filter_map(|(pm, zm)| {
                let a1 = poly_from_roots(&pick(&pg, pm, true));
                let a2 = poly_from_roots(&pick(&pg, pm, false));
                let mut b1 = poly_from_roots(&pick(&zg, zm, true));
                let mut b2 = poly_from_roots(&pick(&zg, zm, false));
                let g1 = b1.iter().sum::<f64>() / a1.iter().sum::<f64>();
                if !(g1.is_finite() && g1.abs() > 1e-12) {
                    return None;
                }
                b1.iter_mut().for_each(|v| *v /= g1);
                b2.iter_mut().for_each(|v| *v *= g1 * lead);
                Some([b1, a1, b2, a2])
            })
            .collect();
        let tried = splits.len();
        // each start is an independent least-squares fit: in parallel, kept
        // in scan order (the stable sort then breaks ties as the scan did)
        let mut scored: Vec<ScoredNetwork> = splits
            .into_par_iter()
            .filter_map(|[b1, a1, b2, a2]| self.start_network(b1, a1, b2, a2, us, ys, skip))
            .collect();
        scored.sort_by(|a, b| a.0.total_cmp(&b.0));
        (scored, tried)
    }

    /// Refine every start network with each extra G₁ order (zero
    /// coefficients appended to b₁ and a₁) by LM on `..n_fit`, in two
    /// rounds (successive halving): every one for a third of `max_iter`
    /// iterations, then the `candidates` best by the hold-out error (by the
    /// fit error without a hold-out) for the rest. Returns the refined
    /// networks with their hold-out RMSE (0 without a hold-out), and those
    /// RMSEs in order (start-major).
    #[allow(clippy::too_many_arguments)]
    fn refine_starts(
        &self,
        starts: &[WienerHammersteinNetwork],
        extras: &[usize],
        u: &[f64],
        y: &[f64],
        n_fit: usize,
        skip: usize,
        total: usize,
        observer: &dyn Observer,
    ) -> Result<(Vec<ScoredNetwork>, Vec<f64>)> {
        let n = u.len();
        let holdout = |m: &WienerHammersteinNetwork| {
            if n_fit < n {
                tail_rms(&m.simulate(u), y, n_fit)
            } else {
                0.0
            }
        };
        let first = self.p.max_iter.div_ceil(3);
        // (hold-out RMSE, fit RMSE, network) after the first round; every
        // refinement is independent: in parallel, kept in start-major order
        let jobs: Vec<(&WienerHammersteinNetwork, usize)> = starts
            .iter()
            .flat_map(|m0| extras.iter().map(move |&extra| (m0, extra)))
            .collect();
        let mut round: Vec<(f64, f64, WienerHammersteinNetwork)> = jobs
            .into_par_iter()
            .enumerate()
            .map(|(i, (m0, extra))| {
                observer.progress(
                    2 + i,
                    total,
                    "Wiener-Hammerstein: joint Levenberg-Marquardt of a split",
                );
                let mut m = m0.clone();
                m.b1.extend(std::iter::repeat_n(0.0, extra));
                m.a1.extend(std::iter::repeat_n(0.0, extra));
                let (m, fit, _) =
                    self.refine(m, &u[..n_fit], &y[..n_fit], first, skip, observer)?;
                Ok((holdout(&m), fit, m))
            })
            .collect::<Result<_>>()?;
        let score = |r: &(f64, f64, WienerHammersteinNetwork)| if n_fit < n { r.0 } else { r.1 };
        let mut order: Vec<usize> = (0..round.len()).collect();
        order.sort_by(|&a, &b| score(&round[a]).total_cmp(&score(&round[b])));
        let rest = self.p.max_iter.saturating_sub(first);
        if rest > 0 {
            let best: Vec<usize> = order.into_iter().take(self.p.candidates).collect();
            let second: Vec<(usize, (f64, f64, WienerHammersteinNetwork))> = best
                .into_par_iter()
                .map(|i| {
                    let m = round[i].2.clone();
                    let (m, fit, _) =
                        self.refine(m, &u[..n_fit], &y[..n_fit], rest, skip, observer)?;
                    Ok((i, (holdout(&m), fit, m)))
                })
                .collect::<Result<_>>()?;
            for (i, r) in second {
                round[i] = r;
            }
        }
        let holdout_rmse = round.iter().map(|r| r.0).collect();
        let refined = round
            .into_iter()
            .map(|(e, fit, m)| (if n_fit < n { e } else { fit }, m))
            .collect();
        Ok((refined, holdout_rmse))
    }

    /// OE best linear approximation with `(poles, zeros)`: ARX start, then
    /// LM on the simulation error. Returns (b, a, RMSE, the transient left
    /// out of the costs).
    fn bla(
        &self,
        u: &[f64],
        y: &[f64],
        (poles, zeros): (usize, usize),
        observer: &dyn Observer,
    ) -> Result<(Vec<f64>, Vec<f64>, f64, usize)> {
        let (na, nb) = (poles, zeros + 1);
        let n0 = na.max(nb);
        let n = u.len();
        let q = na + nb;
        let mut g = DMatrix::<f64>::zeros(q, q);
        let mut r = DVector::<f64>::zeros(q);
        let mut row = vec![0.0; q];
        for k in n0..n {
            for i in 0..na {
                row[i] = -y[k - 1 - i];
            }
            for j in 0..nb {
                row[na + j] = u[k - j];
            }
            for i in 0..q {
                r[i] += row[i] * y[k];
                for j in 0..=i {
                    g[(i, j)] += row[i] * row[j];
                }
            }
        }
        for i in 0..q {
            for j in 0..i {
                g[(j, i)] = g[(i, j)];
            }
            g[(i, i)] += 1e-12 * (1.0 + g[(i, i)]);
        }
        let th = g
            .cholesky()
            .ok_or_else(|| LmnError::Numerical("ARX normal equations".into()))?
            .solve(&r);
        let mut a = vec![1.0];
        a.extend(th.iter().take(na));
        let mut b: Vec<f64> = th.iter().skip(na).copied().collect();
        if max_root_modulus(&a) >= 0.999 {
            // an unstable ARX start: shrink the poles
            let r0: Vec<Complex<f64>> = roots(&a)
                .iter()
                .map(|z| z * (0.95 / z.norm().max(0.95)))
                .collect();
            a = poly_from_roots(&r0);
        }
        // OE LM over (b, a[1..]) with a finite-difference Jacobian; the
        // transient: given, or until the start's slowest mode decayed to 1e-3
        let skip = self
            .p
            .skip
            .unwrap_or_else(|| settling_samples(&a).max(n0))
            .min(n / 4);
        let resid = |p: &[f64]| -> Option<Vec<f64>> {
            let b = &p[..nb];
            let mut a = vec![1.0];
            a.extend_from_slice(&p[nb..]);
            if max_root_modulus(&a) >= 0.999 {
                return None;
            }
            let s = filtered(b, &a, u);
            Some(
                y[skip..]
                    .iter()
                    .zip(&s[skip..])
                    .map(|(y, s)| y - s)
                    .collect(),
            )
        };
        let mut p0 = b.clone();
        p0.extend_from_slice(&a[1..]);
        let (p, e) = lm_fd(&p0, &resid, 60, observer)?;
        b = p[..nb].to_vec();
        a = vec![1.0];
        a.extend_from_slice(&p[nb..]);
        Ok((b, a, e, skip))
    }

    /// The network for fixed filters, coefficients by least squares; returns
    /// the scan RMSE.
    #[allow(clippy::too_many_arguments)]
    fn start_network(
        &self,
        b1: Vec<f64>,
        a1: Vec<f64>,
        b2: Vec<f64>,
        a2: Vec<f64>,
        u: &[f64],
        y: &[f64],
        skip: usize,
    ) -> Option<(f64, WienerHammersteinNetwork)> {
        let v = filtered(&b1, &a1, u);
        if !v.iter().all(|x| x.is_finite()) {
            return None;
        }
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
        if sd.is_nan() || sd <= 0.0 {
            return None;
        }
        let k = self.p.knots;
        let knots: Vec<f64> = (0..k)
            .map(|i| mean + sd * (-2.5 + 5.0 * (i as f64 + 0.5) / k as f64))
            .collect();
        let spacing = if k > 0 { 5.0 * sd / k as f64 } else { sd };
        let mut m = WienerHammersteinNetwork {
            b1,
            a1,
            b2,
            a2,
            nonlinearity: StaticNetwork {
                knots,
                width: self.p.smoothness * spacing,
                coefficients: vec![0.0; 2 * (k + 1)],
                support: None,
            },
        };
        let cols = network_columns(&m, u);
        let skip = skip.min(u.len() / 4);
        let c = solve_columns(&cols, y, skip)?;
        let e: Vec<f64> = (skip..u.len())
            .map(|t| y[t] - cols.iter().zip(&c).map(|(col, c)| col[t] * c).sum::<f64>())
            .collect();
        m.nonlinearity.coefficients = c;
        let r = rms(&e);
        r.is_finite().then_some((r, m))
    }

    /// Joint LM over filter coefficients and network
    /// coefficients (exact columns); see [`JointProblem`] and [`wh_solver`].
    fn refine(
        &self,
        m: WienerHammersteinNetwork,
        u: &[f64],
        y: &[f64],
        iters: usize,
        skip: usize,
        observer: &dyn Observer,
    ) -> Result<(WienerHammersteinNetwork, f64, usize)> {
        let lay = Layout::of(&m);
        let skip = skip.min(u.len() / 4);
        let nf = lay.n_filter();
        let np = nf + lay.nc;
        let ns = u.len() - skip;
        let p0 = lay.pack(&m);
        let mut problem = JointProblem {
            lay,
            model: m,
            u,
            y,
            skip,
            p: vec![],
            e: vec![],
            jac: DMatrix::<f64>::zeros(ns, np),
        };
        let Ok(state) = wh_solver(iters, 1e-7).minimize(&mut problem, &p0, observer) else {
            // the start's simulation error is not finite: nothing to refine
            let mut m = problem.model;
            problem.lay.unpack(&p0, &mut m);
            let c = problem.e.iter().map(|v| v * v).sum::<f64>();
            return Ok((m, (c / ns as f64).sqrt(), 0));
        };
        let mut m = problem.model;
        problem.lay.unpack(&state.theta, &mut m);
        Ok((m, (state.cost / ns as f64).sqrt(), state.iterations))
    }
}

/// The joint refinement as a least-squares problem: θ = the packed filter
/// and network coefficients ([`Layout`]); residuals y − ŷ after `skip`
/// samples; Jacobian columns exact, of the filter coefficients by
/// [`filter_columns`] (until 2026-11-27 forward differences, one
/// simulation per coefficient), of the network coefficients G₂ of the
/// basis functions; trial points with a pole at |z| ≥ 0.999 are
/// inadmissible.
struct JointProblem<'a> {
    lay: Layout,
    /// Scratch model, its coefficients set to the point evaluated last.
    model: WienerHammersteinNetwork,
    u: &'a [f64],
    y: &'a [f64],
    skip: usize,
    /// The last point evaluated and its residuals (the accepted point is
    /// linearised next).
    p: Vec<f64>,
    e: Vec<f64>,
    jac: DMatrix<f64>,
}

impl JointProblem<'_> {
    fn residuals(&self, m: &WienerHammersteinNetwork) -> Vec<f64> {
        let s = m.simulate(self.u);
        self.y[self.skip..]
            .iter()
            .zip(&s[self.skip..])
            .map(|(y, s)| y - s)
            .collect()
    }
    fn eval(&mut self, p: &[f64]) -> f64 {
        self.lay.unpack(p, &mut self.model);
        self.e = self.residuals(&self.model);
        self.p = p.to_vec();
        self.e.iter().map(|v| v * v).sum::<f64>()
    }
}

impl LeastSquaresProblem for JointProblem<'_> {
    fn n_params(&self) -> usize {
        self.lay.n_filter() + self.lay.nc
    }
    fn cost(&mut self, p: &[f64]) -> Option<f64> {
        Some(self.eval(p))
    }
    fn linearize(&mut self, p: &[f64], gram: &mut [f64], grad: &mut [f64]) -> Option<f64> {
        let cost = if self.p.as_slice() == p {
            self.e.iter().map(|v| v * v).sum::<f64>()
        } else {
            self.eval(p)
        };
        let (nf, skip) = (self.lay.n_filter(), self.skip);
        let ns = self.e.len();
        for (j, c) in filter_columns(&self.model, self.u).iter().enumerate() {
            for t in 0..ns {
                self.jac[(t, j)] = c[skip + t];
            }
        }
        let cols = network_columns(&self.model, self.u);
        for (k, c) in cols.iter().enumerate() {
            for t in 0..ns {
                self.jac[(t, nf + k)] = c[skip + t];
            }
        }
        normal_equations(&self.jac, &self.e, gram, grad);
        Some(cost)
    }
    fn admissible(&mut self, p: &[f64]) -> bool {
        let mut m = self.model.clone();
        self.lay.unpack(p, &mut m);
        max_root_modulus(&m.a1) < 0.999 && max_root_modulus(&m.a2) < 0.999
    }
}

/// The Levenberg–Marquardt settings of the Wiener–Hammerstein fits: λ from
/// 1e-3, ×10 after a rejected step, ×0.3 after an accepted one (floor
/// 1e-10), damping λ·(Gᵢᵢ + 1e-12), 10 trials; an accepted step that lowers
/// the cost by at most `tol` (relative) ends the run.
fn wh_solver(iters: usize, tol: f64) -> LevenbergMarquardt {
    LmParams {
        max_iter: iters,
        // the run ends when the decrease is ≤ tol: the solver stops below
        // its tolerance, so take the next number above tol
        tol: f64::from_bits(tol.to_bits() + 1),
        lambda_init: 1e-3,
        lambda_up: 10.0,
        lambda_up_singular: 10.0,
        lambda_down: 0.3,
        lambda_min: 1e-10,
        lambda_max: 1e300,
        max_trials: 10,
        diag_floor: 0.0,
        diag_floor_abs: 0.0,
        diag_add: 1e-12,
        jitter: 0.0,
        jitter_abs: 0.0,
        stall_window: 0,
        stall_tol: 0.0,
        ..LmParams::default()
    }
    .check()
    .expect("valid Wiener-Hammerstein solver settings")
}

/// A residual function `e(p) = y − ŷ` (`None` for an inadmissible, unstable
/// parameter vector) with a forward-difference Jacobian (step
/// 1e-7·(1 + |pⱼ|)); a point whose differences cannot be evaluated ends the
/// run.
struct ResidualProblem<'a> {
    resid: &'a dyn Fn(&[f64]) -> Option<Vec<f64>>,
    np: usize,
    /// The last point evaluated and its residuals.
    p: Vec<f64>,
    e: Option<Vec<f64>>,
    /// Number of residuals (0 until one point was evaluated).
    n_res: usize,
    jac: DMatrix<f64>,
}

impl LeastSquaresProblem for ResidualProblem<'_> {
    fn n_params(&self) -> usize {
        self.np
    }
    fn cost(&mut self, p: &[f64]) -> Option<f64> {
        self.p = p.to_vec();
        self.e = (self.resid)(p);
        let e = self.e.as_ref()?;
        self.n_res = e.len();
        Some(e.iter().map(|v| v * v).sum::<f64>())
    }
    fn linearize(&mut self, p: &[f64], gram: &mut [f64], grad: &mut [f64]) -> Option<f64> {
        if !(self.e.is_some() && self.p.as_slice() == p) {
            self.cost(p)?;
        }
        let e = self.e.as_ref()?;
        let n = e.len();
        if self.jac.nrows() != n {
            self.jac = DMatrix::zeros(n, self.np);
        }
        for j in 0..self.np {
            let h = 1e-7 * (1.0 + p[j].abs());
            let mut pj = p.to_vec();
            pj[j] += h;
            let ej = (self.resid)(&pj)?;
            for t in 0..n {
                // ŷ = y − e
                self.jac[(t, j)] = (e[t] - ej[t]) / h;
            }
        }
        normal_equations(&self.jac, e, gram, grad);
        Some(e.iter().map(|v| v * v).sum::<f64>())
    }
}

/// `JᵀJ` (row-major into `gram`) and `Jᵀe` of a column-major `J` (rows =
/// samples): one blocked matrix product instead of a dot product per
/// entry.
fn normal_equations(jac: &DMatrix<f64>, e: &[f64], gram: &mut [f64], grad: &mut [f64]) {
    let (ns, np) = jac.shape();
    assert!(gram.len() == np * np && grad.len() == np && e.len() == ns);
    let a = jac.as_slice();
    // SAFETY: A = Jᵀ is np × ns with strides (ns, 1) and B = J is ns × np
    // with strides (1, ns), both inside J's ns·np column-major storage; C
    // is np × np with strides (np, 1) inside `gram`, which aliases neither.
    unsafe {
        matrixmultiply::dgemm(
            np,
            ns,
            np,
            1.0,
            a.as_ptr(),
            ns as isize,
            1,
            a.as_ptr(),
            1,
            ns as isize,
            0.0,
            gram.as_mut_ptr(),
            np as isize,
            1,
        );
    }
    for (j, g) in grad.iter_mut().enumerate() {
        *g = a[j * ns..(j + 1) * ns]
            .iter()
            .zip(e)
            .map(|(x, y)| x * y)
            .sum();
    }
}

/// Levenberg–Marquardt with a forward-difference Jacobian ([`wh_solver`],
/// tolerance 1e-9); `resid` returns `None` for an inadmissible (unstable)
/// parameter vector. Returns the parameters and the RMS residual.
fn lm_fd(
    p0: &[f64],
    resid: &dyn Fn(&[f64]) -> Option<Vec<f64>>,
    iters: usize,
    observer: &dyn Observer,
) -> Result<(Vec<f64>, f64)> {
    let mut problem = ResidualProblem {
        resid,
        np: p0.len(),
        p: vec![],
        e: None,
        n_res: 0,
        jac: DMatrix::zeros(0, 0),
    };
    let state = wh_solver(iters, 1e-9)
        .minimize(&mut problem, p0, observer)
        .map_err(|_| LmnError::Unstable("unstable linear start".into()))?;
    Ok((state.theta, (state.cost / problem.n_res as f64).sqrt()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn the_filter_columns_are_the_derivatives_of_the_simulation() {
        // G1 2/2, a network of 4 local models, G2 1/2: every column against
        // central differences of the simulation
        let mut m = WienerHammersteinNetwork {
            b1: vec![0.4, 0.2, -0.1],
            a1: vec![1.0, -0.9, 0.3],
            b2: vec![0.2, 0.5],
            a2: vec![1.0, -0.6, 0.25],
            nonlinearity: StaticNetwork {
                knots: vec![-0.5, 0.2, 0.9],
                width: 0.3,
                coefficients: vec![0.1, 0.8, -0.2, 1.5, 0.3, -0.4, 0.0, 2.0],
                support: None,
            },
        };
        let u: Vec<f64> = (0..300)
            .map(|k| (k as f64 * 0.21).sin() + 0.5 * (k as f64 * 0.057).cos())
            .collect();
        let lay = Layout::of(&m);
        let cols = filter_columns(&m, &u);
        assert_eq!(cols.len(), lay.n_filter());
        let p0 = lay.pack(&m);
        for (j, col) in cols.iter().enumerate() {
            let h = 1e-6;
            let mut at = |d: f64| {
                let mut p = p0.clone();
                p[j] += d;
                lay.unpack(&p, &mut m);
                m.simulate(&u)
            };
            let (hi, lo) = (at(h), at(-h));
            let scale = col.iter().fold(1e-3, |a: f64, v| a.max(v.abs()));
            for k in 0..u.len() {
                let fd = (hi[k] - lo[k]) / (2.0 * h);
                assert!(
                    (fd - col[k]).abs() <= 1e-6 * scale,
                    "column {j} sample {k}: {} vs {fd}",
                    col[k]
                );
            }
        }
    }

    #[test]
    fn the_steady_start_is_the_zero_start_after_a_long_constant_prefix() {
        // a stable G(z) with a zero: the steady start equals the zero-state
        // response to the record preceded by 400 samples of x(0)
        let (b, a) = (vec![0.3, -0.25, 0.1], vec![1.0, -1.2, 0.5]);
        let x: Vec<f64> = (0..60)
            .map(|k| 3.0 + ((k * 37) % 11) as f64 * 0.1)
            .collect();
        let mut long = vec![x[0]; 400];
        long.extend_from_slice(&x);
        let reference = filtered(&b, &a, &long);
        let steady = filtered_from_steady(&b, &a, &x);
        for (k, v) in steady.iter().enumerate() {
            assert!((v - reference[400 + k]).abs() < 1e-9, "{k}: {v}");
        }
        // a constant record stays at its static response G(1)·x0 = 0.15/0.3·3
        let c = filtered_from_steady(&b, &a, &[3.0; 5]);
        assert!(c.iter().all(|v| (v - 1.5).abs() < 1e-12), "{c:?}");
        // a pole at 1 (no static gain): the zero start
        assert_eq!(
            filtered_from_steady(&[1.0], &[1.0, -1.0], &[1.0, 1.0]),
            filtered(&[1.0], &[1.0, -1.0], &[1.0, 1.0])
        );
    }

    #[test]
    fn filter_matches_the_difference_equation_and_roots_round_trip() {
        let (b, a) = (vec![0.5, 0.2], vec![1.0, -0.6, 0.08]);
        let x: Vec<f64> = (0..50).map(|k| ((k * 37) % 11) as f64 - 5.0).collect();
        let y = filtered(&b, &a, &x);
        for k in 2..50 {
            let r = 0.5 * x[k] + 0.2 * x[k - 1] + 0.6 * y[k - 1] - 0.08 * y[k - 2];
            assert!((y[k] - r).abs() < 1e-12);
        }
        // (z − 0.2)(z − 0.4) and a complex pair
        let mut r = roots(&a);
        r.sort_by(|p, q| p.re.total_cmp(&q.re));
        assert!((r[0].re - 0.2).abs() < 1e-12 && (r[1].re - 0.4).abs() < 1e-12);
        let c = vec![1.0, -1.2, 0.85, -0.1];
        let back = poly_from_roots(&roots(&c));
        for (p, q) in back.iter().zip(&c) {
            assert!((p - q).abs() < 1e-10, "{back:?}");
        }
        assert_eq!(root_groups(&roots(&c)).len(), 2);
    }

    #[test]
    fn tree_weights_are_a_partition_of_unity() {
        let f = StaticNetwork {
            knots: vec![-1.0, 0.0, 0.7],
            width: 0.2,
            coefficients: vec![0.0; 8],
            support: None,
        };
        let mut out = vec![0.0; 8];
        for i in 0..200 {
            let v = -3.0 + 0.03 * i as f64;
            f.basis(v, &mut out);
            let s: f64 = out.iter().step_by(2).sum();
            assert!((s - 1.0).abs() < 1e-12 && out.iter().step_by(2).all(|p| *p >= -1e-15));
        }
    }

    /// A generated Wiener–Hammerstein system (2nd-order G₁, saturation-like
    /// f, 2nd-order G₂): the identified network simulates fresh data far
    /// better than the best linear approximation, near the noise.
    #[test]
    fn recovers_a_generated_wiener_hammerstein_system() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(7);
        let n = 12_000;
        let u: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let truth = |u: &[f64]| {
            let v = filtered(&[0.3, 0.2], &[1.0, -0.9, 0.4], u);
            let w: Vec<f64> = v.iter().map(|x| (1.5 * x).tanh() + 0.2 * x).collect();
            filtered(&[0.0, 0.4, -0.1], &[1.0, -1.3, 0.55], &w)
        };
        let y0 = truth(&u);
        let sd = 0.01;
        let y: Vec<f64> = y0
            .iter()
            .map(|v| v + sd * rng.random_range(-1.7..1.7))
            .collect();
        let (m, rep) = WhParams::new()
            .bla(4, 4)
            .skip(200)
            .knots(9)
            .extra_g1(0)
            .max_iter(40)
            .check()
            .unwrap()
            .fit(&u, &y)
            .unwrap();
        let ut: Vec<f64> = (0..4000).map(|_| rng.random_range(-1.0..1.0)).collect();
        let yt = truth(&ut);
        let sim = m.simulate(&ut);
        let e = rms(&sim[200..]
            .iter()
            .zip(&yt[200..])
            .map(|(a, b)| a - b)
            .collect::<Vec<_>>());
        eprintln!("test rmse {e}, BLA {}, report {rep:?}", rep.bla_rmse);
        assert!(
            e < 0.3 * rep.bla_rmse && e < 0.01,
            "test rmse {e}, BLA {}",
            rep.bla_rmse
        );
        // serialise and reload (the support travels with the network)
        use gb_core::DynamicModel;
        assert!(m.nonlinearity.support.is_some());
        let back =
            WienerHammersteinNetwork::decode(&m.encode().unwrap(), m.class_version()).unwrap();
        assert_eq!(back, m);
        assert!(back.check().is_ok());
    }

    /// A network fitted on one record, refined on another record of the
    /// same system (`refit_from`): the structure kept, the error on the
    /// new record no larger than the start's there and within 10 % of a
    /// full fit on it, and both simulate a fresh input alike.
    #[test]
    fn a_refit_from_a_fitted_network_keeps_its_structure_and_reaches_a_full_fit() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(5);
        let truth = |u: &[f64]| {
            let v = filtered(&[0.3, 0.2], &[1.0, -0.9, 0.4], u);
            let w: Vec<f64> = v.iter().map(|x| (1.5 * x).tanh() + 0.2 * x).collect();
            filtered(&[0.0, 0.4, -0.1], &[1.0, -1.3, 0.55], &w)
        };
        let mut record = |n: usize, sd: f64| {
            let u: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
            let y: Vec<f64> = truth(&u)
                .iter()
                .map(|v| v + sd * rng.random_range(-1.7..1.7))
                .collect();
            (u, y)
        };
        let (u1, y1) = record(5000, 0.01);
        let (u2, y2) = record(5000, 0.01);
        let (ut, _) = record(3000, 0.0);
        let yt = truth(&ut);
        let fitter = WhParams::new()
            .bla(4, 4)
            .skip(200)
            .knots(7)
            .extra_g1(0)
            .max_iter(40)
            .check()
            .unwrap();
        let (start, _) = fitter.fit(&u1, &y1).unwrap();
        let (full, rep) = fitter.fit(&u2, &y2).unwrap();
        let (refit, rmse, _) = fitter.refit_from(&start, &u2, &y2).unwrap();
        let shape = |m: &WienerHammersteinNetwork| {
            (
                m.b1.len(),
                m.a1.len(),
                m.b2.len(),
                m.a2.len(),
                m.nonlinearity.n_local_models(),
            )
        };
        assert_eq!(shape(&refit), shape(&start));
        let on = |m: &WienerHammersteinNetwork, u: &[f64], y: &[f64]| {
            let s = m.simulate(u);
            rms(&s[200..]
                .iter()
                .zip(&y[200..])
                .map(|(a, b)| a - b)
                .collect::<Vec<_>>())
        };
        assert!(on(&refit, &u2, &y2) <= on(&start, &u2, &y2) * (1.0 + 1e-9));
        assert!(
            rmse <= 1.1 * rep.rmse,
            "refit {rmse}, full fit {}",
            rep.rmse
        );
        let (e_refit, e_full) = (on(&refit, &ut, &yt), on(&full, &ut, &yt));
        assert!(
            e_refit <= 1.1 * e_full + 1e-4,
            "fresh input: refit {e_refit}, full {e_full}"
        );
    }

    /// A hard saturation (`f(v) = clamp(v, ±0.4)`) fitted on inputs in
    /// [−1, 1], simulated on inputs in [−1.5, 1.5]: beyond the training range
    /// of `v` the network follows the flat outer trend, where its outermost
    /// local models (no data in their validity regions) would not.
    #[test]
    fn beyond_the_training_range_the_network_follows_the_outer_trend() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(11);
        let truth = |u: &[f64]| {
            let v = filtered(&[0.3, 0.2], &[1.0, -0.9, 0.4], u);
            let w: Vec<f64> = v.iter().map(|x| x.clamp(-0.4, 0.4)).collect();
            filtered(&[0.0, 0.4, -0.1], &[1.0, -1.3, 0.55], &w)
        };
        let u: Vec<f64> = (0..8000).map(|_| rng.random_range(-1.0..1.0)).collect();
        let y: Vec<f64> = truth(&u)
            .iter()
            .map(|v| v + 0.005 * rng.random_range(-1.7..1.7))
            .collect();
        let (m, rep) = WhParams::new()
            .bla(4, 4)
            .skip(100)
            .knots(11)
            .extra_g1(0)
            .max_iter(30)
            .check()
            .unwrap()
            .fit(&u, &y)
            .unwrap();
        let [lo, hi] = m
            .nonlinearity
            .support
            .expect("a fitted network has a support");
        let v = m.internal_signal(&u);
        assert!(v.iter().all(|x| (lo..=hi).contains(x)));
        let ut: Vec<f64> = (0..4000).map(|_| rng.random_range(-1.5..1.5)).collect();
        let yt = truth(&ut);
        let err = |m: &WienerHammersteinNetwork| {
            let d: Vec<f64> = m.simulate(&ut)[100..]
                .iter()
                .zip(&yt[100..])
                .map(|(a, b)| a - b)
                .collect();
            rms(&d)
        };
        let mut unbounded = m.clone();
        unbounded.nonlinearity.support = None;
        let (e, e_free) = (err(&m), err(&unbounded));
        let y_rms = rms(&yt);
        eprintln!("beyond the range: rmse {e} (outermost local models {e_free}), output rms {y_rms}, {rep:?}");
        assert!(e < 0.01 * y_rms, "rmse {e}, output rms {y_rms}");
        assert!(e < e_free, "rmse {e}, outermost local models {e_free}");
    }

    /// The generic defaults on the same kind of system: the BLA order and
    /// the transient are derived from the data, through `Identify`.
    #[test]
    fn generic_defaults_choose_the_bla_order_on_the_hold_out() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(17);
        let n = 6000;
        let u: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let v = filtered(&[0.3, 0.2], &[1.0, -0.9, 0.4], &u);
        let w: Vec<f64> = v.iter().map(|x| (1.5 * x).tanh() + 0.2 * x).collect();
        let y0 = filtered(&[0.0, 0.4, -0.1], &[1.0, -1.3, 0.55], &w);
        let y: Vec<f64> = y0
            .iter()
            .map(|v| v + 0.01 * rng.random_range(-1.7..1.7))
            .collect();
        let f = WhParams::new()
            .knots(7)
            .extra_g1(1)
            .max_iter(15)
            .check()
            .unwrap();
        let (m, rep) = f.fit(&u, &y).unwrap();
        eprintln!("WH generic defaults: {rep:?}");
        assert_eq!(
            rep.bla_holdout_rmse.len(),
            WhParams::default().max_bla_order
        );
        let best = rep
            .bla_holdout_rmse
            .iter()
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap();
        assert_eq!(rep.bla_orders, (best.0, best.0));
        // the transient: the slowest pole (|z| ≈ 0.74) decays in ~25 samples
        assert!(rep.skip > 5 && rep.skip < 200, "skip {}", rep.skip);
        assert!(rep.rmse < 0.3 * rep.bla_rmse, "{rep:?}");
        let rec =
            gb_core::Record::new(vec!["u".into()], "y".into(), vec![u.clone()], y.clone()).unwrap();
        let via = f.identify(&Records::single(rec), &gb_core::Silent).unwrap();
        assert_eq!(via, m);
        let two = gb_core::Record::new(
            vec!["a".into(), "b".into()],
            "y".into(),
            vec![u.clone(), u],
            y,
        )
        .unwrap();
        assert!(f.identify(&Records::single(two), &gb_core::Silent).is_err());
    }
}
