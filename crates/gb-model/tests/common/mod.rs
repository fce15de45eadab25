//! Inputs shared by the physics tests.
use rand::Rng;
use rand_distr::{Distribution, Normal};

/// Random force steps: N(0, 1) levels held 5–40 samples, `n` samples.
pub fn steps(n: usize, rng: &mut impl Rng) -> Vec<f64> {
    let mut u = Vec::with_capacity(n);
    while u.len() < n {
        let level: f64 = Normal::new(0.0, 1.0).unwrap().sample(rng);
        let hold = rng.random_range(5..40);
        u.extend(std::iter::repeat_n(level, hold));
    }
    u.truncate(n);
    u
}
