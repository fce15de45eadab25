//! Bouc-Wen benchmark with the grey-box wavelet class on a short training
//! record (`$GREYBOX_DATA`, default `../shared/data`); skipped with a notice
//! when the folder is absent. The full run is `--example bouc_wen`.
use gb_core::{metrics, CsvTable};
use gb_model::{
    linear_from_oe, second_order, NonlinearTerm, OeParams, Signal, Silent, SparseExpansion, Target,
};
use std::path::PathBuf;

fn data_dir() -> Option<PathBuf> {
    let default = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    gb_core::benchmark_data_dir(&default, "bouc_wen")
}

fn load(p: PathBuf) -> (Vec<f64>, Vec<f64>) {
    let t = CsvTable::read(&p).expect("read");
    (
        t.column("u").expect("u").to_vec(),
        t.column("y").expect("y").to_vec(),
    )
}

/// Two training periods (16 384 samples), levels ≤ 2: the multisine test RMSE
/// must beat PNLSS (1.34e-5 m) and be ≥ 10× better than the linear model.
#[test]
fn bouc_wen_short_record_beats_pnlss() {
    let Some(dir) = data_dir() else { return };
    let (u, y) = load(dir.join("bouc_wen/train_multisine_forgione.csv"));
    let (ut, yt) = load(dir.join("bouc_wen/test_multisine.csv"));
    let (u, y) = (u[..16384].to_vec(), y[..16384].to_vec());
    let ts = 1.0 / 750.0;
    // the best linear model from the second period (as the example does)
    let lin = linear_from_oe(&[u[8192..].to_vec()], &y[8192..], 2).unwrap();
    let mut start = second_order(&lin, ts, 8, true).unwrap();
    let (_, xs) = start.simulate_states(std::slice::from_ref(&u)).unwrap();
    let vmax = xs.chunks(3).map(|x| x[1].abs()).fold(0.0, f64::max) * 1.25;
    let zmax = xs.chunks(3).map(|x| x[2].abs()).fold(0.0, f64::max) * 1.25;
    start.terms.push(NonlinearTerm {
        target: Target::State(2),
        args: vec![Signal::State(1), Signal::State(2)],
        expansion: SparseExpansion::new("bior2.2", vec![-vmax, -zmax], vec![vmax, zmax]).unwrap(),
    });
    let (m, report) = OeParams::new()
        .max_iter(20)
        .coarse_level(1)
        .max_level(2)
        .max_new(40)
        .check()
        .unwrap()
        .fit(start, std::slice::from_ref(&u), &y, &Silent)
        .unwrap();
    let steady = |m: &gb_model::SparseStateSpace| {
        let mut z = m.clone();
        z.x0 = vec![0.0; z.n_states];
        let mut s = z
            .simulate(&[[ut.clone(), ut.clone(), ut.clone()].concat()])
            .unwrap();
        s.drain(..2 * ut.len());
        metrics::rmse(&yt, &s).unwrap()
    };
    let (e, e_lin) = (steady(&m), steady(&lin));
    eprintln!(
        "Bouc-Wen (16 384 training samples): multisine test RMSE {e:.3e} m (linear {e_lin:.3e}), {} coefficients, training RMSE {:.3e}",
        m.n_coefficients(),
        report.rmse
    );
    assert!(e < 1.34e-5, "test RMSE {e}");
    assert!(e < 0.1 * e_lin);
}

/// MR damper (Dyke white-noise test), the example's structure on a short
/// record: 4 s of training, levels ≤ 2, free run of the next 2 s (excited)
/// driven by the inputs from the start of the record. The grey-box model
/// must be ≥ 4× better than the order-2 linear output-error model (5.9×
/// measured).
#[test]
fn mr_damper_short_record_beats_linear() {
    let default = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    let Some(dir) = gb_core::benchmark_data_dir(&default, "mr_damper_dyke_nees") else {
        return;
    };
    let t = CsvTable::read(dir.join("mr_damper_dyke_nees/ranran_50.csv")).expect("read");
    let (n_fit, n) = (12_000, 18_000);
    let inputs: Vec<Vec<f64>> = ["D", "V", "Y", "A"]
        .iter()
        .map(|c| t.column(c).expect("column")[..n].to_vec())
        .collect();
    let f = t.column("F").expect("F")[..n].to_vec();
    let head: Vec<Vec<f64>> = inputs.iter().map(|s| s[..n_fit].to_vec()).collect();
    let lin = linear_from_oe(&head[..3], &f[..n_fit], 2).unwrap();
    let e_lin = metrics::nrmse(&f[n_fit..], &lin.simulate(&inputs[..3]).unwrap()[n_fit..]).unwrap();
    let oe = OeParams::new().max_level(2).check().unwrap();
    // the Dyke rig: 3004.8 Hz, resonances started at 150 and 120 Hz
    let (m, _) = gb_model::MrDamperStructure::new(3004.8, vec![150.0, 120.0])
        .fit(&oe, &head, &f[..n_fit], &Silent)
        .unwrap();
    let e = metrics::nrmse(&f[n_fit..], &m.simulate(&inputs).unwrap()[n_fit..]).unwrap();
    eprintln!("MR damper short record: NRMSE {e:.4} vs linear {e_lin:.4}");
    assert!(e_lin > 0.3, "linear model too good: {e_lin}");
    assert!(e < e_lin / 4.0, "grey-box {e} vs linear {e_lin}");
}
