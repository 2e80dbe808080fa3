//! A small tf2-style buffer: the transforms read from `/tf_static` and `/tf` (a ROS 2
//! graph's or a recording's), each frame under its parent, and the lookup of one frame
//! in another through their common ancestor. The newest transform of each frame is the
//! one used (no interpolation between stamps: the estimator asks for a camera's place
//! over the floor, which a fixed camera or a robot standing still keeps).
//!
//! Bounded by frames ([`MAX_FRAMES`]), evicting by age what nobody asks for:
//! - a frame first heard on `/tf_static` ([`TfTopic::Static`]: sent once, latched, never
//!   again) stays, whatever comes for it on `/tf` later;
//! - with [`MAX_FRAMES`] frames known, a new one takes the place of the `/tf` frame
//!   ([`TfTopic::Dynamic`]: sent again and again) taken least recently, those no lookup
//!   passed through first (counted, [`TfBuffer::evicted`]; said once): another
//!   tracker's flood of people's frames cannot crowd out the floor, a camera's place or
//!   a chain looked up; when all are `/tf_static`'s, it is refused.
//!
//! Nothing expires by time alone: a robot standing still may send a frame only when it
//! changes, and it is needed when the next person comes (tf2 too keeps each frame's
//! newest transform; its cache time prunes older ones of the same frame, which this
//! buffer does not keep).
//!
//! A transform with a non-finite value, a translation beyond [`MAX_TRANSLATION_M`], a
//! quaternion not of unit length, an empty or over-long frame id, or making a frame its
//! own ancestor (within 64 parents) is refused (its reason returned), and what was
//! known stays.

use std::cell::Cell;
use std::collections::HashMap;

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

pub use crate::msgs::tf::TfTopic;
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

/// One frame: its newest transform, and what keeps it.
#[derive(Debug, Clone)]
struct Frame {
    parent: String,
    /// Its pose in the parent.
    pose: Isometry3<f64>,
    /// `Static` once heard on `/tf_static`.
    topic: TfTopic,
    /// The buffer's version when it was taken last.
    taken: u64,
    /// A lookup passed through it (set through a shared borrow: a lookup allocates
    /// nothing).
    asked: Cell<bool>,
}

/// The newest transform of each frame, under its parent.
#[derive(Debug, Clone, Default)]
pub struct TfBuffer {
    /// child -> its frame.
    frames: HashMap<String, Frame>,
    /// Transforms taken, in all (so that a user of a lookup knows when to ask again).
    version: u64,
    /// Frames dropped to make room.
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

    /// Frames dropped so far to make room.
    pub fn evicted(&self) -> u64 {
        self.evicted
    }

    /// Makes room for one more frame: drops the `/tf` frame taken least recently, one
    /// no lookup passed through first; `false` when every frame is `/tf_static`'s.
    fn make_room(&mut self) -> bool {
        let victim = self
            .frames
            .iter()
            .filter(|(_, f)| f.topic == TfTopic::Dynamic)
            .min_by_key(|(_, f)| (f.asked.get(), f.taken))
            .map(|(id, _)| id.clone());
        match victim {
            Some(id) => {
                if self.evicted == 0 {
                    tracing::info!(
                        "the transform buffer holds {MAX_FRAMES} frames: /tf frames nobody \
                         looked up make room, the least recently sent first (first: {id})"
                    );
                }
                tracing::debug!("transform buffer full: {id} dropped");
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
        // Not its own ancestor: the parent's chain must not pass through the child.
        if self.ancestors(parent).any(|a| a == child) {
            return Err(format!("{parent} -> {child}: a cycle"));
        }
        // Room is made last: a transform refused evicts nothing.
        if !self.frames.contains_key(child) && self.frames.len() >= MAX_FRAMES && !self.make_room()
        {
            return Err(format!(
                "{child}: more than {MAX_FRAMES} frames, all from the static topic"
            ));
        }
        let pose = Isometry3::from_parts(
            Translation3::new(v.x, v.y, v.z),
            UnitQuaternion::from_quaternion(q),
        );
        self.version += 1;
        // A frame known already keeps its buffers (a robot's /tf streams).
        match self.frames.get_mut(child) {
            Some(f) => {
                f.parent.clear();
                f.parent.push_str(parent);
                f.pose = pose;
                // Latched once, static for good (a relay may send it on /tf too).
                if topic == TfTopic::Static {
                    f.topic = TfTopic::Static;
                }
                f.taken = self.version;
            }
            None => {
                self.frames.insert(
                    child.to_owned(),
                    Frame {
                        parent: parent.to_owned(),
                        pose,
                        topic,
                        taken: self.version,
                        asked: Cell::new(false),
                    },
                );
            }
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
    fn mark_asked(&self, frame: &str) {
        let mut at = frame;
        for _ in 0..MAX_DEPTH {
            let Some(f) = self.frames.get(at) else {
                break;
            };
            f.asked.set(true);
            at = &f.parent;
        }
    }

    /// The pose of `frame` in `target` (`target`'s coordinates of `frame`'s origin and
    /// axes: what `tf2`'s `lookupTransform(target, frame)` gives), `None` when they are
    /// not in one tree. The frames of both chains are asked for from then on: kept
    /// before the others.
    pub fn lookup(&self, target: &str, frame: &str) -> Option<Isometry3<f64>> {
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
    fn a_flood_of_another_tracker_s_frames_keeps_the_floor_and_the_chains_looked_up() {
        let mut b = TfBuffer::new();
        // The camera over the floor, latched (and relayed once on /tf: still latched),
        // never looked up yet; a robot's chain sent once on /tf and looked up; a
        // streaming one, never looked up.
        b.take(&one(at("base_footprint", "camera", 0)), TfTopic::Static);
        b.take(&one(at("base_footprint", "camera", 0)), TfTopic::Dynamic);
        b.take(&one(at("odom", "base_link", 0)), TfTopic::Dynamic);
        assert!(b.lookup("odom", "base_link").is_some());
        b.take(&one(at("map", "odom", 0)), TfTopic::Dynamic);
        // Another tracker's people, 20,000 of them, each once.
        for i in 0..20_000_i64 {
            let refused = b.take(
                &one(at("camera", &format!("person_{i}"), i)),
                TfTopic::Dynamic,
            );
            assert!(refused.is_empty(), "{refused:?}");
            assert!(b.len() <= MAX_FRAMES);
        }
        assert!(b.lookup("base_footprint", "camera").is_some());
        assert!(b.lookup("odom", "base_link").is_some());
        assert!(b.lookup("camera", "person_19999").is_some());
        // Nobody asked for these: the least recently sent went first.
        assert!(b.lookup("camera", "person_0").is_none(), "evicted");
        assert!(b.lookup("map", "odom").is_none(), "evicted");
        assert_eq!(b.evicted(), 20_000 + 3 - MAX_FRAMES as u64);
    }

    #[test]
    fn a_transform_refused_evicts_nothing() {
        let mut b = TfBuffer::new();
        for i in 0..MAX_FRAMES {
            b.take(&one(at("a", &format!("f{i}"), 0)), TfTopic::Dynamic);
        }
        // a under f0 would make a cycle (f0 is under a).
        let refused = b.take(&one(at("f0", "a", 0)), TfTopic::Dynamic);
        assert_eq!(refused.len(), 1, "{refused:?}");
        assert_eq!((b.len(), b.evicted()), (MAX_FRAMES, 0));
    }
}
