//! The last layers of a network whose decoder stops at half resolution (the `-lite` networks,
//! `features: half` in `training/neuspike_net.py`) as one operator: the sub-pixel shuffle of its
//! 4-channel half-resolution output (channel `2 i + j` is the pixel `(2 y + i, 2 x + j)` of the
//! 2x2 block below point `(y, x)`), plus a 1x1 convolution to one channel of each path's
//! full-resolution head feature, then the sigmoid.
//!
//! tract runs them as a four-step shuffle (two of them moving every value), a packing of each
//! head feature for a matrix product, the product and two passes for the sum and the sigmoid:
//! 0.8 ms of `neuspike-spike-8-lite`'s 8.7 ms on 2 threads in 8 bits at 256x400. [`SubpixelOut`]
//! writes each output row once, its rows split across tract's pool.
//!
//! [`SubpixelOut::reference`] is the scalar definition; the fast path takes the same operations
//! in the same order, so the two agree exactly on every instruction set. tract may sum in
//! another order: the two differ by rounding (tests bound it).

use std::sync::Arc;

use ndarray::{Array2, ArrayView3};
use tract_onnx::prelude::*;
use tract_onnx::tract_core::internal::*;
use tract_onnx::tract_core::ops::change_axes::AxisOp;

/// The half-resolution output's channels: the 2x2 block below each point.
pub const BLOCK: usize = 4;

/// The largest half-resolution output whose shuffle [`use_subpixel_out`] checks by running
/// tract's own steps on the values' indices (exact in `f32` up to 2^24).
const MAX_CHECKED: usize = 1 << 24;

/// One path's 1x1 convolution of its head feature to one channel.
#[derive(Clone, Debug, PartialEq)]
pub struct Detail {
    /// `[C]`.
    weights: Vec<f32>,
    bias: f32,
}

impl Detail {
    /// From the 1x1 kernel (`[1, C, 1, 1]` in ONNX's layout: `C` values) and bias; `None` when
    /// there are no weights.
    pub fn new(weights: &[f32], bias: f32) -> Option<Detail> {
        (!weights.is_empty()).then(|| Detail {
            weights: weights.to_vec(),
            bias,
        })
    }

    /// Channels of the head feature it reads.
    pub fn channels(&self) -> usize {
        self.weights.len()
    }
}

/// The shuffle of a `[4, h, w]` output to `[2h, 2w]`, plus each [`Detail`] of its
/// `[C_p, 2h, 2w]` head feature, then the sigmoid.
#[derive(Clone, Debug, PartialEq)]
pub struct SubpixelOut {
    details: Vec<Detail>,
}

impl SubpixelOut {
    /// The operator adding `details` in order; `None` when there is none.
    pub fn new(details: Vec<Detail>) -> Option<SubpixelOut> {
        (!details.is_empty()).then_some(SubpixelOut { details })
    }

    /// The head features it reads, in order.
    pub fn details(&self) -> &[Detail] {
        &self.details
    }

    /// The scalar definition: output `(Y, X)` is `z = coarse[2 (Y % 2) + X % 2][Y / 2][X / 2]`,
    /// then for each detail in order `z = z + d`, where `d` is its bias then one fused
    /// multiply-add per channel in order, `weights[c] * head[c][Y][X]`; then the sigmoid (0 for
    /// `-inf`, 1 for `+inf`, NaN for NaN).
    ///
    /// # Panics
    /// When the shapes do not fit: `coarse` of 4 channels, each head of its detail's channels
    /// and twice `coarse`'s height and width.
    pub fn reference(&self, coarse: ArrayView3<f32>, heads: &[ArrayView3<f32>]) -> Array2<f32> {
        let (b, h, w) = coarse.dim();
        assert_eq!(b, BLOCK, "coarse channels");
        assert_eq!(heads.len(), self.details.len(), "heads");
        for (x, d) in heads.iter().zip(&self.details) {
            assert_eq!(x.dim(), (d.channels(), 2 * h, 2 * w), "head shape");
        }
        Array2::from_shape_fn((2 * h, 2 * w), |(y, x)| {
            let mut z = coarse[[2 * (y % 2) + x % 2, y / 2, x / 2]];
            for (head, d) in heads.iter().zip(&self.details) {
                let mut s = d.bias;
                for (c, &wt) in d.weights.iter().enumerate() {
                    s = wt.mul_add(head[[c, y, x]], s);
                }
                z += s;
            }
            crate::attention::sigmoid(z)
        })
    }

    /// [`reference`](Self::reference) of `coarse` (`[4, h, w]`, row-major) and `heads` (each
    /// `[C_p, 2h, 2w]`) into `out` (`[2h, 2w]`), rows split across `pool` (or this thread when
    /// `None`).
    ///
    /// # Errors
    /// A message when an input or `out` is not of that size.
    pub fn run(
        &self,
        coarse: &[f32],
        heads: &[&[f32]],
        hw: (usize, usize),
        out: &mut [f32],
        pool: Option<&rayon::ThreadPool>,
    ) -> Result<(), String> {
        self.run_on(neuspike_simd::detect(), coarse, heads, hw, out, pool)
    }

    /// [`run`](Self::run) compiled for `isa` (or the widest below it this CPU has); `(h, w)` is
    /// `coarse`'s size.
    pub fn run_on(
        &self,
        isa: neuspike_simd::Isa,
        coarse: &[f32],
        heads: &[&[f32]],
        (h, w): (usize, usize),
        out: &mut [f32],
        pool: Option<&rayon::ThreadPool>,
    ) -> Result<(), String> {
        let half = h.checked_mul(w);
        let plane = half.and_then(|p| p.checked_mul(BLOCK));
        let fits = Some(coarse.len()) == plane
            && Some(out.len()) == plane
            && heads.len() == self.details.len()
            && heads
                .iter()
                .zip(&self.details)
                .all(|(x, d)| Some(x.len()) == plane.and_then(|p| p.checked_mul(d.channels())));
        if !fits {
            let sizes: Vec<usize> = heads.iter().map(|x| x.len()).collect();
            return Err(format!(
                "{} values of coarse output, heads of {sizes:?} and {} out for a {h}x{w} coarse \
                 output and heads of {:?} channels",
                coarse.len(),
                out.len(),
                self.details
                    .iter()
                    .map(Detail::channels)
                    .collect::<Vec<_>>()
            ));
        }
        if h == 0 || w == 0 {
            return Ok(());
        }
        let (ho, wo) = (2 * h, 2 * w);
        let rows = crate::bands::band_rows(ho, pool);
        let tasks = crate::bands::row_bands(out, ho * wo, wo, rows);
        crate::bands::for_each(tasks, pool, |(y0, mut planes)| {
            neuspike_simd::with_isa(
                isa,
                #[inline(always)]
                || self.band(coarse, heads, (h, w), y0, &mut planes),
            )
        });
        Ok(())
    }

    /// Output rows `y0..` of the one plane in `planes`.
    #[inline(always)]
    fn band(
        &self,
        coarse: &[f32],
        heads: &[&[f32]],
        (h, w): (usize, usize),
        y0: usize,
        planes: &mut [&mut [f32]],
    ) {
        let (ho, wo) = (2 * h, 2 * w);
        let Some(plane) = planes.first_mut() else {
            return;
        };
        // One detail's sums along the row.
        let mut d = vec![0f32; wo];
        for (r, dst) in plane.chunks_exact_mut(wo).enumerate() {
            let y = y0 + r;
            let (i, yc) = (y % 2, y / 2);
            let left = &coarse[((2 * i) * h + yc) * w..][..w];
            let right = &coarse[((2 * i + 1) * h + yc) * w..][..w];
            for ((pair, &a), &b) in dst.chunks_exact_mut(2).zip(left).zip(right) {
                pair[0] = a;
                pair[1] = b;
            }
            for (head, detail) in heads.iter().zip(&self.details) {
                d.fill(detail.bias);
                for (c, &wt) in detail.weights.iter().enumerate() {
                    let row = &head[(c * ho + y) * wo..][..wo];
                    for (s, &v) in d.iter_mut().zip(row) {
                        *s = wt.mul_add(v, *s);
                    }
                }
                for (z, &s) in dst.iter_mut().zip(&d) {
                    *z += s;
                }
            }
            for z in dst.iter_mut() {
                *z = crate::attention::sigmoid(*z);
            }
        }
    }
}

/// The tract operator running a [`SubpixelOut`] on the coarse output `[1, 4, h, w]` and each
/// head feature `[1, C_p, 2h, 2w]`, in that order.
#[derive(Clone, Debug, PartialEq)]
pub struct SubpixelOutOp(pub Arc<SubpixelOut>);

impl Eq for SubpixelOutOp {}

impl Op for SubpixelOutOp {
    fn name(&self) -> StaticName {
        "NeuspikeSubpixelOut".into()
    }

    fn info(&self) -> TractResult<Vec<String>> {
        let channels: Vec<usize> = self.0.details.iter().map(Detail::channels).collect();
        Ok(vec![format!(
            "2x2 shuffle of {BLOCK} channels, plus heads of {channels:?} channels, sigmoid"
        )])
    }

    op_as_typed_op!();
}

impl EvalOp for SubpixelOutOp {
    op_out_of_plan!();

    fn eval(&self, _ctx: &EvalContext, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let Some((coarse, heads)) = inputs.split_first() else {
            bail!("NeuspikeSubpixelOut takes the coarse output and the head features");
        };
        let &[1, BLOCK, h, w] = coarse.shape() else {
            bail!(
                "NeuspikeSubpixelOut takes a [1, {BLOCK}, h, w] coarse output, got {:?}",
                coarse.shape()
            );
        };
        ensure!(
            heads.len() == self.0.details.len(),
            "NeuspikeSubpixelOut of {} head features given {}",
            self.0.details.len(),
            heads.len()
        );
        for (x, d) in heads.iter().zip(&self.0.details) {
            ensure!(
                x.shape() == [1, d.channels(), 2 * h, 2 * w],
                "NeuspikeSubpixelOut: head feature of shape {:?} for a {h}x{w} coarse output of \
                 {} channels",
                x.shape(),
                d.channels()
            );
        }
        let coarse = coarse.try_as_plain_ram()?;
        let plain = heads
            .iter()
            .map(|x| x.try_as_plain_ram())
            .collect::<TractResult<TVec<_>>>()?;
        let values = plain
            .iter()
            .map(|p| p.as_slice::<f32>())
            .collect::<TractResult<TVec<_>>>()?;
        let pool = crate::bands::tract_pool();
        let y = crate::bands::output_tensor(&[1, 1, 2 * h, 2 * w], |y| {
            self.0
                .run(
                    coarse.as_slice::<f32>()?,
                    &values,
                    (h, w),
                    y,
                    pool.as_deref(),
                )
                .map_err(|e| format_err!("{e}"))
        })?;
        Ok(tvec!(y))
    }
}

impl TypedOp for SubpixelOutOp {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        let [coarse, heads @ ..] = inputs else {
            bail!("NeuspikeSubpixelOut takes the coarse output and the head features");
        };
        ensure!(coarse.datum_type == f32::datum_type() && coarse.rank() == 4);
        ensure!(heads.len() == self.0.details.len());
        let mut shape = coarse.shape.clone();
        shape.set(1, 1.into());
        shape.set(2, coarse.shape[2].clone() * 2);
        shape.set(3, coarse.shape[3].clone() * 2);
        for x in heads {
            ensure!(x.datum_type == f32::datum_type() && x.rank() == 4);
            ensure!(x.shape[2..] == shape[2..]);
        }
        Ok(tvec!(f32::fact(shape)))
    }

    as_op!();
}

/// The terms of the sum an `Add` node of `model` starts (that node's own outlet when it is not
/// an `Add` read only by the sum), in order, and the `Add` nodes taken with them.
fn sum_terms(
    model: &TypedModel,
    outlet: OutletId,
    terms: &mut Vec<OutletId>,
    adds: &mut Vec<usize>,
) {
    let node = model.node(outlet.node);
    let inner = node.op().name() == "Add"
        && node.inputs.len() == 2
        && crate::matching::only_reader(model, node).is_some();
    if inner {
        adds.push(node.id);
        for &input in &node.inputs {
            sum_terms(model, input, terms, adds);
        }
    } else {
        terms.push(outlet);
    }
}

/// The outlet whose `[1, 4, h, w]` values the nodes ending at `outlet` shuffle to `[1, 1, 2h,
/// 2w]` as [`SubpixelOut::reference`] does, if they do: a chain of tract's axis operations
/// (tract-onnx's `DepthToSpace` of block 2, in either mode), each read only by the next,
/// checked by running them on the values' indices.
fn shuffled(model: &TypedModel, outlet: OutletId) -> Option<OutletId> {
    let mut chain = Vec::new();
    let mut at = outlet;
    loop {
        let node = model.node(at.node);
        if node.op_as::<AxisOp>().is_none() || node.inputs.len() != 1 {
            break;
        }
        if at != outlet && crate::matching::only_reader(model, node).is_none() {
            return None;
        }
        chain.push(node.id);
        at = node.inputs[0];
    }
    if chain.is_empty() {
        return None;
    }
    let concrete = |o: OutletId| -> Option<Vec<usize>> {
        let shape = &model.outlet_fact(o).ok()?.shape;
        shape.as_concrete().map(|s| s.to_vec())
    };
    let &[1, BLOCK, h, w] = concrete(at)?.as_slice() else {
        return None;
    };
    if concrete(outlet)? != [1, 1, 2 * h, 2 * w] || BLOCK * h * w > MAX_CHECKED {
        return None;
    }
    let indices: Vec<f32> = (0..BLOCK * h * w).map(|i| i as f32).collect();
    let mut value = Tensor::from_shape(&[1, BLOCK, h, w], &indices).ok()?;
    for &id in chain.iter().rev() {
        let op = model.node(id).op_as::<AxisOp>()?;
        op.change_tensor(&mut value, false).ok()?;
    }
    if value.shape() != [1, 1, 2 * h, 2 * w] {
        return None;
    }
    let got = value.to_plain_array_view::<f32>().ok()?;
    let exact = got.iter().enumerate().all(|(i, &v)| {
        let (y, x) = (i / (2 * w), i % (2 * w));
        v == ((2 * (y % 2) + x % 2) * h * w + (y / 2) * w + x / 2) as f32
    });
    exact.then_some(at)
}

/// The [`Detail`] a 1x1 convolution to one channel computes at `outlet`, and its input.
fn detail(model: &TypedModel, outlet: OutletId) -> Option<(Detail, OutletId)> {
    let node = model.node(outlet.node);
    let conv = crate::matching::conv_node(model, node)?;
    let &[1, _, 1, 1] = conv.shape.as_slice() else {
        return None;
    };
    let fits = conv.group == 1 && conv.stride == 1 && conv.pad == 0 && conv.bias.len() == 1;
    let d = Detail::new(&conv.kernel, *conv.bias.first()?)?;
    fits.then_some((d, node.inputs[0]))
}

/// The [`SubpixelOut`] a sigmoid `node` ends, with its inputs (the coarse output, then the head
/// features), if the sum it reads is one sub-pixel shuffle and 1x1 convolutions to one channel
/// (the shuffle first: the order of the operator's sum).
fn as_subpixel_out(model: &TypedModel, node: &TypedNode) -> Option<(SubpixelOut, TVec<OutletId>)> {
    if node.op().name() != "Sigmoid" || node.inputs.len() != 1 {
        return None;
    }
    let (mut terms, mut adds) = (Vec::new(), Vec::new());
    sum_terms(model, node.inputs[0], &mut terms, &mut adds);
    let [first, rest @ ..] = terms.as_slice() else {
        return None;
    };
    if adds.is_empty() {
        return None;
    }
    let coarse = shuffled(model, *first)?;
    let mut inputs = tvec![coarse];
    let mut details = Vec::new();
    for &term in rest {
        // Each term is read by the sum alone.
        crate::matching::only_reader(model, model.node(term.node))?;
        let (d, x) = detail(model, term)?;
        details.push(d);
        inputs.push(x);
    }
    Some((SubpixelOut::new(details)?, inputs))
}

/// Replaces every sigmoid of the typed `model` whose input is the sum of a sub-pixel shuffle
/// (`DepthToSpace` of a 4-channel output) and 1x1 convolutions of head features to one channel
/// by a [`SubpixelOutOp`]; returns how many. It runs before tract declutters the model:
/// decluttering turns a 1x1 convolution into a matrix product and a bias.
pub fn use_subpixel_out(model: &mut TypedModel) -> TractResult<usize> {
    let mut replaced = 0;
    for id in model.eval_order()? {
        let node = model.node(id);
        let Some((op, inputs)) = as_subpixel_out(model, node) else {
            continue;
        };
        let name = node.name.clone();
        crate::matching::replace(model, &name, SubpixelOutOp(Arc::new(op)), &inputs, id, &[])?;
        replaced += 1;
    }
    Ok(replaced)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::pattern;
    use ndarray::Array3;

    fn op(channels: &[usize], seed: u32) -> SubpixelOut {
        let details = channels
            .iter()
            .zip(seed..)
            .map(|(&c, s)| Detail::new(&pattern(c, s), pattern(1, s + 10)[0]).unwrap())
            .collect();
        SubpixelOut::new(details).unwrap()
    }

    #[test]
    fn matches_the_reference_exactly_on_every_isa_and_thread_count() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap();
        for (i, (channels, (h, w))) in [
            (vec![8], (8, 25)),
            (vec![8, 8], (5, 3)),
            (vec![1], (1, 1)),
            (vec![3, 5], (7, 13)),
        ]
        .into_iter()
        .enumerate()
        {
            let s = op(&channels, 3 * i as u32);
            let coarse = pattern(BLOCK * h * w, 40 + i as u32);
            // Values beyond the sigmoid's range too.
            let coarse: Vec<f32> = coarse.iter().map(|v| v * 30.0).collect();
            let heads: Vec<Vec<f32>> = channels
                .iter()
                .zip(50..)
                .map(|(&c, s)| pattern(c * 4 * h * w, s))
                .collect();
            let views: Vec<ArrayView3<f32>> = heads
                .iter()
                .zip(&channels)
                .map(|(x, &c)| ArrayView3::from_shape((c, 2 * h, 2 * w), x).unwrap())
                .collect();
            let coarse_view = ArrayView3::from_shape((BLOCK, h, w), &coarse).unwrap();
            let want = s.reference(coarse_view, &views);
            let slices: Vec<&[f32]> = heads.iter().map(Vec::as_slice).collect();
            for isa in neuspike_simd::Isa::ALL
                .into_iter()
                .filter(|i| i.is_supported())
            {
                for pool in [None, Some(&pool)] {
                    let mut got = vec![f32::NAN; 4 * h * w];
                    s.run_on(isa, &coarse, &slices, (h, w), &mut got, pool)
                        .unwrap();
                    assert_eq!(
                        got.as_slice(),
                        want.as_slice().unwrap(),
                        "{channels:?} {h}x{w} {isa:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn the_shuffle_puts_each_channel_at_its_pixel_of_the_block() {
        // No detail weight: the output is the sigmoid of the shuffled coarse values.
        let s = SubpixelOut::new(vec![Detail::new(&[0.0], 0.0).unwrap()]).unwrap();
        let coarse = Array3::from_shape_fn((BLOCK, 2, 3), |(c, y, x)| {
            (c * 100 + y * 10 + x) as f32 / 1000.0
        });
        let head = Array3::<f32>::zeros((1, 4, 6));
        let got = s.reference(coarse.view(), &[head.view()]);
        for (y, x, c, yc, xc) in [
            (0, 0, 0, 0, 0),
            (0, 1, 1, 0, 0),
            (1, 0, 2, 0, 0),
            (1, 1, 3, 0, 0),
            (3, 4, 2, 1, 2),
        ] {
            let want = crate::attention::sigmoid(coarse[[c, yc, xc]]);
            assert_eq!(got[[y, x]], want, "({y}, {x})");
        }
    }

    #[test]
    fn extremes_and_bad_sizes() {
        let s = SubpixelOut::new(vec![Detail::new(&[1.0], 0.0).unwrap()]).unwrap();
        for (z, want) in [
            (f32::INFINITY, Some(1.0)),
            (f32::NEG_INFINITY, Some(0.0)),
            (f32::NAN, None),
        ] {
            let mut y = [0.5; 4];
            s.run(&[z; 4], &[&[0.0; 4]], (1, 1), &mut y, None).unwrap();
            for v in y {
                match want {
                    Some(w) => assert_eq!(v, w, "{z}"),
                    None => assert!(v.is_nan(), "{z}: {v}"),
                }
            }
        }
        let mut y = [0.0; 4];
        assert!(
            s.run(&[0.0; 3], &[&[0.0; 4]], (1, 1), &mut y, None)
                .is_err()
        );
        assert!(
            s.run(&[0.0; 4], &[&[0.0; 3]], (1, 1), &mut y, None)
                .is_err()
        );
        assert!(s.run(&[0.0; 4], &[], (1, 1), &mut y, None).is_err());
        assert!(
            s.run(&[0.0; 4], &[&[0.0; 4]], (1, 1), &mut y[..3], None)
                .is_err()
        );
        assert!(
            s.run(&[0.0; 4], &[&[0.0; 4]], (usize::MAX, 2), &mut y, None)
                .is_err()
        );
        assert!(SubpixelOut::new(Vec::new()).is_none());
        assert!(Detail::new(&[], 0.0).is_none());
    }

    /// tract-onnx's `DepthToSpace` (as `mode`), 1x1 convolutions, their sum and the sigmoid.
    fn tract_layers(s: &SubpixelOut, (h, w): (usize, usize), mode: &str) -> TypedModel {
        use tract_onnx::tract_core::ops::cnn::{Conv, KernelFormat, PaddingSpec, PoolSpec};
        use tract_onnx::tract_core::ops::nn::DataFormat;
        let mut model = TypedModel::default();
        let coarse = model
            .add_source("coarse", f32::fact([1, BLOCK, h, w]))
            .unwrap();
        // DepthToSpace of block 2 as tract-onnx expands it (DCR and CRD agree for one channel).
        let from = tvec![BLOCK.into()];
        let to: TVec<TDim> = tvec![2.into(), 2.into(), 1.into()];
        let steps = match mode {
            "DCR" => vec![
                AxisOp::Reshape(1, from, to),
                AxisOp::Move(2, 5),
                AxisOp::Move(1, 3),
            ],
            // Pixel (2y + j, 2x + i) from channel 2i + j.
            "swapped" => vec![
                AxisOp::Reshape(1, from, to.into_iter().rev().collect()),
                AxisOp::Move(2, 5),
                AxisOp::Move(2, 3),
            ],
            _ => vec![
                AxisOp::Reshape(1, from, to.into_iter().rev().collect()),
                AxisOp::Move(3, 5),
                AxisOp::Move(2, 3),
            ],
        };
        let mut y = tvec![coarse];
        for (i, step) in steps.into_iter().enumerate() {
            y = model.wire_node(format!("d2s.{i}"), step, &y).unwrap();
        }
        let last = AxisOp::Reshape(
            2,
            tvec![h.into(), 2.into(), w.into(), 2.into()],
            tvec![(2 * h).into(), (2 * w).into()],
        );
        let mut sum = model.wire_node("d2s.last", last, &y).unwrap();
        for (p, d) in s.details.iter().enumerate() {
            let c = d.channels();
            let x = model
                .add_source(format!("head{p}"), f32::fact([1, c, 2 * h, 2 * w]))
                .unwrap();
            let conv = Conv {
                pool_spec: PoolSpec {
                    data_format: DataFormat::NCHW,
                    kernel_shape: tvec![1, 1],
                    padding: PaddingSpec::Valid,
                    dilations: None,
                    strides: None,
                    input_channels: c,
                    output_channels: 1,
                },
                kernel_fmt: KernelFormat::OIHW,
                group: 1,
                q_params: None,
            };
            let k = model
                .add_const(
                    format!("k{p}"),
                    Tensor::from_shape(&[1, c, 1, 1], &d.weights).unwrap(),
                )
                .unwrap();
            let b = model
                .add_const(
                    format!("b{p}"),
                    Tensor::from_shape(&[1], &[d.bias]).unwrap(),
                )
                .unwrap();
            let t = model.wire_node(format!("pw{p}"), conv, &[x, k, b]).unwrap();
            sum = model
                .wire_node(
                    format!("add{p}"),
                    tract_onnx::tract_core::ops::math::add(),
                    &[sum[0], t[0]],
                )
                .unwrap();
        }
        let y = model
            .wire_node("sig", tract_onnx::tract_core::ops::nn::sigmoid(), &sum)
            .unwrap();
        model.select_output_outlets(&y).unwrap();
        model
    }

    fn run_model(model: TypedModel, inputs: &[Tensor]) -> Vec<f32> {
        let plan = model.into_optimized().unwrap().into_runnable().unwrap();
        let out = plan
            .run(inputs.iter().cloned().map(|t| t.into_tvalue()).collect())
            .unwrap();
        let out = out[0].clone().into_tensor();
        out.to_plain_array_view::<f32>()
            .unwrap()
            .iter()
            .copied()
            .collect()
    }

    #[test]
    fn the_operator_computes_what_tracts_layers_do() {
        for (mode, channels, (h, w)) in [("CRD", vec![8], (6, 20)), ("DCR", vec![8, 8], (3, 5))] {
            let s = op(&channels, 11);
            let model = tract_layers(&s, (h, w), mode);
            let mut inputs =
                vec![Tensor::from_shape(&[1, BLOCK, h, w], &pattern(BLOCK * h * w, 1)).unwrap()];
            for (p, &c) in channels.iter().enumerate() {
                let x = pattern(c * 4 * h * w, 2 + p as u32);
                inputs.push(Tensor::from_shape(&[1, c, 2 * h, 2 * w], &x).unwrap());
            }
            let want = run_model(model.clone(), &inputs);
            let mut ours = model.clone();
            assert_eq!(use_subpixel_out(&mut ours).unwrap(), 1, "{mode}: {ours}");
            let ours = ours.into_decluttered().unwrap();
            let found = ours.nodes().iter().find_map(|n| n.op_as::<SubpixelOutOp>());
            assert_eq!(found.map(|op| op.0.details.len()), Some(channels.len()));
            assert_eq!(
                ours.nodes().len(),
                2 + channels.len(),
                "sources and ours: {ours}"
            );
            let got = run_model(ours, &inputs);
            assert_eq!(got.len(), want.len());
            for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                assert!(
                    (g - w).abs() < 1e-5,
                    "{mode} {channels:?}, value {i}: {g} vs {w}"
                );
            }
        }
    }

    #[test]
    fn another_arrangement_or_no_sum_is_left_to_tract() {
        let s = op(&[4], 5);
        // The block's rows and columns exchanged: not the shuffle, though of the same shape.
        let mut model = tract_layers(&s, (3, 4), "swapped");
        assert_eq!(use_subpixel_out(&mut model).unwrap(), 0);
        // A shuffle alone, no detail: nothing to fuse (tract's sigmoid is as fast).
        let mut model = TypedModel::default();
        let x = model.add_source("coarse", f32::fact([1, 4, 2, 2])).unwrap();
        let y = model
            .wire_node("sig", tract_onnx::tract_core::ops::nn::sigmoid(), &[x])
            .unwrap();
        model.select_output_outlets(&y).unwrap();
        assert_eq!(use_subpixel_out(&mut model).unwrap(), 0);
    }
}
