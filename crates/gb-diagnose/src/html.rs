//! The diagnosis as one self-contained HTML page: inline SVG plots (plotters'
//! SVG backend, no fonts needed, no JavaScript, no network). A pure
//! renderer: everything it draws was computed by the diagnosis (the
//! residuals of every accepted model, the evidence, the models' views).
//!
//! What the page shows, in the order an engineer reads it (MATLAB's
//! `compare` and `resid` are the models):
//! 1. measured vs simulated output (baseline and final), full record and a zoom;
//!    For a physics model (the engineer's model file): its parameter table
//!    (estimates, standard errors, 95 % intervals, warnings, correlated
//!    pairs) and the final model's 95 % prediction band ([`physics`]);
//! 2. residuals vs time, residual auto-correlation and input
//!    cross-correlation with 95 % bands, the higher-order correlation tests
//!    r_{u²'e}, r_{u²'e²} (Billings & Voon 1986);
//! 3. one evidence plot per accepted cause, drawn from the data its
//!    extension provides ([`Extension::evidence_view`](crate::Extension::evidence_view));
//! 4. the extension: what each model class shows of itself
//!    ([`DynamicModel::views`](gb_core::DynamicModel::views): LOLIMOT
//!    partition, Preisach density, wavelet term);
//! 5. the gain table with bootstrap intervals and the model summary.
use crate::curves::{range, thin};
use crate::report::{Report, Step};
use crate::{introducing, stats, DiagnoseData, DiagnoseError, Diagnosis};
use gb_core::{ModelView, ViewData};
use plotters::prelude::*;
use std::fmt::Write as _;

mod physics;

const W: u32 = 860;
const H: u32 = 320;
const BAND_LAGS: usize = 40;

fn draw_err<E: std::fmt::Debug>(e: E) -> DiagnoseError {
    DiagnoseError::Report(format!("plot: {e:?}"))
}

/// Compact tick label.
fn tick(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e4).contains(&a) {
        format!("{v:.1e}")
    } else if a >= 100.0 {
        format!("{v:.0}")
    } else if a >= 1.0 {
        format!("{v:.2}")
    } else {
        format!("{v:.3}")
    }
}

/// 0 for a tick that is zero up to rounding relative to the axis span.
fn snap(v: f64, span: f64) -> f64 {
    if v.abs() < 1e-9 * span.abs() {
        0.0
    } else {
        v
    }
}

#[derive(Clone, Copy)]
enum Kind {
    Line,
    Points,
    /// Vertical stems from 0 (correlation functions).
    Stems,
}

struct Series {
    name: String,
    color: RGBColor,
    kind: Kind,
    points: Vec<(f64, f64)>,
}

impl Series {
    fn new(name: &str, color: RGBColor, kind: Kind, points: Vec<(f64, f64)>) -> Self {
        Self {
            name: name.to_string(),
            color,
            kind,
            points,
        }
    }
}

const MEASURED: RGBColor = RGBColor(40, 40, 40);
const BASE: RGBColor = RGBColor(214, 96, 77);
const FINAL: RGBColor = RGBColor(33, 102, 172);
const BAND: RGBColor = RGBColor(120, 120, 120);

type Chart<'a, 'b> = ChartContext<
    'a,
    SVGBackend<'b>,
    Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
>;

/// White background, caption and axes areas of every plot.
fn frame<'a, 'b>(
    root: &'a DrawingArea<SVGBackend<'b>, plotters::coord::Shift>,
    title: &str,
    x: std::ops::Range<f64>,
    y: std::ops::Range<f64>,
) -> Result<Chart<'a, 'b>, DiagnoseError> {
    root.fill(&WHITE).map_err(draw_err)?;
    ChartBuilder::on(root)
        .caption(title, ("sans-serif", 16))
        .margin(10)
        .x_label_area_size(38)
        .y_label_area_size(64)
        .build_cartesian_2d(x, y)
        .map_err(draw_err)
}

/// The series legend of every plot: upper right, on a translucent box.
fn legend<'a, 'b: 'a>(ch: &mut Chart<'a, 'b>) -> Result<(), DiagnoseError> {
    ch.configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(RGBColor(180, 180, 180))
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(draw_err)
}

/// A 2-D chart of line/point/stem series with optional horizontal lines
/// (confidence bands), as an SVG string.
fn chart(
    title: &str,
    xlabel: &str,
    ylabel: &str,
    series: &[Series],
    hlines: &[f64],
    log_y: bool,
) -> Result<String, DiagnoseError> {
    let tr = |v: f64| if log_y { v.max(1e-300).log10() } else { v };
    let (x0, x1) = range(series.iter().flat_map(|s| s.points.iter().map(|p| p.0)));
    let (y0, y1) = range(
        series
            .iter()
            .flat_map(|s| s.points.iter().map(move |p| tr(p.1)))
            .chain(hlines.iter().copied())
            .chain(
                series
                    .iter()
                    .filter(|s| matches!(s.kind, Kind::Stems))
                    .map(|_| 0.0),
            ),
    );
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, (W, H)).into_drawing_area();
        let mut ch = frame(&root, title, x0..x1, y0..y1)?;
        let ylab = if log_y {
            format!("log10 {ylabel}")
        } else {
            ylabel.to_string()
        };
        ch.configure_mesh()
            .x_desc(xlabel)
            .y_desc(ylab)
            .x_labels(8)
            .y_labels(6)
            .x_label_formatter(&|v| tick(snap(*v, x1 - x0)))
            .y_label_formatter(&|v| tick(snap(*v, y1 - y0)))
            .light_line_style(RGBColor(238, 238, 238))
            .draw()
            .map_err(draw_err)?;
        for &h in hlines {
            ch.draw_series(LineSeries::new(
                [(x0, h), (x1, h)],
                ShapeStyle::from(&BAND).stroke_width(1),
            ))
            .map_err(draw_err)?;
        }
        for s in series {
            let c = s.color;
            let pts: Vec<(f64, f64)> = s.points.iter().map(|&(x, y)| (x, tr(y))).collect();
            let anno = match s.kind {
                Kind::Line => ch
                    .draw_series(LineSeries::new(pts, ShapeStyle::from(&c).stroke_width(1)))
                    .map_err(draw_err)?,
                Kind::Points => ch
                    .draw_series(
                        pts.into_iter()
                            .map(|p| Circle::new(p, 2, c.mix(0.6).filled())),
                    )
                    .map_err(draw_err)?,
                Kind::Stems => ch
                    .draw_series(pts.into_iter().map(|(x, y)| {
                        PathElement::new(
                            vec![(x, 0.0), (x, y)],
                            ShapeStyle::from(&c).stroke_width(2),
                        )
                    }))
                    .map_err(draw_err)?,
            };
            if !s.name.is_empty() {
                anno.label(s.name.clone()).legend(move |(x, y)| {
                    PathElement::new(
                        vec![(x, y), (x + 18, y)],
                        ShapeStyle::from(&c).stroke_width(2),
                    )
                });
            }
        }
        if series.iter().any(|s| !s.name.is_empty()) {
            legend(&mut ch)?;
        }
        root.present().map_err(draw_err)?;
    }
    Ok(buf)
}

/// Rectangles `(x0, y0, x1, y1, value)` coloured on a diverging scale
/// (blue < 0 < red), or outlined when `outline` is set.
fn rect_chart(
    title: &str,
    xlabel: &str,
    ylabel: &str,
    rects: &[(f64, f64, f64, f64, f64)],
    outline: bool,
) -> Result<String, DiagnoseError> {
    let (x0, x1) = range(rects.iter().flat_map(|r| [r.0, r.2]));
    let (y0, y1) = range(rects.iter().flat_map(|r| [r.1, r.3]));
    let vmax = rects
        .iter()
        .map(|r| r.4.abs())
        .fold(0.0f64, f64::max)
        .max(1e-300);
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, (W, 420)).into_drawing_area();
        let mut ch = frame(&root, title, x0..x1, y0..y1)?;
        ch.configure_mesh()
            .x_desc(xlabel)
            .y_desc(ylabel)
            .x_label_formatter(&|v| tick(snap(*v, x1 - x0)))
            .y_label_formatter(&|v| tick(snap(*v, y1 - y0)))
            .disable_mesh()
            .draw()
            .map_err(draw_err)?;
        ch.draw_series(rects.iter().map(|&(a, b, c, d, v)| {
            let style = if outline {
                ShapeStyle::from(&FINAL).stroke_width(2)
            } else {
                diverging(v / vmax).filled()
            };
            Rectangle::new([(a, b), (c, d)], style)
        }))
        .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    Ok(buf)
}

/// Blue–white–red colour for t ∈ [−1, 1].
fn diverging(t: f64) -> RGBColor {
    let t = t.clamp(-1.0, 1.0);
    let mix = |a: u8, b: u8, s: f64| (a as f64 + (b as f64 - a as f64) * s).round() as u8;
    if t >= 0.0 {
        RGBColor(mix(255, 178, t), mix(255, 24, t), mix(255, 43, t))
    } else {
        RGBColor(mix(255, 33, -t), mix(255, 102, -t), mix(255, 172, -t))
    }
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

fn figure(out: &mut String, id: &str, caption: &str, svg: &str) {
    let _ = writeln!(
        out,
        "<figure id=\"{id}\" class=\"plot\">{svg}<figcaption>{}</figcaption></figure>",
        esc(caption)
    );
}

const STYLE: &str = "body{font-family:sans-serif;max-width:900px;margin:2em auto;color:#222}\
h1{font-size:1.5em}h2{font-size:1.2em;border-bottom:1px solid #ccc;margin-top:2em}\
table{border-collapse:collapse;font-size:.85em}td,th{border:1px solid #ccc;padding:3px 6px}\
tr.yes{background:#e8f4e8}figure{margin:1em 0}figcaption{font-size:.85em;color:#555}\
.lead{font-size:1.1em}footer{margin-top:3em;font-size:.8em;color:#888}";

/// Colours of the series of a view, in order.
const PALETTE: [RGBColor; 4] = [BASE, RGBColor(103, 0, 31), FINAL, RGBColor(5, 48, 97)];

/// Every model view the page shows, with its figure id and a note: the
/// final model's views, then those of earlier models in the chain whose
/// keys the final model lacks (e.g. the partition of the input–output
/// model a hidden-state model replaced).
fn model_views(dg: &Diagnosis) -> Vec<(String, ModelView, &'static str)> {
    let mut out: Vec<(String, ModelView, &'static str)> = vec![];
    let last = dg.chain.len().saturating_sub(1);
    for (i, e) in dg.chain.iter().enumerate().rev() {
        let m = &e.model;
        for v in m.dynamics.views(&m.input_names, &m.output_names) {
            if out.iter().any(|(_, w, _)| w.key == v.key) {
                continue;
            }
            let note = if i == last {
                ""
            } else {
                " (of an earlier model in the chain)"
            };
            out.push((format!("plot-{}", v.key), v, note));
        }
    }
    out
}

/// Ids of the plots that [`render_html`] writes for a diagnosis, in page
/// order: every id is the `id` of a `<figure>` holding one inline `<svg>`.
pub fn plot_ids(d: &Diagnosis) -> Vec<String> {
    let mut v: Vec<String> = ["compare", "compare-zoom", "residual-time", "acf"]
        .iter()
        .map(|s| format!("plot-{s}"))
        .collect();
    if physics::has_band_plot(d) {
        v.insert(2, physics::BANDS_ID.to_string());
        v.insert(3, physics::BANDS_ZOOM_ID.to_string());
    }
    for j in 0..d.model.input_names.len() {
        v.push(format!("plot-ccf-{j}"));
        v.push(format!("plot-hoc-{j}"));
    }
    for (i, s) in accepted(&d.report.steps).enumerate() {
        if step_extension(s).is_some() {
            v.push(format!("plot-evidence-{}-{}", i + 1, s.cause));
        }
    }
    // table views are HTML tables, not figures
    v.extend(
        model_views(d)
            .into_iter()
            .filter(|(_, view, _)| !matches!(view.data, ViewData::Table { .. }))
            .map(|(id, _, _)| id),
    );
    v
}

fn accepted(steps: &[Step]) -> impl Iterator<Item = &Step> {
    steps.iter().filter(|s| s.accepted)
}

/// A view as SVG (tables are drawn by [`view_table`]).
fn view_svg(v: &ModelView) -> Result<Option<String>, DiagnoseError> {
    Ok(match &v.data {
        ViewData::Cells {
            x_label,
            y_label,
            cells,
            outline,
        } => {
            let rects: Vec<(f64, f64, f64, f64, f64)> = cells
                .iter()
                .map(|c| (c[0], c[1], c[2], c[3], c[4]))
                .collect();
            Some(rect_chart(&v.title, x_label, y_label, &rects, *outline)?)
        }
        ViewData::Curves {
            x_label,
            y_label,
            series,
            log_y,
        } => {
            let s: Vec<Series> = series
                .iter()
                .enumerate()
                .map(|(i, s)| {
                    let kind = if s.markers { Kind::Points } else { Kind::Line };
                    let colour = if series.len() == 2 && i == 1 && !s.markers && series[0].markers {
                        MEASURED
                    } else {
                        PALETTE[i % PALETTE.len()]
                    };
                    Series::new(&s.name, colour, kind, s.points.clone())
                })
                .collect();
            Some(chart(&v.title, x_label, y_label, &s, &[], *log_y)?)
        }
        _ => None,
    })
}

/// A table view as HTML.
fn view_table(v: &ModelView) -> Option<String> {
    let ViewData::Table { header, rows } = &v.data else {
        return None;
    };
    let mut s = format!("<h3>{}</h3>\n<table>\n<tr>", esc(&v.title));
    for h in header {
        let _ = write!(s, "<th>{}</th>", esc(h));
    }
    s.push_str("</tr>\n");
    for r in rows {
        s.push_str("<tr>");
        for c in r {
            let _ = write!(s, "<td>{}</td>", esc(c));
        }
        s.push_str("</tr>\n");
    }
    s.push_str("</table>\n");
    Some(s)
}

/// Title, verdict and the gain table.
fn summary_section(body: &mut String, r: &Report, title: &str) {
    let causes = if r.causes.is_empty() {
        format!("none: {}", r.no_cause_reason())
    } else {
        r.cause_names().join(", ")
    };
    let _ = write!(
        body,
        "<h1>{}</h1>\n<p class=\"lead\">Causes: <b>{}</b>. Validation NRMSE (free-run simulation) \
         {:.4} &rarr; {:.4}.</p>\n<p class=\"verdict\">Verdict: {}.</p>\n<p>Data: inputs {} &rarr; output {}; {} fit / {} select / {} \
         report samples; {}.</p>\n<p>Decisions: {}.</p>\n",
        esc(title),
        esc(&causes),
        r.baseline.nrmse,
        r.final_model.nrmse,
        esc(&r.verdict.text),
        esc(&r.data.inputs.join(", ")),
        esc(&r.data.output),
        r.data.samples_fit,
        r.data.samples_select,
        r.data.samples_validate,
        esc(&r.data.split),
        esc(&r.data.decision)
    );
    body.push_str("<h2>Steps and gains</h2>\n<table>\n<tr><th>step</th><th>cause</th><th>extension</th><th>NRMSE before</th><th>NRMSE after</th><th>gain</th><th>select gain [95 % CI]</th><th>nll before</th><th>nll after</th><th>accepted</th></tr>\n");
    let _ = writeln!(
        body,
        "<tr><td>0</td><td>baseline</td><td>{}</td><td></td><td>{:.4}</td><td></td><td></td><td></td><td>{:.3}</td><td></td></tr>",
        esc(&r.baseline.model),
        r.baseline.nrmse,
        r.baseline.nll
    );
    for s in &r.steps {
        let gain = if s.gain_metric == "nll" {
            format!("{:+.3} nats", s.gain)
        } else {
            format!("{:+.1} %", 100.0 * s.gain)
        };
        let yes = if s.accepted { "yes" } else { "no" };
        let _ = writeln!(
            body,
            "<tr class=\"{yes}\"><td>{}</td><td>{}</td><td>{}</td><td>{:.4}</td><td>{:.4}</td><td>{}</td><td>{:+.3} [{:+.3}, {:+.3}]</td><td>{:.3}</td><td>{:.3}</td><td>{yes}</td></tr>",
            s.iteration,
            s.cause,
            esc(&s.extension),
            s.nrmse_before,
            s.nrmse_after,
            gain,
            s.gain_select,
            s.gain_ci[0],
            s.gain_ci[1],
            s.nll_before,
            s.nll_after,
        );
    }
    body.push_str("</table>\n");
    let _ = writeln!(
        body,
        "<p class=\"model\">Final model: <code>{}</code> ({} parameters, class <code>{}</code>, SPEC <code>{}</code>, order {}).</p>",
        esc(&r.final_model.model),
        r.final_model.parameters,
        esc(&r.final_model.class),
        esc(&r.final_model.spec),
        r.final_model.order
    );
}

/// The report block's time axis, measured output and inputs.
struct Signals<'a> {
    t: Vec<f64>,
    y: &'a [f64],
    u: Vec<&'a [f64]>,
    start: usize,
}

impl<'a> Signals<'a> {
    fn of(dg: &Diagnosis, d: &'a DiagnoseData) -> Self {
        let n = dg.chain.first().map_or(0, |e| e.report.e.len());
        let end = d.report_range.end;
        let start = end - n.min(end);
        Self {
            t: (start..end).map(|k| k as f64).collect(),
            y: &d.report.output[start..end],
            u: d.report.inputs.iter().map(|u| &u[start..end]).collect(),
            start,
        }
    }
}

/// Measured vs simulated, whole record and a zoom.
fn compare_section(body: &mut String, dg: &Diagnosis, s: &Signals) -> Result<(), DiagnoseError> {
    let r = &dg.report;
    let (base, fin) = (&dg.chain[0].report, &dg.chain[dg.chain.len() - 1].report);
    let yname = &r.data.output;
    let (title, whole) = if r.data.report_in_sample {
        (
            "<h2>Measured vs simulated (the report block, free run; in-sample: the short record is cross-validated whole, the held-out figure is the decisions line's cross-validated NRMSE)</h2>\n",
            "Whole report block (thinned for display).",
        )
    } else {
        (
            "<h2>Measured vs simulated (validation data, free run)</h2>\n",
            "Whole validation record (thinned for display).",
        )
    };
    body.push_str(title);
    let t = &s.t;
    let svg = chart(
        "Measured and simulated output",
        "sample",
        yname,
        &[
            Series::new("measured", MEASURED, Kind::Line, thin(t, s.y, 2500)),
            Series::new(
                &format!("baseline (NRMSE {:.3})", r.baseline.nrmse),
                BASE,
                Kind::Line,
                thin(t, &base.yhat, 2500),
            ),
            Series::new(
                &format!("final (NRMSE {:.3})", r.final_model.nrmse),
                FINAL,
                Kind::Line,
                thin(t, &fin.yhat, 2500),
            ),
        ],
        &[],
        false,
    )?;
    figure(body, "plot-compare", whole, &svg);
    let zn = 400.min(t.len());
    let z0 = (t.len() - zn) / 2;
    let zw = z0..z0 + zn;
    let svg = chart(
        &format!("Zoom: samples {}..{}", s.start + z0, s.start + z0 + zn),
        "sample",
        yname,
        &[
            Series::new(
                "measured",
                MEASURED,
                Kind::Line,
                thin(&t[zw.clone()], &s.y[zw.clone()], zn),
            ),
            Series::new(
                "baseline",
                BASE,
                Kind::Line,
                thin(&t[zw.clone()], &base.yhat[zw.clone()], zn),
            ),
            Series::new(
                "final",
                FINAL,
                Kind::Line,
                thin(&t[zw.clone()], &fin.yhat[zw.clone()], zn),
            ),
        ],
        &[],
        false,
    )?;
    figure(
        body,
        "plot-compare-zoom",
        "A window at full resolution.",
        &svg,
    );
    Ok(())
}

/// Correlation values `v` at lags 0, 1, … shifted by `shift` (side by side
/// stems).
fn lagged(v: Vec<f64>, shift: f64) -> Vec<(f64, f64)> {
    v.into_iter()
        .enumerate()
        .map(|(k, c)| (k as f64 + shift, c))
        .collect()
}

/// Residual vs time, auto-correlation, and per input the cross-correlation
/// and higher-order tests.
fn residual_section(body: &mut String, dg: &Diagnosis, s: &Signals) -> Result<(), DiagnoseError> {
    let (base, fin) = (&dg.chain[0].report, &dg.chain[dg.chain.len() - 1].report);
    body.push_str("<h2>Residual analysis</h2>\n");
    let svg = chart(
        "Simulation residual e = y - y_sim",
        "sample",
        "residual",
        &[
            Series::new("baseline", BASE, Kind::Line, thin(&s.t, &base.e, 2500)),
            Series::new("final", FINAL, Kind::Line, thin(&s.t, &fin.e, 2500)),
        ],
        &[],
        false,
    )?;
    figure(body, "plot-residual-time", "Residual vs time.", &svg);
    let band = 1.96 / (base.e.len().max(1) as f64).sqrt();
    let acf_b = stats::autocorrelation(&base.e, BAND_LAGS);
    let acf_f = stats::autocorrelation(&fin.e, BAND_LAGS);
    let svg = chart(
        "Residual auto-correlation r_ee(tau)",
        "lag tau",
        "r_ee",
        &[
            Series::new(
                "baseline",
                BASE,
                Kind::Stems,
                lagged(acf_b[1..].to_vec(), 0.85),
            ),
            Series::new(
                "final",
                FINAL,
                Kind::Stems,
                lagged(acf_f[1..].to_vec(), 1.15),
            ),
        ],
        &[band, -band],
        false,
    )?;
    figure(
        body,
        "plot-acf",
        &format!("Lags 1..{BAND_LAGS}; grey lines: 95 % band ±1.96/sqrt(N) of a white residual. Bars outside the band: unmodelled dynamics or noise colour."),
        &svg,
    );
    for (j, uj) in s.u.iter().enumerate() {
        let name = dg
            .report
            .data
            .inputs
            .get(j)
            .cloned()
            .unwrap_or_else(|| format!("u{j}"));
        input_tests(body, j, &name, uj, &base.e, &fin.e, band)?;
    }
    Ok(())
}

/// Cross-correlation and Billings–Voon tests of one input.
fn input_tests(
    body: &mut String,
    j: usize,
    name: &str,
    uj: &[f64],
    eb: &[f64],
    ef: &[f64],
    band: f64,
) -> Result<(), DiagnoseError> {
    let svg = chart(
        &format!("Input-residual cross-correlation r_ue(tau), input {name}"),
        "lag tau",
        "r_ue",
        &[
            Series::new(
                "baseline",
                BASE,
                Kind::Stems,
                lagged(stats::cross_correlation(uj, eb, BAND_LAGS), -0.15),
            ),
            Series::new(
                "final",
                FINAL,
                Kind::Stems,
                lagged(stats::cross_correlation(uj, ef, BAND_LAGS), 0.15),
            ),
        ],
        &[band, -band],
        false,
    )?;
    figure(
        body,
        &format!("plot-ccf-{j}"),
        "Residual correlated with past input: the model misses input-driven behaviour.",
        &svg,
    );
    let m = gb_core::metrics::mean(uj);
    let u2: Vec<f64> = uj.iter().map(|v| (v - m) * (v - m)).collect();
    let sq = |e: &[f64]| -> Vec<f64> { e.iter().map(|v| v * v).collect() };
    let cc = |e: &[f64], shift| lagged(stats::cross_correlation(&u2, e, BAND_LAGS), shift);
    let svg = chart(
        &format!("Higher-order correlation tests, input {name}"),
        "lag tau",
        "correlation",
        &[
            Series::new("baseline r_u2'e", BASE, Kind::Stems, cc(eb, -0.3)),
            Series::new(
                "baseline r_u2'e2",
                RGBColor(244, 165, 130),
                Kind::Stems,
                cc(&sq(eb), -0.1),
            ),
            Series::new("final r_u2'e", FINAL, Kind::Stems, cc(ef, 0.1)),
            Series::new(
                "final r_u2'e2",
                RGBColor(146, 197, 222),
                Kind::Stems,
                cc(&sq(ef), 0.3),
            ),
        ],
        &[band, -band],
        false,
    )?;
    figure(
        body,
        &format!("plot-hoc-{j}"),
        "Billings-Voon tests: squared (mean-removed) input against residual and squared residual; outside the band = unmodelled nonlinearity.",
        &svg,
    );
    Ok(())
}

/// The extension whose evidence plot a step shows: the process-noise
/// extension for process noise found, else the one introducing its cause.
fn step_extension(s: &Step) -> Option<&'static dyn crate::Extension> {
    match &s.noise {
        Some(n) if n.kind == "process" => Some(&crate::extensions::ProcessNoise),
        _ => introducing(s.cause),
    }
}

/// One evidence plot per accepted cause, from the residuals before and
/// after its step.
fn evidence_section(body: &mut String, dg: &Diagnosis) -> Result<(), DiagnoseError> {
    let acc: Vec<&Step> = accepted(&dg.report.steps).collect();
    if !acc.is_empty() {
        body.push_str("<h2>Evidence for each named cause</h2>\n");
    }
    for (i, s) in acc.iter().enumerate() {
        let (Some(before), Some(after)) = (dg.chain.get(i), dg.chain.get(i + 1)) else {
            continue;
        };
        let Some(view) = step_extension(s)
            .and_then(|e| e.evidence_view(&before.report, &after.report, &dg.report.data.output))
        else {
            continue;
        };
        if let Some(svg) = view_svg(&view)? {
            let caption = format!("Step {}: {}. {}", s.iteration, s.cause, s.evidence);
            figure(
                body,
                &format!("plot-evidence-{}-{}", i + 1, s.cause),
                &caption,
                &svg,
            );
        }
    }
    Ok(())
}

/// The final model and what each model class shows of itself.
fn extension_section(body: &mut String, dg: &Diagnosis) -> Result<(), DiagnoseError> {
    body.push_str("<h2>The extension</h2>\n");
    let last = &dg.chain[dg.chain.len() - 1];
    let _ = writeln!(
        body,
        "<p>Final model (class <code>{}</code>): <b>{}</b>, {} parameters, order {} (baseline {}). Noise model: <b>{}</b>{}.</p>",
        esc(last.model.dynamics.class()),
        esc(&last.model.dynamics.describe()),
        last.model.dynamics.n_parameters(),
        last.lineage.order(),
        dg.chain[0].lineage.order(),
        esc(&last.model.noise.describe()),
        last.finding.as_ref().map_or(String::new(), |f| format!(
            " (of the simulation residual); {}",
            esc(&f.line())
        ))
    );
    for (id, v, note) in model_views(dg) {
        if let Some(t) = view_table(&v) {
            body.push_str(&t);
        } else if let Some(svg) = view_svg(&v)? {
            figure(body, &id, &format!("{}{note}", v.caption), &svg);
        }
    }
    Ok(())
}

/// Render the diagnosis `dg` of data `d` as a self-contained HTML page.
/// `d` must be the data the diagnosis was run on (it supplies the measured
/// signals; every simulation comes from `dg`).
pub fn render_html(dg: &Diagnosis, d: &DiagnoseData, title: &str) -> Result<String, DiagnoseError> {
    Ok(document(title, &body_of(dg, d, title)?, dg.report.version))
}

/// One HTML report of the diagnoses of several outputs (`(output name,
/// diagnosis, its data)`): a table of the outputs' causes and NRMSEs with
/// links, then each output's report (the sections of [`render_html`]) in
/// its own `<section>`, figure ids prefixed by the output's position.
pub fn render_html_outputs(
    parts: &[(&str, &Diagnosis, &DiagnoseData)],
    title: &str,
) -> Result<String, DiagnoseError> {
    let Some(first) = parts.first() else {
        return Err(DiagnoseError::Report("no outputs to report".into()));
    };
    let mut body = format!(
        "<h1>{}</h1>\n<table>\n<tr><th>output</th><th>causes</th><th>validation NRMSE before</th><th>after</th><th>verdict</th></tr>\n",
        esc(title)
    );
    for (o, (name, dg, _)) in parts.iter().enumerate() {
        let r = &dg.report;
        let causes = if r.causes.is_empty() {
            "none".to_string()
        } else {
            r.cause_names().join(", ")
        };
        let _ = writeln!(
            body,
            "<tr><td><a href=\"#output-{}\">{}</a></td><td>{}</td><td>{:.4}</td><td>{:.4}</td><td>{}</td></tr>",
            o + 1,
            esc(name),
            esc(&causes),
            r.baseline.nrmse,
            r.final_model.nrmse,
            esc(&r.verdict.text)
        );
    }
    body.push_str("</table>\n");
    for (o, (name, dg, d)) in parts.iter().enumerate() {
        let inner = body_of(dg, d, &format!("output {name}"))?
            .replace("id=\"", &format!("id=\"o{}-", o + 1));
        let _ = write!(
            body,
            "<section id=\"output-{}\">\n{inner}</section>\n",
            o + 1
        );
    }
    Ok(document(title, &body, first.1.report.version))
}

/// The sections of one diagnosis' report.
fn body_of(dg: &Diagnosis, d: &DiagnoseData, title: &str) -> Result<String, DiagnoseError> {
    if dg.chain.is_empty() {
        return Err(DiagnoseError::Report("a diagnosis without models".into()));
    }
    let s = Signals::of(dg, d);
    let mut body = String::new();
    summary_section(&mut body, &dg.report, title);
    compare_section(&mut body, dg, &s)?;
    physics::physics_section(&mut body, dg, d, &s)?;
    residual_section(&mut body, dg, &s)?;
    evidence_section(&mut body, dg)?;
    extension_section(&mut body, dg)?;
    Ok(body)
}

/// A standalone HTML document around `body`.
fn document(title: &str, body: &str, version: u32) -> String {
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n{body}<footer>greybox {} report format {}</footer>\n</body>\n</html>\n",
        esc(title),
        env!("CARGO_PKG_VERSION"),
        version
    )
}
