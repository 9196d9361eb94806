//! `bf16` multiply-accumulate over a list of taps, two input channels at a time: the inner loop
//! of a direct convolution in `bf16` (`f32`'s sign, exponent and top 7 mantissa bits).
//!
//! A tap's value at a point is a 32-bit word of two `bf16` (two input channels of one point,
//! channel 0 in the low half), its weight for an output channel a word of two `bf16` (the same
//! two channels); one step adds the two products to an `f32` sum. AVX-512 BF16 does that for 16
//! points in one instruction (`vdpbf16ps`, 32 products), twice the multiply-adds of an `f32` FMA
//! of the same width, on half the bytes. The words are laid out as [`crate::dot`]'s 8-bit ones
//! ([`WordTaps`], [`dot::OUTS`] output channels a group).
//!
//! The product of two `bf16` is exact in `f32` (8 significant bits by 8), so a step is two
//! roundings: the sum plus the second channel's product, then plus the first's, as Intel defines
//! `vdpbf16ps`. That order is [`accumulate`]'s definition on every path; a CPU whose
//! instruction rounds otherwise differs from it by a rounding of the sum per step (the tests
//! allow that). Edges, stated: [`to_bf16`] rounds to the nearest (ties to even), an `f32` past
//! `bf16`'s largest finite value becomes an infinity, a subnormal becomes a zero of its sign (as
//! the instruction reads one), a NaN stays a NaN.

use crate::dot::{self, WordTaps};

/// Channels in one word: two `bf16`.
pub const CHANNELS: usize = 2;

/// How [`accumulate`] runs: the widest path this CPU has, or a narrower one to compare.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Bf16Path {
    /// Plain loops in `f32`, vectorised by the compiler for the instruction set
    /// [`crate::detect`] gives.
    Portable,
    /// AVX-512 BF16 (`vdpbf16ps`).
    Avx512,
}

impl Bf16Path {
    /// Every path, narrowest first.
    pub const ALL: [Bf16Path; 2] = [Bf16Path::Portable, Bf16Path::Avx512];

    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Bf16Path::Portable => "portable",
            Bf16Path::Avx512 => "avx512",
        }
    }

    /// Whether this CPU runs it (AVX-512: F, BW, DQ and BF16, and `NEUSPIKE_ISA` not narrower
    /// than `avx512`).
    pub fn is_supported(self) -> bool {
        self <= detect()
    }
}

/// The widest [`Bf16Path`] this CPU runs.
pub fn detect() -> Bf16Path {
    #[cfg(target_arch = "x86_64")]
    {
        if crate::detect() == crate::Isa::Avx512
            && std::arch::is_x86_feature_detected!("avx512bf16")
        {
            return Bf16Path::Avx512;
        }
    }
    Bf16Path::Portable
}

/// `v` in `bf16`, rounded to the nearest (ties to even); a subnormal is read as a zero of its
/// sign, a NaN stays a NaN (quiet), a finite value past `bf16`'s largest rounds to an infinity.
/// Compares and integer adds only, so that the compiler vectorises a loop of it.
#[inline(always)]
pub fn to_bf16(v: f32) -> u16 {
    let bits = v.to_bits();
    let magnitude = bits & 0x7fff_ffff;
    let rounded = bits.wrapping_add(0x7fff + ((bits >> 16) & 1)) >> 16;
    let out = if magnitude > 0x7f80_0000 {
        (bits >> 16) | 0x0040
    } else if magnitude < 0x0080_0000 {
        (bits >> 16) & 0x8000
    } else {
        rounded
    };
    out as u16
}

/// A `bf16` as the `f32` it stands for (exact).
#[inline(always)]
pub fn to_f32(v: u16) -> f32 {
    f32::from_bits(u32::from(v) << 16)
}

/// Two values as the word [`accumulate`] reads: `a` (the first channel) in the low half.
#[inline(always)]
pub fn pair(a: f32, b: f32) -> u32 {
    u32::from(to_bf16(a)) | u32::from(to_bf16(b)) << 16
}

/// One step of the definition: `acc` plus the high halves' product, then plus the low halves'
/// (each product exact in `f32`).
#[inline(always)]
pub fn step(acc: f32, v: u32, w: u32) -> f32 {
    let hi = to_f32((v >> 16) as u16) * to_f32((w >> 16) as u16);
    let lo = to_f32(v as u16) * to_f32(w as u16);
    acc + hi + lo
}

/// For every group `g < groups`, output channel `o <` [`dot::OUTS`] and point `i < width`, adds
/// to `out[(OUTS g + o) out_stride + i]` every tap's two products of a value and a weight (the
/// words of [`WordTaps`], two `bf16` each), tap after tap, in the order of the module's
/// definition.
///
/// Runs on `path` or the widest path below it this CPU has.
///
/// # Panics
/// If `width` is not a multiple of [`dot::POINTS`], or a tap, weight or output lies outside its
/// slice (checked before any work).
pub fn accumulate(
    path: Bf16Path,
    taps: &WordTaps,
    out: &mut [f32],
    out_stride: usize,
    groups: usize,
    width: usize,
) {
    let WordTaps {
        rows,
        offsets,
        weights,
        group_stride,
    } = *taps;
    assert!(width.is_multiple_of(dot::POINTS), "width {width}");
    if groups == 0 || width == 0 {
        return;
    }
    crate::taps::check_reaches(
        crate::taps::Reaches {
            offsets,
            rows: rows.len(),
            weights: weights.len(),
            group_stride,
            out: out.len(),
            out_stride,
        },
        groups,
        width,
    );
    #[cfg(target_arch = "x86_64")]
    if path.min(detect()) == Bf16Path::Avx512 {
        let args = x86::Args {
            rows: rows.as_ptr(),
            offsets,
            weights: weights.as_ptr(),
            group_stride,
            out: out.as_mut_ptr(),
            out_stride,
            groups,
        };
        // SAFETY: the CPU has AVX-512 F and BF16 (`detect`); every index the kernel forms is
        // below a reach checked above, and outputs of different channels do not overlap
        // (`out_stride >= width`).
        #[allow(unsafe_code)]
        return unsafe { x86::bf16(&args, width / 16) };
    }
    let _ = path;
    crate::dispatch(
        #[inline(always)]
        || portable(taps, out, out_stride, groups, width),
    )
}

/// The definition, in plain loops.
#[inline(always)]
fn portable(taps: &WordTaps, out: &mut [f32], out_stride: usize, groups: usize, width: usize) {
    for g in 0..groups {
        for o in 0..dot::OUTS {
            let dst = &mut out[(dot::OUTS * g + o) * out_stride..][..width];
            for (t, &offset) in taps.offsets.iter().enumerate() {
                let w = taps.weights[g * taps.group_stride + dot::OUTS * t + o];
                for (a, &v) in dst.iter_mut().zip(&taps.rows[offset..][..width]) {
                    *a = step(*a, v, w);
                }
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod x86 {
    use std::arch::x86_64::*;

    use crate::dot::OUTS;

    /// [`super::accumulate`]'s checked arguments as pointers.
    pub struct Args<'a> {
        pub rows: *const u32,
        pub offsets: &'a [usize],
        pub weights: *const u32,
        pub group_stride: usize,
        pub out: *mut f32,
        pub out_stride: usize,
        pub groups: usize,
    }

    /// Every point in blocks of at most 6 vectors of 16, every group for each block, so a
    /// block's tap rows stay in the L1 cache while the groups go by.
    ///
    /// # Safety
    /// The CPU has AVX-512 F and BF16; `args` and `vectors` (of 16 points) are within the checks
    /// of [`super::accumulate`].
    #[target_feature(enable = "avx512f,avx512bf16")]
    pub unsafe fn bf16(args: &Args, vectors: usize) {
        for (x, p) in crate::taps::blocks(vectors, 6) {
            for g in 0..args.groups {
                // SAFETY: points 16x..16(x + p) are below the width.
                match p {
                    6 => unsafe { block16::<6>(args, g, 16 * x) },
                    5 => unsafe { block16::<5>(args, g, 16 * x) },
                    4 => unsafe { block16::<4>(args, g, 16 * x) },
                    3 => unsafe { block16::<3>(args, g, 16 * x) },
                    2 => unsafe { block16::<2>(args, g, 16 * x) },
                    _ => unsafe { block16::<1>(args, g, 16 * x) },
                }
            }
        }
    }

    /// 16 words as the 32 `bf16` they hold.
    #[target_feature(enable = "avx512f,avx512bf16")]
    #[inline]
    fn halves(v: __m512i) -> __m512bh {
        // SAFETY: both are 64 bytes of plain bits.
        unsafe { std::mem::transmute::<__m512i, __m512bh>(v) }
    }

    /// Group `g`'s channels at points `i..i + 16P`.
    ///
    /// # Safety
    /// As [`bf16`], and `i + 16P` at most the width.
    #[target_feature(enable = "avx512f,avx512bf16")]
    #[inline]
    unsafe fn block16<const P: usize>(args: &Args, g: usize, i: usize) {
        // SAFETY: every pointer below stays within the reaches `accumulate` checked.
        unsafe {
            let out = args.out.add(OUTS * g * args.out_stride + i);
            let mut acc = [[_mm512_setzero_ps(); P]; OUTS];
            for (o, acc) in acc.iter_mut().enumerate() {
                for (p, acc) in acc.iter_mut().enumerate() {
                    *acc = _mm512_loadu_ps(out.add(o * args.out_stride + 16 * p));
                }
            }
            let mut w = args.weights.add(g * args.group_stride);
            for &offset in args.offsets {
                let src = args.rows.add(offset + i);
                let mut v = [halves(_mm512_setzero_si512()); P];
                for (p, v) in v.iter_mut().enumerate() {
                    *v = halves(_mm512_loadu_si512(src.add(16 * p).cast()));
                }
                for (o, acc) in acc.iter_mut().enumerate() {
                    let w = halves(_mm512_set1_epi32(*w.add(o) as i32));
                    for (acc, &v) in acc.iter_mut().zip(&v) {
                        *acc = _mm512_dpbf16_ps(*acc, v, w);
                    }
                }
                w = w.add(OUTS);
            }
            for (o, acc) in acc.iter().enumerate() {
                for (p, &acc) in acc.iter().enumerate() {
                    _mm512_storeu_ps(out.add(o * args.out_stride + 16 * p), acc);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dot::{OUTS, POINTS};

    /// Values of both signs over a few orders of magnitude, from a seed.
    fn values(n: usize, seed: u32) -> Vec<f32> {
        (0..n)
            .map(|i| {
                let h = (i as u32).wrapping_mul(2_654_435_761).wrapping_add(seed) >> 8;
                let m = (h % 2001) as f32 / 1000.0 - 1.0;
                m * [1.0, 0.01, 30.0][(h >> 12) as usize % 3]
            })
            .collect()
    }

    #[test]
    fn conversion_rounds_to_the_nearest_even_and_states_its_edges() {
        // Exact values stay; halfway cases go to the even neighbour.
        assert_eq!(to_f32(to_bf16(1.5)), 1.5);
        let one = 1f32.to_bits();
        let half_up = f32::from_bits(one + 0x8000);
        assert_eq!(to_f32(to_bf16(half_up)), 1.0, "tie to even (down)");
        let odd = f32::from_bits(one + 0x1_0000);
        let tie_from_odd = f32::from_bits(one + 0x1_8000);
        assert_eq!(to_bf16(tie_from_odd), to_bf16(odd) + 1, "tie to even (up)");
        assert_eq!(
            to_f32(to_bf16(f32::from_bits(one + 0x8001))),
            to_f32(to_bf16(odd))
        );
        // Ends.
        assert_eq!(to_f32(to_bf16(f32::MAX)), f32::INFINITY);
        assert_eq!(to_f32(to_bf16(f32::NEG_INFINITY)), f32::NEG_INFINITY);
        assert!(to_f32(to_bf16(f32::NAN)).is_nan());
        // A NaN whose payload lies in the low bits alone stays a NaN.
        assert!(to_f32(to_bf16(f32::from_bits(0x7f80_0001))).is_nan());
        let tiny = f32::from_bits(0x8000_1234);
        assert_eq!(to_bf16(tiny), 0x8000, "a subnormal is a zero of its sign");
        assert_eq!(to_bf16(-0.0), 0x8000);
        // Every value within half a step of bf16's 8 significant bits: 2^-8 of itself.
        for v in values(10_000, 5) {
            let r = to_f32(to_bf16(v));
            assert!((r - v).abs() <= v.abs() * 2f32.powi(-8), "{v} -> {r}");
        }
    }

    /// Every path gives the definition's sums, within a rounding of the sum per step where a
    /// CPU's instruction orders the two products otherwise, at every block remainder.
    #[test]
    fn every_path_gives_the_definitions_sums() {
        for width in [16, 32, 48, 64, 80, 96, 112, 160, 400] {
            let (groups, n_taps) = (3, 11);
            let x = values(CHANNELS * (width * 7 + 5), 1);
            let rows: Vec<u32> = x.chunks_exact(2).map(|p| pair(p[0], p[1])).collect();
            let offsets: Vec<usize> = (0..n_taps).map(|t| (t * 37) % (width * 6 + 5)).collect();
            let group_stride = OUTS * n_taps + 3;
            let k = values(CHANNELS * groups * group_stride, 2);
            let weights: Vec<u32> = k.chunks_exact(2).map(|p| pair(p[0], p[1])).collect();
            let out_stride = width + 16;
            let start = values(OUTS * groups * out_stride, 3);
            let mut want = start.clone();
            let mut size = vec![0f32; want.len()];
            for g in 0..groups {
                for o in 0..OUTS {
                    for i in 0..width {
                        let at = (OUTS * g + o) * out_stride + i;
                        for (t, &off) in offsets.iter().enumerate() {
                            let (v, w) = (rows[off + i], weights[g * group_stride + OUTS * t + o]);
                            want[at] = step(want[at], v, w);
                            size[at] += step(0.0, v, w).abs() + want[at].abs();
                        }
                    }
                }
            }
            for path in Bf16Path::ALL {
                let taps = WordTaps {
                    rows: &rows,
                    offsets: &offsets,
                    weights: &weights,
                    group_stride,
                };
                let mut out = start.clone();
                accumulate(path, &taps, &mut out, out_stride, groups, width);
                for (i, ((&g, &w), &s)) in out.iter().zip(&want).zip(&size).enumerate() {
                    assert!(
                        (g - w).abs() <= s * f32::EPSILON,
                        "{} at width {width}, output {i}: {g} for {w}",
                        path.name()
                    );
                }
                if path == Bf16Path::Portable {
                    assert_eq!(out, want, "the plain loops are the definition");
                }
            }
        }
    }

    #[test]
    #[should_panic(expected = "taps reach")]
    fn a_tap_past_its_rows_is_refused() {
        let rows = vec![0; 40];
        let taps = WordTaps {
            rows: &rows,
            offsets: &[0, 30],
            weights: &[0; 8],
            group_stride: 8,
        };
        accumulate(Bf16Path::Avx512, &taps, &mut [0.0; 64], 16, 1, POINTS);
    }

    #[test]
    fn the_widest_path_is_supported() {
        assert!(detect().is_supported());
        assert!(Bf16Path::Portable.is_supported());
    }
}
