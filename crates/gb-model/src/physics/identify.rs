//! Fitting a physics model to records: validated settings implementing
//! [`gb_core::Identify`].
use super::error::{PhysicsError, PhysicsResult};
use super::fit::{coordinates, summarise, OeProblem, Optimum, Segment};
use super::model::PhysicsModel;
use super::spec::PhysicsSpec;
use gb_core::solver::{LevenbergMarquardt, LmParams, Termination};
use gb_core::{Identify, Observer, Record, Records};

/// Settings of a physics fit; validate with [`check`](Self::check).
///
/// | setting | default | meaning |
/// |---|---|---|
/// | `max_iter` | 200 | Levenberg–Marquardt iterations |
/// | `tol` | 1e-10 | relative cost decrease that counts as converged |
/// | `stall` | (10, 1e-5) | stop when 10 iterations together lower the cost by less than 0.001 % (a crawl along a flat valley; 1e-4 also stopped the overflow limit of the tanks test while it was still on its way) |
/// | `direct_max_iter` | `max_iter` | iterations of the fit from the start values in [`PhysicsFit::identify_growing`] (the path beside the growing prefixes) |
#[derive(Debug, Clone)]
pub struct PhysicsFitParams {
    spec: PhysicsSpec,
    source: Option<String>,
    lm: LmParams,
    direct_max_iter: Option<usize>,
    integrated: bool,
}

impl PhysicsFitParams {
    /// Fit `spec` with the default settings.
    pub fn new(spec: PhysicsSpec) -> Self {
        Self {
            spec,
            source: None,
            lm: LmParams::default().max_iter(200).tol(1e-10).stall(10, 1e-5),
            direct_max_iter: None,
            integrated: false,
        }
    }
    /// Fit the error of the outputs' running sums per record, their means
    /// projected out (`gb_core::integrated`), instead of the outputs'
    /// error: for a model of an integrating system's increments, whose
    /// running sum is what is measured (with white noise on it, the
    /// maximum-likelihood criterion). The fit report (RMSE, σ̂,
    /// intervals) stays that of the increments at the optimum.
    pub fn integrated(mut self, on: bool) -> Self {
        self.integrated = on;
        self
    }
    /// Most iterations.
    pub fn max_iter(mut self, n: usize) -> Self {
        self.lm = self.lm.max_iter(n);
        self
    }
    /// Most iterations of the fit from the start values beside the growing
    /// prefixes of [`PhysicsFit::identify_growing`] (default: `max_iter`).
    /// Where the start is already a fitted model (a term added at 0) and
    /// the direct fit crawls, the growing path has usually long converged.
    pub fn direct_max_iter(mut self, n: usize) -> Self {
        self.direct_max_iter = Some(n);
        self
    }
    /// Convergence tolerance.
    pub fn tol(mut self, t: f64) -> Self {
        self.lm = self.lm.tol(t);
        self
    }
    /// Stop when `window` iterations together lower the cost by less than
    /// `tol` (relative; window 0: never).
    pub fn stall(mut self, window: usize, tol: f64) -> Self {
        self.lm = self.lm.stall(window, tol);
        self
    }
    /// Give up after iteration `after` when the cost is still above `ratio`
    /// times the start cost ([`LmParams::futile`]: a screen for an
    /// extension that must gain a stated fraction; a fit that passes the
    /// check ends where it would without it).
    pub fn futile(mut self, after: usize, ratio: f64) -> Self {
        self.lm = self.lm.futile(after, ratio);
        self
    }
    /// The model file's text, stored with the fitted model.
    pub fn source(mut self, text: String) -> Self {
        self.source = Some(text);
        self
    }
    /// Validate once (compiles the equations).
    pub fn check(self) -> PhysicsResult<PhysicsFit> {
        let mut model = PhysicsModel::new(self.spec)?;
        if let Some(s) = self.source {
            model = model.with_source(s);
        }
        let direct = match self.direct_max_iter {
            Some(n) => self.lm.max_iter(n),
            None => self.lm,
        };
        Ok(PhysicsFit {
            model,
            lm: self.lm.check()?,
            direct_lm: direct.check()?,
            integrated: self.integrated,
        })
    }
}

/// A validated physics fit.
#[derive(Debug, Clone)]
pub struct PhysicsFit {
    model: PhysicsModel,
    lm: LevenbergMarquardt,
    /// The solver of the direct path of [`identify_growing`](Self::identify_growing).
    direct_lm: LevenbergMarquardt,
    /// The integrated criterion ([`PhysicsFitParams::integrated`]).
    integrated: bool,
}

impl PhysicsFit {
    /// The unfitted model (start values).
    pub fn model(&self) -> &PhysicsModel {
        &self.model
    }

    /// The same settings started from `model`.
    fn with_model(&self, model: PhysicsModel) -> PhysicsFit {
        PhysicsFit {
            model,
            lm: self.lm,
            direct_lm: self.direct_lm,
            integrated: self.integrated,
        }
    }

    /// The direct path of [`identify_growing`](Self::identify_growing):
    /// these settings with the direct fit's solver.
    fn direct(&self) -> PhysicsFit {
        PhysicsFit {
            model: self.model.clone(),
            lm: self.direct_lm,
            direct_lm: self.direct_lm,
            integrated: self.integrated,
        }
    }

    /// The sample time, after checking `data` (one [`Records`] per model
    /// output, in the model's order: the same inputs and record lengths).
    fn check_data(&self, data: &[Records]) -> PhysicsResult<f64> {
        let spec = self.model.spec();
        if spec.outputs.len() != data.len() {
            return Err(PhysicsError::Data(format!(
                "model '{}' has {} outputs [{}]; the data give {}",
                spec.name,
                spec.outputs.len(),
                spec.outputs
                    .iter()
                    .map(|o| o.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
                data.len()
            )));
        }
        let first = &data[0];
        for (d, out) in data.iter().zip(&spec.outputs) {
            if d.input_names() != spec.inputs.as_slice() {
                return Err(PhysicsError::Data(format!(
                    "the data's inputs [{}] are not the model's inputs [{}]",
                    d.input_names().join(", "),
                    spec.inputs.join(", ")
                )));
            }
            if d.output_name() != out.name {
                return Err(PhysicsError::Data(format!(
                    "the data's output '{}' is not the model's output '{}'",
                    d.output_name(),
                    out.name
                )));
            }
            let lens = |r: &Records| r.iter().map(Record::len).collect::<Vec<_>>();
            if lens(d) != lens(first) {
                return Err(PhysicsError::Data(format!(
                    "output '{}': records of other lengths than output '{}'",
                    out.name, spec.outputs[0].name
                )));
            }
        }
        let ts = spec
            .sample_time
            .or(first.first().sample_time)
            .ok_or_else(|| {
                PhysicsError::Data(format!(
                    "model '{}': the sample time is unknown: give sample_time in the model file or a uniform t column in the data",
                    spec.name
                ))
            })?;
        if let Some(r) = first.iter().find(|r| r.is_empty()) {
            return Err(PhysicsError::Data(format!(
                "an empty record (output '{}')",
                r.output_name
            )));
        }
        Ok(ts)
    }

    /// The start must simulate: the error names the sample where it
    /// diverges.
    fn check_start(&self, p: &mut OeProblem<'_>) -> PhysicsResult<()> {
        if p.sse().is_some() {
            return Ok(());
        }
        let seg = &p.segments[0];
        let mut y = vec![0.0; seg.len() * self.model.n_outputs_fit()];
        let at = match self.model.run(&p.theta, &p.x0, &seg.u, &mut y) {
            Err(PhysicsError::Diverged(k)) => format!("diverges at sample {k}"),
            _ => "is not finite".into(),
        };
        Err(PhysicsError::Numerical(format!(
            "model '{}': the simulation with the start values {at}; check the start values, signs and units",
            self.model.spec().name
        )))
    }
}

impl PhysicsFit {
    /// The fit from the start values, and the fit continued over growing
    /// prefixes of the first record (1/32, 1/8, 1/2, then all records;
    /// prefixes shorter than 50 samples skipped), each started
    /// from the last one's estimates; the one with the smaller training
    /// RMSE wins (the two paths run side by side when a thread is free).
    /// Output-error costs of oscillating systems have local
    /// minima away from the start that a short prefix does not have (the
    /// simulated and measured phases drift apart only over long records).
    pub fn identify_growing(
        &self,
        data: &Records,
        obs: &dyn Observer,
    ) -> PhysicsResult<PhysicsModel> {
        self.identify_growing_outputs(std::slice::from_ref(data), obs)
    }

    /// [`identify_growing`](Self::identify_growing) for a model of several
    /// outputs: `data[o]` holds output `o`'s records (see
    /// [`identify_outputs`](Self::identify_outputs)).
    ///
    /// A free input delay is first held at its start value (the whole
    /// procedure above), then freed from that fit's estimates: far from
    /// the optimum the delay trades against the other parameters (on the
    /// EMPS record, freed from the start it ends on its bound at training
    /// NRMSE 1.9; held first, the fit reaches 0.029 before it is freed).
    ///
    /// With Preisach operators on states whose driver the output measures,
    /// the fit is also started from [`forced_cells_start`]; the fit with
    /// the smaller training RMSE wins.
    ///
    /// [`forced_cells_start`]: Self::forced_cells_start
    pub fn identify_growing_outputs(
        &self,
        data: &[Records],
        obs: &dyn Observer,
    ) -> PhysicsResult<PhysicsModel> {
        let plain = self.identify_growing_plain(data, obs);
        let Some(start) = self.forced_cells_start(data, obs) else {
            return plain;
        };
        let forced = self.with_model(start).identify_outputs(data, obs);
        better_of(forced, plain)
    }

    /// With Preisach operators on one state `x_d` that the output measures
    /// (`y = s·x_d + g₀`, `g` using no other state, input or cell): the
    /// model fitted with its cells switched by the measured
    /// `x̂_d = (y − g₀)/s` (held inputs over each sample), then started at
    /// those estimates. The cells then do not move with θ, so that fit is
    /// smooth where the closed loop's cost jumps each time a relay's
    /// switching sub-step moves (an output-error fit from zero weights
    /// stops in such a local optimum). `None` when not applicable.
    fn forced_cells_start(&self, data: &[Records], obs: &dyn Observer) -> Option<PhysicsModel> {
        let c = self.model.compiled();
        let driver = c.ops.first()?.driver;
        if data.len() != 1 || c.ops.iter().any(|o| o.driver != driver) {
            return None;
        }
        let (g0, slope) = self.output_of_driver(driver)?;
        let measured: Vec<Vec<f64>> = data[0]
            .iter()
            .map(|r| r.output.iter().map(|y| (y - g0) / slope).collect())
            .collect();
        let fit = self.forced_fit(&data[0], &measured, obs)?;
        self.model
            .clone()
            .with_values(fit.parameters().to_vec(), fit.initial_state().to_vec())
            .ok()?
            .with_start_at_values()
            .ok()
    }

    /// `(g₀, s)` when output 0 is `s·x_d + g₀` at the start values, using no
    /// other state, input or cell.
    fn output_of_driver(&self, driver: usize) -> Option<(f64, f64)> {
        let c = self.model.compiled();
        let (n, nu) = (c.n, c.nu);
        if c.g_used[0].iter().any(|&v| v < n + nu && v != driver) {
            return None;
        }
        let theta = self.model.parameters();
        let g_at = |xd: f64| {
            let mut vals = self.model.initial_state().to_vec();
            vals[driver] = xd;
            vals.resize(n + nu, 0.0);
            vals.extend_from_slice(theta);
            let mut sl = c.g.slots(0);
            sl.v[..vals.len()].copy_from_slice(&vals);
            c.g.run_pre(&mut sl);
            c.g.run_input(&mut sl);
            c.g.run(&mut sl);
            c.g.out(&sl, 0)
        };
        let (g0, g1, g2) = (g_at(0.0), g_at(1.0), g_at(2.0));
        let slope = g1 - g0;
        let affine = (g2 - g0 - 2.0 * slope).abs() <= 1e-9 * slope.abs();
        (slope.is_finite() && slope != 0.0 && g0.is_finite() && affine).then_some((g0, slope))
    }

    /// The model with its cells as held inputs switched by `signals` (the
    /// driver per record), fitted on `data` from the start values.
    fn forced_fit(
        &self,
        data: &Records,
        signals: &[Vec<f64>],
        obs: &dyn Observer,
    ) -> Option<PhysicsModel> {
        let spec = self.model.spec();
        let c = self.model.compiled();
        let mut forced = spec.clone();
        forced.inputs.extend(
            spec.hysteresis
                .iter()
                .flat_map(|h| (0..h.n_cells()).map(|j| h.cell_name(j))),
        );
        forced.hysteresis.clear();
        let records: Vec<Record> = data
            .iter()
            .zip(signals)
            .map(|(r, xd)| {
                let mut inputs = r.inputs.clone();
                for o in &c.ops {
                    let grid = |x: f64| (x - o.center) * o.inv_half;
                    let mut st = o.cells.relay_states(grid(*xd.first()?));
                    let mut cols = vec![vec![0.0; r.len()]; o.cells.n_cells()];
                    let mut buf = vec![0.0; o.cells.n_cells()];
                    for (k, &x) in xd.iter().enumerate() {
                        o.cells.step(&mut st, grid(x), &mut buf);
                        for (col, b) in cols.iter_mut().zip(&buf) {
                            col[k] = *b;
                        }
                    }
                    inputs.extend(cols);
                }
                let rec = Record::new(
                    forced.inputs.clone(),
                    r.output_name.clone(),
                    inputs,
                    r.output.clone(),
                )
                .ok()?;
                Some(match r.sample_time {
                    Some(ts) => rec.with_sample_time(ts),
                    None => rec,
                })
            })
            .collect::<Option<_>>()?;
        let model = PhysicsModel::new(forced)
            .ok()?
            .with_values(
                self.model.parameters().to_vec(),
                self.model.initial_state().to_vec(),
            )
            .ok()?;
        self.with_model(model)
            .identify_growing_plain(&[Records::new(records).ok()?], obs)
            .ok()
    }

    /// [`identify_growing_outputs`](Self::identify_growing_outputs)
    /// without the start from forced cells.
    fn identify_growing_plain(
        &self,
        data: &[Records],
        obs: &dyn Observer,
    ) -> PhysicsResult<PhysicsModel> {
        let spec = self.model.spec();
        if let Some(d) = spec
            .input_delay_index()
            .filter(|&d| !spec.parameters[d].fixed)
        {
            let mut held = spec.clone();
            held.parameters[d].fixed = true;
            let mut model = PhysicsModel::new(held)?;
            if let Some(t) = self.model.source() {
                model = model.with_source(t.to_string());
            }
            let stage1 = self.with_model(model).identify_growing_plain(data, obs)?;
            let start = self
                .model
                .clone()
                .with_values(
                    stage1.parameters().to_vec(),
                    stage1.initial_state().to_vec(),
                )?
                .with_start_at_values()?;
            return self.with_model(start).identify_outputs(data, obs);
        }
        // the two paths are independent: run them side by side when a
        // thread is free (the same fits, the same choice)
        let (direct, grown) = rayon::join(
            || self.direct().identify_outputs(data, obs),
            || self.identify_grown(data, obs),
        );
        better_of(grown?, direct)
    }

    /// The fit continued over growing prefixes of the first record (see
    /// [`identify_growing_plain`](Self::identify_growing_plain)); the outer
    /// error when a start cannot be built, the inner one the final fit's.
    fn identify_grown(
        &self,
        data: &[Records],
        obs: &dyn Observer,
    ) -> PhysicsResult<PhysicsResult<PhysicsModel>> {
        let n = data.first().map_or(0, |d| d.first().len());
        let mut start = self.model.clone();
        for part in [32, 8, 2] {
            if n / part < 50 {
                continue;
            }
            let sub: Vec<Records> = data
                .iter()
                .map(|d| Records::single(d.first().slice(0..n / part)))
                .collect();
            let fit = self.with_model(start.clone());
            if let Ok(m) = fit.identify_outputs(&sub, obs) {
                start = start.with_values(m.parameters().to_vec(), m.initial_state().to_vec())?;
            }
        }
        Ok(self
            .with_model(start.with_start_at_values()?)
            .identify_outputs(data, obs))
    }
}

impl PhysicsModel {
    /// The same model whose spec starts at its current values (parameter
    /// values and initial states clamped to their bounds): the start of a
    /// refit.
    pub fn with_start_at_values(&self) -> PhysicsResult<PhysicsModel> {
        let mut spec = self.spec().clone();
        for (p, v) in spec.parameters.iter_mut().zip(self.parameters()) {
            p.value = v.clamp(p.lower, p.upper);
        }
        for (s, v) in spec.states.iter_mut().zip(self.initial_state()) {
            s.initial = v.clamp(s.lower, s.upper);
        }
        let m = PhysicsModel::new(spec)?;
        Ok(match self.source() {
            Some(t) => m.with_source(t.to_string()),
            None => m,
        })
    }

    fn n_outputs_fit(&self) -> usize {
        self.spec().outputs.len()
    }
}

impl Identify for PhysicsFit {
    type Model = PhysicsModel;
    type Error = PhysicsError;

    /// Output-error fit of a one-output model (see
    /// [`PhysicsFit::identify_outputs`]).
    fn identify(&self, data: &Records, obs: &dyn Observer) -> PhysicsResult<PhysicsModel> {
        self.identify_outputs(std::slice::from_ref(data), obs)
    }
}

impl PhysicsFit {
    /// Output-error fit of the free parameters and free initial states
    /// (shared by all records) by Levenberg–Marquardt on the free-run
    /// simulation error, bounds enforced by rejecting trials outside them.
    /// `data[o]` holds the records of model output `o` (same inputs and
    /// lengths for every output). With several outputs each output's error
    /// is weighed by `w_o = sd(y_1)/sd(y_o)` (every output counts in the
    /// units of the first; `w_1 = 1`), so the fit's NRMSE is the RMS of the
    /// outputs' NRMSEs. With Gaussian priors the cost is
    /// `SSE + σ̂² Σ ((θ − μ)/sd)²` (the MAP estimate), σ̂² from a first
    /// pass, then refitted once.
    pub fn identify_outputs(
        &self,
        data: &[Records],
        obs: &dyn Observer,
    ) -> PhysicsResult<PhysicsModel> {
        let ts = self.check_data(data)?;
        let spec = self.model.spec();
        let first = data[0].first();
        let u0: Vec<f64> = first.inputs.iter().map(|s| s[0]).collect();
        let (theta0, x00) = (self.model.parameters(), self.model.initial_state());
        self.model.compiled().check_point(spec, x00, &u0, theta0)?;
        // per record: the inputs (same for every output) and each output
        let per_output: Vec<Vec<&Record>> = data.iter().map(|d| d.iter().collect()).collect();
        let segments: Vec<Segment<'_>> = per_output[0]
            .iter()
            .enumerate()
            .map(|(r, rec)| Segment {
                u: rec.inputs.iter().map(Vec::as_slice).collect(),
                y: per_output.iter().map(|d| d[r].output.as_slice()).collect(),
            })
            .collect();
        let sds: Vec<f64> = data.iter().map(output_sd).collect();
        if let Some(o) = sds.iter().position(|&s| !(s > 0.0 && s.is_finite())) {
            return Err(PhysicsError::Data(format!(
                "output '{}' is constant",
                spec.outputs[o].name
            )));
        }
        let coords = coordinates(spec, theta0, x00, false);
        let mut p = OeProblem::new(
            self.model.compiled(),
            ts,
            spec.substeps,
            segments,
            coords.clone(),
            theta0.to_vec(),
            x00.to_vec(),
        );
        p.weights = sds.iter().map(|s| sds[0] / s).collect();
        self.check_start(&mut p)?;
        p.integrated = self.integrated;
        let n = p.samples();
        let mut iterations = 0;
        let mut termination = "no free parameters".to_string();
        if !coords.is_empty() {
            let priors = coords.iter().any(|c| c.prior.is_some());
            for pass in 0..if priors { 2 } else { 1 } {
                if priors {
                    // σ² of the current point weighs the priors
                    let sse = p.sse().unwrap_or(f64::INFINITY);
                    p.prior_weight = sse / (n.saturating_sub(coords.len()).max(1)) as f64;
                    p.with_prior = true;
                }
                let phi0 = p.phi();
                let st = self.lm.minimize(&mut p, &phi0, obs)?;
                p.unpack(&st.theta);
                iterations += st.iterations;
                termination = termination_text(st.termination);
                if pass == 1 || !priors {
                    break;
                }
            }
        }
        let l = coords.len();
        let (mut gram, mut grad) = (vec![0.0; l * l], vec![0.0; l]);
        p.integrated = false;
        let sse = p
            .gram(&mut gram, &mut grad)
            .ok_or_else(|| PhysicsError::Numerical("the fitted model does not simulate".into()))?;
        let y_sd = sds[0];
        let report = summarise(&Optimum {
            spec,
            coords: &coords,
            theta: &p.theta,
            x0: &p.x0,
            gram: &gram,
            sse,
            samples: n,
            y_sd,
            iterations,
            termination,
        })?;
        let mut m = self.model.clone();
        let (theta, x0) = (p.theta.clone(), p.x0.clone());
        m.set_fitted(theta, x0, ts, report);
        Ok(m)
    }
}

/// `a` when its training RMSE is below `b`'s (a failed fit: infinite),
/// else `b`.
fn better_of(
    a: PhysicsResult<PhysicsModel>,
    b: PhysicsResult<PhysicsModel>,
) -> PhysicsResult<PhysicsModel> {
    let rmse = |m: &PhysicsResult<PhysicsModel>| {
        m.as_ref()
            .ok()
            .and_then(PhysicsModel::fit_report)
            .map_or(f64::INFINITY, |r| r.rmse)
    };
    if rmse(&a) < rmse(&b) {
        a
    } else {
        b
    }
}

fn termination_text(t: Option<Termination>) -> String {
    match t {
        Some(Termination::Converged) => "converged".into(),
        Some(Termination::MaxIterations) => "stopped at the iteration limit".into(),
        Some(Termination::NoImprovement) => "converged (no further decrease)".into(),
        Some(Termination::DampingOverflow) => "converged (damping limit)".into(),
        Some(Termination::Infeasible) => "stopped: infeasible point".into(),
        Some(Termination::Stalled) => "stopped: progress below the stall threshold".into(),
        Some(Termination::Futile) => "stopped: too little progress for the gain it needs".into(),
        _ => "stopped".into(),
    }
}

/// Standard deviation of all records' outputs together.
fn output_sd(data: &Records) -> f64 {
    let all: Vec<f64> = data.iter().flat_map(|r| r.output.iter().copied()).collect();
    let n = all.len().max(1) as f64;
    let m = all.iter().sum::<f64>() / n;
    (all.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / n).sqrt()
}
