//! The partition of a local model network: a binary tree whose leaves carry
//! the local models (Nelles 2020, ch. 14; Nelles, "Axes-oblique partitioning
//! strategies for local model networks", IEEE ISIC 2006 — HILOMOT).
//!
//! Two kinds of validity (weight) functions share the tree:
//!
//! * [`WeightKind::Gaussian`] — classic LOLIMOT: every leaf is an
//!   axis-parallel cell [l, u]; μᵢ(z) = exp(−½ Σ_d ((z_d − c_id)/σ_id)²) with
//!   c the cell centre and σ = 0.4 (u − l); Φᵢ = μᵢ / Σ_l μ_l.
//! * [`WeightKind::Tree`] — hierarchical sigmoid weights: inner node n splits
//!   with ψ_n(z) = 1 / (1 + exp(−(w_nᵀz + w_n0))) (right child ψ, left
//!   child 1 − ψ); a leaf's weight is the product along its path. Σᵢ Φᵢ = 1
//!   by construction, no normalisation, hence no reactivation. The steepness
//!   ‖w‖ is the smoothness parameter (axis splits start at
//!   ‖w‖ = 1/(smoothness · cell extent)); oblique splits optimise w.
//!
//! Derivatives used by the gradient-based optimisation: with the subtree
//! outputs Y_leaf = L_leaf and Y_n = ψ_n Y_right + (1 − ψ_n) Y_left,
//! ∂ŷ/∂a_n = Φ_n ψ_n (1 − ψ_n)(Y_right − Y_left), a_n = w_nᵀz + w_n0.
use serde::{Deserialize, Serialize};

/// Which validity functions a network uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum WeightKind {
    /// Normalised Gaussians over axis-parallel cells (LOLIMOT).
    Gaussian,
    /// Decision-tree sigmoid weights (product along the path).
    Tree,
}

/// An inner node's split: ψ(z) = σ(wᵀz + w0) is the right child's share.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Split {
    /// Index of the left child (weight 1 − ψ).
    pub left: usize,
    /// Index of the right child (weight ψ).
    pub right: usize,
    /// Direction and steepness over z (normalised signal units).
    pub w: Vec<f64>,
    /// Offset.
    pub w0: f64,
    /// Axis split: the dimension (None: oblique).
    pub axis: Option<usize>,
}

/// A tree node: inner (with a split) or leaf (with local parameters).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Node {
    /// Parent node.
    pub parent: Option<usize>,
    /// Lower corner of the node's cell (normalised z units).
    pub lower: Vec<f64>,
    /// Upper corner of the node's cell.
    pub upper: Vec<f64>,
    /// The split of an inner node.
    pub split: Option<Split>,
    /// Local model parameters θ over φ = [1, x, monomials, user columns] (leaves).
    pub theta: Vec<f64>,
    /// Effective number of parameters of the local estimate, tr((XᵀQX)⁻¹ XᵀQ²X).
    pub n_eff: f64,
}

/// Weights below this are treated as zero (rows left out of a leaf's fit).
pub(crate) const TINY: f64 = 1e-13;

/// eˣ without branches or libm calls, so that loops over it vectorise:
/// x = n ln2 + r (Cody–Waite, |r| ≤ ln2/2), eʳ by its Taylor polynomial of
/// degree 13 (relative error < 1e-15), 2ⁿ by writing the exponent bits.
/// x is clamped to ±700.
#[inline(always)]
pub fn fast_exp(x: f64) -> f64 {
    fast_exp_g::<false>(x)
}

/// [`fast_exp`]; with `FMA` the polynomial uses fused multiply–adds (only
/// for code compiled with the `fma` target feature).
#[inline(always)]
pub(crate) fn fast_exp_g<const FMA: bool>(x: f64) -> f64 {
    const MAGIC: f64 = 6_755_399_441_055_744.0; // 1.5·2^52: rounds to an integer
    const LN2_HI: f64 = f64::from_bits(0x3fe6_2e42_fee0_0000);
    const LN2_LO: f64 = f64::from_bits(0x3dea_39ef_3579_3c76);
    let x = x.clamp(-700.0, 700.0);
    let t = x * std::f64::consts::LOG2_E + MAGIC;
    let n = t - MAGIC;
    let r = x - n * LN2_HI - n * LN2_LO;
    // Σ_{i=0}^{13} rⁱ/i! by Estrin's scheme (short dependency chains: the
    // simulation loop is latency bound)
    let fma = |a: f64, b: f64, c: f64| if FMA { a.mul_add(b, c) } else { a * b + c };
    const C: [f64; 14] = [
        1.0,
        1.0,
        0.5,
        1.0 / 6.0,
        1.0 / 24.0,
        1.0 / 120.0,
        1.0 / 720.0,
        1.0 / 5_040.0,
        1.0 / 40_320.0,
        1.0 / 362_880.0,
        1.0 / 3_628_800.0,
        1.0 / 39_916_800.0,
        1.0 / 479_001_600.0,
        1.0 / 6_227_020_800.0,
    ];
    let r2 = r * r;
    let r4 = r2 * r2;
    let r8 = r4 * r4;
    let q0 = fma(C[1], r, C[0]);
    let q1 = fma(C[3], r, C[2]);
    let q2 = fma(C[5], r, C[4]);
    let q3 = fma(C[7], r, C[6]);
    let q4 = fma(C[9], r, C[8]);
    let q5 = fma(C[11], r, C[10]);
    let q6 = fma(C[13], r, C[12]);
    let s0 = fma(q1, r2, q0);
    let s1 = fma(q3, r2, q2);
    let s2 = fma(q5, r2, q4);
    let t0 = fma(s1, r4, s0);
    let t1 = fma(q6, r4, s2);
    let p = fma(t1, r8, t0);
    p * f64::from_bits(t.to_bits().wrapping_add(1023) << 52)
}
/// Gaussian width relative to the cell extent.
pub(crate) const K_SIGMA: f64 = 0.4;

/// The partition tree with its local models.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Partition {
    /// Weight functions.
    pub kind: WeightKind,
    /// Nodes; node 0 is the root, children come after their parents.
    pub nodes: Vec<Node>,
}

/// Scratch space for weight evaluation (allocated once per call).
#[derive(Debug, Clone)]
pub(crate) struct WScratch {
    pub leaves: Vec<usize>,
    pub inner: Vec<usize>,
    pub psi: Vec<f64>,
    pub phi: Vec<f64>,
    pub yc: Vec<f64>,
    pub da: Vec<f64>,
    pub g: Vec<f64>,
    pub ea: Vec<f64>,
}

impl Partition {
    /// One leaf covering the box [lower, upper] with `p` zero parameters.
    pub fn root(kind: WeightKind, lower: Vec<f64>, upper: Vec<f64>, p: usize) -> Self {
        Self {
            kind,
            nodes: vec![Node {
                parent: None,
                lower,
                upper,
                split: None,
                theta: vec![0.0; p],
                n_eff: 0.0,
            }],
        }
    }

    /// Dimension of z.
    pub fn nz(&self) -> usize {
        self.nodes.first().map_or(0, |n| n.lower.len())
    }

    /// Reachable nodes in preorder (parents before children).
    pub fn preorder(&self) -> Vec<usize> {
        let mut out = Vec::with_capacity(self.nodes.len());
        let mut stack = vec![0usize];
        while let Some(n) = stack.pop() {
            if n >= self.nodes.len() {
                continue;
            }
            out.push(n);
            if let Some(s) = &self.nodes[n].split {
                stack.push(s.right);
                stack.push(s.left);
            }
        }
        out
    }

    /// Leaves in preorder.
    pub fn leaves(&self) -> Vec<usize> {
        self.preorder()
            .into_iter()
            .filter(|&n| self.nodes[n].split.is_none())
            .collect()
    }

    /// Inner nodes in preorder.
    pub fn inner(&self) -> Vec<usize> {
        self.preorder()
            .into_iter()
            .filter(|&n| self.nodes[n].split.is_some())
            .collect()
    }

    /// Number of leaves (local models).
    pub fn n_leaves(&self) -> usize {
        self.leaves().len()
    }

    /// Drop unreachable nodes and renumber in preorder.
    pub fn compact(&mut self) {
        let order = self.preorder();
        let mut map = vec![usize::MAX; self.nodes.len()];
        for (i, &n) in order.iter().enumerate() {
            map[n] = i;
        }
        let mut nodes = Vec::with_capacity(order.len());
        for &n in &order {
            let mut nd = self.nodes[n].clone();
            nd.parent = nd.parent.map(|p| map[p]);
            if let Some(s) = &mut nd.split {
                s.left = map[s.left];
                s.right = map[s.right];
            }
            nodes.push(nd);
        }
        self.nodes = nodes;
    }

    /// Check the tree's internal consistency for `p` local and `nz` partition
    /// dimensions (after deserialisation).
    pub fn is_consistent(&self, p: usize, nz: usize) -> bool {
        let nn = self.nodes.len();
        if nn == 0 || self.nodes[0].parent.is_some() {
            return false;
        }
        // A tree: every node but the root is the child of exactly one node,
        // the one its `parent` names (a shared child would make the
        // traversals exponential, a wrong parent index out of range).
        let mut referenced = vec![0u8; nn];
        for (i, n) in self.nodes.iter().enumerate() {
            if let Some(s) = &n.split {
                for c in [s.left, s.right] {
                    if c <= i || c >= nn || self.nodes[c].parent != Some(i) {
                        return false;
                    }
                    referenced[c] = referenced[c].saturating_add(1);
                }
            }
        }
        if referenced[1..].iter().any(|&r| r != 1) {
            return false;
        }
        for (i, n) in self.nodes.iter().enumerate() {
            if n.lower.len() != nz || n.upper.len() != nz {
                return false;
            }
            match &n.split {
                Some(s) => {
                    if s.left <= i || s.right <= i || s.left >= nn || s.right >= nn {
                        return false;
                    }
                    if s.w.len() != nz || s.axis.is_some_and(|a| a >= nz) {
                        return false;
                    }
                }
                None => {
                    if n.theta.len() != p {
                        return false;
                    }
                }
            }
        }
        self.preorder().len() <= nn
    }

    pub(crate) fn scratch(&self) -> WScratch {
        let nn = self.nodes.len();
        let leaves = self.leaves();
        WScratch {
            inner: self.inner(),
            psi: vec![0.0; nn],
            phi: vec![0.0; nn],
            yc: vec![0.0; nn],
            da: vec![0.0; nn],
            g: vec![0.0; leaves.len() * self.nz().max(1)],
            ea: vec![0.0; self.inner().len()],
            leaves,
        }
    }

    /// Validity of every node at z (leaves: Φᵢ; inner nodes, tree kind: the
    /// product along the path) into `s.phi`.
    #[inline]
    pub(crate) fn weights(&self, z: &[f64], s: &mut WScratch) {
        if s.leaves.len() == 1 {
            s.phi[s.leaves[0]] = 1.0;
            return;
        }
        match self.kind {
            WeightKind::Tree => {
                // a_n = w_nᵀz + w_n0 for every split, then all exponentials
                // in one (vectorisable) pass, then the products down the tree
                for (e, &n) in s.ea.iter_mut().zip(&s.inner) {
                    if let Some(sp) = &self.nodes[n].split {
                        let mut a = sp.w0;
                        for (wd, zd) in sp.w.iter().zip(z) {
                            a += wd * zd;
                        }
                        *e = -a;
                    }
                }
                for e in s.ea.iter_mut() {
                    *e = fast_exp(*e);
                }
                s.phi[0] = 1.0;
                for (e, &n) in s.ea.iter().zip(&s.inner) {
                    if let Some(sp) = &self.nodes[n].split {
                        let pn = s.phi[n];
                        let psi = 1.0 / (1.0 + e);
                        s.psi[n] = psi;
                        s.phi[sp.right] = pn * psi;
                        s.phi[sp.left] = pn * (1.0 - psi);
                    }
                }
            }
            WeightKind::Gaussian => {
                let nz = z.len();
                let mut mx = f64::NEG_INFINITY;
                for (i, &l) in s.leaves.iter().enumerate() {
                    let nd = &self.nodes[l];
                    let mut q = 0.0;
                    for d in 0..nz {
                        let c = 0.5 * (nd.lower[d] + nd.upper[d]);
                        let sg = (K_SIGMA * (nd.upper[d] - nd.lower[d])).max(1e-6);
                        let t = (z[d] - c) / sg;
                        q += t * t;
                        s.g[i * nz + d] = -(z[d] - c) / (sg * sg);
                    }
                    s.phi[l] = -0.5 * q;
                    mx = mx.max(s.phi[l]);
                }
                let mut sum = 0.0;
                for &l in &s.leaves {
                    let v = (s.phi[l] - mx).exp();
                    s.phi[l] = v;
                    sum += v;
                }
                for &l in &s.leaves {
                    s.phi[l] /= sum;
                }
            }
        }
    }

    /// After `weights` and with the leaf outputs in `s.yc[leaf]`: the
    /// derivatives ∂ŷ/∂a_n of every inner node (tree kind) into `s.da`, and
    /// ∂ŷ/∂z added to `gz`.
    #[inline]
    pub(crate) fn weight_derivatives(&self, z: &[f64], s: &mut WScratch, gz: &mut [f64]) {
        if s.leaves.len() == 1 {
            return;
        }
        match self.kind {
            WeightKind::Tree => {
                for &n in s.inner.iter().rev() {
                    let Some(sp) = &self.nodes[n].split else {
                        continue;
                    };
                    let psi = s.psi[n];
                    let (yl, yr) = (s.yc[sp.left], s.yc[sp.right]);
                    s.yc[n] = psi * yr + (1.0 - psi) * yl;
                    let da = s.phi[n] * psi * (1.0 - psi) * (yr - yl);
                    s.da[n] = da;
                    if da != 0.0 {
                        for (g, wd) in gz.iter_mut().zip(&sp.w) {
                            *g += da * wd;
                        }
                    }
                }
            }
            WeightKind::Gaussian => {
                let nz = z.len();
                for d in 0..nz {
                    let mut gbar = 0.0;
                    for (i, &l) in s.leaves.iter().enumerate() {
                        gbar += s.phi[l] * s.g[i * nz + d];
                    }
                    let mut v = 0.0;
                    for (i, &l) in s.leaves.iter().enumerate() {
                        v += s.phi[l] * (s.g[i * nz + d] - gbar) * s.yc[l];
                    }
                    gz[d] += v;
                }
            }
        }
    }

    /// Number of split parameters optimised globally (tree kind: w and w0 of
    /// every inner node; Gaussian: none).
    pub fn n_split_parameters(&self) -> usize {
        match self.kind {
            WeightKind::Tree => self.inner().len() * (self.nz() + 1),
            WeightKind::Gaussian => 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A random tree of `m` leaves with random oblique splits.
    fn random_tree(nz: usize, m: usize, seed: &[f64]) -> Partition {
        let mut p = Partition::root(WeightKind::Tree, vec![-1.0; nz], vec![1.0; nz], 1);
        let mut c = 0;
        let mut next = || {
            c += 1;
            seed[c % seed.len()]
        };
        while p.n_leaves() < m {
            let leaves = p.leaves();
            let l = leaves[(next().abs() * 1000.0) as usize % leaves.len()];
            let w: Vec<f64> = (0..nz).map(|_| 5.0 * next()).collect();
            let w0 = next();
            let nn = p.nodes.len();
            let child = |pp: &Partition| Node {
                parent: Some(l),
                lower: pp.nodes[l].lower.clone(),
                upper: pp.nodes[l].upper.clone(),
                split: None,
                theta: vec![0.0],
                n_eff: 0.0,
            };
            let (a, b) = (child(&p), child(&p));
            p.nodes.push(a);
            p.nodes.push(b);
            p.nodes[l].split = Some(Split {
                left: nn,
                right: nn + 1,
                w,
                w0,
                axis: None,
            });
        }
        p
    }

    #[test]
    fn fast_exp_matches_std_exp() {
        for i in -69900..=69900 {
            let x = i as f64 * 0.01 + 0.003;
            let (a, b) = (fast_exp(x), x.exp());
            assert!((a - b).abs() <= 4e-15 * b, "x {x}: {a} vs {b}");
        }
    }

    proptest! {
        #[test]
        fn tree_weights_sum_to_one(
            seed in proptest::collection::vec(-1.0f64..1.0, 8..40),
            z in proptest::collection::vec(-3.0f64..3.0, 3),
            m in 1usize..25,
        ) {
            let p = random_tree(3, m, &seed);
            let mut s = p.scratch();
            p.weights(&z, &mut s);
            let sum: f64 = s.leaves.iter().map(|&l| s.phi[l]).sum();
            prop_assert!((sum - 1.0).abs() < 1e-10, "sum {}", sum);
            prop_assert!(s.leaves.iter().all(|&l| s.phi[l] >= 0.0));
        }
    }
}
