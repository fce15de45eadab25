//! What a report can draw of an input–output network: its LOLIMOT
//! partition and its identified Preisach density.
use crate::LocalModelNetwork;
use gb_core::{ModelView, ViewData};

/// The partition (more than one local model) and the Preisach relay
/// weights (a relay grid on the output), if present.
pub(crate) fn network_views(
    net: &LocalModelNetwork,
    inputs: &[String],
    outputs: &[String],
) -> Vec<ModelView> {
    let y = outputs.first().map_or("y", String::as_str);
    let mut v = vec![];
    if net.leaves.len() > 1 {
        v.push(partition(net, inputs, y));
    }
    if net.spec.output_relays > 0 {
        v.push(preisach_density(net, y));
    }
    v
}

/// The cells projected on the two most-split partition dimensions (unit
/// scaled).
fn partition(net: &LocalModelNetwork, inputs: &[String], y: &str) -> ModelView {
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
    let names = net.spec.regressor_names(y, inputs);
    let name = |d: usize| {
        net.z_index
            .get(d)
            .and_then(|&i| names.get(i).cloned())
            .unwrap_or_else(|| format!("z{d}"))
    };
    let cells = net
        .leaves
        .iter()
        .map(|l| {
            let (y0, y1) = if dy == dx {
                (0.0, 1.0)
            } else {
                (l.lower[dy], l.upper[dy])
            };
            [l.lower[dx], y0, l.upper[dx], y1, 1.0]
        })
        .collect();
    ModelView {
        key: "partition".into(),
        title: format!("LOLIMOT partition, {} local models", net.leaves.len()),
        caption: "LOLIMOT partition: the local models' cells projected on the two most-split partition variables (unit-scaled).".into(),
        data: ViewData::Cells {
            x_label: name(dx),
            y_label: if dy == dx {
                "(one split dimension)".into()
            } else {
                name(dy)
            },
            cells,
            outline: true,
        },
    }
}

/// Relay weights summed over lags on the (β, α) half-plane of the output,
/// in physical units (the cells of `RelayCells::uniform(levels, 2.5, sub)`).
fn preisach_density(net: &LocalModelNetwork, y: &str) -> ModelView {
    let levels = net.spec.output_relays;
    let nrel = net.spec.n_relays();
    // the cells follow the plays and the output map's ramps in each block
    let nop = net.spec.output_play.len() + net.spec.n_ramps();
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
    let h = 2.5;
    let step = 2.0 * h / levels as f64;
    let s = &net.output_scaling;
    let phys = |v: f64| s.from_norm(v);
    let mut cells = vec![];
    let mut k = 0;
    for i in 0..levels {
        for j in 0..=i {
            let a0 = -h + step * i as f64;
            let b0 = -h + step * j as f64;
            cells.push([
                phys(b0),
                phys(a0),
                phys(b0 + step),
                phys(a0 + step),
                w[k] * s.scale.abs(),
            ]);
            k += 1;
        }
    }
    ModelView {
        key: "preisach".into(),
        title: "Identified Preisach density (relay weights)".into(),
        caption: "Identified Preisach relay weights (discrete density, summed over lags) on the (beta, alpha) half-plane of the simulated output; red positive, blue negative.".into(),
        data: ViewData::Cells {
            x_label: format!("beta (switch-down threshold of {y})"),
            y_label: format!("alpha (switch-up threshold of {y})"),
            cells,
            outline: false,
        },
    }
}
