//! Identification of a known Preisach density from noisy data.
#![allow(clippy::needless_range_loop)]
use gb_preisach::{
    fit_grid_preisach, Everett, FitOptions, GridEverett, GridPreisachRegressor,
    HysteresisRegressor, InitialState, ParametricEverett, Preisach,
};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use rand_xoshiro::Xoshiro256PlusPlus;

fn random_input(seed: u64, lo: f64, hi: f64, turns: usize, per: usize) -> Vec<f64> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut x = vec![0.0];
    let mut prev = 0.0;
    for _ in 0..turns {
        let next = rng.random_range(lo..hi);
        for k in 1..=per {
            x.push(prev + (next - prev) * k as f64 / per as f64);
        }
        prev = next;
    }
    x
}

fn truth(n: usize) -> GridEverett {
    let f = ParametricEverett::gaussian(1.0, 0.35, 0.3, -0.35, 0.3).unwrap();
    GridEverett::from_everett(&f, -1.0, 1.0, n).unwrap()
}

#[test]
fn identification_recovers_known_density_from_noisy_data() {
    let n = 10;
    let g = truth(n);
    let model = Preisach::new(g.clone());
    let init = InitialState::NegativeSaturation;
    let x = random_input(1, -1.0, 1.0, 500, 6);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(2);
    let noise = Normal::new(0.0, 0.01).unwrap();
    let y: Vec<f64> = model
        .simulate(&x, &init)
        .unwrap()
        .into_iter()
        .map(|v| v + noise.sample(&mut rng))
        .collect();
    let reg = GridPreisachRegressor::new(-1.0, 1.0, n, init.clone()).unwrap();
    let rel_err = |w: &[f64]| {
        let num: f64 = w
            .iter()
            .zip(g.masses())
            .map(|(a, b)| (a - b) * (a - b))
            .sum();
        let den: f64 = g.masses().iter().map(|b| b * b).sum();
        (num / den).sqrt()
    };
    // Non-negative fit.
    let fit = fit_grid_preisach(&x, &y, &reg, &FitOptions::default()).unwrap();
    let e = rel_err(fit.model.everett().masses());
    eprintln!("density errors: nonneg {e}");
    assert!(e < 0.1, "non-negative fit: relative density error {e}");
    assert!(fit.model.everett().masses().iter().all(|w| *w >= 0.0));
    assert!(fit.rmse < 0.011, "rmse {}", fit.rmse);
    // Unconstrained ridge fit with a bias.
    let opts = FitOptions {
        ridge: 1e-6,
        nonnegative: false,
        bias: true,
        ..FitOptions::default()
    };
    let fit2 = fit_grid_preisach(&x, &y, &reg, &opts).unwrap();
    let e2 = rel_err(fit2.model.everett().masses());
    eprintln!("density errors: ridge {e2}, bias {}", fit2.bias);
    assert!(
        e2 < 0.15 && fit2.bias.abs() < 0.01,
        "ridge fit: error {e2}, bias {}",
        fit2.bias
    );
    // The identified model predicts fresh data.
    let xv = random_input(3, -1.0, 1.0, 100, 6);
    let yv = model.simulate(&xv, &init).unwrap();
    let yp = fit.model.simulate(&xv, &init).unwrap();
    let rmse = (yv
        .iter()
        .zip(&yp)
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>()
        / yv.len() as f64)
        .sqrt();
    assert!(rmse < 0.01, "validation rmse {rmse}");
    // the identified model has the loops of the truth (positive control of
    // `negative_control_no_hysteresis_in_static_data`)
    let (w_fit, w_true) = (loop_width(&fit.model), loop_width(&model));
    eprintln!("loop width: fit {w_fit}, truth {w_true}");
    assert!(
        (w_fit - w_true).abs() < 0.1 * w_true,
        "loop width {w_fit} vs truth {w_true}"
    );
    assert!(off_diagonal_fraction(fit.model.everett()) > 0.5);
}

/// Share of the identified mass in square cells (α > β, the hysteretic
/// part); the diagonal cells (α = β) are the reversible part.
fn off_diagonal_fraction(g: &GridEverett) -> f64 {
    let cells = g.density_table();
    let total: f64 = cells.iter().map(|c| c.mass.abs()).sum();
    let off: f64 = cells
        .iter()
        .filter(|c| !c.diagonal)
        .map(|c| c.mass.abs())
        .sum();
    off / total
}

/// Largest vertical width of the major loop (-1 -> 1 -> -1), relative to its
/// height: 0 for a single-valued (non-hysteretic) model.
fn loop_width<E: Everett>(p: &Preisach<E>) -> f64 {
    let m = 200;
    let up: Vec<f64> = (0..=m).map(|k| -1.0 + 2.0 * k as f64 / m as f64).collect();
    let x: Vec<f64> = up.iter().chain(up.iter().rev().skip(1)).copied().collect();
    let y = p.simulate(&x, &InitialState::NegativeSaturation).unwrap();
    let height =
        y.iter().fold(f64::MIN, |a, &b| a.max(b)) - y.iter().fold(f64::MAX, |a, &b| a.min(b));
    // y on the way up at up[k] is y[k]; on the way down it is y[2m - k]
    (0..=m)
        .map(|k| (y[2 * m - k] - y[k]).abs())
        .fold(0.0, f64::max)
        / height
}

/// Negative control: the same identifier on data WITHOUT hysteresis (a
/// static, single-valued, increasing function of the same input plus the
/// same noise) must find (almost) none — the mass goes to the diagonal
/// (reversible) cells and the identified model has no loop — while the
/// hysteretic data above give the truth's loop.
#[test]
fn negative_control_no_hysteresis_in_static_data() {
    let n = 10;
    let init = InitialState::NegativeSaturation;
    let x = random_input(1, -1.0, 1.0, 500, 6);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(2);
    let noise = Normal::new(0.0, 0.01).unwrap();
    let y: Vec<f64> = x
        .iter()
        .map(|&v| 0.5 * (1.0 + (2.0 * v).tanh()) + noise.sample(&mut rng))
        .collect();
    let reg = GridPreisachRegressor::new(-1.0, 1.0, n, init.clone()).unwrap();
    let opts = FitOptions {
        bias: true,
        ..FitOptions::default()
    };
    let fit = fit_grid_preisach(&x, &y, &reg, &opts).unwrap();
    // the static function is fitted (to the noise and the grid's
    // piecewise-linear interpolation)
    assert!(fit.rmse < 0.02, "rmse {}", fit.rmse);
    let frac = off_diagonal_fraction(fit.model.everett());
    let width = loop_width(&fit.model);
    let truth_width = loop_width(&Preisach::new(truth(n)));
    eprintln!("static data: off-diagonal mass {frac}, loop width {width} (hysteretic truth {truth_width})");
    assert!(
        frac < 0.05,
        "hysteretic mass fraction {frac} on static data"
    );
    assert!(
        width < 0.05 * truth_width,
        "loop width {width} on static data (truth with hysteresis: {truth_width})"
    );
}

#[test]
fn smooth_everett_identified_on_coarser_grid() {
    // Data from the continuous parametric model, fitted on a 12-interval grid:
    // the grid Everett function approximates F.
    let f = ParametricEverett::lorentzian(1.0, 0.3, 0.15, -0.3, 0.15).unwrap();
    let init = InitialState::NegativeSaturation;
    let x = random_input(5, -1.0, 1.0, 400, 8);
    let y = Preisach::new(f).simulate(&x, &init).unwrap();
    let reg = GridPreisachRegressor::new(-1.0, 1.0, 12, init).unwrap();
    let fit = fit_grid_preisach(
        &x,
        &y,
        &reg,
        &FitOptions {
            smoothness: 1e-4,
            bias: true,
            ..FitOptions::default()
        },
    )
    .unwrap();
    let scale = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    eprintln!("smooth fit rmse {} of {scale}", fit.rmse);
    assert!(fit.rmse < 0.02 * scale, "rmse {} of {scale}", fit.rmse);
}

#[test]
fn regressor_rows_reproduce_output_and_derivative() {
    let g = truth(8);
    let reg = GridPreisachRegressor::new(-1.0, 1.0, 8, InitialState::PositiveSaturation)
        .unwrap()
        .with_memory_cap(6)
        .unwrap();
    let model = reg.model(g.masses().to_vec()).unwrap();
    let x = random_input(9, -1.2, 1.2, 200, 5);
    let y = model
        .simulate(&x, &InitialState::PositiveSaturation)
        .unwrap();
    let r = reg.regressors(&x).unwrap();
    let mut st = model.state(&InitialState::PositiveSaturation).unwrap();
    for t in 0..x.len() {
        let lin: f64 = r
            .columns
            .iter()
            .zip(g.masses())
            .map(|(c, w)| c[t] * w)
            .sum();
        assert!((lin - y[t]).abs() < 1e-12, "t = {t}");
        let dlin: f64 = r
            .derivatives
            .iter()
            .zip(g.masses())
            .map(|(c, w)| c[t] * w)
            .sum();
        let (_, d) = model.step_with_derivative(&mut st, x[t]);
        assert!((dlin - d).abs() < 1e-10, "t = {t}: {dlin} vs {d}");
    }
    let _ = g.total();
}
