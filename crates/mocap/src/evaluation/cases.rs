//! What the evaluation runs on: its [`Settings`], and each held-out sequence prepared
//! as a [`Case`] (its views and heat maps).

use super::Mean;
use crate::MappedSequence;
use crate::synth::{self, CameraSpec, ErrorModel, Projection, RenderedMaps, View, heatmaps};
use posestream_math::skeleton::Skeleton;

/// What the evaluation runs on.
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    /// Frames per sequence at most (from the start).
    pub max_frames: usize,
    /// Orbit speed of the moving camera of Table 1, deg/s.
    pub orbit_deg_per_s: f64,
    /// The heat-map camera (azimuth is set per sequence).
    pub camera: CameraSpec,
    /// The synthetic detector's error model (seeded per sequence from its `seed`).
    pub errors: ErrorModel,
    /// PCK threshold, pixels of a 256-pixel crop.
    pub pck_threshold: f64,
    /// Crop box side, times the joints' extent.
    pub margin: f64,
    /// Mean bone length (metres, over the layout's tree) every held-out subject is scaled
    /// to, so that millimetres refer to a body of known size.
    pub limb_length: f64,
    /// Actions of the per-action table (the held-out contents); empty = every action.
    pub actions: Vec<String>,
    /// The sequences are the split's training files, not its held-out ones (`eval
    /// --train`, to calibrate without looking at the held-out motion).
    pub training: bool,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            max_frames: 150,
            orbit_deg_per_s: 15.0,
            camera: CameraSpec::default(),
            errors: ErrorModel::default(),
            pck_threshold: 10.0,
            margin: 1.25,
            limb_length: posestream_math::solver::perspective::PerspectiveParams::default()
                .mean_limb_length,
            actions: Vec::new(),
            training: false,
        }
    }
}

/// One held-out sequence, prepared.
#[derive(Debug, Clone)]
pub struct Case {
    /// File stem.
    pub name: String,
    /// Action (content) of the file.
    pub action: String,
    /// Orthographic static view (Table 1).
    pub still: View,
    /// Orthographic orbiting view (Table 1).
    pub orbit: View,
    /// Pinhole view the heat maps were rendered from (Table 3).
    pub pinhole: View,
    /// Heat maps of the pinhole view.
    pub maps: RenderedMaps,
}

impl Case {
    /// Prepares the views and heat maps of a mapped sequence; `index` picks its azimuth
    /// and the error model's seed.
    pub fn new(
        name: String,
        action: String,
        seq: &MappedSequence,
        skeleton: &Skeleton,
        settings: &Settings,
        index: usize,
    ) -> Result<Self, String> {
        let mut seq = seq
            .frames_from(0, settings.max_frames)
            .ok_or("the sequence has no frames")?;
        let scale = settings.limb_length / mean_bone_length(&seq, skeleton);
        if !scale.is_finite() {
            return Err("the subject's bones have no length".into());
        }
        seq.positions.iter_mut().for_each(|v| *v *= scale);
        let azimuth = (47.0 * index as f64) % 360.0;
        let ortho = CameraSpec {
            azimuth_deg: azimuth,
            projection: Projection::Orthographic,
            orbit_deg_per_s: 0.0,
            ..settings.camera.clone()
        };
        let still = synth::view(&seq, skeleton, &ortho)?;
        let orbit = synth::view(
            &seq,
            skeleton,
            &CameraSpec {
                orbit_deg_per_s: settings.orbit_deg_per_s,
                ..ortho
            },
        )?;
        let pin = CameraSpec {
            azimuth_deg: azimuth,
            ..settings.camera.clone()
        };
        let pinhole = synth::view(&seq, skeleton, &pin)?;
        let boxes = synth::crop_boxes(&pinhole.image_2d, pinhole.joints, settings.margin);
        let errors = ErrorModel {
            seed: settings.errors.seed.wrapping_add(index as u64),
            ..settings.errors.clone()
        };
        let maps = heatmaps::render(&pinhole.image_2d, &boxes, skeleton, &errors)
            .map_err(|e| e.to_string())?;
        Ok(Self {
            name,
            action,
            still,
            orbit,
            pinhole,
            maps,
        })
    }
}

/// The mean bone length of a sequence over the skeleton's tree (its units).
pub fn mean_bone_length(seq: &MappedSequence, skeleton: &Skeleton) -> f64 {
    let mut total = Mean::default();
    for frame in seq.positions.chunks_exact(3 * seq.joints) {
        for (a, b) in skeleton.bones() {
            let d: f64 = (0..3)
                .map(|i| (frame[3 * a + i] - frame[3 * b + i]).powi(2))
                .sum();
            total.add(d.sqrt(), 1.0);
        }
    }
    total.get()
}
