//! Hysteresis regressors: signals → columns that enter a model linearly,
//! with their derivatives with respect to the current input sample (for the
//! output-error / NOE gradients of gb-lmn and gb-model).

use crate::everett::{Everett, GridEverett, GridNode};
use crate::play::PlayOperatorBank;
use crate::preisach::{check_finite, InitialState, Preisach, PreisachState};
use crate::PreisachError;
use serde::{Deserialize, Serialize};

/// Regressor columns of a whole signal and their derivatives
/// ∂φ_c(t)/∂x(t) with respect to the current input sample.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Regressors {
    /// One vector per column, each as long as the signal.
    pub columns: Vec<Vec<f64>>,
    /// ∂column/∂x(t), same shape as `columns`.
    pub derivatives: Vec<Vec<f64>>,
}

/// Something that turns a scalar signal into hysteresis regressor columns,
/// sample by sample with caller-owned state.
///
/// ```
/// use gb_preisach::{HysteresisRegressor, PlayOperatorBank};
/// let bank = PlayOperatorBank::uniform(1.0, 2).unwrap();
/// let r = bank.regressors(&[0.0, 2.0, 1.5]).unwrap();
/// assert_eq!(r.columns.len(), 2);
/// assert_eq!(r.derivatives[0], vec![0.0, 1.0, 0.0]);
/// ```
pub trait HysteresisRegressor {
    /// Memory of the operators.
    type State;

    /// Number of columns.
    fn n_columns(&self) -> usize;

    /// Memory before the first sample `x0` (operators that start relaxed at
    /// the first sample use it; the others ignore it).
    fn start(&self, x0: f64) -> Result<Self::State, PreisachError>;

    /// Advance with input `x`; writes the regressor row φ(t) into `row` and
    /// ∂φ(t)/∂x(t) into `d_row` (both of length [`n_columns`](Self::n_columns);
    /// shorter slices are a programming error and may panic).
    fn step(&self, state: &mut Self::State, x: f64, row: &mut [f64], d_row: &mut [f64]);

    /// Columns and derivatives for a whole signal.
    fn regressors(&self, x: &[f64]) -> Result<Regressors, PreisachError> {
        check_finite(x)?;
        let m = self.n_columns();
        let mut columns = vec![Vec::with_capacity(x.len()); m];
        let mut derivatives = vec![Vec::with_capacity(x.len()); m];
        let Some(&x0) = x.first() else {
            return Ok(Regressors {
                columns,
                derivatives,
            });
        };
        let mut st = self.start(x0)?;
        let (mut row, mut d_row) = (vec![0.0; m], vec![0.0; m]);
        for &v in x {
            self.step(&mut st, v, &mut row, &mut d_row);
            for c in 0..m {
                columns[c].push(row[c]);
                derivatives[c].push(d_row[c]);
            }
        }
        Ok(Regressors {
            columns,
            derivatives,
        })
    }
}

/// Play bank state: outputs and moving flags.
#[derive(Debug, Clone)]
pub struct PlayBankState {
    outputs: Vec<f64>,
    moving: Vec<bool>,
}

impl HysteresisRegressor for PlayOperatorBank {
    type State = PlayBankState;

    fn n_columns(&self) -> usize {
        self.len()
    }

    fn start(&self, x0: f64) -> Result<PlayBankState, PreisachError> {
        Ok(PlayBankState {
            outputs: self.initial_state(x0),
            moving: vec![false; self.len()],
        })
    }

    fn step(&self, st: &mut PlayBankState, x: f64, row: &mut [f64], d_row: &mut [f64]) {
        PlayOperatorBank::step(self, &mut st.outputs, x, &mut st.moving);
        row.copy_from_slice(&st.outputs);
        for (d, m) in d_row.iter_mut().zip(&st.moving) {
            *d = if *m { 1.0 } else { 0.0 };
        }
    }
}

/// Regressor of a Preisach model with a nonparametric [`GridEverett`]
/// function on `[lo, hi]` with `n` intervals: the output is
/// y(t) = φ(t)ᵀ w with w the n(n+1)/2 cell masses, because
/// y = −F(α₀, β₀) + 2 Σ ±F(corners) and F is linear in w.
///
/// ```
/// use gb_preisach::{GridEverett, GridPreisachRegressor, HysteresisRegressor, InitialState, Preisach};
/// let reg = GridPreisachRegressor::new(-1.0, 1.0, 4, InitialState::NegativeSaturation).unwrap();
/// let x = [0.0, 0.7, -0.2, 0.4];
/// let phi = reg.regressors(&x).unwrap();
/// let g = GridEverett::uniform_density(-1.0, 1.0, 4, 1.0).unwrap();
/// let y = Preisach::new(g.clone()).simulate(&x, &InitialState::NegativeSaturation).unwrap();
/// for t in 0..x.len() {
///     let lin: f64 = phi.columns.iter().zip(g.masses()).map(|(c, w)| c[t] * w).sum();
///     assert!((lin - y[t]).abs() < 1e-12);
/// }
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GridPreisachRegressor {
    tracker: Preisach<GridEverett>,
    init: InitialState,
}

impl GridPreisachRegressor {
    /// Regressor for a grid on `[lo, hi]` with `n` intervals, starting the
    /// memory in `init`.
    pub fn new(lo: f64, hi: f64, n: usize, init: InitialState) -> Result<Self, PreisachError> {
        let g = GridEverett::new(lo, hi, n, vec![0.0; GridEverett::parameter_count(n)])?;
        let tracker = Preisach::new(g);
        tracker.state(&init)?;
        Ok(Self { tracker, init })
    }

    /// Cap the memory (see [`Preisach::with_memory_cap`]).
    pub fn with_memory_cap(mut self, cap: usize) -> Result<Self, PreisachError> {
        self.tracker = self.tracker.with_memory_cap(cap)?;
        Ok(self)
    }

    /// Grid bounds and number of intervals.
    pub fn grid(&self) -> (f64, f64, usize) {
        let (lo, hi) = self.tracker.everett().bounds();
        (lo, hi, self.tracker.everett().intervals())
    }

    /// The initial state.
    pub fn initial_state(&self) -> &InitialState {
        &self.init
    }

    /// The memory cap.
    pub fn memory_cap(&self) -> Option<usize> {
        self.tracker.memory_cap()
    }

    /// Derivatives ∂φ(t)/∂s_j of the current regressor row with respect to
    /// the stored extrema s_j (one row of length
    /// [`n_columns`](HysteresisRegressor::n_columns) per extremum, aligned
    /// with [`PreisachState::extrema`] and
    /// [`PreisachState::extremum_times`]); the counterpart of
    /// [`Preisach::extremum_sensitivities`].
    pub fn extremum_derivatives(&self, st: &PreisachState<GridNode>) -> Vec<Vec<f64>> {
        let g = self.tracker.everett();
        let c = st.corners();
        let k = c.len();
        let p = GridEverett::parameter_count(g.intervals());
        let node = |j: usize| if j < k { &c[j].node } else { &st.run_node };
        (1..k)
            .map(|j| {
                let mut out = vec![0.0; p];
                let (prev, cur, next) = (node(j - 1), node(j), node(j + 1));
                if j % 2 == 1 {
                    g.add_basis_derivative(cur, prev, 2.0, true, &mut out);
                    g.add_basis_derivative(cur, next, -2.0, true, &mut out);
                } else {
                    g.add_basis_derivative(next, cur, 2.0, false, &mut out);
                    g.add_basis_derivative(prev, cur, -2.0, false, &mut out);
                }
                out
            })
            .collect()
    }

    /// A Preisach model with these grid, memory cap and the given masses.
    pub fn model(&self, masses: Vec<f64>) -> Result<Preisach<GridEverett>, PreisachError> {
        let (lo, hi, n) = self.grid();
        let p = Preisach::new(GridEverett::new(lo, hi, n, masses)?);
        match self.memory_cap() {
            Some(c) => p.with_memory_cap(c),
            None => Ok(p),
        }
    }
}

impl HysteresisRegressor for GridPreisachRegressor {
    type State = PreisachState<GridNode>;

    fn n_columns(&self) -> usize {
        GridEverett::parameter_count(self.tracker.everett().intervals())
    }

    fn start(&self, _x0: f64) -> Result<Self::State, PreisachError> {
        self.tracker.state(&self.init)
    }

    fn step(&self, st: &mut Self::State, x: f64, row: &mut [f64], d_row: &mut [f64]) {
        let g = self.tracker.everett();
        self.tracker.step(st, x);
        row.iter_mut().for_each(|v| *v = 0.0);
        d_row.iter_mut().for_each(|v| *v = 0.0);
        let (lo, hi) = g.bounds();
        g.add_basis(&g.node(hi), &g.node(lo), -1.0, row);
        let c = st.corners();
        let k = c.len();
        let link = |j: usize, prev: &GridNode, cur: &GridNode, row: &mut [f64]| {
            if j % 2 == 1 {
                g.add_basis(cur, prev, 2.0, row);
            } else {
                g.add_basis(prev, cur, -2.0, row);
            }
        };
        for j in 1..k {
            link(j, &c[j - 1].node, &c[j].node, row);
        }
        let last = &c[k - 1].node;
        link(k, last, &st.run_node, row);
        if x > lo && x < hi {
            if k % 2 == 1 {
                g.add_basis_derivative(&st.run_node, last, 2.0, true, d_row);
            } else {
                g.add_basis_derivative(last, &st.run_node, -2.0, false, d_row);
            }
        }
    }
}
