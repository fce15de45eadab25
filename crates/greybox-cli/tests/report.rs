//! `greybox diagnose --report`: one self-contained HTML page that opens in
//! headless Chromium without errors, with every plot laid out and drawn
//! (and, for the engineer's model file, its parameter tables and the
//! prediction band plot).
//!
//! Chromium is Debian's `chromium` package (`.ci/run` installs it and sets
//! GREYBOX_REQUIRE_CHROMIUM=1, so in CI a missing browser fails the test;
//! elsewhere the browser part is skipped with a notice).
mod common;
use gb_core::{DynamicModel, Init};
use gb_model::physics::{ModelFile, Parameter, PhysicsModel, TermTarget};
use rand::Rng;
use rand_distr::{Distribution, Normal};
use std::path::{Path, PathBuf};
use std::process::Command;

fn tmp(name: &str) -> PathBuf {
    common::scratch("greybox-report", name)
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
document.querySelectorAll('table.physics').forEach(function(t){
 var r=t.getBoundingClientRect();
 out.push('table:'+t.id+' '+Math.round(r.width)+' '+Math.round(r.height)+' '+t.rows.length);});
var p=document.createElement('pre');p.id='greybox-check';
p.textContent='errors='+window.__errors.length+'\\n'+out.join('\\n');document.body.appendChild(p);
</script>";

/// No scripts, no external resources.
fn assert_self_contained(page: &str) {
    assert!(page.starts_with("<!DOCTYPE html>"));
    assert!(!page.contains("<script"), "the report needs no JavaScript");
    for attr in ["src=", "href=", "@import", "url("] {
        assert!(
            !page.contains(attr),
            "external reference '{attr}' in report"
        );
    }
}

/// One element the probe measured: id (`table:ID` for a table), rendered
/// width and height, and drawn elements (rows for a table).
struct Laid {
    id: String,
    width: f64,
    height: f64,
    count: usize,
}

/// The page opened in headless Chromium with the probe: what it laid out,
/// after checking that the page ran without errors; `None` (with a
/// notice) when no browser is installed and GREYBOX_REQUIRE_CHROMIUM is
/// unset.
fn laid_out(page: &str, d: &Path) -> Option<Vec<Laid>> {
    let Some(browser) = chromium() else {
        if std::env::var_os("GREYBOX_REQUIRE_CHROMIUM").is_some() {
            panic!("GREYBOX_REQUIRE_CHROMIUM is set but no chromium on PATH");
        }
        eprintln!("notice: chromium not found on PATH; skipping the browser check (apt-get install chromium)");
        return None;
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
    Some(
        lines
            .map(|l| {
                let f: Vec<&str> = l.split_whitespace().collect();
                assert_eq!(f.len(), 4, "probe line {l}");
                Laid {
                    id: f[0].to_string(),
                    width: f[1].parse().unwrap(),
                    height: f[2].parse().unwrap(),
                    count: f[3].parse().unwrap(),
                }
            })
            .collect(),
    )
}

/// Every plot laid out at a readable size and drawn; returns their ids.
fn check_plots(laid: &[Laid]) -> Vec<String> {
    let mut seen = vec![];
    for p in laid.iter().filter(|p| !p.id.starts_with("table:")) {
        let (w, h, n) = (p.width, p.height, p.count);
        assert!(
            w >= 400.0 && h >= 200.0,
            "plot {} laid out at {w}x{h}",
            p.id
        );
        assert!(n >= 20, "plot {} has only {n} drawn elements", p.id);
        seen.push(p.id.clone());
    }
    seen
}

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

    assert_self_contained(&page);
    // the plots the issue asks for, for a hysteresis diagnosis
    let expected = [
        "plot-compare",
        "plot-compare-zoom",
        "plot-residual-time",
        "plot-acf",
        "plot-ccf-0",
        "plot-hoc-0",
        "plot-evidence-1-hysteresis",
        // the shock absorber's hysteretic force ends in the mechanical
        // grey-box model (a physics model): its 95 % prediction band
        "plot-physics-bands",
        "plot-physics-bands-zoom",
    ];
    for id in expected {
        assert!(
            page.contains(&format!("<figure id=\"{id}\"")),
            "{id} missing"
        );
    }
    assert!(page.contains("Steps and gains") && page.contains("<table>"));

    let Some(laid) = laid_out(&page, &d) else {
        return;
    };
    let seen = check_plots(&laid);
    for id in expected {
        assert!(seen.iter().any(|s| s == id), "{id} not rendered: {seen:?}");
    }
    let _ = std::fs::remove_dir_all(&d);
}

const TS: f64 = 0.05;

/// Random force steps held 5–40 samples.
fn force_steps(n: usize, rng: &mut impl Rng) -> Vec<f64> {
    let level = Normal::new(0.0, 1.0).unwrap();
    let mut u = Vec::with_capacity(n);
    while u.len() < n {
        let hold = rng.random_range(5..40);
        u.extend(std::iter::repeat_n(level.sample(rng), hold));
    }
    u.truncate(n);
    u
}

/// `examples/models/msd.toml`'s truth (m = 1, c = 0.4, k = 4) with a
/// hardening spring 6·x³ the file lacks, 20 RK4 steps per sample, plus
/// white noise of 0.01; written as `t,F,y` to `path`.
fn msd_cubic_csv(path: &Path, model_file: &Path, n: usize, seed: u64) {
    let mut rng = gb_core::rng::seeded(seed);
    let u = force_steps(n, &mut rng);
    let mut spec = ModelFile::read(model_file).unwrap().spec;
    spec.substeps = 20;
    spec.sample_time = Some(TS);
    spec.parameters.push(Parameter::new("k3", 6.0));
    spec.add_term(TermTarget::State(1), "-k3/m*x^3").unwrap();
    let truth = PhysicsModel::new(spec)
        .unwrap()
        .with_values(vec![1.0, 0.4, 4.0, 6.0], vec![0.0, 0.0])
        .unwrap();
    let clean = truth
        .simulate(std::slice::from_ref(&u), Init::Stored)
        .unwrap();
    let noise = Normal::new(0.0, 0.01).unwrap();
    let mut s = String::from("t,F,y\n");
    for (k, (f, y)) in u.iter().zip(&clean).enumerate() {
        s.push_str(&format!(
            "{},{f},{}\n",
            k as f64 * TS,
            y + noise.sample(&mut rng)
        ));
    }
    std::fs::write(path, s).unwrap();
}

#[test]
fn physics_report_shows_parameter_tables_and_the_prediction_band() {
    let d = tmp("physics");
    let model_file =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../examples/models/msd.toml");
    let (train, val) = (d.join("train.csv"), d.join("validate.csv"));
    msd_cubic_csv(&train, &model_file, 2000, 31);
    msd_cubic_csv(&val, &model_file, 1500, 32);
    let report = d.join("r.html");
    let o = Command::new(env!("CARGO_BIN_EXE_greybox"))
        .arg("diagnose")
        .arg(&train)
        .arg("--validate")
        .arg(&val)
        .arg("--model-file")
        .arg(&model_file)
        .arg("--report")
        .arg(&report)
        .output()
        .expect("run greybox");
    let so = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "diagnose failed: {so}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let page = std::fs::read_to_string(&report).expect("report written");
    assert_self_contained(&page);
    // the linear file misses the cubic spring: baseline and final differ,
    // one table each, every physical parameter with an interval
    for id in [
        "physics-parameters-baseline",
        "physics-parameters-final-model",
    ] {
        let at = page
            .find(&format!("<table id=\"{id}\""))
            .unwrap_or_else(|| panic!("table {id} missing\n{so}"));
        let table = &page[at..at + page[at..].find("</table>").unwrap()];
        for name in ["<td>m</td>", "<td>c</td>", "<td>k</td>"] {
            assert!(table.contains(name), "{name} not in {id}: {table}");
        }
        assert!(table.contains("95 % interval") && table.matches("[").count() >= 3);
    }
    let fig = page
        .find("<figure id=\"plot-physics-bands\"")
        .expect("band plot missing");
    let caption = &page[fig..fig + page[fig..].find("</figure>").unwrap()];
    let coverage: f64 = caption
        .split("it covers ")
        .nth(1)
        .and_then(|r| r.split(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no coverage in the caption: {caption}"));
    // 95 % band of the extended model on held-out noisy data
    assert!((85.0..=100.0).contains(&coverage), "coverage {coverage} %");

    let Some(laid) = laid_out(&page, &d) else {
        return;
    };
    let seen = check_plots(&laid);
    for id in ["plot-physics-bands", "plot-physics-bands-zoom"] {
        assert!(seen.iter().any(|s| s == id), "{id} not rendered: {seen:?}");
    }
    for id in [
        "physics-parameters-baseline",
        "physics-parameters-final-model",
    ] {
        let t = laid
            .iter()
            .find(|p| p.id == format!("table:{id}"))
            .unwrap_or_else(|| panic!("table {id} not laid out"));
        assert!(
            t.width >= 300.0 && t.height >= 60.0 && t.count >= 4,
            "table {id} laid out at {}x{} with {} rows",
            t.width,
            t.height,
            t.count
        );
    }
    let _ = std::fs::remove_dir_all(&d);
}
