//! Parameters of the input–output network class ([`LocalModelNetwork`]):
//! a linear output-error model of order n, or a LOLIMOT local model network
//! on the same regressors, each optionally with play-operator / discrete
//! Preisach columns and a Student-t (robust, IRLS) noise model.
//!
//! | field | default | meaning |
//! |---|---|---|
//! | `order` | 2 | n = n_a = n_b per input |
//! | `delay` | 1 per input | dead time n_k per input; 0 = direct feedthrough, and then the input enters with lags 0..n (n + 1 coefficients: the biproper transfer function of order n) |
//! | `network` | false | LOLIMOT local model network instead of one linear model |
//! | `hysteresis` | false | play operators and a relay grid on the simulated output, play operators per input |
//! | `separable_hysteresis` | false | the hysteresis weights at lags 1..L as one shape times one lag filter (one hysteretic force; W + L − 1 weights instead of W·L) |
//! | `hysteresis_on` | both | which signals carry those columns: both, the input plays only (hysteresis before the dynamics, a backlash) or the output plays only (a Prandtl–Ishlinskii force on the state, no relay grid: shift-invariant) |
//! | `input_play_at` | none | play thresholds per input (normalised units) instead of the grid of input plays: a backlash of fitted width |
//! | `relay_sub` | 4 | relays per cell side of the output relay grid ([`gb_preisach::RelayCells`]): its columns move in 16 steps per cell, not one jump (1 = hard relays) |
//! | `output_map` | 0 | ramp columns of a static map g(ŷ) of the simulated output fed back at lags 1..n+1 (a nonlinear spring or friction force of the output state; knots at quantiles of the output; 0: none) |
//! | `robust` | false | Student-t noise model, IRLS output-error fit |
//! | `detail` | 0 | capacity level: `10 + 5·detail` leaves, `6(1+detail)` output plays |
//! | `fit` | [`FitOptions::default`] | Levenberg–Marquardt settings |
//! | `lolimot` | [`LolimotOptions::default`] | LOLIMOT settings |
use crate::lolimot::{fit_lmn_oe_obs, fit_lmn_oe_records};
use crate::noe::{fit_linear_oe_warm_obs, fit_linear_oe_warm_records, Experiment};
use crate::{FitOptions, LmnError, LocalModelNetwork, LolimotOptions, NetworkSpec};
use gb_core::{Identify, Observer, Record, Records, Silent};

/// Largest order of an input–output network.
pub const MAX_IO_ORDER: usize = 30;

/// Which signals carry the hysteresis columns of an input–output network.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum HysteresisOn {
    /// Play operators and a relay grid on the simulated output, play
    /// operators on every input.
    #[default]
    Both,
    /// Play operators on every input only: u ↦ P_r(u) before the linear
    /// dynamics (a backlash, a hysteretic actuator).
    Inputs,
    /// Play operators on the simulated output only (no relay grid): a
    /// Prandtl–Ishlinskii force F = Σ w_r P_r(ŷ) acting on the dynamics'
    /// state, invariant to a shift of the operating point.
    Output,
}

/// Parameters of an input–output network fit (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct IoNetworkParams {
    /// Dynamic order n (n_a = n_b = n per input).
    pub order: usize,
    /// Dead time per input (empty: 1 for every input).
    pub delay: Vec<usize>,
    /// A direct feedthrough behind the dead time: every input with a dead
    /// time d ≥ 1 gets n + 1 numerator terms `b₀ u(k−d) + … + b_n u(k−d−n)`
    /// (a biproper transfer function after the dead time, as delay 0 always
    /// has), not n.
    pub feedthrough: bool,
    /// LOLIMOT local model network instead of one linear model.
    pub network: bool,
    /// Play-operator / discrete Preisach columns.
    pub hysteresis: bool,
    /// Which signals carry the hysteresis columns.
    pub hysteresis_on: HysteresisOn,
    /// Train the hysteresis weights as one hysteretic force through one
    /// lag filter (β[l, i] = c_l wᵢ; `FitOptions::separable_hysteresis`).
    pub separable_hysteresis: bool,
    /// Relays per cell side of the output relay grid (≥ 1; 1 = one hard
    /// relay per cell).
    pub relay_sub: usize,
    /// Play thresholds per input in normalised (unit-variance) units,
    /// replacing the grid of input plays (`None`: the grid): a backlash of
    /// fitted half-width is one threshold on one input.
    pub input_play_at: Option<Vec<Vec<f64>>>,
    /// Intervals of a static map of the simulated output inside the loop
    /// (0: none): g(ŷ) piecewise linear, its ramp columns at lags 1..n+1.
    pub output_map: usize,
    /// Student-t noise model with a robust (IRLS) fit.
    pub robust: bool,
    /// Capacity level of the nonlinear parts.
    pub detail: u8,
    /// Output-error training options.
    pub fit: FitOptions,
    /// LOLIMOT options (network structures only).
    pub lolimot: LolimotOptions,
}

impl IoNetworkParams {
    /// The linear output-error model of order `order`, dead time 1.
    pub fn linear(order: usize) -> Self {
        Self {
            order,
            delay: vec![],
            feedthrough: false,
            network: false,
            hysteresis: false,
            hysteresis_on: HysteresisOn::Both,
            separable_hysteresis: false,
            relay_sub: 4,
            input_play_at: None,
            output_map: 0,
            robust: false,
            detail: 0,
            fit: FitOptions::default(),
            lolimot: LolimotOptions::default(),
        }
    }

    /// Largest number of local models: `10 + 5·detail`.
    pub fn max_leaves(&self) -> usize {
        10 + 5 * self.detail as usize
    }

    /// The components as a model SPEC (`linear`, `lmn+preisach+student-t`).
    pub fn spec_name(&self) -> String {
        let mut s = String::from(if self.network { "lmn" } else { "linear" });
        if self.hysteresis {
            s.push_str("+preisach");
        }
        if self.output_map > 0 {
            s.push_str("+feedback");
        }
        if self.robust {
            s.push_str("+student-t");
        }
        s
    }

    /// The regressor structure for `n_inputs` inputs.
    pub fn network_spec(&self, n_inputs: usize) -> NetworkSpec {
        let mut spec = NetworkSpec::order(self.order, n_inputs);
        if self.delay.len() == n_inputs {
            spec.nk = self.delay.clone();
            // direct feedthrough: b₀ u(k) + … + b_n u(k−n), order n biproper
            for (b, &d) in spec.nb.iter_mut().zip(&self.delay) {
                if d == 0 || self.feedthrough {
                    *b = self.order + 1;
                }
            }
        }
        if self.hysteresis {
            // thresholds in normalised (unit-variance) output units
            let d = 1 + self.detail as usize;
            let (no, ni) = (6 * d, 8 * d);
            if self.hysteresis_on != HysteresisOn::Inputs {
                spec.output_play = (1..=no).map(|i| 2.4 * i as f64 / no as f64).collect();
                if self.hysteresis_on == HysteresisOn::Both {
                    spec.output_relays = 6 + 2 * self.detail as usize;
                    spec.relay_sub = self.relay_sub;
                }
            }
            // lags 1..n+1: the hysteretic force acts inside n-th order
            // continuous dynamics and varies between samples
            spec.hysteresis_lags = self.order + 1;
            if self.hysteresis_on != HysteresisOn::Output {
                spec.input_play = match &self.input_play_at {
                    Some(at) if at.len() == n_inputs => at.clone(),
                    _ => vec![(1..=ni).map(|i| 2.4 * i as f64 / ni as f64).collect(); n_inputs],
                };
            }
        }
        if self.output_map > 0 {
            // uniform over ±2.4 normalised units; `network_spec_on` puts the
            // knots at quantiles of the record's output
            let m = self.output_map;
            spec.output_knots = (0..=m).map(|i| -2.4 + 4.8 * i as f64 / m as f64).collect();
            spec.hysteresis_lags = self.order + 1;
        }
        spec
    }

    /// [`network_spec`](Self::network_spec) for the record `data`: every
    /// input's play thresholds above R = (q₉₉ − q₁) / 2 of the normalised
    /// input dropped (keeping at least one): such a play barely moves, its
    /// column is a constant set by the record's first sample, which a new
    /// record does not share. For a Gaussian input R ≈ 2.3.
    /// The output map's knots are the 1 %, …, 99 % quantiles of the
    /// normalised output at equal steps of probability (duplicates merged):
    /// dense where the output dwells, as a velocity does around a sticking
    /// friction's zero.
    pub fn network_spec_on(&self, data: &Record) -> NetworkSpec {
        let mut spec = self.network_spec(data.n_inputs());
        if self.output_map > 0 {
            if let Some(k) = quantile_knots(&data.output, self.output_map) {
                spec.output_knots = k;
            }
        }
        for (plays, u) in spec.input_play.iter_mut().zip(&data.inputs) {
            let r = half_range(u);
            if r.is_finite() && plays.len() > 1 {
                let keep = plays.iter().filter(|&&t| t <= r).count().max(1);
                plays.truncate(keep);
            }
        }
        spec
    }

    /// Validate once; the result fits.
    pub fn check(&self) -> Result<ValidIoNetworkParams, LmnError> {
        if self.order == 0 || self.order > MAX_IO_ORDER {
            return Err(LmnError::InvalidArgument(format!(
                "order must be in 1..={MAX_IO_ORDER}, got {}",
                self.order
            )));
        }
        if self.delay.iter().any(|&d| d > 64) {
            return Err(LmnError::InvalidArgument(
                "a dead time of at most 64 samples".into(),
            ));
        }
        if self.relay_sub == 0 || self.relay_sub > 64 {
            return Err(LmnError::InvalidArgument(format!(
                "relays per cell side must be in 1..=64, got {}",
                self.relay_sub
            )));
        }
        self.fit.check()?;
        self.lolimot.check()?;
        Ok(ValidIoNetworkParams(self.clone()))
    }
}

/// Validated [`IoNetworkParams`].
#[derive(Debug, Clone, PartialEq)]
pub struct ValidIoNetworkParams(IoNetworkParams);

/// Optional starts of an input–output network fit.
#[derive(Debug, Clone, Copy, Default)]
pub struct WarmStart<'a> {
    /// Free-run simulation of a previous model on the data, used as output
    /// lags while LOLIMOT grows the network (output-error construction).
    pub simulated_output: Option<&'a [f64]>,
    /// A previous network whose parameters start a linear fit.
    pub network: Option<&'a LocalModelNetwork>,
    /// With several records ([`ValidIoNetworkParams::fit_records`]): the
    /// previous model's free-run simulation of every record (LOLIMOT's
    /// output-error construction; `simulated_output` is then unused).
    pub simulated_outputs: Option<&'a [Vec<f64>]>,
}

impl ValidIoNetworkParams {
    /// The parameters.
    pub fn params(&self) -> &IoNetworkParams {
        &self.0
    }

    /// Fit on one record by output-error identification.
    pub fn fit(&self, data: &Record, warm: WarmStart<'_>) -> Result<LocalModelNetwork, LmnError> {
        self.fit_with_observer(data, warm, &Silent)
    }

    /// [`fit`](Self::fit), reporting every Levenberg–Marquardt iteration of
    /// the output-error training to `observer`.
    pub fn fit_with_observer(
        &self,
        data: &Record,
        warm: WarmStart<'_>,
        observer: &dyn Observer,
    ) -> Result<LocalModelNetwork, LmnError> {
        let p = &self.0;
        if !p.delay.is_empty() && p.delay.len() != data.n_inputs() {
            return Err(LmnError::InvalidArgument(format!(
                "{} dead times for {} inputs",
                p.delay.len(),
                data.n_inputs()
            )));
        }
        let spec = p.network_spec_on(data);
        let mut fopts = p.fit.clone();
        fopts.robust = p.robust;
        fopts.separable_hysteresis |= p.separable_hysteresis;
        if p.network {
            let mut lopts = p.lolimot.clone();
            lopts.max_leaves = lopts.max_leaves.max(p.max_leaves());
            fit_lmn_oe_obs(
                &spec,
                &data.inputs,
                &data.output,
                warm.simulated_output,
                &lopts,
                &fopts,
                observer,
            )
        } else {
            fit_linear_oe_warm_obs(
                &spec,
                &data.inputs,
                &data.output,
                &fopts,
                warm.network,
                observer,
            )
        }
    }
}

impl ValidIoNetworkParams {
    /// Fit on several records as separate experiments: the output-error
    /// cost is Σᵢ Σₖ (yᵢ(k) − ŷᵢ(k))², every record simulated from its own
    /// starting history (a linear model: [`fit_linear_oe_warm_records`]; a
    /// LOLIMOT network: [`fit_lmn_oe_records`], grown on the union of the
    /// records' regression rows). The data-dependent parts of the structure
    /// (play thresholds, output-map knots) are read on all records
    /// together. One record: [`fit_with_observer`](Self::fit_with_observer).
    pub fn fit_records(
        &self,
        data: &[Record],
        warm: WarmStart<'_>,
        observer: &dyn Observer,
    ) -> Result<LocalModelNetwork, LmnError> {
        let p = &self.0;
        let (first, all) = match data {
            [] => return Err(LmnError::InvalidArgument("no record given".into())),
            [one] => return self.fit_with_observer(one, warm, observer),
            [first, ..] => (first, data),
        };
        if let Some(r) = all.iter().find(|r| r.n_inputs() != first.n_inputs()) {
            return Err(LmnError::Dimension(format!(
                "records with {} and {} inputs",
                first.n_inputs(),
                r.n_inputs()
            )));
        }
        if !p.delay.is_empty() && p.delay.len() != first.n_inputs() {
            return Err(LmnError::InvalidArgument(format!(
                "{} dead times for {} inputs",
                p.delay.len(),
                first.n_inputs()
            )));
        }
        let joined = Record::new(
            first.input_names.clone(),
            first.output_name.clone(),
            (0..first.n_inputs())
                .map(|j| {
                    all.iter()
                        .flat_map(|r| r.inputs[j].iter().copied())
                        .collect()
                })
                .collect(),
            all.iter().flat_map(|r| r.output.iter().copied()).collect(),
        )
        .map_err(|e| LmnError::InvalidArgument(e.to_string()))?;
        let spec = p.network_spec_on(&joined);
        let mut fopts = p.fit.clone();
        fopts.robust = p.robust;
        fopts.separable_hysteresis |= p.separable_hysteresis;
        let exps = Experiment::all(all);
        if p.network {
            let mut lopts = p.lolimot.clone();
            lopts.max_leaves = lopts.max_leaves.max(p.max_leaves());
            let sims: Option<Vec<&[f64]>> = warm
                .simulated_outputs
                .map(|s| s.iter().map(Vec::as_slice).collect());
            return fit_lmn_oe_records(&spec, &exps, sims.as_deref(), &lopts, &fopts, observer);
        }
        fit_linear_oe_warm_records(&spec, &exps, &fopts, warm.network, observer)
    }
}

impl Identify for ValidIoNetworkParams {
    type Model = LocalModelNetwork;
    type Error = LmnError;
    /// One record or several ([`ValidIoNetworkParams::fit_records`]).
    fn identify(
        &self,
        data: &Records,
        observer: &dyn Observer,
    ) -> Result<LocalModelNetwork, LmnError> {
        self.fit_records(data.as_slice(), WarmStart::default(), observer)
    }
}

/// `u` normalised by its [`Scaling`](crate::Scaling) (the network's own
/// normalisation) and sorted; `None` for fewer than 10 samples, a constant
/// or a non-finite signal.
fn normalised_sorted(u: &[f64]) -> Option<Vec<f64>> {
    let sd = gb_core::metrics::std(u);
    if u.len() < 10 || !(sd > 0.0 && sd.is_finite()) {
        return None;
    }
    let sc = crate::Scaling::of(u);
    let mut z: Vec<f64> = u.iter().map(|&v| sc.to_norm(v)).collect();
    if z.iter().any(|v| !v.is_finite()) {
        return None;
    }
    z.sort_by(f64::total_cmp);
    Some(z)
}

/// The p-quantile of sorted values (nearest rank).
fn quantile(z: &[f64], p: f64) -> f64 {
    z[((z.len() - 1) as f64 * p).round() as usize]
}

/// `m + 1` knots at the 1 %, …, 99 % quantiles of the normalised `y` (at
/// equal steps of probability), those closer than 0.02 standard deviations
/// to the previous one dropped; `None` when fewer than two remain or `y`
/// is too short or constant.
fn quantile_knots(y: &[f64], m: usize) -> Option<Vec<f64>> {
    let z = normalised_sorted(y).filter(|_| m > 0)?;
    let mut knots: Vec<f64> = vec![];
    for i in 0..=m {
        let t = quantile(&z, 0.01 + 0.98 * i as f64 / m as f64);
        if knots.last().is_none_or(|&l| t - l >= 0.02) {
            knots.push(t);
        }
    }
    (knots.len() >= 2).then_some(knots)
}

/// Half the 1 %–99 % quantile range of `u` in units of its standard
/// deviation (NaN for a constant or too short signal): the largest play
/// threshold (normalised units) that still moves on `u`.
pub fn half_range(u: &[f64]) -> f64 {
    normalised_sorted(u).map_or(f64::NAN, |z| {
        (quantile(&z, 0.99) - quantile(&z, 0.01)) / 2.0
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// A Lur'e system: a cubic spring force on the output inside the loop,
    /// y(k) = 1.5 y(k−1) − 0.7 y(k−2) − 0.08 y(k−1)³ + 0.2 u(k−1) + noise.
    fn lure(n: usize, seed: u64) -> Record {
        let mut r = Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut u = vec![0.0; n];
        for k in 0..n {
            // a held random level every 8 samples
            u[k] = if k % 8 == 0 {
                r.random_range(-2.0..2.0)
            } else {
                u[k - 1]
            };
        }
        let mut x = vec![0.0f64; n];
        for k in 2..n {
            x[k] = 1.5 * x[k - 1] - 0.7 * x[k - 2] - 0.08 * x[k - 1].powi(3) + 0.2 * u[k - 1];
        }
        let y: Vec<f64> = x
            .iter()
            .map(|v| v + 0.01 * r.random_range(-1.0..1.0))
            .collect();
        Record::new(vec!["u".into()], "y".into(), vec![u], y).unwrap()
    }

    fn nrmse(m: &LocalModelNetwork, rec: &Record) -> f64 {
        let sim = gb_core::DynamicModel::simulate(m, &rec.inputs, gb_core::Init::Rest).unwrap();
        let e: f64 = sim
            .iter()
            .zip(&rec.output)
            .map(|(a, b)| (a - b).powi(2))
            .sum();
        let v: f64 = rec.output.iter().map(|b| b * b).sum();
        (e / v).sqrt()
    }

    /// `p` fitted on `train` without a warm start.
    fn cold_fit(train: &Record, p: IoNetworkParams) -> LocalModelNetwork {
        p.check().unwrap().fit(train, WarmStart::default()).unwrap()
    }

    /// A hysteretic spring in a lightly damped loop: a play operator of
    /// half-width 0.5 on the output pulls it back,
    /// x(k) = 1.92 x(k−1) − 0.96 x(k−2) − 0.01 p(k−1) + 0.002 u(k−1),
    /// p = play(x), under a sum of sines near the resonance.
    fn play_spring(n: usize, seed: u64) -> Record {
        let mut r = Xoshiro256PlusPlus::seed_from_u64(seed);
        let f: Vec<(f64, f64)> = (0..12)
            .map(|i| {
                (
                    0.01 + 0.004 * i as f64,
                    r.random_range(0.0..std::f64::consts::TAU),
                )
            })
            .collect();
        let u: Vec<f64> = (0..n)
            .map(|k| {
                f.iter()
                    .map(|(w, ph)| (w * k as f64 * std::f64::consts::TAU + ph).sin())
                    .sum()
            })
            .collect();
        let (mut x, mut p) = (vec![0.0f64; n], 0.0f64);
        for k in 2..n {
            p = p.clamp(x[k - 1] - 0.5, x[k - 1] + 0.5);
            x[k] = 1.92 * x[k - 1] - 0.96 * x[k - 2] - 0.01 * p + 0.002 * u[k - 1];
        }
        let sd = gb_core::metrics::std(&x);
        let y: Vec<f64> = x
            .iter()
            .map(|v| v + 0.01 * sd * r.random_range(-1.0..1.0))
            .collect();
        Record::new(vec!["u".into()], "y".into(), vec![u], y).unwrap()
    }

    /// Without a warm start, the hysteresis structure is also started from
    /// its own linear part (the hysteresis weights at zero): its simulation
    /// error is a small fraction of the linear model's (from the
    /// least-squares start alone: 0.92 against the linear model's 0.11 on
    /// the training record).
    #[test]
    fn a_cold_hysteresis_fit_starts_from_its_linear_part() {
        let (train, test) = (play_spring(4000, 3), play_spring(3000, 4));
        let fit = |p: IoNetworkParams| cold_fit(&train, p);
        let linear = fit(IoNetworkParams::linear(2));
        let play = fit(IoNetworkParams {
            hysteresis: true,
            hysteresis_on: HysteresisOn::Output,
            ..IoNetworkParams::linear(2)
        });
        let (tl, tp) = (nrmse(&linear, &train), nrmse(&play, &train));
        assert!(
            tp < 0.3 * tl,
            "training: play operators {tp:.4} vs linear {tl:.4}"
        );
        let (el, ep) = (nrmse(&linear, &test), nrmse(&play, &test));
        assert!(
            ep < 0.7 * el,
            "new record: play operators {ep:.4} vs linear {el:.4}"
        );
    }

    /// The feedback map finds the spring the linear model cannot express:
    /// on a new record its simulation error is a small fraction of the
    /// linear model's, and its knots sit at the output's quantiles.
    #[test]
    fn a_feedback_map_models_a_nonlinear_spring_inside_the_loop() {
        let (train, test) = (lure(3000, 1), lure(2000, 2));
        let fit = |p: IoNetworkParams| cold_fit(&train, p);
        let linear = fit(IoNetworkParams::linear(2));
        let map = fit(IoNetworkParams {
            output_map: 8,
            separable_hysteresis: true,
            ..IoNetworkParams::linear(2)
        });
        assert_eq!(map.spec.n_ramps(), 8);
        let k = &map.spec.output_knots;
        assert!(
            k[0] < -1.5 && k[8] > 1.5 && k.windows(2).all(|w| w[1] > w[0]),
            "{k:?}"
        );
        let (el, em) = (nrmse(&linear, &test), nrmse(&map, &test));
        assert!(em < 0.2 * el, "feedback map {em:.4} vs linear {el:.4}");
        assert_eq!(map.spec.hysteresis_lags, 3);
        // the model file keeps the knots
        let body = gb_core::DynamicModel::encode(&map).unwrap();
        let back = LocalModelNetwork::decode(&body, 2).unwrap();
        assert_eq!(nrmse(&back, &test), em);
    }
}
