//! [`Conv3x3`] in 8 bits: [`Precision::Int8`].
//!
//! Each call quantises its input afresh, per input channel, from the channel's range in this
//! frame (so a dark frame and a bright one both get 256 levels, and no calibration is shipped
//! or can go stale): `x ≈ s_c (q - z_c)` with `q` in `0..=255`, the range widened to hold 0 so
//! that 0 (the padding off the image) is exact. Each channel's scale is folded into the weights,
//! which are then quantised per output channel, symmetrically: `w s_c ≈ t_o k` with `k` in
//! `-127..=127`. An output is then `y_o = t_o (Σ k q - Σ k z) + b_o - e_o`: 32-bit integer
//! sums of 8-bit products ([`neuspike_simd::dot`]), which every path computes exactly, then one
//! multiply and one add in `f32`. `e_o` corrects the weights' rounding at the input's mean: the
//! rounding errors `t_o k - w s_c` of an output do not sum to 0, and times inputs that are
//! mostly positive (after a ReLU) they shift the whole output, which a deep network turns into
//! an error of the image's level. With `m_c` the mean of channel `c`'s levels over the input
//! (the zeros off the image apart, an edge-padded input's repeated rows and columns counted; an
//! integer sum, so every path has the same), `e_o = Σ_c
//! (m_c - z_c) Σ_taps (t_o k - w s_c)`, in `f64`, channel by channel, tap by tap. Without it
//! `neuspike-fused-8` lost 0.45 dB PSNR in 8 bits on the held-out set's normal scenes; with it,
//! 0.09 dB. The fast path and [`Conv3x3::reference_int8`] therefore
//! agree bit for bit; against the `f32` [`Conv3x3::reference`] the error is the quantisation's
//! (tested with a stated tolerance).
//!
//! Edges, stated: a channel's range is taken over its finite values; a channel that is all 0
//! (or whose range is below `255 f32::MIN_POSITIVE`) reads as 0; a NaN reads as the bottom of
//! its channel's range (0 for a channel without negative values), +inf and -inf as its ends; an
//! output channel whose scaled weights are all 0, or beyond `f32`'s range, gives its bias. The
//! 32-bit sums are exact up to [`MAX_CHANNELS`] input channels.

use neuspike_simd::dot::{self, WordTaps};

use super::*;

/// The most input channels an 8-bit convolution takes: `9 x 4096 x 255 x 127 < 2^31`, so a
/// sum cannot wrap.
pub const MAX_CHANNELS: usize = 4096;

/// Input channels (four to a quad) of one block of taps, as [`CHANNELS`] for `f32`.
const QUADS: usize = 8;

/// How one input channel is quantised: `x ≈ scale (q - zero)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChannelQuant {
    /// The step between two levels (0 for a channel read as 0).
    pub scale: f32,
    /// `1 / scale` (0 for a channel read as 0).
    pub inv: f32,
    /// The level of 0.
    pub zero: u8,
}

impl ChannelQuant {
    /// The quantisation of values in `lo..=hi` (widened to hold 0) on 256 levels.
    pub fn from_range(lo: f32, hi: f32) -> ChannelQuant {
        let (lo, hi) = (lo.min(0.0), hi.max(0.0));
        // Each end divided first: `hi - lo` itself may overflow.
        let scale = hi / 255.0 - lo / 255.0;
        if !(scale >= f32::MIN_POSITIVE && scale.is_finite()) {
            return ChannelQuant {
                scale: 0.0,
                inv: 0.0,
                zero: 0,
            };
        }
        let inv = 1.0 / scale;
        ChannelQuant {
            scale,
            inv,
            zero: ((-lo * inv).clamp(0.0, 255.0) + 0.5) as u8,
        }
    }

    /// The level of `v`: `v / scale + zero` rounded to the nearest (ties to even), within
    /// `0..=255` (NaN at 0).
    #[inline(always)]
    pub fn quantize(self, v: f32) -> u8 {
        self.level(v) as u8
    }

    /// [`quantize`](Self::quantize) as a 32-bit word, in operations every vector unit has:
    /// compares and selects (a NaN fails the first and becomes 0), then the rounding of adding
    /// `1.5 x 2^23` (whose last bits are then the integer, rounded to even). A conversion to an
    /// integer would not do: Rust's saturating one keeps the loop scalar.
    #[inline(always)]
    fn level(self, v: f32) -> u32 {
        let y = v * self.inv + f32::from(self.zero);
        let y = if y > 0.0 { y } else { 0.0 };
        let y = if y < 255.0 { y } else { 255.0 };
        (y + ROUND).to_bits() - ROUND.to_bits()
    }
}

/// The smallest and largest finite value of `values`, each from `(lo, hi)` (finite).
#[inline(always)]
fn finite_range(values: &[f32], (lo, hi): (f32, f32)) -> (f32, f32) {
    // Compares that keep the held value on NaN (the compiler's plain `vminps`/`vmaxps`), four
    // vectors of 16 lanes so that the compares do not wait on each other; an infinity found
    // sends the values through the slow filter below.
    let keep_lo = |l: &mut [f32; 16], c: &[f32]| {
        for (l, &v) in l.iter_mut().zip(c) {
            *l = if v < *l { v } else { *l };
        }
    };
    let keep_hi = |h: &mut [f32; 16], c: &[f32]| {
        for (h, &v) in h.iter_mut().zip(c) {
            *h = if v > *h { v } else { *h };
        }
    };
    let (mut l0, mut l1, mut l2, mut l3) = ([lo; 16], [lo; 16], [lo; 16], [lo; 16]);
    let (mut h0, mut h1, mut h2, mut h3) = ([hi; 16], [hi; 16], [hi; 16], [hi; 16]);
    let chunks = values.chunks_exact(64);
    let rest = chunks.remainder();
    for c in chunks {
        keep_lo(&mut l0, &c[..16]);
        keep_lo(&mut l1, &c[16..32]);
        keep_lo(&mut l2, &c[32..48]);
        keep_lo(&mut l3, &c[48..]);
        keep_hi(&mut h0, &c[..16]);
        keep_hi(&mut h1, &c[16..32]);
        keep_hi(&mut h2, &c[32..48]);
        keep_hi(&mut h3, &c[48..]);
    }
    let mut range = (lo, hi);
    for v in l0.into_iter().chain(l1).chain(l2).chain(l3) {
        range.0 = if v < range.0 { v } else { range.0 };
    }
    for v in h0.into_iter().chain(h1).chain(h2).chain(h3) {
        range.1 = if v > range.1 { v } else { range.1 };
    }
    for &v in rest {
        range.0 = if v < range.0 { v } else { range.0 };
        range.1 = if v > range.1 { v } else { range.1 };
    }
    if range.0.is_finite() && range.1.is_finite() {
        return range;
    }
    values
        .iter()
        .filter(|v| v.is_finite())
        .fold((lo, hi), |(l, h), &v| (l.min(v), h.max(v)))
}

/// The mean level less the zero of a channel whose `n` levels sum to `sum` (0 for no values).
fn mean_level(sum: u64, n: usize, q: ChannelQuant) -> f64 {
    if n == 0 {
        return 0.0;
    }
    sum as f64 / n as f64 - f64::from(q.zero)
}

/// One output channel's weights `w` times their input channels' scales `s` (into `scaled`),
/// quantised into `k` by `t_o`, the largest product's size over 127 (half away from zero, as
/// `f32::round`, without its library call); `None`, and `k` left as it is, when `t_o` is 0 or
/// not finite. The largest size is kept lane by lane, so the loop is not one chain of `max`.
#[inline(always)]
fn quantize_weights(w: &[f32], s: &[f32], scaled: &mut [f32], k: &mut [i8]) -> Option<f32> {
    const LANES: usize = 16;
    for ((d, &w), &s) in scaled.iter_mut().zip(w).zip(s) {
        *d = w * s;
    }
    let mut lanes = [0f32; LANES];
    let chunks = scaled.chunks_exact(LANES);
    let most = chunks.remainder().iter().fold(0f32, |m, d| m.max(d.abs()));
    for chunk in chunks {
        for (m, d) in lanes.iter_mut().zip(chunk) {
            *m = m.max(d.abs());
        }
    }
    let most = lanes.into_iter().fold(most, f32::max);
    let t_o = most / 127.0;
    if !(t_o >= f32::MIN_POSITIVE && t_o.is_finite()) {
        return None;
    }
    let inv = 1.0 / t_o;
    for (k, &v) in k.iter_mut().zip(scaled.iter()) {
        let r = (v * inv).clamp(-127.0, 127.0);
        *k = to_i8((r + 0.5f32.copysign(r)).trunc());
    }
    Some(t_o)
}

/// `1.5 x 2^23`: added to an `f32` of magnitude below `2^22`, it leaves the value rounded to a
/// whole number (ties to even) in the sum's last mantissa bits.
const ROUND: f32 = 12_582_912.0;

/// `t`, a whole number in [-127, 127] or NaN, as `t as i8` gives it (NaN 0), in operations
/// the compiler vectorises (it does not vectorise the saturating `as`): `t + 1.5 * 2^23` is
/// exact and holds `2^22 + t` in its mantissa, whose low byte is `t` in two's complement.
#[inline(always)]
fn to_i8(t: f32) -> i8 {
    let t = if t.is_nan() { 0.0 } else { t };
    (t + ROUND).to_bits() as u8 as i8
}

/// Pixel `i` of a packed plane (see [`packed_plane_bytes`]); a pixel past the plane is clear.
#[inline(always)]
fn bit(plane: &[u8], i: usize) -> bool {
    plane.get(i / 8).is_some_and(|b| (b >> (i % 8)) & 1 == 1)
}

/// The 8 pixels `i..i + 8` of a packed plane as the bits of a byte, pixel `i` at bit 0 (pixels
/// past the plane clear).
#[inline(always)]
fn byte_at(plane: &[u8], i: usize) -> u8 {
    let (at, shift) = (i / 8, i % 8);
    let lo = u16::from(plane.get(at).copied().unwrap_or(0));
    let hi = u16::from(plane.get(at + 1).copied().unwrap_or(0));
    ((lo | hi << 8) >> shift) as u8
}

/// Set pixels among `start..start + len` of a packed plane.
fn ones(plane: &[u8], start: usize, len: usize) -> u64 {
    let end = start + len;
    let mut i = start;
    let mut n = 0u64;
    while i < end && !i.is_multiple_of(8) {
        n += u64::from(bit(plane, i));
        i += 1;
    }
    let bytes = (end - i) / 8;
    let whole = plane.get(i / 8..i / 8 + bytes).unwrap_or(&[]);
    let (words, rest) = whole.as_chunks::<8>();
    n += words
        .iter()
        .map(|w| u64::from(u64::from_le_bytes(*w).count_ones()))
        .sum::<u64>();
    n += rest.iter().map(|b| u64::from(b.count_ones())).sum::<u64>();
    i += bytes * 8;
    while i < end {
        n += u64::from(bit(plane, i));
        i += 1;
    }
    n
}

/// A binary channel's quantisation and its mean level less its zero, from its packed plane of
/// `(rows, wv)` pixels read as if padded to `(h, w)` by repeating its last row and column:
/// what [`Conv3x3::quantization`] finds on the plane unpacked to 0.0/1.0 (its range is 0 to 1
/// when a pixel is set, else 0 to 0; its level sum counts the set pixels, the padding's
/// included).
fn bit_quantization(
    plane: &[u8],
    (rows, wv): (usize, usize),
    (h, w): (usize, usize),
) -> (ChannelQuant, f64) {
    let total = ones(plane, 0, rows * wv);
    let q = ChannelQuant::from_range(0.0, if total > 0 { 1.0 } else { 0.0 });
    let last_column: u64 = (0..rows)
        .map(|iy| u64::from(bit(plane, iy * wv + wv - 1)))
        .sum();
    let last_row = ones(plane, (rows - 1) * wv, wv);
    let corner = u64::from(bit(plane, rows * wv - 1));
    let (more_w, more_h) = (w.saturating_sub(wv) as u64, h.saturating_sub(rows) as u64);
    let set = total + last_column * more_w + more_h * (last_row + corner * more_w);
    let n = (h * w) as u64;
    let sum = set * u64::from(q.level(1.0)) + (n - set) * u64::from(q.level(0.0));
    (q, mean_level(sum, h * w, q))
}

/// Byte `j` of `SPREAD[b]` is bit `j` of `b`.
const SPREAD: [u64; 256] = {
    let mut table = [0u64; 256];
    let mut b = 0;
    while b < 256 {
        let mut j = 0;
        while j < 8 {
            if (b >> j) & 1 == 1 {
                table[b] |= 1 << (8 * j);
            }
            j += 1;
        }
        b += 1;
    }
    table
};

/// The words of `out.len()` pixels of four binary channels from pixel `start` of their packed
/// `planes` on: `table[m]` for the pixel whose set bits (channel `j` at bit `j`) make `m`.
/// Eight pixels at a time: each plane's byte spread to a bit per byte, the four shifted into a
/// nibble per byte.
#[inline(always)]
fn bit_words(planes: [&[u8]; 4], start: usize, table: &[u32; 16], out: &mut [u32]) {
    for (chunk, x0) in out.chunks_mut(8).zip((start..).step_by(8)) {
        let nibbles = planes.iter().enumerate().fold(0u64, |s, (j, p)| {
            s | SPREAD[usize::from(byte_at(p, x0))] << j
        });
        for (k, o) in chunk.iter_mut().enumerate() {
            *o = table[((nibbles >> (8 * k)) & 15) as usize];
        }
    }
}

/// ORs into each of `out`'s words `set[1]` where pixel `start + x` of the packed `plane` is
/// set, `set[0]` where it is clear.
#[inline(always)]
fn or_bit_levels(plane: &[u8], start: usize, set: [u32; 2], out: &mut [u32]) {
    for (chunk, x0) in out.chunks_mut(8).zip((start..).step_by(8)) {
        let byte = byte_at(plane, x0);
        for (k, o) in chunk.iter_mut().enumerate() {
            *o |= set[usize::from((byte >> k) & 1)];
        }
    }
}

/// The quantised weights of one call, from the input channels' quantisation.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct Plan8 {
    quant: Vec<ChannelQuant>,
    /// `k`, `[c_out][9][quads * 4]`: per output channel and tap, every input channel's weight
    /// side by side, channels past `c_in` 0.
    k: Vec<i8>,
    /// `k` as the kernel reads it: `[c_out / 4][quads][9][4 outputs]` words of 4 channels
    /// ([`dot::word`]) (empty on [`DotPath::Amx`]).
    words: Vec<u32>,
    /// `k` as [`dot::accumulate_tiles`] reads it, one vector per block of
    /// [`dot::TILE_QUADS`] quads (empty unless the path is [`DotPath::Amx`]).
    tiles: Vec<Vec<u32>>,
    /// Per output channel, `t_o`.
    scale: Vec<f32>,
    /// Per output channel, `Σ k z` over every channel and tap.
    offset: Vec<i32>,
    /// Per output channel, `b_o - e_o`: the bias less the weights' rounding at the input's mean.
    bias: Vec<f32>,
}

impl Conv3x3 {
    /// Quads of input channels (the last one padded with channels of weight 0).
    fn quads(&self) -> usize {
        self.c_in.div_ceil(dot::CHANNELS)
    }

    /// Input channels, padded to whole quads.
    fn c_pad(&self) -> usize {
        self.quads() * dot::CHANNELS
    }

    /// Where `k[o][c][ky][kx]` lies in [`Plan8::k`].
    fn k_at(&self, o: usize, c: usize, tap: usize) -> usize {
        (o * TAPS + tap) * self.c_pad() + c
    }

    /// The weights quantised for inputs quantised as `quant` (one per input channel), packed
    /// for `path`. Per output channel, on the tap-major copy of the weights, in loops over
    /// contiguous channels the compiler vectorises: every call makes a new plan (the input's
    /// ranges move from frame to frame).
    fn plan8(&self, quant: Vec<ChannelQuant>, means: &[f64], path: DotPath) -> Plan8 {
        let c_pad = self.c_pad();
        let row = TAPS * c_pad;
        let mut k = vec![0i8; self.c_out * row];
        let mut scale = vec![0f32; self.c_out];
        let mut offset = vec![0i32; self.c_out];
        // Each input channel's scale and level of 0 at each of its weights (padding channels:
        // 0 and 0, their weights are 0 anyway).
        let (mut s, mut z) = (vec![0f32; row], vec![0i32; row]);
        for (c, q) in quant.iter().enumerate() {
            for t in 0..TAPS {
                (s[t * c_pad + c], z[t * c_pad + c]) = (q.scale, i32::from(q.zero));
            }
        }
        let mut scaled = vec![0f32; row];
        let mut bias = self.bias.clone();
        let (mut k_sum, mut w_sum) = (vec![0i32; c_pad], vec![0f32; c_pad]);
        neuspike_simd::dispatch(
            #[inline(always)]
            || {
                for (o, (ks, w)) in k
                    .chunks_exact_mut(row)
                    .zip(self.by_tap.chunks_exact(row))
                    .enumerate()
                {
                    let Some(t_o) = quantize_weights(w, &s, &mut scaled, ks) else {
                        continue;
                    };
                    scale[o] = t_o;
                    offset[o] = ks.iter().zip(&z).map(|(&k, &z)| i32::from(k) * z).sum();
                    // Per channel, its taps' `k` and `w s_c` summed, tap by tap.
                    k_sum.fill(0);
                    w_sum.fill(0.0);
                    for (ks, ws) in ks.chunks_exact(c_pad).zip(scaled.chunks_exact(c_pad)) {
                        for (((a, b), &k), &w) in k_sum.iter_mut().zip(&mut w_sum).zip(ks).zip(ws) {
                            *a += i32::from(k);
                            *b += w;
                        }
                    }
                    let error: f64 = means
                        .iter()
                        .zip(k_sum.iter().zip(&w_sum))
                        .map(|(&m, (&k, &w))| m * (f64::from(t_o) * f64::from(k) - f64::from(w)))
                        .sum();
                    bias[o] = (f64::from(self.bias[o]) - error) as f32;
                }
            },
        );
        let (words, tiles) = if path == DotPath::Amx {
            (Vec::new(), self.tiles(&k))
        } else {
            (self.words(&k), Vec::new())
        };

        Plan8 {
            quant,
            k,
            words,
            tiles,
            scale,
            offset,
            bias,
        }
    }

    /// The four channels' weights of `k` from `at` on, as one word.
    fn quad_word(k: &[i8], at: usize) -> u32 {
        let b = &k[at..at + dot::CHANNELS];
        dot::word([b[0], b[1], b[2], b[3]].map(|v| v as u8))
    }

    /// [`Plan8::k`] as [`dot::accumulate`] reads it: `[c_out / 4][quads][9][4]` words of four
    /// channels.
    fn words(&self, k: &[i8]) -> Vec<u32> {
        let quads = self.quads();
        let mut words = vec![0u32; self.c_out * quads * TAPS];
        for o in 0..self.c_out {
            let (g, lane) = (o / OUTS, o % OUTS);
            for quad in 0..quads {
                for t in 0..TAPS {
                    let at = ((g * quads + quad) * TAPS + t) * OUTS + lane;
                    words[at] = Self::quad_word(k, self.k_at(o, quad * dot::CHANNELS, t));
                }
            }
        }
        words
    }

    /// [`Plan8::k`] in the tiles of [`dot::TileTaps`], one vector per block of
    /// [`dot::TILE_QUADS`] quads, taps in the order kernel row by row, column by column.
    fn tiles(&self, k: &[i8]) -> Vec<Vec<u32>> {
        let (quads, groups) = (self.quads(), self.c_out.div_ceil(dot::TILE_OUTS));
        (0..quads)
            .step_by(dot::TILE_QUADS)
            .map(|q0| {
                let nq = (quads - q0).min(dot::TILE_QUADS);
                let mut tile = vec![0u32; groups * TAPS * dot::TILE_OUTS * nq];
                for o in 0..self.c_out {
                    let (g, row) = (o / dot::TILE_OUTS, o % dot::TILE_OUTS);
                    for t in 0..TAPS {
                        let dst = &mut tile[((g * TAPS + t) * dot::TILE_OUTS + row) * nq..][..nq];
                        for (q, d) in dst.iter_mut().enumerate() {
                            *d = Self::quad_word(k, self.k_at(o, (q0 + q) * dot::CHANNELS, t));
                        }
                    }
                }
                tile
            })
            .collect()
    }

    /// Output channel `o`'s terms: its offset, `t_o` and bias, taken out of the loop over its
    /// points (through the vectors' heap the compiler would reload them at every store).
    #[inline(always)]
    fn terms(&self, plan: &Plan8, o: usize) -> (i32, f32, f32) {
        (plan.offset[o], plan.scale[o], plan.bias[o])
    }

    /// An output's value from its integer sum and its channel's [`terms`](Self::terms).
    #[inline(always)]
    fn dequantize(&self, (offset, scale, bias): (i32, f32, f32), sum: i32) -> f32 {
        let y = sum.wrapping_sub(offset) as f32 * scale + bias;
        if self.relu { y.max(0.0) } else { y }
    }

    /// The 8-bit definition ([`Precision::Int8`], see [`int8`](self)) on `input` (`[C, H, W]`),
    /// whatever [`precision`](Self::precision) says: the input's per-channel quantisation, then
    /// for each output the sum, input channel by channel, kernel row by row, column by column,
    /// of the 8-bit products (a tap off the image reads the level of 0), then
    /// `t_o (sum - offset) + b_o` and the ReLU if any.
    pub fn reference_int8(&self, input: ArrayView3<f32>) -> Result<Array3<f32>, Conv3x3Error> {
        let (_, h, w) = input.dim();
        let (ho, wo) = (self.out_len(h), self.out_len(w));
        self.check(input.shape(), self.c_out * ho * wo)?;
        self.check_int8()?;
        let (quant, means) = self.reference_quantization(input);
        let plan = self.plan8(quant, &means, DotPath::Portable);
        let level = |c: usize, y: isize, x: isize| -> i32 {
            let q = plan.quant[c];
            if y < 0 || x < 0 || y >= h as isize || x >= w as isize {
                i32::from(q.zero)
            } else {
                i32::from(q.quantize(input[[c, y as usize, x as usize]]))
            }
        };
        let s = self.stride as isize;
        Ok(Array3::from_shape_fn((self.c_out, ho, wo), |(o, y, x)| {
            let mut sum = 0i32;
            for c in 0..self.c_in {
                for ky in 0..3 {
                    for kx in 0..3 {
                        let k = plan.k[self.k_at(o, c, ky * 3 + kx)];
                        let v = level(
                            c,
                            y as isize * s + ky as isize - 1,
                            x as isize * s + kx as isize - 1,
                        );
                        sum = sum.wrapping_add(i32::from(k) * v);
                    }
                }
            }
            self.dequantize(self.terms(&plan, o), sum)
        }))
    }

    /// [`quantization`](Self::quantization) in plain loops over `input`, all of it: each
    /// channel's quantisation from its finite range, and its mean level less its zero.
    fn reference_quantization(&self, input: ArrayView3<f32>) -> (Vec<ChannelQuant>, Vec<f64>) {
        (0..self.c_in)
            .map(|c| {
                let plane = input.slice(ndarray::s![c, .., ..]);
                let (lo, hi) = plane
                    .iter()
                    .filter(|v| v.is_finite())
                    .fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), &v| {
                        (l.min(v), h.max(v))
                    });
                let q = ChannelQuant::from_range(lo, hi);
                let sum: u64 = plane.iter().map(|&v| u64::from(q.quantize(v))).sum();
                (q, mean_level(sum, plane.len(), q))
            })
            .unzip()
    }

    /// Refuses more input channels than the 32-bit sums hold.
    pub(super) fn check_int8(&self) -> Result<(), Conv3x3Error> {
        if self.c_in > MAX_CHANNELS {
            return Err(Conv3x3Error::Int8Channels(self.c_in));
        }
        Ok(())
    }

    /// Every input channel's quantisation from its finite range, and the mean of its levels
    /// less its zero over the input read as `(h, w)` (an `Edge` input's padding included, as the
    /// convolution reads it), channels split across `pool`.
    fn quantization(
        &self,
        input: Input,
        (h, w): (usize, usize),
        pool: Option<&rayon::ThreadPool>,
    ) -> (Vec<ChannelQuant>, Vec<f64>) {
        let mut found = vec![(ChannelQuant::from_range(0.0, 0.0), 0.0); self.c_in];
        let tasks: Vec<_> = found.iter_mut().enumerate().collect();
        crate::bands::for_each(tasks, pool, |(c, slot)| {
            if let Some((plane, view)) = input.bit_plane(c) {
                *slot = bit_quantization(plane, view, (h, w));
                return;
            }
            *slot = neuspike_simd::dispatch(
                #[inline(always)]
                || {
                    let rows = match input {
                        // The view's own rows: the padding repeats them.
                        Input::Edge(x) => x.dim().1.min(h),
                        _ => h,
                    };
                    // From 0: every range is widened to hold 0 anyway.
                    let range = match input.plane(c, h) {
                        Some(plane) => finite_range(plane, (0.0, 0.0)),
                        None => {
                            (0..rows).fold((0.0, 0.0), |r, iy| finite_range(input.row(c, iy, h), r))
                        }
                    };
                    let q = ChannelQuant::from_range(range.0, range.1);
                    // Each row's levels, its last one repeated to `w`; the last row's to `h`.
                    let (mut sum, mut last) = (0u64, 0u64);
                    for iy in 0..rows {
                        let row = input.row(c, iy, h);
                        let levels: u32 = row.iter().map(|&v| q.level(v)).sum();
                        let pad = row.last().map_or(0, |&v| {
                            u64::from(q.level(v)) * w.saturating_sub(row.len()) as u64
                        });
                        last = u64::from(levels) + pad;
                        sum += last;
                    }
                    sum += last * (h - rows) as u64;
                    (q, mean_level(sum, h * w, q))
                },
            );
        });
        found.into_iter().unzip()
    }

    /// [`drive`](Self::drive) in 8 bits: the input's quantisation and the weights' once, then
    /// the output rows in bands across `pool`.
    pub(super) fn drive_int8(
        &self,
        isa: neuspike_simd::Isa,
        path: DotPath,
        input: Input,
        (h, w): (usize, usize),
        output: &mut [f32],
        pool: Option<&rayon::ThreadPool>,
    ) {
        let (ho, wo) = (self.out_len(h), self.out_len(w));
        let (quant, means) = self.quantization(input, (h, w), pool);
        let plan = self.plan8(quant, &means, path);
        let rows = crate::bands::band_rows(ho, pool);
        let tasks = crate::bands::row_bands(output, ho * wo, wo, rows);
        let band = |(y0, mut planes): (usize, Vec<&mut [f32]>)| {
            BUFFERS8.with_borrow_mut(|buffers| {
                neuspike_simd::with_isa(
                    isa,
                    #[inline(always)]
                    || match self.stride {
                        1 => self.band8::<1>(path, &plan, input, (h, w), y0, &mut planes, buffers),
                        _ => self.band8::<2>(path, &plan, input, (h, w), y0, &mut planes, buffers),
                    },
                )
            })
        };
        crate::bands::for_each(tasks, pool, band);
    }

    /// [`band`](Self::band) in 8 bits: each input row read is quantised, four channels to a
    /// word (a point's four levels side by side, as [`dot::accumulate`] reads them), into `S`
    /// rows of `len` words, three input rows kept in a ring.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn band8<const S: usize>(
        &self,
        path: DotPath,
        plan: &Plan8,
        input: Input,
        (h, w): (usize, usize),
        y0: usize,
        planes: &mut [&mut [f32]],
        buffers: &mut Buffers8,
    ) {
        let wo = self.out_len(w);
        let wv = wo.div_ceil(dot::POINTS) * dot::POINTS;
        let len = wv + dot::POINTS;
        let quads = self.quads();
        let Buffers8 {
            scratch,
            levels,
            out,
            offsets,
        } = buffers;
        out.resize(self.c_out * wv, 0);
        // `[quads][3 slots][S][len]`; every slot is written before it is read.
        let quad_rows = S * len;
        let scratch = aligned(scratch, quads * 3 * quad_rows);
        // Each quad's level of 0, the word a tap off the image reads.
        let zeros: Vec<u32> = (0..quads)
            .map(|quad| {
                dot::word(std::array::from_fn(|j| {
                    plan.quant
                        .get(quad * dot::CHANNELS + j)
                        .map_or(0, |q| q.zero)
                }))
            })
            .collect();
        // For a quad of four binary channels, the word of each of the 16 ways its four bits can
        // be set (channel `j` at bit `j`).
        let tables: Vec<Option<[u32; 16]>> = (0..quads)
            .map(|quad| {
                let c0 = quad * dot::CHANNELS;
                let quant = plan.quant.get(c0..c0 + dot::CHANNELS)?;
                (0..dot::CHANNELS)
                    .all(|j| input.bit_plane(c0 + j).is_some())
                    .then(|| {
                        std::array::from_fn(|m| {
                            (0..dot::CHANNELS)
                                .map(|j| {
                                    let level = if (m >> j) & 1 == 1 { 1.0 } else { 0.0 };
                                    quant[j].level(level) << (8 * j)
                                })
                                .fold(0, |a, b| a | b)
                        })
                    })
            })
            .collect();
        let mut held: [Option<isize>; 3] = [None; 3];
        let n_rows = planes.first().map_or(0, |p| p.len() / wo);
        for y in y0..y0 + n_rows {
            let mut slots = [0; 3];
            for (ky, slot) in slots.iter_mut().enumerate() {
                let iy = (y * S + ky) as isize - 1;
                *slot = iy.rem_euclid(3) as usize;
                if held[*slot] == Some(iy) {
                    continue;
                }
                let inside = usize::try_from(iy).ok().filter(|&iy| iy < h);
                for (quad, &zero) in zeros.iter().enumerate() {
                    // A plain `match`, not a closure: a closure may be compiled out of line,
                    // for the baseline instruction set.
                    let src = match inside {
                        Some(iy) => {
                            let c0 = quad * dot::CHANNELS;
                            let n = input.row_len(c0, h);
                            let bits: [_; dot::CHANNELS] =
                                std::array::from_fn(|j| input.bit_plane(c0 + j));
                            let whole = plan.quant.get(c0..c0 + 4);
                            if let (Some(table), [Some(b0), Some(b1), Some(b2), Some(b3)]) =
                                (&tables[quad], bits)
                            {
                                // Four binary channels: each word from the table of the 16
                                // ways four bits can be set.
                                let (rows, wv) = b0.1;
                                levels.resize(n, 0);
                                bit_words(
                                    [b0.0, b1.0, b2.0, b3.0],
                                    iy.min(rows - 1) * wv,
                                    table,
                                    &mut levels[..n],
                                );
                                Some(&levels[..])
                            } else if let (Some(&[q0, q1, q2, q3]), [None, None, None, None]) =
                                (whole, bits)
                            {
                                // Every word written below: no zeros first.
                                levels.resize(n, 0);
                                // A whole quad: one pass making each word.
                                let [r0, r1, r2, r3] =
                                    [0, 1, 2, 3].map(|j| input.row(c0 + j, iy, h));
                                for ((((l, &a), &b), &c), &d) in
                                    levels.iter_mut().zip(r0).zip(r1).zip(r2).zip(r3)
                                {
                                    *l = q0.level(a)
                                        | q1.level(b) << 8
                                        | q2.level(c) << 16
                                        | q3.level(d) << 24;
                                }
                                Some(&levels[..])
                            } else {
                                levels.clear();
                                levels.resize(n, 0);
                                for (j, bit_plane) in bits.into_iter().enumerate() {
                                    let c = quad * dot::CHANNELS + j;
                                    let Some(&q) = plan.quant.get(c) else { break };
                                    let shift = 8 * j as u32;
                                    if let Some((plane, (rows, wv))) = bit_plane {
                                        let set = [q.level(0.0), q.level(1.0)].map(|l| l << shift);
                                        or_bit_levels(plane, iy.min(rows - 1) * wv, set, levels);
                                        continue;
                                    }
                                    for (l, &v) in levels.iter_mut().zip(input.row(c, iy, h)) {
                                        *l |= q.level(v) << shift;
                                    }
                                }
                                Some(&levels[..])
                            }
                        }
                        None => None,
                    };
                    let dst = &mut scratch[(quad * 3 + *slot) * quad_rows..][..quad_rows];
                    Self::padded::<S, u32>(src, w, dst, zero);
                }
                held[*slot] = Some(iy);
            }
            out.fill(0);
            if path == DotPath::Amx {
                let taps: [usize; TAPS] =
                    std::array::from_fn(|t| Self::taps::<S>(slots[t / 3] * quad_rows, len)[t % 3]);
                for (b, tile) in plan.tiles.iter().enumerate() {
                    let q0 = b * dot::TILE_QUADS;
                    let first = taps.map(|at| at + q0 * 3 * quad_rows);
                    let taps = dot::TileTaps {
                        rows: scratch,
                        taps: &first,
                        quad_stride: 3 * quad_rows,
                        quads: (quads - q0).min(dot::TILE_QUADS),
                        weights: tile,
                    };
                    dot::accumulate_tiles(path, &taps, out, wv, self.c_out, wv);
                }
            } else {
                for q0 in (0..quads).step_by(QUADS) {
                    offsets.clear();
                    for quad in q0..(q0 + QUADS).min(quads) {
                        for slot in slots {
                            let at = (quad * 3 + slot) * quad_rows;
                            offsets.extend(Self::taps::<S>(at, len));
                        }
                    }
                    let taps = WordTaps {
                        rows: scratch,
                        offsets,
                        weights: &plan.words[q0 * TAPS * OUTS..],
                        group_stride: quads * TAPS * OUTS,
                    };
                    dot::accumulate(path, &taps, out, wv, self.c_out / OUTS, wv);
                }
            }
            for (o, plane) in planes.iter_mut().enumerate() {
                let terms = self.terms(plan, o);
                let dst = &mut plane[(y - y0) * wo..][..wo];
                for (d, &sum) in dst.iter_mut().zip(&out[o * wv..][..wo]) {
                    *d = self.dequantize(terms, sum);
                }
            }
        }
    }
}

/// The working rows of [`Conv3x3::band8`], kept per thread from one band to the next.
#[derive(Default)]
struct Buffers8 {
    /// Input rows quantised and padded for the taps, `[quads][3 slots][S][len]` words.
    scratch: Vec<u32>,
    /// One input row's levels, four channels to a word.
    levels: Vec<u32>,
    /// One output row of every channel, `[O][wv]` sums.
    out: Vec<i32>,
    /// The offsets of one block's tap rows in the scratch rows.
    offsets: Vec<usize>,
}

thread_local! {
    static BUFFERS8: std::cell::RefCell<Buffers8> = std::cell::RefCell::default();
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{bits_case, conv, layer_input as input, pattern, runs_give};
    use ndarray::Array4;
    use proptest::prelude::*;

    /// Every path, instruction set and thread count gives the 8-bit definition's bits.
    fn check(c_in: usize, c_out: usize, stride: usize, (h, w): (usize, usize), seed: u32) {
        let base = conv(c_in, c_out, stride, seed);
        let base = if seed % 2 == 1 {
            base.with_relu()
        } else {
            base
        };
        let x = input(c_in * h * w, seed + 2, seed);
        let view = ArrayView3::from_shape((c_in, h, w), &x).unwrap();
        let want = base.reference_int8(view).unwrap();
        for path in DotPath::ALL.into_iter().filter(|p| p.is_supported()) {
            let conv = base.clone().with_precision(Precision::Int8(path));
            let what = format!("{c_in}->{c_out} at {h}x{w}, stride {stride}, {path:?}");
            runs_give(&conv, &x, (h, w), want.as_slice().unwrap(), &what);
        }
    }

    #[test]
    fn matches_the_8_bit_definition_at_the_networks_sizes() {
        for (seed, &(c_in, c_out, stride, hw)) in (1..).zip(&crate::testing::NETWORK_LAYERS) {
            check(c_in, c_out, stride, hw, seed);
        }
        // Input channels that are not a multiple of four.
        check(6, 8, 1, (7, 33), 6);
        check(3, 4, 2, (7, 33), 7);
    }

    /// The error against the `f32` definition stays within its worst case: per output channel,
    /// `Σ (t/2 (|x|max / s + 1/2) + |w| s / 2)` over the channels and taps (an input is off by
    /// at most half its step, a weight by half of `t`), and it is small on average (below 1% of
    /// the outputs' RMS).
    fn close_to_f32(c_in: usize, c_out: usize, stride: usize, (h, w): (usize, usize), seed: u32) {
        let conv = conv(c_in, c_out, stride, seed);
        let x = input(c_in * h * w, seed + 2, seed);
        let view = ArrayView3::from_shape((c_in, h, w), &x).unwrap();
        let exact = conv.reference(view).unwrap();
        let got = conv.reference_int8(view).unwrap();
        let (mut err2, mut sum2) = (0f64, 0f64);
        for o in 0..c_out {
            let mut bound = 1e-4f32;
            let scale = |c: usize| {
                let (lo, hi) = view
                    .slice(ndarray::s![c, .., ..])
                    .fold((0f32, 0f32), |(l, h), &v| (l.min(v), h.max(v)));
                (ChannelQuant::from_range(lo, hi).scale, lo.abs().max(hi))
            };
            let most = (0..c_in)
                .flat_map(|c| (0..TAPS).map(move |t| (c, t)))
                .map(|(c, t)| (conv.weight(o, c, t / 3, t % 3) * scale(c).0).abs())
                .fold(0f32, f32::max);
            let t_o = most / 127.0;
            for c in 0..c_in {
                let (s, big) = scale(c);
                for t in 0..TAPS {
                    let w = conv.weight(o, c, t / 3, t % 3).abs();
                    let levels = if s > 0.0 { big / s + 0.5 } else { 0.0 };
                    bound += t_o / 2.0 * levels + w * s / 2.0;
                }
            }
            for (a, b) in exact
                .slice(ndarray::s![o, .., ..])
                .iter()
                .zip(got.slice(ndarray::s![o, .., ..]))
            {
                assert!(
                    (a - b).abs() <= bound,
                    "output {o}: {b} for {a}, bound {bound}"
                );
                err2 += f64::from(a - b).powi(2);
                sum2 += f64::from(*a).powi(2);
            }
        }
        assert!(
            err2 < 1e-4 * sum2,
            "{c_in}->{c_out}: RMS error {} of RMS {}",
            err2.sqrt(),
            sum2.sqrt()
        );
    }

    #[test]
    fn stays_within_its_stated_error_of_the_f32_definition() {
        for (seed, (c_in, c_out, stride)) in
            [(32, 8, 1), (8, 16, 1), (16, 32, 2), (64, 64, 1), (5, 4, 2)]
                .into_iter()
                .enumerate()
        {
            close_to_f32(c_in, c_out, stride, (12, 40), seed as u32);
        }
    }

    /// [`quantize_weights`]' definition in a plain loop: `f32::round` and the saturating `as`.
    fn plain_weights(w: &[f32], s: &[f32]) -> Option<(f32, Vec<i8>)> {
        let scaled: Vec<f32> = w.iter().zip(s).map(|(w, s)| w * s).collect();
        let most = scaled.iter().fold(0f32, |m, v| m.max(v.abs()));
        let t_o = most / 127.0;
        if !(t_o >= f32::MIN_POSITIVE && t_o.is_finite()) {
            return None;
        }
        let k = scaled
            .iter()
            .map(|v| (v * (1.0 / t_o)).clamp(-127.0, 127.0).round() as i8)
            .collect();
        Some((t_o, k))
    }

    #[test]
    fn weights_quantise_as_the_plain_definition() {
        let quantized = |w: &[f32], s: &[f32]| {
            let (mut scaled, mut k) = (vec![0f32; w.len()], vec![0i8; w.len()]);
            neuspike_simd::dispatch(
                #[inline(always)]
                || quantize_weights(w, s, &mut scaled, &mut k),
            )
            .map(|t_o| (t_o, k))
        };
        for n in [1, 9, 15, 16, 17, 36, 288, 577] {
            let w = pattern(n, n as u32);
            let s: Vec<f32> = pattern(n, 7).iter().map(|v| v.abs() + 0.01).collect();
            assert_eq!(quantized(&w, &s), plain_weights(&w, &s), "{n} weights");
        }
        // Ties: 127 times a half step lands on halves; they go away from zero.
        let w: Vec<f32> = (-254..=254).map(|i| i as f32 / 2.0).collect();
        let s = vec![1.0; w.len()];
        assert_eq!(quantized(&w, &s), plain_weights(&w, &s));
        // A NaN weight is a level of 0; an infinite one leaves no scale; none at all either.
        let mut w = pattern(40, 3);
        w[17] = f32::NAN;
        let got = quantized(&w, &[1.0; 40]).expect("a scale");
        assert_eq!(got.1[17], 0);
        assert_eq!(Some(got), plain_weights(&w, &[1.0; 40]));
        w[3] = f32::INFINITY;
        assert_eq!(quantized(&w, &[1.0; 40]), None);
        assert_eq!(quantized(&[0.0; 20], &[1.0; 20]), None);
    }

    #[test]
    fn the_rounding_correction_takes_the_shift_out_of_each_output() {
        // Inputs after a ReLU: positive, their mean far from 0, as in a network.
        let (c_in, c_out, (h, w)) = (32, 16, (12, 40));
        let conv = conv(c_in, c_out, 1, 11);
        let x: Vec<f32> = pattern(c_in * h * w, 12)
            .iter()
            .map(|v| v.abs() * 3.0)
            .collect();
        let view = ArrayView3::from_shape((c_in, h, w), &x).unwrap();
        let (exact, got) = (
            conv.reference(view).unwrap(),
            conv.reference_int8(view).unwrap(),
        );
        // The same without the correction: the plan's bias against the layer's own.
        let (quant, means) = conv.reference_quantization(view);
        let plan = conv.plan8(quant, &means, DotPath::Portable);
        let shift = |o: usize, corrected: bool| {
            let undo = if corrected {
                0.0
            } else {
                conv.bias[o] - plan.bias[o]
            };
            let d = exact.slice(ndarray::s![o, .., ..]);
            let g = got.slice(ndarray::s![o, .., ..]);
            g.iter()
                .zip(d)
                .map(|(&g, &d)| f64::from(g + undo - d))
                .sum::<f64>()
                / d.len() as f64
        };
        let (with, without): (f64, f64) = (0..c_out)
            .map(|o| (shift(o, true).abs(), shift(o, false).abs()))
            .fold((0.0, 0.0), |(a, b), (x, y)| (a + x, b + y));
        assert!(
            with < without / 3.0,
            "mean shift {with} with the correction, {without} without"
        );
    }

    #[test]
    fn spikes_and_a_zero_channel_are_exact_levels() {
        // 0 and 1 are levels 0 and 255 exactly; an all-zero channel reads as 0.
        let q = ChannelQuant::from_range(0.0, 1.0);
        assert_eq!((q.quantize(0.0), q.quantize(1.0), q.zero), (0, 255, 0));
        let zero = ChannelQuant::from_range(0.0, 0.0);
        assert_eq!(zero.scale, 0.0);
        assert_eq!([zero.quantize(5.0), zero.quantize(f32::NAN)], [0, 0]);
        // Signed: 0 is a level; the ends and the infinities clamp; NaN reads as the bottom.
        let q = ChannelQuant::from_range(-1.0, 3.0);
        assert_eq!(q.zero, 64, "{q:?}");
        assert_eq!(q.quantize(0.0), q.zero);
        assert_eq!([q.quantize(-1.0), q.quantize(3.0)], [0, 255]);
        assert_eq!(
            [q.quantize(f32::NEG_INFINITY), q.quantize(f32::INFINITY)],
            [0, 255]
        );
        assert_eq!(q.quantize(f32::NAN), 0);
        // Ranges at f32's ends do not overflow.
        let q = ChannelQuant::from_range(f32::MIN, f32::MAX);
        assert!(q.scale.is_finite() && q.scale > 0.0, "{q:?}");
        // A range too small for its reciprocal: read as 0.
        assert_eq!(ChannelQuant::from_range(0.0, 1e-37).scale, 0.0);
    }

    #[test]
    fn non_finite_inputs_give_finite_outputs() {
        let conv = conv(8, 8, 1, 3).with_precision(Precision::int8());
        let (h, w) = (5, 20);
        let mut x = input(8 * h * w, 4, 1);
        x[3] = f32::NAN;
        x[50] = f32::INFINITY;
        x[120] = f32::NEG_INFINITY;
        let mut got = vec![0.0; 8 * h * w];
        conv.run(&x, (h, w), &mut got, None).unwrap();
        assert!(got.iter().all(|v| v.is_finite()));
        let view = ArrayView3::from_shape((8, h, w), &x).unwrap();
        assert_eq!(
            got,
            conv.reference_int8(view)
                .unwrap()
                .into_raw_vec_and_offset()
                .0
        );
    }

    #[test]
    fn parts_and_edge_padding_give_the_8_bit_definitions_bits() {
        for stride in [1, 2] {
            let conv = conv(8, 8, stride, 4)
                .with_relu()
                .with_precision(Precision::int8());
            crate::testing::parts_and_edge_give(&conv, |c, x| c.reference_int8(x).unwrap());
        }
    }

    #[test]
    fn precisions_read_back_their_names() {
        let supported = DotPath::ALL.into_iter().filter(|p| p.is_supported());
        for p in std::iter::once(Precision::F32).chain(supported.map(Precision::Int8)) {
            assert_eq!(p.to_string().parse::<Precision>(), Ok(p));
        }
        assert_eq!("int8".parse::<Precision>(), Ok(Precision::int8()));
        let e = "int4".parse::<Precision>().unwrap_err();
        assert!(e.contains("`int4`") && e.contains("int8-vnni"), "{e}");
        assert!("int8-avx".parse::<Precision>().is_err());
    }

    #[test]
    fn too_many_channels_are_refused_in_8_bits_only() {
        let weights = Array4::<f32>::zeros((4, MAX_CHANNELS + 1, 3, 3));
        let conv = Conv3x3::new(weights.view(), &[0.0], 1).unwrap();
        let x = vec![0.0; (MAX_CHANNELS + 1) * 2 * 2];
        let mut y = vec![0.0; 4 * 2 * 2];
        conv.run(&x, (2, 2), &mut y, None).unwrap();
        let err = conv
            .with_precision(Precision::int8())
            .run(&x, (2, 2), &mut y, None)
            .unwrap_err();
        assert_eq!(err, Conv3x3Error::Int8Channels(MAX_CHANNELS + 1));
        assert!(err.to_string().contains("4097 input channels"), "{err}");
    }

    /// Packed binary planes read without tables give, on every path and precision, the bits of
    /// the same planes unpacked to 0.0/1.0 (itself tested against the definitions).
    fn bits_check(
        (d, planes, c_out, stride): (usize, usize, usize, usize),
        (h, w): (usize, usize),
        (hp, wp): (usize, usize),
        seed: u32,
        empty: &[usize],
    ) {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        let (base, dense, bits, all) = bits_case((d, planes, c_out, stride), (h, w), seed, empty);
        let dense = ArrayView3::from_shape((d, h, w), &dense).unwrap();
        let precisions = DotPath::ALL
            .into_iter()
            .filter(|p| p.is_supported())
            .map(Precision::Int8)
            .chain([Precision::F32]);
        for precision in precisions {
            let conv = base.clone().with_precision(precision);
            let n = c_out * conv.out_len(hp) * conv.out_len(wp);
            let mut want = vec![f32::NAN; n];
            conv.run_edge_padded(all.view(), (hp, wp), &mut want, None)
                .unwrap();
            for pool in [None, Some(&pool)] {
                let mut got = vec![f32::NAN; n];
                conv.run_edge_padded_bits_by(false, dense, &bits, planes, (hp, wp), &mut got, pool)
                    .unwrap();
                assert_eq!(
                    got,
                    want,
                    "{d} dense + {planes} packed -> {c_out}, stride {stride}, {h}x{w} as \
                     {hp}x{wp}, {precision}, pool {}",
                    pool.is_some()
                );
            }
        }
    }

    #[test]
    fn packed_planes_give_the_unpacked_planes_bits() {
        // The spike representation at the network's size (1 dense channel, 31 planes), padded
        // rows; widths that are not a multiple of 8 (rows starting inside a byte); no dense
        // channel; quads mixed and whole; stride 2; empty planes; one pixel.
        bits_check((1, 31, 4, 1), (13, 400), (16, 400), 1, &[]);
        bits_check((1, 31, 8, 1), (9, 37), (16, 40), 2, &[3, 4]);
        bits_check((0, 8, 4, 1), (5, 21), (8, 24), 3, &[0]);
        bits_check((5, 6, 4, 2), (11, 197), (16, 200), 4, &[]);
        bits_check((2, 3, 4, 2), (7, 18), (8, 21), 5, &[2]);
        bits_check((1, 3, 4, 1), (1, 1), (5, 9), 6, &[]);
        bits_check((0, 4, 4, 1), (3, 5), (3, 5), 7, &[0, 1, 2, 3]);
    }

    #[test]
    fn packed_planes_refuse_what_they_cannot_read() {
        let conv = conv(1 + 4, 4, 1, 1).with_precision(Precision::int8());
        let dense = vec![0.5f32; 6 * 10];
        let dense = ArrayView3::from_shape((1, 6, 10), &dense).unwrap();
        let per = crate::conv3x3::packed_plane_bytes(6, 10);
        let mut out = vec![0.0; 4 * 8 * 16];
        // Too few bytes, another channel count, a size smaller than the view's.
        for (bits, planes, hw) in [
            (4 * per - 1, 4, (8, 16)),
            (5 * per, 5, (8, 16)),
            (4 * per, 4, (4, 16)),
        ] {
            let bits = vec![0xffu8; bits];
            let err = conv.run_edge_padded_bits(dense, &bits, planes, hw, &mut out, None);
            assert!(
                matches!(err, Err(Conv3x3Error::Shape { .. })),
                "{planes} planes in {} bytes as {hw:?}: {err:?}",
                bits.len()
            );
        }
    }

    #[test]
    fn set_pixels_are_counted_wherever_a_run_starts() {
        let plane: Vec<u8> = pattern(40, 9)
            .iter()
            .map(|v| (v * 1000.0) as i32 as u8)
            .collect();
        for start in [0, 1, 7, 8, 13, 64, 65] {
            for len in [0, 1, 7, 8, 9, 63, 64, 65, 200] {
                let want = (start..start + len).filter(|&i| bit(&plane, i)).count() as u64;
                assert_eq!(ones(&plane, start, len), want, "{start}..+{len}");
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        #[test]
        fn matches_the_8_bit_definition_anywhere(
            c_in in 1usize..20,
            groups in 1usize..4,
            stride in 1usize..3,
            h in 1usize..12,
            w in 1usize..70,
            seed in 0u32..1000,
        ) {
            check(c_in, 4 * groups, stride, (h, w), seed);
        }
    }
}
