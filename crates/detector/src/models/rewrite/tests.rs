//! Unit tests of `rewrite`.

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
