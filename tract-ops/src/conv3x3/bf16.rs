//! [`Conv3x3`] in `bf16`: [`Precision::Bf16`].
//!
//! Each input value and weight is rounded to `bf16` ([`bf16::to_bf16`]: 8 significant bits,
//! `f32`'s range), and the products are summed in `f32` ([`neuspike_simd::bf16`]): no
//! calibration and no statistics of the frame, the input converted as it is read. An output is
//! its bias, then input channels two by two, kernel row by row, column by column, each step
//! adding the second channel's product, then the first's, to the `f32` sum; the portable path
//! and [`Conv3x3::reference_bf16`] agree bit for bit, a CPU's instruction within a rounding of
//! the sum per step. Against the `f32` [`Conv3x3::reference`] each input and weight is off by at
//! most `2^-8` of itself, so an output by at most `(2^-7 + 2^-16) Σ |w x|` besides the sums'
//! roundings (tested). Edges: as [`bf16::to_bf16`] (a subnormal reads as 0, a NaN stays a NaN and an
//! infinity an infinity, as in `f32`).

use neuspike_simd::bf16::{self, Bf16Path};
use neuspike_simd::dot::WordTaps;

use super::*;

/// Pairs of input channels of one block of taps (32 channels, as [`CHANNELS`] is for `f32`).
const PAIRS: usize = 16;

impl Conv3x3 {
    /// Pairs of input channels (the last one padded with a channel of weight 0).
    fn pairs(&self) -> usize {
        self.c_in.div_ceil(bf16::CHANNELS)
    }

    /// The weight of output channel `o`, input channel `c` (0 past `c_in`), tap `t`.
    fn tap_weight(&self, o: usize, c: usize, t: usize) -> f32 {
        if c < self.c_in {
            self.weight(o, c, t / 3, t % 3)
        } else {
            0.0
        }
    }

    /// The weights in `bf16` as [`bf16::accumulate`] reads them: `[c_out / 4][pairs][9][4]`
    /// words of two channels.
    pub(super) fn bf16_weights(&self) -> Vec<u32> {
        let pairs = self.pairs();
        let mut words = vec![0u32; self.c_out * pairs * TAPS];
        for o in 0..self.c_out {
            let (g, lane) = (o / OUTS, o % OUTS);
            for p in 0..pairs {
                for t in 0..TAPS {
                    let c = p * bf16::CHANNELS;
                    words[((g * pairs + p) * TAPS + t) * OUTS + lane] =
                        bf16::pair(self.tap_weight(o, c, t), self.tap_weight(o, c + 1, t));
                }
            }
        }
        words
    }

    /// The `bf16` definition ([`Precision::Bf16`], see [`bf16`](self)) on `input` (`[C, H,
    /// W]`), whatever [`precision`](Self::precision) says, in plain loops.
    pub fn reference_bf16(&self, input: ArrayView3<f32>) -> Result<Array3<f32>, Conv3x3Error> {
        let (_, h, w) = input.dim();
        let (ho, wo) = (self.out_len(h), self.out_len(w));
        self.check(input.shape(), self.c_out * ho * wo)?;
        let value = |c: usize, y: isize, x: isize| -> f32 {
            if c >= self.c_in || y < 0 || x < 0 || y >= h as isize || x >= w as isize {
                0.0
            } else {
                input[[c, y as usize, x as usize]]
            }
        };
        let s = self.stride as isize;
        Ok(Array3::from_shape_fn((self.c_out, ho, wo), |(o, y, x)| {
            let mut sum = self.bias[o];
            for p in 0..self.pairs() {
                let c = p * bf16::CHANNELS;
                for t in 0..TAPS {
                    let (iy, ix) = (
                        y as isize * s + (t / 3) as isize - 1,
                        x as isize * s + (t % 3) as isize - 1,
                    );
                    let v = bf16::pair(value(c, iy, ix), value(c + 1, iy, ix));
                    let k = bf16::pair(self.tap_weight(o, c, t), self.tap_weight(o, c + 1, t));
                    sum = bf16::step(sum, v, k);
                }
            }
            if self.relu { sum.max(0.0) } else { sum }
        }))
    }

    /// [`drive`](Self::drive) in `bf16`: the output rows in bands across `pool`.
    pub(super) fn drive_bf16(
        &self,
        isa: neuspike_simd::Isa,
        path: Bf16Path,
        input: Input,
        (h, w): (usize, usize),
        output: &mut [f32],
        pool: Option<&rayon::ThreadPool>,
    ) {
        let (ho, wo) = (self.out_len(h), self.out_len(w));
        let rows = crate::bands::band_rows(ho, pool);
        let tasks = crate::bands::row_bands(output, ho * wo, wo, rows);
        let band = |(y0, mut planes): (usize, Vec<&mut [f32]>)| {
            BUFFERS16.with_borrow_mut(|buffers| {
                neuspike_simd::with_isa(
                    isa,
                    #[inline(always)]
                    || match self.stride {
                        1 => self.band16::<1>(path, input, (h, w), y0, &mut planes, buffers),
                        _ => self.band16::<2>(path, input, (h, w), y0, &mut planes, buffers),
                    },
                )
            })
        };
        crate::bands::for_each(tasks, pool, band);
    }

    /// [`band`](Self::band) in `bf16`: each input row read is converted, two channels to a
    /// word, into `S` rows of `len` words, three input rows kept in a ring.
    #[inline(always)]
    fn band16<const S: usize>(
        &self,
        path: Bf16Path,
        input: Input,
        (h, w): (usize, usize),
        y0: usize,
        planes: &mut [&mut [f32]],
        buffers: &mut Buffers16,
    ) {
        let wo = self.out_len(w);
        let wv = wo.div_ceil(POINTS) * POINTS;
        let len = wv + POINTS;
        let pairs = self.pairs();
        let Buffers16 {
            scratch,
            words,
            out,
            offsets,
        } = buffers;
        out.resize(self.c_out * wv, 0.0);
        // `[pairs][3 slots][S][len]`; every slot is written before it is read.
        let pair_rows = S * len;
        let scratch = aligned(scratch, pairs * 3 * pair_rows);
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
                for p in 0..pairs {
                    // A plain `match`, not a closure: a closure may be compiled out of line,
                    // for the baseline instruction set.
                    let src = match inside {
                        Some(iy) => {
                            let c = p * bf16::CHANNELS;
                            let a = input.row(c, iy, h);
                            words.resize(a.len(), 0);
                            if c + 1 < self.c_in {
                                let b = input.row(c + 1, iy, h);
                                for ((d, &a), &b) in words.iter_mut().zip(a).zip(b) {
                                    *d = bf16::pair(a, b);
                                }
                            } else {
                                for (d, &a) in words.iter_mut().zip(a) {
                                    *d = bf16::pair(a, 0.0);
                                }
                            }
                            Some(&words[..])
                        }
                        None => None,
                    };
                    let dst = &mut scratch[(p * 3 + *slot) * pair_rows..][..pair_rows];
                    Self::padded::<S, u32>(src, w, dst, 0);
                }
                held[*slot] = Some(iy);
            }
            for (row, &bias) in out.chunks_exact_mut(wv).zip(&self.bias) {
                row.fill(bias);
            }
            for p0 in (0..pairs).step_by(PAIRS) {
                offsets.clear();
                for p in p0..(p0 + PAIRS).min(pairs) {
                    for slot in slots {
                        let at = (p * 3 + slot) * pair_rows;
                        offsets.extend(Self::taps::<S>(at, len));
                    }
                }
                let taps = WordTaps {
                    rows: scratch,
                    offsets,
                    weights: &self.bf16[p0 * TAPS * OUTS..],
                    group_stride: pairs * TAPS * OUTS,
                };
                bf16::accumulate(path, &taps, out, wv, self.c_out / OUTS, wv);
            }
            for (o, plane) in planes.iter_mut().enumerate() {
                self.put(&mut plane[(y - y0) * wo..][..wo], &out[o * wv..][..wo]);
            }
        }
    }
}

/// The working rows of [`Conv3x3::band16`], kept per thread from one band to the next.
#[derive(Default)]
struct Buffers16 {
    /// Input rows in `bf16`, padded for the taps, `[pairs][3 slots][S][len]` words.
    scratch: Vec<u32>,
    /// One input row of two channels, a word a point.
    words: Vec<u32>,
    /// One output row of every channel, `[O][wv]` sums.
    out: Vec<f32>,
    /// The offsets of one block's tap rows in the scratch rows.
    offsets: Vec<usize>,
}

thread_local! {
    static BUFFERS16: std::cell::RefCell<Buffers16> = std::cell::RefCell::default();
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{conv, layer_input as input, runs_give};

    /// The portable path gives the definition's bits at every thread count; every other path
    /// this CPU has comes within a rounding of the sum per step (`9 C` steps, each off by at
    /// most half an `f32` step of a partial sum, bounded by `Σ |w x| + |b|`).
    fn check(c_in: usize, c_out: usize, stride: usize, (h, w): (usize, usize), seed: u32) {
        let base = conv(c_in, c_out, stride, seed);
        let base = if seed % 2 == 1 {
            base.with_relu()
        } else {
            base
        };
        let x = input(c_in * h * w, seed + 2, seed);
        let view = ArrayView3::from_shape((c_in, h, w), &x).unwrap();
        let want = base.reference_bf16(view).unwrap();
        let portable = base
            .clone()
            .with_precision(Precision::Bf16(Bf16Path::Portable));
        let what = format!("{c_in}->{c_out} at {h}x{w}, stride {stride}");
        runs_give(&portable, &x, (h, w), want.as_slice().unwrap(), &what);
        let size = magnitudes(&base, view);
        let steps = (9 * c_in.div_ceil(2) * 2) as f32;
        for path in Bf16Path::ALL.into_iter().filter(|p| p.is_supported()) {
            let conv = base.clone().with_precision(Precision::Bf16(path));
            let mut got = vec![f32::NAN; want.len()];
            conv.run(&x, (h, w), &mut got, None).unwrap();
            for ((g, w), s) in got.iter().zip(want.iter()).zip(size.iter()) {
                let bound = steps * f32::EPSILON * s;
                assert!((g - w).abs() <= bound, "{what}, {path:?}: {g} for {w}");
            }
        }
    }

    /// Per output, `Σ |w x| + |b|` over its taps (0 off the image).
    fn magnitudes(conv: &Conv3x3, x: ArrayView3<f32>) -> Array3<f32> {
        let abs = conv.clone();
        let packed = abs.packed.iter().map(|v| v.abs()).collect();
        let bias = abs.bias.iter().map(|v| v.abs()).collect();
        let abs = Conv3x3 {
            packed,
            bias,
            relu: false,
            ..abs
        };
        abs.reference(x.mapv(f32::abs).view()).unwrap()
    }

    #[test]
    fn matches_the_bf16_definition_at_the_networks_sizes() {
        for (seed, &(c_in, c_out, stride, hw)) in (1..).zip(&crate::testing::NETWORK_LAYERS) {
            check(c_in, c_out, stride, hw, seed);
        }
        // Odd input channels: the last pair is half padding.
        check(5, 8, 1, (7, 33), 6);
        check(3, 4, 2, (7, 33), 7);
    }

    #[test]
    fn stays_within_its_stated_error_of_the_f32_definition() {
        for (seed, (c_in, c_out, stride)) in
            [(32, 8, 1), (8, 16, 1), (16, 32, 2), (64, 64, 1), (5, 4, 2)]
                .into_iter()
                .enumerate()
        {
            let (h, w) = (12, 40);
            let conv = conv(c_in, c_out, stride, seed as u32);
            let x = input(c_in * h * w, seed as u32 + 2, seed as u32);
            let view = ArrayView3::from_shape((c_in, h, w), &x).unwrap();
            let exact = conv.reference(view).unwrap();
            let got = conv.reference_bf16(view).unwrap();
            let size = magnitudes(&conv, view);
            let steps = (9 * c_in.div_ceil(2) * 2) as f32;
            for ((a, b), s) in exact.iter().zip(got.iter()).zip(size.iter()) {
                let bound = s * (2f32.powi(-7) + 2f32.powi(-16) + 2.0 * steps * f32::EPSILON);
                assert!(
                    (a - b).abs() <= bound,
                    "{c_in}->{c_out}: {b} for {a}, bound {bound}"
                );
            }
        }
    }

    #[test]
    fn parts_and_edge_padding_give_the_bf16_definitions_bits() {
        for stride in [1, 2] {
            let conv = conv(8, 8, stride, 4)
                .with_relu()
                .with_precision(Precision::Bf16(Bf16Path::Portable));
            crate::testing::parts_and_edge_give(&conv, |c, x| c.reference_bf16(x).unwrap());
        }
    }

    #[test]
    fn non_finite_inputs_stay_as_in_f32() {
        // An infinity gives infinities and NaNs where it reaches, as in `f32`; elsewhere finite.
        let conv = conv(8, 8, 1, 3).with_precision(Precision::bf16());
        let (h, w) = (5, 20);
        let mut x = input(8 * h * w, 4, 1);
        x[50] = f32::INFINITY;
        let mut got = vec![0.0; 8 * h * w];
        conv.run(&x, (h, w), &mut got, None).unwrap();
        let view = ArrayView3::from_shape((8, h, w), &x).unwrap();
        let exact = conv.reference(view).unwrap();
        for (g, e) in got.iter().zip(exact.iter()) {
            assert_eq!(g.is_finite(), e.is_finite(), "{g} against {e}");
        }
    }

    #[test]
    fn precisions_read_back_their_names() {
        for p in Bf16Path::ALL.into_iter().filter(|p| p.is_supported()) {
            let p = Precision::Bf16(p);
            assert_eq!(p.to_string().parse::<Precision>(), Ok(p));
        }
        assert_eq!("bf16".parse::<Precision>(), Ok(Precision::bf16()));
        assert!("bf16-amx".parse::<Precision>().is_err());
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(24))]
        #[test]
        fn matches_the_bf16_definition_anywhere(
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
