//! How people are tracked (`[detector.images.tracking]`), with each value's domain.

use serde::{Deserialize, Serialize};

use posestream_base::{OutOfDomain, check_real};

/// How people are tracked (`[detector.images.tracking]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackingSettings {
    /// People tracked at most at once; more are ignored (counted).
    pub max_people: usize,
    /// Frames in a row a new person must be seen before their track is reported (a
    /// scene's first frame reports at once).
    pub birth_frames: u32,
    /// Frames in a row a track may be unseen and still be re-acquired with its id.
    pub lost_frames: u32,
    /// The person detector runs at least every this many frames while people are
    /// followed (to find newcomers); always when nobody is, and after a loss.
    pub detect_every: u32,
    /// Person-detector scores from this up to `detection_threshold` are the second,
    /// low-score pass: they may re-acquire a track, and start one only where a second
    /// opinion finds a person ([`Assignment::Candidate`]).
    pub low_threshold: f32,
    /// A box overlapping a track's predicted box by less than this (IoU) is not that
    /// track.
    pub match_iou: f64,
    /// A confident box overlapping a track seen this frame by more than this (IoU) is
    /// that person, not a new one.
    pub duplicate_iou: f64,
    /// Seconds after a person was last seen that their ended track's look is
    /// remembered: a newcomer who looks like them, where they could have gone, gets
    /// their id back (a track ends `lost_frames` after it was last seen).
    pub reid_seconds: f64,
    /// Ended tracks remembered at most (the oldest forgotten first).
    pub reid_capacity: usize,
    /// A newcomer's look at most this far (Bhattacharyya distance, 0 to 1) from a lost
    /// or remembered person's may be them (0: nobody is found again by their look).
    pub reid_distance: f64,
    /// Landmark looks at the people followed per frame, about (0: everyone every
    /// frame): the others wait, the most urgent looked at first (`tracker/schedule.rs`),
    /// their newest heat maps carried over. 4 keeps 8-10 people at 15 frames/s on 2
    /// cores with LiteRT; more cores afford more.
    pub looks_per_frame: usize,
    /// Frames in a row a followed person waits for a look at most (looked at then even
    /// past `looks_per_frame`).
    pub max_wait_frames: u32,
}

impl Default for TrackingSettings {
    fn default() -> Self {
        Self {
            max_people: 12,
            birth_frames: 2,
            lost_frames: 30,
            detect_every: 10,
            low_threshold: 0.2,
            match_iou: 0.2,
            duplicate_iou: 0.5,
            reid_seconds: 5.0,
            reid_capacity: 64,
            reid_distance: 0.3,
            looks_per_frame: 4,
            max_wait_frames: 1,
        }
    }
}

impl TrackingSettings {
    /// People at most (the estimator's `max_tracks` is at most this many).
    pub const MAX_PEOPLE: usize = 64;
    /// Ended tracks remembered at most.
    pub const MAX_REMEMBERED: usize = 4096;

    /// Checks every value is in its domain; the error names the key.
    pub fn check(&self) -> Result<(), OutOfDomain> {
        let count = |key: &'static str, v: u64, lo: u64, hi: u64| {
            if (lo..=hi).contains(&v) {
                Ok(())
            } else {
                Err(OutOfDomain::new(
                    key,
                    format!("an integer in {lo}..={hi}"),
                    v.to_string(),
                ))
            }
        };
        count(
            "tracking.max_people",
            self.max_people as u64,
            1,
            Self::MAX_PEOPLE as u64,
        )?;
        count("tracking.birth_frames", self.birth_frames.into(), 1, 1000)?;
        count("tracking.lost_frames", self.lost_frames.into(), 0, 100_000)?;
        count(
            "tracking.detect_every",
            self.detect_every.into(),
            1,
            100_000,
        )?;
        check_real(
            "tracking.low_threshold",
            f64::from(self.low_threshold),
            0.0,
            1.0,
            false,
        )?;
        check_real("tracking.match_iou", self.match_iou, 0.0, 1.0, false)?;
        check_real(
            "tracking.duplicate_iou",
            self.duplicate_iou,
            0.0,
            1.0,
            false,
        )?;
        check_real(
            "tracking.reid_seconds",
            self.reid_seconds,
            0.0,
            3600.0,
            false,
        )?;
        count(
            "tracking.reid_capacity",
            self.reid_capacity as u64,
            0,
            Self::MAX_REMEMBERED as u64,
        )?;
        check_real(
            "tracking.reid_distance",
            self.reid_distance,
            0.0,
            1.0,
            false,
        )?;
        count(
            "tracking.looks_per_frame",
            self.looks_per_frame as u64,
            0,
            Self::MAX_PEOPLE as u64,
        )?;
        count(
            "tracking.max_wait_frames",
            self.max_wait_frames.into(),
            0,
            30,
        )?;

        Ok(())
    }
}
