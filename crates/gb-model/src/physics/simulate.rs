//! The discretisation: classical RK4 with `substeps` steps of
//! `h = Ts / substeps` per sample, the input held constant over the sample
//! (zero-order hold), `y_k = g(x_k, u_k, θ)` before the step. With
//! sensitivities the same RK4 steps run on `(x, S)`, `Ṡ = f_x S + f_θ`:
//! every stage's derivative lanes are the tape's directional derivatives
//! along the stage's sensitivity rows, so `S` is the exact derivative of
//! the discrete RK4 map (explicit RK commutes with differentiation) and
//! `∂y_k/∂θ = g_x S_k + g_θ`.
use super::spec::Compiled;
use super::tape::Slots;

/// Which derivative lane each free parameter and each free initial state
/// has (`None`: fixed).
#[derive(Debug, Clone, PartialEq, Default)]
pub(crate) struct Lanes {
    /// Per parameter.
    pub(crate) param: Vec<Option<usize>>,
    /// Per state (its initial value).
    pub(crate) state: Vec<Option<usize>>,
    /// Number of lanes.
    pub(crate) n: usize,
}

/// The scratch of one simulation (slots of both tapes, stage buffers).
#[derive(Debug, Clone)]
pub(crate) struct Integrator<'c> {
    c: &'c Compiled,
    fs: Slots,
    gs: Slots,
    h: f64,
    substeps: usize,
    /// Some state has a finite `min` or `max` (else no clamping).
    bounded: bool,
    x: Vec<f64>,
    xt: Vec<f64>,
    k: [Vec<f64>; 4],
    /// Sensitivities `S` (n × lanes, row-major) and their stage copies.
    s: Vec<f64>,
    st: Vec<f64>,
    ks: [Vec<f64>; 4],
}

impl<'c> Integrator<'c> {
    /// An integrator with parameters `theta`, step `ts / substeps`, and
    /// `lanes` derivative lanes (0: values only).
    pub(crate) fn new(
        c: &'c Compiled,
        theta: &[f64],
        ts: f64,
        substeps: usize,
        lanes: &Lanes,
    ) -> Self {
        let (n, nu, l) = (c.n, c.nu, lanes.n);
        let mut fs = c.f.slots(l);
        let mut gs = c.g.slots(l);
        for s in [&mut fs, &mut gs] {
            s.v[n + nu..n + nu + theta.len()].copy_from_slice(theta);
            for (p, lane) in lanes.param.iter().enumerate() {
                if let Some(k) = lane {
                    s.d[(n + nu + p) * l + k] = 1.0;
                }
            }
        }
        if l == 0 {
            c.f.run_pre(&mut fs);
            c.g.run_pre(&mut gs);
        } else {
            c.f.run_pre_dual(&mut fs);
            c.g.run_pre_dual(&mut gs);
        }
        let z = |m: usize| vec![0.0; m];
        Self {
            c,
            fs,
            gs,
            h: ts / substeps as f64,
            substeps,
            bounded: c
                .range
                .iter()
                .any(|&(lo, hi)| lo > f64::NEG_INFINITY || hi < f64::INFINITY),
            x: z(n),
            xt: z(n),
            k: [z(n), z(n), z(n), z(n)],
            s: z(n * l),
            st: z(n * l),
            ks: [z(n * l), z(n * l), z(n * l), z(n * l)],
        }
    }

    /// Start at `x0`; with lanes, `S(0)` has a 1 at each free initial
    /// state's lane.
    pub(crate) fn reset(&mut self, x0: &[f64], lanes: &Lanes) {
        self.x.copy_from_slice(x0);
        self.s.fill(0.0);
        for (i, lane) in lanes.state.iter().enumerate() {
            if let Some(k) = lane {
                self.s[i * lanes.n + k] = 1.0;
            }
        }
    }

    /// Set the held input of this sample.
    #[inline]
    /// The current state.
    pub(crate) fn state(&self) -> &[f64] {
        &self.x
    }

    pub(crate) fn set_input(&mut self, u: impl Iterator<Item = f64>) {
        let n = self.c.n;
        for (j, v) in u.enumerate() {
            self.fs.v[n + j] = v;
            self.gs.v[n + j] = v;
        }
    }

    /// Outputs `y = g(x, u)` into `y` (one per output).
    #[inline]
    pub(crate) fn output(&mut self, y: &mut [f64]) {
        let n = self.c.n;
        self.gs.v[..n].copy_from_slice(&self.x);
        self.c.g.run(&mut self.gs);
        for (o, yo) in y.iter_mut().enumerate() {
            *yo = self.c.g.out(&self.gs, o);
        }
    }

    /// Outputs and their derivatives (`dy[o * lanes + l]`).
    pub(crate) fn output_dual(&mut self, y: &mut [f64], dy: &mut [f64]) {
        let (n, l) = (self.c.n, self.gs.lanes);
        self.gs.v[..n].copy_from_slice(&self.x);
        self.gs.d[..n * l].copy_from_slice(&self.s);
        self.c.g.run_dual(&mut self.gs);
        for (o, yo) in y.iter_mut().enumerate() {
            *yo = self.c.g.out(&self.gs, o);
            dy[o * l..(o + 1) * l].copy_from_slice(self.c.g.out_lanes(&self.gs, o));
        }
    }

    /// `k[stage] = f(state slots, u)`: the tape run on the state already
    /// in the first `n` slots.
    #[inline(always)]
    fn rhs(&mut self, stage: usize) {
        self.c.f.run(&mut self.fs);
        let k = &mut self.k[stage];
        for (i, ki) in k.iter_mut().enumerate() {
            *ki = self.c.f.out(&self.fs, i);
        }
    }

    /// The stage point `x + a·k[stage]`, written straight into the state
    /// slots of `f` (no copy per stage).
    #[inline(always)]
    fn stage_slots(&mut self, stage: usize, a: f64) {
        let k = &self.k[stage];
        if !self.bounded {
            for ((v, x), ki) in self.fs.v.iter_mut().zip(&self.x).zip(k) {
                *v = x + a * ki;
            }
            return;
        }
        for (((v, x), ki), &(lo, hi)) in self.fs.v.iter_mut().zip(&self.x).zip(k).zip(&self.c.range)
        {
            *v = (x + a * ki).max(lo).min(hi);
        }
    }

    /// One sample: `substeps` RK4 steps with the held input. `false`
    /// when the state left the finite numbers.
    #[inline]
    pub(crate) fn step(&mut self) -> bool {
        let (h, n) = (self.h, self.c.n);
        self.fs.v[..n].copy_from_slice(&self.x);
        for _ in 0..self.substeps {
            self.rhs(0);
            self.stage_slots(0, 0.5 * h);
            self.rhs(1);
            self.stage_slots(1, 0.5 * h);
            self.rhs(2);
            self.stage_slots(2, h);
            self.rhs(3);
            let [k1, k2, k3, k4] = &self.k;
            // the new state, also into the slots of the next sub-step
            for (i, (x, v)) in self.x.iter_mut().zip(&mut self.fs.v).enumerate() {
                let next = *x + h / 6.0 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]);
                *x = if self.bounded {
                    let (lo, hi) = self.c.range[i];
                    next.max(lo).min(hi)
                } else {
                    next
                };
                *v = *x;
            }
        }
        self.x.iter().all(|v| v.is_finite())
    }

    fn rhs_dual(&mut self, stage: usize, from_t: bool) {
        let (n, l) = (self.c.n, self.fs.lanes);
        let (x, s) = if from_t {
            (&self.xt, &self.st)
        } else {
            (&self.x, &self.s)
        };
        self.fs.v[..n].copy_from_slice(x);
        self.fs.d[..n * l].copy_from_slice(s);
        self.c.f.run_dual(&mut self.fs);
        for i in 0..n {
            self.k[stage][i] = self.c.f.out(&self.fs, i);
            self.ks[stage][i * l..(i + 1) * l].copy_from_slice(self.c.f.out_lanes(&self.fs, i));
        }
    }

    fn stage_point(&mut self, stage: usize, a: f64) {
        for (j, st) in self.st.iter_mut().enumerate() {
            *st = self.s[j] + a * self.ks[stage][j];
        }
        let l = self.st.len() / self.xt.len().max(1);
        for (i, xt) in self.xt.iter_mut().enumerate() {
            *xt = self.x[i] + a * self.k[stage][i];
            if clamp_to(xt, self.c.range[i]) {
                self.st[i * l..(i + 1) * l].fill(0.0);
            }
        }
    }

    /// One sample with sensitivities.
    pub(crate) fn step_dual(&mut self) -> bool {
        let h = self.h;
        for _ in 0..self.substeps {
            self.rhs_dual(0, false);
            self.stage_point(0, 0.5 * h);
            self.rhs_dual(1, true);
            self.stage_point(1, 0.5 * h);
            self.rhs_dual(2, true);
            self.stage_point(2, h);
            self.rhs_dual(3, true);
            let [k1, k2, k3, k4] = &self.k;
            for (i, x) in self.x.iter_mut().enumerate() {
                *x += h / 6.0 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]);
            }
            let [k1, k2, k3, k4] = &self.ks;
            for (j, s) in self.s.iter_mut().enumerate() {
                *s += h / 6.0 * (k1[j] + 2.0 * (k2[j] + k3[j]) + k4[j]);
            }
            let l = self.s.len() / self.x.len().max(1);
            for (i, x) in self.x.iter_mut().enumerate() {
                if clamp_to(x, self.c.range[i]) {
                    self.s[i * l..(i + 1) * l].fill(0.0);
                }
            }
        }
        self.x.iter().all(|v| v.is_finite()) && self.s.iter().all(|v| v.is_finite())
    }
}

/// Clamp `x` into `[lo, hi]`; `true` when it was outside (its
/// sensitivity is then 0: the bound does not move with θ).
#[inline]
fn clamp_to(x: &mut f64, (lo, hi): (f64, f64)) -> bool {
    if *x < lo {
        *x = lo;
        true
    } else if *x > hi {
        *x = hi;
        true
    } else {
        false
    }
}

/// Free-run simulation from `x0` into `y` (output-major, `ny · N`).
/// `Err(k)`: the state became non-finite at sample `k`.
pub(crate) fn simulate(
    c: &Compiled,
    theta: &[f64],
    x0: &[f64],
    u: &[&[f64]],
    ts: f64,
    substeps: usize,
    y: &mut [f64],
) -> Result<(), usize> {
    let ny = c.g.n_outputs();
    let len = y.len() / ny.max(1);
    let lanes = Lanes::default();
    let mut it = Integrator::new(c, theta, ts, substeps, &lanes);
    it.reset(x0, &lanes);
    let mut yk = vec![0.0; ny];
    for t in 0..len {
        it.set_input(u.iter().map(|s| s[t]));
        it.output(&mut yk);
        for (o, v) in yk.iter().enumerate() {
            y[o * len + t] = *v;
        }
        if !yk.iter().all(|v| v.is_finite()) || !it.step() {
            return Err(t);
        }
    }
    Ok(())
}

/// Simulation of `len` samples with sensitivities: `sink(k, y_k, dy_k)`
/// for every sample (`dy_k[o * lanes + l] = ∂y_{k,o}/∂θ_l`).
#[allow(clippy::too_many_arguments)]
pub(crate) fn simulate_dual(
    c: &Compiled,
    theta: &[f64],
    x0: &[f64],
    u: &[&[f64]],
    ts: f64,
    substeps: usize,
    len: usize,
    lanes: &Lanes,
    mut sink: impl FnMut(usize, &[f64], &[f64]),
) -> Result<(), usize> {
    let ny = c.g.n_outputs();
    let mut it = Integrator::new(c, theta, ts, substeps, lanes);
    it.reset(x0, lanes);
    let mut yk = vec![0.0; ny];
    let mut dyk = vec![0.0; ny * lanes.n];
    for t in 0..len {
        it.set_input(u.iter().map(|s| s[t]));
        it.output_dual(&mut yk, &mut dyk);
        if !yk.iter().all(|v| v.is_finite()) {
            return Err(t);
        }
        sink(t, &yk, &dyk);
        if !it.step_dual() {
            return Err(t);
        }
    }
    Ok(())
}
