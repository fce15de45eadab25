//! The Everett-function form and the classic relay grid agree.
#![allow(clippy::needless_range_loop)]
use gb_preisach::{GridEverett, InitialState, ParametricEverett, Preisach, RelayGrid};
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// Random turning points in [lo, hi] with `per` samples on each segment.
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

#[test]
fn relay_grid_equals_grid_everett_on_grid_inputs() {
    // Inputs on grid nodes switch whole cells, so the relay grid is exact.
    let n = 12;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
    let masses: Vec<f64> = (0..GridEverett::parameter_count(n))
        .map(|_| rng.random_range(0.0..1.0))
        .collect();
    let g = GridEverett::new(-1.0, 2.0, n, masses).unwrap();
    let relays = RelayGrid::from_everett(&g, -1.0, 2.0, n).unwrap();
    let x: Vec<f64> = (0..2000)
        .map(|_| -1.0 + 0.25 * rng.random_range(0..=n) as f64)
        .collect();
    let y1 = Preisach::new(g)
        .simulate(&x, &InitialState::NegativeSaturation)
        .unwrap();
    let y2 = relays.simulate(&x, false).unwrap();
    for (a, b) in y1.iter().zip(&y2) {
        assert!((a - b).abs() < 1e-11, "{a} vs {b}");
    }
}

#[test]
fn relay_grid_converges_to_parametric_everett() {
    let f = ParametricEverett::gaussian(1.0, 0.4, 0.3, -0.4, 0.3).unwrap();
    let p = Preisach::new(f);
    let x = random_input(11, -1.8, 1.8, 60, 25);
    let exact = p.simulate(&x, &InitialState::NegativeSaturation).unwrap();
    let err = |n: usize| {
        let r = RelayGrid::from_everett(&f, -3.5, 3.5, n).unwrap();
        let y = r.simulate(&x, false).unwrap();
        y.iter()
            .zip(&exact)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max)
    };
    let (e_coarse, e_fine) = (err(40), err(320));
    eprintln!("relay grid errors {e_coarse} {e_fine}");
    assert!(e_fine < 0.05, "fine relay grid error {e_fine}");
    assert!(
        e_fine < 0.25 * e_coarse,
        "no convergence: {e_coarse} -> {e_fine}"
    );
}
