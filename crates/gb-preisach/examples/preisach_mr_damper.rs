//! MR damper (sinusoidal shaking-table tests, labcontrol-data/mr-damper):
//! force from position and velocity by a linear model F = c₀ + k x + c v and
//! by linear + Preisach (grid Everett function driven by the velocity, and
//! for comparison by the position), all fitted by linear least squares on
//! five tests and validated on five others.
//!
//! Data: `$GREYBOX_DATA/mr_damper_labcontrol/sinusoidal_tests.csv`, or
//! `../shared/data/...` relative to the repository root. Skipped with a
//! notice when absent. Run:
//! `cargo run --release -p gb-preisach --example preisach_mr_damper [OUT_DIR]`
//! (with OUT_DIR, the force–displacement loops are written there as CSV).
use gb_preisach::{GridPreisachRegressor, HysteresisRegressor, InitialState};
use nalgebra::{DMatrix, DVector};
use std::collections::BTreeMap;
use std::path::PathBuf;

struct Test {
    position: Vec<f64>,
    velocity: Vec<f64>,
    force: Vec<f64>,
}

fn data_file() -> PathBuf {
    let root = std::env::var_os("GREYBOX_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    root.join("mr_damper_labcontrol/sinusoidal_tests.csv")
}

fn load(path: &PathBuf) -> Result<BTreeMap<String, Test>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut tests = BTreeMap::new();
    for (i, line) in text.lines().enumerate().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 5 {
            return Err(format!("line {}: expected 5 fields", i + 1));
        }
        let num = |s: &str| {
            s.trim()
                .parse::<f64>()
                .map_err(|e| format!("line {}: {e}", i + 1))
        };
        let t = tests.entry(f[0].to_string()).or_insert_with(|| Test {
            position: Vec::new(),
            velocity: Vec::new(),
            force: Vec::new(),
        });
        t.position.push(num(f[2])?);
        t.velocity.push(num(f[3])?);
        t.force.push(num(f[4])?);
    }
    Ok(tests)
}

fn nrmse(y: &[f64], yhat: &[f64]) -> f64 {
    let n = y.len() as f64;
    let mean = y.iter().sum::<f64>() / n;
    let sd = (y.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n).sqrt();
    let rmse = (y
        .iter()
        .zip(yhat)
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>()
        / n)
        .sqrt();
    rmse / sd
}

/// Regressor matrix: [1, x, v] and optionally the Preisach columns of the
/// velocity (`on_velocity`) or of the position.
fn regressors(
    t: &Test,
    preisach: Option<(&GridPreisachRegressor, bool)>,
) -> Result<DMatrix<f64>, String> {
    let cols = match preisach {
        Some((r, on_velocity)) => {
            let input = if on_velocity {
                &t.velocity
            } else {
                &t.position
            };
            r.regressors(input).map_err(|e| e.to_string())?.columns
        }
        None => Vec::new(),
    };
    let n = t.position.len();
    Ok(DMatrix::from_fn(n, 3 + cols.len(), |i, j| match j {
        0 => 1.0,
        1 => t.position[i],
        2 => t.velocity[i],
        _ => cols[j - 3][i],
    }))
}

fn fit(phi: &DMatrix<f64>, y: &[f64], ridge: f64) -> Result<DVector<f64>, String> {
    let mut g = phi.transpose() * phi;
    let scale = g.trace() / g.nrows() as f64;
    for i in 3..g.nrows() {
        g[(i, i)] += ridge * scale;
    }
    let b = phi.transpose() * DVector::from_column_slice(y);
    g.cholesky()
        .map(|c| c.solve(&b))
        .ok_or_else(|| "singular normal equations".to_string())
}

fn main() -> Result<(), String> {
    let path = data_file();
    if !path.exists() {
        eprintln!(
            "notice: MR damper data not found at {} (set GREYBOX_DATA); skipping",
            path.display()
        );
        return Ok(());
    }
    let out_dir = std::env::args().nth(1).map(PathBuf::from);
    let tests = load(&path)?;
    // Train on every other amplitude (1.1, 3.1, …, 9.1), validate on the
    // interleaved ones (2.1, …, 10.1): the Everett function is only
    // identified where the training input went.
    let train_ids = [
        "ensaio1.1",
        "ensaio3.1",
        "ensaio5.1",
        "ensaio7.1",
        "ensaio9.1",
    ];
    let valid_ids = [
        "ensaio2.1",
        "ensaio4.1",
        "ensaio6.1",
        "ensaio8.1",
        "ensaio10.1",
    ];
    let get = |id: &str| tests.get(id).ok_or(format!("test {id} missing"));
    let range = |velocity: bool| -> Result<(f64, f64), String> {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for id in train_ids.iter().chain(&valid_ids) {
            let t = get(id)?;
            for &v in if velocity { &t.velocity } else { &t.position } {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
        Ok((lo, hi))
    };
    let n = 12;
    let ridge = 1e-5;
    let reg_of = |velocity: bool| -> Result<GridPreisachRegressor, String> {
        let (lo, hi) = range(velocity)?;
        GridPreisachRegressor::new(lo, hi, n, InitialState::NegativeSaturation)
            .map_err(|e| e.to_string())
    };
    let (reg_v, reg_x) = (reg_of(true)?, reg_of(false)?);
    let stack =
        |pre: Option<(&GridPreisachRegressor, bool)>| -> Result<(DMatrix<f64>, Vec<f64>), String> {
            let mut rows: Vec<DMatrix<f64>> = Vec::new();
            let mut y = Vec::new();
            for id in &train_ids {
                let t = get(id)?;
                rows.push(regressors(t, pre)?);
                y.extend_from_slice(&t.force);
            }
            let total: usize = rows.iter().map(|m| m.nrows()).sum();
            let mut phi = DMatrix::zeros(total, rows[0].ncols());
            let mut r0 = 0;
            for m in rows {
                phi.rows_mut(r0, m.nrows()).copy_from(&m);
                r0 += m.nrows();
            }
            Ok((phi, y))
        };
    let (phi, y) = stack(None)?;
    let th_lin = fit(&phi, &y, 0.0)?;
    let (phi, y) = stack(Some((&reg_v, true)))?;
    let th_v = fit(&phi, &y, ridge)?;
    let (phi, y) = stack(Some((&reg_x, false)))?;
    let th_x = fit(&phi, &y, ridge)?;
    let (vlo, vhi) = range(true)?;
    let (xlo, xhi) = range(false)?;
    println!(
        "training on {train_ids:?}; grids with {n} intervals ({} cells) on v in [{vlo:.1}, {vhi:.1}] and x in [{xlo:.2}, {xhi:.2}]; ridge {ridge}",
        reg_v.n_columns()
    );
    println!(
        "linear model: F = {:.3} + {:.4} x + {:.4} v",
        th_lin[0], th_lin[1], th_lin[2]
    );
    println!(
        "{:<11} {:>6} {:>8} {:>14} {:>14}",
        "test", "N", "linear", "lin+Preisach(v)", "lin+Preisach(x)"
    );
    let (mut sums, mut count) = ([0.0; 3], 0);
    for id in train_ids.iter().chain(&valid_ids) {
        let t = get(id)?;
        let yl = regressors(t, None)? * &th_lin;
        let yv = regressors(t, Some((&reg_v, true)))? * &th_v;
        let yx = regressors(t, Some((&reg_x, false)))? * &th_x;
        let e = [
            nrmse(&t.force, yl.as_slice()),
            nrmse(&t.force, yv.as_slice()),
            nrmse(&t.force, yx.as_slice()),
        ];
        let training = train_ids.contains(id);
        let tag = if training { "training" } else { "validation" };
        println!(
            "{id:<11} {:>6} {:>8.4} {:>14.4} {:>14.4}  {tag}",
            t.force.len(),
            e[0],
            e[1],
            e[2]
        );
        if !training {
            for k in 0..3 {
                sums[k] += e[k];
            }
            count += 1;
        }
        if let Some(dir) = &out_dir {
            std::fs::create_dir_all(dir).map_err(|e| e.to_string())?;
            let mut s = String::from(
                "position,velocity,force,linear,linear_preisach_v,linear_preisach_x\n",
            );
            for i in 0..t.force.len() {
                s += &format!(
                    "{},{},{},{},{},{}\n",
                    t.position[i], t.velocity[i], t.force[i], yl[i], yv[i], yx[i]
                );
            }
            std::fs::write(dir.join(format!("mr_damper_{id}.csv")), s)
                .map_err(|e| e.to_string())?;
        }
    }
    if count > 0 {
        println!(
            "mean validation NRMSE over {count} tests: linear {:.4}, linear + Preisach(v) {:.4}, linear + Preisach(x) {:.4}",
            sums[0] / count as f64,
            sums[1] / count as f64,
            sums[2] / count as f64
        );
    }
    Ok(())
}
