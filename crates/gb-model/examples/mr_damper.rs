//! MR damper, white-noise characterisation test (Dyke, NEES-2012-1158):
//! force from displacement, velocity and voltage with the grey-box wavelet
//! state-space class — a Spencer/Bouc-Wen-like structure with a hidden
//! hysteretic state z and a hidden filtered voltage w:
//!
//! ```text
//! z⁺ = a_z z + b_z V + f(V, z),        w⁺ = a_w w + b_w Y,
//! F  = c_z z + c_w w + d·(D, V, Y) + g₁(z, w) + g₂(V, w) + F₀,
//! ```
//!
//! f, g₁, g₂ sparse `bior2.2` expansions, identified by output error on the
//! first 70 % of the record; free-run NRMSE on the last 30 % against the
//! linear output-error model of `gb-lmn` (order 2, same inputs).
//!
//! ```sh
//! cargo run --release -p gb-model --example mr_damper [-- OUT_DIR]
//! ```
//!
//! By default two more states model a resonance (150 Hz start) seen in the
//! force, driven by the inputs, z and a 3-D wavelet term of (V, z, w)
//! (`MR_RES=0` without it, `MR_RESNL=0` without its nonlinear drive;
//! `MR_RES_HZ` its start frequency).
//! Variants (environment): `MR_3D=0` (2-D terms f(V, z), g(z, w), g(V, w)),
//! `MR_W2=1` (second-order voltage filter), `MR_WNL=1` (nonlinear voltage
//! filter), `MR_PREISACH=1` (Preisach operator of D on the force), `MR_Z2=1`
//! (second hysteretic state), `MR_SUB`, `MR_LEVEL`, `MR_COARSE`, `MR_ITER`,
//! `MR_AZ`, `MR_ADAPT=1`; see docs/model.md for their results.
use gb_core::{metrics, CsvTable};
use gb_model::{
    linear_from_oe, NonlinearTerm, OeParams, ProgressBar, Signal, SparseExpansion,
    SparseStateSpace, Structure, Target,
};
use std::path::PathBuf;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::env::var_os("GREYBOX_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    let file = dir.join("mr_damper_dyke_nees/ranran_50.csv");
    if !file.is_file() {
        eprintln!(
            "mr_damper example skipped: {} not found (set GREYBOX_DATA)",
            file.display()
        );
        return Ok(());
    }
    let out = std::env::args().nth(1).map(PathBuf::from);
    let t = CsvTable::read(&file)?;
    let (d, v, volt, f) = (
        t.column("D")?.to_vec(),
        t.column("V")?.to_vec(),
        t.column("Y")?.to_vec(),
        t.column("F")?.to_vec(),
    );
    let n = f.len();
    let n_fit = n * 7 / 10;
    let inputs: Vec<Vec<f64>> = vec![d.clone(), v.clone(), volt.clone()];
    let fit_in: Vec<Vec<f64>> = inputs.iter().map(|s| s[..n_fit].to_vec()).collect();
    let test_in: Vec<Vec<f64>> = inputs.iter().map(|s| s[n_fit..].to_vec()).collect();
    let (f_fit, f_test) = (&f[..n_fit], &f[n_fit..]);
    let t0 = Instant::now();

    // linear baseline (gb-lmn OE, order 2)
    let lin = linear_from_oe(&fit_in, f_fit, 2)?;
    let e_lin = metrics::nrmse(f_test, &lin.simulate(&test_in)?)?;
    println!("linear OE (order 2, inputs D, V, Y): test free-run NRMSE {e_lin:.4}");

    // grey-box start: z a low-passed velocity, w a low-passed voltage
    let az: f64 = std::env::var("MR_AZ")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0.95);
    let mut start = SparseStateSpace::linear(
        vec![az, 0.0, 0.0, 0.95],
        vec![0.0, 1.0 - az, 0.0, 0.0, 0.0, 0.05],
        vec![0.0, 0.0],
        vec![0.0, 0.0, 0.0],
    )?;
    start.y_offset = metrics::mean(f_fit);
    start.substeps = std::env::var("MR_SUB")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1);
    start.structure = Structure {
        a: vec![true, false, false, true],
        b: vec![false, true, false, false, false, true],
        c: vec![true, true],
        d: vec![true, true, true],
        x0: vec![false, false],
        y_offset: true,
    };
    let extra = std::env::var("MR_Z2").map(|v| v == "1").unwrap_or(false);
    let w2 = std::env::var("MR_W2").map(|v| v == "1").unwrap_or(false);
    if w2 {
        // second-order voltage dynamics: w1 ← Y, w2 ← w1 (states z, w1, w2)
        start.n_states = 3;
        start.a = vec![0.95, 0.0, 0.0, 0.0, 0.9, 0.0, 0.0, 0.1, 0.9];
        start.b = vec![0.0, 0.05, 0.0, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0];
        start.c = vec![0.0; 3];
        start.x0 = vec![0.0; 3];
        start
            .process_noise
            .push(gb_model::NoiseModel::Gaussian { sd: 0.0 });
        start.structure = Structure {
            a: vec![true, false, false, false, true, false, false, true, true],
            b: vec![false, true, false, false, false, true, false, false, false],
            c: vec![true; 3],
            d: vec![true; 3],
            x0: vec![false; 3],
            y_offset: true,
        };
    }
    if extra {
        // a second hysteretic state on a slower time scale
        start.n_states = 3;
        start.a = vec![0.95, 0.0, 0.0, 0.0, 0.95, 0.0, 0.0, 0.0, 0.995];
        start.b = vec![0.0, 0.05, 0.0, 0.0, 0.0, 0.05, 0.0, 0.005, 0.0];
        start.c = vec![0.0; 3];
        start.x0 = vec![0.0; 3];
        start
            .process_noise
            .push(gb_model::NoiseModel::Gaussian { sd: 0.0 });
        start.structure = Structure {
            a: vec![true, false, false, false, true, false, false, false, true],
            b: vec![false, true, false, false, false, true, false, true, false],
            c: vec![true; 3],
            d: vec![true; 3],
            x0: vec![false; 3],
            y_offset: true,
        };
    }
    if std::env::var("MR_RES").map(|v| v != "0").unwrap_or(true) {
        // two more linear states: a resonance (test rig / load cell) driven
        // by the inputs and by z, seen in the force
        let n0 = start.n_states;
        let n1 = n0 + 2;
        let freq: f64 = std::env::var("MR_RES_HZ")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(150.0);
        let th = std::f64::consts::TAU * freq / 3004.8;
        let r = 0.97;
        let mut a = vec![0.0; n1 * n1];
        let mut af = vec![false; n1 * n1];
        for i in 0..n0 {
            for j in 0..n0 {
                a[i * n1 + j] = start.a[i * n0 + j];
                af[i * n1 + j] = start.structure.a[i * n0 + j];
            }
        }
        let (p, q) = (n0, n0 + 1);
        a[p * n1 + p] = r * th.cos();
        a[p * n1 + q] = -r * th.sin();
        a[q * n1 + p] = r * th.sin();
        a[q * n1 + q] = r * th.cos();
        for i in [p, q] {
            for j in [p, q] {
                af[i * n1 + j] = true;
            }
            af[i * n1] = true; // driven by z
        }
        let m = start.n_inputs;
        let mut b = start.b.clone();
        let mut bf = start.structure.b.clone();
        b.extend(vec![0.0; 2 * m]);
        bf.extend(vec![true; 2 * m]);
        b[p * m + 1] = 0.01;
        start.n_states = n1;
        start.a = a;
        start.b = b;
        start.c.extend([0.0, 0.0]);
        start.x0.extend([0.0, 0.0]);
        start.process_noise.extend([
            gb_model::NoiseModel::Gaussian { sd: 0.0 },
            gb_model::NoiseModel::Gaussian { sd: 0.0 },
        ]);
        start.structure.a = af;
        start.structure.b = bf;
        start.structure.c.extend([true, true]);
        start.structure.x0.extend([false, false]);
    }
    let ns = start.n_states;
    let (_, xs) = start.simulate_states(&fit_in)?;
    let span = |i: usize| {
        let (lo, hi) = xs
            .chunks(ns)
            .fold((f64::MAX, f64::MIN), |(a, b), x| (a.min(x[i]), b.max(x[i])));
        let m = 0.25 * (hi - lo);
        (lo - m, hi + m)
    };
    let ((zl, zh), (wl, wh)) = (span(0), span(if w2 { 2 } else { 1 }));
    let wstate = if w2 { 2 } else { 1 };
    let vmax = v.iter().fold(0.0f64, |a, x| a.max(x.abs())) * 1.1;
    if extra {
        let (ql, qh) = span(2);
        start.terms.push(NonlinearTerm {
            target: Target::State(2),
            args: vec![Signal::Input(1), Signal::State(2)],
            expansion: SparseExpansion::new("bior2.2", vec![-vmax, ql], vec![vmax, qh])?,
        });
        start.terms.push(NonlinearTerm {
            target: Target::Output,
            args: vec![Signal::State(2), Signal::State(1)],
            expansion: SparseExpansion::new("bior2.2", vec![ql, wl], vec![qh, wh])?,
        });
    }
    let three_d = std::env::var("MR_3D").map(|v| v == "1").unwrap_or(true);
    if three_d {
        // f(V, z, w) and g(V, z, w): the voltage changes the whole loop
        start.terms.push(NonlinearTerm {
            target: Target::State(0),
            args: vec![Signal::Input(1), Signal::State(0), Signal::State(wstate)],
            expansion: SparseExpansion::new("bior2.2", vec![-vmax, zl, wl], vec![vmax, zh, wh])?,
        });
        start.terms.push(NonlinearTerm {
            target: Target::Output,
            args: vec![Signal::Input(1), Signal::State(0), Signal::State(wstate)],
            expansion: SparseExpansion::new("bior2.2", vec![-vmax, zl, wl], vec![vmax, zh, wh])?,
        });
    } else {
        start.terms.push(NonlinearTerm {
            target: Target::State(0),
            args: vec![Signal::Input(1), Signal::State(0)],
            expansion: SparseExpansion::new("bior2.2", vec![-vmax, zl], vec![vmax, zh])?,
        });
        start.terms.push(NonlinearTerm {
            target: Target::Output,
            args: vec![Signal::State(0), Signal::State(1)],
            expansion: SparseExpansion::new("bior2.2", vec![zl, wl], vec![zh, wh])?,
        });
        start.terms.push(NonlinearTerm {
            target: Target::Output,
            args: vec![Signal::Input(1), Signal::State(1)],
            expansion: SparseExpansion::new("bior2.2", vec![-vmax, wl], vec![vmax, wh])?,
        });
    }
    if std::env::var("MR_PREISACH")
        .map(|v| v == "1")
        .unwrap_or(false)
    {
        // a Preisach operator of the displacement (seal friction, accumulator)
        let dmax = d.iter().fold(0.0f64, |a, x| a.max(x.abs())) * 1.05;
        start.hysteresis.push(gb_model::HysteresisTerm {
            target: Target::Output,
            input: 0,
            everett: gb_model::WaveletEverett::new(SparseExpansion::new(
                "bior2.2",
                vec![-dmax, -dmax],
                vec![dmax, dmax],
            )?)?,
        });
    }
    if std::env::var("MR_WNL").map(|v| v == "1").unwrap_or(false) {
        // nonlinear voltage dynamics (e.g. different rise and decay)
        let ylo = volt.iter().cloned().fold(f64::MAX, f64::min);
        let yhi = volt.iter().cloned().fold(f64::MIN, f64::max);
        let m = 0.05 * (yhi - ylo);
        start.terms.push(NonlinearTerm {
            target: Target::State(1),
            args: vec![Signal::Input(2), Signal::State(1)],
            expansion: SparseExpansion::new("bior2.2", vec![ylo - m, wl], vec![yhi + m, wh])?,
        });
    }
    if ns >= 4 && std::env::var("MR_RESNL").map(|v| v != "0").unwrap_or(true) {
        // the resonance driven by the nonlinear force as well
        start.terms.push(NonlinearTerm {
            target: Target::State(ns - 2),
            args: vec![Signal::Input(1), Signal::State(0), Signal::State(1)],
            expansion: SparseExpansion::new("bior2.2", vec![-vmax, zl, wl], vec![vmax, zh, wh])?,
        });
    }
    let fit = OeParams::new()
        .adapt_boxes(std::env::var("MR_ADAPT").map(|v| v == "1").unwrap_or(false))
        .max_iter(
            std::env::var("MR_ITER")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(30),
        )
        .coarse_level(
            std::env::var("MR_COARSE")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(1),
        )
        .max_level(
            std::env::var("MR_LEVEL")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(3),
        )
        .check()?;
    let (model, report) = fit.fit(start, &fit_in, f_fit, &mut ProgressBar::new())?;
    for s in &report.stages {
        println!(
            "  stage {:<16} coefficients {:>4}  train RMSE {:.2} N  {}",
            s.stage,
            s.coefficients,
            s.rmse,
            if s.accepted { "kept" } else { "rejected" }
        );
    }
    let sim = model.simulate(&test_in)?;
    let e = metrics::nrmse(f_test, &sim)?;
    println!(
        "wavelet grey-box: test free-run NRMSE {e:.4} ({:.1}x better than linear); fit {:.1} s; {}",
        e_lin / e,
        t0.elapsed().as_secs_f64(),
        model.describe()
    );
    if let Some(o) = out {
        std::fs::create_dir_all(&o)?;
        let lsim = lin.simulate(&test_in)?;
        let rows: Vec<String> = (0..f_test.len())
            .map(|k| {
                format!(
                    "{},{},{},{},{}",
                    v[n_fit + k],
                    d[n_fit + k],
                    f_test[k],
                    lsim[k],
                    sim[k]
                )
            })
            .collect();
        gb_core::write_atomic(
            o.join("mr_damper_loops.csv"),
            format!(
                "velocity,displacement,force,linear,model\n{}\n",
                rows.join("\n")
            )
            .as_bytes(),
        )?;
        gb_core::write_atomic(o.join("mr_damper.gbs"), &model.to_bytes()?)?;
    }
    Ok(())
}
