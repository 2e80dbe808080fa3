//! A small tf2-style buffer: the transforms read from `/tf_static` and `/tf` (a ROS 2
//! graph's or a recording's), each frame under its parent, and the lookup of one frame
//! in another through their common ancestor. The newest transform of each frame is the
//! one used (no interpolation between stamps: the estimator asks for a camera's place
//! over the floor, which a fixed camera or a robot standing still keeps).
//!
//! Bounded by frames and by age, evicting what nobody asks for (as tf2 keeps `/tf` for
//! its cache time and `/tf_static` for good):
//! - a frame from `/tf_static` ([`TfTopic::Static`]: sent once, latched) stays;
//! - a frame from `/tf` ([`TfTopic::Dynamic`]: sent again and again) that no lookup
//!   passed through is dropped once its newest stamp is [`MAX_AGE_NS`] (10 s) older
//!   than the newest stamp taken (swept every [`SWEEP_EVERY`] transforms);
//! - with [`MAX_FRAMES`] frames known, a new one takes the place of the `/tf` frame
//!   taken least recently, those no lookup passed through first (another tracker's flood
//!   of people's frames cannot crowd out a robot's chain or a camera's place); when all
//!   are `/tf_static`'s, it is refused.
//!
//! A transform with a non-finite value, a translation beyond [`MAX_TRANSLATION_M`], a
//! quaternion not of unit length, an empty or over-long frame id, or making a frame its
//! own ancestor (within 64 parents) is refused (its reason returned), and what was
//! known stays.

use std::collections::HashMap;

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

pub use crate::msgs::tf::TfTopic;
use crate::msgs::tf::{TFMessage, TransformStamped};

/// Frames a buffer holds at most.
pub const MAX_FRAMES: usize = 256;
/// A `/tf` frame nobody asked for is dropped when its newest stamp is this much older
/// than the newest stamp taken (tf2's default cache time, 10 s).
pub const MAX_AGE_NS: i64 = 10_000_000_000;
/// Transforms taken between two sweeps of the frames too old.
pub const SWEEP_EVERY: u64 = 64;
/// Parents a lookup climbs at most (deeper trees are refused).
const MAX_DEPTH: usize = 64;
/// A frame id's bytes at most.
const MAX_FRAME_ID: usize = 256;
/// The farthest a frame may be from its parent, metres, on each axis: 1,000 km, far beyond
/// any room, robot or map a camera's pose is given in; a translation beyond it is a
/// broken publisher's (a sum over a chain of such frames stays finite).
pub const MAX_TRANSLATION_M: f64 = 1e6;

/// One frame: its newest transform, and what keeps it.
#[derive(Debug, Clone)]
struct Frame {
    parent: String,
    /// Its pose in the parent.
    pose: Isometry3<f64>,
    /// The topic it came on last.
    topic: TfTopic,
    /// Its newest transform's stamp.
    stamp_ns: i64,
    /// The buffer's version when it was taken last.
    taken: u64,
    /// A lookup passed through it.
    asked: bool,
}

/// The newest transform of each frame, under its parent.
#[derive(Debug, Clone, Default)]
pub struct TfBuffer {
    /// child -> its frame.
    frames: HashMap<String, Frame>,
    /// Transforms taken, in all (so that a user of a lookup knows when to ask again).
    version: u64,
    /// The newest stamp taken (`/tf`'s).
    newest_ns: i64,
    /// Frames dropped, by age or to make room.
    evicted: u64,
}

impl TfBuffer {
    /// An empty buffer.
    pub fn new() -> Self {
        Self::default()
    }

    /// Takes every transform of `message`, which came on `topic`; the reasons of those
    /// refused.
    pub fn take(&mut self, message: &TFMessage, topic: TfTopic) -> Vec<String> {
        self.take_where(message, topic, |_| true)
    }

    /// Takes the transforms of `message` (which came on `topic`) that `wanted` keeps
    /// (the others are passed over, neither taken nor refused); the reasons of those
    /// refused.
    pub fn take_where(
        &mut self,
        message: &TFMessage,
        topic: TfTopic,
        wanted: impl Fn(&TransformStamped) -> bool,
    ) -> Vec<String> {
        message
            .transforms
            .iter()
            .filter(|t| wanted(t))
            .filter_map(|t| self.take_one(t, topic).err())
            .collect()
    }

    /// Transforms taken so far (grows with each one taken).
    pub fn version(&self) -> u64 {
        self.version
    }

    /// Frames known now.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// No frame known.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Frames dropped so far, by age or to make room.
    pub fn evicted(&self) -> u64 {
        self.evicted
    }

    /// Drops the `/tf` frames nobody asked for whose newest stamp is more than
    /// [`MAX_AGE_NS`] older than the newest taken.
    fn sweep(&mut self) {
        let oldest = self.newest_ns.saturating_sub(MAX_AGE_NS);
        let before = self.frames.len();
        self.frames
            .retain(|_, f| f.topic == TfTopic::Static || f.asked || f.stamp_ns >= oldest);
        self.evicted += (before - self.frames.len()) as u64;
    }

    /// Makes room for one more frame: drops the `/tf` frame taken least recently, one
    /// no lookup passed through first; `false` when every frame is `/tf_static`'s.
    fn make_room(&mut self) -> bool {
        let victim = self
            .frames
            .iter()
            .filter(|(_, f)| f.topic == TfTopic::Dynamic)
            .min_by_key(|(_, f)| (f.asked, f.taken))
            .map(|(id, _)| id.clone());
        match victim {
            Some(id) => {
                self.frames.remove(&id);
                self.evicted += 1;
                true
            }
            None => false,
        }
    }

    fn take_one(&mut self, t: &TransformStamped, topic: TfTopic) -> Result<(), String> {
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
        if !self.frames.contains_key(child) && self.frames.len() >= MAX_FRAMES && !self.make_room()
        {
            return Err(format!(
                "{child}: more than {MAX_FRAMES} frames, all from the static topic"
            ));
        }
        // Not its own ancestor: the parent's chain must not pass through the child.
        if self.ancestors(parent).any(|a| a == child) {
            return Err(format!("{parent} -> {child}: a cycle"));
        }
        let pose = Isometry3::from_parts(
            Translation3::new(v.x, v.y, v.z),
            UnitQuaternion::from_quaternion(q),
        );
        let stamp_ns = t.header.stamp.nanos();
        self.version += 1;
        // A frame known already keeps its buffers (a robot's /tf streams).
        match self.frames.get_mut(child) {
            Some(f) => {
                f.parent.clear();
                f.parent.push_str(parent);
                f.pose = pose;
                f.topic = topic;
                f.stamp_ns = stamp_ns;
                f.taken = self.version;
            }
            None => {
                self.frames.insert(
                    child.to_owned(),
                    Frame {
                        parent: parent.to_owned(),
                        pose,
                        topic,
                        stamp_ns,
                        taken: self.version,
                        asked: false,
                    },
                );
            }
        }
        if topic == TfTopic::Dynamic {
            self.newest_ns = self.newest_ns.max(stamp_ns);
        }
        if self.version.is_multiple_of(SWEEP_EVERY) {
            self.sweep();
        }
        Ok(())
    }

    /// `frame`'s ancestors, nearest first (at most [`MAX_DEPTH`]).
    fn ancestors<'a>(&'a self, frame: &'a str) -> impl Iterator<Item = &'a str> + 'a {
        let mut at = frame;
        std::iter::from_fn(move || {
            let parent = &self.frames.get(at)?.parent;
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
            let Some(f) = self.frames.get(at) else {
                break;
            };
            pose = f.pose * pose;
            at = &f.parent;
        }
        (pose, at)
    }

    /// Marks `frame` and its ancestors as asked for (kept before the others).
    fn mark_asked(&mut self, frame: &str) {
        let mut at = frame.to_owned();
        for _ in 0..MAX_DEPTH {
            let Some(f) = self.frames.get_mut(&at) else {
                break;
            };
            f.asked = true;
            at.clone_from(&f.parent);
        }
    }

    /// The pose of `frame` in `target` (`target`'s coordinates of `frame`'s origin and
    /// axes: what `tf2`'s `lookupTransform(target, frame)` gives), `None` when they are
    /// not in one tree. The frames of both chains are asked for from then on: kept
    /// before the others.
    pub fn lookup(&mut self, target: &str, frame: &str) -> Option<Isometry3<f64>> {
        let (target, frame) = (
            target.trim_start_matches('/'),
            frame.trim_start_matches('/'),
        );
        let (a, root_a) = self.in_root(target);
        let (b, root_b) = self.in_root(frame);
        let found = root_a == root_b
            && (self.frames.contains_key(target) || self.frames.contains_key(frame));
        if !found {
            return None;
        }
        let pose = a.inverse() * b;
        self.mark_asked(target);
        self.mark_asked(frame);
        Some(pose)
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
        let refused = b.take(
            &TFMessage {
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
            },
            TfTopic::Static,
        );
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
        b.take(
            &TFMessage {
                transforms: vec![tf(
                    "base_footprint",
                    "base_link",
                    [0.0, 0.0, 0.5],
                    [0.0, 0.0, 0.0, 1.0],
                )],
            },
            TfTopic::Dynamic,
        );
        let cam = b.lookup("base_footprint", "camera_link").unwrap();
        assert!((cam.translation.z - 1.7).abs() < 1e-12);
    }

    #[test]
    fn refuses_cycles_bad_values_and_more_frames_than_the_limit() {
        let mut b = TfBuffer::new();
        let id = [0.0, 0.0, 0.0, 1.0];
        let bad = b.take(
            &TFMessage {
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
            },
            TfTopic::Static,
        );
        assert_eq!(bad.len(), 7, "{bad:?}");
        assert!(b.lookup("a", "c").is_some());
        let version = b.version();
        let many = TFMessage {
            transforms: (0..MAX_FRAMES + 10)
                .map(|i| tf("a", &format!("x{i}"), [0.0; 3], id))
                .collect(),
        };
        // All from /tf_static: nothing to make room with.
        let refused = b.take(&many, TfTopic::Static);
        assert_eq!(refused.len(), 2 + 10, "two frames were there already");
        assert_eq!(b.frames.len(), MAX_FRAMES);
        assert!(b.version() > version);
    }

    /// A transform of `parent` -> `child` stamped `ns`.
    fn at(parent: &str, child: &str, ns: i64) -> TransformStamped {
        let mut t = tf(parent, child, [0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0]);
        t.header.stamp = crate::msgs::Time::from_nanos(ns);
        t
    }

    fn one(t: TransformStamped) -> TFMessage {
        TFMessage {
            transforms: vec![t],
        }
    }

    #[test]
    fn a_flood_of_another_tracker_s_frames_keeps_the_floor_and_the_robot_s_chain() {
        let mut b = TfBuffer::new();
        // The camera over the floor, latched; a robot's chain streaming on /tf, asked
        // for.
        b.take(&one(at("base_footprint", "camera", 0)), TfTopic::Static);
        b.take(&one(at("odom", "base_link", 0)), TfTopic::Dynamic);
        assert!(b.lookup("odom", "base_link").is_some());
        // Another tracker's people, 20,000 of them, 1 ms apart, each once, with the
        // robot's base_link sent every 100.
        for i in 0..20_000_i64 {
            let ns = i * 1_000_000;
            let refused = b.take(
                &one(at("camera", &format!("person_{i}"), ns)),
                TfTopic::Dynamic,
            );
            assert!(refused.is_empty(), "{refused:?}");
            if i % 100 == 0 {
                b.take(&one(at("odom", "base_link", ns)), TfTopic::Dynamic);
            }
            assert!(b.len() <= MAX_FRAMES);
        }
        assert!(b.lookup("base_footprint", "camera").is_some());
        assert!(b.lookup("odom", "base_link").is_some());
        assert!(b.lookup("camera", "person_19999").is_some());
        assert!(b.lookup("camera", "person_0").is_none(), "evicted");
        assert!(b.evicted() >= 20_000 - MAX_FRAMES as u64);
    }

    #[test]
    fn tf_frames_nobody_asked_for_age_out_and_static_or_asked_ones_stay() {
        let mut b = TfBuffer::new();
        b.take(&one(at("map", "static_thing", 0)), TfTopic::Static);
        b.take(&one(at("map", "asked", 0)), TfTopic::Dynamic);
        assert!(b.lookup("map", "asked").is_some());
        for k in 0..10 {
            b.take(&one(at("map", &format!("old_{k}"), 0)), TfTopic::Dynamic);
        }
        assert_eq!(b.len(), 12);
        // 11 s later, a sweep's worth of transforms of one frame: the old ones go.
        for _ in 0..SWEEP_EVERY {
            b.take(&one(at("map", "new", 11_000_000_000)), TfTopic::Dynamic);
        }
        assert!(b.lookup("map", "old_3").is_none());
        assert!(b.lookup("map", "static_thing").is_some());
        assert!(b.lookup("map", "asked").is_some());
        assert!(b.lookup("map", "new").is_some());
        assert_eq!((b.len(), b.evicted()), (3, 10));
    }
}
