//! The estimator node's decision core, without I/O (as mcap's `LinearReader` is for its
//! blocking and tokio readers): a driver moves every input to it ([`Input`], or what a
//! source gave, [`EstimatorCore::received`]) with the time on its [`Clock`], and sends
//! the [`Plan`] it writes. Both drivers (`nodes::drivers`: blocking, tokio) behave alike
//! because the behaviour is here:
//!
//! - a heat-map frame goes through the node; the skeletons it releases are planned with
//!   the frame's image (the previous image's arrays go first);
//! - a quiet input (nothing for a while) completes the image in hand: its people
//!   without ids get theirs, its arrays go;
//! - a track is ended, its owed estimates published, once no frame was taken for the
//!   window's `max_gap_seconds` on the clock, at the first input that shows it: a quiet
//!   input or a refused message live (wall time), the next frame in a replay (the
//!   recorded stamps: a replay's result does not depend on how fast it runs);
//! - the camera's calibration and transforms are taken where they come, before the
//!   frames after them;
//! - a message the transport refused is counted by kind; an error that ends the source
//!   ends the loop ([`Flow::End`]), its reason kept for the report.

use std::time::{Duration, Instant};

use serde::Serialize;

use super::{EstimatorNode, FloorReport, MetricTiming};
use crate::msgs::sensor::CameraInfo;
use crate::msgs::tf::{TFMessage, TfTopic};
use crate::msgs::{HeatMapsView, Skeleton3D};
use crate::nodes::errors::Refusals;
use crate::nodes::latency::{LatencyHistogram, LatencySummary};
use crate::nodes::publish::{Plan, Planner, Sinks};
use crate::streaming::StreamCounters;
use crate::transport::{Lent, Received, TransportError};

/// What a driver moves to the core.
#[derive(Debug, Clone, Copy)]
pub enum Input<'a> {
    /// A heat-map frame, lent where it arrived, and its source's stamp (a recording's log
    /// time, else the sender's).
    Frame(&'a HeatMapsView<'a>, u64),
    /// The camera's calibration.
    Calibration(&'a CameraInfo),
    /// Transforms, and the topic they came on (`/tf_static`, `/tf`).
    Transforms(&'a TFMessage, TfTopic),
    /// A message the transport refused before it reached the node.
    Refused(&'a TransportError),
    /// Nothing arrived for a while.
    Quiet,
}

impl<'a> Input<'a> {
    /// What a source lent, with its stamp.
    pub fn lent(lent: Lent<'a>, stamp: u64) -> Self {
        match lent {
            Lent::Frame(frame) => Self::Frame(frame, stamp),
            Lent::Calibration(info) => Self::Calibration(info),
            Lent::Transforms(tf, topic) => Self::Transforms(tf, topic),
        }
    }
}

/// Whether a driver goes on reading after what its source gave.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flow {
    /// More may come.
    Continue,
    /// The source closed, or broke (the reason is in the report).
    End,
}

/// Where the core's time comes from (nanoseconds; only differences count).
#[derive(Debug, Clone, Copy)]
pub enum Clock {
    /// Wall time since the start: a live source's pauses are the camera's.
    Wall(Instant),
    /// The newest frame's stamp: a replayed recording's time is in its stamps.
    Stamps(u64),
}

impl Clock {
    /// The clock of a source that is live (wall time) or replayed (its stamps).
    pub fn of(live: bool) -> Self {
        if live {
            Self::Wall(Instant::now())
        } else {
            Self::Stamps(0)
        }
    }

    /// The time of `input`, nanoseconds.
    pub fn now(&mut self, input: &Input<'_>) -> u64 {
        match self {
            Self::Wall(start) => u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX),
            Self::Stamps(newest) => {
                if let Input::Frame(_, stamp) = input {
                    *newest = (*newest).max(*stamp);
                }
                *newest
            }
        }
    }
}

/// What the estimator service did.
#[derive(Debug, Clone, Serialize)]
pub struct EstimatorReport {
    /// Heat-map messages received.
    pub frames: u64,
    /// Messages refused (undecodable, inconsistent, beyond the limits, unknown joints).
    pub malformed: u64,
    /// The refusals by kind.
    pub refused: Refusals,
    /// Skeleton messages published.
    pub skeletons: u64,
    /// Sends that failed.
    pub failed_sends: u64,
    /// The window's counters.
    pub counters: StreamCounters,
    /// Estimates the metric step failed on (published in dictionary units).
    pub metric_failures: u64,
    /// What the metric step cost.
    pub metric: MetricTiming,
    /// Time per heat-map message in the estimator node.
    pub update: LatencySummary,
    /// Why the input ended early, if it did.
    pub input_error: Option<String>,
    /// Tracks the node made for people whose heat maps came without an id.
    pub unknown_id_tracks: u64,
    /// Where learning the floor stood at the end (`[estimator.metric.floor] source =
    /// "learnt"`).
    pub learnt_floor: Option<FloorReport>,
    /// With the floor from TF: frames the transform buffer dropped to make room.
    pub tf_evicted: u64,
}

/// The estimator node's decision core; see the module docs.
pub struct EstimatorCore<'a> {
    node: &'a mut EstimatorNode,
    planner: &'a mut Planner,
    /// A track with no frame taken for this long (on the clock) ends.
    idle_after_ns: u64,
    /// When a frame was last taken; `None` while no track is open.
    last_taken: Option<u64>,
    /// The capture time of the newest image handled (the learnt floor's stamp).
    newest_capture_ns: Option<i64>,
    /// The skeletons the node released (moved into the plan).
    out: Vec<Skeleton3D>,
    frames: u64,
    latency: LatencyHistogram,
    input_error: Option<String>,
}

impl<'a> EstimatorCore<'a> {
    /// The core of `node`, planning with `planner`.
    pub fn new(node: &'a mut EstimatorNode, planner: &'a mut Planner) -> Self {
        let gap = Duration::from_secs_f64(node.settings().max_gap_seconds);
        Self {
            node,
            planner,
            idle_after_ns: u64::try_from(gap.as_nanos()).unwrap_or(u64::MAX),
            last_taken: None,
            newest_capture_ns: None,
            out: Vec::new(),
            frames: 0,
            latency: LatencyHistogram::default(),
            input_error: None,
        }
    }

    /// Takes one input at `now_ns` on the driver's clock; what to publish goes to `plan`.
    pub fn step(&mut self, input: Input<'_>, now_ns: u64, plan: &mut Plan) {
        match input {
            Input::Frame(frame, stamp) => {
                self.frames += 1;
                self.planner.frame_stamp(stamp);
                // A frame after the gap (a replay's stamps jump over a quiet spell) ends
                // the tracks first, as the quiet spell did live.
                self.end_idle(now_ns, plan);
                let taken = self.node.frames_accepted();
                let began = Instant::now();
                // A refused message is counted and logged by the node.
                let _ = self.node.handle_view(frame, &mut self.out);
                self.latency.record(began.elapsed());
                self.plan(Some((frame.stamp_ns, frame.sequence)), plan);
                // Only frames the window took keep a track alive: a stream of refused
                // frames does not hold an idle track open.
                if self.node.frames_accepted() > taken {
                    self.last_taken = Some(now_ns);
                }
                self.end_idle(now_ns, plan);
            }
            Input::Calibration(info) => {
                // Counted and logged by the node if refused.
                let _ = self.node.camera_info(info);
            }
            Input::Transforms(tf, topic) => self.node.transforms(tf, topic),
            Input::Refused(error) => {
                self.node.count_refused(error);
                // A stream of refused messages holds no idle track open.
                self.end_idle(now_ns, plan);
            }
            Input::Quiet => {
                // The image handled last is complete (its people without ids are given
                // theirs and estimated).
                self.node.complete_image(&mut self.out);
                if !self.out.is_empty() {
                    self.plan(None, plan);
                }
                self.planner.flush_arrays(plan);
                self.end_idle(now_ns, plan);
            }
        }
    }

    /// What a source gave (a message already lent to [`EstimatorCore::step`]): nothing
    /// for a while is [`Input::Quiet`], a refused message is counted, and a closed or
    /// broken source ends the loop.
    pub fn received(
        &mut self,
        got: Result<Received<()>, TransportError>,
        now_ns: u64,
        plan: &mut Plan,
    ) -> Flow {
        match got {
            Ok(Received::Message((), _)) => Flow::Continue,
            Ok(Received::Idle) => {
                self.step(Input::Quiet, now_ns, plan);
                Flow::Continue
            }
            Ok(Received::Closed) => Flow::End,
            Err(e) if e.refusal().is_some() => {
                self.step(Input::Refused(&e), now_ns, plan);
                Flow::Continue
            }
            Err(e) => {
                // Reported by the caller, from the report.
                self.input_error = Some(e.to_string());
                Flow::End
            }
        }
    }

    /// The end of the stream: every track ends with the estimates still owed.
    pub fn close(&mut self, plan: &mut Plan) {
        self.node.finish(&mut self.out);
        self.planner.flush_arrays(plan);
        self.plan(None, plan);
    }

    /// Takes back a plan that was sent: its skeletons and arrays are written over next.
    pub fn recycle(&mut self, plan: &mut Plan) {
        self.planner.recycle(&mut plan.arrays);
        plan.clear();
    }

    /// What the node did, its skeletons sent to `sinks`.
    pub fn report(&self, sinks: &Sinks) -> EstimatorReport {
        let node = &*self.node;
        EstimatorReport {
            frames: self.frames,
            malformed: node.malformed(),
            refused: node.refused().clone(),
            skeletons: sinks.skeletons.sent,
            failed_sends: sinks.failed(),
            counters: node.counters(),
            metric_failures: node.metric_failures(),
            metric: node.metric_timing(),
            update: self.latency.summary(),
            input_error: self.input_error.clone(),
            unknown_id_tracks: node.tracks_from_unknown_ids(),
            learnt_floor: node.learnt_floor(),
            tf_evicted: node.tf_evicted(),
        }
    }

    /// Plans the skeletons released by a message of `image` (`None`: by none).
    fn plan(&mut self, image: Option<(i64, u64)>, plan: &mut Plan) {
        let (size, floor) = (self.node.image_size(), self.node.floor());
        self.planner
            .skeletons(image, &mut self.out, size, floor, plan);
        if let Some((capture_ns, _)) = image {
            self.newest_capture_ns = Some(capture_ns);
        }
        // A floor trusted by estimates released without an image (a quiet input, the
        // end) goes out too, stamped with the newest image.
        if let Some(capture_ns) = self.newest_capture_ns {
            self.planner
                .learnt_floor(self.node.learnt_floor_fit(), capture_ns, plan);
        }
        // What the plan's skeletons held before, to be written over by the node.
        self.node.recycle(&mut self.out);
    }

    /// Ends the tracks when no frame was taken for the window's gap.
    fn end_idle(&mut self, now_ns: u64, plan: &mut Plan) {
        if self
            .last_taken
            .is_some_and(|t| now_ns.saturating_sub(t) > self.idle_after_ns)
        {
            self.node.finish(&mut self.out);
            self.plan(None, plan);
            self.last_taken = None;
        }
    }
}

#[cfg(test)]
mod tests;
