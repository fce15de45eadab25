//! The SMC path of the state-space class against closed forms and truths.
//!
//! * A linear-Gaussian model with a hidden second state: the particle filter
//!   of `Smc::filter_states` (through the class's own noisy model) against a
//!   two-state Kalman filter and RTS smoother written here.
//! * Posterior intervals of the noise scales from `Smc::fit` against the true
//!   scales over seeded data sets (coverage).
use gb_model::{NoiseModel, OeParams, Silent, SmcParams, SparseStateSpace, StateEstimate};
use rand_distr::{Distribution, StandardNormal};

const A: [f64; 4] = [0.9, 0.1, -0.2, 0.8];
const B: [f64; 2] = [0.0, 0.5];
const SD_V: [f64; 2] = [0.05, 0.1];
const SD_W: f64 = 0.1;
const T: usize = 200;

fn model(sd_v: [f64; 2], sd_w: f64) -> SparseStateSpace {
    let mut m =
        SparseStateSpace::linear(A.to_vec(), B.to_vec(), vec![1.0, 0.0], vec![0.0]).unwrap();
    m.process_noise = sd_v.iter().map(|&sd| NoiseModel::Gaussian { sd }).collect();
    m.measurement_noise = NoiseModel::Gaussian { sd: sd_w };
    m
}

fn input(n: usize) -> Vec<f64> {
    (0..n)
        .map(|t| (0.07 * t as f64).sin() + 0.5 * (0.23 * t as f64).cos())
        .collect()
}

/// Data of the model's own convention: `x_0 = v_0`,
/// `x_t = A x_{t-1} + B u_{t-1} + v_t`, `y_t = x_{t,1} + w_t`.
fn simulate(u: &[f64], seed: u64) -> (Vec<f64>, Vec<[f64; 2]>) {
    let mut r = gb_core::rng::seeded(seed);
    let mut n = || -> f64 { StandardNormal.sample(&mut r) };
    let mut x = [SD_V[0] * n(), SD_V[1] * n()];
    let mut y = Vec::new();
    let mut xs = Vec::new();
    for t in 0..u.len() {
        if t > 0 {
            x = [
                A[0] * x[0] + A[1] * x[1] + B[0] * u[t - 1] + SD_V[0] * n(),
                A[2] * x[0] + A[3] * x[1] + B[1] * u[t - 1] + SD_V[1] * n(),
            ];
        }
        xs.push(x);
        y.push(x[0] + SD_W * n());
    }
    (y, xs)
}

type M2 = [[f64; 2]; 2];

fn mul(a: &M2, b: &M2) -> M2 {
    let mut c = [[0.0; 2]; 2];
    for i in 0..2 {
        for j in 0..2 {
            c[i][j] = a[i][0] * b[0][j] + a[i][1] * b[1][j];
        }
    }
    c
}

fn tr(a: &M2) -> M2 {
    [[a[0][0], a[1][0]], [a[0][1], a[1][1]]]
}

/// Kalman filter and RTS smoother of the two-state model (closed form):
/// predict `m⁻ = A m + B u_{t-1}`, `P⁻ = A P Aᵀ + Q` (at t = 0: `m⁻ = 0`, `P⁻ = Q`);
/// update with `S = P⁻₁₁ + R`, `K = P⁻_{·1}/S`, `e = y_t − m⁻₁`,
/// `log p(y_t | y_{0:t-1}) = −½(ln 2πS + e²/S)`; smoother
/// `G = P_t Aᵀ (P⁻_{t+1})⁻¹`, `m^s_t = m_t + G (m^s_{t+1} − m⁻_{t+1})`,
/// `P^s_t = P_t + G (P^s_{t+1} − P⁻_{t+1}) Gᵀ`.
struct Kalman {
    ll: f64,
    mean: Vec<[f64; 2]>,
    var: Vec<[f64; 2]>,
    smooth_mean: Vec<[f64; 2]>,
    smooth_var: Vec<[f64; 2]>,
}

fn kalman(u: &[f64], y: &[f64], sd_v: [f64; 2], sd_w: f64) -> Kalman {
    let a: M2 = [[A[0], A[1]], [A[2], A[3]]];
    let q: M2 = [[sd_v[0].powi(2), 0.0], [0.0, sd_v[1].powi(2)]];
    let r = sd_w * sd_w;
    let (mut m, mut p) = ([0.0; 2], q);
    let mut ll = 0.0;
    let (mut fm, mut fp, mut pm, mut pp) = (vec![], vec![], vec![], vec![]);
    for t in 0..y.len() {
        if t > 0 {
            m = [
                a[0][0] * m[0] + a[0][1] * m[1] + B[0] * u[t - 1],
                a[1][0] * m[0] + a[1][1] * m[1] + B[1] * u[t - 1],
            ];
            let app = mul(&mul(&a, &p), &tr(&a));
            p = [
                [app[0][0] + q[0][0], app[0][1]],
                [app[1][0], app[1][1] + q[1][1]],
            ];
        }
        pm.push(m);
        pp.push(p);
        let s = p[0][0] + r;
        let k = [p[0][0] / s, p[1][0] / s];
        let e = y[t] - m[0];
        ll += -0.5 * ((std::f64::consts::TAU * s).ln() + e * e / s);
        m = [m[0] + k[0] * e, m[1] + k[1] * e];
        p = [
            [p[0][0] - k[0] * k[0] * s, p[0][1] - k[0] * k[1] * s],
            [p[1][0] - k[1] * k[0] * s, p[1][1] - k[1] * k[1] * s],
        ];
        fm.push(m);
        fp.push(p);
    }
    let n = y.len();
    let (mut sm, mut sp) = (fm.clone(), fp.clone());
    for t in (0..n - 1).rev() {
        let pn = pp[t + 1];
        let det = pn[0][0] * pn[1][1] - pn[0][1] * pn[1][0];
        let inv: M2 = [
            [pn[1][1] / det, -pn[0][1] / det],
            [-pn[1][0] / det, pn[0][0] / det],
        ];
        let g = mul(&mul(&fp[t], &tr(&a)), &inv);
        let dm = [sm[t + 1][0] - pm[t + 1][0], sm[t + 1][1] - pm[t + 1][1]];
        sm[t] = [
            fm[t][0] + g[0][0] * dm[0] + g[0][1] * dm[1],
            fm[t][1] + g[1][0] * dm[0] + g[1][1] * dm[1],
        ];
        let dp: M2 = [
            [sp[t + 1][0][0] - pn[0][0], sp[t + 1][0][1] - pn[0][1]],
            [sp[t + 1][1][0] - pn[1][0], sp[t + 1][1][1] - pn[1][1]],
        ];
        let gdg = mul(&mul(&g, &dp), &tr(&g));
        sp[t] = [
            [fp[t][0][0] + gdg[0][0], fp[t][0][1] + gdg[0][1]],
            [fp[t][1][0] + gdg[1][0], fp[t][1][1] + gdg[1][1]],
        ];
    }
    Kalman {
        ll,
        mean: fm,
        var: fp.iter().map(|p| [p[0][0], p[1][1]]).collect(),
        smooth_mean: sm,
        smooth_var: sp.iter().map(|p| [p[0][0], p[1][1]]).collect(),
    }
}

/// RMS over samples and states of `(a − b)/√v`.
fn rms_z(a: &[Vec<f64>], b: &[[f64; 2]], v: &[[f64; 2]]) -> f64 {
    let mut s = 0.0;
    for i in 0..2 {
        for t in 0..b.len() {
            s += (a[i][t] - b[t][i]).powi(2) / v[t][i];
        }
    }
    (s / (2 * b.len()) as f64).sqrt()
}

fn filter(m: &SparseStateSpace, u: &[f64], y: &[f64], n: usize, seed: u64) -> StateEstimate {
    SmcParams::new()
        .particles(n)
        .seed(seed)
        .check()
        .unwrap()
        .filter_states(m, &[u.to_vec()], y, true)
        .unwrap()
}

/// `z = (mean(r) − 1) / (sd(r)/√R)` of the ratios `r = exp(d)`: tests
/// `E[p̂/p] = 1` (the particle likelihood is unbiased on the natural scale).
fn ratio_z(d: &[f64]) -> f64 {
    let r: Vec<f64> = d.iter().map(|v| v.exp()).collect();
    let n = r.len() as f64;
    let mean = r.iter().sum::<f64>() / n;
    let sd = (r.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    (mean - 1.0) / (sd / n.sqrt())
}

/// Log-likelihood: over 10 filter seeds at N = 2000, `d = log p̂ − log p_Kalman`
/// has `E[e^d] = 1` within 4 standard errors and `|mean d| < 0.5` (the Monte
/// Carlo sd of `log p̂` is ≈ 0.45 here, so the se of the mean is ≈ 0.15, plus
/// the downward bias `Var/2` ≈ 0.1). Negative control: the particle filter
/// of the same data with σ_v of the hidden state 30 % too large fails both.
#[test]
fn particle_likelihood_matches_the_kalman_filter() {
    let u = input(T);
    let (y, _) = simulate(&u, 1);
    let kf = kalman(&u, &y, SD_V, SD_W);
    let d_of = |m: &SparseStateSpace| -> Vec<f64> {
        (0..10)
            .map(|s| {
                let smc = SmcParams::new()
                    .particles(2000)
                    .seed(100 + s)
                    .check()
                    .unwrap();
                smc.log_likelihood(m, std::slice::from_ref(&u), &y).unwrap() - kf.ll
            })
            .collect()
    };
    let mean = |d: &[f64]| d.iter().sum::<f64>() / d.len() as f64;
    let d = d_of(&model(SD_V, SD_W));
    let (z, md) = (ratio_z(&d), mean(&d));
    eprintln!("log p̂ − log p: {d:.3?}; mean {md:.3}; z of E[p̂/p] = 1: {z:.2}");
    assert!(z.abs() < 4.0 && md.abs() < 0.5, "z = {z}, mean {md}");
    let wrong = d_of(&model([SD_V[0], 1.3 * SD_V[1]], SD_W));
    let (zw, mw) = (ratio_z(&wrong), mean(&wrong));
    eprintln!("negative control (σ_v2 × 1.3): mean {mw:.3}, z {zw:.2}");
    assert!(
        zw.abs() > 4.0 && mw.abs() > 0.5,
        "control z = {zw}, mean {mw}"
    );
}

/// Filtered and smoothed moments and 95 % bands of both states (the second
/// hidden) against the Kalman filter and RTS smoother, one run at N = 4000:
/// RMS of the standardised mean error < 0.1 (filter) and < 0.2 (smoother, 200
/// backward trajectories; Monte Carlo se ≈ 0.07), the variance ratios within
/// 15 % / 30 % (RMS), the band edges within 0.15 / 0.3 Kalman sd of
/// `m ± 1.96 √P` (RMS). Negative control: the filtered means are more than
/// 0.3 sd (RMS) away from the smoothed ones, so the smoother check can fail.
#[test]
fn particle_states_match_the_kalman_filter_and_smoother() {
    let u = input(T);
    let (y, _) = simulate(&u, 2);
    let kf = kalman(&u, &y, SD_V, SD_W);
    let est = filter(&model(SD_V, SD_W), &u, &y, 4000, 7);
    let f = &est.filtered;
    let s = est.smoothed.as_ref().unwrap();
    let var_err = |v: &[Vec<f64>], k: &[[f64; 2]]| -> f64 {
        let mut e = 0.0;
        for i in 0..2 {
            for t in 0..T {
                e += (v[i][t] / k[t][i] - 1.0).powi(2);
            }
        }
        (e / (2 * T) as f64).sqrt()
    };
    let band_err = |lo: &[Vec<f64>], hi: &[Vec<f64>], m: &[[f64; 2]], v: &[[f64; 2]]| -> f64 {
        let mut e = 0.0;
        for i in 0..2 {
            for t in 0..T {
                let sd = v[t][i].sqrt();
                e += ((lo[i][t] - (m[t][i] - 1.96 * sd)) / sd).powi(2);
                e += ((hi[i][t] - (m[t][i] + 1.96 * sd)) / sd).powi(2);
            }
        }
        (e / (4 * T) as f64).sqrt()
    };
    let zf = rms_z(&f.mean, &kf.mean, &kf.var);
    let vf = var_err(&f.var, &kf.var);
    let bf = band_err(&f.lo, &f.hi, &kf.mean, &kf.var);
    let zs = rms_z(&s.mean, &kf.smooth_mean, &kf.smooth_var);
    let vs = var_err(&s.var, &kf.smooth_var);
    let bs = band_err(&s.lo, &s.hi, &kf.smooth_mean, &kf.smooth_var);
    let control = rms_z(&f.mean, &kf.smooth_mean, &kf.smooth_var);
    eprintln!(
        "filter: mean z {zf:.3}, var {vf:.3}, band {bf:.3}; smoother: mean z {zs:.3}, var {vs:.3}, band {bs:.3}; \
         filter vs RTS (control) {control:.3}"
    );
    assert!(zf < 0.1 && vf < 0.15 && bf < 0.15, "filter {zf} {vf} {bf}");
    assert!(zs < 0.2 && vs < 0.3 && bs < 0.3, "smoother {zs} {vs} {bs}");
    assert!(control > 0.3, "control {control}");
}

/// One state, `x_t = 0.9 x_{t-1} + 0.5 u_{t-1} + v_t`, `y_t = x_t + w_t`,
/// `σ_v = 0.1`, `σ_w = 0.1`, `x_0 = v_0`; `C = 1` and `D = 0` known.
fn scalar_record(n: usize, seed: u64) -> (Vec<f64>, Vec<f64>) {
    let mut r = gb_core::rng::seeded(seed);
    let mut g = || -> f64 { StandardNormal.sample(&mut r) };
    let u: Vec<f64> = (0..n)
        .map(|t| (0.05 * t as f64 + seed as f64).sin() + 0.5 * (0.17 * t as f64).sin())
        .collect();
    let mut x = 0.1 * g();
    let mut y = Vec::with_capacity(n);
    for t in 0..n {
        if t > 0 {
            x = 0.9 * x + 0.5 * u[t - 1] + 0.1 * g();
        }
        y.push(x + 0.1 * g());
    }
    (u, y)
}

/// Per seed: whether the 95 % intervals of the process and the measurement
/// scale cover the truth, the smaller ESS and the larger split-R̂ of the two.
type Hit = ([bool; 2], f64, f64);

/// For each seed: the output-error fit, then PMMH (the tuned sampler, at
/// most 4 × `particles`) on the two noise scales; returns per seed whether
/// the 95 % intervals of the process and the measurement scale cover the
/// truth (0.1 each), with the chain's diagnostics.
fn coverage(seeds: std::ops::Range<u64>, n: usize, particles: usize, iters: usize) -> Vec<Hit> {
    // two threads, seeds interleaved; results in seed order
    let all: Vec<u64> = seeds.collect();
    let mut out: Vec<(u64, Hit)> = std::thread::scope(|sc| {
        let handles: Vec<_> = (0..2)
            .map(|k| {
                let mine: Vec<u64> = all.iter().copied().skip(k).step_by(2).collect();
                sc.spawn(move || {
                    mine.into_iter()
                        .map(|seed| (seed, coverage_one(seed, n, particles, iters)))
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().unwrap())
            .collect()
    });
    out.sort_by_key(|o| o.0);
    out.into_iter().map(|o| o.1).collect()
}

fn coverage_one(seed: u64, n: usize, particles: usize, iters: usize) -> Hit {
    let (u, y) = scalar_record(n, seed);
    let mut start = SparseStateSpace::linear(vec![0.5], vec![1.0], vec![1.0], vec![0.0]).unwrap();
    start.structure.c = vec![false];
    start.structure.d = vec![false];
    let inputs = [u];
    let (oe, _) = OeParams::new()
        .check()
        .unwrap()
        .fit(start, &inputs, &y, &Silent)
        .unwrap();
    let (_, rep) = SmcParams::new()
        .particles(particles)
        .iterations(iters, iters / 4)
        .coefficients(0)
        .seed(seed)
        .tuned(4 * particles)
        .check()
        .unwrap()
        .fit(&oe, &inputs, &y, &Silent)
        .unwrap();
    let p = &rep.parameters;
    assert_eq!(p[0].name, "process_scale[x1]");
    assert_eq!(p[1].name, "measurement_scale");
    let hit = |k: usize| p[k].lo <= 0.1 && 0.1 <= p[k].hi;
    eprintln!(
        "seed {seed}: a {:.3}; σ_v [{:.3}, {:.3}] ESS {:.0} R̂ {:.2}; σ_w [{:.3}, {:.3}] ESS {:.0} R̂ {:.2}; acceptance {:.2}; N {}",
        oe.a[0], p[0].lo, p[0].hi, p[0].ess, p[0].rhat, p[1].lo, p[1].hi, p[1].ess, p[1].rhat,
        rep.acceptance_rate, rep.particles
    );
    (
        [hit(0), hit(1)],
        p[0].ess.min(p[1].ess),
        p[0].rhat.max(p[1].rhat),
    )
}

/// Small, always-run version of the coverage check: 2 seeds (N = 200
/// particles to start, 2000 iterations, ≈ 1 min), 4 intervals, at least 3
/// cover the truth (correct 95 % intervals miss 2 of 4 with probability
/// 1.4 %; a chain stuck at the output-error start — σ_v 0.05 of the state
/// increments, σ_w the OE RMSE — or an interval that ignores the process
/// noise misses most). The chains mix: ESS ≥ 60 of 1500 draws and split-R̂
/// ≤ 1.1 for both scales (observed 88–133 and ≤ 1.05; the fixed sampler
/// with 200 particles and the proposal adapted after burn-in gave 44–58 and
/// up to 1.13).
#[test]
fn posterior_intervals_of_the_noise_scales_cover_the_truth() {
    let hits = coverage(1..3, 300, 200, 2000);
    let n = hits.iter().flat_map(|h| h.0).filter(|h| *h).count();
    assert!(n >= 3, "{n} of 4 intervals cover the truth: {hits:?}");
    for (k, h) in hits.iter().enumerate() {
        assert!(
            h.1 >= 60.0 && h.2 <= 1.1,
            "seed {}: ESS {}, R̂ {}",
            k + 1,
            h.1,
            h.2
        );
    }
}

/// Coverage over 40 seeds (80 intervals): between 85 % and 99 % must cover
/// the truth. Slow in a debug build (minutes), hence ignored; run with
/// `cargo test --release -p gb-model --test smc -- --ignored`.
#[test]
#[ignore = "40 PMMH runs; run in release (docs/smc.md has the figures)"]
fn posterior_interval_coverage_over_40_seeds() {
    let hits = coverage(1..41, 300, 200, 2000);
    let v = hits.iter().filter(|h| h.0[0]).count();
    let w = hits.iter().filter(|h| h.0[1]).count();
    let all = v + w;
    let mut ess: Vec<f64> = hits.iter().map(|h| h.1).collect();
    ess.sort_by(f64::total_cmp);
    let unmixed = hits.iter().filter(|h| h.2 > 1.1).count();
    eprintln!(
        "coverage: σ_v {v}/40, σ_w {w}/40, all {all}/80; smaller ESS median {:.0}, split-R̂ > 1.1 in {unmixed}/40",
        ess[20]
    );
    assert!((68..=79).contains(&all), "{all} of 80");
}
