//! The physics part of the page, for a diagnosis whose baseline or final
//! model is the engineer's model file (class `physics`): a parameter table
//! per physics model (estimates, standard errors, 95 % intervals, fixed or
//! free, the identifiability warnings and strongly correlated pairs), and
//! the measured output with the final model's simulation and its 95 %
//! prediction band on the report block (drawn from the stored covariance;
//! nothing is refitted).
use super::{draw_err, esc, figure, frame, legend, snap, tick, Signals, BAND, FINAL, MEASURED};
use crate::curves::{range, thin};
use crate::physics::physics_of;
use crate::{DiagnoseError, Diagnosis};
use gb_core::Init;
use gb_model::physics::{prediction_bands, BandParams, Bands, FitReport, PhysicsModel};
use plotters::prelude::*;
use std::fmt::Write as _;

/// Id of the band plot (whole report block).
pub(super) const BANDS_ID: &str = "plot-physics-bands";
/// Id of the band plot's zoom (a window at full resolution).
pub(super) const BANDS_ZOOM_ID: &str = "plot-physics-bands-zoom";
/// Samples in the zoom window.
const ZOOM: usize = 300;

/// Points drawn per curve of the band plot.
const MAX_POINTS: usize = 2500;

/// Whether the final model of `dg` is a physics model (the page then has
/// the band plot).
pub(super) fn has_band_plot(dg: &Diagnosis) -> bool {
    dg.chain
        .last()
        .is_some_and(|e| physics_of(&e.model).is_some())
}

/// The physics models of the chain that get a table: the baseline and the
/// final model, labelled.
fn tabled(dg: &Diagnosis) -> Vec<(&'static str, &PhysicsModel)> {
    let mut v = vec![];
    if let Some(m) = dg.chain.first().and_then(|e| physics_of(&e.model)) {
        v.push(("baseline", m));
    }
    if dg.chain.len() > 1 {
        if let Some(m) = dg.chain.last().and_then(|e| physics_of(&e.model)) {
            v.push(("final model", m));
        }
    }
    v
}

/// The physics section: the tables, then the band plot (of a physics final
/// model). Writes nothing when neither the baseline nor the final model is
/// a physics model.
pub(super) fn physics_section(
    body: &mut String,
    dg: &Diagnosis,
    d: &crate::DiagnoseData,
    s: &Signals,
) -> Result<(), DiagnoseError> {
    let models = tabled(dg);
    if models.is_empty() {
        return Ok(());
    }
    body.push_str("<h2>Physical parameters (the model file's equations)</h2>\n");
    for (label, m) in &models {
        parameter_table(body, label, m);
    }
    if has_band_plot(dg) {
        band_plot(body, dg, d, s)?;
    }
    Ok(())
}

/// The status of an estimate in words.
fn status(e: &gb_model::physics::Estimate) -> &'static str {
    if e.fixed {
        "fixed"
    } else if e.at_bound {
        "free, at a bound"
    } else if !e.std_error.is_finite() {
        "free, not identifiable"
    } else {
        "free"
    }
}

/// One model's table of estimates and its warnings.
fn parameter_table(body: &mut String, label: &str, m: &PhysicsModel) {
    let id = format!("physics-parameters-{}", label.replace(' ', "-"));
    let _ = writeln!(
        body,
        "<h3>{}: '{}'</h3>",
        esc(&capitalised(label)),
        esc(&m.spec().name)
    );
    let Some(r) = m.fit_report() else {
        // an unfitted model: its values only
        let _ = writeln!(
            body,
            "<table id=\"{id}\" class=\"physics\">\n<tr><th>parameter</th><th>value</th><th>status</th></tr>"
        );
        for (p, v) in m.spec().parameters.iter().zip(m.parameters()) {
            let st = if p.fixed {
                "fixed"
            } else {
                "free (not fitted)"
            };
            let _ = writeln!(
                body,
                "<tr><td>{}</td><td>{v:.6e}</td><td>{st}</td></tr>",
                esc(&p.name)
            );
        }
        body.push_str("</table>\n");
        return;
    };
    let _ = writeln!(
        body,
        "<table id=\"{id}\" class=\"physics\">\n<tr><th>parameter</th><th>estimate</th><th>std. error</th><th>95 % interval</th><th>status</th></tr>"
    );
    for e in &r.estimates {
        let (se, iv) = if e.fixed || !e.std_error.is_finite() {
            ("&mdash;".to_string(), "&mdash;".to_string())
        } else {
            (
                format!("{:.3e}", e.std_error),
                format!("[{:.6e}, {:.6e}]", e.interval.0, e.interval.1),
            )
        };
        let _ = writeln!(
            body,
            "<tr><td>{}</td><td>{:.6e}</td><td>{se}</td><td>{iv}</td><td>{}</td></tr>",
            esc(&e.name),
            e.value,
            status(e)
        );
    }
    body.push_str("</table>\n");
    fit_notes(body, r);
}

/// The fit's conditioning, warnings and strongly correlated pairs.
fn fit_notes(body: &mut String, r: &FitReport) {
    let _ = writeln!(
        body,
        "<p>Output-error fit on {} samples: RMSE {:.4e}, NRMSE {:.4}, &sigma;&#770; {:.4e}; condition number of the scaled J<sup>T</sup>J {:.2e}; {} iterations ({}).</p>",
        r.samples,
        r.rmse,
        r.nrmse,
        r.sigma,
        r.condition,
        r.iterations,
        esc(&r.termination)
    );
    if r.warnings.is_empty() && r.correlated.is_empty() {
        body.push_str("<p>No identifiability warning; no strongly correlated pair.</p>\n");
        return;
    }
    body.push_str("<ul class=\"physics-warnings\">\n");
    for w in &r.warnings {
        let _ = writeln!(body, "<li>warning: {}</li>", esc(w));
    }
    for (a, b, rho) in &r.correlated {
        let _ = writeln!(
            body,
            "<li>strongly correlated: {} and {} (&rho; = {rho:+.3})</li>",
            esc(a),
            esc(b)
        );
    }
    body.push_str("</ul>\n");
}

/// `s` with its first letter upper-case.
fn capitalised(s: &str) -> String {
    let mut c = s.chars();
    c.next()
        .map_or(String::new(), |f| f.to_uppercase().chain(c).collect())
}

/// The final model's 95 % prediction band on the scored report block, from
/// its stored covariance: simulated from the record's start with the
/// initial state of the init window, as its residuals were.
fn report_bands(dg: &Diagnosis, d: &crate::DiagnoseData, s: &Signals) -> Result<Bands, String> {
    let last = &dg.chain[dg.chain.len() - 1].model;
    let end = d.report_range.end;
    let w = dg.report.data.init_window.min(end);
    let inputs: Vec<Vec<f64>> = d.report.inputs.iter().map(|u| u[..end].to_vec()).collect();
    let b = prediction_bands(
        last,
        &inputs,
        Init::Window(&d.report.output[..w]),
        BandParams::default(),
    )
    .map_err(|e| e.to_string())?;
    Ok(Bands {
        lo: b.lo[s.start..end].to_vec(),
        hi: b.hi[s.start..end].to_vec(),
        ..b
    })
}

/// Measured output, the final simulation and its band (when it could be
/// computed), with the band's coverage of the measured samples in the
/// caption.
fn band_plot(
    body: &mut String,
    dg: &Diagnosis,
    d: &crate::DiagnoseData,
    s: &Signals,
) -> Result<(), DiagnoseError> {
    let fin = &dg.chain[dg.chain.len() - 1].report;
    let bands = report_bands(dg, d, s);
    let caption = match &bands {
        Ok(b) => {
            let inside =
                s.y.iter()
                    .zip(b.lo.iter().zip(&b.hi))
                    .filter(|(y, (lo, hi))| (*lo..=*hi).contains(y))
                    .count();
            format!(
                "Grey: the final model's 95 % prediction band ({} parameter draws from the fit's covariance{}, plus the noise sigma = {:.3e}); it covers {:.1} % of the {} measured samples of the report block ({} inside).",
                b.draws,
                if b.failed > 0 { format!(", {} diverged and left out", b.failed) } else { String::new() },
                dg.chain[dg.chain.len() - 1].model.noise.sd(),
                100.0 * inside as f64 / s.y.len().max(1) as f64,
                s.y.len(),
                inside
            )
        }
        Err(e) => format!("No prediction band: {e}."),
    };
    body.push_str("<h3>Prediction band of the final model (validation data, free run)</h3>\n");
    let (band, yname) = (bands.as_ref().ok(), &dg.report.data.output);
    let n = s.t.len().min(fin.yhat.len());
    let title = "Measured output, final simulation and 95 % prediction band";
    let svg = band_chart(s, &fin.yhat, band, yname, 0..n, title)?;
    figure(body, BANDS_ID, &caption, &svg);
    let zn = ZOOM.min(n);
    let z0 = (n - zn) / 2;
    let title = format!("Zoom: samples {}..{}", s.start + z0, s.start + z0 + zn);
    let svg = band_chart(s, &fin.yhat, band, yname, z0..z0 + zn, &title)?;
    figure(
        body,
        BANDS_ZOOM_ID,
        "The same at full resolution in a window of the report block.",
        &svg,
    );
    Ok(())
}

/// The band as a filled polygon under the measured and simulated outputs,
/// over the samples `window` of the report block.
fn band_chart(
    s: &Signals,
    yhat: &[f64],
    band: Option<&Bands>,
    yname: &str,
    window: std::ops::Range<usize>,
    title: &str,
) -> Result<String, DiagnoseError> {
    let t = &s.t[window.clone()];
    let measured = thin(t, &s.y[window.clone()], MAX_POINTS);
    let simulated = thin(t, &yhat[window.clone()], MAX_POINTS);
    let (lo, hi) = band.map_or((vec![], vec![]), |b| {
        (
            thin(t, &b.lo[window.clone()], MAX_POINTS),
            thin(t, &b.hi[window.clone()], MAX_POINTS),
        )
    });
    let (x0, x1) = range(measured.iter().map(|p| p.0));
    let (y0, y1) = range(
        [&measured, &simulated, &lo, &hi]
            .into_iter()
            .flat_map(|c| c.iter().map(|p| p.1)),
    );
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, (super::W, super::H)).into_drawing_area();
        let mut ch = frame(&root, title, x0..x1, y0..y1)?;
        ch.configure_mesh()
            .x_desc("sample")
            .y_desc(yname)
            .x_labels(8)
            .y_labels(6)
            .x_label_formatter(&|v| tick(snap(*v, x1 - x0)))
            .y_label_formatter(&|v| tick(snap(*v, y1 - y0)))
            .light_line_style(RGBColor(238, 238, 238))
            .draw()
            .map_err(draw_err)?;
        if !lo.is_empty() {
            let outline: Vec<(f64, f64)> = lo.iter().chain(hi.iter().rev()).copied().collect();
            ch.draw_series(std::iter::once(Polygon::new(
                outline,
                BAND.mix(0.35).filled(),
            )))
            .map_err(draw_err)?
            .label("95 % prediction band")
            .legend(|(x, y)| {
                Rectangle::new([(x, y - 4), (x + 18, y + 4)], BAND.mix(0.35).filled())
            });
        }
        for (name, colour, pts) in [
            ("measured", MEASURED, measured),
            ("final simulation", FINAL, simulated),
        ] {
            ch.draw_series(LineSeries::new(
                pts,
                ShapeStyle::from(&colour).stroke_width(1),
            ))
            .map_err(draw_err)?
            .label(name)
            .legend(move |(x, y)| {
                PathElement::new(
                    vec![(x, y), (x + 18, y)],
                    ShapeStyle::from(&colour).stroke_width(2),
                )
            });
        }
        legend(&mut ch)?;
        root.present().map_err(draw_err)?;
    }
    Ok(buf)
}
