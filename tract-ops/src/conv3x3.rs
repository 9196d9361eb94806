//! The 3x3 convolution of the learned networks (padding 1, stride 1 or 2, no groups),
//! register-blocked, and the tract operator that runs it in place of tract's own.
//!
//! Most of a NeuSpike-Net's time goes to 3x3 convolutions, the longest at full and half
//! resolution (the encoders' heads and first layers, the decoder's last merges). There tract
//! either copies the input 9 times (im2col) for a matrix product, or runs its direct convolution,
//! which walks an offset table per tap. [`Conv3x3`] copies every input row it reads once per
//! channel into a scratch row padded with the zeros off the image (stride 2: its even and its odd
//! columns apart), so each of the 9 taps of a run of output points is one run of memory at a
//! fixed offset. The three input rows of an output row are kept in a ring, so going down a row
//! copies only the new ones. [`neuspike_simd::taps::accumulate`] then holds 4 output channels
//! by 24 (AVX2) or 96 (AVX-512) points in registers, 12 or 24 accumulators, through the taps of
//! 8 input channels at a time, the partial sums waiting in an output row between blocks. Output
//! rows are split in bands across tract's thread pool.
//!
//! A row is computed in whole vectors, so 50 points would cost 64: at stride 1, rows narrower
//! than 128 points are copied a few at a time one after the other into one scratch plane (each
//! with a zero on either side) and computed as one run of points, 2 of every `w + 2` wasted
//! (`Conv3x3::band_flat`). [`use_conv3x3`] takes over rows of at least [`MIN_WIDTH`] points,
//! where it is faster than tract's matrix product.
//!
//! [`Conv3x3::reference`] is the scalar definition; the fast path takes the same fused
//! multiply-adds in the same order (bias, then input channel, kernel row, kernel column), so the
//! two agree exactly on every instruction set.

use std::sync::Arc;

use ndarray::{Array3, ArrayView3, ArrayView4};
use neuspike_simd::bf16::Bf16Path;
use neuspike_simd::dot::DotPath;
use neuspike_simd::taps::{self, POINTS, Taps};

pub mod bf16;
mod binary;
pub mod events;
pub mod int8;
use tract_onnx::prelude::*;
use tract_onnx::tract_core::internal::*;

/// Output channels one block keeps in registers.
const OUTS: usize = taps::OUTS;
/// Taps of the kernel.
const TAPS: usize = 9;
/// Input channels of one block.
const CHANNELS: usize = 8;
/// Output rows narrower than this (stride 1) are computed a few rows at a time as one run of
/// points (`Conv3x3::band_flat`), wider ones row by row. At 200 (8 of 208 points wasted row by
/// row) the two were level in `bench-model --profile`.
pub const FLAT_BELOW: usize = 128;
/// Values of the scratch planes of [`Conv3x3::band_flat`] (256 KB: they stay in the L2 cache
/// beside the partial sums).
const FLAT_SCRATCH: usize = 1 << 16;

/// A 3x3, padding-1 convolution of stride 1 or 2 with its weights packed for the kernel.
#[derive(Clone, Debug)]
pub struct Conv3x3 {
    c_in: usize,
    c_out: usize,
    stride: usize,
    /// `[c_out / 4][c_in][9][4]`: for a group of four output channels, an input channel and a tap,
    /// the four weights side by side.
    packed: Vec<f32>,
    /// `[c_out][9][quads * 4]`: for an output channel and a tap, the weights of every input
    /// channel side by side, channels past `c_in` 0 (what [`int8`] quantises each call).
    by_tap: Vec<f32>,
    /// The weights in `bf16` as [`bf16`] reads them (empty unless the precision is
    /// [`Precision::Bf16`]).
    bf16: Vec<u32>,
    bias: Vec<f32>,
    /// Whether the output goes through `max(0, y)` (a ReLU after the convolution).
    relu: bool,
    /// How it computes.
    precision: Precision,
    /// The tables [`Conv3x3::run_edge_padded_bits`] reads its binary channels with, made at its
    /// first call.
    binary: std::sync::OnceLock<binary::Tables>,
}

/// How a [`Conv3x3`] computes: in `f32` (the reference every other precision is tested
/// against), in `bf16` ([`bf16`]: inputs and weights rounded to 8 significant bits, sums in
/// `f32`), or in 8 bits ([`int8`]: each frame's input quantised per channel, the weights per
/// output channel, sums in 32-bit integers).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Precision {
    /// `f32` fused multiply-adds.
    #[default]
    F32,
    /// `bf16` inputs by `bf16` weights, summed in `f32`, on the [`Bf16Path`] named.
    Bf16(Bf16Path),
    /// Unsigned 8-bit inputs by signed 8-bit weights, on the [`DotPath`] named.
    Int8(DotPath),
}

impl Precision {
    /// 8 bits on the widest path this CPU has.
    pub fn int8() -> Precision {
        Precision::Int8(neuspike_simd::dot::detect())
    }

    /// `bf16` on the widest path this CPU has.
    pub fn bf16() -> Precision {
        Precision::Bf16(neuspike_simd::bf16::detect())
    }
}

/// The name [`Precision`]'s `FromStr` reads back: `f32`, `bf16-<path>` (`bf16-avx512`, ...)
/// or `int8-<path>` (`int8-amx`, ...).
impl std::fmt::Display for Precision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Precision::F32 => f.write_str("f32"),
            Precision::Bf16(path) => write!(f, "bf16-{}", path.name()),
            Precision::Int8(path) => write!(f, "int8-{}", path.name()),
        }
    }
}

/// `f32`; `bf16` or `int8`, the widest such path this CPU has ([`Precision::bf16`],
/// [`Precision::int8`]); or a path by name, `bf16-portable`, `bf16-avx512`, `int8-portable`,
/// `int8-vnni` or `int8-amx`, refused where this CPU does not run it.
impl std::str::FromStr for Precision {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "f32" => return Ok(Precision::F32),
            "bf16" => return Ok(Precision::bf16()),
            "int8" => return Ok(Precision::int8()),
            _ => {}
        }
        let unknown = || {
            format!(
                "precision `{s}`: expected f32, bf16, bf16-portable, bf16-avx512, int8, \
                 int8-portable, int8-vnni or int8-amx"
            )
        };
        let missing = |name: &str| format!("precision `{s}`: this CPU has no {name}");
        if let Some(name) = s.strip_prefix("bf16-") {
            let path = Bf16Path::ALL
                .into_iter()
                .find(|p| p.name() == name)
                .ok_or_else(unknown)?;
            return match path.is_supported() {
                true => Ok(Precision::Bf16(path)),
                false => Err(missing("AVX-512 BF16")),
            };
        }
        let path = s
            .strip_prefix("int8-")
            .and_then(|name| DotPath::ALL.into_iter().find(|p| p.name() == name))
            .ok_or_else(unknown)?;
        if !path.is_supported() {
            return Err(missing(path.name()));
        }
        Ok(Precision::Int8(path))
    }
}

/// Why a convolution cannot be a [`Conv3x3`].
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum Conv3x3Error {
    /// The weights are not `[O, C, 3, 3]`.
    #[error("weights of shape {0:?}, not [O, C, 3, 3]")]
    Weights(Vec<usize>),
    /// The output channels are not a multiple of four.
    #[error("{0} output channels, not a multiple of 4")]
    Channels(usize),
    /// The stride is neither 1 nor 2.
    #[error("stride {0}, not 1 or 2")]
    Stride(usize),
    /// The bias has neither one value per output channel nor a single one.
    #[error("a bias of {got} values for {channels} output channels")]
    Bias {
        /// Values in the bias.
        got: usize,
        /// Output channels.
        channels: usize,
    },
    /// More input channels than an 8-bit convolution's sums hold ([`int8::MAX_CHANNELS`]).
    #[error("{0} input channels, more than the {max} an 8-bit convolution takes", max = int8::MAX_CHANNELS)]
    Int8Channels(usize),
    /// An event or instant that event integration does not take
    /// ([`Conv3x3::run_edge_padded_events`]).
    #[error("events: {0}")]
    Events(String),
    /// The input is not `[C, H, W]` with the weights' `C`, or the output does not fit it.
    #[error("input {input:?} and output of {output} values for a {c_in}-to-{c_out} convolution")]
    Shape {
        /// The input's shape.
        input: Vec<usize>,
        /// The output's length.
        output: usize,
        /// Input channels of the weights.
        c_in: usize,
        /// Output channels of the weights.
        c_out: usize,
    },
}

impl Conv3x3 {
    /// Packs `weights` (`[O, C, 3, 3]`, ONNX's layout) and `bias` (`O` values, or one for all)
    /// for a convolution of `stride` (1 or 2, both axes).
    pub fn new(
        weights: ArrayView4<f32>,
        bias: &[f32],
        stride: usize,
    ) -> Result<Conv3x3, Conv3x3Error> {
        let (c_out, c_in, kh, kw) = weights.dim();
        if (kh, kw) != (3, 3) || c_in == 0 || c_out == 0 {
            return Err(Conv3x3Error::Weights(weights.shape().to_vec()));
        }
        if !c_out.is_multiple_of(OUTS) {
            return Err(Conv3x3Error::Channels(c_out));
        }
        if !(1..=2).contains(&stride) {
            return Err(Conv3x3Error::Stride(stride));
        }
        let bias = match bias.len() {
            n if n == c_out => bias.to_vec(),
            1 => vec![bias[0]; c_out],
            got => {
                return Err(Conv3x3Error::Bias {
                    got,
                    channels: c_out,
                });
            }
        };
        let mut packed = Vec::with_capacity(c_out * c_in * TAPS);
        for g in 0..c_out / OUTS {
            for c in 0..c_in {
                for ky in 0..3 {
                    for kx in 0..3 {
                        packed.extend((0..OUTS).map(|o| weights[[g * OUTS + o, c, ky, kx]]));
                    }
                }
            }
        }
        let c_pad = c_in.div_ceil(neuspike_simd::dot::CHANNELS) * neuspike_simd::dot::CHANNELS;
        let mut by_tap = vec![0f32; c_out * TAPS * c_pad];
        for ((o, ky, kx), row) in ndarray::indices((c_out, 3, 3))
            .into_iter()
            .zip(by_tap.chunks_exact_mut(c_pad))
        {
            for (c, v) in row.iter_mut().take(c_in).enumerate() {
                *v = weights[[o, c, ky, kx]];
            }
        }
        Ok(Conv3x3 {
            c_in,
            c_out,
            stride,
            packed,
            by_tap,
            bf16: Vec::new(),
            bias,
            relu: false,
            precision: Precision::F32,
            binary: std::sync::OnceLock::new(),
        })
    }

    /// The same convolution followed by a ReLU, `y.max(0.0)` (0 for NaN, as tract's `Max`).
    pub fn with_relu(self) -> Conv3x3 {
        Conv3x3 { relu: true, ..self }
    }

    /// The same convolution computed in `precision`.
    pub fn with_precision(self, precision: Precision) -> Conv3x3 {
        let bf16 = match precision {
            Precision::Bf16(_) => self.bf16_weights(),
            _ => Vec::new(),
        };
        Conv3x3 {
            precision,
            bf16,
            ..self
        }
    }

    /// How it computes.
    pub fn precision(&self) -> Precision {
        self.precision
    }

    /// Whether a ReLU follows the convolution.
    pub fn relu(&self) -> bool {
        self.relu
    }

    /// Input channels.
    pub fn c_in(&self) -> usize {
        self.c_in
    }

    /// Output channels.
    pub fn c_out(&self) -> usize {
        self.c_out
    }

    /// The stride (1 or 2).
    pub fn stride(&self) -> usize {
        self.stride
    }

    /// Output rows (or columns) for `n` input ones: `(n - 1) / stride + 1`, 0 for 0.
    pub fn out_len(&self, n: usize) -> usize {
        if n == 0 { 0 } else { (n - 1) / self.stride + 1 }
    }

    /// The weight of output channel `o`, input channel `c`, tap `(ky, kx)`.
    fn weight(&self, o: usize, c: usize, ky: usize, kx: usize) -> f32 {
        let g = o / OUTS;
        self.packed[((g * self.c_in + c) * TAPS + ky * 3 + kx) * OUTS + o % OUTS]
    }

    fn check(&self, input: &[usize], output: usize) -> Result<(), Conv3x3Error> {
        if matches!(self.precision, Precision::Int8(_)) {
            self.check_int8()?;
        }
        match *input {
            [c, h, w]
                if c == self.c_in && output == self.c_out * self.out_len(h) * self.out_len(w) =>
            {
                Ok(())
            }
            _ => Err(Conv3x3Error::Shape {
                input: input.to_vec(),
                output,
                c_in: self.c_in,
                c_out: self.c_out,
            }),
        }
    }

    /// The same convolution as a one-node tract model of tract's own operator, input
    /// `[1, C, h, w]` (tests and benchmarks compare the two).
    pub fn tract_model(&self, h: usize, w: usize) -> TractResult<TypedModel> {
        use tract_onnx::tract_core::ops::cnn::{Conv, KernelFormat, PaddingSpec, PoolSpec};
        use tract_onnx::tract_core::ops::nn::DataFormat;
        let (c, o) = (self.c_in, self.c_out);
        let weights: Vec<f32> = (0..o * c * TAPS)
            .map(|i| self.weight(i / (c * TAPS), i / TAPS % c, i % TAPS / 3, i % 3))
            .collect();
        let mut model = TypedModel::default();
        let x = model.add_source("x", f32::fact([1, c, h, w]))?;
        let k = model.add_const("k", Tensor::from_shape(&[o, c, 3, 3], &weights)?)?;
        let b = model.add_const("b", Tensor::from_shape(&[o], &self.bias)?)?;
        let conv = Conv {
            pool_spec: PoolSpec {
                data_format: DataFormat::NCHW,
                kernel_shape: tvec![3, 3],
                padding: PaddingSpec::Explicit(tvec![1, 1], tvec![1, 1]),
                dilations: None,
                strides: Some(tvec![self.stride, self.stride]),
                input_channels: c,
                output_channels: o,
            },
            kernel_fmt: KernelFormat::OIHW,
            group: 1,
            q_params: None,
        };
        let mut y = model.wire_node("conv", conv, &[x, k, b])?;
        if self.relu {
            let zero = model.add_const("zero", tensor4(&[[[[0f32]]]]))?;
            let relu = tract_onnx::tract_core::ops::math::max();
            y = model.wire_node("relu", relu, &[y[0], zero])?;
        }
        model.select_output_outlets(&y)?;
        Ok(model)
    }

    /// The scalar definition: `[O, (H - 1) / s + 1, (W - 1) / s + 1]` from `[C, H, W]`, each
    /// output the bias then, input channel by channel, kernel row by row, column by column, one
    /// fused multiply-add per tap (a tap off the image reads 0).
    pub fn reference(&self, input: ArrayView3<f32>) -> Result<Array3<f32>, Conv3x3Error> {
        let (_, h, w) = input.dim();
        let (ho, wo) = (self.out_len(h), self.out_len(w));
        self.check(input.shape(), self.c_out * ho * wo)?;
        let at = |c: usize, y: isize, x: isize| -> f32 {
            if y < 0 || x < 0 || y >= h as isize || x >= w as isize {
                0.0
            } else {
                input[[c, y as usize, x as usize]]
            }
        };
        let s = self.stride as isize;
        Ok(Array3::from_shape_fn((self.c_out, ho, wo), |(o, y, x)| {
            let mut acc = self.bias[o];
            for c in 0..self.c_in {
                for ky in 0..3 {
                    for kx in 0..3 {
                        let v = at(
                            c,
                            y as isize * s + ky as isize - 1,
                            x as isize * s + kx as isize - 1,
                        );
                        acc = self.weight(o, c, ky, kx).mul_add(v, acc);
                    }
                }
            }
            if self.relu { acc.max(0.0) } else { acc }
        }))
    }

    /// The convolution of `input` (`[C, H, W]`, row-major) into `output` (`[O, H', W']`, see
    /// [`out_len`](Self::out_len)), output rows split across `pool` (or this thread when `None`).
    pub fn run(
        &self,
        input: &[f32],
        hw: (usize, usize),
        output: &mut [f32],
        pool: Option<&rayon::ThreadPool>,
    ) -> Result<(), Conv3x3Error> {
        self.run_on(neuspike_simd::detect(), input, hw, output, pool)
    }

    /// [`run`](Self::run) compiled for `isa` (or the widest below it this CPU has).
    pub fn run_on(
        &self,
        isa: neuspike_simd::Isa,
        input: &[f32],
        (h, w): (usize, usize),
        output: &mut [f32],
        pool: Option<&rayon::ThreadPool>,
    ) -> Result<(), Conv3x3Error> {
        if input.len() != self.c_in * h * w {
            return Err(Conv3x3Error::Shape {
                input: vec![input.len()],
                output: output.len(),
                c_in: self.c_in,
                c_out: self.c_out,
            });
        }
        self.check(&[self.c_in, h, w], output.len())?;
        self.drive(isa, Input::Dense(input, w), (h, w), output, pool);
        Ok(())
    }

    /// The convolution of the channel concatenation of `parts` (each `(values, channels)`,
    /// `[channels, H, W]` row-major), without making the concatenation: each channel's rows are
    /// read from its part.
    ///
    /// # Errors
    /// [`Conv3x3Error::Shape`] when the parts' channels do not add up to the input channels, a
    /// part is not `channels * H * W` values, or `output` does not fit.
    pub fn run_concat(
        &self,
        parts: &[(&[f32], usize)],
        (h, w): (usize, usize),
        output: &mut [f32],
        pool: Option<&rayon::ThreadPool>,
    ) -> Result<(), Conv3x3Error> {
        let channels: usize = parts.iter().map(|p| p.1).sum();
        let sized = parts
            .iter()
            .all(|&(v, c)| Some(v.len()) == c.checked_mul(h).and_then(|n| n.checked_mul(w)));
        if channels != self.c_in || !sized {
            return Err(Conv3x3Error::Shape {
                input: parts.iter().map(|p| p.1).collect(),
                output: output.len(),
                c_in: self.c_in,
                c_out: self.c_out,
            });
        }
        self.check(&[self.c_in, h, w], output.len())?;
        self.drive(
            neuspike_simd::detect(),
            Input::Parts(parts, w),
            (h, w),
            output,
            pool,
        );
        Ok(())
    }

    /// The convolution of `input` (`[C, H, W]`, each row contiguous in memory) padded to
    /// `(hp, wp)` by repeating its last row and column ([`crate::pad_edge`]), without
    /// making the padded copy: each row is read where it lies. The output is `[O, H', W']` of
    /// the padded size.
    ///
    /// # Errors
    /// [`Conv3x3Error::Shape`] when `input` has other channels, is empty, is larger than
    /// `(hp, wp)`, has rows that are not contiguous, or `output` does not fit.
    pub fn run_edge_padded(
        &self,
        input: ArrayView3<f32>,
        (hp, wp): (usize, usize),
        output: &mut [f32],
        pool: Option<&rayon::ThreadPool>,
    ) -> Result<(), Conv3x3Error> {
        let (c, h, w) = input.dim();
        let shape_error = || Conv3x3Error::Shape {
            input: input.shape().to_vec(),
            output: output.len(),
            c_in: self.c_in,
            c_out: self.c_out,
        };
        let rows_contiguous = w <= 1 || input.strides()[2] == 1;
        if c != self.c_in || h == 0 || w == 0 || h > hp || w > wp || !rows_contiguous {
            return Err(shape_error());
        }
        self.check(&[self.c_in, hp, wp], output.len())?;
        self.drive(
            neuspike_simd::detect(),
            Input::Edge(input),
            (hp, wp),
            output,
            pool,
        );
        Ok(())
    }

    /// [`run_edge_padded`](Self::run_edge_padded) of the channel concatenation of `dense`
    /// (`[D, h, w]`, each row contiguous) and `planes` binary channels of `h x w` pixels given
    /// bit-packed in `bits` ([`packed_plane_bytes`]; bytes past the planes are not read): the
    /// spike representation's raw planes as the window holds them, without their `f32` copy
    /// (32 bits a pixel for one).
    ///
    /// At stride 1 on AVX-512, in any precision, the planes are read by table lookups
    /// ([`binary`]: for a tap and an output channel, the sum of four planes' weights is one of
    /// 16 values, looked up for 16 points at once): the `f32` convolution, up to the order of its
    /// sums, 72 lookups a point and output channel for 31 planes. Elsewhere, in 8 bits
    /// ([`Precision::Int8`]) the planes are read as bits: a binary channel's range is 0 to 1 when
    /// it has a set bit, so its levels are 0 and 255, its mean level a count of set bits, and the
    /// words of four such channels come from a table of 16; the result is the one
    /// [`run_edge_padded`](Self::run_edge_padded) gives on the planes unpacked to 0.0/1.0, bit
    /// for bit (tested). Other precisions unpack the planes and run that.
    ///
    /// # Errors
    /// As [`run_edge_padded`](Self::run_edge_padded) for the concatenation, and
    /// [`Conv3x3Error::Shape`] when `bits` holds fewer than `planes` planes.
    pub fn run_edge_padded_bits(
        &self,
        dense: ArrayView3<f32>,
        bits: &[u8],
        planes: usize,
        hw: (usize, usize),
        output: &mut [f32],
        pool: Option<&rayon::ThreadPool>,
    ) -> Result<(), Conv3x3Error> {
        self.run_edge_padded_bits_by(true, dense, bits, planes, hw, output, pool)
    }

    /// [`run_edge_padded_bits`](Self::run_edge_padded_bits) by tables where they run (`tables`,
    /// at stride 1 on AVX-512), or without them as on a CPU without AVX-512 (`!tables`: tests
    /// and benchmarks compare the two).
    #[doc(hidden)]
    #[allow(clippy::too_many_arguments)]
    pub fn run_edge_padded_bits_by(
        &self,
        tables: bool,
        dense: ArrayView3<f32>,
        bits: &[u8],
        planes: usize,
        (hp, wp): (usize, usize),
        output: &mut [f32],
        pool: Option<&rayon::ThreadPool>,
    ) -> Result<(), Conv3x3Error> {
        let (d, h, w) = dense.dim();
        let per = packed_plane_bytes(h, w);
        let shape_error = || Conv3x3Error::Shape {
            input: vec![d, planes, h, w, bits.len()],
            output: output.len(),
            c_in: self.c_in,
            c_out: self.c_out,
        };
        // (An empty view's strides are 0.)
        let rows_contiguous = d == 0 || w <= 1 || dense.strides()[2] == 1;
        let bits_held = planes.checked_mul(per).is_some_and(|n| n <= bits.len());
        if d + planes != self.c_in
            || h == 0
            || w == 0
            || h > hp
            || w > wp
            || !rows_contiguous
            || !bits_held
        {
            return Err(shape_error());
        }
        let isa = neuspike_simd::detect();
        if tables && self.stride == 1 && isa == neuspike_simd::Isa::Avx512 {
            self.check(&[self.c_in, hp, wp], output.len())?;
            let made = self.binary.get_or_init(|| binary::Tables::new(self, d));
            let other;
            let tables = if made.dense_channels() == d {
                made
            } else {
                other = binary::Tables::new(self, d);
                &other
            };
            return tables.run(isa, self.relu, dense, bits, planes, (hp, wp), output, pool);
        }
        if !matches!(self.precision, Precision::Int8(_)) {
            let all = unpacked(dense, bits, planes).ok_or_else(shape_error)?;
            return self.run_edge_padded(all.view(), (hp, wp), output, pool);
        }
        self.check(&[self.c_in, hp, wp], output.len())?;
        self.drive(
            neuspike_simd::detect(),
            // A view of this call's lifetime, as `bits`' (views are invariant in theirs).
            Input::Bits(dense.view(), &bits[..planes * per]),
            (hp, wp),
            output,
            pool,
        );
        Ok(())
    }

    /// Splits the output rows of `input` (of size `(h, w)`, checked) in bands across `pool`.
    fn drive(
        &self,
        isa: neuspike_simd::Isa,
        input: Input,
        (h, w): (usize, usize),
        output: &mut [f32],
        pool: Option<&rayon::ThreadPool>,
    ) {
        let (ho, wo) = (self.out_len(h), self.out_len(w));
        if ho == 0 || wo == 0 {
            return;
        }
        match self.precision {
            Precision::Int8(path) => {
                return self.drive_int8(isa, path, input, (h, w), output, pool);
            }
            Precision::Bf16(path) => {
                return self.drive_bf16(isa, path, input, (h, w), output, pool);
            }
            Precision::F32 => {}
        }
        let rows = crate::bands::band_rows(ho, pool);
        let tasks = crate::bands::row_bands(output, ho * wo, wo, rows);
        let band = |(y0, mut planes): (usize, Vec<&mut [f32]>)| {
            BUFFERS.with_borrow_mut(|buffers| {
                neuspike_simd::with_isa(
                    isa,
                    #[inline(always)]
                    || match self.stride {
                        1 if wo < FLAT_BELOW => {
                            self.band_flat(isa, input, (h, w), y0, &mut planes, buffers)
                        }
                        1 => self.band::<1>(isa, input, (h, w), y0, &mut planes, buffers),
                        _ => self.band::<2>(isa, input, (h, w), y0, &mut planes, buffers),
                    },
                )
            })
        };
        crate::bands::for_each(tasks, pool, band);
    }

    /// Output rows `y0..` of every plane in `planes` (each a band of whole rows), stride `S`.
    ///
    /// The kernel reads tap `(ky, kx)` of a row of output points as one run of memory: each
    /// input row it reads is copied, channel by channel, into `S` scratch rows of `len` values
    /// (see [`padded`](Self::padded)), where tap `kx` of point `x` lies at a fixed offset from `x`.
    /// Three input rows are kept (the slot of row `iy` is `iy mod 3`), so going down one output
    /// row copies only the `S` input rows it has not read yet.
    #[inline(always)]
    fn band<const S: usize>(
        &self,
        isa: neuspike_simd::Isa,
        input: Input,
        (h, w): (usize, usize),
        y0: usize,
        planes: &mut [&mut [f32]],
        buffers: &mut Buffers,
    ) {
        let wo = self.out_len(w);
        // Whole vectors of output points; a scratch row also holds the taps of the last point,
        // up to 2 past it, and keeps the next row on a 64-byte boundary.
        let wv = wo.div_ceil(POINTS) * POINTS;
        let len = wv + POINTS;
        let Buffers {
            scratch,
            out,
            offsets,
        } = buffers;
        out.resize(self.c_out * wv, 0.0);
        // `[C][3 slots][S][len]`; every slot is written before it is read.
        let scratch = aligned(scratch, self.c_in * 3 * S * len);
        let mut held: [Option<isize>; 3] = [None; 3];
        let n_rows = planes.first().map_or(0, |p| p.len() / wo);
        for y in y0..y0 + n_rows {
            let mut slots = [0; 3];
            for (ky, slot) in slots.iter_mut().enumerate() {
                let iy = (y * S + ky) as isize - 1;
                *slot = iy.rem_euclid(3) as usize;
                if held[*slot] != Some(iy) {
                    let inside = usize::try_from(iy).ok().filter(|&iy| iy < h);
                    for c in 0..self.c_in {
                        let src = inside.map(|iy| input.row(c, iy, h));
                        let rows = &mut scratch[(c * 3 + *slot) * S * len..][..S * len];
                        Self::padded::<S, f32>(src, w, rows, 0.0);
                    }
                    held[*slot] = Some(iy);
                }
            }
            for (row, &bias) in out.chunks_exact_mut(wv).zip(&self.bias) {
                row.fill(bias);
            }
            // Blocks of input channels, the partial sums waiting in `out` between blocks, so a
            // block's tap rows for the points in registers stay in the L1 cache.
            for c0 in (0..self.c_in).step_by(CHANNELS) {
                offsets.clear();
                for c in c0..(c0 + CHANNELS).min(self.c_in) {
                    for slot in slots {
                        let at = (c * 3 + slot) * S * len;
                        offsets.extend(Self::taps::<S>(at, len));
                    }
                }
                let taps = Taps {
                    rows: scratch,
                    offsets,
                    weights: &self.packed[c0 * TAPS * OUTS..],
                    group_stride: self.c_in * TAPS * OUTS,
                };
                taps::accumulate(isa, &taps, out, wv, self.c_out / OUTS, wv);
            }
            for (o, plane) in planes.iter_mut().enumerate() {
                self.put(&mut plane[(y - y0) * wo..][..wo], &out[o * wv..][..wo]);
            }
        }
    }

    /// Stride 1 on narrow rows: output rows `y0..` of every plane in `planes`, a few rows at a
    /// time, as one run of points.
    ///
    /// A row of `w` points is computed in whole vectors; at `w = 50` a row-by-row run computes
    /// 64 points for 50. Here the input rows a few output rows read are copied, channel by
    /// channel, one after the other into one scratch plane, each with a zero before and after it
    /// (rows of `w + 2`, zero rows above and below the image): tap `(ky, kx)` of the point at
    /// `r (w + 2) + x` is then at `r (w + 2) + x + ky (w + 2) + kx` for every output row `r` of the
    /// chunk, so the chunk is one run of `rows (w + 2)` points, 2 of every `w + 2` of them
    /// computed for nothing (4% at `w = 50`).
    #[inline(always)]
    fn band_flat(
        &self,
        isa: neuspike_simd::Isa,
        input: Input,
        (h, w): (usize, usize),
        y0: usize,
        planes: &mut [&mut [f32]],
        buffers: &mut Buffers,
    ) {
        let pw = w + 2;
        let n_rows = planes.first().map_or(0, |p| p.len() / w);
        // Rows per chunk: the scratch planes of all channels within FLAT_SCRATCH values.
        let chunk = (FLAT_SCRATCH / (self.c_in * pw)).clamp(1, n_rows.max(1));
        let Buffers {
            scratch,
            out,
            offsets,
        } = buffers;
        for r0 in (0..n_rows).step_by(chunk) {
            let rows = chunk.min(n_rows - r0);
            let npts = (rows * pw).div_ceil(POINTS) * POINTS;
            // The last point's taps reach 2 rows and 2 values past it.
            let plane = (npts + 2 * pw + 2).next_multiple_of(POINTS);
            let scratch = aligned(scratch, self.c_in * plane);
            for (c, dst) in scratch.chunks_exact_mut(plane).enumerate() {
                // Scratch row k is input row y0 + r0 + k - 1.
                for (k, row) in dst[..(rows + 2) * pw].chunks_exact_mut(pw).enumerate() {
                    let iy = (y0 + r0 + k).checked_sub(1).filter(|&iy| iy < h);
                    Self::padded::<1, f32>(iy.map(|iy| input.row(c, iy, h)), w, row, 0.0);
                }
                dst[(rows + 2) * pw..].fill(0.0);
            }
            out.resize(self.c_out * npts, 0.0);
            for (row, &bias) in out.chunks_exact_mut(npts).zip(&self.bias) {
                row.fill(bias);
            }
            for c0 in (0..self.c_in).step_by(CHANNELS) {
                offsets.clear();
                for c in c0..(c0 + CHANNELS).min(self.c_in) {
                    for ky in 0..3 {
                        let at = c * plane + ky * pw;
                        offsets.extend([at, at + 1, at + 2]);
                    }
                }
                let taps = Taps {
                    rows: scratch,
                    offsets,
                    weights: &self.packed[c0 * TAPS * OUTS..],
                    group_stride: self.c_in * TAPS * OUTS,
                };
                taps::accumulate(isa, &taps, out, npts, self.c_out / OUTS, npts);
            }
            for (o, plane) in planes.iter_mut().enumerate() {
                for r in 0..rows {
                    let src = &out[o * npts + r * pw..][..w];
                    self.put(&mut plane[(r0 + r) * w..][..w], src);
                }
            }
        }
    }

    /// Where taps `kx = 0, 1, 2` of point 0 lie in the `S` scratch rows of `len` values that
    /// [`padded`](Self::padded) makes from one input row, from `at`: stride 1, `kx` on; stride
    /// 2, the odd columns' row (`len` on), the even one's, the odd one's a point further.
    #[inline(always)]
    fn taps<const S: usize>(at: usize, len: usize) -> [usize; 3] {
        if S == 1 {
            [at, at + 1, at + 2]
        } else {
            [at + len, at, at + len + 1]
        }
    }

    /// One output row from its sums: `src` as it is, or through the ReLU.
    #[inline(always)]
    fn put(&self, dst: &mut [f32], src: &[f32]) {
        if self.relu {
            for (d, &v) in dst.iter_mut().zip(src) {
                *d = v.max(0.0);
            }
        } else {
            dst.copy_from_slice(src);
        }
    }

    /// The `S` scratch rows (`len` values each) of one input row `src` (`None` off the image)
    /// of `w` values, `src`'s last repeated up to `w` when it is shorter, `zero` wherever a tap
    /// falls off the image.
    ///
    /// Stride 1: the row shifted right by one, tap `kx` of point `x` at `x + kx`.
    /// Stride 2: the even columns (`2x`: tap 1 at `x`), then the odd ones shifted right by one
    /// (`2x - 1`: tap 0 at `x`, tap 2 at `x + 1`).
    #[inline(always)]
    fn padded<const S: usize, T: Copy>(src: Option<&[T]>, w: usize, rows: &mut [T], zero: T) {
        let Some(src) = src.filter(|s| !s.is_empty()) else {
            rows.fill(zero);
            return;
        };
        let (first, second) = rows.split_at_mut(rows.len() / S);
        let n = src.len().min(w);
        let last = src[n - 1];
        if S == 1 {
            first[0] = zero;
            first[1..=n].copy_from_slice(&src[..n]);
            first[n + 1..=w].fill(last);
            first[w + 1..].fill(zero);
        } else {
            let (evens, odds) = (w.div_ceil(2), w / 2);
            // Pairs, which the compiler turns into vector shuffles (a step of 2 it does not).
            let pairs = src[..n].chunks_exact(2);
            let done = n / 2;
            if let [single] = pairs.remainder() {
                first[done] = *single;
            }
            for ((e, o), pair) in first.iter_mut().zip(&mut second[1..]).zip(pairs) {
                *e = pair[0];
                *o = pair[1];
            }
            // Past the end of `src` (only when the row is padded): its last value, repeated.
            first[n.div_ceil(2)..evens].fill(last);
            second[done + 1..=odds].fill(last);
            first[evens..].fill(zero);
            second[0] = zero;
            second[odds + 1..].fill(zero);
        }
    }
}

/// Where a convolution's input rows come from.
#[derive(Clone, Copy)]
enum Input<'a> {
    /// `[C, H, W]`, row-major, all of it, and its `W`.
    Dense(&'a [f32], usize),
    /// The channel concatenation of parts `(values, channels)`, each `[channels, H, W]`
    /// row-major, and the `W`.
    Parts(&'a [(&'a [f32], usize)], usize),
    /// `[C, h, w]` with contiguous rows, read as if padded to a larger size by repeating its
    /// last row (here) and column ([`Conv3x3::padded`]).
    Edge(ArrayView3<'a, f32>),
    /// As `Edge`, of the channel concatenation of a dense `[D, h, w]` part (contiguous rows)
    /// and binary channels given as bit-packed planes of `h x w` pixels ([`packed_plane_bytes`]): only
    /// the 8-bit path reads it ([`Conv3x3::run_edge_padded_bits`]).
    Bits(ArrayView3<'a, f32>, &'a [u8]),
}

/// The channel concatenation of `dense` (`[D, h, w]`) and `planes` binary planes bit-packed in
/// `bits` ([`packed_plane_bytes`]) unpacked to 0.0/1.0, `[D + planes, h, w]`; `None` when
/// `bits` holds fewer planes.
pub fn unpacked(dense: ArrayView3<f32>, bits: &[u8], planes: usize) -> Option<Array3<f32>> {
    let (d, h, w) = dense.dim();
    let per = packed_plane_bytes(h, w);
    if planes.checked_mul(per)? > bits.len() {
        return None;
    }
    let mut all = Array3::<f32>::zeros((d + planes, h, w));
    all.slice_mut(ndarray::s![..d, .., ..]).assign(&dense);
    // Each plane's pixels one run of memory (a fresh standard array), eight to a byte.
    let values = all.as_slice_mut()?;
    let outputs = values[d * h * w..].chunks_exact_mut((h * w).max(1));
    neuspike_simd::dispatch(
        #[inline(always)]
        || {
            for (out, plane) in outputs.zip(bits.chunks_exact(per.max(1))).take(planes) {
                for (o, &byte) in out.chunks_mut(8).zip(plane) {
                    for (b, v) in o.iter_mut().enumerate() {
                        *v = f32::from((byte >> b) & 1);
                    }
                }
            }
        },
    );
    Some(all)
}

/// Bytes of one bit-packed plane of `h x w` pixels, as a spike window holds its planes and
/// [`Conv3x3::run_edge_padded_bits`] reads them: plane `k` is `bits[k * per..(k + 1) * per]`
/// with `per = ceil(h w / 8)`, pixel `i` (row-major) at bit `i % 8` of its byte `i / 8`.
pub fn packed_plane_bytes(h: usize, w: usize) -> usize {
    (h * w).div_ceil(8)
}

impl<'a> Input<'a> {
    /// Channel `c`'s values as one run of memory when they are (`h` rows: the padded height),
    /// without the padding an `Edge` input repeats.
    #[inline]
    fn plane(self, c: usize, h: usize) -> Option<&'a [f32]> {
        match self {
            Input::Dense(x, w) => x.get(c * h * w..(c + 1) * h * w),
            Input::Parts(parts, w) => {
                let mut c = c;
                for &(x, channels) in parts {
                    if c < channels {
                        return x.get(c * h * w..(c + 1) * h * w);
                    }
                    c -= channels;
                }
                None
            }
            Input::Edge(x) => x.slice_move(ndarray::s![c, .., ..]).to_slice(),
            Input::Bits(x, _) => (c < x.dim().0)
                .then(|| x.slice_move(ndarray::s![c, .., ..]).to_slice())
                .flatten(),
        }
    }

    /// Channel `c`'s packed plane and the view's `(rows, w)` when `c` is a binary channel of a
    /// `Bits` input.
    #[inline]
    fn bit_plane(self, c: usize) -> Option<(&'a [u8], (usize, usize))> {
        match self {
            Input::Bits(x, bits) => {
                let (d, rows, w) = x.dim();
                let k = c.checked_sub(d)?;
                let per = packed_plane_bytes(rows, w);
                Some((bits.get(k * per..(k + 1) * per)?, (rows, w)))
            }
            _ => None,
        }
    }

    /// The values in a row of channel `c` before any padding: `w` for `Dense` and `Parts`, the
    /// view's width for `Edge` and `Bits`.
    #[inline]
    fn row_len(self, c: usize, h: usize) -> usize {
        match self {
            Input::Bits(x, _) => x.dim().2,
            _ => self.row(c, 0, h).len(),
        }
    }

    /// Row `iy` (`< h`, the padded height) of channel `c`: `w` values for `Dense`, the
    /// view's row (the last when `iy` is past it) for `Edge`.
    #[inline]
    fn row(self, c: usize, iy: usize, h: usize) -> &'a [f32] {
        match self {
            // Past the last part (the channels were checked to add up): no row.
            Input::Dense(_, w) | Input::Parts(_, w) => {
                self.plane(c, h).map_or(&[], |p| &p[iy * w..][..w])
            }
            Input::Edge(x) => {
                let (_, rows, w) = x.dim();
                let row = x.slice_move(ndarray::s![c, iy.min(rows - 1), ..]);
                // Contiguous, as `run_edge_padded` checked; one value when not.
                let row = row.to_slice().unwrap_or(&[]);
                &row[..w.min(row.len())]
            }
            // A binary channel has no `f32` row (its readers take `bit_plane`).
            Input::Bits(x, _) if c >= x.dim().0 => &[],
            Input::Bits(x, _) => Input::Edge(x).row(c, iy, h),
        }
    }
}

/// The working rows of [`Conv3x3::band`], kept per thread from one band to the next: fresh
/// allocations of this size come from the system as pages faulted in on first touch.
#[derive(Default)]
struct Buffers {
    /// Input rows padded for the taps, `[C][3 slots][S][len]` values, from a 64-byte boundary.
    scratch: Vec<f32>,
    /// One output row of every channel, `[O][wv]`.
    out: Vec<f32>,
    /// The offsets of one block's tap rows in the scratch rows.
    offsets: Vec<usize>,
}

thread_local! {
    static BUFFERS: std::cell::RefCell<Buffers> = std::cell::RefCell::default();
}

/// `len` values of `buffer` from its first 64-byte boundary (a cache line, and an AVX-512
/// vector), growing it as needed; the values are whatever was there.
fn aligned<T: Copy + Default>(buffer: &mut Vec<T>, len: usize) -> &mut [T] {
    let values = 64 / std::mem::size_of::<T>();
    if buffer.len() < len + values {
        buffer.resize(len + values, T::default());
    }
    let skew = buffer.as_ptr().addr() % 64 / std::mem::size_of::<T>();
    let start = (values - skew) % values;
    &mut buffer[start..start + len]
}

/// The tract operator running a [`Conv3x3`] on `[N, C, H, W]` input.
#[derive(Clone, Debug)]
pub struct Conv3x3Op(pub Arc<Conv3x3>);

impl PartialEq for Conv3x3Op {
    fn eq(&self, other: &Self) -> bool {
        let (a, b) = (&self.0, &other.0);
        a.c_in == b.c_in
            && a.c_out == b.c_out
            && a.stride == b.stride
            && a.relu == b.relu
            && a.precision == b.precision
            && a.packed
                .iter()
                .map(|v| v.to_bits())
                .eq(b.packed.iter().map(|v| v.to_bits()))
            && a.bias
                .iter()
                .map(|v| v.to_bits())
                .eq(b.bias.iter().map(|v| v.to_bits()))
    }
}

impl Eq for Conv3x3Op {}

impl Op for Conv3x3Op {
    fn name(&self) -> StaticName {
        "NeuspikeConv3x3".into()
    }

    fn info(&self) -> TractResult<Vec<String>> {
        let relu = if self.0.relu { ", then ReLU" } else { "" };
        Ok(vec![format!(
            "{} -> {} channels, stride {}{relu}, {}",
            self.0.c_in, self.0.c_out, self.0.stride, self.0.precision
        )])
    }

    op_as_typed_op!();
}

impl EvalOp for Conv3x3Op {
    op_out_of_plan!();

    fn eval(&self, _ctx: &EvalContext, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        // One input, or the parts of its channel concatenation (see `use_conv3x3`).
        let Some(&[n, _, h, w]) = inputs.first().map(|i| i.shape()) else {
            bail!(
                "NeuspikeConv3x3 takes [N, C, H, W], got {:?}",
                inputs.first().map(|i| i.shape())
            );
        };
        let mut channels = TVec::new();
        for input in &inputs {
            let &[ni, c, hi, wi] = input.shape() else {
                bail!(
                    "NeuspikeConv3x3 takes [N, C, H, W], got {:?}",
                    input.shape()
                );
            };
            ensure!(
                (ni, hi, wi) == (n, h, w),
                "parts of shapes {:?} and {:?}",
                inputs[0].shape(),
                input.shape()
            );
            channels.push(c);
        }
        let c: usize = channels.iter().sum();
        ensure!(
            c == self.0.c_in,
            "{c} input channels, expected {}",
            self.0.c_in
        );
        let (ho, wo) = (self.0.out_len(h), self.0.out_len(w));
        let pool = crate::bands::tract_pool();
        let plain = inputs
            .iter()
            .map(|i| i.try_as_plain_ram())
            .collect::<TractResult<TVec<_>>>()?;
        let values = plain
            .iter()
            .map(|p| p.as_slice::<f32>())
            .collect::<TractResult<TVec<_>>>()?;
        let y = crate::bands::output_tensor(&[n, self.0.c_out, ho, wo], |y| {
            if c * h * w > 0 && ho * wo > 0 {
                for (b, y) in y.chunks_exact_mut(self.0.c_out * ho * wo).enumerate() {
                    let parts: TVec<(&[f32], usize)> = values
                        .iter()
                        .zip(&channels)
                        .map(|(v, &ci)| (&v[b * ci * h * w..][..ci * h * w], ci))
                        .collect();
                    if let [(x, _)] = parts.as_slice() {
                        self.0.run(x, (h, w), y, pool.as_deref())?;
                    } else {
                        self.0.run_concat(&parts, (h, w), y, pool.as_deref())?;
                    }
                }
            }
            Ok(())
        })?;
        Ok(tvec!(y))
    }
}

impl TypedOp for Conv3x3Op {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        let Some(input) = inputs.first() else {
            bail!("NeuspikeConv3x3 takes one input or more (the parts of its concatenation)");
        };
        for part in inputs {
            ensure!(part.datum_type == f32::datum_type() && part.rank() == 4);
            ensure!(part.shape[0] == input.shape[0] && part.shape[2..] == input.shape[2..]);
        }
        let mut shape: TVec<TDim> = input.shape.iter().cloned().collect();
        shape[1] = self.0.c_out.into();
        if self.0.stride == 2 {
            // (n - 1) / 2 + 1 for n >= 1.
            shape[2] = shape[2].clone().div_ceil(2);
            shape[3] = shape[3].clone().div_ceil(2);
        }
        Ok(tvec!(f32::fact(shape)))
    }

    as_op!();
}

/// Output widths from which [`use_conv3x3`] is worth it. Measured with `neuspike bench-model
/// --profile` (base widths 16 and 24, 256x400, AVX-512) and `bench_conv3x3`: ours is faster
/// than tract's best path at every width the networks have. At width 50, stride 1 (rows
/// computed a few at a time, [`FLAT_BELOW`]): 2.10 against 2.49 ms for the 128-channel layer,
/// one thread; stride 2 (a row of 50 points computed as 64): 1.44-1.54 against 1.58-1.78 ms
/// for the 64-to-128 layer on one thread, 0.73-0.77 against 0.87-1.64 on two (tract's times
/// with the padding it adds).
pub const MIN_WIDTH: usize = 40;

/// The [`Conv3x3`] that computes `node`, if it is a 3x3, padding-1 convolution of stride 1 or 2
/// without dilation, groups or quantisation, on f32 NCHW input of a known width giving at least
/// `min_width` output points per row, with constant weights and bias.
fn as_conv3x3(model: &TypedModel, node: &TypedNode, min_width: usize) -> Option<Conv3x3> {
    let conv = crate::matching::conv_node(model, node)?;
    if conv.kernel_size != [3, 3]
        || conv.pad != 1
        || conv.group != 1
        || !(1..=2).contains(&conv.stride)
    {
        return None;
    }
    let fact = model.outlet_fact(node.inputs[0]).ok()?;
    let width = fact.shape[3].to_usize().ok()?;
    if (width.max(1) - 1) / conv.stride + 1 < min_width {
        return None;
    }
    let &[o, c, kh, kw] = conv.shape.as_slice() else {
        return None;
    };
    let kernel = ArrayView4::from_shape((o, c, kh, kw), &conv.kernel).ok()?;
    Conv3x3::new(kernel, &conv.bias, conv.stride).ok()
}

/// The node of `model` that only applies a ReLU to `node`'s output, if its output has no other
/// use: `max(y, 0)` (how tract-onnx writes ONNX's `Relu`) against a constant of zeros that does
/// not broadcast `y` to a larger shape.
pub(crate) fn relu_after(model: &TypedModel, node: &TypedNode) -> Option<usize> {
    use tract_onnx::tract_core::ops::binary::TypedBinOp;
    let out = OutletId::new(node.id, 0);
    let relu = model.node(crate::matching::only_reader(model, node)?);
    let max = relu.op_as::<TypedBinOp>()?;
    if max.0.name() != "Max" || relu.inputs.len() != 2 {
        return None;
    }
    let slot = relu.inputs.iter().position(|&i| i == out)?;
    let (_, zero) = crate::matching::values(model, relu.inputs[1 - slot])?;
    let same_shape = model.outlet_fact(OutletId::new(relu.id, 0)).ok()?.shape
        == model.outlet_fact(out).ok()?.shape;
    (same_shape && zero.iter().all(|&v| v == 0.0)).then_some(relu.id)
}

/// The parts of `outlet` if it is a concatenation along channels (axis 1) read by nothing else
/// (and not a model output): the convolution reads them in place and the concatenation goes.
fn concatenated(model: &TypedModel, outlet: OutletId) -> TractResult<Option<TVec<OutletId>>> {
    use tract_onnx::tract_core::ops::array::TypedConcat;
    let node = model.node(outlet.node);
    let only_reader = node.outputs[outlet.slot].successors.len() == 1
        && !model.output_outlets()?.contains(&outlet);
    Ok(node
        .op_as::<TypedConcat>()
        .filter(|c| c.axis == 1 && only_reader && !node.inputs.is_empty())
        .map(|_| node.inputs.iter().copied().collect()))
}

/// Replaces every convolution of the (decluttered) `model` that a [`Conv3x3`] computes with
/// output rows of at least `min_width` points ([`MIN_WIDTH`] where it pays) by a
/// [`Conv3x3Op`], taking in the ReLU that follows it if any, and reading the parts of the
/// channel concatenation before it if any (the decoder's merges: no concatenated copy),
/// computing in `precision`; returns how many.
pub fn use_conv3x3(
    model: &mut TypedModel,
    min_width: usize,
    precision: Precision,
) -> TractResult<usize> {
    let mut replaced = 0;
    for id in model.eval_order()? {
        let node = model.node(id);
        let Some(conv) = as_conv3x3(model, node, min_width) else {
            continue;
        };
        let relu = relu_after(model, node);
        let conv = if relu.is_some() {
            conv.with_relu()
        } else {
            conv
        }
        .with_precision(precision);
        let parts = concatenated(model, node.inputs[0])?.unwrap_or_else(|| tvec![node.inputs[0]]);
        let (name, op) = (node.name.clone(), Conv3x3Op(Arc::new(conv)));
        let gone: TVec<usize> = std::iter::once(id).chain(relu).collect();
        crate::matching::replace(model, &name, op, &parts, relu.unwrap_or(id), &gone)?;
        replaced += 1;
    }
    Ok(replaced)
}

/// Takes out of `model` each [`Conv3x3Op`] that is the only reader of a model input, so the
/// caller runs it on the representation where it lies ([`Conv3x3::run_edge_padded`]) and feeds
/// the model its output instead: the input is not copied into a padded tensor first. Returns,
/// for each input of the model, the convolution taken (the input is now that convolution's
/// output, a source named `<input>.conv`), or `None` (the input is unchanged).
pub fn take_first_convolutions(model: &mut TypedModel) -> TractResult<Vec<Option<Arc<Conv3x3>>>> {
    let inputs = model.input_outlets()?.to_vec();
    let mut taken = vec![None; inputs.len()];
    for (slot, input) in inputs.into_iter().enumerate() {
        let source = model.node(input.node);
        let [next] = source.outputs[input.slot].successors.as_slice() else {
            continue;
        };
        let conv = model.node(next.node);
        let Some(op) = conv.op_as::<Conv3x3Op>().filter(|_| conv.inputs.len() == 1) else {
            continue;
        };
        let out = OutletId::new(conv.id, 0);
        if model.output_outlets()?.contains(&out) {
            continue;
        }
        let name = format!("{}.conv", source.name);
        let (conv_id, source_id, op) = (conv.id, source.id, op.0.clone());
        let fact = model.outlet_fact(out)?.clone();
        let mut patch = TypedModelPatch::default();
        let new = patch.add_source(&name, fact)?;
        // The new source takes the old one's place among the model's inputs.
        patch.inputs.insert(new.node, source_id);
        patch.shunt_outside(model, out, new)?;
        patch.obliterate(conv_id)?;
        patch.apply(model)?;
        taken[slot] = Some(op);
    }
    Ok(taken)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{conv, pattern, runs_give};
    use ndarray::Array4;
    use proptest::prelude::*;

    /// The fast path on every instruction set and thread count against the reference, exactly.
    fn check(c_in: usize, c_out: usize, stride: usize, (h, w): (usize, usize), seed: u32) {
        let conv = conv(c_in, c_out, stride, seed);
        // Half the cases with a ReLU taken in.
        let conv = if seed % 2 == 1 {
            conv.with_relu()
        } else {
            conv
        };
        let input = pattern(c_in * h * w, seed + 2);
        let view = ArrayView3::from_shape((c_in, h, w), &input).unwrap();
        let want = conv.reference(view).unwrap();
        let what = format!("{c_in}->{c_out} at {h}x{w}, stride {stride}");
        runs_give(&conv, &input, (h, w), want.as_slice().unwrap(), &what);
    }

    #[test]
    fn matches_the_reference_at_the_networks_sizes() {
        for (seed, &(c_in, c_out, stride, hw)) in (1..).zip(&crate::testing::NETWORK_LAYERS) {
            check(c_in, c_out, stride, hw, seed);
        }
        // Narrow rows, computed a few at a time: 2 rows a chunk here, 3 chunks.
        check(256, 8, 1, (5, 100), 6);
    }

    #[test]
    fn parts_of_a_concatenation_give_the_concatenations_bits() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        for (stride, (h, w)) in [(1, (9, 37)), (2, (8, 20))] {
            let conv = conv(8, 8, stride, 4).with_relu();
            let input = pattern(8 * h * w, 3);
            let mut want = vec![0.0; 8 * conv.out_len(h) * conv.out_len(w)];
            conv.run(&input, (h, w), &mut want, None).unwrap();
            let (a, b) = input.split_at(3 * h * w);
            for pool in [None, Some(&pool)] {
                let mut got = vec![f32::NAN; want.len()];
                conv.run_concat(&[(a, 3), (b, 5)], (h, w), &mut got, pool)
                    .unwrap();
                assert_eq!(got, want, "stride {stride}");
            }
            // Channels that do not add up, or a part of the wrong size: refused.
            let mut got = vec![0.0; want.len()];
            for parts in [
                vec![(a, 3)],
                vec![(a, 3), (b, 4)],
                vec![(a, 3), (&b[1..], 5)],
            ] {
                let err = conv.run_concat(&parts, (h, w), &mut got, None);
                assert!(matches!(err, Err(Conv3x3Error::Shape { .. })), "{err:?}");
            }
        }
    }

    #[test]
    fn edge_padded_input_read_in_place_gives_the_padded_copys_bits() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        // (c_in, c_out, stride, real size, padded size): padded in rows, columns, both, neither,
        // to odd and even widths, one row or column repeated many times.
        for (i, &(c, o, stride, (h, w), (hp, wp))) in [
            (32, 8, 1, (13, 390), (16, 400)),
            (8, 8, 1, (16, 400), (16, 400)),
            (4, 4, 1, (1, 1), (5, 21)),
            (8, 16, 2, (11, 197), (16, 200)),
            (3, 4, 2, (7, 18), (8, 21)),
            (3, 4, 2, (8, 1), (8, 6)),
        ]
        .iter()
        .enumerate()
        {
            let conv = conv(c, o, stride, i as u32);
            let input = pattern(c * h * w, i as u32 + 7);
            let view = ArrayView3::from_shape((c, h, w), &input).unwrap();
            let padded = crate::pad_edge(view, hp, wp);
            let padded = ArrayView3::from_shape((c, hp, wp), &padded).unwrap();
            let want = conv.reference(padded).unwrap();
            // The same values as a crop of a larger array: rows contiguous, the whole not one
            // run of memory.
            let mut larger = ndarray::Array3::<f32>::from_elem((c, h + 2, w + 3), f32::NAN);
            larger
                .slice_mut(ndarray::s![.., 1..h + 1, 2..w + 2])
                .assign(&view);
            let crop = larger.slice(ndarray::s![.., 1..h + 1, 2..w + 2]);
            for (pool, view) in [(None, view), (Some(&pool), view), (Some(&pool), crop)] {
                let mut got = vec![f32::NAN; want.len()];
                conv.run_edge_padded(view, (hp, wp), &mut got, pool)
                    .unwrap();
                assert_eq!(
                    got.as_slice(),
                    want.as_slice().unwrap(),
                    "{c}->{o}, stride {stride}, {h}x{w} as {hp}x{wp}, pool {}, one run {}",
                    pool.is_some(),
                    view.as_slice().is_some()
                );
            }
        }
    }

    #[test]
    fn edge_padding_refuses_what_it_cannot_read() {
        let conv = conv(2, 4, 1, 1);
        let input = pattern(2 * 4 * 6, 2);
        let view = ArrayView3::from_shape((2, 4, 6), &input).unwrap();
        let mut out = vec![0.0; 4 * 8 * 8];
        // Larger than the padded size, rows across memory (a transposed view), empty, or an
        // output of the wrong size: an error, nothing written.
        let transposed = ArrayView3::from_shape((2, 6, 4), &input).unwrap();
        let transposed = transposed.permuted_axes([0, 2, 1]);
        for (x, hw, n) in [
            (view, (3, 8), 4 * 3 * 8),
            (transposed, (8, 8), 4 * 8 * 8),
            (view.slice_move(ndarray::s![.., ..0, ..]), (8, 8), 4 * 8 * 8),
            (view, (8, 8), 4 * 8 * 7),
        ] {
            out.resize(n, 0.0);
            out.fill(0.0);
            let err = conv.run_edge_padded(x, hw, &mut out, None);
            assert!(
                matches!(err, Err(Conv3x3Error::Shape { .. })),
                "{:?} as {hw:?}: {err:?}",
                x.shape()
            );
            assert!(out.iter().all(|&v| v == 0.0));
        }
    }

    #[test]
    fn matches_the_reference_at_edges() {
        // Widths below, at and around one vector and one block; one row; one column.
        for (h, w) in [
            (1, 1),
            (1, 7),
            (2, 8),
            (3, 9),
            (4, 23),
            (5, 24),
            (3, 25),
            (6, 33),
            (7, 1),
        ] {
            for stride in [1, 2] {
                check(3, 4, stride, (h, w), (h * 100 + w) as u32);
            }
        }
    }

    #[test]
    fn a_single_tap_is_a_shift() {
        // Only the top-left tap is 1: output (y, x) is input (y - 1, x - 1), 0 off the image.
        let mut weights = Array4::zeros((4, 1, 3, 3));
        weights[[2, 0, 0, 0]] = 1.0;
        let conv = Conv3x3::new(weights.view(), &[0.0], 1).unwrap();
        let (h, w) = (5, 30);
        let input: Vec<f32> = (0..h * w).map(|i| i as f32 + 1.0).collect();
        let mut out = vec![f32::NAN; 4 * h * w];
        conv.run(&input, (h, w), &mut out, None).unwrap();
        for y in 0..h {
            for x in 0..w {
                let want = if y == 0 || x == 0 {
                    0.0
                } else {
                    input[(y - 1) * w + x - 1]
                };
                assert_eq!(out[2 * h * w + y * w + x], want, "({y}, {x})");
                assert_eq!(out[y * w + x], 0.0);
            }
        }
    }

    #[test]
    fn refuses_what_it_cannot_compute() {
        let w = Array4::<f32>::zeros((6, 2, 3, 3));
        assert_eq!(
            Conv3x3::new(w.view(), &[0.0], 1).unwrap_err(),
            Conv3x3Error::Channels(6)
        );
        let w = Array4::<f32>::zeros((4, 2, 5, 5));
        assert!(matches!(
            Conv3x3::new(w.view(), &[0.0], 1),
            Err(Conv3x3Error::Weights(_))
        ));
        let w = Array4::<f32>::zeros((4, 2, 3, 3));
        assert_eq!(
            Conv3x3::new(w.view(), &[0.0; 3], 1).unwrap_err(),
            Conv3x3Error::Bias {
                got: 3,
                channels: 4
            }
        );
        assert_eq!(
            Conv3x3::new(w.view(), &[0.0], 3).unwrap_err(),
            Conv3x3Error::Stride(3)
        );
        assert_eq!(
            Conv3x3::new(w.view(), &[0.0], 0).unwrap_err(),
            Conv3x3Error::Stride(0)
        );
        let conv = Conv3x3::new(w.view(), &[0.0; 4], 1).unwrap();
        let mut out = vec![0.0; 4 * 6];
        assert!(conv.run(&[0.0; 5], (2, 3), &mut out, None).is_err());
        assert!(conv.run(&[0.0; 12], (2, 3), &mut out[..5], None).is_err());
        // Stride 2 writes ceil(2 / 2) x ceil(3 / 2) points per channel, not 2 x 3.
        let conv = Conv3x3::new(w.view(), &[0.0; 4], 2).unwrap();
        assert!(conv.run(&[0.0; 12], (2, 3), &mut out, None).is_err());
        assert!(conv.run(&[0.0; 12], (2, 3), &mut out[..8], None).is_ok());
    }

    /// A model of one tract `Conv` (3x3, padding 1, `stride`) and its input.
    fn one_conv(c: usize, o: usize, stride: usize, (h, w): (usize, usize)) -> (TypedModel, Tensor) {
        // Odd sizes with a ReLU after the convolution, to check that it is taken in.
        let conv = conv(c, o, stride, 7);
        let conv = if h % 2 == 1 { conv.with_relu() } else { conv };
        let model = conv.tract_model(h, w).unwrap();
        let input = Tensor::from_shape(&[1, c, h, w], &pattern(c * h * w, 9)).unwrap();
        (model, input)
    }

    #[test]
    fn the_operator_computes_what_tracts_convolution_does() {
        for (stride, (h, w)) in [(1, (7, 19)), (2, (8, 20)), (2, (7, 19)), (2, (1, 2))] {
            let (model, input) = one_conv(5, 8, stride, (h, w));
            let run = |model: TypedModel| crate::testing::run_typed(model, &input);
            let want = run(model.clone());
            let mut ours = model;
            assert_eq!(
                use_conv3x3(&mut ours.clone(), w.div_ceil(stride) + 1, Precision::F32).unwrap(),
                0
            );
            assert_eq!(
                use_conv3x3(&mut ours, w.div_ceil(stride), Precision::F32).unwrap(),
                1
            );
            let ours = ours.into_decluttered().unwrap();
            let op = ours.nodes().iter().find_map(|n| n.op_as::<Conv3x3Op>());
            assert_eq!(op.map(|op| op.0.relu()), Some(h % 2 == 1));
            assert_eq!(ours.nodes().len(), 2, "source and ours: {ours}");
            let ((shape, got), (want_shape, want)) = (run(ours), want);
            assert_eq!(shape, want_shape, "stride {stride}, {h}x{w}");
            for (i, (g, w)) in got.iter().zip(want).enumerate() {
                // 45 products of values below 1 in another order: a few ulps of 45.
                assert!(
                    (g - w).abs() < 1e-4,
                    "stride {stride}, {h}x{w}, value {i}: {g} vs {w}"
                );
            }
        }
    }

    #[test]
    fn a_first_convolution_is_taken_out_and_its_output_becomes_the_input() {
        let (c, o, (h, w)) = (3, 8, (6, 20));
        let conv = conv(c, o, 1, 3).with_relu();
        let mut model = conv.tract_model(h, w).unwrap();
        // A node after the convolution: one that is itself the model's output stays in.
        let y = model.output_outlets().unwrap()[0];
        let half = model.add_const("half", tensor4(&[[[[0.5f32]]]])).unwrap();
        let z = model
            .wire_node("max", tract_onnx::tract_core::ops::math::max(), &[y, half])
            .unwrap();
        model.select_output_outlets(&z).unwrap();
        let mut as_output = conv.tract_model(h, w).unwrap();
        assert_eq!(use_conv3x3(&mut as_output, 1, Precision::F32).unwrap(), 1);
        assert_eq!(take_first_convolutions(&mut as_output).unwrap().len(), 1);
        assert!(take_first_convolutions(&mut as_output).unwrap()[0].is_none());

        let input = pattern(c * h * w, 5);
        let x = Tensor::from_shape(&[1, c, h, w], &input).unwrap();
        let run = |model: TypedModel, x: Tensor| crate::testing::run_typed(model, &x).1;
        let mut ours = model;
        assert_eq!(use_conv3x3(&mut ours, 1, Precision::F32).unwrap(), 1);
        let want = run(ours.clone(), x);
        let taken = take_first_convolutions(&mut ours).unwrap();
        let [Some(first)] = taken.as_slice() else {
            panic!("not taken: {taken:?}");
        };
        assert!(first.relu());
        let inputs = ours.input_outlets().unwrap();
        assert_eq!(inputs.len(), 1);
        assert_eq!(ours.node(inputs[0].node).name, "x.conv");
        assert_eq!(
            ours.outlet_fact(inputs[0]).unwrap().shape.as_concrete(),
            Some(&[1, o, h, w][..])
        );
        assert!(
            ours.nodes()
                .iter()
                .all(|n| n.op_as::<Conv3x3Op>().is_none())
        );
        // The caller computes it, then the model does the rest: what the whole model gave.
        let view = ArrayView3::from_shape((c, h, w), &input).unwrap();
        let mut y = vec![0.0; o * h * w];
        first.run_edge_padded(view, (h, w), &mut y, None).unwrap();
        let y = Tensor::from_shape(&[1, o, h, w], &y).unwrap();
        assert_eq!(run(ours, y), want);
    }

    #[test]
    fn convolutions_it_cannot_compute_are_left_to_tract() {
        use tract_onnx::tract_core::ops::cnn::Conv;
        for (o, stride) in [(6, 1), (8, 3)] {
            // A stride-1 model with the stride or the channels changed behind the kernel's back.
            let mut conv = conv(3, 8, 1, 7);
            conv.stride = stride;
            conv.c_out = o;
            conv.bias.truncate(o);
            let mut model = conv.tract_model(9, 9).unwrap();
            assert_eq!(
                use_conv3x3(&mut model, 1, Precision::F32).unwrap(),
                0,
                "{o} outputs, stride {stride}"
            );
            assert!(model.nodes().iter().any(|n| n.op_is::<Conv>()));
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        #[test]
        fn matches_the_reference_anywhere(
            c_in in 1usize..6, groups in 1usize..4, stride in 1usize..=2, h in 1usize..9,
            w in 1usize..60, seed: u32
        ) {
            check(c_in, 4 * groups, stride, (h, w), seed);
        }
    }
}
