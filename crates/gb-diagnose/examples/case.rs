//! Diagnose one generated case and print the text report.
//!
//! ```sh
//! cargo run --release -p gb-diagnose --example case -- linear 3 [--n-train N] [--order auto|N] [--csv DIR] [--noise-free]
//! ```
//!
//! `--csv DIR` also writes the case as `DIR/train.csv` and `DIR/validate.csv`
//! (for `greybox fit` / `greybox diagnose` on the same data); `--noise-free`
//! draws the same case without noise (what a model class can reach).
use gb_diagnose::generator::{draw_with, Knobs};
use gb_diagnose::{diagnose, DiagnoseData, DiagnoseOptions, OrderChoice};
use std::error::Error;
use std::time::Instant;

fn main() -> Result<(), Box<dyn Error>> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    if a.len() < 2 {
        eprintln!("usage: case FAMILY SEED [--n-train N] [--n-validate N] [--order auto|N] [--csv DIR] [--noise-free]");
        std::process::exit(2);
    }
    let mut knobs = Knobs::default();
    let mut order = None;
    let mut csv_dir = None;
    let mut i = 2;
    while i < a.len() {
        if a[i] == "--noise-free" {
            knobs.noise_free = true;
            i += 1;
            continue;
        }
        if i + 1 >= a.len() {
            return Err(format!("flag {} needs a value", a[i]).into());
        }
        match a[i].as_str() {
            "--n-train" => knobs.n_train = Some(a[i + 1].parse()?),
            "--n-validate" => knobs.n_validate = Some(a[i + 1].parse()?),
            "--csv" => csv_dir = Some(std::path::PathBuf::from(&a[i + 1])),
            "--order" => {
                order = Some(match a[i + 1].as_str() {
                    "auto" => OrderChoice::Auto,
                    n => OrderChoice::Fixed(n.parse()?),
                })
            }
            f => return Err(format!("unknown flag {f}").into()),
        }
        i += 2;
    }
    let c = draw_with(&a[0], a[1].parse()?, &knobs)?;
    println!(
        "{}\nexpected {:?}, floor {:.4}, true order {}, delay {}, feedthrough {}",
        c.description, c.expected, c.noise_floor_nrmse, c.true_order, c.input_delay, c.feedthrough
    );
    if let Some(dir) = &csv_dir {
        std::fs::create_dir_all(dir)?;
        for (name, r) in [("train.csv", &c.train), ("validate.csv", &c.validate)] {
            let mut names: Vec<&str> = r.input_names.iter().map(String::as_str).collect();
            names.push(&r.output_name);
            let mut cols: Vec<&[f64]> = r.inputs.iter().map(Vec::as_slice).collect();
            cols.push(&r.output);
            gb_core::write_csv_atomic(dir.join(name), &names, &cols)?;
        }
    }
    let d = DiagnoseData::with_validation(c.train.clone(), c.validate.clone())?;
    let o = DiagnoseOptions {
        order: order.unwrap_or(OrderChoice::Fixed(c.model_order)),
        ..DiagnoseOptions::default()
    };
    let t = Instant::now();
    match diagnose(&d, &o, None) {
        Ok(r) => print!("{}", r.report.to_text()),
        Err(e) => println!("error: {e}"),
    }
    println!("{:.1} s", t.elapsed().as_secs_f64());
    Ok(())
}
