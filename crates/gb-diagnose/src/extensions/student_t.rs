//! `noise`: a Student-t noise model with a robust (IRLS) output-error fit.
use crate::curves::qq;
use crate::evaluate::{Evaluated, Lineage, Residuals};
use crate::extension::{Context, Extension, GainMetric, Proposal};
use crate::report::NoiseFound;
use crate::{Cause, DiagnoseError};
use gb_core::{FittedModel, ModelView, Series, ViewData};

/// Whether the fitted noise law is itself heavy-tailed by the measure that
/// proposed it: a Student-t's excess kurtosis `6/(ν − 4)` (infinite for
/// ν ≤ 4) above `kurtosis`, i.e. ν < 4 + 6/kurtosis (16 at the default
/// 0.5). Under cross-validation the pooled held-out residuals of the folds'
/// refits can be heavy-tailed where the noise is not (a fold that fits a
/// sweep's band less well); the fit on the training record then ends near
/// the Gaussian (ν at its upper bound) and names no noise.
///
/// ```text
/// ν = 3   → ∞ (heavy)      ν = 10 → 1.0 (heavy)      ν = 100 → 0.06 (Gaussian)
/// ```
fn fitted_tails_heavy(noise: &gb_core::NoiseModel, kurtosis: f64) -> bool {
    match noise {
        gb_core::NoiseModel::StudentT { nu, .. } => *nu <= 4.0 || 6.0 / (nu - 4.0) > kurtosis,
        _ => true,
    }
}

/// Model the noise as Student-t and fit robustly. Counts only when the
/// residual is heavy-tailed and the fit does not lose simulation accuracy.
pub struct StudentTNoise;

impl Extension for StudentTNoise {
    fn name(&self) -> &'static str {
        "student-t-noise"
    }
    fn cause(&self) -> Cause {
        Cause::Noise
    }
    fn metric(&self) -> GainMetric {
        GainMetric::Nll
    }
    fn once(&self) -> bool {
        true
    }
    fn propose(&self, ctx: &Context) -> Vec<Proposal> {
        match ctx.current.lineage.io() {
            Some(p) if !p.robust => vec![Proposal {
                cause: Cause::Noise,
                lineage: Lineage::Io(gb_lmn::IoNetworkParams {
                    robust: true,
                    ..p.clone()
                }),
                text: "Student-t noise model, robust (IRLS) output-error fit".into(),
            }],
            _ => vec![],
        }
    }
    fn fit(&self, p: &Proposal, ctx: &Context) -> Result<FittedModel, DiagnoseError> {
        super::fit_io(p.lineage.io().expect("an input-output proposal"), ctx)
    }
    /// Heavy tails (Jarque–Bera rejects and the excess kurtosis is large),
    /// in the decision residual and in the fitted noise law (see
    /// [`fitted_tails_heavy`]), and the simulation no worse than the
    /// policy's tolerance.
    fn admits(&self, ctx: &Context, c: &Evaluated) -> bool {
        let pol = ctx.policy();
        let n = ctx.evidence.normality;
        let heavy = n.3 < pol.heavy_tail_p && n.1 > pol.heavy_tail_kurtosis;
        heavy
            && fitted_tails_heavy(&c.model.noise, pol.heavy_tail_kurtosis)
            && c.scores.nrmse_select <= ctx.current.scores.nrmse_select * pol.noise_nrmse_tolerance
    }
    /// The noise found: white, heavy-tailed measurement noise.
    fn rescore(&self, _ctx: &Context, c: &mut Evaluated) -> Result<(), DiagnoseError> {
        c.finding = Some(NoiseFound {
            kind: "measurement".into(),
            text: format!(
                "measurement noise (white, heavy-tailed): {}",
                c.model.noise.describe()
            ),
            prediction: vec![],
        });
        Ok(())
    }
    fn evidence(&self, _p: &Proposal, ctx: &Context) -> String {
        ctx.evidence.noise_text()
    }
    fn evidence_view(&self, b: &Residuals, _a: &Residuals, _output: &str) -> Option<ModelView> {
        let (q, line) = qq(&b.e);
        Some(ModelView {
            key: "noise".into(),
            title: "Normal Q-Q plot of the residual: bent tails are heavy-tailed noise".into(),
            caption: String::new(),
            data: ViewData::Curves {
                x_label: "normal quantile".into(),
                y_label: "standardised residual".into(),
                series: vec![
                    Series {
                        name: "residual".into(),
                        points: q,
                        markers: true,
                    },
                    Series {
                        name: "normal".into(),
                        points: line,
                        markers: false,
                    },
                ],
                log_y: false,
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::fitted_tails_heavy;
    use gb_core::NoiseModel;

    /// ν at the fit's upper bound is a Gaussian, ν = 3 or 10 is heavy; the
    /// border follows the kurtosis level (ν = 16 at 0.5, 10 at 1).
    #[test]
    fn fitted_student_t_is_heavy_only_below_the_kurtosis_border() {
        let t = |nu| NoiseModel::StudentT { nu, scale: 1.0 };
        assert!(fitted_tails_heavy(&t(3.0), 0.5));
        assert!(fitted_tails_heavy(&t(10.0), 0.5));
        assert!(fitted_tails_heavy(&t(15.9), 0.5));
        assert!(!fitted_tails_heavy(&t(16.1), 0.5));
        assert!(!fitted_tails_heavy(&t(100.0), 0.5));
        assert!(!fitted_tails_heavy(&t(10.5), 1.0));
        assert!(fitted_tails_heavy(&NoiseModel::Gaussian { sd: 1.0 }, 0.5));
    }
}
