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

/// `c + a·b` (portable kernels; the AVX2 kernels in `simd.rs` fuse it).
#[inline(always)]
fn madd(a: f64, b: f64, c: f64) -> f64 {
    a * b + c
}

/// Outputs per block of the vectorised kernels.
const BLOCK: usize = 8;
/// Largest half filter length with a specialised portable kernel (`F ≤ 12`).
const MAX_HALF: usize = 6;

/// Interior analysis kernel, half filter length `H` known at compile time:
/// `a[i] = Σ_t lo[2t] x[2i+2t] + lo[2t+1] x[2i+2t+1]` (polyphase form),
/// computed for `BLOCK` consecutive outputs at once on a deinterleaved copy of
/// the input window so that the inner loops run over contiguous data.
#[inline(always)]
fn analysis_interior_fixed<const H: usize>(
    x: &[f64],
    lo: &[f64],
    hi: &[f64],
    a: &mut [f64],
    d: &mut [f64],
) {
    let mut lo_e = [0.0; H];
    let mut lo_o = [0.0; H];
    let mut hi_e = [0.0; H];
    let mut hi_o = [0.0; H];
    for t in 0..H {
        lo_e[t] = lo[2 * t];
        lo_o[t] = lo[2 * t + 1];
        hi_e[t] = hi[2 * t];
        hi_o[t] = hi[2 * t + 1];
    }
    let n = a.len();
    let full = n - n % BLOCK;
    let span = BLOCK + H - 1;
    let mut xe = [0.0; BLOCK + MAX_HALF];
    let mut xo = [0.0; BLOCK + MAX_HALF];
    for i0 in (0..full).step_by(BLOCK) {
        let xs = &x[2 * i0..2 * i0 + 2 * span];
        for k in 0..span {
            xe[k] = xs[2 * k];
            xo[k] = xs[2 * k + 1];
        }
        let mut sa = [0.0; BLOCK];
        let mut sd = [0.0; BLOCK];
        for t in 0..H {
            for l in 0..BLOCK {
                sa[l] = madd(lo_e[t], xe[t + l], sa[l]);
                sa[l] = madd(lo_o[t], xo[t + l], sa[l]);
                sd[l] = madd(hi_e[t], xe[t + l], sd[l]);
                sd[l] = madd(hi_o[t], xo[t + l], sd[l]);
            }
        }
        a[i0..i0 + BLOCK].copy_from_slice(&sa);
        d[i0..i0 + BLOCK].copy_from_slice(&sd);
    }
    analysis_interior_dyn(&x[2 * full..], lo, hi, &mut a[full..], &mut d[full..]);
}

#[inline(always)]
fn analysis_interior_dyn(x: &[f64], lo: &[f64], hi: &[f64], a: &mut [f64], d: &mut [f64]) {
    let f = lo.len();
    for (i, (ai, di)) in a.iter_mut().zip(d.iter_mut()).enumerate() {
        let w = &x[2 * i..2 * i + f];
        let mut sa = 0.0;
        let mut sd = 0.0;
        for ((l, h), v) in lo.iter().zip(hi).zip(w) {
            sa = madd(*l, *v, sa);
            sd = madd(*h, *v, sd);
        }
        *ai = sa;
        *di = sd;
    }
}

#[inline(always)]
fn analysis_interior_generic(x: &[f64], lo: &[f64], hi: &[f64], a: &mut [f64], d: &mut [f64]) {
    macro_rules! dispatch {
        ($($h:literal)*) => {
            match lo.len() / 2 {
                $($h => analysis_interior_fixed::<$h>(x, lo, hi, a, d),)*
                _ => analysis_interior_dyn(x, lo, hi, a, d),
            }
        };
    }
    // Longer filters: the blocked kernel spills registers; the plain loop is faster.
    dispatch!(1 2 3 4 5 6);
}

/// `a[i] = Σ_j lo[j] x[2i+j]` for the whole of `a` (needs `x.len() ≥ 2(len−1)+F`).
fn analysis_interior(x: &[f64], lo: &[f64], hi: &[f64], a: &mut [f64], d: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    if lo.len() / 2 <= crate::simd::MAX_HALF && crate::simd::available() {
        // SAFETY: AVX2 and FMA are available, 1 ≤ H ≤ MAX_HALF, and the caller
        // guarantees the input window covers every output.
        let done = unsafe { crate::simd::analysis(x, lo, hi, a, d) };
        analysis_interior_dyn(&x[2 * done..], lo, hi, &mut a[done..], &mut d[done..]);
        return;
    }
    analysis_interior_generic(x, lo, hi, a, d);
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

/// Synthesis pairs kernel, `H` known at compile time: output pair
/// `(2u, 2u+1)` uses the windows `a[u..u+H]`, `d[u..u+H]` with the even and odd
/// polyphase components; `BLOCK` pairs at a time.
#[inline(always)]
fn synthesis_pairs_fixed<const H: usize>(
    a: &[f64],
    d: &[f64],
    poly: &[Vec<f64>; 4],
    out: &mut [f64],
) {
    let mut le = [0.0; H];
    let mut lo = [0.0; H];
    let mut he = [0.0; H];
    let mut ho = [0.0; H];
    le.copy_from_slice(&poly[0][..H]);
    lo.copy_from_slice(&poly[1][..H]);
    he.copy_from_slice(&poly[2][..H]);
    ho.copy_from_slice(&poly[3][..H]);
    let pairs = out.len() / 2;
    let full = pairs - pairs % BLOCK;
    let span = BLOCK + H - 1;
    for u0 in (0..full).step_by(BLOCK) {
        let wa = &a[u0..u0 + span];
        let wd = &d[u0..u0 + span];
        let mut ev = [0.0; BLOCK];
        let mut od = [0.0; BLOCK];
        for t in 0..H {
            for l in 0..BLOCK {
                ev[l] = madd(le[t], wa[t + l], ev[l]);
                ev[l] = madd(he[t], wd[t + l], ev[l]);
                od[l] = madd(lo[t], wa[t + l], od[l]);
                od[l] = madd(ho[t], wd[t + l], od[l]);
            }
        }
        let o = &mut out[2 * u0..2 * u0 + 2 * BLOCK];
        for l in 0..BLOCK {
            o[2 * l] = ev[l];
            o[2 * l + 1] = od[l];
        }
    }
    synthesis_pairs_dyn(&a[full..], &d[full..], poly, &mut out[2 * full..]);
}

#[inline(always)]
fn synthesis_pairs_dyn(a: &[f64], d: &[f64], poly: &[Vec<f64>; 4], out: &mut [f64]) {
    let h = poly[0].len();
    let [le, lo, he, ho] = poly;
    for (u, pair) in out.chunks_exact_mut(2).enumerate() {
        let wa = &a[u..u + h];
        let wd = &d[u..u + h];
        let (mut ev, mut od) = (0.0, 0.0);
        for t in 0..h {
            ev = madd(le[t], wa[t], ev);
            ev = madd(he[t], wd[t], ev);
            od = madd(lo[t], wa[t], od);
            od = madd(ho[t], wd[t], od);
        }
        pair[0] = ev;
        pair[1] = od;
    }
}

#[inline(always)]
fn synthesis_pairs_generic(a: &[f64], d: &[f64], poly: &[Vec<f64>; 4], out: &mut [f64]) {
    macro_rules! dispatch {
        ($($h:literal)*) => {
            match poly[0].len() {
                $($h => synthesis_pairs_fixed::<$h>(a, d, poly, out),)*
                _ => synthesis_pairs_dyn(a, d, poly, out),
            }
        };
    }
    // Longer filters: the blocked kernel spills registers; the plain loop is faster.
    dispatch!(1 2 3 4 5 6);
}

/// `out[2u] = a[u..u+H]·lo_even + d[u..u+H]·hi_even`, `out[2u+1]` likewise with
/// the odd components, for every pair of `out` (needs `a.len() ≥ out.len()/2 + H − 1`).
fn synthesis_pairs(a: &[f64], d: &[f64], poly: &[Vec<f64>; 4], out: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    if crate::simd::available() {
        // SAFETY: AVX2 and FMA are available and the caller guarantees the
        // coefficient windows cover every output pair.
        let done = unsafe { crate::simd::synthesis_pairs(a, d, poly, out) };
        synthesis_pairs_dyn(&a[done..], &d[done..], poly, &mut out[2 * done..]);
        return;
    }
    synthesis_pairs_generic(a, d, poly, out);
}

/// Periodization synthesis: `out[m]` with `p = m + H − 1`, `q = ⌊p/2⌋`,
/// phase `p mod 2`, window `a[q−H+1..=q]` taken mod `n`. The interior, where
/// no index wraps, runs through the pairs kernel.
fn synthesis_periodization(a: &[f64], d: &[f64], poly: &[Vec<f64>; 4], out: &mut [f64]) {
    let n = a.len();
    let h = poly[0].len();
    let one = |m: usize| -> f64 {
        let p = m + h - 1;
        let q = p / 2;
        let (pl, ph) = if p % 2 == 0 {
            (&poly[0], &poly[2])
        } else {
            (&poly[1], &poly[3])
        };
        let mut s = 0.0;
        for t in 0..h {
            // index q − H + 1 + t, mod n
            let idx = (q + n * h + 1 + t - h) % n;
            s += a[idx] * pl[t] + d[idx] * ph[t];
        }
        s
    };
    // Pairs sharing a window: (2u, 2u+1) for odd H, (2u+1, 2u+2) for even H,
    // with window start u − c.
    let (c, first_out) = if h % 2 == 1 {
        ((h - 1) / 2, 0)
    } else {
        ((h - 2) / 2, 1)
    };
    let u_lo = c;
    let u_hi = (n + c + 1).saturating_sub(h);
    let (m_lo, m_hi) = if u_hi > u_lo {
        let m_lo = 2 * u_lo + first_out;
        let m_hi = (2 * u_hi + first_out).min(2 * n);
        // keep whole pairs only
        let m_hi = m_lo + (m_hi - m_lo) / 2 * 2;
        synthesis_pairs(&a[u_lo - c..], &d[u_lo - c..], poly, &mut out[m_lo..m_hi]);
        (m_lo, m_hi)
    } else {
        (0, 0)
    };
    for m in (0..m_lo).chain(m_hi..2 * n) {
        out[m] = one(m);
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
    if approx.len() != detail.len() {
        return Err(WaveletError::ShapeMismatch(format!(
            "approximation has {} coefficients, detail {}",
            approx.len(),
            detail.len()
        )));
    }
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

/// Portable analysis interior (for comparing the SIMD kernels in tests).
#[cfg(test)]
pub(crate) fn analysis_portable(x: &[f64], lo: &[f64], hi: &[f64], a: &mut [f64], d: &mut [f64]) {
    analysis_interior_generic(x, lo, hi, a, d);
}

/// Portable synthesis pairs (for comparing the SIMD kernels in tests).
#[cfg(test)]
pub(crate) fn synthesis_pairs_portable(
    a: &[f64],
    d: &[f64],
    poly: &[Vec<f64>; 4],
    out: &mut [f64],
) {
    synthesis_pairs_generic(a, d, poly, out);
}
