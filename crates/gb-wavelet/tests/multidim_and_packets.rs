//! 2-D transform and wavelet packets compared with PyWavelets.

mod common;

use common::{fixture, floats, rel_err};
use gb_wavelet::{
    wavedec2, waverec2, Array2D, EntropyCost, Mode, PacketNode, Wavelet, WaveletPacket,
};

#[test]
fn wavedec2_matches_pywavelets() {
    let f = fixture("wavedec2.json");
    let rows = f["rows"].as_u64().expect("rows") as usize;
    let cols = f["cols"].as_u64().expect("cols") as usize;
    let image = Array2D::new(rows, cols, floats(&f["image"])).expect("image");
    let shape = |v: &serde_json::Value| {
        let s = floats(v);
        (s[0] as usize, s[1] as usize)
    };
    for case in f["cases"].as_array().expect("cases") {
        let w = Wavelet::new(case["wavelet"].as_str().expect("name")).expect("wavelet");
        let mode: Mode = case["mode"].as_str().expect("mode").parse().expect("mode");
        let what = format!("{} {}", w.name(), mode);
        let c = wavedec2(&image, &w, mode, Some(2)).expect("wavedec2");
        let levels = case["coeffs"].as_array().expect("levels");
        assert_eq!(c.approx.shape(), shape(&levels[0]["shape"]), "{what}");
        assert!(
            rel_err(c.approx.data(), &floats(&levels[0]["data"]), &what) < 1e-10,
            "{what}"
        );
        assert_eq!(c.details.len(), levels.len() - 1);
        for (d, r) in c.details.iter().zip(&levels[1..]) {
            assert_eq!(d.horizontal.shape(), shape(&r["shape"]), "{what}");
            for (band, key) in [
                (&d.horizontal, "horizontal"),
                (&d.vertical, "vertical"),
                (&d.diagonal, "diagonal"),
            ] {
                let e = rel_err(band.data(), &floats(&r[key]), &what);
                assert!(e < 1e-10, "{what} {key}: {e}");
            }
        }
        let back = waverec2(&c, &w, mode).expect("waverec2");
        for r in 0..rows {
            for col in 0..cols {
                let (a, b) = (
                    back.get(r, col).expect("in range"),
                    image.get(r, col).expect("in range"),
                );
                assert!((a - b).abs() < 1e-12, "{what} reconstruction ({r},{col})");
            }
        }
    }
}

#[test]
fn packets_match_pywavelets() {
    let f = fixture("packets.json");
    let x = floats(&f["signal"]);
    for case in f["cases"].as_array().expect("cases") {
        let w = Wavelet::new(case["wavelet"].as_str().expect("name")).expect("wavelet");
        let mode: Mode = case["mode"].as_str().expect("mode").parse().expect("mode");
        let maxlevel = case["maxlevel"].as_u64().expect("level") as usize;
        let wp = WaveletPacket::new(&x, &w, mode, Some(maxlevel)).expect("packet");
        let nodes = case["nodes"].as_object().expect("nodes");
        assert_eq!(nodes.len(), (2usize << maxlevel) - 2);
        for (path, reference) in nodes {
            let ours = wp.node_by_path(path).expect("node exists");
            let e = rel_err(ours, &floats(reference), path);
            assert!(e < 1e-10, "{} {mode} {path}: {e}", w.name());
        }
        let freq: Vec<String> = WaveletPacket::frequency_order(maxlevel)
            .into_iter()
            .map(|index| {
                PacketNode {
                    level: maxlevel,
                    index,
                }
                .path()
            })
            .collect();
        let reference: Vec<String> = case["freq_paths"]
            .as_array()
            .expect("paths")
            .iter()
            .map(|p| p.as_str().expect("path").to_string())
            .collect();
        assert_eq!(freq, reference);
        // every best basis reconstructs the signal
        for cost in [
            EntropyCost::Shannon,
            EntropyCost::LogEnergy,
            EntropyCost::Norm(1.0),
            EntropyCost::Threshold(0.3),
        ] {
            let basis = wp.best_basis(cost);
            let y = wp.reconstruct(&basis).expect("reconstruct");
            assert!(rel_err(&y[..x.len()], &x, "basis") < 1e-12, "{cost}");
        }
    }
}

/// The best basis has the minimal cost among all admissible bases (checked
/// by exhaustive enumeration on a depth-3 tree).
#[test]
fn best_basis_is_minimal() {
    let x: Vec<f64> = (0..64)
        .map(|i| {
            let t = i as f64 / 64.0;
            (40.0 * t * t).sin() + if i > 40 { 1.0 } else { 0.0 }
        })
        .collect();
    let w = Wavelet::new("db2").expect("wavelet");
    let wp = WaveletPacket::new(&x, &w, Mode::Periodization, Some(3)).expect("packet");
    fn all_bases(level: usize, index: usize, max: usize) -> Vec<Vec<PacketNode>> {
        let mut out = vec![vec![PacketNode { level, index }]];
        if level < max {
            for a in all_bases(level + 1, 2 * index, max) {
                for d in all_bases(level + 1, 2 * index + 1, max) {
                    let mut b = a.clone();
                    b.extend(d);
                    out.push(b);
                }
            }
        }
        out
    }
    let cost = EntropyCost::Shannon;
    let total = |b: &[PacketNode]| {
        b.iter()
            .map(|n| cost.cost(wp.node(*n).expect("node")))
            .sum::<f64>()
    };
    let best = wp.best_basis(cost);
    let bases = all_bases(0, 0, 3);
    assert_eq!(bases.len(), 26);
    let min = bases.iter().map(|b| total(b)).fold(f64::INFINITY, f64::min);
    assert!((total(&best) - min).abs() < 1e-12);
    assert!("norm:1.5".parse::<EntropyCost>().is_ok() && "bogus".parse::<EntropyCost>().is_err());
}
