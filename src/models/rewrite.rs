//! Rewrites a TFLite flatbuffer so that `tract-tflite` loads it: MediaPipe's BlazePose
//! landmark models keep their weights as float16 constants behind `DEQUANTIZE`
//! operators, which tract does not implement.
//!
//! The rewrite edits the file's bytes in place and appends what does not fit, which a
//! flatbuffer allows because every reference is a forward offset relative to where it
//! is stored:
//! - each `DEQUANTIZE` of a float16 constant: the float32 values are appended as a new
//!   byte vector, the constant's buffer points to them and its type becomes float32;
//! - every operator input (and subgraph output) that read the `DEQUANTIZE`'s output
//!   reads that constant instead (tensor indices patched in place);
//! - the `DEQUANTIZE` operators leave the subgraph's operator list (compacted in place).
//!
//! Nothing else changes: tensor indices, the other operators and their options stay
//! where they are. The result passes the flatbuffers verifier (`root_as_model`).
//!
//! Not handled yet (the person detector needs them): `DENSIFY` (sparse constants) and
//! `DEPTH_TO_SPACE`; a model with them is refused by tract, not by this rewrite.

use tract_tflite::tflite::{self, BuiltinOperator, TensorType};

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

/// Stores at `at` the forward offset to `target`.
fn set_offset(b: &mut [u8], at: usize, target: usize) -> Result<(), RewriteError> {
    let rel = target
        .checked_sub(at)
        .and_then(|r| u32::try_from(r).ok())
        .ok_or_else(|| RewriteError::Unsupported("an offset does not fit".into()))?;
    b[at..at + 4].copy_from_slice(&rel.to_le_bytes());
    Ok(())
}

/// Pads `b` to a multiple of `align`, then appends a vector: its length (u32) and
/// `items`. Returns the vector's position (its length prefix).
fn append_vector(b: &mut Vec<u8>, len: usize, items: &[u8], align: usize) -> usize {
    // The elements start 4 bytes after the prefix: align them.
    while (b.len() + 4) % align != 0 {
        b.push(0);
    }
    let at = b.len();
    b.extend_from_slice(&(len as u32).to_le_bytes());
    b.extend_from_slice(items);
    at
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
    let mut out = model.to_vec();
    let mut kept = Vec::new();
    let mut report = RewriteReport::default();
    // DEQUANTIZE output tensor -> the constant it is now.
    let mut replaced = std::collections::HashMap::new();
    for op in operators.iter() {
        let code = codes.get(op.opcode_index() as usize);
        let builtin =
            BuiltinOperator(i32::from(code.deprecated_builtin_code()).max(code.builtin_code().0));
        if builtin != BuiltinOperator::DEQUANTIZE {
            kept.push(op._tab.loc());
            continue;
        }
        let (Some(inputs), Some(outputs)) = (op.inputs(), op.outputs()) else {
            return Err(invalid(&"a DEQUANTIZE without inputs or outputs"));
        };
        let (input, output) = (
            tensors.get(inputs.get(0) as usize),
            tensors.get(outputs.get(0) as usize),
        );
        if input.type_() != TensorType::FLOAT16 || output.type_() != TensorType::FLOAT32 {
            return Err(RewriteError::Unsupported(format!(
                "DEQUANTIZE from {:?} to {:?} (only float16 to float32)",
                input.type_(),
                output.type_()
            )));
        }
        let buffer = buffers.get(input.buffer() as usize);
        let data = buffer
            .data()
            .filter(|d| !d.is_empty())
            .ok_or_else(|| RewriteError::Unsupported("DEQUANTIZE of a non-constant".into()))?;
        let values: Vec<u8> = data
            .bytes()
            .chunks_exact(2)
            .flat_map(|h| {
                half::f16::from_le_bytes([h[0], h[1]])
                    .to_f32()
                    .to_le_bytes()
            })
            .collect();
        let data_field = field_position(&out, buffer._tab.loc(), tflite::Buffer::VT_DATA)
            .ok_or_else(|| invalid(&"a constant buffer without data"))?;
        let vector = append_vector(&mut out, values.len(), &values, 16);
        set_offset(&mut out, data_field, vector)?;
        let type_field = field_position(&out, input._tab.loc(), tflite::Tensor::VT_TYPE_)
            .ok_or_else(|| invalid(&"a float16 tensor without a type field"))?;
        out[type_field] = TensorType::FLOAT32.0 as u8;
        replaced.insert(outputs.get(0), inputs.get(0));
        let _ = output;
        report.dequantized += 1;
    }
    // Readers of a folded output read the constant instead.
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
    for &table in &kept {
        redirect(&mut out, table, tflite::Operator::VT_INPUTS);
    }
    redirect(&mut out, graph._tab.loc(), tflite::SubGraph::VT_OUTPUTS);
    // The operator list, compacted in place: the kept entries move to the front and the
    // length shrinks. Each entry is a forward offset to its table (the tables lie after
    // the list, as a flatbuffer builder writes them); moving an entry forward only makes
    // its offset larger.
    let list_field = field_position(&out, graph._tab.loc(), tflite::SubGraph::VT_OPERATORS)
        .ok_or_else(|| invalid(&"a subgraph without operators"))?;
    let list = list_field + u32_at(&out, list_field) as usize;
    for (i, &table) in kept.iter().enumerate() {
        set_offset(&mut out, list + 4 + 4 * i, table)?;
    }
    out[list..list + 4].copy_from_slice(&(kept.len() as u32).to_le_bytes());
    report.operators = kept.len();
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
        let op =
            |b: &mut flatbuffers::FlatBufferBuilder<'static>,
             code,
             ins: &[i32],
             outs: &[i32],
             options: Option<flatbuffers::WIPOffset<flatbuffers::UnionWIPOffset>>| {
                let inputs = b.create_vector(ins);
                let outputs = b.create_vector(outs);
                Operator::create(
                    b,
                    &OperatorArgs {
                        opcode_index: code,
                        inputs: Some(inputs),
                        outputs: Some(outputs),
                        builtin_options_type: if options.is_some() {
                            BuiltinOptions::AddOptions
                        } else {
                            BuiltinOptions::NONE
                        },
                        builtin_options: options,
                        ..Default::default()
                    },
                )
            };
        let dequantize = op(&mut b, 0, &[0], &[1], None);
        let add_options = AddOptions::create(&mut b, &AddOptionsArgs::default());
        let add = op(&mut b, 1, &[2, 1], &[3], Some(add_options.as_union_value()));
        let operators = b.create_vector(&[dequantize, add]);
        let inputs = b.create_vector(&[2]);
        let outputs = b.create_vector(&[3]);
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
        let codes: Vec<_> = [BuiltinOperator::DEQUANTIZE, BuiltinOperator::ADD]
            .iter()
            .map(|&code| {
                OperatorCode::create(
                    &mut b,
                    &OperatorCodeArgs {
                        deprecated_builtin_code: code.0 as i8,
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
                operators: 1
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

    #[test]
    fn other_bytes_are_refused_with_an_error() {
        assert!(matches!(
            rewrite_for_tract(b"not a model"),
            Err(RewriteError::Invalid(_))
        ));
    }
}
