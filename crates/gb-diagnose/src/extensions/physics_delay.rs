//! `dynamics` in the timing of the engineer's model: an input delay,
//! estimated with every physical parameter.
use crate::evaluate::Lineage;
use crate::extension::{Context, Extension, Proposal};
use crate::physics::physics_row_text;
use crate::physics::{current_physics, fit_physics, physics_fit_record, physics_of};
use crate::{Cause, DiagnoseError};
use gb_core::{DynamicModel, FittedModel, Init};
use gb_model::physics::{Parameter, PhysicsModel};

/// An input delay `d` for a physics model without one: the held input
/// `u_j` acts on `[t_j + d, t_{j+1} + d)` (a dead time for `d > 0`; for
/// `−Ts < d < 0` the output is sampled after the input acted, as when a
/// hold is centred on the sample instant or the output is read late in the
/// sample). `d` is a new free parameter in `[−Ts, max(10, L + 2)·Ts]`,
/// started at the lag `L` (in samples, to a fraction by a parabola through
/// the peak) that maximises the cross-correlation of the measured output
/// with the current model's simulation on the fit record: `y_k ≈ ŷ_{k−L}`.
/// The fit holds `d` at that start while the other parameters adapt, then
/// frees it (gb-model's `identify_growing`). Proposed at every step until
/// the model has a delay: a timing error can hide behind a larger misfit
/// (the Bouc–Wen benchmark from a linear model: the delay pays only once
/// the hysteresis is in).
pub struct PhysicsInputDelay;

/// The marker of the extension in a lineage spec.
const MARKER: &str = " + input delay";

/// The lag `L` (samples, fractional) in `lo..=hi` that maximises
/// `Σ_k (y_k − ȳ)(ŷ_{k−L} − m)`, refined by a parabola through the peak.
fn xcorr_lag(y: &[f64], sim: &[f64], lo: i64, hi: i64) -> Option<f64> {
    let n = y.len().min(sim.len());
    if n < 4 * (hi - lo).unsigned_abs() as usize + 8 {
        return None;
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let (my, ms) = (mean(&y[..n]), mean(&sim[..n]));
    let corr = |lag: i64| -> f64 {
        let (mut s, mut c) = (0.0, 0usize);
        for k in 0..n as i64 {
            let j = k - lag;
            if j >= 0 && (j as usize) < n {
                s += (y[k as usize] - my) * (sim[j as usize] - ms);
                c += 1;
            }
        }
        s / c.max(1) as f64
    };
    let c: Vec<f64> = (lo - 1..=hi + 1).map(corr).collect();
    let (best, _) = c[1..c.len() - 1]
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))?;
    let i = best + 1;
    let (a, b, d) = (c[i - 1], c[i], c[i + 1]);
    let den = a - 2.0 * b + d;
    let frac = if den < 0.0 {
        (0.5 * (a - d) / den).clamp(-0.5, 0.5)
    } else {
        0.0
    };
    Some((lo + best as i64) as f64 + frac)
}

/// A parameter name for the delay not yet used in the model.
fn delay_name(m: &PhysicsModel) -> String {
    let used = |n: &str| {
        let s = m.spec();
        s.parameters.iter().any(|p| p.name == n)
            || s.states.iter().any(|x| x.name == n)
            || s.inputs.iter().any(|x| x == n)
    };
    let mut name = "t_delay".to_string();
    while used(&name) {
        name.push('_');
    }
    name
}

impl Extension for PhysicsInputDelay {
    fn name(&self) -> &'static str {
        "physics-input-delay"
    }
    fn cause(&self) -> Cause {
        Cause::Dynamics
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        let Some((m, base)) = current_physics(ctx) else {
            return vec![];
        };
        if m.spec().input_delay.is_some() || base.contains(MARKER) || m.spec().inputs.is_empty() {
            return vec![];
        }
        vec![Proposal {
            cause: Cause::Dynamics,
            lineage: Lineage::Other {
                spec: format!("{base}{MARKER}"),
                order: m.spec().states.len(),
            },
            text: format!(
                "an input delay {} (estimated, started at the lag of the peak cross-correlation of measured and simulated output) in the model '{}', every parameter refitted",
                delay_name(m),
                m.spec().name
            ),
        }]
    }
    fn fit(&self, _p: &Proposal, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
        let bad = |m: &str| DiagnoseError::InvalidArgument(format!("physics-input-delay: {m}"));
        let core =
            |e: gb_model::physics::PhysicsError| DiagnoseError::from(gb_core::CoreError::from(e));
        let cur = physics_of(&ctx.current.model).ok_or_else(|| bad("not a physics model"))?;
        let ts = cur.sample_time().map_err(core)?;
        let rec = physics_fit_record(ctx, cur);
        let sim = match ctx.simulated_fit {
            Some(s) if s.len() == rec.len() => s.to_vec(),
            _ => cur.simulate(&rec.inputs, Init::Stored)?,
        };
        let lag = xcorr_lag(&rec.output, &sim, -1, 10).unwrap_or(0.0);
        let (lo, hi) = (-ts, (lag + 2.0).max(10.0) * ts);
        let name = delay_name(cur);
        let mut spec = cur.with_start_at_values().map_err(core)?.spec().clone();
        spec.parameters
            .push(Parameter::new(&name, (lag * ts).clamp(lo, hi)).bounds(lo, hi));
        spec.input_delay = Some(name);
        fit_physics(&spec, &rec, ctx.observer)
    }
    fn evidence(&self, _p: &Proposal, ctx: &Context) -> String {
        ctx.evidence.dynamics_text()
    }
    fn row_text(&self, p: &Proposal, fitted: &FittedModel) -> String {
        physics_row_text(p, fitted)
    }
}

#[cfg(test)]
mod tests {
    use super::xcorr_lag;

    /// A smooth signal delayed by 2.3 samples is found at lag 2.3 (to the
    /// parabola's accuracy), and one advanced by half a sample at −0.5.
    #[test]
    fn the_cross_correlation_peak_gives_the_fractional_lag() {
        let x = |t: f64| (0.05 * t).sin() + 0.5 * (0.013 * t + 1.0).sin();
        let sim: Vec<f64> = (0..4000).map(|k| x(k as f64)).collect();
        for lag in [2.3, -0.5, 0.0, 7.0] {
            let y: Vec<f64> = (0..4000).map(|k| x(k as f64 - lag)).collect();
            let got = xcorr_lag(&y, &sim, -1, 10).unwrap();
            assert!((got - lag).abs() < 0.1, "lag {lag}: got {got}");
        }
    }
}
