//! The estimator's outputs about bodies rather than skeletons: each person's frames on
//! `/tf` ([`BodyFrames`]) and REP-155's body topics ([`HriBodies`]): the ids tracked in
//! each image on `<ns>/tracked`, and per body `<ns>/<id>/roi` and `<ns>/<id>/skeleton2d`.
//! A body's topics are made when it is first seen and dropped once it has not been seen
//! for [`RETIRE_AFTER`] (its track ended, or it left), so their number follows the
//! people in view: at most [`MAX_BODY_TOPICS`] bodies at once, and [`MAX_BODIES_MADE`]
//! over a process's life (ros2-client keeps every publisher it ever made in its node's
//! `ros_discovery_info`, which would otherwise grow for ever; later bodies get no
//! topics of their own, counted, while `/tf` and the tracked ids go on).
//!
//! With the floor known, each body's footprint too (`body_<id>_footprint` under the floor
//! frame: where the person stands), and a floor from the configuration as a frame under
//! the camera's ([`Bodies::with_floor`]).
//!
//! Bodies are described at one lag, [`Bodies::lag`]: the newest estimates when the window
//! publishes them (the least delay, as TF and HRI consumers want), else the refined ones.

use super::Publishers;
use super::ServiceError;
use crate::floor::FloorModel;
use crate::msgs::hri::{IdsList, NormalizedRegionOfInterest2D, Skeleton2D};
use crate::msgs::sensor::RegionOfInterest;
use crate::msgs::tf::{TFMessage, TransformStamped};
use crate::msgs::{Header, Skeleton3D, Skeleton3DArray, SkeletonState};
use crate::nodes::config::HriRoi;
use crate::nodes::frames::BodyFrames;
use crate::nodes::hri::{HriBodies, body_id, normalized_roi, tracked};
use crate::transport::Message;
use crate::transport::ros2::Ros2;

/// Bodies whose topics are kept at once; past it, the one seen least recently loses
/// them (they are made again when it is seen again).
pub const MAX_BODY_TOPICS: usize = 64;

/// Makes publishers while the loop runs: a ROS 2 node shared with the wiring, and the
/// output recording and live view, as configured.
#[derive(Clone, Default)]
pub struct TopicMaker {
    /// The ROS 2 node, when publishing on ROS 2.
    pub ros: Option<Ros2>,
    /// The output recording and the live view, if any.
    pub taps: super::wiring::Taps,
}

impl TopicMaker {
    /// Publishers of `M` on `topic`.
    pub fn publishers<M: Message>(&self, topic: &str) -> Result<Publishers<M>, ServiceError> {
        let mut out = Publishers::default();
        if let Some(ros) = &self.ros {
            out.add_ros2(format!("ros2 {topic}"), ros.sink::<M>(topic)?);
        }
        self.taps.add_to(&mut out, topic)?;
        Ok(out)
    }
}

/// How long a body's topics stay after it was last seen (its track ended or it left):
/// DDS delivers in the background, and a publisher dropped at once may lose what it sent
/// last; a person lost for less keeps them.
pub const RETIRE_AFTER: std::time::Duration = std::time::Duration::from_secs(2);

/// Bodies given topics of their own over a process's life, at most (see the module docs).
/// Each costs memory that is not given back when its topics go (measured: about 130 kB a
/// body, a hostile peer sending a new track id in every frame took the estimator from 25
/// to 345 MB over 2,559 bodies): with 1024 it levels off at 106 MB.
pub const MAX_BODIES_MADE: u64 = 1024;

/// One body's REP-155 topics.
struct BodyTopics {
    track_id: u32,
    roi: RoiTopic,
    skeleton2d: Publishers<Skeleton2D>,
    /// When it was seen last.
    seen: std::time::Instant,
    /// Made while discovery knew subscribers of its topics: its first messages wait until
    /// then for the new publishers to match them (else they go to nobody).
    settle_until: Option<std::time::Instant>,
}

/// A body's `roi` publishers, of the configured type (`[outputs] hri_roi`).
enum RoiTopic {
    Pixels(Publishers<RegionOfInterest>),
    Normalized(Publishers<NormalizedRegionOfInterest2D>),
}

/// A body's region, as its `roi` topic carries it.
enum Roi {
    Pixels(RegionOfInterest),
    Normalized(NormalizedRegionOfInterest2D),
}

impl RoiTopic {
    fn publish(&mut self, roi: &Roi, stamp_ns: u64) {
        match (self, roi) {
            (Self::Pixels(p), Roi::Pixels(r)) => p.publish(r, stamp_ns),
            (Self::Normalized(p), Roi::Normalized(r)) => p.publish(r, stamp_ns),
            _ => {}
        }
    }

    async fn publish_async(&mut self, roi: &Roi, stamp_ns: u64) {
        match (self, roi) {
            (Self::Pixels(p), Roi::Pixels(r)) => p.publish_async(r, stamp_ns).await,
            (Self::Normalized(p), Roi::Normalized(r)) => p.publish_async(r, stamp_ns).await,
            _ => {}
        }
    }

    fn flush(&mut self) {
        match self {
            Self::Pixels(p) => p.flush(),
            Self::Normalized(p) => p.flush(),
        }
    }

    fn failed(&self) -> u64 {
        match self {
            Self::Pixels(p) => p.failed,
            Self::Normalized(p) => p.failed,
        }
    }
}

/// REP-155's body topics.
pub struct HriTopics {
    convert: HriBodies,
    roi_kind: HriRoi,
    maker: TopicMaker,
    namespace: String,
    tracked: Publishers<IdsList>,
    bodies: Vec<BodyTopics>,
    /// Bodies given topics so far.
    made: u64,
    /// Bodies refused topics of their own ([`MAX_BODIES_MADE`]).
    pub refused: u64,
    /// Sends of dropped bodies' topics that failed, and bodies whose topics could not be
    /// made.
    failed: u64,
}

/// What the estimator publishes about bodies (frames, REP-155), see the module docs.
pub struct Bodies {
    /// The lag described.
    pub lag: u32,
    frames: BodyFrames,
    /// `/tf` (empty when off).
    pub tf: Publishers<TFMessage>,
    /// REP-155 topics, when on.
    pub hri: Option<HriTopics>,
    /// The transforms of the skeleton in hand (reused).
    message: TFMessage,
    /// Whether it was said that skeletons without a camera calibration get no frames
    /// and no body messages of their own.
    said_uncalibrated: bool,
    /// Where people stand, when the floor is on ([`Bodies::with_floor`]).
    floor: Option<FloorFrames>,
}

/// The floor's frames on `/tf`: each body's footprint under the floor frame and, when
/// the floor is not in the TF tree already (from the configuration), the floor frame
/// under the camera's.
struct FloorFrames {
    /// The floor frame (`[estimator.metric.floor] frame`).
    frame: String,
    /// Whether to publish the floor frame itself (under the skeleton's camera frame).
    publish_floor: bool,
    /// The floor in hand ([`Bodies::set_floor`]).
    model: Option<FloorModel>,
}

impl Default for Bodies {
    /// Nothing published.
    fn default() -> Self {
        Self {
            lag: 0,
            frames: BodyFrames::new(&[]),
            tf: Publishers::default(),
            hri: None,
            message: TFMessage::default(),
            said_uncalibrated: false,
            floor: None,
        }
    }
}

impl Bodies {
    /// Frames on `tf` and, with `hri` (its namespace, maker and roi type), REP-155 topics, for
    /// skeletons of `joint_names` at `lag`.
    pub fn new(
        joint_names: &[String],
        lag: u32,
        tf: Publishers<TFMessage>,
        hri: Option<(String, TopicMaker, HriRoi)>,
    ) -> Result<Self, ServiceError> {
        let hri = match hri {
            Some((namespace, maker, roi_kind)) => Some(HriTopics {
                convert: HriBodies::new(joint_names),
                roi_kind,
                tracked: maker.publishers(&format!("{namespace}/tracked"))?,
                maker,
                namespace,
                bodies: Vec::new(),
                made: 0,
                refused: 0,
                failed: 0,
            }),
            None => None,
        };
        Ok(Self {
            lag,
            frames: BodyFrames::new(joint_names),
            tf,
            hri,
            message: TFMessage::default(),
            said_uncalibrated: false,
            floor: None,
        })
    }

    /// With the floor on: each body's footprint (`body_<id>_footprint`) under the floor
    /// frame `frame` as well, and with `publish_floor` the floor frame itself under the
    /// camera frame (a floor from the configuration, which no TF tree holds).
    pub fn with_floor(mut self, frame: &str, publish_floor: bool) -> Self {
        self.floor = Some(FloorFrames {
            frame: frame.to_owned(),
            publish_floor,
            model: None,
        });
        self
    }

    /// The floor the skeletons about to be published were placed on (the node's,
    /// [`EstimatorNode::floor`](crate::nodes::EstimatorNode::floor)); `None` while
    /// there is none (no footprints).
    pub fn set_floor(&mut self, model: Option<FloorModel>) {
        if let Some(floor) = &mut self.floor {
            floor.model = model;
        }
    }

    /// Nothing to publish.
    pub fn is_empty(&self) -> bool {
        self.tf.is_empty() && self.hri.is_none()
    }

    /// Publishes what `skeleton` says of its body (nothing unless it is at [`Bodies::lag`],
    /// nor for a track's last estimates, which repeat frames already described): its
    /// frames (in metres) and, in images of `image_size` (columns, rows; `None`: unknown,
    /// no region or 2D skeleton), its REP-155 region and 2D skeleton. (A new body whose
    /// topics a subscriber already waits for is not waited for here, on the estimator's
    /// thread: see [`Bodies::publish_async`].)
    pub fn publish(
        &mut self,
        skeleton: &Skeleton3D,
        image_size: Option<(f64, f64)>,
        stamp_ns: u64,
    ) {
        let (frames, body) = self.prepare(skeleton, image_size);
        if frames {
            self.tf.publish(&self.message, stamp_ns);
        }
        if let (Some((i, roi, points)), Some(hri)) = (body, &mut self.hri) {
            let body = &mut hri.bodies[i];
            body.settle_until = None;
            if let Some(roi) = roi {
                body.roi.publish(&roi, stamp_ns);
            }
            body.skeleton2d.publish(&points, stamp_ns);
        }
    }

    /// [`Bodies::publish`] on a runtime ([`Publishers::publish_async`]); a new body's
    /// first messages wait (awaited, the input goes on) for its publishers to match
    /// subscribers discovery already knows.
    pub async fn publish_async(
        &mut self,
        skeleton: &Skeleton3D,
        image_size: Option<(f64, f64)>,
        stamp_ns: u64,
    ) {
        let (frames, body) = self.prepare(skeleton, image_size);
        if frames {
            self.tf.publish_async(&self.message, stamp_ns).await;
        }
        if let (Some((i, roi, points)), Some(hri)) = (body, &mut self.hri) {
            let body = &mut hri.bodies[i];
            if let Some(wait) = body.settle() {
                tokio::time::sleep(wait).await;
            }
            if let Some(roi) = roi {
                body.roi.publish_async(&roi, stamp_ns).await;
            }
            body.skeleton2d.publish_async(&points, stamp_ns).await;
        }
    }

    /// What to send of `skeleton`: whether its frames are in `self.message`, and its
    /// body's index with its region and 2D skeleton.
    #[allow(clippy::type_complexity, reason = "one private hand-over")]
    fn prepare(
        &mut self,
        skeleton: &Skeleton3D,
        image_size: Option<(f64, f64)>,
    ) -> (bool, Option<(usize, Option<Roi>, Skeleton2D)>) {
        self.message.transforms.clear();
        if skeleton.lag != self.lag || skeleton.state == SkeletonState::Lost as u8 {
            return (false, None);
        }
        if !self.said_uncalibrated
            && (skeleton.units != crate::msgs::Units::Metres as u8 || image_size.is_none())
        {
            self.said_uncalibrated = true;
            tracing::info!(
                "no camera calibration (CameraInfo) yet: skeletons in dictionary units get no \
                 frames on /tf, and bodies no REP-155 roi or skeleton2d (their ids are still \
                 listed as tracked)"
            );
        }
        if !self.tf.is_empty() {
            self.frames.transforms(skeleton, &mut self.message);
            if let Some(FloorFrames {
                frame,
                publish_floor,
                model: Some(model),
            }) = &self.floor
                && !self.message.transforms.is_empty()
            {
                self.frames
                    .footprint(skeleton, model, frame, &mut self.message);
                if *publish_floor {
                    self.message.transforms.push(floor_under_camera(
                        &skeleton.header,
                        model,
                        frame,
                    ));
                }
            }
        }
        let frames = !self.message.transforms.is_empty();
        let body = self
            .hri
            .as_mut()
            .and_then(|hri| hri.prepare(skeleton, image_size));
        (frames, body)
    }

    /// The ids tracked in an image's `array` (at [`Bodies::lag`]; others are skipped),
    /// when REP-155 topics are on.
    fn tracked_ids(&self, array: &Skeleton3DArray) -> Option<IdsList> {
        if array.lag != self.lag || self.hri.is_none() {
            return None;
        }
        Some(tracked(&array.header, &array.skeletons))
    }

    /// Publishes the ids tracked in an image's `array`, if it is at [`Bodies::lag`].
    pub fn tracked(&mut self, array: &Skeleton3DArray, stamp_ns: u64) {
        if let (Some(ids), Some(hri)) = (self.tracked_ids(array), &mut self.hri) {
            hri.tracked.publish(&ids, stamp_ns);
        }
    }

    /// [`Bodies::tracked`] on a runtime.
    pub async fn tracked_async(&mut self, array: &Skeleton3DArray, stamp_ns: u64) {
        if let (Some(ids), Some(hri)) = (self.tracked_ids(array), &mut self.hri) {
            hri.tracked.publish_async(&ids, stamp_ns).await;
        }
    }

    /// Flushes every output.
    pub fn flush(&mut self) {
        self.tf.flush();
        if let Some(hri) = &mut self.hri {
            hri.tracked.flush();
            for b in hri.bodies.iter_mut() {
                b.roi.flush();
                b.skeleton2d.flush();
            }
        }
    }

    /// Sends that failed.
    pub fn failed(&self) -> u64 {
        let hri = self.hri.as_ref().map_or(0, |h| {
            h.failed
                + h.tracked.failed
                + h.bodies
                    .iter()
                    .map(|b| b.roi.failed() + b.skeleton2d.failed)
                    .sum::<u64>()
        });
        self.tf.failed + hri
    }
}

impl BodyTopics {
    /// How long its first messages still wait for its publishers to match (once).
    fn settle(&mut self) -> Option<std::time::Duration> {
        let until = self.settle_until.take()?;
        Some(until.saturating_duration_since(std::time::Instant::now()))
    }
}

impl HriTopics {
    /// Body `skeleton`'s index with its region and 2D skeleton, to be sent (none for a
    /// track's last estimate, which drops its body's topics, or without the image size).
    fn prepare(
        &mut self,
        skeleton: &Skeleton3D,
        image_size: Option<(f64, f64)>,
    ) -> Option<(usize, Option<Roi>, Skeleton2D)> {
        let id = skeleton.track_id;
        let now = std::time::Instant::now();
        // Bodies not seen for a while lose their topics.
        let failed = &mut self.failed;
        self.bodies.retain(|b| {
            let keep = now.duration_since(b.seen) < RETIRE_AFTER || b.track_id == id;
            if !keep {
                *failed += b.roi.failed() + b.skeleton2d.failed;
            }
            keep
        });
        let size = image_size?;
        let i = match self.bodies.iter().position(|b| b.track_id == id) {
            Some(i) => i,
            None => self.open(id)?,
        };
        self.bodies[i].seen = now;
        let points = self.convert.skeleton2d(skeleton, size);
        let roi = self
            .convert
            .roi(skeleton, size)
            .map(|r| match self.roi_kind {
                HriRoi::Pixels => Roi::Pixels(r),
                HriRoi::Normalized => Roi::Normalized(normalized_roi(&r, &points, size)),
            });
        Some((i, roi, points))
    }

    /// Makes body `id`'s topics (room made by the body seen least recently); its index.
    fn open(&mut self, id: u32) -> Option<usize> {
        if self.made >= MAX_BODIES_MADE {
            self.refused += 1;
            if self.refused == 1 {
                tracing::warn!(
                    "{MAX_BODIES_MADE} bodies had REP-155 topics of their own: later ones get \
                     none (counted; /tf and {}/tracked go on)",
                    self.namespace
                );
            }
            return None;
        }
        if self.bodies.len() >= MAX_BODY_TOPICS
            && let Some(oldest) = (0..self.bodies.len()).min_by_key(|&i| self.bodies[i].seen)
        {
            let gone = self.bodies.swap_remove(oldest);
            self.failed += gone.roi.failed() + gone.skeleton2d.failed;
        }
        self.made += 1;
        let base = format!("{}/{}", self.namespace, body_id(id));
        let (roi_topic, skeleton2d_topic) = (format!("{base}/roi"), format!("{base}/skeleton2d"));
        let roi = match self.roi_kind {
            HriRoi::Pixels => self.maker.publishers(&roi_topic).map(RoiTopic::Pixels),
            HriRoi::Normalized => self.maker.publishers(&roi_topic).map(RoiTopic::Normalized),
        };
        let made = roi.and_then(|roi| Ok((roi, self.maker.publishers(&skeleton2d_topic)?)));
        // Subscribers discovery knows already (a consumer that expected this body).
        // A new body's first messages wait for its new publishers to match them
        // (matching runs in the background).
        let settle = self.maker.ros.as_ref().and_then(|ros| {
            (ros.subscriptions(&roi_topic) + ros.subscriptions(&skeleton2d_topic) > 0)
                .then(|| ros.match_settle())
        });
        match made {
            Ok((roi, skeleton2d)) => {
                self.bodies.push(BodyTopics {
                    track_id: id,
                    roi,
                    skeleton2d,
                    seen: std::time::Instant::now(),
                    settle_until: settle.map(|d| std::time::Instant::now() + d),
                });
                Some(self.bodies.len() - 1)
            }
            Err(e) => {
                self.failed += 1;
                if self.failed == 1 {
                    tracing::warn!(
                        "no REP-155 topics for body {}: {e} (further failures are counted)",
                        body_id(id)
                    );
                }
                None
            }
        }
    }
}

/// The floor frame `frame` under the camera frame of `header`: the inverse of the
/// camera's pose over the floor.
fn floor_under_camera(header: &Header, floor: &FloorModel, frame: &str) -> TransformStamped {
    let inverse =
        nalgebra::Isometry3::from_parts(floor.translation().into(), floor.rotation()).inverse();
    let (t, q) = (inverse.translation.vector, inverse.rotation);
    TransformStamped::new(header.clone(), frame, [t.x, t.y, t.z], [q.i, q.j, q.k, q.w])
}
