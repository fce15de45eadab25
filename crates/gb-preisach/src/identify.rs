//! Identification of a nonparametric Preisach model by (regularised,
//! optionally non-negative) linear least squares.
//!
//! With the grid Everett function the Preisach output is linear in the cell
//! masses w (J. Hauth 2008: the primitive-function trick), y(t) = φ(t)ᵀ w, so
//! for any input — not only first-order reversal curves — the masses solve
//!
//! min_w ‖Φ w + b·1 − y‖² + λ_r ‖w‖² + λ_s Σ_{neighbour cells} (w_a − w_b)²,
//! optionally subject to w ≥ 0 (non-negative density ⇔ F increasing in α and
//! decreasing in β).
//!
//! The penalties are scaled by tr(ΦᵀΦ)/p so that λ is dimensionless.

use crate::everett::{cell_index, GridEverett};
use crate::pi::PrandtlIshlinskii;
use crate::play::PlayOperatorBank;
use crate::preisach::{check_finite, Preisach};
use crate::regressor::{GridPreisachRegressor, HysteresisRegressor};
use crate::PreisachError;
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

/// Options of [`fit_grid_preisach`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FitOptions {
    /// Ridge weight λ_r (relative to tr(ΦᵀΦ)/p), ≥ 0.
    pub ridge: f64,
    /// Smoothness weight λ_s on differences of neighbouring square cells
    /// (relative), ≥ 0.
    pub smoothness: f64,
    /// Constrain the density to be non-negative (w ≥ 0).
    pub nonnegative: bool,
    /// Fit an additive constant b as well (never constrained).
    pub bias: bool,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            ridge: 1e-9,
            smoothness: 0.0,
            nonnegative: true,
            bias: false,
        }
    }
}

/// Result of [`fit_grid_preisach`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PreisachFit {
    /// The identified model; its Everett function holds the density
    /// (see [`GridEverett::density_table`]).
    pub model: Preisach<GridEverett>,
    /// Additive constant (0 unless [`FitOptions::bias`]).
    pub bias: f64,
    /// Fitted output on the estimation data.
    pub fitted: Vec<f64>,
    /// Root mean square error of the fit.
    pub rmse: f64,
}

/// Fit the cell masses of a grid Preisach model to input `x` and measured
/// output `y`.
///
/// ```
/// use gb_preisach::{fit_grid_preisach, FitOptions, GridEverett, GridPreisachRegressor, InitialState, Preisach};
/// let truth = Preisach::new(GridEverett::uniform_density(-1.0, 1.0, 4, 1.0).unwrap());
/// let x: Vec<f64> = (0..400).map(|k| (k as f64 * 0.05).sin() * (1.0 - k as f64 / 500.0)).collect();
/// let y = truth.simulate(&x, &InitialState::NegativeSaturation).unwrap();
/// let reg = GridPreisachRegressor::new(-1.0, 1.0, 4, InitialState::NegativeSaturation).unwrap();
/// let fit = fit_grid_preisach(&x, &y, &reg, &FitOptions::default()).unwrap();
/// assert!(fit.rmse < 1e-6);
/// ```
pub fn fit_grid_preisach(
    x: &[f64],
    y: &[f64],
    reg: &GridPreisachRegressor,
    opts: &FitOptions,
) -> Result<PreisachFit, PreisachError> {
    check_finite(x)?;
    check_finite(y)?;
    if x.len() != y.len() {
        return Err(PreisachError::DimensionMismatch {
            expected: x.len(),
            got: y.len(),
        });
    }
    if x.is_empty() {
        return Err(PreisachError::InvalidArgument("no data".into()));
    }
    let p = reg.n_columns();
    let q = p + usize::from(opts.bias);
    // Normal equations, accumulated row by row.
    let mut gram = DMatrix::<f64>::zeros(q, q);
    let mut rhs = DVector::<f64>::zeros(q);
    let mut st = reg.start(x[0])?;
    let (mut row, mut d_row) = (vec![0.0; p], vec![0.0; p]);
    let mut full = DVector::<f64>::zeros(q);
    for (&xt, &yt) in x.iter().zip(y) {
        reg.step(&mut st, xt, &mut row, &mut d_row);
        full.rows_mut(0, p).copy_from_slice(&row);
        if opts.bias {
            full[p] = 1.0;
        }
        gram.ger(1.0, &full, &full, 1.0);
        rhs.axpy(yt, &full, 1.0);
    }
    let (_, _, n) = reg.grid();
    let free: Vec<bool> = (0..q).map(|i| i >= p || !opts.nonnegative).collect();
    let w = regularised_least_squares(gram, rhs, p, Some(n), opts, &free)?;
    let bias = if opts.bias { w[p] } else { 0.0 };
    let model = reg.model(w.rows(0, p).iter().copied().collect())?;
    let fitted: Vec<f64> = model
        .simulate(x, reg.initial_state())?
        .into_iter()
        .map(|v| v + bias)
        .collect();
    let rmse = (fitted
        .iter()
        .zip(y)
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>()
        / y.len() as f64)
        .sqrt();
    Ok(PreisachFit {
        model,
        bias,
        fitted,
        rmse,
    })
}

/// Result of [`fit_prandtl_ishlinskii`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PrandtlIshlinskiiFit {
    /// The identified model.
    pub model: PrandtlIshlinskii,
    /// Additive constant (0 unless [`FitOptions::bias`]).
    pub bias: f64,
    /// Root mean square error of the fit.
    pub rmse: f64,
}

/// Fit a Prandtl–Ishlinskii model y ≈ a₀ x + Σ aᵢ p_{rᵢ}\[x\] (+ b) with the
/// given thresholds by linear least squares on the play-operator columns
/// (plays relaxed at `x[0]`). With [`FitOptions::nonnegative`] all weights
/// including a₀ are ≥ 0, which makes the model invertible when a₀ > 0;
/// `ridge` acts on the play weights, `smoothness` is ignored.
///
/// ```
/// use gb_preisach::{fit_prandtl_ishlinskii, FitOptions, PrandtlIshlinskii};
/// let truth = PrandtlIshlinskii::new(0.5, vec![0.1, 0.3], vec![0.4, 0.2]).unwrap();
/// let x: Vec<f64> = (0..300).map(|k| (k as f64 * 0.05).sin() * (1.0 + k as f64 / 300.0)).collect();
/// let y = truth.apply(&x).unwrap();
/// let fit = fit_prandtl_ishlinskii(&x, &y, vec![0.1, 0.3], &FitOptions::default()).unwrap();
/// assert!((fit.model.weights()[0] - 0.4).abs() < 1e-6);
/// ```
pub fn fit_prandtl_ishlinskii(
    x: &[f64],
    y: &[f64],
    thresholds: Vec<f64>,
    opts: &FitOptions,
) -> Result<PrandtlIshlinskiiFit, PreisachError> {
    check_finite(x)?;
    check_finite(y)?;
    if x.len() != y.len() {
        return Err(PreisachError::DimensionMismatch {
            expected: x.len(),
            got: y.len(),
        });
    }
    if x.is_empty() {
        return Err(PreisachError::InvalidArgument("no data".into()));
    }
    let bank = PlayOperatorBank::new(thresholds.clone())?;
    let m = bank.len();
    // Unknowns: play weights (0..m), a₀ (m), bias (m + 1).
    let q = m + 1 + usize::from(opts.bias);
    let mut gram = DMatrix::<f64>::zeros(q, q);
    let mut rhs = DVector::<f64>::zeros(q);
    let mut state = bank.initial_state(x[0]);
    let mut moving = vec![false; m];
    let mut full = DVector::<f64>::zeros(q);
    for (&xt, &yt) in x.iter().zip(y) {
        bank.step(&mut state, xt, &mut moving);
        full.rows_mut(0, m).copy_from_slice(&state);
        full[m] = xt;
        if opts.bias {
            full[m + 1] = 1.0;
        }
        gram.ger(1.0, &full, &full, 1.0);
        rhs.axpy(yt, &full, 1.0);
    }
    let free: Vec<bool> = (0..q).map(|i| i > m || !opts.nonnegative).collect();
    let w = regularised_least_squares(gram, rhs, m, None, opts, &free)?;
    let model = PrandtlIshlinskii::new(w[m], thresholds, w.rows(0, m).iter().copied().collect())?;
    let bias = if opts.bias { w[m + 1] } else { 0.0 };
    let fitted: Vec<f64> = model.apply(x)?;
    let rmse = (fitted
        .iter()
        .zip(y)
        .map(|(a, b)| (a + bias - b) * (a + bias - b))
        .sum::<f64>()
        / y.len() as f64)
        .sqrt();
    Ok(PrandtlIshlinskiiFit { model, bias, rmse })
}

/// Solve the penalised normal equations (ΦᵀΦ + penalties) w = Φᵀy: ridge on
/// the first `p` unknowns, smoothness on the cells of a grid with `grid`
/// intervals (the first n(n+1)/2 unknowns), non-negativity on the unknowns
/// not marked `free`.
fn regularised_least_squares(
    mut gram: DMatrix<f64>,
    rhs: DVector<f64>,
    p: usize,
    grid: Option<usize>,
    opts: &FitOptions,
    free: &[bool],
) -> Result<DVector<f64>, PreisachError> {
    if !(opts.ridge.is_finite()
        && opts.ridge >= 0.0
        && opts.smoothness.is_finite()
        && opts.smoothness >= 0.0)
    {
        return Err(PreisachError::InvalidArgument(format!(
            "ridge and smoothness must be finite and >= 0, got {} and {}",
            opts.ridge, opts.smoothness
        )));
    }
    let q = gram.nrows();
    let scale = (gram.trace() / q as f64).max(f64::MIN_POSITIVE);
    let ridge = opts.ridge * scale;
    for i in 0..p {
        gram[(i, i)] += ridge;
    }
    if let (Some(n), true) = (grid, opts.smoothness > 0.0) {
        let s = opts.smoothness * scale;
        let mut pair = |a: usize, b: usize| {
            gram[(a, a)] += s;
            gram[(b, b)] += s;
            gram[(a, b)] -= s;
            gram[(b, a)] -= s;
        };
        for k in 0..n {
            for l in 0..k {
                if k + 1 < n {
                    pair(cell_index(k, l), cell_index(k + 1, l));
                }
                if l + 1 < k {
                    pair(cell_index(k, l), cell_index(k, l + 1));
                }
            }
        }
    }
    if free.iter().all(|f| *f) {
        return solve_subset(&gram, &rhs, free);
    }
    nnls_normal(&gram, &rhs, free)
}

/// Solve the sub-system of the unknowns marked `active`; the others are 0.
fn solve_subset(
    gram: &DMatrix<f64>,
    rhs: &DVector<f64>,
    active: &[bool],
) -> Result<DVector<f64>, PreisachError> {
    let idx: Vec<usize> = (0..active.len()).filter(|&i| active[i]).collect();
    let mut out = DVector::zeros(active.len());
    if idx.is_empty() {
        return Ok(out);
    }
    let m = idx.len();
    let sub = DMatrix::from_fn(m, m, |r, c| gram[(idx[r], idx[c])]);
    let b = DVector::from_fn(m, |r, _| rhs[idx[r]]);
    let sol = match sub.clone().cholesky() {
        Some(ch) => ch.solve(&b),
        None => sub.lu().solve(&b).ok_or_else(|| {
            PreisachError::Numerical("singular normal equations; increase the ridge".into())
        })?,
    };
    for (r, &i) in idx.iter().enumerate() {
        out[i] = sol[r];
    }
    Ok(out)
}

/// Non-negative least squares on the normal equations (Lawson–Hanson active
/// set in the form of Bro & De Jong 1997): min ½wᵀGw − bᵀw, w_i ≥ 0 unless
/// `free[i]`.
fn nnls_normal(
    gram: &DMatrix<f64>,
    rhs: &DVector<f64>,
    free: &[bool],
) -> Result<DVector<f64>, PreisachError> {
    let q = rhs.len();
    let mut passive = free.to_vec();
    let mut w = solve_subset(gram, rhs, &passive)?;
    let tol = 1e-12 * rhs.amax().max(1e-300) * (q as f64);
    let max_outer = 3 * q + 10;
    for _ in 0..max_outer {
        let grad = rhs - gram * &w;
        let mut best = None;
        let mut gmax = tol;
        for i in 0..q {
            if !passive[i] && grad[i] > gmax {
                gmax = grad[i];
                best = Some(i);
            }
        }
        let Some(j) = best else {
            return Ok(w);
        };
        passive[j] = true;
        for _ in 0..=q {
            let s = solve_subset(gram, rhs, &passive)?;
            let mut alpha = f64::INFINITY;
            let mut arg = None;
            for i in 0..q {
                if passive[i] && !free[i] && s[i] <= 0.0 {
                    let a = w[i] / (w[i] - s[i]);
                    if a < alpha {
                        alpha = a;
                        arg = Some(i);
                    }
                }
            }
            let Some(drop) = arg else {
                w = s;
                break;
            };
            w += (s - &w) * alpha;
            w[drop] = 0.0;
            passive[drop] = false;
            for i in 0..q {
                if passive[i] && !free[i] && w[i] <= 0.0 {
                    w[i] = 0.0;
                    passive[i] = false;
                }
            }
        }
    }
    Err(PreisachError::Numerical(
        "non-negative least squares did not converge".into(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nnls_matches_known_solution() {
        // min ‖A w − b‖², w ≥ 0 with A = I, b = (1, −2, 3): w = (1, 0, 3).
        let g = DMatrix::identity(3, 3);
        let b = DVector::from_vec(vec![1.0, -2.0, 3.0]);
        let w = nnls_normal(&g, &b, &[false; 3]).unwrap();
        assert_eq!(w.as_slice(), &[1.0, 0.0, 3.0]);
        // Coupled case checked against KKT conditions.
        let a = DMatrix::from_row_slice(
            4,
            3,
            &[1.0, 0.5, 0.0, 0.2, 1.0, 0.3, 0.0, 0.4, 1.0, 0.7, 0.1, 0.2],
        );
        let b = DVector::from_vec(vec![1.0, -1.0, 0.5, 0.2]);
        let (g, r) = (a.transpose() * &a, a.transpose() * &b);
        let w = nnls_normal(&g, &r, &[false, false, true]).unwrap();
        let grad = &r - &g * &w;
        for i in 0..3 {
            if i == 2 || w[i] > 0.0 {
                assert!(grad[i].abs() < 1e-12);
            } else {
                assert!(w[i] == 0.0 && grad[i] <= 1e-12);
            }
        }
    }
}
