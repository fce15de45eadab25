//! Excitation signals: random-phase multisine, filtered Gaussian noise,
//! PRBS and sine sweeps, optionally plus a slow component. Every signal is
//! returned with unit rms; its band is set relative to the system's
//! reference frequency `f_ref` (cycles per sample).
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// The kinds of excitation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ExcitationKind {
    /// Random-phase multisine on a random band.
    Multisine,
    /// White Gaussian noise through a 4th-order low-pass.
    FilteredNoise,
    /// Random binary signal held for a random number of samples.
    Prbs,
    /// Logarithmic sine sweeps, up and down.
    Sweep,
}

impl ExcitationKind {
    /// Every kind.
    pub const ALL: [Self; 4] = [
        Self::Multisine,
        Self::FilteredNoise,
        Self::Prbs,
        Self::Sweep,
    ];

    /// Short name.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Multisine => "multisine",
            Self::FilteredNoise => "noise",
            Self::Prbs => "prbs",
            Self::Sweep => "sweep",
        }
    }

    /// Parse a short name.
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == s)
    }
}

/// An excitation design: the kind and its random shape, relative to the
/// system's reference frequency.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Excitation {
    /// The kind.
    pub kind: ExcitationKind,
    /// A slow component (random walk or slow sine) is added.
    pub slow: bool,
    /// Upper band edge (multisine, noise cut-off, sweep end) as a multiple of f_ref.
    pub band_hi: f64,
    /// Lower band edge as a fraction of the upper one.
    pub band_lo: f64,
    /// PRBS hold time as a fraction of the reference period (≥ 1 sample).
    pub hold: f64,
    /// Number of sweeps over the record (alternating up and down).
    pub sweeps: usize,
    /// rms of the slow component relative to the main one.
    pub slow_share: f64,
    /// The slow component is a sine (else a random walk).
    pub slow_sine: bool,
    /// Cycles of the slow component over the record.
    pub slow_cycles: f64,
}

impl Excitation {
    /// Draw a design; `kind` and `slow` override the random choices (the
    /// same random numbers are consumed either way).
    pub(crate) fn draw(r: &mut impl Rng, kind: Option<ExcitationKind>, slow: Option<bool>) -> Self {
        let k = ExcitationKind::ALL[r.random_range(0..4)];
        let s = r.random::<f64>() < 0.3;
        Self {
            kind: kind.unwrap_or(k),
            slow: slow.unwrap_or(s),
            band_hi: r.random_range(1.5..4.0),
            band_lo: r.random_range(0.0..0.3),
            hold: r.random_range(0.05..0.3),
            sweeps: r.random_range(1..=4),
            slow_share: r.random_range(0.3..1.0),
            slow_sine: r.random::<bool>(),
            slow_cycles: r.random_range(0.5..3.0),
        }
    }

    /// Short description.
    pub fn describe(&self) -> String {
        format!(
            "{}{}",
            self.kind.name(),
            if self.slow { "+slow" } else { "" }
        )
    }

    /// A realisation of `n` samples with unit rms; `f_ref` in cycles/sample.
    pub(crate) fn realise(&self, n: usize, f_ref: f64, r: &mut impl Rng) -> Vec<f64> {
        let hi = (self.band_hi * f_ref).min(0.45);
        let lo = self.band_lo * hi;
        let mut x = match self.kind {
            ExcitationKind::Multisine => multisine(n, lo, hi, r),
            ExcitationKind::FilteredNoise => lowpass_noise(n, hi, r),
            ExcitationKind::Prbs => {
                let hold = (self.hold / f_ref).round().max(1.0) as usize;
                prbs(n, hold, r)
            }
            ExcitationKind::Sweep => sweep(n, (0.3 * lo).max(0.05 * hi), hi, self.sweeps, r),
        };
        if self.slow {
            let s = if self.slow_sine {
                let ph = r.random_range(0.0..2.0 * PI);
                (0..n)
                    .map(|k| (2.0 * PI * self.slow_cycles * k as f64 / n as f64 + ph).sin())
                    .collect()
            } else {
                random_walk(n, self.slow_cycles, r)
            };
            let s = unit_rms(s);
            x.iter_mut()
                .zip(&s)
                .for_each(|(a, b)| *a += self.slow_share * b);
        }
        unit_rms(x)
    }
}

fn unit_rms(mut x: Vec<f64>) -> Vec<f64> {
    let s = gb_core::metrics::rms(&x);
    if s > 0.0 {
        x.iter_mut().for_each(|v| *v /= s);
    }
    x
}

/// Random-phase multisine on the bins of a period of at most 4096 samples
/// inside [lo, hi] cycles/sample, repeated over the record.
fn multisine(n: usize, lo: f64, hi: f64, r: &mut impl Rng) -> Vec<f64> {
    let p = n.clamp(16, 4096);
    let k_lo = ((lo * p as f64).ceil() as usize).max(1);
    let k_hi = ((hi * p as f64).floor() as usize).clamp(k_lo, p / 2 - 1);
    let cos_t: Vec<f64> = (0..p)
        .map(|i| (2.0 * PI * i as f64 / p as f64).cos())
        .collect();
    let sin_t: Vec<f64> = (0..p)
        .map(|i| (2.0 * PI * i as f64 / p as f64).sin())
        .collect();
    let mut period = vec![0.0; p];
    for k in k_lo..=k_hi {
        let ph: f64 = r.random_range(0.0..2.0 * PI);
        let (c, s) = (ph.cos(), ph.sin());
        for (t, v) in period.iter_mut().enumerate() {
            let i = (k * t) % p;
            *v += cos_t[i] * c - sin_t[i] * s;
        }
    }
    (0..n).map(|t| period[t % p]).collect()
}

/// One RBJ low-pass biquad section (Q = 1/√2) with cut-off `fc` cycles/sample.
pub(crate) struct Biquad {
    b: [f64; 3],
    a: [f64; 2],
    z: [f64; 2],
}

impl Biquad {
    pub(crate) fn lowpass(fc: f64) -> Self {
        let w0 = 2.0 * PI * fc.clamp(1e-5, 0.49);
        let alpha = w0.sin() / std::f64::consts::SQRT_2;
        let a0 = 1.0 + alpha;
        let c = w0.cos();
        Self {
            b: [(1.0 - c) / 2.0 / a0, (1.0 - c) / a0, (1.0 - c) / 2.0 / a0],
            a: [-2.0 * c / a0, (1.0 - alpha) / a0],
            z: [0.0; 2],
        }
    }

    /// Transposed direct form II.
    pub(crate) fn step(&mut self, x: f64) -> f64 {
        let y = self.b[0] * x + self.z[0];
        self.z[0] = self.b[1] * x - self.a[0] * y + self.z[1];
        self.z[1] = self.b[2] * x - self.a[1] * y;
        y
    }
}

/// White Gaussian noise through two low-pass biquads (after a warm-up).
pub(crate) fn lowpass_noise(n: usize, fc: f64, r: &mut impl Rng) -> Vec<f64> {
    let (mut f1, mut f2) = (Biquad::lowpass(fc), Biquad::lowpass(fc));
    let warm = ((4.0 / fc.max(1e-4)) as usize).min(20_000);
    let mut out = Vec::with_capacity(n);
    for k in 0..n + warm {
        let e: f64 = StandardNormal.sample(r);
        let y = f2.step(f1.step(e));
        if k >= warm {
            out.push(y);
        }
    }
    unit_rms(out)
}

fn prbs(n: usize, hold: usize, r: &mut impl Rng) -> Vec<f64> {
    let mut level = if r.random::<bool>() { 1.0 } else { -1.0 };
    (0..n)
        .map(|k| {
            if k % hold == 0 && r.random::<bool>() {
                level = -level;
            }
            level
        })
        .collect()
}

/// Logarithmic sweeps between `fa` and `fb` (cycles/sample), `sweeps`
/// segments alternating up and down, continuous phase.
fn sweep(n: usize, fa: f64, fb: f64, sweeps: usize, r: &mut impl Rng) -> Vec<f64> {
    let seg = (n / sweeps.max(1)).max(1);
    let mut phase = r.random_range(0.0..2.0 * PI);
    let ratio = fb / fa.max(1e-6);
    (0..n)
        .map(|k| {
            let s = k / seg;
            let t = (k % seg) as f64 / seg as f64;
            let t = if s % 2 == 0 { t } else { 1.0 - t };
            phase += 2.0 * PI * fa * ratio.powf(t);
            phase.sin()
        })
        .collect()
}

/// A leaky random walk with a corner at about `cycles` per record.
fn random_walk(n: usize, cycles: f64, r: &mut impl Rng) -> Vec<f64> {
    let leak = (-2.0 * PI * cycles / n.max(1) as f64).exp();
    let mut w = 0.0;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let e: f64 = StandardNormal.sample(r);
        w = leak * w + e;
        out.push(w);
    }
    // remove the mean so that the slow part does not only add an offset
    let m = gb_core::metrics::mean(&out);
    out.iter_mut().for_each(|v| *v -= m);
    out
}
