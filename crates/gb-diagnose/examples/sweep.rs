//! Run the diagnosis on cases drawn from the generator's families and
//! tabulate right causes, final NRMSE against the noise floor and time.
//!
//! ```sh
//! cargo run --release -p gb-diagnose --example sweep -- --seeds 10 --markdown docs/sweep-baseline.md
//! cargo run --release -p gb-diagnose --example sweep -- --quick
//! cargo run --release -p gb-diagnose --example sweep -- --families duffing,backlash --seeds 3 --dry-run
//! ```
//!
//! Flags: `--families a,b,..` (default all), `--seeds N` (seeds 1..=N,
//! default 10), `--first-seed S`, `--quick` (a fixed small subset),
//! `--cases fam:seed,..` (just these cases; overrides `--families` and
//! `--seeds`), `--markdown FILE`, `--json FILE`, `--order case|auto|N` (default: the
//! case's engineer order), `--sequential`, `--dry-run` (list the cases),
//! knob overrides `--n-train N`, `--n-validate N`, `--snr DB`, `--excitation multisine|noise|prbs|sweep`,
//! `--spp X`.
use gb_diagnose::generator::{draw_with, ExcitationKind, Knobs, FAMILIES};
use gb_diagnose::sweep::{markdown, run, CaseResult, CaseSpec, OrderMode, SweepOptions};
use std::sync::atomic::{AtomicUsize, Ordering};

struct Args {
    families: Vec<String>,
    cases: Vec<(String, u64)>,
    seeds: u64,
    first_seed: u64,
    quick: bool,
    markdown: Option<String>,
    json: Option<String>,
    opts: SweepOptions,
    dry_run: bool,
    knobs: Knobs,
}

fn parse() -> Result<Args, String> {
    let mut a = Args {
        families: FAMILIES.iter().map(|s| s.to_string()).collect(),
        cases: vec![],
        seeds: 10,
        first_seed: 1,
        quick: false,
        markdown: None,
        json: None,
        opts: SweepOptions::default(),
        dry_run: false,
        knobs: Knobs::default(),
    };
    let mut it = std::env::args().skip(1);
    while let Some(f) = it.next() {
        let mut val = || it.next().ok_or(format!("{f} needs a value"));
        let num = |s: String| {
            s.parse::<f64>()
                .map_err(|_| format!("{f}: '{s}' is not a number"))
        };
        match f.as_str() {
            "--families" => a.families = val()?.split(',').map(str::to_string).collect(),
            "--cases" => {
                for c in val()?.split(',') {
                    let (f, s) = c
                        .split_once(':')
                        .ok_or(format!("--cases: '{c}' is not family:seed"))?;
                    a.cases.push((f.to_string(), num(s.to_string())? as u64));
                }
            }
            "--seeds" => a.seeds = num(val()?)? as u64,
            "--first-seed" => a.first_seed = num(val()?)? as u64,
            "--quick" => a.quick = true,
            "--markdown" => a.markdown = Some(val()?),
            "--json" => a.json = Some(val()?),
            "--sequential" => a.opts.parallel = false,
            "--dry-run" => a.dry_run = true,
            "--order" => {
                a.opts.order = match val()?.as_str() {
                    "case" => OrderMode::Case,
                    "auto" => OrderMode::Auto,
                    n => OrderMode::Fixed(num(n.to_string())? as usize),
                }
            }
            "--n-train" => a.knobs.n_train = Some(num(val()?)? as usize),
            "--n-validate" => a.knobs.n_validate = Some(num(val()?)? as usize),
            "--snr" => a.knobs.snr_db = Some(num(val()?)?),
            "--spp" => a.knobs.samples_per_period = Some(num(val()?)?),
            "--excitation" => {
                let v = val()?;
                a.knobs.excitation =
                    Some(ExcitationKind::parse(&v).ok_or(format!("unknown excitation '{v}'"))?)
            }
            other => return Err(format!("unknown flag '{other}'")),
        }
    }
    for f in a.families.iter().chain(a.cases.iter().map(|(f, _)| f)) {
        if !FAMILIES.contains(&f.as_str()) {
            return Err(format!(
                "unknown family '{f}' (known: {})",
                FAMILIES.join(", ")
            ));
        }
    }
    Ok(a)
}

fn specs(a: &Args) -> Vec<CaseSpec> {
    if a.quick {
        let knobs = Knobs {
            n_train: Some(1500),
            n_validate: Some(750),
            ..Knobs::default()
        };
        let fams = ["linear", "duffing", "backlash", "two-mass", "student-t"];
        return fams
            .iter()
            .flat_map(|f| {
                let k = knobs.clone();
                (1..=2).map(move |s| CaseSpec {
                    family: f.to_string(),
                    seed: s,
                    knobs: k.clone(),
                })
            })
            .collect();
    }
    if !a.cases.is_empty() {
        return a
            .cases
            .iter()
            .map(|(f, s)| CaseSpec {
                family: f.clone(),
                seed: *s,
                knobs: a.knobs.clone(),
            })
            .collect();
    }
    let names: Vec<&str> = a.families.iter().map(String::as_str).collect();
    let mut v = CaseSpec::grid(&names, a.first_seed..=a.first_seed + a.seeds.max(1) - 1);
    v.iter_mut().for_each(|s| s.knobs = a.knobs.clone());
    v
}

fn main() {
    let a = match parse() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("sweep: {e}");
            std::process::exit(2);
        }
    };
    let specs = specs(&a);
    if a.dry_run {
        for s in &specs {
            match draw_with(&s.family, s.seed, &s.knobs) {
                Ok(c) => println!(
                    "{} {}: expect [{}] floor {:.4} strength {:.3} | {}",
                    s.family,
                    s.seed,
                    c.expected.join(","),
                    c.noise_floor_nrmse,
                    c.effect_strength,
                    c.description
                ),
                Err(e) => println!("{} {}: error {e}", s.family, s.seed),
            }
        }
        return;
    }
    let done = AtomicUsize::new(0);
    let total = specs.len();
    let progress = |r: &CaseResult| {
        let k = done.fetch_add(1, Ordering::Relaxed) + 1;
        eprintln!(
            "[{k}/{total}] {} {}: expect [{}] named [{}] final/floor {:.2} {} {:.1}s{}",
            r.family,
            r.seed,
            r.expected.join(","),
            r.named.join(","),
            r.ratio,
            if r.right { "RIGHT" } else { "wrong" },
            r.seconds,
            r.error
                .as_deref()
                .map(|e| format!(" error: {e}"))
                .unwrap_or_default()
        );
    };
    let t = std::time::Instant::now();
    let results = run(&specs, &a.opts, Some(&progress));
    let wall = t.elapsed().as_secs_f64();
    let title = format!(
        "Diagnosis sweep: {} cases ({}), order {:?}, {} on {} threads, {:.0} s wall",
        results.len(),
        if a.quick {
            "--quick".to_string()
        } else {
            format!(
                "seeds {}..={}",
                a.first_seed,
                a.first_seed + a.seeds.max(1) - 1
            )
        },
        a.opts.order,
        if a.opts.parallel {
            "cases in parallel"
        } else {
            "one case at a time"
        },
        rayon::current_num_threads(),
        wall
    );
    let md = markdown(&results, &title);
    println!("{md}");
    let write = |path: &str, text: String| {
        if let Err(e) = std::fs::write(path, text) {
            eprintln!("sweep: {path}: {e}");
            std::process::exit(2);
        }
    };
    if let Some(p) = &a.markdown {
        write(p, md);
    }
    if let Some(p) = &a.json {
        match serde_json::to_string_pretty(&results) {
            Ok(s) => write(p, s),
            Err(e) => eprintln!("sweep: {e}"),
        }
    }
}
