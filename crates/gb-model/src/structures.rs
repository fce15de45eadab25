//! Known-physics (grey-box) structures built from the best linear model.
use crate::basis::SparseExpansion;
use crate::error::{ModelError, Result};
use crate::everett::WaveletEverett;
use crate::identify::{OeParams, OeReport};
use crate::linear::linear_from_oe;
use crate::model::{HysteresisTerm, NonlinearTerm, Signal, SparseStateSpace, Structure, Target};
use gb_core::Observer;

/// Start model of the Bouc-Wen recipe: the [`second_order`] hysteretic
/// structure (position, velocity, hidden restoring force z) from the best
/// order-2 linear OE model of `u → y`, plus a `ż`-row `bior2.2` term
/// f(v, z) on the box ±1.25 × the start model's simulated |v|, |z|. The
/// linear model is fitted on `lin_range` (e.g. a period after the
/// transient). Returns the start model and the linear model.
pub fn hysteretic_mechanical_start(
    u: &[f64],
    y: &[f64],
    lin_range: std::ops::Range<usize>,
    ts: f64,
    substeps: usize,
) -> Result<(SparseStateSpace, SparseStateSpace)> {
    if lin_range.end > u.len().min(y.len()) || lin_range.is_empty() {
        return Err(ModelError::InvalidArgument(format!(
            "linear-fit range {lin_range:?} outside the {} samples",
            u.len().min(y.len())
        )));
    }
    let lin = linear_from_oe(&[u[lin_range.clone()].to_vec()], &y[lin_range], 2)?;
    let mut start = second_order(&lin, ts, substeps, true)?;
    let (_, xs) = start.simulate_states(&[u.to_vec()])?;
    let vmax = xs.chunks(3).map(|x| x[1].abs()).fold(0.0, f64::max) * 1.25;
    let zmax = xs.chunks(3).map(|x| x[2].abs()).fold(0.0, f64::max) * 1.25;
    start.terms.push(NonlinearTerm {
        target: Target::State(2),
        args: vec![Signal::State(1), Signal::State(2)],
        expansion: SparseExpansion::new("bior2.2", vec![-vmax, -zmax], vec![vmax, zmax])?,
    });
    Ok((start, lin))
}

/// Continuous-time `(ω², 2ζω, 1/m)` of a 2-state, 1-input discrete model
/// from its poles, `s = ln λ / Ts`, and the static gain (`1/m = ω²·G(1)`):
/// a complex pair (an oscillator, `ω² = |s|²`, `2ζω = −2 Re s`) or two
/// stable positive real poles (an overdamped mass–spring–damper,
/// `ω² = s₁s₂`, `2ζω = −(s₁ + s₂)`, ζ ≥ 1: friction or a stiff damper can
/// make the best linear model of a mechanical system overdamped). A
/// negative real pole has no continuous-time counterpart.
pub fn second_order_parameters(lin: &SparseStateSpace, ts: f64) -> Result<(f64, f64, f64)> {
    if lin.n_states != 2 || lin.n_inputs != 1 || !(ts > 0.0 && ts.is_finite()) {
        return Err(ModelError::InvalidArgument(
            "a 2-state, 1-input model and a sample time > 0 are needed".into(),
        ));
    }
    let a = &lin.a;
    let tr = a[0] + a[3];
    let det = a[0] * a[3] - a[1] * a[2];
    let re = 0.5 * tr;
    let disc = det - re * re;
    let (w2, cc) = if disc > 0.0 && det > 0.0 {
        let im = disc.sqrt();
        let s_re = (re * re + im * im).sqrt().ln() / ts;
        let s_im = im.atan2(re) / ts;
        (s_re * s_re + s_im * s_im, -2.0 * s_re)
    } else {
        let r = (-disc).sqrt();
        let (p1, p2) = (re + r, re - r);
        if !(p2 > 0.0 && p1 < 1.0) {
            return Err(ModelError::InvalidArgument(format!(
                "the linear model's poles {p1:.4} and {p2:.4} are neither a complex pair nor two stable positive real poles (not a mechanical second-order system)"
            )));
        }
        let (s1, s2) = (p1.ln() / ts, p2.ln() / ts);
        (s1 * s2, -(s1 + s2))
    };
    let (i11, i12, i21, i22) = (1.0 - a[0], -a[1], -a[2], 1.0 - a[3]);
    let idet = i11 * i22 - i12 * i21;
    if idet.abs() < 1e-300 {
        return Err(ModelError::Numerical("integrating linear model".into()));
    }
    let x1 = (i22 * lin.b[0] - i12 * lin.b[1]) / idet;
    let x2 = (-i21 * lin.b[0] + i11 * lin.b[1]) / idet;
    let dc = lin.c[0] * x1 + lin.c[1] * x2 + lin.d[0];
    Ok((w2, cc, w2 * dc))
}

/// The second-order mechanical structure `ÿ = −ω² y − 2ζω ẏ + u/m (− z)`
/// equivalent to `lin` (2 states, 1 input, sample time `ts`), discretised
/// with `substeps` sub-steps; the output is the position.
///
/// * `hysteretic = false`: states `(y, v)`, the kinematics row
///   `y⁺ = y + h v` fixed (explicit Euler), the velocity row and `b₂` free
///   (known physics);
/// * `hysteretic = true`: states `(y, v, z)` with a restoring force z of its
///   own dynamics `ż = (ω²/2) v` (stiffness split equally between `k y` and
///   z, so the start equals `lin`), symplectic Euler; all of `A`, `b₁, b₂`
///   and `x₀` free — the
///   Bouc-Wen shape, ready for a wavelet term `f(v, z)` on row 2.
///
/// ```
/// let lin = gb_model::SparseStateSpace::linear(
///     vec![1.6, 1.0, -0.8, 0.0], vec![0.1, 0.05], vec![1.0, 0.0], vec![0.0])?;
/// let m = gb_model::second_order(&lin, 0.01, 4, true)?;
/// assert_eq!(m.n_states, 3);
/// let u = vec![(0..200).map(|t| (t as f64 * 0.1).sin()).collect::<Vec<f64>>()];
/// let (a, b) = (lin.simulate(&u)?, m.simulate(&u)?);
/// let e = gb_core::metrics::nrmse(&a, &b)?;
/// assert!(e < 0.05, "{e}");
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn second_order(
    lin: &SparseStateSpace,
    ts: f64,
    substeps: usize,
    hysteretic: bool,
) -> Result<SparseStateSpace> {
    let (w2, cc, gain) = second_order_parameters(lin, ts)?;
    let substeps = substeps.max(1);
    let h = ts / substeps as f64;
    let mut m = if hysteretic {
        let k = 0.5 * w2;
        let a = vec![
            1.0 - h * h * k,
            h * (1.0 - h * cc),
            -h * h,
            -h * k,
            1.0 - h * cc,
            -h,
            0.0,
            h * k,
            1.0,
        ];
        let mut m = SparseStateSpace::linear(
            a,
            vec![h * h * gain, h * gain, 0.0],
            vec![1.0, 0.0, 0.0],
            vec![0.0],
        )?;
        m.structure = Structure {
            a: vec![true; 9],
            b: vec![true, true, false],
            c: vec![false; 3],
            d: vec![false],
            x0: vec![true; 3],
            y_offset: false,
        };
        m
    } else {
        let a = vec![1.0, h, -h * w2, 1.0 - h * cc];
        let mut m = SparseStateSpace::linear(a, vec![0.0, h * gain], vec![1.0, 0.0], vec![0.0])?;
        m.structure = Structure {
            a: vec![false, false, true, true],
            b: vec![false, true],
            c: vec![false; 2],
            d: vec![false],
            x0: vec![false; 2],
            y_offset: false,
        };
        m
    };
    m.substeps = substeps;
    m.y_offset = 0.0;
    Ok(m)
}

/// A black-box start for data without known physics (the CLI's
/// `--model state-space[+preisach]`): the best linear model of `order`
/// (`gb-lmn` OE) in observer form, a 2-D wavelet term `f(x₁, u₁)` on the
/// first state row, optionally a Preisach component of the first input on
/// the output; identified by output error (levels 1–3, boxes fitted to the
/// linear simulation). `names`: the inputs' and the output's names.
pub fn fit_state_space(
    inputs: &[Vec<f64>],
    y: &[f64],
    order: usize,
    preisach: bool,
    names: Vec<String>,
    obs: &dyn Observer,
) -> Result<(SparseStateSpace, OeReport)> {
    if inputs.is_empty() {
        return Err(ModelError::InvalidArgument(
            "the state-space model needs at least one input".into(),
        ));
    }
    let mut m = linear_from_oe(inputs, y, order.max(1))?;
    m.signal_names = names;
    let (lo, hi) = inputs[0]
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), v| (a.min(*v), b.max(*v)));
    let span = (hi - lo).max(1e-12);
    // placeholder box; OeParams::adapt_boxes fits it to the linear simulation
    m.terms.push(NonlinearTerm {
        target: Target::State(0),
        args: vec![Signal::State(0), Signal::Input(0)],
        expansion: SparseExpansion::new("bior2.2", vec![-1.0, lo], vec![1.0, lo + span])?,
    });
    if preisach {
        let (a, b) = (lo - 0.05 * span, hi + 0.05 * span);
        m.hysteresis.push(HysteresisTerm {
            target: Target::Output,
            input: 0,
            everett: WaveletEverett::new(SparseExpansion::new("bior2.2", vec![a, a], vec![b, b])?)?,
        });
    }
    m.check()?;
    OeParams::new()
        .coarse_level(1)
        .max_level(3)
        .adapt_boxes(true)
        .check()?
        .fit(m, inputs, y, obs)
}

#[cfg(test)]
mod tests {
    use super::second_order_parameters;
    use crate::SparseStateSpace;

    /// `ẍ = −k x − c ẋ + g u` sampled at `ts` in modal form: the discrete
    /// poles `e^{s·ts}` of its continuous poles `s`, and output weights that
    /// give the static gain `g/k`.
    fn modal(s1: f64, s2: f64, g: f64, ts: f64) -> SparseStateSpace {
        let (p1, p2) = ((s1 * ts).exp(), (s2 * ts).exp());
        let k = s1 * s2;
        // c (I − A)⁻¹ b = c₁/(1 − p₁) + c₂/(1 − p₂) with b = (1, 1):
        // split the gain g/k equally between the modes
        let c = vec![0.5 * g / k * (1.0 - p1), 0.5 * g / k * (1.0 - p2)];
        SparseStateSpace::linear(vec![p1, 0.0, 0.0, p2], vec![1.0, 1.0], c, vec![0.0]).unwrap()
    }

    /// An overdamped system (poles −1 and −4 rad/s: k = 4, c = 5) comes
    /// back as its continuous-time parameters; a negative real pole and an
    /// unstable pole are refused.
    #[test]
    fn an_overdamped_model_has_its_mechanical_parameters() {
        let (w2, cc, g) = second_order_parameters(&modal(-1.0, -4.0, 3.0, 0.1), 0.1).unwrap();
        assert!((w2 - 4.0).abs() < 1e-9, "k {w2}");
        assert!((cc - 5.0).abs() < 1e-9, "c {cc}");
        assert!((g - 3.0).abs() < 1e-9, "g {g}");
        let neg = SparseStateSpace::linear(
            vec![0.5, 0.0, 0.0, -0.3],
            vec![1.0, 1.0],
            vec![1.0, 1.0],
            vec![0.0],
        )
        .unwrap();
        assert!(second_order_parameters(&neg, 0.1).is_err());
        assert!(second_order_parameters(&modal(0.5, -4.0, 1.0, 0.1), 0.1).is_err());
    }
}
