use crate::PreisachError;
use serde::{Deserialize, Serialize};

/// The play (backlash) operator of half-width r ≥ 0:
///
/// p(k) = max(x(k) − r, min(x(k) + r, p(k−1))).
///
/// It is rate independent; r = 0 gives the identity.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PlayOperator {
    r: f64,
}

impl PlayOperator {
    /// A play operator of half-width `r` (finite, ≥ 0).
    pub fn new(r: f64) -> Result<Self, PreisachError> {
        if !(r.is_finite() && r >= 0.0) {
            return Err(PreisachError::InvalidArgument(format!(
                "play threshold must be finite and >= 0, got {r}"
            )));
        }
        Ok(Self { r })
    }

    /// Half-width r.
    pub fn threshold(&self) -> f64 {
        self.r
    }

    /// One step: new output from the previous output `p` and input `x`.
    /// Returns `(p_new, moving)`; when `moving`, ∂p/∂x = 1 and ∂p/∂p_prev = 0,
    /// otherwise ∂p/∂x = 0 and ∂p/∂p_prev = 1.
    #[inline]
    pub fn step(&self, p: f64, x: f64) -> (f64, bool) {
        if x - self.r > p {
            (x - self.r, true)
        } else if x + self.r < p {
            (x + self.r, true)
        } else {
            (p, false)
        }
    }
}

/// A bank of play operators with thresholds r₁ < … < r_m driven by one
/// signal; their outputs are regressor columns whose weights enter a model
/// linearly (Prandtl–Ishlinskii: y = Σ wᵢ pᵢ).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlayOperatorBank {
    ops: Vec<PlayOperator>,
}

impl PlayOperatorBank {
    /// A bank with the given thresholds (each finite and ≥ 0, at least one).
    pub fn new(thresholds: Vec<f64>) -> Result<Self, PreisachError> {
        if thresholds.is_empty() {
            return Err(PreisachError::InvalidArgument(
                "a play bank needs at least one threshold".into(),
            ));
        }
        let ops = thresholds
            .into_iter()
            .map(PlayOperator::new)
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self { ops })
    }

    /// `m` thresholds spread evenly over (0, `half_range`]: r_i = i·half_range/m,
    /// i = 1..m. Rate-independent memory of every amplitude up to `half_range`.
    pub fn uniform(half_range: f64, m: usize) -> Result<Self, PreisachError> {
        if !(half_range.is_finite() && half_range > 0.0) || m == 0 {
            return Err(PreisachError::InvalidArgument(format!(
                "uniform play bank needs half_range > 0 and m > 0, got {half_range}, {m}"
            )));
        }
        Self::new((1..=m).map(|i| half_range * i as f64 / m as f64).collect())
    }

    /// Number of operators (columns).
    pub fn len(&self) -> usize {
        self.ops.len()
    }

    /// True when the bank has no operators (never, by construction).
    pub fn is_empty(&self) -> bool {
        self.ops.is_empty()
    }

    /// Thresholds r_i.
    pub fn thresholds(&self) -> Vec<f64> {
        self.ops.iter().map(PlayOperator::threshold).collect()
    }

    /// Demagnetised-like initial state for a start at input `x0`: every
    /// operator output equals `x0`.
    pub fn initial_state(&self, x0: f64) -> Vec<f64> {
        vec![x0; self.ops.len()]
    }

    /// Advance all operators with input `x`: `state` holds the outputs and is
    /// updated in place; `moving[i]` tells whether operator i followed the
    /// input (∂pᵢ/∂x = 1) or stayed (∂pᵢ/∂pᵢ_prev = 1). No allocation.
    #[inline]
    pub fn step(&self, state: &mut [f64], x: f64, moving: &mut [bool]) {
        for ((op, p), mv) in self.ops.iter().zip(state.iter_mut()).zip(moving.iter_mut()) {
            let (np, m) = op.step(*p, x);
            *p = np;
            *mv = m;
        }
    }

    /// Outputs of every operator for the whole signal `x`, starting from
    /// [`initial_state`](Self::initial_state)`(x[0])`; one column per operator.
    pub fn apply(&self, x: &[f64]) -> Vec<Vec<f64>> {
        let mut cols = vec![Vec::with_capacity(x.len()); self.ops.len()];
        let Some(&x0) = x.first() else { return cols };
        let mut state = self.initial_state(x0);
        let mut moving = vec![false; self.ops.len()];
        for &v in x {
            self.step(&mut state, v, &mut moving);
            for (c, p) in cols.iter_mut().zip(&state) {
                c.push(*p);
            }
        }
        cols
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn play_is_rate_independent() {
        // Inserting intermediate points on monotone segments does not change
        // the outputs at the original turning points.
        let bank = PlayOperatorBank::new(vec![0.3]).unwrap();
        let coarse = [0.0, 1.0, -0.5, 0.7];
        let fine: Vec<f64> = vec![0.0, 0.5, 1.0, 0.25, -0.5, 0.1, 0.7];
        let a = bank.apply(&coarse)[0].clone();
        let b = bank.apply(&fine)[0].clone();
        assert_eq!([a[1], a[2], a[3]], [b[2], b[4], b[6]]);
    }

    #[test]
    fn play_stays_within_band() {
        let bank = PlayOperatorBank::uniform(1.0, 4).unwrap();
        let x: Vec<f64> = (0..500).map(|k| (k as f64 * 0.37).sin() * 3.0).collect();
        let cols = bank.apply(&x);
        for (c, r) in cols.iter().zip(bank.thresholds()) {
            for (p, xi) in c.iter().zip(&x) {
                assert!((p - xi).abs() <= r + 1e-12);
            }
        }
    }

    #[test]
    fn invalid_thresholds_rejected() {
        assert!(PlayOperatorBank::new(vec![]).is_err());
        assert!(PlayOperatorBank::new(vec![-1.0]).is_err());
        assert!(PlayOperatorBank::uniform(0.0, 3).is_err());
    }
}
