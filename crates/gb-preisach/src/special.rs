//! Special functions: the complementary error function and the normal and
//! Cauchy distribution functions used by the parametric Everett functions.
//!
//! `erfc` is a port of FreeBSD `s_erf.c` (via the MIT-licensed Rust `libm`
//! crate); accuracy about one ulp. Original notice:
//!
//! Copyright (C) 1993 by Sun Microsystems, Inc. All rights reserved.
//! Developed at SunPro, a Sun Microsystems, Inc. business.
//! Permission to use, copy, modify, and distribute this
//! software is freely granted, provided that this notice
//! is preserved.
#![allow(clippy::excessive_precision, clippy::unreadable_literal)]

const ERX: f64 = 8.45062911510467529297e-01; /* 0x3FEB0AC1, 0x60000000 */
/*
 * Coefficients for approximation to  erf on [0,0.84375]
 */
const PP0: f64 = 1.28379167095512558561e-01; /* 0x3FC06EBA, 0x8214DB68 */
const PP1: f64 = -3.25042107247001499370e-01; /* 0xBFD4CD7D, 0x691CB913 */
const PP2: f64 = -2.84817495755985104766e-02; /* 0xBF9D2A51, 0xDBD7194F */
const PP3: f64 = -5.77027029648944159157e-03; /* 0xBF77A291, 0x236668E4 */
const PP4: f64 = -2.37630166566501626084e-05; /* 0xBEF8EAD6, 0x120016AC */
const QQ1: f64 = 3.97917223959155352819e-01; /* 0x3FD97779, 0xCDDADC09 */
const QQ2: f64 = 6.50222499887672944485e-02; /* 0x3FB0A54C, 0x5536CEBA */
const QQ3: f64 = 5.08130628187576562776e-03; /* 0x3F74D022, 0xC4D36B0F */
const QQ4: f64 = 1.32494738004321644526e-04; /* 0x3F215DC9, 0x221C1A10 */
const QQ5: f64 = -3.96022827877536812320e-06; /* 0xBED09C43, 0x42A26120 */
/*
 * Coefficients for approximation to  erf  in [0.84375,1.25]
 */
const PA0: f64 = -2.36211856075265944077e-03; /* 0xBF6359B8, 0xBEF77538 */
const PA1: f64 = 4.14856118683748331666e-01; /* 0x3FDA8D00, 0xAD92B34D */
const PA2: f64 = -3.72207876035701323847e-01; /* 0xBFD7D240, 0xFBB8C3F1 */
const PA3: f64 = 3.18346619901161753674e-01; /* 0x3FD45FCA, 0x805120E4 */
const PA4: f64 = -1.10894694282396677476e-01; /* 0xBFBC6398, 0x3D3E28EC */
const PA5: f64 = 3.54783043256182359371e-02; /* 0x3FA22A36, 0x599795EB */
const PA6: f64 = -2.16637559486879084300e-03; /* 0xBF61BF38, 0x0A96073F */
const QA1: f64 = 1.06420880400844228286e-01; /* 0x3FBB3E66, 0x18EEE323 */
const QA2: f64 = 5.40397917702171048937e-01; /* 0x3FE14AF0, 0x92EB6F33 */
const QA3: f64 = 7.18286544141962662868e-02; /* 0x3FB2635C, 0xD99FE9A7 */
const QA4: f64 = 1.26171219808761642112e-01; /* 0x3FC02660, 0xE763351F */
const QA5: f64 = 1.36370839120290507362e-02; /* 0x3F8BEDC2, 0x6B51DD1C */
const QA6: f64 = 1.19844998467991074170e-02; /* 0x3F888B54, 0x5735151D */
/*
 * Coefficients for approximation to  erfc in [1.25,1/0.35]
 */
const RA0: f64 = -9.86494403484714822705e-03; /* 0xBF843412, 0x600D6435 */
const RA1: f64 = -6.93858572707181764372e-01; /* 0xBFE63416, 0xE4BA7360 */
const RA2: f64 = -1.05586262253232909814e+01; /* 0xC0251E04, 0x41B0E726 */
const RA3: f64 = -6.23753324503260060396e+01; /* 0xC04F300A, 0xE4CBA38D */
const RA4: f64 = -1.62396669462573470355e+02; /* 0xC0644CB1, 0x84282266 */
const RA5: f64 = -1.84605092906711035994e+02; /* 0xC067135C, 0xEBCCABB2 */
const RA6: f64 = -8.12874355063065934246e+01; /* 0xC0545265, 0x57E4D2F2 */
const RA7: f64 = -9.81432934416914548592e+00; /* 0xC023A0EF, 0xC69AC25C */
const SA1: f64 = 1.96512716674392571292e+01; /* 0x4033A6B9, 0xBD707687 */
const SA2: f64 = 1.37657754143519042600e+02; /* 0x4061350C, 0x526AE721 */
const SA3: f64 = 4.34565877475229228821e+02; /* 0x407B290D, 0xD58A1A71 */
const SA4: f64 = 6.45387271733267880336e+02; /* 0x40842B19, 0x21EC2868 */
const SA5: f64 = 4.29008140027567833386e+02; /* 0x407AD021, 0x57700314 */
const SA6: f64 = 1.08635005541779435134e+02; /* 0x405B28A3, 0xEE48AE2C */
const SA7: f64 = 6.57024977031928170135e+00; /* 0x401A47EF, 0x8E484A93 */
const SA8: f64 = -6.04244152148580987438e-02; /* 0xBFAEEFF2, 0xEE749A62 */
/*
 * Coefficients for approximation to  erfc in [1/.35,28]
 */
const RB0: f64 = -9.86494292470009928597e-03; /* 0xBF843412, 0x39E86F4A */
const RB1: f64 = -7.99283237680523006574e-01; /* 0xBFE993BA, 0x70C285DE */
const RB2: f64 = -1.77579549177547519889e+01; /* 0xC031C209, 0x555F995A */
const RB3: f64 = -1.60636384855821916062e+02; /* 0xC064145D, 0x43C5ED98 */
const RB4: f64 = -6.37566443368389627722e+02; /* 0xC083EC88, 0x1375F228 */
const RB5: f64 = -1.02509513161107724954e+03; /* 0xC0900461, 0x6A2E5992 */
const RB6: f64 = -4.83519191608651397019e+02; /* 0xC07E384E, 0x9BDC383F */
const SB1: f64 = 3.03380607434824582924e+01; /* 0x403E568B, 0x261D5190 */
const SB2: f64 = 3.25792512996573918826e+02; /* 0x40745CAE, 0x221B9F0A */
const SB3: f64 = 1.53672958608443695994e+03; /* 0x409802EB, 0x189D5118 */
const SB4: f64 = 3.19985821950859553908e+03; /* 0x40A8FFB7, 0x688C246A */
const SB5: f64 = 2.55305040643316442583e+03; /* 0x40A3F219, 0xCEDF3BE6 */
const SB6: f64 = 4.74528541206955367215e+02; /* 0x407DA874, 0xE79FE763 */
const SB7: f64 = -2.24409524465858183362e+01; /* 0xC03670E2, 0x42712D62 */

#[inline]
fn erfc1(x: f64) -> f64 {
    let s = x.abs() - 1.0;
    let p = PA0 + s * (PA1 + s * (PA2 + s * (PA3 + s * (PA4 + s * (PA5 + s * PA6)))));
    let q = 1.0 + s * (QA1 + s * (QA2 + s * (QA3 + s * (QA4 + s * (QA5 + s * QA6)))));
    1.0 - ERX - p / q
}

#[inline]
fn erfc2(ix: u32, x: f64) -> f64 {
    if ix < 0x3ff40000 {
        return erfc1(x);
    }
    let x = x.abs();
    let s = 1.0 / (x * x);
    let (r, big_s) = if ix < 0x4006db6d {
        (
            RA0 + s * (RA1 + s * (RA2 + s * (RA3 + s * (RA4 + s * (RA5 + s * (RA6 + s * RA7)))))),
            1.0 + s
                * (SA1
                    + s * (SA2
                        + s * (SA3 + s * (SA4 + s * (SA5 + s * (SA6 + s * (SA7 + s * SA8))))))),
        )
    } else {
        (
            RB0 + s * (RB1 + s * (RB2 + s * (RB3 + s * (RB4 + s * (RB5 + s * RB6))))),
            1.0 + s * (SB1 + s * (SB2 + s * (SB3 + s * (SB4 + s * (SB5 + s * (SB6 + s * SB7)))))),
        )
    };
    let z = f64::from_bits(x.to_bits() & 0xffff_ffff_0000_0000);
    (-z * z - 0.5625).exp() * ((z - x) * (z + x) + r / big_s).exp() / x
}

/// Complementary error function erfc(x) = 1 − erf(x), about 1 ulp.
pub fn erfc(x: f64) -> f64 {
    let hi = (x.to_bits() >> 32) as u32;
    let sign = hi >> 31 != 0;
    let ix = hi & 0x7fffffff;
    if ix >= 0x7ff00000 {
        // NaN, ±∞
        return if sign { 2.0 } else { 0.0 } + 1.0 / x;
    }
    if ix < 0x3feb0000 {
        // |x| < 0.84375
        if ix < 0x3c700000 {
            return 1.0 - x;
        }
        let z = x * x;
        let r = PP0 + z * (PP1 + z * (PP2 + z * (PP3 + z * PP4)));
        let s = 1.0 + z * (QQ1 + z * (QQ2 + z * (QQ3 + z * (QQ4 + z * QQ5))));
        let y = r / s;
        if sign || ix < 0x3fd00000 {
            return 1.0 - (x + x * y);
        }
        return 0.5 - (x - 0.5 + x * y);
    }
    if ix < 0x403c0000 {
        // 0.84375 <= |x| < 28
        return if sign {
            2.0 - erfc2(ix, x)
        } else {
            erfc2(ix, x)
        };
    }
    if sign {
        2.0
    } else {
        0.0
    }
}

/// Standard normal distribution function Φ(z) = erfc(−z/√2)/2.
#[inline]
pub fn normal_cdf(z: f64) -> f64 {
    0.5 * erfc(-z * std::f64::consts::FRAC_1_SQRT_2)
}

const PHI_LO: f64 = -9.0;
const PHI_INV_H: f64 = 16.0;
const PHI_CELLS: usize = 288;
const PHI_DEG: usize = 8;

/// One table cell: 8 coefficients in one 64-byte cache line, stored as the
/// pairs (c₀, c₄), (c₁, c₅), (c₂, c₆), (c₃, c₇) so the two halves of the
/// Estrin scheme run as one two-lane vector.
#[derive(Clone, Copy)]
#[repr(align(64))]
pub(crate) struct PhiCell([f64; PHI_DEG]);

pub(crate) type PhiTable = [PhiCell; PHI_CELLS];
static PHI_TABLE: std::sync::OnceLock<Box<PhiTable>> = std::sync::OnceLock::new();

/// Piecewise polynomial table of Φ on [−9, 9]: 288 cells of width 1/16, each
/// the degree-7 Chebyshev interpolant of Φ (from [`erfc`]) written in
/// monomials of w = u/2 ∈ [−½, ½] (u ∈ [−1, 1] the Chebyshev variable; the
/// coefficients are scaled by 2^m, exactly).
#[allow(clippy::needless_range_loop)]
pub(crate) fn phi_table() -> &'static PhiTable {
    PHI_TABLE.get_or_init(|| {
        let k = PHI_DEG;
        let nodes: Vec<f64> = (0..k)
            .map(|i| (std::f64::consts::PI * (i as f64 + 0.5) / k as f64).cos())
            .collect();
        // Monomial coefficients of T_0..T_{k-1}.
        let mut t = vec![vec![0.0; k]; k];
        t[0][0] = 1.0;
        t[1][1] = 1.0;
        for j in 2..k {
            for m in 0..k {
                let shifted = if m > 0 { 2.0 * t[j - 1][m - 1] } else { 0.0 };
                t[j][m] = shifted - t[j - 2][m];
            }
        }
        (0..PHI_CELLS)
            .map(|cell| {
                let z0 = PHI_LO + cell as f64 / PHI_INV_H;
                let f: Vec<f64> = nodes
                    .iter()
                    .map(|u| normal_cdf(z0 + (u + 1.0) * 0.5 / PHI_INV_H))
                    .collect();
                let mut mono = [0.0; PHI_DEG];
                for j in 0..k {
                    let mut c: f64 = (0..k)
                        .map(|i| {
                            f[i] * (std::f64::consts::PI * j as f64 * (i as f64 + 0.5) / k as f64)
                                .cos()
                        })
                        .sum::<f64>()
                        * 2.0
                        / k as f64;
                    if j == 0 {
                        c *= 0.5;
                    }
                    for m in 0..k {
                        mono[m] += c * t[j][m];
                    }
                }
                for (m, v) in mono.iter_mut().enumerate() {
                    *v *= (1u32 << m) as f64;
                }
                let [c0, c1, c2, c3, c4, c5, c6, c7] = mono;
                PhiCell([c0, c4, c1, c5, c2, c6, c3, c7])
            })
            .collect::<Vec<_>>()
            .try_into()
            .unwrap_or_else(|_| unreachable!())
    })
}

/// Cell coordinate t = (z − z_lo)·16 − ½ of the [`phi_table`] for z (cell i
/// is t ∈ [i − ½, i + ½)): Φ(z) is [`normal_cdf_at`]`(table, z·16 + 143.5)`.
pub(crate) const PHI_T_SCALE: f64 = PHI_INV_H;
/// Offset of the cell coordinate (−z_lo·16 − ½).
pub(crate) const PHI_T_OFFSET: f64 = -PHI_LO * PHI_INV_H - 0.5;

/// Lowest table coordinate of the [`phi_table`] (cell 0 is t ∈ [−½, ½)).
pub(crate) const PHI_T_MIN: f64 = -0.5;
/// End of the table coordinates (exclusive).
pub(crate) const PHI_T_MAX: f64 = PHI_CELLS as f64 - 0.5;

/// Φ at the table coordinate `t` = (z − z_lo)·16 − ½, from the table
/// (absolute error below 5e-15) or, outside [−9, 9], from [`normal_cdf`].
#[inline(always)]
pub(crate) fn normal_cdf_at(table: &PhiTable, t: f64) -> f64 {
    if !(PHI_T_MIN..PHI_T_MAX).contains(&t) {
        return normal_cdf((t - PHI_T_OFFSET) / PHI_T_SCALE);
    }
    normal_cdf_in_table(table, t)
}

/// Φ from the table at a coordinate the caller has checked to lie in
/// [[`PHI_T_MIN`], [`PHI_T_MAX`]) (elsewhere the value is meaningless).
#[inline(always)]
pub(crate) fn normal_cdf_in_table(table: &PhiTable, t: f64) -> f64 {
    // Round to the nearest cell centre i: adding 1.5·2^52 leaves round(t) in
    // the low mantissa bits (|t| < 2^31), and w = t − i ∈ [−½, ½] exactly.
    const ROUND: f64 = 6_755_399_441_055_744.0;
    let r = t + ROUND;
    let i = (r.to_bits() as u32 as usize).min(PHI_CELLS - 1);
    let w = t - (r - ROUND);
    let c = &table[i].0;
    // Estrin's scheme, the halves q₀ = c₀ + c₁w + (c₂ + c₃w)w² and
    // q₁ = c₄ + c₅w + (c₆ + c₇w)w² side by side.
    let w2 = w * w;
    let a = [c[0] + c[2] * w, c[1] + c[3] * w];
    let b = [c[4] + c[6] * w, c[5] + c[7] * w];
    let q = [a[0] + b[0] * w2, a[1] + b[1] * w2];
    q[0] + q[1] * (w2 * w2)
}

/// Fast standard normal distribution function: the [`phi_table`]
/// interpolant on [−9, 9] (absolute error below 5e-15), [`normal_cdf`]
/// outside.
#[cfg(test)]
pub fn normal_cdf_fast(z: f64) -> f64 {
    normal_cdf_at(phi_table(), z * PHI_T_SCALE + PHI_T_OFFSET)
}

/// Standard normal density φ(z).
#[inline]
pub fn normal_pdf(z: f64) -> f64 {
    const INV_SQRT_2PI: f64 = 0.398_942_280_401_432_7;
    INV_SQRT_2PI * (-0.5 * z * z).exp()
}

/// Standard Cauchy (Lorentzian) distribution function 1/2 + atan(z)/π.
#[inline]
pub fn cauchy_cdf(z: f64) -> f64 {
    0.5 + z.atan() * std::f64::consts::FRAC_1_PI
}

/// Standard Cauchy density 1/(π(1+z²)).
#[inline]
pub fn cauchy_pdf(z: f64) -> f64 {
    std::f64::consts::FRAC_1_PI / (1.0 + z * z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn erfc_reference_values() {
        // Reference values (Abramowitz & Stegun, table 7.1 / high-precision).
        let cases = [
            (0.0, 1.0),
            (0.5, 0.479_500_122_186_953_5),
            (1.0, 0.157_299_207_050_285_13),
            (2.0, 0.004_677_734_981_047_266),
            (3.0, 2.209_049_699_858_544e-5),
            (-1.0, 1.842_700_792_949_715),
        ];
        for (x, e) in cases {
            let v = erfc(x);
            assert!(((v - e) / e).abs() < 1e-14, "erfc({x}) = {v}, want {e}");
        }
        assert_eq!(erfc(f64::INFINITY), 0.0);
        assert_eq!(erfc(f64::NEG_INFINITY), 2.0);
        assert!((normal_cdf(1.959_963_984_540_054) - 0.975).abs() < 1e-15);
    }

    #[test]
    fn fast_normal_cdf_matches_erfc() {
        let mut worst: f64 = 0.0;
        let mut z = -12.0;
        while z < 12.0 {
            worst = worst.max((normal_cdf_fast(z) - normal_cdf(z)).abs());
            z += 0.000_731;
        }
        assert!(worst < 5e-15, "max abs error {worst}");
        assert_eq!(normal_cdf_fast(f64::INFINITY), 1.0);
        assert_eq!(normal_cdf_fast(f64::NEG_INFINITY), 0.0);
    }

    #[test]
    fn cdfs_integrate_pdfs() {
        // Trapezoid check that the pdfs are the derivatives of the cdfs.
        for (cdf, pdf) in [
            (normal_cdf as fn(f64) -> f64, normal_pdf as fn(f64) -> f64),
            (cauchy_cdf, cauchy_pdf),
        ] {
            let h = 1e-5;
            for z in [-2.0, -0.3, 0.0, 0.7, 3.0] {
                let d = (cdf(z + h) - cdf(z - h)) / (2.0 * h);
                assert!((d - pdf(z)).abs() < 1e-8);
            }
        }
    }
}
