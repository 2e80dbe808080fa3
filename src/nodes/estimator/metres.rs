//! The estimator node in metres: the camera's calibration (configured, or a
//! `sensor_msgs/CameraInfo`), the metric step of each estimate it publishes, and the
//! floor under the camera (configured, from TF, or learnt from the people seen).

use super::EstimatorNode;
use crate::camera::Intrinsics;
use crate::error::EstimateError;
use crate::floor::{BodyScale, FloorModel, FloorSource, FloorStd};
use crate::learnt_floor::{FloorLearner, LearningSettings, LearningState, LearntFloor};
use crate::limits::Limits;
use crate::metres::{MetricPose, MetricSettings, MetricStep, OnFloor};
use crate::msgs::tf::TFMessage;
use crate::msgs::{self};
use crate::nodes::errors::{NodeError, SetupError};
use crate::nodes::frames;
use crate::nodes::tf_buffer::{TfBuffer, TfTopic};
use crate::streaming::FrameEstimate;
use posestream_base::PixelMap;

/// The intrinsics and the image size (columns, rows) of a camera's calibration
/// (`sensor_msgs/CameraInfo`'s `k`, `width`, `height`); why it cannot be used otherwise
/// (focal lengths, no image size, an image beyond the limits).
pub fn calibration(
    info: &msgs::sensor::CameraInfo,
    limits: &Limits,
) -> Result<(Intrinsics, (f64, f64)), String> {
    let k = &info.k;
    let camera = Intrinsics::new(k[0], k[4], k[2], k[5])?;
    if info.width == 0 || info.height == 0 {
        return Err(format!("image size {} x {}", info.width, info.height));
    }
    limits
        .image(u64::from(info.width), u64::from(info.height))
        .map_err(|e| e.to_string())?;
    Ok((camera, (f64::from(info.width), f64::from(info.height))))
}

/// The floor from TF: the transforms taken, the floor frame, and what the floor in hand
/// was looked up for (the buffer's version and the camera frame).
pub(super) struct FloorFromTf {
    pub(super) buffer: TfBuffer,
    pub(super) frame: String,
    pub(super) looked_up: Option<(u64, String)>,
    /// The floor was missing once (logged once).
    pub(super) missing_said: bool,
}

/// The metric step of a node whose camera is known.
pub(super) struct Metric {
    pub(super) step: MetricStep,
    pub(super) camera: Intrinsics,
    /// The images' size (columns, rows), when a `CameraInfo` gave it: a crop box whose
    /// centre is outside is not of these images.
    pub(super) size: Option<(f64, f64)>,
    /// The floor under the camera, when known (`[estimator.metric.floor]`).
    pub(super) floor: Option<FloorModel>,
    /// With the floor learnt: the learner, and the lag of the estimates it learns from
    /// (the refined ones when the window publishes them).
    pub(super) learner: Option<(FloorLearner, usize)>,
    /// How far off the floor may be: a learnt floor's deviations (`None`: exact).
    pub(super) floor_std: Option<FloorStd>,
    /// With the floor learnt: how many times the floor trusted changed (a new fit, or
    /// none trusted), so that each is published once.
    pub(super) floor_changes: u64,
    /// The frame in hand, in metres (reused).
    pub(super) pose: MetricPose,
    /// Estimates the step failed on (published in dictionary units).
    pub(super) failures: u64,
    /// What the step cost so far.
    pub(super) timing: MetricTiming,
}

/// Where learning the floor stands, for the reports: the state, and the floor trusted
/// (else the newest fit, not trusted) with its uncertainty.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FloorReport {
    /// `learning`, `accepted`, or `rejected: <why>`.
    pub state: String,
    /// Person-frames kept.
    pub points: usize,
    /// The camera's height above the floor, metres.
    pub height: Option<f64>,
    /// Its standard deviation, metres: the fit's and the size prior's
    /// (`scale_std` of it), composed.
    pub height_std: Option<f64>,
    /// The fit's share of it, metres.
    pub height_fit_std: Option<f64>,
    /// Pitch, degrees, positive looking down.
    pub pitch: Option<f64>,
    /// Its standard deviation, degrees: the fit's and a bias it does not see, composed.
    pub pitch_std: Option<f64>,
    /// The fit's share of it, degrees.
    pub pitch_fit_std: Option<f64>,
    /// Roll, degrees.
    pub roll: Option<f64>,
    /// Its standard deviation, degrees.
    pub roll_std: Option<f64>,
    /// Of the roots, those on their plane, as a fraction.
    pub inliers: Option<f64>,
}

impl FloorReport {
    pub(super) fn of(learner: &FloorLearner) -> Self {
        let newest = learner.floor().or(learner.newest());
        let angles = newest.map(|f| f.model.pitch_roll());
        Self {
            state: match learner.state() {
                LearningState::Learning => "learning".into(),
                LearningState::Accepted => "accepted".into(),
                LearningState::Rejected(why) => format!("rejected: {why}"),
            },
            points: learner.points(),
            height: newest.map(|f| f.model.height()),
            height_std: newest.map(|f| f.height_std),
            height_fit_std: newest.map(|f| f.height_fit_std),
            pitch: angles.map(|a| a.0),
            pitch_std: newest.map(|f| f.pitch_std),
            pitch_fit_std: newest.map(|f| f.pitch_fit_std),
            roll: angles.map(|a| a.1),
            roll_std: newest.map(|f| f.roll_std),
            inliers: newest.map(|f| f.inliers),
        }
    }
}

/// What the metric step cost so far (`EstimatorNode::metric_timing`).
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct MetricTiming {
    /// Estimates adjusted (each published estimate of each person: the newest and, with
    /// a lag, its refinement).
    pub estimates: u64,
    /// Seconds in the step, summed.
    pub seconds: f64,
    /// Of those, the ones adjusted (a metric pose made).
    pub adjusted: u64,
    /// The perspective adjustment's iterations on those adjusted, summed.
    pub iterations: u64,
}

impl EstimatorNode {
    /// The same node, publishing metres in the camera frame when `settings` name the
    /// camera's intrinsics (dictionary units otherwise).
    pub fn with_metric(mut self, settings: &MetricSettings) -> Result<Self, SetupError> {
        // Checked here, so that a camera given later cannot fail on them.
        MetricStep::new(self.template.estimator(), settings.clone())?;
        self.metric_settings = settings.clone();
        self.metric = None;
        self.tf = (settings.floor.source == FloorSource::Tf).then(|| FloorFromTf {
            buffer: TfBuffer::new(),
            frame: settings.floor.frame.clone(),
            looked_up: None,
            missing_said: false,
        });
        if let Some(camera) = settings.camera() {
            self.set_camera(camera, None)?;
        }
        Ok(self)
    }

    fn set_camera(
        &mut self,
        camera: Intrinsics,
        size: Option<(f64, f64)>,
    ) -> Result<(), EstimateError> {
        let learner = (self.metric_settings.floor.source == FloorSource::Learnt).then(|| {
            let s = &self.metric_settings;
            let settings = LearningSettings {
                root_height_m: s.floor.root_height * s.mean_limb_length,
                size_std: s.scale_std,
                ..LearningSettings::default()
            };
            let window = self.template.settings();
            let lag = match window.outputs {
                crate::streaming::Emitted::Newest => 0,
                _ => window.lag,
            };
            (FloorLearner::new(settings), lag)
        });
        match &mut self.metric {
            Some(m) => {
                if m.camera != camera {
                    // Another camera: sizes kept by id were of its people (or of ids
                    // given again).
                    self.kept_sizes.clear();
                }
                if m.camera != camera && learner.is_some() {
                    // Another camera: what was learnt was of the other's floor.
                    m.learner = learner;
                    m.floor = None;
                    m.floor_std = None;
                    m.floor_changes += 1;
                }
                m.camera = camera;
                m.size = size;
            }
            None => {
                self.metric = Some(Metric {
                    step: MetricStep::new(self.template.estimator(), self.metric_settings.clone())?,
                    camera,
                    size,
                    floor: self.metric_settings.floor.configured(),
                    learner,
                    floor_std: None,
                    floor_changes: 0,
                    pose: MetricPose::default(),
                    failures: 0,
                    timing: MetricTiming::default(),
                })
            }
        }
        Ok(())
    }

    /// Takes the camera's calibration (`sensor_msgs/CameraInfo`, the intrinsics `k` of
    /// the images the crop boxes are in): from now on skeletons are in metres, with
    /// these intrinsics in place of any configured ones. A calibration the step cannot
    /// use is refused and counted (`camera-info`); the camera known before stays.
    pub fn camera_info(&mut self, info: &msgs::sensor::CameraInfo) -> Result<(), NodeError> {
        let result = self.camera_info_inner(info);
        if let Err(e) = &result {
            self.refused.note(e.kind(), e);
        }
        result
    }

    fn camera_info_inner(&mut self, info: &msgs::sensor::CameraInfo) -> Result<(), NodeError> {
        let refuse = |reason: String| NodeError::CameraInfo { reason };
        let (camera, size) = calibration(info, &self.limits).map_err(refuse)?;
        let size = Some(size);
        if let Some(m) = &self.metric
            && m.camera == camera
            && m.size == size
        {
            return Ok(());
        }
        self.set_camera(camera, size)
            .map_err(|e| refuse(e.to_string()))
    }

    /// Takes transforms (`/tf_static`, `/tf`): with the floor from TF, the camera's place
    /// over the floor frame comes from them (the newest of each frame). Transforms the
    /// buffer cannot hold are refused and counted (`tf`); without a floor from TF they
    /// are not looked at. People's frames (posestream's own body and joint frames, heard
    /// back on `/tf`: [`frames::is_body_transform`]) are passed over.
    pub fn transforms(&mut self, message: &TFMessage, topic: TfTopic) {
        let Some(tf) = &mut self.tf else {
            return;
        };
        let wanted = |t: &msgs::tf::TransformStamped| {
            !frames::is_body_transform(&t.header.frame_id, &t.child_frame_id)
        };
        for reason in tf.buffer.take_where(message, topic, wanted) {
            let e = NodeError::Transform { reason };
            self.refused.note(e.kind(), &e);
        }
    }

    /// The floor the metric step uses now (from the configuration, TF, or learnt and
    /// trusted).
    pub fn floor(&self) -> Option<FloorModel> {
        self.metric.as_ref().and_then(|m| m.floor)
    }

    /// With the floor learnt and the camera known: the floor trusted now (`None`: none),
    /// and how many times that changed, so that a publisher can send each once.
    pub fn learnt_floor_fit(&self) -> Option<(u64, Option<&LearntFloor>)> {
        let m = self.metric.as_ref()?;
        let (learner, _) = m.learner.as_ref()?;
        Some((m.floor_changes, learner.floor()))
    }

    /// With the floor from TF: frames the transform buffer dropped to make room for new
    /// ones (the `/tf` frame sent least recently, one no lookup passed through first).
    pub fn tf_evicted(&self) -> u64 {
        self.tf.as_ref().map_or(0, |tf| tf.buffer.evicted())
    }

    /// Where learning the floor stands (`None` unless it is learnt and the camera known).
    pub fn learnt_floor(&self) -> Option<FloorReport> {
        let (learner, _) = self.metric.as_ref()?.learner.as_ref()?;
        Some(FloorReport::of(learner))
    }

    /// With the floor from TF: looks it up again for `camera_frame` when a transform
    /// came since, or the camera frame changed.
    pub(super) fn update_floor(&mut self, camera_frame: &str) {
        let (Some(tf), Some(m)) = (&mut self.tf, &mut self.metric) else {
            return;
        };
        let version = tf.buffer.version();
        if tf
            .looked_up
            .as_ref()
            .is_some_and(|(v, f)| *v == version && f == camera_frame)
        {
            return;
        }
        // The frame id's buffer kept (no allocation while a robot's /tf streams).
        match &mut tf.looked_up {
            Some((v, f)) => {
                *v = version;
                f.clear();
                f.push_str(camera_frame);
            }
            None => tf.looked_up = Some((version, camera_frame.to_owned())),
        }
        let pose = tf.buffer.lookup(&tf.frame, camera_frame);
        m.floor = pose.and_then(|p| FloorModel::new(p.rotation, p.translation.vector).ok());
        if m.floor.is_none() && !tf.missing_said {
            tf.missing_said = true;
            tracing::warn!(
                "no floor yet: no transform from {} to the camera frame {camera_frame:?} on \
                 /tf_static or /tf (or the camera is not above it); metres from the assumed size",
                tf.frame
            );
        }
    }

    /// Estimates the metric step failed on (a pose without size, a non-finite result):
    /// published in dictionary units.
    pub fn metric_failures(&self) -> u64 {
        self.metric.as_ref().map_or(0, |m| m.failures)
    }

    /// What the metric step cost so far (zero without a camera).
    pub fn metric_timing(&self) -> MetricTiming {
        self.metric
            .as_ref()
            .map_or_else(MetricTiming::default, |m| m.timing)
    }
}

/// With the floor learnt: the root of the pose in hand (of track `id`, estimate lag
/// `lag`) to the learner; the floor the metric step uses follows what the learner
/// trusts (the change logged).
pub(super) fn learn_floor(m: &mut Metric, id: u32, lag: usize) {
    let Some((learner, learn_lag)) = &mut m.learner else {
        return;
    };
    if lag != *learn_lag {
        return;
    }
    let before = learner.state();
    if learner.note(id, m.pose.root_at_size) {
        m.floor = learner.floor().map(|f| f.model);
        m.floor_std = learner.floor().map(|f| FloorStd {
            height: f.height_std,
            pitch: f.pitch_std.to_radians(),
        });
        m.floor_changes += 1;
    }
    let after = learner.state();
    if std::mem::discriminant(&before) != std::mem::discriminant(&after) {
        match (after, learner.newest()) {
            (LearningState::Accepted, Some(f)) => {
                tracing::info!("floor learnt: {}", describe(f));
            }
            (LearningState::Rejected(why), Some(f)) => {
                tracing::warn!(
                    "the learnt floor is not trusted: {why} ({}); metres from the assumed size",
                    describe(f)
                );
            }
            _ => tracing::info!("the learnt floor is uncertain again: learning on"),
        }
    }
}

/// A learnt floor in words.
pub(super) fn describe(f: &LearntFloor) -> String {
    let (pitch, roll) = f.model.pitch_roll();
    format!(
        "camera {:.2} +- {:.2} m high (the fit's +- {:.2}, the rest people's sizes), pitch \
         {pitch:.1} +- {:.1} (the fit's +- {:.1}), roll {roll:.1} +- {:.1} degrees, from {} \
         person-frames ({:.0} % on the plane)",
        f.model.height(),
        f.height_std,
        f.height_fit_std,
        f.pitch_std,
        f.pitch_fit_std,
        f.roll_std,
        f.points,
        100.0 * f.inliers
    )
}

/// The metric pose of estimate `e` into `m.pose`: refused when the frame's crop box is
/// not in the camera's images (it does not overlap them; a crop may reach past an
/// image's edge, as BlazePose's body circle does). `looked`: the frame's heat maps come
/// from a look in its image ([`OnFloor::looked`]).
pub(super) fn metric_pose(
    m: &mut Metric,
    e: &FrameEstimate,
    to_image: &PixelMap,
    map_size: (f64, f64),
    scale: &mut BodyScale,
    looked: bool,
) -> Result<(), String> {
    if let Some((width, height)) = m.size {
        let [x0, y0] = to_image.apply(-0.5, -0.5);
        let [x1, y1] = to_image.apply(map_size.0 - 0.5, map_size.1 - 0.5);
        let overlaps = |a0: f64, a1: f64, n: f64| a0.min(a1) < n && a0.max(a1) > 0.0;
        if !(overlaps(x0, x1, width) && overlaps(y0, y1, height)) {
            return Err(format!(
                "the crop box ({x0:.0}, {y0:.0}) - ({x1:.0}, {y1:.0}) is outside the camera's {width} x {height} images"
            ));
        }
    }
    let began = std::time::Instant::now();
    let adjusted = m
        .step
        .adjust(
            e,
            to_image,
            &m.camera,
            m.floor.as_ref().map(|floor| OnFloor {
                floor,
                scale,
                looked,
                std: m.floor_std,
            }),
            &mut m.pose,
        )
        .map_err(|e| e.to_string());
    m.timing.estimates += 1;
    m.timing.seconds += began.elapsed().as_secs_f64();
    if adjusted.is_ok() {
        m.timing.adjusted += 1;
        m.timing.iterations += m.step.iterations() as u64;
    }
    adjusted
}
