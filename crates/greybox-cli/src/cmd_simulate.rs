//! `greybox simulate`: a saved model of any class on the inputs of a CSV.
use crate::io::write_simulation;
use crate::{Result, SimulateArgs};
use gb_core::{CsvTable, Init};

/// Simulate in free run; with `--init-window N` the first N measured
/// outputs set the initial state and the errors cover samples N.. only;
/// without, the model starts from the state it stores.
pub fn run(a: SimulateArgs) -> Result<()> {
    let m = gb_model::registry::load(&a.model).map_err(|e| e.to_string())?;
    let t = CsvTable::read(&a.data).map_err(|e| e.to_string())?;
    let inputs: Vec<Vec<f64>> = m
        .input_names
        .iter()
        .map(|n| t.column(n).map(<[f64]>::to_vec))
        .collect::<std::result::Result<_, _>>()
        .map_err(|e| e.to_string())?;
    let out_name = m.output_name().to_string();
    let y = t.column(&out_name).ok().map(<[f64]>::to_vec);
    if a.init_window > t.n_rows() {
        return Err(format!(
            "--init-window {} exceeds the {} samples of {}",
            a.init_window,
            t.n_rows(),
            a.data.display()
        ));
    }
    let init = match &y {
        Some(y) if a.init_window > 0 => Init::Window(&y[..a.init_window]),
        None if a.init_window > 0 => {
            return Err(format!(
                "{}: --init-window needs the output column '{out_name}'",
                a.data.display()
            ))
        }
        _ => Init::Stored,
    };
    let sim = m.simulate(&inputs, init).map_err(|e| e.to_string())?;
    let bands = if a.bands {
        Some(bands(&m, &inputs, init, y.as_deref(), a.init_window)?)
    } else {
        None
    };
    let extra: Vec<(&str, &[f64])> = bands
        .as_ref()
        .map(|b| vec![("y_sim_lo", b.lo.as_slice()), ("y_sim_hi", b.hi.as_slice())])
        .unwrap_or_default();
    write_simulation(
        &a.out,
        &m.input_names,
        &inputs,
        y.as_deref(),
        &sim,
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
