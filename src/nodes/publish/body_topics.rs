//! REP-155's body topics, as sinks: the ids tracked in each image on `<ns>/tracked`, and
//! per body `<ns>/<id>/roi` and `<ns>/<id>/skeleton2d`. A body's topics are made when it
//! is first seen and dropped once it has not been seen for [`RETIRE_AFTER`] (its track
//! ended, or it left), so their number follows the people in view: at most
//! [`MAX_BODY_TOPICS`] bodies at once, and [`MAX_BODIES_MADE`] over a process's life
//! (ros2-client keeps every publisher it ever made in its node's `ros_discovery_info`,
//! which would otherwise grow for ever; later bodies get no topics of their own, counted,
//! while `/tf` and the tracked ids go on).

use std::time::{Duration, Instant};

use super::plan::{BodyMessages, Roi};
use super::publishers::Publishers;
use crate::msgs::hri::{IdsList, NormalizedRegionOfInterest2D, Skeleton2D};
use crate::msgs::sensor::RegionOfInterest;
use crate::nodes::config::HriRoi;
use crate::nodes::errors::ServiceError;
use crate::nodes::hri::body_id;
use crate::nodes::publish::taps::Taps;
use crate::transport::Message;
use crate::transport::ros2::Ros2;

/// Bodies whose topics are kept at once; past it, the one seen least recently loses
/// them (they are made again when it is seen again).
pub const MAX_BODY_TOPICS: usize = 64;

/// How long a body's topics stay after it was last seen (its track ended or it left):
/// DDS delivers in the background, and a publisher dropped at once may lose what it sent
/// last; a person lost for less keeps them.
pub const RETIRE_AFTER: Duration = Duration::from_secs(2);

/// Bodies given topics of their own over a process's life, at most (see the module docs).
/// Each costs memory that is not given back when its topics go (measured: about 130 kB a
/// body, a hostile peer sending a new track id in every frame took the estimator from 25
/// to 345 MB over 2,559 bodies): with 1024 it levels off at 106 MB.
pub const MAX_BODIES_MADE: u64 = 1024;

/// Makes publishers while the loop runs: a ROS 2 node shared with the wiring, and the
/// output recording and live view, as configured.
#[derive(Clone, Default)]
pub struct TopicMaker {
    /// The ROS 2 node, when publishing on ROS 2.
    pub ros: Option<Ros2>,
    /// The output recording and the live view, if any.
    pub taps: Taps,
}

impl TopicMaker {
    /// Publishers of `M` on `topic`.
    pub fn publishers<M: Message>(&self, topic: &str) -> Result<Publishers<M>, ServiceError> {
        let mut out = Publishers::default();
        if let Some(ros) = &self.ros {
            out.add_ros2(format!("ros2 {topic}"), ros.sink::<M>(topic)?);
        }
        self.taps.add_to(&mut out, topic)?;
        Ok(out)
    }
}

/// One body's REP-155 topics.
pub(super) struct BodyTopics {
    track_id: u32,
    pub(super) roi: RoiTopic,
    pub(super) skeleton2d: Publishers<Skeleton2D>,
    /// When it was seen last.
    seen: Instant,
    /// Made while discovery knew subscribers of its topics: its first messages wait until
    /// then for the new publishers to match them (else they go to nobody).
    settle_until: Option<Instant>,
}

/// A body's `roi` publishers, of the configured type (`[outputs] hri_roi`).
pub(super) enum RoiTopic {
    Pixels(Publishers<RegionOfInterest>),
    Normalized(Publishers<NormalizedRegionOfInterest2D>),
}

impl RoiTopic {
    /// The publishers of `roi`'s type, with it (none: a region of the other type).
    pub(super) fn with<'a>(&'a mut self, roi: &'a Roi) -> Option<RoiSend<'a>> {
        match (self, roi) {
            (Self::Pixels(p), Roi::Pixels(r)) => Some(RoiSend::Pixels(p, r)),
            (Self::Normalized(p), Roi::Normalized(r)) => Some(RoiSend::Normalized(p, r)),
            _ => None,
        }
    }

    fn flush(&mut self) {
        match self {
            Self::Pixels(p) => p.flush(),
            Self::Normalized(p) => p.flush(),
        }
    }

    fn failed(&self) -> u64 {
        match self {
            Self::Pixels(p) => p.failed,
            Self::Normalized(p) => p.failed,
        }
    }
}

/// A region and the publishers of its type.
pub(super) enum RoiSend<'a> {
    Pixels(&'a mut Publishers<RegionOfInterest>, &'a RegionOfInterest),
    Normalized(
        &'a mut Publishers<NormalizedRegionOfInterest2D>,
        &'a NormalizedRegionOfInterest2D,
    ),
}

impl BodyTopics {
    /// How long its first messages still wait for its publishers to match (once).
    pub(super) fn settle(&mut self) -> Option<Duration> {
        let until = self.settle_until.take()?;
        Some(until.saturating_duration_since(Instant::now()))
    }
}

/// REP-155's body topics; see the module docs.
pub struct HriSinks {
    roi_kind: HriRoi,
    maker: TopicMaker,
    namespace: String,
    /// `<ns>/tracked`.
    pub tracked: Publishers<IdsList>,
    bodies: Vec<BodyTopics>,
    /// Bodies given topics so far.
    made: u64,
    /// Bodies refused topics of their own ([`MAX_BODIES_MADE`]).
    pub refused: u64,
    /// Sends of dropped bodies' topics that failed, and bodies whose topics could not be
    /// made.
    failed: u64,
}

impl HriSinks {
    /// The topics under `namespace`, made by `maker`, regions of `roi_kind`.
    pub fn new(
        namespace: String,
        maker: TopicMaker,
        roi_kind: HriRoi,
    ) -> Result<Self, ServiceError> {
        Ok(Self {
            roi_kind,
            tracked: maker.publishers(&format!("{namespace}/tracked"))?,
            maker,
            namespace,
            bodies: Vec::new(),
            made: 0,
            refused: 0,
            failed: 0,
        })
    }

    /// The topics of the body of `b`, to send its messages on (none without its messages
    /// or room for its topics); bodies not seen for [`RETIRE_AFTER`] lose theirs first.
    pub(super) fn body(&mut self, b: &BodyMessages) -> Option<&mut BodyTopics> {
        let id = b.track_id;
        let now = Instant::now();
        let failed = &mut self.failed;
        self.bodies.retain(|body| {
            let keep = now.duration_since(body.seen) < RETIRE_AFTER || body.track_id == id;
            if !keep {
                *failed += body.roi.failed() + body.skeleton2d.failed;
            }
            keep
        });
        b.messages.as_ref()?;
        let i = match self.bodies.iter().position(|body| body.track_id == id) {
            Some(i) => i,
            None => self.open(id)?,
        };
        let body = &mut self.bodies[i];
        body.seen = now;
        Some(body)
    }

    /// Makes body `id`'s topics (room made by the body seen least recently); its index.
    fn open(&mut self, id: u32) -> Option<usize> {
        if self.made >= MAX_BODIES_MADE {
            self.refused += 1;
            if self.refused == 1 {
                tracing::warn!(
                    "{MAX_BODIES_MADE} bodies had REP-155 topics of their own: later ones get \
                     none (counted; /tf and {}/tracked go on)",
                    self.namespace
                );
            }
            return None;
        }
        if self.bodies.len() >= MAX_BODY_TOPICS
            && let Some(oldest) = (0..self.bodies.len()).min_by_key(|&i| self.bodies[i].seen)
        {
            let gone = self.bodies.swap_remove(oldest);
            self.failed += gone.roi.failed() + gone.skeleton2d.failed;
        }
        self.made += 1;
        let base = format!("{}/{}", self.namespace, body_id(id));
        let (roi_topic, skeleton2d_topic) = (format!("{base}/roi"), format!("{base}/skeleton2d"));
        let roi = match self.roi_kind {
            HriRoi::Pixels => self.maker.publishers(&roi_topic).map(RoiTopic::Pixels),
            HriRoi::Normalized => self.maker.publishers(&roi_topic).map(RoiTopic::Normalized),
        };
        let made = roi.and_then(|roi| Ok((roi, self.maker.publishers(&skeleton2d_topic)?)));
        // Subscribers discovery knows already (a consumer that expected this body).
        // A new body's first messages wait for its new publishers to match them
        // (matching runs in the background).
        let settle = self.maker.ros.as_ref().and_then(|ros| {
            (ros.subscriptions(&roi_topic) + ros.subscriptions(&skeleton2d_topic) > 0)
                .then(|| ros.match_settle())
        });
        match made {
            Ok((roi, skeleton2d)) => {
                self.bodies.push(BodyTopics {
                    track_id: id,
                    roi,
                    skeleton2d,
                    seen: Instant::now(),
                    settle_until: settle.map(|d| Instant::now() + d),
                });
                Some(self.bodies.len() - 1)
            }
            Err(e) => {
                self.failed += 1;
                if self.failed == 1 {
                    tracing::warn!(
                        "no REP-155 topics for body {}: {e} (further failures are counted)",
                        body_id(id)
                    );
                }
                None
            }
        }
    }

    /// Flushes every topic.
    pub fn flush(&mut self) {
        self.tracked.flush();
        for b in &mut self.bodies {
            b.roi.flush();
            b.skeleton2d.flush();
        }
    }

    /// Sends that failed.
    pub fn failed(&self) -> u64 {
        self.failed
            + self.tracked.failed
            + self
                .bodies
                .iter()
                .map(|b| b.roi.failed() + b.skeleton2d.failed)
                .sum::<u64>()
    }
}
