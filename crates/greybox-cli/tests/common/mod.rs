//! Helpers shared by the CLI tests: a fresh scratch folder per test and the
//! `greybox` binary run as a user runs it.
#![allow(dead_code)]
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The number printed after `label` (e.g. `"RMSE "`, `"NRMSE "`) on the
/// first line of `out` that has one (`simulate`'s error line).
pub fn printed(out: &str, label: &str) -> f64 {
    out.lines()
        .find_map(|l| l.split(label).nth(1))
        .and_then(|r| r.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no {label}in\n{out}"))
}

/// `greybox simulate MODEL TEST -o SIM --init-window W` (it must succeed)
/// and the number it prints after `label` (`"RMSE "`, `"NRMSE "`).
pub fn simulated(
    model: &std::path::Path,
    test: &std::path::Path,
    sim: &std::path::Path,
    w: usize,
    label: &str,
) -> f64 {
    let s = |p: &std::path::Path| p.to_str().expect("a UTF-8 path").to_string();
    let w = w.to_string();
    let o = run(&[
        "simulate",
        &s(model),
        &s(test),
        "-o",
        &s(sim),
        "--init-window",
        &w,
    ]);
    let (out, err) = text(&o);
    assert!(o.status.success(), "{out}\n{err}");
    printed(&out, label)
}

/// The `greybox` binary of this build.
pub fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_greybox"))
}

/// An empty folder `<temp>/<prefix>-<pid>-<name>` (removed first if it
/// exists). The first call of a test process also removes the folders
/// `<prefix>-<pid>-*` that earlier test processes left behind, where the
/// system shows which processes are alive (`/proc`), so that repeated
/// test runs do not pile scratch folders up in the temp folder.
pub fn scratch(prefix: &str, name: &str) -> PathBuf {
    static SWEPT: std::sync::Once = std::sync::Once::new();
    SWEPT.call_once(|| remove_stale(prefix));
    let d = std::env::temp_dir().join(format!("{prefix}-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("create the scratch folder");
    d
}

/// Removes `<temp>/<prefix>-<pid>-*` of processes that are no longer
/// running (none where `/proc` is absent: nothing is removed there).
fn remove_stale(prefix: &str) {
    let proc = std::path::Path::new("/proc");
    if !proc.join("self").exists() {
        return;
    }
    let Ok(entries) = std::fs::read_dir(std::env::temp_dir()) else {
        return;
    };
    let head = format!("{prefix}-");
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().to_string();
        let Some(pid) = name
            .strip_prefix(&head)
            .and_then(|rest| rest.split('-').next())
            .and_then(|p| p.parse::<u32>().ok())
        else {
            continue;
        };
        if pid != std::process::id() && !proc.join(pid.to_string()).exists() {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
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

/// Rows `rows` of the CSV `from` (after its header) written to `to` with
/// a header: every column, or only `columns` in that order.
pub fn csv_rows(from: &Path, to: &Path, rows: std::ops::Range<usize>, columns: Option<&[&str]>) {
    let all = std::fs::read_to_string(from).unwrap();
    let mut lines = all.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let keep: Vec<usize> = match columns {
        Some(cs) => cs
            .iter()
            .map(|n| head.iter().position(|h| h.trim() == *n).unwrap())
            .collect(),
        None => (0..head.len()).collect(),
    };
    let pick = |l: &str| {
        let v: Vec<&str> = l.split(',').collect();
        keep.iter().map(|&i| v[i]).collect::<Vec<_>>().join(",")
    };
    let body: Vec<String> = lines.skip(rows.start).take(rows.len()).map(pick).collect();
    let header = keep.iter().map(|&i| head[i]).collect::<Vec<_>>().join(",");
    std::fs::write(to, format!("{header}\n{}\n", body.join("\n"))).unwrap();
}
