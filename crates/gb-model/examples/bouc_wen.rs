//! Bouc-Wen hysteretic benchmark (Noël & Schoukens 2016) with the grey-box
//! wavelet state-space class: a second-order mechanical structure
//! (position, velocity) plus a hidden hysteretic restoring force z with its
//! own dynamics `z⁺ = a₃₂ v + a₃₃ z + f(v, z)`, f a sparse wavelet expansion,
//! identified by output error on the training record.
//!
//! ```sh
//! cargo run --release -p gb-model --example bouc_wen [-- OUT_DIR]
//! ```
//!
//! Reads `$GREYBOX_DATA/bouc_wen/` (default `../shared/data`); skips with a
//! notice when absent. Writes the model and the test simulations to OUT_DIR
//! when given.
use gb_core::{metrics, CsvTable};
use gb_model::{hysteretic_mechanical_start, second_order_parameters, OeParams};
use std::path::PathBuf;
use std::time::Instant;

/// Progress on stderr, one line per stage of the fit (the `greybox` CLI
/// draws a bar through the same `gb_core::Observer`).
#[derive(Default)]
struct StageLog(std::sync::Mutex<String>);

impl gb_core::Observer for StageLog {
    fn progress(&self, _done: usize, _total: usize, message: &str) {
        let stage = message.split(':').next().unwrap_or(message);
        if let Ok(mut last) = self.0.lock() {
            if *last != stage {
                eprintln!("  {message}");
                *last = stage.to_string();
            }
        }
    }
}

fn data_dir() -> Option<PathBuf> {
    let d = std::env::var_os("GREYBOX_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    d.join("bouc_wen").is_dir().then_some(d)
}

fn load(p: PathBuf) -> Result<(Vec<f64>, Vec<f64>), Box<dyn std::error::Error>> {
    let t = CsvTable::read(&p)?;
    Ok((t.column("u")?.to_vec(), t.column("y")?.to_vec()))
}

fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let Some(dir) = data_dir() else {
        eprintln!("bouc_wen example skipped: data folder not found (set GREYBOX_DATA)");
        return Ok(());
    };
    let out = std::env::args().nth(1).map(PathBuf::from);
    let (u, y) = load(dir.join("bouc_wen/train_multisine_forgione.csv"))?;
    let (ut, yt) = load(dir.join("bouc_wen/test_multisine.csv"))?;
    let (us, ys) = load(dir.join("bouc_wen/test_sinesweep.csv"))?;
    let ts = 1.0 / 750.0;
    let substeps = env_usize("BW_SUBSTEPS", 8);
    let max_level = env_usize("BW_MAX_LEVEL", 4) as i32;
    let n_train = env_usize("BW_TRAIN", u.len()).min(u.len());
    let (u, y) = (u[..n_train].to_vec(), y[..n_train].to_vec());
    let t0 = Instant::now();

    // 1.–2. best linear model (gb-lmn OE, order 2, on the second period) and
    //    the grey-box start: m ÿ + c ẏ + k y + z = u, ż = k_z ẏ + f(ẏ, z)
    let (start, lin) = hysteretic_mechanical_start(&u, &y, 8192..16384, ts, substeps)?;
    let (w2, two_zeta_w, gain) = second_order_parameters(&lin, ts)?;
    let lin_test = {
        let mut y2 = lin.simulate(&[[ut.clone(), ut.clone()].concat()])?;
        y2.drain(..ut.len());
        metrics::rmse(&yt, &y2)?
    };
    println!(
        "linear OE (order 2): f0 = {:.2} Hz, zeta = {:.4}, 1/m = {:.4}; test multisine RMSE {:.3e} m",
        w2.sqrt() / (2.0 * std::f64::consts::PI),
        two_zeta_w / (2.0 * w2.sqrt()),
        gain,
        lin_test
    );

    // 3. output error, coarse-to-fine
    let fit = OeParams::new()
        .max_iter(env_usize("BW_ITER", 40))
        .coarse_level(1)
        .max_level(max_level)
        .max_new(env_usize("BW_MAX_NEW", 40))
        .check()?;
    let (model, report) = fit.fit(start, std::slice::from_ref(&u), &y, &StageLog::default())?;
    let fit_time = t0.elapsed().as_secs_f64();
    for s in &report.stages {
        println!(
            "  stage {:<22} coefficients {:>4}  train RMSE {:.4e}  BIC {:.1}  {}",
            s.stage,
            s.coefficients,
            s.rmse,
            s.bic,
            if s.accepted { "kept" } else { "rejected" }
        );
    }
    println!(
        "identification: {} LM iterations, {:.1} s; training RMSE {:.3e} m; path {:?}; log-likelihood {:.1}",
        report.iterations, fit_time, report.rmse, report.path, report.log_likelihood
    );
    println!("model: {}", model.describe());

    // 4. tests: multisine in steady state (the periodic input run twice, the
    //    second period scored), sine sweep from rest
    let mut x0 = model.clone();
    x0.x0 = vec![0.0; 3];
    let mut yms = x0.simulate(&[[ut.clone(), ut.clone(), ut.clone()].concat()])?;
    yms.drain(..2 * ut.len());
    let rm = metrics::rmse(&yt, &yms)?;
    let t1 = Instant::now();
    let yss = x0.simulate(std::slice::from_ref(&us))?;
    let sim_time = t1.elapsed().as_secs_f64();
    let rs = metrics::rmse(&ys, &yss)?;
    println!(
        "test multisine RMSE {:.3e} m (NRMSE {:.4}); sine sweep RMSE {:.3e} m (NRMSE {:.4})",
        rm,
        metrics::nrmse(&yt, &yms)?,
        rs,
        metrics::nrmse(&ys, &yss)?
    );
    println!(
        "simulation: {} samples in {:.3} s = {:.2} M samples/s ({} sub-steps each)",
        us.len(),
        sim_time,
        us.len() as f64 / sim_time / 1e6,
        model.substeps
    );
    if let Some(dir) = out {
        std::fs::create_dir_all(&dir)?;
        gb_core::write_atomic(dir.join("bouc_wen.gbs"), &model.to_bytes()?)?;
        let rows: Vec<String> = yt
            .iter()
            .zip(&yms)
            .map(|(a, b)| format!("{a},{b}"))
            .collect();
        gb_core::write_atomic(
            dir.join("bw_multisine.csv"),
            format!("y,yhat\n{}\n", rows.join("\n")).as_bytes(),
        )?;
        let f = &model.terms[0].expansion;
        let rows: Vec<String> = f
            .table(41)
            .iter()
            .map(|r| format!("{},{},{}", r[0], r[1], r[2]))
            .collect();
        gb_core::write_atomic(
            dir.join("bw_f.csv"),
            format!("v,z,f\n{}\n", rows.join("\n")).as_bytes(),
        )?;
    }
    Ok(())
}
