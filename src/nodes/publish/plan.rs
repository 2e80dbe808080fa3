//! A plan of what to publish: the messages a node's step made, in the order they go out,
//! each with its stamp. A node's decision core writes it ([`super::Planner`]); a driver
//! hands it to the sinks ([`super::Sinks::send`], or awaited on a runtime), then back to
//! the core, whose next plan is written over it (its messages' buffers reused).

use std::sync::Arc;

use crate::msgs::hri::{IdsList, NormalizedRegionOfInterest2D, Skeleton2D};
use crate::msgs::sensor::RegionOfInterest;
use crate::msgs::tf::{PoseWithCovarianceStamped, TFMessage};
use crate::msgs::visualization::ImageMarker;
use crate::msgs::{MarkerArray, Skeleton3D, Skeleton3DArray};

/// One message of a plan: the output it goes to, and its index in the plan's messages
/// of that type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Publication {
    /// [`Plan::skeletons`]: a skeleton (`topics.skeletons`).
    Skeleton(usize),
    /// [`Plan::markers`]: a skeleton's markers (`topics.markers`).
    Markers(usize),
    /// [`Plan::arrays`]: an image's skeletons together (`topics.skeleton_arrays`).
    Array(usize),
    /// [`Plan::image_markers`]: an image's skeletons over it (`topics.image_markers`).
    ImageMarker(usize),
    /// [`Plan::tracked`]: REP-155's bodies tracked in an image.
    Tracked(usize),
    /// [`Plan::transforms`]: a body's frames on `/tf`.
    Transforms(usize),
    /// [`Plan::bodies`]: a body's REP-155 topics.
    Body(usize),
    /// [`Plan::floors`]: the learnt floor with its covariance (`topics.floor`).
    Floor(usize),
}

/// A body's region, as its `roi` topic carries it (`[outputs] hri_roi`).
#[derive(Debug, Clone, PartialEq)]
pub enum Roi {
    /// `sensor_msgs/RegionOfInterest`, pixels.
    Pixels(RegionOfInterest),
    /// `hri_msgs/NormalizedRegionOfInterest2D`.
    Normalized(NormalizedRegionOfInterest2D),
}

/// What is said of one body seen in an image on its REP-155 topics.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BodyMessages {
    /// Its track.
    pub track_id: u32,
    /// Its region (if its joints give one) and 2D skeleton; `None` while the images'
    /// size is unknown (the body is still seen: its topics stay).
    pub messages: Option<(Option<Roi>, Skeleton2D)>,
}

/// Messages of one type written over those of earlier plans.
#[derive(Debug, Clone)]
pub struct Pool<T> {
    items: Vec<T>,
    len: usize,
}

impl<T> Default for Pool<T> {
    fn default() -> Self {
        Self {
            items: Vec::new(),
            len: 0,
        }
    }
}

impl<T: Default> Pool<T> {
    /// The next message (one of an earlier plan, to be written over, or a new one) and
    /// its index.
    pub fn add(&mut self) -> (usize, &mut T) {
        if self.len == self.items.len() {
            self.items.push(T::default());
        }
        self.len += 1;
        (self.len - 1, &mut self.items[self.len - 1])
    }
}

impl<T> Pool<T> {
    /// Message `i` of this plan.
    pub fn get(&self, i: usize) -> Option<&T> {
        self.items[..self.len].get(i)
    }

    /// Message `i` of this plan, to change.
    pub fn get_mut(&mut self, i: usize) -> Option<&mut T> {
        self.items[..self.len].get_mut(i)
    }

    /// The messages of this plan.
    pub fn as_slice(&self) -> &[T] {
        &self.items[..self.len]
    }

    /// Takes back the message [`Pool::add`] gave last (it turned out empty).
    pub fn retract(&mut self) {
        self.len = self.len.saturating_sub(1);
    }

    /// Forgets this plan's messages (kept, to be written over).
    pub fn clear(&mut self) {
        self.len = 0;
    }
}

/// What a step publishes, in order; see the module docs.
#[derive(Debug, Default)]
pub struct Plan {
    /// Each message with its stamp (the log time in a recording), in the order sent.
    pub order: Vec<(Publication, u64)>,
    /// Skeletons, shared with the publishers that serialise them (ROS 2 takes them
    /// without a copy); [`Plan::add_skeletons`] writes them.
    pub skeletons: Vec<Arc<Skeleton3D>>,
    /// Skeletons of plans sent, written over by the next ones.
    spare_skeletons: Vec<Arc<Skeleton3D>>,
    /// Each skeleton's markers.
    pub markers: Pool<MarkerArray>,
    /// Images' skeletons together (handed back to the grouping that made them).
    pub arrays: Vec<Skeleton3DArray>,
    /// Images' skeletons drawn over them.
    pub image_markers: Pool<ImageMarker>,
    /// REP-155's bodies tracked per image.
    pub tracked: Pool<IdsList>,
    /// Bodies' frames.
    pub transforms: Pool<TFMessage>,
    /// Bodies' REP-155 messages.
    pub bodies: Pool<BodyMessages>,
    /// The learnt floor, when it changed.
    pub floors: Pool<PoseWithCovarianceStamped>,
}

impl Plan {
    /// Nothing to send.
    pub fn is_empty(&self) -> bool {
        self.order.is_empty()
    }

    /// Moves `skeletons` into the plan, each into a skeleton of a plan sent before (its
    /// contents swapped: `skeletons` is left holding theirs, to be handed back to the node
    /// that wrote them and written over; a skeleton still shared is not reused).
    pub fn add_skeletons(&mut self, skeletons: &mut [Skeleton3D]) {
        for s in skeletons {
            let mut kept = self.spare_skeletons.pop().unwrap_or_default();
            match Arc::get_mut(&mut kept) {
                Some(slot) => std::mem::swap(slot, s),
                None => kept = Arc::new(std::mem::take(s)),
            }
            self.skeletons.push(kept);
        }
    }

    /// Forgets what was sent; the messages stay to be written over. (Arrays go back to
    /// their grouping first: [`super::Planner::recycle`].)
    pub fn clear(&mut self) {
        self.order.clear();
        self.spare_skeletons.append(&mut self.skeletons);
        self.markers.clear();
        self.arrays.clear();
        self.image_markers.clear();
        self.tracked.clear();
        self.transforms.clear();
        self.bodies.clear();
        self.floors.clear();
    }
}
