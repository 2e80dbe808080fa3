//! The translation of a [`GraphModel`] into a tract model, node by node.

use std::collections::HashMap;
use std::sync::Arc;

use base64::Engine as _;
use tract_tflite::internal::tract_core::ops::array::{Pad, PadMode, Slice, TypedConcat};
use tract_tflite::internal::tract_core::ops::change_axes::{perm_to_ops, wire_with_rank_broadcast};
use tract_tflite::internal::tract_core::ops::cnn::{
    Conv, KernelFormat, MaxPool, PaddingSpec, PoolSpec,
};
use tract_tflite::internal::tract_core::ops::math::add;
use tract_tflite::internal::tract_core::ops::nn::{
    CoordTransformer, DataFormat, Interpolator, Nearest, Resize, leaky_relu, sigmoid,
};
use tract_tflite::internal::*;

use super::{GraphModel, Node, TfjsError, invalid, tract, unsupported};

/// A node's output while translating: a constant (known here, for shape arithmetic)
/// or a wire of the tract model.
#[derive(Clone)]
enum Value {
    Const(Arc<Tensor>),
    Wire(OutletId),
}

/// The spatial sizes of each `ResizeBilinear`, at the graph's own input size: `(input,
/// output)` for height and width. A graph converted for one input size carries its
/// resizes' output sizes as constants; at another input size each keeps its ratio.
type Resizes = HashMap<String, [(usize, usize); 2]>;

/// An attribute's integer list (`{"list": {"i": ["1", "2"]}}`).
fn int_list(node: &Node, key: &str) -> Option<Vec<usize>> {
    node.attr
        .get(key)?
        .get("list")?
        .get("i")?
        .as_array()?
        .iter()
        .map(|v| {
            v.as_str()
                .and_then(|s| s.parse().ok())
                .or_else(|| v.as_u64().and_then(|n| usize::try_from(n).ok()))
        })
        .collect()
}

/// An attribute's string (`{"s": base64}`).
fn string_attr(node: &Node, key: &str) -> Option<String> {
    let s = node.attr.get(key)?.get("s")?.as_str()?;
    let bytes = base64::engine::general_purpose::STANDARD.decode(s).ok()?;
    String::from_utf8(bytes).ok()
}

fn bool_attr(node: &Node, key: &str) -> bool {
    node.attr
        .get(key)
        .and_then(|v| v.get("b"))
        .and_then(serde_json::Value::as_bool)
        .unwrap_or(false)
}

fn float_attr(node: &Node, key: &str) -> Option<f32> {
    Some(node.attr.get(key)?.get("f")?.as_f64()? as f32)
}

/// A tensor's values of type `T`, in order.
pub(super) fn values<T: Datum + Copy>(t: &Tensor) -> Result<Vec<T>, TfjsError> {
    t.to_plain_array_view::<T>()
        .map(|v| v.iter().copied().collect())
        .map_err(|e| invalid(format!("a constant: {e}")))
}

/// A constant's values as integers.
fn ints(t: &Tensor) -> Result<Vec<i64>, TfjsError> {
    let t = t
        .cast_to::<i64>()
        .map_err(|e| invalid(format!("integer constant: {e}")))?;
    values::<i64>(&t)
}

/// A square spatial window of a convolution or pool: `[1, k, k, 1]`-style attributes.
fn spatial(node: &Node, key: &str) -> Result<Option<TVec<usize>>, TfjsError> {
    match int_list(node, key) {
        None => Ok(None),
        // Strides and dilations of 1 to 64 (0 would divide by zero).
        Some(v)
            if v.len() == 4 && v[0] == 1 && v[3] == 1 && v.iter().all(|s| (1..=64).contains(s)) =>
        {
            Ok(Some(tvec![v[1], v[2]]))
        }
        Some(v) => Err(unsupported(format!("{}: {key} {v:?}", node.name))),
    }
}

fn padding(node: &Node) -> Result<PaddingSpec, TfjsError> {
    match string_attr(node, "padding").as_deref() {
        Some("VALID") => Ok(PaddingSpec::Valid),
        Some("SAME") => Ok(PaddingSpec::SameUpper),
        other => Err(unsupported(format!("{}: padding {other:?}", node.name))),
    }
}

fn nhwc(node: &Node) -> Result<(), TfjsError> {
    match string_attr(node, "data_format").as_deref() {
        None | Some("NHWC") => Ok(()),
        other => Err(unsupported(format!("{}: data format {other:?}", node.name))),
    }
}

/// The translation of a graph into a tract model.
struct Translation<'a> {
    graph: &'a GraphModel,
    model: TypedModel,
    values: HashMap<String, Vec<Value>>,
    /// Resize sizes to record (at the graph's own size) or to scale (at another).
    resizes: &'a mut Resizes,
    record: bool,
}

impl Translation<'_> {
    /// The value an input reference (`name` or `name:port`) names.
    fn value(&self, input: &str) -> Result<Value, TfjsError> {
        let (name, port) = match input.rsplit_once(':') {
            Some((n, p)) => (n, p.parse().map_err(|_| invalid(format!("input {input}")))?),
            None => (input, 0usize),
        };
        self.values
            .get(name)
            .and_then(|v| v.get(port))
            .cloned()
            .ok_or_else(|| invalid(format!("input {input} before it is defined")))
    }

    fn inputs(&self, node: &Node) -> Result<Vec<Value>, TfjsError> {
        node.input
            .iter()
            .filter(|i| !i.starts_with('^'))
            .map(|i| self.value(i))
            .collect()
    }

    fn wire(&mut self, name: &str, v: &Value) -> Result<OutletId, TfjsError> {
        match v {
            Value::Wire(o) => Ok(*o),
            Value::Const(t) => self
                .model
                .add_const(format!("{name}.const"), t.clone())
                .map_err(tract(format!("{name}: a constant"))),
        }
    }

    fn constant<'v>(node: &Node, v: &'v Value) -> Result<&'v Arc<Tensor>, TfjsError> {
        match v {
            Value::Const(t) => Ok(t),
            Value::Wire(_) => Err(unsupported(format!(
                "{} ({}): an input computed at run time where a constant is needed",
                node.name, node.op
            ))),
        }
    }

    fn shape(&self, o: OutletId) -> Result<Vec<usize>, TfjsError> {
        let fact = self.model.outlet_fact(o).map_err(tract("a shape"))?;
        fact.shape
            .as_concrete()
            .map(<[usize]>::to_vec)
            .ok_or_else(|| unsupported("a shape not known before running"))
    }

    fn op(
        &mut self,
        name: &str,
        op: impl Into<Box<dyn TypedOp>>,
        inputs: &[OutletId],
    ) -> Result<Value, TfjsError> {
        let out = self
            .model
            .wire_node(name, op.into(), inputs)
            .map_err(tract(name.to_string()))?;
        Ok(Value::Wire(out[0]))
    }

    /// The value(s) of `node`.
    fn node(&mut self, node: &Node, source: OutletId) -> Result<Vec<Value>, TfjsError> {
        let name = node.name.as_str();
        let inputs = self.inputs(node)?;
        let arity = |n: usize| {
            if inputs.len() < n {
                Err(invalid(format!(
                    "{name} ({}): {} inputs",
                    node.op,
                    inputs.len()
                )))
            } else {
                Ok(())
            }
        };
        let one = |v: Value| Ok(vec![v]);
        match node.op.as_str() {
            "Const" => {
                let t = self
                    .graph
                    .weights
                    .get(name)
                    .ok_or_else(|| invalid(format!("constant {name} not in the weights")))?;
                one(Value::Const(Arc::new(t.clone())))
            }
            "Placeholder" => one(Value::Wire(source)),
            "Identity" => {
                arity(1)?;
                one(inputs[0].clone())
            }
            "Add" | "AddV2" => {
                arity(2)?;
                if let (Value::Const(a), Value::Const(b)) = (&inputs[0], &inputs[1]) {
                    return one(Value::Const(Arc::new(add_constants(name, a, b)?)));
                }
                let a = self.wire(&format!("{name}.a"), &inputs[0])?;
                let b = self.wire(&format!("{name}.b"), &inputs[1])?;
                let out = wire_with_rank_broadcast(name, &mut self.model, add(), &[a, b])
                    .map_err(tract(name.to_string()))?;
                one(Value::Wire(out[0]))
            }
            "Sigmoid" => {
                arity(1)?;
                let x = self.wire(name, &inputs[0])?;
                one(self.op(name, sigmoid(), &[x])?)
            }
            "LeakyRelu" => {
                arity(1)?;
                let alpha = float_attr(node, "alpha").unwrap_or(0.2);
                let x = self.wire(name, &inputs[0])?;
                one(self.op(name, leaky_relu(alpha), &[x])?)
            }
            "Transpose" => {
                arity(2)?;
                let perm: Vec<usize> = ints(Self::constant(node, &inputs[1])?)?
                    .into_iter()
                    .map(|p| usize::try_from(p).map_err(|_| invalid(format!("{name}: perm"))))
                    .collect::<Result<_, _>>()?;
                let mut x = self.wire(name, &inputs[0])?;
                let rank = self.shape(x)?.len();
                let mut sorted = perm.clone();
                sorted.sort_unstable();
                if sorted != (0..rank).collect::<Vec<_>>() {
                    return Err(invalid(format!("{name}: permutation {perm:?}")));
                }
                for (k, op) in perm_to_ops(&perm).into_iter().enumerate() {
                    let Value::Wire(o) = self.op(&format!("{name}.{k}"), op, &[x])? else {
                        unreachable!("op gives a wire")
                    };
                    x = o;
                }
                one(Value::Wire(x))
            }
            "Pad" | "PadV2" => {
                arity(2)?;
                let pads = ints(Self::constant(node, &inputs[1])?)?;
                let value = match inputs.get(2) {
                    Some(v) => Self::constant(node, v)?
                        .cast_to::<f32>()
                        .map_err(|e| invalid(format!("{name}: {e}")))
                        .and_then(|t| values::<f32>(&t))?
                        .first()
                        .copied()
                        .ok_or_else(|| invalid(format!("{name}: pad value")))?,
                    None => 0.0,
                };
                let x = self.wire(name, &inputs[0])?;
                let rank = self.shape(x)?.len();
                // A network's padding: a few cells a side.
                if pads.len() != 2 * rank || pads.iter().any(|&p| !(0..=64).contains(&p)) {
                    return Err(invalid(format!("{name}: paddings {pads:?}")));
                }
                let pads = pads
                    .chunks_exact(2)
                    .map(|p| (p[0] as usize, p[1] as usize))
                    .collect();
                let mode = PadMode::Constant(Arc::new(tensor0(value)));
                one(self.op(name, Pad { pads, mode }, &[x])?)
            }
            "Conv2D" => {
                arity(2)?;
                nhwc(node)?;
                let kernel = Self::constant(node, &inputs[1])?.clone();
                let &[kh, kw, ci, co] = kernel.shape() else {
                    return Err(invalid(format!("{name}: kernel {:?}", kernel.shape())));
                };
                let x = self.wire(name, &inputs[0])?;
                let channels = *self.shape(x)?.last().unwrap_or(&0);
                if ci == 0 || channels % ci != 0 {
                    return Err(invalid(format!("{name}: {channels} channels, kernel {ci}")));
                }
                let pool_spec = PoolSpec {
                    data_format: DataFormat::NHWC,
                    kernel_shape: tvec![kh, kw],
                    padding: padding(node)?,
                    dilations: spatial(node, "dilations")?,
                    strides: spatial(node, "strides")?,
                    input_channels: channels,
                    output_channels: co,
                };
                let conv = Conv {
                    pool_spec,
                    kernel_fmt: KernelFormat::HWIO,
                    group: channels / ci,
                    q_params: None,
                };
                let k = self.wire(&format!("{name}.kernel"), &Value::Const(kernel))?;
                let bias = Value::Const(Arc::new(
                    Tensor::zero::<f32>(&[co]).map_err(tract(name.to_string()))?,
                ));
                let b = self.wire(&format!("{name}.bias"), &bias)?;
                one(self.op(name, conv, &[x, k, b])?)
            }
            "MaxPool" => {
                arity(1)?;
                nhwc(node)?;
                let x = self.wire(name, &inputs[0])?;
                let channels = *self.shape(x)?.last().unwrap_or(&0);
                let kernel =
                    spatial(node, "ksize")?.ok_or_else(|| invalid(format!("{name}: no ksize")))?;
                let pool_spec = PoolSpec {
                    data_format: DataFormat::NHWC,
                    kernel_shape: kernel,
                    padding: padding(node)?,
                    dilations: None,
                    strides: spatial(node, "strides")?,
                    input_channels: channels,
                    output_channels: channels,
                };
                one(self.op(
                    name,
                    MaxPool {
                        pool_spec,
                        with_index_outputs: None,
                    },
                    &[x],
                )?)
            }
            "ConcatV2" => {
                arity(2)?;
                let (axis, parts) = inputs.split_last().expect("two inputs");
                let axis = ints(Self::constant(node, axis)?)?
                    .first()
                    .copied()
                    .unwrap_or(0);
                let wires = parts
                    .iter()
                    .enumerate()
                    .map(|(k, v)| self.wire(&format!("{name}.{k}"), v))
                    .collect::<Result<Vec<_>, _>>()?;
                let rank = self.shape(wires[0])?.len() as i64;
                let axis = if axis < 0 { axis + rank } else { axis };
                if !(0..rank).contains(&axis) {
                    return Err(invalid(format!("{name}: axis {axis}")));
                }
                one(self.op(name, TypedConcat::new(axis as usize), &wires)?)
            }
            "Reshape" => {
                arity(2)?;
                let wanted = ints(Self::constant(node, &inputs[1])?)?;
                let x = self.wire(name, &inputs[0])?;
                let from = self.shape(x)?;
                let to = reshaped(name, &from, &wanted)?;
                let op = AxisOp::Reshape(
                    0,
                    from.iter().map(|&d| d.to_dim()).collect(),
                    to.iter().map(|&d| d.to_dim()).collect(),
                );
                one(self.op(name, op, &[x])?)
            }
            "SparseToDense" => {
                arity(4)?;
                let c: Vec<&Arc<Tensor>> = inputs
                    .iter()
                    .map(|v| Self::constant(node, v))
                    .collect::<Result<_, _>>()?;
                one(Value::Const(Arc::new(sparse_to_dense(
                    name, c[0], c[1], c[2], c[3],
                )?)))
            }
            "SplitV" => {
                arity(3)?;
                let sizes = ints(Self::constant(node, &inputs[1])?)?;
                let axis = ints(Self::constant(node, &inputs[2])?)?
                    .first()
                    .copied()
                    .unwrap_or(0);
                let x = self.wire(name, &inputs[0])?;
                let shape = self.shape(x)?;
                let rank = shape.len() as i64;
                let axis = if axis < 0 { axis + rank } else { axis };
                let total = sizes
                    .iter()
                    .try_fold(0i64, |n, &s| if s < 0 { None } else { n.checked_add(s) });
                if !(0..rank).contains(&axis) || total != Some(shape[axis as usize] as i64) {
                    return Err(unsupported(format!("{name}: split {sizes:?} of {shape:?}")));
                }
                let mut start = 0usize;
                let mut out = Vec::new();
                for (k, s) in sizes.iter().enumerate() {
                    let end = start + *s as usize;
                    out.push(self.op(
                        &format!("{name}.{k}"),
                        Slice::new(axis as usize, start, end),
                        &[x],
                    )?);
                    start = end;
                }
                Ok(out)
            }
            "ResizeBilinear" => {
                arity(2)?;
                let size = ints(Self::constant(node, &inputs[1])?)?;
                let x = self.wire(name, &inputs[0])?;
                let shape = self.shape(x)?;
                let (&[h, w], &[n, _, _, c]) = (&size[..], &shape[..]) else {
                    return Err(invalid(format!("{name}: size {size:?} of {shape:?}")));
                };
                // An upsampling's output, not an image's: at most 1 << 14 a side.
                if !(1..=1 << 14).contains(&h) || !(1..=1 << 14).contains(&w) {
                    return Err(unsupported(format!("{name}: resize to {h} x {w}")));
                }
                let (h, w) = (h as usize, w as usize);
                let [out_h, out_w] = if self.record {
                    self.resizes
                        .insert(name.to_string(), [(shape[1], h), (shape[2], w)]);
                    [h, w]
                } else {
                    let [rh, rw] = self
                        .resizes
                        .get(name)
                        .ok_or_else(|| invalid(format!("{name}: not at the graph's own size")))?;
                    let scale = |(from, to): (usize, usize), now: usize| {
                        let scaled = now.checked_mul(to)?;
                        (from > 0 && scaled.is_multiple_of(from)).then(|| scaled / from)
                    };
                    match (scale(*rh, shape[1]), scale(*rw, shape[2])) {
                        (Some(a), Some(b)) => [a, b],
                        _ => {
                            return Err(unsupported(format!(
                                "{name}: no whole output size for {shape:?}"
                            )));
                        }
                    }
                };
                let coord_transformer = if bool_attr(node, "align_corners") {
                    CoordTransformer::AlignCorners
                } else if bool_attr(node, "half_pixel_centers") {
                    CoordTransformer::HalfPixel
                } else {
                    CoordTransformer::Asymmetric
                };
                let sizes = tensor1(&[n as i64, out_h as i64, out_w as i64, c as i64]);
                let s = self.wire(&format!("{name}.sizes"), &Value::Const(Arc::new(sizes)))?;
                let op = Resize {
                    coord_transformer,
                    interpolator: Interpolator::Linear,
                    nearest: Nearest::Floor,
                    optional_scales_input: None,
                    optional_sizes_input: Some(1),
                };
                one(self.op(name, op, &[x, s])?)
            }
            other => Err(unsupported(format!("operator {other} ({name})"))),
        }
    }
}

/// The sum of two integer constants of one shape (shape arithmetic).
fn add_constants(name: &str, a: &Tensor, b: &Tensor) -> Result<Tensor, TfjsError> {
    let (x, y) = (ints(a)?, ints(b)?);
    if x.len() != y.len() {
        return Err(unsupported(format!("{name}: constants of {x:?} and {y:?}")));
    }
    let sum: Vec<i32> = x
        .iter()
        .zip(&y)
        .map(|(p, q)| i32::try_from(p.saturating_add(*q)).unwrap_or(i32::MAX))
        .collect();
    Tensor::from_shape(a.shape(), &sum).map_err(|e| invalid(format!("{name}: {e}")))
}

/// `SparseToDense` of constants (shape arithmetic): a vector of `shape`'s one length,
/// `default` everywhere but at `indices`.
pub(super) fn sparse_to_dense(
    name: &str,
    indices: &Tensor,
    shape: &Tensor,
    values: &Tensor,
    default: &Tensor,
) -> Result<Tensor, TfjsError> {
    let shape = ints(shape)?;
    let &[len] = &shape[..] else {
        return Err(unsupported(format!("{name}: dense shape {shape:?}")));
    };
    let len = usize::try_from(len)
        .ok()
        .filter(|&n| n <= 1 << 16)
        .ok_or_else(|| invalid(format!("{name}: length {len}")))?;
    let fill = ints(default)?.first().copied().unwrap_or(0);
    let mut out = vec![fill; len];
    let (indices, values) = (ints(indices)?, ints(values)?);
    for (k, &i) in indices.iter().enumerate() {
        let v = if values.len() == 1 {
            values[0]
        } else {
            *values
                .get(k)
                .ok_or_else(|| invalid(format!("{name}: values")))?
        };
        *usize::try_from(i)
            .ok()
            .and_then(|i| out.get_mut(i))
            .ok_or_else(|| invalid(format!("{name}: index {i}")))? = v;
    }
    let out: Vec<i32> = out
        .iter()
        .map(|&v| v.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32)
        .collect();
    Ok(tensor1(&out))
}

/// TensorFlow's reshape of `from` to `wanted` (one dimension may be -1).
pub(super) fn reshaped(
    name: &str,
    from: &[usize],
    wanted: &[i64],
) -> Result<Vec<usize>, TfjsError> {
    let bad = || invalid(format!("{name}: reshape {from:?} to {wanted:?}"));
    let total = from
        .iter()
        .try_fold(1usize, |n, &d| n.checked_mul(d))
        .ok_or_else(bad)?;
    let known = wanted
        .iter()
        .filter(|&&d| d != -1)
        .try_fold(1i64, |n, &d| n.checked_mul(d))
        .ok_or_else(bad)?;
    let free = wanted.iter().filter(|&&d| d == -1).count();
    // A free dimension needs the others' product (0 would leave it undetermined).
    if wanted.iter().any(|&d| d < -1) || free > 1 || (free == 1 && known == 0) {
        return Err(bad());
    }
    let known = usize::try_from(known).map_err(|_| bad())?;
    let out: Vec<usize> = wanted
        .iter()
        .map(|&d| if d == -1 { total / known } else { d as usize })
        .collect();
    let product = out.iter().try_fold(1usize, |n, &d| n.checked_mul(d));
    if product != Some(total) {
        return Err(bad());
    }
    Ok(out)
}

impl GraphModel {
    /// The graph's one input (`Placeholder`): its name and its shape as written.
    fn input(&self) -> Result<(&Node, Vec<usize>), TfjsError> {
        let mut found = self.nodes.iter().filter(|n| n.op == "Placeholder");
        let node = found.next().ok_or_else(|| invalid("no input"))?;
        if found.next().is_some() {
            return Err(unsupported("more than one input"));
        }
        let shape = node
            .attr
            .get("shape")
            .and_then(|s| s.get("shape")?.get("dim")?.as_array().cloned())
            .ok_or_else(|| invalid(format!("input {}: no shape", node.name)))?
            .iter()
            .map(|d| {
                d.get("size")
                    .and_then(|s| s.as_str().and_then(|s| s.parse().ok()).or(s.as_u64()))
                    .and_then(|n| usize::try_from(n).ok())
                    .ok_or_else(|| {
                        invalid(format!("input {}: a dimension of unknown size", node.name))
                    })
            })
            .collect::<Result<Vec<usize>, _>>()?;
        Ok((node, shape))
    }

    /// Translates the graph for an NCHW image input of `height x width` (its own
    /// `[1, 3, H, W]` placeholder), fed as NHWC `[1, height, width, 3]`; `finish` wires
    /// the model's outputs from the values of `outputs` (node names); decluttered by
    /// tract.
    pub fn to_tract(
        &self,
        height: usize,
        width: usize,
        outputs: &[&str],
        finish: impl Fn(&mut TypedModel, &[OutletId]) -> TractResult<Vec<OutletId>>,
    ) -> Result<TypedModel, TfjsError> {
        let (_, own) = self.input()?;
        let &[1, 3, own_h, own_w] = &own[..] else {
            return Err(unsupported(format!(
                "input of shape {own:?} (an NCHW image wanted)"
            )));
        };
        // The graph's own size first: what its resizes do there.
        let mut resizes = Resizes::new();
        let (mut model, outlets) = if (own_h, own_w) == (height, width) {
            self.translate(height, width, outputs, &mut resizes, true)?
        } else {
            self.translate(own_h, own_w, outputs, &mut resizes, true)?;
            self.translate(height, width, outputs, &mut resizes, false)?
        };
        let outlets = finish(&mut model, &outlets).map_err(tract("the outputs"))?;
        model
            .select_output_outlets(&outlets)
            .map_err(tract("the outputs"))?;
        let mut model = model
            .into_decluttered()
            .and_then(|m| m.into_compact())
            .map_err(tract("decluttering"))?;
        // Names from the nodes' places: tract's decluttering names some nodes in an
        // order of its own hash maps, and a written file would differ by a name from
        // one run to the next (its checksum is pinned).
        for node in model.nodes_mut() {
            node.name = format!("{}_{}", node.op.name(), node.id);
        }
        Ok(model)
    }

    fn translate(
        &self,
        height: usize,
        width: usize,
        outputs: &[&str],
        resizes: &mut Resizes,
        record: bool,
    ) -> Result<(TypedModel, Vec<OutletId>), TfjsError> {
        let mut t = Translation {
            graph: self,
            model: TypedModel::default(),
            values: HashMap::new(),
            resizes,
            record,
        };
        let image = t
            .model
            .add_source("image", f32::fact([1, height, width, 3]))
            .map_err(tract("the input"))?;
        // NHWC in, the graph's NCHW from it.
        let Value::Wire(source) = t.op("image.nchw", AxisOp::Move(3, 1), &[image])? else {
            unreachable!("op gives a wire")
        };
        // Nodes in an order where every input comes first (the file's order need not be).
        let mut pending: Vec<&Node> = self.nodes.iter().collect();
        while !pending.is_empty() {
            let before = pending.len();
            let mut left = Vec::new();
            for node in pending {
                let ready = node
                    .input
                    .iter()
                    .filter(|i| !i.starts_with('^'))
                    .all(|i| t.value(i).is_ok());
                if ready {
                    let v = t.node(node, source)?;
                    t.values.insert(node.name.clone(), v);
                } else {
                    left.push(node);
                }
            }
            if left.len() == before {
                return Err(invalid(format!(
                    "{} nodes with inputs never defined (or a cycle), e.g. {}",
                    left.len(),
                    left[0].name
                )));
            }
            pending = left;
        }
        let outlets = outputs
            .iter()
            .map(|&o| match t.value(o)? {
                Value::Wire(w) => Ok(w),
                Value::Const(_) => Err(unsupported(format!("output {o} is a constant"))),
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok((t.model, outlets))
    }
}
