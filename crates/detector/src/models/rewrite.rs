//! Rewrites a TFLite flatbuffer so that `tract-tflite` loads it. MediaPipe's BlazePose
//! models keep their weights as float16 constants behind `DEQUANTIZE` operators, the
//! person detector also keeps some sparse (`DENSIFY`) and upsamples with
//! `DEPTH_TO_SPACE`; tract implements none of the three.
//!
//! The rewrite edits the file's bytes in place and appends what does not fit
//! ([`super::append`]), which a flatbuffer allows because every reference is a forward
//! offset relative to where it is stored:
//! - each `DENSIFY` of a sparse float16 constant: the constant is expanded to its dense
//!   values (the sparse format of the TFLite schema: dense and CSR dimensions in
//!   storage order), which the `DEQUANTIZE` reading it then folds;
//! - each `DEQUANTIZE` of a float16 constant: the float32 values are appended as a new
//!   byte vector, the constant's buffer points to them and its type becomes float32;
//! - every operator input (and subgraph output) that read a folded output reads that
//!   constant instead (tensor indices patched in place);
//! - each `DEPTH_TO_SPACE` (block b, `[1,H,W,b*b*C]`) becomes `RESHAPE` to
//!   `[1,H,W,b,b,C]`, `TRANSPOSE` by `[0,1,3,2,4,5]`, `RESHAPE` to `[1,H*b,W*b,C]`:
//!   new operator tables, appended; the tensors they need take the vector slots of
//!   tensors the folding left unused, the permutation's data the slot of an unused
//!   buffer, and the `TRANSPOSE` operator code the slot of an unused one;
//! - the operator list is rebuilt in place (it only shrinks).
//!
//! Nothing else changes: tensor indices, the other operators and their options stay
//! where they are. The result passes the flatbuffers verifier (`root_as_model`).

use std::collections::{BTreeSet, HashMap};

use half::f16;
use tract_tflite::tflite::{
    self, BuiltinOperator, BuiltinOptions, DimensionType, SparseIndexVector, TensorType,
};

use super::append::{Value, append_table, append_vector, set_forward};

/// Why a model could not be rewritten.
#[derive(Debug, thiserror::Error)]
pub enum RewriteError {
    /// Not a valid TFLite flatbuffer.
    #[error("not a TFLite model: {0}")]
    Invalid(String),
    /// The model uses something this rewrite does not handle.
    #[error("cannot rewrite: {0}")]
    Unsupported(String),
}

/// What a rewrite did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RewriteReport {
    /// `DEQUANTIZE` operators folded into float32 constants.
    pub dequantized: usize,
    /// `DENSIFY` operators folded (sparse constants made dense).
    pub densified: usize,
    /// `DEPTH_TO_SPACE` operators replaced by reshape, transpose, reshape.
    pub depth_to_space: usize,
    /// Operators left.
    pub operators: usize,
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn i32_at(b: &[u8], at: usize) -> i32 {
    u32_at(b, at) as i32
}

fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}

/// Where field `vt_offset` (a generated `VT_*` constant) of the table at `table` is
/// stored, if it is present.
fn field_position(b: &[u8], table: usize, vt_offset: u16) -> Option<usize> {
    let vtable = (table as i64 - i64::from(i32_at(b, table))) as usize;
    let vtable_len = u16_at(b, vtable);
    if vt_offset >= vtable_len {
        return None;
    }
    match u16_at(b, vtable + vt_offset as usize) {
        0 => None,
        off => Some(table + off as usize),
    }
}

fn too_far() -> RewriteError {
    RewriteError::Unsupported("an offset does not fit".into())
}

/// Stores at `at` the forward offset to `target`.
fn set_offset(b: &mut [u8], at: usize, target: usize) -> Result<(), RewriteError> {
    set_forward(b, at, target).ok_or_else(too_far)
}

/// The position of slot `i` of the vector that field `vt` of `table` refers to.
fn vector_slot(b: &[u8], table: usize, vt: u16, i: usize) -> Option<usize> {
    let field = field_position(b, table, vt)?;
    let vector = field + u32_at(b, field) as usize;
    (i < u32_at(b, vector) as usize).then_some(vector + 4 + 4 * i)
}

fn builtin_of(code: &tflite::OperatorCode) -> BuiltinOperator {
    BuiltinOperator(i32::from(code.deprecated_builtin_code()).max(code.builtin_code().0))
}

/// The segments (`segments`) or indices of a CSR dimension, whatever their width.
fn index_vector(d: &tflite::DimensionMetadata, segments: bool) -> Option<Vec<usize>> {
    let kind = if segments {
        d.array_segments_type()
    } else {
        d.array_indices_type()
    };
    Some(match kind {
        SparseIndexVector::Int32Vector => {
            let v = if segments {
                d.array_segments_as_int_32_vector()
            } else {
                d.array_indices_as_int_32_vector()
            };
            v?.values()?.iter().map(|x| x.max(0) as usize).collect()
        }
        SparseIndexVector::Uint16Vector => {
            let v = if segments {
                d.array_segments_as_uint_16_vector()
            } else {
                d.array_indices_as_uint_16_vector()
            };
            v?.values()?.iter().map(usize::from).collect()
        }
        SparseIndexVector::Uint8Vector => {
            let v = if segments {
                d.array_segments_as_uint_8_vector()
            } else {
                d.array_indices_as_uint_8_vector()
            };
            v?.values()?.iter().map(usize::from).collect()
        }
        _ => return None,
    })
}

/// Values of one densified constant at most: 16 M (32 MB of float16); the largest tensor
/// of any BlazePose model holds 1.6 M values (`pose_landmark_heavy`).
const MAX_DENSE_VALUES: usize = 1 << 24;

/// The dense float16 values of a sparse constant tensor.
fn densify(tensor: &tflite::Tensor, data: &[u8]) -> Result<Vec<u8>, RewriteError> {
    let unsupported = |what: &str| RewriteError::Unsupported(format!("sparse tensor: {what}"));
    let shape: Vec<usize> = tensor
        .shape()
        .ok_or_else(|| unsupported("no shape"))?
        .iter()
        .map(|d| d.max(0) as usize)
        .collect();
    let sparsity = tensor
        .sparsity()
        .ok_or_else(|| unsupported("no sparsity parameters"))?;
    let order: Vec<i32> = sparsity
        .traversal_order()
        .map(|v| v.iter().collect())
        .unwrap_or_default();
    if order != (0..shape.len() as i32).collect::<Vec<_>>()
        || sparsity.block_map().is_some_and(|m| !m.is_empty())
    {
        return Err(unsupported(
            "only plain storage order without blocks is read",
        ));
    }
    enum Dim {
        Dense(usize),
        Csr(Vec<usize>, Vec<usize>),
    }
    let dims: Vec<Dim> = sparsity
        .dim_metadata()
        .ok_or_else(|| unsupported("no dimension metadata"))?
        .iter()
        .map(|d| match d.format() {
            DimensionType::DENSE => Ok(Dim::Dense(d.dense_size().max(0) as usize)),
            DimensionType::SPARSE_CSR => Ok(Dim::Csr(
                index_vector(&d, true).ok_or_else(|| unsupported("segments"))?,
                index_vector(&d, false).ok_or_else(|| unsupported("indices"))?,
            )),
            _ => Err(unsupported("unknown dimension format")),
        })
        .collect::<Result<_, _>>()?;
    if dims.len() != shape.len()
        || dims
            .iter()
            .zip(&shape)
            .any(|(d, &s)| matches!(d, Dim::Dense(size) if *size != s))
    {
        return Err(unsupported("metadata and shape disagree"));
    }
    // The shape is the file's claim: its size must be countable and bounded before the
    // dense copy is allocated (a 1 kB file once asked for gigabytes: found by fuzzing).
    let total = shape
        .iter()
        .try_fold(1_usize, |n, &s| n.checked_mul(s))
        .filter(|&n| n <= MAX_DENSE_VALUES)
        .ok_or_else(|| unsupported("more values than a model constant holds"))?;
    let strides: Vec<usize> = (0..shape.len())
        .map(|k| shape[k + 1..].iter().product())
        .collect();
    let mut dense = vec![0_u8; 2 * total];
    // Depth-first over the storage: (level, index of the parent entry, dense offset).
    let mut stack = vec![(0_usize, 0_usize, 0_usize)];
    while let Some((level, parent, offset)) = stack.pop() {
        if level == dims.len() {
            let (from, to) = (2 * parent, 2 * offset);
            let value = data
                .get(from..from + 2)
                .ok_or_else(|| unsupported("too few values"))?;
            dense
                .get_mut(to..to + 2)
                .ok_or_else(|| unsupported("an index out of the shape"))?
                .copy_from_slice(value);
            continue;
        }
        match &dims[level] {
            Dim::Dense(size) => {
                for i in 0..*size {
                    stack.push((level + 1, parent * size + i, offset + i * strides[level]));
                }
            }
            Dim::Csr(segments, indices) => {
                let (a, b) = (
                    *segments
                        .get(parent)
                        .ok_or_else(|| unsupported("segments"))?,
                    *segments
                        .get(parent + 1)
                        .ok_or_else(|| unsupported("segments"))?,
                );
                for k in a..b {
                    let i = *indices.get(k).ok_or_else(|| unsupported("indices"))?;
                    if i >= shape[level] {
                        return Err(unsupported("an index out of the shape"));
                    }
                    stack.push((level + 1, k, offset + i * strides[level]));
                }
            }
        }
    }
    Ok(dense)
}

/// Rewrites `model` (the bytes of a `.tflite` file) for tract.
pub fn rewrite_for_tract(model: &[u8]) -> Result<(Vec<u8>, RewriteReport), RewriteError> {
    let invalid = |e: &dyn std::fmt::Display| RewriteError::Invalid(e.to_string());
    let root = tflite::root_as_model(model).map_err(|e| invalid(&e))?;
    let subgraphs = root.subgraphs().ok_or_else(|| invalid(&"no subgraphs"))?;
    if subgraphs.len() != 1 {
        return Err(RewriteError::Unsupported(format!(
            "{} subgraphs (one expected)",
            subgraphs.len()
        )));
    }
    let graph = subgraphs.get(0);
    let codes = root
        .operator_codes()
        .ok_or_else(|| invalid(&"no operator codes"))?;
    let tensors = graph.tensors().ok_or_else(|| invalid(&"no tensors"))?;
    let buffers = root.buffers().ok_or_else(|| invalid(&"no buffers"))?;
    let operators = graph.operators().ok_or_else(|| invalid(&"no operators"))?;
    // Every index the file holds (operator codes, tensors, buffers) is checked once here,
    // so that the lookups below stay in range whatever the file says.
    for op in operators.iter() {
        if op.opcode_index() as usize >= codes.len() {
            return Err(invalid(&"an operator code index out of range"));
        }
        let ios = op
            .inputs()
            .into_iter()
            .chain(op.outputs())
            .flat_map(|v| v.iter());
        for t in ios {
            if t < -1 || t >= 0 && t as usize >= tensors.len() {
                return Err(invalid(&"a tensor index out of range"));
            }
        }
    }
    if tensors.iter().any(|t| t.buffer() as usize >= buffers.len()) {
        return Err(invalid(&"a buffer index out of range"));
    }
    let builtin = |op: &tflite::Operator| builtin_of(&codes.get(op.opcode_index() as usize));
    let io = |op: &tflite::Operator| -> Result<(i32, i32), RewriteError> {
        match (op.inputs(), op.outputs()) {
            (Some(i), Some(o))
                if !i.is_empty() && !o.is_empty() && i.get(0) >= 0 && o.get(0) >= 0 =>
            {
                Ok((i.get(0), o.get(0)))
            }
            _ => Err(invalid(&"an operator without inputs or outputs")),
        }
    };
    let mut out = model.to_vec();
    let mut report = RewriteReport::default();
    // DENSIFY output -> (the sparse constant, its dense float16 bytes).
    let mut densified = HashMap::new();
    for op in operators
        .iter()
        .filter(|op| builtin(op) == BuiltinOperator::DENSIFY)
    {
        let (input, output) = io(&op)?;
        let tensor = tensors.get(input as usize);
        let data = buffers
            .get(tensor.buffer() as usize)
            .data()
            .filter(|d| !d.is_empty())
            .ok_or_else(|| RewriteError::Unsupported("DENSIFY of a non-constant".into()))?;
        if tensor.type_() != TensorType::FLOAT16 {
            return Err(RewriteError::Unsupported(format!(
                "DENSIFY of {:?} (only float16)",
                tensor.type_()
            )));
        }
        densified.insert(output, (input, densify(&tensor, data.bytes())?));
        report.densified += 1;
    }
    // DEQUANTIZE output tensor -> the constant it is now.
    let mut replaced = HashMap::new();
    for op in operators
        .iter()
        .filter(|op| builtin(op) == BuiltinOperator::DEQUANTIZE)
    {
        let (dq_input, output) = io(&op)?;
        let (constant, values) = match densified.get(&dq_input) {
            Some((sparse, dense)) => (*sparse, dense.clone()),
            None => {
                let tensor = tensors.get(dq_input as usize);
                let data = buffers
                    .get(tensor.buffer() as usize)
                    .data()
                    .filter(|d| !d.is_empty())
                    .ok_or_else(|| {
                        RewriteError::Unsupported("DEQUANTIZE of a non-constant".into())
                    })?;
                (dq_input, data.bytes().to_vec())
            }
        };
        let input = tensors.get(constant as usize);
        let output_type = tensors.get(output as usize).type_();
        if input.type_() != TensorType::FLOAT16 || output_type != TensorType::FLOAT32 {
            return Err(RewriteError::Unsupported(format!(
                "DEQUANTIZE from {:?} to {:?} (only float16 to float32)",
                input.type_(),
                output_type
            )));
        }
        let values: Vec<u8> = values
            .chunks_exact(2)
            .flat_map(|h| f16::from_le_bytes([h[0], h[1]]).to_f32().to_le_bytes())
            .collect();
        let buffer = buffers.get(input.buffer() as usize);
        let data_field = field_position(&out, buffer._tab.loc(), tflite::Buffer::VT_DATA)
            .ok_or_else(|| invalid(&"a constant buffer without data"))?;
        let vector = append_vector(&mut out, values.len(), &values, 16);
        set_offset(&mut out, data_field, vector)?;
        let type_field = field_position(&out, input._tab.loc(), tflite::Tensor::VT_TYPE_)
            .ok_or_else(|| invalid(&"a float16 tensor without a type field"))?;
        out[type_field] = TensorType::FLOAT32.0 as u8;
        replaced.insert(output, constant);
        report.dequantized += 1;
    }
    // Tensors and buffers nothing reads any more: room for the new operators' tensors.
    let mut spare_tensors: Vec<i32> = replaced
        .keys()
        .chain(densified.keys())
        .copied()
        .collect::<BTreeSet<_>>()
        .into_iter()
        .collect();
    spare_tensors.reverse();
    let mut buffer_users = vec![0_usize; buffers.len()];
    for t in tensors.iter() {
        if let Some(n) = buffer_users.get_mut(t.buffer() as usize) {
            *n += 1;
        }
    }
    let mut spare_buffers: Vec<u32> = spare_tensors
        .iter()
        .map(|&t| tensors.get(t as usize).buffer())
        .filter(|&b| b != 0 && buffer_users.get(b as usize) == Some(&1))
        .collect();
    // Operator codes nothing uses any more.
    let mut spare_codes: Vec<usize> = (0..codes.len())
        .filter(|&i| {
            matches!(
                builtin_of(&codes.get(i)),
                BuiltinOperator::DEQUANTIZE
                    | BuiltinOperator::DENSIFY
                    | BuiltinOperator::DEPTH_TO_SPACE
            )
        })
        .collect();
    let model_table = root._tab.loc();
    let graph_table = graph._tab.loc();
    let mut code_of = |out: &mut Vec<u8>, op: BuiltinOperator| -> Result<u32, RewriteError> {
        if let Some(i) =
            (0..codes.len()).find(|&i| builtin_of(&codes.get(i)) == op && !spare_codes.contains(&i))
        {
            return Ok(i as u32);
        }
        let slot_index = spare_codes
            .pop()
            .ok_or_else(|| RewriteError::Unsupported("no operator code slot left".into()))?;
        let table = append_table(
            out,
            &[
                (
                    tflite::OperatorCode::VT_DEPRECATED_BUILTIN_CODE,
                    Value::U8(op.0 as u8),
                ),
                (tflite::OperatorCode::VT_VERSION, Value::U32(1)),
                (
                    tflite::OperatorCode::VT_BUILTIN_CODE,
                    Value::U32(op.0 as u32),
                ),
            ],
        )
        .ok_or_else(too_far)?;
        let slot = vector_slot(
            out,
            model_table,
            tflite::Model::VT_OPERATOR_CODES,
            slot_index,
        )
        .ok_or_else(|| invalid(&"operator codes"))?;
        set_offset(out, slot, table)?;
        Ok(slot_index as u32)
    };
    let mut new_tensor = |out: &mut Vec<u8>,
                          shape: Vec<i32>,
                          ty: TensorType,
                          buffer: u32,
                          name: String|
     -> Result<i32, RewriteError> {
        let index = spare_tensors
            .pop()
            .ok_or_else(|| RewriteError::Unsupported("no tensor slot left".into()))?;
        let table = append_table(
            out,
            &[
                (tflite::Tensor::VT_SHAPE, Value::I32s(shape)),
                (tflite::Tensor::VT_TYPE_, Value::U8(ty.0 as u8)),
                (tflite::Tensor::VT_BUFFER, Value::U32(buffer)),
                (tflite::Tensor::VT_NAME, Value::Str(name)),
            ],
        )
        .ok_or_else(too_far)?;
        let slot = vector_slot(
            out,
            graph_table,
            tflite::SubGraph::VT_TENSORS,
            index as usize,
        )
        .ok_or_else(|| invalid(&"tensors"))?;
        set_offset(out, slot, table)?;
        Ok(index)
    };
    let operator = |out: &mut Vec<u8>,
                    code: u32,
                    inputs: Vec<i32>,
                    outputs: Vec<i32>,
                    options: (BuiltinOptions, Vec<(u16, Value)>)|
     -> Result<usize, RewriteError> {
        append_table(
            out,
            &[
                (tflite::Operator::VT_OPCODE_INDEX, Value::U32(code)),
                (tflite::Operator::VT_INPUTS, Value::I32s(inputs)),
                (tflite::Operator::VT_OUTPUTS, Value::I32s(outputs)),
                (
                    tflite::Operator::VT_BUILTIN_OPTIONS_TYPE,
                    Value::U8(options.0.0),
                ),
                (
                    tflite::Operator::VT_BUILTIN_OPTIONS,
                    Value::Table(options.1),
                ),
            ],
        )
        .ok_or_else(too_far)
    };
    // The operator list: kept operators, DEPTH_TO_SPACE expanded.
    let (mut list, mut originals) = (Vec::new(), Vec::new());
    let mut perm = None;
    for op in operators.iter() {
        let kind = builtin(&op);
        if matches!(kind, BuiltinOperator::DEQUANTIZE | BuiltinOperator::DENSIFY) {
            continue;
        }
        if kind != BuiltinOperator::DEPTH_TO_SPACE {
            list.push(op._tab.loc());
            originals.push(op._tab.loc());
            continue;
        }
        let (input, output) = io(&op)?;
        let block = op
            .builtin_options_as_depth_to_space_options()
            .map(|o| o.block_size())
            .ok_or_else(|| invalid(&"DEPTH_TO_SPACE without options"))?;
        let shape: Vec<i32> = tensors
            .get(input as usize)
            .shape()
            .map(|s| s.iter().collect())
            .unwrap_or_default();
        let &[n, h, w, c] = shape.as_slice() else {
            return Err(RewriteError::Unsupported(
                "DEPTH_TO_SPACE of a non-4D tensor".into(),
            ));
        };
        let squared = block.checked_mul(block).filter(|&b| b >= 1);
        let (Some(squared), Some(out_h), Some(out_w)) =
            (squared, h.checked_mul(block), w.checked_mul(block))
        else {
            return Err(invalid(&"DEPTH_TO_SPACE block size"));
        };
        if block < 1 || c % squared != 0 {
            return Err(invalid(&"DEPTH_TO_SPACE block size"));
        }
        let c_out = c / squared;
        let name = format!("depth_to_space_{}", report.depth_to_space);
        let perm = match perm {
            Some(p) => p,
            None => {
                let buffer = spare_buffers
                    .pop()
                    .ok_or_else(|| RewriteError::Unsupported("no buffer slot left".into()))?;
                let data: Vec<u8> = [0_i32, 1, 3, 2, 4, 5]
                    .iter()
                    .flat_map(|v| v.to_le_bytes())
                    .collect();
                let table =
                    append_table(&mut out, &[(tflite::Buffer::VT_DATA, Value::Bytes(data))])
                        .ok_or_else(too_far)?;
                let slot = vector_slot(
                    &out,
                    model_table,
                    tflite::Model::VT_BUFFERS,
                    buffer as usize,
                )
                .ok_or_else(|| invalid(&"buffers"))?;
                set_offset(&mut out, slot, table)?;
                let p = new_tensor(
                    &mut out,
                    vec![6],
                    TensorType::INT32,
                    buffer,
                    "depth_to_space_perm".into(),
                )?;
                perm = Some(p);
                p
            }
        };
        let split = new_tensor(
            &mut out,
            vec![n, h, w, block, block, c_out],
            TensorType::FLOAT32,
            0,
            format!("{name}_split"),
        )?;
        let moved = new_tensor(
            &mut out,
            vec![n, h, block, w, block, c_out],
            TensorType::FLOAT32,
            0,
            format!("{name}_moved"),
        )?;
        let reshape = code_of(&mut out, BuiltinOperator::RESHAPE)?;
        let transpose = code_of(&mut out, BuiltinOperator::TRANSPOSE)?;
        let reshape_to = |shape: Vec<i32>| {
            (
                BuiltinOptions::ReshapeOptions,
                vec![(tflite::ReshapeOptions::VT_NEW_SHAPE, Value::I32s(shape))],
            )
        };
        list.push(operator(
            &mut out,
            reshape,
            vec![input],
            vec![split],
            reshape_to(vec![n, h, w, block, block, c_out]),
        )?);
        list.push(operator(
            &mut out,
            transpose,
            vec![split, perm],
            vec![moved],
            (BuiltinOptions::TransposeOptions, vec![]),
        )?);
        list.push(operator(
            &mut out,
            reshape,
            vec![moved],
            vec![output],
            reshape_to(vec![n, out_h, out_w, c_out]),
        )?);
        report.depth_to_space += 1;
    }
    // Readers of a folded output read the constant instead (the new operators read
    // none, and reuse some of those tensor indices).
    let redirect = |out: &mut Vec<u8>, table: usize, vt: u16| {
        if let Some(field) = field_position(out, table, vt) {
            let vector = field + u32_at(out, field) as usize;
            for j in 0..u32_at(out, vector) as usize {
                let at = vector + 4 + 4 * j;
                if let Some(&to) = replaced.get(&i32_at(out, at)) {
                    out[at..at + 4].copy_from_slice(&i32::to_le_bytes(to));
                }
            }
        }
    };
    for &table in &originals {
        redirect(&mut out, table, tflite::Operator::VT_INPUTS);
    }
    redirect(&mut out, graph_table, tflite::SubGraph::VT_OUTPUTS);
    // The operator list, rewritten in place: it only shrinks or keeps its length, and
    // every table it lists lies after it (the originals, as a flatbuffer builder writes
    // them, and the appended ones).
    let list_field = field_position(&out, graph_table, tflite::SubGraph::VT_OPERATORS)
        .ok_or_else(|| invalid(&"a subgraph without operators"))?;
    let list_at = list_field + u32_at(&out, list_field) as usize;
    if list.len() > u32_at(&out, list_at) as usize {
        return Err(RewriteError::Unsupported(
            "more operators than before".into(),
        ));
    }
    for (i, &table) in list.iter().enumerate() {
        set_offset(&mut out, list_at + 4 + 4 * i, table)?;
    }
    out[list_at..list_at + 4].copy_from_slice(&(list.len() as u32).to_le_bytes());
    report.operators = list.len();
    tflite::root_as_model(&out).map_err(|e| invalid(&format!("after the rewrite: {e}")))?;
    Ok((out, report))
}

#[cfg(test)]
mod tests {
    use super::*;
    use tract_tflite::prelude::*;
    use tract_tflite::tflite::{
        AddOptions, AddOptionsArgs, Buffer, BufferArgs, BuiltinOptions, Model, ModelArgs, Operator,
        OperatorArgs, OperatorCode, OperatorCodeArgs, SubGraph, SubGraphArgs, Tensor as FlatTensor,
        TensorArgs,
    };

    type Builder = flatbuffers::FlatBufferBuilder<'static>;
    type Union = flatbuffers::WIPOffset<flatbuffers::UnionWIPOffset>;

    /// An operator table.
    fn op(
        b: &mut Builder,
        code: u32,
        ins: &[i32],
        outs: &[i32],
        options: Option<(BuiltinOptions, Union)>,
    ) -> flatbuffers::WIPOffset<Operator<'static>> {
        let inputs = b.create_vector(ins);
        let outputs = b.create_vector(outs);
        Operator::create(
            b,
            &OperatorArgs {
                opcode_index: code,
                inputs: Some(inputs),
                outputs: Some(outputs),
                builtin_options_type: options.map_or(BuiltinOptions::NONE, |o| o.0),
                builtin_options: options.map(|o| o.1),
                ..Default::default()
            },
        )
    }

    /// The subgraph (one input, one output), operator codes and model; the bytes.
    fn finish_model(
        mut b: Builder,
        tensors: flatbuffers::WIPOffset<
            flatbuffers::Vector<'static, flatbuffers::ForwardsUOffset<FlatTensor<'static>>>,
        >,
        ops: &[flatbuffers::WIPOffset<Operator<'static>>],
        io: (i32, i32),
        codes: &[BuiltinOperator],
        buffers: flatbuffers::WIPOffset<
            flatbuffers::Vector<'static, flatbuffers::ForwardsUOffset<Buffer<'static>>>,
        >,
    ) -> Vec<u8> {
        let operators = b.create_vector(ops);
        let inputs = b.create_vector(&[io.0]);
        let outputs = b.create_vector(&[io.1]);
        let graph = SubGraph::create(
            &mut b,
            &SubGraphArgs {
                tensors: Some(tensors),
                inputs: Some(inputs),
                outputs: Some(outputs),
                operators: Some(operators),
                ..Default::default()
            },
        );
        let codes: Vec<_> = codes
            .iter()
            .map(|&code| {
                OperatorCode::create(
                    &mut b,
                    &OperatorCodeArgs {
                        deprecated_builtin_code: code.0.min(127) as i8,
                        builtin_code: code,
                        version: 1,
                        ..Default::default()
                    },
                )
            })
            .collect();
        let codes = b.create_vector(&codes);
        let graphs = b.create_vector(&[graph]);
        let model = Model::create(
            &mut b,
            &ModelArgs {
                version: 3,
                operator_codes: Some(codes),
                subgraphs: Some(graphs),
                buffers: Some(buffers),
                ..Default::default()
            },
        );
        b.finish(model, Some("TFL3"));
        b.finished_data().to_vec()
    }

    /// `out = x + dequantize(c)` with `c` a float16 constant: the shape of every weight
    /// of the BlazePose landmark models.
    fn tiny_model(c: &[f32]) -> Vec<u8> {
        let mut b = flatbuffers::FlatBufferBuilder::new();
        let half: Vec<u8> = c
            .iter()
            .flat_map(|v| half::f16::from_f32(*v).to_le_bytes())
            .collect();
        let data = b.create_vector(&half);
        let empty = Buffer::create(&mut b, &BufferArgs::default());
        let constant = Buffer::create(&mut b, &BufferArgs { data: Some(data) });
        let buffers = b.create_vector(&[empty, constant]);
        let n = c.len() as i32;
        let tensor = |b: &mut flatbuffers::FlatBufferBuilder<'static>, name, ty, buffer| {
            let shape = b.create_vector(&[1, n]);
            let name = b.create_string(name);
            FlatTensor::create(
                b,
                &TensorArgs {
                    shape: Some(shape),
                    type_: ty,
                    buffer,
                    name: Some(name),
                    ..Default::default()
                },
            )
        };
        let t0 = tensor(&mut b, "c16", TensorType::FLOAT16, 1);
        let t1 = tensor(&mut b, "c32", TensorType::FLOAT32, 0);
        let t2 = tensor(&mut b, "x", TensorType::FLOAT32, 0);
        let t3 = tensor(&mut b, "out", TensorType::FLOAT32, 0);
        let tensors = b.create_vector(&[t0, t1, t2, t3]);
        let dequantize = op(&mut b, 0, &[0], &[1], None);
        let add_options = AddOptions::create(&mut b, &AddOptionsArgs::default());
        let add = op(
            &mut b,
            1,
            &[2, 1],
            &[3],
            Some((BuiltinOptions::AddOptions, add_options.as_union_value())),
        );
        let codes = [BuiltinOperator::DEQUANTIZE, BuiltinOperator::ADD];
        finish_model(b, tensors, &[dequantize, add], (2, 3), &codes, buffers)
    }

    #[test]
    fn float16_constants_behind_dequantize_become_float32_constants_tract_runs() {
        let c = [0.5_f32, -1.25, 2.0, 3.5];
        let original = tiny_model(&c);
        // tract cannot load the original ...
        assert!(
            tract_tflite::tflite()
                .model_for_read(&mut &original[..])
                .is_err()
        );
        // ... and runs the rewrite.
        let (rewritten, report) = rewrite_for_tract(&original).expect("rewrite");
        assert_eq!(
            report,
            RewriteReport {
                dequantized: 1,
                operators: 1,
                ..Default::default()
            }
        );
        let model = tract_tflite::tflite()
            .model_for_read(&mut &rewritten[..])
            .expect("loads")
            .into_runnable()
            .expect("runnable");
        let x = tract_ndarray::arr2(&[[1.0_f32, 2.0, 3.0, 4.0]]).into_tensor();
        let out = model.run(tvec!(x.into())).expect("runs");
        let out: Vec<f32> = out[0]
            .to_plain_array_view::<f32>()
            .expect("f32")
            .iter()
            .copied()
            .collect();
        assert_eq!(out, vec![1.5, 0.75, 5.0, 7.5]);
    }

    /// `out = depth_to_space(x + densify->dequantize(s), 2) + dequantize(b)`: a sparse
    /// float16 constant (CSR last dimension), a float16 one, and a `DEPTH_TO_SPACE`, as
    /// in the person detector.
    fn detector_like_model(sparse: &[(usize, f32)], b16: &[f32; 4]) -> Vec<u8> {
        use tract_tflite::tflite::{
            DepthToSpaceOptions, DepthToSpaceOptionsArgs, DimensionMetadata, DimensionMetadataArgs,
            Int32Vector, Int32VectorArgs, SparsityParameters, SparsityParametersArgs,
        };
        let mut b = flatbuffers::FlatBufferBuilder::new();
        let half = |v: &[f32]| -> Vec<u8> {
            v.iter()
                .flat_map(|x| half::f16::from_f32(*x).to_le_bytes())
                .collect()
        };
        let values: Vec<f32> = sparse.iter().map(|(_, v)| *v).collect();
        let data_sparse = b.create_vector(&half(&values));
        let data_b = b.create_vector(&half(b16));
        // Buffer 0 empty; 1 the sparse values; 2, 3, 5 empty (one per tensor); 4 b16.
        let mut buffers = vec![Buffer::create(&mut b, &BufferArgs::default())];
        buffers.push(Buffer::create(
            &mut b,
            &BufferArgs {
                data: Some(data_sparse),
            },
        ));
        buffers.push(Buffer::create(&mut b, &BufferArgs::default()));
        buffers.push(Buffer::create(&mut b, &BufferArgs::default()));
        buffers.push(Buffer::create(&mut b, &BufferArgs { data: Some(data_b) }));
        buffers.push(Buffer::create(&mut b, &BufferArgs::default()));
        let buffers = b.create_vector(&buffers);
        // Sparsity: dims 0-2 dense (size 1), dim 3 CSR.
        let indices: Vec<i32> = sparse.iter().map(|(i, _)| *i as i32).collect();
        let mut dims = Vec::new();
        for _ in 0..3 {
            dims.push(DimensionMetadata::create(
                &mut b,
                &DimensionMetadataArgs {
                    format: DimensionType::DENSE,
                    dense_size: 1,
                    ..Default::default()
                },
            ));
        }
        let seg_values = b.create_vector(&[0, indices.len() as i32]);
        let segments = Int32Vector::create(
            &mut b,
            &Int32VectorArgs {
                values: Some(seg_values),
            },
        );
        let idx_values = b.create_vector(&indices);
        let idx = Int32Vector::create(
            &mut b,
            &Int32VectorArgs {
                values: Some(idx_values),
            },
        );
        dims.push(DimensionMetadata::create(
            &mut b,
            &DimensionMetadataArgs {
                format: DimensionType::SPARSE_CSR,
                array_segments_type: SparseIndexVector::Int32Vector,
                array_segments: Some(segments.as_union_value()),
                array_indices_type: SparseIndexVector::Int32Vector,
                array_indices: Some(idx.as_union_value()),
                ..Default::default()
            },
        ));
        let dims = b.create_vector(&dims);
        let order = b.create_vector(&[0, 1, 2, 3]);
        let sparsity = SparsityParameters::create(
            &mut b,
            &SparsityParametersArgs {
                traversal_order: Some(order),
                dim_metadata: Some(dims),
                ..Default::default()
            },
        );
        let tensor = |b: &mut flatbuffers::FlatBufferBuilder<'static>,
                      name: &str,
                      shape: &[i32],
                      ty,
                      buffer,
                      sparse: bool| {
            let shape = b.create_vector(shape);
            let name = b.create_string(name);
            FlatTensor::create(
                b,
                &TensorArgs {
                    shape: Some(shape),
                    type_: ty,
                    buffer,
                    name: Some(name),
                    sparsity: sparse.then_some(sparsity),
                    ..Default::default()
                },
            )
        };
        let row = [1, 1, 1, 4];
        let square = [1, 2, 2, 1];
        let t = [
            tensor(&mut b, "s16", &row, TensorType::FLOAT16, 1, true),
            tensor(&mut b, "dense16", &row, TensorType::FLOAT16, 2, false),
            tensor(&mut b, "s32", &row, TensorType::FLOAT32, 3, false),
            tensor(&mut b, "x", &row, TensorType::FLOAT32, 0, false),
            tensor(&mut b, "sum", &row, TensorType::FLOAT32, 0, false),
            tensor(&mut b, "d2s", &square, TensorType::FLOAT32, 0, false),
            tensor(&mut b, "b16", &square, TensorType::FLOAT16, 4, false),
            tensor(&mut b, "b32", &square, TensorType::FLOAT32, 5, false),
            tensor(&mut b, "out", &square, TensorType::FLOAT32, 0, false),
        ];
        let tensors = b.create_vector(&t);
        let add = |b: &mut Builder| {
            let o = AddOptions::create(b, &AddOptionsArgs::default());
            Some((BuiltinOptions::AddOptions, o.as_union_value()))
        };
        let d2s = DepthToSpaceOptions::create(&mut b, &DepthToSpaceOptionsArgs { block_size: 2 })
            .as_union_value();
        let (add1, add2) = (add(&mut b), add(&mut b));
        let ops = [
            op(&mut b, 0, &[0], &[1], None),
            op(&mut b, 1, &[1], &[2], None),
            op(&mut b, 2, &[3, 2], &[4], add1),
            op(
                &mut b,
                3,
                &[4],
                &[5],
                Some((BuiltinOptions::DepthToSpaceOptions, d2s)),
            ),
            op(&mut b, 1, &[6], &[7], None),
            op(&mut b, 2, &[5, 7], &[8], add2),
        ];
        let codes = [
            BuiltinOperator::DENSIFY,
            BuiltinOperator::DEQUANTIZE,
            BuiltinOperator::ADD,
            BuiltinOperator::DEPTH_TO_SPACE,
        ];
        finish_model(b, tensors, &ops, (3, 8), &codes, buffers)
    }

    #[test]
    fn sparse_constants_and_depth_to_space_are_rewritten_and_tract_runs_them() {
        // s = [0, 0.5, 0, -2] stored sparse; b added after the depth-to-space.
        let original = detector_like_model(&[(1, 0.5), (3, -2.0)], &[10.0, 20.0, 30.0, 40.0]);
        assert!(
            tract_tflite::tflite()
                .model_for_read(&mut &original[..])
                .is_err()
        );
        let (rewritten, report) = rewrite_for_tract(&original).expect("rewrite");
        assert_eq!(
            report,
            RewriteReport {
                dequantized: 2,
                densified: 1,
                depth_to_space: 1,
                operators: 2 + 3,
            }
        );
        let model = tract_tflite::tflite()
            .model_for_read(&mut &rewritten[..])
            .expect("loads")
            .into_runnable()
            .expect("runnable");
        let x = tract_ndarray::arr1(&[1.0_f32, 2.0, 3.0, 4.0])
            .into_shape_with_order((1, 1, 1, 4))
            .expect("shape")
            .into_tensor();
        let out = model.run(tvec!(x.into())).expect("runs");
        assert_eq!(out[0].shape(), &[1, 2, 2, 1]);
        let got: Vec<f32> = out[0]
            .to_plain_array_view::<f32>()
            .expect("f32")
            .iter()
            .copied()
            .collect();
        // x + s = [1, 2.5, 3, 2]; depth-to-space puts channel (i * 2 + j) at row i,
        // column j; then + b.
        assert_eq!(got, vec![11.0, 22.5, 33.0, 42.0]);
    }

    #[test]
    fn other_bytes_are_refused_with_an_error() {
        assert!(matches!(
            rewrite_for_tract(b"not a model"),
            Err(RewriteError::Invalid(_))
        ));
    }
}
