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
    write_simulation(
        &a.out,
        &m.input_names,
        &inputs,
        y.as_deref(),
        &sim,
        a.init_window,
    )
}
