//! `hysteresis` before the dynamics: one play operator (a backlash) on one
//! input, its half-width fitted on the training data.
use crate::evaluate::{residuals_on, Evaluated, Lineage};
use crate::extension::{Context, Extension, Proposal};
use crate::plan::core;
use crate::{Cause, DiagnoseError};
use gb_core::FittedModel;
use gb_lmn::{HysteresisOn, IoNetworkParams, LocalModelNetwork};
use rayon::prelude::*;

/// Half-widths scanned, in units of the input's standard deviation
/// (ratio 1.5 from 0.04 σ to 1.5 σ; those above the input's half range
/// `(q₉₉ − q₁)/2` are dropped).
const SCAN: [f64; 10] = [0.04, 0.06, 0.09, 0.135, 0.2, 0.3, 0.45, 0.68, 1.0, 1.5];

/// Fine steps around the scan's best: `r·1.5^(k/FINE)` for
/// `k = −FINE+1 … FINE−1` (a grid ratio of 1.07).
const FINE: i32 = 6;

/// Choices per dead time: every scan value with its fine steps.
const PER_DELAY: usize = SCAN.len() * (2 * FINE - 1) as usize;

/// The half-width of choice `c` ([`Extension::fit_choosing`]): within its
/// dead time's `c mod PER_DELAY`, scan index `/ (2·FINE − 1)`, fine step
/// `mod (2·FINE − 1) − (FINE − 1)`; the dead time is alternative
/// `c / PER_DELAY` ([`alternatives`]).
fn half_width_of(c: usize) -> Option<f64> {
    let c = c % PER_DELAY;
    let per = (2 * FINE - 1) as usize;
    let base = SCAN.get(c / per)?;
    let k = (c % per) as i32 - (FINE - 1);
    Some(base * 1.5f64.powf(f64::from(k) / f64::from(FINE)))
}

/// A backlash (play operator `P_r`, half-width `r`) on input `j`, then the
/// current linear dynamics, the input itself kept as a regressor:
///
/// ```text
/// ŷ(k) = −Σ aᵢ ŷ(k−i) + Σ bᵢ u_j(k−d−i) + Σ cₗ P_r[u_j](k−d−l) + …
/// ```
///
/// `r` is chosen by the fit block's free-run error (a scan, then finer
/// steps around its best; a best at or below the scan's lowest value, where
/// the play is the input itself, is no backlash and the candidate is
/// dropped: a scan whose best is its lowest value takes no fine steps);
/// every other coefficient is fitted output-error for
/// each `r`. The grid of [`super::PreisachColumns`]' input plays (steps of
/// 0.3 σ) can only interpolate a gear play of, say, 0.2 σ; this fits it.
pub struct Backlash;

/// The dead times a proposal tries: with one input its own and the
/// variants of [`super::delay_variants`] (a backlash holds the response at
/// every reversal, which a linear fit takes for extra dead time); with
/// several, its own.
fn alternatives(io: &IoNetworkParams) -> Vec<Vec<usize>> {
    if io.delay.len() != 1 {
        return vec![io.delay.clone()];
    }
    super::delay_variants(&io.delay[0].to_string())
        .iter()
        .filter_map(|d| d.parse().ok().map(|k| vec![k]))
        .collect()
}

/// The input a proposal's play sits on.
fn input_of(p: &Proposal) -> Option<usize> {
    let io = p.lineage.io()?;
    let at = io.input_play_at.as_ref()?;
    at.iter().position(|t| !t.is_empty())
}

impl Backlash {
    /// Fit the proposal with half-width `r` on input `j`; its free-run
    /// NRMSE on the fit block (after the init window) as the score.
    fn fit_at(io: &IoNetworkParams, j: usize, r: f64, ctx: &Context) -> Option<(f64, FittedModel)> {
        let mut at = vec![vec![]; ctx.fit.n_inputs()];
        at[j] = vec![r];
        let p = IoNetworkParams {
            input_play_at: Some(at),
            ..io.clone()
        };
        let m = super::fit_io(&p, ctx).ok()?;
        let w = ctx.plan.w.min(ctx.fit.len() / 4);
        let res = residuals_on(&m, ctx.fit, &(0..ctx.fit.len()), w).ok()?;
        let sd = gb_core::metrics::std(ctx.fit.output.get(w..)?);
        let score = gb_core::metrics::rms(&res.e) / sd.max(1e-300);
        score.is_finite().then_some((score, m))
    }

    /// [`search`](Self::search) at the proposal's dead time; then each
    /// other dead time of [`alternatives`] fitted at the half-width found,
    /// and the search repeated at the one whose fit-block error is smallest
    /// if that beats the first. With no backlash at the proposal's dead
    /// time, the search at each other one. The best fit and its choice
    /// index (see [`half_width_of`]).
    fn search_delays(
        io: &IoNetworkParams,
        j: usize,
        ctx: &Context,
    ) -> Option<(usize, FittedModel)> {
        let alts = alternatives(io);
        let at = |i: usize| IoNetworkParams {
            delay: alts[i].clone(),
            ..io.clone()
        };
        let offset = |i: usize, (c, s, m): (usize, f64, FittedModel)| (c + i * PER_DELAY, s, m);
        let first = Self::search(&at(0), j, ctx);
        let pick = |v: Vec<(usize, f64, FittedModel)>| {
            v.into_iter()
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(c, _, m)| (c, m))
        };
        let Some(first) = first else {
            let rest: Vec<_> = (1..alts.len())
                .into_par_iter()
                .filter_map(|i| Self::search(&at(i), j, ctx).map(|r| offset(i, r)))
                .collect();
            return pick(rest);
        };
        let r = half_width_of(first.0)?;
        let other = (1..alts.len())
            .into_par_iter()
            .filter_map(|i| Self::fit_at(&at(i), j, r, ctx).map(|(s, _)| (i, s)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .filter(|&(_, s)| s < first.1);
        let again = other.and_then(|(i, _)| Self::search(&at(i), j, ctx).map(|r| offset(i, r)));
        pick([Some(first), again].into_iter().flatten().collect())
    }

    /// Scan [`SCAN`], then the fine steps around its best; the best fit,
    /// its score and its choice index (see [`half_width_of`]). `None` when
    /// the best is at or below the scan's lowest value (no backlash).
    fn search(io: &IoNetworkParams, j: usize, ctx: &Context) -> Option<(usize, f64, FittedModel)> {
        let top = gb_lmn::half_range(&ctx.fit.inputs[j]);
        let per = (2 * FINE - 1) as usize;
        let centre = (FINE - 1) as usize;
        let coarse: Vec<usize> = (0..SCAN.len())
            .filter(|&i| !top.is_finite() || i == 0 || SCAN[i] <= top)
            .map(|i| i * per + centre)
            .collect();
        let fit_all = |choices: &[usize]| Self::fit_choices(io, j, ctx, choices);
        let best =
            |v: Vec<(usize, f64, FittedModel)>| v.into_iter().min_by(|a, b| a.1.total_cmp(&b.1));
        let first = best(fit_all(&coarse))?;
        // the scan's lowest value is the input itself: no backlash (any
        // gain would be the delay variant's alone), and the fine steps
        // around it (half below it, half within a grid step above it)
        // would look for a play narrower than the scan resolves; the fine
        // steps around any other value all lie above it
        if first.0 == centre {
            return None;
        }
        let base = first.0 - centre;
        Some(Self::climb(io, j, ctx, first, base..base + per))
    }

    /// Descent on the fine steps `range` from the fitted choice `start`:
    /// its two neighbours, then on in the direction that lowered the score
    /// while it goes on lowering it — the best fit, its score and its
    /// choice index. Near its optimum the fit error is unimodal in the
    /// half-width, so this finds the fine step that all of them would
    /// (two to six fits instead of ten).
    fn climb(
        io: &IoNetworkParams,
        j: usize,
        ctx: &Context,
        start: (usize, f64, FittedModel),
        range: std::ops::Range<usize>,
    ) -> (usize, f64, FittedModel) {
        let c = start.0;
        let near: Vec<usize> = [c.checked_sub(1), c.checked_add(1)]
            .into_iter()
            .flatten()
            .filter(|k| range.contains(k))
            .collect();
        let mut best = start;
        for f in Self::fit_choices(io, j, ctx, &near) {
            if f.1 < best.1 {
                best = f;
            }
        }
        let up = match best.0.cmp(&c) {
            std::cmp::Ordering::Equal => return best,
            o => o == std::cmp::Ordering::Greater,
        };
        loop {
            let next = if up {
                best.0.checked_add(1)
            } else {
                best.0.checked_sub(1)
            };
            let Some(next) = next.filter(|k| range.contains(k)) else {
                return best;
            };
            match Self::fit_choices(io, j, ctx, &[next]).pop() {
                Some(f) if f.1 < best.1 => best = f,
                _ => return best,
            }
        }
    }

    /// A delay rival's search from the half-width its sibling at the
    /// current delay found (choice `sibling`): the [`climb`](Self::climb)
    /// from it over the fine steps around its scan value — the best fit,
    /// its score and its choice index.
    fn search_fine(
        io: &IoNetworkParams,
        j: usize,
        ctx: &Context,
        sibling: usize,
    ) -> Option<(usize, f64, FittedModel)> {
        let per = (2 * FINE - 1) as usize;
        let at = sibling % PER_DELAY;
        let base = at / per * per;
        let start = Self::fit_choices(io, j, ctx, &[at]).pop()?;
        Some(Self::climb(io, j, ctx, start, base..base + per))
    }

    /// Each half-width choice of `choices` fitted ([`fit_at`](Self::fit_at),
    /// in parallel): the choice, its score and its fit, in order; the
    /// choices that could not be fitted left out.
    fn fit_choices(
        io: &IoNetworkParams,
        j: usize,
        ctx: &Context,
        choices: &[usize],
    ) -> Vec<(usize, f64, FittedModel)> {
        choices
            .par_iter()
            .filter_map(|&c| {
                let (s, m) = Self::fit_at(io, j, half_width_of(c)?, ctx)?;
                Some((c, s, m))
            })
            .collect()
    }
}

impl Extension for Backlash {
    fn fit_cost(&self) -> u8 {
        3
    }
    fn name(&self) -> &'static str {
        "backlash"
    }
    fn cause(&self) -> Cause {
        Cause::Hysteresis
    }
    /// When the current model is a plain linear input–output model: one
    /// proposal per input at the current delays; with one input, the fit
    /// tries the [`alternatives`] as well, except under cross-validation,
    /// where each alternative is a proposal of its own
    /// ([`super::delay_choices`]).
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        let Some(p) = ctx
            .current
            .lineage
            .io()
            .filter(|p| !p.hysteresis && !p.network && p.output_map == 0)
        else {
            return vec![];
        };
        let n = ctx.fit.n_inputs();
        let (_, delay) = super::io_structure(p, n);
        let choices = if n == 1 {
            super::delay_choices(ctx, &delay)
        } else {
            vec![(delay.clone(), format!("input delay {delay}"))]
        };
        let mut out = vec![];
        for (d, words) in choices {
            // one dead time (the others, `a|b`, are tried by the fit)
            let d = d.split('|').next().unwrap_or_default().to_string();
            let Some(dv) = d
                .split('/')
                .map(|v| v.parse().ok())
                .collect::<Option<Vec<usize>>>()
            else {
                continue;
            };
            for j in 0..n {
                // NaN marks the input whose half-width the fit chooses
                // (`input_of`); `rescore` writes the fitted one
                let mut at = vec![vec![]; n];
                at[j] = vec![f64::NAN];
                out.push(Proposal {
                    cause: Cause::Hysteresis,
                    lineage: Lineage::Io(IoNetworkParams {
                        hysteresis: true,
                        hysteresis_on: HysteresisOn::Inputs,
                        separable_hysteresis: false,
                        input_play_at: Some(at),
                        delay: dv.clone(),
                        ..p.clone()
                    }),
                    text: format!(
                        "a backlash on input '{}' (one play operator, its half-width fitted on the training data), the input kept as well, then the linear dynamics of order {} ({words}), trained output-error",
                        ctx.fit.input_names.get(j).map_or("?", String::as_str),
                        p.order
                    ),
                });
            }
        }
        out
    }
    /// The half-width is searched on the fit block (on one training record
    /// longer than the policy's `nonlinear_fit_samples`, on that many
    /// leading samples); a fold of cross-validation refits at the chosen
    /// half-width only, as the current model's order and delay are kept.
    fn fit_choosing(
        &self,
        p: &Proposal,
        ctx: &Context,
    ) -> Result<(FittedModel, Option<usize>), DiagnoseError> {
        let bad = || DiagnoseError::InvalidArgument("backlash: not a backlash proposal".into());
        let io = p.lineage.io().ok_or_else(bad)?;
        let j = input_of(p).ok_or_else(bad)?;
        let found = super::on_leading(ctx, ctx.policy().nonlinear_fit_samples, |c| {
            match ctx.start_choice {
                Some(k) => {
                    let delay = alternatives(io).get(k / PER_DELAY)?.clone();
                    let at = IoNetworkParams {
                        delay,
                        ..io.clone()
                    };
                    half_width_of(k)
                        .and_then(|r| Self::fit_at(&at, j, r, c))
                        .map(|(_, m)| (k, m))
                }
                None if c.plan.cv() => match ctx.rival_of {
                    Some((_, Some(k))) => Self::search_fine(io, j, c, k),
                    _ => Self::search(io, j, c),
                }
                .map(|(k, _, m)| (k, m)),
                None => Self::search_delays(io, j, c),
            }
        });
        found.map(|(k, m)| (m, Some(k))).ok_or_else(|| {
            DiagnoseError::Core(gb_core::CoreError::Unstable(
                "backlash: no half-width could be fitted".into(),
            ))
        })
    }
    /// The fitted half-width goes into the lineage: later steps (an order
    /// increase) keep this play, not the grid.
    fn rescore(&self, _ctx: &Context, c: &mut Evaluated) -> Result<(), DiagnoseError> {
        let at = fitted_plays(&c.model);
        let nk = fitted_delays(&c.model);
        if let (Lineage::Io(p), Some(at)) = (&mut c.lineage, at) {
            p.input_play_at = Some(at);
            if let Some(nk) = nk.filter(|k| k.len() == p.delay.len()) {
                p.delay = nk;
            }
        }
        Ok(())
    }
    fn delay_rivals_key(&self, p: &Proposal) -> Option<String> {
        super::delay_free_key(&p.lineage)
    }
    /// A rival delay searches the fine steps around the half-width found at
    /// the current delay ([`Backlash::search_fine`]): a play's width hardly
    /// moves with a one-sample shift, and the coarse scan is half its cost.
    fn starts_from_rival(&self) -> bool {
        true
    }
    fn evidence(&self, _p: &Proposal, ctx: &Context) -> String {
        ctx.evidence.hysteresis_text()
    }
    fn row_text(&self, p: &Proposal, fitted: &FittedModel) -> String {
        let r = fitted_plays(fitted)
            .and_then(|at| at.into_iter().flatten().next())
            .map_or(String::new(), |r| {
                format!(" -> half-width {r:.3} standard deviations of the input")
            });
        let nk = fitted_delays(fitted)
            .filter(|_| !r.is_empty())
            .map_or(String::new(), |k| {
                format!(", input delay {}", super::slash_list(&k))
            });
        format!("{}{r}{nk}", p.text)
    }
    fn input(&self, p: &Proposal, ctx: &Context) -> Option<String> {
        input_of(p).and_then(|j| ctx.fit.input_names.get(j).cloned())
    }
}

/// The input dead times of a fitted input–output network.
fn fitted_delays(m: &FittedModel) -> Option<Vec<usize>> {
    core(m)
        .as_any()
        .downcast_ref::<LocalModelNetwork>()
        .map(|n| n.spec.nk.clone())
}

/// The input play thresholds of a fitted input–output network.
fn fitted_plays(m: &FittedModel) -> Option<Vec<Vec<f64>>> {
    core(m)
        .as_any()
        .downcast_ref::<LocalModelNetwork>()
        .map(|n| n.spec.input_play.clone())
}
