//! 95 % prediction bands: the parameter uncertainty propagated by sampling
//! the fitted covariance (fixed seed) through the simulation, plus the
//! measurement noise.
use super::error::{PhysicsError, PhysicsResult};
use super::fit::Coordinate;
use super::model::PhysicsModel;
use gb_core::{CoreError, FittedModel, Init};
use nalgebra::{DMatrix, SymmetricEigen};
use rand_distr::{Distribution, StandardNormal};

/// Prediction bands of the first output.
#[derive(Debug, Clone, PartialEq)]
pub struct Bands {
    /// Lower 95 % limit per sample.
    pub lo: Vec<f64>,
    /// Upper 95 % limit per sample.
    pub hi: Vec<f64>,
    /// Parameter draws that simulated.
    pub draws: usize,
    /// Parameter draws whose simulation diverged (left out).
    pub failed: usize,
}

/// Settings of [`PhysicsModel::prediction_bands`].
///
/// | setting | default | meaning |
/// |---|---|---|
/// | `draws` | 200 | parameter vectors drawn from `N(θ̂, Cov)` |
/// | `seed` | 17 | seed of the draws (`gb_core::rng::seeded`) |
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BandParams {
    /// Parameter draws.
    pub draws: usize,
    /// Seed.
    pub seed: u64,
}

impl Default for BandParams {
    fn default() -> Self {
        Self {
            draws: 200,
            seed: 17,
        }
    }
}

impl PhysicsModel {
    /// 95 % prediction bands of the first output on inputs `u`, starting as
    /// `init` says (the initial state is resolved once with the fitted
    /// parameters). Each draw `θ_s ~ N(θ̂, Cov)` of the free parameters
    /// (clamped to their bounds) is simulated; per sample the band is
    /// `m ± 1.96 √(s² + σ²)` with the mean `m` and variance `s²` over the
    /// draws and the noise standard deviation σ.
    pub fn prediction_bands(
        &self,
        u: &[Vec<f64>],
        init: Init<'_>,
        noise_sd: f64,
        p: BandParams,
    ) -> PhysicsResult<Bands> {
        let fit = self.fit_report().ok_or_else(|| {
            PhysicsError::Data("prediction bands need a fitted model (its covariance)".into())
        })?;
        let us: Vec<&[f64]> = u.iter().map(Vec::as_slice).collect();
        let len = u.first().map_or(0, Vec::len);
        let ny = self.spec().outputs.len();
        let x0 = match init {
            Init::Periodic { .. } => {
                return Err(PhysicsError::Data(
                    "prediction bands start from a state, not a periodic steady state".into(),
                ))
            }
            i => self.resolve_init(&us, i)?,
        };
        // the parameters' block of the covariance and its square root
        let idx: Vec<(usize, usize)> = fit
            .free
            .iter()
            .enumerate()
            .filter_map(|(k, c)| match *c {
                Coordinate::Parameter(i) => Some((k, i)),
                _ => None,
            })
            .collect();
        let m = idx.len();
        let mut cov = DMatrix::zeros(m, m);
        for (a, &(ka, _)) in idx.iter().enumerate() {
            for (b, &(kb, _)) in idx.iter().enumerate() {
                let v = fit.cov(ka, kb);
                cov[(a, b)] = if v.is_finite() { v } else { 0.0 };
            }
        }
        let eig = SymmetricEigen::new(cov);
        let mut root = eig.eigenvectors.clone();
        for (j, lam) in eig.eigenvalues.iter().enumerate() {
            let s = lam.max(0.0).sqrt();
            root.column_mut(j).scale_mut(s);
        }
        let mut rng = gb_core::rng::seeded(p.seed);
        let (mut mean, mut m2) = (vec![0.0; len], vec![0.0; len]);
        let mut y = vec![0.0; ny * len];
        let (mut ok, mut failed) = (0usize, 0usize);
        let spec = self.spec();
        for _ in 0..p.draws {
            let z: Vec<f64> = (0..m).map(|_| StandardNormal.sample(&mut rng)).collect();
            let mut theta = self.parameters().to_vec();
            for (a, &(_, i)) in idx.iter().enumerate() {
                let d: f64 = (0..m).map(|b| root[(a, b)] * z[b]).sum();
                let pr = &spec.parameters[i];
                theta[i] = (theta[i] + d).clamp(pr.lower, pr.upper);
            }
            if self.run(&theta, &x0, &us, &mut y).is_err() {
                failed += 1;
                continue;
            }
            ok += 1;
            // Welford's running mean and variance
            for t in 0..len {
                let delta = y[t] - mean[t];
                mean[t] += delta / ok as f64;
                m2[t] += delta * (y[t] - mean[t]);
            }
        }
        if ok < 2 || failed > p.draws / 2 {
            return Err(PhysicsError::Numerical(format!(
                "{failed} of {} parameter draws diverged: the covariance is too wide for bands",
                p.draws
            )));
        }
        let z = 1.959_963_984_540_054;
        let s2n = noise_sd * noise_sd;
        let half: Vec<f64> = m2
            .iter()
            .map(|v| z * (v / (ok - 1) as f64 + s2n).sqrt())
            .collect();
        Ok(Bands {
            lo: mean.iter().zip(&half).map(|(m, h)| m - h).collect(),
            hi: mean.iter().zip(&half).map(|(m, h)| m + h).collect(),
            draws: ok,
            failed,
        })
    }
}

/// Prediction bands of a fitted model of the physics class (its noise
/// model gives σ); an error naming the class for any other.
pub fn prediction_bands(
    model: &FittedModel,
    u: &[Vec<f64>],
    init: Init<'_>,
    p: BandParams,
) -> Result<Bands, CoreError> {
    let m = model
        .dynamics
        .as_any()
        .downcast_ref::<PhysicsModel>()
        .ok_or_else(|| {
            CoreError::Unsupported(format!(
                "prediction bands need a model with a parameter covariance (class 'physics', fitted with --model-file); this model is of class '{}'",
                model.dynamics.class()
            ))
        })?;
    Ok(m.prediction_bands(u, init, model.noise.sd(), p)?)
}
