//! Noise families: densities integrate to one, samplers match densities and moments.
use gb_smc::noise::{ln_gamma, Noise};
use gb_smc::rng::stream;

fn families() -> Vec<(&'static str, Noise)> {
    vec![
        ("gaussian", Noise::gaussian(0.5, 2.0).unwrap()),
        ("student-t", Noise::student_t(5.0, -1.0, 1.5).unwrap()),
        ("laplace", Noise::laplace(0.3, 0.8).unwrap()),
        (
            "mixture",
            Noise::mixture(vec![
                (0.7, Noise::gaussian(-2.0, 0.5).unwrap()),
                (0.3, Noise::laplace(3.0, 1.0).unwrap()),
            ])
            .unwrap(),
        ),
    ]
}

#[test]
fn ln_gamma_values() {
    assert!((ln_gamma(1.0)).abs() < 1e-13);
    assert!((ln_gamma(5.0) - 24f64.ln()).abs() < 1e-12);
    assert!((ln_gamma(0.5) - std::f64::consts::PI.sqrt().ln()).abs() < 1e-12);
    assert!((ln_gamma(100.5) - 361.435_540_467_777_6).abs() < 1e-10);
    assert!((ln_gamma(3.7) - 1.428_072_326_665_388_3).abs() < 1e-12);
}

#[test]
fn densities_integrate_to_one_and_match_samplers() {
    let h = 0.001;
    for (name, noise) in families() {
        // midpoint rule on [-200, 200] and numerical CDF on a grid
        let n_grid = (400.0 / h) as usize;
        let mut cdf = Vec::with_capacity(n_grid);
        let mut acc = 0.0;
        for k in 0..n_grid {
            let x = -200.0 + (k as f64 + 0.5) * h;
            acc += noise.log_pdf(x).exp() * h;
            cdf.push(acc);
        }
        assert!((acc - 1.0).abs() < 1e-4, "{name}: integral {acc}");
        // samples: empirical CDF at a few points, mean and variance
        let n = 40_000;
        let mut rng = stream(77, 0, 0, 0);
        let xs: Vec<f64> = (0..n).map(|_| noise.sample(&mut rng)).collect();
        for x0 in [-3.0, -1.0, 0.0, 0.5, 2.0, 4.0] {
            let k = ((x0 + 200.0) / h) as usize;
            let f = cdf[k];
            let emp = xs.iter().filter(|&&x| x < x0).count() as f64 / n as f64;
            let se = (f * (1.0 - f) / n as f64).sqrt().max(1e-4);
            assert!(
                (emp - f).abs() < 4.5 * se,
                "{name}: CDF at {x0}: {emp} vs {f}"
            );
        }
        let m = xs.iter().sum::<f64>() / n as f64;
        let v = xs.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n as f64 - 1.0);
        let (tm, tv) = (noise.mean().unwrap(), noise.variance().unwrap());
        assert!(
            (m - tm).abs() < 4.5 * (tv / n as f64).sqrt(),
            "{name}: mean {m} vs {tm}"
        );
        assert!((v / tv - 1.0).abs() < 0.1, "{name}: var {v} vs {tv}");
    }
}

#[test]
fn constructors_validate() {
    assert!(Noise::gaussian(0.0, 0.0).is_err());
    assert!(Noise::student_t(-1.0, 0.0, 1.0).is_err());
    assert!(Noise::laplace(0.0, f64::NAN).is_err());
    assert!(Noise::mixture(vec![]).is_err());
    assert!(Noise::mixture(vec![(0.0, Noise::gaussian(0.0, 1.0).unwrap())]).is_err());
    assert_eq!(Noise::student_t(1.0, 0.0, 1.0).unwrap().mean(), None);
}

#[test]
fn ziggurat_standard_normal_matches_the_normal_cdf() {
    // Φ at a few points (including the tail beyond the ziggurat edge R ≈ 3.654)
    let pts = [
        (-3.9, 4.809_634_5e-5),
        (-3.0, 1.349_898e-3),
        (-2.0, 2.275_013e-2),
        (-1.0, 0.158_655_25),
        (0.0, 0.5),
        (0.5, 0.691_462_46),
        (1.5, 0.933_192_8),
        (2.5, 0.993_790_3),
        (3.8, 0.999_927_65),
    ];
    let n = 400_000;
    let mut rng = stream(5, 1, 2, 3);
    let xs: Vec<f64> = (0..n)
        .map(|_| gb_smc::rng::standard_normal(&mut rng))
        .collect();
    for (x0, f) in pts {
        let emp = xs.iter().filter(|&&x| x < x0).count() as f64 / n as f64;
        let se = (f * (1.0 - f) / n as f64).sqrt();
        assert!((emp - f).abs() < 4.5 * se, "Φ({x0}): {emp} vs {f}");
    }
}
