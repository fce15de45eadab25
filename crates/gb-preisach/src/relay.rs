//! The classic discrete Preisach model: a finite grid of weighted relays.
//! Used as a cross-check of the Everett-function form (same outputs up to
//! the discretisation of the density).

use crate::everett::Everett;
use crate::preisach::check_finite;
use crate::PreisachError;
use serde::{Deserialize, Serialize};

/// Weighted relays γ_{αβ}: up (+1) when x ≥ α, down (−1) when x ≤ β,
/// unchanged in between; output y = Σ w_k γ_k.
///
/// ```
/// use gb_preisach::RelayGrid;
/// let r = RelayGrid::new(vec![0.5], vec![-0.5], vec![2.0]).unwrap();
/// assert_eq!(r.simulate(&[0.0, 0.6, 0.0, -0.6], false).unwrap(), vec![-2.0, 2.0, 2.0, -2.0]);
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RelayGrid {
    alpha: Vec<f64>,
    beta: Vec<f64>,
    weight: Vec<f64>,
}

impl RelayGrid {
    /// Relays with up thresholds `alpha`, down thresholds `beta` (α ≥ β) and
    /// weights, all finite and of equal length.
    pub fn new(alpha: Vec<f64>, beta: Vec<f64>, weight: Vec<f64>) -> Result<Self, PreisachError> {
        if alpha.len() != beta.len() || alpha.len() != weight.len() {
            return Err(PreisachError::DimensionMismatch {
                expected: alpha.len(),
                got: if alpha.len() != beta.len() {
                    beta.len()
                } else {
                    weight.len()
                },
            });
        }
        for ((a, b), w) in alpha.iter().zip(&beta).zip(&weight) {
            if !(a.is_finite() && b.is_finite() && w.is_finite()) || a < b {
                return Err(PreisachError::InvalidArgument(format!(
                    "relay needs finite alpha >= beta and weight, got ({a}, {b}, {w})"
                )));
            }
        }
        Ok(Self {
            alpha,
            beta,
            weight,
        })
    }

    /// Discretise an Everett function on `[lo, hi]` with `n` intervals: one
    /// relay per cell of the triangular grid, at its centroid, weighted by the
    /// cell's mass (second difference of F).
    pub fn from_everett<E: Everett>(
        f: &E,
        lo: f64,
        hi: f64,
        n: usize,
    ) -> Result<Self, PreisachError> {
        if !(lo.is_finite() && hi.is_finite() && lo < hi) || n == 0 {
            return Err(PreisachError::InvalidArgument(format!(
                "relay grid needs finite lo < hi and n >= 1, got [{lo}, {hi}], n = {n}"
            )));
        }
        let d = (hi - lo) / n as f64;
        let h = |i: usize| lo + d * i as f64;
        let (mut alpha, mut beta, mut weight) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..n {
            for l in 0..=k {
                if l == k {
                    alpha.push(h(k) + 2.0 * d / 3.0);
                    beta.push(h(k) + d / 3.0);
                    weight.push(f.everett(h(k + 1), h(k)));
                } else {
                    alpha.push(h(k) + 0.5 * d);
                    beta.push(h(l) + 0.5 * d);
                    weight.push(
                        f.everett(h(k + 1), h(l))
                            - f.everett(h(k + 1), h(l + 1))
                            - f.everett(h(k), h(l))
                            + f.everett(h(k), h(l + 1)),
                    );
                }
            }
        }
        Self::new(alpha, beta, weight)
    }

    /// The discrete Preisach operator on a uniform triangular grid: `levels`
    /// thresholds tᵢ = −h + 2h(i + ½)/levels over [−h, h] (h =
    /// `half_range`), one relay per pair α = tᵢ ≥ β = tⱼ (levels·(levels+1)/2
    /// relays, the diagonal α = β included), unit weights. Its relay states
    /// ([`relay_states`](Self::relay_states), [`switch`](Self::switch)) are
    /// regressor columns whose weights (the discretised density) a model
    /// estimates linearly (Mayergoyz 2003, ch. 1).
    ///
    /// ```
    /// use gb_preisach::RelayGrid;
    /// let g = RelayGrid::uniform(2, 1.0).unwrap(); // thresholds ±0.5
    /// let mut s = g.relay_states(0.0);
    /// assert_eq!(s, vec![1.0, -1.0, -1.0]); // (α, β) = (−½, −½), (½, −½), (½, ½)
    /// g.switch(&mut s, 0.6);
    /// assert_eq!(s, vec![1.0, 1.0, 1.0]);
    /// ```
    pub fn uniform(levels: usize, half_range: f64) -> Result<Self, PreisachError> {
        if !(half_range.is_finite() && half_range > 0.0) {
            return Err(PreisachError::InvalidArgument(format!(
                "a uniform relay grid needs half_range > 0, got {half_range}"
            )));
        }
        let t = |i: usize| -half_range + 2.0 * half_range * (i as f64 + 0.5) / levels as f64;
        let (mut alpha, mut beta) = (vec![], vec![]);
        for i in 0..levels {
            for j in 0..=i {
                alpha.push(t(i));
                beta.push(t(j));
            }
        }
        let weight = vec![1.0; alpha.len()];
        Self::new(alpha, beta, weight)
    }

    /// Relay states (±1) for a start at `x0`: relays that `x0` has switched
    /// follow it, the others take the demagnetised state (+1 below the line
    /// α + β = 2·x0, −1 above).
    pub fn relay_states(&self, x0: f64) -> Vec<f64> {
        self.alpha
            .iter()
            .zip(&self.beta)
            .map(|(&a, &b)| {
                if x0 >= a {
                    1.0
                } else if x0 <= b {
                    -1.0
                } else if a + b < 2.0 * x0 {
                    1.0
                } else {
                    -1.0
                }
            })
            .collect()
    }

    /// Switch relay states held as ±1 values (regressor columns) with the
    /// input `x`, without forming the output (no allocation).
    #[inline]
    pub fn switch(&self, state: &mut [f64], x: f64) {
        for ((s, &a), &b) in state.iter_mut().zip(&self.alpha).zip(&self.beta) {
            if x >= a {
                *s = 1.0;
            } else if x <= b {
                *s = -1.0;
            }
        }
    }

    /// Number of relays.
    pub fn len(&self) -> usize {
        self.alpha.len()
    }

    /// True when there are no relays.
    pub fn is_empty(&self) -> bool {
        self.alpha.is_empty()
    }

    /// All relays up (`positive`) or down.
    pub fn initial_state(&self, positive: bool) -> Vec<bool> {
        vec![positive; self.alpha.len()]
    }

    /// Switch the relays for input `x` and return the output.
    pub fn step(&self, state: &mut [bool], x: f64) -> f64 {
        let mut y = 0.0;
        for (((s, a), b), w) in state
            .iter_mut()
            .zip(&self.alpha)
            .zip(&self.beta)
            .zip(&self.weight)
        {
            if x >= *a {
                *s = true;
            } else if x <= *b {
                *s = false;
            }
            y += if *s { *w } else { -*w };
        }
        y
    }

    /// Outputs for the whole input, from saturation (`positive` or not).
    pub fn simulate(&self, x: &[f64], positive: bool) -> Result<Vec<f64>, PreisachError> {
        check_finite(x)?;
        let mut st = self.initial_state(positive);
        Ok(x.iter().map(|&v| self.step(&mut st, v)).collect())
    }
}
