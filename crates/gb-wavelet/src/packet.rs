//! Wavelet packets (Hauth 2008, §4.1.6): the full binary tree obtained by
//! splitting both the approximation and the detail of every node, and the
//! Coifman–Wickerhauser best basis for an additive cost.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::error::{Result, WaveletError};
use crate::mode::Mode;
use crate::transform::{analysis, idwt};
use crate::wavelet::Wavelet;

/// A node of the packet tree: `level` (0 = root) and its `index` in natural
/// order (the path's `a`/`d` letters read as binary digits 0/1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct PacketNode {
    /// Depth in the tree.
    pub level: usize,
    /// Position in natural order.
    pub index: usize,
}

impl PacketNode {
    /// PyWavelets' path, e.g. `"ada"`.
    pub fn path(&self) -> String {
        (0..self.level)
            .rev()
            .map(|b| if (self.index >> b) & 1 == 0 { 'a' } else { 'd' })
            .collect()
    }

    /// Parses a path of `a`/`d` letters.
    pub fn from_path(path: &str) -> Result<Self> {
        let mut index = 0;
        for ch in path.chars() {
            index = 2 * index
                + match ch {
                    'a' => 0,
                    'd' => 1,
                    _ => {
                        return Err(WaveletError::InvalidParameter(format!(
                            "packet path `{path}`"
                        )))
                    }
                };
        }
        Ok(Self {
            level: path.len(),
            index,
        })
    }
}

/// Additive information cost `M(c) = Σ_i m(c_i)` for best-basis selection.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum EntropyCost {
    /// Coifman–Wickerhauser entropy `−Σ c² ln c²` (0 ln 0 = 0).
    Shannon,
    /// `Σ ln c²` over non-zero `c`.
    LogEnergy,
    /// Number of `|c| > t`.
    Threshold(f64),
    /// `Σ |c|^p`.
    Norm(f64),
}

impl EntropyCost {
    /// The cost of a coefficient vector.
    pub fn cost(&self, c: &[f64]) -> f64 {
        match *self {
            EntropyCost::Shannon => c
                .iter()
                .filter(|v| **v != 0.0)
                .map(|v| {
                    let s = v * v;
                    -s * s.ln()
                })
                .sum(),
            EntropyCost::LogEnergy => c.iter().filter(|v| **v != 0.0).map(|v| (v * v).ln()).sum(),
            EntropyCost::Threshold(t) => c.iter().filter(|v| v.abs() > t).count() as f64,
            EntropyCost::Norm(p) => c.iter().map(|v| v.abs().powf(p)).sum(),
        }
    }
}

impl FromStr for EntropyCost {
    type Err = WaveletError;
    /// `shannon`, `log-energy`, `threshold:T`, `norm:P`.
    fn from_str(s: &str) -> Result<Self> {
        let lower = s.trim().to_ascii_lowercase();
        let (name, arg) = lower
            .split_once(':')
            .map_or((lower.as_str(), None), |(n, a)| (n, Some(a)));
        let value = |a: Option<&str>| -> Result<f64> {
            a.and_then(|v| v.parse::<f64>().ok())
                .filter(|v| v.is_finite())
                .ok_or_else(|| WaveletError::UnknownCost(s.to_string()))
        };
        match name {
            "shannon" | "entropy" => Ok(Self::Shannon),
            "log-energy" | "logenergy" => Ok(Self::LogEnergy),
            "threshold" => Ok(Self::Threshold(value(arg)?)),
            "norm" => Ok(Self::Norm(value(arg)?)),
            _ => Err(WaveletError::UnknownCost(s.to_string())),
        }
    }
}

impl fmt::Display for EntropyCost {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Shannon => f.write_str("shannon"),
            Self::LogEnergy => f.write_str("log-energy"),
            Self::Threshold(t) => write!(f, "threshold:{t}"),
            Self::Norm(p) => write!(f, "norm:{p}"),
        }
    }
}

/// Deepest packet tree accepted (`2^20` leaves).
pub const MAX_PACKET_LEVEL: usize = 20;

/// The full wavelet packet tree of a signal, like `pywt.WaveletPacket`.
///
/// ```
/// use gb_wavelet::{EntropyCost, Mode, Wavelet, WaveletPacket};
/// let x: Vec<f64> = (0..64).map(|i| (i as f64 * 0.9).sin()).collect();
/// let w = Wavelet::new("db2")?;
/// let wp = WaveletPacket::new(&x, &w, Mode::Periodization, Some(3))?;
/// assert_eq!(wp.node_by_path("ad").map(|c| c.len()), Some(16));
/// let basis = wp.best_basis(EntropyCost::Shannon);
/// let y = wp.reconstruct(&basis)?;
/// assert!(x.iter().zip(&y).all(|(a, b)| (a - b).abs() < 1e-12));
/// # Ok::<(), gb_wavelet::WaveletError>(())
/// ```
#[derive(Debug, Clone)]
pub struct WaveletPacket {
    wavelet: Wavelet,
    mode: Mode,
    /// `nodes[level][index]`, natural order; `nodes[0][0]` is the signal.
    nodes: Vec<Vec<Vec<f64>>>,
}

impl WaveletPacket {
    /// Decomposes `signal` to `max_level` (`None`: [`Wavelet::max_level`]).
    pub fn new(
        signal: &[f64],
        wavelet: &Wavelet,
        mode: Mode,
        max_level: Option<usize>,
    ) -> Result<Self> {
        if signal.is_empty() {
            return Err(WaveletError::EmptyInput("signal"));
        }
        let max_level = max_level.unwrap_or_else(|| wavelet.max_level(signal.len()));
        if max_level > MAX_PACKET_LEVEL {
            return Err(WaveletError::InvalidParameter(format!(
                "packet depth {max_level} > {MAX_PACKET_LEVEL}"
            )));
        }
        let mut nodes = vec![vec![signal.to_vec()]];
        for level in 0..max_level {
            let mut next = Vec::with_capacity(2 << level);
            for parent in &nodes[level] {
                let n = wavelet.dwt_len(parent.len(), mode);
                let (mut a, mut d) = (vec![0.0; n], vec![0.0; n]);
                analysis(
                    parent,
                    &wavelet.dec_lo_rev,
                    &wavelet.dec_hi_rev,
                    mode,
                    &mut a,
                    &mut d,
                );
                next.push(a);
                next.push(d);
            }
            nodes.push(next);
        }
        Ok(Self {
            wavelet: wavelet.clone(),
            mode,
            nodes,
        })
    }

    /// Depth of the tree.
    pub fn max_level(&self) -> usize {
        self.nodes.len() - 1
    }

    /// Coefficients of a node.
    pub fn node(&self, node: PacketNode) -> Option<&[f64]> {
        self.nodes
            .get(node.level)?
            .get(node.index)
            .map(Vec::as_slice)
    }

    /// Coefficients of a node, mutable (e.g. to threshold before reconstructing).
    pub fn node_mut(&mut self, node: PacketNode) -> Option<&mut Vec<f64>> {
        self.nodes.get_mut(node.level)?.get_mut(node.index)
    }

    /// Coefficients of the node with PyWavelets path `path` (`""` = root).
    pub fn node_by_path(&self, path: &str) -> Option<&[f64]> {
        self.node(PacketNode::from_path(path).ok()?)
    }

    /// All nodes of a level in natural order.
    pub fn level(&self, level: usize) -> Option<&[Vec<f64>]> {
        self.nodes.get(level).map(Vec::as_slice)
    }

    /// Natural indices of a level's nodes in frequency order (Gray code,
    /// PyWavelets' `order="freq"`).
    pub fn frequency_order(level: usize) -> Vec<usize> {
        (0..1usize << level).map(|k| k ^ (k >> 1)).collect()
    }

    /// Coifman–Wickerhauser best basis: bottom-up, a node replaces its
    /// children when its cost is not larger than theirs combined. Returns the
    /// chosen nodes in natural (left-to-right) order.
    pub fn best_basis(&self, cost: EntropyCost) -> Vec<PacketNode> {
        let top = self.max_level();
        // (cost, basis) for each node of the current level
        let mut best: Vec<(f64, Vec<PacketNode>)> = (0..self.nodes[top].len())
            .map(|i| {
                let n = PacketNode {
                    level: top,
                    index: i,
                };
                (cost.cost(&self.nodes[top][i]), vec![n])
            })
            .collect();
        for level in (0..top).rev() {
            let mut next = Vec::with_capacity(self.nodes[level].len());
            let mut children = best.into_iter();
            for (i, data) in self.nodes[level].iter().enumerate() {
                let (ca, ba) = children.next().unwrap_or_default();
                let (cd, bd) = children.next().unwrap_or_default();
                let own = cost.cost(data);
                if own <= ca + cd {
                    next.push((own, vec![PacketNode { level, index: i }]));
                } else {
                    let mut b = ba;
                    b.extend(bd);
                    next.push((ca + cd, b));
                }
            }
            best = next;
        }
        best.into_iter().next().map(|(_, b)| b).unwrap_or_default()
    }

    /// Reconstructs the signal from the (possibly modified) coefficients of
    /// the nodes of `basis`, which must tile the tree (every leaf-to-root path
    /// meets exactly one of them). Like PyWavelets, each inverse step is
    /// cropped to the length of the node it rebuilds.
    pub fn reconstruct(&self, basis: &[PacketNode]) -> Result<Vec<f64>> {
        self.rebuild(PacketNode { level: 0, index: 0 }, basis)
    }

    fn rebuild(&self, node: PacketNode, basis: &[PacketNode]) -> Result<Vec<f64>> {
        if basis.contains(&node) {
            return self
                .node(node)
                .map(<[f64]>::to_vec)
                .ok_or_else(|| WaveletError::InvalidParameter(format!("no node {}", node.path())));
        }
        if node.level >= self.max_level() {
            return Err(WaveletError::InvalidParameter(format!(
                "basis does not cover node `{}`",
                node.path()
            )));
        }
        let a = self.rebuild(
            PacketNode {
                level: node.level + 1,
                index: 2 * node.index,
            },
            basis,
        )?;
        let d = self.rebuild(
            PacketNode {
                level: node.level + 1,
                index: 2 * node.index + 1,
            },
            basis,
        )?;
        let mut out = idwt(&a, &d, &self.wavelet, self.mode)?;
        let len = self.nodes[node.level][node.index].len();
        out.truncate(len);
        Ok(out)
    }
}
