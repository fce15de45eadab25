//! The diagnosis as one self-contained HTML page: inline SVG plots (plotters'
//! SVG backend, no fonts needed, no JavaScript, no network).
//!
//! What the page shows, in the order an engineer reads it (MATLAB's
//! `compare` and `resid` are the models):
//! 1. measured vs simulated output (baseline and final), full record and a zoom;
//! 2. residuals vs time, residual auto-correlation and input
//!    cross-correlation with 95 % bands, the higher-order tests
//!    r_{u²'e}, r_{u²'e²} (Billings & Voon 1986);
//! 3. one evidence plot per accepted cause: residual-vs-input loops
//!    (`hysteresis`), residual vs simulated output (`nonlinearity`),
//!    residual spectrum (`dynamics`), normal Q–Q plot (`noise`);
//! 4. the extension: chosen order, LOLIMOT partition, identified Preisach
//!    relay weights as a heat map on the (β, α) half-plane;
//! 5. the gain table with bootstrap intervals and the model summary.
use crate::diagnose::{residuals_on, DiagnoseData, Diagnosis, Step};
use crate::{stats, DiagnoseError, GreyBoxModel};
use plotters::prelude::*;
use std::fmt::Write as _;

const W: u32 = 860;
const H: u32 = 320;
const BAND_LAGS: usize = 40;

/// Ids of the plots that [`render_html`] writes for a diagnosis, in page
/// order: every id is the `id` of a `<figure>` holding one inline `<svg>`.
pub fn plot_ids(d: &Diagnosis) -> Vec<String> {
    let mut v: Vec<String> = ["compare", "compare-zoom", "residual-time", "acf"]
        .iter()
        .map(|s| format!("plot-{s}"))
        .collect();
    for j in 0..d.model.network.input_scaling.len() {
        v.push(format!("plot-ccf-{j}"));
        v.push(format!("plot-hoc-{j}"));
    }
    for (i, s) in accepted(&d.report.steps).enumerate() {
        v.push(format!("plot-evidence-{}-{}", i + 1, s.cause));
    }
    if network_model(d).is_some() {
        v.push("plot-partition".into());
    }
    if preisach_model(d).is_some() {
        v.push("plot-preisach".into());
    }
    if state_space_term(&d.model).is_some() {
        v.push("plot-state-space".into());
    }
    v
}

/// The last model of the chain with a local model network (the final one,
/// or the one a hidden-state model replaced).
fn network_model(d: &Diagnosis) -> Option<&GreyBoxModel> {
    d.chain
        .iter()
        .chain(std::iter::once(&d.model))
        .rev()
        .find(|m| m.state_space.is_none() && m.network.leaves.len() > 1)
}

/// The last model of the chain with a Preisach component on the output.
fn preisach_model(d: &Diagnosis) -> Option<&GreyBoxModel> {
    d.chain
        .iter()
        .chain(std::iter::once(&d.model))
        .rev()
        .find(|m| m.state_space.is_none() && m.network.spec.output_relays > 0)
}

/// The first 2-D wavelet term of a hidden-state model (what its plot shows).
fn state_space_term(m: &GreyBoxModel) -> Option<&gb_model::NonlinearTerm> {
    m.state_space
        .as_ref()?
        .terms
        .iter()
        .find(|t| t.args.len() == 2 && t.expansion.nnz() > 0)
}

fn accepted(steps: &[Step]) -> impl Iterator<Item = &Step> {
    steps.iter().filter(|s| s.accepted)
}

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

/// Points (x, y) of one curve.
type Curve = Vec<(f64, f64)>;

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

fn range(points: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in points.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (-1.0, 1.0);
    }
    let pad = if hi > lo {
        0.05 * (hi - lo)
    } else {
        0.5 * lo.abs().max(1e-12)
    };
    (lo - pad, hi + pad)
}

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
            ch.configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(RGBColor(180, 180, 180))
                .position(SeriesLabelPosition::UpperRight)
                .draw()
                .map_err(draw_err)?;
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

/// Every `stride`-th point of `(x, y)` pairs so that at most `max` remain.
fn thin(x: &[f64], y: &[f64], max: usize) -> Vec<(f64, f64)> {
    let n = x.len().min(y.len());
    let stride = n.div_ceil(max.max(1)).max(1);
    (0..n).step_by(stride).map(|k| (x[k], y[k])).collect()
}

/// Periodogram |Σ e_k e^{−iωk}|²/N at `m` frequencies ω ∈ (0, π] (Goertzel
/// recursion per frequency, no allocation beyond the output).
fn periodogram(e: &[f64], m: usize) -> Vec<(f64, f64)> {
    let n = e.len().max(1) as f64;
    (1..=m)
        .map(|i| {
            let f = 0.5 * i as f64 / m as f64;
            let w = 2.0 * std::f64::consts::PI * f;
            let c = 2.0 * w.cos();
            let (mut s1, mut s2) = (0.0, 0.0);
            for &v in e {
                let s0 = v + c * s1 - s2;
                s2 = s1;
                s1 = s0;
            }
            let p = s1 * s1 + s2 * s2 - c * s1 * s2;
            (f, p / n)
        })
        .collect()
}

/// Smoothed periodogram: moving average over `half` neighbours on each side.
fn smooth(p: &[(f64, f64)], half: usize) -> Vec<(f64, f64)> {
    (0..p.len())
        .map(|i| {
            let a = i.saturating_sub(half);
            let b = (i + half + 1).min(p.len());
            let m = p[a..b].iter().map(|v| v.1).sum::<f64>() / (b - a) as f64;
            (p[i].0, m)
        })
        .collect()
}

/// Standard normal quantile Φ⁻¹(p) (Acklam's rational approximation,
/// relative error < 1.2e-9).
pub fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.383_577_518_672_69e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e1,
        1.615858368580409e2,
        -1.556989798598866e2,
        6.680131188771972e1,
        -1.328068155288572e1,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    const D: [f64; 4] = [
        7.784695709041462e-3,
        3.224671290700398e-1,
        2.445134137142996,
        3.754408661907416,
    ];
    let p = p.clamp(1e-300, 1.0 - 1e-16);
    let pl = 0.02425;
    if p < pl {
        let q = (-2.0 * p.ln()).sqrt();
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    } else if p <= 1.0 - pl {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    } else {
        let q = (-2.0 * (1.0 - p).ln()).sqrt();
        -(((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    }
}

/// Simulation of one model on the report block.
struct Sim {
    e: Vec<f64>,
    yhat: Vec<f64>,
}

fn sim(m: &GreyBoxModel, d: &DiagnoseData) -> Result<Sim, DiagnoseError> {
    let (e, yhat) = residuals_on(m, &d.report, &d.report_range)?;
    Ok(Sim { e, yhat })
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

/// Render the diagnosis `dg` of data `d` as a self-contained HTML page.
///
/// The models of `dg.chain` are simulated (free run, the same init window as
/// the report) on the report block of `d`; `d` must be the data the
/// diagnosis was run on.
pub fn render_html(dg: &Diagnosis, d: &DiagnoseData, title: &str) -> Result<String, DiagnoseError> {
    let r = &dg.report;
    let base_model = dg.chain.first().unwrap_or(&dg.model);
    let base = sim(base_model, d)?;
    let fin = sim(&dg.model, d)?;
    let start = d.report_range.start.max(crate::EVAL_SKIP);
    let end = d.report_range.end;
    let t: Vec<f64> = (start..end).map(|k| k as f64).collect();
    let y = &d.report.output[start..end];
    let u: Vec<&[f64]> = d.report.inputs.iter().map(|u| &u[start..end]).collect();
    let yname = &r.data.output;

    let mut body = String::new();
    // --- header and summary
    let causes = if r.causes.is_empty() {
        "none: the model is adequate (no extension pays on held-out data)".to_string()
    } else {
        r.causes.join(", ")
    };
    let _ = write!(
        body,
        "<h1>{}</h1>\n<p class=\"lead\">Causes: <b>{}</b>. Validation NRMSE (free-run simulation) \
         {:.4} &rarr; {:.4}.</p>\n<p>Data: inputs {} &rarr; output {}; {} fit / {} select / {} \
         report samples; {}.</p>\n",
        esc(title),
        esc(&causes),
        r.baseline.nrmse,
        r.final_model.nrmse,
        esc(&r.data.inputs.join(", ")),
        esc(yname),
        r.data.samples_fit,
        r.data.samples_select,
        r.data.samples_validate,
        esc(&r.data.split)
    );
    // --- gain table
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
        let _ = writeln!(
            body,
            "<tr class=\"{}\"><td>{}</td><td>{}</td><td>{}</td><td>{:.4}</td><td>{:.4}</td><td>{}</td><td>{:+.3} [{:+.3}, {:+.3}]</td><td>{:.3}</td><td>{:.3}</td><td>{}</td></tr>",
            if s.accepted { "yes" } else { "no" },
            s.iteration,
            esc(&s.cause),
            esc(&s.extension),
            s.nrmse_before,
            s.nrmse_after,
            gain,
            s.gain_select,
            s.gain_ci[0],
            s.gain_ci[1],
            s.nll_before,
            s.nll_after,
            if s.accepted { "yes" } else { "no" }
        );
    }
    body.push_str("</table>\n");
    let _ = writeln!(
        body,
        "<p class=\"model\">Final model: <code>{}</code> ({} parameters, SPEC <code>{}</code>, order {}).</p>",
        esc(&r.final_model.model),
        r.final_model.parameters,
        esc(&r.final_model.spec),
        r.final_model.order
    );

    // --- compare
    body.push_str("<h2>Measured vs simulated (validation data, free run)</h2>\n");
    let svg = chart(
        "Measured and simulated output",
        "sample",
        yname,
        &[
            Series::new("measured", MEASURED, Kind::Line, thin(&t, y, 2500)),
            Series::new(
                &format!("baseline (NRMSE {:.3})", r.baseline.nrmse),
                BASE,
                Kind::Line,
                thin(&t, &base.yhat, 2500),
            ),
            Series::new(
                &format!("final (NRMSE {:.3})", r.final_model.nrmse),
                FINAL,
                Kind::Line,
                thin(&t, &fin.yhat, 2500),
            ),
        ],
        &[],
        false,
    )?;
    figure(
        &mut body,
        "plot-compare",
        "Whole validation record (thinned for display).",
        &svg,
    );
    let zn = 400.min(t.len());
    let z0 = (t.len() - zn) / 2;
    let zw = z0..z0 + zn;
    let svg = chart(
        &format!("Zoom: samples {}..{}", start + z0, start + z0 + zn),
        "sample",
        yname,
        &[
            Series::new(
                "measured",
                MEASURED,
                Kind::Line,
                thin(&t[zw.clone()], &y[zw.clone()], zn),
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
        &mut body,
        "plot-compare-zoom",
        "A window at full resolution.",
        &svg,
    );

    // --- residual analysis
    body.push_str("<h2>Residual analysis</h2>\n");
    let svg = chart(
        "Simulation residual e = y - y_sim",
        "sample",
        "residual",
        &[
            Series::new("baseline", BASE, Kind::Line, thin(&t, &base.e, 2500)),
            Series::new("final", FINAL, Kind::Line, thin(&t, &fin.e, 2500)),
        ],
        &[],
        false,
    )?;
    figure(&mut body, "plot-residual-time", "Residual vs time.", &svg);
    let n = base.e.len().max(1) as f64;
    let band = 1.96 / n.sqrt();
    let lagged = |v: Vec<f64>, shift: f64| -> Vec<(f64, f64)> {
        v.into_iter()
            .enumerate()
            .map(|(k, c)| (k as f64 + shift, c))
            .collect()
    };
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
        &mut body,
        "plot-acf",
        &format!("Lags 1..{BAND_LAGS}; grey lines: 95 % band ±1.96/sqrt(N) of a white residual. Bars outside the band: unmodelled dynamics or noise colour."),
        &svg,
    );
    for (j, uj) in u.iter().enumerate() {
        let name = r
            .data
            .inputs
            .get(j)
            .cloned()
            .unwrap_or_else(|| format!("u{j}"));
        let cb = stats::cross_correlation(uj, &base.e, BAND_LAGS);
        let cf = stats::cross_correlation(uj, &fin.e, BAND_LAGS);
        let svg = chart(
            &format!("Input-residual cross-correlation r_ue(tau), input {name}"),
            "lag tau",
            "r_ue",
            &[
                Series::new("baseline", BASE, Kind::Stems, lagged(cb, -0.15)),
                Series::new("final", FINAL, Kind::Stems, lagged(cf, 0.15)),
            ],
            &[band, -band],
            false,
        )?;
        figure(
            &mut body,
            &format!("plot-ccf-{j}"),
            "Residual correlated with past input: the model misses input-driven behaviour.",
            &svg,
        );
        let m = gb_core::metrics::mean(uj);
        let u2: Vec<f64> = uj.iter().map(|v| (v - m) * (v - m)).collect();
        let e2: Vec<f64> = fin.e.iter().map(|v| v * v).collect();
        let eb2: Vec<f64> = base.e.iter().map(|v| v * v).collect();
        let svg = chart(
            &format!("Higher-order correlation tests, input {name}"),
            "lag tau",
            "correlation",
            &[
                Series::new(
                    "baseline r_u2'e",
                    BASE,
                    Kind::Stems,
                    lagged(stats::cross_correlation(&u2, &base.e, BAND_LAGS), -0.3),
                ),
                Series::new(
                    "baseline r_u2'e2",
                    RGBColor(244, 165, 130),
                    Kind::Stems,
                    lagged(stats::cross_correlation(&u2, &eb2, BAND_LAGS), -0.1),
                ),
                Series::new(
                    "final r_u2'e",
                    FINAL,
                    Kind::Stems,
                    lagged(stats::cross_correlation(&u2, &fin.e, BAND_LAGS), 0.1),
                ),
                Series::new(
                    "final r_u2'e2",
                    RGBColor(146, 197, 222),
                    Kind::Stems,
                    lagged(stats::cross_correlation(&u2, &e2, BAND_LAGS), 0.3),
                ),
            ],
            &[band, -band],
            false,
        )?;
        figure(
            &mut body,
            &format!("plot-hoc-{j}"),
            "Billings-Voon tests: squared (mean-removed) input against residual and squared residual; outside the band = unmodelled nonlinearity.",
            &svg,
        );
    }

    // --- evidence per accepted cause
    let acc: Vec<&Step> = accepted(&r.steps).collect();
    if !acc.is_empty() {
        body.push_str("<h2>Evidence for each named cause</h2>\n");
    }
    for (i, s) in acc.iter().enumerate() {
        let before_m = dg.chain.get(i).unwrap_or(base_model);
        let after_m = dg.chain.get(i + 1).unwrap_or(&dg.model);
        let b = sim(before_m, d)?;
        let a = sim(after_m, d)?;
        let id = format!("plot-evidence-{}-{}", i + 1, s.cause);
        let caption = format!("Step {}: {}. {}", s.iteration, s.cause, s.evidence);
        let svg = match s.cause.as_str() {
            "hysteresis" => {
                let (up, down) = direction_means(&b.yhat, &b.e, 24);
                let (up_a, down_a) = direction_means(&a.yhat, &a.e, 24);
                chart(
                    "Mean residual vs simulated output, rising vs falling: two branches = a loop = hysteresis",
                    &format!("simulated {yname}"),
                    "mean residual",
                    &[
                        Series::new("before, rising", BASE, Kind::Line, up),
                        Series::new("before, falling", RGBColor(103, 0, 31), Kind::Line, down),
                        Series::new("after, rising", FINAL, Kind::Line, up_a),
                        Series::new("after, falling", RGBColor(5, 48, 97), Kind::Line, down_a),
                    ],
                    &[0.0],
                    false,
                )?
            }
            "nonlinearity" => chart(
                "Residual vs simulated output: a systematic curve is a static nonlinearity",
                &format!("simulated {yname}"),
                "residual",
                &[
                    Series::new("before", BASE, Kind::Points, thin(&b.yhat, &b.e, 1500)),
                    Series::new("after", FINAL, Kind::Points, thin(&a.yhat, &a.e, 1500)),
                    Series::new(
                        "before, binned mean",
                        RGBColor(103, 0, 31),
                        Kind::Line,
                        binned_mean(&b.yhat, &b.e, 30),
                    ),
                ],
                &[],
                false,
            )?,
            "dynamics" => chart(
                "Residual spectrum (smoothed periodogram): peaks are unmodelled modes",
                "frequency [cycles/sample]",
                "power",
                &[
                    Series::new(
                        "before",
                        BASE,
                        Kind::Line,
                        smooth(&periodogram(&b.e, 400), 3),
                    ),
                    Series::new(
                        "after",
                        FINAL,
                        Kind::Line,
                        smooth(&periodogram(&a.e, 400), 3),
                    ),
                ],
                &[],
                true,
            )?,
            _ => {
                let (q, line) = qq(&b.e);
                chart(
                    "Normal Q-Q plot of the residual: bent tails are heavy-tailed noise",
                    "normal quantile",
                    "standardised residual",
                    &[
                        Series::new("residual", BASE, Kind::Points, q),
                        Series::new("normal", MEASURED, Kind::Line, line),
                    ],
                    &[],
                    false,
                )?
            }
        };
        figure(&mut body, &id, &caption, &svg);
    }

    // --- extension
    body.push_str("<h2>The extension</h2>\n");
    if dg.model.state_space.is_none() {
        let _ = writeln!(
            body,
            "<p>Chosen dynamic order: <b>{}</b> (baseline {}). Local models: <b>{}</b>. Hysteresis columns: <b>{}</b>. Noise model: <b>{}</b>.</p>",
            dg.model.structure.order,
            r.baseline.order,
            dg.model.network.leaves.len(),
            dg.model.network.spec.n_hysteresis(),
            esc(&dg.model.network.noise.describe())
        );
    }
    let replaced = if dg.model.state_space.is_some() {
        " (of the input–output model the hidden-state model replaced)"
    } else {
        ""
    };
    if let Some(m) = network_model(dg) {
        let svg = partition_plot(m, &r.data.inputs, yname)?;
        figure(
            &mut body,
            "plot-partition",
            &format!("LOLIMOT partition{replaced}: the local models' cells projected on the two most-split partition variables (unit-scaled)."),
            &svg,
        );
    }
    if let Some(m) = preisach_model(dg) {
        let svg = preisach_plot(m, yname)?;
        figure(
            &mut body,
            "plot-preisach",
            &format!("Identified Preisach relay weights{replaced} (discrete density, summed over lags) on the (beta, alpha) half-plane of the simulated output; red positive, blue negative."),
            &svg,
        );
    }

    if let Some(ss) = &dg.model.state_space {
        let _ = writeln!(
            body,
            "<p>Hidden-state model (gb-model, the thesis' wavelet-sparse state space): <b>{}</b>, {} parameters.</p>",
            esc(&ss.describe()),
            ss.n_parameters()
        );
        if let Some(t) = state_space_term(&dg.model) {
            let svg = state_space_plot(t, &dg.model.input_names)?;
            let target = match t.target {
                gb_model::Target::State(i) => format!("state row x{}", i + 1),
                gb_model::Target::Output => "the output".into(),
            };
            figure(
                &mut body,
                "plot-state-space",
                &format!(
                    "Identified sparse wavelet term added to {target}, over its box ({} non-zero coefficients); red positive, blue negative.",
                    t.expansion.nnz()
                ),
                &svg,
            );
        }
    }

    Ok(format!(
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n{body}<footer>greybox {} report format {}</footer>\n</body>\n</html>\n",
        esc(title),
        env!("CARGO_PKG_VERSION"),
        r.version
    ))
}

const STYLE: &str = "body{font-family:sans-serif;max-width:900px;margin:2em auto;color:#222}\
h1{font-size:1.5em}h2{font-size:1.2em;border-bottom:1px solid #ccc;margin-top:2em}\
table{border-collapse:collapse;font-size:.85em}td,th{border:1px solid #ccc;padding:3px 6px}\
tr.yes{background:#e8f4e8}figure{margin:1em 0}figcaption{font-size:.85em;color:#555}\
.lead{font-size:1.1em}footer{margin-top:3em;font-size:.8em;color:#888}";

fn binned_mean(x: &[f64], e: &[f64], bins: usize) -> Vec<(f64, f64)> {
    let (lo, hi) = range(x.iter().copied());
    let mut s = vec![0.0; bins];
    let mut c = vec![0usize; bins];
    for (&xv, &ev) in x.iter().zip(e) {
        let b = (((xv - lo) / (hi - lo)) * bins as f64) as usize;
        let b = b.min(bins - 1);
        s[b] += ev;
        c[b] += 1;
    }
    (0..bins)
        .filter(|&b| c[b] >= 5)
        .map(|b| {
            (
                lo + (b as f64 + 0.5) * (hi - lo) / bins as f64,
                s[b] / c[b] as f64,
            )
        })
        .collect()
}

/// Binned mean of `e` over the level of `x`, separately for samples where
/// `x` rises and where it falls: without memory both branches coincide.
fn direction_means(x: &[f64], e: &[f64], bins: usize) -> (Curve, Curve) {
    let (mut xu, mut eu, mut xd, mut ed) = (vec![], vec![], vec![], vec![]);
    for k in 1..x.len().min(e.len()) {
        if x[k] > x[k - 1] {
            xu.push(x[k]);
            eu.push(e[k]);
        } else if x[k] < x[k - 1] {
            xd.push(x[k]);
            ed.push(e[k]);
        }
    }
    (binned_mean(&xu, &eu, bins), binned_mean(&xd, &ed, bins))
}

fn qq(e: &[f64]) -> (Curve, Curve) {
    let m = gb_core::metrics::mean(e);
    let sd = gb_core::metrics::std(e).max(1e-300);
    let mut z: Vec<f64> = e.iter().map(|v| (v - m) / sd).collect();
    z.sort_by(f64::total_cmp);
    let n = z.len();
    let stride = n.div_ceil(1500).max(1);
    let mut pts: Vec<(f64, f64)> = (0..n)
        .step_by(stride)
        .map(|i| (normal_quantile((i as f64 + 0.5) / n as f64), z[i]))
        .collect();
    if n > 0 && (n - 1) % stride != 0 {
        pts.push((normal_quantile((n as f64 - 0.5) / n as f64), z[n - 1]));
    }
    let q = normal_quantile(0.5 / n.max(1) as f64).abs();
    (pts, vec![(-q, -q), (q, q)])
}

fn partition_plot(
    m: &GreyBoxModel,
    inputs: &[String],
    yname: &str,
) -> Result<String, DiagnoseError> {
    let net = &m.network;
    let nz = net.z_index.len();
    // the two partition dimensions split most often (distinct inner bounds)
    let mut counts: Vec<(usize, usize)> = (0..nz)
        .map(|dim| {
            let mut b: Vec<f64> = net
                .leaves
                .iter()
                .flat_map(|l| [l.lower[dim], l.upper[dim]])
                .filter(|v| *v > 1e-9 && *v < 1.0 - 1e-9)
                .collect();
            b.sort_by(f64::total_cmp);
            b.dedup_by(|a, c| (*a - *c).abs() < 1e-9);
            (b.len(), dim)
        })
        .collect();
    counts.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
    let dx = counts.first().map_or(0, |c| c.1);
    let dy = counts.get(1).map_or(dx, |c| c.1);
    let names = net.spec.regressor_names(yname, inputs);
    let name = |d: usize| {
        net.z_index
            .get(d)
            .and_then(|&i| names.get(i).cloned())
            .unwrap_or_else(|| format!("z{d}"))
    };
    let rects: Vec<(f64, f64, f64, f64, f64)> = net
        .leaves
        .iter()
        .map(|l| {
            let (y0, y1) = if dy == dx {
                (0.0, 1.0)
            } else {
                (l.lower[dy], l.upper[dy])
            };
            (l.lower[dx], y0, l.upper[dx], y1, 1.0)
        })
        .collect();
    rect_chart(
        &format!("LOLIMOT partition, {} local models", net.leaves.len()),
        &name(dx),
        &if dy == dx {
            "(one split dimension)".to_string()
        } else {
            name(dy)
        },
        &rects,
        true,
    )
}

fn preisach_plot(m: &GreyBoxModel, yname: &str) -> Result<String, DiagnoseError> {
    let net = &m.network;
    let levels = net.spec.output_relays;
    let nrel = net.spec.n_relays();
    let nop = net.spec.output_play.len();
    let block = net.spec.output_block();
    let mut w = vec![0.0; nrel];
    for l in 0..net.spec.hysteresis_lags {
        let off = l * block + nop;
        if let Some(seg) = net.beta.get(off..off + nrel) {
            for (a, b) in w.iter_mut().zip(seg) {
                *a += b;
            }
        }
    }
    // relay thresholds as in gb_lmn::RelayGrid::new(levels, 2.5), in physical units
    let h = 2.5;
    let step = 2.0 * h / levels as f64;
    let s = &net.output_scaling;
    let phys = |v: f64| s.from_norm(v);
    let mut rects = vec![];
    let mut k = 0;
    for i in 0..levels {
        for j in 0..=i {
            let a0 = -h + step * i as f64;
            let b0 = -h + step * j as f64;
            rects.push((
                phys(b0),
                phys(a0),
                phys(b0 + step),
                phys(a0 + step),
                w[k] * s.scale.abs(),
            ));
            k += 1;
        }
    }
    rect_chart(
        "Identified Preisach density (relay weights)",
        &format!("beta (switch-down threshold of {yname})"),
        &format!("alpha (switch-up threshold of {yname})"),
        &rects,
        false,
    )
}

/// Heat map of a 2-D wavelet term over its box (24 × 24 cells).
fn state_space_plot(
    t: &gb_model::NonlinearTerm,
    input_names: &[String],
) -> Result<String, DiagnoseError> {
    let name = |s: &gb_model::Signal| match *s {
        gb_model::Signal::State(i) => format!("hidden state x{}", i + 1),
        gb_model::Signal::Input(j) => input_names
            .get(j)
            .cloned()
            .unwrap_or_else(|| format!("u{}", j + 1)),
    };
    let (lo, hi) = (t.expansion.lo(), t.expansion.hi());
    let n = 24;
    let mut rects = Vec::with_capacity(n * n);
    for i in 0..n {
        for j in 0..n {
            let x0 = lo[0] + (hi[0] - lo[0]) * i as f64 / n as f64;
            let x1 = lo[0] + (hi[0] - lo[0]) * (i + 1) as f64 / n as f64;
            let y0 = lo[1] + (hi[1] - lo[1]) * j as f64 / n as f64;
            let y1 = lo[1] + (hi[1] - lo[1]) * (j + 1) as f64 / n as f64;
            let v = t.expansion.eval(&[0.5 * (x0 + x1), 0.5 * (y0 + y1)]);
            rects.push((x0, y0, x1, y1, v));
        }
    }
    rect_chart(
        "Identified wavelet term of the hidden-state model",
        &name(&t.args[0]),
        &name(&t.args[1]),
        &rects,
        false,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_quantile_matches_known_values() {
        // Φ⁻¹ at tabulated points (Abramowitz & Stegun 26.2)
        for (p, z) in [
            (0.5, 0.0),
            (0.975, 1.959963984540054),
            (0.8413447460685429, 1.0),
            (0.001, -3.090232306167813),
            (1e-6, -4.753424308822899),
        ] {
            assert!((normal_quantile(p) - z).abs() < 1e-7, "p={p}");
        }
    }

    #[test]
    fn periodogram_finds_a_sinusoid() {
        let e: Vec<f64> = (0..2000)
            .map(|k| (2.0 * std::f64::consts::PI * 0.1 * k as f64).sin())
            .collect();
        let p = periodogram(&e, 200);
        let (f, _) = p
            .iter()
            .copied()
            .fold((0.0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
        assert!((f - 0.1).abs() < 1e-9, "peak at {f}");
    }
}
