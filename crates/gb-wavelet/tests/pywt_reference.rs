//! Transforms compared with values computed by PyWavelets
//! (`tests/fixtures/gen_fixtures.py`).

mod common;

use common::{fixture, floats, rel_err};
use gb_wavelet::{dwt, idwt, wavedec, waverec, Mode, Wavelet};

const TOL: f64 = 1e-10;

#[test]
fn filters_match_pywavelets() {
    let f = fixture("filters.json");
    let list = f["wavelets"].as_array().expect("list");
    assert!(list.len() >= 75);
    for entry in list {
        let name = entry["name"].as_str().expect("name");
        let w = Wavelet::new(name).expect("known wavelet");
        for (ours, key) in [
            (w.dec_lo(), "dec_lo"),
            (w.dec_hi(), "dec_hi"),
            (w.rec_lo(), "rec_lo"),
            (w.rec_hi(), "rec_hi"),
        ] {
            let reference = floats(&entry[key]);
            let e = rel_err(ours, &reference, name);
            assert!(e < 1e-10, "{name} {key}: {e}");
        }
    }
}

#[test]
fn wavedec_every_family_mode_and_level() {
    let f = fixture("dwt_cases.json");
    let a_in = floats(&f["idwt_approx"]);
    let d_in = floats(&f["idwt_detail"]);
    let mut worst = 0.0f64;
    let mut count = 0;
    for case in f["cases"].as_array().expect("cases") {
        let w = Wavelet::new(case["wavelet"].as_str().expect("name")).expect("wavelet");
        let mode: Mode = case["mode"].as_str().expect("mode").parse().expect("mode");
        let what = format!("{} {}", w.name(), mode);
        if let Some(reference) = case.get("idwt") {
            let y = idwt(&a_in, &d_in, &w, mode).expect("idwt");
            let e = rel_err(&y, &floats(reference), &what);
            assert!(e < TOL, "idwt {what}: {e}");
            worst = worst.max(e);
            continue;
        }
        let len = case["signal_len"].as_u64().expect("len");
        let x = floats(&f["signals"][len.to_string()]);
        let level = case["level"].as_u64().expect("level") as usize;
        let coeffs = wavedec(&x, &w, mode, Some(level)).expect("wavedec");
        let reference = case["coeffs"].as_array().expect("coeffs");
        assert_eq!(coeffs.len(), reference.len(), "{what}");
        for (c, r) in coeffs.iter().zip(reference) {
            let e = rel_err(c, &floats(r), &what);
            assert!(e < TOL, "wavedec {what} N={len}: {e}");
            worst = worst.max(e);
        }
        // single level agrees with the first level of wavedec
        let (a1, d1) = dwt(&x, &w, mode).expect("dwt");
        assert!(rel_err(&d1, &coeffs[2], &what) == 0.0);
        let y = waverec(&coeffs, &w, mode).expect("waverec");
        let e = rel_err(&y[..x.len()], &x, &what);
        assert!(e < 1e-12, "perfect reconstruction {what} N={len}: {e}");
        let _ = a1;
        count += 1;
    }
    assert!(count >= 750, "{count}");
    println!("max relative error vs PyWavelets (short signals): {worst:e}");
}

#[test]
fn wavedec_long_signals_default_level() {
    let f = fixture("wavedec_long.json");
    let mut worst = 0.0f64;
    for (key, level) in f["max_levels"].as_object().expect("levels") {
        let (name, len) = key.split_once('/').expect("key");
        let w = Wavelet::new(name).expect("wavelet");
        assert_eq!(
            w.max_level(len.parse().expect("len")) as u64,
            level.as_u64().expect("level")
        );
    }
    for case in f["cases"].as_array().expect("cases") {
        let w = Wavelet::new(case["wavelet"].as_str().expect("name")).expect("wavelet");
        let mode: Mode = case["mode"].as_str().expect("mode").parse().expect("mode");
        let len = case["signal_len"].as_u64().expect("len");
        let x = floats(&f["signals"][len.to_string()]);
        let what = format!("{} {} N={len}", w.name(), mode);
        let coeffs = wavedec(&x, &w, mode, None).expect("wavedec");
        let reference = case["coeffs"].as_array().expect("coeffs");
        assert_eq!(coeffs.len(), reference.len(), "{what}");
        for (c, r) in coeffs.iter().zip(reference) {
            let e = rel_err(c, &floats(r), &what);
            assert!(e < TOL, "{what}: {e}");
            worst = worst.max(e);
        }
        let y = waverec(&coeffs, &w, mode).expect("waverec");
        let e = rel_err(&y[..x.len()], &x, &what);
        assert!(e < 1e-12, "perfect reconstruction {what}: {e}");
    }
    println!("max relative error vs PyWavelets (long signals): {worst:e}");
}
