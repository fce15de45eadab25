//! An integrating model: a model of any class simulates the increments
//! Δy(k) = y(k) − y(k−1) of the output, and the output is their running
//! sum (a pole at 1 in front of any dynamics). For integrating plants
//! (force → position) whose output drifts like a random walk, which an
//! output-error model kept stable cannot follow.
//!
//! Starting a simulation: with an init window the increments model
//! estimates its state from the window's increments and the level is the
//! least-squares offset of the summed simulation to the window; with a
//! history the level is anchored at the last history sample; at rest the
//! level is 0; an explicit state is `[level, inner state…]`.
use crate::registry::StoredPart;
use gb_core::{check_inputs, CoreError, DynamicModel, Init, ModelView, Stepper, Workspace};
use serde::{Deserialize, Serialize};
use std::any::Any;

/// Tag of the class in model files.
pub const INTEGRATING_CLASS: &str = "integrating";

/// A model of the increments of the output, summed (see the module docs).
#[derive(Debug, Clone)]
pub struct IntegratingModel {
    inner: Box<dyn DynamicModel>,
}

#[derive(Serialize, Deserialize)]
struct Body {
    inner: StoredPart,
}

/// The increments of `y` (Δy(0) = Δy(1): same length, same alignment).
pub fn output_increments(y: &[f64]) -> Vec<f64> {
    let mut d: Vec<f64> = (0..y.len())
        .map(|k| if k == 0 { 0.0 } else { y[k] - y[k - 1] })
        .collect();
    if d.len() > 1 {
        d[0] = d[1];
    }
    d
}

impl IntegratingModel {
    /// Integrate the output of `inner` (a one-output model of the increments).
    pub fn new(inner: Box<dyn DynamicModel>) -> Result<Self, CoreError> {
        if inner.n_outputs() != 1 {
            return Err(CoreError::InvalidArgument(
                "an integrating model integrates one output".into(),
            ));
        }
        if inner.class() == INTEGRATING_CLASS {
            return Err(CoreError::InvalidArgument(
                "an integrating model of an integrating model".into(),
            ));
        }
        Ok(Self { inner })
    }

    /// The model of the increments.
    pub fn inner(&self) -> &dyn DynamicModel {
        self.inner.as_ref()
    }

    /// Decode a model-file body of class `integrating` (the inner model is
    /// decoded through the registry).
    pub fn decode(body: &[u8], version: u32) -> Result<Self, CoreError> {
        let b: Body = gb_core::decode_postcard(INTEGRATING_CLASS, version, 1, body)?;
        Self::new(b.inner.decode(INTEGRATING_CLASS, "of an unknown class")?)
    }
}

/// Σ over the window of (wₖ − sₖ − c)², c the least-squares level: the
/// squared misfit of the running sums `s` of increments `d` to the
/// measured positions `w`, the level fitted.
fn window_misfit(w: &[f64], d: &[f64], s: &mut [f64]) -> f64 {
    summed(d, 0.0, s);
    centred_residual(w, s).iter().map(|r| r * r).sum()
}

impl IntegratingModel {
    /// The output history of an input–output increments model (its first
    /// `history_len` increments) that fits the window's *positions* `w`
    /// (level fitted), by Gauss–Newton with a forward-difference Jacobian
    /// started from the history the inner model estimated from the window's
    /// increments `d`. The increments of noisy positions carry twice the
    /// noise variance and little of a slow signal: an initial velocity
    /// taken from them leaves a position offset after its transient (a
    /// viscous mass at 40 samples per period, an order-1 model with dead
    /// time 0: a fresh record simulated at 0.38 of its spread, 0.14 from
    /// the window's positions). A state-space inner model keeps its own
    /// estimate: with its state fitted from 0 this way, the dry-friction
    /// template won the sweep's `integrator` seed 8 and ended at 1.73× the
    /// noise floor against 1.09× (docs/diagnose.md). `None` when the window
    /// is too short or the fit is no closer to the positions than `d`.
    fn history_fitting_positions(
        &self,
        u: &[Vec<f64>],
        w: &[f64],
        d: &[f64],
        ws: &mut Workspace,
    ) -> Option<Vec<f64>> {
        let m = self.inner.history_len();
        let nw = w.len().min(d.len());
        if m == 0 || nw < 2 * m + 2 {
            return None;
        }
        let w = &w[..nw];
        let uw: Vec<Vec<f64>> = u.iter().map(|c| c[..nw].to_vec()).collect();
        let (mut dd, mut s) = (vec![0.0; nw], vec![0.0; nw]);
        let before = window_misfit(w, &d[..nw], &mut s);
        let mut misfit = |x: &[f64], dd: &mut [f64], s: &mut [f64]| -> Option<f64> {
            self.inner
                .simulate_into(&uw, Init::History(x), dd, ws)
                .ok()?;
            let c = window_misfit(w, dd, s);
            c.is_finite().then_some(c)
        };
        let mut x = d[..m].to_vec();
        let mut best = misfit(&x, &mut dd, &mut s)?;
        let scale = d[..nw].iter().map(|v| v.abs()).fold(0.0, f64::max);
        for _ in 0..6 {
            let r = centred_residual(w, &s);
            let mut jac = Vec::with_capacity(m);
            for i in 0..m {
                let step = 1e-6 * scale.max(x[i].abs()).max(1e-150);
                let mut xp = x.clone();
                xp[i] += step;
                misfit(&xp, &mut dd, &mut s)?;
                let rp = centred_residual(w, &s);
                jac.push(
                    rp.iter()
                        .zip(&r)
                        .map(|(a, b)| (a - b) / step)
                        .collect::<Vec<_>>(),
                );
            }
            let delta = gauss_newton_step(&jac, &r)?;
            let trial: Vec<f64> = x.iter().zip(delta.iter()).map(|(a, b)| a - b).collect();
            match misfit(&trial, &mut dd, &mut s) {
                Some(c) if c < best * (1.0 - 1e-9) => {
                    x = trial;
                    best = c;
                }
                _ => break,
            }
        }
        (best < before).then_some(x)
    }
}

/// The Gauss–Newton step δ = (JᵀJ + εI)⁻¹ Jᵀr (ε a 1e-12 relative ridge) for
/// the Jacobian columns `jac` of the residual `r` (the new point is x − δ).
fn gauss_newton_step(jac: &[Vec<f64>], r: &[f64]) -> Option<nalgebra::DVector<f64>> {
    let m = jac.len();
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(p, q)| p * q).sum::<f64>();
    let jtj = nalgebra::DMatrix::from_fn(m, m, |i, j| dot(&jac[i], &jac[j]));
    let jtr = nalgebra::DVector::from_fn(m, |i, _| dot(&jac[i], r));
    let ridge = 1e-12 * (0..m).map(|i| jtj[(i, i)]).fold(0.0, f64::max);
    let lhs = jtj + nalgebra::DMatrix::identity(m, m) * ridge.max(1e-300);
    Some(lhs.cholesky()?.solve(&jtr))
}

/// wₖ − sₖ − c with c the least-squares level.
fn centred_residual(w: &[f64], s: &[f64]) -> Vec<f64> {
    let c = w.iter().zip(s).map(|(a, b)| a - b).sum::<f64>() / w.len() as f64;
    w.iter().zip(s).map(|(a, b)| a - b - c).collect()
}

/// Running sum of the increments `d`: `y(0) = level`, `y(k) = y(k−1) + d(k)`.
fn summed(d: &[f64], level: f64, y: &mut [f64]) {
    let mut acc = level;
    for (k, v) in d.iter().enumerate() {
        if k > 0 {
            acc += v;
        }
        y[k] = acc;
    }
}

impl DynamicModel for IntegratingModel {
    fn class(&self) -> &'static str {
        INTEGRATING_CLASS
    }
    fn n_inputs(&self) -> usize {
        self.inner.n_inputs()
    }
    fn n_states(&self) -> usize {
        1 + self.inner.n_states()
    }
    fn history_len(&self) -> usize {
        1 + self.inner.history_len()
    }
    fn integrates(&self) -> bool {
        true
    }
    fn describe(&self) -> String {
        format!(
            "integrating (pole at 1): the increments by a {}",
            self.inner.describe()
        )
    }
    fn n_parameters(&self) -> usize {
        self.inner.n_parameters()
    }
    fn simulate_into(
        &self,
        u: &[Vec<f64>],
        init: Init<'_>,
        y: &mut [f64],
        ws: &mut Workspace,
    ) -> Result<(), CoreError> {
        check_inputs(self.n_inputs(), u)?;
        let n = u.first().map_or(0, Vec::len);
        if y.len() != n {
            return Err(CoreError::Dimension(format!(
                "output buffer of {} samples for a simulation of {n}",
                y.len()
            )));
        }
        let mut d = vec![0.0; n];
        let anchor: Option<(&[f64], bool)> = match init {
            Init::Window(w) => {
                let dw = output_increments(w);
                self.inner.simulate_into(u, Init::Window(&dw), &mut d, ws)?;
                if let Some(h) = self.history_fitting_positions(u, w, &d, ws) {
                    self.inner.simulate_into(u, Init::History(&h), &mut d, ws)?;
                }
                Some((w, true))
            }
            Init::History(h) => {
                let dh = output_increments(h);
                self.inner
                    .simulate_into(u, Init::History(&dh), &mut d, ws)?;
                Some((h, false))
            }
            Init::State(x) => {
                if x.len() != self.n_states() {
                    return Err(CoreError::Dimension(format!(
                        "{} state values for a model with {} states",
                        x.len(),
                        self.n_states()
                    )));
                }
                self.inner
                    .simulate_into(u, Init::State(&x[1..]), &mut d, ws)?;
                summed(&d, x[0], y);
                return Ok(());
            }
            other => {
                self.inner.simulate_into(u, other, &mut d, ws)?;
                None
            }
        };
        summed(&d, 0.0, y);
        if let Some((m, window)) = anchor {
            let m = &m[..m.len().min(n)];
            let level = if m.is_empty() {
                0.0
            } else if window {
                // least-squares offset over the window
                m.iter().zip(y.iter()).map(|(a, b)| a - b).sum::<f64>() / m.len() as f64
            } else {
                m[m.len() - 1] - y[m.len() - 1]
            };
            y.iter_mut().for_each(|v| *v += level);
        }
        Ok(())
    }
    fn stepper(&self, init: Init<'_>) -> Result<Box<dyn Stepper + '_>, CoreError> {
        let (level, inner) = match init {
            Init::State(x) if x.len() == self.n_states() => {
                (x[0], self.inner.stepper(Init::State(&x[1..]))?)
            }
            Init::Rest | Init::Stored => (0.0, self.inner.stepper(init)?),
            _ => {
                return Err(CoreError::Unsupported(
                    "an integrating model steps from rest, stored or an explicit state".into(),
                ))
            }
        };
        Ok(Box::new(SumStepper {
            inner,
            acc: level,
            first: true,
        }))
    }
    fn encode(&self) -> Result<Vec<u8>, CoreError> {
        let b = Body {
            inner: StoredPart::of(self.inner.as_ref())?,
        };
        postcard::to_allocvec(&b)
            .map_err(|e| CoreError::ModelFile(format!("cannot encode model: {e}")))
    }
    fn views(&self, input_names: &[String], output_names: &[String]) -> Vec<ModelView> {
        self.inner.views(input_names, output_names)
    }
    fn clone_box(&self) -> Box<dyn DynamicModel> {
        Box::new(self.clone())
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

struct SumStepper<'a> {
    inner: Box<dyn Stepper + 'a>,
    acc: f64,
    first: bool,
}

impl Stepper for SumStepper<'_> {
    fn step(&mut self, u: &[f64], y: &mut [f64]) -> Result<(), CoreError> {
        let mut d = [0.0];
        self.inner.step(u, &mut d)?;
        if !self.first {
            self.acc += d[0];
        }
        self.first = false;
        y[0] = self.acc;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::SparseStateSpace;

    fn inner() -> Box<dyn DynamicModel> {
        // x⁺ = 0.5 x + u, y = x: the increments
        Box::new(SparseStateSpace::linear(vec![0.5], vec![1.0], vec![1.0], vec![0.0]).unwrap())
    }

    #[test]
    fn it_sums_the_increments_and_reads_back_through_the_registry() {
        let m = IntegratingModel::new(inner()).unwrap();
        let u = vec![vec![1.0, 0.0, -1.0, 2.0, 0.5, 0.0]];
        let d = inner().simulate(&u, Init::Rest).unwrap();
        let y = m.simulate(&u, Init::Rest).unwrap();
        // y(k) = Σ_{1..k} Δ, from 0
        let mut acc = 0.0;
        for k in 0..u[0].len() {
            if k > 0 {
                acc += d[k];
            }
            assert!((y[k] - acc).abs() < 1e-12, "{k}");
        }
        let s = m.simulate(&u, Init::State(&[3.0, 0.0])).unwrap();
        assert!((s[4] - (3.0 + y[4])).abs() < 1e-12);
        let fm = gb_core::FittedModel::new(
            vec!["u".into()],
            vec!["y".into()],
            Box::new(m),
            gb_core::NoiseModel::Gaussian { sd: 0.1 },
        )
        .unwrap();
        let back = crate::registry::from_bytes(&fm.to_bytes().unwrap(), "m.gbm").unwrap();
        assert_eq!(back.dynamics.class(), "integrating");
        assert_eq!(back.simulate(&u, Init::Rest).unwrap(), y);
        assert!(back.describe().contains("integrating (pole at 1)"));
    }

    /// An input–output model of increments, v(k) = 0.95 v(k−1) + 0.05
    /// u(k−1), its one-sample history v(0) (from an init window: the first
    /// sample, as a model without a better estimate would take it).
    #[derive(Clone, Debug)]
    struct SlowVelocity;

    impl DynamicModel for SlowVelocity {
        fn class(&self) -> &'static str {
            "slow-velocity"
        }
        fn n_inputs(&self) -> usize {
            1
        }
        fn n_states(&self) -> usize {
            1
        }
        fn history_len(&self) -> usize {
            1
        }
        fn describe(&self) -> String {
            "slow velocity".into()
        }
        fn n_parameters(&self) -> usize {
            2
        }
        fn simulate_into(
            &self,
            u: &[Vec<f64>],
            init: Init<'_>,
            y: &mut [f64],
            _: &mut Workspace,
        ) -> Result<(), CoreError> {
            let v0 = match init {
                Init::History(h) | Init::Window(h) | Init::State(h) => h.first().copied(),
                _ => None,
            };
            for k in 0..y.len() {
                y[k] = if k == 0 {
                    v0.unwrap_or(0.0)
                } else {
                    0.95 * y[k - 1] + 0.05 * u[0][k - 1]
                };
            }
            Ok(())
        }
        fn encode(&self) -> Result<Vec<u8>, CoreError> {
            Ok(vec![])
        }
        fn clone_box(&self) -> Box<dyn DynamicModel> {
            Box::new(self.clone())
        }
        fn as_any(&self) -> &dyn Any {
            self
        }
    }

    /// A slow velocity (v(k) = 0.95 v(k−1) + 0.05 u(k−1), the increments) started at
    /// x₀ = 2 and level 1, its position measured with noise of σ = 0.5 over
    /// a 30-sample window: the state fitted to the window's positions
    /// simulates the noise-free position after the window to within σ/2,
    /// and at most half the error of the state estimated from the window's
    /// increments alone (the route before the fit, each increment carrying
    /// noise of variance 2σ²).
    #[test]
    fn an_init_window_fits_the_start_to_the_positions() {
        use rand_distr::{Distribution, StandardNormal};
        let inner = || -> Box<dyn DynamicModel> { Box::new(SlowVelocity) };
        let m = IntegratingModel::new(inner()).unwrap();
        let n = 300;
        let u = vec![(0..n).map(|k| (0.07 * k as f64).sin()).collect::<Vec<_>>()];
        let truth = m.simulate(&u, Init::State(&[1.0, 2.0])).unwrap();
        let mut rng = gb_core::rng::seeded(3);
        let sigma = 0.5;
        let noisy: Vec<f64> = truth
            .iter()
            .map(|v| {
                let z: f64 = StandardNormal.sample(&mut rng);
                v + sigma * z
            })
            .collect();
        let w = &noisy[..30];
        let rms_after = |y: &[f64]| {
            let e: Vec<f64> = (30..n).map(|k| y[k] - truth[k]).collect();
            (e.iter().map(|v| v * v).sum::<f64>() / e.len() as f64).sqrt()
        };
        let fitted = rms_after(&m.simulate(&u, Init::Window(w)).unwrap());
        // the increments-only route: the inner state from the increments,
        // then the least-squares level
        let d = inner()
            .simulate(&u, Init::Window(&output_increments(w)))
            .unwrap();
        let mut y = vec![0.0; n];
        summed(&d, 0.0, &mut y);
        let level = w.iter().zip(&y).map(|(a, b)| a - b).sum::<f64>() / w.len() as f64;
        y.iter_mut().for_each(|v| *v += level);
        let from_increments = rms_after(&y);
        assert!(fitted < 0.5 * sigma, "{fitted} vs sigma {sigma}");
        assert!(
            fitted < 0.5 * from_increments,
            "{fitted} vs {from_increments} from the increments"
        );
    }

    #[test]
    fn an_init_window_sets_the_level() {
        let m = IntegratingModel::new(inner()).unwrap();
        let u = vec![vec![0.0; 40]];
        // no input, a constant window: the level is the window's
        let w = [5.0; 6];
        let y = m.simulate(&u, Init::Window(&w)).unwrap();
        assert!(y.iter().all(|v| (v - 5.0).abs() < 1e-9), "{y:?}");
        let h = m.simulate(&u, Init::History(&[1.0, 2.0])).unwrap();
        assert!((h[1] - 2.0).abs() < 1e-9);
        assert!(IntegratingModel::new(Box::new(m.clone())).is_err());
    }
}
