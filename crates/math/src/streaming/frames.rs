//! What goes into the window and what comes out: a frame of heat maps
//! ([`FrameMaps`], checked: [`CheckedFrame`]), the estimates ([`FrameEstimate`], in the
//! reused buffers of [`Estimates`]), where a track stands ([`TrackState`]) and the
//! window's counters ([`StreamCounters`]).

use serde::{Deserialize, Serialize};

use super::Scores;
#[cfg(doc)]
use super::{StreamSettings, WindowEstimator};
use crate::heatmaps::HeatMapSequence;
use crate::solver::FrameFit;

/// One frame of heat maps as the window receives it.
#[derive(Debug, Clone, Copy)]
pub struct FrameMaps<'a> {
    /// The detector's frame number (consecutive frames differ by one).
    pub sequence: u64,
    /// Capture time, nanoseconds.
    pub stamp_ns: i64,
    /// Map height (rows).
    pub height: usize,
    /// Map width (columns).
    pub width: usize,
    /// p maps of `height x width`, row-major, joint-major: borrowed from the message
    /// or sample that brought them (the window's ring is their one copy).
    pub values: Scores<'a>,
}

impl<'a> FrameMaps<'a> {
    /// The frame of a sequence of heat maps.
    pub fn of(maps: &'a HeatMapSequence, t: usize, sequence: u64, stamp_ns: i64) -> Self {
        let n = maps.joints * maps.height * maps.width;
        Self {
            sequence,
            stamp_ns,
            height: maps.height,
            width: maps.width,
            values: Scores::F32(&maps.values[t * n..(t + 1) * n]),
        }
    }
}

/// A frame [`WindowEstimator::check_frame`] found well formed (sizes agree, every score
/// finite), and whether it holds evidence of someone (a positive score).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CheckedFrame {
    pub(super) evidence: bool,
}

impl CheckedFrame {
    /// True if some score is positive.
    pub fn has_evidence(&self) -> bool {
        self.evidence
    }
}

/// Where a track stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TrackState {
    /// Fewer frames than the lag have arrived since the track started.
    Initialising,
    /// Running normally.
    Tracking,
    /// The last estimates of a track that ended (gap, restart or end of stream).
    Lost,
}

/// One estimate emitted by the window.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameEstimate {
    /// The sequence number of the frame it describes.
    pub sequence: u64,
    /// That frame's capture time, nanoseconds.
    pub stamp_ns: i64,
    /// Frames that arrived after it before this estimate was made (0: newest).
    pub lag: usize,
    /// Where the track stood.
    pub state: TrackState,
    /// 3D joints `R S`, camera frame (x right, y down, z forward), dictionary units,
    /// centred: `[x, y, z]` per joint.
    pub pose: Vec<f64>,
    /// Standard deviation of each coordinate of `pose` (dictionary units, `[x, y, z]`
    /// per joint): the E-step's 2D spread moved to model units, times
    /// [`StreamSettings::std_scale`] (x, y) and [`StreamSettings::depth_std_scale`]
    /// (z: depth is not observed, only the spread of the image's evidence), and
    /// [`StreamSettings::newest_std_scale`] the fewer frames came after it.
    pub pose_std: Vec<f64>,
    /// The expected 2D joints (heat-map pixels): `[x, y]` per joint.
    pub keypoints: Vec<f64>,
    /// Per-joint 2D standard deviation (heat-map pixels) from the E-step.
    pub keypoint_std: Vec<f64>,
    /// The model's reprojection (heat-map pixels): `[x, y]` per joint.
    pub projected: Vec<f64>,
    /// The frame's weak-perspective fit (normalised units), for a metric step after the
    /// window ([`crate::metres::MetricStep`]).
    pub fit: FrameFit,
    /// Heat-map pixels per normalised unit of `fit`.
    pub pixels_per_unit: f64,
    /// The track's shape beyond the dictionary `fit` is composed with (row-major 3 x p,
    /// [`crate::solver::adapt`]; zero for the paper's model).
    pub offset: Vec<f64>,
}

impl Default for FrameEstimate {
    fn default() -> Self {
        Self {
            sequence: 0,
            stamp_ns: 0,
            lag: 0,
            state: TrackState::Initialising,
            pose: Vec::new(),
            pose_std: Vec::new(),
            keypoints: Vec::new(),
            keypoint_std: Vec::new(),
            projected: Vec::new(),
            fit: FrameFit::zero(0),
            pixels_per_unit: 0.0,
            offset: Vec::new(),
        }
    }
}

/// The estimates a push releases, oldest first, in buffers reused from push to push:
/// [`Estimates::clear`] keeps every estimate and its vectors, and the next push writes
/// over them, so a warm window emits without allocating
/// ([`WindowEstimator::push_into`]). Reads as a slice of [`FrameEstimate`]s.
#[derive(Clone, Default)]
pub struct Estimates {
    items: Vec<FrameEstimate>,
    len: usize,
}

impl std::fmt::Debug for Estimates {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

impl Estimates {
    /// Forgets the estimates, keeping their buffers for the next push.
    pub fn clear(&mut self) {
        self.len = 0;
    }

    /// The next estimate to fill: a reused one (its vectors keep their capacity), or a
    /// new one while fewer have ever been needed.
    pub(super) fn next_slot(&mut self) -> &mut FrameEstimate {
        if self.len == self.items.len() {
            self.items.push(FrameEstimate::default());
        }
        self.len += 1;
        &mut self.items[self.len - 1]
    }
}

impl std::ops::Deref for Estimates {
    type Target = [FrameEstimate];
    fn deref(&self) -> &[FrameEstimate] {
        &self.items[..self.len]
    }
}

/// Counters of what the window did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct StreamCounters {
    /// Frames accepted.
    pub frames: u64,
    /// Frames dropped because they came late or out of order.
    pub late: u64,
    /// Frames rejected as malformed (wrong size, non-finite values).
    pub malformed: u64,
    /// Frames without evidence (no positive score in any map): no estimate; they count
    /// as dropped frames.
    pub empty: u64,
    /// Frames missing from the numbering within a track (dropped upstream; frames that
    /// came without evidence are counted in `empty` instead).
    pub missing: u64,
    /// Tracks ended by a gap or a restart.
    pub resets: u64,
    /// Tracks started.
    pub tracks: u64,
}

impl std::ops::AddAssign for StreamCounters {
    /// Adds another window's counts (a node with several tracks reports their sum).
    fn add_assign(&mut self, other: Self) {
        self.frames += other.frames;
        self.late += other.late;
        self.malformed += other.malformed;
        self.empty += other.empty;
        self.missing += other.missing;
        self.resets += other.resets;
        self.tracks += other.tracks;
    }
}
