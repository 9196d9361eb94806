//! Multiply-accumulate over a list of taps, register-blocked with each instruction set's own
//! vector intrinsics: the inner loop of a direct convolution.
//!
//! The compiler's vectoriser keeps at most about 8 accumulators of a plain loop in registers;
//! a convolution wants more (FMA latency times the FMA pipes: 8-10 in flight on current cores).
//! [`accumulate`] keeps [`OUTS`] output channels by 3 vectors of 8 points (12 accumulators of
//! the 16 AVX2 registers) or by 6 vectors of 16 points (24 of the 32 AVX-512 registers), loads
//! each tap's vectors once for all the channels and broadcasts the weights.

use crate::Isa;

/// Output channels one group holds.
pub const OUTS: usize = 4;

/// The multiple of points every width passed to [`accumulate`] is (the widest vector's lanes).
pub const POINTS: usize = 16;

/// The inputs of [`accumulate`]: tap `t` of point `i` reads `rows[offsets[t] + i]` with, for
/// output channel `o` of group `g`, weight `weights[g * group_stride + OUTS * t + o]`.
#[derive(Clone, Copy, Debug)]
pub struct Taps<'a> {
    /// The values the taps read.
    pub rows: &'a [f32],
    /// Where each tap's row of points starts in `rows`.
    pub offsets: &'a [usize],
    /// The weights, `OUTS` per tap, then the next group `group_stride` values on.
    pub weights: &'a [f32],
    /// The distance between two groups' weights in `weights`.
    pub group_stride: usize,
}

/// For every group `g < groups`, output channel `o < OUTS` and point `i < width`, takes the
/// value `a = out[(OUTS g + o) out_stride + i]` through every tap `t` in order,
/// `a = w.mul_add(v, a)` with `w`, `v` the tap's weight and value (see [`Taps`]), and stores it
/// back: one rounding per tap, so every instruction set gives the same bits.
///
/// Runs on `isa` or the widest instruction set below it this CPU has.
///
/// # Panics
/// If `width` is not a multiple of [`POINTS`], or a tap, weight or output lies outside its
/// slice (checked before any work).
pub fn accumulate(
    isa: Isa,
    taps: &Taps,
    out: &mut [f32],
    out_stride: usize,
    groups: usize,
    width: usize,
) {
    let Taps {
        rows,
        offsets,
        weights,
        group_stride,
    } = *taps;
    assert!(width.is_multiple_of(POINTS), "width {width}");
    if groups == 0 || width == 0 {
        return;
    }
    check_reaches(
        Reaches {
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
    {
        let args = x86::Args {
            rows: rows.as_ptr(),
            offsets,
            weights: weights.as_ptr(),
            group_stride,
            out: out.as_mut_ptr(),
            out_stride,
            groups,
        };
        match isa.min(crate::detect()) {
            // SAFETY: the CPU has AVX-512 F and FMA; every index the kernel forms is below a
            // reach checked above, and outputs of different channels do not overlap
            // (`out_stride >= width`).
            #[allow(unsafe_code)]
            Isa::Avx512 => return unsafe { x86::avx512(&args, width / 16) },
            // SAFETY: as above, with AVX2 and FMA.
            #[allow(unsafe_code)]
            Isa::Avx2 => return unsafe { x86::avx2(&args, width / 8) },
            Isa::Baseline => {}
        }
    }
    let _ = isa;
    for g in 0..groups {
        for o in 0..OUTS {
            let dst = &mut out[(OUTS * g + o) * out_stride..][..width];
            for (t, &offset) in offsets.iter().enumerate() {
                let w = weights[g * group_stride + OUTS * t + o];
                for (a, &v) in dst.iter_mut().zip(&rows[offset..offset + width]) {
                    *a = w.mul_add(v, *a);
                }
            }
        }
    }
}

/// The lengths an accumulation over taps reads and writes (in values or words).
pub(crate) struct Reaches<'a> {
    /// Where each tap's run of points starts.
    pub offsets: &'a [usize],
    /// The values the taps read.
    pub rows: usize,
    /// The weights, [`OUTS`] per tap, then the next group `group_stride` on.
    pub weights: usize,
    /// The distance between two groups' weights.
    pub group_stride: usize,
    /// The outputs, [`OUTS`] rows a group.
    pub out: usize,
    /// The distance between two output rows.
    pub out_stride: usize,
}

/// Panics unless every tap's run of `width` points, every group's weights and every output row
/// of `groups` groups lies within its length (`groups` and `width` at least 1), and output rows
/// do not overlap. Checked arithmetic: a reach that wrapped around would pass.
pub(crate) fn check_reaches(r: Reaches, groups: usize, width: usize) {
    let reach = r
        .offsets
        .iter()
        .max()
        .map_or(Some(0), |&m| m.checked_add(width));
    assert!(
        reach.is_some_and(|x| x <= r.rows),
        "taps reach {reach:?} of {}",
        r.rows
    );
    let reach = (groups - 1)
        .checked_mul(r.group_stride)
        .and_then(|x| x.checked_add(OUTS.checked_mul(r.offsets.len())?));
    assert!(
        reach.is_some_and(|x| x <= r.weights),
        "weights reach {reach:?} of {}",
        r.weights
    );
    let reach = OUTS
        .checked_mul(groups)
        .and_then(|n| (n - 1).checked_mul(r.out_stride)?.checked_add(width));
    assert!(
        reach.is_some_and(|x| x <= r.out),
        "outputs reach {reach:?} of {}",
        r.out
    );
    assert!(
        r.out_stride >= width,
        "output rows of {} for {width} points",
        r.out_stride
    );
}

/// `vectors` split into runs `(first, length)` of at most `most`, as even as can be: a short
/// last run (7 as 6 + 1) would hold too few accumulators to hide the FMA latency, 4 + 3 does.
pub(crate) fn blocks(vectors: usize, most: usize) -> impl Iterator<Item = (usize, usize)> {
    let n = vectors.div_ceil(most.max(1));
    let (base, longer) = (vectors / n.max(1), vectors % n.max(1));
    (0..n).map(move |b| (b * base + b.min(longer), base + usize::from(b < longer)))
}

#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod x86 {
    use std::arch::x86_64::*;

    use super::OUTS;

    /// [`super::accumulate`]'s checked arguments as pointers.
    pub struct Args<'a> {
        pub rows: *const f32,
        pub offsets: &'a [usize],
        pub weights: *const f32,
        pub group_stride: usize,
        pub out: *mut f32,
        pub out_stride: usize,
        pub groups: usize,
    }

    /// Every point in blocks of at most 3 vectors of 8, every group for each block, so a
    /// block's tap rows stay in the L1 cache while the groups go by.
    ///
    /// # Safety
    /// The CPU has AVX2 and FMA; `args` and `vectors` (of 8 points) are within the checks of
    /// [`super::accumulate`].
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn avx2(args: &Args, vectors: usize) {
        for (x, p) in super::blocks(vectors, 3) {
            for g in 0..args.groups {
                // SAFETY: points 8x..8(x + p) are below the width.
                match p {
                    3 => unsafe { block8::<3>(args, g, 8 * x) },
                    2 => unsafe { block8::<2>(args, g, 8 * x) },
                    _ => unsafe { block8::<1>(args, g, 8 * x) },
                }
            }
        }
    }

    /// Group `g`'s channels at points `i..i + 8P`.
    ///
    /// # Safety
    /// As [`avx2`], and `i + 8P` at most the width.
    #[target_feature(enable = "avx2,fma")]
    #[inline]
    unsafe fn block8<const P: usize>(args: &Args, g: usize, i: usize) {
        // SAFETY: every pointer below stays within the reaches `accumulate` checked.
        unsafe {
            let out = args.out.add(OUTS * g * args.out_stride + i);
            let mut acc = [[_mm256_setzero_ps(); P]; OUTS];
            for (o, acc) in acc.iter_mut().enumerate() {
                for (p, acc) in acc.iter_mut().enumerate() {
                    *acc = _mm256_loadu_ps(out.add(o * args.out_stride + 8 * p));
                }
            }
            let mut w = args.weights.add(g * args.group_stride);
            for &offset in args.offsets {
                let src = args.rows.add(offset + i);
                let mut v = [_mm256_setzero_ps(); P];
                for (p, v) in v.iter_mut().enumerate() {
                    *v = _mm256_loadu_ps(src.add(8 * p));
                }
                for (o, acc) in acc.iter_mut().enumerate() {
                    let w = _mm256_broadcast_ss(&*w.add(o));
                    for (acc, &v) in acc.iter_mut().zip(&v) {
                        *acc = _mm256_fmadd_ps(w, v, *acc);
                    }
                }
                w = w.add(OUTS);
            }
            for (o, acc) in acc.iter().enumerate() {
                for (p, &acc) in acc.iter().enumerate() {
                    _mm256_storeu_ps(out.add(o * args.out_stride + 8 * p), acc);
                }
            }
        }
    }

    /// [`avx2`] with vectors of 16 points in blocks of at most 6.
    ///
    /// # Safety
    /// The CPU has AVX-512 F and FMA; `args` and `vectors` (of 16 points) are within the checks
    /// of [`super::accumulate`].
    #[target_feature(enable = "avx512f,fma")]
    pub unsafe fn avx512(args: &Args, vectors: usize) {
        for (x, p) in super::blocks(vectors, 6) {
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

    /// Group `g`'s channels at points `i..i + 16P`.
    ///
    /// # Safety
    /// As [`avx512`], and `i + 16P` at most the width.
    #[target_feature(enable = "avx512f,fma")]
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
                let mut v = [_mm512_setzero_ps(); P];
                for (p, v) in v.iter_mut().enumerate() {
                    *v = _mm512_loadu_ps(src.add(16 * p));
                }
                for (o, acc) in acc.iter_mut().enumerate() {
                    let w = _mm512_set1_ps(*w.add(o));
                    for (acc, &v) in acc.iter_mut().zip(&v) {
                        *acc = _mm512_fmadd_ps(w, v, *acc);
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

    fn values(n: usize, seed: u32) -> Vec<f32> {
        (0..n)
            .map(|i| {
                let k = (i as u32).wrapping_mul(2_654_435_761).wrapping_add(seed) >> 9;
                (k % 4001) as f32 / 997.0 - 2.0
            })
            .collect()
    }

    /// Every instruction set gives the scalar definition's bits, at every block remainder.
    #[test]
    fn every_isa_gives_the_definitions_bits() {
        for width in [16, 32, 48, 64, 80, 96, 112, 160, 400] {
            let (groups, n_taps) = (3, 11);
            let rows = values(width * 7 + 5, 1);
            let offsets: Vec<usize> = (0..n_taps).map(|t| (t * 37) % (width * 6 + 5)).collect();
            let group_stride = OUTS * n_taps + 3;
            let weights = values(groups * group_stride, 2);
            let out_stride = width + 16;
            let start = values(OUTS * groups * out_stride, 3);
            let mut want = start.clone();
            for g in 0..groups {
                for o in 0..OUTS {
                    for i in 0..width {
                        let a = &mut want[(OUTS * g + o) * out_stride + i];
                        for (t, &off) in offsets.iter().enumerate() {
                            *a =
                                weights[g * group_stride + OUTS * t + o].mul_add(rows[off + i], *a);
                        }
                    }
                }
            }
            let taps = Taps {
                rows: &rows,
                offsets: &offsets,
                weights: &weights,
                group_stride,
            };
            for isa in Isa::ALL {
                let mut out = start.clone();
                accumulate(isa, &taps, &mut out, out_stride, groups, width);
                let same = out
                    .iter()
                    .zip(&want)
                    .all(|(a, b)| a.to_bits() == b.to_bits());
                assert!(same, "{} at width {width}", isa.name());
            }
        }
    }

    #[test]
    fn blocks_cover_the_row_evenly() {
        for most in [3, 6] {
            for vectors in 0..40 {
                let runs: Vec<_> = blocks(vectors, most).collect();
                let mut next = 0;
                for &(first, len) in &runs {
                    assert_eq!(first, next);
                    assert!((1..=most).contains(&len), "{vectors} by {most}: {runs:?}");
                    next += len;
                }
                assert_eq!(next, vectors);
                let (min, max) = runs
                    .iter()
                    .fold((most, 0), |(a, b), r| (a.min(r.1), b.max(r.1)));
                assert!(
                    runs.is_empty() || max - min <= 1,
                    "{vectors} by {most}: {runs:?}"
                );
            }
        }
        assert_eq!(blocks(7, 6).collect::<Vec<_>>(), [(0, 4), (4, 3)]);
    }

    #[test]
    #[should_panic(expected = "taps reach")]
    fn a_tap_past_its_rows_is_refused() {
        let rows = vec![0.0; 40];
        let taps = Taps {
            rows: &rows,
            offsets: &[0, 30],
            weights: &[0.0; 8],
            group_stride: 8,
        };
        accumulate(Isa::Avx512, &taps, &mut [0.0; 64], 16, 1, 16);
    }

    #[test]
    #[should_panic(expected = "taps reach None")]
    fn a_reach_that_wraps_around_is_refused() {
        let taps = Taps {
            rows: &[0.0; 64],
            offsets: &[usize::MAX - 8],
            weights: &[0.0; 4],
            group_stride: 4,
        };
        accumulate(Isa::Avx512, &taps, &mut [0.0; 64], 16, 1, 16);
    }
}
