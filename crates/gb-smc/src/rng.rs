//! Counter-based seeding of reproducible random streams.
//!
//! Every random draw of the crate comes from a `Xoshiro256PlusPlus` stream
//! seeded by a hash of `(seed, domain, t, k)` (for instance `k` = particle
//! chunk, `t` = time step). Work is split into chunks of fixed size
//! [`CHUNK`], independent of the rayon thread count, so results are
//! bit-identical for a given seed on any number of threads.
use rand::SeedableRng;
pub use rand_xoshiro::Xoshiro256PlusPlus;

/// The random generator used by models and filters.
pub type SmcRng = Xoshiro256PlusPlus;

/// Particles per random stream / parallel work item (fixed, so that results
/// do not depend on the thread count).
pub const CHUNK: usize = 2048;

/// Smallest particle count for which IF2's particle passes use rayon (below it
/// the thread hand-off costs more than it saves; results are identical either
/// way). Particle filters use [`FILTER_PAR_MIN`].
pub const PAR_MIN: usize = 4096;

/// Smallest particle count for which a particle filter runs its time steps on
/// rayon. A step costs about 5 ns per particle on one core (N = 10 000: about
/// 50 µs), while each step needs a fork-join, which costs microseconds on an
/// idle machine and can stall a step for a whole scheduler time slice when the
/// cores are shared; below this size the steps run on the calling thread
/// (results are identical either way).
pub const FILTER_PAR_MIN: usize = 16_384;

/// Smallest particle count for which the light O(N) passes (normalisation,
/// resampling; ~1 ns per particle) are split over threads: one fork-join per
/// step fewer matters more than the pass itself below this size.
pub const PAR_MIN_LIGHT: usize = 65_536;

#[inline]
fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Independent stream for `(seed, domain, t, k)`.
///
/// ```
/// use rand::Rng;
/// let mut a = gb_smc::rng::stream(1, 0, 5, 2);
/// let mut b = gb_smc::rng::stream(1, 0, 5, 2);
/// assert_eq!(a.random::<u64>(), b.random::<u64>());
/// ```
#[inline]
pub fn stream(seed: u64, domain: u64, t: u64, k: u64) -> SmcRng {
    let mut h = mix(seed.wrapping_add(0x9E37_79B9_7F4A_7C15));
    h = mix(h ^ domain.wrapping_mul(0xD1B5_4A32_D192_ED03));
    h = mix(h ^ t.wrapping_mul(0xAEF1_7502_108E_F2D9));
    h = mix(h ^ k.wrapping_mul(0xDB4F_0B91_75AE_2165));
    SmcRng::seed_from_u64(h)
}

/// A derived 64-bit seed (e.g. the filter seed of PMMH iteration `t`).
#[inline]
pub fn derive_seed(seed: u64, domain: u64, t: u64) -> u64 {
    mix(mix(mix(seed ^ 0x5851_F42D_4C95_7F2D) ^ domain.wrapping_mul(0x9E37_79B9_7F4A_7C15)) ^ t)
}

#[allow(dead_code)]
pub(crate) mod domain {
    pub const MOVE: u64 = 1;
    pub const RESAMPLE: u64 = 2;
    pub const FILL: u64 = 3;
    pub const BACKWARD: u64 = 4;
    pub const PMMH_FILTER: u64 = 5;
    pub const PMMH_MH: u64 = 6;
    pub const IF2: u64 = 7;
    pub const PMMH_TUNE: u64 = 8;
}

/// Ziggurat tables (256 layers) for the standard normal, built once.
struct Zig {
    x: [f64; 257],
    f: [f64; 257],
}

#[inline(always)]
fn zig_tables() -> &'static Zig {
    static TABLES: std::sync::OnceLock<Zig> = std::sync::OnceLock::new();
    match TABLES.get() {
        Some(t) => t,
        None => zig_init(&TABLES),
    }
}

#[cold]
#[inline(never)]
fn zig_init(tables: &'static std::sync::OnceLock<Zig>) -> &'static Zig {
    tables.get_or_init(|| {
        // Marsaglia & Tsang (2000): R = right-most layer edge, V = layer area.
        const R: f64 = 3.654_152_885_361_009;
        const V: f64 = 0.004_928_673_233_99;
        let pdf = |x: f64| (-0.5 * x * x).exp();
        let mut x = [0.0; 257];
        x[0] = V / pdf(R);
        x[1] = R;
        for i in 1..255 {
            x[i + 1] = (-2.0 * (V / x[i] + pdf(x[i])).ln()).sqrt();
        }
        x[256] = 0.0;
        let mut f = [0.0; 257];
        for i in 0..257 {
            f[i] = pdf(x[i]);
        }
        Zig { x, f }
    })
}

/// Standard normal draw (256-layer ziggurat; one `u64` on the fast path, ~99 %).
///
/// Inlined so that the generator state stays in registers inside particle
/// loops; `rand_distr::StandardNormal` works too but is slower there.
///
/// ```
/// let mut rng = gb_smc::rng::stream(3, 0, 0, 0);
/// let n = 100_000;
/// let (s, s2) = (0..n).map(|_| gb_smc::rng::standard_normal(&mut rng))
///     .fold((0.0, 0.0), |(a, b), z| (a + z, b + z * z));
/// assert!((s / n as f64).abs() < 0.02 && (s2 / n as f64 - 1.0).abs() < 0.02);
/// ```
#[inline(always)]
pub fn standard_normal(rng: &mut SmcRng) -> f64 {
    use rand::RngCore;
    let t = zig_tables();
    loop {
        let bits = rng.next_u64();
        let i = (bits & 0xff) as usize;
        // u ∈ [−1, 1) from the 52 high bits
        let u = f64::from_bits((1024u64 << 52) | (bits >> 12)) - 3.0;
        let x = u * t.x[i];
        if x.abs() < t.x[i + 1] {
            return x;
        }
        if let Some(z) = normal_slow(rng, t, i, u, x) {
            return z;
        }
    }
}

/// Fills `out` with independent standard normal draws (the same 256-layer
/// ziggurat as [`standard_normal`], organised for vectorisation): per block of
/// 128, all raw `u64` draws first, then the branch-free fast path for the whole
/// block, then the rare rejected entries (~1 %) in order. Deterministic for a
/// given stream, but a different sequence from calling [`standard_normal`] in a loop.
///
/// ```
/// let mut rng = gb_smc::rng::stream(3, 0, 0, 0);
/// let mut z = vec![0.0; 100_000];
/// gb_smc::rng::fill_standard_normal(&mut rng, &mut z);
/// let n = z.len() as f64;
/// let (s, s2) = z.iter().fold((0.0, 0.0), |(a, b), &x| (a + x, b + x * x));
/// assert!((s / n).abs() < 0.02 && (s2 / n - 1.0).abs() < 0.02);
/// ```
#[inline(always)]
pub fn fill_standard_normal(rng: &mut SmcRng, out: &mut [f64]) {
    use rand::RngCore;
    const B: usize = 128;
    let t = zig_tables();
    let mut bits = [0u64; B];
    for blk in out.chunks_mut(B) {
        let bits = &mut bits[..blk.len()];
        for b in bits.iter_mut() {
            *b = rng.next_u64();
        }
        let mut rej = [0u64; B / 64];
        zig_fast(t, bits, blk, &mut rej);
        if rej.iter().any(|&m| m != 0) {
            fill_rejected(rng, t, blk, bits, &rej);
        }
    }
}

/// Ziggurat fast path for a block of raw draws: `out_j = u_j x_{i_j}`, and bit
/// `j` of `rej` set where `|out_j| ≥ x_{i_j + 1}` (slow path needed). Branch-free.
#[inline(always)]
fn zig_fast(t: &Zig, bits: &[u64], out: &mut [f64], rej: &mut [u64]) {
    for ((oc, bc), r) in out.chunks_mut(64).zip(bits.chunks(64)).zip(rej.iter_mut()) {
        // the mask stays in a register (an `|=` into memory per draw would chain
        // every iteration through store-to-load forwarding)
        let mut m = 0u64;
        for (j, (o, &b)) in oc.iter_mut().zip(bc).enumerate() {
            let i = (b & 0xff) as usize;
            let u = f64::from_bits((1024u64 << 52) | (b >> 12)) - 3.0;
            let x = u * t.x[i];
            *o = x;
            m |= ((x.abs() >= t.x[i + 1]) as u64) << j;
        }
        *r = m;
    }
}

/// Completes the ziggurat draws that missed the fast path (bits set in `rej`), in order.
#[cold]
#[inline(never)]
fn fill_rejected(rng: &mut SmcRng, t: &Zig, out: &mut [f64], bits: &[u64], rej: &[u64]) {
    for (w, &m) in rej.iter().enumerate() {
        let mut m = m;
        while m != 0 {
            let j = w * 64 + m.trailing_zeros() as usize;
            m &= m - 1;
            let b = bits[j];
            let i = (b & 0xff) as usize;
            let u = f64::from_bits((1024u64 << 52) | (b >> 12)) - 3.0;
            let x = u * t.x[i];
            out[j] = match normal_slow(rng, t, i, u, x) {
                Some(z) => z,
                None => standard_normal(rng),
            };
        }
    }
}

#[cold]
#[inline(never)]
fn normal_slow(rng: &mut SmcRng, t: &Zig, i: usize, u: f64, x: f64) -> Option<f64> {
    use rand::Rng;
    const R: f64 = 3.654_152_885_361_009;
    if i == 0 {
        // tail beyond R (Marsaglia 1964)
        loop {
            let a: f64 = rng.random::<f64>();
            let b: f64 = rng.random::<f64>();
            if a <= 0.0 || b <= 0.0 {
                continue;
            }
            let xt = -a.ln() / R;
            let yt = -b.ln();
            if 2.0 * yt >= xt * xt {
                return Some(if u < 0.0 { -(R + xt) } else { R + xt });
            }
        }
    }
    let v: f64 = rng.random();
    if t.f[i + 1] + (t.f[i] - t.f[i + 1]) * v < (-0.5 * x * x).exp() {
        Some(x)
    } else {
        None
    }
}
