//! Resampling schemes and the effective sample size.
//!
//! All schemes draw `M` ancestor indices `a_1..a_M` with
//! `E[#{j : a_j = i}] = M W_i` (unbiased offspring counts), in O(N + M):
//!
//! * multinomial: `a_j = F^{-1}(U_(j))` with sorted i.i.d. uniforms,
//! * residual: `⌊M W_i⌋` deterministic copies, the rest multinomial on the residuals,
//! * stratified: `U_j = (j + V_j)/M`, `V_j` i.i.d. uniform,
//! * systematic: `U_j = (j + V)/M`, one uniform `V`.
use crate::error::{Result, SmcError};
use crate::rng::SmcRng;
use rand::Rng;
use serde::{Deserialize, Serialize};

/// A resampling scheme.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[non_exhaustive]
pub enum Resampling {
    /// Multinomial (i.i.d. draws).
    Multinomial,
    /// Residual (deterministic copies + multinomial residual).
    Residual,
    /// Stratified (one uniform per stratum).
    Stratified,
    /// Systematic (one uniform for all strata; lowest variance in practice).
    #[default]
    Systematic,
}

/// Effective sample size `(Σ w)² / Σ w²` of (unnormalised) weights.
///
/// ```
/// assert_eq!(gb_smc::ess(&[1.0, 1.0, 1.0, 1.0]), 4.0);
/// assert_eq!(gb_smc::ess(&[1.0, 0.0, 0.0, 0.0]), 1.0);
/// ```
pub fn ess(weights: &[f64]) -> f64 {
    let (s, s2) = weights
        .iter()
        .fold((0.0, 0.0), |(s, s2), &w| (s + w, s2 + w * w));
    if s2 > 0.0 {
        s * s / s2
    } else {
        0.0
    }
}

/// Draws `ancestors.len()` ancestor indices from non-negative (unnormalised)
/// `weights` with the given scheme.
///
/// ```
/// use gb_smc::{resample, Resampling};
/// let mut rng = gb_smc::rng::stream(0, 0, 0, 0);
/// let mut a = [0usize; 4];
/// resample(Resampling::Systematic, &[0.0, 1.0, 0.0, 3.0], &mut rng, &mut a).unwrap();
/// assert_eq!(a, [1, 3, 3, 3]);
/// ```
pub fn resample(
    scheme: Resampling,
    weights: &[f64],
    rng: &mut SmcRng,
    ancestors: &mut [usize],
) -> Result<()> {
    if weights.is_empty() {
        return Err(SmcError::InvalidWeights("empty weight vector"));
    }
    let mut total = 0.0;
    for &w in weights {
        if !(w >= 0.0 && w.is_finite()) {
            return Err(SmcError::InvalidWeights("negative or non-finite weight"));
        }
        total += w;
    }
    if total <= 0.0 || !total.is_finite() {
        return Err(SmcError::InvalidWeights("weights sum to zero"));
    }
    resample_unchecked(scheme, weights, total, rng, ancestors, &mut Vec::new());
    Ok(())
}

/// Index of the last positive weight (guards floating-point overshoot).
#[inline]
fn last_positive(w: &[f64]) -> usize {
    w.iter().rposition(|&x| x > 0.0).unwrap_or(w.len() - 1)
}

/// Walks increasing points `u_j` (given by `point(j)`) through the cumulative weights.
#[inline]
fn walk(w: &[f64], out: &mut [usize], mut point: impl FnMut(usize) -> f64) {
    let last = last_positive(w);
    let mut i = 0usize;
    let mut cum = w[0];
    for (j, a) in out.iter_mut().enumerate() {
        let u = point(j);
        while cum < u && i < last {
            i += 1;
            cum += w[i];
        }
        *a = i;
    }
}

/// Systematic resampling through offspring counts, free of data-dependent branches:
/// `k_i = #{j : (j + v)/M ≤ C_i / C_N}` (points at or below the cumulative weight `C_i`)
/// and `a_j = #{i : k_i ≤ j}`, clamped to the last positive weight.
fn systematic(w: &[f64], total: f64, v: f64, out: &mut [usize], cnt: &mut Vec<u32>) {
    let m = out.len();
    cnt.clear();
    cnt.resize(m + 1, 0);
    let scale = m as f64 / total;
    let shift = 1.0 - v;
    let mut c = 0.0;
    for &wi in w {
        c += wi;
        // floor(c·scale − v) + 1 for c·scale ≥ v, else 0 (`as` saturates at 0)
        let k = ((c * scale + shift) as usize).min(m);
        cnt[k] += 1;
    }
    let last = last_positive(w);
    let mut acc = 0usize;
    for (a, &c) in out.iter_mut().zip(cnt.iter()) {
        acc += c as usize;
        *a = acc.min(last);
    }
}

/// Resampling without validation; `total` must be `Σ weights > 0`.
pub(crate) fn resample_unchecked(
    scheme: Resampling,
    w: &[f64],
    total: f64,
    rng: &mut SmcRng,
    out: &mut [usize],
    scratch: &mut Vec<u32>,
) {
    let m = out.len();
    if m == 0 {
        return;
    }
    let step = total / m as f64;
    match scheme {
        Resampling::Systematic => {
            let v: f64 = rng.random();
            systematic(w, total, v, out, scratch);
        }
        Resampling::Stratified => {
            walk(w, out, |j| (j as f64 + rng.random::<f64>()) * step);
        }
        Resampling::Multinomial => multinomial(w, total, rng, out),
        Resampling::Residual => {
            let mf = m as f64;
            let mut k = 0usize;
            let mut rtotal = 0.0;
            for (i, &wi) in w.iter().enumerate() {
                let e = mf * wi / total;
                let c = (e.floor() as usize).min(m - k);
                for a in &mut out[k..k + c] {
                    *a = i;
                }
                k += c;
                rtotal += e - e.floor();
            }
            if k < m {
                let rest = &mut out[k..];
                if rtotal > 0.0 {
                    // multinomial on residual weights r_i = M W_i − ⌊M W_i⌋, computed on the fly
                    let res = |i: usize| {
                        let e = mf * w[i] / total;
                        e - e.floor()
                    };
                    multinomial_by(w.len(), res, rtotal, rng, rest);
                } else {
                    multinomial(w, total, rng, rest);
                }
            }
        }
    }
}

fn multinomial(w: &[f64], total: f64, rng: &mut SmcRng, out: &mut [usize]) {
    multinomial_by(w.len(), |i| w[i], total, rng, out)
}

/// O(N + M) multinomial resampling: sorted uniforms generated in decreasing
/// order (`U_(M) = V^{1/M}`, `U_(k) = U_(k+1) V_k^{1/k}`) and walked from the top.
fn multinomial_by(
    n: usize,
    w: impl Fn(usize) -> f64,
    total: f64,
    rng: &mut SmcRng,
    out: &mut [usize],
) {
    let m = out.len();
    let first_pos = (0..n).find(|&i| w(i) > 0.0).unwrap_or(0);
    let mut i = n - 1;
    // cumulative weight strictly below index i
    let mut below = total - w(i);
    let mut u = 1.0f64;
    for k in (0..m).rev() {
        let v: f64 = rng.random();
        u *= v.powf(1.0 / (k + 1) as f64);
        let x = u * total;
        while x < below && i > first_pos {
            i -= 1;
            below -= w(i);
        }
        // skip zero-weight indices
        while w(i) <= 0.0 && i > first_pos {
            i -= 1;
            below -= w(i);
        }
        out[k] = i;
    }
}
