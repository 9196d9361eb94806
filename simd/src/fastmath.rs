//! Elementary functions without branches or library calls, so the loops that take them
//! vectorise, and give the same bits on every instruction set (IEEE adds, multiplies and fused
//! multiply-adds, each rounded once; see the crate's documentation):
//!
//! | function | domain | where |
//! |---|---|---|
//! | [`exp_nonpos`] | `e^min(x, 0)`, NaN gives 1 | the event filters and the physics fusion (decays, outputs) |
//! | [`exp_neg`] | [`exp_nonpos`], but NaN gives 0 | event integration's weights `e^(-dt / tau)` |
//! | [`ln_fast`] | `ln x` in `f32`, clamped to the normal range | the DVS's log intensity |
//! | [`sigmoid`] | `1 / (1 + e^-z)` in `f32`, NaN kept | the networks' attention maps and outputs |
//!
//! One exponential: [`exp_neg`] is [`exp_nonpos`] with one edge of its own (a weight of NaN, `0 *
//! inf` at `tau = 0`, counts nothing, where a filter's decay of NaN keeps the state). Each function
//! has a test against the standard library and at its edges.
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
pub fn exp_nonpos(x: f64) -> f64 {
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
pub fn exp_nonpos_reference(x: f64) -> f64 {
    x.min(0.0).exp()
}

/// [`exp_nonpos`] for event weights `exp(-dt / tau)`: the same function, except that NaN (`0 *
/// inf`, an event at the instant itself when `tau = 0`) gives 0, a weight that counts nothing.
/// Exactly 1 at `x = ±0` and for `x > 0` (callers pass `-dt / tau` with `dt >= 0`); 0 below
/// `ln(f64::MIN_POSITIVE)`, `-inf` included; elsewhere within 4 ulp of `f64::exp` (tested).
#[inline(always)]
pub fn exp_neg(x: f64) -> f64 {
    // A select, not a branch: the loop still vectorises.
    if x.is_nan() { 0.0 } else { exp_nonpos(x) }
}

/// The larger of `x` and `floor`, and `floor` when `x` is NaN: `f32::max` without its NaN
/// handling, so a vectorised loop takes one max instruction instead of three.
#[inline(always)]
pub fn max_or(x: f32, floor: f32) -> f32 {
    if x > floor { x } else { floor }
}

/// The smaller of `x` and `ceiling`, and `ceiling` when `x` is NaN (see [`max_or`]).
#[inline(always)]
pub fn min_or(x: f32, ceiling: f32) -> f32 {
    if x < ceiling { x } else { ceiling }
}

/// Natural logarithm in single precision without branches or divisions, so loops over it
/// vectorise; within `2e-6 * max(1, |ln x|)` of the exact value (tested). Defined everywhere: the
/// input is first clamped to `[f32::MIN_POSITIVE, f32::MAX]` (NaN becomes `MIN_POSITIVE`).
///
/// `x = m 2^e` with `m` in `[sqrt(1/2), sqrt(2))`; `ln m = f q(f)` with `f = m - 1` and `q` a
/// degree-8 polynomial fitted (least squares, reweighted towards minimax) to `ln(1 + f) / f` on
/// that interval: its error there is below `4e-8`. Horner's rule in fused multiply-adds, so inside
/// [`crate::with_isa`] on AVX2 or AVX-512 each step is one instruction (elsewhere the C library's
/// `fmaf`, the same bits).
#[inline(always)]
pub fn ln_fast(x: f32) -> f32 {
    const LN_2: f32 = std::f32::consts::LN_2;
    const Q: [f32; 9] = [
        0.999_999_9,
        -0.499_999_73,
        0.333_350_1,
        -0.250_032_87,
        0.199_388_41,
        -0.165_329_08,
        0.150_675_92,
        -0.145_771_15,
        0.086_929_22,
    ];
    // Not `clamp`, which keeps a NaN: a NaN becomes `MIN_POSITIVE`, as documented.
    let x = min_or(max_or(x, f32::MIN_POSITIVE), f32::MAX);
    let bits = x.to_bits();
    let e = ((bits >> 23) & 0xff) as i32 - 127;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000); // [1, 2)
    let big = m > std::f32::consts::SQRT_2;
    let m = if big { m * 0.5 } else { m };
    let e = (e + i32::from(big)) as f32;
    let f = m - 1.0;
    let mut q = Q[8];
    for &c in Q[..8].iter().rev() {
        q = q.mul_add(f, c);
    }
    e.mul_add(LN_2, f * q)
}

/// `1 / (1 + e^-z)` in single precision without branches or library calls, so loops over it
/// vectorise (`f32::exp` is one C library call per element).
///
/// - `e = e^-|z|` in `(0, 1]`, then `1 / (1 + e)` for `z >= 0` and `e / (1 + e)` below: no
///   overflow on either side.
/// - `e` is [`exp_nonpos_f32`]: Cody-Waite reduction to `|r| <= ln(2)/2` and a degree-7 Taylor
///   polynomial (remainder below `6e-9`), in fused multiply-adds.
/// - Within `2e-7` of the exact value and 4 ulp of it (relative) wherever it is above
///   `f32::MIN_POSITIVE` (tested against `f64`); `z <= -87.3` gives 0, `+inf` 1, `-inf` 0,
///   NaN NaN.
#[inline(always)]
pub fn sigmoid(z: f32) -> f32 {
    let e = exp_nonpos_f32(-z.abs());
    let s = (if z >= 0.0 { 1.0 } else { e }) / (1.0 + e);
    // A select, not a branch: NaN stays NaN.
    if z.is_nan() { z } else { s }
}

/// `e^x` in single precision for `x <= 0`: 0 below `ln(f32::MIN_POSITIVE)` (about `-87.34`,
/// `-inf` included), where the true value is subnormal; 1 at `x >= 0`; NaN gives 1 (as
/// `f32::min` drops it). Within 2 ulp of the exact value elsewhere (tested through [`sigmoid`]).
#[inline(always)]
#[allow(clippy::manual_clamp)] // `clamp` would keep a NaN.
pub fn exp_nonpos_f32(x: f32) -> f32 {
    /// `ln(f32::MIN_POSITIVE)` = `-126 ln 2`.
    const X_MIN: f32 = -87.336_54;
    /// `1.5 * 2^23`: adding it rounds a number below `2^22` to an integer in the low bits.
    const SHIFT: f32 = 12_582_912.0;
    /// `ln 2` split so that `k * LN2_HI` is exact for `|k| <= 2^8` (Cephes' constants).
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    let xc = x.min(0.0).max(X_MIN);
    let t = xc.mul_add(std::f32::consts::LOG2_E, SHIFT);
    let kf = t - SHIFT;
    let k_bits = t.to_bits().wrapping_sub(SHIFT.to_bits());
    let r = kf.mul_add(-LN2_LO, kf.mul_add(-LN2_HI, xc));
    let mut p: f32 = 1.0 / 5_040.0;
    for c in [
        1.0 / 720.0,
        1.0 / 120.0,
        1.0 / 24.0,
        1.0 / 6.0,
        0.5,
        1.0,
        1.0,
    ] {
        p = p.mul_add(r, c);
    }
    // 2^k, k in [-126, 0]: a biased exponent in [1, 127], always normal.
    let y = p * f32::from_bits(k_bits.wrapping_add(127) << 23);
    if x < X_MIN { 0.0 } else { y }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    use proptest::prelude::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 4.0 * f64::EPSILON * b.abs() + 1e-300
    }

    #[test]
    fn sigmoid_is_close_everywhere_and_exact_at_the_edges() {
        let exact = |z: f32| 1.0 / (1.0 + (-f64::from(z)).exp());
        let mut worst = (0.0f64, 0.0f64);
        for i in -1_000_000..=1_000_000 {
            let z = i as f32 * 1e-4;
            let (got, want) = (f64::from(sigmoid(z)), exact(z));
            let err = (got - want).abs();
            worst.0 = worst.0.max(err);
            if want > f64::from(f32::MIN_POSITIVE) {
                worst.1 = worst.1.max(err / want);
            }
        }
        assert!(
            worst.0 < 2e-7 && worst.1 < 4.0 * f64::from(f32::EPSILON),
            "{worst:?}"
        );
        for z in [-87.0f32, -60.0, -20.0, -1e-30, 1e-30, 15.0, 17.0] {
            let (got, want) = (f64::from(sigmoid(z)), exact(z));
            assert!(
                (got - want).abs() <= 4.0 * f64::from(f32::EPSILON) * want,
                "{z}"
            );
        }
        assert_eq!(sigmoid(0.0), 0.5);
        assert_eq!(sigmoid(-0.0), 0.5);
        assert_eq!(sigmoid(f32::INFINITY), 1.0);
        assert_eq!(sigmoid(f32::MAX), 1.0);
        assert_eq!(sigmoid(f32::NEG_INFINITY), 0.0);
        assert_eq!(sigmoid(-88.0), 0.0);
        assert_eq!(sigmoid(f32::MIN), 0.0);
        assert!(sigmoid(f32::NAN).is_nan());
        assert_eq!(exp_nonpos_f32(f32::NAN), 1.0);
        assert_eq!(exp_nonpos_f32(5.0), 1.0);
        // Exactly k ln 2 lands on a power of two.
        for k in [1, 2, 10, 100, 125] {
            let x = -(k as f32) * std::f32::consts::LN_2;
            let want = f64::from(x).exp();
            let got = f64::from(exp_nonpos_f32(x));
            assert!(
                (got - want).abs() <= 2.0 * f64::from(f32::EPSILON) * want,
                "k = {k}"
            );
        }
        let zs: Vec<f32> = (0..4096).map(|i| i as f32 * 0.05 - 100.0).collect();
        let run = |isa| {
            crate::with_isa(
                isa,
                #[inline(always)]
                || zs.iter().map(|&z| sigmoid(z)).collect::<Vec<_>>(),
            )
        };
        let want = run(crate::Isa::Baseline);
        for isa in crate::Isa::ALL {
            assert_eq!(run(isa), want, "{}", isa.name());
        }
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
            crate::with_isa(
                isa,
                #[inline(always)]
                || xs.iter().map(|&x| exp_nonpos(x)).collect::<Vec<_>>(),
            )
        };
        let want = run(crate::Isa::Baseline);
        for isa in crate::Isa::ALL {
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

    #[test]
    fn exp_neg_is_close_to_exp_and_exact_at_the_edges() {
        let mut worst = 0.0f64;
        let mut x = 0.0f64;
        while x >= -708.0 {
            for x in [x, x - 1e-9, x * 0.999_999_7] {
                let (got, want) = (exp_neg(x), x.exp());
                worst = worst.max(((got - want) / want).abs());
            }
            x -= 0.013_7;
        }
        assert!(worst <= 1e-15, "relative error {worst:e}");
        for tiny in [-1e-300, -f64::MIN_POSITIVE, -1e-17] {
            assert_eq!(exp_neg(tiny), 1.0);
        }
        assert_eq!(exp_neg(0.0), 1.0);
        assert_eq!(exp_neg(-0.0), 1.0);
        assert_eq!(exp_neg(1.0), 1.0);
        assert_eq!(exp_neg(-708.5), 0.0);
        assert!(exp_neg(-708.1) <= 2.0 * f64::MIN_POSITIVE);
        assert_eq!(exp_neg(f64::NEG_INFINITY), 0.0);
        assert_eq!(exp_neg(f64::NAN), 0.0);
        let isas: Vec<f64> = crate::Isa::ALL
            .iter()
            .map(|&isa| {
                crate::with_isa(
                    isa,
                    #[inline(always)]
                    || (0..4096).map(|i| exp_neg(-0.17 * i as f64)).sum::<f64>(),
                )
            })
            .collect();
        assert!(isas.windows(2).all(|p| p[0].to_bits() == p[1].to_bits()));
    }

    #[test]
    fn ln_fast_is_close_everywhere_and_finite_at_the_edges() {
        let mut worst = 0.0f64;
        let mut check = |x: f32| {
            let exact = f64::from(x).ln();
            let err = (f64::from(ln_fast(x)) - exact).abs() / exact.abs().max(1.0);
            worst = worst.max(err);
        };
        for k in -37_000..38_000 {
            check(10f32.powf(k as f32 / 1000.0));
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for _ in 0..200_000 {
            let bits = rand::Rng::random_range(&mut rng, 0x0080_0000u32..0x7f80_0000);
            check(f32::from_bits(bits));
        }
        assert!(worst <= 2e-6, "worst relative error {worst}");
        let lo = f64::from(f32::MIN_POSITIVE).ln();
        for x in [0.0, -1.0, f32::NAN, f32::NEG_INFINITY] {
            assert!((f64::from(ln_fast(x)) - lo).abs() < 1e-4, "{x}");
        }
        assert!((f64::from(ln_fast(f32::INFINITY)) - f64::from(f32::MAX).ln()).abs() < 1e-4);
        assert_eq!(ln_fast(1.0), 0.0);
    }
}
