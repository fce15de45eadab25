//! Single-level discrete wavelet transform: analysis (`dwt`) and synthesis (`idwt`).
//!
//! Analysis, with the extended signal `x̃` of [`Mode`]:
//! `a[i] = Σ_k dec_lo[k] x̃[2i+1+s−k]`, `d[i] = Σ_k dec_hi[k] x̃[2i+1+s−k]`,
//! with `s = 0` for the padding modes and `s = F/2−1` (indices mod the even
//! period) for `Periodization`.
//!
//! Synthesis: `x[m] = Σ_i a[i] rec_lo[p−2i] + d[i] rec_hi[p−2i]` with
//! `p = m+F−2` (padding modes; `2n−F+2` outputs) or `p = m+F/2−1` and `i` taken
//! mod `n` (`Periodization`; `2n` outputs).

use crate::error::{Result, WaveletError};
use crate::mode::Mode;
use crate::wavelet::Wavelet;

/// Number of approximation (= detail) coefficients of one analysis step.
///
/// ```
/// use gb_wavelet::{dwt_len, Mode};
/// assert_eq!(dwt_len(1001, 8, Mode::Periodization), 501);
/// assert_eq!(dwt_len(1001, 8, Mode::Symmetric), 504);
/// ```
pub fn dwt_len(signal_len: usize, filter_len: usize, mode: Mode) -> usize {
    if signal_len == 0 {
        return 0;
    }
    match mode {
        Mode::Periodization => signal_len.div_ceil(2),
        _ => (signal_len + filter_len - 1) / 2,
    }
}

/// Length of one synthesis step from `coeff_len` coefficients per band
/// (`None` if the coefficients are too short for the filter).
pub fn idwt_len(coeff_len: usize, filter_len: usize, mode: Mode) -> Option<usize> {
    if coeff_len == 0 {
        return None;
    }
    match mode {
        Mode::Periodization => Some(2 * coeff_len),
        _ => (2 * coeff_len + 2)
            .checked_sub(filter_len)
            .filter(|&l| l > 0),
    }
}

/// Value of the extended signal at (possibly out-of-range) index `idx`.
#[inline]
fn extended(x: &[f64], idx: isize, mode: Mode) -> f64 {
    let n = x.len() as isize;
    if (0..n).contains(&idx) {
        return x[idx as usize];
    }
    match mode {
        Mode::Zero => 0.0,
        Mode::Constant => {
            if idx < 0 {
                x[0]
            } else {
                x[x.len() - 1]
            }
        }
        Mode::Symmetric => {
            let p = idx.rem_euclid(2 * n);
            if p < n {
                x[p as usize]
            } else {
                x[(2 * n - 1 - p) as usize]
            }
        }
        Mode::Periodic => x[idx.rem_euclid(n) as usize],
        Mode::Periodization => {
            let period = n + (n & 1);
            let p = idx.rem_euclid(period);
            if p < n {
                x[p as usize]
            } else {
                x[x.len() - 1]
            }
        }
    }
}

/// Interior analysis kernel with a compile-time filter length.
#[inline(always)]
fn analysis_interior_fixed<const F: usize>(
    x: &[f64],
    lo: &[f64],
    hi: &[f64],
    a: &mut [f64],
    d: &mut [f64],
) {
    let lo: &[f64; F] = lo.try_into().expect("filter length checked by dispatch");
    let hi: &[f64; F] = hi.try_into().expect("filter length checked by dispatch");
    for (i, (ai, di)) in a.iter_mut().zip(d.iter_mut()).enumerate() {
        let w = &x[2 * i..2 * i + F];
        let mut sa = 0.0;
        let mut sd = 0.0;
        for j in 0..F {
            sa += lo[j] * w[j];
            sd += hi[j] * w[j];
        }
        *ai = sa;
        *di = sd;
    }
}

fn analysis_interior_dyn(x: &[f64], lo: &[f64], hi: &[f64], a: &mut [f64], d: &mut [f64]) {
    let f = lo.len();
    for (i, (ai, di)) in a.iter_mut().zip(d.iter_mut()).enumerate() {
        let w = &x[2 * i..2 * i + f];
        let mut sa = 0.0;
        let mut sd = 0.0;
        for ((l, h), v) in lo.iter().zip(hi).zip(w) {
            sa += l * v;
            sd += h * v;
        }
        *ai = sa;
        *di = sd;
    }
}

/// `a[i] = Σ_j lo[j] x[2i+j]` for the whole of `a` (needs `x.len() ≥ 2(len−1)+F`).
fn analysis_interior(x: &[f64], lo: &[f64], hi: &[f64], a: &mut [f64], d: &mut [f64]) {
    macro_rules! dispatch {
        ($($f:literal)*) => {
            match lo.len() {
                $($f => analysis_interior_fixed::<$f>(x, lo, hi, a, d),)*
                _ => analysis_interior_dyn(x, lo, hi, a, d),
            }
        };
    }
    dispatch!(2 4 6 8 10 12 14 16 18 20 22 24 26 28 30 32 34 36 38 40);
}

/// One analysis step into caller-supplied buffers (no allocation).
pub(crate) fn analysis(
    x: &[f64],
    lo_rev: &[f64],
    hi_rev: &[f64],
    mode: Mode,
    a: &mut [f64],
    d: &mut [f64],
) {
    let f = lo_rev.len() as isize;
    let n = x.len() as isize;
    let n_out = a.len() as isize;
    let s: isize = if mode == Mode::Periodization {
        f / 2 - 1
    } else {
        0
    };
    // window of output i starts at base(i) = 2i + s + 2 − F.
    let base = |i: isize| 2 * i + s + 2 - f;
    let i_lo = ((f - 2 - s).max(0) + 1) / 2;
    let i_hi = if n >= s + 2 {
        ((n - s - 2) / 2 + 1).min(n_out)
    } else {
        0
    };
    let boundary = |i: isize, a: &mut [f64], d: &mut [f64]| {
        let b = base(i);
        let mut sa = 0.0;
        let mut sd = 0.0;
        for j in 0..lo_rev.len() {
            let v = extended(x, b + j as isize, mode);
            sa += lo_rev[j] * v;
            sd += hi_rev[j] * v;
        }
        a[i as usize] = sa;
        d[i as usize] = sd;
    };
    if i_lo < i_hi {
        for i in 0..i_lo {
            boundary(i, a, d);
        }
        let (lo_u, hi_u) = (i_lo as usize, i_hi as usize);
        analysis_interior(
            &x[base(i_lo) as usize..],
            lo_rev,
            hi_rev,
            &mut a[lo_u..hi_u],
            &mut d[lo_u..hi_u],
        );
        for i in i_hi..n_out {
            boundary(i, a, d);
        }
    } else {
        for i in 0..n_out {
            boundary(i, a, d);
        }
    }
}

#[inline(always)]
fn dot<const H: usize>(w: &[f64], p: &[f64]) -> f64 {
    let w: &[f64; H] = w.try_into().expect("window length checked by dispatch");
    let p: &[f64; H] = p.try_into().expect("filter length checked by dispatch");
    let mut s = 0.0;
    for j in 0..H {
        s += w[j] * p[j];
    }
    s
}

#[inline(always)]
fn dot_dyn(w: &[f64], p: &[f64]) -> f64 {
    w.iter().zip(p).map(|(a, b)| a * b).sum()
}

/// Non-periodic synthesis: every output pair `(2u, 2u+1)` uses the windows
/// `a[u..u+H]`, `d[u..u+H]`.
#[inline(always)]
fn synthesis_pairs_fixed<const H: usize>(
    a: &[f64],
    d: &[f64],
    poly: &[Vec<f64>; 4],
    out: &mut [f64],
) {
    let [le, lo, he, ho] = poly;
    for (u, pair) in out.chunks_exact_mut(2).enumerate() {
        let wa = &a[u..u + H];
        let wd = &d[u..u + H];
        pair[0] = dot::<H>(wa, le) + dot::<H>(wd, he);
        pair[1] = dot::<H>(wa, lo) + dot::<H>(wd, ho);
    }
}

fn synthesis_pairs_dyn(a: &[f64], d: &[f64], poly: &[Vec<f64>; 4], out: &mut [f64]) {
    let h = poly[0].len();
    let [le, lo, he, ho] = poly;
    for (u, pair) in out.chunks_exact_mut(2).enumerate() {
        let wa = &a[u..u + h];
        let wd = &d[u..u + h];
        pair[0] = dot_dyn(wa, le) + dot_dyn(wd, he);
        pair[1] = dot_dyn(wa, lo) + dot_dyn(wd, ho);
    }
}

fn synthesis_pairs(a: &[f64], d: &[f64], poly: &[Vec<f64>; 4], out: &mut [f64]) {
    macro_rules! dispatch {
        ($($h:literal)*) => {
            match poly[0].len() {
                $($h => synthesis_pairs_fixed::<$h>(a, d, poly, out),)*
                _ => synthesis_pairs_dyn(a, d, poly, out),
            }
        };
    }
    dispatch!(1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19 20);
}

/// Periodization synthesis: `out[m]` with `p = m + H − 1`, `q = ⌊p/2⌋`,
/// phase `p mod 2`, window `a[q−H+1..=q]` taken mod `n`.
fn synthesis_periodization(a: &[f64], d: &[f64], poly: &[Vec<f64>; 4], out: &mut [f64]) {
    let n = a.len();
    let h = poly[0].len();
    for (m, o) in out.iter_mut().enumerate() {
        let p = m + h - 1;
        let q = p / 2;
        let (pl, ph) = if p % 2 == 0 {
            (&poly[0], &poly[2])
        } else {
            (&poly[1], &poly[3])
        };
        if q + 1 >= h && q < n {
            let lo = q + 1 - h;
            *o = dot_dyn(&a[lo..=q], pl) + dot_dyn(&d[lo..=q], ph);
        } else {
            let mut s = 0.0;
            for t in 0..h {
                // index q − H + 1 + t, mod n
                let idx = (q + n * h + 1 + t - h) % n;
                s += a[idx] * pl[t] + d[idx] * ph[t];
            }
            *o = s;
        }
    }
}

fn check_len(name: &'static str, expected: usize, got: usize) -> Result<()> {
    if expected == got {
        Ok(())
    } else {
        Err(WaveletError::BufferLength {
            name,
            expected,
            got,
        })
    }
}

impl Wavelet {
    /// Number of coefficients per band of one analysis step of a signal of
    /// `signal_len` samples (see [`dwt_len`]).
    pub fn dwt_len(&self, signal_len: usize, mode: Mode) -> usize {
        dwt_len(signal_len, self.filter_len(), mode)
    }

    /// One analysis step into caller-supplied buffers, each of length
    /// [`Wavelet::dwt_len`]. No allocation.
    ///
    /// ```
    /// use gb_wavelet::{Mode, Wavelet};
    /// let w = Wavelet::new("haar")?;
    /// let (mut a, mut d) = ([0.0; 2], [0.0; 2]);
    /// w.dwt_into(&[1.0, 3.0, 5.0, 7.0], Mode::Periodization, &mut a, &mut d)?;
    /// let r = 2f64.sqrt();
    /// assert!((a[0] - 4.0 / r).abs() < 1e-14 && (d[0] + 2.0 / r).abs() < 1e-14);
    /// # Ok::<(), gb_wavelet::WaveletError>(())
    /// ```
    pub fn dwt_into(
        &self,
        signal: &[f64],
        mode: Mode,
        approx: &mut [f64],
        detail: &mut [f64],
    ) -> Result<()> {
        if signal.is_empty() {
            return Err(WaveletError::EmptyInput("signal"));
        }
        let n_out = self.dwt_len(signal.len(), mode);
        check_len("approx", n_out, approx.len())?;
        check_len("detail", n_out, detail.len())?;
        analysis(
            signal,
            &self.dec_lo_rev,
            &self.dec_hi_rev,
            mode,
            approx,
            detail,
        );
        Ok(())
    }

    /// Output length of one synthesis step (see [`idwt_len`]).
    pub fn idwt_len(&self, coeff_len: usize, mode: Mode) -> Option<usize> {
        idwt_len(coeff_len, self.filter_len(), mode)
    }

    /// One synthesis step into a caller-supplied buffer of length
    /// [`Wavelet::idwt_len`]; `approx` and `detail` must have equal length.
    /// No allocation.
    pub fn idwt_into(
        &self,
        approx: &[f64],
        detail: &[f64],
        mode: Mode,
        out: &mut [f64],
    ) -> Result<()> {
        if approx.len() != detail.len() {
            return Err(WaveletError::ShapeMismatch(format!(
                "approximation has {} coefficients, detail {}",
                approx.len(),
                detail.len()
            )));
        }
        let len = self
            .idwt_len(approx.len(), mode)
            .ok_or(WaveletError::TooShort {
                coeff_len: approx.len(),
                filter_len: self.filter_len(),
            })?;
        check_len("out", len, out.len())?;
        synthesis(approx, detail, &self.rec_poly, mode, out);
        Ok(())
    }
}

/// Synthesis without checks (lengths already validated).
pub(crate) fn synthesis(a: &[f64], d: &[f64], poly: &[Vec<f64>; 4], mode: Mode, out: &mut [f64]) {
    if mode == Mode::Periodization {
        synthesis_periodization(a, d, poly, out);
    } else {
        synthesis_pairs(a, d, poly, out);
    }
}

/// Single-level analysis, allocating: returns `(approx, detail)` like `pywt.dwt`.
///
/// ```
/// use gb_wavelet::{dwt, idwt, Mode, Wavelet};
/// let w = Wavelet::new("db2")?;
/// let x = [1.0, 2.0, 0.5, -1.0, 3.0];
/// let (a, d) = dwt(&x, &w, Mode::Symmetric)?;
/// assert_eq!(a.len(), 4);
/// let y = idwt(&a, &d, &w, Mode::Symmetric)?;
/// assert!(x.iter().zip(&y).all(|(u, v)| (u - v).abs() < 1e-12));
/// # Ok::<(), gb_wavelet::WaveletError>(())
/// ```
pub fn dwt(signal: &[f64], wavelet: &Wavelet, mode: Mode) -> Result<(Vec<f64>, Vec<f64>)> {
    let n = wavelet.dwt_len(signal.len(), mode);
    let mut a = vec![0.0; n];
    let mut d = vec![0.0; n];
    wavelet.dwt_into(signal, mode, &mut a, &mut d)?;
    Ok((a, d))
}

/// Single-level synthesis, allocating, like `pywt.idwt`.
pub fn idwt(approx: &[f64], detail: &[f64], wavelet: &Wavelet, mode: Mode) -> Result<Vec<f64>> {
    let len = wavelet
        .idwt_len(approx.len(), mode)
        .ok_or(WaveletError::TooShort {
            coeff_len: approx.len(),
            filter_len: wavelet.filter_len(),
        })?;
    let mut out = vec![0.0; len];
    wavelet.idwt_into(approx, detail, mode, &mut out)?;
    Ok(out)
}
