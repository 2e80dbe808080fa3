//! What the estimator says of bodies rather than skeletons, planned: each person's frames
//! on `/tf` ([`BodyFrames`]) and REP-155's body messages ([`HriBodies`]): the ids tracked
//! in each image, and per body its region and 2D skeleton. With the floor known, each
//! body's footprint too (`body_<id>_footprint` under the floor frame: where the person
//! stands), and a floor from the configuration as a frame under the camera's
//! ([`BodyPlanner::with_floor`]). Where they go (the body topics made and retired as
//! people come and go) is the sinks': [`super::body_topics`].
//!
//! Bodies are described at one lag, [`BodyPlanner::lag`]: the newest estimates when the
//! window publishes them (the least delay, as TF and HRI consumers want), else the
//! refined ones.

use super::body_topics::{HriSinks, TopicMaker};
use super::plan::{BodyMessages, Plan, Publication, Roi};
use super::publishers::Publishers;
use crate::floor::FloorModel;
use crate::msgs::hri::IdsList;
use crate::msgs::tf::{TFMessage, TransformStamped};
use crate::msgs::{Header, Skeleton3D, Skeleton3DArray, SkeletonState};
use crate::nodes::config::HriRoi;
use crate::nodes::errors::ServiceError;
use crate::nodes::frames::BodyFrames;
use crate::nodes::hri::{HriBodies, normalized_roi, tracked};

/// Plans what is said of bodies; see the module docs.
pub struct BodyPlanner {
    /// The lag described.
    pub lag: u32,
    frames: BodyFrames,
    /// Whether frames go on `/tf`.
    tf: bool,
    /// REP-155's messages, when on: how a skeleton becomes them, and the region's type.
    hri: Option<(HriBodies, HriRoi)>,
    /// Whether it was said that skeletons without a camera calibration get no frames
    /// and no body messages of their own.
    said_uncalibrated: bool,
    /// Where people stand, when the floor is on ([`BodyPlanner::with_floor`]).
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
    /// The floor in hand ([`BodyPlanner::set_floor`]).
    model: Option<FloorModel>,
}

impl Default for BodyPlanner {
    /// Nothing said of bodies.
    fn default() -> Self {
        Self {
            lag: 0,
            frames: BodyFrames::new(&[]),
            tf: false,
            hri: None,
            said_uncalibrated: false,
            floor: None,
        }
    }
}

impl BodyPlanner {
    /// Frames on `/tf` (with `tf`) and REP-155 messages (with `hri`, its region type), of
    /// skeletons of `joint_names` at `lag`.
    pub fn new(joint_names: &[String], lag: u32, tf: bool, hri: Option<HriRoi>) -> Self {
        Self {
            lag,
            frames: BodyFrames::new(joint_names),
            tf,
            hri: hri.map(|kind| (HriBodies::new(joint_names), kind)),
            said_uncalibrated: false,
            floor: None,
        }
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

    /// The floor the skeletons about to be planned were placed on (the node's); `None`
    /// while there is none (no footprints).
    pub fn set_floor(&mut self, model: Option<FloorModel>) {
        if let Some(floor) = &mut self.floor {
            floor.model = model;
        }
    }

    /// Nothing is said of bodies.
    pub fn is_empty(&self) -> bool {
        !self.tf && self.hri.is_none()
    }

    /// Whether REP-155's messages are on (the ids tracked per image need the skeletons
    /// grouped by image).
    pub fn hri(&self) -> bool {
        self.hri.is_some()
    }

    /// Plans what `skeleton` says of its body (nothing unless it is at [`Self::lag`], nor
    /// for a track's last estimates, which repeat frames already described): its frames
    /// (in metres) and, in images of `image_size` (columns, rows; `None`: unknown, no
    /// region or 2D skeleton), its REP-155 region and 2D skeleton.
    pub fn plan(
        &mut self,
        skeleton: &Skeleton3D,
        image_size: Option<(f64, f64)>,
        stamp_ns: u64,
        plan: &mut Plan,
    ) {
        if skeleton.lag != self.lag || skeleton.state == SkeletonState::Lost as u8 {
            return;
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
        if self.tf {
            let (k, message) = plan.transforms.add();
            message.transforms.clear();
            self.frames.transforms(skeleton, message);
            if let Some(FloorFrames {
                frame,
                publish_floor,
                model: Some(model),
            }) = &self.floor
                && !message.transforms.is_empty()
            {
                self.frames.footprint(skeleton, model, frame, message);
                if *publish_floor {
                    message
                        .transforms
                        .push(floor_under_camera(&skeleton.header, model, frame));
                }
            }
            if message.transforms.is_empty() {
                plan.transforms.retract();
            } else {
                plan.order.push((Publication::Transforms(k), stamp_ns));
            }
        }
        if let Some((convert, roi_kind)) = &self.hri {
            let (k, body) = plan.bodies.add();
            *body = BodyMessages {
                track_id: skeleton.track_id,
                messages: image_size.map(|size| {
                    let points = convert.skeleton2d(skeleton, size);
                    let roi = convert.roi(skeleton, size).map(|r| match roi_kind {
                        HriRoi::Pixels => Roi::Pixels(r),
                        HriRoi::Normalized => Roi::Normalized(normalized_roi(&r, &points, size)),
                    });
                    (roi, points)
                }),
            };
            plan.order.push((Publication::Body(k), stamp_ns));
        }
    }

    /// The ids tracked in an image's `array`, if it is at [`Self::lag`] and REP-155's
    /// messages are on.
    pub fn tracked(&self, array: &Skeleton3DArray) -> Option<IdsList> {
        (array.lag == self.lag && self.hri.is_some())
            .then(|| tracked(&array.header, &array.skeletons))
    }
}

/// What is said of bodies and where it goes: the planner, `/tf`'s publishers and
/// REP-155's topics.
#[derive(Default)]
pub struct Bodies {
    /// What is said.
    pub planner: BodyPlanner,
    /// `/tf` (empty when off).
    pub tf: Publishers<TFMessage>,
    /// REP-155's topics, when on.
    pub hri: Option<HriSinks>,
}

impl Bodies {
    /// Frames on `tf` and, with `hri` (its namespace, maker and roi type), REP-155 topics,
    /// for skeletons of `joint_names` at `lag`.
    pub fn new(
        joint_names: &[String],
        lag: u32,
        tf: Publishers<TFMessage>,
        hri: Option<(String, TopicMaker, HriRoi)>,
    ) -> Result<Self, ServiceError> {
        let planner = BodyPlanner::new(
            joint_names,
            lag,
            !tf.is_empty(),
            hri.as_ref().map(|(_, _, kind)| *kind),
        );
        let hri = hri
            .map(|(namespace, maker, kind)| HriSinks::new(namespace, maker, kind))
            .transpose()?;
        Ok(Self { planner, tf, hri })
    }

    /// [`BodyPlanner::with_floor`].
    pub fn with_floor(mut self, frame: &str, publish_floor: bool) -> Self {
        self.planner = self.planner.with_floor(frame, publish_floor);
        self
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
