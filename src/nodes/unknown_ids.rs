//! People without ids: heat maps whose `track_id` is 0 ([`UNKNOWN_TRACK`], as a detector
//! without tracking sends every person) are given ids by the estimator node itself, with
//! the image detector's tracker ([`Tracker`]) on their crop boxes alone.
//!
//! The heat maps of one image come one message per person, and the tracker matches an
//! image's boxes together (a minimum-cost assignment, so the order of the people within
//! an image does not matter). So the node holds an image's messages without an id (a
//! copy each, into buffers reused from image to image) until the image is complete: the
//! first message of another image, a quiet input, or the end of the stream. Their
//! skeletons come out one image later than those of messages with ids.
//!
//! The ids given start at [`ASSIGNED_BASE`] (2^31): messages with ids keep theirs, so a
//! stream mixing both (documented in `HeatMaps.msg`) has its people apart as long as no
//! detector numbers its own from 2^31 up.

use posestream_detector::tracker::{Observation, Tracker, TrackingSettings};

use crate::msgs::{HeatMaps, HeatMapsView, Time};

/// `HeatMaps.track_id` of a person whose detector gave no id.
pub const UNKNOWN_TRACK: u32 = 0;

/// The first id the node gives a person without one (the tracker's ids added to it).
pub const ASSIGNED_BASE: u32 = 1 << 31;

/// The messages without an id of the image in hand, and the tracker that gives them ids.
pub struct UnknownIds {
    tracker: Tracker,
    /// The image in hand: capture time and frame number.
    image: Option<(i64, u64)>,
    /// Its messages, copies (the first `held` of `messages`; the rest are spare).
    messages: Vec<HeatMaps>,
    held: usize,
    observations: Vec<Observation>,
    /// Which held messages have a box (all, as the node checks; reused).
    boxed: Vec<bool>,
}

impl UnknownIds {
    /// At most `max_people` people tracked at once (the node's `max_tracks`).
    pub fn new(max_people: usize) -> Self {
        // A detector's boxes are all there is: each new person is reported at once.
        let settings = TrackingSettings {
            max_people: max_people.clamp(1, TrackingSettings::MAX_PEOPLE),
            birth_frames: 1,
            ..TrackingSettings::default()
        };
        Self {
            tracker: Tracker::new(settings, 0.5),
            image: None,
            messages: Vec::new(),
            held: 0,
            observations: Vec::new(),
            boxed: Vec::new(),
        }
    }

    /// Whether messages of an image other than `msg`'s are held (they go first).
    pub fn held_before(&self, msg: &HeatMapsView<'_>) -> bool {
        self.held > 0 && self.image != Some((msg.stamp_ns, msg.sequence))
    }

    /// Whether messages are held.
    pub fn is_holding(&self) -> bool {
        self.held > 0
    }

    /// Holds a copy of `msg` (of the image in hand, or the first of one; its crop box
    /// checked by the caller), unless `max_held` are held already (then `false`).
    pub fn hold(&mut self, msg: &HeatMapsView<'_>, max_held: usize) -> bool {
        if self.held >= max_held {
            return false;
        }
        self.image = Some((msg.stamp_ns, msg.sequence));
        if self.held == self.messages.len() {
            self.messages.push(HeatMaps::default());
        }
        copy_into(msg, &mut self.messages[self.held]);
        self.held += 1;
        true
    }

    /// Gives the held messages their ids (the tracker on their boxes, one image) and
    /// hands each to `take` with its id (`None`: the tracker took none for it: a box on
    /// a person already in the image, or no room); then they are spare.
    pub fn release(&mut self, mut take: impl FnMut(&HeatMaps, Option<u32>)) {
        if self.held == 0 {
            return;
        }
        self.observations.clear();
        // Held messages have a crop box (the node checks it first).
        self.boxed.clear();
        for m in &self.messages[..self.held] {
            let region = m.crop().ok();
            self.boxed.push(region.is_some());
            if let Some(region) = region {
                self.observations.push(Observation { region, score: 1.0 });
            }
        }
        let mut ids = self.tracker.frame_of_boxes(&self.observations).into_iter();
        let ids = self
            .boxed
            .iter()
            .map(|&b| if b { ids.next().flatten() } else { None });
        for (m, id) in self.messages[..self.held].iter_mut().zip(ids) {
            let id = id.map(|id| ASSIGNED_BASE.wrapping_add(id));
            if let Some(id) = id {
                m.track_id = id;
            }
            take(m, id);
        }
        self.held = 0;
        self.image = None;
    }

    /// Tracks started for people without ids so far.
    pub fn tracks_made(&self) -> u64 {
        self.tracker.stats().births
    }
}

/// Copies `view` into `out`, reusing its buffers.
fn copy_into(view: &HeatMapsView<'_>, out: &mut HeatMaps) {
    out.header.stamp = Time::from_nanos(view.stamp_ns);
    out.header.frame_id.clear();
    out.header.frame_id.push_str(view.frame_id);
    out.sequence = view.sequence;
    out.track_id = view.track_id;
    if out.joint_names.as_slice() != view.joint_names {
        out.joint_names.clear();
        out.joint_names.extend_from_slice(view.joint_names);
    }
    out.height = view.height;
    out.width = view.width;
    [out.crop_x, out.crop_y, out.crop_width, out.crop_height] = view.crop;
    out.encoding = view.encoding;
    out.values.clear();
    out.values.extend_from_slice(view.values);
    out.quantized_values.clear();
    out.quantized_values
        .extend_from_slice(view.quantized_values);
    out.quantization_scale = view.quantization_scale;
    out.frames_since_look = view.frames_since_look;
}
