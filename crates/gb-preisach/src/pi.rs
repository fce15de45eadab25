//! Stop and generalised play operators and the Prandtl–Ishlinskii model
//! with its exact inverse (Brokate & Sprekels 1996, ch. 2–3;
//! Krasnosel'skii & Pokrovskii 1989).

use crate::play::{PlayOperator, PlayOperatorBank};
use crate::preisach::check_finite;
use crate::regressor::{HysteresisRegressor, PlayBankState};
use crate::PreisachError;
use serde::{Deserialize, Serialize};

/// The stop (elastic–plastic) operator of half-width r ≥ 0,
/// s_r\[x\] = x − p_r\[x\], so |s| ≤ r and s follows input increments until it
/// saturates at ±r.
///
/// ```
/// use gb_preisach::StopOperator;
/// let s = StopOperator::new(0.5).unwrap();
/// assert_eq!(s.apply(&[0.0, 0.25, 1.0, 0.75]), vec![0.0, 0.25, 0.5, 0.25]);
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StopOperator {
    play: PlayOperator,
}

impl StopOperator {
    /// A stop operator of half-width `r` (finite, ≥ 0).
    pub fn new(r: f64) -> Result<Self, PreisachError> {
        Ok(Self {
            play: PlayOperator::new(r)?,
        })
    }

    /// Half-width r.
    pub fn threshold(&self) -> f64 {
        self.play.threshold()
    }

    /// One step; `p` is the state (the companion play output x − s). Returns
    /// the stop output s and ∂s/∂x (1 while elastic, 0 while saturated).
    #[inline]
    pub fn step(&self, p: &mut f64, x: f64) -> (f64, f64) {
        let (np, moving) = self.play.step(*p, x);
        *p = np;
        (x - np, if moving { 0.0 } else { 1.0 })
    }

    /// Output for a whole signal, starting relaxed (s = 0) at `x[0]`.
    pub fn apply(&self, x: &[f64]) -> Vec<f64> {
        let Some(&x0) = x.first() else {
            return Vec::new();
        };
        let mut p = x0;
        x.iter().map(|&v| self.step(&mut p, v).0).collect()
    }
}

/// A bank of stop operators (regressor columns s_{r_i}\[x\]); the stop
/// counterpart of [`PlayOperatorBank`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StopOperatorBank {
    plays: PlayOperatorBank,
}

impl StopOperatorBank {
    /// A bank with the given thresholds (each finite and ≥ 0, at least one).
    pub fn new(thresholds: Vec<f64>) -> Result<Self, PreisachError> {
        Ok(Self {
            plays: PlayOperatorBank::new(thresholds)?,
        })
    }

    /// Thresholds r_i.
    pub fn thresholds(&self) -> Vec<f64> {
        self.plays.thresholds()
    }
}

impl HysteresisRegressor for StopOperatorBank {
    type State = PlayBankState;

    fn n_columns(&self) -> usize {
        self.plays.len()
    }

    fn start(&self, x0: f64) -> Result<PlayBankState, PreisachError> {
        HysteresisRegressor::start(&self.plays, x0)
    }

    fn step(&self, st: &mut PlayBankState, x: f64, row: &mut [f64], d_row: &mut [f64]) {
        HysteresisRegressor::step(&self.plays, st, x, row, d_row);
        for (r, d) in row.iter_mut().zip(d_row.iter_mut()) {
            *r = x - *r;
            *d = 1.0 - *d;
        }
    }
}

/// A non-decreasing envelope curve of a [`GeneralizedPlay`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Envelope {
    /// γ(x) = slope·x + offset, slope ≥ 0.
    Affine {
        /// Slope (≥ 0).
        slope: f64,
        /// Offset.
        offset: f64,
    },
    /// γ(x) = amplitude·tanh(gain·(x − center)) + offset, amplitude·gain ≥ 0.
    Tanh {
        /// Amplitude.
        amplitude: f64,
        /// Gain.
        gain: f64,
        /// Centre.
        center: f64,
        /// Offset.
        offset: f64,
    },
}

impl Envelope {
    /// γ(x) and γ'(x).
    #[inline]
    pub fn eval(&self, x: f64) -> (f64, f64) {
        match *self {
            Envelope::Affine { slope, offset } => (slope * x + offset, slope),
            Envelope::Tanh {
                amplitude,
                gain,
                center,
                offset,
            } => {
                let t = (gain * (x - center)).tanh();
                (amplitude * t + offset, amplitude * gain * (1.0 - t * t))
            }
        }
    }

    fn validate(&self) -> Result<(), PreisachError> {
        let ok = match *self {
            Envelope::Affine { slope, offset } => {
                slope.is_finite() && offset.is_finite() && slope >= 0.0
            }
            Envelope::Tanh {
                amplitude,
                gain,
                center,
                offset,
            } => {
                [amplitude, gain, center, offset]
                    .iter()
                    .all(|v| v.is_finite())
                    && amplitude * gain >= 0.0
            }
        };
        if ok {
            Ok(())
        } else {
            Err(PreisachError::InvalidArgument(format!(
                "envelope must be finite and non-decreasing: {self:?}"
            )))
        }
    }
}

/// Generalised play operator (Brokate & Sprekels 1996, ch. 2): with
/// non-decreasing envelopes γ_a ≤ γ_d (ascending and descending branch),
///
/// p(k) = max(γ_a(x(k)), min(γ_d(x(k)), p(k−1))).
///
/// The play of half-width r is γ_a(x) = x − r, γ_d(x) = x + r. Where the
/// envelopes cross (γ_a > γ_d) the output is γ_a.
///
/// ```
/// use gb_preisach::{Envelope, GeneralizedPlay};
/// let g = GeneralizedPlay::new(
///     Envelope::Affine { slope: 1.0, offset: -0.5 },
///     Envelope::Affine { slope: 1.0, offset: 0.5 },
/// ).unwrap();
/// assert_eq!(g.apply(&[0.0, 1.0, 0.8], 0.0), vec![0.0, 0.5, 0.5]);
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GeneralizedPlay {
    ascending: Envelope,
    descending: Envelope,
}

impl GeneralizedPlay {
    /// A generalised play with the ascending and descending envelopes.
    pub fn new(ascending: Envelope, descending: Envelope) -> Result<Self, PreisachError> {
        ascending.validate()?;
        descending.validate()?;
        Ok(Self {
            ascending,
            descending,
        })
    }

    /// One step from the previous output `p`: returns the new output and
    /// ∂p/∂x (the envelope slope while on an envelope, else 0).
    #[inline]
    pub fn step(&self, p: f64, x: f64) -> (f64, f64) {
        let (ga, da) = self.ascending.eval(x);
        if ga > p {
            return (ga, da);
        }
        let (gd, dd) = self.descending.eval(x);
        if gd < p {
            (gd, dd)
        } else {
            (p, 0.0)
        }
    }

    /// Output for a whole signal from the initial output `p0`.
    pub fn apply(&self, x: &[f64], p0: f64) -> Vec<f64> {
        let mut p = p0;
        x.iter()
            .map(|&v| {
                p = self.step(p, v).0;
                p
            })
            .collect()
    }
}

/// Prandtl–Ishlinskii model y = a₀ x + Σᵢ aᵢ p_{rᵢ}\[x\] with thresholds
/// 0 ≤ r₁ < … < r_n and weights with Cᵢ = a₀ + Σ_{j≤i} a_j > 0 (e.g.
/// a₀ > 0, aᵢ ≥ 0), which makes it invertible.
///
/// The inverse is again Prandtl–Ishlinskii (Krasnosel'skii–Pokrovskii;
/// Brokate & Sprekels 1996, ch. 2), on the output y:
/// r̂ᵢ = a₀ rᵢ + Σ_{j<i} a_j (rᵢ − r_j), â₀ = 1/a₀,
/// âᵢ = −aᵢ / (Cᵢ C_{i−1}) (C₀ = a₀), with play states
/// p̂ᵢ = Cᵢ pᵢ + Σ_{j>i} a_j p_j.
///
/// ```
/// use gb_preisach::PrandtlIshlinskii;
/// let pi = PrandtlIshlinskii::new(1.0, vec![0.1, 0.3], vec![0.5, 0.25]).unwrap();
/// let x = [0.0, 0.8, -0.3, 0.4];
/// let mut st = pi.initial_state(x[0]);
/// let inv = pi.inverse().unwrap();
/// let mut ist = pi.inverse_state(&st).unwrap();
/// for &v in &x {
///     let y = pi.step(&mut st, v);
///     assert!((inv.step(&mut ist, y) - v).abs() < 1e-12);
/// }
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PrandtlIshlinskii {
    a0: f64,
    plays: Vec<PlayOperator>,
    weights: Vec<f64>,
}

impl PrandtlIshlinskii {
    /// A PI model; validates thresholds (finite, ≥ 0, strictly increasing),
    /// weights (finite, as many as thresholds) and invertibility (Cᵢ > 0).
    pub fn new(a0: f64, thresholds: Vec<f64>, weights: Vec<f64>) -> Result<Self, PreisachError> {
        if thresholds.len() != weights.len() {
            return Err(PreisachError::DimensionMismatch {
                expected: thresholds.len(),
                got: weights.len(),
            });
        }
        if !(a0.is_finite() && a0 > 0.0) {
            return Err(PreisachError::InvalidArgument(format!(
                "PI needs a0 > 0, got {a0}"
            )));
        }
        if thresholds.windows(2).any(|w| w[0] >= w[1]) {
            return Err(PreisachError::InvalidArgument(
                "PI thresholds must be strictly increasing".into(),
            ));
        }
        let mut c = a0;
        for &w in &weights {
            c += w;
            if !(w.is_finite() && c > 0.0) {
                return Err(PreisachError::InvalidArgument(format!(
                    "PI weights must be finite with a0 + partial sums > 0 (got partial sum {c})"
                )));
            }
        }
        let plays = thresholds
            .into_iter()
            .map(PlayOperator::new)
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self { a0, plays, weights })
    }

    /// Linear gain a₀.
    pub fn linear_gain(&self) -> f64 {
        self.a0
    }

    /// Thresholds rᵢ.
    pub fn thresholds(&self) -> Vec<f64> {
        self.plays.iter().map(PlayOperator::threshold).collect()
    }

    /// Weights aᵢ.
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// Relaxed play states for a start at input `x0`.
    pub fn initial_state(&self, x0: f64) -> Vec<f64> {
        vec![x0; self.plays.len()]
    }

    /// Advance the plays (`state`, caller-owned) with `x`; returns y.
    #[inline]
    pub fn step(&self, state: &mut [f64], x: f64) -> f64 {
        let mut y = self.a0 * x;
        for ((op, p), w) in self.plays.iter().zip(state.iter_mut()).zip(&self.weights) {
            *p = op.step(*p, x).0;
            y += w * *p;
        }
        y
    }

    /// [`step`](Self::step) plus ∂y/∂x = a₀ + Σ_{moving} aᵢ.
    pub fn step_with_derivative(&self, state: &mut [f64], x: f64) -> (f64, f64) {
        let (mut y, mut d) = (self.a0 * x, self.a0);
        for ((op, p), w) in self.plays.iter().zip(state.iter_mut()).zip(&self.weights) {
            let (np, moving) = op.step(*p, x);
            *p = np;
            y += w * np;
            if moving {
                d += w;
            }
        }
        (y, d)
    }

    /// Output for a whole signal from relaxed plays at `x[0]`.
    pub fn apply(&self, x: &[f64]) -> Result<Vec<f64>, PreisachError> {
        check_finite(x)?;
        let Some(&x0) = x.first() else {
            return Ok(Vec::new());
        };
        let mut st = self.initial_state(x0);
        Ok(x.iter().map(|&v| self.step(&mut st, v)).collect())
    }

    /// The exact inverse operator (see the type documentation). Fails only
    /// if the inverse parameters overflow.
    pub fn inverse(&self) -> Result<PrandtlIshlinskii, PreisachError> {
        let r = self.thresholds();
        let n = r.len();
        let mut rh = Vec::with_capacity(n);
        let mut ah = Vec::with_capacity(n);
        let mut c_prev = self.a0;
        // Σ_{j<i} a_j and Σ_{j<i} a_j r_j.
        let (mut sa, mut sar) = (0.0, 0.0);
        for (&ri, &wi) in r.iter().zip(&self.weights) {
            rh.push(self.a0 * ri + sa * ri - sar);
            let c = c_prev + wi;
            ah.push(-wi / (c * c_prev));
            sa += wi;
            sar += wi * ri;
            c_prev = c;
        }
        PrandtlIshlinskii::new(
            1.0 / self.a0,
            rh.into_iter().map(|t| t.max(0.0)).collect(),
            ah,
        )
    }

    /// Play states of [`inverse`](Self::inverse) matching this model's
    /// `state`: p̂ᵢ = Cᵢ pᵢ + Σ_{j>i} a_j p_j.
    pub fn inverse_state(&self, state: &[f64]) -> Result<Vec<f64>, PreisachError> {
        let n = self.weights.len();
        if state.len() != n {
            return Err(PreisachError::DimensionMismatch {
                expected: n,
                got: state.len(),
            });
        }
        let mut out = vec![0.0; n];
        let mut tail = 0.0; // Σ_{j>i} a_j p_j
        let total: f64 = self.a0 + self.weights.iter().sum::<f64>();
        let mut c = total; // C_i computed downwards: C_n = total
        for i in (0..n).rev() {
            out[i] = c * state[i] + tail;
            tail += self.weights[i] * state[i];
            c -= self.weights[i];
        }
        Ok(out)
    }
}
