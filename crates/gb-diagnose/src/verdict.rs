//! The honest verdict: whether the final model's residuals still hold
//! structure. "Adequate" only when every residual test passes at the
//! stated level; a misfit the tests still see is reported as unexplained,
//! with the failing tests and what was tried.
//!
//! The tests run on the select block's free-run residuals `e` of the final
//! model (data the decisions were made on, never the report block); under
//! blocked cross-validation of one record, on the final model's own
//! residuals over the folds' scored samples and on each fold's held-out
//! residuals, a test rejecting when the former or at least half the
//! latter reject ([`verdict_tested`]):
//!
//! - whiteness: Ljung–Box on r_ee(1..=25);
//! - per input `u`: the portmanteau `Q = N rᵀ P⁺ r` of the input–residual
//!   cross-correlation `r = r_ab(0..=25)` and of the higher-order
//!   correlations r_{u²'e}, r_{u²'e²} (Billings & Voon 1986), computed
//!   between *prewhitened* series (each filtered by its own AR(10) model,
//!   Levinson–Durbin on its auto-correlation; Box & Jenkins): an
//!   output-error residual is coloured when the noise is, and without
//!   prewhitening two independent coloured series correlate spuriously.
//!   `P` is the lag-correlation matrix of the prewhitened input (a
//!   multisine or a sweep stays coloured after AR(10)); χ² with rank(P)
//!   degrees of freedom (26 for a white input);
//! - static nonlinearity and memory (direction of motion) F tests with the
//!   sample count deflated by the residual's lag-1 correlation ρ₁,
//!   `N_eff = N (1 − ρ₁)/(1 + ρ₁)`.
//!
//! Under cross-validation those residuals have gaps (the folds' blocks,
//! held-out samples left out where a fold's fit would extrapolate): the
//! whiteness and correlation tests take lag products, and the
//! prewhitening its history, only inside a contiguous run
//! ([`crate::plan::Tested`]'s run starts).
//!
//! Each of the k tests runs at `level / k` (Bonferroni). If an input-related
//! test fails the misfit is unexplained; if only whiteness fails, the
//! remaining error is coloured noise (the structure explains the input-driven
//! behaviour; a noise model would help prediction, not simulation).
//!
//! The tests see correlation, not size. A slow excitation leaves them few
//! effective samples, and a misfit that follows the input's history (a
//! hysteresis loop) can pass them. So the residual is also compared with
//! the white-noise level `σ̂_w = median(|d₁|)/0.6745`, `d₁` the finest db4
//! detail coefficients (Donoho & Johnstone 1994), the smaller of that of
//! the measured output `y = ŷ + e` and that of the residual `e`: four
//! vanishing moments keep what is sampled well above its bandwidth out of
//! `d₁`, a fast signal (or misfit) leaks in and inflates `σ̂_w` — the
//! lenient side. "Adequate" and "coloured noise" need
//! `RMS(e) ≤ ratio · σ̂_w` (policy `verdict_noise_ratio`); above it the
//! misfit is unexplained and the text says how many times the noise level
//! it is: a coloured residual far above the white-noise level is coloured
//! noise or unmodelled behaviour, which the residual alone cannot tell.
use crate::evidence::MAX_LAG;
use crate::stats;
use serde::{Deserialize, Serialize};

/// What the residual tests say about the final model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum VerdictKind {
    /// Every test passes: no structure left that the tests can see.
    Adequate,
    /// Only whiteness fails: the remaining error is coloured noise.
    ColouredNoise,
    /// An input-related test fails: a misfit no named cause explains.
    Unexplained,
}

/// The verdict with the tests behind it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Verdict {
    /// The kind.
    pub kind: VerdictKind,
    /// Overall level of the tests.
    pub level: f64,
    /// Every test: name, statistic, p-value, rejected.
    pub tests: Vec<(String, f64, f64, bool)>,
    /// One or two sentences for the reports.
    pub text: String,
    /// RMS of the residual over the white-noise level `σ̂_w`, when the
    /// level could be estimated.
    #[serde(default)]
    pub noise_ratio: Option<f64>,
}

/// The contiguous runs of a series cut at `starts` (indices where a new
/// run begins; empty or `[0]`: one run), as ranges.
fn runs(len: usize, starts: &[usize]) -> Vec<std::ops::Range<usize>> {
    let mut cuts: Vec<usize> = starts
        .iter()
        .copied()
        .filter(|&s| s > 0 && s < len)
        .collect();
    cuts.sort_unstable();
    cuts.dedup();
    let mut out = Vec::with_capacity(cuts.len() + 1);
    let mut from = 0;
    for c in cuts.into_iter().chain(std::iter::once(len)) {
        if c > from {
            out.push(from..c);
        }
        from = c;
    }
    out
}

/// `Σ a(t) b(t + τ)` over the pairs inside one run, `a` and `b` centred.
fn lagged_sum(a: &[f64], b: &[f64], runs: &[std::ops::Range<usize>], tau: usize) -> f64 {
    runs.iter()
        .filter(|r| r.len() > tau)
        .map(|r| {
            (r.start..r.end - tau)
                .map(|t| a[t] * b[t + tau])
                .sum::<f64>()
        })
        .sum()
}

/// The cross-correlation `r_ab(0..=m)` of two series with gaps: lag
/// products only inside a run (a sample and its lagged partner are `τ`
/// samples apart in time), the means and norms over all samples. One run:
/// [`stats::cross_correlation`].
fn cross_correlation_runs(
    a: &[f64],
    b: &[f64],
    runs: &[std::ops::Range<usize>],
    m: usize,
) -> Vec<f64> {
    let n = a.len().min(b.len());
    let (ma, mb) = (
        gb_core::metrics::mean(&a[..n]),
        gb_core::metrics::mean(&b[..n]),
    );
    let ac: Vec<f64> = a[..n].iter().map(|v| v - ma).collect();
    let bc: Vec<f64> = b[..n].iter().map(|v| v - mb).collect();
    let den = (ac.iter().map(|v| v * v).sum::<f64>() * bc.iter().map(|v| v * v).sum::<f64>())
        .sqrt()
        .max(1e-300);
    (0..=m.min(n.saturating_sub(1)))
        .map(|tau| lagged_sum(&ac, &bc, runs, tau) / den)
        .collect()
}

/// Order of the prewhitening AR models.
const AR_ORDER: usize = 10;

/// `x` (mean removed) filtered by its own AR(`p`) model: the innovations
/// `x(k) − Σ aᵢ x(k−i)`, `a` from Levinson–Durbin on the biased
/// auto-correlation (always a stable filter). With gaps: one AR(`p`) model from the
/// auto-correlation inside the runs, its innovations computed inside each
/// run (the first `p` samples of a run have no history and are dropped,
/// as is a run of `p` samples or fewer); returns them with their runs. A
/// gap (held-out samples left out where a fit extrapolates, several
/// folds' blocks one after the other) would otherwise put a jump into
/// both series at the same sample and correlate them: an AR-noise
/// residual at the noise floor on a sweep read as input-driven
/// (p = 4e-11; 0.41 without the gaps).
fn prewhiten_runs(
    x: &[f64],
    rs: &[std::ops::Range<usize>],
    p: usize,
) -> (Vec<f64>, Vec<std::ops::Range<usize>>) {
    let m = gb_core::metrics::mean(x);
    let xc: Vec<f64> = x.iter().map(|v| v - m).collect();
    let rr = cross_correlation_runs(&xc, &xc, rs, p);
    let a = stats::ar_yule_walker(&rr, p);
    let mut out = Vec::with_capacity(xc.len());
    let mut out_runs = Vec::with_capacity(rs.len());
    for run in rs.iter().filter(|r| r.len() > p) {
        let from = out.len();
        out.extend(
            (run.start + p..run.end)
                .map(|t| xc[t] - (1..=p).map(|i| a[i - 1] * xc[t - i]).sum::<f64>()),
        );
        out_runs.push(from..out.len());
    }
    (out, out_runs)
}

/// Eigenvalues of the lag-correlation matrix below this fraction of the
/// largest are left out of [`cross_test`] (their directions are estimated
/// no better than the sampling error of the auto-correlation).
const CROSS_RANK_TOL: f64 = 0.01;

/// Portmanteau test of the cross-correlation of `a` and `e`, both
/// prewhitened: `Q = N rᵀ P⁺ r`, `r` the cross-correlations at lags
/// `0..=MAX_LAG` and `P` the Toeplitz matrix of the prewhitened `a`'s
/// auto-correlation. Under independence, with `e` white, `√N r` is normal
/// with covariance `P` (Ljung 1999, §16.6), so `Q` is χ² with rank(P)
/// degrees of freedom. A multisine or a sweep stays coloured after the
/// AR prewhitening; the plain sum `N Σ r²` then treats correlated lags as
/// independent and rejects far more often than its level (a linear
/// system at the noise floor read as "unexplained").
fn cross_test(a: &[f64], e: &[f64]) -> (f64, f64) {
    cross_test_runs(a, e, &runs(e.len(), &[]))
}

/// [`cross_test`] of series with gaps (see [`prewhiten_runs`]): lag
/// products only inside a run. One run: the plain test.
fn cross_test_runs(a: &[f64], e: &[f64], rs: &[std::ops::Range<usize>]) -> (f64, f64) {
    let (aw, wr) = prewhiten_runs(a, rs, AR_ORDER);
    let (ew, _) = prewhiten_runs(e, rs, AR_ORDER);
    let n = ew.len() as f64;
    if ew.len() <= MAX_LAG {
        return (0.0, 1.0);
    }
    let r = cross_correlation_runs(&aw, &ew, &wr, MAX_LAG);
    let m = r.len();
    if m == 0 {
        return (0.0, 1.0);
    }
    let ra = cross_correlation_runs(&aw, &aw, &wr, m - 1);
    let p = nalgebra::DMatrix::from_fn(m, m, |i, j| ra.get(i.abs_diff(j)).copied().unwrap_or(0.0));
    let eig = nalgebra::SymmetricEigen::new(p);
    let top = eig.eigenvalues.iter().copied().fold(0.0, f64::max);
    let rv = nalgebra::DVector::from_column_slice(&r);
    let (mut q, mut dof) = (0.0, 0usize);
    for (i, &l) in eig.eigenvalues.iter().enumerate() {
        if l > CROSS_RANK_TOL * top {
            let proj = eig.eigenvectors.column(i).dot(&rv);
            q += n * proj * proj / l;
            dof += 1;
        }
    }
    if dof == 0 {
        return (0.0, 1.0);
    }
    (q, stats::chi2_sf(q, dof as f64))
}

/// Whether no test of [`verdict_tested`] rejects at `level` and the
/// residual is within `ratio` times the white-noise level: the tests read
/// as the final verdict reads them (under cross-validation each p-value
/// the smaller of the model's own over the folds' samples and the lower
/// median of the folds' held-out ones, lag products inside contiguous
/// runs). Uncorrected, each of the `m` tests runs at `level` (a lenient
/// reading: any hint of structure counts); `corrected`, at `level / m`
/// (Bonferroni: `level` bounds the chance that a residual at the noise
/// floor fails any test).
pub(crate) fn quiet(t: &crate::plan::Tested, (level, corrected): (f64, bool), ratio: f64) -> bool {
    // at the smallest level no test rejects: the kind then says only
    // whether the residual is small enough; the p-values are read here
    let v = verdict_tested(t, (f64::MIN_POSITIVE, ratio, ratio), &[]);
    let per_test = if corrected {
        level / v.tests.len().max(1) as f64
    } else {
        level
    };
    v.kind == VerdictKind::Adequate && v.tests.iter().all(|t| t.2 >= per_test)
}

/// Whether every residual test but whiteness passes at `level` (divided
/// by the number of tests, whiteness included, when `corrected`): the
/// input-driven behaviour is explained, whatever the colour of the rest.
pub(crate) fn input_quiet(t: &crate::plan::Tested, (level, corrected): (f64, bool)) -> bool {
    let v = verdict_tested(t, (f64::MIN_POSITIVE, f64::INFINITY, f64::INFINITY), &[]);
    let per_test = if corrected {
        level / v.tests.len().max(1) as f64
    } else {
        level
    };
    v.tests
        .iter()
        .filter(|t| !t.0.starts_with("whiteness"))
        .all(|t| t.2 >= per_test)
}

/// p-values of the prewhitened input–residual cross-correlation test
/// (the verdict's `r_ue`), one per input; `e` and the inputs `u` over the
/// same samples.
pub(crate) fn input_cross_p(e: &[f64], u: &[Vec<f64>]) -> Vec<f64> {
    u.iter()
        .filter(|uj| uj.len() == e.len())
        .map(|uj| cross_test(uj, e).1)
        .collect()
}

/// White-noise level of `y`: `median(|d₁|)/0.6745` of its finest db4
/// detail coefficients (`None` for fewer than 16 samples).
///
/// ```
/// use rand::Rng;
/// // white noise of sd 0.5 (uniform) around a slow sine: σ̂_w ≈ 0.5
/// let mut rng = gb_core::rng::seeded(1);
/// let y: Vec<f64> = (0..4000)
///     .map(|k| (k as f64 * 0.01).sin() + 0.5 * 12f64.sqrt() * (rng.random::<f64>() - 0.5))
///     .collect();
/// let s = gb_diagnose::white_noise_level(&y).unwrap();
/// assert!((s - 0.5).abs() < 0.1, "{s}");
/// ```
pub fn white_noise_level(y: &[f64]) -> Option<f64> {
    if y.len() < 16 {
        return None;
    }
    let w = gb_wavelet::Wavelet::new("db4").ok()?;
    let (_, d) = gb_wavelet::dwt(y, &w, gb_wavelet::Mode::Symmetric).ok()?;
    // the border coefficients see the reflected extension
    let inner = &d[4..d.len().saturating_sub(4).max(4)];
    let s = gb_wavelet::noise_sigma(inner);
    (s.is_finite() && s > 0.0).then_some(s)
}

/// The verdict's clause when the final model does not carry over to the
/// report block: `RMS(report) > ratio · RMS(decision)` over the residuals
/// `(decision, report)` (the report block held out, scored once, used for
/// no decision), `None` otherwise or when either is shorter than 100
/// samples. It names the inputs whose report values leave the range of
/// the fit record `fit` by more than 5 % of that range (extrapolation).
///
/// ```text
/// ; on the report block the residual RMS is 66.2× the decision data's: the model does not carry over there (…)
/// ```
pub(crate) fn report_carry_over(
    (decision, report): (&[f64], &[f64]),
    (fit, report_inputs): (&gb_core::Record, &[&[f64]]),
    ratio: f64,
) -> Option<String> {
    if decision.len() < 100 || report.len() < 100 {
        return None;
    }
    let r = gb_core::metrics::rms(report) / gb_core::metrics::rms(decision).max(f64::MIN_POSITIVE);
    if r.is_nan() || r <= ratio {
        return None;
    }
    let outside: Vec<String> = fit
        .inputs
        .iter()
        .zip(report_inputs)
        .zip(&fit.input_names)
        .filter_map(|((u, v), name)| {
            let ((lo, hi), (a, b)) = (gb_core::metrics::min_max(u), gb_core::metrics::min_max(v));
            let margin = 0.05 * (hi - lo);
            (a < lo - margin || b > hi + margin).then(|| {
                format!("input '{name}' spans [{a:.4e}, {b:.4e}] there, [{lo:.4e}, {hi:.4e}] in the fit record")
            })
        })
        .collect();
    let why = if outside.is_empty() {
        "behaviour the training record does not show".to_string()
    } else {
        format!("extrapolation: {}", outside.join("; "))
    };
    Some(format!(
        "; on the report block (held out, used for no decision) the residual RMS is {r:.1}× the decision data's: the model does not carry over there ({why})"
    ))
}

impl Verdict {
    /// This verdict with the clause `note` of [`report_carry_over`]: an
    /// "adequate" or "coloured noise" verdict becomes unexplained, its own
    /// reading kept as what the decision data show.
    pub(crate) fn not_carried_over(&mut self, note: &str) {
        if self.kind == VerdictKind::Unexplained {
            self.text.push_str(note);
            return;
        }
        let seen = self
            .text
            .strip_prefix("adequate: ")
            .unwrap_or(&self.text)
            .to_string();
        self.kind = VerdictKind::Unexplained;
        self.text = format!("unexplained misfit{note}; on the decision data: {seen}");
    }
}

/// Every residual test of the final model at overall `level`; `ratio`
/// bounds the residual RMS, in units of the white-noise level of the
/// measured output `yhat + e`, that "adequate" or "coloured noise" may
/// leave (see the module docs). One series, no folds: what
/// [`verdict_tested`] reads on a select block.
#[cfg(test)]
pub fn verdict(
    e: &[f64],
    yhat: &[f64],
    u: &[Vec<f64>],
    (level, ratio): (f64, f64),
    tried: &[String],
) -> Verdict {
    verdict_coloured(e, yhat, u, (level, ratio, ratio), tried)
}

/// [`verdict`] with its own bound for "coloured noise": only whiteness
/// rejects and `RMS(e) ≤ coloured · σ̂_w` (`coloured ≤ ratio`, policy
/// `coloured_noise_ratio`); a coloured residual above it is unexplained.
#[cfg(test)]
pub(crate) fn verdict_coloured(
    e: &[f64],
    yhat: &[f64],
    u: &[Vec<f64>],
    levels: (f64, f64, f64),
    tried: &[String],
) -> Verdict {
    judge(residual_tests(e, yhat, u, &[]), e, yhat, levels, tried)
}

/// Every residual test of the final model at overall level `levels.0`;
/// `levels.1` bounds the residual RMS, in units of the white-noise level
/// of the measured output `yhat + e`, that "adequate" may leave and
/// `levels.2` (≤ `levels.1`, policy `coloured_noise_ratio`) the one
/// "coloured noise" may (only whiteness rejects), on what
/// [`crate::plan::Plan::tested`] gives: under
/// cross-validation each test's p-value is the smaller of the final
/// model's own (over the folds' samples, in-sample) and the lower median
/// of the folds' (each fold's refit on its held-out samples), so it
/// rejects when the final model's residual rejects or at least half the
/// folds' do. One fold whose refit extrapolates (a log sweep's band
/// refitted on the other frequencies) cannot make the final model
/// unexplained, and a flexible model's in-sample residual, whiter than
/// held-out ones, cannot make it adequate when the held-out folds see
/// structure.
pub(crate) fn verdict_tested(
    t: &crate::plan::Tested,
    levels: (f64, f64, f64),
    tried: &[String],
) -> Verdict {
    let (e, yhat) = (&t.whole.e, &t.whole.yhat);
    let mut tests = residual_tests(e, yhat, &t.inputs, &t.whole_starts);
    let per_fold: Vec<Vec<(String, f64, f64, bool)>> = t
        .folds
        .iter()
        .enumerate()
        .map(|(k, (r, u))| {
            let starts = t.fold_starts.get(k).map_or(&[][..], Vec::as_slice);
            residual_tests(&r.e, &r.yhat, u, starts)
        })
        .collect();
    for (i, test) in tests.iter_mut().enumerate() {
        let mut ps: Vec<f64> = per_fold
            .iter()
            .filter_map(|f| f.get(i).map(|x| x.2))
            .collect();
        if ps.len() == t.folds.len() && !ps.is_empty() {
            ps.sort_by(f64::total_cmp);
            // the lower median: rejected by at least half the folds
            test.2 = test.2.min(ps[(ps.len() - 1) / 2]);
        }
    }
    judge(tests, e, yhat, levels, tried)
}

/// Every residual test of `e` (statistic, p-value; not yet judged).
fn residual_tests(
    e: &[f64],
    yhat: &[f64],
    u: &[Vec<f64>],
    starts: &[usize],
) -> Vec<(String, f64, f64, bool)> {
    let mut tests: Vec<(String, f64, f64, bool)> = vec![];
    let rs = runs(e.len(), starts);
    let r = cross_correlation_runs(e, e, &rs, MAX_LAG);
    let (q, p) = stats::ljung_box(&r, e.len());
    tests.push(("whiteness (Ljung-Box)".into(), q, p, false));
    for (j, uj) in u.iter().enumerate() {
        let m = gb_core::metrics::mean(uj);
        let u2: Vec<f64> = uj.iter().map(|v| (v - m) * (v - m)).collect();
        let e2: Vec<f64> = e.iter().map(|v| v * v).collect();
        let (q, p) = cross_test_runs(uj, e, &rs);
        tests.push((
            format!("input {} cross-correlation r_ue", j + 1),
            q,
            p,
            false,
        ));
        let (q, p) = cross_test_runs(&u2, e, &rs);
        tests.push((format!("input {} higher-order r_u2'e", j + 1), q, p, false));
        let (q, p) = cross_test_runs(&u2, &e2, &rs);
        tests.push((format!("input {} higher-order r_u2'e2", j + 1), q, p, false));
    }
    let rho = r.get(1).copied().unwrap_or(0.0).clamp(-0.99, 0.99);
    let deflate = ((1.0 - rho) / (1.0 + rho)).min(1.0);
    let ev = crate::Evidence::compute(e, yhat, u);
    for (name, (f, _)) in [
        ("static nonlinearity", ev.static_nonlinearity),
        ("memory (direction of motion)", ev.memory),
    ] {
        let n = e.len() as f64;
        let d1 = if name == "memory (direction of motion)" {
            3.0
        } else {
            2.0 + 2.0 * u.len() as f64
        };
        let d2 = (n * deflate - 4.0 * (1.0 + u.len() as f64)).max(1.0);
        let f_eff = f * deflate;
        tests.push((name.into(), f_eff, stats::f_sf(f_eff, d1, d2), false));
    }
    tests
}

/// The verdict from the residual tests of `e` (see the module docs).
fn judge(
    mut tests: Vec<(String, f64, f64, bool)>,
    e: &[f64],
    yhat: &[f64],
    (level, ratio, coloured): (f64, f64, f64),
    tried: &[String],
) -> Verdict {
    let k = tests.len() as f64;
    for t in tests.iter_mut() {
        t.3 = t.2 < level / k;
    }
    // the finest scale of y = ŷ + e holds the noise plus what of the
    // signal leaks in; that of e the noise plus the misfit's leak: the
    // smaller is the tighter estimate of the measurement noise
    let y: Vec<f64> = yhat.iter().zip(e).map(|(a, b)| a + b).collect();
    let noise_level = [white_noise_level(&y), white_noise_level(e)]
        .into_iter()
        .flatten()
        .reduce(f64::min);
    let times = noise_level.map(|s| gb_core::metrics::rms(e) / s);
    let failed: Vec<&(String, f64, f64, bool)> = tests.iter().filter(|t| t.3).collect();
    let input_failed = failed.iter().any(|t| !t.0.starts_with("whiteness"));
    // a coloured residual must be nearer the noise level than a white one
    let bound = if failed.is_empty() {
        ratio
    } else {
        coloured.min(ratio)
    };
    let too_large = times.is_some_and(|t| t > bound);
    let kind = if input_failed || too_large {
        VerdictKind::Unexplained
    } else if !failed.is_empty() {
        VerdictKind::ColouredNoise
    } else {
        VerdictKind::Adequate
    };
    let list = failed
        .iter()
        .map(|t| format!("{} (p={:.1e})", t.0, t.2))
        .collect::<Vec<_>>()
        .join(", ");
    let size = times.map_or(String::new(), |t| {
        let t = if t < 100.0 {
            format!("{t:.1}")
        } else {
            format!("{t:.1e}")
        };
        format!("; the residual is {t}× the white-noise level of the output's finest wavelet scale")
    });
    let tried = if tried.is_empty() {
        "nothing".to_string()
    } else {
        tried.join("; ")
    };
    let text = match kind {
        VerdictKind::Adequate => format!(
            "adequate: no residual test rejects at the {:.0} % level (whiteness, input cross-correlation, higher-order correlations, static nonlinearity, memory){size}",
            100.0 * level
        ),
        VerdictKind::ColouredNoise => format!(
            "the input-driven behaviour is explained; the remaining error is coloured noise ({list}): a noise model would help prediction, not simulation{size}"
        ),
        VerdictKind::Unexplained if !input_failed => format!(
            "unexplained misfit: {}{size} (more than {bound}×): noise that coloured and large, or input-driven behaviour the correlation tests do not resolve; tried: {tried}",
            if failed.is_empty() {
                "no residual test rejects at the stated level".to_string()
            } else {
                format!("only {list} rejects")
            }
        ),
        VerdictKind::Unexplained => format!(
            "unexplained misfit: {list} at the {:.0} % level{size}; tried: {tried}",
            100.0 * level,
        ),
    };
    Verdict {
        kind,
        level,
        tests,
        text,
        noise_ratio: times,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    fn noise(n: usize, seed: u64) -> Vec<f64> {
        let mut r = gb_core::rng::seeded(seed);
        (0..n).map(|_| r.random::<f64>() - 0.5).collect()
    }

    /// Lag products never span a gap: two runs whose only shared pattern
    /// straddles the cut (a jump at the end of the first run in `a`, at
    /// the start of the second in `b`, one sample apart) correlate at lag 1
    /// read as one series, not read as two runs; one run is the plain
    /// cross-correlation.
    #[test]
    fn lag_products_stay_inside_a_run() {
        let n = 400;
        let (mut a, mut b) = (noise(2 * n, 1), noise(2 * n, 2));
        a[n - 1] += 20.0;
        b[n] += 20.0;
        let one = runs(2 * n, &[]);
        let two = runs(2 * n, &[n]);
        assert_eq!(two, vec![0..n, n..2 * n]);
        let plain = crate::stats::cross_correlation(&a, &b, 3);
        let as_one = cross_correlation_runs(&a, &b, &one, 3);
        for (x, y) in plain.iter().zip(&as_one) {
            assert!((x - y).abs() < 1e-12, "{plain:?} vs {as_one:?}");
        }
        let as_two = cross_correlation_runs(&a, &b, &two, 3);
        assert!(as_one[1] > 0.3, "one series: {as_one:?}");
        assert!(as_two[1].abs() < 0.1, "two runs: {as_two:?}");
        // prewhitening drops each run's first p samples
        let (w, wr) = prewhiten_runs(&a, &two, AR_ORDER);
        assert_eq!(
            wr,
            vec![0..n - AR_ORDER, n - AR_ORDER..2 * n - 2 * AR_ORDER]
        );
        assert_eq!(w.len(), 2 * n - 2 * AR_ORDER);
        // and the cross test with the gap declared passes where the one
        // series rejects
        assert!(cross_test(&a, &b).1 < 1e-6, "{:?}", cross_test(&a, &b));
        assert!(
            cross_test_runs(&a, &b, &two).1 > 0.01,
            "{:?}",
            cross_test_runs(&a, &b, &two)
        );
    }

    fn lowpass(x: &[f64], a: f64) -> Vec<f64> {
        let mut y = vec![0.0; x.len()];
        for k in 1..x.len() {
            y[k] = a * y[k - 1] + x[k];
        }
        y
    }

    #[test]
    fn white_independent_residual_is_adequate() {
        let u = lowpass(&noise(4000, 1), 0.8);
        let e = noise(4000, 2);
        let yhat = lowpass(&u, 0.5);
        let v = verdict(&e, &yhat, &[u], (0.01, f64::INFINITY), &[]);
        assert_eq!(v.kind, VerdictKind::Adequate, "{v:?}");
    }

    /// The screen's reading holds its level: white residuals independent
    /// of a coloured input, 300 draws. Bonferroni-corrected at 1 %, at
    /// most 2 % of them read as not quiet (by chance, any test rejecting);
    /// each test at 1 % uncorrected, at least 4 % do (the family of tests
    /// rejects more often than each alone; measured: 2 and 21 of 300) —
    /// structure-free residuals the screen should let stop the search.
    #[test]
    fn the_corrected_quiet_reading_holds_its_level() {
        let (mut corrected, mut each) = (0, 0);
        let draws = 300;
        for seed in 0..draws {
            let u = lowpass(&noise(1000, 1000 + seed), 0.8);
            let yhat = lowpass(&u, 0.5);
            let t = crate::plan::Tested {
                whole: crate::evaluate::Residuals {
                    e: noise(1000, 2000 + seed),
                    yhat,
                    nll: vec![],
                },
                inputs: vec![u],
                folds: vec![],
                whole_starts: vec![],
                fold_starts: vec![],
            };
            corrected += usize::from(!quiet(&t, (0.01, true), 10.0));
            each += usize::from(!quiet(&t, (0.01, false), 10.0));
        }
        assert!(corrected <= draws as usize / 50, "{corrected} of {draws}");
        assert!(
            each >= draws as usize / 25,
            "each {each}, corrected {corrected}"
        );
    }

    #[test]
    fn coloured_noise_is_not_called_unexplained() {
        // coloured residuals independent of a coloured input, 20 draws: at a
        // 1 % level at most one may be called unexplained
        let mut unexplained = 0;
        for seed in 0..20 {
            let u = lowpass(&noise(4000, 100 + seed), 0.9);
            let e = lowpass(&noise(4000, 200 + seed), 0.9);
            let yhat = lowpass(&u, 0.5);
            let v = verdict(&e, &yhat, &[u], (0.01, f64::INFINITY), &[]);
            assert_ne!(
                v.kind,
                VerdictKind::Adequate,
                "coloured residual called adequate"
            );
            if v.kind == VerdictKind::Unexplained {
                unexplained += 1;
            }
        }
        assert!(
            unexplained <= 1,
            "{unexplained} of 20 coloured-noise draws called unexplained"
        );
    }

    /// A residual the correlation tests call coloured noise is unexplained
    /// once it is far above the output's white-noise level (a slow misfit
    /// 10× the measurement noise), and stays coloured noise when it is
    /// near it (mildly coloured noise at the measurement level); a white
    /// residual is at the level by construction.
    #[test]
    fn a_large_coloured_residual_is_unexplained() {
        let n = 4000;
        let u = lowpass(&noise(n, 7), 0.8);
        let yhat: Vec<f64> = (0..n).map(|k| (k as f64 * 0.01).sin()).collect();
        let white = noise(n, 8);
        let slow = lowpass(&noise(n, 9), 0.99);
        let scale = |x: &[f64], s: f64| -> Vec<f64> {
            let r = gb_core::metrics::rms(x);
            x.iter().map(|v| v * s / r).collect()
        };
        let (w, sl) = (scale(&white, 0.01), scale(&slow, 0.1));
        let large: Vec<f64> = w.iter().zip(&sl).map(|(a, b)| a + b).collect();
        let v = verdict(&large, &yhat, std::slice::from_ref(&u), (0.01, 3.0), &[]);
        assert_eq!(v.kind, VerdictKind::Unexplained, "{}", v.text);
        assert!(v.text.contains("white-noise level"), "{}", v.text);
        let mild = scale(&lowpass(&white, 0.3), 0.01);
        let v = verdict(&mild, &yhat, std::slice::from_ref(&u), (0.01, 3.0), &[]);
        assert_eq!(v.kind, VerdictKind::ColouredNoise, "{}", v.text);
        let v = verdict(&w, &yhat, &[u], (0.01, 3.0), &[]);
        assert_eq!(v.kind, VerdictKind::Adequate, "{}", v.text);
    }

    /// A coloured residual about twice the white-noise level is coloured
    /// noise under the bound 3 and unexplained under a coloured-noise bound
    /// of 1.5; a white residual is adequate under either (the bound acts on
    /// the coloured branch only); the ratio is reported.
    #[test]
    fn the_coloured_noise_bound_acts_on_coloured_residuals_only() {
        let n = 4000;
        let u = lowpass(&noise(n, 7), 0.8);
        let yhat = lowpass(&u, 0.5);
        let scale = |x: &[f64], s: f64| -> Vec<f64> {
            let r = gb_core::metrics::rms(x);
            x.iter().map(|v| v * s / r).collect()
        };
        let w = scale(&noise(n, 8), 0.01);
        let slow = scale(&lowpass(&noise(n, 19), 0.9), 0.02);
        let e: Vec<f64> = w.iter().zip(&slow).map(|(a, b)| a + b).collect();
        let us = std::slice::from_ref(&u);
        let lenient = verdict_coloured(&e, &yhat, us, (0.01, 3.0, 3.0), &[]);
        assert_eq!(lenient.kind, VerdictKind::ColouredNoise, "{}", lenient.text);
        let times = lenient.noise_ratio.unwrap_or(f64::NAN);
        assert!(times > 1.5 && times < 3.0, "{times}");
        let strict = verdict_coloured(&e, &yhat, us, (0.01, 3.0, 1.5), &[]);
        assert_eq!(strict.kind, VerdictKind::Unexplained, "{}", strict.text);
        assert!(strict.text.contains("more than 1.5×"), "{}", strict.text);
        let white = verdict_coloured(&w, &yhat, us, (0.01, 3.0, 1.5), &[]);
        assert_eq!(white.kind, VerdictKind::Adequate, "{}", white.text);
    }

    /// A multisine of 40 tones (periodic, random phases): what AR(10)
    /// prewhitening leaves coloured.
    fn multisine(n: usize, seed: u64) -> Vec<f64> {
        let mut r = gb_core::rng::seeded(seed);
        let ph: Vec<f64> = (0..40)
            .map(|_| std::f64::consts::TAU * r.random::<f64>())
            .collect();
        (0..n)
            .map(|k| {
                (0..40)
                    .map(|i| {
                        (std::f64::consts::TAU * (i + 1) as f64 * k as f64 / 500.0 + ph[i]).cos()
                    })
                    .sum()
            })
            .collect()
    }

    /// Under independence the input–residual test holds its level for a
    /// multisine input (the plain sum of squared lags against χ²(26)
    /// rejected 15 of these 100 white residuals at 5 %), and it still sees
    /// a missed input term of a tenth of the noise.
    #[test]
    fn the_cross_correlation_test_holds_its_level_for_a_multisine() {
        let draws = 100;
        let u = multisine(2000, 1);
        let rejected = (0..draws)
            .filter(|&s| cross_test(&u, &noise(2000, 100 + s)).1 < 0.05)
            .count();
        assert!(rejected <= 12, "{rejected} of {draws} rejected at 5 %");
        // the noise is uniform on ±0.5 (sd 1/√12), the multisine's sd √20
        let (sd_noise, sd_u) = (12f64.sqrt().recip(), 20f64.sqrt());
        let w = noise(2000, 7);
        let e: Vec<f64> = (0..2000)
            .map(|k| w[k] + 0.1 * sd_noise * u[k.saturating_sub(3)] / sd_u)
            .collect();
        assert!(cross_test(&u, &e).1 < 1e-3, "{:?}", cross_test(&u, &e));
    }

    #[test]
    fn a_missed_input_term_is_unexplained() {
        let u = lowpass(&noise(4000, 5), 0.8);
        let w = noise(4000, 6);
        // residual holds a squared-input term the model missed
        let m = gb_core::metrics::mean(&u);
        let e: Vec<f64> = u
            .iter()
            .zip(&w)
            .map(|(a, b)| 0.3 * (a - m).powi(2) + b)
            .collect();
        let yhat = lowpass(&u, 0.5);
        let v = verdict(
            &e,
            &yhat,
            &[u],
            (0.01, f64::INFINITY),
            &["nonlinearity: LOLIMOT".into()],
        );
        assert_eq!(v.kind, VerdictKind::Unexplained, "{v:?}");
        assert!(v.text.contains("tried: nonlinearity"), "{}", v.text);
    }

    /// Under cross-validation one fold whose residual follows the input (a
    /// refit that extrapolates) does not make the model unexplained when
    /// its own residual and the other folds' are white and independent;
    /// two of four such folds do, though its in-sample residual is white.
    #[test]
    fn the_folds_reject_when_half_of_them_see_the_input() {
        let n = 1000;
        let input_term = |u: &[f64], w: &[f64]| -> Vec<f64> {
            u.iter().zip(w).map(|(a, b)| 0.5 * a + b).collect()
        };
        let fold = |k: u64, bad: bool| {
            let u = lowpass(&noise(n, 300 + k), 0.8);
            let w = noise(n, 400 + k);
            let e = if bad { input_term(&u, &w) } else { w };
            let yhat = lowpass(&u, 0.5);
            (
                crate::evaluate::Residuals {
                    e,
                    yhat,
                    nll: vec![],
                },
                vec![u],
            )
        };
        let tested = |bad: &[u64]| {
            let folds: Vec<_> = (0..4).map(|k| fold(k, bad.contains(&k))).collect();
            let inputs = vec![folds.iter().flat_map(|f| f.1[0].clone()).collect()];
            crate::plan::Tested {
                whole: crate::evaluate::Residuals {
                    e: noise(4 * n, 9),
                    yhat: folds.iter().flat_map(|f| f.0.yhat.clone()).collect(),
                    nll: vec![],
                },
                inputs,
                folds,
                whole_starts: vec![],
                fold_starts: vec![],
            }
        };
        let levels = (0.01, f64::INFINITY, f64::INFINITY);
        let none = verdict_tested(&tested(&[]), levels, &[]);
        assert_eq!(none.kind, VerdictKind::Adequate, "{none:?}");
        let one = verdict_tested(&tested(&[2]), levels, &[]);
        assert_eq!(one.kind, VerdictKind::Adequate, "{one:?}");
        let two = verdict_tested(&tested(&[0, 2]), levels, &[]);
        assert_eq!(two.kind, VerdictKind::Unexplained, "{two:?}");
        // the concatenated folds, as before: one bad fold rejects
        let t = tested(&[2]);
        let pooled: Vec<f64> = t.folds.iter().flat_map(|f| f.0.e.clone()).collect();
        let v = verdict(
            &pooled,
            &t.whole.yhat,
            &t.inputs,
            (0.01, f64::INFINITY),
            &[],
        );
        assert_eq!(v.kind, VerdictKind::Unexplained, "{v:?}");
    }

    /// The report block's residual against the decision data's: within
    /// the ratio no clause; above it a clause with the ratio, naming an
    /// input that leaves the fit record's range; nothing for short blocks.
    #[test]
    fn a_model_that_does_not_carry_over_to_the_report_block_is_named() {
        // alternating ±a: RMS exactly a
        let pm = |a: f64, n: usize| -> Vec<f64> {
            (0..n).map(|k| if k % 2 == 0 { a } else { -a }).collect()
        };
        let u: Vec<f64> = (0..400).map(|k| (k as f64 * 0.1).sin()).collect();
        let fit = gb_core::Record::new(
            vec!["u".into()],
            "y".into(),
            vec![u.clone()],
            vec![0.0; 400],
        )
        .unwrap();
        let inside: Vec<f64> = u.iter().map(|v| 0.9 * v).collect();
        let beyond: Vec<f64> = u.iter().map(|v| 1.3 * v).collect();
        let dec = pm(1.0, 400);
        let within = report_carry_over((&dec, &pm(1.4, 400)), (&fit, &[&inside]), 1.5);
        assert!(within.is_none(), "{within:?}");
        let far = report_carry_over((&dec, &pm(3.0, 400)), (&fit, &[&inside]), 1.5).unwrap();
        assert!(
            far.contains("3.0×") && far.contains("does not show"),
            "{far}"
        );
        let out = report_carry_over((&dec, &pm(3.0, 400)), (&fit, &[&beyond]), 1.5).unwrap();
        assert!(out.contains("input 'u' spans"), "{out}");
        assert!(report_carry_over((&dec, &pm(3.0, 99)), (&fit, &[&inside]), 1.5).is_none());
    }

    /// A verdict that does not carry over becomes unexplained: "adequate"
    /// keeps its reading after "on the decision data", "coloured noise"
    /// its whole text, an unexplained one only gains the clause.
    #[test]
    fn a_verdict_that_does_not_carry_over_is_unexplained() {
        let v = |kind, text: &str| Verdict {
            kind,
            level: 0.01,
            tests: vec![],
            text: text.into(),
            noise_ratio: None,
        };
        let mut a = v(VerdictKind::Adequate, "adequate: no residual test rejects");
        a.not_carried_over("; X");
        assert_eq!(a.kind, VerdictKind::Unexplained);
        assert_eq!(
            a.text,
            "unexplained misfit; X; on the decision data: no residual test rejects"
        );
        let mut c = v(
            VerdictKind::ColouredNoise,
            "the remaining error is coloured noise (whiteness (p=0.001)): a noise model",
        );
        c.not_carried_over("; X");
        assert!(c.text.ends_with("on the decision data: the remaining error is coloured noise (whiteness (p=0.001)): a noise model"), "{}", c.text);
        let mut u = v(VerdictKind::Unexplained, "unexplained misfit: whiteness");
        u.not_carried_over("; X");
        assert_eq!(u.text, "unexplained misfit: whiteness; X");
    }
}
