//! What the rewrites read off tract's nodes: a convolution's geometry and constant weights, a
//! constant's values, the only reader of a node. One reading for every operator, so each
//! matcher states only what it needs (a kernel size, a stride, groups).

use tract_onnx::prelude::*;

/// A 2-D convolution of `f32` NCHW input (rank 4) with a constant OIHW kernel and bias, no
/// dilation or quantisation, the same stride and padding on both axes.
pub(crate) struct ConvNode {
    /// Kernel height and width.
    pub kernel_size: [usize; 2],
    /// The stride of both axes.
    pub stride: usize,
    /// The padding on every side (`SAME` padding of an odd kernel at stride 1: half of it).
    pub pad: usize,
    /// Groups.
    pub group: usize,
    /// The kernel's shape, `[O, C / group, kh, kw]`.
    pub shape: Vec<usize>,
    /// The kernel's values in logical order.
    pub kernel: Vec<f32>,
    /// The bias' values.
    pub bias: Vec<f32>,
}

/// The convolution `node` computes, if it is one as [`ConvNode`] describes.
pub(crate) fn conv_node(model: &TypedModel, node: &TypedNode) -> Option<ConvNode> {
    use tract_onnx::tract_core::ops::cnn::{Conv, KernelFormat, PaddingSpec};
    use tract_onnx::tract_core::ops::nn::DataFormat;
    let conv = node.op_as::<Conv>()?;
    let spec = &conv.pool_spec;
    let &[kh, kw] = spec.kernel_shape.as_slice() else {
        return None;
    };
    let uniform = |v: &Option<TVec<usize>>| match v {
        None => Some(1),
        Some(v) if v.len() == 2 && v[0] == v[1] => Some(v[0]),
        Some(_) => None,
    };
    let stride = uniform(&spec.strides)?;
    let pad = match &spec.padding {
        PaddingSpec::Explicit(before, after) if before.len() == 2 && after.len() == 2 => {
            let p = before[0];
            before.iter().chain(after).all(|&v| v == p).then_some(p)?
        }
        PaddingSpec::Valid => 0,
        // The same output size pads half an odd kernel on each side at stride 1 only.
        PaddingSpec::SameUpper | PaddingSpec::SameLower
            if stride == 1 && kh == kw && kh % 2 == 1 =>
        {
            kh / 2
        }
        _ => return None,
    };
    let fact = model.outlet_fact(*node.inputs.first()?).ok()?;
    if uniform(&spec.dilations)? != 1
        || conv.q_params.is_some()
        || conv.kernel_fmt != KernelFormat::OIHW
        || spec.data_format != DataFormat::NCHW
        || node.inputs.len() != 3
        || fact.datum_type != f32::datum_type()
        || fact.rank() != 4
    {
        return None;
    }
    let (shape, kernel) = values(model, node.inputs[1])?;
    let (_, bias) = values(model, node.inputs[2])?;
    Some(ConvNode {
        kernel_size: [kh, kw],
        stride,
        pad,
        group: conv.group,
        shape,
        kernel,
        bias,
    })
}

/// The values of the constant on `outlet` as `f32`, in logical order, with its shape. Before
/// decluttering a bias may still be a `Cast` of a constant: that constant, cast.
pub(crate) fn values(model: &TypedModel, outlet: OutletId) -> Option<(Vec<usize>, Vec<f32>)> {
    let konst = |o: OutletId| model.outlet_fact(o).ok()?.konst.clone();
    let node = model.node(outlet.node);
    let k = konst(outlet).or_else(|| match node.inputs.as_slice() {
        [from] if node.op().name() == "Cast" => konst(*from),
        _ => None,
    })?;
    let k = k.cast_to::<f32>().ok()?;
    let v = k.to_plain_array_view::<f32>().ok()?;
    Some((v.shape().to_vec(), v.iter().copied().collect()))
}

/// The only node reading `node`'s output, if it is not a model output.
pub(crate) fn only_reader(model: &TypedModel, node: &TypedNode) -> Option<usize> {
    let out = OutletId::new(node.id, 0);
    let [next] = node.outputs.first()?.successors.as_slice() else {
        return None;
    };
    (!model.output_outlets().ok()?.contains(&out)).then_some(next.node)
}

/// Puts a node computing `op` on `inputs`, named `name`, in `model` in place of the output of
/// node `last` (what read that output reads the new node's), then removes the nodes in
/// `obliterate`: the one rewrite every operator here makes.
pub(crate) fn replace(
    model: &mut TypedModel,
    name: &str,
    op: impl Into<Box<dyn TypedOp>>,
    inputs: &[OutletId],
    last: usize,
    obliterate: &[usize],
) -> TractResult<()> {
    let mut patch = TypedModelPatch::default();
    let taps = patch.taps(model, inputs)?;
    let y = patch.wire_node(name, op, &taps)?;
    patch.shunt_outside(model, OutletId::new(last, 0), y[0])?;
    for &id in obliterate {
        patch.obliterate(id)?;
    }
    patch.apply(model)
}
