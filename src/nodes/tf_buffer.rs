//! A small tf2-style buffer: the transforms read from `/tf_static` and `/tf` (a ROS 2
//! graph's or a recording's), each frame under its parent, and the lookup of one frame
//! in another through their common ancestor. The newest transform of each frame is the
//! one used (no interpolation between stamps: the estimator asks for a camera's place
//! over the floor, which a fixed camera or a robot standing still keeps).
//!
//! Bounded: at most [`MAX_FRAMES`] frames (never evicted: a frame once known stays
//! until the node ends); a transform of one more, with a non-finite value, a translation
//! beyond [`MAX_TRANSLATION_M`], a quaternion not of unit length, an empty or over-long frame id, or making a frame its own
//! ancestor (within 64 parents) is refused (its reason returned), and what was known
//! stays.

use std::collections::HashMap;

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

use crate::msgs::tf::{TFMessage, TransformStamped};

/// Frames a buffer holds at most.
pub const MAX_FRAMES: usize = 256;
/// Parents a lookup climbs at most (deeper trees are refused).
const MAX_DEPTH: usize = 64;
/// A frame id's bytes at most.
const MAX_FRAME_ID: usize = 256;
/// The farthest a frame may be from its parent, metres, on each axis: 1,000 km, far beyond
/// any room, robot or map a camera's pose is given in; a translation beyond it is a
/// broken publisher's (a sum over a chain of such frames stays finite).
pub const MAX_TRANSLATION_M: f64 = 1e6;

/// The newest transform of each frame, under its parent.
#[derive(Debug, Clone, Default)]
pub struct TfBuffer {
    /// child -> (parent, the child's pose in the parent).
    frames: HashMap<String, (String, Isometry3<f64>)>,
    /// Transforms taken, in all (so that a user of a lookup knows when to ask again).
    version: u64,
}

impl TfBuffer {
    /// An empty buffer.
    pub fn new() -> Self {
        Self::default()
    }

    /// Takes every transform of `message`; the reasons of those refused.
    pub fn take(&mut self, message: &TFMessage) -> Vec<String> {
        self.take_where(message, |_| true)
    }

    /// Takes the transforms of `message` that `wanted` keeps (the others are passed
    /// over, neither taken nor refused); the reasons of those refused.
    pub fn take_where(
        &mut self,
        message: &TFMessage,
        wanted: impl Fn(&TransformStamped) -> bool,
    ) -> Vec<String> {
        message
            .transforms
            .iter()
            .filter(|t| wanted(t))
            .filter_map(|t| self.take_one(t).err())
            .collect()
    }

    /// Transforms taken so far (grows with each one taken).
    pub fn version(&self) -> u64 {
        self.version
    }

    fn take_one(&mut self, t: &TransformStamped) -> Result<(), String> {
        let (parent, child) = (
            t.header.frame_id.trim_start_matches('/'),
            t.child_frame_id.trim_start_matches('/'),
        );
        for id in [parent, child] {
            if id.is_empty() || id.len() > MAX_FRAME_ID {
                return Err(format!(
                    "frame id of {} bytes (1..={MAX_FRAME_ID})",
                    id.len()
                ));
            }
        }
        if parent == child {
            return Err(format!("{child:?} under itself"));
        }
        let (v, r) = (&t.transform.translation, &t.transform.rotation);
        let values = [v.x, v.y, v.z, r.x, r.y, r.z, r.w];
        if values.iter().any(|x| !x.is_finite()) {
            return Err(format!("{parent} -> {child}: a value is not finite"));
        }
        if [v.x, v.y, v.z].iter().any(|x| x.abs() > MAX_TRANSLATION_M) {
            return Err(format!(
                "{parent} -> {child}: a translation of more than {MAX_TRANSLATION_M:e} m"
            ));
        }
        let q = Quaternion::new(r.w, r.x, r.y, r.z);
        // A rotation's quaternion is of unit length (tf2 refuses others too); this also
        // refuses a zero one and one whose length overflows.
        if (q.norm_squared() - 1.0).abs() > 1e-2 {
            return Err(format!(
                "{parent} -> {child}: a quaternion not of unit length"
            ));
        }
        if !self.frames.contains_key(child) && self.frames.len() >= MAX_FRAMES {
            return Err(format!("{child}: more than {MAX_FRAMES} frames"));
        }
        // Not its own ancestor: the parent's chain must not pass through the child.
        if self.ancestors(parent).any(|a| a == child) {
            return Err(format!("{parent} -> {child}: a cycle"));
        }
        let pose = Isometry3::from_parts(
            Translation3::new(v.x, v.y, v.z),
            UnitQuaternion::from_quaternion(q),
        );
        // A frame known already keeps its buffers (a robot's /tf streams).
        match self.frames.get_mut(child) {
            Some((p, known)) => {
                p.clear();
                p.push_str(parent);
                *known = pose;
            }
            None => {
                self.frames
                    .insert(child.to_owned(), (parent.to_owned(), pose));
            }
        }
        self.version += 1;
        Ok(())
    }

    /// `frame`'s ancestors, nearest first (at most [`MAX_DEPTH`]).
    fn ancestors<'a>(&'a self, frame: &'a str) -> impl Iterator<Item = &'a str> + 'a {
        let mut at = frame;
        std::iter::from_fn(move || {
            let (parent, _) = self.frames.get(at)?;
            at = parent;
            Some(parent.as_str())
        })
        .take(MAX_DEPTH)
    }

    /// `frame`'s pose in its tree's root, and that root.
    fn in_root<'a>(&'a self, frame: &'a str) -> (Isometry3<f64>, &'a str) {
        let mut pose = Isometry3::identity();
        let mut at = frame;
        for _ in 0..MAX_DEPTH {
            let Some((parent, local)) = self.frames.get(at) else {
                break;
            };
            pose = local * pose;
            at = parent;
        }
        (pose, at)
    }

    /// The pose of `frame` in `target` (`target`'s coordinates of `frame`'s origin and
    /// axes: what `tf2`'s `lookupTransform(target, frame)` gives), `None` when they are
    /// not in one tree.
    pub fn lookup(&self, target: &str, frame: &str) -> Option<Isometry3<f64>> {
        let (target, frame) = (
            target.trim_start_matches('/'),
            frame.trim_start_matches('/'),
        );
        let (a, root_a) = self.in_root(target);
        let (b, root_b) = self.in_root(frame);
        (root_a == root_b && (self.frames.contains_key(target) || self.frames.contains_key(frame)))
            .then(|| a.inverse() * b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::Header;

    fn tf(parent: &str, child: &str, xyz: [f64; 3], q: [f64; 4]) -> TransformStamped {
        let header = Header {
            frame_id: parent.into(),
            ..Header::default()
        };
        TransformStamped::new(header, child, xyz, q)
    }

    #[test]
    fn composes_a_chain_and_siblings_through_their_common_parent() {
        let mut b = TfBuffer::new();
        let half = std::f64::consts::FRAC_1_SQRT_2;
        // base_footprint -> base_link (0.1 up) -> camera_link (1.2 up, turned 90 deg about z).
        let refused = b.take(&TFMessage {
            transforms: vec![
                tf(
                    "base_footprint",
                    "base_link",
                    [0.0, 0.0, 0.1],
                    [0.0, 0.0, 0.0, 1.0],
                ),
                tf(
                    "/base_link",
                    "camera_link",
                    [0.3, 0.0, 1.2],
                    [0.0, 0.0, half, half],
                ),
                tf("base_link", "wheel", [0.0, 0.2, 0.0], [0.0, 0.0, 0.0, 1.0]),
            ],
        });
        assert!(refused.is_empty(), "{refused:?}");
        let cam = b.lookup("base_footprint", "camera_link").unwrap();
        assert!((cam.translation.vector - nalgebra::Vector3::new(0.3, 0.0, 1.3)).norm() < 1e-12);
        // The camera's x is the floor's y (turned 90 degrees).
        let x = cam.rotation * nalgebra::Vector3::x();
        assert!((x - nalgebra::Vector3::y()).norm() < 1e-12, "{x:?}");
        // A sibling through base_link; the inverse lookup.
        let w = b.lookup("camera_link", "wheel").unwrap();
        let back = b.lookup("wheel", "camera_link").unwrap();
        assert!((w * back).translation.vector.norm() < 1e-12);
        // Not in one tree, or unknown.
        assert!(b.lookup("map", "camera_link").is_none());
        assert!(b.lookup("nowhere", "elsewhere").is_none());
        // A newer transform replaces the older one.
        b.take(&TFMessage {
            transforms: vec![tf(
                "base_footprint",
                "base_link",
                [0.0, 0.0, 0.5],
                [0.0, 0.0, 0.0, 1.0],
            )],
        });
        let cam = b.lookup("base_footprint", "camera_link").unwrap();
        assert!((cam.translation.z - 1.7).abs() < 1e-12);
    }

    #[test]
    fn refuses_cycles_bad_values_and_more_frames_than_the_limit() {
        let mut b = TfBuffer::new();
        let id = [0.0, 0.0, 0.0, 1.0];
        let bad = b.take(&TFMessage {
            transforms: vec![
                tf("a", "b", [0.0; 3], id),
                tf("b", "c", [0.0; 3], id),
                tf("c", "a", [0.0; 3], id),
                tf("a", "a", [0.0; 3], id),
                tf("a", "d", [f64::NAN, 0.0, 0.0], id),
                tf("a", "h", [0.0, 1e300, 0.0], id),
                tf("a", "e", [0.0; 3], [0.0; 4]),
                tf("", "f", [0.0; 3], id),
                tf("a", &"g".repeat(MAX_FRAME_ID + 1), [0.0; 3], id),
            ],
        });
        assert_eq!(bad.len(), 7, "{bad:?}");
        assert!(b.lookup("a", "c").is_some());
        let version = b.version();
        let many = TFMessage {
            transforms: (0..MAX_FRAMES + 10)
                .map(|i| tf("a", &format!("x{i}"), [0.0; 3], id))
                .collect(),
        };
        let refused = b.take(&many);
        assert_eq!(refused.len(), 2 + 10, "two frames were there already");
        assert_eq!(b.frames.len(), MAX_FRAMES);
        assert!(b.version() > version);
    }
}
