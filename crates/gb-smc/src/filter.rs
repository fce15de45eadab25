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
use crate::rng::{domain, stream, CHUNK, FILTER_PAR_MIN, PAR_MIN_LIGHT};
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
    /// Use rayon over particle chunks from
    /// [`FILTER_PAR_MIN`](crate::rng::FILTER_PAR_MIN) particles up (results do
    /// not depend on it).
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
    cum: Vec<f64>,
    cum_new: Vec<f64>,
    anc: Vec<usize>,
    aux: Vec<f64>,
    stats: Vec<ChunkStat>,
    fac: Vec<f64>,
    off: Vec<f64>,
    bnd: Vec<usize>,
    counts: Vec<u32>,
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
            cum: Vec::new(),
            cum_new: Vec::new(),
            anc: Vec::new(),
            aux: Vec::new(),
            stats: Vec::new(),
            fac: Vec::new(),
            off: Vec::new(),
            bnd: Vec::new(),
            counts: Vec::new(),
        }
    }
}

/// Per-chunk result of a move: chunk-relative exponentials `e_i = exp(ℓ_i − max)`
/// with `sum = Σ e_i` (the last chunk-relative cumulative sum) and `sum2 = Σ e_i²`.
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

/// What a run carries from one step to the next.
#[derive(Debug, Clone, Copy)]
struct Carry {
    norm: Norm,
    ess: f64,
    loglik: f64,
}

/// Combines the chunk statistics (sequentially, in chunk order) and sets the
/// per-chunk factors `f_k = exp(max_k − max) / Σ` that normalise `e_i`.
fn combine(stats: &[ChunkStat], t: usize, fac: &mut Vec<f64>) -> Result<Norm> {
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
    fac.clear();
    for s in stats {
        if s.max > f64::NEG_INFINITY {
            let f = (s.max - max).exp();
            sum += s.sum * f;
            sum2 += s.sum2 * f * f;
            fac.push(f);
        } else {
            fac.push(0.0);
        }
    }
    for f in fac.iter_mut() {
        *f /= sum;
    }
    Ok(Norm { max, sum, sum2 })
}

/// `W_i = e_i f_k`: normalised weights.
fn normalise(parallel: bool, w: &mut [f64], fac: &[f64]) {
    let body = |(wc, &f): (&mut [f64], &f64)| wc.iter_mut().for_each(|x| *x *= f);
    if parallel && w.len() >= PAR_MIN_LIGHT {
        w.par_chunks_mut(CHUNK).zip(fac.par_iter()).for_each(body);
    } else {
        w.chunks_mut(CHUNK).zip(fac.iter()).for_each(body);
    }
}

/// Systematic resampling plan shared by all output chunks of a step.
///
/// The global cumulative weight of particle `i` in chunk `k` is
/// `C_i = o_k + P_i f_k` (`P_i`: chunk-relative cumulative sum of `e_i`,
/// `o_{k+1} = o_k + P_last f_k`), and particle `i` covers the
/// `K(i) = #{j : (j + v)/N ≤ C_i / C_{N−1}}` first outputs, so
/// `a_j = min{i : K(i) > j}`. `K` is monotone and `K(N − 1) = N`;
/// `b_k = K(last particle of chunk k − 1)`. Any output chunk can thus find its
/// ancestors from `P`, `o`, `f` and `b` alone, independently of the others.
#[derive(Clone, Copy)]
struct Sys<'a> {
    cum: &'a [f64],
    fac: &'a [f64],
    off: &'a [f64],
    bnd: &'a [usize],
    total: f64,
    scale: f64,
    shift: f64,
    n: usize,
}

impl Sys<'_> {
    #[inline(always)]
    fn count(&self, c: f64) -> usize {
        let k = ((c * self.scale + self.shift) as usize).min(self.n);
        if c >= self.total {
            self.n
        } else {
            k
        }
    }
}

/// Offsets `o_k` and boundaries `b_k` of the systematic plan.
fn plan(
    stats: &[ChunkStat],
    fac: &[f64],
    v: f64,
    n: usize,
    off: &mut Vec<f64>,
    bnd: &mut Vec<usize>,
) -> (f64, f64, f64) {
    off.clear();
    let mut o = 0.0;
    off.push(o);
    for (s, &f) in stats.iter().zip(fac) {
        o += s.sum * f;
        off.push(o);
    }
    let total = o;
    let scale = n as f64 / total;
    let shift = 1.0 - v;
    let sys = Sys {
        cum: &[],
        fac,
        off,
        bnd: &[],
        total,
        scale,
        shift,
        n,
    };
    bnd.clear();
    bnd.extend(off.iter().map(|&o| sys.count(o)));
    bnd[0] = 0;
    (total, scale, shift)
}

/// Ancestors `a_j` of the outputs `j ∈ [s, s + out.len())` (systematic plan),
/// written to `out` as "`i + 1` at position `K(i)`" (the last writer of a
/// position is the first particle covering it) for [`fill_forward`]; zero elsewhere.
#[inline(always)]
fn sys_ancestors(sys: &Sys<'_>, s: usize, out: &mut [usize]) {
    let e = s + out.len();
    // first parent chunk whose outputs reach past s (b_K = N > s)
    let mut k = sys.bnd[1..].partition_point(|&b| b <= s);
    out.iter_mut().for_each(|a| *a = 0);
    let mut first = true;
    loop {
        let base = k * CHUNK;
        let pk = &sys.cum[base..(base + CHUNK).min(sys.n)];
        let (o, f) = (sys.off[k], sys.fac[k]);
        let start = if first {
            let i = pk.partition_point(|&p| sys.count(o + p * f) <= s);
            out[0] = base + i;
            first = false;
            i
        } else {
            0
        };
        // the last chunk needed: its outputs reach e (b_K = N ≥ e)
        let done = sys.bnd[k + 1] >= e;
        let stop = if done {
            pk.partition_point(|&p| sys.count(o + p * f) < e)
        } else {
            pk.len()
        };
        // s < K(i) < e for these particles, so K(i) < N and C_i < C_{N−1}:
        // `count` reduces to the plain conversion (no clamping)
        for (i, &p) in (base + start + 1..).zip(&pk[start..stop]) {
            let x = (o + p * f) * sys.scale + sys.shift;
            debug_assert!((0.0..(e + 1) as f64).contains(&x));
            // SAFETY: x is finite and in [0, e + 1) (0 ≤ C_i < C_{N−1}, scale =
            // N / C_{N−1} > 0, shift ∈ (0, 1], and ⌊x⌋ = K(i) < e), so the
            // truncation is representable (`as` would add saturation checks).
            let c: usize = unsafe { x.to_int_unchecked() };
            out[c - s] = i;
        }
        if done {
            break;
        }
        k += 1;
    }
}

/// Fills the unwritten (zero) positions with the last written value. The
/// written values increase, so this is a running maximum; it is done with
/// bit operations because which positions are written is random (a branch
/// would mispredict, and LLVM turns a `max`/select in this loop into one).
#[inline(always)]
fn fill_forward(a: &mut [usize]) {
    let mut acc = 0usize;
    for x in a.iter_mut() {
        let v = *x;
        // all ones iff v == 0 (the values are < 2^63)
        let keep = ((v as i64).wrapping_sub(1) >> 63) as usize;
        acc = v | (acc & keep);
        *x = acc;
    }
}

/// [`fill_forward`] and `x_j ← x_old[a_j]` in one pass.
#[inline(never)]
fn fill_forward_gather<S: Clone>(a: &mut [usize], x_old: &[S], x: &mut [S]) {
    let mut acc = 0usize;
    for (ai, xi) in a.iter_mut().zip(x.iter_mut()) {
        let v = *ai;
        let keep = ((v as i64).wrapping_sub(1) >> 63) as usize;
        acc = v | (acc & keep);
        *ai = acc;
        *xi = x_old[acc].clone();
    }
}

/// How a step weights a moved particle on top of `log g_t` (and the proposal ratio).
#[derive(Clone, Copy)]
enum Base {
    /// After resampling (bootstrap / guided): nothing.
    Zero,
    /// Without resampling: `ℓ_{t−1}^{a} − max ℓ_{t−1}`.
    Prev(f64),
    /// APF after resampling: `−log η_t^{a}`.
    Apf,
}

/// Everything a chunk task reads.
struct Ctx<'a, M: StateSpaceModel> {
    model: &'a M,
    t: usize,
    y: &'a M::Obs,
    u: &'a [f64],
    seed: u64,
    /// bootstrap: batch methods of the model
    batch: bool,
    x_old: &'a [M::State],
    lw_old: &'a [f64],
    aux: &'a [f64],
    base: Base,
    sys: Option<Sys<'a>>,
}

type Item<'a, S> = (
    usize,
    (
        (((&'a mut [S], &'a mut [f64]), &'a mut [f64]), &'a mut [f64]),
        &'a mut [usize],
    ),
);

/// One output chunk `m` of one step: ancestors, move, log-weights, chunk-relative
/// exponentials `e_i`, their cumulative sums and statistics.
#[inline(always)]
fn task_body<M: StateSpaceModel>(ctx: &Ctx<'_, M>, item: Item<'_, M::State>) -> ChunkStat {
    let (m, ((((xc, lc), wc), pc), ac)) = item;
    let t = ctx.t;
    let model = ctx.model;
    let (y, u) = (ctx.y, ctx.u);
    let mut rng = stream(ctx.seed, domain::MOVE, t as u64, m as u64);
    if t == 0 {
        if ctx.batch {
            for xi in xc.iter_mut() {
                *xi = model.sample_initial(u, &mut rng);
            }
            model.log_observation_batch(0, xc, y, u, lc);
        } else {
            for (xi, li) in xc.iter_mut().zip(lc.iter_mut()) {
                *xi = model.sample_initial_proposal(y, u, &mut rng);
                *li =
                    model.log_observation(0, xi, y, u) + model.log_initial_proposal_ratio(xi, y, u);
            }
        }
    } else {
        let x_old = ctx.x_old;
        let gathered = match &ctx.sys {
            Some(sys) => {
                sys_ancestors(sys, m * CHUNK, ac);
                if ctx.batch {
                    fill_forward_gather(ac, x_old, xc);
                    true
                } else {
                    fill_forward(ac);
                    false
                }
            }
            None => false,
        };
        let (lw_old, aux) = (ctx.lw_old, ctx.aux);
        let base = |a: usize| -> f64 {
            match ctx.base {
                Base::Zero => 0.0,
                Base::Prev(shift) => lw_old[a] - shift,
                Base::Apf => -aux[a],
            }
        };
        if ctx.batch {
            if !gathered {
                for (xi, &a) in xc.iter_mut().zip(ac.iter()) {
                    *xi = x_old[a].clone();
                }
            }
            model.sample_transition_batch(t, xc, u, &mut rng);
            model.log_observation_batch(t, xc, y, u, lc);
            if !matches!(ctx.base, Base::Zero) {
                for (li, &a) in lc.iter_mut().zip(ac.iter()) {
                    *li += base(a);
                }
            }
        } else {
            for ((xi, li), &a) in xc.iter_mut().zip(lc.iter_mut()).zip(ac.iter()) {
                let p = &x_old[a];
                *xi = model.sample_proposal(t, p, y, u, &mut rng);
                *li = base(a)
                    + model.log_observation(t, xi, y, u)
                    + model.log_proposal_ratio(t, p, xi, y, u);
            }
        }
    }
    finish_chunk(lc, wc, pc)
}

/// Max and validity of the log-weights, `e_i = exp(ℓ_i − max)`, `Σ e²`, and the
/// chunk-relative cumulative sums `P` (blocks of 64 summed independently, then
/// offset: a fixed association, so the result does not depend on the CPU).
#[inline(always)]
fn finish_chunk(lc: &[f64], wc: &mut [f64], pc: &mut [f64]) -> ChunkStat {
    const L: usize = 8;
    let mut mx = [f64::NEG_INFINITY; L];
    let mut bad = [false; L];
    let mut it = lc.chunks_exact(L);
    for c in &mut it {
        for k in 0..L {
            let l = c[k];
            bad[k] |= l.is_nan() || l == f64::INFINITY;
            mx[k] = if l > mx[k] { l } else { mx[k] };
        }
    }
    for (k, &l) in it.remainder().iter().enumerate() {
        bad[k] |= l.is_nan() || l == f64::INFINITY;
        mx[k] = if l > mx[k] { l } else { mx[k] };
    }
    let mut max = f64::NEG_INFINITY;
    for &v in &mx {
        max = if v > max { v } else { max };
    }
    let bad = bad.iter().any(|&b| b);
    if max == f64::NEG_INFINITY || bad {
        wc.iter_mut().for_each(|x| *x = 0.0);
        pc.iter_mut().for_each(|x| *x = 0.0);
        return ChunkStat {
            max,
            sum: 0.0,
            sum2: 0.0,
            bad,
        };
    }
    for (wi, &l) in wc.iter_mut().zip(lc) {
        *wi = exp_nonpos(l - max);
    }
    let (_, sum2) = lane_sums(wc);
    let sum = prefix_sums(wc, pc);
    ChunkStat {
        max,
        sum,
        sum2,
        bad: false,
    }
}

/// Cumulative sums of `w` into `p` in blocks of 64 (each block from 0, then the
/// block offsets added); returns the total `p.last()`.
#[inline(always)]
pub(crate) fn prefix_sums(w: &[f64], p: &mut [f64]) -> f64 {
    const B: usize = 64;
    const NB: usize = 8;
    for (wg, pg) in w.chunks(B * NB).zip(p.chunks_mut(B * NB)) {
        if wg.len() == B * NB && pg.len() == B * NB {
            // the same sums, eight independent chains interleaved
            let mut c = [0.0f64; NB];
            for r in 0..B {
                for l in 0..NB {
                    c[l] += wg[l * B + r];
                    pg[l * B + r] = c[l];
                }
            }
        } else {
            for (wb, pb) in wg.chunks(B).zip(pg.chunks_mut(B)) {
                let mut c = 0.0;
                for (x, q) in wb.iter().zip(pb.iter_mut()) {
                    c += x;
                    *q = c;
                }
            }
        }
    }
    let mut off = 0.0;
    for (i, pb) in p.chunks_mut(B).enumerate() {
        if i > 0 {
            pb.iter_mut().for_each(|q| *q += off);
        }
        off = *pb.last().expect("non-empty block");
    }
    off
}

/// Instruction sets the chunk tasks are compiled for. The same IEEE operations
/// run in the same order on each (no FMA contraction), so results are
/// bit-identical whichever one runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Isa {
    Base,
    #[cfg(target_arch = "x86_64")]
    Avx2,
    #[cfg(target_arch = "x86_64")]
    Avx512,
}

impl Isa {
    pub(crate) fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f")
                && std::arch::is_x86_feature_detected!("avx512dq")
                && std::arch::is_x86_feature_detected!("avx512vl")
            {
                return Isa::Avx512;
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                return Isa::Avx2;
            }
        }
        Isa::Base
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn task_avx2<M: StateSpaceModel>(ctx: &Ctx<'_, M>, item: Item<'_, M::State>) -> ChunkStat {
    task_body(ctx, item)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512dq,avx512vl")]
fn task_avx512<M: StateSpaceModel>(ctx: &Ctx<'_, M>, item: Item<'_, M::State>) -> ChunkStat {
    task_body(ctx, item)
}

#[inline]
fn task<M: StateSpaceModel>(isa: Isa, ctx: &Ctx<'_, M>, item: Item<'_, M::State>) -> ChunkStat {
    match isa {
        Isa::Base => task_body(ctx, item),
        // SAFETY: `Isa::detect` checked that the CPU supports these features.
        #[cfg(target_arch = "x86_64")]
        Isa::Avx2 => unsafe { task_avx2(ctx, item) },
        #[cfg(target_arch = "x86_64")]
        Isa::Avx512 => unsafe { task_avx512(ctx, item) },
    }
}

/// Runs all output chunks of one step (rayon from `FILTER_PAR_MIN` particles up).
#[allow(clippy::too_many_arguments)]
fn run_step<M: StateSpaceModel>(
    isa: Isa,
    parallel: bool,
    ctx: &Ctx<'_, M>,
    x: &mut [M::State],
    lw: &mut [f64],
    w: &mut [f64],
    cum: &mut [f64],
    anc: &mut [usize],
    stats: &mut Vec<ChunkStat>,
) {
    if parallel && x.len() >= FILTER_PAR_MIN {
        x.par_chunks_mut(CHUNK)
            .zip(lw.par_chunks_mut(CHUNK))
            .zip(w.par_chunks_mut(CHUNK))
            .zip(cum.par_chunks_mut(CHUNK))
            .zip(anc.par_chunks_mut(CHUNK))
            .enumerate()
            .map(|item| task(isa, ctx, item))
            .collect_into_vec(stats);
    } else {
        stats.clear();
        stats.extend(
            x.chunks_mut(CHUNK)
                .zip(lw.chunks_mut(CHUNK))
                .zip(w.chunks_mut(CHUNK))
                .zip(cum.chunks_mut(CHUNK))
                .zip(anc.chunks_mut(CHUNK))
                .enumerate()
                .map(|item| task(isa, ctx, item)),
        );
    }
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
    ///
    /// With `parallel` and `N ≥ FILTER_PAR_MIN` (16 384; one rayon fork-join per time step), the
    /// run is moved onto a rayon worker when called from outside the pool, so
    /// that the thread driving the time loop takes part in every step instead of
    /// sleeping on a latch and being woken at every step; `observer` then runs
    /// on that worker (hence `Send`).
    pub fn run_with<M, F>(
        &self,
        model: &M,
        obs: &Observations<'_, M::Obs>,
        ws: &mut FilterWorkspace<M::State>,
        observer: F,
    ) -> Result<FilterOutput<M::State>>
    where
        M: StateSpaceModel,
        F: FnMut(&FilterStep<'_, M::State>) + Send,
    {
        let isa = Isa::detect();
        if self.config.parallel
            && self.config.n_particles >= FILTER_PAR_MIN
            && rayon::current_thread_index().is_none()
        {
            rayon::scope(|_| self.run_impl(isa, model, obs, ws, observer))
        } else {
            self.run_impl(isa, model, obs, ws, observer)
        }
    }

    pub(crate) fn run_impl<M, F>(
        &self,
        isa: Isa,
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
        self.prepare(model, obs.input(0), ws);
        let mut history = cfg.store_history.then(|| FilterHistory {
            n,
            states: Vec::with_capacity(n * tt),
            weights: Vec::with_capacity(n * tt),
            ancestors: Vec::with_capacity(n * tt),
        });
        let mut incs = Vec::with_capacity(tt);
        let mut ess_hist = Vec::with_capacity(tt);
        let mut rs_hist = Vec::with_capacity(tt);
        let mut carry = None;
        for t in 0..tt {
            let (inc, resampled) =
                self.advance(isa, model, t, obs.y(t), obs.input(t), ws, &mut carry)?;
            let ess = carry.as_ref().map_or(f64::NAN, |c: &Carry| c.ess);
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
        let loglik = carry.as_ref().map_or(0.0, |c| c.loglik);
        Ok(FilterOutput {
            log_likelihood: loglik,
            log_likelihood_increments: incs,
            ess: ess_hist,
            resampled: rs_hist,
            history,
        })
    }

    /// Buffers for a run whose first input is `u0` (the fill value of the
    /// particle buffers is an initial draw, as every run has it).
    fn prepare<M: StateSpaceModel>(
        &self,
        model: &M,
        u0: &[f64],
        ws: &mut FilterWorkspace<M::State>,
    ) {
        let cfg = &self.config;
        let n = cfg.n_particles;
        if ws.x.len() != n {
            let mut rng = stream(cfg.seed, domain::FILL, 0, 0);
            let s = model.sample_initial(u0, &mut rng);
            ws.x = vec![s; n];
            ws.x_new = ws.x.clone();
        }
        ws.lw.resize(n, 0.0);
        ws.lw_new.resize(n, 0.0);
        ws.w.resize(n, 0.0);
        ws.cum.resize(n, 0.0);
        ws.cum_new.resize(n, 0.0);
        ws.anc.clear();
        ws.anc.extend(0..n);
        if cfg.kind == FilterKind::Auxiliary {
            ws.aux.resize(n, 0.0);
        }
    }

    /// Step `t` of a run (`carry` is `None` before step 0 and holds the
    /// normaliser, ESS and log-likelihood after each step): returns
    /// `log p̂(y_t | y_{0:t-1})` and whether the particles were resampled.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    fn advance<M: StateSpaceModel>(
        &self,
        isa: Isa,
        model: &M,
        t: usize,
        y: &M::Obs,
        u: &[f64],
        ws: &mut FilterWorkspace<M::State>,
        carry: &mut Option<Carry>,
    ) -> Result<(f64, bool)> {
        let cfg = &self.config;
        let n = cfg.n_particles;
        let par = cfg.parallel;
        let seed = cfg.seed;
        let kind = cfg.kind;
        let batch = kind == FilterKind::Bootstrap;
        let always = cfg.ess_threshold >= 1.0;
        let ln_n = (n as f64).ln();
        // systematic resampling inside the move tasks (not for the APF, whose
        // first-stage weights are resampled before the move)
        let fused = kind != FilterKind::Auxiliary && cfg.resampling == Resampling::Systematic;
        let Some(prev) = *carry else {
            // t = 0
            let ctx = Ctx {
                model,
                t,
                y,
                u,
                seed,
                batch,
                x_old: &[],
                lw_old: &[],
                aux: &[],
                base: Base::Zero,
                sys: None,
            };
            run_step(
                isa,
                par,
                &ctx,
                &mut ws.x_new,
                &mut ws.lw_new,
                &mut ws.w,
                &mut ws.cum_new,
                &mut ws.anc,
                &mut ws.stats,
            );
            let norm = combine(&ws.stats, t, &mut ws.fac)?;
            std::mem::swap(&mut ws.x, &mut ws.x_new);
            std::mem::swap(&mut ws.lw, &mut ws.lw_new);
            std::mem::swap(&mut ws.cum, &mut ws.cum_new);
            normalise(par, &mut ws.w, &ws.fac);
            let inc = norm.max + norm.sum.ln() - ln_n;
            *carry = Some(Carry {
                norm,
                ess: norm.sum * norm.sum / norm.sum2,
                loglik: inc,
            });
            return Ok((inc, false));
        };
        let (norm, ess) = (prev.norm, prev.ess);
        let mut extra = 0.0;
        let mut rng = stream(seed, domain::RESAMPLE, t as u64, 0);
        let mut sys_v = None;
        let resampled = if kind == FilterKind::Auxiliary {
            // log η_t(x_{t-1}^i)
            let (x, aux) = (&ws.x, &mut ws.aux);
            let map = |(a, xi): (&mut f64, &M::State)| *a = model.log_auxiliary(t, xi, y, u);
            if par && n >= FILTER_PAR_MIN {
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
            if rs && fused {
                sys_v = Some(rng.random::<f64>());
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
        let sys = match sys_v {
            Some(v) => {
                let (total, scale, shift) =
                    plan(&ws.stats, &ws.fac, v, n, &mut ws.off, &mut ws.bnd);
                Some(Sys {
                    cum: &ws.cum,
                    fac: &ws.fac,
                    off: &ws.off,
                    bnd: &ws.bnd,
                    total,
                    scale,
                    shift,
                    n,
                })
            }
            None => None,
        };
        let prev_ln = if resampled { ln_n } else { norm.sum.ln() };
        let base = if !resampled {
            Base::Prev(norm.max)
        } else if kind == FilterKind::Auxiliary {
            Base::Apf
        } else {
            Base::Zero
        };
        let ctx = Ctx {
            model,
            t,
            y,
            u,
            seed,
            batch,
            x_old: &ws.x,
            lw_old: &ws.lw,
            aux: &ws.aux,
            base,
            sys,
        };
        run_step(
            isa,
            par,
            &ctx,
            &mut ws.x_new,
            &mut ws.lw_new,
            &mut ws.w,
            &mut ws.cum_new,
            &mut ws.anc,
            &mut ws.stats,
        );
        let norm = combine(&ws.stats, t, &mut ws.fac)?;
        std::mem::swap(&mut ws.x, &mut ws.x_new);
        std::mem::swap(&mut ws.lw, &mut ws.lw_new);
        std::mem::swap(&mut ws.cum, &mut ws.cum_new);
        normalise(par, &mut ws.w, &ws.fac);
        let inc = norm.max + norm.sum.ln() - prev_ln + extra;
        *carry = Some(Carry {
            norm,
            ess: norm.sum * norm.sum / norm.sum2,
            loglik: prev.loglik + inc,
        });
        Ok((inc, resampled))
    }

    /// A filter fed one observation at a time ([`OnlineFilter::push`]) for
    /// online use; it runs the same steps as [`run`](Self::run), so pushing
    /// a record sample by sample gives the same log-likelihood, bit for bit.
    pub fn online<'m, M: StateSpaceModel>(&self, model: &'m M) -> OnlineFilter<'m, M> {
        OnlineFilter {
            pf: self.clone(),
            model,
            ws: FilterWorkspace::new(),
            carry: None,
            t: 0,
            isa: Isa::detect(),
            failed: false,
        }
    }
}

/// A particle filter fed one observation at a time (from
/// [`ParticleFilter::online`]): the online form of [`ParticleFilter::run`]
/// with the same random streams, so the log-likelihood after pushing
/// `y_0, …, y_{T-1}` equals that of a batch run on the same record.
///
/// ```
/// use gb_smc::{FilterConfig, LinearGaussian, Observations};
/// let model = LinearGaussian::ar1(0.9, 1.0, 0.5).unwrap();
/// let (_, y) = model.simulate(50, 3);
/// let pf = FilterConfig::new(500).seed(1).build().unwrap();
/// let mut online = pf.online(&model);
/// for yt in &y {
///     online.push(yt, &[]).unwrap();
/// }
/// let batch = pf.run(&model, &Observations::new(&y)).unwrap();
/// assert_eq!(online.log_likelihood(), batch.log_likelihood);
/// ```
pub struct OnlineFilter<'m, M: StateSpaceModel> {
    pf: ParticleFilter,
    model: &'m M,
    ws: FilterWorkspace<M::State>,
    carry: Option<Carry>,
    t: usize,
    isa: Isa,
    failed: bool,
}

impl<M: StateSpaceModel> OnlineFilter<'_, M> {
    /// Filters the next observation `y_t` with the inputs `u_t` (`t` counts
    /// the pushes from 0) and returns `log p̂(y_t | y_{0:t-1})`. After an
    /// error the filter is spent and every further push fails.
    pub fn push(&mut self, y: &M::Obs, u: &[f64]) -> Result<f64> {
        if self.failed {
            return Err(SmcError::InvalidParameter {
                name: "push",
                value: self.t as f64,
                reason: "the filter failed at an earlier step",
            });
        }
        if self.t == 0 {
            self.pf.prepare(self.model, u, &mut self.ws);
        }
        let r = self.pf.advance(
            self.isa,
            self.model,
            self.t,
            y,
            u,
            &mut self.ws,
            &mut self.carry,
        );
        match r {
            Ok((inc, _)) => {
                self.t += 1;
                Ok(inc)
            }
            Err(e) => {
                self.failed = true;
                Err(e)
            }
        }
    }

    /// Number of observations pushed.
    pub fn len(&self) -> usize {
        self.t
    }

    /// `true` before the first push.
    pub fn is_empty(&self) -> bool {
        self.t == 0
    }

    /// `log p̂(y_{0:t-1})` of the observations pushed so far (0 before the first).
    pub fn log_likelihood(&self) -> f64 {
        self.carry.as_ref().map_or(0.0, |c| c.loglik)
    }

    /// ESS of the current filtering weights (NaN before the first push).
    pub fn ess(&self) -> f64 {
        self.carry.as_ref().map_or(f64::NAN, |c| c.ess)
    }

    /// The current particles `x_{t-1}^i` (empty before the first push).
    pub fn particles(&self) -> &[M::State] {
        if self.t == 0 {
            &[]
        } else {
            &self.ws.x
        }
    }

    /// The current normalised weights `W_{t-1}^i` (empty before the first push).
    pub fn weights(&self) -> &[f64] {
        if self.t == 0 {
            &[]
        } else {
            &self.ws.w
        }
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
    fn every_instruction_set_gives_identical_bits() {
        use super::{FilterWorkspace, Isa};
        use crate::{FilterConfig, FilterKind, LinearGaussian, Observations, Resampling};
        let model = LinearGaussian::ar1(0.9, 1.0, 0.5).unwrap();
        let (_, y) = model.simulate(50, 2);
        let obs = Observations::new(&y);
        let mut isas = vec![Isa::Base];
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                isas.push(Isa::Avx2);
            }
            if Isa::detect() == Isa::Avx512 {
                isas.push(Isa::Avx512);
            }
        }
        for kind in [FilterKind::Bootstrap, FilterKind::Guided] {
            for (rs, tau) in [
                (Resampling::Systematic, 1.0),
                (Resampling::Systematic, 0.5),
                (Resampling::Stratified, 1.0),
            ] {
                let pf = FilterConfig::new(5000)
                    .kind(kind)
                    .resampling(rs)
                    .ess_threshold(tau)
                    .seed(4)
                    .store_history(true)
                    .build()
                    .unwrap();
                let runs: Vec<_> = isas
                    .iter()
                    .map(|&isa| {
                        pf.run_impl(isa, &model, &obs, &mut FilterWorkspace::new(), |_| {})
                            .unwrap()
                    })
                    .collect();
                for r in &runs[1..] {
                    assert_eq!(r.log_likelihood.to_bits(), runs[0].log_likelihood.to_bits());
                    let (a, b) = (
                        r.history.as_ref().unwrap(),
                        runs[0].history.as_ref().unwrap(),
                    );
                    assert_eq!(a.states, b.states);
                    assert_eq!(a.weights, b.weights);
                    assert_eq!(a.ancestors, b.ancestors);
                }
            }
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
