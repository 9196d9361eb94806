//! The learned networks' last layers as one operator: a 3x3 depthwise convolution (padding 1),
//! the 1x1 convolution to the output channels after it, and the sigmoid after that if any.
//!
//! tract runs them as three passes over the decoder's last feature (at full resolution, base 8:
//! 3.3 MB at 256x400), a depthwise convolution on one thread, a packing of its output for the
//! matrix product, the product; 0.85 ms of `neuspike-spike-8`'s 14 ms on 2 threads in 8 bits.
//! [`DepthwiseOut`] reads the feature once, row by row, each row's depthwise sums kept in a
//! scratch row while the 1x1 convolution takes them in, its output rows split across tract's
//! pool.
//!
//! [`DepthwiseOut::reference`] is the scalar definition; the fast path takes the same fused
//! multiply-adds in the same order, so the two agree exactly on every instruction set. tract
//! may sum in another order: the two differ by rounding (tests bound it).

use std::sync::Arc;

use ndarray::{Array3, ArrayView3};
use tract_onnx::prelude::*;
use tract_onnx::tract_core::internal::*;

/// Taps of the depthwise kernel.
const TAPS: usize = 9;

/// A 3x3 depthwise convolution (padding 1, stride 1) of `C` channels, a 1x1 convolution from
/// them to `O` channels, and optionally a sigmoid.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthwiseOut {
    channels: usize,
    outs: usize,
    /// `[C][3][3]`.
    depthwise: Vec<f32>,
    /// `[C]`.
    depthwise_bias: Vec<f32>,
    /// `[O][C]`.
    pointwise: Vec<f32>,
    /// `[O]`.
    pointwise_bias: Vec<f32>,
    sigmoid: bool,
}

impl DepthwiseOut {
    /// From the depthwise kernel (`[C, 1, 3, 3]` in ONNX's layout: `9 C` values) and bias (`C`),
    /// and the 1x1 kernel (`[O, C, 1, 1]`: `O C` values) and bias (`O`); `None` when the sizes
    /// do not fit together or a count is 0.
    pub fn new(
        depthwise: &[f32],
        depthwise_bias: &[f32],
        pointwise: &[f32],
        pointwise_bias: &[f32],
    ) -> Option<DepthwiseOut> {
        let channels = depthwise_bias.len();
        let outs = pointwise_bias.len();
        let fits = channels > 0
            && outs > 0
            && depthwise.len() == TAPS * channels
            && pointwise.len() == outs * channels;
        fits.then(|| DepthwiseOut {
            channels,
            outs,
            depthwise: depthwise.to_vec(),
            depthwise_bias: depthwise_bias.to_vec(),
            pointwise: pointwise.to_vec(),
            pointwise_bias: pointwise_bias.to_vec(),
            sigmoid: false,
        })
    }

    /// The same layers followed by the sigmoid, `1 / (1 + exp(-z))`.
    pub fn with_sigmoid(self) -> DepthwiseOut {
        DepthwiseOut {
            sigmoid: true,
            ..self
        }
    }

    /// Whether a sigmoid ends it.
    pub fn sigmoid(&self) -> bool {
        self.sigmoid
    }

    /// Input channels.
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Output channels.
    pub fn outs(&self) -> usize {
        self.outs
    }

    /// The scalar definition on `x` (`[C, H, W]`): each channel's depthwise sum `d` is its bias
    /// then one fused multiply-add per tap (kernel row, column; 0 off the image); output `o` is
    /// its bias then one fused multiply-add per channel in order, `pointwise[o][c] * d[c]`;
    /// then the sigmoid if any (0 for `-inf`, 1 for `+inf`, NaN for NaN).
    ///
    /// # Panics
    /// When `x` does not have `C` channels.
    pub fn reference(&self, x: ArrayView3<f32>) -> Array3<f32> {
        let (c, h, w) = x.dim();
        assert_eq!(c, self.channels, "channels");
        let d = Array3::from_shape_fn((c, h, w), |(k, y, i)| {
            let mut z = self.depthwise_bias[k];
            for ky in 0..3 {
                for kx in 0..3 {
                    let (yy, xx) = ((y + ky).wrapping_sub(1), (i + kx).wrapping_sub(1));
                    let v = if yy < h && xx < w {
                        x[[k, yy, xx]]
                    } else {
                        0.0
                    };
                    z = self.depthwise[k * TAPS + ky * 3 + kx].mul_add(v, z);
                }
            }
            z
        });
        Array3::from_shape_fn((self.outs, h, w), |(o, y, i)| {
            let mut z = self.pointwise_bias[o];
            for k in 0..c {
                z = self.pointwise[o * c + k].mul_add(d[[k, y, i]], z);
            }
            if self.sigmoid {
                crate::attention::sigmoid(z)
            } else {
                z
            }
        })
    }

    /// [`reference`](Self::reference) of `x` (`[C, H, W]`, row-major) into `out` (`[O, H,
    /// W]`), rows split across `pool` (or this thread when `None`).
    ///
    /// # Errors
    /// A message when `x` or `out` is not of that size.
    pub fn run(
        &self,
        x: &[f32],
        hw: (usize, usize),
        out: &mut [f32],
        pool: Option<&rayon::ThreadPool>,
    ) -> Result<(), String> {
        self.run_on(neuspike_simd::detect(), x, hw, out, pool)
    }

    /// [`run`](Self::run) compiled for `isa` (or the widest below it this CPU has).
    pub fn run_on(
        &self,
        isa: neuspike_simd::Isa,
        x: &[f32],
        (h, w): (usize, usize),
        out: &mut [f32],
        pool: Option<&rayon::ThreadPool>,
    ) -> Result<(), String> {
        let plane = h.checked_mul(w);
        let n_in = plane.and_then(|p| p.checked_mul(self.channels));
        let n_out = plane.and_then(|p| p.checked_mul(self.outs));
        if Some(x.len()) != n_in || Some(out.len()) != n_out {
            return Err(format!(
                "{} values in and {} out for {}x{h}x{w} to {} channels",
                x.len(),
                out.len(),
                self.channels,
                self.outs
            ));
        }
        if h == 0 || w == 0 {
            return Ok(());
        }
        let rows = crate::bands::band_rows(h, pool);
        let tasks = crate::bands::row_bands(out, h * w, w, rows);
        crate::bands::for_each(tasks, pool, |(y0, mut planes)| {
            neuspike_simd::with_isa(
                isa,
                #[inline(always)]
                || self.band(x, (h, w), y0, &mut planes),
            )
        });
        Ok(())
    }

    /// Output rows `y0..` of every plane in `planes`.
    #[inline(always)]
    fn band(&self, x: &[f32], (h, w): (usize, usize), y0: usize, planes: &mut [&mut [f32]]) {
        let c = self.channels;
        // Three input rows with a zero on either side, and one channel's depthwise sums.
        let pw = w + 2;
        let mut rows = vec![0f32; 3 * pw];
        let mut d = vec![0f32; w];
        let n_rows = planes.first().map_or(0, |p| p.len() / w);
        for y in y0..y0 + n_rows {
            for (o, plane) in planes.iter_mut().enumerate() {
                plane[(y - y0) * w..][..w].fill(self.pointwise_bias[o]);
            }
            for k in 0..c {
                for (ky, row) in rows.chunks_exact_mut(pw).enumerate() {
                    let yy = (y + ky).wrapping_sub(1);
                    let body = &mut row[1..=w];
                    if yy < h {
                        body.copy_from_slice(&x[(k * h + yy) * w..][..w]);
                    } else {
                        body.fill(0.0);
                    }
                }
                d.fill(self.depthwise_bias[k]);
                for (ky, row) in rows.chunks_exact(pw).enumerate() {
                    for kx in 0..3 {
                        let wt = self.depthwise[k * TAPS + ky * 3 + kx];
                        for (z, &v) in d.iter_mut().zip(&row[kx..kx + w]) {
                            *z = wt.mul_add(v, *z);
                        }
                    }
                }
                for (o, plane) in planes.iter_mut().enumerate() {
                    let wt = self.pointwise[o * c + k];
                    let dst = &mut plane[(y - y0) * w..][..w];
                    for (z, &v) in dst.iter_mut().zip(&d) {
                        *z = wt.mul_add(v, *z);
                    }
                }
            }
            if self.sigmoid {
                for plane in planes.iter_mut() {
                    for z in &mut plane[(y - y0) * w..][..w] {
                        *z = crate::attention::sigmoid(*z);
                    }
                }
            }
        }
    }
}

/// The tract operator running a [`DepthwiseOut`] on `[1, C, H, W]` input.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthwiseOutOp(pub Arc<DepthwiseOut>);

impl Eq for DepthwiseOutOp {}

impl Op for DepthwiseOutOp {
    fn name(&self) -> StaticName {
        "NeuspikeDepthwiseOut".into()
    }

    fn info(&self) -> TractResult<Vec<String>> {
        let d = &self.0;
        Ok(vec![format!(
            "{} -> {}{}",
            d.channels,
            d.outs,
            if d.sigmoid { ", sigmoid" } else { "" }
        )])
    }

    op_as_typed_op!();
}

impl EvalOp for DepthwiseOutOp {
    op_out_of_plan!();

    fn eval(&self, _ctx: &EvalContext, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let x = args_1!(inputs);
        let &[1, c, h, w] = x.shape() else {
            bail!(
                "NeuspikeDepthwiseOut takes [1, C, H, W], got {:?}",
                x.shape()
            );
        };
        ensure!(
            c == self.0.channels,
            "NeuspikeDepthwiseOut of {} channels given {c}",
            self.0.channels
        );
        let x = x.try_as_plain_ram()?;
        let pool = crate::bands::tract_pool();
        let y = crate::bands::output_tensor(&[1, self.0.outs, h, w], |y| {
            self.0
                .run(x.as_slice::<f32>()?, (h, w), y, pool.as_deref())
                .map_err(|e| format_err!("{e}"))
        })?;
        Ok(tvec!(y))
    }
}

impl TypedOp for DepthwiseOutOp {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        let [x] = inputs else {
            bail!("NeuspikeDepthwiseOut takes one input");
        };
        ensure!(x.datum_type == f32::datum_type() && x.rank() == 4);
        let mut shape = x.shape.clone();
        shape.set(1, self.0.outs.into());
        Ok(tvec!(f32::fact(shape)))
    }

    as_op!();
}

/// The [`DepthwiseOut`] computing `node` and the 1x1 convolution (and sigmoid) after it, with
/// the last node it takes over.
fn as_depthwise_out(model: &TypedModel, node: &TypedNode) -> Option<(DepthwiseOut, usize)> {
    use crate::matching::{conv_node, only_reader};
    let dw = conv_node(model, node)?;
    let c = dw.group;
    let fits = dw.kernel_size == [3, 3] && dw.stride == 1 && dw.pad == 1;
    if !fits || dw.shape != [c, 1, 3, 3] || dw.bias.len() != c {
        return None;
    }
    let next = model.node(only_reader(model, node)?);
    let pw = conv_node(model, next)?;
    let &[o, pc, 1, 1] = pw.shape.as_slice() else {
        return None;
    };
    if pw.group != 1 || pw.stride != 1 || pw.pad != 0 || pc != c || pw.bias.len() != o {
        return None;
    }
    let op = DepthwiseOut::new(&dw.kernel, &dw.bias, &pw.kernel, &pw.bias)?;
    match only_reader(model, next).map(|s| model.node(s)) {
        Some(sig) if sig.op().name() == "Sigmoid" && sig.inputs.len() == 1 => {
            Some((op.with_sigmoid(), sig.id))
        }
        _ => Some((op, next.id)),
    }
}

/// Replaces every 3x3 depthwise convolution of the typed `model` read only by a 1x1
/// convolution (and that by a sigmoid, if so) by a [`DepthwiseOutOp`]; returns how many. It
/// runs before tract declutters the model: decluttering turns a 1x1 convolution into a matrix
/// product and a bias.
pub fn use_depthwise_out(model: &mut TypedModel) -> TractResult<usize> {
    let mut replaced = 0;
    for id in model.eval_order()? {
        let node = model.node(id);
        let Some((op, last)) = as_depthwise_out(model, node) else {
            continue;
        };
        let (name, x) = (node.name.clone(), node.inputs[0]);
        crate::matching::replace(model, &name, DepthwiseOutOp(Arc::new(op)), &[x], last, &[])?;
        replaced += 1;
    }
    Ok(replaced)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::pattern;

    fn layers(c: usize, o: usize, seed: u32) -> DepthwiseOut {
        DepthwiseOut::new(
            &pattern(9 * c, seed),
            &pattern(c, seed + 1),
            &pattern(o * c, seed + 2),
            &pattern(o, seed + 3),
        )
        .unwrap()
    }

    #[test]
    fn matches_the_reference_exactly_on_every_isa_and_thread_count() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap();
        for (i, &(c, o, h, w, sigmoid)) in [
            (8, 1, 9, 50, true),
            (1, 1, 1, 1, false),
            (3, 2, 4, 7, true),
            (5, 3, 13, 21, false),
        ]
        .iter()
        .enumerate()
        {
            let d = layers(c, o, i as u32);
            let d = if sigmoid { d.with_sigmoid() } else { d };
            let x = pattern(c * h * w, 10 + i as u32);
            let want = d.reference(ArrayView3::from_shape((c, h, w), &x).unwrap());
            for isa in neuspike_simd::Isa::ALL
                .into_iter()
                .filter(|i| i.is_supported())
            {
                for pool in [None, Some(&pool)] {
                    let mut got = vec![f32::NAN; o * h * w];
                    d.run_on(isa, &x, (h, w), &mut got, pool).unwrap();
                    assert_eq!(
                        got.as_slice(),
                        want.as_slice().unwrap(),
                        "{c}->{o} {h}x{w} {isa:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn extremes_and_bad_sizes() {
        // One channel, the centre tap 1, no biases: the sigmoid of the input itself.
        let mut k = [0.0; 9];
        k[4] = 1.0;
        let d = DepthwiseOut::new(&k, &[0.0], &[1.0], &[0.0])
            .unwrap()
            .with_sigmoid();
        for (x, want) in [
            (f32::INFINITY, Some(1.0)),
            (f32::NEG_INFINITY, Some(0.0)),
            (f32::NAN, None),
            (2.0, Some(crate::attention::sigmoid(2.0))),
        ] {
            let mut y = [0.0];
            d.run(&[x], (1, 1), &mut y, None).unwrap();
            match want {
                Some(v) => assert_eq!(y[0], v, "{x}"),
                None => assert!(y[0].is_nan(), "{x}: {}", y[0]),
            }
        }
        let mut y = [0.0; 4];
        assert!(d.run(&[1.0; 3], (2, 2), &mut y, None).is_err());
        assert!(d.run(&[1.0; 4], (2, 2), &mut y[..3], None).is_err());
        assert!(d.run(&[1.0; 4], (usize::MAX, 2), &mut y, None).is_err());
        assert!(DepthwiseOut::new(&k, &[0.0], &[1.0, 2.0], &[0.0]).is_none());
        assert!(DepthwiseOut::new(&[], &[], &[], &[]).is_none());
    }

    /// tract's own depthwise 3x3, 1x1 and sigmoid, wired as tract-onnx declutters the ONNX ones.
    fn tract_layers(d: &DepthwiseOut, (h, w): (usize, usize)) -> TypedModel {
        use tract_onnx::tract_core::ops::cnn::{Conv, KernelFormat, PaddingSpec, PoolSpec};
        use tract_onnx::tract_core::ops::nn::DataFormat;
        let (c, o) = (d.channels, d.outs);
        let mut model = TypedModel::default();
        let x = model.add_source("x", f32::fact([1, c, h, w])).unwrap();
        let conv = |k: usize, pad: usize, group: usize, outs: usize| Conv {
            pool_spec: PoolSpec {
                data_format: DataFormat::NCHW,
                kernel_shape: tvec![k, k],
                padding: PaddingSpec::Explicit(tvec![pad, pad], tvec![pad, pad]),
                dilations: None,
                strides: None,
                input_channels: c,
                output_channels: outs,
            },
            kernel_fmt: KernelFormat::OIHW,
            group,
            q_params: None,
        };
        let konst = |model: &mut TypedModel, name: &str, shape: &[usize], v: &[f32]| {
            model
                .add_const(name, Tensor::from_shape(shape, v).unwrap())
                .unwrap()
        };
        let k = konst(&mut model, "dk", &[c, 1, 3, 3], &d.depthwise);
        let b = konst(&mut model, "db", &[c], &d.depthwise_bias);
        let y = model.wire_node("dw", conv(3, 1, c, c), &[x, k, b]).unwrap();
        let k = konst(&mut model, "pk", &[o, c, 1, 1], &d.pointwise);
        let b = konst(&mut model, "pb", &[o], &d.pointwise_bias);
        let mut y = model
            .wire_node("pw", conv(1, 0, 1, o), &[y[0], k, b])
            .unwrap();
        if d.sigmoid {
            y = model
                .wire_node("sig", tract_onnx::tract_core::ops::nn::sigmoid(), &y)
                .unwrap();
        }
        model.select_output_outlets(&y).unwrap();
        model
    }

    #[test]
    fn the_operator_computes_what_tracts_layers_do() {
        for (sigmoid, (c, o, (h, w))) in [(true, (8, 1, (6, 40))), (false, (3, 2, (4, 5)))] {
            let d = layers(c, o, 7);
            let d = if sigmoid { d.with_sigmoid() } else { d };
            let model = tract_layers(&d, (h, w));
            let input = Tensor::from_shape(&[1, c, h, w], &pattern(c * h * w, 8)).unwrap();
            let run = |model: TypedModel| crate::testing::run_typed(model, &input);
            let (want_shape, want) = run(model.clone());
            let mut ours = model.clone();
            assert_eq!(use_depthwise_out(&mut ours).unwrap(), 1, "{ours}");
            let ours = ours.into_decluttered().unwrap();
            let op = ours
                .nodes()
                .iter()
                .find_map(|n| n.op_as::<DepthwiseOutOp>());
            assert_eq!(op.map(|op| op.0.sigmoid()), Some(sigmoid));
            assert_eq!(ours.nodes().len(), 2, "source and ours: {ours}");
            let (shape, got) = run(ours);
            assert_eq!(shape, want_shape);
            for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                // Sums of a few products of values below 1 in another order, and tract's
                // sigmoid (a rational approximation): a few ulps.
                assert!((g - w).abs() < 1e-5, "{c}->{o}, value {i}: {g} vs {w}");
            }
        }
    }
}
