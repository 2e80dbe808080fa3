//! The learnt floor with its uncertainty, planned: `geometry_msgs/PoseWithCovarianceStamped`
//! on `topics.floor`, beside the floor frame on `/tf` ([`super::BodyPlanner::with_floor`]).
//! The pose is the camera's over the floor frame (`header.frame_id`, x forward under the
//! camera, y left, z up): the inverse of the `/tf` transform, as a localisation's pose
//! is the robot's over its map. Its covariance, in the floor frame's axes (x forward
//! under the camera, y left, z up), from the fit and the size prior ([`LearntFloor`]'s
//! deviations): the camera's height on z; its pitch, a turn about y; its roll, a turn
//! about the camera's own forward axis, which a camera pitched down by `p` has at
//! `(cos p, 0, -sin p)`: its variance shared between the turns about x and z (`cos^2 p`,
//! `sin^2 p`, and `-sin p cos p` between them). x and y are the floor frame's own
//! definition (under the camera): exact, zero; the yaw too but for the roll's share.
//!
//! Each floor trusted goes out once, when it is trusted (each new fit), stamped with the
//! newest image the node had handled then; a floor no longer trusted is not retracted
//! here (the skeletons' `metric_source` says what placed them), nor one of another
//! camera (after a new `CameraInfo` the floor is learnt again, and published when
//! trusted).

use super::plan::{Plan, Publication};
use crate::learnt_floor::LearntFloor;
use crate::msgs::tf::{Covariance, PoseWithCovariance, PoseWithCovarianceStamped};
use crate::msgs::visualization::{Point, Pose, Quaternion};
use crate::msgs::{Header, Time};

/// Plans the learnt floor's messages; see the module docs.
#[derive(Debug, Clone)]
pub struct FloorPlanner {
    /// The floor frame (`[estimator.metric.floor] published_frame`).
    frame: String,
    /// The change of the floor trusted published last.
    published: Option<u64>,
}

impl FloorPlanner {
    /// The learnt floor as the pose of the camera over frame `frame`.
    pub fn new(frame: &str) -> Self {
        Self {
            frame: frame.to_owned(),
            published: None,
        }
    }

    /// Plans the floor trusted now (`fit`: the number of changes so far, and the floor,
    /// `EstimatorNode::learnt_floor_fit`) if it changed since the last one planned,
    /// stamped `stamp_ns` (the newest image handled) and sent with `sent_ns`. A floor
    /// with a value that is not finite is not sent.
    pub fn plan(
        &mut self,
        fit: Option<(u64, Option<&LearntFloor>)>,
        stamp_ns: i64,
        sent_ns: u64,
        plan: &mut Plan,
    ) {
        let Some((changes, floor)) = fit else {
            return;
        };
        if self.published == Some(changes) {
            return;
        }
        self.published = Some(changes);
        let Some(floor) = floor else {
            return;
        };
        let pose = floor_pose(floor, &self.frame, stamp_ns);
        let p = &pose.pose.pose;
        let values = [p.position.x, p.position.y, p.position.z]
            .into_iter()
            .chain([
                p.orientation.x,
                p.orientation.y,
                p.orientation.z,
                p.orientation.w,
            ])
            .chain(pose.pose.covariance.0);
        if !values.into_iter().all(f64::is_finite) {
            return;
        }
        let (k, message) = plan.floors.add();
        *message = pose;
        plan.order.push((Publication::Floor(k), sent_ns));
    }
}

/// The camera's pose over the floor frame `frame` with its covariance; see the module
/// docs.
pub fn floor_pose(floor: &LearntFloor, frame: &str, stamp_ns: i64) -> PoseWithCovarianceStamped {
    let (t, q) = (floor.model.translation(), floor.model.rotation());
    let (height, pitch, roll) = (
        floor.height_std,
        floor.pitch_std.to_radians(),
        floor.roll_std.to_radians(),
    );
    // The roll's axis, the camera's forward, in the floor frame: (cos p, 0, -sin p).
    let (sin, cos) = floor.model.pitch_roll().0.to_radians().sin_cos();
    let mut covariance = Covariance::diagonal([
        0.0,
        0.0,
        height * height,
        roll * roll * cos * cos,
        pitch * pitch,
        roll * roll * sin * sin,
    ]);
    covariance.0[3 * 6 + 5] = -roll * roll * sin * cos;
    covariance.0[5 * 6 + 3] = -roll * roll * sin * cos;
    PoseWithCovarianceStamped {
        header: Header {
            stamp: Time::from_nanos(stamp_ns),
            frame_id: frame.to_owned(),
        },
        pose: PoseWithCovariance {
            pose: Pose {
                position: Point {
                    x: t.x,
                    y: t.y,
                    z: t.z,
                },
                orientation: Quaternion {
                    x: q.i,
                    y: q.j,
                    z: q.k,
                    w: q.w,
                },
            },
            covariance,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::floor::FloorModel;

    fn learnt(height: f64, pitch: f64) -> LearntFloor {
        LearntFloor {
            model: FloorModel::from_height_pitch_roll(height, pitch, 0.0).unwrap(),
            height_std: 0.05,
            height_fit_std: 0.02,
            pitch_std: 1.0,
            pitch_fit_std: 0.5,
            roll_std: 2.0,
            points: 300,
            inliers: 0.9,
            residual: 0.02,
            spread: 1.0,
            heights: (height, height),
        }
    }

    #[test]
    fn the_pose_is_the_camera_s_over_the_floor_with_its_deviations_squared() {
        let m = floor_pose(&learnt(2.0, 15.0), "posestream_floor", 7);
        assert_eq!(m.header.frame_id, "posestream_floor");
        let p = &m.pose.pose.position;
        assert!(p.x.abs() < 1e-12 && p.y.abs() < 1e-12 && (p.z - 2.0).abs() < 1e-12);
        let c = &m.pose.covariance.0;
        assert!((c[2 * 6 + 2] - 0.0025).abs() < 1e-12);
        assert!((c[4 * 6 + 4] - 1f64.to_radians().powi(2)).abs() < 1e-15);
        // The roll about the camera's forward axis, 15 degrees down: mostly about x.
        let (roll, (sin, cos)) = (2f64.to_radians().powi(2), 15f64.to_radians().sin_cos());
        assert!((c[3 * 6 + 3] - roll * cos * cos).abs() < 1e-15);
        assert!((c[5 * 6 + 5] - roll * sin * sin).abs() < 1e-15);
        assert!((c[3 * 6 + 5] + roll * sin * cos).abs() < 1e-15);
        assert_eq!(c[3 * 6 + 5], c[5 * 6 + 3]);
        assert_eq!(c.iter().filter(|v| **v != 0.0).count(), 6);
        // Level: the roll about x alone.
        let level = floor_pose(&learnt(2.0, 0.0), "f", 0).pose.covariance.0;
        assert_eq!(level.iter().filter(|v| **v != 0.0).count(), 3);
    }

    #[test]
    fn each_change_of_the_floor_goes_out_once_and_none_trusted_says_nothing() {
        let floor = learnt(2.0, 15.0);
        let mut planner = FloorPlanner::new("f");
        let mut plan = Plan::default();
        planner.plan(Some((1, Some(&floor))), 5, 5, &mut plan);
        planner.plan(Some((1, Some(&floor))), 6, 6, &mut plan);
        assert_eq!(plan.order, vec![(Publication::Floor(0), 5)]);
        planner.plan(Some((2, None)), 7, 7, &mut plan);
        planner.plan(None, 8, 8, &mut plan);
        planner.plan(Some((3, Some(&floor))), 9, 9, &mut plan);
        assert_eq!(plan.order.len(), 2);
        assert_eq!(plan.floors.as_slice().len(), 2);
        // A deviation that is not finite: nothing sent.
        let broken = LearntFloor {
            height_std: f64::NAN,
            ..floor
        };
        planner.plan(Some((4, Some(&broken))), 10, 10, &mut plan);
        assert_eq!(plan.order.len(), 2);
    }
}
