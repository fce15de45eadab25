//! `greybox diagnose --report`: one self-contained HTML page that opens in
//! headless Chromium without errors, with every plot laid out and drawn.
//!
//! Chromium is Debian's `chromium` package (`.ci/run` installs it and sets
//! GREYBOX_REQUIRE_CHROMIUM=1, so in CI a missing browser fails the test;
//! elsewhere the browser part is skipped with a notice).
use std::path::{Path, PathBuf};
use std::process::Command;

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("greybox-report-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn chromium() -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    for dir in std::env::split_paths(&path) {
        for name in ["chromium", "chromium-browser", "google-chrome"] {
            let p = dir.join(name);
            if p.is_file() {
                return Some(p);
            }
        }
    }
    None
}

/// Runs headless Chromium on `page` and returns the DOM it serialises.
fn dump_dom(browser: &Path, page: &Path, profile: &Path) -> String {
    let o = Command::new(browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--window-size=1000,1200",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg("--dump-dom")
        .arg(format!("file://{}", page.display()))
        .output()
        .expect("run chromium");
    assert!(o.status.success(), "chromium failed: {:?}", o.status);
    String::from_utf8_lossy(&o.stdout).to_string()
}

/// Appended to a copy of the report: records script errors and, after
/// layout, the rendered size and element count of every plot's SVG.
const PROBE_HEAD: &str =
    "<script>window.__errors=[];window.addEventListener('error',function(e){window.__errors.push(String(e.message||e.type));},true);</script>";
const PROBE_TAIL: &str = "<script>
var out=[];document.querySelectorAll('figure.plot').forEach(function(f){
 var s=f.querySelector('svg');var r=s?s.getBoundingClientRect():{width:0,height:0};
 var n=s?s.querySelectorAll('polyline,path,circle,rect,line,text').length:0;
 out.push(f.id+' '+Math.round(r.width)+' '+Math.round(r.height)+' '+n);});
var p=document.createElement('pre');p.id='greybox-check';
p.textContent='errors='+window.__errors.length+'\\n'+out.join('\\n');document.body.appendChild(p);
</script>";

#[test]
fn html_report_is_self_contained_and_renders_every_plot() {
    let d = tmp("shock");
    let report = d.join("report.html");
    let o = Command::new(env!("CARGO_BIN_EXE_greybox"))
        .args(["diagnose", "--example", "shock-absorber", "--report"])
        .arg(&report)
        .output()
        .expect("run greybox");
    assert!(
        o.status.success(),
        "diagnose failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(String::from_utf8_lossy(&o.stdout).contains("HTML report written"));
    let page = std::fs::read_to_string(&report).expect("report written");

    // self-contained: no scripts, no external resources
    assert!(page.starts_with("<!DOCTYPE html>"));
    assert!(!page.contains("<script"), "the report needs no JavaScript");
    for attr in ["src=", "href=", "@import", "url("] {
        assert!(
            !page.contains(attr),
            "external reference '{attr}' in report"
        );
    }
    // the plots the issue asks for, for a hysteresis diagnosis
    let expected = [
        "plot-compare",
        "plot-compare-zoom",
        "plot-residual-time",
        "plot-acf",
        "plot-ccf-0",
        "plot-hoc-0",
        "plot-evidence-1-hysteresis",
        "plot-preisach",
        // the shock absorber's hysteretic force ends in the hidden-state model
        "plot-state-space",
    ];
    for id in expected {
        assert!(
            page.contains(&format!("<figure id=\"{id}\"")),
            "{id} missing"
        );
    }
    assert!(page.contains("Steps and gains") && page.contains("<table>"));

    let Some(browser) = chromium() else {
        if std::env::var_os("GREYBOX_REQUIRE_CHROMIUM").is_some() {
            panic!("GREYBOX_REQUIRE_CHROMIUM is set but no chromium on PATH");
        }
        eprintln!("notice: chromium not found on PATH; skipping the browser check (apt-get install chromium)");
        return;
    };
    let probe = d.join("probe.html");
    let probed = page
        .replacen("<head>", &format!("<head>{PROBE_HEAD}"), 1)
        .replacen("</body>", &format!("{PROBE_TAIL}</body>"), 1);
    std::fs::write(&probe, probed).unwrap();
    let dom = dump_dom(&browser, &probe, &d.join("profile"));
    let at = dom
        .find("<pre id=\"greybox-check\">")
        .expect("probe ran in the page");
    let text = &dom[at + "<pre id=\"greybox-check\">".len()..];
    let text = &text[..text.find("</pre>").expect("probe output closed")];
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("errors=0"), "page errors: {text}");
    let mut seen = vec![];
    for l in lines {
        let f: Vec<&str> = l.split_whitespace().collect();
        assert_eq!(f.len(), 4, "probe line {l}");
        let (w, h, n): (f64, f64, usize) = (
            f[1].parse().unwrap(),
            f[2].parse().unwrap(),
            f[3].parse().unwrap(),
        );
        assert!(
            w >= 400.0 && h >= 200.0,
            "plot {} laid out at {w}x{h}",
            f[0]
        );
        assert!(n >= 20, "plot {} has only {n} drawn elements", f[0]);
        seen.push(f[0].to_string());
    }
    for id in expected {
        assert!(seen.iter().any(|s| s == id), "{id} not rendered: {seen:?}");
    }
    let _ = std::fs::remove_dir_all(&d);
}
