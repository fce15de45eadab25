//! What a report can draw of the hidden-state model: its first 2-D wavelet
//! term as a heat map over the term's box.
use crate::model::{Signal, SparseStateSpace, Target};
use gb_core::{ModelView, ViewData};

/// The first 2-D wavelet term with non-zero coefficients, on 24 × 24 cells.
pub(crate) fn state_space_views(m: &SparseStateSpace, inputs: &[String]) -> Vec<ModelView> {
    let Some(t) = m
        .terms
        .iter()
        .find(|t| t.args.len() == 2 && t.expansion.nnz() > 0)
    else {
        return vec![];
    };
    let name = |s: &Signal| match *s {
        Signal::State(i) => format!("hidden state x{}", i + 1),
        Signal::Input(j) => inputs
            .get(j)
            .cloned()
            .unwrap_or_else(|| format!("u{}", j + 1)),
    };
    let (lo, hi) = (t.expansion.lo(), t.expansion.hi());
    let n = 24;
    let mut cells = Vec::with_capacity(n * n);
    for i in 0..n {
        for j in 0..n {
            let x0 = lo[0] + (hi[0] - lo[0]) * i as f64 / n as f64;
            let x1 = lo[0] + (hi[0] - lo[0]) * (i + 1) as f64 / n as f64;
            let y0 = lo[1] + (hi[1] - lo[1]) * j as f64 / n as f64;
            let y1 = lo[1] + (hi[1] - lo[1]) * (j + 1) as f64 / n as f64;
            let v = t.expansion.eval(&[0.5 * (x0 + x1), 0.5 * (y0 + y1)]);
            cells.push([x0, y0, x1, y1, v]);
        }
    }
    let target = match t.target {
        Target::State(i) => format!("state row x{}", i + 1),
        Target::Output => "the output".into(),
    };
    vec![ModelView {
        key: "state-space".into(),
        title: "Identified wavelet term of the hidden-state model".into(),
        caption: format!(
            "Identified sparse wavelet term added to {target}, over its box ({} non-zero coefficients); red positive, blue negative.",
            t.expansion.nnz()
        ),
        data: ViewData::Cells {
            x_label: name(&t.args[0]),
            y_label: name(&t.args[1]),
            cells,
            outline: false,
        },
    }]
}
