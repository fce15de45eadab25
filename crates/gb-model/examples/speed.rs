//! Simulation speed of identified models (issue 7: ≥ 10 M samples/s).
//!
//! ```sh
//! cargo run --release -p gb-model --example speed [-- MODEL.gbs ...]
//! ```
//!
//! Without arguments it times two generated models: a second-order
//! mechanical model with a 1-D sparse wavelet spring (1 sub-step) and a
//! Bouc-Wen-shaped 3-state model with a 2-D sparse wavelet term on levels
//! 1–4 (8 sub-steps); with arguments, the given model files. Best of 5 runs
//! over 2²⁰ samples, one core.
use gb_model::{NonlinearTerm, Signal, SparseExpansion, SparseStateSpace, Target};
use std::time::Instant;

fn time(name: &str, m: &SparseStateSpace, n: usize) -> Result<(), Box<dyn std::error::Error>> {
    let inputs: Vec<Vec<f64>> = (0..m.n_inputs)
        .map(|j| {
            (0..n)
                .map(|t| ((t * 7919 + j * 31) % 1000) as f64 / 1000.0 - 0.5)
                .collect()
        })
        .collect();
    let mut best = f64::INFINITY;
    let mut check = 0.0;
    for _ in 0..5 {
        let t0 = Instant::now();
        let y = m.simulate(&inputs)?;
        best = best.min(t0.elapsed().as_secs_f64());
        check += y[n - 1];
    }
    println!(
        "{name}: {:.1} M samples/s ({:.1} ns/sample, {} sub-steps, {} non-zero coefficients) [{check:.3e}]",
        n as f64 / best / 1e6,
        best / n as f64 * 1e9,
        m.substeps,
        m.n_coefficients()
    );
    Ok(())
}

fn expansion(
    dims: usize,
    max_level: i32,
    lo: f64,
    hi: f64,
) -> Result<SparseExpansion, gb_model::ModelError> {
    let mut e = SparseExpansion::new("bior2.2", vec![lo; dims], vec![hi; dims])?;
    e.add_coarse_grid(1)?;
    for level in 1..=max_level {
        let mut c = e.detail_candidates(level);
        // sparse: keep every third detail atom
        c = c.into_iter().step_by(3).collect();
        for x in c {
            e.push(x)?;
        }
    }
    let vals: Vec<f64> = (0..e.len())
        .map(|i| 1e-4 * (((i * 7919) % 21) as f64 - 10.0))
        .collect();
    e.set_values(&vals)?;
    e.drop_zeros();
    Ok(e)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let n = 1 << 20;
    let files: Vec<String> = std::env::args().skip(1).collect();
    if !files.is_empty() {
        for f in files {
            let m = SparseStateSpace::from_bytes(&std::fs::read(&f)?)?;
            time(&f, &m, n)?;
        }
        return Ok(());
    }
    let h = 0.0125;
    let mut msd = SparseStateSpace::linear(
        vec![1.0, h, -h * 4.0, 1.0 - h * 0.6],
        vec![0.0, h],
        vec![1.0, 0.0],
        vec![0.0],
    )?;
    msd.terms.push(NonlinearTerm {
        target: Target::State(1),
        args: vec![Signal::State(0)],
        expansion: expansion(1, 3, -1.0, 1.0)?,
    });
    time("mechanical, 1-D wavelet spring", &msd, n)?;
    let hs = 1.0 / 6000.0;
    let mut bw = SparseStateSpace::linear(
        vec![
            1.0,
            hs,
            0.0,
            -hs * 2.5e4,
            1.0 - hs * 20.0,
            -hs,
            0.0,
            hs * 2.5e4,
            1.0 - hs * 5.0,
        ],
        vec![0.0, hs * 0.5, 0.0],
        vec![1.0, 0.0, 0.0],
        vec![0.0],
    )?;
    bw.substeps = 8;
    bw.terms.push(NonlinearTerm {
        target: Target::State(2),
        args: vec![Signal::State(1), Signal::State(2)],
        expansion: expansion(2, 4, -1.0, 1.0)?,
    });
    time("Bouc-Wen-shaped, 2-D wavelet term, 8 sub-steps", &bw, n)?;
    Ok(())
}
