//! Thresholding functions, threshold rules and denoising.

mod common;

use common::{fixture, floats, rel_err};
use gb_wavelet::{
    denoise, denoise_with, noise_sigma, sure_risk, sure_threshold, upper_tail, wavedec, waverec,
    DenoiseOptions, EmpiricalBayes, Mode, ThresholdFunction, ThresholdRule, Wavelet,
};
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// Standard normal samples by Box–Muller (fixed seed).
fn normals(n: usize, seed: u64) -> Vec<f64> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let u: f64 = 1.0 - rng.random::<f64>();
            let v: f64 = rng.random::<f64>();
            (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
        })
        .collect()
}

#[test]
fn threshold_functions_match_pywavelets() {
    let f = fixture("threshold.json");
    let data = floats(&f["data"]);
    let value = f["value"].as_f64().expect("value");
    for name in ["soft", "hard", "garrote"] {
        let function: ThresholdFunction = name.parse().expect("function");
        let ours: Vec<f64> = data.iter().map(|&x| function.apply(x, value)).collect();
        let e = rel_err(&ours, &floats(&f["results"][name]), name);
        assert!(e < 1e-14, "{name}: {e}");
    }
}

#[test]
fn normal_tail_matches_erfc() {
    let f = fixture("normal.json");
    for (x, p) in floats(&f["x"]).iter().zip(floats(&f["upper_tail"])) {
        let ours = upper_tail(*x);
        assert!((ours - p).abs() <= 1e-12 * p, "x = {x}: {ours} vs {p}");
    }
}

#[test]
fn sure_threshold_equals_brute_force_minimum() {
    for seed in 0..20u64 {
        let n = 50 + 37 * seed as usize;
        let mut x = normals(n, seed);
        // a few strong coefficients so that SURE is not degenerate
        for (k, v) in x.iter_mut().enumerate().take(n / 5) {
            *v += if k % 2 == 0 { 3.0 } else { -2.0 };
        }
        let t = sure_threshold(&x);
        let cap = (2.0 * (n as f64).ln()).sqrt();
        let risk = sure_risk(&x, t);
        // brute force: a fine grid on [0, cap] plus every |x_i| below the cap
        let mut best = f64::INFINITY;
        let grid = (0..=20_000).map(|k| cap * k as f64 / 20_000.0);
        for s in grid.chain(x.iter().map(|v| v.abs()).filter(|&v| v <= cap)) {
            best = best.min(sure_risk(&x, s));
        }
        assert!(
            (risk - best).abs() < 1e-9,
            "seed {seed}: SURE({t}) = {risk}, brute {best}"
        );
        assert!(t <= cap);
    }
}

#[test]
fn empirical_bayes_posterior_median_matches_quadrature() {
    // posterior of θ | x: (1−w')δ₀ + w' ∝ (a/2)e^{−a|θ|} φ(x−θ)
    for &(w, a) in &[(0.1, 0.5), (0.5, 0.5), (0.02, 1.0)] {
        let eb = EmpiricalBayes {
            weight: w,
            scale: a,
        };
        for &x in &[-6.0, -2.5, 0.3, 1.0, 2.0, 3.0, 4.5, 8.0] {
            let phi = |z: f64| (-0.5 * z * z).exp() / (2.0 * std::f64::consts::PI).sqrt();
            let dens = |th: f64| w * 0.5 * a * (-a * th.abs()).exp() * phi(x - th);
            let (lo, hi, m) = (-30.0, 30.0, 600_000);
            let h = (hi - lo) / m as f64;
            let cont: Vec<f64> = (0..m)
                .map(|k| dens(lo + (k as f64 + 0.5) * h) * h)
                .collect();
            let atom = (1.0 - w) * phi(x);
            let total: f64 = cont.iter().sum::<f64>() + atom;
            // median of the mixture: negative cells, the atom at 0, positive cells
            let negative: f64 = cont.iter().take(m / 2).sum();
            let median = if negative >= 0.5 * total {
                let mut cum = 0.0;
                let k = cont.iter().position(|c| {
                    cum += c;
                    cum >= 0.5 * total
                });
                lo + (k.expect("found") as f64 + 0.5) * h
            } else if negative + atom >= 0.5 * total {
                0.0
            } else {
                let mut cum = negative + atom;
                let k = cont.iter().skip(m / 2).position(|c| {
                    cum += c;
                    cum >= 0.5 * total
                });
                (k.expect("found") as f64 + 0.5) * h
            };
            let ours = eb.posterior_median(x);
            assert!(
                (ours - median).abs() < 1e-3,
                "w={w} a={a} x={x}: {ours} vs {median}"
            );
        }
    }
}

#[test]
fn empirical_bayes_threshold_and_weight_are_consistent() {
    let a = 0.5;
    for &t in &[1.5, 2.5, 3.5] {
        let w = EmpiricalBayes::weight_for_threshold(t, a);
        let eb = EmpiricalBayes {
            weight: w,
            scale: a,
        };
        assert!((eb.threshold() - t).abs() < 1e-8, "{t}: {}", eb.threshold());
    }
}

/// A signal with a known sparse set of wavelet coefficients plus unit noise:
/// thresholding keeps every true coefficient, and the universal rule finds
/// exactly the support in nearly all of 10 noise draws (the universal threshold lets noise through with probability
/// ≈ 1/√(π ln n) per draw, ~0.2 here).
#[test]
fn thresholding_recovers_sparse_support() {
    let w = Wavelet::new("db4").expect("wavelet");
    let n = 1024;
    let mode = Mode::Periodization;
    let mut coeffs = wavedec(&vec![0.0; n], &w, mode, Some(5)).expect("layout");
    let support = [
        (1usize, 3usize, 12.0),
        (2, 7, -10.0),
        (3, 20, 9.0),
        (4, 100, -11.0),
        (5, 300, 10.0),
        (5, 17, 9.5),
    ];
    coeffs[0].iter_mut().for_each(|v| *v = 2.0);
    for &(band, idx, v) in &support {
        coeffs[band][idx] = v;
    }
    let clean = waverec(&coeffs, &w, mode).expect("synthesis");
    let mut truth: Vec<(usize, usize)> = support.iter().map(|&(b, i, _)| (b, i)).collect();
    truth.sort_unstable();
    for rule in [
        ThresholdRule::Universal,
        ThresholdRule::EmpiricalBayes,
        ThresholdRule::Sure,
    ] {
        let mut exact = 0;
        for seed in 0..10 {
            let noise = normals(n, 100 + seed);
            let noisy: Vec<f64> = clean.iter().zip(&noise).map(|(c, z)| c + z).collect();
            let mut options = DenoiseOptions::new(rule, mode);
            options.level = Some(5);
            options.function = ThresholdFunction::Hard;
            let out = denoise_with(&noisy, &w, &options).expect("denoise");
            assert!((out.sigma - 1.0).abs() < 0.15, "sigma {}", out.sigma);
            let mut found = Vec::new();
            for (band, c) in out.coefficients.iter().enumerate().skip(1) {
                for (i, v) in c.iter().enumerate() {
                    if *v != 0.0 {
                        found.push((band, i));
                    }
                }
            }
            assert!(truth.iter().all(|t| found.contains(t)), "{rule}: {found:?}");
            exact += usize::from(found == truth);
        }
        if rule == ThresholdRule::Universal {
            // SURE and empirical Bayes adapt the threshold per level to
            // minimise risk, not false discoveries: containment only.
            assert!(exact >= 7, "{rule}: exact support in {exact}/10 draws");
        }
    }
}

#[test]
fn every_rule_reduces_the_error_on_a_smooth_signal() {
    let n = 2048;
    let clean: Vec<f64> = (0..n)
        .map(|i| {
            let t = i as f64 / n as f64;
            (t * (1.0 - t)).sqrt() * (2.0 * std::f64::consts::PI * 1.05 / (t + 0.05)).sin() * 10.0
        })
        .collect();
    let noisy: Vec<f64> = clean
        .iter()
        .zip(normals(n, 3))
        .map(|(c, z)| c + z)
        .collect();
    let mse = |v: &[f64]| {
        v.iter()
            .zip(&clean)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            / n as f64
    };
    let w = Wavelet::new("sym8").expect("wavelet");
    let base = mse(&noisy);
    for rule in ["universal", "sure", "bayes", "ebayes"] {
        let rule: ThresholdRule = rule.parse().expect("rule");
        for mode in [Mode::Periodization, Mode::Symmetric] {
            let y = denoise(&noisy, &w, rule, mode).expect("denoise");
            assert_eq!(y.len(), n);
            let e = mse(&y);
            assert!(e < 0.5 * base, "{rule} {mode}: {e} vs {base}");
        }
    }
    let finest = wavedec(&noisy, &w, Mode::Periodization, Some(1)).expect("dwt");
    assert!((noise_sigma(&finest[1]) - 1.0).abs() < 0.1);
}

#[test]
fn rule_and_function_names_parse() {
    assert!("bogus".parse::<ThresholdRule>().is_err());
    assert!("bogus".parse::<ThresholdFunction>().is_err());
    for r in ["sure", "universal", "bayes", "ebayes"] {
        let rule: ThresholdRule = r.parse().expect("rule");
        assert_eq!(rule.to_string(), r);
    }
}
