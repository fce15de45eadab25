use crate::{LmnError, NetworkSpec, Scaling};
use gb_core::gram::dot;
use gb_core::NoiseModel;
use gb_preisach::PlayOperatorBank;
use serde::{Deserialize, Serialize};

/// One local model: a hyper-rectangle of the (unit-scaled) partition space,
/// its Gaussian validity function μ(z) = exp(−½ Σ_d ((z_d − c_d)/σ_d)²) and
/// its affine parameters θ over [1, x_dyn].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Leaf {
    /// Lower corner of the cell (unit-scaled partition coordinates).
    pub lower: Vec<f64>,
    /// Upper corner of the cell.
    pub upper: Vec<f64>,
    /// Local model parameters [offset, weights of x_dyn…].
    pub theta: Vec<f64>,
}

/// Width of the validity functions relative to the cell extent (Nelles: 1/3…1/2).
pub(crate) const K_SIGMA: f64 = 0.4;

impl Leaf {
    pub(crate) fn center(&self, d: usize) -> f64 {
        0.5 * (self.lower[d] + self.upper[d])
    }
    pub(crate) fn sigma(&self, d: usize) -> f64 {
        (K_SIGMA * (self.upper[d] - self.lower[d])).max(1e-6)
    }
}

/// A local model network in normalised signal units, with its scalings, so
/// that it simulates physical signals directly. One leaf = a linear model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LocalModelNetwork {
    /// Dynamic structure.
    pub spec: NetworkSpec,
    /// Normalisation of each input.
    pub input_scaling: Vec<Scaling>,
    /// Normalisation of the output.
    pub output_scaling: Scaling,
    /// Lower bounds of the partition variables (normalised signal units).
    pub z_lower: Vec<f64>,
    /// Upper bounds of the partition variables.
    pub z_upper: Vec<f64>,
    /// Local models.
    pub leaves: Vec<Leaf>,
    /// Weights of the global hysteresis columns.
    pub beta: Vec<f64>,
    /// Indices into x_dyn of the partition variables.
    pub z_index: Vec<usize>,
    /// Residual (noise) model fitted on the training residuals, in physical units.
    pub noise: NoiseModel,
}

/// Scratch space for network evaluation (no allocation per time step).
#[derive(Debug, Clone, Default)]
pub struct EvalScratch {
    pub(crate) z: Vec<f64>,
    pub(crate) phi: Vec<f64>,
    pub(crate) local: Vec<f64>,
    pub(crate) g: Vec<f64>,
}

impl LocalModelNetwork {
    /// Number of parameters: leaves × (1 + n_dyn) + n_hysteresis.
    pub fn n_parameters(&self) -> usize {
        self.leaves.len() * (1 + self.spec.n_dynamic()) + self.beta.len()
    }

    /// Number of local models.
    pub fn n_leaves(&self) -> usize {
        self.leaves.len()
    }

    pub(crate) fn scratch(&self) -> EvalScratch {
        let nz = self.z_lower.len();
        let m = self.leaves.len();
        EvalScratch {
            z: vec![0.0; nz],
            phi: vec![if m == 1 { 1.0 } else { 0.0 }; m],
            local: vec![0.0; m],
            g: vec![0.0; m * nz.max(1)],
        }
    }

    /// Flattened parameter vector [θ₁ … θ_M, β].
    pub fn parameters(&self) -> Vec<f64> {
        let mut p: Vec<f64> = self
            .leaves
            .iter()
            .flat_map(|l| l.theta.iter().copied())
            .collect();
        p.extend_from_slice(&self.beta);
        p
    }

    /// Set parameters from a flattened vector (see [`parameters`](Self::parameters)).
    pub fn set_parameters(&mut self, p: &[f64]) {
        let w = 1 + self.spec.n_dynamic();
        for (i, l) in self.leaves.iter_mut().enumerate() {
            l.theta.copy_from_slice(&p[i * w..(i + 1) * w]);
        }
        let nb = self.beta.len();
        self.beta.copy_from_slice(&p[p.len() - nb..]);
    }

    /// Normalised validity functions Φᵢ(z) = μᵢ / Σ μ_l at unit-scaled z (in `s.phi`).
    #[inline]
    pub(crate) fn validity(&self, s: &mut EvalScratch) {
        let m = self.leaves.len();
        if m == 1 {
            s.phi[0] = 1.0;
            return;
        }
        let nz = s.z.len();
        let mut maxl = f64::NEG_INFINITY;
        for (i, leaf) in self.leaves.iter().enumerate() {
            let mut q = 0.0;
            for d in 0..nz {
                let sd = leaf.sigma(d);
                let t = (s.z[d] - leaf.center(d)) / sd;
                q += t * t;
                s.g[i * nz + d] = -(s.z[d] - leaf.center(d)) / (sd * sd);
            }
            s.phi[i] = -0.5 * q;
            maxl = maxl.max(s.phi[i]);
        }
        let mut sum = 0.0;
        for v in s.phi.iter_mut() {
            *v = (*v - maxl).exp();
            sum += *v;
        }
        for v in s.phi.iter_mut() {
            *v /= sum;
        }
    }

    /// Map the partition variables of `x` to unit-scaled z (in `s.z`).
    #[inline]
    pub(crate) fn fill_z(&self, x: &[f64], s: &mut EvalScratch) {
        for (d, &i) in self.z_index.iter().enumerate() {
            let w = (self.z_upper[d] - self.z_lower[d]).max(1e-12);
            s.z[d] = (x[i] - self.z_lower[d]) / w;
        }
    }

    /// Evaluate ŷ (normalised) for regressor x = [x_dyn, h]. If `grad_theta`
    /// is given it receives ∂ŷ/∂θ (length n_parameters); if `grad_x` is given
    /// it receives ∂ŷ/∂x (length n_dyn + n_hyst), including the derivative of
    /// the validity functions:
    ///
    /// ∂Φᵢ/∂z_d = Φᵢ (g_id − Σ_l Φ_l g_ld),  g_id = −(z_d − c_id)/σ_id².
    pub(crate) fn eval(
        &self,
        x: &[f64],
        s: &mut EvalScratch,
        grad_theta: Option<&mut [f64]>,
        grad_x: Option<&mut [f64]>,
    ) -> f64 {
        let nd = self.spec.n_dynamic();
        let m = self.leaves.len();
        if m > 1 {
            self.fill_z(x, s);
            self.validity(s);
        }
        let mut y = 0.0;
        for (i, leaf) in self.leaves.iter().enumerate() {
            let th = &leaf.theta;
            let l = th[0] + dot(&th[1..], &x[..nd]);
            s.local[i] = l;
            y += s.phi[i] * l;
        }
        y += dot(&self.beta, &x[nd..]);
        if let Some(gt) = grad_theta {
            let w = nd + 1;
            for i in 0..m {
                let p = s.phi[i];
                gt[i * w] = p;
                for j in 0..nd {
                    gt[i * w + 1 + j] = p * x[j];
                }
            }
            let off = m * w;
            gt[off..off + self.beta.len()].copy_from_slice(&x[nd..nd + self.beta.len()]);
        }
        if let Some(gx) = grad_x {
            for j in 0..nd {
                let mut v = 0.0;
                for i in 0..m {
                    v += s.phi[i] * self.leaves[i].theta[j + 1];
                }
                gx[j] = v;
            }
            for (g, b) in gx[nd..].iter_mut().zip(&self.beta) {
                *g = *b;
            }
            if m > 1 {
                let nz = s.z.len();
                for (d, &xi) in self.z_index.iter().enumerate() {
                    let mut gbar = 0.0;
                    for i in 0..m {
                        gbar += s.phi[i] * s.g[i * nz + d];
                    }
                    let mut v = 0.0;
                    for i in 0..m {
                        v += s.phi[i] * (s.g[i * nz + d] - gbar) * s.local[i];
                    }
                    let w = (self.z_upper[d] - self.z_lower[d]).max(1e-12);
                    gx[xi] += v / w;
                }
            }
        }
        y
    }

    /// Input play banks (normalised thresholds), one per input.
    pub(crate) fn input_banks(&self) -> Result<Vec<Option<PlayOperatorBank>>, LmnError> {
        self.spec
            .input_play
            .iter()
            .map(|t| {
                if t.is_empty() {
                    Ok(None)
                } else {
                    PlayOperatorBank::new(t.clone())
                        .map(Some)
                        .map_err(|e| LmnError::InvalidArgument(e.to_string()))
                }
            })
            .collect()
    }

    /// Output play bank (normalised thresholds), if any.
    pub(crate) fn output_bank(&self) -> Result<Option<PlayOperatorBank>, LmnError> {
        if self.spec.output_play.is_empty() {
            Ok(None)
        } else {
            PlayOperatorBank::new(self.spec.output_play.clone())
                .map(Some)
                .map_err(|e| LmnError::InvalidArgument(e.to_string()))
        }
    }

    /// Per output lag i (index i−1), the summed weights of the output play
    /// columns that act like an extra ŷ(k−i) term while the operators move.
    pub(crate) fn output_play_shifts(&self) -> Vec<f64> {
        let na = self.spec.na;
        let nop = self.spec.output_play.len();
        let b = self.spec.output_block();
        let mut v = vec![0.0; na];
        for l in 0..self.spec.hysteresis_lags {
            if l < na {
                v[l] = self.beta[l * b..l * b + nop].iter().sum();
            }
        }
        v
    }

    /// Preisach cells (a relay grid) on the output, if any.
    pub(crate) fn relay_cells(&self) -> Option<gb_preisach::RelayCells> {
        (self.spec.output_relays > 0)
            .then(|| {
                gb_preisach::RelayCells::uniform(self.spec.output_relays, 2.5, self.spec.relay_sub)
                    .ok()
            })
            .flatten()
    }

    /// Spectral radius of each leaf's autoregressive part, without and with all
    /// output-play columns moving (they then act like an extra ŷ(k−1) weight).
    pub fn max_spectral_radius(&self) -> f64 {
        let na = self.spec.na;
        if na == 0 {
            return 0.0;
        }
        let shifts = self.output_play_shifts();
        let mut worst: f64 = 0.0;
        for leaf in &self.leaves {
            let a: Vec<f64> = leaf.theta[1..=na].to_vec();
            worst = worst.max(spectral_radius(&a));
            if shifts.iter().any(|v| *v != 0.0) {
                let mut a2 = a.clone();
                for (ai, s) in a2.iter_mut().zip(&shifts) {
                    *ai += s;
                }
                worst = worst.max(spectral_radius(&a2));
            }
        }
        worst
    }

    /// One-line description.
    pub fn describe(&self) -> String {
        format!(
            "{}, {} noise",
            self.describe_structure(),
            self.noise.describe()
        )
    }

    /// The description without the noise model.
    pub fn describe_structure(&self) -> String {
        let nb: Vec<String> = self.spec.nb.iter().map(|b| b.to_string()).collect();
        let mut lags = format!("nb={}", nb.join("/"));
        if self.spec.nk.iter().any(|&k| k != 1) {
            let nk: Vec<String> = self.spec.nk.iter().map(|k| k.to_string()).collect();
            lags.push_str(&format!(", nk={}", nk.join("/")));
        }
        let core = if self.leaves.len() == 1 {
            format!("linear output-error, order {} ({lags})", self.spec.na)
        } else {
            format!(
                "local model network, {} local linear models, order {} ({lags})",
                self.leaves.len(),
                self.spec.na
            )
        };
        let sp = &self.spec;
        let ni: usize = sp.input_play.iter().map(Vec::len).sum();
        let mut hyst = String::new();
        if sp.n_ramps() > 0 {
            hyst.push_str(&format!(
                " + feedback map of the output ({} intervals, at lags 1..{})",
                sp.n_ramps(),
                sp.hysteresis_lags
            ));
        }
        if sp.output_play.len() + sp.n_relays() + ni > 0 {
            hyst.push_str(&format!(
                " + Preisach component ({} play operators and {} Preisach cells{} on the output, {} play operators on the inputs, at lags 1..{})",
                sp.output_play.len(),
                sp.n_relays(),
                if sp.relay_sub > 1 && sp.n_relays() > 0 {
                    format!(" of {}x{} relays", sp.relay_sub, sp.relay_sub)
                } else {
                    String::new()
                },
                ni,
                sp.hysteresis_lags
            ));
        }
        format!("{core}{hyst}")
    }
}

/// Spectral radius of the AR polynomial z^n − a₁ z^{n−1} − … − a_n
/// (companion-matrix eigenvalues).
pub fn spectral_radius(a: &[f64]) -> f64 {
    let n = a.len();
    if n == 0 {
        return 0.0;
    }
    if n == 1 {
        return a[0].abs();
    }
    let mut c = nalgebra::DMatrix::<f64>::zeros(n, n);
    for j in 0..n {
        c[(0, j)] = a[j];
    }
    for i in 1..n {
        c[(i, i - 1)] = 1.0;
    }
    c.complex_eigenvalues()
        .iter()
        .map(|z| z.norm())
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spectral_radius_of_known_polynomials() {
        // (z-0.5)(z-0.8) = z^2 - 1.3 z + 0.4  -> a = [1.3, -0.4]
        assert!((spectral_radius(&[1.3, -0.4]) - 0.8).abs() < 1e-12);
        // complex pair with radius 0.9: z^2 - 2 r cos(w) z + r^2
        let r: f64 = 0.9;
        let w: f64 = 0.3;
        assert!((spectral_radius(&[2.0 * r * w.cos(), -r * r]) - 0.9).abs() < 1e-12);
        assert!((spectral_radius(&[1.2]) - 1.2).abs() < 1e-15);
    }
}
