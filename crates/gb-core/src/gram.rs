//! The normal equations of a least-squares problem, accumulated row by row.
//!
//! A Levenberg–Marquardt linearisation needs `G = JᵀJ = Σₖ jₖ jₖᵀ` and
//! `g = Jᵀe = Σₖ jₖ eₖ` over the rows `jₖ` of the Jacobian, which the
//! simulation produces one sample at a time. A rank-one update per row
//! touches all of `G` for every sample (memory bound, ~n²/2 loads and
//! stores); [`GramAccumulator`] keeps the rows of a block and adds the
//! block's product `BᵀB` with one packed GEMM (matrixmultiply), which
//! reuses each loaded entry across the block.
//!
//! ```
//! use gb_core::gram::GramAccumulator;
//! // rows (1, 2) and (3, 4): G = [[1 + 9, 2 + 12], [2 + 12, 4 + 16]]
//! let mut g = vec![0.0; 4];
//! let mut acc = GramAccumulator::new(2);
//! acc.push(&mut g, &[1.0, 2.0]);
//! acc.push(&mut g, &[3.0, 4.0]);
//! acc.finish(&mut g);
//! assert_eq!(g, vec![10.0, 14.0, 14.0, 20.0]);
//! ```

/// Rows kept before a block is added to `G`.
const BLOCK_ROWS: usize = 128;

/// `G += Σ jₖ jₖᵀ` over pushed rows, in blocks (caller-owned `G`, `n × n`,
/// any symmetric layout: the result is symmetric). Call
/// [`finish`](Self::finish) once after the last row; until then `G` holds
/// only part of the sum.
#[derive(Debug, Clone)]
pub struct GramAccumulator {
    n: usize,
    rows: usize,
    block: Vec<f64>,
}

impl GramAccumulator {
    /// An empty accumulator for rows of length `n`.
    pub fn new(n: usize) -> Self {
        Self {
            n,
            rows: 0,
            block: vec![0.0; BLOCK_ROWS * n],
        }
    }

    /// The slot of the next row (length `n`), to be filled by the caller
    /// (every entry: the slot holds an older row). `gram` takes the block
    /// when it is full.
    #[inline]
    pub fn next_row(&mut self, gram: &mut [f64]) -> &mut [f64] {
        if self.rows == BLOCK_ROWS {
            self.flush(gram);
        }
        let n = self.n;
        let at = self.rows * n;
        self.rows += 1;
        &mut self.block[at..at + n]
    }

    /// Append the row `j` (length `n`).
    #[inline]
    pub fn push(&mut self, gram: &mut [f64], j: &[f64]) {
        self.next_row(gram).copy_from_slice(j);
    }

    /// Add the kept rows to `gram` and make it symmetric (its upper
    /// triangle, as stored column-major, copied onto the lower).
    pub fn finish(&mut self, gram: &mut [f64]) {
        self.flush(gram);
        mirror_upper(gram, self.n);
    }

    /// `gram += BᵀB` for the kept rows `B` (upper triangle at least).
    fn flush(&mut self, gram: &mut [f64]) {
        add_gram(gram, self.n, &self.block, self.rows);
        self.rows = 0;
    }
}

/// Upper triangle (column-major) of `G += BᵀB` for a row-major block `B`
/// (`rows` × n) into the `n × n` matrix `g`: packed GEMMs on column
/// panels, each covering rows 0..end of its panel, so about (1/2 + 1/2P)
/// of the full product's flops. [`GramAccumulator::finish`] mirrors it.
pub fn add_gram(g: &mut [f64], n: usize, block: &[f64], rows: usize) {
    assert!(g.len() >= n * n && block.len() >= rows * n);
    if rows == 0 || n == 0 {
        return;
    }
    let panels = if n >= 96 { 4 } else { 1 };
    for p in 0..panels {
        let (j0, j1) = (n * p / panels, n * (p + 1) / panels);
        if j1 == j0 {
            continue;
        }
        // SAFETY: Bᵀ restricted to rows 0..j1 is j1 × rows with strides
        // (1, n) into `block`; B restricted to columns j0..j1 is rows ×
        // (j1 − j0) with strides (n, 1) starting at block[j0]; both stay
        // within block[..rows·n] (checked above). C is G's columns j0..j1,
        // rows 0..j1: strides (1, n) starting at g[j0·n], inside the n × n
        // column-major storage (checked above). G does not alias `block`
        // (one is borrowed mutably).
        unsafe {
            matrixmultiply::dgemm(
                j1,
                rows,
                j1 - j0,
                1.0,
                block.as_ptr(),
                1,
                n as isize,
                block.as_ptr().add(j0),
                n as isize,
                1,
                1.0,
                g.as_mut_ptr().add(j0 * n),
                1,
                n as isize,
            );
        }
    }
}

/// Copy the upper triangle of the column-major `n × n` matrix `g` onto
/// its lower triangle (after the last [`add_gram`]).
pub fn mirror_upper(g: &mut [f64], n: usize) {
    for j in 0..n {
        for i in j + 1..n {
            g[j * n + i] = g[i * n + j];
        }
    }
}

/// `Σᵢ aᵢ bᵢ` over the common length, summed in four interleaved partial
/// sums: a plain loop is one chain of dependent additions (one add latency
/// per term), which dominates the evaluation of a network whose local
/// models and hysteresis columns have tens to hundreds of weights.
///
/// ```
/// // 1·4 + 2·5 + 3·6 + 4·7 + 5·8 = 4 + 10 + 18 + 28 + 40
/// assert_eq!(gb_core::gram::dot(&[1.0, 2.0, 3.0, 4.0, 5.0], &[4.0, 5.0, 6.0, 7.0, 8.0]), 100.0);
/// ```
#[inline]
pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut s = [0.0; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        s[0] += x[0] * y[0];
        s[1] += x[1] * y[1];
        s[2] += x[2] * y[2];
        s[3] += x[3] * y[3];
    }
    let mut tail = 0.0;
    for (x, y) in ra.iter().zip(rb) {
        tail += x * y;
    }
    (s[0] + s[2]) + (s[1] + s[3]) + tail
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The blocked sum equals the plain sum of outer products, across
    /// block boundaries and for the panelled sizes.
    #[test]
    fn blocked_gram_is_the_sum_of_outer_products() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(3);
        for &(n, rows) in &[(1, 5), (7, 300), (25, 129), (100, 260)] {
            let data: Vec<f64> = (0..n * rows).map(|_| rng.random_range(-1.0..1.0)).collect();
            let mut plain = vec![0.0; n * n];
            for r in data.chunks(n) {
                for a in 0..n {
                    for b in 0..n {
                        plain[a * n + b] += r[a] * r[b];
                    }
                }
            }
            let mut g = vec![0.5; n * n];
            let mut acc = GramAccumulator::new(n);
            for r in data.chunks(n) {
                acc.next_row(&mut g).copy_from_slice(r);
            }
            acc.finish(&mut g);
            for (x, y) in g.iter().zip(&plain) {
                assert!(
                    (x - 0.5 - y).abs() < 1e-9 * (1.0 + y.abs()),
                    "{n} {rows}: {x} vs {y}"
                );
            }
        }
    }

    /// The four-sum dot product equals the plain sum for every remainder
    /// length and ignores the longer operand's tail.
    #[test]
    fn dot_is_the_plain_sum_for_every_length() {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(5);
        for n in 0..14 {
            let a: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
            let b: Vec<f64> = (0..n + 3).map(|_| rng.random_range(-1.0..1.0)).collect();
            let plain: f64 = a.iter().zip(&b).map(|(x, y)| x * y).sum();
            assert!((dot(&a, &b) - plain).abs() < 1e-14, "{n}");
            assert!((dot(&b, &a) - plain).abs() < 1e-14, "{n}");
        }
    }
}
