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

/// A discrete Preisach operator whose density is constant on each cell of
/// a uniform triangular grid over [−h, h]: `levels` intervals of width
/// d = 2h/levels per axis, one cell Cᵢⱼ = [αᵢ, αᵢ + d] × [βⱼ, βⱼ + d] for
/// every i ≥ j (the diagonal cells cut to α ≥ β). Its column for cell C is
/// the mean relay state over the cell,
///
/// c_C[x](k) = (1/|C|) ∬_C γ_{αβ}[x](k) dα dβ,
///
/// approximated by `sub` × `sub` relays at the centres of a sub-grid of the
/// cell (sub(sub + 1)/2 on a diagonal cell). The model output Σ_C μ_C c_C
/// is the Preisach operator of the piecewise-constant density μ
/// (Mayergoyz 2003, ch. 1; Hauth 2008, sec. 3.3): linear in the cell
/// weights μ_C, like the hard relays of [`RelayGrid::uniform`], but moving
/// in `sub`² steps per cell instead of one jump, so that a hysteresis loop
/// narrower than a cell is represented. `sub = 1` is
/// [`RelayGrid::uniform`].
///
/// A step only visits the relays whose threshold lies between the last
/// input and the new one (relays sorted by α and by β): after an input x
/// every relay with α ≤ x is up and every other relay with β ≥ x is down,
/// so a rise to x′ > x can only switch up relays with α ∈ [x, x′], a fall
/// only switch down relays with β ∈ [x′, x]. The per-cell sums of the ±1
/// states are integers, exact in floating point, so the columns are those
/// of a pass over every relay to the last bit.
///
/// ```
/// use gb_preisach::RelayCells;
/// let c = RelayCells::uniform(1, 1.0, 4).unwrap(); // one cell, 10 relays
/// let mut s = c.relay_states(-2.0);
/// let mut col = [0.0];
/// c.columns(&s, &mut col);
/// assert_eq!(col, [-1.0]);
/// c.step(&mut s, 0.0, &mut col); // x passes the α < 0 half: 3 of 10 relays up
/// assert!((col[0] - (-1.0 + 2.0 * 3.0 / 10.0)).abs() < 1e-12);
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct RelayCells {
    relays: RelayGrid,
    cell: Vec<usize>,
    inv_size: Vec<f64>,
    /// relay indices in increasing α, and those α
    by_alpha: Vec<usize>,
    alpha_sorted: Vec<f64>,
    /// relay indices in increasing β, and those β
    by_beta: Vec<usize>,
    beta_sorted: Vec<f64>,
}

/// The state of a [`RelayCells`] operator: the relay states (±1), their
/// sum per cell, and the last input.
#[derive(Debug, Clone, PartialEq)]
pub struct RelayCellsState {
    relays: Vec<f64>,
    sums: Vec<f64>,
    last: f64,
}

impl RelayCellsState {
    /// The relay states (±1), in the order of the cells.
    pub fn relays(&self) -> &[f64] {
        &self.relays
    }
}

impl RelayCells {
    /// `levels` ≥ 1 intervals over [−`half_range`, `half_range`], `sub` ≥ 1
    /// relays per cell side.
    pub fn uniform(levels: usize, half_range: f64, sub: usize) -> Result<Self, PreisachError> {
        if !(half_range.is_finite() && half_range > 0.0) || levels == 0 || sub == 0 {
            return Err(PreisachError::InvalidArgument(format!(
                "relay cells need half_range > 0, levels >= 1 and sub >= 1, got {half_range}, {levels}, {sub}"
            )));
        }
        // the expression of `RelayGrid::uniform` at sub = 1, so that the
        // thresholds (and the demagnetised start's ties α + β = 2x₀) agree
        // to the last bit
        let at = |i: usize, p: usize| {
            -half_range + 2.0 * half_range * ((i * sub + p) as f64 + 0.5) / (levels * sub) as f64
        };
        let (mut alpha, mut beta, mut cell, mut inv_size) = (vec![], vec![], vec![], vec![]);
        for i in 0..levels {
            for j in 0..=i {
                let c = inv_size.len();
                let mut n = 0usize;
                for p in 0..sub {
                    for q in 0..sub {
                        if i == j && q > p {
                            continue;
                        }
                        alpha.push(at(i, p));
                        beta.push(at(j, q));
                        cell.push(c);
                        n += 1;
                    }
                }
                inv_size.push(1.0 / n as f64);
            }
        }
        let sorted = |t: &[f64]| {
            let mut idx: Vec<usize> = (0..t.len()).collect();
            idx.sort_by(|&a, &b| t[a].total_cmp(&t[b]));
            let vals = idx.iter().map(|&i| t[i]).collect::<Vec<_>>();
            (idx, vals)
        };
        let (by_alpha, alpha_sorted) = sorted(&alpha);
        let (by_beta, beta_sorted) = sorted(&beta);
        let weight = vec![1.0; alpha.len()];
        Ok(Self {
            relays: RelayGrid::new(alpha, beta, weight)?,
            cell,
            inv_size,
            by_alpha,
            alpha_sorted,
            by_beta,
            beta_sorted,
        })
    }

    /// Number of cells (columns): levels·(levels + 1)/2.
    pub fn n_cells(&self) -> usize {
        self.inv_size.len()
    }

    /// The state for a start at `x0`: relay states as
    /// [`RelayGrid::relay_states`].
    pub fn relay_states(&self, x0: f64) -> RelayCellsState {
        let relays = self.relays.relay_states(x0);
        let mut sums = vec![0.0; self.n_cells()];
        for (&s, &c) in relays.iter().zip(&self.cell) {
            sums[c] += s;
        }
        RelayCellsState {
            relays,
            sums,
            last: x0,
        }
    }

    /// The cell columns (mean relay state per cell) into `out`
    /// (length [`n_cells`](Self::n_cells)).
    #[inline]
    pub fn columns(&self, state: &RelayCellsState, out: &mut [f64]) {
        for ((o, s), w) in out.iter_mut().zip(&state.sums).zip(&self.inv_size) {
            *o = s * w;
        }
    }

    /// Switch the relays with the input `x` (up when x ≥ α, down when
    /// x ≤ β) and write the [`columns`](Self::columns) into `out`.
    #[inline]
    pub fn step(&self, state: &mut RelayCellsState, x: f64, out: &mut [f64]) {
        let last = state.last;
        if last.is_nan() {
            // no ordered start (a NaN input): one pass over every relay
            self.relays.switch(&mut state.relays, x);
            state.sums.fill(0.0);
            for (&s, &c) in state.relays.iter().zip(&self.cell) {
                state.sums[c] += s;
            }
        } else if x > last {
            let lo = self.alpha_sorted.partition_point(|&a| a < last);
            let hi = self.alpha_sorted.partition_point(|&a| a <= x);
            for &r in &self.by_alpha[lo..hi] {
                if state.relays[r] != 1.0 {
                    state.relays[r] = 1.0;
                    state.sums[self.cell[r]] += 2.0;
                }
            }
        } else if x < last {
            let lo = self.beta_sorted.partition_point(|&b| b < x);
            let hi = self.beta_sorted.partition_point(|&b| b <= last);
            let alpha = &self.relays.alpha;
            for &r in &self.by_beta[lo..hi] {
                if alpha[r] > x && state.relays[r] != -1.0 {
                    state.relays[r] = -1.0;
                    state.sums[self.cell[r]] -= 2.0;
                }
            }
        }
        if !x.is_nan() {
            state.last = x;
        }
        self.columns(state, out);
    }
}

#[cfg(test)]
mod cell_tests {
    use super::*;

    #[test]
    fn one_relay_per_cell_is_the_uniform_grid() {
        let g = RelayGrid::uniform(6, 2.5).unwrap();
        let c = RelayCells::uniform(6, 2.5, 1).unwrap();
        let x = [0.3, -1.7, 2.2, 0.9, -0.4, 1.1, -2.6, 0.0];
        for x0 in [0.0, 0.1] {
            assert_eq!(
                g.relay_states(x0),
                c.relay_states(x0).relays(),
                "start at {x0}"
            );
        }
        let (mut sg, mut sc) = (g.relay_states(0.1), c.relay_states(0.1));
        let mut col = vec![0.0; c.n_cells()];
        for &v in &x {
            g.switch(&mut sg, v);
            c.step(&mut sc, v, &mut col);
            assert_eq!(col, sg);
            assert_eq!(sc.relays(), &sg[..]);
        }
    }

    /// The step that visits only the relays between the last and the new
    /// input gives, to the last bit, the relays and columns of a pass over
    /// every relay: a random walk, jumps, repeats, inputs exactly on
    /// thresholds, outside the range, and a NaN.
    #[test]
    fn the_ordered_step_is_the_pass_over_every_relay() {
        let (levels, h, sub) = (7, 1.3, 3);
        let c = RelayCells::uniform(levels, h, sub).unwrap();
        let g = &c.relays;
        let on_threshold = g.alpha[11];
        let mut x = vec![
            0.2,
            0.2,
            on_threshold,
            g.beta[5],
            3.0,
            -3.0,
            f64::NAN,
            0.4,
            0.4,
        ];
        let mut v = 0.0f64;
        let mut seed = 12345u64;
        for _ in 0..2000 {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let r = (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
            v = if r.abs() < 0.01 {
                2.0 * r * h * 50.0
            } else {
                (v + 0.3 * r).clamp(-1.6, 1.6)
            };
            x.push(v);
        }
        for x0 in [0.0, 0.37, -2.0, f64::NAN] {
            let mut full = g.relay_states(x0);
            let mut st = c.relay_states(x0);
            let (mut col, mut expect) = (vec![0.0; c.n_cells()], vec![0.0; c.n_cells()]);
            for (k, &xk) in x.iter().enumerate() {
                g.switch(&mut full, xk);
                expect.fill(0.0);
                for (&s, &cell) in full.iter().zip(&c.cell) {
                    expect[cell] += s;
                }
                for (e, w) in expect.iter_mut().zip(&c.inv_size) {
                    *e *= w;
                }
                c.step(&mut st, xk, &mut col);
                assert_eq!(st.relays(), &full[..], "relays at k = {k}, x0 = {x0}");
                assert_eq!(col, expect, "columns at k = {k}, x0 = {x0}");
            }
        }
    }

    /// A cell's column moves in proportion to the area of the cell that
    /// the input sweeps: from saturation down, rising to the middle of an
    /// off-diagonal cell's α range switches half of its relays up.
    #[test]
    fn a_cell_column_is_its_swept_area_fraction() {
        let c = RelayCells::uniform(2, 1.0, 8).unwrap(); // cells of width 1
        let mut s = c.relay_states(-5.0);
        let mut col = vec![0.0; 3];
        c.step(&mut s, 0.5, &mut col); // the cell α ∈ [0, 1], β ∈ [−1, 0] is index 1
        assert!((col[1] - 0.0).abs() < 1e-12, "{col:?}");
        // the lower diagonal cell (α, β ∈ [−1, 0]) is fully up; of the
        // upper one (36 relays, α ≥ β) those with α ≤ 0.5 are: 1+2+3+4 = 10
        assert_eq!(col[0], 1.0);
        assert!(
            (col[2] - (2.0 * 10.0 / 36.0 - 1.0)).abs() < 1e-12,
            "{col:?}"
        );
        // coming back down to −0.25 switches the relays with β ≥ −0.25 down
        c.step(&mut s, -0.25, &mut col);
        // relays of the cell up: α ≤ 0.5 (4 of 8 columns) and β < −0.25
        // (6 of 8 rows): 24 of 64 → column 2·24/64 − 1
        assert!(
            (col[1] - (2.0 * 24.0 / 64.0 - 1.0)).abs() < 1e-12,
            "{col:?}"
        );
    }
}
