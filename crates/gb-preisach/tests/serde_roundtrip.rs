//! Model files: postcard and JSON round trips.
use gb_preisach::{
    fit_grid_preisach, FitOptions, GridEverett, GridPreisachRegressor, InitialState,
    ParametricEverett, PrandtlIshlinskii, Preisach, RelayGrid,
};
use serde::{de::DeserializeOwned, Serialize};

fn roundtrip<T: Serialize + DeserializeOwned + PartialEq + std::fmt::Debug>(v: &T) -> T {
    let bytes = postcard::to_allocvec(v).unwrap();
    let back: T = postcard::from_bytes(&bytes).unwrap();
    assert_eq!(&back, v);
    // JSON loads too (serde_json's default float parser may differ in the
    // last ulp, so only postcard is compared exactly).
    let json = serde_json::to_string(v).unwrap();
    let _: T = serde_json::from_str(&json).unwrap();
    back
}

#[test]
fn models_survive_postcard_and_json() {
    let x: Vec<f64> = (0..300)
        .map(|k| (k as f64 * 0.1).sin() * (1.0 - k as f64 / 400.0))
        .collect();
    let init = InitialState::Demagnetised {
        center: 0.0,
        amplitude: 1.0,
        steps: 5,
    };
    let p = Preisach::new(ParametricEverett::lorentzian(1.0, 0.3, 0.1, -0.3, 0.1).unwrap())
        .with_memory_cap(16)
        .unwrap();
    let p2 = roundtrip(&p);
    assert_eq!(
        p.simulate(&x, &init).unwrap(),
        p2.simulate(&x, &init).unwrap()
    );

    let g = Preisach::new(GridEverett::uniform_density(-1.0, 1.0, 6, 1.0).unwrap());
    let g2 = roundtrip(&g);
    assert_eq!(
        g.simulate(&x, &init).unwrap(),
        g2.simulate(&x, &init).unwrap()
    );

    let y = g.simulate(&x, &init).unwrap();
    let reg = GridPreisachRegressor::new(-1.0, 1.0, 6, init.clone()).unwrap();
    let _ = roundtrip(&reg);
    let fit = fit_grid_preisach(&x, &y, &reg, &FitOptions::default()).unwrap();
    let fit2 = roundtrip(&fit);
    assert_eq!(
        fit2.model.simulate(&x, &init).unwrap(),
        fit.model.simulate(&x, &init).unwrap()
    );

    let pi = PrandtlIshlinskii::new(0.8, vec![0.0, 0.1, 0.3], vec![0.2, 0.3, 0.1]).unwrap();
    let pi2 = roundtrip(&pi);
    assert_eq!(pi.apply(&x).unwrap(), pi2.apply(&x).unwrap());

    let r = RelayGrid::from_everett(g.everett(), -1.0, 1.0, 6).unwrap();
    let _ = roundtrip(&r);
    let _ = roundtrip(&init);
}

#[test]
fn invalid_model_files_are_rejected() {
    // A grid file whose mass vector has the wrong length fails to load.
    let bad = r#"{"lo":-1.0,"hi":1.0,"n":3,"masses":[0.1,0.2]}"#;
    assert!(serde_json::from_str::<GridEverett>(bad).is_err());
}
