//! TensorFlow.js graph models (`model.json` + binary weight shards), read and turned
//! into a tract model, without TensorFlow: the person detector ships as one
//! ([`super::nanodet`]).
//!
//! A TF.js graph model is a TensorFlow `GraphDef` written as JSON (`modelTopology.node`:
//! name, op, inputs, attributes) with its constants moved out to a weights manifest
//! (names, shapes, dtypes, optional float16 storage) over the shards' concatenated
//! bytes. [`GraphModel::parse`] reads both, checking every size against the bytes
//! there are (checked arithmetic, limits); [`GraphModel::to_tract`] wires its nodes as
//! tract operators for an input of a chosen size. Only the operators such converted
//! detectors use are known (those of NanoDet's graph, written by `onnx-tf`): any other
//! is an error naming it. tract's own TensorFlow reader knows neither `LeakyRelu`,
//! `ResizeBilinear`, `PadV2`, `SplitV` nor `SparseToDense`, hence this translation.

use std::collections::HashMap;

use half::f16;
use tract_tflite::internal::*;

/// `model.json` larger than this is not a model of ours (NanoDet's: 122 kB).
pub const MAX_JSON_BYTES: u64 = 8 << 20;
/// Weight shards larger than this in all (NanoDet's: 7.6 MB).
pub const MAX_WEIGHT_BYTES: u64 = 256 << 20;
/// Nodes in a graph at most (NanoDet's: 489).
pub const MAX_NODES: usize = 100_000;

/// Why a TF.js model could not be read or translated.
#[derive(Debug, thiserror::Error)]
pub enum TfjsError {
    /// Not a TF.js graph model (or a damaged one).
    #[error("not a TensorFlow.js graph model: {0}")]
    Invalid(String),
    /// It uses something the translation does not know.
    #[error("cannot translate the graph: {0}")]
    Unsupported(String),
    /// tract refused what was wired.
    #[error("{context}: {reason}")]
    Tract {
        /// What was being done.
        context: String,
        /// tract's message.
        reason: String,
    },
}

fn invalid(what: impl Into<String>) -> TfjsError {
    TfjsError::Invalid(what.into())
}

fn unsupported(what: impl Into<String>) -> TfjsError {
    TfjsError::Unsupported(what.into())
}

fn tract(context: impl Into<String>) -> impl FnOnce(TractError) -> TfjsError {
    let context = context.into();
    move |e| TfjsError::Tract {
        context,
        reason: format!("{e:#}"),
    }
}

#[derive(serde::Deserialize)]
#[serde(rename_all = "camelCase")]
struct ModelJson {
    format: Option<String>,
    model_topology: Topology,
    weights_manifest: Vec<ManifestGroup>,
}

#[derive(serde::Deserialize)]
struct Topology {
    node: Vec<Node>,
}

/// One node of the graph.
#[derive(Debug, Clone, serde::Deserialize)]
pub struct Node {
    /// Its name.
    pub name: String,
    /// The TensorFlow operator.
    pub op: String,
    /// Its inputs: `name` or `name:port` (`^name`: a control input, ignored).
    #[serde(default)]
    pub input: Vec<String>,
    /// Its attributes, as TF.js writes an `AttrValue` in JSON.
    #[serde(default)]
    pub attr: HashMap<String, serde_json::Value>,
}

#[derive(serde::Deserialize)]
struct ManifestGroup {
    paths: Vec<String>,
    weights: Vec<WeightEntry>,
}

#[derive(serde::Deserialize)]
struct WeightEntry {
    name: String,
    shape: Vec<i64>,
    dtype: String,
    quantization: Option<Quantization>,
}

#[derive(serde::Deserialize)]
struct Quantization {
    dtype: String,
}

/// A TF.js graph model: its nodes and its constants.
#[derive(Debug)]
pub struct GraphModel {
    /// The nodes, in the file's order.
    pub nodes: Vec<Node>,
    /// The constants by node name (float16 ones widened to float32).
    pub weights: HashMap<String, Tensor>,
}

impl GraphModel {
    /// Reads `json` (`model.json`) and its weight shards: `shard(path)` gives the bytes
    /// of each path the manifest names. Every weight's size is checked against the
    /// bytes there are; the shards must be used exactly.
    pub fn parse(
        json: &[u8],
        mut shard: impl FnMut(&str) -> Option<Vec<u8>>,
    ) -> Result<Self, TfjsError> {
        if json.len() as u64 > MAX_JSON_BYTES {
            return Err(invalid(format!("model.json over {MAX_JSON_BYTES} bytes")));
        }
        let model: ModelJson =
            serde_json::from_slice(json).map_err(|e| invalid(format!("model.json: {e}")))?;
        if model.format.as_deref().is_some_and(|f| f != "graph-model") {
            return Err(invalid(format!("format {:?}", model.format)));
        }
        let nodes = model.model_topology.node;
        if nodes.len() > MAX_NODES {
            return Err(invalid(format!("{} nodes, over {MAX_NODES}", nodes.len())));
        }
        let mut weights = HashMap::new();
        let mut total = 0u64;
        for group in model.weights_manifest {
            let mut bytes = Vec::new();
            for path in &group.paths {
                let data = shard(path).ok_or_else(|| invalid(format!("no weight shard {path}")))?;
                total = total.saturating_add(data.len() as u64);
                if total > MAX_WEIGHT_BYTES {
                    return Err(invalid(format!("weights over {MAX_WEIGHT_BYTES} bytes")));
                }
                bytes.extend_from_slice(&data);
            }
            let mut at = 0usize;
            for w in group.weights {
                let (tensor, used) = weight(&w, &bytes[at..])?;
                at += used;
                weights.insert(w.name, tensor);
            }
            if at != bytes.len() {
                return Err(invalid(format!(
                    "the manifest uses {at} of the shards' {} bytes",
                    bytes.len()
                )));
            }
        }
        Ok(Self { nodes, weights })
    }
}

/// One weight from the start of `bytes`: the tensor and the bytes it took.
fn weight(w: &WeightEntry, bytes: &[u8]) -> Result<(Tensor, usize), TfjsError> {
    let shape: Vec<usize> = w
        .shape
        .iter()
        .map(|&d| usize::try_from(d).map_err(|_| invalid(format!("{}: dimension {d}", w.name))))
        .collect::<Result<_, _>>()?;
    let count = shape
        .iter()
        .try_fold(1usize, |n, &d| n.checked_mul(d))
        .ok_or_else(|| invalid(format!("{}: shape {shape:?} overflows", w.name)))?;
    let stored = match (&w.quantization, w.dtype.as_str()) {
        (None, t) => t,
        (Some(q), "float32") if q.dtype == "float16" => "float16",
        (Some(q), t) => {
            return Err(unsupported(format!(
                "{}: {t} stored as {}",
                w.name, q.dtype
            )));
        }
    };
    let width = match stored {
        "float16" => 2,
        "float32" | "int32" => 4,
        other => return Err(unsupported(format!("{}: dtype {other}", w.name))),
    };
    let len = count
        .checked_mul(width)
        .filter(|&n| n <= bytes.len())
        .ok_or_else(|| invalid(format!("{}: {count} values past the shards' end", w.name)))?;
    let raw = &bytes[..len];
    let tensor = match stored {
        "float16" => {
            let v: Vec<f32> = raw
                .chunks_exact(2)
                .map(|c| f16::from_le_bytes([c[0], c[1]]).to_f32())
                .collect();
            Tensor::from_shape(&shape, &v)
        }
        "float32" => {
            let v: Vec<f32> = raw
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            Tensor::from_shape(&shape, &v)
        }
        _ => {
            let v: Vec<i32> = raw
                .chunks_exact(4)
                .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            Tensor::from_shape(&shape, &v)
        }
    }
    .map_err(|e| invalid(format!("{}: {e}", w.name)))?;
    Ok((tensor, len))
}

mod translate;

#[cfg(test)]
mod tests;
