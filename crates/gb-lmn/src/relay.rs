use serde::{Deserialize, Serialize};

/// Discrete Preisach operator: relays R_{αβ} (α ≥ β) on a triangular grid of
/// `levels` thresholds over [−h, h]. A relay switches to +1 when the input
/// reaches α and to −1 when it falls to β, and otherwise keeps its state;
/// the relay states are regressor columns whose weights (the discretised
/// Preisach density) enter linearly (Mayergoyz 2003, ch. 1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RelayGrid {
    alpha: Vec<f64>,
    beta: Vec<f64>,
}

impl RelayGrid {
    /// Grid with `levels` thresholds over [−half_range, half_range]
    /// (levels·(levels+1)/2 relays).
    pub fn new(levels: usize, half_range: f64) -> Self {
        let mut alpha = vec![];
        let mut beta = vec![];
        let t = |i: usize| -half_range + 2.0 * half_range * (i as f64 + 0.5) / levels as f64;
        for i in 0..levels {
            for j in 0..=i {
                alpha.push(t(i));
                beta.push(t(j));
            }
        }
        Self { alpha, beta }
    }

    /// Number of relays.
    pub fn len(&self) -> usize {
        self.alpha.len()
    }

    /// True for a grid without relays (zero levels).
    pub fn is_empty(&self) -> bool {
        self.alpha.is_empty()
    }

    /// Initial states for a start at `x0`: switched relays follow `x0`, the
    /// others take the demagnetised state (+1 below the line α + β = 2 x0).
    pub fn initial_state(&self, x0: f64) -> Vec<f64> {
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

    /// Advance every relay with input `x` (O(number of relays), no allocation).
    #[inline]
    pub fn step(&self, state: &mut [f64], x: f64) {
        for ((s, &a), &b) in state.iter_mut().zip(&self.alpha).zip(&self.beta) {
            if x >= a {
                *s = 1.0;
            } else if x <= b {
                *s = -1.0;
            }
        }
    }
}
