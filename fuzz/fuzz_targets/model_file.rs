//! Bytes -> `registry::from_bytes` (what `greybox simulate` loads a `.gbm`
//! or `.gbs` with) and, when it loads, a short simulation.
#![no_main]
use gb_core::Init;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(m) = gb_model::registry::from_bytes(data, "fuzz.gbm") else {
        return;
    };
    let _ = m.describe();
    let n = m.input_names.len();
    if n > 64 {
        return;
    }
    let len = 40;
    let u: Vec<Vec<f64>> = (0..n)
        .map(|j| {
            (0..len)
                .map(|k| ((k as f64) * 0.3 + j as f64).sin())
                .collect()
        })
        .collect();
    let _ = m.simulate(&u, Init::Stored);
    let _ = m.simulate(&u, Init::Rest);
    let y: Vec<f64> = (0..10).map(|k| (k as f64 * 0.1).cos()).collect();
    let _ = m.simulate(&u, Init::Window(&y));
    if let Ok(bytes) = m.to_bytes() {
        let _ = gb_model::registry::from_bytes(&bytes, "again.gbm");
    }
});
