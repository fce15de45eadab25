//! Goodness-of-fit metrics.
//!
//! With measured output y and simulated output ŷ over N samples:
//! - RMSE = sqrt(1/N Σ (y − ŷ)²)
//! - NRMSE = RMSE / std(y) (0 = perfect, 1 = as good as the mean)
//! - fit% = 100 (1 − ‖y − ŷ‖ / ‖y − ȳ‖) (MATLAB's `compare` figure)
use crate::CoreError;

/// Arithmetic mean (0 for an empty slice).
pub fn mean(x: &[f64]) -> f64 {
    if x.is_empty() {
        0.0
    } else {
        x.iter().sum::<f64>() / x.len() as f64
    }
}

/// Population standard deviation sqrt(1/N Σ (x − x̄)²).
pub fn std(x: &[f64]) -> f64 {
    let m = mean(x);
    if x.is_empty() {
        return 0.0;
    }
    (x.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / x.len() as f64).sqrt()
}

/// `(min, max)` of a slice; `(∞, −∞)` when it is empty.
///
/// ```
/// assert_eq!(gb_core::metrics::min_max(&[0.5, -2.0, 3.0]), (-2.0, 3.0));
/// ```
pub fn min_max(x: &[f64]) -> (f64, f64) {
    x.iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        })
}

/// Root mean square of a slice.
pub fn rms(x: &[f64]) -> f64 {
    if x.is_empty() {
        return 0.0;
    }
    (x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64).sqrt()
}

fn check(y: &[f64], yhat: &[f64]) -> Result<(), CoreError> {
    if y.len() != yhat.len() {
        return Err(CoreError::Dimension(format!(
            "measured output has {} samples, simulated {}",
            y.len(),
            yhat.len()
        )));
    }
    if y.is_empty() {
        return Err(CoreError::TooShort {
            context: "metric".into(),
            needed: 1,
            got: 0,
        });
    }
    Ok(())
}

/// RMSE between measured `y` and simulated `yhat`.
pub fn rmse(y: &[f64], yhat: &[f64]) -> Result<f64, CoreError> {
    check(y, yhat)?;
    let s: f64 = y.iter().zip(yhat).map(|(a, b)| (a - b) * (a - b)).sum();
    Ok((s / y.len() as f64).sqrt())
}

/// NRMSE = RMSE / std(y).
pub fn nrmse(y: &[f64], yhat: &[f64]) -> Result<f64, CoreError> {
    let r = rmse(y, yhat)?;
    let s = std(y);
    if s <= 0.0 {
        return Err(CoreError::Constant {
            context: "NRMSE".into(),
            name: "output".into(),
        });
    }
    Ok(r / s)
}

/// MATLAB-style fit percentage 100 (1 − ‖y − ŷ‖ / ‖y − ȳ‖).
pub fn fit_percent(y: &[f64], yhat: &[f64]) -> Result<f64, CoreError> {
    Ok(100.0 * (1.0 - nrmse(y, yhat)?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn nrmse_of_mean_predictor_is_one() {
        let y = [1.0, 2.0, 3.0, 4.0];
        let m = mean(&y);
        assert_relative_eq!(nrmse(&y, &[m; 4]).unwrap(), 1.0, epsilon = 1e-12);
        assert_relative_eq!(fit_percent(&y, &y).unwrap(), 100.0);
    }

    #[test]
    fn std_matches_definition() {
        // population std of 2,4,4,4,5,5,7,9 is exactly 2
        assert_relative_eq!(std(&[2.0, 4.0, 4.0, 4.0, 5.0, 5.0, 7.0, 9.0]), 2.0);
    }

    #[test]
    fn mismatched_lengths_error() {
        assert!(rmse(&[1.0], &[1.0, 2.0]).is_err());
        assert!(nrmse(&[1.0, 1.0], &[1.0, 2.0]).is_err());
    }
}
