//! Markdown tables of a sweep.
use super::CaseResult;
use std::fmt::Write;

fn finite(v: impl Iterator<Item = f64>) -> Vec<f64> {
    let mut x: Vec<f64> = v.filter(|x| !x.is_nan()).collect();
    x.sort_by(f64::total_cmp);
    x
}

fn median(x: &[f64]) -> f64 {
    match x.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => x[n / 2],
        n => 0.5 * (x[n / 2 - 1] + x[n / 2]),
    }
}

fn max(x: &[f64]) -> f64 {
    x.last().copied().unwrap_or(f64::NAN)
}

fn frac(k: usize, n: usize) -> String {
    if n == 0 {
        return "–".into();
    }
    format!("{k}/{n} ({:.0} %)", 100.0 * k as f64 / n as f64)
}

fn count(r: &[&CaseResult], f: impl Fn(&CaseResult) -> bool) -> usize {
    r.iter().filter(|c| f(c)).count()
}

fn causes(v: &[String]) -> String {
    if v.is_empty() {
        "none".into()
    } else {
        v.join("+")
    }
}

fn headline(out: &mut String, all: &[&CaseResult]) {
    let n = all.len();
    let clean: Vec<&CaseResult> = all
        .iter()
        .copied()
        .filter(|c| c.expected.is_empty())
        .collect();
    let ratios = finite(all.iter().map(|c| c.ratio));
    let times = finite(all.iter().map(|c| c.seconds));
    let _ = writeln!(out, "| figure | value |\n|---|---|");
    let rows = [
        ("cases", n.to_string()),
        (
            "right (causes right, final ≤ 1.5× floor)",
            frac(count(all, |c| c.right), n),
        ),
        (
            "right, final ≤ 1.3× floor",
            frac(count(all, |c| c.right_tight), n),
        ),
        (
            "right cause & no foreign cause (any NRMSE)",
            frac(count(all, |c| c.causes_right), n),
        ),
        (
            "a foreign cause named",
            frac(count(all, |c| !c.foreign_named.is_empty()), n),
        ),
        (
            "no cause named on clean linear data (linear, dead-time)",
            frac(
                count(&clean, |c| c.error.is_none() && c.named.is_empty()),
                clean.len(),
            ),
        ),
        (
            "final ≤ 1.3× floor (any causes)",
            frac(count(all, |c| c.ratio <= 1.3), n),
        ),
        (
            "final ≤ 1.5× floor (any causes)",
            frac(count(all, |c| c.ratio <= 1.5), n),
        ),
        ("median final/floor", format!("{:.2}", median(&ratios))),
        (
            "verdict \"adequate\" while final > 1.5× floor",
            frac(count(all, |c| c.adequate_above_floor), n),
        ),
        (
            "verdict \"adequate\" or \"coloured noise\" while final > 1.5× floor",
            frac(count(all, |c| c.explained_above_floor), n),
        ),
        ("errors", count(all, |c| c.error.is_some()).to_string()),
        (
            "median / max time per case (s)",
            format!("{:.1} / {:.1}", median(&times), max(&times)),
        ),
    ];
    for (k, v) in rows {
        let _ = writeln!(out, "| {k} | {v} |");
    }
}

fn per_family(out: &mut String, all: &[&CaseResult]) {
    let _ = writeln!(
        out,
        "| family | expected | cases | right cause & no foreign | foreign named | no cause named | right ≤1.5× | right ≤1.3× | median final/floor | max final/floor | \"adequate\" >1.5× | median / max time (s) |\n|---|---|---|---|---|---|---|---|---|---|---|---|"
    );
    let mut fams: Vec<&str> = vec![];
    for c in all {
        if !fams.contains(&c.family.as_str()) {
            fams.push(&c.family);
        }
    }
    for f in fams {
        let r: Vec<&CaseResult> = all.iter().copied().filter(|c| c.family == f).collect();
        let n = r.len();
        let ratios = finite(r.iter().map(|c| c.ratio));
        let times = finite(r.iter().map(|c| c.seconds));
        let _ = writeln!(
            out,
            "| {f} | {} | {n} | {} | {} | {} | {} | {} | {:.2} | {:.2} | {} | {:.1} / {:.1} |",
            causes(&r[0].expected),
            frac(count(&r, |c| c.causes_right), n),
            count(&r, |c| !c.foreign_named.is_empty()),
            frac(count(&r, |c| c.error.is_none() && c.named.is_empty()), n),
            frac(count(&r, |c| c.right), n),
            frac(count(&r, |c| c.right_tight), n),
            median(&ratios),
            max(&ratios),
            count(&r, |c| c.adequate_above_floor),
            median(&times),
            max(&times),
        );
    }
}

fn confusion(out: &mut String, all: &[&CaseResult]) {
    let cols = [
        "none",
        "nonlinearity",
        "hysteresis",
        "dynamics",
        "noise",
        "error",
    ];
    let first = |v: &[String]| v.first().cloned().unwrap_or_else(|| "none".into());
    let _ = writeln!(out, "| expected \\ first named | {} |", cols.join(" | "));
    let _ = writeln!(out, "|---|{}", "---|".repeat(cols.len()));
    for row in &cols[..5] {
        let r: Vec<&CaseResult> = all
            .iter()
            .copied()
            .filter(|c| first(&c.expected) == *row)
            .collect();
        if r.is_empty() {
            continue;
        }
        let cells: Vec<String> = cols
            .iter()
            .map(|col| {
                count(&r, |c| {
                    if *col == "error" {
                        c.error.is_some()
                    } else {
                        c.error.is_none() && first(&c.named) == *col
                    }
                })
                .to_string()
            })
            .collect();
        let _ = writeln!(out, "| {row} | {} |", cells.join(" | "));
    }
}

fn distribution(out: &mut String, all: &[&CaseResult]) {
    let edges = [1.1, 1.3, 1.5, 2.0];
    let _ = writeln!(
        out,
        "| expected | ≤1.1 | ≤1.3 | ≤1.5 | ≤2 | >2 |\n|---|---|---|---|---|---|"
    );
    let mut groups: Vec<String> = vec![];
    for c in all {
        let g = causes(&c.expected);
        if !groups.contains(&g) {
            groups.push(g);
        }
    }
    groups.push("all".into());
    for g in groups {
        let r: Vec<f64> = all
            .iter()
            .filter(|c| g == "all" || causes(&c.expected) == g)
            .map(|c| c.ratio)
            .filter(|x| !x.is_nan())
            .collect();
        let mut cells = vec![];
        let mut lo = 0.0;
        for e in edges {
            cells.push(r.iter().filter(|&&x| x > lo && x <= e).count());
            lo = e;
        }
        cells.push(r.iter().filter(|&&x| x > lo).count());
        let cells: Vec<String> = cells.iter().map(|k| k.to_string()).collect();
        let _ = writeln!(out, "| {g} | {} |", cells.join(" | "));
    }
}

fn failures(out: &mut String, all: &[&CaseResult]) {
    let _ = writeln!(
        out,
        "| family | seed | expected | named | baseline | final | floor | final/floor | strength | N | samples/period | excitation | SNR | candidates (iteration cause select-gain) |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
    );
    for c in all.iter().filter(|c| !c.right) {
        let named = match &c.error {
            Some(e) => format!("error: {}", e.replace('|', "/")),
            None => causes(&c.named),
        };
        let _ = writeln!(
            out,
            "| {} | {} | {} | {named} | {:.4} | {:.4} | {:.4} | {:.2} | {:.3} | {} | {:.1} | {} | {:.1} | {} |",
            c.family,
            c.seed,
            causes(&c.expected),
            c.baseline_nrmse,
            c.final_nrmse,
            c.floor,
            c.ratio,
            c.effect_strength,
            c.n_train,
            c.samples_per_period,
            c.excitation,
            c.snr_db,
            c.steps.join("; "),
        );
    }
}

/// The sweep's tables as markdown; `title` heads them (e.g. the command).
pub fn markdown(results: &[CaseResult], title: &str) -> String {
    let all: Vec<&CaseResult> = results.iter().collect();
    let mut out = String::new();
    let _ = writeln!(out, "# {title}\n");
    let _ = writeln!(out, "## Headline\n");
    headline(&mut out, &all);
    let _ = writeln!(out, "\n## Per family\n");
    per_family(&mut out, &all);
    let _ = writeln!(
        out,
        "\n## Confusion (first expected cause × first named cause)\n"
    );
    confusion(&mut out, &all);
    let _ = writeln!(out, "\n## Final validation NRMSE / noise floor\n");
    distribution(&mut out, &all);
    let _ = writeln!(
        out,
        "\n## Failures ({} of {})\n",
        all.iter().filter(|c| !c.right).count(),
        all.len()
    );
    failures(&mut out, &all);
    out
}
