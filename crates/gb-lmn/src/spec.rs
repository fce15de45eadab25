use crate::LmnError;
use serde::{Deserialize, Serialize};

fn one() -> usize {
    1
}

/// Dynamic structure of a network: which delayed signals form the regressor
/// x(k), which of them span the partition space z(k), and optional hysteresis
/// (play-operator) columns.
///
/// x(k) = [ŷ(k−1), …, ŷ(k−n_a), u₁(k−d₁), …, u₁(k−d₁−n_{b,1}+1), …]
/// followed by the hysteresis columns
/// h(k) = [P_r(ŷ)(k−1) for r in output thresholds, P_r(u_j)(k−d_j) …].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NetworkSpec {
    /// Number of output lags n_a.
    pub na: usize,
    /// Number of lags per input n_{b,j}.
    pub nb: Vec<usize>,
    /// Dead time per input d_j (≥ 0; 1 = strictly proper).
    pub nk: Vec<usize>,
    /// Play-operator thresholds (normalised units) on the simulated output.
    pub output_play: Vec<f64>,
    /// Levels of a relay grid (discrete Preisach operator) on the simulated
    /// output over ±2.5 normalised units (0: none).
    #[serde(default)]
    pub output_relays: usize,
    /// Relays per cell side of that grid ([`gb_preisach::RelayCells`]: 1 =
    /// one hard relay per cell). Stored after the network in a model file
    /// of `io-network` version 2 (version 1: always 1).
    #[serde(skip, default = "one")]
    pub relay_sub: usize,
    /// Knots t₀ < … < t_M (normalised units) of a static map of the
    /// simulated output inside the loop: M ramp columns
    /// r_m(ŷ) = clamp((ŷ − t_m)/(t_{m+1} − t_m), 0, 1), a piecewise-linear
    /// g(ŷ) = Σ w_m r_m(ŷ), flat beyond the outer knots, fed back at the
    /// hysteresis lags (a Preisach
    /// density on the line α = β: no memory). Empty: none. Stored after the
    /// network in a model file of `io-network` version 2.
    #[serde(skip)]
    pub output_knots: Vec<f64>,
    /// Play-operator thresholds (normalised units) per input.
    pub input_play: Vec<Vec<f64>>,
    /// Lags of every hysteresis column (1: only the latest; n: lags 1..n, as
    /// a hysteretic force inside n-th order dynamics needs).
    #[serde(default = "one")]
    pub hysteresis_lags: usize,
    /// Indices into the dynamic part of x that span the partition space
    /// (empty: all of them).
    pub partition: Vec<usize>,
}

impl NetworkSpec {
    /// Linear structure of order `na` with `nb[j]` lags of input j, dead time 1.
    pub fn linear(na: usize, nb: &[usize]) -> Self {
        Self {
            na,
            nb: nb.to_vec(),
            nk: vec![1; nb.len()],
            output_play: vec![],
            output_relays: 0,
            relay_sub: 1,
            output_knots: vec![],
            input_play: vec![vec![]; nb.len()],
            hysteresis_lags: 1,
            partition: vec![],
        }
    }

    /// The usual output-error structure of order n for `n_inputs` inputs:
    /// n_a = n, n_b = n per input, dead time 1.
    pub fn order(n: usize, n_inputs: usize) -> Self {
        Self::linear(n, &vec![n; n_inputs])
    }

    /// Validate against `n_inputs` input signals.
    pub fn check(&self, n_inputs: usize) -> Result<(), LmnError> {
        if self.nb.len() != n_inputs
            || self.nk.len() != n_inputs
            || self.input_play.len() != n_inputs
        {
            return Err(LmnError::InvalidArgument(format!(
                "structure is for {} inputs, data has {n_inputs}",
                self.nb.len()
            )));
        }
        if self.na == 0 && self.nb.iter().all(|&b| b == 0) {
            return Err(LmnError::InvalidArgument(
                "structure has no regressors".into(),
            ));
        }
        if self.na > 64 || self.nb.iter().any(|&b| b > 64) {
            return Err(LmnError::InvalidArgument(
                "at most 64 lags per signal".into(),
            ));
        }
        let nd = self.n_dynamic();
        if let Some(&i) = self.partition.iter().find(|&&i| i >= nd) {
            return Err(LmnError::InvalidArgument(format!(
                "partition index {i} out of range (dynamic regressors: {nd})"
            )));
        }
        for r in self
            .output_play
            .iter()
            .chain(self.input_play.iter().flatten())
        {
            if !(r.is_finite() && *r >= 0.0) {
                return Err(LmnError::InvalidArgument(format!(
                    "play threshold {r} must be >= 0"
                )));
            }
        }
        if self.relay_sub == 0 || self.relay_sub > 64 {
            return Err(LmnError::InvalidArgument(format!(
                "relays per cell side must be in 1..=64, got {}",
                self.relay_sub
            )));
        }
        if self.output_knots.iter().any(|t| !t.is_finite())
            || self.output_knots.windows(2).any(|w| w[1] <= w[0])
            || self.output_knots.len() == 1
        {
            return Err(LmnError::InvalidArgument(
                "output map knots must be finite and increasing (none, or at least two)".into(),
            ));
        }
        Ok(())
    }

    /// Number of dynamic regressors (lags of outputs and inputs).
    pub fn n_dynamic(&self) -> usize {
        self.na + self.nb.iter().sum::<usize>()
    }

    /// Number of hysteresis columns.
    pub fn n_hysteresis(&self) -> usize {
        self.hysteresis_lags
            * (self.output_block() + self.input_play.iter().map(Vec::len).sum::<usize>())
    }

    /// Columns of one lag of the output-side block: the plays, the ramps of
    /// the output map, then the relay cells.
    pub fn output_block(&self) -> usize {
        self.output_play.len() + self.n_ramps() + self.n_relays()
    }

    /// Number of ramp columns of the output map (knots − 1).
    pub fn n_ramps(&self) -> usize {
        self.output_knots.len().saturating_sub(1)
    }

    /// Number of relay columns: levels·(levels+1)/2.
    pub fn n_relays(&self) -> usize {
        self.output_relays * (self.output_relays + 1) / 2
    }

    /// Largest delay: the number of initial samples a simulation needs.
    pub fn max_lag(&self) -> usize {
        let ul = self
            .nb
            .iter()
            .zip(&self.nk)
            .filter(|(b, _)| **b > 0)
            .map(|(b, k)| k + b - 1)
            .max()
            .unwrap_or(0);
        let l = self.hysteresis_lags.max(1);
        let uh = self
            .input_play
            .iter()
            .zip(&self.nk)
            .filter(|(p, _)| !p.is_empty())
            .map(|(_, k)| k + l - 1)
            .max()
            .unwrap_or(0);
        let oh = if self.output_block() > 0 { l } else { 0 };
        self.na.max(ul).max(uh).max(oh).max(1)
    }

    /// Indices of the partition space (all dynamic regressors if unset).
    pub fn partition_indices(&self) -> Vec<usize> {
        if self.partition.is_empty() {
            (0..self.n_dynamic()).collect()
        } else {
            self.partition.clone()
        }
    }

    /// Human-readable names of the dynamic regressors.
    pub fn regressor_names(&self, output: &str, inputs: &[String]) -> Vec<String> {
        let mut v: Vec<String> = (1..=self.na).map(|i| format!("{output}(k-{i})")).collect();
        for (j, name) in inputs.iter().enumerate() {
            for i in 0..self.nb[j] {
                v.push(format!("{name}(k-{})", self.nk[j] + i));
            }
        }
        v
    }
}
