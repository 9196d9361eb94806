//! Bilinear samples of an image at arbitrary texels, with each instruction set's gather
//! instruction: the inner loop of rendering a turned or zoomed view.
//!
//! The compiler's vectoriser leaves a loop of loads at computed indices scalar (its cost model
//! judges gathers not worth it, and bounds checks stand in the way). [`bilinear`] loads 16
//! (AVX-512) or 8 (AVX2) texels per instruction. Indices are clamped to the image's last texel
//! in the vectors themselves, so no index can read outside it and no check runs before the loop.

use crate::Isa;

/// The inputs of [`bilinear`] for sample `j`: the four texels `texels[index[k][j]]` (`k` = top
/// left, top right, bottom left, bottom right) and the weights `weight[0][j]` of the right
/// column, `weight[1][j]` of the bottom row.
#[derive(Clone, Copy, Debug)]
pub struct Corners<'a> {
    /// The image the samples read.
    pub texels: &'a [f32],
    /// The four corners' indices into `texels`, one slice per corner.
    pub index: [&'a [u32]; 4],
    /// The right column's and the bottom row's weights.
    pub weight: [&'a [f32]; 2],
}

/// `out[j] = (a (1 - wx) + b wx) (1 - wy) + (c (1 - wx) + d wx) wy` for every sample `j`, with
/// `a, b, c, d` the four corners' texels and `wx, wy` the weights (see [`Corners`]), as separate
/// multiplies and adds in that order, so every instruction set gives the same bits. An index past
/// the image reads its last texel; an empty image gives 0.
///
/// Runs on `isa` or the widest instruction set below it this CPU has.
///
/// # Panics
/// If an index or weight slice is shorter than `out`.
pub fn bilinear(isa: Isa, corners: &Corners, out: &mut [f32]) {
    let n = out.len();
    assert!(
        corners.index.iter().all(|s| s.len() >= n) && corners.weight.iter().all(|s| s.len() >= n),
        "{n} samples from shorter corner lists"
    );
    let texels = corners.texels;
    if texels.is_empty() {
        out.fill(0.0);
        return;
    }
    // The gathers take signed 32-bit indices.
    let last = (texels.len() - 1).min(i32::MAX as usize) as u32;
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    {
        let args = x86::Args {
            texels: texels.as_ptr(),
            last,
            index: corners.index.map(<[u32]>::as_ptr),
            weight: corners.weight.map(<[f32]>::as_ptr),
            out: out.as_mut_ptr(),
        };
        match isa.min(crate::detect()) {
            // SAFETY: the CPU has AVX-512 F; every index is clamped to `last`, inside `texels`,
            // and every sample below `16 (n / 16) <= n` is inside the slices checked above.
            #[allow(unsafe_code)]
            Isa::Avx512 => {
                done = 16 * (n / 16);
                unsafe { x86::avx512(&args, n / 16) }
            }
            // SAFETY: as above, with AVX2 and 8 samples a vector.
            #[allow(unsafe_code)]
            Isa::Avx2 => {
                done = 8 * (n / 8);
                unsafe { x86::avx2(&args, n / 8) }
            }
            Isa::Baseline => {}
        }
    }
    let _ = isa;
    let texel = |k: usize, j: usize| texels[corners.index[k][j].min(last) as usize];
    for (j, o) in out.iter_mut().enumerate().skip(done) {
        let (wx1, wy1) = (corners.weight[0][j], corners.weight[1][j]);
        let wx0 = 1.0 - wx1;
        let top = texel(0, j) * wx0 + texel(1, j) * wx1;
        let bottom = texel(2, j) * wx0 + texel(3, j) * wx1;
        *o = top * (1.0 - wy1) + bottom * wy1;
    }
}

#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod x86 {
    use std::arch::x86_64::*;

    /// [`super::bilinear`]'s checked arguments as pointers.
    pub struct Args {
        pub texels: *const f32,
        pub last: u32,
        pub index: [*const u32; 4],
        pub weight: [*const f32; 2],
        pub out: *mut f32,
    }

    /// The first `16 vectors` samples.
    ///
    /// # Safety
    /// The CPU has AVX-512 F; `texels` holds `last + 1` values, and the index, weight and output
    /// slices at least `16 vectors`.
    #[target_feature(enable = "avx512f")]
    pub unsafe fn avx512(args: &Args, vectors: usize) {
        // SAFETY: every load and store is at a sample below `16 vectors`, and every gathered
        // index is clamped to `last`.
        unsafe {
            let last = _mm512_set1_epi32(args.last as i32);
            let one = _mm512_set1_ps(1.0);
            for v in 0..vectors {
                let j = 16 * v;
                let texel = |k: usize| {
                    let i = _mm512_loadu_si512(args.index[k].add(j).cast());
                    let i = _mm512_min_epu32(i, last);
                    _mm512_i32gather_ps::<4>(i, args.texels.cast())
                };
                let wx1 = _mm512_loadu_ps(args.weight[0].add(j));
                let wy1 = _mm512_loadu_ps(args.weight[1].add(j));
                let wx0 = _mm512_sub_ps(one, wx1);
                let top = _mm512_add_ps(_mm512_mul_ps(texel(0), wx0), _mm512_mul_ps(texel(1), wx1));
                let bottom =
                    _mm512_add_ps(_mm512_mul_ps(texel(2), wx0), _mm512_mul_ps(texel(3), wx1));
                let value = _mm512_add_ps(
                    _mm512_mul_ps(top, _mm512_sub_ps(one, wy1)),
                    _mm512_mul_ps(bottom, wy1),
                );
                _mm512_storeu_ps(args.out.add(j), value);
            }
        }
    }

    /// The first `8 vectors` samples.
    ///
    /// # Safety
    /// As [`avx512`], with AVX2 and 8 samples a vector.
    #[target_feature(enable = "avx2")]
    pub unsafe fn avx2(args: &Args, vectors: usize) {
        // SAFETY: as in `avx512`.
        unsafe {
            let last = _mm256_set1_epi32(args.last as i32);
            let one = _mm256_set1_ps(1.0);
            for v in 0..vectors {
                let j = 8 * v;
                let texel = |k: usize| {
                    let i = _mm256_loadu_si256(args.index[k].add(j).cast());
                    let i = _mm256_min_epu32(i, last);
                    _mm256_i32gather_ps::<4>(args.texels, i)
                };
                let wx1 = _mm256_loadu_ps(args.weight[0].add(j));
                let wy1 = _mm256_loadu_ps(args.weight[1].add(j));
                let wx0 = _mm256_sub_ps(one, wx1);
                let top = _mm256_add_ps(_mm256_mul_ps(texel(0), wx0), _mm256_mul_ps(texel(1), wx1));
                let bottom =
                    _mm256_add_ps(_mm256_mul_ps(texel(2), wx0), _mm256_mul_ps(texel(3), wx1));
                let value = _mm256_add_ps(
                    _mm256_mul_ps(top, _mm256_sub_ps(one, wy1)),
                    _mm256_mul_ps(bottom, wy1),
                );
                _mm256_storeu_ps(args.out.add(j), value);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic spread of values in `[0, 1)`.
    fn values(n: usize, seed: u32) -> Vec<f32> {
        (0..n as u32)
            .map(|i| {
                let h = (i ^ seed.wrapping_mul(0x9E37_79B9)).wrapping_mul(0x85EB_CA6B);
                (h >> 8) as f32 / (1u32 << 24) as f32
            })
            .collect()
    }

    #[test]
    fn every_isa_gives_the_scalar_bits_clamping_indices_past_the_image() {
        let texels = values(1000, 7);
        for n in [0, 1, 7, 8, 15, 16, 17, 40, 333] {
            // Some indices past the image: they read its last texel.
            let index: [Vec<u32>; 4] = std::array::from_fn(|k| {
                (0..n as u32)
                    .map(|j| (j * 97 + k as u32 * 13) % 1100)
                    .collect()
            });
            let weight: [Vec<f32>; 2] = std::array::from_fn(|k| values(n, 11 + k as u32));
            let corners = Corners {
                texels: &texels,
                index: std::array::from_fn(|k| &index[k][..]),
                weight: [&weight[0], &weight[1]],
            };
            let want: Vec<f32> = (0..n)
                .map(|j| {
                    let t = |k: usize| texels[(index[k][j] as usize).min(999)];
                    let (wx, wy) = (weight[0][j], weight[1][j]);
                    (t(0) * (1.0 - wx) + t(1) * wx) * (1.0 - wy)
                        + (t(2) * (1.0 - wx) + t(3) * wx) * wy
                })
                .collect();
            for isa in Isa::ALL {
                let mut out = vec![f32::NAN; n];
                bilinear(isa, &corners, &mut out);
                let same = out
                    .iter()
                    .zip(&want)
                    .all(|(a, b)| a.to_bits() == b.to_bits());
                assert!(same, "{} with {n} samples", isa.name());
            }
        }
    }

    #[test]
    fn an_empty_image_gives_zeros() {
        let index = [0u32, 5];
        let weight = [0.5f32, 0.5];
        let corners = Corners {
            texels: &[],
            index: [&index; 4],
            weight: [&weight; 2],
        };
        let mut out = [1.0f32; 2];
        bilinear(Isa::Avx512, &corners, &mut out);
        assert_eq!(out, [0.0, 0.0]);
    }

    #[test]
    #[should_panic(expected = "shorter corner lists")]
    fn short_corner_lists_are_refused() {
        let corners = Corners {
            texels: &[1.0; 4],
            index: [&[0u32; 3]; 4],
            weight: [&[0.0f32; 4]; 2],
        };
        bilinear(Isa::Avx2, &corners, &mut [0.0; 4]);
    }
}
