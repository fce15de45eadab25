//! Reproducible random streams.
//!
//! All seeded randomness in greybox uses `Xoshiro256PlusPlus`, whose output is
//! specified and portable (unlike `StdRng`, which may change between `rand`
//! versions).
use rand::SeedableRng;
pub use rand_xoshiro::Xoshiro256PlusPlus;

/// A reproducible generator for `seed`.
///
/// ```
/// use rand::Rng;
/// let mut a = gb_core::rng::seeded(7);
/// let mut b = gb_core::rng::seeded(7);
/// assert_eq!(a.random::<u64>(), b.random::<u64>());
/// ```
pub fn seeded(seed: u64) -> Xoshiro256PlusPlus {
    Xoshiro256PlusPlus::seed_from_u64(seed)
}

/// An independent stream `stream` derived from `seed` (for per-task or
/// per-particle streams that do not depend on scheduling).
pub fn stream(seed: u64, stream: u64) -> Xoshiro256PlusPlus {
    // SplitMix-style mixing of the pair into one 64-bit seed.
    let mut z = seed ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    Xoshiro256PlusPlus::seed_from_u64(z ^ (z >> 31))
}
