//! Static and hysteretic maps used by the generator: input nonlinearities
//! (applied to the held input before the dynamics), output (sensor)
//! nonlinearities, and a relay-grid Preisach operator.

/// A map applied to one input sample (stateful for backlash).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum InputMap {
    /// u
    Identity,
    /// L·tanh(u/L)
    Tanh(f64),
    /// clip(u, ±L)
    Clip(f64),
    /// u + a·u³
    Cubic(f64),
    /// u + a·u²
    Square(f64),
    /// u + a·|u|
    AbsPlus(f64),
    /// u − clip(u, ±d)
    DeadZone(f64),
    /// play operator of half-width b (gear backlash)
    Backlash(f64),
}

impl InputMap {
    /// Apply to `u`; `state` is the backlash play position (unused otherwise).
    pub(crate) fn apply(&self, u: f64, state: &mut f64) -> f64 {
        match *self {
            Self::Identity => u,
            Self::Tanh(l) => l * (u / l).tanh(),
            Self::Clip(l) => u.clamp(-l, l),
            Self::Cubic(a) => u + a * u * u * u,
            Self::Square(a) => u + a * u * u,
            Self::AbsPlus(a) => u + a * u.abs(),
            Self::DeadZone(d) => u - u.clamp(-d, d),
            Self::Backlash(b) => {
                if u - b > *state {
                    *state = u - b;
                } else if u + b < *state {
                    *state = u + b;
                }
                *state
            }
        }
    }
}

/// A map applied to the output of the dynamics (a Wiener sensor).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum OutputMap {
    /// y
    Identity,
    /// L·tanh(y/L)
    Tanh(f64),
    /// y + a₂y² + a₃y³
    Poly(f64, f64),
}

impl OutputMap {
    pub(crate) fn apply(&self, y: f64) -> f64 {
        match *self {
            Self::Identity => y,
            Self::Tanh(l) => l * (y / l).tanh(),
            Self::Poly(a2, a3) => y + a2 * y * y + a3 * y * y * y,
        }
    }
}

/// Discrete Preisach operator: relays on a triangular grid over
/// [−half_range, half_range] with a density that is Gaussian in the loop
/// width (α − β, scale `width`·half_range) and in the bias (α + β)/2.
/// The output is Σ wᵢ sᵢ with Σ wᵢ = 1, so it lies in [−1, 1].
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct RelayGrid {
    up: Vec<f64>,
    down: Vec<f64>,
    weight: Vec<f64>,
    state: Vec<f64>,
}

impl RelayGrid {
    pub(crate) fn new(half_range: f64, n: usize, width: f64) -> Self {
        let mut g = Self {
            up: vec![],
            down: vec![],
            weight: vec![],
            state: vec![],
        };
        let cell = 2.0 * half_range / n as f64;
        for i in 0..n {
            for j in 0..=i {
                let a = -half_range + cell * (i as f64 + 0.5);
                let b = -half_range + cell * (j as f64 + 0.5);
                let w = (-((a - b) / (width * half_range)).powi(2)).exp()
                    * (-(0.5 * (a + b) / half_range).powi(2)).exp();
                g.up.push(a);
                g.down.push(b);
                g.weight.push(w);
                // demagnetised start: relays with α + β > 0 are down
                g.state.push(if a + b > 0.0 { -1.0 } else { 1.0 });
            }
        }
        let s: f64 = g.weight.iter().sum();
        g.weight.iter_mut().for_each(|w| *w /= s);
        g
    }

    /// Feed input `x`, return the output.
    pub(crate) fn step(&mut self, x: f64) -> f64 {
        let mut y = 0.0;
        for i in 0..self.state.len() {
            if x >= self.up[i] {
                self.state[i] = 1.0;
            } else if x <= self.down[i] {
                self.state[i] = -1.0;
            }
            y += self.weight[i] * self.state[i];
        }
        y
    }

    /// Current output without moving the input.
    pub(crate) fn output(&self) -> f64 {
        self.weight
            .iter()
            .zip(&self.state)
            .map(|(w, s)| w * s)
            .sum()
    }
}
