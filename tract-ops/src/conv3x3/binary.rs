//! A first convolution of bit-packed binary planes by table lookups
//! ([`Conv3x3::run_edge_padded_bits`] on AVX-512).
//!
//! For one output channel and one tap, four binary channels' contributions at a point are the sum
//! of the weights of the channels whose bit is set: one of 16 values, made once per network from
//! the `f32` weights. Each input row's bits are spread once into a row of 4-bit indices per group
//! of four planes (its edge column repeated and a zero either side, as the padding asks), and
//! [`neuspike_simd::lut::accumulate`] adds, for 16 points a permute, the table entries of every
//! tap and group. A network's head reading 31 spike planes makes 72 lookups a point and output
//! channel where the dense convolution makes 279 multiply-adds, and in `f32`: the result is the
//! `f32` convolution's up to the order of its sums (tested with a tolerance), whatever precision
//! the rest of the network runs in. The dense channels before the planes (the spike
//! representation's interval channel) go through an `f32` [`Conv3x3`] of their own first.

use std::cell::RefCell;

use ndarray::{Array4, ArrayView3};
use neuspike_simd::lut::{self, ENTRIES};

use super::{Conv3x3, Conv3x3Error, TAPS, packed_plane_bytes};

/// Planes of one 4-bit index.
const GROUP: usize = 4;

/// `SPREAD[b]`: byte `i` of the word is bit `i` of `b`, 0 or 1.
const SPREAD: [u64; 256] = {
    let mut table = [0u64; 256];
    let mut b = 0;
    while b < 256 {
        let mut i = 0;
        while i < 8 {
            table[b] |= (((b >> i) & 1) as u64) << (8 * i);
            i += 1;
        }
        b += 1;
    }
    table
};

thread_local! {
    /// A band's rows of indices.
    static ROWS: RefCell<Vec<u8>> = RefCell::default();
}

/// The tables of a [`Conv3x3`] whose last `planes` input channels are binary.
#[derive(Clone, Debug)]
pub(crate) struct Tables {
    /// Dense input channels before the planes.
    dense_channels: usize,
    /// Groups of [`GROUP`] planes (the last may hold fewer).
    groups: usize,
    /// `[c_out][9 taps][groups]` tables.
    tables: Vec<[f32; ENTRIES]>,
    /// The convolution of the dense channels, with the bias (`None` without dense channels).
    dense: Option<Box<Conv3x3>>,
    bias: Vec<f32>,
}

impl Tables {
    /// The tables of `conv` for `dense_channels` dense channels before its binary ones.
    pub(crate) fn new(conv: &Conv3x3, dense_channels: usize) -> Tables {
        let planes = conv.c_in - dense_channels.min(conv.c_in);
        let groups = planes.div_ceil(GROUP);
        let mut tables = Vec::with_capacity(conv.c_out * TAPS * groups);
        for o in 0..conv.c_out {
            for tap in 0..TAPS {
                for g in 0..groups {
                    tables.push(std::array::from_fn(|n| {
                        (0..GROUP)
                            .filter(|&j| GROUP * g + j < planes && (n >> j) & 1 == 1)
                            .map(|j| {
                                let c = dense_channels + GROUP * g + j;
                                conv.weight(o, c, tap / 3, tap % 3)
                            })
                            .sum()
                    }));
                }
            }
        }
        let dense = (dense_channels > 0).then(|| {
            let weights =
                Array4::from_shape_fn((conv.c_out, dense_channels, 3, 3), |(o, c, y, x)| {
                    conv.weight(o, c, y, x)
                });
            // Checked by the convolution it comes from: 3x3, outputs a multiple of 4.
            Conv3x3::new(weights.view(), &conv.bias, 1)
                .map(Box::new)
                .unwrap_or_else(|e| unreachable!("a part of a valid convolution: {e}"))
        });
        Tables {
            dense_channels,
            groups,
            tables,
            dense,
            bias: conv.bias.clone(),
        }
    }

    /// The dense channels these tables were made for.
    pub(crate) fn dense_channels(&self) -> usize {
        self.dense_channels
    }

    /// The convolution of `dense` (`[D, h, w]`) and `planes` bit-packed planes of `h x w`
    /// pixels, edge-padded to `(hp, wp)`, at stride 1, into `output` (`[c_out, hp, wp]`); every
    /// size checked by the caller; then `max(0, y)` where `relu`.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn run(
        &self,
        isa: neuspike_simd::Isa,
        relu: bool,
        dense: ArrayView3<f32>,
        bits: &[u8],
        planes: usize,
        (hp, wp): (usize, usize),
        output: &mut [f32],
        pool: Option<&rayon::ThreadPool>,
    ) -> Result<(), Conv3x3Error> {
        let (_, h, w) = dense.dim();
        let plane = hp * wp;
        match &self.dense {
            Some(conv) => conv.run_edge_padded(dense, (hp, wp), output, pool)?,
            None => {
                for (o, out) in output.chunks_mut(plane.max(1)).enumerate() {
                    out.fill(self.bias[o]);
                }
            }
        }
        let per = packed_plane_bytes(h, w);
        // An index row: a zero, `wp` points, a zero, and room for the last 8-point word.
        let len = wp + 2 + 8;
        let rows = crate::bands::band_rows(hp, pool);
        let tasks = crate::bands::row_bands(output, plane, wp, rows);
        let band = |(y0, mut outs): (usize, Vec<&mut [f32]>)| {
            let n_rows = outs.first().map_or(0, |p| p.len() / wp.max(1));
            ROWS.with_borrow_mut(|buf| {
                // Input rows y0 - 1 ..= y0 + n_rows, each `groups` index rows.
                let span = self.groups * len;
                buf.clear();
                buf.resize((n_rows + 2) * span, 0);
                for (r, rows) in buf.chunks_exact_mut(span).enumerate() {
                    let iy = (y0 + r).checked_sub(1).filter(|&y| y < hp);
                    if let Some(iy) = iy {
                        let sy = iy.min(h - 1);
                        self.index_rows(bits, per, planes, (sy, w), wp, rows);
                    }
                }
                let mut index: Vec<&[u8]> = Vec::with_capacity(TAPS * self.groups);
                for r in 0..n_rows {
                    index.clear();
                    for ky in 0..3 {
                        let rows = &buf[(r + ky) * span..(r + ky + 1) * span];
                        for kx in 0..3 {
                            for g in 0..self.groups {
                                index.push(&rows[g * len + kx..g * len + kx + wp]);
                            }
                        }
                    }
                    let mut row_out: Vec<&mut [f32]> = outs
                        .iter_mut()
                        .map(|p| &mut p[r * wp..(r + 1) * wp])
                        .collect();
                    lut::accumulate(isa, &self.tables, &index, &mut row_out, wp);
                    if relu {
                        for v in row_out.iter_mut().flat_map(|p| p.iter_mut()) {
                            *v = v.max(0.0);
                        }
                    }
                }
            });
        };
        crate::bands::for_each(tasks, pool, band);
        Ok(())
    }

    /// The index rows of source row `sy` (of width `w`) read as `wp` points: per group, a 0,
    /// the 4-bit indices of its planes' bits at every point (the last column repeated past `w`),
    /// then zeros. `rows` is `groups` rows of `wp + 10` bytes, zeroed.
    fn index_rows(
        &self,
        bits: &[u8],
        per: usize,
        planes: usize,
        (sy, w): (usize, usize),
        wp: usize,
        rows: &mut [u8],
    ) {
        let len = wp + 2 + 8;
        let start = sy * w;
        let words = w.div_ceil(8);
        // The row's bytes of each plane, from bit `start` on: `words` bytes (bits past the row's
        // last point land past `w` in the index row, where the edge column overwrites them).
        let (at, off) = (start / 8, start % 8);
        let mut shifted = Vec::new();
        for (g, row) in rows.chunks_exact_mut(len).enumerate() {
            let dst = &mut row[1..1 + 8 * words];
            for k in GROUP * g..(GROUP * (g + 1)).min(planes) {
                let plane = &bits[k * per..(k + 1) * per];
                let src: &[u8] = if off == 0 {
                    &plane[at..at + words]
                } else {
                    shifted.clear();
                    shifted.extend((at..at + words).map(|i| {
                        let next = plane.get(i + 1).copied().unwrap_or(0);
                        ((u16::from(plane[i]) | u16::from(next) << 8) >> off) as u8
                    }));
                    &shifted
                };
                let shift = k % GROUP;
                for (d, &b) in dst.chunks_exact_mut(8).zip(src) {
                    let d: &mut [u8; 8] = d.try_into().unwrap_or_else(|_| unreachable!("8 bytes"));
                    *d = (u64::from_le_bytes(*d) | SPREAD[usize::from(b)] << shift).to_le_bytes();
                }
            }
        }
        for row in rows.chunks_exact_mut(len) {
            let edge = row[w];
            row[w + 1..=wp].fill(edge);
            row[wp + 1..].fill(0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::conv3x3::Precision;
    use crate::testing::bits_case;

    /// The tables give the `f32` convolution of the planes unpacked to 0.0/1.0, whatever the
    /// precision asked, up to the order of the sums: within `1e-5` of each output's `Σ |w| + |b|`.
    fn tables_check(
        (d, planes, c_out): (usize, usize, usize),
        (h, w): (usize, usize),
        (hp, wp): (usize, usize),
        seed: u32,
        empty: &[usize],
    ) {
        if neuspike_simd::detect() != neuspike_simd::Isa::Avx512 {
            eprintln!("no AVX-512 here: the tables are not used, nothing to check");
            return;
        }
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        let (base, dense, bits, all) = bits_case((d, planes, c_out, 1), (h, w), seed, empty);
        let dense = ArrayView3::from_shape((d, h, w), &dense).unwrap();
        let n = c_out * hp * wp;
        let mut want = vec![f32::NAN; n];
        base.run_edge_padded(all.view(), (hp, wp), &mut want, None)
            .unwrap();
        let scale: Vec<f32> = (0..c_out)
            .map(|o| {
                let taps: f32 = (0..d + planes)
                    .flat_map(|c| (0..9).map(move |t| (c, t)))
                    .map(|(c, t)| base.weight(o, c, t / 3, t % 3).abs())
                    .sum();
                taps + base.bias[o].abs() + 1.0
            })
            .collect();
        let precisions = [Precision::F32, Precision::int8(), Precision::bf16()];
        for precision in precisions {
            let conv = base.clone().with_precision(precision);
            for pool in [None, Some(&pool)] {
                let mut got = vec![f32::NAN; n];
                conv.run_edge_padded_bits(dense, &bits, planes, (hp, wp), &mut got, pool)
                    .unwrap();
                for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                    let o = i / (hp * wp);
                    assert!(
                        (g - w).abs() <= 1e-5 * scale[o],
                        "{d} dense + {planes} packed -> {c_out}, {h}x{w} as {hp}x{wp}, \
                         {precision}, pool {}: output {i}: {g} against {w}",
                        pool.is_some()
                    );
                }
            }
        }
    }

    #[test]
    fn tables_give_the_f32_convolution_of_the_unpacked_planes() {
        // The spike representation at the network's size (1 dense channel, 31 planes, padded
        // rows); a last group of fewer than 4 planes; widths not a multiple of 8 or 16 (rows
        // starting inside a byte); no dense channel; several dense ones; empty planes; one
        // pixel; 12 outputs (two passes of the kernel).
        tables_check((1, 31, 4), (13, 400), (16, 400), 1, &[]);
        tables_check((1, 31, 8), (9, 37), (16, 40), 2, &[3, 4]);
        tables_check((0, 8, 4), (5, 21), (8, 24), 3, &[0]);
        tables_check((3, 6, 12), (11, 197), (16, 200), 4, &[]);
        tables_check((1, 3, 4), (1, 1), (5, 9), 6, &[]);
        tables_check((0, 4, 4), (3, 5), (3, 5), 7, &[0, 1, 2, 3]);
    }

    #[test]
    fn every_byte_spreads_to_its_bits() {
        for (b, spread) in SPREAD.iter().enumerate() {
            let word = spread.to_le_bytes();
            for (i, &v) in word.iter().enumerate() {
                assert_eq!(usize::from(v), (b >> i) & 1, "byte {b:#x}, bit {i}");
            }
        }
    }
}
