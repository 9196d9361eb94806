//! `exp` of a non-positive `f64` without branches, so loops over it vectorise.
//!
//! Every exponential the filters and the fusion take is of a non-positive number: decay factors
//! `exp(-alpha dt)` with `dt >= 0`, and outputs `exp(min(x, 0))` clamped to luminance 1. `f64::exp`
//! calls libm once per element and blocks vectorisation; [`exp_nonpos`] is Cody-Waite range reduction
//! plus a degree-13 Taylor polynomial, branch-free, within a few ulp of `f64::exp` (tested).

/// `ln(f64::MIN_POSITIVE)` = `-1022 ln 2`: below it the true result is subnormal or zero and
/// [`exp_nonpos`] returns 0.
const X_MIN: f64 = -708.396_418_532_264_1;
/// `1.5 * 2^52`: adding it rounds a number of magnitude below `2^51` to an integer held in the low
/// bits of the sum.
const SHIFT: f64 = 6_755_399_441_055_744.0;
/// `ln 2` split so that `k * LN2_HI` is exact for `|k| <= 2^11` (fdlibm's constants).
const LN2_HI: f64 = 6.931_471_803_691_238e-1;
const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;
/// `1 / n!` for `n = 0..=13`.
const INV_FACT: [f64; 14] = [
    1.0,
    1.0,
    1.0 / 2.0,
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

/// `e^min(x, 0)`, in `[0, 1]`.
///
/// - `x >= 0` (and `+inf`) gives exactly 1; `-0.0` gives 1.
/// - `x < ln(f64::MIN_POSITIVE)` (about `-708.4`, `-inf` included) gives 0, where `f64::exp` would
///   give a subnormal below `2.3e-308`.
/// - NaN gives 1, as `f64::min` drops the NaN (so does the scalar oracle `x.min(0.0).exp()`).
///
/// Elsewhere within 4 ulp of `f64::exp` (the Taylor remainder on `|r| <= ln(2)/2` is below
/// `1e-17`; the rest is rounding).
#[inline(always)]
#[allow(clippy::manual_clamp)] // `clamp` would keep a NaN; `min` drops it (NaN gives 1).
pub(crate) fn exp_nonpos(x: f64) -> f64 {
    let xc = x.min(0.0).max(X_MIN);
    // k = round(x / ln 2) in [-1022, 0], read from the low bits of t.
    let t = xc * std::f64::consts::LOG2_E + SHIFT;
    let kf = t - SHIFT;
    let k_bits = t.to_bits().wrapping_sub(SHIFT.to_bits());
    let r = (xc - kf * LN2_HI) - kf * LN2_LO;
    let mut p = INV_FACT[13];
    for &c in INV_FACT[..13].iter().rev() {
        p = p * r + c;
    }
    // 2^k: biased exponent k + 1023 in [1, 1023], always a normal number.
    let scale = f64::from_bits(k_bits.wrapping_add(1023) << 52);
    let y = p * scale;
    if x < X_MIN { 0.0 } else { y }
}

/// The scalar oracle for [`exp_nonpos`].
#[inline]
pub(crate) fn exp_nonpos_reference(x: f64) -> f64 {
    x.min(0.0).exp()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 4.0 * f64::EPSILON * b.abs() + 1e-300
    }

    #[test]
    fn exp_nonpos_asymptotes() {
        assert_eq!(exp_nonpos(0.0), 1.0);
        assert_eq!(exp_nonpos(-0.0), 1.0);
        assert_eq!(exp_nonpos(3.0), 1.0);
        assert_eq!(exp_nonpos(f64::INFINITY), 1.0);
        assert_eq!(exp_nonpos(f64::MAX), 1.0);
        assert_eq!(exp_nonpos(f64::NAN), 1.0);
        assert_eq!(exp_nonpos_reference(f64::NAN), 1.0);
        assert_eq!(exp_nonpos(f64::NEG_INFINITY), 0.0);
        assert_eq!(exp_nonpos(-1e300), 0.0);
        assert_eq!(exp_nonpos(-709.0), 0.0);
        assert!(close(exp_nonpos(X_MIN), f64::MIN_POSITIVE));
        assert!(close(exp_nonpos(-1.0), (-1.0f64).exp()));
        assert!(close(exp_nonpos(-f64::MIN_POSITIVE), 1.0));
        // Exactly k ln 2 lands on a power of two.
        for k in [1, 2, 10, 100, 1000] {
            let x = -f64::from(k) * std::f64::consts::LN_2;
            assert!(close(exp_nonpos(x), x.exp()), "k = {k}");
        }
    }

    #[test]
    fn exp_nonpos_is_the_same_on_every_isa() {
        let xs: Vec<f64> = (0..4096).map(|i| -f64::from(i) * 0.173 + 1.0).collect();
        let run = |isa| {
            neuspike_simd::with_isa(
                isa,
                #[inline(always)]
                || xs.iter().map(|&x| exp_nonpos(x)).collect::<Vec<_>>(),
            )
        };
        let want = run(neuspike_simd::Isa::Baseline);
        for isa in neuspike_simd::Isa::ALL {
            assert_eq!(run(isa), want, "{}", isa.name());
        }
    }

    proptest! {
        #[test]
        fn exp_nonpos_matches_std(x in -708.39f64..=0.0) {
            let (a, b) = (exp_nonpos(x), exp_nonpos_reference(x));
            prop_assert!(close(a, b), "x = {x}: {a} vs {b}");
        }

        #[test]
        fn exp_nonpos_small_arguments(x in -1e-3f64..=0.0) {
            let (a, b) = (exp_nonpos(x), exp_nonpos_reference(x));
            prop_assert!(close(a, b), "x = {x}: {a} vs {b}");
        }

        #[test]
        fn exp_nonpos_below_range_is_tiny(x in -1e6f64..-708.39) {
            prop_assert!(exp_nonpos(x) <= f64::MIN_POSITIVE);
            prop_assert!((exp_nonpos(x) - exp_nonpos_reference(x)).abs() <= f64::MIN_POSITIVE);
        }
    }
}
