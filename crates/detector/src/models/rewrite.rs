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
mod tests;
