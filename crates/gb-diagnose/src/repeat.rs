//! Whether the select block repeats an input stretch of the fit block: a
//! periodic excitation recorded over several periods (a multisine, a
//! reference trajectory run again). Held-out blocks of such a record meet
//! the same input with new noise, so their gains show how a model
//! reproduces this excitation, not how it carries over to other inputs —
//! a flexible model can learn the trajectory (EMPS: four runs of one
//! trajectory, a local model network of 10 leaves at 0.06 mm on the held-out
//! run and 13 mm on the pulses test). [`shift_disagreement`] asks the
//! models instead: a step that carries over changes the response to the
//! input time-reversed or scaled about as much as to the input itself.

use gb_core::{FittedModel, Init, Record};
use std::ops::Range;

/// Samples per probe window of the select block.
const WINDOW: usize = 256;
/// Fit-block samples scanned (the last ones) for each probe.
const SCAN: usize = 200_000;

/// Pearson correlation of `a` (centred, its norm `na`) with every window
/// of `b` of `a.len()` samples: the largest and the offset into `b`.
fn best_match(a: &[f64], na: f64, b: &[f64]) -> (f64, usize) {
    let w = a.len();
    if b.len() < w || na <= 0.0 {
        return (0.0, 0);
    }
    let (mut s1, mut s2) = (0.0, 0.0);
    for v in &b[..w] {
        s1 += v;
        s2 += v * v;
    }
    let mut best = (f64::NEG_INFINITY, 0);
    for j in 0..=b.len() - w {
        if j > 0 {
            let (out, inn) = (b[j - 1], b[j + w - 1]);
            s1 += inn - out;
            s2 += inn * inn - out * out;
        }
        let var = s2 - s1 * s1 / w as f64;
        if var <= 1e-12 * s2.abs().max(1e-300) {
            continue;
        }
        let dot: f64 = a.iter().zip(&b[j..j + w]).map(|(x, y)| x * y).sum();
        let r = dot / (na * var.sqrt());
        if r > best.0 {
            best = (r, j);
        }
    }
    best
}

/// Probe windows of the select block (evenly spaced, first and last
/// included); the median correlation decides, so that a quiet stretch
/// (a rest, where the input is mostly noise) does not hide a repeat.
const PROBES: usize = 5;

/// If the samples `s` of `rec` repeat its samples `f` in every input —
/// the median over [`PROBES`] windows of the select block of the best
/// correlation with a window of the fit block at least `min_corr` — that
/// median (the smallest over the inputs) and the shift (samples from the
/// match to the window) of the first window. `None` when the blocks are
/// too short or an input does not repeat.
pub(crate) fn repeated_input(
    rec: &Record,
    f: Range<usize>,
    s: Range<usize>,
    min_corr: f64,
) -> Option<(f64, usize)> {
    let w = WINDOW.min(s.len() / 4);
    if w < 32 || f.len() < 2 * w || f.end > rec.len() || s.end > rec.len() {
        return None;
    }
    let f = f.start.max(f.end.saturating_sub(SCAN))..f.end;
    let starts: Vec<usize> = (0..PROBES)
        .map(|i| s.start + i * (s.len() - w) / (PROBES - 1))
        .collect();
    let (mut lowest, mut shift) = (f64::INFINITY, None);
    for u in &rec.inputs {
        let mut rs = Vec::with_capacity(PROBES);
        for &k in &starts {
            let a = &u[k..k + w];
            let m = a.iter().sum::<f64>() / w as f64;
            let ac: Vec<f64> = a.iter().map(|v| v - m).collect();
            let na = ac.iter().map(|v| v * v).sum::<f64>().sqrt();
            let (r, j) = best_match(&ac, na, &u[f.clone()]);
            rs.push(if r.is_finite() { r } else { 0.0 });
            shift.get_or_insert(k - (f.start + j).min(k));
        }
        rs.sort_by(f64::total_cmp);
        let median = rs[PROBES / 2];
        if median < min_corr {
            return None;
        }
        lowest = lowest.min(median);
    }
    shift.map(|p| (lowest, p))
}

/// The note for the decisions line when the select block of `rec`
/// repeats its fit block's input ([`repeated_input`]).
pub(crate) fn repeated_note(
    rec: &Record,
    f: Range<usize>,
    s: Range<usize>,
    min_corr: f64,
) -> Option<String> {
    let (r, p) = repeated_input(rec, f, s, min_corr)?;
    Some(format!(
        "; the select block repeats the fit block's input (its windows' best correlation with the fit block {r:.4} in the median, the first a repeat of {p} samples before: a periodic excitation, a trajectory run again): the held-out gains show how a model reproduces this input with new noise, not how it carries over to other inputs — score the model on a record with another excitation"
    ))
}

/// Correlation above which an input counts as the rate of another.
const RATE_CORRELATION: f64 = 0.95;

/// Pearson correlation of `a` and `b` (0 when either is constant).
fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    if n < 3 {
        return 0.0;
    }
    let (ma, mb) = (
        a[..n].iter().sum::<f64>() / n as f64,
        b[..n].iter().sum::<f64>() / n as f64,
    );
    let (mut ab, mut aa, mut bb) = (0.0, 0.0, 0.0);
    for (x, y) in a[..n].iter().zip(&b[..n]) {
        ab += (x - ma) * (y - mb);
        aa += (x - ma) * (x - ma);
        bb += (y - mb) * (y - mb);
    }
    if aa > 0.0 && bb > 0.0 {
        ab / (aa * bb).sqrt()
    } else {
        0.0
    }
}

/// The sign each input takes when time runs backwards: −1 for an input
/// that is the rate of another (its correlation with the other's central
/// difference `(u_i(k+1) − u_i(k−1))/2` above [`RATE_CORRELATION`]: a
/// velocity beside its displacement) whose own sign is +1, and so on along
/// a chain (an acceleration beside them flips twice). Reversing time
/// reverses a rate's sign; reversing the samples alone would pair a
/// displacement with the velocity of another motion.
fn reversal_signs(u: &[Vec<f64>]) -> Vec<f64> {
    let rates: Vec<Vec<f64>> = u
        .iter()
        .map(|s| {
            (0..s.len())
                .map(|k| {
                    let (a, b) = (k.saturating_sub(1), (k + 1).min(s.len() - 1));
                    (s[b] - s[a]) / 2.0
                })
                .collect()
        })
        .collect();
    let of: Vec<Option<usize>> = u
        .iter()
        .enumerate()
        .map(|(j, s)| {
            (0..u.len()).find(|&i| i != j && correlation(&rates[i], s) > RATE_CORRELATION)
        })
        .collect();
    // along a chain: each pass settles one more link
    let mut sign = vec![1.0; u.len()];
    for _ in 0..u.len() {
        for (j, i) in of.iter().enumerate() {
            if let Some(i) = *i {
                sign[j] = -sign[i];
            }
        }
    }
    sign
}

/// The training input transformed so that it keeps its amplitude
/// distribution and spectrum but is not the trajectory: every input
/// time-reversed (a rate of another input also negated,
/// [`reversal_signs`]), and every input scaled by 0.8 about its mean.
fn shifted_inputs(u: &[Vec<f64>]) -> [(&'static str, Vec<Vec<f64>>); 2] {
    let signs = reversal_signs(u);
    let reversed = u
        .iter()
        .zip(&signs)
        .map(|(s, &g)| s.iter().rev().map(|v| g * v).collect())
        .collect();
    let scaled = u
        .iter()
        .map(|s| {
            let m = s.iter().sum::<f64>() / s.len().max(1) as f64;
            s.iter().map(|v| m + 0.8 * (v - m)).collect()
        })
        .collect();
    [("time-reversed", reversed), ("scaled by 0.8", scaled)]
}

/// The simulation of `m` on `u` from its stored start; `None` when it
/// fails or is not finite.
fn finite_simulation(m: &FittedModel, u: &[Vec<f64>]) -> Option<Vec<f64>> {
    let y = m.simulate(u, Init::Stored).ok()?;
    y.iter().all(|v| v.is_finite()).then_some(y)
}

/// `sqrt(mean((a − b)²))` over the samples from `skip` on; `None` when
/// there are none.
fn rms_difference(a: &[f64], b: &[f64], skip: usize) -> Option<f64> {
    let n = a.len().min(b.len());
    if n <= skip {
        return None;
    }
    let ss: f64 = a[skip..n]
        .iter()
        .zip(&b[skip..n])
        .map(|(p, q)| (p - q) * (p - q))
        .sum();
    Some((ss / (n - skip) as f64).sqrt())
}

/// How much more a candidate disagrees with the current model on inputs
/// the training record does not show than on its own input `u`:
/// `max_v D(u_v) / D(u)` over the [`shifted_inputs`] `u_v`, with `D` the
/// [`rms_difference`] of the two simulations, and the variant that gave it.
/// On a repeated excitation a candidate that reproduces the trajectory
/// better but does not carry over parts from the current model far more on
/// the shifted inputs than on the trajectory (EMPS: a 10-leaf network after
/// the friction law, 14.9× time-reversed; Bouc–Wen's hidden-state model
/// after the Preisach component, 0.99×). A candidate whose simulation of a
/// shifted input fails while the current model's does not gives infinity;
/// `None` when the two models cannot be compared on `u` itself.
pub(crate) fn shift_disagreement(
    current: &FittedModel,
    candidate: &FittedModel,
    u: &[Vec<f64>],
) -> Option<(f64, &'static str)> {
    let skip = skip_of(u);
    let base = rms_difference(
        &finite_simulation(current, u)?,
        &finite_simulation(candidate, u)?,
        skip,
    )?;
    if !(base > 0.0 && base.is_finite()) {
        return None;
    }
    let mut worst: Option<(f64, &'static str)> = None;
    for (name, v) in shifted_inputs(u) {
        let Some(ya) = finite_simulation(current, &v) else {
            continue;
        };
        let r = match finite_simulation(candidate, &v) {
            Some(yb) => match rms_difference(&ya, &yb, skip) {
                Some(d) => d / base,
                None => continue,
            },
            None => f64::INFINITY,
        };
        if worst.is_none_or(|(w, _)| r > w) {
            worst = Some((r, name));
        }
    }
    worst
}

/// The samples [`rms_difference`] skips at the start of a simulation of
/// `u` (its transient from the stored start).
fn skip_of(u: &[Vec<f64>]) -> usize {
    (u.first().map_or(0, Vec::len) / 10).min(50)
}

/// A witness that `candidate`'s departure from `current` on the shifted
/// input `how` of `u` is the system's, not the trajectory's: among
/// `others` (rival models of other classes fitted to the same
/// trajectory), the one whose simulation there differs least from the
/// candidate's, when by at most as much (rms) as the candidate differs
/// from `current` on `u` itself; its index in `others` and that ratio.
/// Two model classes fitted to one trajectory agree off it only where both
/// found the system; a model the trajectory tuned (the current model, a
/// network that learnt it) parts from them there.
pub(crate) fn shift_witness<'m>(
    candidate: &FittedModel,
    current: &FittedModel,
    others: impl IntoIterator<Item = &'m FittedModel>,
    u: &[Vec<f64>],
    how: &str,
) -> Option<(usize, f64)> {
    let skip = skip_of(u);
    let (_, v) = shifted_inputs(u)
        .into_iter()
        .find(|(name, _)| *name == how)?;
    let cand_u = finite_simulation(candidate, u)?;
    let base = rms_difference(&cand_u, &finite_simulation(current, u)?, skip)?;
    if !(base > 0.0 && base.is_finite()) {
        return None;
    }
    let cand_v = finite_simulation(candidate, &v)?;
    others
        .into_iter()
        .enumerate()
        .filter_map(|(j, m)| {
            let on_v = rms_difference(&cand_v, &finite_simulation(m, &v)?, skip)?;
            (on_v <= base).then_some((j, on_v / base))
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    fn record(u: Vec<f64>) -> Record {
        let y = u.clone();
        Record::new(vec!["u".into()], "y".into(), vec![u], y).unwrap()
    }

    /// A displacement, its velocity (sampled derivative), its acceleration
    /// and an unrelated input: reversed in time, the velocity changes sign,
    /// the acceleration and the others do not.
    #[test]
    fn time_reversal_negates_the_rates() {
        let n = 2000;
        let mut r = gb_core::rng::seeded(5);
        let mut x = vec![0.0; n];
        for k in 1..n {
            x[k] = 0.99 * x[k - 1] + r.random::<f64>() - 0.5;
        }
        let diff = |s: &[f64]| -> Vec<f64> {
            (0..s.len())
                .map(|k| s[(k + 1).min(s.len() - 1)] - s[k.saturating_sub(1)])
                .collect()
        };
        let v = diff(&x);
        let a = diff(&v);
        let other: Vec<f64> = (0..n).map(|_| r.random::<f64>()).collect();
        assert_eq!(
            reversal_signs(&[v.clone(), other.clone(), x.clone(), a]),
            vec![-1.0, 1.0, 1.0, 1.0]
        );
        assert_eq!(reversal_signs(&[x, other]), vec![1.0, 1.0]);
    }

    /// A random input repeated with period 1000 is found (shift a multiple
    /// of the period, correlation 1); with small noise on it too; the same
    /// length of an unrepeated random input is not.
    #[test]
    fn a_repeated_input_is_found_and_a_fresh_one_is_not() {
        let mut r = gb_core::rng::seeded(3);
        let period: Vec<f64> = (0..1000).map(|_| r.random::<f64>() - 0.5).collect();
        let rep: Vec<f64> = (0..6000).map(|k| period[k % 1000]).collect();
        let (c, p) = repeated_input(&record(rep.clone()), 0..3000, 3000..4500, 0.99).unwrap();
        assert!(c > 0.999999 && p % 1000 == 0 && p > 0, "{c} {p}");
        let noisy: Vec<f64> = rep
            .iter()
            .map(|v| v + 0.02 * (r.random::<f64>() - 0.5))
            .collect();
        assert!(repeated_input(&record(noisy), 0..3000, 3000..4500, 0.99).is_some());
        let fresh: Vec<f64> = (0..6000).map(|_| r.random::<f64>() - 0.5).collect();
        assert_eq!(
            repeated_input(&record(fresh), 0..3000, 3000..4500, 0.99),
            None
        );
    }

    /// `y(k) = a·y(k−1) + b·u(k)`, plus `off` wherever the input is not the
    /// stored trajectory `track` (and `on` where it is): a model that has
    /// learnt one input sequence.
    #[derive(Debug, Clone)]
    struct Tracker {
        a: f64,
        b: f64,
        track: Vec<f64>,
        on: f64,
        off: f64,
    }
    impl gb_core::DynamicModel for Tracker {
        fn class(&self) -> &'static str {
            "test-tracker"
        }
        fn n_inputs(&self) -> usize {
            1
        }
        fn n_states(&self) -> usize {
            1
        }
        fn describe(&self) -> String {
            "tracker".into()
        }
        fn n_parameters(&self) -> usize {
            2
        }
        fn simulate_into(
            &self,
            u: &[Vec<f64>],
            _: Init<'_>,
            y: &mut [f64],
            _: &mut gb_core::Workspace,
        ) -> Result<(), gb_core::CoreError> {
            let mut s = 0.0;
            for (k, yk) in y.iter_mut().enumerate() {
                s = self.a * s + self.b * u[0][k];
                let on_track = self.track.get(k).is_some_and(|t| *t == u[0][k]);
                *yk = s + if on_track { self.on } else { self.off };
            }
            Ok(())
        }
        fn encode(&self) -> Result<Vec<u8>, gb_core::CoreError> {
            Ok(vec![])
        }
        fn clone_box(&self) -> Box<dyn gb_core::DynamicModel> {
            Box::new(self.clone())
        }
        fn as_any(&self) -> &dyn std::any::Any {
            self
        }
    }

    fn fitted(m: Tracker) -> FittedModel {
        FittedModel::new(
            vec!["u".into()],
            vec!["y".into()],
            Box::new(m),
            gb_core::NoiseModel::Gaussian { sd: 1.0 },
        )
        .unwrap()
    }

    /// Against a first-order model: a candidate with another gain parts
    /// from it about as much on the shifted inputs as on the trajectory
    /// (ratio ≤ 1.1: the difference is a linear response, 0.8× when
    /// scaled); one that adds 0.01 on the trajectory and 0.3 off it parts
    /// 30× as much; one whose simulation breaks off the trajectory gives
    /// infinity.
    #[test]
    fn a_candidate_that_learnt_the_trajectory_parts_from_the_current_model_off_it() {
        let mut r = gb_core::rng::seeded(5);
        let u: Vec<f64> = (0..2000).map(|_| r.random::<f64>() - 0.3).collect();
        let plain = |b: f64, on: f64, off: f64| Tracker {
            a: 0.9,
            b,
            track: u.clone(),
            on,
            off,
        };
        let current = fitted(plain(1.0, 0.0, 0.0));
        let regain = fitted(plain(1.1, 0.0, 0.0));
        let learnt = fitted(plain(1.0, 0.01, 0.3));
        let broken = fitted(plain(1.0, 0.01, f64::NAN));
        let uu = vec![u.clone()];
        let (g, _) = shift_disagreement(&current, &regain, &uu).unwrap();
        assert!(g > 0.5 && g < 1.1, "{g}");
        let (l, how) = shift_disagreement(&current, &learnt, &uu).unwrap();
        assert!((l - 30.0).abs() < 0.5, "{l} {how}");
        let (b, _) = shift_disagreement(&current, &broken, &uu).unwrap();
        assert!(b.is_infinite(), "{b}");
        // no difference on the input itself: nothing to compare
        assert!(shift_disagreement(&current, &current, &uu).is_none());
    }

    /// The current model learnt the trajectory (+0.3 off it), the
    /// candidate is the plain system: it parts from the current model 30×
    /// as much off the trajectory. A rival of another gain (1.02) agrees
    /// with it off the trajectory (a witness, ratio 0.02/0.3-ish); a rival
    /// that learnt the trajectory too, or none, is no witness.
    #[test]
    fn a_rival_that_agrees_off_the_trajectory_witnesses_for_the_candidate() {
        let mut r = gb_core::rng::seeded(7);
        let u: Vec<f64> = (0..2000).map(|_| r.random::<f64>() - 0.3).collect();
        let model = |b: f64, on: f64, off: f64| {
            fitted(Tracker {
                a: 0.9,
                b,
                track: u.clone(),
                on,
                off,
            })
        };
        let current = model(1.0, 0.01, 0.3);
        let candidate = model(1.0, 0.0, 0.0);
        let uu = vec![u.clone()];
        let (ratio, how) = shift_disagreement(&current, &candidate, &uu).unwrap();
        assert!(ratio > 20.0, "{ratio}");
        let near = model(1.002, 0.0, 0.0);
        let learnt = model(1.0, 0.0, 0.25);
        let (j, gap) = shift_witness(&candidate, &current, [&learnt, &near], &uu, how).unwrap();
        assert_eq!(j, 1, "{gap}");
        assert!(gap > 0.0 && gap < 1.0, "{gap}");
        assert_eq!(
            shift_witness(&candidate, &current, [&learnt], &uu, how),
            None
        );
        assert_eq!(shift_witness(&candidate, &current, [], &uu, how), None);
    }
}
