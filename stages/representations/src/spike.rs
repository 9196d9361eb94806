//! Spike-plane representations: TFP, ISI, TFI and the NeuSpike-Net spike tensor.
//!
//! Input planes are `ArrayView3<u8>` shaped `[N, H, W]`; plane `k` was read at
//! `t_first_ns + k * plane_period_ns`. A value is a spike when it is nonzero (the sources send 0/1;
//! any other nonzero byte counts as one spike, never as several), so every output stays in its
//! documented range whatever the bytes are.
//!
//! Each kernel has a plain scalar `*_reference` (the oracle) and a fast path that scans whole rows
//! (contiguous slices where the layout allows) and hands blocks of [`ROWS_PER_TASK`] rows to rayon
//! once the input has at least [`MIN_ELEMENTS_FOR_RAYON`] elements. Both give bit-identical
//! results; the tests check it.

use ndarray::{ArrayView1, ArrayView3, ArrayViewMut2, ArrayViewMut3, Axis, Zip, s};
use rayon::prelude::*;

use crate::error::{RepresentError, shape_str};

/// Rows of the output handed to one rayon task.
pub const ROWS_PER_TASK: usize = 8;

/// Input elements (planes x pixels read) below which a kernel stays on the calling thread.
pub const MIN_ELEMENTS_FOR_RAYON: usize = 1 << 16;

/// Largest number of planes the spike kernels accept (plane indices and counts are kept in `u32`).
pub const MAX_PLANES: usize = (u32::MAX - 1) as usize;

// ---------------------------------------------------------------------------------------------
// Checks shared by the kernels
// ---------------------------------------------------------------------------------------------

/// Checks that there is at least one plane, not more than [`MAX_PLANES`], and returns `N`.
fn check_planes(spikes: &ArrayView3<u8>) -> Result<usize, RepresentError> {
    let n = spikes.len_of(Axis(0));
    if n == 0 {
        return Err(RepresentError::Param {
            name: "spikes planes N",
            value: "0".to_owned(),
            reason: "at least one spike plane is needed",
        });
    }
    if n > MAX_PLANES {
        return Err(RepresentError::Param {
            name: "spikes planes N",
            value: n.to_string(),
            reason: "more planes than the kernels can index (u32::MAX - 1)",
        });
    }
    Ok(n)
}

/// Checks that an `[H, W]` destination matches the planes' `[H, W]`.
fn check_image(
    what: &'static str,
    spikes: &ArrayView3<u8>,
    dst_dim: (usize, usize),
) -> Result<(), RepresentError> {
    let (_, h, w) = spikes.dim();
    if dst_dim != (h, w) {
        return Err(RepresentError::Shape {
            what,
            expected: shape_str(&[h, w]),
            actual: shape_str(&[dst_dim.0, dst_dim.1]),
        });
    }
    Ok(())
}

/// Checks that the reference plane lies inside the planes given.
fn check_reference_plane(c: usize, n: usize) -> Result<(), RepresentError> {
    if c >= n {
        return Err(RepresentError::Index {
            what: "reference plane c".to_owned(),
            value: c as u64,
            limit: n as u64,
        });
    }
    Ok(())
}

/// Whether a kernel reading `elements` input elements should fan out over rayon.
fn use_rayon(elements: usize) -> bool {
    elements >= MIN_ELEMENTS_FOR_RAYON
}

// ---------------------------------------------------------------------------------------------
// TFP
// ---------------------------------------------------------------------------------------------

/// Firing rate for `count` spikes over `n` planes, `count / n` correctly rounded to `f32`; the one
/// formula every path uses. Below 2^24 planes both numbers are exact in `f32` and one `f32`
/// division rounds correctly (it equals the `f64` quotient rounded to `f32`: double rounding is
/// harmless for a quotient when the wide format has more than twice the bits plus two).
#[inline]
fn rate(count: u32, n: usize) -> f32 {
    if n <= 1 << 24 {
        count as f32 / n as f32
    } else {
        (f64::from(count) / n as f64) as f32
    }
}

/// TFP (texture from playback): the mean firing over all `N` planes given, per pixel.
///
/// `dst[y, x] = (number of planes k with spikes[k, y, x] != 0) / N`, the firing rate per tick, in
/// `[0, 1]` (1 for a pixel that fires every tick). The caller slices the window it wants (an odd
/// window centred on the reference plane, per docs/definitions.md); this kernel averages everything given.
///
/// # Errors
/// - [`RepresentError::Param`] when `N == 0` (no rate is defined) or `N > MAX_PLANES`.
/// - [`RepresentError::Shape`] when `dst` is not `[H, W]`.
///
/// An image with `H == 0` or `W == 0` is accepted and leaves nothing to write.
///
/// ```
/// use ndarray::{Array2, Array3};
/// let mut spikes = Array3::<u8>::zeros((8, 1, 2));
/// for k in (0..8).step_by(4) { spikes[[k, 0, 0]] = 1; }
/// let mut rate = Array2::<f32>::zeros((1, 2));
/// neuspike_representations::tfp_into(spikes.view(), rate.view_mut()).unwrap();
/// assert_eq!(rate[[0, 0]], 0.25);
/// assert_eq!(rate[[0, 1]], 0.0);
/// ```
pub fn tfp_into(spikes: ArrayView3<u8>, dst: ArrayViewMut2<f32>) -> Result<(), RepresentError> {
    check_planes(&spikes)?;
    check_image("tfp dst", &spikes, dst.dim())?;
    tfp_rows(spikes, dst, ROWS_PER_TASK, use_rayon(spikes.len()));
    Ok(())
}

/// [`tfp_into`] straight from bit-packed planes, without unpacking them: `bits` holds planes of
/// `ceil(H W / 8)` bytes each, pixel `i = y W + x` at bit `i & 7` of byte `i >> 3` (the
/// `SpikeChunk` layout), and the TFP averages `planes` (a range of plane indices). `H` and `W`
/// come from `dst`. Equal to unpacking and calling [`tfp_into`] (tested, on every instruction
/// set).
///
/// Counting is bit-sliced: each 64-pixel word of a plane is added into six bit planes of
/// counters by carry-save logic (`AND` and `XOR` only, 64 pixels an operation, vectorised), for
/// blocks of up to 63 planes; each block's counters are then read out eight pixels at a time
/// into `u32` counts.
///
/// # Errors
/// - [`RepresentError::Param`] when the range is empty or longer than [`MAX_PLANES`].
/// - [`RepresentError::Shape`] when `bits` holds fewer than `planes.end` planes.
pub fn tfp_packed_into(
    bits: &[u8],
    planes: std::ops::Range<usize>,
    dst: ArrayViewMut2<f32>,
) -> Result<(), RepresentError> {
    tfp_packed_into_with(neuspike_simd::detect(), bits, planes, dst)
}

/// One packed plane as little-endian 64-pixel words (`dst` is `ceil(plane.len() / 8)` long; the
/// last word is zero-padded).
pub(crate) fn plane_words(plane: &[u8], dst: &mut [u64]) {
    let (whole, tail) = plane.split_at(plane.len() / 8 * 8);
    for (d, c) in dst.iter_mut().zip(whole.chunks_exact(8)) {
        let mut b = [0u8; 8];
        b.copy_from_slice(c);
        *d = u64::from_le_bytes(b);
    }
    if let Some(last) = dst.last_mut()
        && !tail.is_empty()
    {
        let mut b = [0u8; 8];
        b[..tail.len()].copy_from_slice(tail);
        *last = u64::from_le_bytes(b);
    }
}

/// Bit planes of the sliced counters: counts up to 63 per block.
const SLICE_LEVELS: usize = 6;
/// Planes per block of sliced counting.
const SLICE_BLOCK: usize = (1 << SLICE_LEVELS) - 1;

/// [`tfp_packed_into`] compiled for a chosen instruction set (tests and benchmarks).
#[doc(hidden)]
pub fn tfp_packed_into_with(
    isa: neuspike_simd::Isa,
    bits: &[u8],
    planes: std::ops::Range<usize>,
    mut dst: ArrayViewMut2<f32>,
) -> Result<(), RepresentError> {
    let n = planes.len();
    if n == 0 || n > MAX_PLANES {
        return Err(RepresentError::Param {
            name: "spikes planes N",
            value: n.to_string(),
            reason: "between 1 and u32::MAX - 1 planes are needed",
        });
    }
    let (h, w) = dst.dim();
    let pixels = h * w;
    let per = pixels.div_ceil(8);
    if bits.len() < planes.end * per {
        return Err(RepresentError::Shape {
            what: "packed spike planes",
            expected: format!(
                "at least {} bytes ({} planes of {per})",
                planes.end * per,
                planes.end
            ),
            actual: format!("{} bytes", bits.len()),
        });
    }
    let words = per.div_ceil(8);
    let mut counts = vec![0u32; words * 64];
    // levels[b * words + i]: bit b of the counters of pixels 64 i .. 64 i + 63.
    let mut levels = vec![0u64; SLICE_LEVELS * words];
    let mut word_of_plane = vec![0u64; words];
    let mut start = planes.start;
    while start < planes.end {
        let end = (start + SLICE_BLOCK).min(planes.end);
        levels.fill(0);
        for k in start..end {
            plane_words(&bits[k * per..(k + 1) * per], &mut word_of_plane);
            neuspike_simd::with_isa(
                isa,
                #[inline(always)]
                || {
                    let (l0, rest) = levels.split_at_mut(words);
                    let (l1, rest) = rest.split_at_mut(words);
                    let (l2, rest) = rest.split_at_mut(words);
                    let (l3, rest) = rest.split_at_mut(words);
                    let (l4, l5) = rest.split_at_mut(words);
                    for (i, &x) in word_of_plane.iter().enumerate() {
                        // Carry-save add of one bit per pixel into six bit planes.
                        let mut c = x;
                        for l in [&mut l0[i], &mut l1[i], &mut l2[i], &mut l3[i], &mut l4[i]] {
                            let t = *l & c;
                            *l ^= c;
                            c = t;
                        }
                        l5[i] ^= c; // counts stay <= 63: no carry out of the top plane
                    }
                },
            );
        }
        // Read out: 32 pixels at a time (one half of a word), each lane shifting its own bit
        // out of the six planes (vectorised as variable shifts).
        neuspike_simd::with_isa(
            isa,
            #[inline(always)]
            || {
                for (i, counts) in counts.chunks_exact_mut(64).enumerate() {
                    for (half, counts) in counts.chunks_exact_mut(32).enumerate() {
                        let mut bits = [0u32; SLICE_LEVELS];
                        for (b, v) in bits.iter_mut().enumerate() {
                            *v = (levels[b * words + i] >> (32 * half)) as u32;
                        }
                        for (p, c) in counts.iter_mut().enumerate() {
                            let mut v = 0u32;
                            for (b, &l) in bits.iter().enumerate() {
                                v |= ((l >> p) & 1) << b;
                            }
                            *c += v;
                        }
                    }
                }
            },
        );
        start = end;
    }
    match dst.as_slice_mut() {
        Some(out) => {
            for (o, &c) in out.iter_mut().zip(&counts) {
                *o = rate(c, n);
            }
        }
        None => {
            for ((y, x), o) in dst.indexed_iter_mut() {
                *o = rate(counts[y * w + x], n);
            }
        }
    }
    Ok(())
}

/// Scalar oracle for [`tfp_into`]: one pixel at a time, one plane at a time. Same checks.
#[doc(hidden)]
pub fn tfp_reference(
    spikes: ArrayView3<u8>,
    mut dst: ArrayViewMut2<f32>,
) -> Result<(), RepresentError> {
    let n = check_planes(&spikes)?;
    check_image("tfp dst", &spikes, dst.dim())?;
    let (_, h, w) = spikes.dim();
    for y in 0..h {
        for x in 0..w {
            let mut count = 0u32;
            for k in 0..n {
                if spikes[[k, y, x]] != 0 {
                    count += 1;
                }
            }
            dst[[y, x]] = rate(count, n);
        }
    }
    Ok(())
}

/// Adds one plane row's spikes to per-pixel counts.
#[inline]
fn add_spikes(counts: &mut [u32], row: ArrayView1<u8>) {
    match row.as_slice() {
        Some(bytes) => {
            for (count, &b) in counts.iter_mut().zip(bytes) {
                *count += u32::from(b != 0);
            }
        }
        None => {
            for (count, &b) in counts.iter_mut().zip(row.iter()) {
                *count += u32::from(b != 0);
            }
        }
    }
}

/// Fast TFP over blocks of `rows_per_task` rows (`>= 1`), on rayon when `parallel`.
/// Shapes are checked by the caller.
fn tfp_rows(
    spikes: ArrayView3<u8>,
    mut dst: ArrayViewMut2<f32>,
    rows_per_task: usize,
    parallel: bool,
) {
    let n = spikes.len_of(Axis(0));
    let w = dst.ncols();
    let task = |(block, mut dst_block): (usize, ArrayViewMut2<f32>)| {
        let mut counts = vec![0u32; w];
        let y0 = block * rows_per_task;
        for (dy, mut dst_row) in dst_block.outer_iter_mut().enumerate() {
            counts.fill(0);
            for k in 0..n {
                add_spikes(&mut counts, spikes.slice(s![k, y0 + dy, ..]));
            }
            for (d, &count) in dst_row.iter_mut().zip(&counts) {
                *d = rate(count, n);
            }
        }
    };
    let blocks = dst.axis_chunks_iter_mut(Axis(0), rows_per_task.max(1));
    if parallel {
        blocks.into_par_iter().enumerate().for_each(task);
    } else {
        blocks.enumerate().for_each(task);
    }
}

// ---------------------------------------------------------------------------------------------
// ISI and TFI
// ---------------------------------------------------------------------------------------------

/// ISI in ticks from the row scan's `prev + 1` (0 = no spike at or before `c`) and `next`
/// (`N` = no spike after `c`). Missing sides take `prev = -1` and `next = N`, the nearest positions
/// outside the planes searched, which makes the result the shortest ISI consistent with the
/// planes: exact where both spikes were seen, a lower bound otherwise, and always `>= 1` because
/// `next > c >= prev`.
#[inline]
fn isi_ticks(prev_plus1: u32, next: u32) -> u32 {
    next + 1 - prev_plus1
}

/// Whether both the previous and the next spike were seen.
#[inline]
fn isi_valid(prev_plus1: u32, next: u32, n: u32) -> bool {
    prev_plus1 != 0 && next != n
}

/// TFI value (per tick) for an ISI in ticks; the one formula both paths use.
#[inline]
fn tfi_value(isi: u32) -> f32 {
    1.0 / isi as f32
}

/// Per-row scratch of the ISI scan: for every pixel of one row, `prev + 1` of the last spike at or
/// before `c` (0 when none) and the index of the first spike after `c` (`N` when none).
struct IsiRowScan {
    prev_plus1: Vec<u32>,
    next: Vec<u32>,
}

impl IsiRowScan {
    fn new(w: usize) -> Self {
        Self {
            prev_plus1: vec![0; w],
            next: vec![0; w],
        }
    }

    /// Scans row `y` outwards from `c`: backwards over `c, c-1, .., 0` writing the first spike met
    /// (the last at or before `c`), forwards over `c+1, .., N-1` likewise, each side stopping as
    /// soon as every pixel of the row has its spike. Branch-free per pixel, contiguous where the
    /// layout allows; costs `O(W * longest gap in the row)` rather than `O(W * N)`.
    fn run(&mut self, spikes: &ArrayView3<u8>, c: usize, y: usize) {
        let n = spikes.len_of(Axis(0));
        self.prev_plus1.fill(0);
        self.next.fill(n as u32);
        for k in (0..=c).rev() {
            let row = spikes.slice(s![k, y, ..]);
            if fill_first_spike(&mut self.prev_plus1, row, (k + 1) as u32, 0) == 0 {
                break;
            }
        }
        for k in c + 1..n {
            let row = spikes.slice(s![k, y, ..]);
            if fill_first_spike(&mut self.next, row, k as u32, n as u32) == 0 {
                break;
            }
        }
    }
}

/// Where a slot still holds `unset` and the plane row has a spike, writes `mark`; returns how many
/// slots still hold `unset` afterwards. `mark != unset`.
#[inline]
fn fill_first_spike(slots: &mut [u32], row: ArrayView1<u8>, mark: u32, unset: u32) -> u32 {
    let mut missing = 0u32;
    let mut step = |slot: &mut u32, b: u8| {
        let take = (*slot == unset) & (b != 0);
        *slot = if take { mark } else { *slot };
        missing += u32::from(*slot == unset);
    };
    match row.as_slice() {
        Some(bytes) => {
            for (slot, &b) in slots.iter_mut().zip(bytes) {
                step(slot, b);
            }
        }
        None => {
            for (slot, &b) in slots.iter_mut().zip(row.iter()) {
                step(slot, b);
            }
        }
    }
    missing
}

/// Inter-spike interval (ISI) at reference plane `c`, in ticks, with a validity mask.
///
/// Per docs/definitions.md: `prev` = the last spike at or before `c`, `next` = the first spike after `c`,
/// `ISI = next - prev`. The search is limited to the `N` planes given.
///
/// Where both exist, `isi[y, x] = next - prev` (`>= 1`) and `valid[y, x] = true`.
/// Where either is missing the ISI is unknown: `valid[y, x] = false` and `isi[y, x]` is the
/// shortest ISI the planes allow, taking a missing `prev` as `-1` and a missing `next` as `N`
/// (the nearest positions outside the window):
///
/// | seen        | `isi` written      |
/// |-------------|--------------------|
/// | prev, next  | `next - prev` (exact, valid) |
/// | next only   | `next + 1`         |
/// | prev only   | `N - prev`         |
/// | neither     | `N + 1`            |
///
/// The value is a lower bound on the true ISI, so `phi / isi` is an upper bound on the luminance:
/// a pixel dark over the whole window gets `phi / (N + 1)`, dimmer than anything the window could
/// have measured. It is finite and `>= 1` always. (The brief suggested
/// `next_or_N - prev_or_0 + 1`; this is the same bound where `prev` is missing and one tick tighter
/// where only `next` is missing.)
///
/// `isi` holds whole ticks as `f32`, exact up to `2^24` planes.
///
/// # Errors
/// - [`RepresentError::Param`] when `N == 0` or `N > MAX_PLANES`.
/// - [`RepresentError::Index`] when `c >= N`.
/// - [`RepresentError::Shape`] when `isi` or `valid` is not `[H, W]`.
pub fn isi_into(
    spikes: ArrayView3<u8>,
    c: usize,
    isi: ArrayViewMut2<f32>,
    valid: ArrayViewMut2<bool>,
) -> Result<(), RepresentError> {
    check_isi_args(&spikes, c, isi.dim())?;
    check_image("isi valid", &spikes, valid.dim())?;
    isi_rows(
        spikes,
        c,
        isi,
        valid,
        ROWS_PER_TASK,
        use_rayon(spikes.len()),
    );
    Ok(())
}

/// [`isi_into`] straight from bit-packed planes (the layout of [`tfp_packed_into`]): `bits` holds
/// at least `n` planes, the window is planes `0..n`, the reference plane is `c`; `H` and `W` come
/// from `isi`. Equal to unpacking and calling [`isi_into`] (tested, on every instruction set).
///
/// Bit-parallel: `ISI - 1` is the number of planes without a spike between the reference and
/// the nearest spike on each side, so walking outwards from `c`, each plane adds the mask of
/// pixels still waiting (64 pixels a word, carry-save into bit-sliced counters). The walk stops
/// as soon as no pixel waits: a bright window costs a few planes.
///
/// # Errors
/// As [`isi_into`], plus [`RepresentError::Shape`] when `bits` holds fewer than `n` planes.
pub fn isi_packed_into(
    bits: &[u8],
    n: usize,
    c: usize,
    isi: ArrayViewMut2<f32>,
    valid: ArrayViewMut2<bool>,
) -> Result<(), RepresentError> {
    isi_packed_into_with(neuspike_simd::detect(), bits, n, c, isi, valid)
}

/// [`isi_packed_into`] compiled for a chosen instruction set (tests and benchmarks).
#[doc(hidden)]
pub fn isi_packed_into_with(
    isi_set: neuspike_simd::Isa,
    bits: &[u8],
    n: usize,
    c: usize,
    mut isi: ArrayViewMut2<f32>,
    mut valid: ArrayViewMut2<bool>,
) -> Result<(), RepresentError> {
    if n == 0 || n > MAX_PLANES {
        return Err(RepresentError::Param {
            name: "spikes planes N",
            value: n.to_string(),
            reason: "between 1 and u32::MAX - 1 planes are needed",
        });
    }
    check_reference_plane(c, n)?;
    let (h, w) = isi.dim();
    if valid.dim() != (h, w) {
        return Err(RepresentError::Shape {
            what: "isi valid",
            expected: format!("[{h}, {w}]"),
            actual: format!("{:?}", valid.dim()),
        });
    }
    let per = (h * w).div_ceil(8);
    if bits.len() < n * per {
        return Err(RepresentError::Shape {
            what: "packed spike planes",
            expected: format!("at least {} bytes ({n} planes of {per})", n * per),
            actual: format!("{} bytes", bits.len()),
        });
    }
    let words = per.div_ceil(8);
    // Counters up to N (the planes without a spike on both sides): `levels` bit planes.
    let levels = (usize::BITS - n.leading_zeros()) as usize;
    let mut sliced = vec![0u64; levels * words];
    let mut words_of_plane = vec![0u64; words];
    // Pixels past the image in the last word never wait.
    let mut waiting_tail = vec![u64::MAX; words];
    let rem = (h * w) % 64;
    if rem != 0 {
        waiting_tail[words - 1] = (1u64 << rem) - 1;
    }
    let mut found = [vec![0u64; words], vec![0u64; words]];
    let mut carry = vec![0u64; words];
    for (side, found) in found.iter_mut().enumerate() {
        let mut waiting = waiting_tail.clone();
        let (backward, forward) = ((0..=c).rev(), c + 1..n);
        let order: &mut dyn Iterator<Item = usize> = if side == 0 {
            &mut { backward }
        } else {
            &mut { forward }
        };
        for k in order {
            plane_words(&bits[k * per..(k + 1) * per], &mut words_of_plane);
            let any = neuspike_simd::with_isa(
                isi_set,
                #[inline(always)]
                || {
                    let mut any = 0u64;
                    for ((wt, &x), c) in waiting.iter_mut().zip(&words_of_plane).zip(&mut carry) {
                        *wt &= !x;
                        *c = *wt;
                        any |= *wt;
                    }
                    // Carry-save add of the waiting mask into the sliced counters, a level
                    // at a time over all words.
                    for level in sliced.chunks_exact_mut(words) {
                        for (l, c) in level.iter_mut().zip(carry.iter_mut()) {
                            let t = *l & *c;
                            *l ^= *c;
                            *c = t;
                        }
                    }
                    any
                },
            );
            if any == 0 {
                break;
            }
        }
        for ((f, &wt), &all) in found.iter_mut().zip(&waiting).zip(&waiting_tail) {
            *f = all & !wt;
        }
    }
    // Read out: 32 pixels at a time, each lane shifting its own bit out of every level.
    let mut count = vec![0u32; words * 64];
    neuspike_simd::with_isa(
        isi_set,
        #[inline(always)]
        || {
            for (i, count) in count.chunks_exact_mut(64).enumerate() {
                for (half, count) in count.chunks_exact_mut(32).enumerate() {
                    for (b, level) in sliced.chunks_exact(words).enumerate() {
                        let l = (level[i] >> (32 * half)) as u32;
                        for (p, o) in count.iter_mut().enumerate() {
                            *o |= ((l >> p) & 1) << b;
                        }
                    }
                }
            }
        },
    );
    // ISI = 1 + the count; valid where both sides found a spike.
    let bit = |f: &[u64], p: usize| (f[p / 64] >> (p % 64)) & 1 == 1;
    match (isi.as_slice_mut(), valid.as_slice_mut()) {
        (Some(d), Some(v)) => neuspike_simd::with_isa(
            isi_set,
            #[inline(always)]
            || {
                let chunks = d.chunks_mut(64).zip(v.chunks_mut(64)).zip(count.chunks(64));
                for (i, ((d, v), k)) in chunks.enumerate() {
                    let both = found[0][i] & found[1][i];
                    for (p, ((d, v), &k)) in d.iter_mut().zip(v).zip(k).enumerate() {
                        *d = (k + 1) as f32;
                        *v = (both >> p) & 1 == 1;
                    }
                }
            },
        ),
        _ => {
            for (((y, x), d), v) in isi.indexed_iter_mut().zip(valid.iter_mut()) {
                let p = y * w + x;
                *d = (count[p] + 1) as f32;
                *v = bit(&found[0], p) && bit(&found[1], p);
            }
        }
    }
    Ok(())
}

/// Checks shared by the ISI kernels: planes, reference plane, destination shape.
fn check_isi_args(
    spikes: &ArrayView3<u8>,
    c: usize,
    dst_dim: (usize, usize),
) -> Result<usize, RepresentError> {
    let n = check_planes(spikes)?;
    check_reference_plane(c, n)?;
    check_image("isi/tfi dst", spikes, dst_dim)?;
    Ok(n)
}

/// Scalar oracle for [`isi_into`]: per pixel, walk backwards from `c` and forwards from `c + 1`
/// until a spike. Same checks, same values.
#[doc(hidden)]
pub fn isi_reference(
    spikes: ArrayView3<u8>,
    c: usize,
    mut isi: ArrayViewMut2<f32>,
    mut valid: ArrayViewMut2<bool>,
) -> Result<(), RepresentError> {
    let n = check_isi_args(&spikes, c, isi.dim())?;
    check_image("isi valid", &spikes, valid.dim())?;
    let (_, h, w) = spikes.dim();
    for y in 0..h {
        for x in 0..w {
            let (ticks, ok) = isi_one_pixel(&spikes, c, y, x, n);
            isi[[y, x]] = ticks as f32;
            valid[[y, x]] = ok;
        }
    }
    Ok(())
}

/// The reference search for one pixel, written in signed positions as docs/definitions.md states it.
fn isi_one_pixel(spikes: &ArrayView3<u8>, c: usize, y: usize, x: usize, n: usize) -> (u32, bool) {
    let prev = (0..=c).rev().find(|&k| spikes[[k, y, x]] != 0);
    let next = (c + 1..n).find(|&k| spikes[[k, y, x]] != 0);
    let prev_pos = prev.map_or(-1, |k| k as i64);
    let next_pos = next.map_or(n as i64, |k| k as i64);
    (
        (next_pos - prev_pos) as u32,
        prev.is_some() && next.is_some(),
    )
}

/// Fast ISI + mask over row blocks. Shapes are checked by the caller.
fn isi_rows(
    spikes: ArrayView3<u8>,
    c: usize,
    mut isi: ArrayViewMut2<f32>,
    mut valid: ArrayViewMut2<bool>,
    rows_per_task: usize,
    parallel: bool,
) {
    let n = spikes.len_of(Axis(0)) as u32;
    let w = isi.ncols();
    let rows_per_task = rows_per_task.max(1);
    type Blocks<'a> = (ArrayViewMut2<'a, f32>, ArrayViewMut2<'a, bool>);
    let task = |(block, (mut isi_block, mut valid_block)): (usize, Blocks<'_>)| {
        let mut scan = IsiRowScan::new(w);
        let y0 = block * rows_per_task;
        let rows = isi_block.outer_iter_mut().zip(valid_block.outer_iter_mut());
        for (dy, (mut isi_row, mut valid_row)) in rows.enumerate() {
            scan.run(&spikes, c, y0 + dy);
            let found = scan.prev_plus1.iter().zip(&scan.next);
            for ((d, v), (&p, &q)) in isi_row.iter_mut().zip(valid_row.iter_mut()).zip(found) {
                *d = isi_ticks(p, q) as f32;
                *v = isi_valid(p, q, n);
            }
        }
    };
    let isi_blocks = isi.axis_chunks_iter_mut(Axis(0), rows_per_task);
    let valid_blocks = valid.axis_chunks_iter_mut(Axis(0), rows_per_task);
    if parallel {
        isi_blocks
            .into_par_iter()
            .zip(valid_blocks)
            .enumerate()
            .for_each(task);
    } else {
        isi_blocks.zip(valid_blocks).enumerate().for_each(task);
    }
}

/// TFI (texture from interval): `1 / ISI` at reference plane `c`, per tick, in `(0, 1]`.
///
/// Uses exactly the ISI of [`isi_into`], including its value where the ISI is unknown: such a
/// pixel gets `1 / (lower bound)`, e.g. `1 / (N + 1)` for a pixel with no spike in the window.
/// This kernel writes no mask; call [`isi_into`] when the caller needs to know which pixels were
/// measured. A pixel that fires every tick gets 1.
///
/// # Errors
/// As [`isi_into`]: `N == 0` or too many planes (`Param`), `c >= N` (`Index`), `dst` not
/// `[H, W]` (`Shape`).
pub fn tfi_into(
    spikes: ArrayView3<u8>,
    c: usize,
    dst: ArrayViewMut2<f32>,
) -> Result<(), RepresentError> {
    check_isi_args(&spikes, c, dst.dim())?;
    tfi_rows(spikes, c, dst, ROWS_PER_TASK, use_rayon(spikes.len()));
    Ok(())
}

/// Scalar oracle for [`tfi_into`].
#[doc(hidden)]
pub fn tfi_reference(
    spikes: ArrayView3<u8>,
    c: usize,
    mut dst: ArrayViewMut2<f32>,
) -> Result<(), RepresentError> {
    let n = check_isi_args(&spikes, c, dst.dim())?;
    let (_, h, w) = spikes.dim();
    for y in 0..h {
        for x in 0..w {
            dst[[y, x]] = tfi_value(isi_one_pixel(&spikes, c, y, x, n).0);
        }
    }
    Ok(())
}

/// Fast TFI over row blocks. Shapes are checked by the caller.
fn tfi_rows(
    spikes: ArrayView3<u8>,
    c: usize,
    mut dst: ArrayViewMut2<f32>,
    rows_per_task: usize,
    parallel: bool,
) {
    let w = dst.ncols();
    let rows_per_task = rows_per_task.max(1);
    let task = |(block, mut dst_block): (usize, ArrayViewMut2<f32>)| {
        let mut scan = IsiRowScan::new(w);
        let y0 = block * rows_per_task;
        for (dy, mut dst_row) in dst_block.outer_iter_mut().enumerate() {
            scan.run(&spikes, c, y0 + dy);
            let found = scan.prev_plus1.iter().zip(&scan.next);
            for (d, (&p, &q)) in dst_row.iter_mut().zip(found) {
                *d = tfi_value(isi_ticks(p, q));
            }
        }
    };
    let blocks = dst.axis_chunks_iter_mut(Axis(0), rows_per_task);
    if parallel {
        blocks.into_par_iter().enumerate().for_each(task);
    } else {
        blocks.enumerate().for_each(task);
    }
}

// ---------------------------------------------------------------------------------------------
// NeuSpike-Net spike representation
// ---------------------------------------------------------------------------------------------

/// First plane of the raw block of `raw` planes around `c` in `N` planes: `c - raw / 2`, clamped so
/// that the block stays inside `[0, N)`. Needs `raw <= N`.
///
/// Exposed so that a caller can tell which planes (and so which instants) the raw channels hold.
pub fn raw_block_start(c: usize, raw: usize, n: usize) -> usize {
    c.saturating_sub(raw / 2).min(n.saturating_sub(raw))
}

/// The NeuSpike-Net spike representation at reference plane `c`: `n` channels `[n, H, W]`.
///
/// - Channel 0: `1 / ISI` at `c`, exactly what [`tfi_into`] writes (in `(0, 1]`; unknown ISIs
///   take its documented lower bound, so a dark pixel gets `1 / (N + 1)`).
/// - Channels `1..n`: the `n - 1` raw planes `start, start + 1, .., start + n - 2` as 0.0/1.0
///   (nonzero bytes become 1.0), where `start = raw_block_start(c, n - 1, N)` =
///   `c - (n - 1) / 2`, clamped so the block stays inside `[0, N)`. Away from the edges the
///   reference plane is channel `1 + (n - 1) / 2`: for the paper's `n = 32`, channels 1..=31 are
///   planes `c - 15 ..= c + 15` and `c` is channel 16. Near an edge the block shifts inwards
///   instead of padding, so every raw channel is a real plane.
///
/// `n == 1` gives the ISI channel alone.
///
/// # Errors
/// - [`RepresentError::Param`] when `N == 0` or too many planes.
/// - [`RepresentError::Index`] when `c >= N`.
/// - [`RepresentError::Shape`] when `dst` is not `[n, H, W]` with `n >= 1`, or when `N < n - 1`
///   (fewer planes than raw channels).
pub fn spike_representation_into(
    spikes: ArrayView3<u8>,
    c: usize,
    dst: ArrayViewMut3<f32>,
) -> Result<(), RepresentError> {
    let start = check_representation(&spikes, c, dst.dim())?;
    let parallel = use_rayon(spikes.len());
    spike_representation_fast(spikes, c, start, dst, ROWS_PER_TASK, parallel);
    Ok(())
}

/// [`spike_representation_into`] straight from `n` bit-packed planes (the spike chunk's packing:
/// plane `k` is `bits[k * per..(k + 1) * per]` with `per = ceil(H * W / 8)`, pixel `i` at bit
/// `i % 8` of byte `i / 8`), as the node gets them: the ISI channel from [`isi_packed_into`]
/// (`1 / ISI`, the same bits as [`tfi_into`]), the raw channels unpacked straight to 0.0/1.0.
/// Single-threaded. Equal to the reference bit for bit (tested).
///
/// # Errors
/// As [`spike_representation_into`], plus [`RepresentError::Shape`] when `bits` holds fewer
/// than `n` planes.
pub fn spike_representation_packed_into(
    bits: &[u8],
    n: usize,
    c: usize,
    mut dst: ArrayViewMut3<f32>,
) -> Result<(), RepresentError> {
    let (channels, h, w) = dst.dim();
    let raw = check_channels(channels, n, (h, w))?;
    let mut valid = ndarray::Array2::<bool>::from_elem((h, w), false);
    isi_packed_into(bits, n, c, dst.index_axis_mut(Axis(0), 0), valid.view_mut())?;
    dst.index_axis_mut(Axis(0), 0)
        .mapv_inplace(|isi| tfi_value(isi as u32));
    let per = (h * w).div_ceil(8);
    let start = raw_block_start(c, raw, n);
    for ch in 1..channels {
        let k = start + ch - 1;
        let plane = &bits[k * per..(k + 1) * per];
        let mut out = dst.index_axis_mut(Axis(0), ch);
        match out.as_slice_mut() {
            Some(out) => unpack_plane(plane, out),
            None => {
                for (i, d) in out.iter_mut().enumerate() {
                    *d = f32::from((plane[i / 8] >> (i % 8)) & 1);
                }
            }
        }
    }
    Ok(())
}

/// [`spike_representation_packed_into`] of `channels` channels as its two parts, for a reader
/// that takes the raw planes bit-packed (a network whose first convolution runs in 8 bits reads
/// them so): channel 0 written into `isi` (`[H, W]`, the same bits), and the range of `bits`
/// that holds the `channels - 1` raw planes in channel order (`ceil(H W / 8)` bytes a plane).
///
/// # Errors
/// As [`spike_representation_packed_into`].
pub fn spike_representation_parts(
    bits: &[u8],
    n: usize,
    c: usize,
    channels: usize,
    mut isi: ArrayViewMut2<f32>,
) -> Result<std::ops::Range<usize>, RepresentError> {
    let (h, w) = isi.dim();
    let raw = check_channels(channels, n, (h, w))?;
    let mut valid = ndarray::Array2::<bool>::from_elem((h, w), false);
    isi_packed_into(bits, n, c, isi.view_mut(), valid.view_mut())?;
    isi.mapv_inplace(|isi| tfi_value(isi as u32));
    let per = (h * w).div_ceil(8);
    let start = raw_block_start(c, raw, n);
    Ok(start * per..(start + raw) * per)
}

/// One packed plane to 0.0/1.0 per pixel (`out.len()` pixels), eight at a time.
fn unpack_plane(plane: &[u8], out: &mut [f32]) {
    neuspike_simd::dispatch(
        #[inline(always)]
        || {
            let (whole, tail) = out.as_chunks_mut::<8>();
            for (o, &byte) in whole.iter_mut().zip(plane) {
                for (b, d) in o.iter_mut().enumerate() {
                    *d = f32::from((byte >> b) & 1);
                }
            }
            if let Some(&byte) = plane.get(whole.len()) {
                for (b, d) in tail.iter_mut().enumerate() {
                    *d = f32::from((byte >> b) & 1);
                }
            }
        },
    );
}

/// Checks for the spike representation; returns the first raw plane.
fn check_representation(
    spikes: &ArrayView3<u8>,
    c: usize,
    dst_dim: (usize, usize, usize),
) -> Result<usize, RepresentError> {
    let (channels, dh, dw) = dst_dim;
    if channels == 0 {
        check_channels(channels, 0, (dh, dw))?;
    }
    let n = check_isi_args(spikes, c, (dh, dw))?;
    let raw = check_channels(channels, n, (dh, dw))?;
    Ok(raw_block_start(c, raw, n))
}

/// The spike representation's channel count against `n` planes of `(h, w)`: at least the ISI
/// channel, and no more raw channels than planes. Returns the raw channels.
fn check_channels(
    channels: usize,
    n: usize,
    (h, w): (usize, usize),
) -> Result<usize, RepresentError> {
    if channels == 0 {
        return Err(RepresentError::Shape {
            what: "spike representation dst channels",
            expected: "[n >= 1, H, W] (channel 0 is the ISI channel)".to_owned(),
            actual: shape_str(&[channels, h, w]),
        });
    }
    let raw = channels - 1;
    if raw > n {
        return Err(RepresentError::Shape {
            what: "spike representation planes (N must be >= n - 1 raw channels)",
            expected: format!("[N >= {raw}, H, W]"),
            actual: shape_str(&[n, h, w]),
        });
    }
    Ok(raw)
}

/// Scalar oracle for [`spike_representation_into`].
#[doc(hidden)]
pub fn spike_representation_reference(
    spikes: ArrayView3<u8>,
    c: usize,
    mut dst: ArrayViewMut3<f32>,
) -> Result<(), RepresentError> {
    let start = check_representation(&spikes, c, dst.dim())?;
    tfi_reference(spikes, c, dst.index_axis_mut(Axis(0), 0))?;
    let (channels, h, w) = dst.dim();
    for ch in 1..channels {
        let k = start + ch - 1;
        for y in 0..h {
            for x in 0..w {
                dst[[ch, y, x]] = if spikes[[k, y, x]] != 0 { 1.0 } else { 0.0 };
            }
        }
    }
    Ok(())
}

/// Fast spike representation. Shapes are checked by the caller.
fn spike_representation_fast(
    spikes: ArrayView3<u8>,
    c: usize,
    start: usize,
    mut dst: ArrayViewMut3<f32>,
    rows_per_task: usize,
    parallel: bool,
) {
    let raw = dst.len_of(Axis(0)) - 1;
    tfi_rows(
        spikes,
        c,
        dst.index_axis_mut(Axis(0), 0),
        rows_per_task,
        parallel,
    );
    let planes = spikes.slice(s![start..start + raw, .., ..]);
    let zip = Zip::from(dst.slice_mut(s![1.., .., ..])).and(planes);
    let copy = |d: &mut f32, &b: &u8| *d = f32::from(u8::from(b != 0));
    if parallel {
        zip.par_for_each(copy);
    } else {
        zip.for_each(copy);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::{Array2, Array3, ShapeBuilder};
    use proptest::prelude::*;

    /// Planes `[n, 1, w]` where pixel `x` fires at the planes listed for it.
    fn planes(n: usize, fires: &[&[usize]]) -> Array3<u8> {
        let mut s = Array3::<u8>::zeros((n, 1, fires.len()));
        for (x, ks) in fires.iter().enumerate() {
            for &k in *ks {
                s[[k, 0, x]] = 1;
            }
        }
        s
    }

    fn isi_of(s: &Array3<u8>, c: usize) -> (Array2<f32>, Array2<bool>) {
        let (_, h, w) = s.dim();
        let mut isi = Array2::<f32>::zeros((h, w));
        let mut valid = Array2::from_elem((h, w), true);
        isi_into(s.view(), c, isi.view_mut(), valid.view_mut()).expect("isi");
        (isi, valid)
    }

    const EVERY_4: &[usize] = &[0, 4, 8, 12];
    const EVERY_TICK: &[usize] = &[0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15];

    #[test]
    fn constant_rate_pixel_gives_rate_quarter_isi_four_tfi_quarter() {
        let s = planes(16, &[EVERY_4]);
        let mut rate = Array2::<f32>::zeros((1, 1));
        tfp_into(s.view(), rate.view_mut()).expect("tfp");
        assert_eq!(rate[[0, 0]], 0.25);
        for c in 0..12 {
            let (isi, valid) = isi_of(&s, c);
            assert_eq!(isi[[0, 0]], 4.0, "c = {c}");
            assert!(valid[[0, 0]], "c = {c}");
            let mut tfi = Array2::<f32>::zeros((1, 1));
            tfi_into(s.view(), c, tfi.view_mut()).expect("tfi");
            assert_eq!(tfi[[0, 0]], 0.25);
        }
    }

    proptest! {
        #[test]
        fn spike_representation_packed_equals_the_reference(
            (n, h, w, seed) in (1usize..40, 1usize..6, 1usize..20, any::<u64>()),
            c_frac in 0.0f64..1.0,
            channels in 1usize..34,
        ) {
            let channels = channels.min(n + 1);
            let c = ((n as f64 * c_frac) as usize).min(n - 1);
            let (planes, bits) = random_planes(seed, (n, h, w), false);
            let mut want = Array3::<f32>::zeros((channels, h, w));
            spike_representation_reference(planes.view(), c, want.view_mut()).expect("reference");
            let mut got = Array3::<f32>::from_elem((channels, h, w), f32::NAN);
            spike_representation_packed_into(&bits, n, c, got.view_mut()).expect("packed");
            prop_assert_eq!(&got, &want);
            // A strided destination takes the element-wise path to the same values.
            let mut wide = Array3::<f32>::from_elem((channels, h, 2 * w), f32::NAN);
            let mut strided = wide.slice_mut(s![.., .., ..;2]);
            spike_representation_packed_into(&bits, n, c, strided.view_mut()).expect("strided");
            prop_assert_eq!(&strided, &want);
            // Its parts: the ISI channel, and the raw planes where they lie in `bits`.
            let mut isi = Array2::<f32>::from_elem((h, w), f32::NAN);
            let raw = spike_representation_parts(&bits, n, c, channels, isi.view_mut())
                .expect("parts");
            prop_assert_eq!(&isi, &want.index_axis(Axis(0), 0));
            let per = (h * w).div_ceil(8);
            prop_assert_eq!(raw.len(), (channels - 1) * per);
            for (k, plane) in bits[raw].chunks_exact(per).enumerate() {
                for i in 0..h * w {
                    let bit = f32::from((plane[i / 8] >> (i % 8)) & 1);
                    prop_assert_eq!(bit, want[[k + 1, i / w, i % w]]);
                }
            }
        }
    }

    #[test]
    fn silent_pixel_is_invalid_with_finite_isi_of_n_plus_one() {
        let s = planes(16, &[&[]]);
        for c in [0, 7, 15] {
            let (isi, valid) = isi_of(&s, c);
            assert!(!valid[[0, 0]]);
            assert_eq!(isi[[0, 0]], 17.0);
            let mut tfi = Array2::<f32>::zeros((1, 1));
            tfi_into(s.view(), c, tfi.view_mut()).expect("tfi");
            assert_eq!(tfi[[0, 0]], 1.0 / 17.0);
        }
        let mut rate = Array2::<f32>::from_elem((1, 1), 9.0);
        tfp_into(s.view(), rate.view_mut()).expect("tfp");
        assert_eq!(rate[[0, 0]], 0.0);
    }

    #[test]
    fn saturating_pixel_has_isi_one_everywhere_including_edges() {
        let s = planes(16, &[EVERY_TICK]);
        for c in 0..15 {
            let (isi, valid) = isi_of(&s, c);
            assert_eq!((isi[[0, 0]], valid[[0, 0]]), (1.0, true), "c = {c}");
        }
        // At c = N - 1 there is no next spike: invalid, bound N - prev = 1.
        let (isi, valid) = isi_of(&s, 15);
        assert_eq!((isi[[0, 0]], valid[[0, 0]]), (1.0, false));
        let mut rate = Array2::<f32>::zeros((1, 1));
        tfp_into(s.view(), rate.view_mut()).expect("tfp");
        assert_eq!(rate[[0, 0]], 1.0);
    }

    #[test]
    fn reference_plane_at_both_edges() {
        // Pixel 0 fires at 0, 4, 8, 12; pixel 1 at 2, 6, 10, 14.
        let s = planes(16, &[EVERY_4, &[2, 6, 10, 14]]);
        let (isi, valid) = isi_of(&s, 0);
        assert_eq!((isi[[0, 0]], valid[[0, 0]]), (4.0, true)); // prev 0, next 4
        assert_eq!((isi[[0, 1]], valid[[0, 1]]), (3.0, false)); // prev missing: next 2 + 1
        let (isi, valid) = isi_of(&s, 15);
        assert_eq!((isi[[0, 0]], valid[[0, 0]]), (4.0, false)); // next missing: 16 - 12
        assert_eq!((isi[[0, 1]], valid[[0, 1]]), (2.0, false)); // 16 - 14
        let (isi, valid) = isi_of(&s, 14);
        assert_eq!((isi[[0, 1]], valid[[0, 1]]), (2.0, false)); // prev 14, next missing
        assert_eq!((isi[[0, 0]], valid[[0, 0]]), (4.0, false)); // prev 12, next missing
        let (isi, valid) = isi_of(&s, 13);
        assert_eq!((isi[[0, 1]], valid[[0, 1]]), (4.0, true)); // 10 -> 14
    }

    #[test]
    fn one_plane_one_pixel() {
        let s = planes(1, &[&[0]]);
        let (isi, valid) = isi_of(&s, 0);
        assert_eq!((isi[[0, 0]], valid[[0, 0]]), (1.0, false));
        let s = planes(1, &[&[]]);
        let (isi, valid) = isi_of(&s, 0);
        assert_eq!((isi[[0, 0]], valid[[0, 0]]), (2.0, false));
    }

    #[test]
    fn one_by_w_image_keeps_pixels_apart() {
        let s = planes(8, &[&[], &[3], &[1, 5], EVERY_TICK.split_at(8).0]);
        let (isi, valid) = isi_of(&s, 3);
        assert_eq!(isi.row(0).to_vec(), vec![9.0, 5.0, 4.0, 1.0]);
        assert_eq!(valid.row(0).to_vec(), vec![false, false, true, true]);
        let mut rate = Array2::<f32>::zeros((1, 4));
        tfp_into(s.view(), rate.view_mut()).expect("tfp");
        assert_eq!(rate.row(0).to_vec(), vec![0.0, 0.125, 0.25, 1.0]);
    }

    #[test]
    fn nonzero_bytes_count_once() {
        let mut s = Array3::<u8>::zeros((4, 1, 1));
        s[[0, 0, 0]] = 255;
        s[[2, 0, 0]] = 2;
        let mut rate = Array2::<f32>::zeros((1, 1));
        tfp_into(s.view(), rate.view_mut()).expect("tfp");
        assert_eq!(rate[[0, 0]], 0.5);
        let mut rep = Array3::<f32>::zeros((3, 1, 1));
        spike_representation_into(s.view(), 1, rep.view_mut()).expect("rep");
        assert_eq!(rep.iter().copied().collect::<Vec<_>>(), vec![0.5, 1.0, 0.0]);
    }

    #[test]
    fn errors_name_the_problem() {
        let s = Array3::<u8>::zeros((0, 2, 2));
        let mut d = Array2::<f32>::zeros((2, 2));
        let e = tfp_into(s.view(), d.view_mut()).expect_err("N = 0");
        assert!(e.to_string().contains("N = 0"), "{e}");

        let s = Array3::<u8>::zeros((4, 2, 2));
        let mut small = Array2::<f32>::zeros((2, 3));
        let e = tfp_into(s.view(), small.view_mut()).expect_err("shape");
        assert!(e.to_string().contains("[2, 3]"), "{e}");

        let e = tfi_into(s.view(), 4, d.view_mut()).expect_err("c");
        assert!(
            matches!(
                e,
                RepresentError::Index {
                    value: 4,
                    limit: 4,
                    ..
                }
            ),
            "{e}"
        );

        let mut mask = Array2::from_elem((3, 2), false);
        let e = isi_into(s.view(), 0, d.view_mut(), mask.view_mut()).expect_err("mask shape");
        assert!(matches!(e, RepresentError::Shape { .. }), "{e}");

        let mut rep = Array3::<f32>::zeros((6, 2, 2));
        let e = spike_representation_into(s.view(), 0, rep.view_mut()).expect_err("N < n-1");
        assert!(e.to_string().contains("N >= 5"), "{e}");
        let mut rep = Array3::<f32>::zeros((0, 2, 2));
        assert!(spike_representation_into(s.view(), 0, rep.view_mut()).is_err());
    }

    #[test]
    fn spike_representation_layout_centred_and_clamped() {
        // Plane k holds the value (k mod 2) at pixel 0 and 1 at pixel 1 only on plane k == 5.
        let n = 12;
        let mut s = Array3::<u8>::zeros((n, 1, 2));
        for k in 0..n {
            s[[k, 0, 0]] = (k % 2) as u8;
        }
        s[[5, 0, 1]] = 1;
        // 5 channels: ISI + 4 raw planes starting at c - 2.
        let mut rep = Array3::<f32>::zeros((5, 1, 2));
        spike_representation_into(s.view(), 6, rep.view_mut()).expect("rep");
        assert_eq!(rep[[0, 0, 0]], 0.5); // ISI 2
        assert_eq!(rep[[0, 0, 1]], 1.0 / 7.0); // prev 5, next missing: 12 - 5
        let raw: Vec<f32> = (1..5).map(|ch| rep[[ch, 0, 0]]).collect();
        assert_eq!(raw, vec![0.0, 1.0, 0.0, 1.0]); // planes 4, 5, 6, 7
        let raw: Vec<f32> = (1..5).map(|ch| rep[[ch, 0, 1]]).collect();
        assert_eq!(raw, vec![0.0, 1.0, 0.0, 0.0]);
        // Clamped at the start and at the end.
        assert_eq!(raw_block_start(1, 4, n), 0);
        assert_eq!(raw_block_start(11, 4, n), 8);
        assert_eq!(raw_block_start(16, 31, 32), 1);
        assert_eq!(raw_block_start(15, 31, 32), 0);
        assert_eq!(raw_block_start(31, 31, 31), 0);
        spike_representation_into(s.view(), 11, rep.view_mut()).expect("rep end");
        let raw: Vec<f32> = (1..5).map(|ch| rep[[ch, 0, 0]]).collect();
        assert_eq!(raw, vec![0.0, 1.0, 0.0, 1.0]); // planes 8..12
        // Paper size: 32 channels from exactly 31 planes.
        let s = Array3::<u8>::ones((31, 2, 3));
        let mut rep = Array3::<f32>::zeros((32, 2, 3));
        spike_representation_into(s.view(), 30, rep.view_mut()).expect("rep 32");
        assert!(rep.iter().all(|&v| v == 1.0));
        // One channel: ISI only.
        let mut rep = Array3::<f32>::zeros((1, 2, 3));
        spike_representation_into(s.view(), 3, rep.view_mut()).expect("rep 1");
        assert!(rep.iter().all(|&v| v == 1.0));
    }

    #[test]
    fn large_input_takes_the_rayon_path_and_matches() {
        let (n, h, w) = (32, 40, 70); // 89_600 elements >= MIN_ELEMENTS_FOR_RAYON
        assert!(use_rayon(n * h * w));
        let s = Array3::from_shape_fn((n, h, w), |(k, y, x)| {
            u8::from((k * 7 + y * 3 + x) % 5 == 0)
        });
        let mut fast = Array2::<f32>::zeros((h, w));
        let mut slow = Array2::<f32>::zeros((h, w));
        tfp_into(s.view(), fast.view_mut()).expect("tfp");
        tfp_reference(s.view(), slow.view_mut()).expect("tfp ref");
        assert_eq!(fast, slow);
        tfi_into(s.view(), 13, fast.view_mut()).expect("tfi");
        tfi_reference(s.view(), 13, slow.view_mut()).expect("tfi ref");
        assert_eq!(fast, slow);
    }

    /// Random planes with an uneven density per pixel, and a reference plane inside them.
    fn spikes_and_c() -> impl Strategy<Value = (Array3<u8>, usize)> {
        (1usize..12, 1usize..7, 1usize..9).prop_flat_map(|(n, h, w)| {
            (
                proptest::collection::vec(0u8..4, n * h * w),
                0..n,
                Just((n, h, w)),
            )
                .prop_map(|(bytes, c, (n, h, w))| {
                    // 0..4 -> spike with probability 1/2, some bytes > 1.
                    let data: Vec<u8> = bytes
                        .iter()
                        .map(|&b| if b >= 2 { b - 1 } else { 0 })
                        .collect();
                    let a = Array3::from_shape_vec((n, h, w), data).expect("shape");
                    (a, c)
                })
        })
    }

    proptest! {
        #[test]
        fn tfp_fast_equals_reference_and_stays_in_unit_range(
            (s, _c) in spikes_and_c(), rows in 1usize..4, par in any::<bool>()
        ) {
            let (_, h, w) = s.dim();
            let mut slow = Array2::<f32>::zeros((h, w));
            tfp_reference(s.view(), slow.view_mut()).expect("ref");
            let mut fast = Array2::<f32>::from_elem((h, w), f32::NAN);
            tfp_rows(s.view(), fast.view_mut(), rows, par);
            prop_assert_eq!(&fast, &slow);
            prop_assert!(fast.iter().all(|&v| (0.0..=1.0).contains(&v)));
            let mut public = Array2::<f32>::zeros((h, w));
            tfp_into(s.view(), public.view_mut()).expect("tfp");
            prop_assert_eq!(&public, &slow);
        }

        #[test]
        fn isi_fast_equals_reference_and_is_at_least_one(
            (s, c) in spikes_and_c(), rows in 1usize..4, par in any::<bool>()
        ) {
            let (n, h, w) = s.dim();
            let mut isi_slow = Array2::<f32>::zeros((h, w));
            let mut valid_slow = Array2::from_elem((h, w), false);
            isi_reference(s.view(), c, isi_slow.view_mut(), valid_slow.view_mut()).expect("ref");
            let mut isi_fast = Array2::<f32>::from_elem((h, w), f32::NAN);
            let mut valid_fast = Array2::from_elem((h, w), true);
            isi_rows(s.view(), c, isi_fast.view_mut(), valid_fast.view_mut(), rows, par);
            prop_assert_eq!(&isi_fast, &isi_slow);
            prop_assert_eq!(&valid_fast, &valid_slow);
            for (&i, &v) in isi_fast.iter().zip(&valid_fast) {
                prop_assert!(i >= 1.0 && i <= (n + 1) as f32);
                if !v { prop_assert!(i.is_finite()); }
            }
            let mut tfi_slow = Array2::<f32>::zeros((h, w));
            tfi_reference(s.view(), c, tfi_slow.view_mut()).expect("tfi ref");
            let mut tfi_fast = Array2::<f32>::from_elem((h, w), f32::NAN);
            tfi_rows(s.view(), c, tfi_fast.view_mut(), rows, par);
            prop_assert_eq!(&tfi_fast, &tfi_slow);
            prop_assert!(tfi_fast.iter().all(|&v| v > 0.0 && v <= 1.0));
        }

        #[test]
        fn representation_fast_equals_reference(
            (s, c) in spikes_and_c(), channels in 1usize..6, rows in 1usize..4, par in any::<bool>()
        ) {
            let (n, h, w) = s.dim();
            prop_assume!(channels - 1 <= n);
            let mut slow = Array3::<f32>::zeros((channels, h, w));
            spike_representation_reference(s.view(), c, slow.view_mut()).expect("ref");
            let start = raw_block_start(c, channels - 1, n);
            prop_assert!(start + channels - 1 <= n);
            let mut fast = Array3::<f32>::from_elem((channels, h, w), f32::NAN);
            spike_representation_fast(s.view(), c, start, fast.view_mut(), rows, par);
            prop_assert_eq!(&fast, &slow);
        }

        #[test]
        fn non_contiguous_views_match_reference((s, c) in spikes_and_c()) {
            // Fortran-order planes and a transposed destination exercise the strided paths.
            let (n, h, w) = s.dim();
            let mut f = Array3::<u8>::zeros((n, h, w).f());
            f.assign(&s);
            let mut slow = Array2::<f32>::zeros((h, w));
            tfi_reference(s.view(), c, slow.view_mut()).expect("ref");
            let mut fast_t = Array2::<f32>::zeros((w, h));
            tfi_into(f.view(), c, fast_t.view_mut().reversed_axes()).expect("tfi");
            prop_assert_eq!(&fast_t.t(), &slow.view());
            tfp_reference(s.view(), slow.view_mut()).expect("ref");
            tfp_into(f.view(), fast_t.view_mut().reversed_axes()).expect("tfp");
            prop_assert_eq!(&fast_t.t(), &slow.view());
        }
    }

    /// Random planes (xorshift from `seed`) with a per-case firing threshold from sparse to
    /// dense (`thin` more bits of shift make it sparser), and their packed form.
    fn random_planes(seed: u64, shape: (usize, usize, usize), thin: bool) -> (Array3<u8>, Vec<u8>) {
        let mut state = seed | 1;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let threshold = if thin { next() >> (next() % 8) } else { next() };
        let planes = Array3::from_shape_fn(shape, |_| u8::from(next() < threshold));
        let bits = neuspike_schemas::pack_planes(planes.view());
        (planes, bits)
    }

    proptest::proptest! {
        #[test]
        fn tfp_packed_equals_unpacked(
            h in 1usize..9,
            w in 1usize..13,
            total in 1usize..300,
            seed in proptest::prelude::any::<u64>(),
            cut in 0usize..1000,
        ) {
            let (planes, bits) = random_planes(seed, (total, h, w), false);
            let start = cut % total;
            let end = start + 1 + (cut * 7) % (total - start);
            let mut want = Array2::<f32>::zeros((h, w));
            tfp_reference(planes.slice(ndarray::s![start..end, .., ..]), want.view_mut()).unwrap();
            for isa in neuspike_simd::Isa::ALL {
                let mut got = Array2::<f32>::from_elem((h, w), f32::NAN);
                tfp_packed_into_with(isa, &bits, start..end, got.view_mut()).unwrap();
                proptest::prop_assert_eq!(&got, &want, "{:?}", isa);
            }
        }
    }

    proptest::proptest! {
        #[test]
        fn isi_packed_equals_unpacked(
            h in 1usize..9,
            w in 1usize..13,
            n in 1usize..140,
            seed in proptest::prelude::any::<u64>(),
            c_at in 0usize..1000,
        ) {
            let (planes, bits) = random_planes(seed, (n, h, w), true);
            let c = c_at % n;
            let mut want = Array2::<f32>::zeros((h, w));
            let mut want_ok = Array2::<bool>::from_elem((h, w), false);
            isi_reference(planes.view(), c, want.view_mut(), want_ok.view_mut()).unwrap();
            for isa in neuspike_simd::Isa::ALL {
                let mut got = Array2::<f32>::from_elem((h, w), f32::NAN);
                let mut ok = Array2::<bool>::from_elem((h, w), true);
                isi_packed_into_with(isa, &bits, n, c, got.view_mut(), ok.view_mut()).unwrap();
                proptest::prop_assert_eq!(&got, &want, "{:?}", isa);
                proptest::prop_assert_eq!(&ok, &want_ok, "{:?}", isa);
            }
        }
    }

    #[test]
    fn tfp_packed_names_short_input_and_empty_range() {
        let mut dst = Array2::<f32>::zeros((2, 4));
        let e = tfp_packed_into(&[0u8; 3], 0..4, dst.view_mut())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("3 bytes") && e.contains("packed spike planes"),
            "{e}"
        );
        let e = tfp_packed_into(&[0u8; 3], 1..1, dst.view_mut())
            .unwrap_err()
            .to_string();
        assert!(e.contains("spikes planes N") && e.contains('0'), "{e}");
    }

    #[test]
    fn rate_in_single_precision_equals_the_double_quotient() {
        for n in 1..=600usize {
            for count in 0..=n as u32 {
                assert_eq!(
                    rate(count, n).to_bits(),
                    ((f64::from(count) / n as f64) as f32).to_bits(),
                    "{count}/{n}"
                );
            }
        }
        for (count, n) in [(12_345_678u32, 16_777_215usize), (16_777_215, 16_777_216)] {
            assert_eq!(rate(count, n), (f64::from(count) / n as f64) as f32);
        }
    }
}
