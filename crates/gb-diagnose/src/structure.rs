//! The structure of the baseline read from the training data before any
//! output-error fit: the input delay per input (a least-squares ARX scan of
//! n_k) and whether the output integrates (a real ARX pole at 1).
//!
//! The scan only proposes: the candidates it returns are confirmed by the
//! output-error fit on the decision data (`diagnose::baseline`).
use gb_core::{metrics, Record};
use nalgebra::{DMatrix, DVector};

/// What the ARX scan found.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Scan {
    /// The n_k vector with the smallest ARX loss.
    pub best: Vec<usize>,
    /// The real pole of the best ARX model closest to 1.
    pub real_pole: f64,
}

/// One record's normalised inputs and output.
type Normalised = (Vec<Vec<f64>>, Vec<f64>);

/// Least-squares ARX model y(k) = c + Σ aᵢ y(k−i) + Σⱼ Σ_{l = nkⱼ..=last}
/// bⱼₗ uⱼ(k−l) on signals normalised to unit variance, scored from `start`
/// of every record of `data` (the union of their rows: no regressor spans
/// two records): the mean squared one-step error, the number of parameters
/// and the `a` coefficients. `None` when the normal equations are singular.
fn arx(
    data: &[Normalised],
    na: usize,
    nk: &[usize],
    last: usize,
    start: usize,
) -> Option<(f64, usize, Vec<f64>)> {
    let p = 1
        + na
        + nk.iter()
            .map(|&k| last + 1 - k.min(last + 1))
            .sum::<usize>();
    let n_rows: usize = data
        .iter()
        .map(|(_, y)| y.len().saturating_sub(start))
        .sum();
    if n_rows < 2 * p + 10 {
        return None;
    }
    let mut g = DMatrix::<f64>::zeros(p, p);
    let mut h = DVector::<f64>::zeros(p);
    let mut phi = vec![0.0; p];
    let mut yy = 0.0;
    for (u, y) in data {
        accumulate(
            u,
            y,
            (na, nk, last, start),
            &mut phi,
            (&mut g, &mut h, &mut yy),
        );
    }
    for a in 0..p {
        for b in 0..a {
            g[(a, b)] = g[(b, a)];
        }
    }
    let ridge = 1e-9 * (0..p).map(|i| g[(i, i)]).fold(0.0, f64::max);
    for i in 0..p {
        g[(i, i)] += ridge;
    }
    let theta = g.clone().cholesky()?.solve(&h);
    // Σ e² = yᵀy − 2θᵀh + θᵀGθ
    let sse = yy - 2.0 * theta.dot(&h) + theta.dot(&(&g * &theta));
    let rows = n_rows as f64;
    Some((
        (sse / rows).max(1e-300),
        p,
        theta.iter().skip(1).take(na).copied().collect(),
    ))
}

/// Add one record's ARX rows k = start..n to the upper triangle of
/// G = Σ φφᵀ, to h = Σ φ y and to yᵀy.
fn accumulate(
    u: &[Vec<f64>],
    y: &[f64],
    (na, nk, last, start): (usize, &[usize], usize, usize),
    phi: &mut [f64],
    (g, h, yy): (&mut DMatrix<f64>, &mut DVector<f64>, &mut f64),
) {
    let (p, n) = (phi.len(), y.len());
    for k in start..n {
        phi[0] = 1.0;
        for i in 1..=na {
            phi[i] = y[k - i];
        }
        let mut c = 1 + na;
        for (j, uj) in u.iter().enumerate() {
            for l in nk[j]..=last {
                phi[c] = uj[k - l];
                c += 1;
            }
        }
        for a in 0..p {
            let pa = phi[a];
            h[a] += pa * y[k];
            for b in a..p {
                g[(a, b)] += pa * phi[b];
            }
        }
        *yy += y[k] * y[k];
    }
}

/// The real root of z^na − a₁ z^{na−1} − … − a_na closest to 1 (−∞ when
/// there is none).
fn real_pole_near_one(a: &[f64]) -> f64 {
    let n = a.len();
    if n == 0 {
        return f64::NEG_INFINITY;
    }
    let mut c = DMatrix::<f64>::zeros(n, n);
    for (i, ai) in a.iter().enumerate() {
        c[(0, i)] = *ai;
    }
    for i in 1..n {
        c[(i, i - 1)] = 1.0;
    }
    c.complex_eigenvalues()
        .iter()
        .filter(|z| z.im.abs() < 1e-6 * (1.0 + z.re.abs()))
        .map(|z| z.re)
        .min_by(|x, y| (x - 1.0).abs().total_cmp(&(y - 1.0).abs()))
        .unwrap_or(f64::NEG_INFINITY)
}

/// Every signal `xs[i]` normalised by the mean and standard deviation of
/// all of them together.
fn normalised(xs: &[&[f64]]) -> Vec<Vec<f64>> {
    let all = xs.concat();
    let m = metrics::mean(&all);
    let s = metrics::std(&all);
    let s = if s > 0.0 && s.is_finite() { s } else { 1.0 };
    xs.iter()
        .map(|x| x.iter().map(|v| (v - m) / s).collect())
        .collect()
}

/// Scan the input delay of every input over `0..=max_delay` on the records
/// `fits` (separate experiments: their first `max_samples` samples in
/// order, normalised together, the ARX rows of each after its own first
/// `start` samples). The ARX models have n_a = max(order, 2)
/// output lags and the input lags nk..=max_delay + n_a: nested models, so
/// dropping leading lags that carry nothing lowers the Bayesian information
/// criterion N ln σ² + p ln N, and dropping a lag that carries the response
/// raises it. The delay minimises it, by coordinate descent over the inputs
/// (two passes). It proposes (the output-error scan and check decide): with
/// output noise an ARX model is biased, and on oversampled records the
/// output lags amplify the noise of the equation error.
pub(crate) fn scan(fits: &[Record], order: usize, max_delay: usize, max_samples: usize) -> Scan {
    // the first max_samples samples of the records, in order
    let mut left = max_samples;
    let lens: Vec<usize> = fits
        .iter()
        .map(|r| {
            let n = r.len().min(left);
            left -= n;
            n
        })
        .collect();
    let m = fits.first().map_or(0, Record::n_inputs);
    let signal = |x: &dyn Fn(&Record) -> &[f64]| -> Vec<Vec<f64>> {
        let parts: Vec<&[f64]> = fits.iter().zip(&lens).map(|(r, &n)| &x(r)[..n]).collect();
        normalised(&parts)
    };
    let mut u: Vec<Vec<Vec<f64>>> = (0..m).map(|j| signal(&|r: &Record| &r.inputs[j])).collect();
    let data: Vec<Normalised> = signal(&|r: &Record| &r.output)
        .into_iter()
        .enumerate()
        .map(|(i, y)| {
            (
                u.iter_mut().map(|uj| std::mem::take(&mut uj[i])).collect(),
                y,
            )
        })
        .collect();
    let na = order.max(2);
    let last = max_delay + na;
    let start = last.max(na);
    let rows = lens
        .iter()
        .map(|n| n.saturating_sub(start))
        .sum::<usize>()
        .max(1) as f64;
    let bic = |t: &[usize]| {
        arx(&data, na, t, last, start).map_or(f64::INFINITY, |(l, p, _)| {
            rows * l.ln() + p as f64 * rows.ln()
        })
    };
    let mut best = vec![1usize.min(max_delay); m];
    let mut best_bic = bic(&best);
    for _pass in 0..2 {
        for j in 0..m {
            for d in 0..=max_delay {
                let mut t = best.clone();
                t[j] = d;
                let b = bic(&t);
                if b < best_bic - 1e-9 {
                    best_bic = b;
                    best = t;
                }
            }
        }
    }
    let real_pole = arx(&data, na, &best, last, start)
        .map_or(f64::NEG_INFINITY, |(_, _, a)| real_pole_near_one(&a));
    Scan { best, real_pole }
}

/// The increments Δy(k) = y(k) − y(k−1) of a record's output, with
/// Δy(0) = Δy(1) (the record keeps its length and alignment).
pub fn increments(r: &Record) -> Record {
    let mut out = r.clone();
    let y = &r.output;
    for k in (1..y.len()).rev() {
        out.output[k] = y[k] - y[k - 1];
    }
    if y.len() > 1 {
        out.output[0] = out.output[1];
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand_distr::{Distribution, StandardNormal};

    /// y(k) = 1.5 y(k−1) − 0.7 y(k−2) + u(k−d) + 0.5 u(k−d−1) + noise, and
    /// optionally a feedthrough term when d = 0.
    fn record(d: usize, n: usize, seed: u64) -> Record {
        let mut r = gb_core::rng::seeded(seed);
        let u: Vec<f64> = (0..n).map(|_| StandardNormal.sample(&mut r)).collect();
        let mut y = vec![0.0; n];
        for k in 2..n {
            let uk = |l: usize| if k >= d + l { u[k - d - l] } else { 0.0 };
            y[k] = 1.5 * y[k - 1] - 0.7 * y[k - 2] + uk(0) + 0.5 * uk(1);
        }
        let e: Vec<f64> = (0..n)
            .map(|_| {
                let v: f64 = StandardNormal.sample(&mut r);
                0.05 * v
            })
            .collect();
        let y = y.iter().zip(&e).map(|(a, b)| a + b).collect();
        Record::new(vec!["u".into()], "y".into(), vec![u], y).unwrap()
    }

    #[test]
    fn the_scan_finds_delay_feedthrough_and_dead_time() {
        for (d, seed) in [(0usize, 1u64), (1, 2), (3, 3), (9, 4), (17, 5)] {
            let s = scan(&[record(d, 2000, seed)], 2, 20, 100_000);
            assert_eq!(s.best, vec![d], "true delay {d}");
            assert!(s.real_pole < 0.99, "{}", s.real_pole);
        }
    }

    #[test]
    fn an_integrator_shows_a_real_pole_at_one() {
        let r = record(1, 3000, 7);
        let mut pos = r.clone();
        let mut acc = 0.0;
        for k in 0..pos.len() {
            acc += 0.1 * r.output[k];
            pos.output[k] = acc;
        }
        let s = scan(std::slice::from_ref(&pos), 2, 20, 100_000);
        assert!((s.real_pole - 1.0).abs() < 0.01, "{}", s.real_pole);
        let back = increments(&pos);
        assert!((back.output[5] - 0.1 * r.output[5]).abs() < 1e-12);
        assert_eq!(back.output[0], back.output[1]);
    }
}
