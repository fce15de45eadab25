//! Pruning: after growing, merge sibling leaves whose split does not pay by
//! the criterion (Nelles 2020, sec. 14.7 "complexity reduction"; the thesis'
//! improvement of LOLIMOT). Greedy: among all inner nodes whose children are
//! both leaves, merge the one that gives the best criterion; repeat while
//! the criterion does not get worse. The merged leaf is re-estimated by
//! weighted least squares with its node's weights (tree weights: the product
//! along its path; Gaussians: its cell's normalised Gaussian, and every other
//! leaf re-estimated under the new normalisation).
use crate::hilomot::{dense_weights, info_criterion, refit_all, wls, Rows};
use crate::lmn::{split_params, Criterion, LmnModel};
use crate::regressors::Layout;
use crate::tree::{Partition, WeightKind, TINY};
use crate::LmnError;
use gb_core::Records;

/// SSE of a partition on the rows.
pub(crate) fn sse_of(part: &Partition, rows: &Rows) -> f64 {
    let (leaves, phi) = dense_weights(part, rows);
    let n = rows.n;
    let mut sse = 0.0;
    for r in 0..n {
        let mut y = 0.0;
        for (i, &l) in leaves.iter().enumerate() {
            let w = phi[i * n + r];
            if w > 0.0 {
                y += w * rows.local(r, &part.nodes[l].theta);
            }
        }
        sse += (rows.t[r] - y).powi(2);
    }
    sse
}

/// Merge node `n`'s two leaf children into `n`; returns (sse, n_eff) of the result.
fn merge(part: &mut Partition, n: usize, rows: &Rows, ridge: f64) -> Option<(f64, f64)> {
    match part.kind {
        WeightKind::Gaussian => {
            part.nodes[n].split = None;
            part.nodes[n].theta = vec![0.0; rows.p];
            refit_all(part, rows, ridge)
        }
        _ => {
            let mut s = part.scratch();
            let mut idx = Vec::new();
            let mut w = Vec::new();
            for r in 0..rows.n {
                part.weights(rows.zrow(r), &mut s);
                if s.phi[n] > TINY {
                    idx.push(r as u32);
                    w.push(s.phi[n]);
                }
            }
            let (th, ne) = wls(rows, &idx, &w, ridge, true)?;
            part.nodes[n].split = None;
            part.nodes[n].theta = th;
            part.nodes[n].n_eff = ne;
            let sse = sse_of(part, rows);
            let neff: f64 = part
                .leaves()
                .iter()
                .map(|&l| part.nodes[l].n_eff)
                .sum::<f64>()
                + split_params(part);
            Some((sse, neff))
        }
    }
}

/// Greedy pruning; returns (splits removed, final score).
pub(crate) fn prune(
    part: &mut Partition,
    rows: &Rows,
    ridge: f64,
    start: f64,
    score: &dyn Fn(&Partition, f64, f64) -> f64,
) -> (usize, f64) {
    let mut cur = start;
    let mut removed = 0;
    loop {
        let cands: Vec<usize> = part
            .inner()
            .into_iter()
            .filter(|&n| {
                part.nodes[n].split.as_ref().is_some_and(|s| {
                    part.nodes[s.left].split.is_none() && part.nodes[s.right].split.is_none()
                })
            })
            .collect();
        let mut best: Option<(f64, Partition)> = None;
        for n in cands {
            let mut t = part.clone();
            let Some((sse, neff)) = merge(&mut t, n, rows, ridge) else {
                continue;
            };
            let s = score(&t, sse, neff);
            if best.as_ref().is_none_or(|b| s < b.0) {
                best = Some((s, t));
            }
        }
        match best {
            Some((s, t)) if s <= cur => {
                *part = t;
                cur = s;
                removed += 1;
            }
            _ => break,
        }
    }
    part.compact();
    (removed, cur)
}

impl LmnModel {
    /// Prune this network on training experiments by an information criterion
    /// (AICc or BIC): merge sibling leaves while the criterion does not get
    /// worse. Returns the number of splits removed. Local models are
    /// re-estimated by local least squares (any global optimisation of the
    /// merged leaves is lost; run [`LmnModel::refine`] afterwards).
    ///
    /// ```
    /// use gb_core::{Record, Records};
    /// use gb_lmn::{Criterion, LmnParams, RegressorSpec};
    /// let u: Vec<f64> = (0..300).map(|k| (k as f64 * 0.37).sin()).collect();
    /// let y: Vec<f64> = u.iter().map(|v| 2.0 * v + 1.0).collect();
    /// let e = Records::single(Record::new(vec!["u".into()], "y".into(), vec![u], y).unwrap());
    /// let mut m = LmnParams::new(RegressorSpec::arx(0, &[1], &[0])).max_leaves(1).fit(&e).unwrap();
    /// assert_eq!(m.prune(&e, Criterion::Aicc).unwrap(), 0);
    /// ```
    pub fn prune(&mut self, train: &Records, criterion: Criterion) -> Result<usize, LmnError> {
        if criterion == Criterion::Validation {
            return Err(LmnError::InvalidArgument(
                "pruning by validation data: use LmnParams with Criterion::Validation".into(),
            ));
        }
        let nexps = self.normalise_records(train)?;
        let lay = Layout::new(&self.regressors);
        let rows = Rows::build(&lay, &nexps, self.regressors.nx());
        let ridge = 1e-8;
        let sse = sse_of(&self.partition, &rows);
        let start = info_criterion(criterion, sse, rows.n, self.effective_parameters());
        let score =
            |_: &Partition, sse: f64, neff: f64| info_criterion(criterion, sse, rows.n, neff);
        let (removed, v) = prune(&mut self.partition, &rows, ridge, start, &score);
        if removed > 0 {
            self.summary.pruned += removed;
            self.summary.criterion = criterion;
            self.summary.criterion_value = v;
        }
        Ok(removed)
    }
}
