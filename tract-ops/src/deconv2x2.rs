//! The decoder's upsampling of the learned networks: a 2x2 transposed convolution of stride 2
//! (no padding, no groups), and the tract operator that runs it in place of tract's own.
//!
//! Each output pixel takes exactly one tap: `y[o, 2i + ky, 2j + kx] = b[o] + sum_c w[o, c, ky,
//! kx] x[c, i, j]`. tract computes it as a matrix product into a `[O * 4, H * W]` buffer, then
//! scatters that into the image on one thread (`DeconvSum`), then applies the ReLU that follows
//! on one thread: 1.8 ms of a base-16 network's 49 at full resolution on 2 threads, most of it
//! on one. [`Deconv2x2`] computes each output row straight: for output row `2i + ky`, the
//! values for `kx = 0` and `kx = 1` of every output channel are `2 O` rows of `W` points over
//! the taps of the `C` input rows `i` ([`neuspike_simd::taps::accumulate`]), interleaved into
//! the output row with the ReLU taken in. Input rows are split in bands across tract's pool.
//!
//! [`Deconv2x2::reference`] is the scalar definition; the fast path takes the same fused
//! multiply-adds in the same order (bias, then input channel), so the two agree exactly.

use std::sync::Arc;

use ndarray::{Array3, ArrayView3, ArrayView4};
use neuspike_simd::taps::{self, POINTS, Taps};
use tract_onnx::prelude::*;
use tract_onnx::tract_core::internal::*;

/// Output values one block of the kernel keeps in registers per point: two output channels by
/// the two kernel columns.
const OUTS: usize = taps::OUTS;
/// Input channels of one call of the kernel: their rows, for the points in registers, stay in
/// the L1 cache across the output channels.
const CHANNELS: usize = 32;

/// A 2x2 transposed convolution of stride 2, no padding, with its weights packed for the kernel.
#[derive(Clone, Debug)]
pub struct Deconv2x2 {
    c_in: usize,
    c_out: usize,
    /// `[ky][c_out / 2][c_in][4]`: for kernel row `ky`, output channels `2g` and `2g + 1` and an
    /// input channel, the weights `(2g, kx 0), (2g, kx 1), (2g + 1, kx 0), (2g + 1, kx 1)`.
    packed: Vec<f32>,
    bias: Vec<f32>,
    /// Whether the output goes through `max(0, y)` (a ReLU after the convolution).
    relu: bool,
}

/// Why a transposed convolution cannot be a [`Deconv2x2`], or an input it cannot take.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum Deconv2x2Error {
    /// The weights are not `[O, C, 2, 2]`, or have no channels.
    #[error("weights of shape {0:?}, not [O, C, 2, 2]")]
    Weights(Vec<usize>),
    /// An odd number of output channels (a block takes them two by two).
    #[error("{0} output channels, not a multiple of 2")]
    Channels(usize),
    /// The bias has neither one value per output channel nor a single one.
    #[error("a bias of {got} values for {channels} output channels")]
    Bias {
        /// Values in the bias.
        got: usize,
        /// Output channels.
        channels: usize,
    },
    /// The input is not `[C, H, W]` with the weights' `C`, or the output is not `[O, 2H, 2W]`.
    #[error("input {input:?} and output of {output} values for a {c_in}-to-{c_out} upsampling")]
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

impl Deconv2x2 {
    /// Packs `weights` (`[O, C, 2, 2]`: output channel, input channel, kernel row, column) and
    /// `bias` (`O` values, or one for all).
    pub fn new(weights: ArrayView4<f32>, bias: &[f32]) -> Result<Deconv2x2, Deconv2x2Error> {
        let (c_out, c_in, kh, kw) = weights.dim();
        if (kh, kw) != (2, 2) || c_in == 0 || c_out == 0 {
            return Err(Deconv2x2Error::Weights(weights.shape().to_vec()));
        }
        if !c_out.is_multiple_of(2) {
            return Err(Deconv2x2Error::Channels(c_out));
        }
        let bias = match bias.len() {
            n if n == c_out => bias.to_vec(),
            1 => vec![bias[0]; c_out],
            got => {
                return Err(Deconv2x2Error::Bias {
                    got,
                    channels: c_out,
                });
            }
        };
        let mut packed = Vec::with_capacity(c_out * c_in * 4);
        for ky in 0..2 {
            for g in 0..c_out / 2 {
                for c in 0..c_in {
                    for o in [2 * g, 2 * g + 1] {
                        packed.extend([weights[[o, c, ky, 0]], weights[[o, c, ky, 1]]]);
                    }
                }
            }
        }
        Ok(Deconv2x2 {
            c_in,
            c_out,
            packed,
            bias,
            relu: false,
        })
    }

    /// The same upsampling followed by a ReLU, `y.max(0.0)` (0 for NaN, as tract's `Max`).
    pub fn with_relu(self) -> Deconv2x2 {
        Deconv2x2 { relu: true, ..self }
    }

    /// Whether a ReLU is taken in.
    pub fn relu(&self) -> bool {
        self.relu
    }

    /// The weight of output channel `o`, input channel `c`, tap `(ky, kx)`.
    fn weight(&self, o: usize, c: usize, ky: usize, kx: usize) -> f32 {
        let g = o / 2;
        self.packed[(((ky * self.c_out / 2 + g) * self.c_in + c) * 2 + o % 2) * 2 + kx]
    }

    fn check(&self, input: &[usize], output: usize) -> Result<(), Deconv2x2Error> {
        match *input {
            [c, h, w] if c == self.c_in && Some(output) == self.out_len(h, w) => Ok(()),
            _ => Err(Deconv2x2Error::Shape {
                input: input.to_vec(),
                output,
                c_in: self.c_in,
                c_out: self.c_out,
            }),
        }
    }

    /// Values of the output for `h x w` input, `O * 2h * 2w`, or `None` when that overflows.
    fn out_len(&self, h: usize, w: usize) -> Option<usize> {
        self.c_out
            .checked_mul(h.checked_mul(2)?)?
            .checked_mul(w.checked_mul(2)?)
    }

    /// The scalar definition: `[O, 2H, 2W]` from `[C, H, W]`, each output the bias then one fused
    /// multiply-add per input channel, in order.
    pub fn reference(&self, input: ArrayView3<f32>) -> Result<Array3<f32>, Deconv2x2Error> {
        let (_, h, w) = input.dim();
        let len = self.out_len(h, w).unwrap_or(usize::MAX);
        self.check(input.shape(), len)?;
        Ok(Array3::from_shape_fn(
            (self.c_out, 2 * h, 2 * w),
            |(o, y, x)| {
                let mut acc = self.bias[o];
                for c in 0..self.c_in {
                    acc = self
                        .weight(o, c, y % 2, x % 2)
                        .mul_add(input[[c, y / 2, x / 2]], acc);
                }
                if self.relu { acc.max(0.0) } else { acc }
            },
        ))
    }

    /// The upsampling of `input` (`[C, H, W]`, row-major) into `output` (`[O, 2H, 2W]`), input
    /// rows split across `pool` (or this thread when `None`).
    pub fn run(
        &self,
        input: &[f32],
        hw: (usize, usize),
        output: &mut [f32],
        pool: Option<&rayon::ThreadPool>,
    ) -> Result<(), Deconv2x2Error> {
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
    ) -> Result<(), Deconv2x2Error> {
        if Some(input.len()) != h.checked_mul(w).and_then(|n| n.checked_mul(self.c_in)) {
            return Err(Deconv2x2Error::Shape {
                input: vec![input.len()],
                output: output.len(),
                c_in: self.c_in,
                c_out: self.c_out,
            });
        }
        self.check(&[self.c_in, h, w], output.len())?;
        if h == 0 || w == 0 {
            return Ok(());
        }
        // Band b gets input rows [b * rows, ..), output rows twice those, of every plane.
        let rows = crate::bands::band_rows(h, pool);
        let tasks = crate::bands::row_bands(output, 4 * h * w, 4 * w, rows);
        let band = |(i0, mut planes): (usize, Vec<&mut [f32]>)| {
            BUFFERS.with_borrow_mut(|buffers| {
                neuspike_simd::with_isa(
                    isa,
                    #[inline(always)]
                    || self.band(isa, input, (h, w), i0, &mut planes, buffers),
                )
            })
        };
        crate::bands::for_each(tasks, pool, band);
        Ok(())
    }

    /// Output rows `2 i0..` of every plane in `planes` (each a band of whole rows).
    #[inline(always)]
    fn band(
        &self,
        isa: neuspike_simd::Isa,
        input: &[f32],
        (h, w): (usize, usize),
        i0: usize,
        planes: &mut [&mut [f32]],
        buffers: &mut Buffers,
    ) {
        // Whole vectors of points; the rows past `w` are zeros, their sums never read.
        let wv = w.div_ceil(POINTS) * POINTS;
        let Buffers { rows, out, offsets } = buffers;
        rows.resize(self.c_in * wv, 0.0);
        out.resize(2 * self.c_out * wv, 0.0);
        let n_rows = planes.first().map_or(0, |p| p.len() / (4 * w));
        for i in i0..i0 + n_rows {
            for (c, row) in rows.chunks_exact_mut(wv).enumerate() {
                row[..w].copy_from_slice(&input[(c * h + i) * w..][..w]);
                row[w..].fill(0.0);
            }
            for ky in 0..2 {
                // Row `2o + kx` of `out`: output channel o's points of column parity kx.
                for (o, pair) in out.chunks_exact_mut(2 * wv).enumerate() {
                    pair.fill(self.bias[o]);
                }
                let weights = &self.packed[ky * self.c_out * self.c_in * 2..];
                for c0 in (0..self.c_in).step_by(CHANNELS) {
                    offsets.clear();
                    offsets.extend((c0..(c0 + CHANNELS).min(self.c_in)).map(|c| c * wv));
                    let taps = Taps {
                        rows,
                        offsets,
                        weights: &weights[c0 * OUTS..],
                        group_stride: self.c_in * OUTS,
                    };
                    taps::accumulate(isa, &taps, out, wv, self.c_out / 2, wv);
                }
                let y = 2 * (i - i0) + ky;
                for (o, plane) in planes.iter_mut().enumerate() {
                    let dst = &mut plane[y * 2 * w..][..2 * w];
                    let (even, odd) = (&out[2 * o * wv..][..w], &out[(2 * o + 1) * wv..][..w]);
                    interleave(dst, even, odd, self.relu);
                }
            }
        }
    }
}

/// `dst[2j] = even[j]`, `dst[2j + 1] = odd[j]`, through `max(0)` when `relu`: in runs of 16
/// points of fixed size, which the compiler turns into vector shuffles.
#[inline(always)]
fn interleave(dst: &mut [f32], even: &[f32], odd: &[f32], relu: bool) {
    const RUN: usize = 16;
    let put = |v: f32| if relu { v.max(0.0) } else { v };
    let runs = even.len() / RUN;
    for ((d, e), o) in dst
        .chunks_exact_mut(2 * RUN)
        .zip(even.chunks_exact(RUN))
        .zip(odd.chunks_exact(RUN))
        .take(runs)
    {
        let d: &mut [f32; 2 * RUN] = d.try_into().expect("a run");
        let e: &[f32; RUN] = e.try_into().expect("a run");
        let o: &[f32; RUN] = o.try_into().expect("a run");
        for j in 0..RUN {
            d[2 * j] = put(e[j]);
            d[2 * j + 1] = put(o[j]);
        }
    }
    let done = runs * RUN;
    for ((pair, &e), &o) in dst[2 * done..]
        .chunks_exact_mut(2)
        .zip(&even[done..])
        .zip(&odd[done..])
    {
        pair[0] = put(e);
        pair[1] = put(o);
    }
}

/// The working rows of [`Deconv2x2::band`], kept per thread from one band to the next.
#[derive(Default)]
struct Buffers {
    /// One input row of every channel, `[C][wv]`, zeros past the image.
    rows: Vec<f32>,
    /// The sums for one output row, `[O][2][wv]`.
    out: Vec<f32>,
    /// The offsets of one call's tap rows in `rows`.
    offsets: Vec<usize>,
}

thread_local! {
    static BUFFERS: std::cell::RefCell<Buffers> = std::cell::RefCell::default();
}

/// The tract operator running a [`Deconv2x2`] on `[N, C, H, W]` input.
#[derive(Clone, Debug)]
pub struct Deconv2x2Op(pub Arc<Deconv2x2>);

impl PartialEq for Deconv2x2Op {
    fn eq(&self, other: &Self) -> bool {
        let (a, b) = (&self.0, &other.0);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        a.c_in == b.c_in
            && a.c_out == b.c_out
            && a.relu == b.relu
            && bits(&a.packed) == bits(&b.packed)
            && bits(&a.bias) == bits(&b.bias)
    }
}

impl Eq for Deconv2x2Op {}

impl Op for Deconv2x2Op {
    fn name(&self) -> StaticName {
        "NeuspikeDeconv2x2".into()
    }

    fn info(&self) -> TractResult<Vec<String>> {
        let relu = if self.0.relu { ", then ReLU" } else { "" };
        Ok(vec![format!(
            "{} -> {} channels, 2x up{relu}",
            self.0.c_in, self.0.c_out
        )])
    }

    op_as_typed_op!();
}

impl EvalOp for Deconv2x2Op {
    op_out_of_plan!();

    fn eval(&self, _ctx: &EvalContext, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let input = args_1!(inputs);
        let &[n, c, h, w] = input.shape() else {
            bail!(
                "NeuspikeDeconv2x2 takes [N, C, H, W], got {:?}",
                input.shape()
            );
        };
        ensure!(
            c == self.0.c_in,
            "{c} input channels, expected {}",
            self.0.c_in
        );
        let pool = crate::bands::tract_pool();
        let input = input.try_as_plain_ram()?;
        let x = input.as_slice::<f32>()?;
        let plane = self
            .0
            .out_len(h, w)
            .ok_or_else(|| format_err!("output of {h}x{w} input overflows"))?;
        let y = crate::bands::output_tensor(&[n, self.0.c_out, 2 * h, 2 * w], |y| {
            ensure!(
                y.len() == n * plane,
                "output of {} values for {n} of {plane}",
                y.len()
            );
            if c * h * w > 0 && plane > 0 {
                for (x, y) in x.chunks_exact(c * h * w).zip(y.chunks_exact_mut(plane)) {
                    self.0.run(x, (h, w), y, pool.as_deref())?;
                }
            }
            Ok(())
        })?;
        Ok(tvec!(y))
    }
}

impl TypedOp for Deconv2x2Op {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        let [input] = inputs else {
            bail!("NeuspikeDeconv2x2 takes one input");
        };
        ensure!(input.datum_type == f32::datum_type() && input.rank() == 4);
        let mut shape: TVec<TDim> = input.shape.iter().cloned().collect();
        shape[1] = self.0.c_out.into();
        shape[2] = shape[2].clone() * 2;
        shape[3] = shape[3].clone() * 2;
        Ok(tvec!(f32::fact(shape)))
    }

    as_op!();
}

/// The [`Deconv2x2`] that computes `node`, if it is a 2x2 transposed convolution of stride 2
/// without padding, dilation, output adjustment, groups or quantisation, on f32 NCHW input,
/// with constant weights and bias.
fn as_deconv2x2(model: &TypedModel, node: &TypedNode) -> Option<Deconv2x2> {
    use tract_onnx::tract_core::ops::cnn::{Deconv, PaddingSpec};
    use tract_onnx::tract_core::ops::nn::DataFormat;
    let deconv = node.op_as::<Deconv>()?;
    let spec = &deconv.pool_spec;
    let twos = |v: &Option<TVec<usize>>| v.as_ref().is_some_and(|v| v.as_slice() == [2, 2]);
    let ones = |v: &Option<TVec<usize>>| v.as_ref().is_none_or(|v| v.iter().all(|&d| d == 1));
    let unpadded = match &spec.padding {
        PaddingSpec::Valid => true,
        PaddingSpec::Explicit(before, after) => before.iter().chain(after).all(|&p| p == 0),
        _ => false,
    };
    if deconv.group != 1
        || spec.data_format != DataFormat::NCHW
        || spec.kernel_shape.as_slice() != [2, 2]
        || !twos(&spec.strides)
        || !ones(&spec.dilations)
        || !unpadded
        || deconv.adjustments.iter().any(|&a| a != 0)
        || node.inputs.len() != 3
    {
        return None;
    }
    let fact = model.outlet_fact(node.inputs[0]).ok()?;
    if fact.datum_type != f32::datum_type() || fact.rank() != 4 {
        return None;
    }
    let kernel = model.outlet_fact(node.inputs[1]).ok()?.konst.clone()?;
    let bias = model.outlet_fact(node.inputs[2]).ok()?.konst.clone()?;
    // Whatever the kernel's layout, as [group = 1, O, C, 4].
    let kernel = deconv
        .kernel_format
        .kernel_as_group_o_i_hw(&kernel, 1)
        .ok()?;
    let &[1, o, c, 4] = kernel.shape() else {
        return None;
    };
    let values: Vec<f32> = kernel
        .to_plain_array_view::<f32>()
        .ok()?
        .iter()
        .copied()
        .collect();
    let kernel = ArrayView4::from_shape((o, c, 2, 2), &values).ok()?;
    let bias: Vec<f32> = bias
        .to_plain_array_view::<f32>()
        .ok()?
        .iter()
        .copied()
        .collect();
    Deconv2x2::new(kernel, &bias).ok()
}

/// Replaces every transposed convolution of the (decluttered) `model` that a [`Deconv2x2`]
/// computes by a [`Deconv2x2Op`], taking in the ReLU that follows it if any; returns how many.
pub fn use_deconv2x2(model: &mut TypedModel) -> TractResult<usize> {
    let mut replaced = 0;
    for id in model.eval_order()? {
        let node = model.node(id);
        let Some(deconv) = as_deconv2x2(model, node) else {
            continue;
        };
        let relu = crate::conv3x3::relu_after(model, node);
        let deconv = if relu.is_some() {
            deconv.with_relu()
        } else {
            deconv
        };
        let (name, x) = (node.name.clone(), node.inputs[0]);
        let op = Deconv2x2Op(Arc::new(deconv));
        let gone: TVec<usize> = std::iter::once(id).chain(relu).collect();
        crate::matching::replace(model, &name, op, &[x], relu.unwrap_or(id), &gone)?;
        replaced += 1;
    }
    Ok(replaced)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::pattern;
    use ndarray::{Array1, Array4};

    fn deconv(c_in: usize, c_out: usize, seed: u32) -> Deconv2x2 {
        let weights =
            Array4::from_shape_vec((c_out, c_in, 2, 2), pattern(c_out * c_in * 4, seed)).unwrap();
        let bias = Array1::from(pattern(c_out, seed + 1));
        Deconv2x2::new(weights.view(), bias.as_slice().unwrap()).unwrap()
    }

    #[test]
    fn matches_the_reference_exactly_on_every_isa_and_thread_count() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap();
        // The networks' shapes (narrowed), more channels than one call takes, odd sizes.
        for (i, &(c, o, (h, w))) in [
            (32, 16, (6, 200)),
            (64, 32, (3, 100)),
            (70, 6, (5, 17)),
            (1, 2, (1, 1)),
            (5, 4, (7, 33)),
        ]
        .iter()
        .enumerate()
        {
            let d = deconv(c, o, i as u32);
            let d = if i % 2 == 0 { d.with_relu() } else { d };
            let input = pattern(c * h * w, i as u32 + 9);
            let want = d
                .reference(ArrayView3::from_shape((c, h, w), &input).unwrap())
                .unwrap();
            for isa in neuspike_simd::Isa::ALL
                .into_iter()
                .filter(|i| i.is_supported())
            {
                for pool in [None, Some(&pool)] {
                    let mut got = vec![f32::NAN; want.len()];
                    d.run_on(isa, &input, (h, w), &mut got, pool).unwrap();
                    assert_eq!(
                        got.as_slice(),
                        want.as_slice().unwrap(),
                        "{c}->{o} at {h}x{w}, {isa:?}, pool {}",
                        pool.is_some()
                    );
                }
            }
        }
    }

    #[test]
    fn refuses_what_it_cannot_compute() {
        let w = |shape: (usize, usize, usize, usize)| {
            Array4::from_shape_vec(shape, pattern(shape.0 * shape.1 * shape.2 * shape.3, 1))
                .unwrap()
        };
        assert_eq!(
            Deconv2x2::new(w((4, 2, 3, 3)).view(), &[0.0]).unwrap_err(),
            Deconv2x2Error::Weights(vec![4, 2, 3, 3])
        );
        assert_eq!(
            Deconv2x2::new(w((3, 2, 2, 2)).view(), &[0.0]).unwrap_err(),
            Deconv2x2Error::Channels(3)
        );
        assert!(matches!(
            Deconv2x2::new(w((4, 2, 2, 2)).view(), &[0.0; 3]),
            Err(Deconv2x2Error::Bias { got: 3, .. })
        ));
        let d = deconv(2, 4, 3);
        let mut out = vec![0.0; 4 * 4 * 6];
        assert!(d.run(&[0.0; 2 * 2 * 3], (2, 3), &mut out, None).is_ok());
        for (len, hw, out_len) in [(11, (2, 3), 96), (12, (2, 3), 95), (12, (3, 2), 95)] {
            let mut out = vec![0.0; out_len];
            let err = d.run(&vec![1.0; len], hw, &mut out, None);
            assert!(
                matches!(err, Err(Deconv2x2Error::Shape { .. })),
                "{len} {hw:?} {out_len}"
            );
            assert!(out.iter().all(|&v| v == 0.0));
        }
    }

    /// A one-node model of tract's own transposed convolution (its kernel `[O, C, 2, 2]`, as
    /// tract-onnx wires ONNX's `ConvTranspose`), a ReLU after it when `relu`.
    fn tract_deconv(d: &Deconv2x2, (h, w): (usize, usize)) -> TypedModel {
        use tract_onnx::tract_core::ops::cnn::{Deconv, KernelFormat, PaddingSpec, PoolSpec};
        use tract_onnx::tract_core::ops::nn::DataFormat;
        let (c, o) = (d.c_in, d.c_out);
        let kernel: Vec<f32> = (0..o * c * 4)
            .map(|i| d.weight(i / (4 * c), i / 4 % c, i % 4 / 2, i % 2))
            .collect();
        let mut model = TypedModel::default();
        let x = model.add_source("x", f32::fact([1, c, h, w])).unwrap();
        let k = model
            .add_const("k", Tensor::from_shape(&[o, c, 2, 2], &kernel).unwrap())
            .unwrap();
        let b = model
            .add_const("b", Tensor::from_shape(&[o], &d.bias).unwrap())
            .unwrap();
        let op = Deconv {
            pool_spec: PoolSpec {
                data_format: DataFormat::NCHW,
                kernel_shape: tvec![2, 2],
                padding: PaddingSpec::Valid,
                dilations: None,
                strides: Some(tvec![2, 2]),
                input_channels: c,
                output_channels: o,
            },
            kernel_format: KernelFormat::OIHW,
            adjustments: tvec![0, 0],
            group: 1,
        };
        let mut y = model.wire_node("deconv", op, &[x, k, b]).unwrap();
        if d.relu {
            let zero = model.add_const("zero", tensor4(&[[[[0f32]]]])).unwrap();
            let relu = tract_onnx::tract_core::ops::math::max();
            y = model.wire_node("relu", relu, &[y[0], zero]).unwrap();
        }
        model.select_output_outlets(&y).unwrap();
        model
    }

    #[test]
    fn the_operator_computes_what_tracts_transposed_convolution_does() {
        for (relu, (c, o, (h, w))) in [(true, (6, 4, (3, 5))), (false, (3, 8, (4, 2)))] {
            let d = deconv(c, o, 5);
            let d = if relu { d.with_relu() } else { d };
            let model = tract_deconv(&d, (h, w));
            let input = Tensor::from_shape(&[1, c, h, w], &pattern(c * h * w, 6)).unwrap();
            let run = |model: TypedModel| crate::testing::run_typed(model, &input);
            let (want_shape, want) = run(model.clone());
            let mut ours = model.into_decluttered().unwrap();
            assert_eq!(use_deconv2x2(&mut ours).unwrap(), 1);
            let ours = ours.into_decluttered().unwrap();
            let op = ours.nodes().iter().find_map(|n| n.op_as::<Deconv2x2Op>());
            assert_eq!(op.map(|op| op.0.relu()), Some(relu));
            assert_eq!(ours.nodes().len(), 2, "source and ours: {ours}");
            let (shape, got) = run(ours);
            assert_eq!(shape, want_shape);
            for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                // c products of values below 1 in another order: a few ulps.
                assert!((g - w).abs() < 1e-5, "{c}->{o}, value {i}: {g} vs {w}");
            }
        }
    }
}
