//! Separable hysteresis weights: the L·W hysteresis weights β of a network
//! (W columns at L lags) as one shape w times one lag filter c,
//!
//! β[l, i] = c_l · w_i,  c_0 = 1,
//!
//! a single hysteretic force F(k) = Σᵢ wᵢ hᵢ(k) that enters the dynamics
//! through c(q) = q⁻¹ + c_1 q⁻² + … (W + L − 1 parameters instead of W·L).
//! Levenberg–Marquardt runs on the reduced parameters θ' = [θ_lin, w, c_1..]
//! with the Gauss–Newton Gram G' = Mᵀ G M and gradient g' = Mᵀ g of the full
//! problem, M = ∂θ/∂θ' (every row has at most two entries). The output-error
//! problem forms them without G: its sensitivity recursion runs on S M
//! directly ([`Projected`]), so a linearisation costs O(n'²) per sample
//! instead of O(n²) (n' = W + L − 1 + n_lin against n = W·L + n_lin).
use crate::{LocalModelNetwork, NetworkSpec};
use gb_core::solver::LeastSquaresProblem;

/// Lag and column (l, i) of every hysteresis weight, in β's order: the
/// output block lag by lag, then every input's play columns lag by lag.
fn weight_map(spec: &NetworkSpec) -> (Vec<(usize, usize)>, usize) {
    let lags = spec.hysteresis_lags.max(1);
    let b = spec.output_block();
    let mut map = Vec::with_capacity(spec.n_hysteresis());
    if b > 0 {
        for l in 0..lags {
            map.extend((0..b).map(|i| (l, i)));
        }
    }
    let mut off = b;
    for cols in &spec.input_play {
        for l in 0..lags {
            map.extend((0..cols.len()).map(|i| (l, off + i)));
        }
        off += cols.len();
    }
    (map, off)
}

/// The reparametrisation of one network's parameters.
pub(crate) struct Separable {
    n_lin: usize,
    lags: usize,
    width: usize,
    map: Vec<(usize, usize)>,
}

impl Separable {
    /// `None` when the network has no hysteresis weights at several lags.
    pub(crate) fn new(net: &LocalModelNetwork) -> Option<Self> {
        let (map, width) = weight_map(&net.spec);
        let lags = net.spec.hysteresis_lags;
        if lags < 2 || width == 0 || map.len() != net.beta.len() {
            return None;
        }
        Some(Self {
            n_lin: net.n_parameters() - map.len(),
            lags,
            width,
            map,
        })
    }

    /// Number of reduced parameters.
    pub(crate) fn n_reduced(&self) -> usize {
        self.n_lin + self.width + self.lags - 1
    }

    fn c(&self, r: &[f64], l: usize) -> f64 {
        if l == 0 {
            1.0
        } else {
            r[self.n_lin + self.width + l - 1]
        }
    }

    /// Full parameters of reduced ones.
    pub(crate) fn full(&self, r: &[f64]) -> Vec<f64> {
        let mut th = r[..self.n_lin].to_vec();
        th.extend(
            self.map
                .iter()
                .map(|&(l, i)| self.c(r, l) * r[self.n_lin + i]),
        );
        th
    }

    /// The best separable approximation of full parameters: the weights
    /// as an L×W matrix B ≈ c wᵀ by alternating least squares, scaled to
    /// c_0 = 1 (a zero B gives w = 0, c = e_0).
    pub(crate) fn reduce(&self, th: &[f64]) -> Vec<f64> {
        let (lags, width) = (self.lags, self.width);
        let mut b = vec![0.0; lags * width];
        for (t, &(l, i)) in self.map.iter().enumerate() {
            b[l * width + i] = th[self.n_lin + t];
        }
        let mut c = vec![0.0; lags];
        c[0] = 1.0;
        let mut w = b[..width].to_vec();
        for _ in 0..20 {
            let ww: f64 = w.iter().map(|v| v * v).sum();
            if ww <= 1e-300 {
                break;
            }
            for (l, cl) in c.iter_mut().enumerate() {
                *cl = (0..width).map(|i| b[l * width + i] * w[i]).sum::<f64>() / ww;
            }
            let cc: f64 = c.iter().map(|v| v * v).sum();
            if cc <= 1e-300 {
                break;
            }
            for (i, wi) in w.iter_mut().enumerate() {
                *wi = (0..lags).map(|l| b[l * width + i] * c[l]).sum::<f64>() / cc;
            }
        }
        let cmax = c.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        if c[0].abs() > 1e-3 * cmax && cmax > 0.0 {
            let c0 = c[0];
            w.iter_mut().for_each(|v| *v *= c0);
            c.iter_mut().for_each(|v| *v /= c0);
        } else {
            c = vec![0.0; lags];
            c[0] = 1.0;
            w = b[..width].to_vec();
        }
        let mut r = th[..self.n_lin].to_vec();
        r.extend_from_slice(&w);
        r.extend_from_slice(&c[1..]);
        r
    }

    /// Rows of M = ∂θ/∂θ': (reduced index, value) pairs of every full
    /// parameter.
    pub(crate) fn rows(&self, r: &[f64]) -> Vec<Vec<(usize, f64)>> {
        let mut m: Vec<Vec<(usize, f64)>> = (0..self.n_lin).map(|j| vec![(j, 1.0)]).collect();
        for &(l, i) in &self.map {
            let mut row = vec![(self.n_lin + i, self.c(r, l))];
            if l > 0 {
                row.push((self.n_lin + self.width + l - 1, r[self.n_lin + i]));
            }
            m.push(row);
        }
        m
    }
}

/// A least-squares problem that can linearise in reduced parameters θ'
/// with θ = θ(θ'): the Gram matrix G' = Mᵀ G M and gradient g' = Mᵀ g,
/// M = ∂θ/∂θ' given by its rows (`(j, ∂θ_s/∂θ'_j)` for every s). The
/// default forms G and g and multiplies (O(n²) memory and work in the
/// full size n); a problem may form G' directly.
pub(crate) trait Projected: LeastSquaresProblem {
    fn linearize_projected(
        &mut self,
        theta: &[f64],
        rows: &[Vec<(usize, f64)>],
        gram: &mut [f64],
        grad: &mut [f64],
    ) -> Option<f64> {
        let nf = rows.len();
        let (mut g, mut gr) = (vec![0.0; nf * nf], vec![0.0; nf]);
        let c = self.linearize(theta, &mut g, &mut gr)?;
        project_gram(&g, &gr, rows, gram, grad);
        Some(c)
    }
}

/// G' = Mᵀ G M and g' = Mᵀ g for the rows of M (T = G M first: each row
/// of M has at most two entries); G' is n'×n' with n' = `grad.len()`.
pub(crate) fn project_gram(
    full_gram: &[f64],
    full_grad: &[f64],
    m: &[Vec<(usize, f64)>],
    gram: &mut [f64],
    grad: &mut [f64],
) {
    let (nf, nr) = (m.len(), grad.len());
    let mut t = vec![0.0; nf * nr];
    for r in 0..nf {
        let g = &full_gram[r * nf..(r + 1) * nf];
        let tr = &mut t[r * nr..(r + 1) * nr];
        for (s, row) in m.iter().enumerate() {
            for &(j, v) in row {
                tr[j] += g[s] * v;
            }
        }
    }
    gram.iter_mut().for_each(|v| *v = 0.0);
    grad.iter_mut().for_each(|v| *v = 0.0);
    for (r, row) in m.iter().enumerate() {
        for &(a, v) in row {
            grad[a] += v * full_grad[r];
            let tr = &t[r * nr..(r + 1) * nr];
            for b in 0..nr {
                gram[a * nr + b] += v * tr[b];
            }
        }
    }
}

/// A least-squares problem in full parameters seen through [`Separable`].
pub(crate) struct SeparableProblem<'a, P: Projected> {
    pub(crate) inner: &'a mut P,
    pub(crate) sep: &'a Separable,
}

impl<'a, P: Projected> SeparableProblem<'a, P> {
    pub(crate) fn new(inner: &'a mut P, sep: &'a Separable) -> Self {
        Self { inner, sep }
    }
}

impl<P: Projected> LeastSquaresProblem for SeparableProblem<'_, P> {
    fn n_params(&self) -> usize {
        self.sep.n_reduced()
    }
    fn cost(&mut self, theta: &[f64]) -> Option<f64> {
        self.inner.cost(&self.sep.full(theta))
    }
    /// G' = Mᵀ G M and g' = Mᵀ g ([`Projected`]).
    fn linearize(&mut self, theta: &[f64], gram: &mut [f64], grad: &mut [f64]) -> Option<f64> {
        let m = self.sep.rows(theta);
        self.inner
            .linearize_projected(&self.sep.full(theta), &m, gram, grad)
    }
    fn admissible(&mut self, theta: &[f64]) -> bool {
        self.inner.admissible(&self.sep.full(theta))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{HysteresisOn, IoNetworkParams};

    /// A linear network with the hysteresis columns of `on` at order 2.
    fn net(on: HysteresisOn) -> LocalModelNetwork {
        let spec = IoNetworkParams {
            hysteresis: true,
            hysteresis_on: on,
            ..IoNetworkParams::linear(2)
        }
        .network_spec(1);
        let u = vec![(0..50)
            .map(|k| (k as f64 * 0.3).sin())
            .collect::<Vec<f64>>()];
        let y: Vec<f64> = (0..50).map(|k| (k as f64 * 0.2).cos()).collect();
        let lin = crate::noe::zero_linear_network(&NetworkSpec::order(2, 1), &u, &y);
        crate::noe::embed_hysteresis(&lin, &spec).expect("same dynamic structure")
    }

    #[test]
    fn one_side_only_has_its_columns() {
        let o = net(HysteresisOn::Output).spec;
        assert!(o.input_play.iter().all(Vec::is_empty) && o.output_block() > 0);
        let i = net(HysteresisOn::Inputs).spec;
        assert!(i.output_block() == 0 && i.input_play[0].len() == 8);
    }

    #[test]
    fn a_separable_point_round_trips_and_the_gram_is_projected() {
        let n = net(HysteresisOn::Both);
        let s = Separable::new(&n).expect("three lags");
        let nr = s.n_reduced();
        let r: Vec<f64> = (0..nr)
            .map(|j| ((j * 37 % 11) as f64 - 5.0) / 7.0)
            .collect();
        let th = s.full(&r);
        let back = s.reduce(&th);
        for (a, b) in s.full(&back).iter().zip(&th) {
            assert!((a - b).abs() < 1e-9);
        }
        // a quadratic V = ½|θ − t|²: G = I, g = t − θ; the reduced gradient
        // is Mᵀ g, checked against finite differences of V(full(r))
        struct Quad(Vec<f64>);
        impl LeastSquaresProblem for Quad {
            fn n_params(&self) -> usize {
                self.0.len()
            }
            fn cost(&mut self, th: &[f64]) -> Option<f64> {
                Some(
                    0.5 * th
                        .iter()
                        .zip(&self.0)
                        .map(|(a, b)| (a - b).powi(2))
                        .sum::<f64>(),
                )
            }
            fn linearize(&mut self, th: &[f64], gram: &mut [f64], grad: &mut [f64]) -> Option<f64> {
                let n = th.len();
                gram.iter_mut().for_each(|v| *v = 0.0);
                for i in 0..n {
                    gram[i * n + i] = 1.0;
                    grad[i] = self.0[i] - th[i];
                }
                self.cost(th)
            }
        }
        impl Projected for Quad {}
        let target: Vec<f64> = (0..th.len()).map(|j| (j as f64 * 0.3).sin()).collect();
        let mut q = Quad(target);
        let mut p = SeparableProblem::new(&mut q, &s);
        let (mut gram, mut grad) = (vec![0.0; nr * nr], vec![0.0; nr]);
        p.linearize(&r, &mut gram, &mut grad).expect("finite");
        for j in 0..nr {
            let h = 1e-6;
            let (mut a, mut b) = (r.clone(), r.clone());
            a[j] += h;
            b[j] -= h;
            let d = (p.cost(&a).unwrap() - p.cost(&b).unwrap()) / (2.0 * h);
            assert!(
                (d + grad[j]).abs() < 1e-5,
                "parameter {j}: {d} vs {}",
                grad[j]
            );
        }
        for a in 0..nr {
            for b in 0..nr {
                assert!((gram[a * nr + b] - gram[b * nr + a]).abs() < 1e-12);
            }
        }
    }
}
