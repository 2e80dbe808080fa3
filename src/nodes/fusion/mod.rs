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

use std::collections::{BTreeMap, VecDeque};

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

use super::config::{ExtrinsicsSource, FusionConfig};
use super::tf_buffer::TfBuffer;
use super::{NodeError, Refusals, SetupError};
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

    /// Each camera: calibration, frames, residual against the fused poses, whether its
    /// extrinsics are suspect.
    pub fn cameras(&self) -> Vec<CameraReport> {
        let residuals = self.residuals();
        self.cameras
            .iter()
            .zip(&residuals)
            .enumerate()
            .map(|(v, (c, r))| CameraReport {
                name: c.name.clone(),
                frame_id: c.frame_id.clone().unwrap_or_default(),
                calibrated: c.calibrated().is_some(),
                frames: c.frames,
                used: c.used,
                residual: Some(r.mean()).filter(|m| m.is_finite()),
                residual_frames: r.frames,
                suspect: self.suspects.contains(&v),
            })
            .collect()
    }

    /// Every camera's residuals: the people forgotten and those tracked.
    fn residuals(&self) -> Vec<ViewResidual> {
        let mut all = self.ended_residuals.clone();
        for w in self.windows.values() {
            for (a, r) in all.iter_mut().zip(w.residuals()) {
                a.merge(r);
            }
        }
        all
    }

    /// Takes camera `camera`'s calibration: its intrinsics (unless configured) and, the
    /// first time, its frame id. A calibration that cannot be used is refused
    /// (`camera-info`).
    pub fn camera_info(&mut self, camera: usize, info: &CameraInfo) {
        let result = super::calibration(info, &self.limits).map(|(intrinsics, _)| intrinsics);
        let Some(c) = self.cameras.get_mut(camera) else {
            return;
        };
        match result {
            Ok(intrinsics) => {
                let mut changed = false;
                if c.frame_id.is_none() && !info.header.frame_id.is_empty() {
                    c.frame_id = Some(info.header.frame_id.trim_start_matches('/').to_string());
                    changed = true;
                }
                if c.configured_intrinsics.is_none() && c.intrinsics != Some(intrinsics) {
                    c.intrinsics = Some(intrinsics);
                    changed = true;
                }
                if changed {
                    self.update_rig();
                }
            }
            Err(reason) => {
                let e = NodeError::CameraInfo {
                    reason: format!("camera {}: {reason}", c.name),
                };
                self.refused.note(e.kind(), &e);
            }
        }
    }

    /// Takes transforms (`/tf_static`, `/tf`): with extrinsics from TF, each camera's
    /// pose is `world_frame` to its frame. Transforms the buffer cannot hold are
    /// refused (`tf`); people's frames (ours, heard back) are passed over.
    pub fn transforms(&mut self, message: &TFMessage) {
        if self.extrinsics != ExtrinsicsSource::Tf {
            return;
        }
        let wanted = |t: &msgs::tf::TransformStamped| {
            !super::frames::is_body_transform(&t.header.frame_id, &t.child_frame_id)
        };
        for reason in self.tf.take_where(message, wanted) {
            let e = NodeError::Transform { reason };
            self.refused.note(e.kind(), &e);
        }
        self.update_rig();
    }

    /// Looks the cameras' poses up (TF) and hands the windows every change.
    fn update_rig(&mut self) {
        for (v, c) in self.cameras.iter_mut().enumerate() {
            if self.extrinsics == ExtrinsicsSource::Tf
                && let Some(frame) = &c.frame_id
            {
                c.pose = self.tf.lookup(&self.world_frame, frame);
            }
            let Some(now) = c.calibrated() else {
                continue;
            };
            if now.check().is_err() || now == self.rig[v] {
                continue;
            }
            self.rig[v] = now;
            for w in self.windows.values_mut() {
                // Checked above: cannot fail.
                let _ = w.set_camera(v, now);
            }
        }
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

    fn take(&mut self, camera: usize, msg: &HeatMaps, now_ns: i64) -> Result<Taken, NodeError> {
        let sequence = msg.sequence;
        let refuse = |reason: String| NodeError::Camera { sequence, reason };
        let Some(c) = self.cameras.get(camera) else {
            return Err(refuse(format!("no camera {camera}")));
        };
        let name = c.name.clone();
        self.limits
            .heatmap_values(
                msg.joint_names.len() as u64,
                u64::from(msg.height),
                u64::from(msg.width),
            )
            .map_err(|source| NodeError::Limit { sequence, source })?;
        if !same_layout(&msg.joint_names, &self.joint_names) {
            return Err(NodeError::Joints {
                sequence,
                found: msg.joint_names.clone(),
                expected: self.joint_names.clone(),
            });
        }
        let crop = msg.crop()?;
        if msg.track_id == 0 {
            return Err(refuse(format!(
                "camera {name}: track id 0 (unknown): the fusion matches each camera's \
                 tracks, which need ids of their own (the detector's tracker gives them)"
            )));
        }
        // The scores, dequantised and checked before the frame changes anything.
        msg.values_into(&mut self.decoded)?;
        let cells = msg.joint_names.len() * msg.height as usize * msg.width as usize;
        if self.decoded.len() != cells || cells == 0 {
            return Err(refuse(format!(
                "camera {name}: {} scores for {} maps of {} x {}",
                self.decoded.len(),
                msg.joint_names.len(),
                msg.height,
                msg.width
            )));
        }
        // A well-formed frame: its frame id is its camera's from now on.
        let frame = msg.header.frame_id.trim_start_matches('/');
        match &self.cameras[camera].frame_id {
            Some(known) if known != frame => {
                return Err(refuse(format!(
                    "camera {name}: frame id {frame:?}, not its {known:?}"
                )));
            }
            Some(_) => {}
            None if frame.is_empty() => {
                return Err(refuse(format!("camera {name}: no frame id")));
            }
            None => {
                self.cameras[camera].frame_id = Some(frame.to_string());
                self.update_rig();
            }
        }
        let c = &self.cameras[camera];
        if c.calibrated().is_none() {
            return Err(NodeError::Uncalibrated {
                sequence,
                camera: name,
                what: match (c.intrinsics.is_some(), self.extrinsics) {
                    (false, _) => "its CameraInfo (or [fusion.intrinsics])".into(),
                    (true, ExtrinsicsSource::Tf) => format!(
                        "its pose: {} to {} on TF",
                        self.world_frame,
                        c.frame_id.as_deref().unwrap_or("?")
                    ),
                    (true, ExtrinsicsSource::Config) => "its pose in [fusion.poses]".into(),
                },
            });
        }
        let stamp = msg.header.stamp.nanos();
        let (mut index, mut offset_ns) = self.place(stamp);
        // A frame far from the fused frames' time: its camera's clock is off (refused
        // while the others send on time), or the time started again (a replay, a clock
        // reset): once most cameras have sent `JUMP_FRAMES` such frames in a row, the
        // fused frames start again.
        let far = MAX_PENDING as i64;
        if index < self.next_index - far || index > self.next_index + far {
            let c = &mut self.cameras[camera];
            c.off_clock = (c.off_clock.0 + 1, Some(now_ns));
            let recent = |t: Option<i64>| t.is_some_and(|t| now_ns - t < self.wait_ns.max(1));
            let jumped = |c: &Camera| c.off_clock.0 >= JUMP_FRAMES && recent(c.off_clock.1);
            let off = self.cameras.iter().filter(|c| jumped(c)).count();
            let on = self
                .cameras
                .iter()
                .filter(|c| recent(c.heard_ns) && !recent(c.off_clock.1))
                .count();
            if off > 0 && off > on {
                return Ok(Taken::Restart);
            }
            if index > self.next_index {
                let seconds = (index - self.next_index) as f64 * self.period_ns as f64 * 1e-9;
                return Err(NodeError::Clock {
                    sequence,
                    camera: name,
                    seconds,
                });
            }
        }
        if index < self.next_index {
            return Err(NodeError::Late {
                sequence,
                camera: name,
                behind_ms: (self.next_index - index) as f64 * self.period_ns as f64 * 1e-6,
            });
        }
        // A camera faster than the fused frames, or whose clock runs about half a frame
        // off theirs, puts two frames in one and none in the next: one past the fused
        // frame's time, where one before it is there already, goes to the next.
        if offset_ns > 0
            && let Some(slot) = self.pending.iter().find(|s| s.index == index)
            && slot
                .frames
                .iter()
                .any(|f| f.camera == camera && f.track == msg.track_id && f.offset_ns < 0)
        {
            index += 1;
            offset_ns -= self.period_ns;
        }
        let p = self.pending.iter().position(|s| s.index >= index);
        let existing = p.filter(|&p| self.pending[p].index == index).and_then(|p| {
            self.pending[p]
                .frames
                .iter()
                .position(|f| f.camera == camera && f.track == msg.track_id)
                .map(|i| (p, i))
        });
        if existing.is_none() {
            // At most max_people tracks per camera and fused frame.
            let per_camera = p
                .filter(|&p| self.pending[p].index == index)
                .map_or(0, |p| {
                    self.pending[p]
                        .frames
                        .iter()
                        .filter(|f| f.camera == camera)
                        .count()
                });
            if per_camera >= self.settings.matching.max_people {
                return Err(refuse(format!(
                    "camera {name}: more than {} tracks in one frame \
                     (estimator.fusion.matching.max_people)",
                    self.settings.matching.max_people
                )));
            }
        }
        // Taken.
        let c = &mut self.cameras[camera];
        c.off_clock = (0, None);
        c.newest_ns = Some(c.newest_ns.map_or(stamp, |n| n.max(stamp)));
        c.heard_ns = Some(now_ns);
        c.frames += 1;
        self.counters.frames += 1;
        let frame = match existing {
            // A second frame of the track in this fused frame: the nearer one stays, the
            // other is counted.
            Some((p, i)) => {
                self.counters.superseded += 1;
                let f = &mut self.pending[p].frames[i];
                if f.offset_ns.abs() <= offset_ns.abs() {
                    return Ok(Taken::Frame);
                }
                f
            }
            None => {
                let p = match p {
                    Some(p) if self.pending[p].index == index => p,
                    at => {
                        let at = at.unwrap_or(self.pending.len());
                        self.pending.insert(
                            at,
                            Pending {
                                index,
                                first_heard_ns: now_ns,
                                frames: Vec::new(),
                            },
                        );
                        at
                    }
                };
                let frames = &mut self.pending[p].frames;
                let at = frames.len();
                frames.push(self.spare_frames.pop().unwrap_or_default());
                &mut frames[at]
            }
        };
        frame.camera = camera;
        frame.track = msg.track_id;
        frame.offset_ns = offset_ns;
        frame.crop = Some(crop);
        frame.height = msg.height as usize;
        frame.width = msg.width as usize;
        std::mem::swap(&mut frame.values, &mut self.decoded);
        Ok(Taken::Frame)
    }

    /// The fused frame nearest capture time `stamp` (the first stamp heard starts fused
    /// frame 0; half a period rounds up) and the offset from it, nanoseconds.
    fn place(&mut self, stamp: i64) -> (i64, i64) {
        let epoch = *self.epoch_ns.get_or_insert(stamp);
        let index = (stamp - epoch + self.period_ns / 2).div_euclid(self.period_ns);
        (index, stamp - (epoch + index * self.period_ns))
    }

    /// The time started again (what waited was fused first): the people and the
    /// cameras' clocks are forgotten (their residuals stay counted, their ids are not
    /// given again); the next frame starts fused frame 0.
    fn restart(&mut self) {
        tracing::warn!(
            "the cameras' capture times jumped (a replay started again, a clock reset): the \
             fused frames start again"
        );
        self.counters.restarts += 1;
        for mut slot in self.pending.drain(..) {
            self.spare_frames.append(&mut slot.frames);
        }
        let ended = &mut self.ended_residuals;
        for (_, w) in std::mem::take(&mut self.windows) {
            for (a, r) in ended.iter_mut().zip(w.residuals()) {
                a.merge(r);
            }
        }
        // Its ids go on: a body's id is never given twice.
        self.matcher.forget_all();
        self.epoch_ns = None;
        self.next_index = 0;
        for c in &mut self.cameras {
            c.newest_ns = None;
            c.heard_ns = None;
            c.off_clock = (0, None);
        }
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

    /// Makes fused frame `slot`: matches its tracks into people, pushes each person's
    /// views into their window, appends the estimates' skeletons to `out`.
    fn fuse(&mut self, mut slot: Pending, out: &mut Vec<Skeleton3D>) {
        self.next_index = self.next_index.max(slot.index + 1);
        let epoch = self.epoch_ns.unwrap_or(0);
        let stamp_ns = epoch + slot.index * self.period_ns;
        self.counters.fused += 1;
        // Frames of cameras that lost their calibration since (a TF change) wait no more.
        let cameras = &self.cameras;
        let spare = &mut self.spare_frames;
        let mut i = 0;
        while i < slot.frames.len() {
            if cameras[slot.frames[i].camera].calibrated().is_some() {
                i += 1;
            } else {
                spare.push(slot.frames.swap_remove(i));
            }
        }
        self.peaks.resize_with(slot.frames.len(), Vec::new);
        for (f, peaks) in slot.frames.iter().zip(self.peaks.iter_mut()) {
            match f.crop {
                Some(crop) => {
                    let to_image = crop.pixel_map(f.width, f.height);
                    peaks_into(&f.values, f.height, f.width, &to_image, peaks);
                }
                None => peaks.clear(),
            }
        }
        let observations: Vec<TrackObservation<'_>> = slot
            .frames
            .iter()
            .zip(&self.peaks)
            .map(|(f, peaks)| TrackObservation {
                view: f.camera,
                track: u64::from(f.track),
                peaks,
                box_size: f.crop.map_or(0.0, |c| c.width.max(c.height)),
            })
            .collect();
        self.matcher
            .assign(stamp_ns, &self.rig, &observations, &mut self.ids);
        drop(observations);
        self.counters.unmatched += self.ids.iter().filter(|i| i.is_none()).count() as u64;
        let mut people: Vec<u64> = self.ids.iter().flatten().copied().collect();
        people.sort_unstable();
        people.dedup();
        for id in people {
            let views: Vec<ViewMaps<'_>> = slot
                .frames
                .iter()
                .zip(&self.ids)
                .filter(|(_, m)| **m == Some(id))
                .filter_map(|(f, _)| {
                    Some(ViewMaps {
                        view: f.camera,
                        dt: f.offset_ns as f64 * 1e-9,
                        to_image: f.crop?.pixel_map(f.width, f.height),
                        height: f.height,
                        width: f.width,
                        values: Scores::F32(&f.values),
                    })
                })
                .collect();
            let window = match self.windows.entry(id) {
                std::collections::btree_map::Entry::Occupied(e) => e.into_mut(),
                std::collections::btree_map::Entry::Vacant(e) => {
                    match FusedWindow::new(&self.estimator, self.rig.clone(), self.settings.clone())
                    {
                        Ok(w) => {
                            self.counters.people += 1;
                            e.insert(w)
                        }
                        Err(source) => {
                            let e = NodeError::Estimate {
                                sequence: slot.index as u64,
                                source,
                            };
                            self.refused.note(e.kind(), &e);
                            continue;
                        }
                    }
                }
            };
            self.estimates.clear();
            if let Err(source) = window.push(stamp_ns, &views, &mut self.estimates) {
                let e = NodeError::Estimate {
                    sequence: slot.index as u64,
                    source,
                };
                self.refused.note(e.kind(), &e);
                continue;
            }
            for v in &views {
                self.cameras[v.view].used += 1;
            }
            if let Some(newest) = self.estimates.iter().find(|e| e.lag == 0) {
                self.matcher.set_pose(id, &newest.joints);
            }
            for e in &self.estimates {
                if !e.joints.iter().chain(&e.joint_std).all(|v| v.is_finite()) {
                    let err = NodeError::NonFiniteOutput {
                        sequence: slot.index as u64,
                    };
                    self.refused.note(err.kind(), &err);
                    continue;
                }
                out.push(self.skeleton(id, e, epoch));
                self.counters.skeletons += 1;
            }
        }
        // People the matcher forgot: their windows go, their residuals stay counted.
        let known: Vec<u64> = self.matcher.people().collect();
        let ended = &mut self.ended_residuals;
        self.windows.retain(|id, w| {
            let keep = known.contains(id);
            if !keep {
                for (a, r) in ended.iter_mut().zip(w.residuals()) {
                    a.merge(r);
                }
            }
            keep
        });
        self.spare_frames.append(&mut slot.frames);
        self.check_extrinsics();
    }

    /// Names the cameras whose extrinsics disagree with the others' (a warning when the
    /// set changes).
    fn check_extrinsics(&mut self) {
        let now = suspects(&self.residuals(), &self.check);
        if now != self.suspects {
            for &v in now.iter().filter(|v| !self.suspects.contains(v)) {
                tracing::warn!(
                    "camera {}: its heat maps disagree with the fused poses' projections much \
                     more than the other cameras' do: its extrinsics (pose in {}) are likely \
                     wrong",
                    self.cameras[v].name,
                    self.world_frame
                );
            }
            self.suspects = now;
        }
    }

    /// The skeleton of person `id`'s estimate `e`.
    fn skeleton(&self, id: u64, e: &FusedEstimate, epoch: i64) -> Skeleton3D {
        let index = (e.stamp_ns - epoch).div_euclid(self.period_ns.max(1));
        Skeleton3D {
            header: Header {
                stamp: Time::from_nanos(e.stamp_ns),
                frame_id: self.world_frame.clone(),
            },
            sequence: index.max(0) as u64,
            // Ids from 1; 0 is \"unknown\" in the messages.
            track_id: ((id.max(1) - 1) % u64::from(u32::MAX)) as u32 + 1,
            joint_names: self.joint_names.clone(),
            units: Units::Metres as u8,
            positions: e.joints.clone(),
            position_std: e.joint_std.clone(),
            keypoints: Vec::new(),
            keypoint_std: Vec::new(),
            projected: Vec::new(),
            lag: e.lag as u32,
            state: SkeletonState::Tracking as u8,
            metric_source: if e.monocular {
                MetricSource::Size as u8
            } else {
                MetricSource::Views as u8
            },
            views: e
                .views
                .iter()
                .map(|&v| self.cameras[v].frame_id.clone().unwrap_or_default())
                .collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::HeatMapEncoding;

    const PERIOD: i64 = 33_333_333;

    /// A node of cameras `a` and `b` (poses and intrinsics configured), fused frames at
    /// 30 per second, waiting up to 1 s.
    fn node() -> FusionNode {
        let dict = crate::msgs::shipped::load_dictionary(std::path::Path::new(
            "builtin:dictionaries/default-k128.json",
        ))
        .expect("dictionary");
        let estimator = Estimator::new(dict, crate::Params::default()).expect("estimator");
        let mut config = FusionConfig {
            cameras: vec!["a".into(), "b".into()],
            extrinsics: ExtrinsicsSource::Config,
            wait: 1.0,
            ..FusionConfig::default()
        };
        for (name, x) in [("a", 0.0), ("b", 5.0)] {
            config
                .poses
                .insert(name.into(), vec![x, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
            config
                .intrinsics
                .insert(name.into(), vec![600.0, 600.0, 320.0, 240.0]);
        }
        config
            .check(&super::super::config::Topics::default())
            .expect("config");
        FusionNode::new(
            estimator,
            &config,
            FusionSettings::default(),
            Limits::default(),
        )
        .expect("node")
    }

    /// Camera `camera`'s frame of track 1 at `stamp_ns` (maps without evidence: nothing
    /// is estimated, the frames only placed).
    fn frame(node: &FusionNode, camera: &str, stamp_ns: i64) -> HeatMaps {
        let p = node.joint_names().len();
        HeatMaps {
            track_id: 1,
            ..HeatMaps::from_values(
                Header {
                    stamp: Time::from_nanos(stamp_ns),
                    frame_id: camera.into(),
                },
                0,
                node.joint_names().to_vec(),
                4,
                4,
                CropBox::new(100.0, 100.0, 80.0, 80.0).expect("crop"),
                &vec![0.0; p * 16],
                HeatMapEncoding::Float32,
            )
        }
    }

    #[test]
    fn a_camera_twice_as_fast_as_the_fused_frames_gives_each_its_frame_at_its_time() {
        let mut node = node();
        let mut out = Vec::new();
        for i in 0..40 {
            let stamp = 1_000_000_000 + i * PERIOD / 2;
            let msg = frame(&node, "a", stamp);
            node.heat_maps(0, &msg, stamp, &mut out).expect("taken");
            if i % 2 == 0 {
                // On a fused frame's time: that frame holds it, at no offset.
                let waiting: Vec<i64> = node
                    .pending
                    .iter()
                    .flat_map(|s| s.frames.iter().map(|f| f.offset_ns))
                    .collect();
                assert!(waiting.iter().all(|o| o.abs() <= 1), "{i}: {waiting:?}");
            }
        }
        // Every frame halfway between two fused frames gave way to one at its time.
        assert_eq!(node.counters().superseded, 20);
    }

    #[test]
    fn a_stray_stamp_is_refused_and_a_time_that_jumped_for_good_starts_again() {
        let mut node = node();
        let mut out = Vec::new();
        let (mut now, mut stamp) = (0, 1_000_000_000_000);
        let mut send = |node: &mut FusionNode, cameras: &[&str], shift: i64| {
            now += PERIOD;
            stamp += PERIOD;
            for (c, name) in cameras.iter().enumerate() {
                let msg = frame(node, name, stamp + shift);
                let _ = node.heat_maps(c, &msg, now, &mut out);
            }
        };
        for _ in 0..10 {
            send(&mut node, &["a", "b"], 0);
        }
        // One camera's stray stamps, 100 s back or ahead: refused, nothing restarts.
        for shift in [-100_000_000_000, 100_000_000_000] {
            for _ in 0..JUMP_FRAMES + 5 {
                send(&mut node, &["a"], shift);
                send(&mut node, &["a", "b"], 0);
            }
        }
        assert_eq!(node.counters().restarts, 0);
        assert!(node.refused().of("late") > 0 && node.refused().of("clock") > 0);
        // Both cameras 100 s back for good (a replay started again): once they have
        // said so for JUMP_FRAMES frames, the fused frames start again, once.
        let fused = node.counters().fused;
        for _ in 0..JUMP_FRAMES + 10 {
            send(&mut node, &["a", "b"], -100_000_000_000);
        }
        assert_eq!(node.counters().restarts, 1);
        assert!(node.counters().fused > fused);
    }

    #[test]
    fn hostile_frames_are_refused_by_kind_and_change_nothing() {
        let mut node = node();
        let mut out = Vec::new();
        let good = frame(&node, "a", 1_000_000_000);
        node.heat_maps(0, &good, 0, &mut out).expect("taken");
        let mut cases: Vec<(HeatMaps, &str)> = Vec::new();
        cases.push((
            HeatMaps {
                track_id: 0,
                ..good.clone()
            },
            "camera",
        ));
        cases.push((
            HeatMaps {
                crop_x: f64::NAN,
                ..good.clone()
            },
            "invalid",
        ));
        let mut short = good.clone();
        short.values.truncate(3);
        cases.push((short, "invalid"));
        let mut nan_scale = good.clone();
        nan_scale.encoding = HeatMapEncoding::Uint8.code();
        nan_scale.quantized_values = vec![1; good.values.len()];
        nan_scale.values.clear();
        nan_scale.quantization_scale = f32::NAN;
        cases.push((nan_scale, "invalid"));
        let mut other_frame = good.clone();
        other_frame.header.frame_id = "b".into();
        cases.push((other_frame, "camera"));
        let mut huge = good.clone();
        huge.height = u32::MAX;
        huge.width = u32::MAX;
        cases.push((huge, "beyond-limits"));
        let mut joints = good.clone();
        joints.joint_names.reverse();
        cases.push((joints, "joints"));
        for (stamp, kind) in [(i64::MIN, "late"), (i64::MAX, "clock")] {
            let mut far = good.clone();
            far.header.stamp = Time::from_nanos(stamp);
            cases.push((far, kind));
        }
        for (msg, kind) in &cases {
            let before = node.refused().of(kind);
            assert!(node.heat_maps(0, msg, 1, &mut out).is_err(), "{kind}");
            assert_eq!(node.refused().of(kind), before + 1, "{kind}");
        }
        // Only the good frame was taken; the camera's frame id is still its own.
        assert_eq!(node.counters().frames, 1);
        assert_eq!(node.cameras()[0].frame_id, "a");
    }
}
