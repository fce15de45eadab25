//! `greybox simulate`: a saved model of any class on the inputs of a CSV.
use crate::io::{write_simulation, SimOutput};
use crate::{Result, SimulateArgs};
use gb_core::{CsvTable, FittedModel, Init};
use std::io::Write;

/// Simulate in free run; with `--init-window N` the first N measured
/// outputs set the initial state and the errors cover samples N.. only;
/// without, the model starts from the state it stores.
pub fn run(a: SimulateArgs) -> Result<()> {
    let m = gb_model::registry::load(&a.model).map_err(|e| e.to_string())?;
    if a.data.as_os_str() == "-" {
        if a.out.is_some() || a.init_window > 0 || a.bands {
            return Err(
                "simulate MODEL - streams to standard output from the stored start: no -o, --init-window or --bands"
                    .into(),
            );
        }
        return stream(&m);
    }
    let out = a
        .out
        .as_ref()
        .ok_or("-o FILE is needed (or `-` as DATA to stream rows from standard input)")?;
    let t = CsvTable::read(&a.data).map_err(|e| e.to_string())?;
    let inputs = crate::io::columns(&t, &m.input_names)?;
    // the measured outputs present in the data, one per model output
    let ys: Vec<Option<&[f64]>> = m.output_names.iter().map(|n| t.column(n).ok()).collect();
    if a.init_window > t.n_rows() {
        return Err(format!(
            "--init-window {} exceeds the {} samples of {}",
            a.init_window,
            t.n_rows(),
            a.data.display()
        ));
    }
    // an init window of every output, output-major
    let mut window = Vec::with_capacity(a.init_window * ys.len());
    if a.init_window > 0 {
        for (y, name) in ys.iter().zip(&m.output_names) {
            let y = y.ok_or_else(|| {
                format!(
                    "{}: --init-window needs the output column '{name}'",
                    a.data.display()
                )
            })?;
            window.extend_from_slice(&y[..a.init_window]);
        }
    }
    let init = if a.init_window > 0 {
        Init::Window(&window)
    } else {
        Init::Stored
    };
    let sim = m.simulate(&inputs, init).map_err(|e| e.to_string())?;
    let bands = if a.bands {
        Some(bands(&m, &inputs, init, ys[0], a.init_window)?)
    } else {
        None
    };
    let extra: Vec<(&str, &[f64])> = bands
        .as_ref()
        .map(|b| vec![("y_sim_lo", b.lo.as_slice()), ("y_sim_hi", b.hi.as_slice())])
        .unwrap_or_default();
    let n = t.n_rows();
    let outputs: Vec<SimOutput> = m
        .output_names
        .iter()
        .zip(&ys)
        .zip(sim.chunks(n.max(1)))
        .map(|((name, measured), sim)| SimOutput {
            name,
            measured: *measured,
            sim,
        })
        .collect();
    write_simulation(
        out,
        &m.input_names,
        &inputs,
        &outputs,
        &extra,
        a.init_window,
    )
}

/// The 95 % prediction band of a physics model (parameter draws from its
/// covariance through the simulation, plus its noise σ̂); prints the share
/// of measured samples `n0..` inside it. Other classes: an error.
fn bands(
    m: &gb_core::FittedModel,
    inputs: &[Vec<f64>],
    init: Init<'_>,
    y: Option<&[f64]>,
    n0: usize,
) -> Result<gb_model::physics::Bands> {
    if m.dynamics.class() != gb_model::physics::CLASS {
        return Err(format!(
            "--bands needs a physics model (fitted with --model-file: it has a parameter covariance); this model is of class '{}'",
            m.dynamics.class()
        ));
    }
    if m.output_names.len() > 1 {
        return Err(format!(
            "--bands handles models of one output; this one has {} ({})",
            m.output_names.len(),
            m.output_names.join(", ")
        ));
    }
    let b = gb_model::physics::prediction_bands(m, inputs, init, Default::default())
        .map_err(|e| e.to_string())?;
    println!(
        "95 % prediction band from {} parameter draws ({} diverged, left out) and the noise σ̂ {:.4e}",
        b.draws,
        b.failed,
        m.noise.sd()
    );
    if let Some(y) = y {
        let k = y.len().saturating_sub(n0);
        let inside = (n0..y.len())
            .filter(|&t| b.lo[t] <= y[t] && y[t] <= b.hi[t])
            .count();
        println!(
            "band covers {inside} of {k} measured samples ({:.1} %)",
            100.0 * inside as f64 / k.max(1) as f64
        );
    }
    Ok(b)
}

/// `simulate MODEL -`: rows from standard input, one at a time through the
/// model's stepper (started as `simulate` starts, [`Init::Stored`]); each
/// row's inputs, measured outputs (when the header has them) and simulated
/// outputs are written to standard output and flushed at once, in the
/// columns and number format of the batch output file.
fn stream(m: &FittedModel) -> Result<()> {
    let mut rows = crate::io::RowReader::new(std::io::stdin().lock(), "stdin")?;
    let ui: Vec<usize> = m
        .input_names
        .iter()
        .map(|n| rows.column(n))
        .collect::<Result<_>>()?;
    let measured: Vec<Option<usize>> = m.output_names.iter().map(|n| rows.column(n).ok()).collect();
    let mut stepper = m
        .dynamics
        .stepper(Init::Stored)
        .map_err(|e| format!("simulate -: {e}"))?;
    let names = crate::io::simulation_columns(&m.input_names, &m.output_names, &measured);
    let mut out = std::io::stdout().lock();
    let io_err = |e: std::io::Error| format!("stdout: {e}");
    let (mut row, mut u) = (vec![], vec![0.0; ui.len()]);
    let mut y = vec![0.0; m.output_names.len()];
    let mut first = true;
    while rows.next_row(&mut row)? {
        for (v, &j) in u.iter_mut().zip(&ui) {
            *v = row[j];
        }
        stepper
            .step(&u, &mut y)
            .map_err(|e| format!("stdin: row {}: {e}", rows.row()))?;
        if first {
            writeln!(out, "{}", names.join(",")).map_err(io_err)?;
            first = false;
        }
        let mut line: Vec<String> = u.iter().map(f64::to_string).collect();
        line.extend(measured.iter().flatten().map(|&j| row[j].to_string()));
        line.extend(y.iter().map(f64::to_string));
        writeln!(out, "{}", line.join(",")).map_err(io_err)?;
        out.flush().map_err(io_err)?;
    }
    if first {
        return Err(gb_core::CoreError::Empty {
            path: "stdin".into(),
        }
        .to_string());
    }
    Ok(())
}
