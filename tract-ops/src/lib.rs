//! neuspike's operators for tract, and the rewrites that put them in a decluttered model: where
//! the networks' time goes, computed by kernels written for it and split across tract's pool.
//!
//! | module | operator | replaces |
//! |---|---|---|
//! | [`conv3x3`] | 3x3 convolution, pad 1, stride 1 or 2, its ReLU and a preceding channel concatenation taken in; an input's first convolution run on the input where it lies, its edge padding read in place; in `f32`, `bf16` ([`conv3x3::bf16`]) or 8 bits ([`conv3x3::int8`]) | tract's direct convolution, or im2col and a matrix product |
//! | [`deconv2x2`] | 2x2 stride-2 transposed convolution and its ReLU | a matrix product and a one-thread scatter (`DeconvSum`) |
//! | [`depthwise`] | the networks' last layers: 3x3 depthwise convolution, 1x1 convolution and sigmoid, in one pass | a one-thread depthwise convolution, a packing and a matrix product |
//! | [`subpixel`] | the last layers of a network whose decoder stops at half resolution: the sub-pixel shuffle of its output, the 1x1 convolutions of the head features added to it, and the sigmoid, in one pass | a four-step shuffle, a packing and a matrix product per head, a sum and a sigmoid |
//! | [`attention`] | NeuSpike-Net's spatial attention (Eq. 12) and the channel attention's scaled sums (Eq. 11) | some twenty one-thread passes |
//! | [`bands`] | the split of output rows across tract's pool that every operator uses | |
//!
//! Every operator has a scalar reference whose operations it takes in the same order, so the two
//! agree bit for bit on every instruction set and thread count (tested; in 8 bits, the 8-bit
//! definition, itself tested against the `f32` one within a stated error), and a test against
//! tract's own operator on the same weights. The inner loop of the convolutions is
//! `neuspike_simd::taps` (`neuspike_simd::dot` in 8 bits). `docs/tract-operators.md` sets out the two generic operators, the 3x3
//! convolution and the 2x2 transposed convolution, for tract's maintainers.
#![deny(missing_docs)]

pub mod attention;
pub mod bands;
pub mod conv3x3;
pub mod deconv2x2;
pub mod depthwise;
mod matching;
pub mod subpixel;
#[cfg(test)]
mod testing;

use ndarray::ArrayView3;

/// `x` (`[C, H, W]`) padded to `[C, hp, wp]` by repeating its last row and column, row-major.
pub fn pad_edge(x: ArrayView3<f32>, hp: usize, wp: usize) -> Vec<f32> {
    let mut out = vec![0.0; x.dim().0 * hp * wp];
    pad_edge_into(x, hp, wp, &mut out);
    out
}

/// [`pad_edge`] into `dst` (`C * hp * wp` values, `hp >= H`, `wp >= W`, as the caller
/// guarantees; a shorter `dst` is filled as far as it goes).
pub fn pad_edge_into(x: ArrayView3<f32>, hp: usize, wp: usize, dst: &mut [f32]) {
    let (c, h, w) = x.dim();
    let mut rows = dst.chunks_exact_mut(wp.max(1));
    for ch in 0..c {
        for y in 0..hp {
            let Some(out) = rows.next() else { return };
            let row = x.slice(ndarray::s![ch, y.min(h.saturating_sub(1)), ..]);
            let (body, pad) = out.split_at_mut(w.min(wp));
            match row.as_slice() {
                Some(r) => body.copy_from_slice(&r[..body.len()]),
                None => body.iter_mut().zip(row.iter()).for_each(|(d, &v)| *d = v),
            }
            pad.fill(row.last().copied().unwrap_or(0.0));
        }
    }
}
