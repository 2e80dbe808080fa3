//! Where a plan's messages go: one [`Publishers`] per output. The two drivers differ only
//! in the send call: [`Sinks::send`] blocks where a ROS 2 history is full (a blocking
//! loop), [`Sinks::send_async`] awaits room there and lets a new body's topics settle
//! (the tokio driver).

use std::sync::Arc;

use super::body_topics::{BodyTopics, HriSinks, RoiSend};
use super::plan::{Plan, Publication};
use super::publishers::Publishers;
use crate::msgs::tf::{PoseWithCovarianceStamped, TFMessage};
use crate::msgs::visualization::ImageMarker;
use crate::msgs::{MarkerArray, Skeleton3D, Skeleton3DArray, SkeletonState};
use crate::nodes::latency::FrameClock;

/// A node's outputs: each output's publishers (empty when off).
#[derive(Default)]
pub struct Sinks {
    /// Skeletons.
    pub skeletons: Publishers<Skeleton3D>,
    /// Each skeleton's markers.
    pub markers: Publishers<MarkerArray>,
    /// The skeletons of each image together.
    pub arrays: Publishers<Skeleton3DArray>,
    /// Each image's skeletons drawn over it.
    pub image_markers: Publishers<ImageMarker>,
    /// Bodies' frames.
    pub tf: Publishers<TFMessage>,
    /// REP-155's topics, when on.
    pub hri: Option<HriSinks>,
    /// The learnt floor with its covariance.
    pub floor: Publishers<PoseWithCovarianceStamped>,
    /// Notes when each newest skeleton goes out (latency from its image).
    pub clock: Option<FrameClock>,
}

/// One message of a plan with the publishers it goes to.
enum Send<'s, 'p> {
    Skeleton(&'s mut Publishers<Skeleton3D>, &'p Arc<Skeleton3D>),
    Markers(&'s mut Publishers<MarkerArray>, &'p MarkerArray),
    Array(&'s mut Publishers<Skeleton3DArray>, &'p Skeleton3DArray),
    ImageMarker(&'s mut Publishers<ImageMarker>, &'p ImageMarker),
    Tracked(
        &'s mut Publishers<crate::msgs::hri::IdsList>,
        &'p crate::msgs::hri::IdsList,
    ),
    Transforms(&'s mut Publishers<TFMessage>, &'p TFMessage),
    Body(&'s mut BodyTopics, &'p super::plan::BodyMessages),
    Floor(
        &'s mut Publishers<PoseWithCovarianceStamped>,
        &'p PoseWithCovarianceStamped,
    ),
    Nothing,
}

impl Sinks {
    /// Sends `plan`'s messages in order, blocking where a sink blocks.
    pub fn send(&mut self, plan: &Plan) {
        for &(publication, stamp) in &plan.order {
            match self.route(plan, publication) {
                Send::Skeleton(p, m) => {
                    p.publish_shared(m, stamp);
                    self.note_latency(m);
                }
                Send::Markers(p, m) => p.publish(m, stamp),
                Send::Array(p, m) => p.publish(m, stamp),
                Send::ImageMarker(p, m) => p.publish(m, stamp),
                Send::Tracked(p, m) => p.publish(m, stamp),
                Send::Transforms(p, m) => p.publish(m, stamp),
                Send::Floor(p, m) => p.publish(m, stamp),
                Send::Body(body, b) => {
                    // Not waited for here, on the node's thread: see `send_async`.
                    body.settle();
                    if let Some((roi, points)) = &b.messages {
                        if let Some(roi) = roi.as_ref().and_then(|r| body.roi.with(r)) {
                            match roi {
                                RoiSend::Pixels(p, r) => p.publish(r, stamp),
                                RoiSend::Normalized(p, r) => p.publish(r, stamp),
                            }
                        }
                        body.skeleton2d.publish(points, stamp);
                    }
                }
                Send::Nothing => {}
            }
        }
    }

    /// [`Sinks::send`] on a runtime: a ROS 2 publisher awaited instead of blocking while
    /// its reliable history is full, and a new body's first messages waiting (awaited,
    /// the input goes on) for its publishers to match subscribers discovery knows.
    pub async fn send_async(&mut self, plan: &Plan) {
        for &(publication, stamp) in &plan.order {
            match self.route(plan, publication) {
                Send::Skeleton(p, m) => {
                    p.publish_shared_async(m, stamp).await;
                    self.note_latency(m);
                }
                Send::Markers(p, m) => p.publish_async(m, stamp).await,
                Send::Array(p, m) => p.publish_async(m, stamp).await,
                Send::ImageMarker(p, m) => p.publish_async(m, stamp).await,
                Send::Tracked(p, m) => p.publish_async(m, stamp).await,
                Send::Transforms(p, m) => p.publish_async(m, stamp).await,
                Send::Floor(p, m) => p.publish_async(m, stamp).await,
                Send::Body(body, b) => {
                    if let Some(wait) = body.settle() {
                        tokio::time::sleep(wait).await;
                    }
                    if let Some((roi, points)) = &b.messages {
                        if let Some(roi) = roi.as_ref().and_then(|r| body.roi.with(r)) {
                            match roi {
                                RoiSend::Pixels(p, r) => p.publish_async(r, stamp).await,
                                RoiSend::Normalized(p, r) => p.publish_async(r, stamp).await,
                            }
                        }
                        body.skeleton2d.publish_async(points, stamp).await;
                    }
                }
                Send::Nothing => {}
            }
        }
    }

    /// The publishers of one planned message, and the message.
    fn route<'s, 'p>(&'s mut self, plan: &'p Plan, publication: Publication) -> Send<'s, 'p> {
        match publication {
            Publication::Skeleton(i) => match plan.skeletons.get(i) {
                Some(m) => Send::Skeleton(&mut self.skeletons, m),
                None => Send::Nothing,
            },
            Publication::Markers(i) => match plan.markers.get(i) {
                Some(m) => Send::Markers(&mut self.markers, m),
                None => Send::Nothing,
            },
            Publication::Array(i) => match plan.arrays.get(i) {
                Some(m) => Send::Array(&mut self.arrays, m),
                None => Send::Nothing,
            },
            Publication::ImageMarker(i) => match plan.image_markers.get(i) {
                Some(m) => Send::ImageMarker(&mut self.image_markers, m),
                None => Send::Nothing,
            },
            Publication::Tracked(i) => match (plan.tracked.get(i), &mut self.hri) {
                (Some(m), Some(hri)) => Send::Tracked(&mut hri.tracked, m),
                _ => Send::Nothing,
            },
            Publication::Transforms(i) => match plan.transforms.get(i) {
                Some(m) => Send::Transforms(&mut self.tf, m),
                None => Send::Nothing,
            },
            Publication::Floor(i) => match plan.floors.get(i) {
                Some(m) => Send::Floor(&mut self.floor, m),
                None => Send::Nothing,
            },
            Publication::Body(i) => match (plan.bodies.get(i), &mut self.hri) {
                (Some(b), Some(hri)) => match hri.body(b) {
                    Some(body) => Send::Body(body, b),
                    None => Send::Nothing,
                },
                _ => Send::Nothing,
            },
        }
    }

    /// A newest (lag 0) skeleton of someone present just went out: its latency, on the
    /// frame clock if there is one.
    fn note_latency(&self, skeleton: &Skeleton3D) {
        if let Some(clock) = &self.clock
            && skeleton.lag == 0
            && skeleton.state != SkeletonState::Lost as u8
        {
            clock.skeleton_out(skeleton.header.stamp.nanos());
        }
    }

    /// Flushes every output.
    pub fn flush(&mut self) {
        self.skeletons.flush();
        self.markers.flush();
        self.arrays.flush();
        self.image_markers.flush();
        self.tf.flush();
        self.floor.flush();
        if let Some(hri) = &mut self.hri {
            hri.flush();
        }
    }

    /// Sends that failed, on every output.
    pub fn failed(&self) -> u64 {
        self.skeletons.failed
            + self.markers.failed
            + self.arrays.failed
            + self.image_markers.failed
            + self.tf.failed
            + self.floor.failed
            + self.hri.as_ref().map_or(0, HriSinks::failed)
    }
}
