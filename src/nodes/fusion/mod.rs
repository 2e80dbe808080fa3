//! The fusion node: several calibrated cameras' heat maps in, one [`Skeleton3D`] per
//! person out, in the world frame (`posestream fuse`; docs/fusion.md, "The service").
//! A thin adapter: the maths is [`crate::fusion`]'s.
//!
//! 1. Each camera's heat-map messages (any track ids: they agree with nobody's) are
//!    checked against the limits and the dictionary's joints, dequantised once into a
//!    buffer of the fused frame nearest their capture time (frames `1 / frame_rate`
//!    apart from the first stamp heard), with their offset from it;
//! 2. a fused frame is made once every camera still sending has sent a later frame, or
//!    `wait` after its first message (in the input's clock), or when too many wait;
//!    a message for a frame already made is refused (`late`);
//! 3. the cameras' tracks are matched into people by geometry ([`Matcher`]), each
//!    person's views go to their [`FusedWindow`], and its estimates become skeletons:
//!    `frame_id` the world frame, metres, the cameras used in `views`.
//!
//! A camera is used once it is calibrated: intrinsics from its `CameraInfo` (or the
//! configuration), its pose from TF (`world_frame` to the frame id of its heat maps) or
//! the configuration. Frames of a camera not calibrated yet are refused (`uncalibrated`).

mod cameras;
mod fuse;
mod take;
#[cfg(test)]
mod tests;

use std::collections::{BTreeMap, VecDeque};

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

use super::config::{ExtrinsicsSource, FusionConfig};
use super::errors::{NodeError, Refusals, SetupError};
use super::tf_buffer::{TfBuffer, TfTopic};
use crate::camera::Intrinsics;
use crate::estimator::Estimator;
use crate::fusion::{
    ExtrinsicsCheck, FusedEstimate, FusedWindow, FusionSettings, Matcher, TrackObservation,
    ViewCamera, ViewMaps, ViewResidual, matching::peaks_into, suspects,
};
use crate::limits::Limits;
use crate::msgs::sensor::CameraInfo;
use crate::msgs::tf::TFMessage;
use crate::msgs::{self, Header, HeatMaps, MetricSource, Skeleton3D, SkeletonState, Time, Units};
use crate::skeleton::same_layout;
use posestream_base::CropBox;
use posestream_base::Scores;

/// Fused frames waiting at most: a frame further ahead makes the oldest ones now.
const MAX_PENDING: usize = 64;

/// Frames in a row far from the fused frames' time that make a camera say the time
/// jumped (fewer: a stray stamp, refused).
const JUMP_FRAMES: usize = 15;

/// What became of a frame.
enum Taken {
    /// It waits in its fused frame (or was replaced there by a nearer one).
    Frame,
    /// Most cameras' time jumped: the fused frames start again (it was not taken).
    Restart,
}

/// Camera frames waiting in them at most (each at most `[limits]`' frame): more make
/// the oldest fused frames now.
const MAX_BUFFERED: usize = 256;

/// One camera as the node knows it.
#[derive(Debug, Clone)]
struct Camera {
    name: String,
    /// Its frame id, from its first heat maps or calibration.
    frame_id: Option<String>,
    /// Intrinsics from the configuration (kept over any `CameraInfo`).
    configured_intrinsics: Option<Intrinsics>,
    intrinsics: Option<Intrinsics>,
    pose: Option<Isometry3<f64>>,
    /// The newest capture time sent, and when (the input's clock) it last sent.
    newest_ns: Option<i64>,
    heard_ns: Option<i64>,
    /// Frames in a row far from the fused frames' time, and when (the input's clock) the
    /// last came.
    off_clock: (usize, Option<i64>),
    /// Frames taken and frames its views were used in.
    frames: u64,
    used: u64,
}

impl Camera {
    fn calibrated(&self) -> Option<ViewCamera> {
        Some(ViewCamera {
            intrinsics: self.intrinsics?,
            world_from_camera: self.pose?,
        })
    }
}

/// One camera's frame of one track, waiting in its fused frame.
#[derive(Debug, Default)]
struct TrackFrame {
    camera: usize,
    track: u32,
    /// Capture time minus the fused frame's, nanoseconds.
    offset_ns: i64,
    crop: Option<CropBox>,
    height: usize,
    width: usize,
    /// The scores, dequantised: the frame's one copy.
    values: Vec<f32>,
}

/// A fused frame being gathered.
#[derive(Debug, Default)]
struct Pending {
    index: i64,
    /// When its first message came (the input's clock).
    first_heard_ns: i64,
    frames: Vec<TrackFrame>,
}

/// What the node counted.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct FusionCounters {
    /// Heat-map messages taken.
    pub frames: u64,
    /// Fused frames made.
    pub fused: u64,
    /// Skeletons made.
    pub skeletons: u64,
    /// People (matched ids) seen.
    pub people: u64,
    /// Camera tracks in fused frames that were matched to nobody.
    pub unmatched: u64,
    /// Frames that a nearer frame of the same camera and track replaced in their fused
    /// frame (a camera faster than `frame_rate`, or two people under one id).
    pub superseded: u64,
    /// Times the fused frames started again (the capture times jumped).
    pub restarts: u64,
}

/// One camera in the node's report.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct CameraReport {
    /// Its name.
    pub name: String,
    /// Its frame id (empty before its first message).
    pub frame_id: String,
    /// Whether it is calibrated (intrinsics and pose known).
    pub calibrated: bool,
    /// Heat-map messages taken.
    pub frames: u64,
    /// Of them, those whose views a person's fused frame used.
    pub used: u64,
    /// Its mean residual against the fused poses (a fraction of the person's box; NaN
    /// before any, as JSON null), and the frames it is over.
    pub residual: Option<f64>,
    /// Frames of that residual.
    pub residual_frames: usize,
    /// Its extrinsics disagree with the other cameras' ([`crate::fusion::extrinsics`]).
    pub suspect: bool,
}

/// The fusion node (module docs).
pub struct FusionNode {
    estimator: Estimator,
    settings: FusionSettings,
    check: ExtrinsicsCheck,
    world_frame: String,
    extrinsics: ExtrinsicsSource,
    period_ns: i64,
    wait_ns: i64,
    limits: Limits,
    joint_names: Vec<String>,
    cameras: Vec<Camera>,
    /// The cameras as the windows take them (placeholders for those not calibrated).
    rig: Vec<ViewCamera>,
    tf: TfBuffer,
    /// The first stamp heard: fused frame 0.
    epoch_ns: Option<i64>,
    /// The first fused frame not made yet.
    next_index: i64,
    pending: VecDeque<Pending>,
    spare_frames: Vec<TrackFrame>,
    /// A message's scores, decoded before its frame takes a place (then swapped in).
    decoded: Vec<f32>,
    matcher: Matcher,
    windows: BTreeMap<u64, FusedWindow>,
    /// Residuals of the people forgotten.
    ended_residuals: Vec<ViewResidual>,
    /// The cameras named as suspects last.
    suspects: Vec<usize>,
    counters: FusionCounters,
    refused: Refusals,
    peaks: Vec<Vec<[f64; 3]>>,
    ids: Vec<Option<u64>>,
    estimates: Vec<FusedEstimate>,
}

impl FusionNode {
    /// The node of `config`'s `[fusion]` cameras with `estimator` (the dictionary and
    /// E-step parameters) and the multi-view settings.
    pub fn new(
        estimator: Estimator,
        config: &FusionConfig,
        settings: FusionSettings,
        limits: Limits,
    ) -> Result<Self, SetupError> {
        let param = |e: String| SetupError::Parameter(crate::error::EstimateError::Parameter(e));
        let placeholder = ViewCamera {
            intrinsics: Intrinsics::new(1000.0, 1000.0, 500.0, 500.0).map_err(param)?,
            world_from_camera: Isometry3::identity(),
        };
        let mut cameras = Vec::new();
        for name in &config.cameras {
            let configured_intrinsics = match config.intrinsics.get(name) {
                Some(k) => Some(
                    Intrinsics::new(k[0], k[1], k[2], k[3])
                        .map_err(|e| param(format!("fusion.intrinsics.{name}: {e}")))?,
                ),
                None => None,
            };
            let configured_pose = match (config.extrinsics, config.poses.get(name)) {
                (ExtrinsicsSource::Config, Some(p)) => Some(Isometry3::from_parts(
                    Translation3::new(p[0], p[1], p[2]),
                    UnitQuaternion::from_quaternion(Quaternion::new(p[6], p[3], p[4], p[5])),
                )),
                _ => None,
            };
            cameras.push(Camera {
                name: name.clone(),
                frame_id: None,
                configured_intrinsics,
                intrinsics: configured_intrinsics,
                pose: configured_pose,
                newest_ns: None,
                heard_ns: None,
                off_clock: (0, None),
                frames: 0,
                used: 0,
            });
        }
        if cameras.is_empty() {
            return Err(param(
                "fusion.cameras is empty: name the cameras to fuse (docs/fusion.md)".into(),
            ));
        }
        settings
            .check()
            .map_err(|e| param(format!("estimator.fusion: {e}")))?;
        let matcher = Matcher::new(settings.matching.clone())
            .map_err(|e| param(format!("estimator.fusion.matching: {e}")))?;
        let joint_names = estimator.dictionary().skeleton().joints.clone();
        let n = cameras.len();
        let mut node = Self {
            check: settings.extrinsics.clone(),
            estimator,
            settings,
            world_frame: config.world_frame.trim_start_matches('/').to_string(),
            extrinsics: config.extrinsics,
            period_ns: (1e9 / config.frame_rate).round() as i64,
            wait_ns: (config.wait * 1e9).round() as i64,
            limits,
            joint_names,
            cameras,
            rig: vec![placeholder; n],
            tf: TfBuffer::new(),
            epoch_ns: None,
            next_index: 0,
            pending: VecDeque::new(),
            spare_frames: Vec::new(),
            decoded: Vec::new(),
            matcher,
            windows: BTreeMap::new(),
            ended_residuals: vec![ViewResidual::default(); n],
            suspects: Vec::new(),
            counters: FusionCounters::default(),
            refused: Refusals::default(),
            peaks: Vec::new(),
            ids: Vec::new(),
            estimates: Vec::new(),
        };
        node.update_rig();
        Ok(node)
    }

    /// The skeletons' joints.
    pub fn joint_names(&self) -> &[String] {
        &self.joint_names
    }

    /// The dictionary's bones.
    pub fn bones(&self) -> Vec<(usize, usize)> {
        self.estimator.dictionary().skeleton().bones().collect()
    }

    /// The skeleton's root joint (the pelvis).
    pub fn root(&self) -> usize {
        self.estimator.dictionary().skeleton().root()
    }

    /// The refined estimates' lag.
    pub fn lag(&self) -> u32 {
        self.settings.lag as u32
    }

    /// What was counted.
    pub fn counters(&self) -> &FusionCounters {
        &self.counters
    }

    /// Messages refused, by kind.
    pub fn refused(&self) -> &Refusals {
        &self.refused
    }

    /// Counts a message its transport refused.
    pub fn count_refused(&mut self, error: &crate::transport::TransportError) {
        self.refused
            .note(error.refusal().unwrap_or("undecodable"), error);
    }

    /// Takes camera `camera`'s heat maps, heard at `now_ns` (the input's clock: arrival
    /// time live, log time in a recording), into their fused frame; then makes the fused
    /// frames that are due, their skeletons appended to `out`. A bad message is refused,
    /// counted and logged once per kind.
    pub fn heat_maps(
        &mut self,
        camera: usize,
        msg: &HeatMaps,
        now_ns: i64,
        out: &mut Vec<Skeleton3D>,
    ) -> Result<(), NodeError> {
        let mut taken = self.take(camera, msg, now_ns);
        if let Ok(Taken::Restart) = taken {
            // What waits is fused first; then the fused frames start from this one.
            self.finish(out);
            self.restart();
            taken = self.take(camera, msg, now_ns);
        }
        if let Err(e) = &taken {
            self.refused.note(e.kind(), e);
        }
        self.step(now_ns, out);
        taken.map(|_| ())
    }

    /// Makes the fused frames that are due at `now_ns` (the input went quiet: call it
    /// now and then); their skeletons appended to `out`.
    pub fn step(&mut self, now_ns: i64, out: &mut Vec<Skeleton3D>) {
        while self
            .pending
            .front()
            .is_some_and(|first| self.due(first, now_ns))
        {
            if let Some(slot) = self.pending.pop_front() {
                self.fuse(slot, out);
            }
        }
    }

    /// Makes every fused frame waiting (the input ended).
    pub fn finish(&mut self, out: &mut Vec<Skeleton3D>) {
        while let Some(slot) = self.pending.pop_front() {
            self.fuse(slot, out);
        }
    }

    /// Whether fused frame `slot` is due at `now_ns`.
    fn due(&self, slot: &Pending, now_ns: i64) -> bool {
        let buffered: usize = self.pending.iter().map(|s| s.frames.len()).sum();
        if self.pending.len() > MAX_PENDING
            || buffered > MAX_BUFFERED
            || now_ns - slot.first_heard_ns >= self.wait_ns
        {
            return true;
        }
        let Some(epoch) = self.epoch_ns else {
            return true;
        };
        // Every camera still sending has sent a frame past this one's half period.
        let end = epoch + slot.index * self.period_ns + self.period_ns / 2;
        self.cameras
            .iter()
            .all(|c| match (c.heard_ns, c.newest_ns) {
                (Some(heard), Some(newest)) => now_ns - heard >= self.wait_ns || newest >= end,
                _ => true,
            })
    }
}
