//! The draw context shared by the family builders: the knobs drawn for a
//! case, the unit-rms excitations, and pilot simulations that size the
//! nonlinear effects relative to the signal levels.
use super::excite::{Excitation, ExcitationKind};
use super::noise::NoiseKind;
use super::plant::{System, Trace};
use super::Knobs;
use gb_core::{metrics, rng, CoreError};
use rand::Rng;

/// Uniform in [a, b).
pub(crate) fn uni(r: &mut impl Rng, a: f64, b: f64) -> f64 {
    if b > a {
        r.random_range(a..b)
    } else {
        a
    }
}

/// Log-uniform in [a, b).
pub(crate) fn logu(r: &mut impl Rng, a: f64, b: f64) -> f64 {
    uni(r, a.ln(), b.ln()).exp()
}

/// The global knobs of a case, drawn before the family's parameters.
#[derive(Debug, Clone)]
pub(crate) struct Drawn {
    pub n_train: usize,
    pub n_validate: usize,
    pub snr_db: f64,
    pub spp: f64,
    pub excitation: Excitation,
    /// the knob fixed `slow`
    pub slow_fixed: bool,
}

impl Drawn {
    /// Every random number is drawn even when a knob overrides it, so the
    /// family's parameters do not depend on the overrides.
    pub(crate) fn draw(r: &mut impl Rng, k: &Knobs) -> Self {
        let n_train = logu(r, 500.0, 20_000.0).round() as usize;
        let frac = uni(r, 0.4, 0.6);
        let snr_db = uni(r, 20.0, 45.0);
        let spp = logu(r, 5.0, 60.0);
        let excitation = Excitation::draw(r, k.excitation, k.slow_component);
        let n_train = k.n_train.unwrap_or(n_train);
        let n_validate = k
            .n_validate
            .unwrap_or_else(|| ((n_train as f64 * frac).round() as usize).max(300));
        Self {
            n_train,
            n_validate,
            snr_db: k.snr_db.unwrap_or(snr_db),
            spp: k.samples_per_period.unwrap_or(spp),
            excitation,
            slow_fixed: k.slow_component.is_some(),
        }
    }
}

/// Signal levels of a pilot run.
#[derive(Debug, Clone)]
pub(crate) struct Levels {
    pub y: Vec<f64>,
    pub trace: Trace,
}

/// rms about the mean.
pub(crate) fn std(x: &[f64]) -> f64 {
    metrics::std(x).max(1e-300)
}

/// The `p`-quantile of |x − mean(x)|.
pub(crate) fn abs_quantile(x: &[f64], p: f64) -> f64 {
    let m = metrics::mean(x);
    let mut a: Vec<f64> = x.iter().map(|v| (v - m).abs()).collect();
    a.sort_by(f64::total_cmp);
    if a.is_empty() {
        return 0.0;
    }
    let i = ((a.len() - 1) as f64 * p.clamp(0.0, 1.0)).round() as usize;
    a[i].max(1e-300)
}

/// A family's description of the case.
pub(crate) struct Built {
    pub system: System,
    pub expected: Vec<&'static str>,
    pub alternatives: Vec<Vec<&'static str>>,
    /// the engineer's baseline order
    pub model_order: usize,
    /// dynamic order of the true system
    pub true_order: usize,
    pub noise: NoiseKind,
    pub nonlinear_input: Option<usize>,
    pub description: String,
    pub parameters: Vec<(String, f64)>,
    /// measure the effect with the engineer's ARX structure (unmodelled dynamics)
    pub strength_engineer: bool,
}

impl Built {
    pub(crate) fn new(system: System, order: usize, expected: Vec<&'static str>) -> Self {
        Self {
            system,
            expected,
            alternatives: vec![],
            model_order: order,
            true_order: order,
            noise: NoiseKind::White,
            nonlinear_input: None,
            description: String::new(),
            parameters: vec![],
            strength_engineer: false,
        }
    }

    pub(crate) fn param(&mut self, name: &str, v: f64) {
        self.parameters.push((name.to_string(), v));
    }
}

/// Shared state of one draw.
pub(crate) struct Ctx {
    pub base: u64,
    pub drawn: Drawn,
    pub ts: f64,
    /// reference (band) frequency in cycles/sample
    pub f_ref: f64,
    /// unit-rms excitations
    pub u_train: Vec<Vec<f64>>,
    pub u_val: Vec<Vec<f64>>,
}

impl Ctx {
    pub(crate) fn new(base: u64, drawn: Drawn) -> Self {
        Self {
            base,
            drawn,
            ts: 1.0,
            f_ref: 0.1,
            u_train: vec![],
            u_val: vec![],
        }
    }

    /// A static map of a binary input is a gain: with PRBS, add the slow
    /// component (unless the knobs fixed it) so that the amplitude varies.
    pub(crate) fn need_amplitude_spread(&mut self) {
        if self.drawn.excitation.kind == ExcitationKind::Prbs && !self.drawn.slow_fixed {
            self.drawn.excitation.slow = true;
        }
    }

    /// Set the sample time (`t_ref` seconds is `spp` samples) and realise
    /// the unit-rms excitations, band relative to `f_band` Hz.
    pub(crate) fn excite(&mut self, t_ref: f64, f_band: f64, n_inputs: usize) {
        self.ts = t_ref / self.drawn.spp;
        self.f_ref = (f_band * self.ts).clamp(1e-4, 0.4);
        self.u_train.clear();
        self.u_val.clear();
        for j in 0..n_inputs as u64 {
            let mut rt = rng::stream(self.base, 100 + 2 * j);
            let mut rv = rng::stream(self.base, 101 + 2 * j);
            let e = &self.drawn.excitation;
            self.u_train
                .push(e.realise(self.drawn.n_train, self.f_ref, &mut rt));
            self.u_val
                .push(e.realise(self.drawn.n_validate, self.f_ref, &mut rv));
        }
    }

    /// Physical inputs of `sys` (training or validation).
    pub(crate) fn inputs(&self, sys: &System, train: bool) -> Vec<Vec<f64>> {
        let u = if train { &self.u_train } else { &self.u_val };
        u.iter()
            .zip(&sys.input_scale)
            .map(|(x, s)| x.iter().map(|v| v * s).collect())
            .collect()
    }

    /// `p`-quantile of |u_j| (physical units of `sys`) on the training record.
    pub(crate) fn input_quantile(&self, sys: &System, j: usize, p: f64) -> f64 {
        let s = sys.input_scale.get(j).copied().unwrap_or(1.0);
        self.u_train.get(j).map_or(1.0, |u| s * abs_quantile(u, p))
    }

    /// Simulate `sys` (ts and sub-steps set here) on at most 4000 training samples.
    pub(crate) fn levels(&self, sys: &mut System, hint: f64) -> Result<Levels, CoreError> {
        sys.ts = self.ts;
        sys.set_substeps(hint);
        let n = self.drawn.n_train.min(4000);
        let u: Vec<Vec<f64>> = self
            .inputs(sys, true)
            .into_iter()
            .map(|mut x| {
                x.truncate(n);
                x
            })
            .collect();
        let mut trace = Trace::default();
        let y = sys.simulate(&u, None, Some(&mut trace))?;
        Ok(Levels { y, trace })
    }
}
