//! Output-error fit of the free parameters (and free initial states) with
//! the workspace's one Levenberg–Marquardt solver, then the uncertainty:
//! `Cov = σ̂² (JᵀJ)⁻¹` at the optimum (with Gaussian priors, the posterior
//! `(JᵀJ/σ̂² + P)⁻¹`), t-based 95 % intervals, strongly correlated pairs,
//! the conditioning of `JᵀJ` and identifiability.
use super::error::{PhysicsError, PhysicsResult};
use super::simulate::{simulate, simulate_dual, Lanes};
use super::spec::{Compiled, PhysicsSpec, Prior};
use gb_core::integrated::{integrated_cost, RunningSum};
use gb_core::solver::LeastSquaresProblem;
use nalgebra::{DMatrix, SymmetricEigen};
use serde::{Deserialize, Serialize};

/// What a free coordinate of the fit is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum Coordinate {
    /// The parameter of this index.
    Parameter(usize),
    /// The initial value of the state of this index.
    InitialState(usize),
}

/// One free coordinate: its scale (the LM works on `θ/scale`), bounds and
/// prior.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Coord {
    pub(crate) what: Coordinate,
    pub(crate) scale: f64,
    pub(crate) lower: f64,
    pub(crate) upper: f64,
    pub(crate) prior: Option<Prior>,
}

/// The free coordinates of `spec` (free parameters, then free initial
/// states), or every initial state when `states_only`.
pub(crate) fn coordinates(
    spec: &PhysicsSpec,
    theta: &[f64],
    x0: &[f64],
    states_only: bool,
) -> Vec<Coord> {
    let scale = |v: f64, lo: f64, hi: f64| {
        if v != 0.0 {
            v.abs()
        } else if (hi - lo).is_finite() && hi > lo {
            0.1 * (hi - lo)
        } else {
            1.0
        }
    };
    let mut c = vec![];
    if !states_only {
        for (i, p) in spec.parameters.iter().enumerate() {
            if !p.fixed {
                c.push(Coord {
                    what: Coordinate::Parameter(i),
                    scale: scale(theta[i], p.lower, p.upper),
                    lower: p.lower,
                    upper: p.upper,
                    prior: p.prior,
                });
            }
        }
    }
    for (i, s) in spec.states.iter().enumerate() {
        if s.free || states_only {
            c.push(Coord {
                what: Coordinate::InitialState(i),
                scale: scale(x0[i], s.lower, s.upper),
                lower: s.lower,
                upper: s.upper,
                prior: None,
            });
        }
    }
    c
}

/// The lanes of `coords` (lane k = coordinate k).
pub(crate) fn lanes_of(coords: &[Coord], np: usize, n: usize) -> Lanes {
    let mut l = Lanes {
        param: vec![None; np],
        state: vec![None; n],
        n: coords.len(),
    };
    for (k, c) in coords.iter().enumerate() {
        match c.what {
            Coordinate::Parameter(i) => l.param[i] = Some(k),
            Coordinate::InitialState(i) => l.state[i] = Some(k),
        }
    }
    l
}

/// One record of the fit: its inputs and the measured outputs (one slice
/// per model output, as long as the inputs).
#[derive(Debug, Clone)]
pub(crate) struct Segment<'a> {
    pub(crate) u: Vec<&'a [f64]>,
    pub(crate) y: Vec<&'a [f64]>,
}

impl Segment<'_> {
    /// Samples of the record.
    pub(crate) fn len(&self) -> usize {
        self.y.first().map_or(0, |y| y.len())
    }
}

/// The output-error least-squares problem: `Σ_records Σ_o Σ_t (w_o (y_o(t) − ŷ_o(t)))²`
/// with one weight per output (1 for a single output).
#[derive(Debug)]
pub(crate) struct OeProblem<'a> {
    pub(crate) c: &'a Compiled,
    pub(crate) ts: f64,
    pub(crate) substeps: usize,
    pub(crate) segments: Vec<Segment<'a>>,
    pub(crate) coords: Vec<Coord>,
    pub(crate) lanes: Lanes,
    /// Full parameter vector and initial state (free entries overwritten).
    pub(crate) theta: Vec<f64>,
    pub(crate) x0: Vec<f64>,
    /// σ² used to weigh the priors (`σ² Σ ((θ − μ)/sd)²` is added to the SSE).
    pub(crate) prior_weight: f64,
    /// Add the priors to cost and Gram.
    pub(crate) with_prior: bool,
    /// Weight of each output's error.
    pub(crate) weights: Vec<f64>,
    /// The integrated criterion (`gb_core::integrated`): the outputs are
    /// increments and the error is that of their running sum per record,
    /// its mean projected out.
    pub(crate) integrated: bool,
    ybuf: Vec<f64>,
}

impl<'a> OeProblem<'a> {
    pub(crate) fn new(
        c: &'a Compiled,
        ts: f64,
        substeps: usize,
        segments: Vec<Segment<'a>>,
        coords: Vec<Coord>,
        theta: Vec<f64>,
        x0: Vec<f64>,
    ) -> Self {
        let lanes = lanes_of(&coords, c.np, c.n);
        Self {
            c,
            ts,
            substeps,
            segments,
            coords,
            lanes,
            theta,
            x0,
            prior_weight: 0.0,
            with_prior: false,
            weights: vec![1.0; c.g.n_outputs()],
            integrated: false,
            ybuf: vec![],
        }
    }

    /// LM coordinates of the current `theta`, `x0`.
    pub(crate) fn phi(&self) -> Vec<f64> {
        self.coords
            .iter()
            .map(|c| self.value(c.what) / c.scale)
            .collect()
    }

    fn value(&self, w: Coordinate) -> f64 {
        match w {
            Coordinate::Parameter(i) => self.theta[i],
            Coordinate::InitialState(i) => self.x0[i],
        }
    }

    /// Write the LM coordinates into `theta`, `x0`.
    pub(crate) fn unpack(&mut self, phi: &[f64]) {
        for (c, p) in self.coords.iter().zip(phi) {
            match c.what {
                Coordinate::Parameter(i) => self.theta[i] = p * c.scale,
                Coordinate::InitialState(i) => self.x0[i] = p * c.scale,
            }
        }
    }

    /// Number of fitted residuals (samples × outputs).
    pub(crate) fn samples(&self) -> usize {
        self.segments.iter().map(|s| s.len() * s.y.len()).sum()
    }

    fn prior_cost(&self) -> f64 {
        if !self.with_prior {
            return 0.0;
        }
        self.coords
            .iter()
            .filter_map(|c| c.prior.map(|p| (c, p)))
            .map(|(c, p)| self.prior_weight * ((self.value(c.what) - p.mean) / p.sd).powi(2))
            .sum()
    }

    /// The sum of squared output errors at the current point.
    pub(crate) fn sse(&mut self) -> Option<f64> {
        let mut sse = 0.0;
        let ny = self.c.g.n_outputs();
        for seg in &self.segments {
            let len = seg.len();
            self.ybuf.resize(ny * len, 0.0);
            simulate(
                self.c,
                &self.theta,
                &self.x0,
                &seg.u,
                self.ts,
                self.substeps,
                &mut self.ybuf,
            )
            .ok()?;
            for ((y, sim), w) in seg.y.iter().zip(self.ybuf.chunks(len)).zip(&self.weights) {
                let e2: f64 = if self.integrated {
                    integrated_cost(y.iter().zip(sim).map(|(y, s)| y - s))
                } else {
                    y.iter().zip(sim).map(|(y, s)| (y - s) * (y - s)).sum()
                };
                sse += w * w * e2;
            }
        }
        sse.is_finite().then_some(sse)
    }

    /// SSE, Gram `JᵀJ` and gradient `Jᵀe` (LM coordinates) at the current
    /// point, without priors (with [`OeProblem::integrated`]: of the
    /// running sums, their means projected out per record and output).
    pub(crate) fn gram(&self, gram: &mut [f64], grad: &mut [f64]) -> Option<f64> {
        let l = self.lanes.n;
        gram.fill(0.0);
        grad.fill(0.0);
        let scale: Vec<f64> = self.coords.iter().map(|c| c.scale).collect();
        let mut acc = gb_core::gram::GramAccumulator::new(l);
        let mut sse = 0.0;
        let mut row = vec![0.0; l];
        for seg in &self.segments {
            let len = seg.len();
            let mut runs: Vec<RunningSum> = match self.integrated {
                true => vec![RunningSum::new(l); seg.y.len()],
                false => vec![],
            };
            let sink = |t: usize, y: &[f64], dy: &[f64]| {
                for (o, (ym, w)) in seg.y.iter().zip(&self.weights).enumerate() {
                    let e = w * (ym[t] - y[o]);
                    let fill = |j: &mut [f64]| {
                        for ((jk, d), s) in j.iter_mut().zip(&dy[o * l..(o + 1) * l]).zip(&scale) {
                            *jk = w * d * s;
                        }
                    };
                    // the row straight into the accumulator, or (the
                    // integrated criterion) its running sum
                    let (e, j): (f64, &[f64]) = match runs.get_mut(o) {
                        None => {
                            let j = acc.next_row(gram);
                            fill(j);
                            (e, j)
                        }
                        Some(r) => {
                            fill(&mut row);
                            let e = r.add(e, &row);
                            acc.push(gram, r.row());
                            (e, r.row())
                        }
                    };
                    sse += e * e;
                    for (g, jk) in grad.iter_mut().zip(j) {
                        *g += jk * e;
                    }
                }
            };
            simulate_dual(
                self.c,
                &self.theta,
                &self.x0,
                &seg.u,
                self.ts,
                self.substeps,
                len,
                &self.lanes,
                sink,
            )
            .ok()?;
            for r in &runs {
                sse -= r.project_mean(gram, grad);
            }
        }
        acc.finish(gram);
        sse.is_finite().then_some(sse)
    }
}

impl LeastSquaresProblem for OeProblem<'_> {
    fn n_params(&self) -> usize {
        self.coords.len()
    }

    fn cost(&mut self, phi: &[f64]) -> Option<f64> {
        self.unpack(phi);
        Some(self.sse()? + self.prior_cost())
    }

    fn linearize(&mut self, phi: &[f64], gram: &mut [f64], grad: &mut [f64]) -> Option<f64> {
        self.unpack(phi);
        let sse = self.gram(gram, grad)?;
        let l = self.lanes.n;
        if self.with_prior {
            for (k, c) in self.coords.iter().enumerate() {
                if let Some(p) = c.prior {
                    let w = self.prior_weight / (p.sd * p.sd);
                    let r = p.mean - self.value(c.what);
                    gram[k * l + k] += w * c.scale * c.scale;
                    grad[k] += w * c.scale * r;
                }
            }
        }
        Some(sse + self.prior_cost())
    }

    fn admissible(&mut self, phi: &[f64]) -> bool {
        self.coords.iter().zip(phi).all(|(c, p)| {
            let v = p * c.scale;
            v.is_finite() && v >= c.lower && v <= c.upper
        })
    }
}

/// One estimated (or fixed) quantity of a fit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    /// Name: the parameter's, or `x(0)` of a state.
    pub name: String,
    /// What it is.
    pub what: Coordinate,
    /// The value.
    pub value: f64,
    /// Standard error (0 when fixed, ∞ when not identifiable).
    pub std_error: f64,
    /// 95 % interval.
    pub interval: (f64, f64),
    /// Known, not estimated.
    pub fixed: bool,
    /// Ended on a bound.
    pub at_bound: bool,
}

/// The result of a fit: estimates with uncertainty and what to watch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitReport {
    /// Every parameter (fixed ones included), then the free initial states.
    pub estimates: Vec<Estimate>,
    /// The free coordinates, in the order of `covariance`.
    pub free: Vec<Coordinate>,
    /// Covariance of the free coordinates (row-major, natural units).
    pub covariance: Vec<f64>,
    /// Pairs with |correlation| > 0.9: names and ρ.
    pub correlated: Vec<(String, String, f64)>,
    /// Condition number of the scaled `JᵀJ` (its correlation form).
    pub condition: f64,
    /// Conditioning, identifiability, bounds, convergence.
    pub warnings: Vec<String>,
    /// Fitted values (samples × outputs).
    pub samples: usize,
    /// Training RMSE of the free-run simulation.
    pub rmse: f64,
    /// Training NRMSE (RMSE / standard deviation of the output).
    pub nrmse: f64,
    /// Noise standard deviation σ̂ = √(SSE / (N − p)).
    pub sigma: f64,
    /// Solver iterations.
    pub iterations: usize,
    /// How the solver stopped.
    pub termination: String,
    /// The t quantile of the intervals (N − p degrees of freedom).
    pub t_quantile: f64,
}

impl FitReport {
    /// Covariance entry of two free coordinates.
    pub fn cov(&self, a: usize, b: usize) -> f64 {
        self.covariance[a * self.free.len() + b]
    }

    /// The report as lines for a terminal.
    pub fn lines(&self) -> Vec<String> {
        let mut v = vec![format!(
            "{:<14} {:>13} {:>11} {:>29}",
            "parameter", "value", "std. error", "95 % interval"
        )];
        for e in &self.estimates {
            let status = if e.fixed {
                "  (fixed)"
            } else if e.at_bound {
                "  (at a bound)"
            } else if !e.std_error.is_finite() {
                "  (not identifiable)"
            } else {
                ""
            };
            let (se, iv) = if e.fixed {
                ("—".to_string(), String::new())
            } else {
                (
                    format!("{:.3e}", e.std_error),
                    format!("[{:.6e}, {:.6e}]", e.interval.0, e.interval.1),
                )
            };
            v.push(format!(
                "{:<14} {:>13.6e} {:>11} {:>29}{status}",
                e.name, e.value, se, iv
            ));
        }
        for (a, b, r) in &self.correlated {
            v.push(format!("strongly correlated: {a} and {b} (ρ = {r:+.3})"));
        }
        if self.estimates.iter().any(|e| !e.fixed) {
            v.push(format!(
                "condition number of the scaled JᵀJ: {:.2e}",
                self.condition
            ));
        }
        for w in &self.warnings {
            v.push(format!("warning: {w}"));
        }
        v.push(format!(
            "training fit (free-run simulation, {} values): RMSE {:.4e}  NRMSE {:.4}  σ̂ {:.4e}; {} iterations ({})",
            self.samples, self.rmse, self.nrmse, self.sigma, self.iterations, self.termination
        ));
        v
    }
}

/// The two-sided 95 % quantile of Student's t with `dof` degrees of
/// freedom (Cornish–Fisher expansion about the normal quantile; error
/// below 1e-4 for dof ≥ 3).
pub fn t_quantile_95(dof: usize) -> f64 {
    let z: f64 = 1.959_963_984_540_054;
    if dof == 0 {
        return f64::INFINITY;
    }
    let n = dof as f64;
    let (z3, z5, z7, z9) = (z.powi(3), z.powi(5), z.powi(7), z.powi(9));
    z + (z3 + z) / (4.0 * n)
        + (5.0 * z5 + 16.0 * z3 + 3.0 * z) / (96.0 * n * n)
        + (3.0 * z7 + 19.0 * z5 + 17.0 * z3 - 15.0 * z) / (384.0 * n.powi(3))
        + (79.0 * z9 + 776.0 * z7 + 1482.0 * z5 - 1920.0 * z3 - 945.0 * z) / (92160.0 * n.powi(4))
}

/// The inputs of [`summarise`].
pub(crate) struct Optimum<'a> {
    pub(crate) spec: &'a PhysicsSpec,
    pub(crate) coords: &'a [Coord],
    pub(crate) theta: &'a [f64],
    pub(crate) x0: &'a [f64],
    /// Data-only Gram at the optimum (LM coordinates).
    pub(crate) gram: &'a [f64],
    pub(crate) sse: f64,
    pub(crate) samples: usize,
    pub(crate) y_sd: f64,
    pub(crate) iterations: usize,
    pub(crate) termination: String,
}

/// Standard errors, intervals, correlations and warnings at the optimum.
pub(crate) fn summarise(o: &Optimum<'_>) -> PhysicsResult<FitReport> {
    let l = o.coords.len();
    if o.samples <= l {
        return Err(PhysicsError::Data(format!(
            "{} samples cannot determine {l} free parameters and initial states",
            o.samples
        )));
    }
    let dof = o.samples - l;
    let s2 = (o.sse / dof as f64).max(f64::MIN_POSITIVE);
    let name = |w: Coordinate| match w {
        Coordinate::Parameter(i) => o.spec.parameters[i].name.clone(),
        Coordinate::InitialState(i) => format!("{}(0)", o.spec.states[i].name),
    };
    let mut warnings = vec![];
    let (cov_phi, condition, unidentified) = precision_inverse(o, s2, &name, &mut warnings);
    // natural units
    let mut cov = vec![0.0; l * l];
    for a in 0..l {
        for b in 0..l {
            cov[a * l + b] = o.coords[a].scale * o.coords[b].scale * cov_phi[a * l + b];
        }
    }
    let tq = t_quantile_95(dof);
    let mut estimates = vec![];
    for (i, p) in o.spec.parameters.iter().enumerate() {
        if p.fixed {
            estimates.push(Estimate {
                name: p.name.clone(),
                what: Coordinate::Parameter(i),
                value: o.theta[i],
                std_error: 0.0,
                interval: (o.theta[i], o.theta[i]),
                fixed: true,
                at_bound: false,
            });
        }
    }
    for (k, c) in o.coords.iter().enumerate() {
        let v = match c.what {
            Coordinate::Parameter(i) => o.theta[i],
            Coordinate::InitialState(i) => o.x0[i],
        };
        let se = if unidentified[k] {
            f64::INFINITY
        } else {
            cov[k * l + k].max(0.0).sqrt()
        };
        let tol = 1e-6 * c.scale;
        let at_bound = (v - c.lower).abs() <= tol || (c.upper - v).abs() <= tol;
        if at_bound {
            warnings.push(format!(
                "{} ended on its bound ({v:.6e} within [{}, {}]): its interval assumes an interior optimum and is not meaningful",
                name(c.what),
                c.lower,
                c.upper
            ));
        } else if se.is_finite() && se > v.abs() && matches!(c.what, Coordinate::Parameter(_)) {
            warnings.push(format!(
                "{} is poorly determined: its standard error {se:.3e} exceeds its value {v:.3e}",
                name(c.what)
            ));
        }
        estimates.push(Estimate {
            name: name(c.what),
            what: c.what,
            value: v,
            std_error: se,
            interval: (v - tq * se, v + tq * se),
            fixed: false,
            at_bound,
        });
    }
    // parameters first (in the model's order), then initial states
    estimates.sort_by_key(|e| match e.what {
        Coordinate::Parameter(i) => i,
        Coordinate::InitialState(i) => o.spec.parameters.len() + i,
    });
    let mut correlated = vec![];
    for a in 0..l {
        for b in a + 1..l {
            let d = (cov[a * l + a] * cov[b * l + b]).sqrt();
            if d > 0.0 && d.is_finite() && !unidentified[a] && !unidentified[b] {
                let r = cov[a * l + b] / d;
                if r.abs() > 0.9 {
                    correlated.push((name(o.coords[a].what), name(o.coords[b].what), r));
                }
            }
        }
    }
    let rmse = (o.sse / o.samples as f64).sqrt();
    Ok(FitReport {
        estimates,
        free: o.coords.iter().map(|c| c.what).collect(),
        covariance: cov,
        correlated,
        condition,
        warnings,
        samples: o.samples,
        rmse,
        nrmse: if o.y_sd > 0.0 {
            rmse / o.y_sd
        } else {
            f64::NAN
        },
        sigma: s2.sqrt(),
        iterations: o.iterations,
        termination: o.termination.clone(),
        t_quantile: tq,
    })
}

/// Condition number of the correlation form of a precision matrix above
/// which the fit is called ill-conditioned.
pub const ILL_CONDITIONED: f64 = 1e8;
/// A parameter whose sensitivity norm is below this fraction of the
/// largest one does not affect the output.
pub const ZERO_SENSITIVITY: f64 = 1e-7;

/// `(JᵀJ/σ² + P)⁻¹` in LM coordinates through its correlation form, its
/// condition number and which coordinates are not identifiable; warnings
/// name them.
fn precision_inverse(
    o: &Optimum<'_>,
    s2: f64,
    name: &dyn Fn(Coordinate) -> String,
    warnings: &mut Vec<String>,
) -> (Vec<f64>, f64, Vec<bool>) {
    let l = o.coords.len();
    if l == 0 {
        // every parameter and initial state stated: nothing to invert
        return (vec![], 1.0, vec![]);
    }
    let mut a = DMatrix::from_row_slice(l, l, o.gram) / s2;
    let gmax = (0..l).map(|k| o.gram[k * l + k]).fold(0.0, f64::max);
    let mut unidentified = vec![false; l];
    for (k, c) in o.coords.iter().enumerate() {
        let g = o.gram[k * l + k];
        if g <= ZERO_SENSITIVITY * ZERO_SENSITIVITY * gmax || g == 0.0 {
            if c.prior.is_none() {
                unidentified[k] = true;
            }
            warnings.push(format!(
                "{} is not identifiable from these data: the output does not depend on it (relative sensitivity {:.1e}){}",
                name(c.what),
                (g / gmax.max(f64::MIN_POSITIVE)).sqrt(),
                if c.prior.is_some() { "; its interval is its prior's" } else { "; fix it or excite the system differently" }
            ));
        }
        if let Some(p) = c.prior {
            a[(k, k)] += c.scale * c.scale / (p.sd * p.sd);
        }
    }
    let d: Vec<f64> = (0..l)
        .map(|k| {
            let v = a[(k, k)];
            if v > 0.0 && !unidentified[k] {
                1.0 / v.sqrt()
            } else {
                0.0
            }
        })
        .collect();
    let mut corr = a.clone();
    for i in 0..l {
        for j in 0..l {
            corr[(i, j)] *= d[i] * d[j];
        }
        if d[i] == 0.0 {
            corr[(i, i)] = 1.0;
        }
    }
    let eig = SymmetricEigen::new(corr);
    let lmax = eig.eigenvalues.iter().cloned().fold(0.0, f64::max);
    let lmin = eig
        .eigenvalues
        .iter()
        .cloned()
        .fold(f64::INFINITY, f64::min);
    let condition = if lmin > 0.0 {
        lmax / lmin
    } else {
        f64::INFINITY
    };
    let mut inv = DMatrix::zeros(l, l);
    let cutoff = 1e-13 * lmax;
    for (m, &lam) in eig.eigenvalues.iter().enumerate() {
        let v = eig.eigenvectors.column(m);
        if lam > cutoff {
            inv += v * v.transpose() / lam;
        } else {
            for k in 0..l {
                if v[k].abs() > 0.1 {
                    unidentified[k] = true;
                }
            }
        }
    }
    if condition > ILL_CONDITIONED && l > 1 {
        // the weakest direction names the parameters the data cannot separate
        let m = (0..l)
            .min_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]))
            .unwrap_or(0);
        let v = eig.eigenvectors.column(m);
        let mut parts: Vec<(f64, String)> = (0..l)
            .filter(|&k| v[k].abs() > 0.2 && d[k] > 0.0)
            .map(|k| (v[k], name(o.coords[k].what)))
            .collect();
        parts.sort_by(|x, y| y.0.abs().total_cmp(&x.0.abs()));
        let dir = parts
            .iter()
            .map(|(c, n)| format!("{c:+.2}·{n}"))
            .collect::<Vec<_>>()
            .join(" ");
        warnings.push(format!(
            "JᵀJ is ill-conditioned (condition number {condition:.1e} after scaling): the data determine only combinations of {}; weakest direction (relative units) {dir}",
            parts.iter().map(|p| p.1.as_str()).collect::<Vec<_>>().join(", ")
        ));
    }
    let mut cov = vec![0.0; l * l];
    for i in 0..l {
        for j in 0..l {
            cov[i * l + j] = d[i] * inv[(i, j)] * d[j];
        }
    }
    (cov, condition, unidentified)
}
