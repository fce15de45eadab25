//! Hide an effect in generated data and require the diagnosis to find it —
//! and not to invent one in clean data.
//!
//! Every system is generated with two seeds; the seed also varies the
//! physical parameters (±15 %) and the SNR (30–33 dB). For each case:
//! - the first named cause is the hidden one (`[]` for clean data);
//! - causes that would be a misdiagnosis never appear (e.g. `hysteresis`
//!   for a static saturation);
//! - the final validation NRMSE is within 2× the noise floor put in.
use gb_diagnose::{diagnose, html, systems, DiagnoseData, DiagnoseOptions, Diagnosis};

/// Every plot the report promises is a `<figure id=…>` holding one
/// well-formed `<svg>` with drawn content.
fn check_report(page: &str, ids: &[String]) {
    for id in ids {
        let at = page
            .find(&format!("<figure id=\"{id}\""))
            .unwrap_or_else(|| panic!("plot {id} missing from the report"));
        let rest = &page[at..];
        let s0 = rest.find("<svg").expect("svg in figure");
        let s1 = rest.find("</svg>").expect("svg closed") + "</svg>".len();
        let end = rest.find("</figure>").expect("figure closed");
        assert!(s0 < s1 && s1 <= end, "svg of {id} not inside its figure");
        let doc = roxmltree::Document::parse(&rest[s0..s1])
            .unwrap_or_else(|e| panic!("svg of {id} is not well-formed: {e}"));
        let drawn = doc
            .descendants()
            .filter(|n| {
                matches!(
                    n.tag_name().name(),
                    "polyline" | "path" | "circle" | "rect" | "line"
                )
            })
            .count();
        assert!(drawn >= 10, "plot {id} has only {drawn} drawn elements");
    }
}

/// The checks above for `system`, seeds 1 and 2: the diagnoses and
/// their noise floors.
fn check(system: &str, forbidden: &[&str]) -> Vec<(Diagnosis, f64)> {
    let mut out = vec![];
    for seed in [1u64, 2] {
        let g = systems::generate(system, seed, 8000, 4000).expect("generate");
        let floor = g.noise_floor_nrmse;
        let expected = g.expected_cause.clone();
        let data = DiagnoseData::with_validation(g.train, g.validate).expect("data");
        let d = diagnose(&data, &DiagnoseOptions::default(), None).expect("diagnose");
        let page = html::render_html(&d, &data, system).expect("html report");
        let ids = html::plot_ids(&d);
        check_report(&page, &ids);
        for c in &d.report.causes {
            assert!(
                ids.iter()
                    .any(|id| id.starts_with("plot-evidence-") && id.ends_with(&format!("-{c}"))),
                "no evidence plot for {c}"
            );
        }
        let r = &d.report;
        let summary = format!(
            "{system} seed {seed}: causes {:?}, baseline NRMSE {:.4}, final {:.4}, noise floor {:.4}",
            r.causes, r.baseline.nrmse, r.final_model.nrmse, floor
        );
        eprintln!("{summary}");
        match &expected {
            None => assert!(r.causes.is_empty(), "false cause named: {summary}"),
            Some(c) => assert_eq!(
                r.cause_names().first().copied(),
                Some(c.as_str()),
                "wrong or missed cause: {summary}"
            ),
        }
        for f in forbidden {
            assert!(
                !r.cause_names().contains(f),
                "misdiagnosis '{f}': {summary}"
            );
        }
        assert!(
            r.final_model.nrmse <= 2.0 * floor,
            "final NRMSE not within 2x the noise floor: {summary}"
        );
        assert!(r.final_model.nrmse.is_finite() && r.baseline.nrmse.is_finite());
        out.push((d, floor));
    }
    out
}

#[test]
fn clean_linear_system_gets_no_cause() {
    let _ = check(
        "linear",
        &["nonlinearity", "hysteresis", "dynamics", "noise"],
    );
}

#[test]
fn duffing_stiffness_is_nonlinearity() {
    let _ = check("duffing", &["hysteresis"]);
}

#[test]
fn input_saturation_is_nonlinearity() {
    let _ = check("saturation", &["hysteresis"]);
}

#[test]
fn dead_zone_is_nonlinearity() {
    let _ = check("deadzone", &["hysteresis"]);
}

#[test]
fn preisach_hysteresis_is_hysteresis() {
    let _ = check("preisach", &["nonlinearity"]);
}

/// Also a hysteretic restoring force: see [`needs_a_hidden_state`].
#[test]
fn bouc_wen_is_hysteresis() {
    for (d, floor) in check("bouc-wen", &["nonlinearity"]) {
        needs_a_hidden_state(&d, floor, "bouc-wen");
    }
}

#[test]
fn backlash_is_hysteresis() {
    let _ = check("backlash", &["nonlinearity"]);
}

#[test]
fn hidden_second_mass_is_dynamics() {
    let _ = check("two-mass", &["nonlinearity", "hysteresis"]);
}

#[test]
fn student_t_noise_is_noise() {
    let _ = check("student-t", &["nonlinearity", "hysteresis", "dynamics"]);
}

/// A hysteretic restoring force (Bouc-Wen spring, Bouc-Wen shock absorber):
/// the input-output extensions (Preisach columns) leave structure in the
/// residuals, so the diagnosis must reach a model with a hidden hysteretic
/// state inside the dynamics — the mechanical template with a Bouc–Wen
/// state, or gb-model's wavelet state space — and the noise floor with it.
fn needs_a_hidden_state(d: &Diagnosis, floor: f64, system: &str) {
    let r = &d.report;
    let summary = format!(
        "{system}: causes {:?}, final {} NRMSE {:.4}, noise floor {floor:.4}",
        r.causes, r.final_model.spec, r.final_model.nrmse
    );
    eprintln!("{summary}");
    assert_eq!(
        r.causes.first().copied(),
        Some(gb_diagnose::Cause::Hysteresis),
        "{summary}"
    );
    // a hidden hysteretic state inside the dynamics: the wavelet
    // state space, or the mechanical template with a Bouc–Wen state
    let class = d.model.dynamics.class();
    assert!(
        class == "state-space" || class == "physics",
        "no hidden-state model: {summary}"
    );
    let last = r
        .steps
        .iter()
        .rfind(|s| s.accepted)
        .expect("an accepted step");
    assert!(
        last.extension.starts_with("hidden-state model")
            || last.extension.starts_with("a mechanical grey-box model"),
        "{summary}"
    );
    assert!(d.model.dynamics.n_states() >= 3, "{summary}");
    // what the input-output extensions reached before it
    let before = last.nrmse_before;
    assert!(
        before > 1.4 * floor,
        "the simple extensions sufficed: {summary}"
    );
    assert!(
        r.final_model.nrmse < 1.15 * floor,
        "not at the noise floor: {summary}"
    );
    if class == "state-space" {
        assert!(html::plot_ids(d).iter().any(|i| i == "plot-state-space"));
    }
}

/// The shock absorber (a Bouc–Wen element between the mass and the
/// ground), seeds 1 and 2: [`needs_a_hidden_state`].
#[test]
fn hysteretic_force_needs_the_hidden_state_model() {
    for seed in [1u64, 2] {
        let g = systems::generate("shock-absorber", seed, 8000, 4000).expect("generate");
        let floor = g.noise_floor_nrmse;
        let data = DiagnoseData::with_validation(g.train, g.validate).expect("data");
        let d = diagnose(&data, &DiagnoseOptions::default(), None).expect("diagnose");
        needs_a_hidden_state(&d, floor, &format!("shock-absorber seed {seed}"));
    }
}
