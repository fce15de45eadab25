//! Particle filters: bootstrap, guided and auxiliary, with adaptive resampling.
//!
//! With normalised weights `W_{t-1}^i` and ancestors `a_i`, one step is
//!
//! ```text
//! x_t^i ~ q_t(· | x_{t-1}^{a_i}, y_t),
//! log w_t^i = log g_t(y_t | x_t^i) + log f_t(x_t^i | x_{t-1}^{a_i}) − log q_t(x_t^i | x_{t-1}^{a_i}, y_t)
//!            [− log η_t(x_{t-1}^{a_i}) for the auxiliary filter],
//! ```
//!
//! weights are exp-normalised with a max shift (`W ∝ exp(log w − max log w)`),
//! and the likelihood factor `p̂(y_t | y_{0:t-1}) = Σ_i W_{t-1}^i w_t^i` (or
//! `(1/N) Σ_i w_t^i` after resampling, times `Σ_i W_{t-1}^i η_t^i` for the APF)
//! multiplies into `p̂(y_{0:T-1})`, an unbiased estimate of the likelihood.
use crate::error::{Result, SmcError};
use crate::model::{Observations, StateSpaceModel, StateVector};
use crate::resampling::{resample_unchecked, Resampling};
use crate::rng::{domain, stream, SmcRng, CHUNK, PAR_MIN, PAR_MIN_LIGHT};
use rand::Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Which particle filter to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[non_exhaustive]
pub enum FilterKind {
    /// Bootstrap filter: propose from the transition `f_t`.
    #[default]
    Bootstrap,
    /// Guided filter: propose from the model's `q_t`.
    Guided,
    /// Auxiliary particle filter: resample with look-ahead weights `η_t`, propose from `q_t`.
    Auxiliary,
}

/// Particle filter settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FilterConfig {
    /// Number of particles `N ≥ 1`.
    pub n_particles: usize,
    /// Filter variant.
    pub kind: FilterKind,
    /// Resampling scheme.
    pub resampling: Resampling,
    /// Resample before step `t` when `ESS_{t-1} < ess_threshold · N`;
    /// `≥ 1` resamples at every step, `0` never.
    pub ess_threshold: f64,
    /// Seed of all random streams.
    pub seed: u64,
    /// Keep all particles, weights and ancestors (needed by the smoothers).
    pub store_history: bool,
    /// Use rayon over particle chunks (results do not depend on it).
    pub parallel: bool,
}

impl FilterConfig {
    /// Bootstrap filter with `n` particles, systematic resampling when ESS < N/2.
    pub fn new(n_particles: usize) -> Self {
        Self {
            n_particles,
            kind: FilterKind::Bootstrap,
            resampling: Resampling::Systematic,
            ess_threshold: 0.5,
            seed: 0,
            store_history: false,
            parallel: true,
        }
    }
    /// Sets the filter variant.
    pub fn kind(mut self, kind: FilterKind) -> Self {
        self.kind = kind;
        self
    }
    /// Sets the resampling scheme.
    pub fn resampling(mut self, r: Resampling) -> Self {
        self.resampling = r;
        self
    }
    /// Sets the ESS threshold (fraction of `N`).
    pub fn ess_threshold(mut self, x: f64) -> Self {
        self.ess_threshold = x;
        self
    }
    /// Sets the seed.
    pub fn seed(mut self, seed: u64) -> Self {
        self.seed = seed;
        self
    }
    /// Stores the history for smoothing.
    pub fn store_history(mut self, yes: bool) -> Self {
        self.store_history = yes;
        self
    }
    /// Enables or disables rayon.
    pub fn parallel(mut self, yes: bool) -> Self {
        self.parallel = yes;
        self
    }
    /// Validates the settings and builds the filter.
    pub fn build(self) -> Result<ParticleFilter> {
        ParticleFilter::new(self)
    }
}

/// All particles, normalised weights and ancestors of a filter run (time-major).
#[derive(Debug, Clone)]
pub struct FilterHistory<S> {
    /// Particles per step `N`.
    pub n: usize,
    /// States, `states[t * N + i]`.
    pub states: Vec<S>,
    /// Normalised filtering weights `W_t^i`, `weights[t * N + i]`.
    pub weights: Vec<f64>,
    /// Ancestor of particle `i` at `t` among the particles at `t − 1`
    /// (`ancestors[t * N + i]`; identity at `t = 0`).
    pub ancestors: Vec<usize>,
}

impl<S> FilterHistory<S> {
    /// Number of stored time steps.
    pub fn len(&self) -> usize {
        self.weights.len().checked_div(self.n).unwrap_or(0)
    }
    /// `true` when nothing is stored.
    pub fn is_empty(&self) -> bool {
        self.weights.is_empty()
    }
    /// Particles at step `t`.
    pub fn states_at(&self, t: usize) -> &[S] {
        &self.states[t * self.n..(t + 1) * self.n]
    }
    /// Normalised weights at step `t`.
    pub fn weights_at(&self, t: usize) -> &[f64] {
        &self.weights[t * self.n..(t + 1) * self.n]
    }
    /// Ancestors of the particles at step `t`.
    pub fn ancestors_at(&self, t: usize) -> &[usize] {
        &self.ancestors[t * self.n..(t + 1) * self.n]
    }
}

/// Result of a filter run.
#[derive(Debug, Clone)]
pub struct FilterOutput<S> {
    /// `log p̂(y_{0:T-1})`; `p̂` is unbiased on the natural scale.
    pub log_likelihood: f64,
    /// `log p̂(y_t | y_{0:t-1})` per step.
    pub log_likelihood_increments: Vec<f64>,
    /// ESS of the filtering weights per step.
    pub ess: Vec<f64>,
    /// Whether resampling happened before step `t`.
    pub resampled: Vec<bool>,
    /// Stored history (with `store_history`).
    pub history: Option<FilterHistory<S>>,
}

/// What an observer of a filter run sees at each step.
#[derive(Debug)]
pub struct FilterStep<'a, S> {
    /// Time step.
    pub t: usize,
    /// Particles `x_t^i`.
    pub particles: &'a [S],
    /// Normalised weights `W_t^i`.
    pub weights: &'a [f64],
    /// Ancestors `a_t^i` (identity at `t = 0` or without resampling).
    pub ancestors: &'a [usize],
    /// ESS of `W_t`.
    pub ess: f64,
    /// Whether resampling happened before this step.
    pub resampled: bool,
    /// `log p̂(y_t | y_{0:t-1})`.
    pub log_likelihood_increment: f64,
}

/// Weighted summaries of the filtering distribution at one step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StepSummary {
    /// Weighted mean per state component.
    pub mean: Vec<f64>,
    /// Weighted variance per state component.
    pub var: Vec<f64>,
    /// `quantiles[c][k]`: quantile `probs[k]` of component `c`.
    pub quantiles: Vec<Vec<f64>>,
}

/// Reusable particle buffers (no allocation per time step; reuse across runs).
#[derive(Debug, Clone, Default)]
pub struct FilterWorkspace<S> {
    x: Vec<S>,
    x_new: Vec<S>,
    lw: Vec<f64>,
    lw_new: Vec<f64>,
    w: Vec<f64>,
    anc: Vec<usize>,
    aux: Vec<f64>,
    stats: Vec<ChunkStat>,
    counts: Vec<u32>,
    anc_next: Vec<usize>,
    bounds: Vec<(f64, usize)>,
}

impl<S> FilterWorkspace<S> {
    /// An empty workspace; buffers grow on first use.
    pub fn new() -> Self {
        Self {
            x: Vec::new(),
            x_new: Vec::new(),
            lw: Vec::new(),
            lw_new: Vec::new(),
            w: Vec::new(),
            anc: Vec::new(),
            aux: Vec::new(),
            stats: Vec::new(),
            counts: Vec::new(),
            anc_next: Vec::new(),
            bounds: Vec::new(),
        }
    }
}

#[derive(Debug, Clone, Copy, Default)]
struct ChunkStat {
    max: f64,
    sum: f64,
    sum2: f64,
    bad: bool,
}

/// Global normaliser of chunked log-weights.
#[derive(Debug, Clone, Copy)]
struct Norm {
    max: f64,
    sum: f64,
    sum2: f64,
}

fn combine(stats: &[ChunkStat], t: usize) -> Result<Norm> {
    let mut max = f64::NEG_INFINITY;
    for s in stats {
        if s.bad {
            return Err(SmcError::InvalidLogWeight { t });
        }
        max = max.max(s.max);
    }
    if max == f64::NEG_INFINITY {
        return Err(SmcError::AllWeightsZero { t });
    }
    let (mut sum, mut sum2) = (0.0, 0.0);
    for s in stats {
        if s.max > f64::NEG_INFINITY {
            let f = (s.max - max).exp();
            sum += s.sum * f;
            sum2 += s.sum2 * f * f;
        }
    }
    Ok(Norm { max, sum, sum2 })
}

/// Exp-normalises a chunk of log-weights: `w_i = exp(lw_i − max_chunk)`.
/// The exponentials vectorise; the sums use four fixed lanes (deterministic order).
#[inline]
fn chunk_exp(lw: &[f64], w: &mut [f64], max: f64, bad: bool) -> ChunkStat {
    if max == f64::NEG_INFINITY || bad {
        w.iter_mut().for_each(|x| *x = 0.0);
        return ChunkStat {
            max,
            sum: 0.0,
            sum2: 0.0,
            bad,
        };
    }
    exp_shifted(lw, w, max);
    let (s, s2) = lane_sums(w);
    ChunkStat {
        max,
        sum: s,
        sum2: s2,
        bad,
    }
}

#[inline(always)]
fn exp_shifted_generic(lw: &[f64], w: &mut [f64], max: f64) {
    for (wi, &l) in w.iter_mut().zip(lw) {
        *wi = exp_nonpos(l - max);
    }
}

/// The same code compiled for AVX2 (4 lanes). No FMA contraction happens, so
/// the results are bit-identical to the baseline (SSE2) build.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn exp_shifted_avx2(lw: &[f64], w: &mut [f64], max: f64) {
    exp_shifted_generic(lw, w, max)
}

/// `w_i = exp(lw_i − max)`, with runtime dispatch to AVX2 where available.
#[inline]
pub(crate) fn exp_shifted(lw: &[f64], w: &mut [f64], max: f64) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked above).
            unsafe { exp_shifted_avx2(lw, w, max) };
            return;
        }
    }
    exp_shifted_generic(lw, w, max)
}

/// `(Σ w, Σ w²)` with four independent accumulators in a fixed order.
#[inline]
pub(crate) fn lane_sums(w: &[f64]) -> (f64, f64) {
    let mut a = [0.0f64; 4];
    let mut b = [0.0f64; 4];
    let mut it = w.chunks_exact(4);
    for c in &mut it {
        for k in 0..4 {
            a[k] += c[k];
            b[k] += c[k] * c[k];
        }
    }
    for (k, &x) in it.remainder().iter().enumerate() {
        a[k] += x;
        b[k] += x * x;
    }
    ((a[0] + a[1]) + (a[2] + a[3]), (b[0] + b[1]) + (b[2] + b[3]))
}

type ChunkItem<'a, S> = (usize, ((&'a mut [S], &'a mut [f64]), &'a mut [f64]));

/// Moves every particle with `f(i, &mut x_i, rng) -> log w_i` in chunks with
/// per-chunk streams; fills `w` with chunk-relative exponentials.
#[allow(clippy::too_many_arguments)]
fn kernel<S, F>(
    parallel: bool,
    x: &mut [S],
    lw: &mut [f64],
    w: &mut [f64],
    stats: &mut Vec<ChunkStat>,
    seed: u64,
    t: usize,
    f: F,
) where
    S: Send,
    F: Fn(usize, &mut S, &mut SmcRng) -> f64 + Sync,
{
    let body = |(k, ((xc, lc), wc)): ChunkItem<'_, S>| {
        let mut rng = stream(seed, domain::MOVE, t as u64, k as u64);
        let base = k * CHUNK;
        let mut max = f64::NEG_INFINITY;
        let mut bad = false;
        for (j, (xi, li)) in xc.iter_mut().zip(lc.iter_mut()).enumerate() {
            let l = f(base + j, xi, &mut rng);
            bad |= l.is_nan() || l == f64::INFINITY;
            *li = l;
            max = if l > max { l } else { max };
        }
        chunk_exp(lc, wc, max, bad)
    };
    if parallel && x.len() >= PAR_MIN {
        x.par_chunks_mut(CHUNK)
            .zip(lw.par_chunks_mut(CHUNK))
            .zip(w.par_chunks_mut(CHUNK))
            .enumerate()
            .map(body)
            .collect_into_vec(stats);
    } else {
        stats.clear();
        stats.extend(
            x.chunks_mut(CHUNK)
                .zip(lw.chunks_mut(CHUNK))
                .zip(w.chunks_mut(CHUNK))
                .enumerate()
                .map(body),
        );
    }
}

/// Turns chunk-relative exponentials into normalised weights `W_i`.
fn normalise(parallel: bool, w: &mut [f64], stats: &[ChunkStat], norm: Norm) {
    let body = |(wc, s): (&mut [f64], &ChunkStat)| {
        let f = if s.max > f64::NEG_INFINITY {
            (s.max - norm.max).exp() / norm.sum
        } else {
            0.0
        };
        wc.iter_mut().for_each(|x| *x *= f);
    };
    if parallel && w.len() >= PAR_MIN_LIGHT {
        w.par_chunks_mut(CHUNK).zip(stats.par_iter()).for_each(body);
    } else {
        w.chunks_mut(CHUNK).zip(stats.iter()).for_each(body);
    }
}

/// Raw pointer to the ancestor buffer, shared by chunks writing disjoint ranges.
#[derive(Clone, Copy)]
struct AncPtr(*mut usize);
// SAFETY: only used to write pairwise disjoint index ranges from different chunks.
unsafe impl Send for AncPtr {}
unsafe impl Sync for AncPtr {}

/// Normalises the weights and draws systematic-resampling ancestors in the same
/// pass, chunk-parallel. Chunk `k` holds normalised mass `μ_k` starting at
/// cumulative offset `o_k` (computed sequentially over chunks, so the result does
/// not depend on scheduling); it owns the outputs `j ∈ [b_k, b_{k+1})` with
/// `b_k = #{j : (j + v)/N ≤ o_k}` and sets `a_j = min{i : k_i > j}` (store `i` at `k_{i-1}`, then a running maximum)
/// where `k_i = #{j : (j + v)/N ≤ C_i}`. O(N) work, no data-dependent branches.
#[allow(clippy::too_many_arguments)]
fn normalise_systematic(
    parallel: bool,
    w: &mut [f64],
    stats: &[ChunkStat],
    norm: Norm,
    v: f64,
    anc: &mut [usize],
    bounds: &mut Vec<(f64, usize)>,
) {
    let n = w.len();
    debug_assert_eq!(anc.len(), n);
    let factor = |s: &ChunkStat| {
        if s.max > f64::NEG_INFINITY {
            (s.max - norm.max).exp() / norm.sum
        } else {
            0.0
        }
    };
    // offsets o_k and output boundaries b_k
    bounds.clear();
    let mut off = 0.0;
    for s in stats {
        bounds.push((off, 0));
        off += s.sum * factor(s);
    }
    let total = off;
    let scale = n as f64 / total;
    let shift = 1.0 - v;
    let kc = stats.len();
    let mut prev = 0usize;
    for (k, b) in bounds.iter_mut().enumerate() {
        let x = if k == 0 {
            0
        } else {
            (((b.0 * scale + shift) as usize).min(n)).max(prev)
        };
        b.1 = x;
        prev = x;
    }
    let ptr = AncPtr(anc.as_mut_ptr());
    let bounds_ref = &bounds[..];
    let body = |(k, (wc, s)): (usize, (&mut [f64], &ChunkStat))| {
        let f = factor(s);
        wc.iter_mut().for_each(|x| *x *= f);
        let (o, start) = bounds_ref[k];
        let end = if k + 1 < kc { bounds_ref[k + 1].1 } else { n };
        if end == start {
            return;
        }
        let p = ptr;
        // SAFETY: the ranges [b_k, b_{k+1}) are disjoint for different k and lie in 0..n.
        let out = unsafe { std::slice::from_raw_parts_mut(p.0.add(start), end - start) };
        // Particle i's first child sits at k_{i-1}: store i there (the last writer
        // for a position is the first particle with k_i > j), then fill forward.
        let i0 = k * CHUNK;
        out.iter_mut().for_each(|a| *a = i0);
        let last = wc.iter().rposition(|&x| x > 0.0).unwrap_or(0);
        let mut c = o;
        let mut prev = start;
        let kof = |c: f64| ((c * scale + shift) as usize).clamp(start, end);
        // pairs: the cumulative sum's dependency chain advances once per two particles
        let mut pairs = wc[..last].chunks_exact(2);
        let mut i = 0;
        for p in &mut pairs {
            if prev < end {
                out[prev - start] = i0 + i;
            }
            let ka = kof(c + p[0]);
            c += p[0] + p[1];
            if ka < end {
                out[ka - start] = i0 + i + 1;
            }
            prev = kof(c);
            i += 2;
        }
        for &wi in pairs.remainder() {
            if prev < end {
                out[prev - start] = i0 + i;
            }
            c += wi;
            prev = kof(c);
            i += 1;
        }
        if prev < end {
            out[prev - start] = i0 + last;
        }
        let mut acc = i0;
        for a in out.iter_mut() {
            acc = acc.max(*a);
            *a = acc;
        }
    };
    if parallel && n >= PAR_MIN_LIGHT {
        w.par_chunks_mut(CHUNK)
            .zip(stats.par_iter())
            .enumerate()
            .for_each(body);
    } else {
        w.chunks_mut(CHUNK)
            .zip(stats.iter())
            .enumerate()
            .for_each(body);
    }
}

/// A configured particle filter.
///
/// ```
/// use gb_smc::{FilterConfig, LinearGaussian, KalmanFilter, Observations};
/// let model = LinearGaussian::ar1(0.9, 1.0, 0.5).unwrap();
/// let (_, y) = model.simulate(100, 3);
/// let pf = FilterConfig::new(2000).seed(1).build().unwrap();
/// let out = pf.run(&model, &Observations::new(&y)).unwrap();
/// let exact = KalmanFilter::new(&model).filter(&y).unwrap().log_likelihood;
/// assert!((out.log_likelihood - exact).abs() < 1.0);
/// ```
#[derive(Debug, Clone)]
pub struct ParticleFilter {
    pub(crate) config: FilterConfig,
}

impl ParticleFilter {
    /// Validates `config`.
    pub fn new(config: FilterConfig) -> Result<Self> {
        if config.n_particles == 0 {
            return Err(SmcError::InvalidParameter {
                name: "n_particles",
                value: 0.0,
                reason: "need at least one particle",
            });
        }
        crate::error::check(
            "ess_threshold",
            config.ess_threshold,
            config.ess_threshold >= 0.0 && config.ess_threshold.is_finite(),
            "must be finite and non-negative",
        )?;
        Ok(Self { config })
    }

    /// The settings.
    pub fn config(&self) -> &FilterConfig {
        &self.config
    }

    /// Runs the filter.
    pub fn run<M: StateSpaceModel>(
        &self,
        model: &M,
        obs: &Observations<'_, M::Obs>,
    ) -> Result<FilterOutput<M::State>> {
        let mut ws = FilterWorkspace::new();
        self.run_with(model, obs, &mut ws, |_| {})
    }

    /// Runs the filter and returns weighted means, variances and the
    /// quantiles `probs` of the filtering distributions.
    pub fn run_summaries<M>(
        &self,
        model: &M,
        obs: &Observations<'_, M::Obs>,
        probs: &[f64],
    ) -> Result<(FilterOutput<M::State>, Vec<StepSummary>)>
    where
        M: StateSpaceModel,
        M::State: StateVector,
    {
        for &p in probs {
            crate::error::check("probs", p, (0.0..=1.0).contains(&p), "must lie in [0, 1]")?;
        }
        let mut ws = FilterWorkspace::new();
        let mut sums = Vec::with_capacity(obs.len());
        let mut buf = Vec::new();
        let out = self.run_with(model, obs, &mut ws, |s| {
            sums.push(summarise(s.particles, s.weights, probs, &mut buf));
        })?;
        Ok((out, sums))
    }

    /// Runs the filter with reusable buffers, calling `observer` at every step.
    pub fn run_with<M, F>(
        &self,
        model: &M,
        obs: &Observations<'_, M::Obs>,
        ws: &mut FilterWorkspace<M::State>,
        mut observer: F,
    ) -> Result<FilterOutput<M::State>>
    where
        M: StateSpaceModel,
        F: FnMut(&FilterStep<'_, M::State>),
    {
        let cfg = &self.config;
        let n = cfg.n_particles;
        let tt = obs.len();
        if tt == 0 {
            return Err(SmcError::EmptyData);
        }
        let par = cfg.parallel;
        let seed = cfg.seed;
        let kind = cfg.kind;
        let always = cfg.ess_threshold >= 1.0;
        let ln_n = (n as f64).ln();

        // buffers
        if ws.x.len() != n {
            let mut rng = stream(seed, domain::FILL, 0, 0);
            let s = model.sample_initial(obs.input(0), &mut rng);
            ws.x = vec![s; n];
            ws.x_new = ws.x.clone();
        }
        ws.lw.resize(n, 0.0);
        ws.lw_new.resize(n, 0.0);
        ws.w.resize(n, 0.0);
        ws.anc.clear();
        ws.anc.extend(0..n);
        ws.anc_next.resize(n, 0);
        let fused = kind != FilterKind::Auxiliary && cfg.resampling == Resampling::Systematic;
        let mut next_ready = false;
        if kind == FilterKind::Auxiliary {
            ws.aux.resize(n, 0.0);
        }
        let mut history = cfg.store_history.then(|| FilterHistory {
            n,
            states: Vec::with_capacity(n * tt),
            weights: Vec::with_capacity(n * tt),
            ancestors: Vec::with_capacity(n * tt),
        });
        let mut incs = Vec::with_capacity(tt);
        let mut ess_hist = Vec::with_capacity(tt);
        let mut rs_hist = Vec::with_capacity(tt);

        // t = 0
        {
            let y = obs.y(0);
            let u = obs.input(0);
            match kind {
                FilterKind::Bootstrap => kernel(
                    par,
                    &mut ws.x,
                    &mut ws.lw,
                    &mut ws.w,
                    &mut ws.stats,
                    seed,
                    0,
                    |_, x, rng| {
                        *x = model.sample_initial(u, rng);
                        model.log_observation(0, x, y, u)
                    },
                ),
                _ => kernel(
                    par,
                    &mut ws.x,
                    &mut ws.lw,
                    &mut ws.w,
                    &mut ws.stats,
                    seed,
                    0,
                    |_, x, rng| {
                        *x = model.sample_initial_proposal(y, u, rng);
                        model.log_observation(0, x, y, u)
                            + model.log_initial_proposal_ratio(x, y, u)
                    },
                ),
            }
        }
        let mut norm = combine(&ws.stats, 0)?;
        let mut ess = norm.sum * norm.sum / norm.sum2;
        if fused && tt > 1 && (always || ess < cfg.ess_threshold * n as f64) {
            let v: f64 = stream(seed, domain::RESAMPLE, 1, 0).random();
            normalise_systematic(
                par,
                &mut ws.w,
                &ws.stats,
                norm,
                v,
                &mut ws.anc_next,
                &mut ws.bounds,
            );
            next_ready = true;
        } else {
            normalise(par, &mut ws.w, &ws.stats, norm);
        }
        let mut inc = norm.max + norm.sum.ln() - ln_n;
        let mut loglik = inc;
        incs.push(inc);
        ess_hist.push(ess);
        rs_hist.push(false);
        if let Some(h) = history.as_mut() {
            h.states.extend_from_slice(&ws.x);
            h.weights.extend_from_slice(&ws.w);
            h.ancestors.extend_from_slice(&ws.anc);
        }
        observer(&FilterStep {
            t: 0,
            particles: &ws.x,
            weights: &ws.w,
            ancestors: &ws.anc,
            ess,
            resampled: false,
            log_likelihood_increment: inc,
        });

        for t in 1..tt {
            let y = obs.y(t);
            let u = obs.input(t);
            let mut extra = 0.0;
            let mut rng = stream(seed, domain::RESAMPLE, t as u64, 0);
            let resampled = if kind == FilterKind::Auxiliary {
                // log η_t(x_{t-1}^i)
                let (x, aux) = (&ws.x, &mut ws.aux);
                let map = |(a, xi): (&mut f64, &M::State)| *a = model.log_auxiliary(t, xi, y, u);
                if par && n >= PAR_MIN {
                    aux.par_iter_mut().zip(x.par_iter()).for_each(map);
                } else {
                    aux.iter_mut().zip(x.iter()).for_each(map);
                }
                // first-stage weights W_i η_i (lw_new is scratch here)
                let scratch = &mut ws.lw_new;
                let mut amax = f64::NEG_INFINITY;
                let mut bad = false;
                for ((s, &wi), &a) in scratch.iter_mut().zip(ws.w.iter()).zip(ws.aux.iter()) {
                    let v = if wi > 0.0 {
                        wi.ln() + a
                    } else {
                        f64::NEG_INFINITY
                    };
                    bad |= v.is_nan() || v == f64::INFINITY;
                    *s = v;
                    amax = if v > amax { v } else { amax };
                }
                if bad {
                    return Err(SmcError::InvalidLogWeight { t });
                }
                if amax == f64::NEG_INFINITY {
                    return Err(SmcError::AllWeightsZero { t });
                }
                let (mut s, mut s2) = (0.0, 0.0);
                for sc in scratch.iter_mut() {
                    let e = (*sc - amax).exp();
                    *sc = e;
                    s += e;
                    s2 += e * e;
                }
                let rs = always || s * s / s2 < cfg.ess_threshold * n as f64;
                if rs {
                    extra = amax + s.ln();
                    resample_unchecked(
                        cfg.resampling,
                        scratch,
                        s,
                        &mut rng,
                        &mut ws.anc,
                        &mut ws.counts,
                    );
                }
                rs
            } else {
                let rs = always || ess < cfg.ess_threshold * n as f64;
                if rs && next_ready {
                    std::mem::swap(&mut ws.anc, &mut ws.anc_next);
                } else if rs {
                    resample_unchecked(
                        cfg.resampling,
                        &ws.w,
                        1.0,
                        &mut rng,
                        &mut ws.anc,
                        &mut ws.counts,
                    );
                }
                rs
            };
            if !resampled {
                for (i, a) in ws.anc.iter_mut().enumerate() {
                    *a = i;
                }
            }
            let prev_ln = if resampled { ln_n } else { norm.sum.ln() };
            let shift = norm.max;
            let apf = kind == FilterKind::Auxiliary;
            let (x_old, lw_old, anc, aux) = (&ws.x, &ws.lw, &ws.anc, &ws.aux);
            let base = |a: usize| -> f64 {
                if !resampled {
                    lw_old[a] - shift
                } else if apf {
                    -aux[a]
                } else {
                    0.0
                }
            };
            match kind {
                FilterKind::Bootstrap => kernel(
                    par,
                    &mut ws.x_new,
                    &mut ws.lw_new,
                    &mut ws.w,
                    &mut ws.stats,
                    seed,
                    t,
                    |i, x, rng| {
                        let a = anc[i];
                        *x = model.sample_transition(t, &x_old[a], u, rng);
                        base(a) + model.log_observation(t, x, y, u)
                    },
                ),
                _ => kernel(
                    par,
                    &mut ws.x_new,
                    &mut ws.lw_new,
                    &mut ws.w,
                    &mut ws.stats,
                    seed,
                    t,
                    |i, x, rng| {
                        let a = anc[i];
                        let p = &x_old[a];
                        *x = model.sample_proposal(t, p, y, u, rng);
                        base(a)
                            + model.log_observation(t, x, y, u)
                            + model.log_proposal_ratio(t, p, x, y, u)
                    },
                ),
            }
            norm = combine(&ws.stats, t)?;
            std::mem::swap(&mut ws.x, &mut ws.x_new);
            std::mem::swap(&mut ws.lw, &mut ws.lw_new);
            ess = norm.sum * norm.sum / norm.sum2;
            next_ready = false;
            if fused && t + 1 < tt && (always || ess < cfg.ess_threshold * n as f64) {
                let v: f64 = stream(seed, domain::RESAMPLE, t as u64 + 1, 0).random();
                normalise_systematic(
                    par,
                    &mut ws.w,
                    &ws.stats,
                    norm,
                    v,
                    &mut ws.anc_next,
                    &mut ws.bounds,
                );
                next_ready = true;
            } else {
                normalise(par, &mut ws.w, &ws.stats, norm);
            }
            inc = norm.max + norm.sum.ln() - prev_ln + extra;
            loglik += inc;
            incs.push(inc);
            ess_hist.push(ess);
            rs_hist.push(resampled);
            if let Some(h) = history.as_mut() {
                h.states.extend_from_slice(&ws.x);
                h.weights.extend_from_slice(&ws.w);
                h.ancestors.extend_from_slice(&ws.anc);
            }
            observer(&FilterStep {
                t,
                particles: &ws.x,
                weights: &ws.w,
                ancestors: &ws.anc,
                ess,
                resampled,
                log_likelihood_increment: inc,
            });
        }
        Ok(FilterOutput {
            log_likelihood: loglik,
            log_likelihood_increments: incs,
            ess: ess_hist,
            resampled: rs_hist,
            history,
        })
    }
}

/// Weighted mean, variance and quantiles of particles (normalised `weights`).
///
/// `buf` is scratch space for the quantile sort (reused between calls).
pub fn summarise<S: StateVector>(
    particles: &[S],
    weights: &[f64],
    probs: &[f64],
    buf: &mut Vec<(f64, f64)>,
) -> StepSummary {
    let d = particles.first().map_or(0, |p| p.components().len());
    let mut mean = vec![0.0; d];
    let mut var = vec![0.0; d];
    for (p, &w) in particles.iter().zip(weights) {
        for (m, &c) in mean.iter_mut().zip(p.components()) {
            *m += w * c;
        }
    }
    for (p, &w) in particles.iter().zip(weights) {
        for ((v, &m), &c) in var.iter_mut().zip(&mean).zip(p.components()) {
            *v += w * (c - m) * (c - m);
        }
    }
    let mut quantiles = Vec::with_capacity(d);
    if !probs.is_empty() {
        for c in 0..d {
            buf.clear();
            buf.extend(
                particles
                    .iter()
                    .zip(weights)
                    .map(|(p, &w)| (p.components()[c], w)),
            );
            quantiles.push(weighted_quantiles(buf, probs));
        }
    }
    StepSummary {
        mean,
        var,
        quantiles,
    }
}

/// Quantiles `probs` of the weighted sample `(value, weight)` (sorted in place);
/// the quantile `p` is the smallest value whose cumulative weight reaches `p · Σw`.
pub fn weighted_quantiles(sample: &mut [(f64, f64)], probs: &[f64]) -> Vec<f64> {
    sample.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
    let total: f64 = sample.iter().map(|s| s.1).sum();
    probs
        .iter()
        .map(|&p| {
            let target = p * total;
            let mut cum = 0.0;
            for &(v, w) in sample.iter() {
                cum += w;
                if cum >= target && w > 0.0 {
                    return v;
                }
            }
            sample.last().map_or(f64::NAN, |s| s.0)
        })
        .collect()
}

/// `exp(x)` for `x ≤ 0` (exp-normalised weights), branch-free and vectorisable:
/// `x = k ln 2 + r`, `|r| ≤ ln 2 / 2`, degree-13 Taylor polynomial for `e^r`
/// (relative error < 4e-16 · few), `2^k` built from the bits of `k + 1.5·2^52`;
/// `0` below `−708`. Portable and bit-reproducible (no libm).
#[inline(always)]
pub(crate) fn exp_nonpos(x: f64) -> f64 {
    const LOG2E: f64 = std::f64::consts::LOG2_E;
    const LN2_HI: f64 = 0.693_147_180_369_123_8;
    const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;
    const ROUND: f64 = 6_755_399_441_055_744.0; // 1.5 · 2^52
    let xc = if x < -708.0 { -708.0 } else { x };
    let t = xc * LOG2E + ROUND;
    let kf = t - ROUND;
    let r = (xc - kf * LN2_HI) - kf * LN2_LO;
    let mut p = 1.0 / 6_227_020_800.0;
    p = p * r + 1.0 / 479_001_600.0;
    p = p * r + 1.0 / 39_916_800.0;
    p = p * r + 1.0 / 3_628_800.0;
    p = p * r + 1.0 / 362_880.0;
    p = p * r + 1.0 / 40_320.0;
    p = p * r + 1.0 / 5_040.0;
    p = p * r + 1.0 / 720.0;
    p = p * r + 1.0 / 120.0;
    p = p * r + 1.0 / 24.0;
    p = p * r + 1.0 / 6.0;
    p = p * r + 0.5;
    p = p * r + 1.0;
    p = p * r + 1.0;
    // k = bits(t) − bits(ROUND) (t lies in the binade of ROUND, ulp 1)
    let k = t.to_bits().wrapping_sub(ROUND.to_bits());
    let scale = f64::from_bits(k.wrapping_add(1023) << 52);
    let e = p * scale;
    if x < -708.0 {
        0.0
    } else {
        e
    }
}

#[cfg(test)]
mod tests {
    use super::exp_nonpos;

    #[test]
    fn exp_dispatch_matches_scalar() {
        let lw: Vec<f64> = (0..1001).map(|i| -(i as f64) * 0.731).collect();
        let mut w = vec![0.0; lw.len()];
        super::exp_shifted(&lw, &mut w, 0.0);
        for (a, &l) in w.iter().zip(&lw) {
            assert_eq!(a.to_bits(), exp_nonpos(l).to_bits());
        }
    }

    #[test]
    fn exp_nonpos_is_accurate() {
        let mut x = 0.0;
        while x > -720.0 {
            let (a, b) = (exp_nonpos(x), x.exp());
            if x >= -708.0 {
                assert!(((a - b) / b).abs() < 4e-15, "x = {x}: {a} vs {b}");
            } else {
                assert_eq!(a, 0.0);
            }
            x -= 0.013_7;
        }
        assert_eq!(exp_nonpos(0.0), 1.0);
        assert_eq!(exp_nonpos(f64::NEG_INFINITY), 0.0);
    }
}
