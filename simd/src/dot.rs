//! 8-bit multiply-accumulate over a list of taps, four input channels at a time: the inner loop
//! of a quantised direct convolution.
//!
//! A tap's value at a point is a 32-bit word of four unsigned bytes (four input channels of one
//! point, channel `j` in bits `8j..8j + 8`), its weight for an output channel a word of four
//! signed bytes (the same four channels); one step adds the four products to a 32-bit sum. AVX-512 VNNI does that for 16 points in one
//! instruction (`vpdpbusd`, 64 products), four times the multiply-adds of an `f32` FMA of the
//! same width. [`accumulate`] keeps [`OUTS`] output channels by up to 6 vectors of 16 points
//! in registers, as [`crate::taps::accumulate`] does for `f32`. Integer sums are exact, so every
//! path gives the same sums (the products' sum wraps modulo 2^32, as the instruction does; the
//! caller keeps it in range, see [`accumulate`]).

use crate::Isa;

/// Output channels one group holds.
pub const OUTS: usize = 4;

/// Channels in one word: a byte each.
pub const CHANNELS: usize = 4;

/// The multiple of points every width passed to [`accumulate`] is.
pub const POINTS: usize = 16;

/// How [`accumulate`] runs: the widest path this CPU has, or a narrower one to compare.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum DotPath {
    /// Plain loops, vectorised by the compiler for the instruction set [`crate::detect`] gives.
    Portable,
    /// AVX-512 VNNI (`vpdpbusd`).
    Vnni,
}

impl DotPath {
    /// Every path, narrowest first.
    pub const ALL: [DotPath; 2] = [DotPath::Portable, DotPath::Vnni];

    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            DotPath::Portable => "portable",
            DotPath::Vnni => "vnni",
        }
    }

    /// Whether this CPU runs it (VNNI: AVX-512 F, BW, DQ and VNNI, and `NEUSPIKE_ISA` not
    /// narrower than `avx512`).
    pub fn is_supported(self) -> bool {
        self <= detect()
    }
}

/// The widest [`DotPath`] this CPU runs.
pub fn detect() -> DotPath {
    #[cfg(target_arch = "x86_64")]
    {
        if crate::detect() == Isa::Avx512 && std::arch::is_x86_feature_detected!("avx512vnni") {
            return DotPath::Vnni;
        }
    }
    DotPath::Portable
}

/// The inputs of [`accumulate`]: tap `t` of point `i` reads the word `rows[offsets[t] + i]`
/// (four unsigned bytes) with, for output channel `o` of group `g`, the word
/// `weights[g * group_stride + OUTS t + o]` (four signed bytes).
#[derive(Clone, Copy, Debug)]
pub struct ByteTaps<'a> {
    /// The values the taps read, a word of four channels per point.
    pub rows: &'a [u32],
    /// Where each tap's run of points starts in `rows`.
    pub offsets: &'a [usize],
    /// The weights, [`OUTS`] words per tap, then the next group `group_stride` words on.
    pub weights: &'a [u32],
    /// The distance between two groups' weights in `weights`.
    pub group_stride: usize,
}

/// Four bytes as the word [`ByteTaps`] reads: byte `j` in bits `8j..8j + 8`.
#[inline(always)]
pub fn word(bytes: [u8; 4]) -> u32 {
    u32::from_le_bytes(bytes)
}

/// For every group `g < groups`, output channel `o < OUTS` and point `i < width`, adds to
/// `out[(OUTS g + o) out_stride + i]` every tap's four products of a value byte (unsigned) and a
/// weight (signed), see [`ByteTaps`], wrapping modulo 2^32. A sum stays exact while the taps
/// times 4 x 255 x 128 stays below 2^31 (more than 16,000 taps).
///
/// Runs on `path` or the widest path below it this CPU has.
///
/// # Panics
/// If `width` is not a multiple of [`POINTS`], or a tap, weight or output lies outside its
/// slice (checked before any work).
pub fn accumulate(
    path: DotPath,
    taps: &ByteTaps,
    out: &mut [i32],
    out_stride: usize,
    groups: usize,
    width: usize,
) {
    let ByteTaps {
        rows,
        offsets,
        weights,
        group_stride,
    } = *taps;
    assert!(width.is_multiple_of(POINTS), "width {width}");
    if groups == 0 || width == 0 {
        return;
    }
    // Checked arithmetic: a reach that wrapped around would pass the checks below.
    let reach = offsets
        .iter()
        .max()
        .map_or(Some(0), |&m| m.checked_add(width));
    assert!(
        reach.is_some_and(|r| r <= rows.len()),
        "taps reach {reach:?} of {}",
        rows.len()
    );
    let reach = (groups - 1)
        .checked_mul(group_stride)
        .and_then(|r| r.checked_add(OUTS.checked_mul(offsets.len())?));
    assert!(
        reach.is_some_and(|r| r <= weights.len()),
        "weights reach {reach:?} of {}",
        weights.len()
    );
    let reach = OUTS
        .checked_mul(groups)
        .and_then(|n| (n - 1).checked_mul(out_stride)?.checked_add(width));
    assert!(
        reach.is_some_and(|r| r <= out.len()),
        "outputs reach {reach:?} of {}",
        out.len()
    );
    assert!(
        out_stride >= width,
        "output rows of {out_stride} for {width} points"
    );
    #[cfg(target_arch = "x86_64")]
    if path.min(detect()) == DotPath::Vnni {
        let args = x86::Args {
            rows: rows.as_ptr(),
            offsets,
            weights: weights.as_ptr(),
            group_stride,
            out: out.as_mut_ptr(),
            out_stride,
            groups,
        };
        // SAFETY: the CPU has AVX-512 F and VNNI (`detect`); every index the kernel forms is
        // below a reach checked above, and outputs of different channels do not overlap
        // (`out_stride >= width`).
        #[allow(unsafe_code)]
        return unsafe { x86::vnni(&args, width / 16) };
    }
    let _ = path;
    crate::dispatch(
        #[inline(always)]
        || portable(taps, out, out_stride, groups, width),
    )
}

/// The definition, in plain loops.
#[inline(always)]
fn portable(taps: &ByteTaps, out: &mut [i32], out_stride: usize, groups: usize, width: usize) {
    for g in 0..groups {
        for o in 0..OUTS {
            let dst = &mut out[(OUTS * g + o) * out_stride..][..width];
            for (t, &offset) in taps.offsets.iter().enumerate() {
                let w = taps.weights[g * taps.group_stride + OUTS * t + o].to_le_bytes();
                let w = w.map(|b| i32::from(b as i8));
                for (a, &v) in dst.iter_mut().zip(&taps.rows[offset..][..width]) {
                    let v = v.to_le_bytes().map(i32::from);
                    let dot = (v[0] * w[0] + v[1] * w[1]).wrapping_add(v[2] * w[2] + v[3] * w[3]);
                    *a = a.wrapping_add(dot);
                }
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod x86 {
    use std::arch::x86_64::*;

    use super::OUTS;

    /// [`super::accumulate`]'s checked arguments as pointers.
    pub struct Args<'a> {
        pub rows: *const u32,
        pub offsets: &'a [usize],
        pub weights: *const u32,
        pub group_stride: usize,
        pub out: *mut i32,
        pub out_stride: usize,
        pub groups: usize,
    }

    /// Every point in blocks of at most 6 vectors of 16, every group for each block, so a
    /// block's tap rows stay in the L1 cache while the groups go by.
    ///
    /// # Safety
    /// The CPU has AVX-512 F and VNNI; `args` and `vectors` (of 16 points) are within the checks
    /// of [`super::accumulate`].
    #[target_feature(enable = "avx512f,avx512vnni")]
    pub unsafe fn vnni(args: &Args, vectors: usize) {
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

    /// Group `g`'s channels at points `i..i + 16P`.
    ///
    /// # Safety
    /// As [`vnni`], and `i + 16P` at most the width.
    #[target_feature(enable = "avx512f,avx512vnni")]
    #[inline]
    unsafe fn block16<const P: usize>(args: &Args, g: usize, i: usize) {
        // SAFETY: every pointer below stays within the reaches `accumulate` checked.
        unsafe {
            let out = args.out.add(OUTS * g * args.out_stride + i);
            let mut acc = [[_mm512_setzero_si512(); P]; OUTS];
            for (o, acc) in acc.iter_mut().enumerate() {
                for (p, acc) in acc.iter_mut().enumerate() {
                    *acc = _mm512_loadu_si512(out.add(o * args.out_stride + 16 * p).cast());
                }
            }
            let mut w = args.weights.add(g * args.group_stride);
            for &offset in args.offsets {
                let src = args.rows.add(offset + i);
                let mut v = [_mm512_setzero_si512(); P];
                for (p, v) in v.iter_mut().enumerate() {
                    *v = _mm512_loadu_si512(src.add(16 * p).cast());
                }
                for (o, acc) in acc.iter_mut().enumerate() {
                    let w = _mm512_set1_epi32(*w.add(o) as i32);
                    for (acc, &v) in acc.iter_mut().zip(&v) {
                        *acc = _mm512_dpbusd_epi32(*acc, v, w);
                    }
                }
                w = w.add(OUTS);
            }
            for (o, acc) in acc.iter().enumerate() {
                for (p, &acc) in acc.iter().enumerate() {
                    _mm512_storeu_si512(out.add(o * args.out_stride + 16 * p).cast(), acc);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bytes(n: usize, seed: u32) -> Vec<u8> {
        (0..n)
            .map(|i| ((i as u32).wrapping_mul(2_654_435_761).wrapping_add(seed) >> 13) as u8)
            .collect()
    }

    fn words(bytes: &[u8]) -> Vec<u32> {
        bytes
            .chunks_exact(4)
            .map(|b| word([b[0], b[1], b[2], b[3]]))
            .collect()
    }

    /// Every path gives the definition's sums, at every block remainder, the extremes of both
    /// byte ranges included.
    #[test]
    fn every_path_gives_the_definitions_sums() {
        for width in [16, 32, 48, 64, 80, 96, 112, 160, 400] {
            let (groups, n_taps) = (3, 11);
            let mut rows = bytes(CHANNELS * (width * 7 + 5), 1);
            rows[..64].fill(255);
            let offsets: Vec<usize> = (0..n_taps).map(|t| (t * 37) % (width * 6 + 5)).collect();
            let group_stride = OUTS * n_taps + 3;
            let mut weights = bytes(CHANNELS * groups * group_stride, 2);
            weights[..16].fill(0x80);
            let out_stride = width + 16;
            let start: Vec<i32> = bytes(OUTS * groups * out_stride, 3)
                .into_iter()
                .map(|b| b as i32 * 1000 - 128_000)
                .collect();
            let mut want = start.clone();
            for g in 0..groups {
                for o in 0..OUTS {
                    for i in 0..width {
                        let a = &mut want[(OUTS * g + o) * out_stride + i];
                        for (t, &off) in offsets.iter().enumerate() {
                            for j in 0..CHANNELS {
                                let w = weights[4 * (g * group_stride + OUTS * t + o) + j] as i8;
                                *a += rows[4 * (off + i) + j] as i32 * w as i32;
                            }
                        }
                    }
                }
            }
            let (rows, weights) = (words(&rows), words(&weights));
            let taps = ByteTaps {
                rows: &rows,
                offsets: &offsets,
                weights: &weights,
                group_stride,
            };
            for path in DotPath::ALL {
                let mut out = start.clone();
                accumulate(path, &taps, &mut out, out_stride, groups, width);
                assert_eq!(out, want, "{} at width {width}", path.name());
            }
        }
    }

    #[test]
    #[should_panic(expected = "taps reach")]
    fn a_tap_past_its_rows_is_refused() {
        let rows = vec![0; 40];
        let taps = ByteTaps {
            rows: &rows,
            offsets: &[0, 30],
            weights: &[0; 8],
            group_stride: 8,
        };
        accumulate(DotPath::Vnni, &taps, &mut [0; 64], 16, 1, 16);
    }

    #[test]
    #[should_panic(expected = "weights reach")]
    fn weights_past_their_slice_are_refused() {
        let taps = ByteTaps {
            rows: &[0; 64],
            offsets: &[0, 0],
            weights: &[0; 4],
            group_stride: 8,
        };
        accumulate(DotPath::Vnni, &taps, &mut [0; 64], 16, 1, 16);
    }

    #[test]
    fn the_widest_path_is_supported() {
        assert!(DotPath::Portable.is_supported());
        assert!(detect().is_supported());
    }
}
