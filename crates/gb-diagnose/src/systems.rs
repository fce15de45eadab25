//! Simulators of the systems used in examples and tests: mass-spring-damper
//! variants each hiding one effect, sampled with zero-order-hold input and
//! RK4 integration (10 sub-steps per sample), with output noise at a given SNR.
//!
//! m ẍ + c ẋ + k x + r(x, ẋ, memory) = F(u),   y = x + noise
//!
//! | system | hidden effect | expected cause |
//! |---|---|---|
//! | `linear` | none | — |
//! | `duffing` | r = k₃x³ | nonlinearity |
//! | `saturation` | F = u_max·tanh(u/u_max) | nonlinearity |
//! | `deadzone` | F = u − clip(u, ±d) | nonlinearity |
//! | `preisach` | r = Preisach operator of x (Gaussian density) | hysteresis |
//! | `bouc-wen` | r = z, ż = αẋ − β\|ẋ\|\|z\|^{n−1}z − γẋ\|z\|^n | hysteresis |
//! | `backlash` | F = play_b(u) (gear backlash) | hysteresis |
//! | `two-mass` | a second, hidden mass coupled to the first | dynamics |
//! | `student-t` | Student-t (ν = 3) output noise | noise |
//! | `shock-absorber` | hysteretic (Bouc-Wen) damper of a wheel mass | hysteresis |
use gb_core::{rng, CoreError, Record};
use rand::Rng;
use rand_distr::{Distribution, StandardNormal, StudentT};
use serde::{Deserialize, Serialize};

/// Names of the generated systems.
pub const SYSTEMS: [&str; 12] = [
    "linear",
    "msd-linear",
    "msd-nonlinear",
    "duffing",
    "saturation",
    "deadzone",
    "preisach",
    "bouc-wen",
    "backlash",
    "two-mass",
    "student-t",
    "shock-absorber",
];

/// The cause a generated system hides (None: none).
pub fn expected_cause(system: &str) -> Option<&'static str> {
    match system {
        "linear" | "msd-linear" => None,
        "duffing" | "msd-nonlinear" | "saturation" | "deadzone" => Some("nonlinearity"),
        "preisach" | "bouc-wen" | "backlash" | "shock-absorber" => Some("hysteresis"),
        "two-mass" => Some("dynamics"),
        "student-t" => Some("noise"),
        _ => None,
    }
}

/// A generated experiment pair and what was put into it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Generated {
    /// System name.
    pub system: String,
    /// Seed used.
    pub seed: u64,
    /// Training data.
    pub train: Record,
    /// Validation data (independent input realisation).
    pub validate: Record,
    /// Standard deviation of the added output noise.
    pub noise_std: f64,
    /// NRMSE a perfect model reaches on the validation data: noise std / std(y).
    pub noise_floor_nrmse: f64,
    /// Signal-to-noise ratio in dB (30–33 dB, drawn per seed).
    pub snr_db: f64,
    /// Sample time in seconds.
    pub ts: f64,
    /// The cause hidden in the data, if any.
    pub expected_cause: Option<String>,
    /// The parameters used (name, value).
    pub parameters: Vec<(String, f64)>,
}

#[derive(Debug, Clone)]
struct Params {
    m: f64,
    c: f64,
    k: f64,
    k3: f64,
    sat: f64,
    dead: f64,
    backlash: f64,
    bw: (f64, f64, f64, f64), // alpha, beta, gamma, n (z in force units via alpha)
    preisach_w: f64,
    m2: f64,
    k2: f64,
    c2: f64,
    u_rms: f64,
    student: bool,
}

fn base_params(system: &str, r: &mut impl Rng) -> Result<Params, CoreError> {
    // ±15 % variation of the physical parameters per seed
    let mut v = |x: f64| x * (1.0 + 0.15 * (2.0 * r.random::<f64>() - 1.0));
    let wn = 2.0 * std::f64::consts::PI * v(4.0); // ~4 Hz at fs = 100 Hz
    let m = 1.0;
    let k = m * wn * wn;
    let zeta = v(0.1);
    let mut p = Params {
        m,
        c: 2.0 * zeta * wn * m,
        k,
        k3: 0.0,
        sat: 0.0,
        dead: 0.0,
        backlash: 0.0,
        bw: (0.0, 0.0, 0.0, 1.0),
        preisach_w: 0.0,
        m2: 0.0,
        k2: 0.0,
        c2: 0.0,
        u_rms: k * 0.01, // static displacement ~ 1 cm rms
        student: false,
    };
    match system {
        "linear" | "msd-linear" => {}
        "duffing" | "msd-nonlinear" => {
            // cubic force equals the linear one at about 4 x rms displacement
            p.k3 = v(1.0) * k / (0.04f64).powi(2);
        }
        "saturation" => p.sat = v(0.9) * p.u_rms,
        "deadzone" => p.dead = v(0.6) * p.u_rms,
        "backlash" => p.backlash = v(0.8) * p.u_rms,
        "bouc-wen" | "shock-absorber" => {
            // hysteretic force of the order of the linear spring force
            let alpha = v(if system == "shock-absorber" { 1.2 } else { 0.8 }) * k;
            let zmax = v(0.8) * k * 0.01; // saturation level of z
                                          // for n = 1, z saturates at alpha / (beta + gamma)
            let bg = alpha / zmax;
            p.bw = (alpha, 0.6 * bg, 0.4 * bg, 1.0);
            if system == "shock-absorber" {
                p.c *= 0.5;
            }
        }
        "preisach" => p.preisach_w = v(0.8) * k * 0.01,
        "two-mass" => {
            p.m2 = v(0.5);
            let wn2 = 2.0 * std::f64::consts::PI * v(9.0);
            p.k2 = p.m2 * wn2 * wn2;
            p.c2 = 2.0 * 0.03 * wn2 * p.m2;
        }
        "student-t" => p.student = true,
        other => {
            return Err(CoreError::InvalidArgument(format!(
                "unknown system '{other}' (known: {})",
                SYSTEMS.join(", ")
            )))
        }
    }
    Ok(p)
}

/// Discrete Preisach operator on a triangular relay grid with a Gaussian
/// density centred on the diagonal (used to generate hysteresis data).
struct RelayGrid {
    alpha: Vec<f64>,
    beta: Vec<f64>,
    weight: Vec<f64>,
    state: Vec<f64>,
}

impl RelayGrid {
    fn new(half_range: f64, n: usize) -> Self {
        let mut alpha = vec![];
        let mut beta = vec![];
        let mut weight = vec![];
        for i in 0..n {
            for j in 0..=i {
                let a = -half_range + 2.0 * half_range * (i as f64 + 0.5) / n as f64;
                let b = -half_range + 2.0 * half_range * (j as f64 + 0.5) / n as f64;
                // density: Gaussian in the interaction (α−β) and bias (α+β)/2 coordinates
                let w = (-((a - b) / (0.6 * half_range)).powi(2)).exp()
                    * (-(0.5 * (a + b) / half_range).powi(2)).exp();
                alpha.push(a);
                beta.push(b);
                weight.push(w);
            }
        }
        let s: f64 = weight.iter().sum();
        weight.iter_mut().for_each(|w| *w /= s);
        let state = vec![-1.0; weight.len()];
        Self {
            alpha,
            beta,
            weight,
            state,
        }
    }
    fn demagnetise(&mut self) {
        // relays below the diagonal anti-diagonal split: α+β>0 → −1 else +1
        for i in 0..self.state.len() {
            self.state[i] = if self.alpha[i] + self.beta[i] > 0.0 {
                -1.0
            } else {
                1.0
            };
        }
    }
    fn step(&mut self, x: f64) -> f64 {
        let mut y = 0.0;
        for i in 0..self.state.len() {
            if x >= self.alpha[i] {
                self.state[i] = 1.0;
            } else if x <= self.beta[i] {
                self.state[i] = -1.0;
            }
            y += self.weight[i] * self.state[i];
        }
        y
    }
}

/// Band-limited random input: white Gaussian noise through a 4th-order
/// low-pass (two cascaded 2nd-order sections), scaled to `rms`.
fn random_input(n: usize, rms: f64, seed: u64) -> Vec<f64> {
    let mut r = rng::stream(seed, 1);
    let warm = 200;
    let mut x = vec![0.0; n + warm];
    let (mut a1, mut a2, mut b1, mut b2) = (0.0, 0.0, 0.0, 0.0);
    // resonant low-pass sections, cut-off ~ 0.12 fs
    let (p1, p2) = (1.1, -0.45);
    for v in x.iter_mut() {
        let e: f64 = StandardNormal.sample(&mut r);
        let s1 = p1 * a1 + p2 * a2 + e;
        a2 = a1;
        a1 = s1;
        let s2 = p1 * b1 + p2 * b2 + s1;
        b2 = b1;
        b1 = s2;
        *v = s2;
    }
    let x = x.split_off(warm);
    let s = gb_core::metrics::rms(&x).max(1e-300);
    x.into_iter().map(|v| v * rms / s).collect()
}

fn simulate(p: &Params, u: &[f64], ts: f64) -> Vec<f64> {
    let sub = 10;
    let h = ts / sub as f64;
    // state: x, v, z (Bouc-Wen), x2, v2
    let mut s = [0.0f64; 5];
    let mut play = 0.0f64;
    let mut grid = if p.preisach_w > 0.0 {
        let mut g = RelayGrid::new(0.03, 24);
        g.demagnetise();
        Some(g)
    } else {
        None
    };
    let mut hyst = grid.as_mut().map_or(0.0, |g| g.step(0.0));
    let mut y = Vec::with_capacity(u.len());
    for &uk in u {
        y.push(s[0]);
        // input nonlinearity (static or backlash) applied to the held input
        let mut f = uk;
        if p.sat > 0.0 {
            f = p.sat * (uk / p.sat).tanh();
        }
        if p.dead > 0.0 {
            f = uk - uk.clamp(-p.dead, p.dead);
        }
        if p.backlash > 0.0 {
            if uk - p.backlash > play {
                play = uk - p.backlash;
            } else if uk + p.backlash < play {
                play = uk + p.backlash;
            }
            f = play;
        }
        for _ in 0..sub {
            let deriv = |s: &[f64; 5]| -> [f64; 5] {
                let (x, v, z, x2, v2) = (s[0], s[1], s[2], s[3], s[4]);
                let mut force = f - p.c * v - p.k * x - p.k3 * x * x * x - z - p.preisach_w * hyst;
                let mut dz = 0.0;
                if p.bw.0 > 0.0 {
                    let (al, be, ga, nn) = p.bw;
                    dz = al * v
                        - be * v.abs() * z.abs().powf(nn - 1.0) * z
                        - ga * v * z.abs().powf(nn);
                }
                let (mut dx2, mut dv2) = (0.0, 0.0);
                if p.m2 > 0.0 {
                    let coupling = p.k2 * (x - x2) + p.c2 * (v - v2);
                    force -= coupling;
                    dx2 = v2;
                    dv2 = coupling / p.m2;
                }
                [v, force / p.m, dz, dx2, dv2]
            };
            let k1 = deriv(&s);
            let add = |a: &[f64; 5], b: &[f64; 5], c: f64| -> [f64; 5] {
                let mut o = [0.0; 5];
                for i in 0..5 {
                    o[i] = a[i] + c * b[i];
                }
                o
            };
            let k2 = deriv(&add(&s, &k1, 0.5 * h));
            let k3 = deriv(&add(&s, &k2, 0.5 * h));
            let k4 = deriv(&add(&s, &k3, h));
            for i in 0..5 {
                s[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
            }
            if let Some(g) = grid.as_mut() {
                hyst = g.step(s[0]);
            }
        }
    }
    y
}

/// Largest data set [`generate`] writes (10 million samples).
pub const MAX_GENERATED: usize = 10_000_000;

/// Generate training (8000 samples) and validation (4000 samples) data for
/// `system` with `seed`: fixed seeds give identical files on every platform.
///
/// ```
/// let g = gb_diagnose::systems::generate("linear", 1, 2000, 1000).unwrap();
/// assert_eq!(g.train.len(), 2000);
/// assert!(g.noise_floor_nrmse > 0.0 && g.noise_floor_nrmse < 0.1);
/// ```
pub fn generate(
    system: &str,
    seed: u64,
    n_train: usize,
    n_validate: usize,
) -> Result<Generated, CoreError> {
    if n_train < 100 || n_validate < 100 {
        return Err(CoreError::InvalidArgument(
            "at least 100 samples per data set".into(),
        ));
    }
    if n_train > MAX_GENERATED || n_validate > MAX_GENERATED {
        return Err(CoreError::InvalidArgument(format!(
            "at most {MAX_GENERATED} samples per data set"
        )));
    }
    let mut r = rng::stream(seed, 0);
    let p = base_params(system, &mut r)?;
    let ts = 0.01;
    let snr_db = 30.0 + 3.0 * r.random::<f64>();
    let u_tr = random_input(n_train, p.u_rms, seed.wrapping_mul(2).wrapping_add(11));
    let u_va = random_input(n_validate, p.u_rms, seed.wrapping_mul(2).wrapping_add(12));
    let y_tr = simulate(&p, &u_tr, ts);
    let y_va = simulate(&p, &u_va, ts);
    if y_tr.iter().chain(&y_va).any(|v| !v.is_finite()) {
        return Err(CoreError::InvalidArgument(format!(
            "simulation of '{system}' diverged"
        )));
    }
    let noise_std = gb_core::metrics::std(&y_tr) * 10f64.powf(-snr_db / 20.0);
    let mut rn = rng::stream(seed, 2);
    let tdist = StudentT::new(3.0).map_err(|e| CoreError::InvalidArgument(e.to_string()))?;
    let mut noise = |n: usize| -> Vec<f64> {
        (0..n)
            .map(|_| {
                if p.student {
                    // scaled so that the standard deviation is noise_std (var of t3 = 3)
                    noise_std / 3f64.sqrt() * tdist.sample(&mut rn)
                } else {
                    let e: f64 = StandardNormal.sample(&mut rn);
                    noise_std * e
                }
            })
            .collect()
    };
    let n_tr = noise(n_train);
    let n_va = noise(n_validate);
    let ytr: Vec<f64> = y_tr.iter().zip(&n_tr).map(|(a, b)| a + b).collect();
    let yva: Vec<f64> = y_va.iter().zip(&n_va).map(|(a, b)| a + b).collect();
    let floor = noise_std / gb_core::metrics::std(&yva);
    let names = vec!["u".to_string()];
    let parameters = vec![
        ("m".into(), p.m),
        ("c".into(), p.c),
        ("k".into(), p.k),
        ("k3".into(), p.k3),
        ("saturation".into(), p.sat),
        ("deadzone".into(), p.dead),
        ("backlash".into(), p.backlash),
        ("bouc_wen_alpha".into(), p.bw.0),
        ("bouc_wen_beta".into(), p.bw.1),
        ("bouc_wen_gamma".into(), p.bw.2),
        ("preisach_weight".into(), p.preisach_w),
        ("m2".into(), p.m2),
        ("k2".into(), p.k2),
        ("c2".into(), p.c2),
        ("u_rms".into(), p.u_rms),
    ];
    Ok(Generated {
        system: system.to_string(),
        seed,
        train: Record::new(names.clone(), "y".into(), vec![u_tr], ytr)?,
        validate: Record::new(names, "y".into(), vec![u_va], yva)?,
        noise_std,
        noise_floor_nrmse: floor,
        snr_db,
        ts,
        expected_cause: expected_cause(system).map(str::to_string),
        parameters,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_system_generates_finite_data() {
        for s in SYSTEMS {
            let g = generate(s, 3, 500, 300).unwrap();
            assert!(g.train.output.iter().all(|v| v.is_finite()), "{s}");
            assert!(gb_core::metrics::std(&g.train.output) > 0.0, "{s}");
        }
        assert!(generate("nope", 1, 500, 500).is_err());
    }

    #[test]
    fn same_seed_same_data_other_seed_other_data() {
        let a = generate("duffing", 5, 300, 200).unwrap();
        let b = generate("duffing", 5, 300, 200).unwrap();
        let c = generate("duffing", 6, 300, 200).unwrap();
        assert_eq!(a.train, b.train);
        assert_ne!(a.train.output, c.train.output);
    }

    #[test]
    fn relay_grid_shows_hysteresis_and_wiping_out() {
        let mut g = RelayGrid::new(1.0, 20);
        g.demagnetise();
        // going up to 0.5 and back to 0 leaves a different output than at the start
        let y0 = g.step(0.0);
        g.step(0.5);
        let y1 = g.step(0.0);
        assert!(y1 > y0 + 1e-3);
        // saturating positively then returning wipes out the history
        g.step(1.0);
        let a = g.step(0.2);
        g.step(-0.3);
        g.step(1.0);
        let b = g.step(0.2);
        assert!((a - b).abs() < 1e-12);
    }
}
