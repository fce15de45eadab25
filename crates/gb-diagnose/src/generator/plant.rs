//! Continuous-time plants sampled with a zero-order-hold input and
//! integrated with RK4 sub-steps.
//!
//! The sampled output at k is taken before the input u(k) is applied, so
//! the dynamics respond from u(k−1) on (one sample of transport, as for any
//! ZOH-sampled strictly proper system); a direct feedthrough term D·f(k)
//! and an integer input delay d come on top.
use super::maps::{InputMap, OutputMap, RelayGrid};
use gb_core::CoreError;

const NS: usize = 8;
type State = [f64; NS];

/// One section of a cascade with unit DC gain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Section {
    /// τ ẋ = w − x
    First { tau: f64 },
    /// ẍ = ω²(w − x) − 2ζω ẋ
    Second { wn: f64, zeta: f64 },
}

/// A mass on a spring with damping and optional nonlinear forces.
/// States: x, v, z (Bouc–Wen), x₂, v₂ (second mass).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Mech {
    pub m: f64,
    pub c: f64,
    pub k: f64,
    /// cubic spring k₃x³
    pub k3: f64,
    /// Coulomb friction level F_c·tanh(v/ε)
    pub coulomb: f64,
    pub eps: f64,
    /// Bouc–Wen (α, β, γ), n = 1: ż = αv − β|v|z − γv|z|
    pub bouc_wen: Option<[f64; 3]>,
    /// Preisach spring: weight (force) and relay grid on x
    pub preisach: Option<(f64, RelayGrid)>,
    /// second mass (m₂, k₂, c₂) coupled to the first
    pub second: Option<[f64; 3]>,
    pub velocity_output: bool,
}

impl Mech {
    pub(crate) fn linear(m: f64, c: f64, k: f64) -> Self {
        Self {
            m,
            c,
            k,
            k3: 0.0,
            coulomb: 0.0,
            eps: 1.0,
            bouc_wen: None,
            preisach: None,
            second: None,
            velocity_output: false,
        }
    }
}

/// The continuous dynamics.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Core {
    Cascade(Vec<Section>),
    Mech(Mech),
}

/// A sampled system: input maps → gains → (delay) → dynamics (+ feedthrough)
/// → output map.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct System {
    pub core: Core,
    /// per input
    pub input_maps: Vec<InputMap>,
    /// per input: force (or cascade input) per mapped input unit
    pub gains: Vec<f64>,
    /// per input: physical rms of the excitation
    pub input_scale: Vec<f64>,
    pub output_map: OutputMap,
    /// input delay in samples
    pub delay: usize,
    /// direct feedthrough D: y(k) += D·f(k)
    pub feedthrough: f64,
    pub ts: f64,
    pub sub: usize,
}

/// Signals recorded by [`System::simulate`] besides the output.
#[derive(Debug, Default, Clone)]
pub(crate) struct Trace {
    pub x: Vec<f64>,
    pub v: Vec<f64>,
    pub force: Vec<f64>,
}

impl System {
    pub(crate) fn new(core: Core, n_inputs: usize) -> Self {
        Self {
            core,
            input_maps: vec![InputMap::Identity; n_inputs],
            gains: vec![1.0; n_inputs],
            input_scale: vec![1.0; n_inputs],
            output_map: OutputMap::Identity,
            delay: 0,
            feedthrough: 0.0,
            ts: 1.0,
            sub: 4,
        }
    }

    /// Number of inputs.
    pub(crate) fn n_inputs(&self) -> usize {
        self.gains.len()
    }

    /// Fastest rate (rad/s) of the dynamics, with `hint` for amplitude-
    /// dependent terms the parameters alone do not show.
    fn fastest_rate(&self, hint: f64) -> f64 {
        let mut r = hint;
        match &self.core {
            Core::Cascade(s) => {
                for sec in s {
                    r = r.max(match *sec {
                        Section::First { tau } => 1.0 / tau,
                        Section::Second { wn, zeta } => wn * (1.0 + zeta),
                    });
                }
            }
            Core::Mech(m) => {
                let mut k = m.k;
                if let Some([a, _, _]) = m.bouc_wen {
                    k += a;
                }
                if let Some([m2, k2, c2]) = m.second {
                    k += k2;
                    r = r.max((k2 * (1.0 / m2 + 1.0 / m.m)).sqrt() + c2 / m2);
                }
                r = r.max((k / m.m).sqrt() + m.c / m.m);
                if m.coulomb > 0.0 {
                    r = r.max(m.coulomb / (m.m * m.eps));
                }
            }
        }
        r
    }

    /// Choose the RK4 sub-steps: h·rate ≤ 0.5, at least 4, at most 400.
    pub(crate) fn set_substeps(&mut self, hint: f64) {
        let r = self.fastest_rate(hint);
        self.sub = ((self.ts * r / 0.5).ceil() as usize).clamp(4, 400);
    }

    fn deriv(&self, s: &State, f: f64, hyst: f64) -> State {
        let mut d = [0.0; NS];
        match &self.core {
            Core::Cascade(secs) => {
                let (mut w, mut i) = (f, 0);
                for sec in secs {
                    match *sec {
                        Section::First { tau } => {
                            d[i] = (w - s[i]) / tau;
                            w = s[i];
                            i += 1;
                        }
                        Section::Second { wn, zeta } => {
                            d[i] = s[i + 1];
                            d[i + 1] = wn * wn * (w - s[i]) - 2.0 * zeta * wn * s[i + 1];
                            w = s[i];
                            i += 2;
                        }
                    }
                }
            }
            Core::Mech(m) => {
                let (x, v, z) = (s[0], s[1], s[2]);
                let mut force = f - m.c * v - m.k * x - m.k3 * x * x * x - hyst;
                if m.coulomb > 0.0 {
                    force -= m.coulomb * (v / m.eps).tanh();
                }
                if let Some([a, b, g]) = m.bouc_wen {
                    force -= z;
                    d[2] = a * v - b * v.abs() * z - g * v * z.abs();
                }
                if let Some([m2, k2, c2]) = m.second {
                    let coupling = k2 * (x - s[3]) + c2 * (v - s[4]);
                    force -= coupling;
                    d[3] = s[4];
                    d[4] = coupling / m2;
                }
                d[0] = v;
                d[1] = force / m.m;
            }
        }
        d
    }

    /// The measured quantity of the dynamics (before feedthrough and map).
    fn observe(&self, s: &State) -> f64 {
        match &self.core {
            Core::Cascade(secs) => {
                let n: usize = secs
                    .iter()
                    .map(|s| match s {
                        Section::First { .. } => 1,
                        Section::Second { .. } => 2,
                    })
                    .sum();
                match secs.last() {
                    Some(Section::Second { .. }) => s[n - 2],
                    Some(Section::First { .. }) => s[n - 1],
                    None => 0.0,
                }
            }
            Core::Mech(m) => {
                if m.velocity_output {
                    s[1]
                } else {
                    s[0]
                }
            }
        }
    }

    fn rk4(&self, s: &mut State, f: f64, hyst: f64, h: f64) {
        let add = |a: &State, b: &State, c: f64| -> State {
            let mut o = *a;
            for i in 0..NS {
                o[i] += c * b[i];
            }
            o
        };
        let k1 = self.deriv(s, f, hyst);
        let k2 = self.deriv(&add(s, &k1, 0.5 * h), f, hyst);
        let k3 = self.deriv(&add(s, &k2, 0.5 * h), f, hyst);
        let k4 = self.deriv(&add(s, &k3, h), f, hyst);
        for i in 0..NS {
            s[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        }
    }

    /// Simulate from rest on the physical inputs `u` (`u[j][k]`), with an
    /// optional force disturbance added to the input force of each sample.
    pub(crate) fn simulate(
        &self,
        u: &[Vec<f64>],
        dist: Option<&[f64]>,
        mut trace: Option<&mut Trace>,
    ) -> Result<Vec<f64>, CoreError> {
        if u.len() != self.n_inputs() {
            return Err(CoreError::Dimension(format!(
                "{} input signals for a system with {} inputs",
                u.len(),
                self.n_inputs()
            )));
        }
        let n = u.first().map_or(0, Vec::len);
        let mut grid = match &self.core {
            Core::Mech(Mech {
                preisach: Some((w, g)),
                ..
            }) => Some((*w, g.clone())),
            _ => None,
        };
        let mut hyst = grid.as_ref().map_or(0.0, |(w, g)| w * g.output());
        let mut map_state = vec![0.0; self.n_inputs()];
        let mut s = [0.0; NS];
        let h = self.ts / self.sub as f64;
        let mut y = Vec::with_capacity(n);
        for k in 0..n {
            let mut f = 0.0;
            if k >= self.delay {
                for j in 0..self.n_inputs() {
                    let m = self.input_maps[j].apply(u[j][k - self.delay], &mut map_state[j]);
                    f += self.gains[j] * m;
                }
            }
            let yk = self
                .output_map
                .apply(self.observe(&s) + self.feedthrough * f);
            if !yk.is_finite() || yk.abs() > 1e15 {
                return Err(CoreError::InvalidArgument(format!(
                    "generated system diverged at sample {k}"
                )));
            }
            y.push(yk);
            if let Some(t) = trace.as_deref_mut() {
                t.x.push(s[0]);
                t.v.push(s[1]);
                t.force.push(f);
            }
            let fd = f + dist.and_then(|d| d.get(k)).copied().unwrap_or(0.0);
            for _ in 0..self.sub {
                self.rk4(&mut s, fd, hyst, h);
                if let Some((w, g)) = grid.as_mut() {
                    hyst = *w * g.step(s[0]);
                }
            }
        }
        Ok(y)
    }
}
