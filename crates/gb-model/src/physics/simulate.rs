//! The discretisation: classical RK4 with `substeps` steps of
//! `h = Ts / substeps` per sample, the input held constant over the sample
//! (zero-order hold), `y_k = g(x_k, u_k, θ)` before the step. With
//! sensitivities the same RK4 steps run on `(x, S)`, `Ṡ = f_x S + f_θ`:
//! every stage's derivative lanes are the tape's directional derivatives
//! along the stage's sensitivity rows, so `S` is the exact derivative of
//! the discrete RK4 map (explicit RK commutes with differentiation) and
//! `∂y_k/∂θ = g_x S_k + g_θ`.
//!
//! An input delay `d` (a parameter) splits into a shift of
//! `D = max(0, ⌈d/Ts⌉)` samples and an offset `τ = D·Ts − d ≥ 0`:
//! `y_k = ỹ_{k−D}` (the first `D` outputs are `g(x₀, u₀)`: the input has
//! not acted yet), where `ỹ_j = g(x(t_j + τ), u_j)` is the output after
//! the held input `u_j` has acted for `τ` (`substeps` RK4 steps of `τ /
//! substeps` from `x_j`, per started sample of `τ`). The state recursion
//! does not depend on `d`; the offset step carries `∂τ/∂d = −1` in the
//! delay's lane (the stage points' `a = c·τ/m` differentiate to `−c/m`),
//! so `∂y/∂d` is again the exact derivative of the discrete map.
use super::spec::Compiled;
use super::tape::{DualPlan, Slots, Tape};

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
    /// The lane work of `f` and `g` (with lanes only).
    plans: Option<(DualPlan, DualPlan)>,
    h: f64,
    substeps: usize,
    /// Some state has a finite `min` or `max` (else no clamping).
    bounded: bool,
    x: Vec<f64>,
    xt: Vec<f64>,
    /// The sample state kept while the offset step runs.
    xo: Vec<f64>,
    so: Vec<f64>,
    /// Input delay: shift `D` (samples), offset `τ` (s), its RK4 steps and
    /// the delay's derivative lane.
    shift: usize,
    tau: f64,
    tau_steps: usize,
    delay_lane: Option<usize>,
    k: [Vec<f64>; 4],
    /// Sensitivities `S` (n × lanes, row-major) and their stage copies.
    s: Vec<f64>,
    st: Vec<f64>,
    ks: [Vec<f64>; 4],
    /// The relay states of the Preisach operators on states, and a
    /// buffer of one operator's cell outputs.
    ops: Vec<gb_preisach::RelayCellsState>,
    cols: Vec<f64>,
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
        let plans = (l > 0).then(|| {
            let plan = |t: &Tape| t.dual_plan(n, nu, &lanes.param, l);
            (plan(&c.f), plan(&c.g))
        });
        match &plans {
            None => {
                c.f.run_pre(&mut fs);
                c.g.run_pre(&mut gs);
            }
            Some((fp, gp)) => {
                c.f.run_pre_dual(&mut fs, fp);
                c.g.run_pre_dual(&mut gs, gp);
            }
        }
        let z = |m: usize| vec![0.0; m];
        let (shift, tau) = c.delay.map_or((0, 0.0), |p| split_delay(theta[p], ts));
        // capped: a delay far below −Ts is a modelling error, not a workload
        let tau_steps = substeps * ((tau / ts).ceil().clamp(1.0, 64.0) as usize);
        let delay_lane = c.delay.and_then(|p| lanes.param.get(p).copied().flatten());
        Self {
            c,
            fs,
            gs,
            plans,
            h: ts / substeps as f64,
            substeps,
            xo: z(n),
            so: z(n * l),
            shift,
            tau,
            tau_steps,
            delay_lane,
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
            ops: c.ops.iter().map(|o| o.cells.relay_states(0.0)).collect(),
            cols: z(c.ops.iter().map(|o| o.cells.n_cells()).max().unwrap_or(0)),
        }
    }

    /// Start at `x0`; with lanes, `S(0)` has a 1 at each free initial
    /// state's lane.
    pub(crate) fn reset(&mut self, x0: &[f64], lanes: &Lanes) {
        self.x.copy_from_slice(x0);
        for (o, st) in self.c.ops.iter().zip(&mut self.ops) {
            *st = o.cells.relay_states(o.grid_input(x0));
        }
        self.s.fill(0.0);
        for (i, lane) in lanes.state.iter().enumerate() {
            if let Some(k) = lane {
                self.s[i * lanes.n + k] = 1.0;
            }
        }
    }

    /// The current state.
    pub(crate) fn state(&self) -> &[f64] {
        &self.x
    }

    /// Set the held input of this sample (and the tapes' input-only nodes);
    /// the Preisach cells switch with the current state.
    #[inline]
    pub(crate) fn set_input(&mut self, u: impl Iterator<Item = f64>) {
        let n = self.c.n;
        for (j, v) in u.enumerate() {
            self.fs.v[n + j] = v;
            self.gs.v[n + j] = v;
        }
        self.switch_cells(true);
        match &self.plans {
            None => {
                self.c.f.run_input(&mut self.fs);
                self.c.g.run_input(&mut self.gs);
            }
            Some((fp, gp)) => {
                self.c.f.run_input_dual(&mut self.fs, fp);
                self.c.g.run_input_dual(&mut self.gs, gp);
            }
        }
    }

    /// Switch the Preisach cells with the current state and write their
    /// outputs into the input slots of `f` (and of `g` when `both`).
    #[inline]
    fn switch_cells(&mut self, both: bool) {
        for (o, st) in self.c.ops.iter().zip(&mut self.ops) {
            let m = o.cells.n_cells();
            let cols = &mut self.cols[..m];
            o.cells.step(st, o.grid_input(&self.x), cols);
            self.fs.v[o.slot..o.slot + m].copy_from_slice(cols);
            if both {
                self.gs.v[o.slot..o.slot + m].copy_from_slice(cols);
            }
        }
    }

    /// Between the RK4 sub-steps of a sample: the cells switch with the
    /// state and `f`'s input-only nodes are recomputed.
    fn switch_cells_f(&mut self) {
        self.switch_cells(false);
        match &self.plans {
            None => self.c.f.run_input(&mut self.fs),
            Some((fp, _)) => self.c.f.run_input_dual(&mut self.fs, fp),
        }
    }

    /// The input delay's shift `D` in samples: `y_k = ỹ_{k−D}`.
    pub(crate) fn shift(&self) -> usize {
        self.shift
    }

    /// The output `ỹ` of this sample: `g` after the held input has acted
    /// for the delay's offset `τ` (without a delay: `g(x, u)`).
    #[inline]
    pub(crate) fn output(&mut self, y: &mut [f64]) {
        if self.tau > 0.0 {
            self.xo.copy_from_slice(&self.x);
            let m = self.tau_steps;
            self.advance(self.tau / m as f64, m);
            self.output_now(y);
            self.x.copy_from_slice(&self.xo);
        } else {
            self.output_now(y);
        }
    }

    /// [`output`](Self::output) with derivatives (`dy[o * lanes + l]`).
    pub(crate) fn output_dual(&mut self, y: &mut [f64], dy: &mut [f64]) {
        if self.tau > 0.0 || self.delay_lane.is_some() {
            self.xo.copy_from_slice(&self.x);
            self.so.copy_from_slice(&self.s);
            let m = self.tau_steps as f64;
            let lane = self.delay_lane.map(|l| (l, -1.0 / m));
            self.advance_dual(self.tau / m, self.tau_steps, lane);
            self.output_dual_now(y, dy);
            self.x.copy_from_slice(&self.xo);
            self.s.copy_from_slice(&self.so);
        } else {
            self.output_dual_now(y, dy);
        }
    }

    /// Outputs `y = g(x, u)` into `y` (one per output): under a delay of
    /// `D` samples, the first `D` outputs (the input has not acted yet).
    #[inline]
    pub(crate) fn output_now(&mut self, y: &mut [f64]) {
        let n = self.c.n;
        self.gs.v[..n].copy_from_slice(&self.x);
        self.c.g.run(&mut self.gs);
        for (o, yo) in y.iter_mut().enumerate() {
            *yo = self.c.g.out(&self.gs, o);
        }
    }

    /// Outputs and their derivatives (`dy[o * lanes + l]`).
    pub(crate) fn output_dual_now(&mut self, y: &mut [f64], dy: &mut [f64]) {
        let (n, l) = (self.c.n, self.gs.lanes);
        self.gs.v[..n].copy_from_slice(&self.x);
        self.gs.d[..n * l].copy_from_slice(&self.s);
        match &self.plans {
            Some((_, gp)) => self.c.g.run_dual(&mut self.gs, gp),
            None => self.c.g.run_unfused(&mut self.gs),
        }
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
        if self.c.ops.is_empty() {
            return self.advance(self.h, self.substeps);
        }
        for i in 0..self.substeps {
            if i > 0 {
                self.switch_cells_f();
            }
            if !self.advance(self.h, 1) {
                return false;
            }
        }
        true
    }

    /// `steps` RK4 steps of `h` with the held input: [`advance_n`] for up
    /// to 4 states, else [`advance_any`] (the same arithmetic).
    ///
    /// [`advance_n`]: Self::advance_n
    /// [`advance_any`]: Self::advance_any
    #[inline]
    fn advance(&mut self, h: f64, steps: usize) -> bool {
        match self.c.n {
            1 => self.advance_n::<1>(h, steps),
            2 => self.advance_n::<2>(h, steps),
            3 => self.advance_n::<3>(h, steps),
            4 => self.advance_n::<4>(h, steps),
            _ => self.advance_any(h, steps),
        }
    }

    /// [`advance`](Self::advance) for `N` states: the state and the stages
    /// `k₁…k₄` in registers, `x + a·k` written into the state slots,
    /// `x ← x + h/6·(k₁ + 2(k₂ + k₃) + k₄)` (clamped into the ranges).
    #[inline(always)]
    fn advance_n<const N: usize>(&mut self, h: f64, steps: usize) -> bool {
        let c = self.c;
        let v = &mut self.fs.v[..];
        let tape = &c.f;
        let outs: [usize; N] = std::array::from_fn(|i| tape.output_slot(i));
        // the unchecked reads below rely on this (the tape's outputs lie
        // below its slot count: `Tape::check_slots`)
        assert!(N <= v.len() && outs.iter().all(|&o| o < v.len()));
        let last: [bool; N] = std::array::from_fn(|i| tape.last_slot() == Some(outs[i]));
        let outs = (&outs, &last);
        let range: [(f64, f64); N] = std::array::from_fn(|i| c.range[i]);
        let clamp = |p: [f64; N]| -> [f64; N] {
            if self.bounded {
                std::array::from_fn(|i| p[i].max(range[i].0).min(range[i].1))
            } else {
                p
            }
        };
        let stage = |x: &[f64; N], a: f64, k: &[f64; N]| -> [f64; N] {
            clamp(std::array::from_fn(|i| x[i] + a * k[i]))
        };
        let mut x: [f64; N] = std::array::from_fn(|i| self.x[i]);
        for _ in 0..steps {
            let k1 = rhs_at(tape, v, outs, &x);
            let k2 = rhs_at(tape, v, outs, &stage(&x, 0.5 * h, &k1));
            let k3 = rhs_at(tape, v, outs, &stage(&x, 0.5 * h, &k2));
            let k4 = rhs_at(tape, v, outs, &stage(&x, h, &k3));
            x = clamp(std::array::from_fn(|i| {
                x[i] + h / 6.0 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i])
            }));
        }
        self.x[..N].copy_from_slice(&x);
        x.iter().all(|v| v.is_finite())
    }

    /// [`advance`](Self::advance) for any number of states.
    fn advance_any(&mut self, h: f64, steps: usize) -> bool {
        let n = self.c.n;
        self.fs.v[..n].copy_from_slice(&self.x);
        for _ in 0..steps {
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
        match &self.plans {
            Some((fp, _)) => self.c.f.run_dual(&mut self.fs, fp),
            None => self.c.f.run_unfused(&mut self.fs),
        }
        for i in 0..n {
            self.k[stage][i] = self.c.f.out(&self.fs, i);
            self.ks[stage][i * l..(i + 1) * l].copy_from_slice(self.c.f.out_lanes(&self.fs, i));
        }
    }

    /// The stage point `x + a·k`, `S + a·k_S`; with `lane = (l, a')`,
    /// `a' = ∂a/∂d` adds `a'·k` to the delay's lane.
    fn stage_point(&mut self, stage: usize, a: f64, lane: Option<(usize, f64)>) {
        for (j, st) in self.st.iter_mut().enumerate() {
            *st = self.s[j] + a * self.ks[stage][j];
        }
        let l = self.st.len() / self.xt.len().max(1);
        if let Some((lane, da)) = lane {
            for (i, k) in self.k[stage].iter().enumerate() {
                self.st[i * l + lane] += da * k;
            }
        }
        for (i, xt) in self.xt.iter_mut().enumerate() {
            *xt = self.x[i] + a * self.k[stage][i];
            if clamp_to(xt, self.c.range[i]) {
                self.st[i * l..(i + 1) * l].fill(0.0);
            }
        }
    }

    /// One sample with sensitivities.
    pub(crate) fn step_dual(&mut self) -> bool {
        if self.c.ops.is_empty() {
            return self.advance_dual(self.h, self.substeps, None);
        }
        for i in 0..self.substeps {
            if i > 0 {
                self.switch_cells_f();
            }
            if !self.advance_dual(self.h, 1, None) {
                return false;
            }
        }
        true
    }

    /// `steps` RK4 steps of `h` on `(x, S)`; with `lane = (l, h')`,
    /// `h' = ∂h/∂d` carries the step's dependence on the delay in lane `l`.
    fn advance_dual(&mut self, h: f64, steps: usize, lane: Option<(usize, f64)>) -> bool {
        let half = lane.map(|(l, dh)| (l, 0.5 * dh));
        for _ in 0..steps {
            self.rhs_dual(0, false);
            self.stage_point(0, 0.5 * h, half);
            self.rhs_dual(1, true);
            self.stage_point(1, 0.5 * h, half);
            self.rhs_dual(2, true);
            self.stage_point(2, h, lane);
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
            if let Some((lane, dh)) = lane {
                let [k1, k2, k3, k4] = &self.k;
                for i in 0..self.x.len() {
                    self.s[i * l + lane] += dh / 6.0 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]);
                }
            }
            for (i, x) in self.x.iter_mut().enumerate() {
                if clamp_to(x, self.c.range[i]) {
                    self.s[i * l..(i + 1) * l].fill(0.0);
                }
            }
        }
        self.x.iter().all(|v| v.is_finite()) && self.s.iter().all(|v| v.is_finite())
    }
}

/// `f(p)`: the tape run with the state slots set to `p`, its outputs read
/// from the slots `outs` (each below `v.len()`, which the caller asserts)
/// or, where `last[i]`, taken from the last node's result (kept in a
/// register: no wait for its store to reach a load).
#[inline(always)]
fn rhs_at<const N: usize>(
    tape: &Tape,
    v: &mut [f64],
    (outs, last): (&[usize; N], &[bool; N]),
    p: &[f64; N],
) -> [f64; N] {
    v[..N].copy_from_slice(p);
    let r = tape.run_values(v);
    std::array::from_fn(|i| {
        if last[i] {
            r
        } else {
            // SAFETY: every `outs[i] < v.len()` (the caller's assertion).
            unsafe { *v.get_unchecked(outs[i]) }
        }
    })
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

/// The shift `D = max(0, ⌈d/Ts⌉)` and offset `τ = D·Ts − d` of an input
/// delay `d` (a non-finite delay: none).
fn split_delay(d: f64, ts: f64) -> (usize, f64) {
    if !d.is_finite() || d <= 0.0 {
        return (0, if d.is_finite() { -d } else { 0.0 });
    }
    let shift = (d / ts).ceil().max(1.0);
    (shift as usize, (shift * ts - d).max(0.0))
}

/// The samples to simulate for `len` outputs under a shift `D`.
#[inline]
fn samples_needed(len: usize, shift: usize) -> usize {
    if len == 0 {
        0
    } else {
        len.saturating_sub(shift).max(1)
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
    let shift = it.shift();
    for t in 0..samples_needed(len, shift) {
        it.set_input(u.iter().map(|s| s[t]));
        if t == 0 && shift > 0 {
            // before the delayed input acts: the initial state's output
            it.output_now(&mut yk);
            for k in 0..shift.min(len) {
                for (o, v) in yk.iter().enumerate() {
                    y[o * len + k] = *v;
                }
            }
        }
        it.output(&mut yk);
        if t + shift < len {
            for (o, v) in yk.iter().enumerate() {
                y[o * len + t + shift] = *v;
            }
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
    let shift = it.shift();
    for t in 0..samples_needed(len, shift) {
        it.set_input(u.iter().map(|s| s[t]));
        if t == 0 && shift > 0 {
            it.output_dual_now(&mut yk, &mut dyk);
            for k in 0..shift.min(len) {
                sink(k, &yk, &dyk);
            }
        }
        it.output_dual(&mut yk, &mut dyk);
        if !yk.iter().all(|v| v.is_finite()) {
            return Err(t);
        }
        if t + shift < len {
            sink(t + shift, &yk, &dyk);
        }
        if !it.step_dual() {
            return Err(t);
        }
    }
    Ok(())
}
