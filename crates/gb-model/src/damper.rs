//! A grey-box structure for magnetorheological (MR) dampers, after
//! Spencer et al. (1997): force from displacement `D`, velocity `V`, the
//! command voltage `Y` and optionally the actuator acceleration `A`.
//!
//! ```text
//! w₁⁺ = a₁ w₁ + b Y,   w₂⁺ = a₂₁ w₁ + a₂ w₂          voltage → field (2nd order)
//! r⁺  = a_r r + b_r V + a_rz z + a_rw·w              relative velocity (lag of V)
//! z⁺  = a_z z + f(r, z, w₂)                          hidden hysteretic state
//! q⁺  = R q + B_q u + e z + f_q(V, z, w₁)            rig resonances (2 states each)
//! F   = c·x + d·u + g(V, z, w₂) + F₀
//! ```
//!
//! Spencer's model drives the Bouc-Wen state by the velocity *relative* to
//! an internal displacement; here that relative velocity is the hidden state
//! `r`, and the Bouc-Wen law, the voltage dependence of its parameters and
//! the viscous/yield force are the 3-D `bior2.2` expansions `f` and `g`,
//! identified by output error. The load cell of a test rig sees structural
//! resonances above the excitation band; each is a 2-state linear block
//! driven by the inputs (with `A`: the inertia the cell feels), the first
//! also by z and by `f_q`.
use crate::basis::SparseExpansion;
use crate::error::{ModelError, Result};
use crate::identify::{OeParams, OeReport, OutputError};
use crate::model::{NoiseModel, NonlinearTerm, Signal, SparseStateSpace, Structure, Target};
use gb_core::Observer;

/// Options of the [MR damper structure](self). There is no `Default`: the
/// sample rate belongs to the record (its `t` column or the user) and the
/// resonance start frequencies to the test rig (the user, or the data:
/// [`spectral_peaks`] of the linear model's training residual).
#[derive(Debug, Clone, PartialEq)]
pub struct MrDamperStructure {
    /// Sample rate in Hz (for the resonance start frequencies).
    pub sample_rate: f64,
    /// Start frequencies (Hz) of the rig resonances, one 2-state block each
    /// (empty: none).
    pub resonances_hz: Vec<f64>,
    /// The relative-velocity state `r` (else `f` takes `V`).
    pub relative_velocity: bool,
    /// Second-order voltage filter (else first order).
    pub second_order_voltage: bool,
}

impl MrDamperStructure {
    /// The full structure (relative-velocity state, second-order voltage
    /// filter) for a record sampled at `sample_rate` Hz, with rig resonances
    /// started at `resonances_hz`.
    pub fn new(sample_rate: f64, resonances_hz: Vec<f64>) -> Self {
        Self {
            sample_rate,
            resonances_hz,
            relative_velocity: true,
            second_order_voltage: true,
        }
    }
}

/// What [`MrDamperStructure::fit_validated`] found.
#[derive(Debug, Clone)]
pub struct ValidatedFit {
    /// The model fitted on the whole record with the chosen ridge weight.
    pub model: SparseStateSpace,
    /// Its identification report.
    pub report: OeReport,
    /// The chosen structure.
    pub structure: MrDamperStructure,
    /// The chosen ridge weight.
    pub ridge: f64,
    /// `(structure index, ridge, validation NRMSE)` of every candidate
    /// (empty for one).
    pub scores: Vec<(usize, f64, f64)>,
}

/// Appends `k` states (zero rows and columns, `c` free) and returns the
/// index of the first.
fn grow(m: &mut SparseStateSpace, k: usize) -> usize {
    let (n0, nu) = (m.n_states, m.n_inputs);
    let n1 = n0 + k;
    let mut a = vec![0.0; n1 * n1];
    let mut af = vec![false; n1 * n1];
    for i in 0..n0 {
        for j in 0..n0 {
            a[i * n1 + j] = m.a[i * n0 + j];
            af[i * n1 + j] = m.structure.a[i * n0 + j];
        }
    }
    m.a = a;
    m.structure.a = af;
    m.b.extend(vec![0.0; k * nu]);
    m.structure.b.extend(vec![false; k * nu]);
    m.c.extend(vec![0.0; k]);
    m.structure.c.extend(vec![true; k]);
    m.x0.extend(vec![0.0; k]);
    m.structure.x0.extend(vec![false; k]);
    m.process_noise
        .extend(vec![NoiseModel::Gaussian { sd: 0.0 }; k]);
    m.n_states = n1;
    n0
}

impl MrDamperStructure {
    /// The start model for `inputs = [D, V, Y]` or `[D, V, Y, A]` and the
    /// measured force `y` (for its mean): all linear couplings at small
    /// values, the wavelet terms empty on boxes of ±1.25 × the start model's
    /// state ranges (±1.1 × max |V| for velocities).
    ///
    /// ```
    /// let n = 400;
    /// let u: Vec<Vec<f64>> = (0..3)
    ///     .map(|k| (0..n).map(|t| ((t * (k + 1)) as f64 * 0.05).sin()).collect())
    ///     .collect();
    /// let y = vec![1.0; n];
    /// let m = gb_model::MrDamperStructure::new(1000.0, vec![150.0, 120.0]).start(&u, &y)?;
    /// assert_eq!(m.n_states, 8); // z, w₁, w₂, r, two resonances
    /// assert_eq!(m.terms.len(), 3);
    /// # Ok::<(), gb_model::ModelError>(())
    /// ```
    pub fn start(&self, inputs: &[Vec<f64>], y: &[f64]) -> Result<SparseStateSpace> {
        let nu = inputs.len();
        if !(3..=4).contains(&nu) {
            return Err(ModelError::InvalidArgument(format!(
                "the MR damper structure takes inputs D, V, Y [, A], got {nu} inputs"
            )));
        }
        let n = y.len();
        if n < 2 || inputs.iter().any(|s| s.len() != n) {
            return Err(ModelError::InvalidArgument(
                "inputs and force must have the same length (≥ 2)".into(),
            ));
        }
        if !(self.sample_rate > 0.0 && self.sample_rate.is_finite())
            || self
                .resonances_hz
                .iter()
                .any(|f| !(*f > 0.0 && *f < 0.5 * self.sample_rate))
        {
            return Err(ModelError::InvalidArgument(
                "resonance frequencies must lie in (0, sample rate / 2)".into(),
            ));
        }
        // z ← V, w ← Y
        let mut m = SparseStateSpace::linear(vec![0.95], vec![0.0; nu], vec![0.0], vec![0.0; nu])?;
        m.b[1] = 0.05;
        m.structure = Structure {
            a: vec![true],
            b: vec![false; nu],
            c: vec![true],
            d: vec![true; nu],
            x0: vec![false],
            y_offset: true,
        };
        m.structure.b[1] = true;
        m.y_offset = gb_core::metrics::mean(y);
        let w1 = grow(&mut m, 1);
        let ns = |m: &SparseStateSpace| m.n_states;
        let set = |m: &mut SparseStateSpace, i: usize, j: usize, v: f64| {
            let n = ns(m);
            m.a[i * n + j] = v;
            m.structure.a[i * n + j] = true;
        };
        let setb = |m: &mut SparseStateSpace, i: usize, j: usize, v: f64| {
            m.b[i * nu + j] = v;
            m.structure.b[i * nu + j] = true;
        };
        set(&mut m, w1, w1, 0.95);
        setb(&mut m, w1, 2, 0.05);
        let w = if self.second_order_voltage {
            let w2 = grow(&mut m, 1);
            // the growth left w₁'s row in place
            let n_now = ns(&m);
            m.a[w1 * n_now + w1] = 0.9;
            m.b[w1 * nu + 2] = 0.1;
            set(&mut m, w2, w1, 0.1);
            set(&mut m, w2, w2, 0.9);
            w2
        } else {
            w1
        };
        let r = if self.relative_velocity {
            let r = grow(&mut m, 1);
            for j in 0..ns(&m) {
                set(&mut m, r, j, if j == r { 0.3 } else { 0.0 });
            }
            setb(&mut m, r, 1, 0.7);
            Some(r)
        } else {
            None
        };
        let res0 = ns(&m);
        for (k, hz) in self.resonances_hz.iter().enumerate() {
            let p = grow(&mut m, 2);
            let q = p + 1;
            let th = std::f64::consts::TAU * hz / self.sample_rate;
            let rad = 0.97;
            set(&mut m, p, p, rad * th.cos());
            set(&mut m, p, q, -rad * th.sin());
            set(&mut m, q, p, rad * th.sin());
            set(&mut m, q, q, rad * th.cos());
            for i in [p, q] {
                if k == 0 {
                    set(&mut m, i, 0, 0.0); // driven by z
                }
                for j in 0..nu {
                    setb(&mut m, i, j, 0.0);
                }
            }
            m.b[p * nu + 1] = 0.01;
        }
        // boxes from the start model's simulation
        let (_, xs) = m.simulate_states(inputs)?;
        let n_s = ns(&m);
        let span = |i: usize| {
            let (lo, hi) = xs
                .chunks(n_s)
                .fold((f64::MAX, f64::MIN), |(a, b), x| (a.min(x[i]), b.max(x[i])));
            let h = 0.25 * (hi - lo).max(1e-9);
            (lo - h, hi + h)
        };
        let vmax = inputs[1]
            .iter()
            .fold(0.0f64, |a, x| a.max(x.abs()))
            .max(1e-9)
            * 1.1;
        let (zl, zh) = span(0);
        let (wl, wh) = span(w);
        let (w1l, w1h) = span(w1);
        let drive = match r {
            Some(r) => {
                let (rl, rh) = span(r);
                let rm = rl.abs().max(rh.abs()).max(vmax);
                (Signal::State(r), -rm, rm)
            }
            None => (Signal::Input(1), -vmax, vmax),
        };
        m.terms.push(NonlinearTerm {
            target: Target::State(0),
            args: vec![drive.0, Signal::State(0), Signal::State(w)],
            expansion: SparseExpansion::new(
                "bior2.2",
                vec![drive.1, zl, wl],
                vec![drive.2, zh, wh],
            )?,
        });
        m.terms.push(NonlinearTerm {
            target: Target::Output,
            args: vec![Signal::Input(1), Signal::State(0), Signal::State(w)],
            expansion: SparseExpansion::new("bior2.2", vec![-vmax, zl, wl], vec![vmax, zh, wh])?,
        });
        if !self.resonances_hz.is_empty() {
            m.terms.push(NonlinearTerm {
                target: Target::State(res0),
                args: vec![Signal::Input(1), Signal::State(0), Signal::State(w1)],
                expansion: SparseExpansion::new(
                    "bior2.2",
                    vec![-vmax, zl, w1l],
                    vec![vmax, zh, w1h],
                )?,
            });
        }
        m.check()?;
        Ok(m)
    }

    /// Starts from [`start`](Self::start) and identifies by output error.
    pub fn fit(
        &self,
        oe: &OutputError,
        inputs: &[Vec<f64>],
        y: &[f64],
        obs: &dyn Observer,
    ) -> Result<(SparseStateSpace, OeReport)> {
        oe.fit(self.start(inputs, y)?, inputs, y, obs)
    }

    /// Chooses the ridge weight among `ridges` on the last 20 % of the
    /// record (fit on the first 80 %, free run of the whole record from
    /// rest, NRMSE on the last 20 %; a fit that fails or diverges scores
    /// ∞), then fits on all of it with the winner. `oe` gives the other
    /// options.
    ///
    /// ```no_run
    /// # let (u, f): (Vec<Vec<f64>>, Vec<f64>) = (vec![], vec![]);
    /// let fit = gb_model::MrDamperStructure::new(3004.8, vec![150.0]).fit_validated(
    ///     &gb_model::OeParams::new(), &[0.0, 1e3], &u, &f, &gb_model::Silent)?;
    /// println!("ridge {} chosen: {:?}", fit.ridge, fit.scores);
    /// # Ok::<(), gb_model::ModelError>(())
    /// ```
    pub fn fit_validated(
        &self,
        oe: &OeParams,
        ridges: &[f64],
        inputs: &[Vec<f64>],
        y: &[f64],
        obs: &dyn Observer,
    ) -> Result<ValidatedFit> {
        Self::select(std::slice::from_ref(self), oe, ridges, inputs, y, obs)
    }

    /// [`fit_validated`](Self::fit_validated) over several structures: every
    /// (structure, ridge) pair is scored on the last 20 % of the record, the
    /// best is refitted on all of it.
    pub fn select(
        structures: &[MrDamperStructure],
        oe: &OeParams,
        ridges: &[f64],
        inputs: &[Vec<f64>],
        y: &[f64],
        obs: &dyn Observer,
    ) -> Result<ValidatedFit> {
        let n = y.len();
        let n_val = n * 8 / 10;
        if ridges.is_empty() || structures.is_empty() || n_val < 2 || n_val == n {
            return Err(ModelError::InvalidArgument(
                "the selection needs a structure, a ridge weight and a record of ≥ 10 samples"
                    .into(),
            ));
        }
        let mut scores = Vec::new();
        let mut best = (f64::INFINITY, 0, ridges[0]);
        if ridges.len() * structures.len() > 1 {
            let head: Vec<Vec<f64>> = inputs
                .iter()
                .map(|s| s[..n_val.min(s.len())].to_vec())
                .collect();
            for (k, st) in structures.iter().enumerate() {
                for &r in ridges {
                    let e = oe
                        .clone()
                        .ridge(r)
                        .check()
                        .and_then(|f| st.fit(&f, &head, &y[..n_val], &crate::Silent))
                        .and_then(|(m, _)| m.simulate(inputs))
                        .ok()
                        .and_then(|s| gb_core::metrics::nrmse(&y[n_val..], &s[n_val..]).ok())
                        .filter(|e| e.is_finite())
                        .unwrap_or(f64::INFINITY);
                    scores.push((k, r, e));
                    if e < best.0 {
                        best = (e, k, r);
                    }
                }
            }
        }
        let structure = structures[best.1].clone();
        let (model, report) = structure.fit(&oe.clone().ridge(best.2).check()?, inputs, y, obs)?;
        Ok(ValidatedFit {
            model,
            report,
            structure,
            ridge: best.2,
            scores,
        })
    }
}

/// Welch power spectrum of `signal`: Hann-windowed segments of `len`
/// samples (a power of two), half overlapping, mean removed; bin `k` is
/// `k·fs/len` Hz, `k = 0..=len/2`. Bins below `from_bin` are left at 0.
fn welch(signal: &[f64], len: usize, from_bin: usize) -> Vec<f64> {
    let half = len / 2;
    let mut psd = vec![0.0; half + 1];
    let win: Vec<f64> = (0..len)
        .map(|i| 0.5 - 0.5 * (std::f64::consts::TAU * i as f64 / len as f64).cos())
        .collect();
    let mut seg = vec![0.0; len];
    let mut start = 0;
    let mut count = 0usize;
    while start + len <= signal.len() {
        let s = &signal[start..start + len];
        let mean = s.iter().sum::<f64>() / len as f64;
        for ((o, x), w) in seg.iter_mut().zip(s).zip(&win) {
            *o = (x - mean) * w;
        }
        for (k, p) in psd.iter_mut().enumerate().skip(from_bin) {
            // Goertzel: |Σ x_i e^{−2πi k i / len}|²
            let c = 2.0 * (std::f64::consts::TAU * k as f64 / len as f64).cos();
            let (mut s1, mut s2) = (0.0, 0.0);
            for &x in &seg {
                let s0 = x + c * s1 - s2;
                s2 = s1;
                s1 = s0;
            }
            *p += s1 * s1 + s2 * s2 - c * s1 * s2;
        }
        count += 1;
        start += half;
    }
    for p in psd.iter_mut() {
        *p /= count.max(1) as f64;
    }
    psd
}

/// The frequency (Hz) below which `fraction` of the power of `signal`
/// (mean removed) lies, from its Welch spectrum: the excitation band of an
/// input.
pub fn band_edge(signal: &[f64], sample_rate: f64, fraction: f64) -> Result<f64> {
    let len = welch_len(signal.len())?;
    check_rate(sample_rate)?;
    let psd = welch(signal, len, 1);
    let total: f64 = psd.iter().sum();
    let mut acc = 0.0;
    for (k, p) in psd.iter().enumerate() {
        acc += p;
        if acc >= fraction * total {
            return Ok(k as f64 * sample_rate / len as f64);
        }
    }
    Ok(0.5 * sample_rate)
}

fn welch_len(n: usize) -> Result<usize> {
    if n < 256 {
        return Err(ModelError::InvalidArgument(format!(
            "{n} samples are too few for a spectrum (at least 256)"
        )));
    }
    // segments of at most 512 samples (a smooth spectrum whose peaks are the
    // broad resonance humps, not single noisy bins), ≥ 4 per record
    let mut len = 512usize;
    while len > 256 && len * 4 > n {
        len /= 2;
    }
    Ok(len)
}

fn check_rate(sample_rate: f64) -> Result<()> {
    if sample_rate > 0.0 && sample_rate.is_finite() {
        Ok(())
    } else {
        Err(ModelError::InvalidArgument(format!(
            "sample rate must be > 0, got {sample_rate}"
        )))
    }
}

/// The `count` largest peaks (Hz) of the Welch power spectrum of `signal`
/// above `min_hz`, strongest first, at least 10 % of their frequency apart.
///
/// The data-driven start of the rig resonances of [`MrDamperStructure`]:
/// the peaks of the *training* residual of the best linear model above the
/// excitation band ([`band_edge`] of the velocity input), which are what
/// the load cell sees beyond the damper. Segments of up to 512 samples
/// (a resolution of `fs/512`, 5.9 Hz at 3 kHz), Hann window, half overlap,
/// peaks refined by a parabola through the log spectrum. On the Dyke MR
/// damper record (training part) this gives 178 and 284 Hz, not the 150 and
/// 120 Hz of the documented results (see docs/model.md).
///
/// ```
/// let fs = 1000.0;
/// let x: Vec<f64> = (0..8000)
///     .map(|t| {
///         let t = t as f64 / fs;
///         (std::f64::consts::TAU * 150.0 * t).sin() + 0.5 * (std::f64::consts::TAU * 320.0 * t).sin()
///     })
///     .collect();
/// let p = gb_model::spectral_peaks(&x, fs, 100.0, 2)?;
/// assert!((p[0] - 150.0).abs() < 1.0 && (p[1] - 320.0).abs() < 1.0);
/// # Ok::<(), gb_model::ModelError>(())
/// ```
pub fn spectral_peaks(
    signal: &[f64],
    sample_rate: f64,
    min_hz: f64,
    count: usize,
) -> Result<Vec<f64>> {
    let len = welch_len(signal.len())?;
    check_rate(sample_rate)?;
    if signal.iter().any(|v| !v.is_finite()) {
        return Err(ModelError::InvalidArgument("signal must be finite".into()));
    }
    let df = sample_rate / len as f64;
    let from = ((min_hz.max(0.0) / df).ceil() as usize).max(1);
    let psd = welch(signal, len, from.saturating_sub(1));
    let mut peaks: Vec<(f64, f64)> = (from.max(1)..len / 2)
        .filter(|&k| psd[k] > psd[k - 1] && psd[k] >= psd[k + 1])
        .map(|k| {
            // parabolic interpolation of the peak on the log spectrum
            let (a, b, c) = (
                psd[k - 1].max(1e-300).ln(),
                psd[k].max(1e-300).ln(),
                psd[k + 1].max(1e-300).ln(),
            );
            let den = a - 2.0 * b + c;
            let off = if den < 0.0 { 0.5 * (a - c) / den } else { 0.0 };
            ((k as f64 + off.clamp(-0.5, 0.5)) * df, psd[k])
        })
        .collect();
    peaks.sort_by(|a, b| b.1.total_cmp(&a.1));
    let mut out: Vec<f64> = Vec::new();
    for (f, _) in peaks {
        if out.len() == count {
            break;
        }
        if out.iter().all(|g| (f - g).abs() >= 0.1 * f.max(*g)) {
            out.push(f);
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The structure of the Dyke test rig (examples/mr_damper.rs).
    fn rig() -> MrDamperStructure {
        MrDamperStructure::new(3004.8, vec![150.0, 120.0])
    }

    fn record(n: usize, n_inputs: usize) -> (Vec<Vec<f64>>, Vec<f64>) {
        let u = (0..n_inputs)
            .map(|k| {
                (0..n)
                    .map(|t| ((t * (k + 2)) as f64 * 0.03).sin())
                    .collect()
            })
            .collect();
        (u, (0..n).map(|t| (t as f64 * 0.05).cos()).collect())
    }

    #[test]
    fn bad_records_and_options_are_rejected() {
        let s = rig();
        let (u, y) = record(300, 2);
        assert!(s.start(&u, &y).is_err(), "two inputs");
        let (u, y) = record(300, 3);
        assert!(s.start(&u, &y[..299]).is_err(), "lengths differ");
        let bad = MrDamperStructure::new(3004.8, vec![2000.0]);
        assert!(bad.start(&u, &y).is_err(), "resonance above Nyquist");
        let fit = s.fit_validated(&OeParams::new(), &[], &u, &y, &crate::Silent);
        assert!(fit.is_err(), "no ridge candidate");
        let sel = MrDamperStructure::select(&[], &OeParams::new(), &[0.0], &u, &y, &crate::Silent);
        assert!(sel.is_err(), "no structure");
    }

    #[test]
    fn four_inputs_drive_only_the_resonances_and_the_output() {
        let (u, y) = record(300, 4);
        let m = rig().start(&u, &y).unwrap();
        let (n, nu) = (m.n_states, m.n_inputs);
        assert_eq!((n, nu), (8, 4));
        // the acceleration column of B is free only on the resonance rows
        for i in 0..n {
            assert_eq!(m.structure.b[i * nu + 3], i >= 4, "row {i}");
        }
        assert!(m.structure.d[3]);
        let without = MrDamperStructure {
            relative_velocity: false,
            second_order_voltage: false,
            ..MrDamperStructure::new(3004.8, vec![])
        };
        let m = without.start(&u[..3], &y).unwrap();
        assert_eq!(m.n_states, 2);
        assert_eq!(m.terms.len(), 2);
        assert_eq!(m.terms[0].args[0], Signal::Input(1));
    }

    #[test]
    fn spectra_find_the_band_and_the_peaks() {
        let fs = 2000.0;
        let tone = |f: f64, t: usize| (std::f64::consts::TAU * f * t as f64 / fs).sin();
        // "excitation" at 20 and 40 Hz, weak "resonances" at 300 and 180 Hz
        let x: Vec<f64> = (0..12_000)
            .map(|t| tone(20.0, t) + tone(40.0, t) + 0.05 * tone(300.0, t) + 0.03 * tone(180.0, t))
            .collect();
        let edge = band_edge(&x, fs, 0.99).unwrap();
        assert!((35.0..60.0).contains(&edge), "{edge}");
        let p = spectral_peaks(&x, fs, edge + 20.0, 2).unwrap();
        assert_eq!(p.len(), 2);
        assert!(
            (p[0] - 300.0).abs() < 2.0 && (p[1] - 180.0).abs() < 2.0,
            "{p:?}"
        );
        assert!(spectral_peaks(&x[..100], fs, 50.0, 2).is_err());
        assert!(spectral_peaks(&x, 0.0, 50.0, 2).is_err());
        assert!(band_edge(&x, f64::NAN, 0.9).is_err());
    }
}
