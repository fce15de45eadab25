//! Standard normal density, tail probability, Mills ratio and quantile.

use std::f64::consts::PI;

/// φ(x) = exp(−x²/2)/√(2π).
pub fn norm_pdf(x: f64) -> f64 {
    (-0.5 * x * x).exp() / (2.0 * PI).sqrt()
}

/// Σ_k x^{2k+1}/(2k+1)!!, so that Φ(x) = 1/2 + φ(x)·series(x).
fn odd_series(x: f64) -> f64 {
    let mut sum = 0.0f64;
    let mut term = x;
    let mut k = 0.0;
    while term.abs() > 1e-17 * sum.abs() || k < 3.0 {
        sum += term;
        k += 1.0;
        term *= x * x / (2.0 * k + 1.0);
    }
    sum
}

/// Laplace's continued fraction `R(x) = 1/(x+1/(x+2/(x+3/(x+…))))`, `x ≥ 2.5`.
fn mills_cf(x: f64) -> f64 {
    let mut t = x;
    for k in (1..=120).rev() {
        t = x + k as f64 / t;
    }
    1.0 / t
}

/// Mills ratio `R(x) = Φ̃(x)/φ(x)` with `Φ̃ = 1 − Φ` (finite for all `x` where φ(x) > 0).
pub fn mills_ratio(x: f64) -> f64 {
    if x >= 2.5 {
        mills_cf(x)
    } else {
        upper_tail(x) / norm_pdf(x)
    }
}

/// Upper tail `Φ̃(x) = P(Z > x)`, accurate to ~1e-13 relative.
pub fn upper_tail(x: f64) -> f64 {
    if x.is_nan() {
        return f64::NAN;
    }
    if x >= 2.5 {
        norm_pdf(x) * mills_cf(x)
    } else if x >= 0.0 {
        0.5 - norm_pdf(x) * odd_series(x)
    } else if x > -2.5 {
        0.5 + norm_pdf(x) * odd_series(-x)
    } else {
        1.0 - norm_pdf(x) * mills_cf(-x)
    }
}

/// Φ(x) = P(Z ≤ x).
pub fn norm_cdf(x: f64) -> f64 {
    upper_tail(-x)
}

/// Quantile Φ⁻¹(p) for `0 < p < 1`: Abramowitz–Stegun 26.2.23 start, then
/// Halley steps on the tail that keeps precision.
pub fn norm_quantile(p: f64) -> f64 {
    if p.is_nan() || p <= 0.0 {
        return if p == 0.0 {
            f64::NEG_INFINITY
        } else {
            f64::NAN
        };
    }
    if p >= 1.0 {
        return if p == 1.0 { f64::INFINITY } else { f64::NAN };
    }
    // Work with the lower tail q = min(p, 1−p) and solve Φ(−y) = q for y ≥ 0.
    let upper = p > 0.5;
    let q = if upper { 1.0 - p } else { p };
    let t = (-2.0 * q.ln()).sqrt();
    let mut y = t
        - (2.515517 + 0.802853 * t + 0.010328 * t * t)
            / (1.0 + 1.432788 * t + 0.189269 * t * t + 0.001308 * t * t * t);
    for _ in 0..4 {
        // f(y) = Φ̃(y) − q, f'(y) = −φ(y), f''(y) = yφ(y)
        let f = upper_tail(y) - q;
        let d = norm_pdf(y);
        if d == 0.0 {
            break;
        }
        let r = f / d; // = −f/f'
        y += r / (1.0 + 0.5 * y * r);
    }
    if upper {
        y
    } else {
        -y
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantile_inverts_cdf() {
        for &p in &[1e-12, 1e-6, 0.01, 0.2, 0.5, 0.75, 0.975, 1.0 - 1e-9] {
            let x = norm_quantile(p);
            assert!(
                (norm_cdf(x) - p).abs() <= 1e-13 * p.min(1.0 - p).max(1e-300) + 1e-16,
                "{p}"
            );
        }
        assert!((norm_quantile(0.75) - 0.6744897501960817).abs() < 1e-14);
        assert!((norm_quantile(0.975) - 1.959963984540054).abs() < 1e-13);
    }
}
