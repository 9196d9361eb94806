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
    /// AMX tiles (`tdpbsud`: 16 output channels by 16 points by 16 quads of channels in one
    /// instruction), for [`accumulate_tiles`]; [`accumulate`] runs VNNI there.
    Amx,
}

impl DotPath {
    /// Every path, narrowest first.
    pub const ALL: [DotPath; 3] = [DotPath::Portable, DotPath::Vnni, DotPath::Amx];

    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            DotPath::Portable => "portable",
            DotPath::Vnni => "vnni",
            DotPath::Amx => "amx",
        }
    }

    /// Whether this CPU runs it (VNNI: AVX-512 F, BW, DQ and VNNI, and `NEUSPIKE_ISA` not
    /// narrower than `avx512`; AMX: VNNI's, AMX-TILE and AMX-INT8, and Linux's permission to
    /// use the tile registers, see [`amx_permitted`]).
    pub fn is_supported(self) -> bool {
        self <= detect()
    }
}

/// The widest [`DotPath`] this CPU runs.
pub fn detect() -> DotPath {
    #[cfg(target_arch = "x86_64")]
    {
        if crate::detect() == Isa::Avx512 && std::arch::is_x86_feature_detected!("avx512vnni") {
            return if amx_permitted() {
                DotPath::Amx
            } else {
                DotPath::Vnni
            };
        }
    }
    DotPath::Portable
}

/// The inputs of [`accumulate`]: tap `t` of point `i` reads the word `rows[offsets[t] + i]`
/// (four unsigned bytes) with, for output channel `o` of group `g`, the word
/// `weights[g * group_stride + OUTS t + o]` (four signed bytes). [`crate::bf16::accumulate`]
/// reads the same words as two `bf16` each.
#[derive(Clone, Copy, Debug)]
pub struct WordTaps<'a> {
    /// The values the taps read, a word of several channels per point.
    pub rows: &'a [u32],
    /// Where each tap's run of points starts in `rows`.
    pub offsets: &'a [usize],
    /// The weights, [`OUTS`] words per tap, then the next group `group_stride` words on.
    pub weights: &'a [u32],
    /// The distance between two groups' weights in `weights`.
    pub group_stride: usize,
}

/// Four bytes as the word [`WordTaps`] reads: byte `j` in bits `8j..8j + 8`.
#[inline(always)]
pub fn word(bytes: [u8; 4]) -> u32 {
    u32::from_le_bytes(bytes)
}

/// For every group `g < groups`, output channel `o < OUTS` and point `i < width`, adds to
/// `out[(OUTS g + o) out_stride + i]` every tap's four products of a value byte (unsigned) and a
/// weight (signed), see [`WordTaps`], wrapping modulo 2^32. A sum stays exact while the taps
/// times 4 x 255 x 128 stays below 2^31 (more than 16,000 taps).
///
/// Runs on `path` or the widest path below it this CPU has.
///
/// # Panics
/// If `width` is not a multiple of [`POINTS`], or a tap, weight or output lies outside its
/// slice (checked before any work).
pub fn accumulate(
    path: DotPath,
    taps: &WordTaps,
    out: &mut [i32],
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
    assert!(width.is_multiple_of(POINTS), "width {width}");
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
    if path.min(detect()) >= DotPath::Vnni {
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

/// Whether this process may use the AMX tile registers: the CPU has AMX-TILE and AMX-INT8
/// (CPUID leaf 7), and Linux granted the permission to use them (`arch_prctl` with
/// `ARCH_REQ_XCOMP_PERM`, asked once per process; without it the first tile instruction would
/// kill the process). `false` where either is missing, and on other systems.
pub fn amx_permitted() -> bool {
    static PERMITTED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *PERMITTED.get_or_init(|| {
        #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
        {
            let leaf = std::arch::x86_64::__cpuid_count(7, 0);
            let (tile, int8) = (leaf.edx >> 24 & 1 == 1, leaf.edx >> 25 & 1 == 1);
            if !(tile && int8) {
                return false;
            }
            const ARCH_REQ_XCOMP_PERM: libc::c_long = 0x1023;
            const XFEATURE_XTILEDATA: libc::c_long = 18;
            // SAFETY: a system call taking two integers; it reads and writes no memory of ours.
            #[allow(unsafe_code)]
            let granted = unsafe {
                libc::syscall(
                    libc::SYS_arch_prctl,
                    ARCH_REQ_XCOMP_PERM,
                    XFEATURE_XTILEDATA,
                )
            } == 0;
            granted
        }
        #[cfg(not(all(target_arch = "x86_64", target_os = "linux")))]
        false
    })
}

/// Output channels of one tile of sums.
pub const TILE_OUTS: usize = 16;

/// Quads of input channels one call of [`accumulate_tiles`] takes at most (a tile's 64 bytes).
pub const TILE_QUADS: usize = 16;

/// The inputs of [`accumulate_tiles`]: tap `t` of point `i` of quad `q` reads the word
/// `rows[taps[t] + q * quad_stride + i]`, with, for output channel `o`, the word
/// `weights[((o / 16) * taps.len() + t) * 16 * quads + (o % 16) * quads + q]`: per group of 16
/// output channels and tap, a tile of 16 rows of `quads` words (rows past the last output
/// channel 0).
#[derive(Clone, Copy, Debug)]
pub struct TileTaps<'a> {
    /// The values the taps read, a word of four channels per point.
    pub rows: &'a [u32],
    /// Where each tap's run of points of quad 0 starts in `rows`.
    pub taps: &'a [usize],
    /// The distance between two quads' runs.
    pub quad_stride: usize,
    /// Quads of input channels, at most [`TILE_QUADS`].
    pub quads: usize,
    /// The weights, tile by tile (see above).
    pub weights: &'a [u32],
}

/// For every output channel `o < outs` and point `i < width`, adds to `out[o out_stride + i]`
/// every tap's and quad's four products (see [`TileTaps`]), wrapping modulo 2^32: the sums
/// [`accumulate`] makes, with the weights in tiles. On AMX where `path` and this CPU allow,
/// else in plain loops.
///
/// # Panics
/// If `width` is not a multiple of [`POINTS`], `quads` is 0 or over [`TILE_QUADS`], or a tap,
/// weight or output lies outside its slice (checked before any work).
pub fn accumulate_tiles(
    path: DotPath,
    taps: &TileTaps,
    out: &mut [i32],
    out_stride: usize,
    outs: usize,
    width: usize,
) {
    assert!(width.is_multiple_of(POINTS), "width {width}");
    assert!(
        (1..=TILE_QUADS).contains(&taps.quads),
        "{} quads in a tile",
        taps.quads
    );
    if outs == 0 || width == 0 || taps.taps.is_empty() {
        return;
    }
    let reach = taps.taps.iter().max().and_then(|&m| {
        m.checked_add((taps.quads - 1).checked_mul(taps.quad_stride)?)?
            .checked_add(width)
    });
    assert!(
        reach.is_some_and(|r| r <= taps.rows.len()),
        "taps reach {reach:?} of {}",
        taps.rows.len()
    );
    let reach = outs
        .div_ceil(TILE_OUTS)
        .checked_mul(taps.taps.len())
        .and_then(|n| n.checked_mul(TILE_OUTS * taps.quads));
    assert!(
        reach.is_some_and(|r| r <= taps.weights.len()),
        "weights reach {reach:?} of {}",
        taps.weights.len()
    );
    let reach = (outs - 1)
        .checked_mul(out_stride)
        .and_then(|r| r.checked_add(width));
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
    if path.min(detect()) == DotPath::Amx {
        // SAFETY: the CPU has AMX-TILE and AMX-INT8 and Linux granted their use
        // (`amx_permitted`, through `detect`); every tile the kernel loads or stores lies within
        // a reach checked above.
        #[allow(unsafe_code)]
        return unsafe { amx::accumulate(taps, out.as_mut_ptr(), out_stride, outs, width) };
    }
    let _ = path;
    crate::dispatch(
        #[inline(always)]
        || portable_tiles(taps, out, out_stride, outs, width),
    )
}

/// [`accumulate_tiles`]' definition, in plain loops.
#[inline(always)]
fn portable_tiles(taps: &TileTaps, out: &mut [i32], out_stride: usize, outs: usize, width: usize) {
    let n_taps = taps.taps.len();
    for o in 0..outs {
        let dst = &mut out[o * out_stride..][..width];
        for (t, &offset) in taps.taps.iter().enumerate() {
            let tile = ((o / TILE_OUTS) * n_taps + t) * TILE_OUTS * taps.quads;
            for q in 0..taps.quads {
                let w = taps.weights[tile + (o % TILE_OUTS) * taps.quads + q].to_le_bytes();
                let w = w.map(|b| i32::from(b as i8));
                let src = &taps.rows[offset + q * taps.quad_stride..][..width];
                for (a, &v) in dst.iter_mut().zip(src) {
                    let v = v.to_le_bytes().map(i32::from);
                    let dot = (v[0] * w[0] + v[1] * w[1]).wrapping_add(v[2] * w[2] + v[3] * w[3]);
                    *a = a.wrapping_add(dot);
                }
            }
        }
    }
}

/// The AMX kernel: tiles of 16 output channels by 16 points, four of them (64 points) held
/// while the taps go by, each tap one tile of weights by four tiles of values.
#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod amx {
    use std::arch::asm;

    use super::{TILE_OUTS, TileTaps};

    /// The tile configuration `ldtilecfg` reads: palette 1, then each tile's bytes per row and
    /// rows.
    #[repr(C, align(64))]
    struct Config([u8; 64]);

    impl Config {
        /// Tiles 0-3 the sums (`outs` rows of 16 words), 4 the weights (`outs` rows of
        /// `quads` words), 5-6 the values (`quads` rows of 16 words).
        fn new(outs: usize, quads: usize) -> Config {
            let mut c = [0u8; 64];
            c[0] = 1;
            let mut tile = |t: usize, rows: usize, bytes: usize| {
                c[16 + 2 * t..18 + 2 * t].copy_from_slice(&(bytes as u16).to_le_bytes());
                c[48 + t] = rows as u8;
            };
            for t in 0..4 {
                tile(t, outs, 64);
            }
            tile(4, outs, 4 * quads);
            tile(5, quads, 64);
            tile(6, quads, 64);
            Config(c)
        }
    }

    /// `tileloadd tmmT, [ptr + stride]`.
    macro_rules! load {
        ($t:literal, $ptr:expr, $stride:expr) => {
            asm!(concat!("tileloadd tmm", $t, ", [{p} + {s}*1]"), p = in(reg) $ptr, s = in(reg) $stride, options(nostack, readonly))
        };
    }

    /// `tilestored [ptr + stride], tmmT`.
    macro_rules! store {
        ($t:literal, $ptr:expr, $stride:expr) => {
            asm!(concat!("tilestored [{p} + {s}*1], tmm", $t), p = in(reg) $ptr, s = in(reg) $stride, options(nostack))
        };
    }

    /// `tdpbsud tmmC, tmm4, tmmB`: sums `C` += weights (signed) by values (unsigned).
    macro_rules! dot {
        ($c:literal, $b:literal) => {
            asm!(
                concat!("tdpbsud tmm", $c, ", tmm4, tmm", $b),
                options(nostack, nomem)
            )
        };
    }

    /// # Safety
    /// The CPU has AMX-TILE and AMX-INT8, Linux granted their use, and `taps`, `out`,
    /// `out_stride`, `outs` and `width` are within the checks of [`super::accumulate_tiles`].
    pub unsafe fn accumulate(
        taps: &TileTaps,
        out: *mut i32,
        out_stride: usize,
        outs: usize,
        width: usize,
    ) {
        let (n_taps, quads) = (taps.taps.len(), taps.quads);
        let (out_bytes, quad_bytes, weight_bytes) =
            (4 * out_stride, 4 * taps.quad_stride, 4 * quads);
        // SAFETY: every tile loaded or stored lies within the reaches `accumulate_tiles`
        // checked: the sums' rows `o < outs` at points below `width`, the weights' tiles of the
        // groups and taps there are, the values' runs of `width` points from each tap of each
        // quad. Tile registers are touched by nothing but these instructions.
        unsafe {
            // `ldtilecfg` costs about as much as a group's products at a row of 50 points: it
            // is loaded again only for a last group of fewer than 16 output channels.
            let mut loaded = 0;
            for g in 0..outs.div_ceil(TILE_OUTS) {
                let rows = (outs - g * TILE_OUTS).min(TILE_OUTS);
                if rows != loaded {
                    let config = Config::new(rows, quads);
                    asm!("ldtilecfg [{c}]", c = in(reg) config.0.as_ptr(), options(nostack, readonly));
                    loaded = rows;
                }
                let sums = out.add(g * TILE_OUTS * out_stride);
                let mut x = 0;
                while x < width {
                    let blocks = ((width - x) / 16).min(4);
                    let at = |b: usize| sums.add(x + 16 * b);
                    load!(0, at(0), out_bytes);
                    if blocks > 1 {
                        load!(1, at(1), out_bytes)
                    }
                    if blocks > 2 {
                        load!(2, at(2), out_bytes)
                    }
                    if blocks > 3 {
                        load!(3, at(3), out_bytes)
                    }
                    for (t, &offset) in taps.taps.iter().enumerate() {
                        let tile = taps
                            .weights
                            .as_ptr()
                            .add((g * n_taps + t) * TILE_OUTS * quads);
                        load!(4, tile, weight_bytes);
                        let values = |b: usize| taps.rows.as_ptr().add(offset + x + 16 * b);
                        load!(5, values(0), quad_bytes);
                        dot!(0, 5);
                        if blocks > 1 {
                            load!(6, values(1), quad_bytes);
                            dot!(1, 6);
                        }
                        if blocks > 2 {
                            load!(5, values(2), quad_bytes);
                            dot!(2, 5);
                        }
                        if blocks > 3 {
                            load!(6, values(3), quad_bytes);
                            dot!(3, 6);
                        }
                    }
                    store!(0, at(0), out_bytes);
                    if blocks > 1 {
                        store!(1, at(1), out_bytes)
                    }
                    if blocks > 2 {
                        store!(2, at(2), out_bytes)
                    }
                    if blocks > 3 {
                        store!(3, at(3), out_bytes)
                    }
                    x += 16 * blocks;
                }
            }
            asm!("tilerelease", options(nostack, nomem));
        }
    }
}

/// The definition, in plain loops.
#[inline(always)]
fn portable(taps: &WordTaps, out: &mut [i32], out_stride: usize, groups: usize, width: usize) {
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
            let taps = WordTaps {
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
        let taps = WordTaps {
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
        let taps = WordTaps {
            rows: &[0; 64],
            offsets: &[0, 0],
            weights: &[0; 4],
            group_stride: 8,
        };
        accumulate(DotPath::Vnni, &taps, &mut [0; 64], 16, 1, 16);
    }

    /// The tiles' sums are the definition's on every path, for 1 to 16 quads, output channels
    /// not a multiple of 16 and widths not a multiple of 64.
    #[test]
    fn tiles_give_the_definitions_sums() {
        for (outs, quads, width) in [
            (8usize, 8usize, 400usize),
            (16, 2, 48),
            (20, 16, 64),
            (4, 1, 16),
            (33, 5, 112),
        ] {
            let n_taps = 9;
            let quad_stride = 3 * (width + 16);
            let rows = words(&bytes(4 * (quads * quad_stride + 64), 5));
            let taps_at: Vec<usize> = (0..n_taps)
                .map(|t| (t % 3) + (t / 3) * (width + 16))
                .collect();
            let weights = words(&bytes(4 * outs.div_ceil(16) * n_taps * 16 * quads, 6));
            let out_stride = width + 16;
            let start: Vec<i32> = bytes(outs * out_stride, 7)
                .into_iter()
                .map(|b| b as i32 * 1000 - 128_000)
                .collect();
            let mut want = start.clone();
            for o in 0..outs {
                for i in 0..width {
                    for (t, &at) in taps_at.iter().enumerate() {
                        for q in 0..quads {
                            let w = weights
                                [((o / 16) * n_taps + t) * 16 * quads + (o % 16) * quads + q];
                            let v = rows[at + q * quad_stride + i];
                            for j in 0..4 {
                                let wj = (w >> (8 * j)) as u8 as i8 as i32;
                                let vj = (v >> (8 * j)) as u8 as i32;
                                want[o * out_stride + i] += wj * vj;
                            }
                        }
                    }
                }
            }
            let taps = TileTaps {
                rows: &rows,
                taps: &taps_at,
                quad_stride,
                quads,
                weights: &weights,
            };
            for path in DotPath::ALL {
                let mut out = start.clone();
                accumulate_tiles(path, &taps, &mut out, out_stride, outs, width);
                assert_eq!(
                    out,
                    want,
                    "{} for {outs} outputs, {quads} quads, width {width}",
                    path.name()
                );
            }
        }
    }

    #[test]
    #[should_panic(expected = "taps reach")]
    fn tiles_past_their_rows_are_refused() {
        // Quad 1 of tap 1 reads points 51..67 of 60.
        let taps = TileTaps {
            rows: &[0; 60],
            taps: &[0, 1],
            quad_stride: 50,
            quads: 2,
            weights: &[0; 64],
        };
        accumulate_tiles(DotPath::Amx, &taps, &mut [0; 16], 16, 1, 16);
    }

    /// The environment variable that makes [`amx_refused_child`] run.
    const REFUSED_CHILD: &str = "NEUSPIKE_AMX_REFUSED_CHILD";

    /// Makes Linux refuse this process the AMX tile registers: a seccomp filter that answers
    /// `arch_prctl(ARCH_REQ_XCOMP_PERM, ..)` with `EPERM` and lets every other call through.
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    #[allow(unsafe_code)]
    fn refuse_amx() {
        // Classic BPF over `struct seccomp_data`: `nr` at 0, the first argument's low word at 16.
        let op = |code: u16, jt: u8, jf: u8, k: u32| libc::sock_filter { code, jt, jf, k };
        const LD_W_ABS: u16 = 0x20;
        const JEQ_K: u16 = 0x15;
        const RET_K: u16 = 0x06;
        const SECCOMP_RET_ERRNO: u32 = 0x0005_0000;
        const SECCOMP_RET_ALLOW: u32 = 0x7fff_0000;
        let mut filter = [
            op(LD_W_ABS, 0, 0, 0),
            op(JEQ_K, 0, 3, libc::SYS_arch_prctl as u32),
            op(LD_W_ABS, 0, 0, 16),
            op(JEQ_K, 0, 1, 0x1023),
            op(RET_K, 0, 0, SECCOMP_RET_ERRNO | libc::EPERM as u32),
            op(RET_K, 0, 0, SECCOMP_RET_ALLOW),
        ];
        let program = libc::sock_fprog {
            len: filter.len() as u16,
            filter: filter.as_mut_ptr(),
        };
        // SAFETY: `prctl` with integer arguments, then with a pointer to `program`, which lives
        // across the call; the kernel copies the filter.
        unsafe {
            assert_eq!(
                libc::prctl(libc::PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0),
                0,
                "no_new_privs"
            );
            assert_eq!(
                libc::prctl(
                    libc::PR_SET_SECCOMP,
                    libc::SECCOMP_MODE_FILTER,
                    &program as *const libc::sock_fprog,
                    0,
                    0
                ),
                0,
                "seccomp filter"
            );
        }
    }

    /// Run by [`amx_refused_falls_back`] in a process of its own: with the permission refused,
    /// the path is VNNI (or plain loops), and sums asked of AMX come out the same.
    #[test]
    #[ignore = "run by amx_refused_falls_back in a child process"]
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    fn amx_refused_child() {
        assert!(
            std::env::var_os(REFUSED_CHILD).is_some(),
            "run by amx_refused_falls_back"
        );
        refuse_amx();
        assert!(!amx_permitted(), "the permission was refused");
        assert_ne!(detect(), DotPath::Amx);
        assert!(!DotPath::Amx.is_supported());
        let (rows, weights) = (
            words(&bytes(4 * 3 * 64, 1)),
            words(&bytes(4 * 16 * 9 * 2, 2)),
        );
        let taps = TileTaps {
            rows: &rows,
            taps: &[0, 1, 2, 16, 17, 18, 32, 33, 34],
            quad_stride: 64,
            quads: 2,
            weights: &weights,
        };
        let (mut amx, mut plain) = (vec![0; 16 * 16], vec![0; 16 * 16]);
        accumulate_tiles(DotPath::Amx, &taps, &mut amx, 16, 16, 16);
        accumulate_tiles(DotPath::Portable, &taps, &mut plain, 16, 16, 16);
        assert_eq!(amx, plain);
        println!("refused: 8-bit path {}", detect().name());
    }

    #[test]
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    fn amx_refused_falls_back() {
        let exe = std::env::current_exe().expect("the test binary");
        let out = std::process::Command::new(exe)
            .args([
                "--ignored",
                "--exact",
                "dot::tests::amx_refused_child",
                "--nocapture",
            ])
            .env(REFUSED_CHILD, "1")
            .output()
            .expect("the child runs");
        let text = String::from_utf8_lossy(&out.stdout).to_string()
            + &String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{text}");
        assert!(
            text.contains("refused: 8-bit path"),
            "the child test ran: {text}"
        );
    }

    #[test]
    fn the_widest_path_is_supported() {
        assert!(DotPath::Portable.is_supported());
        assert!(detect().is_supported());
        eprintln!("8-bit path here: {}", detect().name());
    }
}
