//! Whether the select block repeats an input stretch of the fit block: a
//! periodic excitation recorded over several periods (a multisine, a
//! reference trajectory run again). Held-out blocks of such a record meet
//! the same input with new noise, so their gains show how a model
//! reproduces this excitation, not how it carries over to other inputs —
//! a flexible model can learn the trajectory (EMPS: four runs of one
//! trajectory, a local model network of 10 leaves at 0.06 mm on the held-out
//! run and 13 mm on the pulses test).

use gb_core::Record;
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    fn record(u: Vec<f64>) -> Record {
        let y = u.clone();
        Record::new(vec!["u".into()], "y".into(), vec![u], y).unwrap()
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
}
