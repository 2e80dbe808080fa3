//! The estimator's publishing, planned once for both drivers: each skeleton the node
//! releases goes out at once, with its markers and what it says of its body; the
//! skeletons of an image together ([`ImageArrays`]: arrays, the image's markers over it,
//! REP-155's tracked ids) go out once the image is complete.

use super::bodies::BodyPlanner;
use super::floor::FloorPlanner;
use super::plan::{Plan, Publication};
use crate::floor::FloorModel;
use crate::msgs::{Skeleton3D, Skeleton3DArray};
use crate::nodes::arrays::ImageArrays;
use crate::nodes::markers::{image_markers, skeleton_markers};

/// What the estimator publishes of the skeletons its node releases; see the module docs.
pub struct Planner {
    bones: Vec<(usize, usize)>,
    /// Each skeleton's markers.
    markers: bool,
    /// Each image's skeletons together.
    arrays: bool,
    /// Each image's skeletons drawn over it: those of this lag.
    image_markers: Option<u32>,
    /// Bodies' frames and REP-155 messages.
    pub bodies: BodyPlanner,
    /// The learnt floor with its covariance, when published.
    pub floor: Option<FloorPlanner>,
    /// Groups the skeletons into arrays, when the arrays, the image's markers or
    /// REP-155's tracked ids are published.
    grouping: ImageArrays,
    /// Send each skeleton stamped with the time of the frame that released it (a
    /// replay's log time) instead of its own frame's stamp.
    stamp_at_release: bool,
    /// The stamp of the frame handled last, with `stamp_at_release`.
    released_at: u64,
}

impl Planner {
    /// Skeletons of a dictionary whose bones are `bones`, and with `markers` their markers.
    pub fn new(bones: Vec<(usize, usize)>, markers: bool) -> Self {
        Self {
            bones,
            markers,
            arrays: false,
            image_markers: None,
            bodies: BodyPlanner::default(),
            floor: None,
            grouping: ImageArrays::default(),
            stamp_at_release: false,
            released_at: 0,
        }
    }

    /// The same, with each image's skeletons together ([`ImageArrays`]) when `on`.
    pub fn with_arrays(mut self, on: bool) -> Self {
        self.arrays = on;
        self
    }

    /// The same, drawing each image's skeletons of lag `lag` over it (the image's newest
    /// estimate, or the refined one when only those are published), when `on`.
    pub fn with_image_markers(mut self, on: bool, lag: u32) -> Self {
        self.image_markers = on.then_some(lag);
        self
    }

    /// The same, each skeleton sent stamped with the time of the frame that released it
    /// (its source's stamp: a recording's log time), as a recorder of the live topic
    /// would have logged it; the estimates still owed at the end with the last frame's.
    /// Without it, each skeleton goes with its own frame's stamp.
    pub fn stamped_at_release(mut self) -> Self {
        self.stamp_at_release = true;
        self
    }

    /// The same, publishing the learnt floor as the camera's pose over frame `frame`
    /// ([`FloorPlanner`]).
    pub fn with_learnt_floor(mut self, frame: &str) -> Self {
        self.floor = Some(FloorPlanner::new(frame));
        self
    }

    /// Plans the learnt floor (`fit`: `EstimatorNode::learnt_floor_fit`) when it changed,
    /// learnt by the image captured at `capture_ns`.
    pub fn learnt_floor(
        &mut self,
        fit: Option<(u64, Option<&crate::learnt_floor::LearntFloor>)>,
        capture_ns: i64,
        plan: &mut Plan,
    ) {
        let sent = self.stamp(capture_ns);
        if let Some(floor) = &mut self.floor {
            floor.plan(fit, capture_ns, sent, plan);
        }
    }

    /// Whether skeletons are grouped by image (for arrays, the image's markers, or
    /// REP-155's tracked ids).
    fn grouped(&self) -> bool {
        self.arrays || self.image_markers.is_some() || self.bodies.hri()
    }

    /// The source's stamp of the frame being handled.
    pub fn frame_stamp(&mut self, stamp_ns: u64) {
        self.released_at = stamp_ns;
    }

    /// Plans the `skeletons` released by a heat-map message of `image` (its capture time
    /// and frame number; `None`: by none, as when a track ends at the end of the
    /// stream), of images of `image_size` on `floor` (the node's, when known), and moves
    /// them into the plan ([`Plan::add_skeletons`]: `skeletons` is left with messages to
    /// hand back to the node). The previous image's arrays go first when this is another
    /// image.
    pub fn skeletons(
        &mut self,
        image: Option<(i64, u64)>,
        skeletons: &mut [Skeleton3D],
        image_size: Option<(f64, f64)>,
        floor: Option<FloorModel>,
        plan: &mut Plan,
    ) {
        if self.grouped() && (image.is_some() || !skeletons.is_empty()) {
            let first = plan.arrays.len();
            self.grouping.add(image, skeletons, &mut plan.arrays);
            self.plan_arrays(first, plan);
        }
        self.bodies.set_floor(floor);
        let first = plan.skeletons.len();
        for (i, s) in skeletons.iter().enumerate() {
            let stamp = self.stamp(s.header.stamp.nanos());
            plan.order.push((Publication::Skeleton(first + i), stamp));
            if self.markers {
                let (k, markers) = plan.markers.add();
                *markers = skeleton_markers(s, &self.bones);
                plan.order.push((Publication::Markers(k), stamp));
            }
            if !self.bodies.is_empty() {
                self.bodies.plan(s, image_size, stamp, plan);
            }
        }
        plan.add_skeletons(skeletons);
    }

    /// Plans the arrays of an image that may not be complete yet (the input went quiet,
    /// or ends).
    pub fn flush_arrays(&mut self, plan: &mut Plan) {
        if self.grouping.is_pending() {
            let first = plan.arrays.len();
            self.grouping.flush(&mut plan.arrays);
            self.plan_arrays(first, plan);
        }
    }

    /// Plans the arrays from `first` on.
    fn plan_arrays(&mut self, first: usize, plan: &mut Plan) {
        for i in first..plan.arrays.len() {
            let a = &plan.arrays[i];
            let stamp = self.stamp(a.header.stamp.nanos());
            if self.arrays {
                plan.order.push((Publication::Array(i), stamp));
            }
            if self.image_markers == Some(a.lag) {
                let (k, overlay) = plan.image_markers.add();
                image_markers(a, &self.bones, overlay);
                plan.order.push((Publication::ImageMarker(k), stamp));
            }
            if let Some(ids) = self.bodies.tracked(a) {
                let (k, slot) = plan.tracked.add();
                *slot = ids;
                plan.order.push((Publication::Tracked(k), stamp));
            }
        }
    }

    /// Takes back the arrays of a plan that was sent (its skeletons go back to the node
    /// that wrote them), to be written over.
    pub fn recycle(&mut self, arrays: &mut Vec<Skeleton3DArray>) {
        self.grouping.recycle(arrays);
    }

    /// The stamp a message of a frame captured at `capture_ns` is sent with.
    fn stamp(&self, capture_ns: i64) -> u64 {
        if self.stamp_at_release {
            self.released_at
        } else {
            u64::try_from(capture_ns).unwrap_or(0)
        }
    }
}
