//! Preisach components whose Everett (primitive) function is a 2-D wavelet
//! expansion — the thesis' "two-dimensional primitive functions"
//! (Hauth 2008, ch. 5).
//!
//! With a 2-D expansion `E(α, β) = Σ_λ c_λ Ψ_λ(α, β)` on `[lo, hi]²` the
//! Everett function is
//!
//! ```text
//! F(α, β) = E(α, β) − ½ (E(α, α) + E(β, β)),
//! ```
//!
//! so `F(x, x) = 0` (no jump when a new link of the staircase opens) and `F`
//! stays **linear in the coefficients**. The Preisach output
//! `y = −F(α₀, β₀) + 2 Σ_j (−1)^{j+1} F(max(s_{j−1}, s_j), min(s_{j−1}, s_j))`
//! (Mayergoyz 2003; `gb-preisach`) is then `y(t) = r(t)ᵀ c` with the
//! regressor `r_λ(t)`, the same staircase sum of the basis functions
//! `B_λ(α, β) = Ψ_λ(α, β) − ½(Ψ_λ(α, α) + Ψ_λ(β, β))`.
use crate::basis::{EvalScratch, SparseExpansion};
use crate::error::{ModelError, Result};
use gb_preisach::Everett;
use serde::{Deserialize, Serialize};

/// An Everett function given by a sparse 2-D wavelet expansion; implements
/// [`gb_preisach::Everett`], so `gb_preisach::Preisach<WaveletEverett>`
/// simulates it.
///
/// ```
/// use gb_model::{SparseExpansion, WaveletEverett};
/// use gb_preisach::{Everett, InitialState, Preisach};
/// let mut e = SparseExpansion::new("bior2.2", vec![-1.0, -1.0], vec![1.0, 1.0])?;
/// e.add_coarse_grid(1)?;
/// let n = e.len();
/// e.set_values(&(0..n).map(|i| (i % 3) as f64 * 0.1).collect::<Vec<_>>())?;
/// let f = WaveletEverett::new(e)?;
/// assert_eq!(f.everett(0.3, 0.3), 0.0);
/// let p = Preisach::new(f);
/// let y = p.simulate(&[0.0, 0.8, 0.1, -0.8, 0.1], &InitialState::NegativeSaturation)?;
/// assert_eq!(y.len(), 5);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WaveletEverett {
    expansion: SparseExpansion,
}

impl WaveletEverett {
    /// Wraps a 2-D expansion whose box is a square `[lo, hi]²`.
    pub fn new(expansion: SparseExpansion) -> Result<Self> {
        if expansion.dims() != 2
            || expansion.lo()[0] != expansion.lo()[1]
            || expansion.hi()[0] != expansion.hi()[1]
        {
            return Err(ModelError::InvalidArgument(
                "an Everett expansion needs a square 2-D box [lo, hi]^2".into(),
            ));
        }
        Ok(Self { expansion })
    }
    /// The expansion `E`.
    pub fn expansion(&self) -> &SparseExpansion {
        &self.expansion
    }
    /// Mutable access (identification sets the coefficients).
    pub fn expansion_mut(&mut self) -> &mut SparseExpansion {
        &mut self.expansion
    }

    fn f(&self, a: f64, b: f64) -> f64 {
        let e = &self.expansion;
        e.eval(&[a, b]) - 0.5 * (e.eval(&[a, a]) + e.eval(&[b, b]))
    }

    /// Regressors `r_λ(t)` of the Preisach output for the input `x`, from
    /// negative saturation: `out[t * n + λ]`, `n` = number of coefficients.
    pub fn regressors(&self, x: &[f64]) -> Vec<f64> {
        let n = self.expansion.len();
        let (lo, hi) = self.support();
        let mut out = vec![0.0; x.len() * n];
        let mut stack = vec![lo];
        let mut cur = lo;
        let mut scratch = EvalScratch::default();
        let mut link = vec![0.0; n];
        // −B(hi, lo)
        let mut base = vec![0.0; n];
        self.add_basis(hi, lo, -1.0, &mut base, &mut link, &mut scratch);
        for (t, &xt) in x.iter().enumerate() {
            let xt = if xt.is_nan() { lo } else { xt.clamp(lo, hi) };
            let asc = stack.len() % 2 == 1;
            if (asc && xt < cur) || (!asc && xt > cur) {
                stack.push(cur);
            }
            cur = xt;
            loop {
                let l = stack.len();
                if l < 3 {
                    break;
                }
                let asc = l % 2 == 1;
                if (asc && xt >= stack[l - 2]) || (!asc && xt <= stack[l - 2]) {
                    stack.truncate(l - 2);
                } else {
                    break;
                }
            }
            let row = &mut out[t * n..(t + 1) * n];
            row.copy_from_slice(&base);
            for j in 1..=stack.len() {
                let a = stack[j - 1];
                let b = if j < stack.len() { stack[j] } else { cur };
                let sign = if j % 2 == 1 { 2.0 } else { -2.0 };
                self.add_basis(a.max(b), a.min(b), sign, row, &mut link, &mut scratch);
            }
        }
        out
    }

    /// `row += w · B(a, b)` for all basis functions.
    fn add_basis(
        &self,
        a: f64,
        b: f64,
        w: f64,
        row: &mut [f64],
        _tmp: &mut [f64],
        s: &mut EvalScratch,
    ) {
        if a <= b {
            return;
        }
        let e = &self.expansion;
        e.eval_with(&[a, b], None, true, s);
        for &(i, v) in &s.basis {
            row[i as usize] += w * v;
        }
        e.eval_with(&[a, a], None, true, s);
        for &(i, v) in &s.basis {
            row[i as usize] -= 0.5 * w * v;
        }
        e.eval_with(&[b, b], None, true, s);
        for &(i, v) in &s.basis {
            row[i as usize] -= 0.5 * w * v;
        }
    }
}

impl Everett for WaveletEverett {
    type Node = f64;
    fn support(&self) -> (f64, f64) {
        (self.expansion.lo()[0], self.expansion.hi()[0])
    }
    fn node(&self, x: f64) -> f64 {
        x
    }
    fn value(&self, alpha: &f64, beta: &f64) -> f64 {
        if alpha <= beta {
            return 0.0;
        }
        self.f(*alpha, *beta)
    }
    fn partials(&self, alpha: &f64, beta: &f64) -> (f64, f64) {
        let e = &self.expansion;
        let mut s = EvalScratch::default();
        let mut g = [0.0; 2];
        let mut ga = [0.0; 2];
        let mut gb = [0.0; 2];
        e.eval_with(&[*alpha, *beta], Some(&mut g), false, &mut s);
        e.eval_with(&[*alpha, *alpha], Some(&mut ga), false, &mut s);
        e.eval_with(&[*beta, *beta], Some(&mut gb), false, &mut s);
        (g[0] - 0.5 * (ga[0] + ga[1]), g[1] - 0.5 * (gb[0] + gb[1]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gb_preisach::{InitialState, Preisach};

    #[test]
    fn regressors_reproduce_the_preisach_operator() {
        let mut e = SparseExpansion::new("bior2.2", vec![-1.0, -1.0], vec![1.0, 1.0]).unwrap();
        e.add_coarse_grid(2).unwrap();
        let c = e.detail_candidates(2);
        e.extend_unchecked(c);
        let n = e.len();
        let vals: Vec<f64> = (0..n)
            .map(|i| (((i * 7919) % 17) as f64 - 8.0) * 0.05)
            .collect();
        e.set_values(&vals).unwrap();
        let f = WaveletEverett::new(e).unwrap();
        let x: Vec<f64> = (0..400)
            .map(|t| 0.9 * (t as f64 * 0.05).sin() * (t as f64 * 0.011).cos())
            .collect();
        let p = Preisach::new(f.clone());
        let y = p.simulate(&x, &InitialState::NegativeSaturation).unwrap();
        let r = f.regressors(&x);
        for t in 0..x.len() {
            let yr: f64 = (0..n).map(|k| r[t * n + k] * vals[k]).sum();
            assert!((yr - y[t]).abs() < 1e-9, "t {t}: {yr} vs {}", y[t]);
        }
    }
}
