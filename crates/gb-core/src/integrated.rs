//! The integrated output-error criterion of a model of increments.
//!
//! An integrating system (a pole at 1: a position driven by a force) is
//! modelled by its increments `Δy(k) = y(k) − y(k−1)`; what the user sees
//! is their running sum. With white noise on the measured output, the
//! maximum-likelihood criterion is the error of that running sum, not of
//! the increments, with its mean (the free start value) projected out:
//!
//! ```text
//! Eₖ = Σ_{j≤k} eⱼ,   V = Σₖ (Eₖ − Ē)²,   ∂V/∂θ ∝ Σₖ (Sₖ − S̄)(Eₖ − Ē),   Sₖ = Σ_{j≤k} ∂eⱼ/∂θ
//! ```
//!
//! ```
//! use gb_core::integrated::integrated_cost;
//! // running sums 1, 3, 6: mean 10/3, V = (7/3)² + (1/3)² + (8/3)² = 38/3
//! let v = integrated_cost([1.0, 2.0, 3.0].into_iter());
//! assert!((v - 38.0 / 3.0).abs() < 1e-12);
//! ```

/// Running sums of the integrated criterion along one record: `Eₖ`, `Sₖ`
/// and their sums over `k` (for the mean projected out of the normal
/// equations, [`RunningSum::project_mean`]).
#[derive(Debug, Clone)]
pub struct RunningSum {
    acc_e: f64,
    acc_s: Vec<f64>,
    sum_e: f64,
    sum_s: Vec<f64>,
    count: f64,
}

impl RunningSum {
    /// Empty sums for sensitivity rows of length `np`.
    pub fn new(np: usize) -> Self {
        Self {
            acc_e: 0.0,
            acc_s: vec![0.0; np],
            sum_e: 0.0,
            sum_s: vec![0.0; np],
            count: 0.0,
        }
    }

    /// Add sample k's error `e` and its sensitivity row `s`; returns `Eₖ`
    /// (`Sₖ` is then [`RunningSum::row`]).
    #[inline]
    pub fn add(&mut self, e: f64, s: &[f64]) -> f64 {
        self.acc_e += e;
        self.sum_e += self.acc_e;
        for ((a, t), v) in self.acc_s.iter_mut().zip(self.sum_s.iter_mut()).zip(s) {
            *a += v;
            *t += *a;
        }
        self.count += 1.0;
        self.acc_e
    }

    /// `Sₖ`, the running sum of the sensitivity rows added so far.
    pub fn row(&self) -> &[f64] {
        &self.acc_s
    }

    /// Project the mean out of `JᵀJ = ΣSSᵀ` (`jtj`, `np × np`, any
    /// symmetric layout) and `Jᵀe = ΣSE`: `JᵀJ − (ΣS)(ΣS)ᵀ/N`,
    /// `Jᵀe − (ΣS)(ΣE)/N`; returns `(ΣE)²/N`, the part of `ΣE²` to
    /// subtract from the cost.
    pub fn project_mean(&self, jtj: &mut [f64], jtr: &mut [f64]) -> f64 {
        if self.count < 1.0 {
            return 0.0;
        }
        let (n, np) = (self.count, self.sum_s.len());
        for (i, si) in self.sum_s.iter().enumerate() {
            jtr[i] -= si * self.sum_e / n;
            for (j, sj) in self.sum_s.iter().enumerate() {
                jtj[i * np + j] -= si * sj / n;
            }
        }
        self.sum_e * self.sum_e / n
    }
}

/// `Σₖ (Eₖ − Ē)²` of the running sum `Eₖ` of the errors `e`.
pub fn integrated_cost(e: impl Iterator<Item = f64>) -> f64 {
    let (mut acc, mut s1, mut s2, mut n) = (0.0, 0.0, 0.0, 0.0);
    for v in e {
        acc += v;
        s1 += acc;
        s2 += acc * acc;
        n += 1.0;
    }
    if n < 1.0 {
        0.0
    } else {
        s2 - s1 * s1 / n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The projected normal equations equal those of the explicitly
    /// centred running sums (built here by a separate route: cumulative
    /// sums, then the mean subtracted).
    #[test]
    fn projected_normal_equations_match_the_centred_running_sums() {
        let e = [0.3, -1.2, 0.7, 2.0, -0.4];
        let s = [
            [1.0, 0.5],
            [0.2, -0.3],
            [-0.7, 1.1],
            [0.4, 0.0],
            [0.9, -2.0],
        ];
        let mut run = RunningSum::new(2);
        let (mut jtj, mut jtr, mut cost) = (vec![0.0; 4], vec![0.0; 2], 0.0);
        for (ek, sk) in e.iter().zip(&s) {
            let big_e = run.add(*ek, sk);
            cost += big_e * big_e;
            let r = run.row().to_vec();
            for i in 0..2 {
                jtr[i] += r[i] * big_e;
                for j in 0..2 {
                    jtj[i * 2 + j] += r[i] * r[j];
                }
            }
        }
        cost -= run.project_mean(&mut jtj, &mut jtr);
        // the explicit route
        let cum = |v: Vec<f64>| {
            v.iter()
                .scan(0.0, |a, x| {
                    *a += x;
                    Some(*a)
                })
                .collect::<Vec<_>>()
        };
        let centred = |v: Vec<f64>| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            v.iter().map(|x| x - m).collect::<Vec<_>>()
        };
        let ec = centred(cum(e.to_vec()));
        let sc: Vec<Vec<f64>> = (0..2)
            .map(|i| centred(cum(s.iter().map(|r| r[i]).collect())))
            .collect();
        let want_cost: f64 = ec.iter().map(|x| x * x).sum();
        assert!((cost - want_cost).abs() < 1e-12);
        assert!((integrated_cost(e.iter().copied()) - want_cost).abs() < 1e-12);
        for i in 0..2 {
            let g: f64 = sc[i].iter().zip(&ec).map(|(a, b)| a * b).sum();
            assert!((jtr[i] - g).abs() < 1e-12);
            for j in 0..2 {
                let h: f64 = sc[i].iter().zip(&sc[j]).map(|(a, b)| a * b).sum();
                assert!((jtj[i * 2 + j] - h).abs() < 1e-12);
            }
        }
    }
}
