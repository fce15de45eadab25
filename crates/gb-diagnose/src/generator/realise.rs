//! From a family's description to the records: simulate, add noise,
//! measure the floor and the effect strength.
use super::ctx::{Built, Ctx, Drawn};
use super::linfit::arx_misfit;
use super::noise::{output_noise, process_force, white, NoiseKind};
use super::{families, Case, Family, Knobs};
use gb_core::{metrics, rng, CoreError, Record};

/// Stable 64-bit FNV-1a hash of a family name (mixes the family into the seed).
fn fnv(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

/// Streams: 0 knobs and parameters, 3/4 output noise (train/validation),
/// 5/6 process force, 7/8 measurement noise with process noise,
/// 100 + 2j (+1) the excitation of input j.
pub(crate) fn realise(fam: Family, seed: u64, knobs: &Knobs) -> Result<Case, CoreError> {
    let base = fnv(fam.name()) ^ seed.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    let mut r = rng::stream(base, 0);
    let drawn = Drawn::draw(&mut r, knobs);
    let mut ctx = Ctx::new(base, drawn);
    let mut b = families::build(fam, &mut r, &mut ctx)?;
    b.system.ts = ctx.ts;
    if ctx.u_train.len() != b.system.n_inputs() {
        return Err(CoreError::InvalidArgument(format!(
            "generator: family '{}' realised {} inputs for {}",
            fam.name(),
            ctx.u_train.len(),
            b.system.n_inputs()
        )));
    }
    let (u_tr, u_va) = (ctx.inputs(&b.system, true), ctx.inputs(&b.system, false));
    let y_tr = b.system.simulate(&u_tr, None, None)?;
    let y_va = b.system.simulate(&u_va, None, None)?;
    let strength = effect_strength(&b, (&u_tr, &y_tr), (&u_va, &y_va))?;
    let (m_tr, m_va, floor) = add_noise(&b, &ctx, &y_tr, &y_va, knobs.noise_free)?;
    let names: Vec<String> = if u_tr.len() == 1 {
        vec!["u".into()]
    } else {
        (1..=u_tr.len()).map(|j| format!("u{j}")).collect()
    };
    let d = &ctx.drawn;
    let description = format!(
        "{}; ts {:.3e} s ({:.1} samples/period), {}, SNR {:.1} dB, {} + {} samples",
        b.description,
        ctx.ts,
        d.spp,
        d.excitation.describe(),
        d.snr_db,
        d.n_train,
        d.n_validate
    );
    let own = |v: &[&str]| -> Vec<String> { v.iter().map(|s| s.to_string()).collect() };
    let foreign = crate::Cause::ALL
        .iter()
        .map(|c| c.name())
        .filter(|c| !b.expected.contains(c) && !b.alternatives.iter().any(|a| a.contains(c)))
        .map(|c| c.to_string())
        .collect();
    Ok(Case {
        family: fam.name().to_string(),
        seed,
        description,
        train: Record::new(names.clone(), "y".into(), u_tr, m_tr)?,
        validate: Record::new(names, "y".into(), u_va, m_va)?,
        expected: own(&b.expected),
        acceptable_alternatives: b.alternatives.iter().map(|a| own(a)).collect(),
        foreign,
        noise_floor_nrmse: floor,
        snr_db: d.snr_db,
        noise: b.noise,
        ts: ctx.ts,
        samples_per_period: d.spp,
        excitation: d.excitation,
        model_order: b.model_order,
        true_order: b.true_order,
        input_delay: b.system.delay,
        feedthrough: b.system.feedthrough != 0.0,
        nonlinear_input: b.nonlinear_input,
        effect_strength: strength,
        parameters: b.parameters,
    })
}

type Pair<'a> = (&'a [Vec<f64>], &'a [f64]);

/// Free-run validation NRMSE of the best least-squares ARX model on
/// noise-free data (orders true, true + 1, true + 2: an equation-error fit of
/// nonlinear data can simulate badly at one order and well at the next).
fn effect_strength(b: &Built, train: Pair, validate: Pair) -> Result<f64, CoreError> {
    let s = &b.system;
    let ni = s.n_inputs();
    if b.strength_engineer {
        let n = b.model_order;
        return arx_misfit(train, validate, n, &vec![(1..=n).collect(); ni]);
    }
    let nk = s.delay + usize::from(s.feedthrough == 0.0);
    let mut best = f64::INFINITY;
    for n in b.true_order..=b.true_order + 2 {
        let lags: Vec<usize> = (nk..=nk + n).collect();
        best = best.min(arx_misfit(train, validate, n, &vec![lags; ni])?);
    }
    Ok(best)
}

/// Measured outputs (training, validation) and the noise floor.
fn add_noise(
    b: &Built,
    ctx: &Ctx,
    y_tr: &[f64],
    y_va: &[f64],
    noise_free: bool,
) -> Result<(Vec<f64>, Vec<f64>, f64), CoreError> {
    if noise_free {
        return Ok((y_tr.to_vec(), y_va.to_vec(), 0.0));
    }
    let sigma = metrics::std(y_tr) * 10f64.powf(-ctx.drawn.snr_db / 20.0);
    let (e_tr, e_va) = match b.noise {
        NoiseKind::Process { cutoff } => {
            // linear system: the disturbance's response superposes
            let resp = |stream: u64, n: usize| -> Result<Vec<f64>, CoreError> {
                let d = process_force(n, cutoff, &mut rng::stream(ctx.base, stream));
                let zero = vec![vec![0.0; n]; b.system.n_inputs()];
                b.system.simulate(&zero, Some(&d), None)
            };
            let (d_tr, d_va) = (resp(5, y_tr.len())?, resp(6, y_va.len())?);
            let g = sigma / metrics::std(&d_tr).max(1e-300);
            let w_tr = white(y_tr.len(), sigma / 3.0, &mut rng::stream(ctx.base, 7));
            let w_va = white(y_va.len(), sigma / 3.0, &mut rng::stream(ctx.base, 8));
            let mix = |d: &[f64], w: &[f64]| -> Vec<f64> {
                d.iter().zip(w).map(|(a, b)| g * a + b).collect()
            };
            (mix(&d_tr, &w_tr), mix(&d_va, &w_va))
        }
        k => (
            output_noise(k, y_tr.len(), sigma, &mut rng::stream(ctx.base, 3))?,
            output_noise(k, y_va.len(), sigma, &mut rng::stream(ctx.base, 4))?,
        ),
    };
    let add = |y: &[f64], e: &[f64]| -> Vec<f64> { y.iter().zip(e).map(|(a, b)| a + b).collect() };
    let (m_tr, m_va) = (add(y_tr, &e_tr), add(y_va, &e_va));
    let floor = match b.noise {
        NoiseKind::Process { .. } => metrics::nrmse(&m_va, y_va)?,
        _ => metrics::std(&e_va) / metrics::std(&m_va).max(1e-300),
    };
    Ok((m_tr, m_va, floor))
}
