//! Residual evidence: whiteness, input cross-correlation, higher-order
//! correlation tests (Billings & Voon 1986), a normality test, and a memory
//! test separating hysteresis (direction-dependent residual) from static
//! nonlinearity.
use crate::stats;
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

/// Correlation lags examined.
pub const MAX_LAG: usize = 25;

/// The evidence computed from one model's residuals.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Evidence {
    /// Samples used.
    pub samples: usize,
    /// 95 % confidence band of a correlation under whiteness, 1.96/√N.
    pub band: f64,
    /// Residual auto-correlation r_ee(τ), τ = 0..=25.
    pub autocorrelation: Vec<f64>,
    /// Ljung–Box statistic and p-value of r_ee(1..=25).
    pub ljung_box: (f64, f64),
    /// Input–residual cross-correlation r_ue(τ), τ = 0..=25, per input.
    pub cross_correlation: Vec<Vec<f64>>,
    /// Higher-order test r_{u²'e}(τ) (squared input vs residual), per input.
    pub cross_correlation_u2_e: Vec<Vec<f64>>,
    /// Higher-order test r_{u²'e²}(τ), per input.
    pub cross_correlation_u2_e2: Vec<Vec<f64>>,
    /// Skewness, excess kurtosis, Jarque–Bera statistic and p-value.
    pub normality: (f64, f64, f64, f64),
    /// F statistic and p-value of static nonlinear terms (ŷ², ŷ³, u², u³) explaining the residual.
    pub static_nonlinearity: (f64, f64),
    /// F statistic and p-value of direction-of-motion terms (memory) beyond the static ones.
    pub memory: (f64, f64),
}

fn count_outside(r: &[f64], band: f64, from: usize) -> usize {
    r.iter().skip(from).filter(|v| v.abs() > band).count()
}

impl Evidence {
    /// Compute the evidence from residuals `e`, simulated output `yhat` and
    /// inputs `u` (all over the same samples).
    pub fn compute(e: &[f64], yhat: &[f64], u: &[Vec<f64>]) -> Self {
        let n = e.len();
        let band = 1.96 / (n as f64).sqrt();
        let acf = stats::autocorrelation(e, MAX_LAG);
        let lb = stats::ljung_box(&acf, n);
        let e2: Vec<f64> = e.iter().map(|v| v * v).collect();
        let mut ccf = vec![];
        let mut c2 = vec![];
        let mut c22 = vec![];
        for uj in u {
            ccf.push(stats::cross_correlation(uj, e, MAX_LAG));
            let m = gb_core::metrics::mean(uj);
            let u2: Vec<f64> = uj.iter().map(|v| (v - m) * (v - m)).collect();
            c2.push(stats::cross_correlation(&u2, e, MAX_LAG));
            c22.push(stats::cross_correlation(&u2, &e2, MAX_LAG));
        }
        let normality = stats::jarque_bera(e);
        let (static_nl, memory) = memory_tests(e, yhat, u);
        Self {
            samples: n,
            band,
            autocorrelation: acf,
            ljung_box: lb,
            cross_correlation: ccf,
            cross_correlation_u2_e: c2,
            cross_correlation_u2_e2: c22,
            normality,
            static_nonlinearity: static_nl,
            memory,
        }
    }

    /// Sentence for the `dynamics` cause.
    pub fn dynamics_text(&self) -> String {
        let out_acf = count_outside(&self.autocorrelation, self.band, 1);
        let max_cc = self
            .cross_correlation
            .iter()
            .flat_map(|c| c.iter())
            .fold(0.0f64, |a, v| a.max(v.abs()));
        format!(
            "residual auto-correlation outside ±{:.3} at {}/{} lags (Ljung-Box Q={:.0}, p={:.1e}); max |r_ue|={:.3}",
            self.band, out_acf, MAX_LAG, self.ljung_box.0, self.ljung_box.1, max_cc
        )
    }

    /// Sentence for the `nonlinearity` cause.
    pub fn nonlinearity_text(&self) -> String {
        let ho: usize = self
            .cross_correlation_u2_e
            .iter()
            .chain(&self.cross_correlation_u2_e2)
            .map(|r| count_outside(r, self.band, 0))
            .sum();
        format!(
            "static nonlinear terms explain the residual (F={:.1}, p={:.1e}); higher-order correlations r_u2'e, r_u2'e2 outside band at {} lags",
            self.static_nonlinearity.0, self.static_nonlinearity.1, ho
        )
    }

    /// Sentence for the `hysteresis` cause.
    pub fn hysteresis_text(&self) -> String {
        format!(
            "residual depends on the direction of motion at equal level, a loop (memory F={:.1}, p={:.1e})",
            self.memory.0, self.memory.1
        )
    }

    /// Sentence for the `noise` cause.
    pub fn noise_text(&self) -> String {
        format!(
            "residual is heavy-tailed: excess kurtosis {:.2}, skewness {:.2} (Jarque-Bera {:.0}, p={:.1e})",
            self.normality.1, self.normality.0, self.normality.2, self.normality.3
        )
    }
}

/// Least-squares residual sum of squares of `y` on the columns of `x`.
fn rss(x: &[Vec<f64>], y: &[f64]) -> f64 {
    let n = y.len();
    let p = x.len();
    let mut a = DMatrix::<f64>::zeros(n, p);
    for (j, c) in x.iter().enumerate() {
        for i in 0..n {
            a[(i, j)] = c[i];
        }
    }
    let b = DVector::from_column_slice(y);
    let ata = a.transpose() * &a + DMatrix::<f64>::identity(p, p) * 1e-10;
    let atb = a.transpose() * &b;
    match ata.cholesky() {
        Some(ch) => {
            let th = ch.solve(&atb);
            (b - a * th).norm_squared()
        }
        None => y.iter().map(|v| v * v).sum(),
    }
}

fn f_test(rss0: f64, rss1: f64, q: usize, n: usize, p1: usize) -> (f64, f64) {
    let d2 = n.saturating_sub(p1).max(1) as f64;
    let f = ((rss0 - rss1).max(0.0) / q as f64) / (rss1 / d2).max(1e-300);
    (f, stats::f_sf(f, q as f64, d2))
}

/// (static nonlinearity test, memory test) on the residual.
fn memory_tests(e: &[f64], yhat: &[f64], u: &[Vec<f64>]) -> ((f64, f64), (f64, f64)) {
    let n = e.len();
    if n < 50 {
        return ((0.0, 1.0), (0.0, 1.0));
    }
    let norm = |x: &[f64]| -> Vec<f64> {
        let m = gb_core::metrics::mean(x);
        let s = gb_core::metrics::std(x).max(1e-300);
        x.iter().map(|v| (v - m) / s).collect()
    };
    let yn = norm(yhat);
    // direction of motion of the simulated output
    let s: Vec<f64> = (0..n)
        .map(|k| {
            if k == 0 {
                0.0
            } else {
                (yhat[k] - yhat[k - 1]).signum()
            }
        })
        .collect();
    let mut base: Vec<Vec<f64>> = vec![vec![1.0; n], yn.clone()];
    let mut nl: Vec<Vec<f64>> = vec![
        yn.iter().map(|v| v * v).collect(),
        yn.iter().map(|v| v * v * v).collect(),
    ];
    for uj in u {
        let un = norm(uj);
        base.push(un.clone());
        nl.push(un.iter().map(|v| v * v).collect());
        nl.push(un.iter().map(|v| v * v * v).collect());
    }
    let rss_base = rss(&base, e);
    let mut stat: Vec<Vec<f64>> = base.clone();
    stat.extend(nl.iter().cloned());
    let rss_stat = rss(&stat, e);
    let t_static = f_test(rss_base, rss_stat, nl.len(), n, stat.len());
    let dir: Vec<Vec<f64>> = vec![
        s.clone(),
        s.iter().zip(&yn).map(|(a, b)| a * b).collect(),
        s.iter().zip(&yn).map(|(a, b)| a * b * b).collect(),
    ];
    let mut full = stat.clone();
    full.extend(dir.iter().cloned());
    let rss_full = rss(&full, e);
    let t_mem = f_test(rss_stat, rss_full, dir.len(), n, full.len());
    (t_static, t_mem)
}
