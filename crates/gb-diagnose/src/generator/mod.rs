//! A broad generator of identification problems to tune the diagnosis on.
//!
//! Each [`Case`] is drawn at random from a family of systems: training and
//! validation records (independent input realisations of the same system),
//! the ground truth (family, expected causes, which causes would be a
//! misdiagnosis), the noise floor, the effect strength and the parameters.
//! Fixed seed ⇒ identical data on every platform (Xoshiro streams of
//! [`gb_core::rng`]).
//!
//! | family | system | expected |
//! |---|---|---|
//! | `linear` | cascade of order 1–4 (real poles, resonant pairs), input delay 0–3, sometimes direct feedthrough | — |
//! | `dead-time` | order 1–2 with a dead time of 4–12 samples | — |
//! | `duffing` | mass–spring–damper with a cubic spring | nonlinearity |
//! | `hammerstein-odd` | L·tanh(u/L) or u + a·u³ before a cascade of order 1–3 | nonlinearity |
//! | `hammerstein-even` | u + a·u² or u + a·\|u\| before a cascade | nonlinearity |
//! | `wiener` | cascade, then a tanh sensor saturation or a polynomial | nonlinearity |
//! | `saturation` | input clipped at a quantile of \|u\| | nonlinearity |
//! | `deadzone` | input dead zone | nonlinearity |
//! | `friction` | Coulomb (F_c·tanh(v/ε)) + viscous friction on a mass; velocity or position output | nonlinearity (position: or hysteresis) |
//! | `backlash` | input backlash (play operator) | hysteresis |
//! | `preisach` | relay-grid Preisach spring on the position, inside the loop | hysteresis |
//! | `bouc-wen` | Bouc–Wen restoring force | hysteresis |
//! | `two-mass` | a hidden second mass (the engineer's model has order 2) | dynamics |
//! | `lag` | a cascade of order 3, input delay 0–2 (the engineer's model has order 2) | dynamics |
//! | `two-input` | two inputs, a static nonlinearity on one ([`Case::nonlinear_input`]) | nonlinearity |
//! | `student-t` | Student-t output noise, ν 2.5–4 | noise |
//! | `coloured-noise` | ARMA(1,1) output noise | noise (or none) |
//! | `process-noise` | a low-pass force disturbance in the dynamics | noise (or none) |
//! | `integrator` | a free mass with viscous friction, position output (an integrating system: force → position); in two draws of three Coulomb friction as well | none, or nonlinearity (or hysteresis) |
//!
//! Per draw: the physical parameters, the samples per resonance period (or
//! per time constant) 5–60, the excitation ([`ExcitationKind`], sometimes
//! with a slow component), the SNR 20–45 dB and the training length
//! 500–20 000 (validation about half, at least 300). [`Knobs`] override them.
//!
//! ```
//! use gb_diagnose::generator::{draw_with, Knobs};
//! let c = draw_with("backlash", 3, &Knobs { n_train: Some(800), ..Knobs::default() }).unwrap();
//! assert_eq!(c.train.len(), 800);
//! assert_eq!(c.expected, ["hysteresis"]);
//! ```
mod ctx;
mod excite;
mod families;
mod linfit;
mod maps;
mod noise;
mod plant;
mod realise;
#[cfg(test)]
mod tests;

pub use excite::{Excitation, ExcitationKind};
pub use linfit::{arx_misfit, Arx};
pub use noise::NoiseKind;

use gb_core::{CoreError, Record};
use serde::{Deserialize, Serialize};

/// The families of systems.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[allow(missing_docs)]
pub enum Family {
    Linear,
    DeadTime,
    Duffing,
    HammersteinOdd,
    HammersteinEven,
    Wiener,
    Saturation,
    DeadZone,
    Friction,
    Backlash,
    Preisach,
    BoucWen,
    TwoMass,
    Lag,
    TwoInput,
    StudentT,
    ColouredNoise,
    ProcessNoise,
    Integrator,
}

/// Names of the families, in the order of [`Family::ALL`].
pub const FAMILIES: [&str; 19] = [
    "linear",
    "dead-time",
    "duffing",
    "hammerstein-odd",
    "hammerstein-even",
    "wiener",
    "saturation",
    "deadzone",
    "friction",
    "backlash",
    "preisach",
    "bouc-wen",
    "two-mass",
    "lag",
    "two-input",
    "student-t",
    "coloured-noise",
    "process-noise",
    "integrator",
];

impl Family {
    /// Every family.
    pub const ALL: [Self; 19] = [
        Self::Linear,
        Self::DeadTime,
        Self::Duffing,
        Self::HammersteinOdd,
        Self::HammersteinEven,
        Self::Wiener,
        Self::Saturation,
        Self::DeadZone,
        Self::Friction,
        Self::Backlash,
        Self::Preisach,
        Self::BoucWen,
        Self::TwoMass,
        Self::Lag,
        Self::TwoInput,
        Self::StudentT,
        Self::ColouredNoise,
        Self::ProcessNoise,
        Self::Integrator,
    ];

    /// The family's name.
    pub fn name(&self) -> &'static str {
        let i = Self::ALL.iter().position(|f| f == self).unwrap_or(0);
        FAMILIES[i]
    }

    /// Parse a family name.
    pub fn parse(name: &str) -> Result<Self, CoreError> {
        FAMILIES
            .iter()
            .position(|f| *f == name)
            .map(|i| Self::ALL[i])
            .ok_or_else(|| {
                CoreError::InvalidArgument(format!(
                    "unknown family '{name}' (known: {})",
                    FAMILIES.join(", ")
                ))
            })
    }
}

/// Fixed knobs of a draw (`None`: drawn at random).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Knobs {
    /// Training samples (500–20 000 when drawn).
    pub n_train: Option<usize>,
    /// Validation samples (about half the training length, at least 300).
    pub n_validate: Option<usize>,
    /// Output signal-to-noise ratio in dB (20–45).
    pub snr_db: Option<f64>,
    /// Excitation kind.
    pub excitation: Option<ExcitationKind>,
    /// Add a slow component to the excitation.
    pub slow_component: Option<bool>,
    /// Samples per resonance period or per time constant (5–60).
    pub samples_per_period: Option<f64>,
    /// Generate without any noise (same system, inputs and SNR draw): the
    /// outputs are the true system's.
    pub noise_free: bool,
}

impl Knobs {
    /// Knobs that fix only the record lengths: `n_train` training and
    /// `n_validate` validation samples, everything else drawn.
    pub fn lengths(n_train: usize, n_validate: usize) -> Self {
        Self {
            n_train: Some(n_train),
            n_validate: Some(n_validate),
            ..Self::default()
        }
    }

    fn check(&self) -> Result<(), CoreError> {
        let bad = |m: &str| Err(CoreError::InvalidArgument(format!("generator knobs: {m}")));
        if self
            .n_train
            .is_some_and(|n| !(200..=10_000_000).contains(&n))
        {
            return bad("n_train must be 200..=10000000");
        }
        if self
            .n_validate
            .is_some_and(|n| !(100..=10_000_000).contains(&n))
        {
            return bad("n_validate must be 100..=10000000");
        }
        if self.snr_db.is_some_and(|s| !(-20.0..=200.0).contains(&s)) {
            return bad("snr_db must be -20..=200");
        }
        if self
            .samples_per_period
            .is_some_and(|s| !(2.0..=10_000.0).contains(&s))
        {
            return bad("samples_per_period must be 2..=10000");
        }
        Ok(())
    }
}

/// One generated identification problem and its ground truth.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Case {
    /// Family name.
    pub family: String,
    /// Seed.
    pub seed: u64,
    /// What the system is, in one line.
    pub description: String,
    /// Training record.
    pub train: Record,
    /// Validation record (independent input realisation, same system).
    pub validate: Record,
    /// The causes hidden in the data (`[]`: none).
    pub expected: Vec<String>,
    /// Other cause sets that also count as right (e.g. `[[]]` for Gaussian
    /// coloured or process noise, which an output-error model cannot reduce).
    pub acceptable_alternatives: Vec<Vec<String>>,
    /// Cause names whose naming is a misdiagnosis.
    pub foreign: Vec<String>,
    /// NRMSE of the true noise-free system on the validation record:
    /// std(output noise) / std(y), or for process noise
    /// rms(y − y_noise-free) / std(y).
    pub noise_floor_nrmse: f64,
    /// Nominal SNR in dB: 20 log₁₀(std(noise-free y) / noise std).
    pub snr_db: f64,
    /// The noise put in.
    pub noise: NoiseKind,
    /// Sample time (s).
    pub ts: f64,
    /// Samples per resonance period (or per time constant).
    pub samples_per_period: f64,
    /// The excitation.
    pub excitation: Excitation,
    /// The order of the engineer's baseline (the true order, except for
    /// unmodelled dynamics).
    pub model_order: usize,
    /// The dynamic order of the true system.
    pub true_order: usize,
    /// Input delay in samples (besides the one sample of ZOH sampling).
    pub input_delay: usize,
    /// y(k) responds to u(k).
    pub feedthrough: bool,
    /// Which input carries the nonlinearity (two-input family).
    pub nonlinear_input: Option<usize>,
    /// Free-run validation NRMSE of the least-squares ARX model (orders
    /// true + 2, the true delay) fitted on noise-free training data, scored
    /// on noise-free validation data: how far the system is from linear. For
    /// `two-mass` and `lag` the ARX has the engineer's order (the unmodelled
    /// mode or pole).
    pub effect_strength: f64,
    /// Parameters (name, value); `*_rel` are relative to signal levels.
    pub parameters: Vec<(String, f64)>,
}

impl Case {
    /// True when `named` is a right set of causes: every named cause is
    /// expected and at least one expected cause is named (or none expected
    /// and none named), or `named` equals an acceptable alternative.
    pub fn causes_right(&self, named: &[String]) -> bool {
        let set = |v: &[String]| {
            let mut s = v.to_vec();
            s.sort();
            s.dedup();
            s
        };
        let n = set(named);
        let fits = n.iter().all(|c| self.expected.contains(c))
            && (self.expected.is_empty() == n.is_empty());
        fits || self.acceptable_alternatives.iter().any(|a| set(a) == n)
    }

    /// The named causes that are foreign (a misdiagnosis).
    pub fn foreign_named(&self, named: &[String]) -> Vec<String> {
        named
            .iter()
            .filter(|c| self.foreign.contains(c))
            .cloned()
            .collect()
    }
}

/// A case of `family` with every knob drawn from `seed`.
pub fn draw(family: &str, seed: u64) -> Result<Case, CoreError> {
    draw_with(family, seed, &Knobs::default())
}

/// A case of `family` from `seed` with some knobs fixed. The random
/// numbers drawn for the system do not depend on the knobs (levels set
/// relative to the signals, such as a saturation at a quantile of |u|, and
/// the sample time, set by the samples per period, do).
pub fn draw_with(family: &str, seed: u64, knobs: &Knobs) -> Result<Case, CoreError> {
    let fam = Family::parse(family)?;
    knobs.check()?;
    realise::realise(fam, seed, knobs)
}
