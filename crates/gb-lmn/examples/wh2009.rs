//! WH2009 with the Wiener–Hammerstein local model network: best linear
//! approximation, pole/zero split scan, joint Levenberg–Marquardt.
//! Trained on the official 100 000 estimation samples, free-run simulation
//! of the 78 800 test samples from the zero state, RMSE after the standard
//! init window of 50 samples.
//!
//! ```sh
//! cargo run --release -p gb-lmn --example wh2009
//! ```
use gb_core::{metrics, CsvTable};
use gb_lmn::WhParams;
use std::path::PathBuf;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let default = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    let Some(dir) = gb_core::benchmark_data_dir(&default, "wiener_hammerstein_2009") else {
        return Ok(());
    };
    let d = dir.join("wiener_hammerstein_2009");
    let tr = CsvTable::read(d.join("train.csv"))?;
    let te = CsvTable::read(d.join("test.csv"))?;
    let (u, y) = (tr.column("u")?.to_vec(), tr.column("y")?.to_vec());
    let (ut, yt) = (te.column("u")?.to_vec(), te.column("y")?.to_vec());
    let env = |k: &str, v: usize| {
        std::env::var(k)
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(v)
    };
    // the WH2009 set-up: a 6-pole / 6-zero BLA (two third-order filters),
    // a 200-sample transient and a scan on the first 30 000 samples
    let mut p = WhParams::new()
        .skip(200)
        .scan_samples(30_000)
        .knots(env("WH_KNOTS", 15))
        .extra_g1(env("WH_EXTRA", 3))
        .candidates(env("WH_CAND", 2))
        .max_iter(env("WH_ITER", 60))
        .bla(env("WH_POLES", 6), env("WH_ZEROS", 6));
    p.smoothness = std::env::var("WH_SMOOTH")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(p.smoothness);
    let t0 = Instant::now();
    let (m, rep) = p.check()?.fit(&u, &y)?;
    let secs = t0.elapsed().as_secs_f64();
    let sim = m.simulate(&ut);
    let rmse = metrics::rmse(&yt[50..], &sim[50..])?;
    println!("{}", m.describe());
    println!("{rep:?}");
    println!(
        "WH2009 test: RMSE {:.3} mV (init window 50, {} samples); train RMSE {:.3} mV; fit {secs:.1} s",
        1e3 * rmse,
        yt.len() - 50,
        1e3 * rep.rmse
    );
    Ok(())
}
