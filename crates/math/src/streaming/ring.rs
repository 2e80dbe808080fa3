//! The window's frames and maps, crate-private: each frame's numbering ([`Slot`]), its
//! maps in a ring ([`MapRing`]) and a view of the newest of them ([`Tail`]), and which EM
//! runs over them ([`Which`], and a window EM in parts: [`Sweep`]).

use super::Scores;
#[cfg(doc)]
use super::{StreamSettings, WindowEstimator};
use crate::solver::em::MapSource;
use crate::solver::estep::MapMoments;

/// One frame in the window.
#[derive(Debug, Clone)]
pub(super) struct Slot {
    pub(super) sequence: u64,
    pub(super) stamp_ns: i64,
    /// Frames since the track started (0 for its first).
    pub(super) age: u64,
}

/// The window's maps in a ring: slot `i` holds window frame `(i - start) mod size`.
#[derive(Debug, Clone, Default)]
pub(super) struct MapRing {
    joints: usize,
    pub(super) height: usize,
    pub(super) width: usize,
    start: usize,
    pub(super) len: usize,
    capacity: usize,
    pub(super) values: Vec<f32>,
    pub(super) moments: Vec<MapMoments>,
}

impl MapRing {
    fn slot(&self, t: usize) -> usize {
        (self.start + t) % self.capacity
    }

    /// A ring of `capacity` frames of `joints` maps of `height` x `width`. Its buffers
    /// grow with the frames pushed ([`MapRing::push_back`]), so a short track costs its
    /// own frames, not a whole window's; once full it allocates nothing.
    pub(super) fn configure(
        &mut self,
        capacity: usize,
        joints: usize,
        height: usize,
        width: usize,
    ) {
        self.capacity = capacity;
        self.joints = joints;
        self.height = height;
        self.width = width;
        self.start = 0;
        self.len = 0;
    }

    pub(super) fn clear(&mut self) {
        self.start = 0;
        self.len = 0;
    }

    pub(super) fn pop_front(&mut self) {
        self.start = (self.start + 1) % self.capacity;
        self.len -= 1;
    }

    /// Appends a frame (dequantised, negatives clipped) and its moments.
    pub(super) fn push_back(&mut self, values: &Scores<'_>) {
        let n = self.joints * self.height * self.width;
        let m = self.height * self.width;
        let slot = self.slot(self.len);
        // Room for the slot: doubling (amortised) up to the capacity, never beyond it.
        if self.values.len() < (slot + 1) * n {
            let frames =
                (2 * (self.values.len() / n.max(1))).clamp(slot + 1, self.capacity.max(slot + 1));
            self.values.resize(frames * n, 0.0);
        }
        if self.moments.len() < (slot + 1) * self.joints {
            let frames = (self.values.len() / n.max(1)).max(slot + 1);
            self.moments
                .resize(frames * self.joints, MapMoments::default());
        }
        let dst = &mut self.values[slot * n..(slot + 1) * n];
        values.clipped_into(dst);
        for j in 0..self.joints {
            self.moments[slot * self.joints + j] =
                MapMoments::new(&dst[j * m..(j + 1) * m], self.width);
        }
        self.len += 1;
    }
}

impl MapSource for MapRing {
    fn height(&self) -> usize {
        self.height
    }
    fn width(&self) -> usize {
        self.width
    }
    fn map(&self, t: usize, j: usize) -> &[f32] {
        let m = self.height * self.width;
        let i = self.slot(t) * self.joints + j;
        &self.values[i * m..(i + 1) * m]
    }
    fn moments(&self, t: usize, j: usize) -> &MapMoments {
        &self.moments[self.slot(t) * self.joints + j]
    }
}

/// The frames `from..` of another source.
pub(super) struct Tail<'a, M> {
    pub(super) inner: &'a M,
    pub(super) from: usize,
}

impl<M: MapSource> MapSource for Tail<'_, M> {
    fn height(&self) -> usize {
        self.inner.height()
    }
    fn width(&self) -> usize {
        self.inner.width()
    }
    fn map(&self, t: usize, j: usize) -> &[f32] {
        self.inner.map(self.from + t, j)
    }
    fn moments(&self, t: usize, j: usize) -> &MapMoments {
        self.inner.moments(self.from + t, j)
    }
}

/// Which of the window's EMs (each has its parameters).
#[derive(Debug, Clone, Copy)]
pub(super) enum Which {
    /// Over the newest [`StreamSettings::local_frames`].
    Local,
    /// Over the newest `lag + 1` frames ([`StreamSettings::lag_iterations`]).
    Lagged,
    /// Over the whole window, or a part of it ([`StreamSettings::window_every`]).
    Window,
}

/// A window EM running in parts ([`StreamSettings::window_parts`]), one part per frame.
#[derive(Debug, Clone, Copy)]
pub(super) struct Sweep {
    /// The next part.
    pub(super) part: usize,
    /// Parts in all: [`StreamSettings::window_parts`], at most one per frame.
    pub(super) parts: usize,
    /// Frames in the window when the sweep began: the parts divide these.
    pub(super) frames: usize,
    /// [`WindowEstimator::dropped`] then: frames that left since shift the parts.
    pub(super) dropped: usize,
}

impl Sweep {
    /// The window frames of the next part (and moves on to the one after), with `n`
    /// frames in the window and `dropped` frames left so far. Part i holds the frames
    /// `[i n0 / m, (i+1) n0 / m)` of the n0 there were when the sweep began, shifted by
    /// the frames that have left since; the last part also takes the frames that have
    /// come since. So every frame is in exactly one part, unless it left first.
    pub(super) fn next_part(&mut self, n: usize, dropped: usize) -> std::ops::Range<usize> {
        let shift = dropped - self.dropped;
        let bound = |i: usize| (i * self.frames / self.parts).saturating_sub(shift);
        let from = bound(self.part);
        let to = if self.part + 1 == self.parts {
            n
        } else {
            bound(self.part + 1)
        };
        self.part += 1;
        from..to.max(from)
    }
}
