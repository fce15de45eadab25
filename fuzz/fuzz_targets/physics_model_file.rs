//! str -> `physics::ModelFile::parse` (a `.toml` physics model file) and,
//! when it parses, `.model()`.
#![no_main]
use gb_model::physics::ModelFile;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|text: &str| {
    if let Ok(file) = ModelFile::parse(text, "fuzz.toml") {
        let _ = file.model();
    }
});
