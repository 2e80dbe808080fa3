//! Each person as coordinate frames on `/tf` (`tf2_msgs/TFMessage`), as REP-155 asks: a
//! body frame `body_<id>` midway between the hips, child of the images' camera frame, with REP-155's
//! axes (x forward out of the chest, y to the person's left, z up along the spine), and
//! under it one frame per joint, `<joint>_<id>` (`l_knee_b3`), at the joint and oriented as
//! the body. `<id>` is the body's REP-155 id ([`body_id`]). With the floor known, also
//! where the person stands: `body_<id>_footprint` under the floor frame
//! ([`BodyFrames::footprint`]). Metres only: a skeleton in dictionary units has no place
//! in the camera frame, so it gets no frames.

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3 as V3};

use crate::floor::FloorModel;
use crate::msgs::tf::{TFMessage, TransformStamped};
use crate::msgs::{Header, Skeleton3D, Units};

/// The REP-155 id of track `track_id`: `b<track_id>` (a ROS name token may not start
/// with a digit, and the ids appear in topic names: `/humans/bodies/b3/roi`).
pub fn body_id(track_id: u32) -> String {
    format!("b{track_id}")
}

/// The body frame of track `track_id`: `body_<id>`.
pub fn body_frame(track_id: u32) -> String {
    format!("body_{}", body_id(track_id))
}

/// Whether a transform from `parent` to `child` is one of a body's frames as
/// [`BodyFrames`] names them (`body_b<digits>`, `body_b<digits>_footprint`, or a joint's
/// frame under the body's): frames of people, which no floor or camera chain passes
/// through. An estimator reading `/tf` hears its own and passes them over.
pub fn is_body_transform(parent: &str, child: &str) -> bool {
    let body = |f: &str| {
        f.trim_start_matches('/')
            .strip_prefix("body_b")
            .and_then(|rest| {
                let digits = rest.bytes().take_while(u8::is_ascii_digit).count();
                (digits > 0).then(|| &rest[digits..])
            })
            .is_some_and(|tail| tail.is_empty() || tail == "_footprint")
    };
    body(child) || body(parent)
}

/// Which joints of a skeleton layout place and orient the body frame, and the joints'
/// frame names; made once from the dictionary's joint names.
#[derive(Debug, Clone)]
pub struct BodyFrames {
    /// Joint names as frame names (`l-knee` -> `l_knee`).
    names: Vec<String>,
    /// The origin: midway between these joints (the hips; else the pelvis; else all).
    origin: Vec<usize>,
    /// Up is from the origin to this joint (the thorax, else the neck).
    top: Option<usize>,
    /// Left is from the right to the left of these pairs (hips, shoulders).
    sides: Vec<(usize, usize)>,
}

impl BodyFrames {
    /// The frames of skeletons whose joints are `joint_names`.
    pub fn new(joint_names: &[String]) -> Self {
        let find = |name: &str| joint_names.iter().position(|j| j == name);
        let sides = [("l-hip", "r-hip"), ("l-shoulder", "r-shoulder")]
            .iter()
            .filter_map(|(l, r)| Some((find(l)?, find(r)?)))
            .collect();
        // Frame names of their own: a name that is empty, taken already or the body's
        // own (`body`) becomes `joint<i>`.
        let mut names: Vec<String> = Vec::with_capacity(joint_names.len());
        for (i, j) in joint_names.iter().enumerate() {
            let name: String = j
                .chars()
                .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
                .collect();
            let taken = |n: &str| names.iter().any(|m| m == n);
            let name = if name.is_empty() || name == "body" || taken(&name) {
                format!("joint{i}")
            } else {
                name
            };
            let name = if taken(&name) {
                format!("joint{i}_")
            } else {
                name
            };
            names.push(name);
        }
        Self {
            names,
            origin: match (find("l-hip"), find("r-hip"), find("pelvis")) {
                (Some(l), Some(r), _) => vec![l, r],
                (_, _, Some(p)) => vec![p],
                _ => (0..joint_names.len()).collect(),
            },
            top: find("thorax").or_else(|| find("neck")),
            sides,
        }
    }

    /// The body's origin and axes in the camera frame, when `skeleton` is in metres and
    /// has these joints.
    fn place(&self, skeleton: &Skeleton3D) -> Option<(V3<f64>, Rotation3<f64>)> {
        let n = self.names.len();
        if skeleton.units != Units::Metres as u8 || skeleton.positions.len() != 3 * n || n == 0 {
            return None;
        }
        let joint = |i: usize| V3::from_column_slice(&skeleton.positions[3 * i..3 * i + 3]);
        let origin =
            self.origin.iter().map(|&i| joint(i)).sum::<V3<f64>>() / self.origin.len() as f64;
        Some((origin, self.axes(&joint, origin)))
    }

    /// Appends the transforms of `skeleton` to `out` (nothing unless it is in metres and
    /// has these joints).
    pub fn transforms(&self, skeleton: &Skeleton3D, out: &mut TFMessage) {
        let Some((origin, axes)) = self.place(skeleton) else {
            return;
        };
        let joint = |i: usize| V3::from_column_slice(&skeleton.positions[3 * i..3 * i + 3]);
        let rotation = UnitQuaternion::from_rotation_matrix(&axes);
        let body = body_frame(skeleton.track_id);
        let id = body_id(skeleton.track_id);
        out.transforms
            .push(stamped(&skeleton.header, body.clone(), origin, rotation));
        let header = Header {
            stamp: skeleton.header.stamp.clone(),
            frame_id: body,
        };
        for (i, name) in self.names.iter().enumerate() {
            // The joint in the body's axes.
            let at = axes.inverse() * (joint(i) - origin);
            out.transforms.push(stamped(
                &header,
                format!("{name}_{id}"),
                at,
                UnitQuaternion::identity(),
            ));
        }
    }

    /// Appends where the person of `skeleton` stands on `floor` (the camera frame over
    /// the floor frame `frame`): `body_<id>_footprint` under `frame`, the body's origin
    /// dropped onto the floor (z = 0), turned about the floor's up to face where the
    /// body faces (REP-105's footprint of a robot, for a person). Nothing unless the
    /// skeleton is in metres and has these joints.
    pub fn footprint(
        &self,
        skeleton: &Skeleton3D,
        floor: &FloorModel,
        frame: &str,
        out: &mut TFMessage,
    ) {
        let Some((origin, axes)) = self.place(skeleton) else {
            return;
        };
        let at = floor.to_floor(&origin);
        let forward = floor.rotation() * (axes * V3::x());
        // Facing straight up or down (lying along the view): no heading; the floor's x.
        let yaw = if forward.x.hypot(forward.y) > 1e-9 {
            forward.y.atan2(forward.x)
        } else {
            0.0
        };
        let header = Header {
            stamp: skeleton.header.stamp.clone(),
            frame_id: frame.to_owned(),
        };
        out.transforms.push(stamped(
            &header,
            format!("{}_footprint", body_frame(skeleton.track_id)),
            V3::new(at.x, at.y, 0.0),
            UnitQuaternion::from_axis_angle(&V3::z_axis(), yaw),
        ));
    }

    /// The body's axes in the camera frame (columns x forward, y left, z up); a person
    /// facing the camera upright when the joints do not tell (a joint on top of another).
    fn axes(&self, joint: &dyn Fn(usize) -> V3<f64>, origin: V3<f64>) -> Rotation3<f64> {
        let up = self.top.map(|t| joint(t) - origin);
        let left: V3<f64> = self.sides.iter().map(|&(l, r)| joint(l) - joint(r)).sum();
        if let Some(up) = up
            && let Some(z) = up.try_normalize(1e-9)
            && let Some(y) = (left - left.dot(&z) * z).try_normalize(1e-9)
        {
            let x = y.cross(&z);
            return Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
        }
        // Camera frame: x right, y down, z forward. Facing the camera: forward is -z, up
        // is -y, and the person's left is the image's right (+x).
        Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[-V3::z(), V3::x(), -V3::y()]))
    }
}

fn stamped(
    header: &Header,
    child: String,
    at: V3<f64>,
    rotation: UnitQuaternion<f64>,
) -> TransformStamped {
    let q = rotation.quaternion();
    TransformStamped::new(
        header.clone(),
        child,
        [at.x, at.y, at.z],
        [q.i, q.j, q.k, q.w],
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::tf::Transform;
    use crate::msgs::{SkeletonState, Time};

    fn names() -> Vec<String> {
        [
            "pelvis",
            "l-hip",
            "r-hip",
            "thorax",
            "l-shoulder",
            "r-shoulder",
            "head-top",
        ]
        .map(String::from)
        .to_vec()
    }

    /// A person 3 m in front of the camera, upright, facing it.
    fn facing() -> Skeleton3D {
        let joints = [
            [0.0, 0.0, 3.0],
            [0.1, 0.0, 3.0],
            [-0.1, 0.0, 3.0],
            [0.0, -0.5, 3.0],
            [0.2, -0.5, 3.0],
            [-0.2, -0.5, 3.0],
            [0.0, -0.8, 3.05],
        ];
        Skeleton3D {
            header: Header {
                stamp: Time::from_nanos(5),
                frame_id: "camera".into(),
            },
            track_id: 3,
            units: Units::Metres as u8,
            state: SkeletonState::Tracking as u8,
            joint_names: names(),
            positions: joints.concat(),
            ..Skeleton3D::default()
        }
    }

    fn rotation(t: &Transform) -> UnitQuaternion<f64> {
        let q = &t.rotation;
        UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q.w, q.x, q.y, q.z))
    }

    #[test]
    fn frames_compose_back_to_the_joints_with_the_body_s_axes() {
        let frames = BodyFrames::new(&names());
        let s = facing();
        let mut tf = TFMessage::default();
        frames.transforms(&s, &mut tf);
        assert_eq!(tf.transforms.len(), 1 + names().len());
        let body = &tf.transforms[0];
        assert_eq!(
            (body.header.frame_id.as_str(), body.child_frame_id.as_str()),
            ("camera", "body_b3")
        );
        let r = rotation(&body.transform);
        // Facing the camera: forward is towards it (-z), up is image up (-y), left is
        // the image's right (+x).
        assert!((r * V3::x() - -V3::z()).norm() < 1e-9, "{}", r * V3::x());
        assert!((r * V3::z() - -V3::y()).norm() < 1e-9);
        assert!((r * V3::y() - V3::x()).norm() < 1e-9);
        let t = &body.transform.translation;
        let origin = V3::new(t.x, t.y, t.z);
        for (i, j) in tf.transforms[1..].iter().enumerate() {
            assert_eq!(j.header.frame_id, "body_b3");
            let p = &j.transform.translation;
            let back = origin + r * V3::new(p.x, p.y, p.z);
            let want = V3::from_column_slice(&s.positions[3 * i..3 * i + 3]);
            assert!((back - want).norm() < 1e-12, "{}", j.child_frame_id);
        }
        assert_eq!(tf.transforms[2].child_frame_id, "l_hip_b3");
        // Frame names of their own, whatever the dictionary's joint names.
        let odd = BodyFrames::new(&["l-knee", "l_knee", "", "body"].map(String::from));
        assert_eq!(odd.names, ["l_knee", "joint1", "joint2", "joint3"]);
    }

    #[test]
    fn no_frames_in_dictionary_units_and_upright_when_the_joints_do_not_tell() {
        let frames = BodyFrames::new(&names());
        let mut tf = TFMessage::default();
        let dictionary = Skeleton3D {
            units: Units::Dictionary as u8,
            ..facing()
        };
        frames.transforms(&dictionary, &mut tf);
        assert!(tf.transforms.is_empty());
        let collapsed = Skeleton3D {
            positions: [1.0, 2.0, 3.0].repeat(names().len()),
            ..facing()
        };
        frames.transforms(&collapsed, &mut tf);
        let r = rotation(&tf.transforms[0].transform);
        assert!((r * V3::z() - -V3::y()).norm() < 1e-9);
        assert!(tf.transforms.iter().all(|t| {
            let q = &t.transform.rotation;
            [q.x, q.y, q.z, q.w].iter().all(|v| v.is_finite())
        }));
    }

    #[test]
    fn a_footprint_stands_under_the_body_on_the_floor_facing_where_it_faces() {
        let frames = BodyFrames::new(&names());
        let s = facing();
        // The camera 1.5 m up, level: the floor frame's x is the camera's heading.
        let floor = FloorModel::from_height_pitch_roll(1.5, 0.0, 0.0).expect("floor");
        let mut tf = TFMessage::default();
        frames.footprint(&s, &floor, "base_footprint", &mut tf);
        let [foot] = &tf.transforms[..] else {
            panic!("one footprint: {:?}", tf.transforms);
        };
        assert_eq!(
            (foot.header.frame_id.as_str(), foot.child_frame_id.as_str()),
            ("base_footprint", "body_b3_footprint")
        );
        // The hips' midpoint, 3 m ahead and centred, dropped onto the floor.
        let t = &foot.transform.translation;
        assert!(
            (t.x - 3.0).abs() < 1e-9 && t.y.abs() < 1e-9 && t.z == 0.0,
            "{t:?}"
        );
        // Facing the camera: back along the floor's x.
        let r = rotation(&foot.transform);
        assert!((r * V3::x() - -V3::x()).norm() < 1e-9, "{}", r * V3::x());
        assert!((r * V3::z() - V3::z()).norm() < 1e-9);
        // Dictionary units: none.
        let mut units = s.clone();
        units.units = Units::Dictionary as u8;
        let mut none = TFMessage::default();
        frames.footprint(&units, &floor, "base_footprint", &mut none);
        assert!(none.transforms.is_empty());
    }

    #[test]
    fn people_s_frames_are_told_from_others() {
        for (parent, child) in [
            ("camera", "body_b3"),
            ("body_b3", "l_knee_b3"),
            ("map", "body_b12_footprint"),
            ("/camera", "/body_b0"),
        ] {
            assert!(is_body_transform(parent, child), "{parent} -> {child}");
        }
        for (parent, child) in [
            ("base_link", "body_link"),
            ("map", "body_b"),
            ("map", "body_bx"),
            ("map", "body_b3_elsewhere"),
            ("base_footprint", "camera"),
        ] {
            assert!(!is_body_transform(parent, child), "{parent} -> {child}");
        }
    }
}
