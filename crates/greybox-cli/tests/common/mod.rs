//! Helpers shared by the CLI tests: a fresh scratch folder per test and the
//! `greybox` binary run as a user runs it.
#![allow(dead_code)]
use std::path::PathBuf;
use std::process::{Command, Output};

/// The `greybox` binary of this build.
pub fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_greybox"))
}

/// An empty folder `<temp>/<prefix>-<pid>-<name>` (removed first if it
/// exists).
pub fn scratch(prefix: &str, name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("{prefix}-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("create the scratch folder");
    d
}

/// `greybox ARGS…`, its output captured.
pub fn run(args: &[&str]) -> Output {
    bin().args(args).output().expect("run greybox")
}

/// Standard output and standard error as text.
pub fn text(o: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&o.stdout).to_string(),
        String::from_utf8_lossy(&o.stderr).to_string(),
    )
}
