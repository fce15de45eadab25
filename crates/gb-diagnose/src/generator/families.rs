//! The families of identification problems. Each builder draws the
//! physical parameters, realises the excitation (which fixes the sample
//! time), and sizes the hidden effect relative to the signal levels of a
//! pilot simulation of the system without it.
use super::ctx::{abs_quantile, logu, std, uni, Built, Ctx};
use super::maps::{InputMap, OutputMap, RelayGrid};
use super::noise::NoiseKind;
use super::plant::{Core, Mech, Section, System};
use super::Family;
use gb_core::CoreError;
use rand::Rng;
use std::f64::consts::PI;

type R = gb_core::rng::Xoshiro256PlusPlus;

/// Build the case description of `family`.
pub(crate) fn build(family: Family, r: &mut R, ctx: &mut Ctx) -> Result<Built, CoreError> {
    match family {
        Family::Linear => linear(r, ctx, false),
        Family::DeadTime => linear(r, ctx, true),
        Family::Duffing => duffing(r, ctx),
        Family::HammersteinOdd | Family::HammersteinEven => hammerstein(family, r, ctx),
        Family::Wiener => wiener(r, ctx),
        Family::Saturation | Family::DeadZone | Family::Backlash => input_map(family, r, ctx),
        Family::Friction => friction(r, ctx),
        Family::Integrator => integrator(r, ctx),
        Family::Preisach => preisach(r, ctx),
        Family::BoucWen => bouc_wen(r, ctx),
        Family::TwoMass => two_mass(r, ctx),
        Family::Lag => lag(r, ctx),
        Family::TwoInput => two_input(r, ctx),
        Family::StudentT | Family::ColouredNoise | Family::ProcessNoise => noisy(family, r, ctx),
    }
}

/// A random cascade of unit-DC-gain sections.
struct Cascade {
    sections: Vec<Section>,
    /// reference time: resonance period or time constant of the first section
    t_ref: f64,
    /// highest section frequency (Hz), the band of the excitation
    f_band: f64,
    text: String,
}

fn order_of(s: &Section) -> usize {
    match s {
        Section::First { .. } => 1,
        Section::Second { .. } => 2,
    }
}

/// The other sections lie within a factor 3 of the reference in frequency,
/// with at least 4 samples per resonance period (half a sample per time
/// constant) and at least 15 periods (30 time constants) in the record.
fn cascade(r: &mut R, order: usize, spp: f64, n: usize) -> Cascade {
    let resonant = order >= 2 && r.random::<f64>() < 0.75;
    let (t_ref, w_ref, first) = if resonant {
        let f0 = logu(r, 0.1, 50.0);
        let zeta = logu(r, 0.05, 0.7);
        let wn = 2.0 * PI * f0;
        (1.0 / f0, wn, Section::Second { wn, zeta })
    } else {
        let tau = logu(r, 0.01, 10.0);
        (tau, 1.0 / tau, Section::First { tau })
    };
    let ts = t_ref / spp;
    let span = n as f64 * ts;
    let mut sections = vec![first];
    let mut left = order.saturating_sub(order_of(&first));
    while left > 0 {
        if left >= 2 && r.random::<f64>() < 0.6 {
            // at least 4 samples per period of every resonance
            let wn = (w_ref * logu(r, 0.3, 3.0))
                .min(2.0 * PI / (4.0 * ts))
                .max(30.0 * PI / span);
            sections.push(Section::Second {
                wn,
                zeta: logu(r, 0.05, 0.7),
            });
            left -= 2;
        } else {
            let tau = (logu(r, 0.3, 3.0) / w_ref).max(0.5 * ts).min(span / 30.0);
            sections.push(Section::First { tau });
            left -= 1;
        }
    }
    let mut w_max: f64 = 0.0;
    let parts: Vec<String> = sections
        .iter()
        .map(|s| match *s {
            Section::First { tau } => {
                w_max = w_max.max(1.0 / tau);
                format!("1st-order (tau {tau:.3e} s)")
            }
            Section::Second { wn, zeta } => {
                w_max = w_max.max(wn);
                format!("2nd-order (f0 {:.3e} Hz, zeta {zeta:.2})", wn / (2.0 * PI))
            }
        })
        .collect();
    Cascade {
        sections,
        t_ref,
        f_band: w_max / (2.0 * PI),
        text: parts.join(" -> "),
    }
}

fn cascade_params(b: &mut Built, c: &Cascade) {
    for (i, s) in c.sections.iter().enumerate() {
        match *s {
            Section::First { tau } => b.param(&format!("tau{}", i + 1), tau),
            Section::Second { wn, zeta } => {
                b.param(&format!("f{}", i + 1), wn / (2.0 * PI));
                b.param(&format!("zeta{}", i + 1), zeta);
            }
        }
    }
}

/// A cascade system of `order` with random input and output scales.
fn cascade_system(
    r: &mut R,
    ctx: &mut Ctx,
    order: usize,
    n_inputs: usize,
) -> Result<(System, Cascade), CoreError> {
    let c = cascade(r, order, ctx.drawn.spp, ctx.drawn.n_train);
    let mut sys = System::new(Core::Cascade(c.sections.clone()), n_inputs);
    for j in 0..n_inputs {
        sys.input_scale[j] = logu(r, 0.1, 10.0);
        sys.gains[j] = logu(r, 0.1, 10.0) * if r.random::<bool>() { 1.0 } else { -1.0 };
    }
    ctx.excite(c.t_ref, c.f_band, n_inputs);
    sys.ts = ctx.ts;
    sys.set_substeps(0.0);
    Ok((sys, c))
}

/// A mass–spring–damper with random scales; returns it and f0 (Hz).
fn msd(r: &mut R) -> (Mech, f64) {
    let m = logu(r, 0.2, 5.0);
    let f0 = logu(r, 0.2, 50.0);
    let zeta = logu(r, 0.02, 0.4);
    let w = 2.0 * PI * f0;
    (Mech::linear(m, 2.0 * zeta * w * m, m * w * w), f0)
}

fn msd_system(r: &mut R, ctx: &mut Ctx, b_text: &str) -> (System, f64, String) {
    let (mech, f0) = msd(r);
    let x0 = logu(r, 1e-3, 1e-1);
    let text = format!(
        "{b_text}mass-spring-damper (m {:.3}, f0 {f0:.3e} Hz, zeta {:.3})",
        mech.m,
        mech.c / (2.0 * (mech.k * mech.m).sqrt())
    );
    let k = mech.k;
    let mut sys = System::new(Core::Mech(mech), 1);
    sys.input_scale[0] = k * x0;
    ctx.excite(1.0 / f0, f0, 1);
    (sys, f0, text)
}

fn mech_params(b: &mut Built) {
    if let Core::Mech(m) = &b.system.core {
        let (mm, c, k) = (m.m, m.c, m.k);
        b.param("m", mm);
        b.param("c", c);
        b.param("k", k);
    }
}

fn mech_mut(sys: &mut System) -> Result<&mut Mech, CoreError> {
    match &mut sys.core {
        Core::Mech(m) => Ok(m),
        Core::Cascade(_) => Err(CoreError::InvalidArgument(
            "generator: expected a mechanical core".into(),
        )),
    }
}

fn linear(r: &mut R, ctx: &mut Ctx, dead_time: bool) -> Result<Built, CoreError> {
    let order = if dead_time {
        r.random_range(1..=2)
    } else {
        r.random_range(1..=4)
    };
    let delay = if dead_time {
        r.random_range(4..=12)
    } else {
        r.random_range(0..=3)
    };
    let feed = !dead_time && r.random::<f64>() < 0.25;
    let d = uni(r, 0.1, 0.5) * if r.random::<bool>() { 1.0 } else { -1.0 };
    let (mut sys, c) = cascade_system(r, ctx, order, 1)?;
    sys.delay = delay;
    if feed {
        sys.feedthrough = d;
    }
    let mut b = Built::new(sys, order, vec![]);
    b.description = format!(
        "{}linear {}, input delay {delay}{}",
        if dead_time { "dead time: " } else { "" },
        c.text,
        if feed {
            format!(", direct feedthrough D {d:.2}")
        } else {
            String::new()
        }
    );
    cascade_params(&mut b, &c);
    b.param("delay", delay as f64);
    b.param("feedthrough", if feed { d } else { 0.0 });
    Ok(b)
}

fn duffing(r: &mut R, ctx: &mut Ctx) -> Result<Built, CoreError> {
    let (mut sys, _, text) = msd_system(r, ctx, "Duffing: ");
    let rho = logu(r, 0.02, 0.15);
    let lv = ctx.levels(&mut sys, 0.0)?;
    let x = std(&lv.trace.x);
    let m = mech_mut(&mut sys)?;
    m.k3 = rho * m.k / (x * x);
    let hint = ((m.k + 3.0 * m.k3 * 16.0 * x * x) / m.m).sqrt();
    sys.set_substeps(hint);
    let mut b = Built::new(sys, 2, vec!["nonlinearity"]);
    b.description = format!("{text}, cubic spring k3 x^3 = {rho:.2} k x at rms x");
    mech_params(&mut b);
    b.param("k3_rel", rho);
    Ok(b)
}

fn hammerstein(family: Family, r: &mut R, ctx: &mut Ctx) -> Result<Built, CoreError> {
    let order = r.random_range(1..=3);
    let variant = r.random::<bool>();
    let (p, rho) = (uni(r, 0.6, 0.95), uni(r, 0.05, 0.4));
    ctx.need_amplitude_spread();
    let (mut sys, c) = cascade_system(r, ctx, order, 1)?;
    let u = std(&ctx.inputs(&sys, true)[0]);
    let (map, text) = match (family, variant) {
        (Family::HammersteinOdd, true) => {
            let l = ctx.input_quantile(&sys, 0, p);
            (
                InputMap::Tanh(l),
                format!("L tanh(u/L), L = {p:.2}-quantile of |u|"),
            )
        }
        (Family::HammersteinOdd, false) => (
            InputMap::Cubic(rho / (u * u)),
            format!("u + a u^3, a u_rms^2 = {rho:.2}"),
        ),
        (_, true) => (
            InputMap::Square(rho / u),
            format!("u + a u^2, a u_rms = {rho:.2}"),
        ),
        (_, false) => (
            InputMap::AbsPlus(2.0 * rho),
            format!("u + a |u|, a = {:.2}", 2.0 * rho),
        ),
    };
    sys.input_maps[0] = map;
    let mut b = Built::new(sys, order, vec!["nonlinearity"]);
    b.description = format!("Hammerstein: {text} -> {}", c.text);
    cascade_params(&mut b, &c);
    b.param("quantile", p);
    b.param("strength", rho);
    Ok(b)
}

fn wiener(r: &mut R, ctx: &mut Ctx) -> Result<Built, CoreError> {
    let order = r.random_range(1..=3);
    let tanh = r.random::<bool>();
    let p = uni(r, 0.7, 0.97);
    let (a2, a3) = (
        uni(r, 0.04, 0.1) * if r.random::<bool>() { 1.0 } else { -1.0 },
        uni(r, 0.0, 0.04),
    );
    let (mut sys, c) = cascade_system(r, ctx, order, 1)?;
    let lv = ctx.levels(&mut sys, 0.0)?;
    let y = std(&lv.y);
    let (map, text) = if tanh {
        let l = abs_quantile(&lv.y, p);
        (
            OutputMap::Tanh(l),
            format!("sensor L tanh(y/L), L = {p:.2}-quantile of |y|"),
        )
    } else {
        (
            OutputMap::Poly(a2 / y, a3 / (y * y)),
            format!("sensor y + a2 y^2 + a3 y^3 (a2 y_rms = {a2:.2}, a3 y_rms^2 = {a3:.2})"),
        )
    };
    sys.output_map = map;
    let mut b = Built::new(sys, order, vec!["nonlinearity"]);
    b.description = format!("Wiener: {} -> {text}", c.text);
    cascade_params(&mut b, &c);
    b.param("quantile", p);
    b.param("a2_rel", a2);
    b.param("a3_rel", a3);
    Ok(b)
}

/// Input saturation, dead zone or backlash before a random cascade.
fn input_map(family: Family, r: &mut R, ctx: &mut Ctx) -> Result<Built, CoreError> {
    let order = r.random_range(1..=3);
    let (p_sat, p_dz, rho) = (uni(r, 0.5, 0.9), uni(r, 0.1, 0.4), uni(r, 0.05, 0.4));
    ctx.need_amplitude_spread();
    let (mut sys, c) = cascade_system(r, ctx, order, 1)?;
    let (map, cause, text) = match family {
        Family::Saturation => {
            let l = ctx.input_quantile(&sys, 0, p_sat);
            let t = format!("input saturation at the {p_sat:.2}-quantile of |u|");
            (InputMap::Clip(l), "nonlinearity", t)
        }
        Family::DeadZone => {
            let d = ctx.input_quantile(&sys, 0, p_dz);
            let t = format!("input dead zone at the {p_dz:.2}-quantile of |u|");
            (InputMap::DeadZone(d), "nonlinearity", t)
        }
        _ => {
            let bl = rho * std(&ctx.inputs(&sys, true)[0]);
            let t = format!("input backlash, half-width {rho:.2} u_rms");
            (InputMap::Backlash(bl), "hysteresis", t)
        }
    };
    sys.input_maps[0] = map;
    let mut b = Built::new(sys, order, vec![cause]);
    b.description = format!("{text} -> {}", c.text);
    cascade_params(&mut b, &c);
    b.param(
        "level_quantile",
        match family {
            Family::Saturation => p_sat,
            Family::DeadZone => p_dz,
            _ => rho,
        },
    );
    Ok(b)
}

/// Coulomb + viscous friction on a mass: velocity output of a free mass
/// (1st order) or position output of a mass on a spring (2nd order).
fn friction(r: &mut R, ctx: &mut Ctx) -> Result<Built, CoreError> {
    let velocity = r.random::<bool>();
    let (rho, eps_rel) = (uni(r, 0.1, 0.5), uni(r, 0.02, 0.1));
    let (mut sys, text, order) = if velocity {
        let m = logu(r, 0.2, 5.0);
        let tau = logu(r, 0.01, 10.0);
        let mut mech = Mech::linear(m, m / tau, 0.0);
        mech.velocity_output = true;
        let v0 = logu(r, 1e-2, 1.0);
        let mut sys = System::new(Core::Mech(mech), 1);
        sys.input_scale[0] = m / tau * v0;
        ctx.excite(tau, 1.0 / (2.0 * PI * tau), 1);
        let t = format!("friction: free mass (m {m:.3}, viscous tau {tau:.3e} s), velocity output");
        (sys, t, 1)
    } else {
        let (sys, _, t) = msd_system(r, ctx, "friction: ");
        (sys, format!("{t}, position output"), 2)
    };
    let lv = ctx.levels(&mut sys, 0.0)?;
    let (f_rms, v_rms) = (std(&lv.trace.force), std(&lv.trace.v));
    let m = mech_mut(&mut sys)?;
    m.coulomb = rho * f_rms;
    m.eps = eps_rel * v_rms;
    sys.set_substeps(0.0);
    let mut b = Built::new(sys, order, vec!["nonlinearity"]);
    if !velocity {
        // Coulomb friction makes a rate-independent force-displacement loop
        b.alternatives = vec![vec!["hysteresis"]];
    }
    b.description = format!(
        "{text}, Coulomb friction Fc tanh(v/eps), Fc = {rho:.2} F_rms, eps = {eps_rel:.3} v_rms"
    );
    mech_params(&mut b);
    b.param("coulomb_rel", rho);
    b.param("eps_rel", eps_rel);
    b.param("velocity_output", f64::from(u8::from(velocity)));
    Ok(b)
}

/// A free mass with viscous friction whose position is measured: an
/// integrating system (force → position, a pole at 1), its position a
/// random walk under a zero-mean force. In two draws of three also
/// Coulomb friction `F_c·tanh(v/ε)` on its velocity (the EMPS positioning
/// rig's structure).
fn integrator(r: &mut R, ctx: &mut Ctx) -> Result<Built, CoreError> {
    let coulomb = r.random::<f64>() < 2.0 / 3.0;
    let (rho, eps_rel) = (uni(r, 0.1, 0.5), uni(r, 0.02, 0.1));
    let m = logu(r, 0.2, 5.0);
    let tau = logu(r, 0.01, 10.0);
    let mech = Mech::linear(m, m / tau, 0.0);
    let v0 = logu(r, 1e-2, 1.0);
    let mut sys = System::new(Core::Mech(mech), 1);
    sys.input_scale[0] = m / tau * v0;
    ctx.excite(tau, 1.0 / (2.0 * PI * tau), 1);
    let text =
        format!("integrator: free mass (m {m:.3}, viscous tau {tau:.3e} s), position output");
    let mut b = if coulomb {
        let lv = ctx.levels(&mut sys, 0.0)?;
        let (f_rms, v_rms) = (std(&lv.trace.force), std(&lv.trace.v));
        let mech = mech_mut(&mut sys)?;
        mech.coulomb = rho * f_rms;
        mech.eps = eps_rel * v_rms;
        sys.set_substeps(0.0);
        let mut b = Built::new(sys, 2, vec!["nonlinearity"]);
        b.alternatives = vec![vec!["hysteresis"]];
        b.description = format!(
            "{text}, Coulomb friction Fc tanh(v/eps), Fc = {rho:.2} F_rms, eps = {eps_rel:.3} v_rms"
        );
        b
    } else {
        sys.set_substeps(0.0);
        let mut b = Built::new(sys, 2, vec![]);
        b.description = text;
        b
    };
    mech_params(&mut b);
    b.param("coulomb_rel", if coulomb { rho } else { 0.0 });
    b.param("eps_rel", eps_rel);
    Ok(b)
}

/// A Preisach (relay-grid) spring on the position inside the loop.
fn preisach(r: &mut R, ctx: &mut Ctx) -> Result<Built, CoreError> {
    let (range, rho, width) = (uni(r, 1.5, 3.0), uni(r, 0.15, 0.6), uni(r, 0.3, 0.8));
    let (mut sys, _, text) = msd_system(r, ctx, "Preisach spring: ");
    let lv = ctx.levels(&mut sys, 0.0)?;
    let x = std(&lv.trace.x);
    let m = mech_mut(&mut sys)?;
    let w = rho * m.k * x;
    let half = range * x;
    m.preisach = Some((w, RelayGrid::new(half, 16, width)));
    let hint = ((m.k + 2.0 * w / half) / m.m).sqrt();
    sys.set_substeps(hint);
    let mut b = Built::new(sys, 2, vec!["hysteresis"]);
    b.description = format!(
        "{text}, + Preisach force w P(x): 136 relays on +-{range:.2} x_rms, w = {rho:.2} k x_rms, loop width {width:.2}"
    );
    mech_params(&mut b);
    b.param("preisach_range_rel", range);
    b.param("preisach_weight_rel", rho);
    b.param("preisach_width", width);
    Ok(b)
}

/// A Bouc–Wen restoring force (n = 1) on a mass–spring–damper.
fn bouc_wen(r: &mut R, ctx: &mut Ctx) -> Result<Built, CoreError> {
    let (a_rel, z_rel, share) = (uni(r, 0.3, 1.5), uni(r, 0.3, 1.0), uni(r, 0.3, 0.8));
    let (mut sys, _, text) = msd_system(r, ctx, "Bouc-Wen: ");
    let lv = ctx.levels(&mut sys, 0.0)?;
    let (x, v) = (std(&lv.trace.x), std(&lv.trace.v));
    let m = mech_mut(&mut sys)?;
    let alpha = a_rel * m.k;
    // z saturates at alpha / (beta + gamma) = z_rel alpha x_rms
    let bg = 1.0 / (z_rel * x);
    m.bouc_wen = Some([alpha, share * bg, (1.0 - share) * bg]);
    sys.set_substeps(4.0 * bg * v);
    let mut b = Built::new(sys, 2, vec!["hysteresis"]);
    b.true_order = 3;
    b.description = format!(
        "{text}, + Bouc-Wen z: alpha {a_rel:.2} k, z_max = {z_rel:.2} alpha x_rms, beta/(beta+gamma) {share:.2}"
    );
    mech_params(&mut b);
    b.param("alpha_rel", a_rel);
    b.param("zmax_rel", z_rel);
    b.param("beta_share", share);
    Ok(b)
}

/// A third-order linear cascade (a resonance or a real pole with a
/// further section within a factor 3 in frequency: an actuator or sensor
/// lag) diagnosed from the engineer's order-2 model: the missing pole is
/// the `dynamics` cause, which a low-order model can absorb as a dead
/// time or a nonlinear model imitate.
fn lag(r: &mut R, ctx: &mut Ctx) -> Result<Built, CoreError> {
    let delay = r.random_range(0..=2);
    let (mut sys, c) = cascade_system(r, ctx, 3, 1)?;
    sys.delay = delay;
    let mut b = Built::new(sys, 2, vec!["dynamics"]);
    b.true_order = 3;
    b.strength_engineer = true;
    b.description = format!("lag: linear {}, input delay {delay}", c.text);
    cascade_params(&mut b, &c);
    b.param("delay", delay as f64);
    Ok(b)
}

/// A hidden second mass: the engineer's 2nd-order model misses a mode.
fn two_mass(r: &mut R, ctx: &mut Ctx) -> Result<Built, CoreError> {
    let (mech0, f0) = msd(r);
    let mu = uni(r, 0.1, 0.6);
    let zeta2 = logu(r, 0.01, 0.1);
    let x0 = logu(r, 1e-3, 1e-1);
    let spp = ctx.drawn.spp;
    // at least 4 samples per period of the upper coupled mode
    let bound = spp / (4.0 * (1.0 + mu).sqrt());
    let ratio = if bound >= 1.5 {
        uni(r, 1.5, bound.min(4.0))
    } else {
        uni(r, 0.35, 0.7)
    };
    let (m2, w2) = (mu * mech0.m, 2.0 * PI * f0 * ratio);
    let mut mech = mech0;
    mech.second = Some([m2, m2 * w2 * w2, 2.0 * zeta2 * w2 * m2]);
    let k = mech.k;
    let mut sys = System::new(Core::Mech(mech), 1);
    sys.input_scale[0] = k * x0;
    ctx.excite(1.0 / f0, f0 * ratio.max(1.0), 1);
    sys.ts = ctx.ts;
    sys.set_substeps(0.0);
    let mut b = Built::new(sys, 2, vec!["dynamics"]);
    b.true_order = 4;
    b.strength_engineer = true;
    b.description = format!(
        "two-mass: driven mass (f0 {f0:.3e} Hz) with a hidden second mass (m2/m1 {mu:.2}, f2/f0 {ratio:.2}, zeta2 {zeta2:.3})"
    );
    mech_params(&mut b);
    b.param("mass_ratio", mu);
    b.param("freq_ratio", ratio);
    b.param("zeta2", zeta2);
    Ok(b)
}

/// Two inputs through common dynamics, a static nonlinearity on one of them.
fn two_input(r: &mut R, ctx: &mut Ctx) -> Result<Built, CoreError> {
    let order = r.random_range(1..=3);
    let j = r.random_range(0..2usize);
    let kind = r.random_range(0..3);
    let (p, rho, g_rel) = (uni(r, 0.5, 0.85), uni(r, 0.2, 0.6), logu(r, 0.5, 2.0));
    ctx.need_amplitude_spread();
    let (mut sys, c) = cascade_system(r, ctx, order, 2)?;
    // comparable contributions of the two inputs
    sys.gains[1 - j] = sys.gains[j].abs() * g_rel * sys.gains[1 - j].signum() * sys.input_scale[j]
        / sys.input_scale[1 - j];
    let (map, text) = match kind {
        0 => (
            InputMap::Tanh(ctx.input_quantile(&sys, j, p)),
            format!("L tanh(u/L), L = {p:.2}-quantile"),
        ),
        1 => {
            let u = std(&ctx.inputs(&sys, true)[j]);
            (
                InputMap::Cubic(rho / (u * u)),
                format!("u + a u^3, a u_rms^2 = {rho:.2}"),
            )
        }
        _ => (
            InputMap::DeadZone(ctx.input_quantile(&sys, j, 1.1 - p)),
            format!("dead zone at the {:.2}-quantile", 1.1 - p),
        ),
    };
    sys.input_maps[j] = map;
    let mut b = Built::new(sys, order, vec!["nonlinearity"]);
    b.nonlinear_input = Some(j);
    b.description = format!(
        "two inputs: u{} -> {text}, u{} linear, common {}",
        j + 1,
        2 - j,
        c.text
    );
    cascade_params(&mut b, &c);
    b.param("nonlinear_input", j as f64);
    Ok(b)
}

/// A linear cascade with non-white-Gaussian noise.
fn noisy(family: Family, r: &mut R, ctx: &mut Ctx) -> Result<Built, CoreError> {
    let order = r.random_range(1..=3);
    let nu = uni(r, 2.5, 4.0);
    let (a, cma) = (uni(r, 0.5, 0.95), uni(r, -0.5, 0.5));
    let cut = uni(r, 0.5, 2.0);
    let (sys, c) = cascade_system(r, ctx, order, 1)?;
    let mut b = Built::new(sys, order, vec!["noise"]);
    b.noise = match family {
        Family::StudentT => NoiseKind::StudentT { nu },
        Family::ColouredNoise => NoiseKind::Coloured { a, c: cma },
        _ => NoiseKind::Process {
            cutoff: (cut * ctx.f_ref).min(0.45),
        },
    };
    if family != Family::StudentT {
        // Gaussian noise an OE model cannot reduce: naming nothing is fine too
        b.alternatives = vec![vec![]];
    }
    b.description = format!("linear {} with {}", c.text, b.noise.describe());
    cascade_params(&mut b, &c);
    match b.noise {
        NoiseKind::StudentT { nu } => b.param("nu", nu),
        NoiseKind::Coloured { a, c } => {
            b.param("ar", a);
            b.param("ma", c);
        }
        NoiseKind::Process { cutoff } => b.param("cutoff", cutoff),
        NoiseKind::White => {}
    }
    Ok(b)
}
