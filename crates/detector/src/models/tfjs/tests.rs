//! The TF.js reader and translation on small graphs written here.

use super::translate::{reshaped, sparse_to_dense, values};
use super::*;

fn json(nodes: &str, weights: &str) -> Vec<u8> {
    format!(
        r#"{{"format": "graph-model", "modelTopology": {{"node": [{nodes}]}},
            "weightsManifest": [{{"paths": ["w.bin"], "weights": [{weights}]}}]}}"#
    )
    .into_bytes()
}

const INPUT: &str = r#"{"name": "x", "op": "Placeholder", "attr": {"shape": {"shape": {"dim": [{"size": "1"}, {"size": "3"}, {"size": "4"}, {"size": "4"}]}}}}"#;

#[test]
fn weights_are_read_as_the_manifest_says_and_sizes_are_checked() {
    let nodes =
        format!(r#"{INPUT}, {{"name": "c", "op": "Const"}}, {{"name": "h", "op": "Const"}}"#);
    let weights = r#"{"name": "c", "shape": [2], "dtype": "int32"},
        {"name": "h", "shape": [2], "dtype": "float32", "quantization": {"dtype": "float16", "original_dtype": "float32"}}"#;
    let mut bin = Vec::new();
    bin.extend(7i32.to_le_bytes());
    bin.extend((-3i32).to_le_bytes());
    bin.extend(f16::from_f32(1.5).to_le_bytes());
    bin.extend(f16::NEG_INFINITY.to_le_bytes());
    let g = GraphModel::parse(&json(&nodes, weights), |_| Some(bin.clone())).expect("parsed");
    assert_eq!(values::<i32>(&g.weights["c"]).expect("i32"), [7, -3]);
    assert_eq!(
        values::<f32>(&g.weights["h"]).expect("f32"),
        [1.5, f32::NEG_INFINITY]
    );
    // A shard one byte short, one byte long, missing; a shape that overflows.
    let short = GraphModel::parse(&json(&nodes, weights), |_| Some(bin[..11].to_vec()));
    assert!(matches!(short, Err(TfjsError::Invalid(_))), "{short:?}");
    let mut long = bin.clone();
    long.push(0);
    assert!(GraphModel::parse(&json(&nodes, weights), |_| Some(long.clone())).is_err());
    assert!(GraphModel::parse(&json(&nodes, weights), |_| None).is_err());
    let huge = r#"{"name": "c", "shape": [4294967296, 4294967296, 4294967296], "dtype": "int32"}"#;
    let e = GraphModel::parse(&json(&nodes, huge), |_| Some(bin.clone())).expect_err("refused");
    assert!(e.to_string().contains("overflows"), "{e}");
    assert!(GraphModel::parse(b"{}", |_| None).is_err());
    assert!(GraphModel::parse(b"\xff\xfe", |_| None).is_err());
}

#[test]
fn a_small_graph_translates_and_runs_like_its_definition() {
    // x (NCHW) -> NHWC -> 1x1 conv (2 -> 1 channels... 3 -> 2) + bias -> leaky relu
    // -> split 1 + 1 -> sigmoid of the first.
    let nodes = format!(
        r#"{INPUT},
        {{"name": "perm", "op": "Const"}}, {{"name": "k", "op": "Const"}},
        {{"name": "b", "op": "Const"}}, {{"name": "sizes", "op": "Const"}}, {{"name": "axis", "op": "Const"}},
        {{"name": "t", "op": "Transpose", "input": ["x", "perm"]}},
        {{"name": "conv", "op": "Conv2D", "input": ["t", "k"], "attr": {{"padding": {{"s": "VkFMSUQ="}}, "data_format": {{"s": "TkhXQw=="}}, "strides": {{"list": {{"i": ["1", "1", "1", "1"]}}}}}}}},
        {{"name": "add", "op": "Add", "input": ["conv", "b"]}},
        {{"name": "relu", "op": "LeakyRelu", "input": ["add"], "attr": {{"alpha": {{"f": 0.1}}}}}},
        {{"name": "split", "op": "SplitV", "input": ["relu", "sizes", "axis"]}},
        {{"name": "s", "op": "Sigmoid", "input": ["split"]}},
        {{"name": "out", "op": "Identity", "input": ["split:1"]}}"#
    );
    let weights = r#"{"name": "perm", "shape": [4], "dtype": "int32"},
        {"name": "k", "shape": [1, 1, 3, 2], "dtype": "float32"},
        {"name": "b", "shape": [2], "dtype": "float32"},
        {"name": "sizes", "shape": [2], "dtype": "int32"},
        {"name": "axis", "shape": [], "dtype": "int32"}"#;
    let mut bin = Vec::new();
    for p in [0i32, 2, 3, 1] {
        bin.extend(p.to_le_bytes());
    }
    // Channel 0: r + g + b; channel 1: r - b.
    for v in [1.0f32, 1.0, 1.0, 0.0, 1.0, -1.0] {
        bin.extend(v.to_le_bytes());
    }
    for v in [0.0f32, -1.0] {
        bin.extend(v.to_le_bytes());
    }
    for v in [1i32, 1, 3] {
        bin.extend(v.to_le_bytes());
    }
    let g = GraphModel::parse(&json(&nodes, weights), |_| Some(bin.clone())).expect("parsed");
    // At another size than the graph's own: 2 x 3.
    let model = g
        .to_tract(2, 3, &["s", "out"], |_, o| Ok(o.to_vec()))
        .expect("translated");
    let plan = model.into_runnable().expect("runnable");
    let input: Vec<f32> = (0..18).map(|i| i as f32 * 0.1).collect();
    let out = plan
        .run(tvec![
            Tensor::from_shape(&[1, 2, 3, 3], &input)
                .expect("input")
                .into()
        ])
        .expect("ran");
    let s = values::<f32>(&out[0]).expect("f32");
    let second = values::<f32>(&out[1]).expect("f32");
    assert_eq!(out[0].shape(), &[1, 2, 3, 1]);
    for (p, px) in input.chunks_exact(3).enumerate() {
        let sum = px[0] + px[1] + px[2];
        assert!((s[p] - 1.0 / (1.0 + (-sum).exp())).abs() < 1e-5, "{p}");
        let d = px[0] - px[2] - 1.0;
        let relu = if d < 0.0 { 0.1 * d } else { d };
        assert!((second[p] - relu).abs() < 1e-5, "{p}");
    }
    // An operator it does not know is named.
    let unknown = json(
        &format!(r#"{INPUT}, {{"name": "q", "op": "Qr", "input": ["x"]}}"#),
        "",
    );
    let e = GraphModel::parse(&unknown, |_| Some(Vec::new()))
        .expect("parsed")
        .to_tract(4, 4, &["q"], |_, o| Ok(o.to_vec()))
        .expect_err("refused");
    assert!(e.to_string().contains("operator Qr"), "{e}");
    // An input never defined (or a cycle) is an error, not a loop.
    let cycle = json(
        &format!(
            r#"{INPUT}, {{"name": "a", "op": "Identity", "input": ["b"]}}, {{"name": "b", "op": "Identity", "input": ["a"]}}"#
        ),
        "",
    );
    let e = GraphModel::parse(&cycle, |_| Some(Vec::new()))
        .expect("parsed")
        .to_tract(4, 4, &["a"], |_, o| Ok(o.to_vec()))
        .expect_err("refused");
    assert!(e.to_string().contains("never defined"), "{e}");
}

#[test]
fn reshapes_and_sparse_constants_follow_tensorflow() {
    assert_eq!(
        reshaped("r", &[1, 80, 13, 13], &[1, 80, -1]).expect("ok"),
        [1, 80, 169]
    );
    assert!(reshaped("r", &[1, 80, 13, 13], &[1, 81, -1]).is_err());
    assert!(reshaped("r", &[1, 80], &[-1, -1]).is_err());
    // Nothing to reshape into a free dimension beside a 0; products that overflow.
    assert!(reshaped("r", &[0, 3], &[-1, 0]).is_err());
    assert!(reshaped("r", &[1], &[1 << 32, 1 << 32, -1]).is_err());
    assert!(reshaped("r", &[usize::MAX, 2], &[-1]).is_err());
    let d = sparse_to_dense(
        "s",
        &Tensor::from_shape::<i32>(&[0, 1], &[]).expect("t"),
        &tensor1(&[3i32]),
        &Tensor::from_shape::<i32>(&[0], &[]).expect("t"),
        &tensor0(0i32),
    )
    .expect("dense");
    assert_eq!(values::<i32>(&d).expect("i32"), [0, 0, 0]);
    let big = sparse_to_dense(
        "s",
        &tensor1(&[0i32]),
        &tensor1(&[i32::MAX]),
        &tensor1(&[1i32]),
        &tensor0(0i32),
    );
    assert!(big.is_err());
}
