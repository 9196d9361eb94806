//! The attention of the learned networks' fusion modules as neuspike operators: the spatial
//! attention of the skip connections (Eq. 12), and the channel attention's products and their
//! sum ([`ScaledSumOp`], Eq. 11).
//!
//! The fusion module weights the fused features `x` of a scale by a map computed from `s = x +
//! d` (`d` the decoder's feature there): `y = x * sigmoid(conv7x7([mean_c s, max_c s]) + b)`.
//! tract runs it as some twenty nodes (the add, a channel sum and a scale for the mean, a tree of
//! channel slices and maxima for the max, a concatenation, the convolution, the sigmoid, the
//! product), each a pass over megabytes on one thread: about 5 of a base-16 network's 49 ms at
//! 256x400 on 2 threads. [`SpatialAttention`] reads `x` and `d` once for the two maps, then `x`
//! once more for the product, its rows split across tract's pool.
//!
//! `x` is the channel attention's output, `sum_p x_p * g_p` ([`ScaledSumOp`]). Where nothing
//! else reads it, the attention takes the products' inputs ([`Scaled`]) and forms `x` row by
//! row as it goes, in the same operations: `x` is never written out (at full resolution, base 8,
//! a pass of 3.3 MB written and two read).
//!
//! [`SpatialAttention::reference`] is the scalar definition; the fast path takes the same
//! operations in the same order (the channel sum in channel order, the convolution's fused
//! multiply-adds tap by tap), so the two agree exactly. tract's channel sum may add in another
//! order: the two differ by rounding (tests bound it).

use std::sync::Arc;

use ndarray::{Array3, ArrayView3};
use tract_onnx::prelude::*;
use tract_onnx::tract_core::internal::*;

/// Side of the convolution's kernel.
const K: usize = 7;
/// Its padding on each side.
const PAD: usize = K / 2;

/// The features `x` an attention weights: one tensor (`gates` empty), or the channel
/// attention's sum `x = sum_p xs[p] * gates[p]`, each `xs[p]` `[C, H, W]` and each gate `[C]`,
/// the products summed in order, each rounded, as [`ScaledSumOp`] computes it.
#[derive(Clone, Copy, Debug)]
pub struct Scaled<'a> {
    /// The tensors, `[C][H][W]` each.
    pub xs: &'a [&'a [f32]],
    /// Their gates, `[C]` each; empty when `x` is `xs[0]` itself.
    pub gates: &'a [&'a [f32]],
}

impl<'a> Scaled<'a> {
    /// `x` itself.
    pub fn plain(x: &'a [&'a [f32]]) -> Scaled<'a> {
        Scaled { xs: x, gates: &[] }
    }

    /// Whether the sizes fit `n` values a tensor and `c` channels.
    fn fits(&self, n: usize, c: usize) -> bool {
        !self.xs.is_empty()
            && self.xs.iter().all(|x| x.len() == n)
            && (self.gates.is_empty()
                || (self.gates.len() == self.xs.len() && self.gates.iter().all(|g| g.len() == c)))
    }

    /// The `w` values of `x` from `at` (in channel `k`): read in place, or summed into
    /// `scratch` (at least `w` values).
    #[inline(always)]
    fn row<'s>(&'s self, k: usize, at: usize, w: usize, scratch: &'s mut [f32]) -> &'s [f32] {
        if self.gates.is_empty() {
            return &self.xs[0][at..at + w];
        }
        let out = &mut scratch[..w];
        for (p, (x, g)) in self.xs.iter().zip(self.gates).enumerate() {
            let (x, g) = (&x[at..at + w], g[k]);
            if p == 0 {
                for (o, &v) in out.iter_mut().zip(x) {
                    *o = v * g;
                }
            } else {
                for (o, &v) in out.iter_mut().zip(x) {
                    *o += v * g;
                }
            }
        }
        out
    }
}

/// The attention's parameters: the 2-to-1 7x7 convolution (padding 3) over the channel mean and
/// maximum, and the mean's scale.
#[derive(Clone, Debug, PartialEq)]
pub struct SpatialAttention {
    /// `[2][7][7]`: the mean's taps, then the maximum's.
    weights: Vec<f32>,
    bias: f32,
    /// What the channel sum is multiplied by to give the mean (`1 / C` as the network has it).
    scale: f32,
    /// How many `(x_p, g_p)` pairs `x` is the scaled sum of ([`Scaled`]); 0 when it is one
    /// tensor. The operator's inputs are then `x_0, g_0, ..., d`.
    pairs: usize,
}

/// The logistic function, `1 / (1 + exp(-z))` ([`neuspike_simd::fastmath::sigmoid`], within
/// 4 ulp, vectorised): 0 for `z = -inf`, 1 for `+inf`, NaN for NaN.
#[inline(always)]
pub(crate) fn sigmoid(z: f32) -> f32 {
    neuspike_simd::fastmath::sigmoid(z)
}

impl SpatialAttention {
    /// From the convolution's `[1, 2, 7, 7]` weights (98 values, mean first), its bias and the
    /// mean's scale; `None` for another number of weights.
    pub fn new(weights: &[f32], bias: f32, scale: f32) -> Option<SpatialAttention> {
        (weights.len() == 2 * K * K).then(|| SpatialAttention {
            weights: weights.to_vec(),
            bias,
            scale,
            pairs: 0,
        })
    }

    /// The same attention of the scaled sum of `pairs` pairs ([`Scaled`]; 0: of one tensor).
    pub fn of_scaled_sum(self, pairs: usize) -> SpatialAttention {
        SpatialAttention { pairs, ..self }
    }

    /// How many pairs `x` is the scaled sum of (0: one tensor).
    pub fn pairs(&self) -> usize {
        self.pairs
    }

    /// The scalar definition: `y = x * sigmoid(z)`, `z` the bias then one fused multiply-add per
    /// tap (map, kernel row, column, in order; 0 off the image) over the maps `mean = (sum of
    /// s over channels, in channel order, from 0) * scale` and `max` of `s = x + d`.
    ///
    /// # Panics
    /// When `x` and `d` differ in shape.
    pub fn reference(&self, x: ArrayView3<f32>, d: ArrayView3<f32>) -> Array3<f32> {
        assert_eq!(x.dim(), d.dim(), "x and d");
        let (c, h, w) = x.dim();
        let s = |k: usize, y: usize, i: usize| x[[k, y, i]] + d[[k, y, i]];
        let mean = ndarray::Array2::from_shape_fn((h, w), |(y, i)| {
            (0..c).fold(0.0f32, |a, k| a + s(k, y, i)) * self.scale
        });
        let max = ndarray::Array2::from_shape_fn((h, w), |(y, i)| {
            (1..c).fold(s(0, y, i), |a, k| a.max(s(k, y, i)))
        });
        let maps = [mean, max];
        let map = ndarray::Array2::from_shape_fn((h, w), |(y, i)| {
            let mut z = self.bias;
            for (m, map) in maps.iter().enumerate() {
                for ky in 0..K {
                    for kx in 0..K {
                        let (yy, xx) = ((y + ky).wrapping_sub(PAD), (i + kx).wrapping_sub(PAD));
                        let v = if yy < h && xx < w { map[[yy, xx]] } else { 0.0 };
                        z = self.weights[(m * K + ky) * K + kx].mul_add(v, z);
                    }
                }
            }
            sigmoid(z)
        });
        Array3::from_shape_fn((c, h, w), |(k, y, i)| x[[k, y, i]] * map[[y, i]])
    }

    /// [`reference`](Self::reference) of `x` and `d` (`[C, H, W]`, row-major) into `out`, rows
    /// split across `pool` (or this thread when `None`).
    ///
    /// # Errors
    /// A message when a tensor of `x`, `d` or `out` is not `C * H * W` values, or a gate not `C`.
    pub fn run(
        &self,
        x: Scaled,
        d: &[f32],
        (c, h, w): (usize, usize, usize),
        out: &mut [f32],
        pool: Option<&rayon::ThreadPool>,
    ) -> Result<(), String> {
        let n = c.checked_mul(h).and_then(|n| n.checked_mul(w));
        let fits = n.is_some_and(|n| x.fits(n, c) && d.len() == n && out.len() == n);
        if !fits {
            return Err(format!(
                "{:?}, {} and {} values in, {} out, for {c}x{h}x{w}",
                x.xs.iter().map(|x| x.len()).collect::<Vec<_>>(),
                x.gates.iter().map(|g| g.len()).sum::<usize>(),
                d.len(),
                out.len()
            ));
        }
        if c == 0 || h == 0 || w == 0 {
            return Ok(());
        }
        let rows = crate::bands::band_rows(h, pool);
        // The two maps, zero-padded by 3 on every side, row by row: `[h + 6][2][w + 6]`.
        let pw = w + 2 * PAD;
        let mut maps = vec![0f32; (h + 2 * PAD) * 2 * pw];
        let inner = &mut maps[PAD * 2 * pw..(PAD + h) * 2 * pw];
        let tasks = crate::bands::row_bands(inner, h * 2 * pw, 2 * pw, rows);
        crate::bands::for_each(tasks, pool, |(y0, mut band)| {
            neuspike_simd::dispatch(
                #[inline(always)]
                || {
                    let mut scratch = vec![0f32; w];
                    for (r, row) in band[0].chunks_exact_mut(2 * pw).enumerate() {
                        self.maps_row(x, d, (c, h, w), y0 + r, row, &mut scratch)
                    }
                },
            )
        });
        let maps = &maps;
        let tasks = crate::bands::row_bands(out, h * w, w, rows);
        crate::bands::for_each(tasks, pool, |(y0, mut planes)| {
            neuspike_simd::dispatch(
                #[inline(always)]
                || self.product_rows(x, maps, (h, w), y0, &mut planes),
            )
        });
        Ok(())
    }

    /// Row `y` of the mean and maximum maps of `x + d` into `row` (`[2][w + 6]`, the maps'
    /// values at `3..3 + w`).
    #[inline(always)]
    fn maps_row(
        &self,
        x: Scaled,
        d: &[f32],
        (c, h, w): (usize, usize, usize),
        y: usize,
        row: &mut [f32],
        scratch: &mut [f32],
    ) {
        let (mean, max) = row.split_at_mut(row.len() / 2);
        let (mean, max) = (&mut mean[PAD..PAD + w], &mut max[PAD..PAD + w]);
        mean.fill(0.0);
        for k in 0..c {
            let at = (k * h + y) * w;
            let (xs, ds) = (x.row(k, at, w, scratch), &d[at..at + w]);
            if k == 0 {
                for (((m, a), &xv), &dv) in mean.iter_mut().zip(max.iter_mut()).zip(xs).zip(ds) {
                    let s = xv + dv;
                    *m += s;
                    *a = s;
                }
            } else {
                for (((m, a), &xv), &dv) in mean.iter_mut().zip(max.iter_mut()).zip(xs).zip(ds) {
                    let s = xv + dv;
                    *m += s;
                    *a = a.max(s);
                }
            }
        }
        for m in mean.iter_mut() {
            *m *= self.scale;
        }
    }

    /// Output rows `y0..` of every plane in `planes`: the map's row, then `x` times it.
    #[inline(always)]
    fn product_rows(
        &self,
        x: Scaled,
        maps: &[f32],
        (h, w): (usize, usize),
        y0: usize,
        planes: &mut [&mut [f32]],
    ) {
        let pw = w + 2 * PAD;
        let mut z = vec![0f32; w];
        let mut scratch = vec![0f32; w];
        let n_rows = planes.first().map_or(0, |p| p.len() / w);
        for y in y0..y0 + n_rows {
            z.fill(self.bias);
            for m in 0..2 {
                for ky in 0..K {
                    // Padded row y + ky is image row y + ky - 3.
                    let src = &maps[((y + ky) * 2 + m) * pw..][..pw];
                    for kx in 0..K {
                        let wt = self.weights[(m * K + ky) * K + kx];
                        for (z, &v) in z.iter_mut().zip(&src[kx..kx + w]) {
                            *z = wt.mul_add(v, *z);
                        }
                    }
                }
            }
            for z in z.iter_mut() {
                *z = sigmoid(*z);
            }
            for (k, plane) in planes.iter_mut().enumerate() {
                let dst = &mut plane[(y - y0) * w..][..w];
                let xs = x.row(k, (k * h + y) * w, w, &mut scratch);
                for ((o, &xv), &a) in dst.iter_mut().zip(xs).zip(&z) {
                    *o = xv * a;
                }
            }
        }
    }
}

/// The tract operator running a [`SpatialAttention`] on `x` and `d`, both `[1, C, H, W]`.
#[derive(Clone, Debug, PartialEq)]
pub struct SpatialAttentionOp(pub Arc<SpatialAttention>);

impl Eq for SpatialAttentionOp {}

impl Op for SpatialAttentionOp {
    fn name(&self) -> StaticName {
        "NeuspikeSpatialAttention".into()
    }

    op_as_typed_op!();
}

impl EvalOp for SpatialAttentionOp {
    op_out_of_plan!();

    fn eval(&self, _ctx: &EvalContext, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let pairs = self.0.pairs;
        ensure!(
            inputs.len() == (2 * pairs).max(1) + 1,
            "NeuspikeSpatialAttention of {pairs} pairs given {} inputs",
            inputs.len()
        );
        let shape = inputs[0].shape().to_vec();
        let &[1, c, h, w] = shape.as_slice() else {
            bail!("NeuspikeSpatialAttention takes [1, C, H, W], got {shape:?}");
        };
        let d = inputs.last().expect("checked above");
        ensure!(
            d.shape() == shape.as_slice(),
            "x {shape:?} and d {:?}",
            d.shape()
        );
        let plain = inputs
            .iter()
            .map(|i| i.try_as_plain_ram())
            .collect::<TractResult<TVec<_>>>()?;
        let (xs, gates) = if pairs == 0 {
            (tvec![plain[0].as_slice::<f32>()?], TVec::new())
        } else {
            scaled_pairs(&inputs[..2 * pairs], &plain[..2 * pairs], &shape)?
        };
        let x = Scaled {
            xs: &xs,
            gates: &gates,
        };
        let pool = crate::bands::tract_pool();
        let d = plain.last().expect("checked above").as_slice::<f32>()?;
        let y = crate::bands::output_tensor(&[1, c, h, w], |y| {
            self.0
                .run(x, d, (c, h, w), y, pool.as_deref())
                .map_err(|e| format_err!("{e}"))
        })?;
        Ok(tvec!(y))
    }
}

impl TypedOp for SpatialAttentionOp {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        let (Some(x), Some(d)) = (inputs.first(), inputs.last()) else {
            bail!("NeuspikeSpatialAttention takes x (or its pairs) and d");
        };
        ensure!(inputs.len() == (2 * self.0.pairs).max(1) + 1);
        ensure!(x.datum_type == f32::datum_type() && x.rank() == 4 && x.shape == d.shape);
        Ok(tvec!(f32::fact(x.shape.clone())))
    }

    as_op!();
}

/// The tensors and the gates of a scaled sum's pairs.
type Pairs<'a> = (TVec<&'a [f32]>, TVec<&'a [f32]>);

/// The `x_p` and `g_p` of the pairs `x_0, g_0, x_1, g_1, ...` in `inputs` (their plain values
/// in `plain`), each `x_p` of `shape` (`[1, C, H, W]`) and each `g_p` `[1, C, 1, 1]`.
fn scaled_pairs<'a>(
    inputs: &[TValue],
    plain: &'a [PlainView<'_>],
    shape: &[usize],
) -> TractResult<Pairs<'a>> {
    let c = shape.get(1).copied().unwrap_or(0);
    let (mut xs, mut gs) = (TVec::new(), TVec::new());
    for (i, pair) in plain.chunks_exact(2).enumerate() {
        ensure!(
            inputs[2 * i].shape() == shape && inputs[2 * i + 1].shape() == [1, c, 1, 1],
            "pair {i}: {:?} and {:?} for {shape:?}",
            inputs[2 * i].shape(),
            inputs[2 * i + 1].shape()
        );
        xs.push(pair[0].as_slice::<f32>()?);
        gs.push(pair[1].as_slice::<f32>()?);
    }
    Ok((xs, gs))
}

/// The single value of the constant on `outlet`, if it is one.
fn scalar(model: &TypedModel, outlet: OutletId) -> Option<f32> {
    let k = model.outlet_fact(outlet).ok()?.konst.clone()?;
    let v = k.to_plain_array_view::<f32>().ok()?;
    if v.len() == 1 {
        v.iter().next().copied()
    } else {
        None
    }
}

/// The binary operator of `node` if it is tract's `name` (`Add`, `Mul`, `Max`) on two inputs.
fn binary<'m>(node: &'m TypedNode, name: &str) -> Option<&'m [OutletId]> {
    use tract_onnx::tract_core::ops::binary::TypedBinOp;
    let op = node.op_as::<TypedBinOp>()?;
    (op.0.name() == name && node.inputs.len() == 2).then_some(node.inputs.as_slice())
}

/// The channel ranges of `s` whose maximum `outlet` computes, if it is a tree of `Max` over
/// slices of `s` on axis 1, or a `ReduceMax` of `s` over axis 1 (`0..c`).
fn max_ranges(
    model: &TypedModel,
    outlet: OutletId,
    s: OutletId,
    c: usize,
) -> Option<Vec<(usize, usize)>> {
    use tract_onnx::tract_core::ops::array::Slice;
    use tract_onnx::tract_core::ops::nn::{Reduce, Reducer};
    let node = model.node(outlet.node);
    if let Some(inputs) = binary(node, "Max") {
        let mut a = max_ranges(model, inputs[0], s, c)?;
        a.extend(max_ranges(model, inputs[1], s, c)?);
        return Some(a);
    }
    if node.inputs.first() != Some(&s) {
        return None;
    }
    if let Some(slice) = node.op_as::<Slice>() {
        let (start, end) = (slice.start.to_usize().ok()?, slice.end.to_usize().ok()?);
        return (slice.axis == 1 && start < end).then_some(vec![(start, end)]);
    }
    let reduce = node.op_as::<Reduce>()?;
    (reduce.axes.as_slice() == [1] && matches!(reduce.reducer, Reducer::Max))
        .then_some(vec![(0, c)])
}

/// The attention whose product is `node` (`x * sigmoid(conv(concat(mean, max)))` over `s = x +
/// d`, as tract declutters `Fusion.skip` of `training/neuspike_net.py`), with `x` and `d`.
fn as_spatial_attention(
    model: &TypedModel,
    node: &TypedNode,
) -> Option<(SpatialAttention, OutletId, OutletId)> {
    use tract_onnx::tract_core::ops::array::TypedConcat;
    use tract_onnx::tract_core::ops::nn::{Reduce, Reducer};
    let inputs = binary(node, "Mul")?;
    let (slot, sig) = inputs
        .iter()
        .enumerate()
        .find(|(_, o)| model.node(o.node).op().name() == "Sigmoid")?;
    let x = inputs[1 - slot];
    let fact = model.outlet_fact(x).ok()?;
    let shape = fact.shape.as_concrete()?;
    let &[1, c, _, _] = shape else {
        return None;
    };
    if fact.datum_type != f32::datum_type()
        || model.outlet_fact(OutletId::new(node.id, 0)).ok()?.shape != fact.shape
    {
        return None;
    }
    let sig = model.node(sig.node);
    let conv_node = model.node(sig.inputs.first()?.node);
    let conv = crate::matching::conv_node(model, conv_node)?;
    let fits = conv.kernel_size == [K, K] && conv.stride == 1 && conv.pad == PAD;
    if !fits || conv.group != 1 || conv.shape != [1, 2, K, K] {
        return None;
    }
    let (weights, &[bias]) = (conv.kernel, conv.bias.as_slice()) else {
        return None;
    };
    let concat_node = model.node(conv_node.inputs[0].node);
    if concat_node.op_as::<TypedConcat>()?.axis != 1 || concat_node.inputs.len() != 2 {
        return None;
    }
    // The mean: the channel sum of s, times a constant.
    let norm = binary(model.node(concat_node.inputs[0].node), "Mul")?;
    let (sum, scale) = match (scalar(model, norm[0]), scalar(model, norm[1])) {
        (None, Some(k)) => (norm[0], k),
        (Some(k), None) => (norm[1], k),
        _ => return None,
    };
    let sum_node = model.node(sum.node);
    let reduce = sum_node.op_as::<Reduce>()?;
    if reduce.axes.as_slice() != [1] || !matches!(reduce.reducer, Reducer::Sum) {
        return None;
    }
    let s = *sum_node.inputs.first()?;
    // s = x + d.
    let add = binary(model.node(s.node), "Add")?;
    let d = match add {
        [a, b] if *a == x => *b,
        [a, b] if *b == x => *a,
        _ => return None,
    };
    if model.outlet_fact(d).ok()?.shape != fact.shape {
        return None;
    }
    // The maximum covers every channel of s.
    let mut ranges = max_ranges(model, concat_node.inputs[1], s, c)?;
    ranges.sort_unstable();
    let mut covered = 0;
    for (start, end) in ranges {
        if start > covered || end > c {
            return None;
        }
        covered = covered.max(end);
    }
    if covered != c {
        return None;
    }
    Some((SpatialAttention::new(&weights, bias, scale)?, x, d))
}

/// Replaces every spatial attention of the (decluttered) `model` by a [`SpatialAttentionOp`],
/// reading the channel attention's products in place of `x` where only the attention reads
/// `x` ([`Scaled`]); returns how many. The nodes it took over go when nothing else reads them.
pub fn use_spatial_attention(model: &mut TypedModel) -> TractResult<usize> {
    let mut replaced = 0;
    for id in model.eval_order()? {
        let node = model.node(id);
        let Some((attention, x, d)) = as_spatial_attention(model, node) else {
            continue;
        };
        // x is read by the attention's sum s = x + d and its product, and by nothing else.
        let only_here = model.node(x.node).outputs[x.slot].successors.len() == 2
            && !model.output_outlets()?.contains(&x);
        let pairs = scaled_sum(model, x).filter(|_| only_here);
        let attention = attention.of_scaled_sum(pairs.as_ref().map_or(0, |p| p.len()));
        let mut inputs: TVec<OutletId> = match pairs {
            Some(pairs) => pairs.into_iter().flat_map(|(x, g)| [x, g]).collect(),
            None => tvec![x],
        };
        inputs.push(d);
        let name = node.name.clone();
        let op = SpatialAttentionOp(Arc::new(attention));
        crate::matching::replace(model, &name, op, &inputs, id, &[])?;
        replaced += 1;
    }
    Ok(replaced)
}

/// The channel attention's products and their sum (Eq. 11): `y = sum_p x_p * g_p`, each `x_p`
/// `[1, C, H, W]` scaled by its gate `g_p` (`[1, C, 1, 1]`), as one operator split across
/// tract's pool by channel. tract runs each product and the sum as one-thread passes (about 2
/// of a base-16 network's 45 ms at 256x400 on 2 threads). The products are summed in input
/// order, each rounded, as tract's `Mul` and `Add` do.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ScaledSumOp {
    /// How many `(x, g)` pairs the inputs hold, `x_0, g_0, x_1, g_1, ...`.
    pub pairs: usize,
}

impl ScaledSumOp {
    /// `out` (`[C][H W]`) from the pairs' values, each `x` `[C][H W]` and each `g` `[C]`,
    /// channels split across `pool`.
    fn run(
        xs: &[&[f32]],
        gs: &[&[f32]],
        hw: usize,
        out: &mut [f32],
        pool: Option<&rayon::ThreadPool>,
    ) {
        let tasks: Vec<(usize, &mut [f32])> = out.chunks_mut(hw.max(1)).enumerate().collect();
        crate::bands::for_each(tasks, pool, |(c, plane)| {
            neuspike_simd::dispatch(
                #[inline(always)]
                || {
                    for (p, (x, g)) in xs.iter().zip(gs).enumerate() {
                        let (x, g) = (&x[c * hw..][..hw], g[c]);
                        if p == 0 {
                            for (o, &v) in plane.iter_mut().zip(x) {
                                *o = v * g;
                            }
                        } else {
                            for (o, &v) in plane.iter_mut().zip(x) {
                                *o += v * g;
                            }
                        }
                    }
                },
            )
        });
    }
}

impl Op for ScaledSumOp {
    fn name(&self) -> StaticName {
        "NeuspikeScaledSum".into()
    }

    op_as_typed_op!();
}

impl EvalOp for ScaledSumOp {
    op_out_of_plan!();

    fn eval(&self, _ctx: &EvalContext, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        ensure!(
            self.pairs > 0 && inputs.len() == 2 * self.pairs,
            "NeuspikeScaledSum of {} pairs given {} inputs",
            self.pairs,
            inputs.len()
        );
        let shape = inputs[0].shape().to_vec();
        let &[1, _, h, w] = shape.as_slice() else {
            bail!("NeuspikeScaledSum takes [1, C, H, W], got {shape:?}");
        };
        let plain = inputs
            .iter()
            .map(|i| i.try_as_plain_ram())
            .collect::<TractResult<TVec<_>>>()?;
        let (xs, gs) = scaled_pairs(&inputs, &plain, &shape)?;
        let y = crate::bands::output_tensor(&shape, |y| {
            Self::run(&xs, &gs, h * w, y, crate::bands::tract_pool().as_deref());
            Ok(())
        })?;
        Ok(tvec!(y))
    }
}

impl TypedOp for ScaledSumOp {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        ensure!(self.pairs > 0 && inputs.len() == 2 * self.pairs);
        let x = inputs[0];
        ensure!(x.datum_type == f32::datum_type() && x.rank() == 4);
        Ok(tvec!(f32::fact(x.shape.clone())))
    }

    as_op!();
}

/// `(x, g)` if `outlet` is `x * g` of a `[1, C, H, W]` f32 `x` (`H W > 1`) and a
/// `[1, C, 1, 1]` `g`, in either order.
fn scaled(model: &TypedModel, outlet: OutletId) -> Option<(OutletId, OutletId)> {
    let inputs = binary(model.node(outlet.node), "Mul")?;
    let shape = |o: OutletId| {
        model
            .outlet_fact(o)
            .ok()?
            .shape
            .as_concrete()
            .map(|s| s.to_vec())
    };
    let (a, b) = (shape(inputs[0])?, shape(inputs[1])?);
    let f32_in = model.outlet_fact(inputs[0]).ok()?.datum_type == f32::datum_type();
    let gate = |x: &[usize], g: &[usize]| matches!((x, g), (&[1, c, h, w], &[1, gc, 1, 1]) if c == gc && h * w > 1);
    let (x, g, x_shape) = if gate(&a, &b) {
        (inputs[0], inputs[1], a)
    } else if gate(&b, &a) {
        (inputs[1], inputs[0], b)
    } else {
        return None;
    };
    (f32_in && shape(outlet)? == x_shape).then_some((x, g))
}

/// The `(x_p, g_p)` pairs whose scaled sum `outlet` is: a sum of two products each read by
/// nothing else, or one product.
fn scaled_sum(model: &TypedModel, outlet: OutletId) -> Option<TVec<(OutletId, OutletId)>> {
    let Some(inputs) = binary(model.node(outlet.node), "Add") else {
        return scaled(model, outlet).map(|pair| tvec![pair]);
    };
    let only_here = |o: &OutletId| {
        model.node(o.node).outputs[o.slot].successors.len() == 1
            && !model.output_outlets().is_ok_and(|out| out.contains(o))
    };
    let (a, b) = (scaled(model, inputs[0])?, scaled(model, inputs[1])?);
    let same = model.outlet_fact(a.0).ok()?.shape == model.outlet_fact(b.0).ok()?.shape;
    (same && inputs.iter().all(only_here)).then(|| tvec![a, b])
}

/// Replaces the channel attention's products in the (decluttered) `model`: a sum of two
/// products read by nothing else, and every other product, by a [`ScaledSumOp`]; returns how
/// many operators it wired.
pub fn use_scaled_sums(model: &mut TypedModel) -> TractResult<usize> {
    let mut replaced = 0;
    // The sums first, then the products left.
    for sums in [true, false] {
        for id in model.eval_order()? {
            let node = model.node(id);
            let pairs: TVec<(OutletId, OutletId)> = if sums {
                if binary(node, "Add").is_none() {
                    continue;
                }
                match scaled_sum(model, OutletId::new(id, 0)) {
                    Some(pairs) => pairs,
                    None => continue,
                }
            } else {
                match scaled(model, OutletId::new(id, 0)) {
                    Some(pair) => tvec![pair],
                    None => continue,
                }
            };
            let inputs: TVec<OutletId> = pairs.iter().flat_map(|&(x, g)| [x, g]).collect();
            let (name, op) = (node.name.clone(), ScaledSumOp { pairs: pairs.len() });
            crate::matching::replace(model, &name, op, &inputs, id, &[])?;
            replaced += 1;
        }
    }
    Ok(replaced)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::pattern;

    #[test]
    fn matches_the_reference_exactly() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap();
        for (i, &(c, h, w)) in [(16, 9, 50), (3, 1, 1), (1, 4, 7), (8, 13, 21)]
            .iter()
            .enumerate()
        {
            let a = SpatialAttention::new(&pattern(98, i as u32), 0.3, 1.0 / c as f32).unwrap();
            let x = pattern(c * h * w, 10 + i as u32);
            let d = pattern(c * h * w, 20 + i as u32);
            let want = a.reference(
                ArrayView3::from_shape((c, h, w), &x).unwrap(),
                ArrayView3::from_shape((c, h, w), &d).unwrap(),
            );
            for pool in [None, Some(&pool)] {
                let mut got = vec![f32::NAN; c * h * w];
                a.run(Scaled::plain(&[&x]), &d, (c, h, w), &mut got, pool)
                    .unwrap();
                assert_eq!(got.as_slice(), want.as_slice().unwrap(), "{c}x{h}x{w}");
            }
            // x as the channel attention's sum of one and of two products, formed in place.
            let parts = [pattern(c * h * w, 30 + i as u32), pattern(c * h * w, 31)];
            let gates = [pattern(c, 32), pattern(c, 33)];
            for pairs in [1, 2] {
                let xs: Vec<&[f32]> = parts[..pairs].iter().map(Vec::as_slice).collect();
                let gs: Vec<&[f32]> = gates[..pairs].iter().map(Vec::as_slice).collect();
                let mut x = vec![0f32; c * h * w];
                ScaledSumOp::run(&xs, &gs, h * w, &mut x, None);
                let want = a.reference(
                    ArrayView3::from_shape((c, h, w), &x).unwrap(),
                    ArrayView3::from_shape((c, h, w), &d).unwrap(),
                );
                let scaled = Scaled {
                    xs: &xs,
                    gates: &gs,
                };
                for pool in [None, Some(&pool)] {
                    let mut got = vec![f32::NAN; c * h * w];
                    a.run(scaled, &d, (c, h, w), &mut got, pool).unwrap();
                    assert_eq!(got.as_slice(), want.as_slice().unwrap(), "{pairs} pairs");
                }
            }
        }
    }

    #[test]
    fn scaled_sums_take_the_products_in_order() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        let (c, hw) = (5, 37);
        let xs = [pattern(c * hw, 1), pattern(c * hw, 2)];
        let gs = [pattern(c, 3), pattern(c, 4)];
        for pairs in [1, 2] {
            let want: Vec<f32> = (0..c * hw)
                .map(|i| {
                    let one = xs[0][i] * gs[0][i / hw];
                    if pairs == 2 {
                        one + xs[1][i] * gs[1][i / hw]
                    } else {
                        one
                    }
                })
                .collect();
            let x: Vec<&[f32]> = xs[..pairs].iter().map(Vec::as_slice).collect();
            let g: Vec<&[f32]> = gs[..pairs].iter().map(Vec::as_slice).collect();
            for pool in [None, Some(&pool)] {
                let mut got = vec![f32::NAN; c * hw];
                ScaledSumOp::run(&x, &g, hw, &mut got, pool);
                assert_eq!(got, want, "{pairs} pairs");
            }
        }
    }

    #[test]
    fn extremes_and_bad_sizes() {
        // The map saturates to 1 and 0 far from 0; NaN stays NaN (as would an infinity, which a
        // zero weight turns into NaN); no panic.
        let mut weights = vec![0.0; 98];
        weights[3 * K + 3] = 1.0;
        let a = SpatialAttention::new(&weights, 0.0, 1.0).unwrap();
        for (x, want) in [
            (1e30f32, Some(1e30f32)),
            (-1e30, Some(0.0)),
            (f32::NAN, None),
            (2.0, Some(2.0 * sigmoid(2.0))),
        ] {
            let mut y = [0.0];
            a.run(Scaled::plain(&[&[x]]), &[0.0], (1, 1, 1), &mut y, None)
                .unwrap();
            match want {
                Some(v) => assert_eq!(y[0], v, "{x}"),
                None => assert!(y[0].is_nan(), "{x}: {}", y[0]),
            }
        }
        let (x, d, mut y) = ([1.0; 4], [0.0; 4], [0.0; 4]);
        let xs: [&[f32]; 1] = [&x];
        let plain = Scaled::plain(&xs);
        assert!(a.run(plain, &d, (1, 1, 3), &mut y, None).is_err());
        assert!(a.run(plain, &d[..3], (1, 1, 4), &mut y, None).is_err());
        assert!(a.run(plain, &d, (1, 2, 2), &mut y[..3], None).is_err());
        let no_gate = Scaled {
            xs: &xs,
            gates: &[&[]],
        };
        assert!(a.run(no_gate, &d, (1, 2, 2), &mut y, None).is_err());
        let none = Scaled {
            xs: &[],
            gates: &[],
        };
        assert!(a.run(none, &d, (1, 2, 2), &mut y, None).is_err());
        assert!(a.run(plain, &d, (usize::MAX, 2, 2), &mut y, None).is_err());
        assert!(SpatialAttention::new(&[0.0; 97], 0.0, 1.0).is_none());
        assert_eq!(
            (sigmoid(f32::INFINITY), sigmoid(f32::NEG_INFINITY)),
            (1.0, 0.0)
        );
    }
}
