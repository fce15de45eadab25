//! str -> `ModelSpec` (the `--model` argument of `greybox fit`) and
//! `recipes::check_spec`.
#![no_main]
use gb_core::ModelSpec;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|text: &str| {
    if let Ok(spec) = text.parse::<ModelSpec>() {
        // Display must round-trip to something parseable.
        let shown = spec.to_string();
        let _ = shown.parse::<ModelSpec>();
        let _ = gb_model::recipes::check_spec(&spec);
    }
});
