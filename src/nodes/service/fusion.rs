//! The fusion node's loop (`posestream fuse`): every camera's heat maps and calibration,
//! and the transforms, in; fused skeletons, their markers, body frames on `/tf` and
//! REP-155's tracked ids out ([`crate::nodes::fusion`] does the work).
//!
//! Live (ROS 2), the loop takes what waits on each input in turn, its clock the time
//! since it started; with nothing waiting it sleeps [`IDLE`] and lets the fused frames
//! that are due go. From a recording, every topic's messages are taken in log-time
//! order, the log time the clock.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crate::msgs::sensor::CameraInfo;
use crate::msgs::tf::{TFMessage, TfTopic};
use crate::msgs::{Header, HeatMaps, Skeleton3D, Skeleton3DArray};
use crate::nodes::config::{ExtrinsicsSource, FusionConfig, ServiceConfig};
use crate::nodes::errors::Refusals;
use crate::nodes::errors::ServiceError;
use crate::nodes::fusion::{CameraReport, FusionCounters, FusionNode};
use crate::nodes::latency::{LatencyHistogram, LatencySummary};
use crate::nodes::markers::skeleton_markers;
use crate::nodes::middleware::Middleware;
use crate::nodes::publish::configured::{configured_bodies, publishers};
use crate::nodes::publish::taps::Taps;
use crate::nodes::publish::{BodyPlanner, Plan, Publication, Publishers, Sinks};
use crate::transport::mcap::McapSource;
use crate::transport::{Received, Source, TransportError};

/// How long the live loop sleeps when no input has anything.
pub const IDLE: Duration = Duration::from_millis(2);

/// Messages taken from one input in a turn, at most (a flooding peer delays the others
/// by this many, not without bound).
const PER_TURN: usize = 16;

/// One input's message.
enum Item {
    Maps(usize, HeatMaps),
    Info(usize, CameraInfo),
    Transforms(TFMessage, TfTopic),
}

/// One input of the node.
enum Feed {
    Maps(usize, Box<dyn Source<HeatMaps>>),
    Info(usize, Box<dyn Source<CameraInfo>>),
    Transforms(TfTopic, Box<dyn Source<TFMessage>>),
}

impl Feed {
    fn recv(&mut self) -> Result<Received<Item>, TransportError> {
        fn map<M>(r: Received<M>, f: impl FnOnce(M) -> Item) -> Received<Item> {
            match r {
                Received::Message(m, t) => Received::Message(f(m), t),
                Received::Idle => Received::Idle,
                Received::Closed => Received::Closed,
            }
        }
        Ok(match self {
            Feed::Maps(c, s) => {
                let c = *c;
                map(s.recv(Duration::ZERO)?, |m| Item::Maps(c, m))
            }
            Feed::Info(c, s) => {
                let c = *c;
                map(s.recv(Duration::ZERO)?, |m| Item::Info(c, m))
            }
            Feed::Transforms(topic, s) => {
                let topic = *topic;
                map(s.recv(Duration::ZERO)?, |m| Item::Transforms(m, topic))
            }
        })
    }

    fn what(&self) -> &'static str {
        match self {
            Feed::Maps(..) => "heat maps",
            Feed::Info(..) => "camera info",
            Feed::Transforms(..) => "transforms",
        }
    }
}

/// The fusion node's inputs.
pub struct FusionInput {
    feeds: Vec<Feed>,
    /// Whether each feed has given a message.
    yielded: Vec<bool>,
    /// The next message of each feed (a recording's, merged by log time).
    heads: Vec<Option<(Item, u64)>>,
    /// Whether it is a recording (log-time order, the log time the clock).
    recorded: bool,
    /// Why an input stopped early, if one did.
    error: Option<String>,
}

impl FusionInput {
    /// Each camera's heat maps and calibration, and the transforms, live over ROS 2.
    pub fn ros2(config: &ServiceConfig, middleware: &mut Middleware) -> Result<Self, ServiceError> {
        let ros = middleware.ros()?;
        let mut feeds = Vec::new();
        for (c, name) in config.fusion.cameras.iter().enumerate() {
            let (maps, info) = FusionConfig::camera_topics(name, &config.topics);
            feeds.push(Feed::Maps(c, Box::new(ros.source::<HeatMaps>(&maps)?)));
            feeds.push(Feed::Info(c, Box::new(ros.source::<CameraInfo>(&info)?)));
        }
        if config.fusion.extrinsics == ExtrinsicsSource::Tf {
            use crate::transport::ros2::QosSettings;
            feeds.push(Feed::Transforms(
                TfTopic::Static,
                Box::new(ros.source_with::<TFMessage>(
                    &config.topics.tf_static,
                    &QosSettings::tf_static_listener(),
                )?),
            ));
            feeds.push(Feed::Transforms(
                TfTopic::Dynamic,
                Box::new(
                    ros.source_with::<TFMessage>(&config.topics.tf, &QosSettings::tf_listener())?,
                ),
            ));
        }
        Ok(Self::of(feeds, false))
    }

    /// The same topics from a recording, in log-time order.
    pub fn recording(config: &ServiceConfig, path: &Path) -> Result<Self, ServiceError> {
        let limit = config.limits.max_record_bytes;
        fn open<M: crate::transport::Message>(
            config: &ServiceConfig,
            path: &Path,
            topic: &str,
            limit: usize,
        ) -> Result<McapSource<M>, TransportError> {
            config
                .replay
                .source(McapSource::open_with_limit(path, topic, limit)?)
        }
        // Transforms and calibrations first: at one log time they go before the heat
        // maps.
        let mut feeds = Vec::new();
        if config.fusion.extrinsics == ExtrinsicsSource::Tf {
            for (kind, topic) in [
                (TfTopic::Static, &config.topics.tf_static),
                (TfTopic::Dynamic, &config.topics.tf),
            ] {
                feeds.push(Feed::Transforms(
                    kind,
                    Box::new(open(config, path, topic, limit)?),
                ));
            }
        }
        for (c, name) in config.fusion.cameras.iter().enumerate() {
            let (_, info) = FusionConfig::camera_topics(name, &config.topics);
            feeds.push(Feed::Info(c, Box::new(open(config, path, &info, limit)?)));
        }
        for (c, name) in config.fusion.cameras.iter().enumerate() {
            let (maps, _) = FusionConfig::camera_topics(name, &config.topics);
            feeds.push(Feed::Maps(c, Box::new(open(config, path, &maps, limit)?)));
        }
        Ok(Self::of(feeds, true))
    }

    fn of(feeds: Vec<Feed>, recorded: bool) -> Self {
        let heads = feeds.iter().map(|_| None).collect();
        Self {
            yielded: vec![false; feeds.len()],
            feeds,
            heads,
            recorded,
            error: None,
        }
    }

    /// The next message of feed `i`: `None` when it has none now (or no more: then it
    /// is dropped). A malformed message is refused and counted by `node`.
    fn poll(&mut self, i: usize, node: &mut FusionNode) -> Option<(Item, u64)> {
        // A flood of malformed messages on one input: at most a turn's worth here.
        for _ in 0..PER_TURN {
            match self.feeds[i].recv() {
                Ok(Received::Message(m, t)) => {
                    self.yielded[i] = true;
                    return Some((m, t));
                }
                Ok(Received::Idle) => return None,
                Ok(Received::Closed) => {
                    self.feeds[i] = Feed::Transforms(TfTopic::Dynamic, Box::new(Closed));
                    return None;
                }
                Err(
                    e @ (TransportError::Malformed { .. } | TransportError::BeyondLimits { .. }),
                ) => node.count_refused(&e),
                // A recording without a topic (no /tf, calibration in the configuration).
                Err(e @ TransportError::Broken { .. }) if self.recorded && !self.yielded[i] => {
                    match &self.feeds[i] {
                        // A camera without heat maps fuses nothing: said.
                        Feed::Maps(..) => tracing::warn!("heat maps: {e}"),
                        other => tracing::info!("{}: {e}", other.what()),
                    }
                    self.feeds[i] = Feed::Transforms(TfTopic::Dynamic, Box::new(Closed));
                    return None;
                }
                Err(e) => {
                    let what = self.feeds[i].what();
                    tracing::warn!("{what}: {e}; no more is read from it");
                    self.error.get_or_insert_with(|| format!("{what}: {e}"));
                    self.feeds[i] = Feed::Transforms(TfTopic::Dynamic, Box::new(Closed));
                    return None;
                }
            }
        }
        None
    }

    /// A recording's next message in log-time order; `None` at its end.
    fn next_recorded(&mut self, node: &mut FusionNode) -> Option<(Item, u64)> {
        for i in 0..self.feeds.len() {
            if self.heads[i].is_none() {
                self.heads[i] = self.poll(i, node);
            }
        }
        let first = (0..self.heads.len())
            .filter(|&i| self.heads[i].is_some())
            .min_by_key(|&i| self.heads[i].as_ref().map_or(u64::MAX, |h| h.1))?;
        self.heads[first].take()
    }
}

/// A feed that has ended.
struct Closed;

impl Source<TFMessage> for Closed {
    fn recv(&mut self, _: Duration) -> Result<Received<TFMessage>, TransportError> {
        Ok(Received::Closed)
    }
}

/// Where the fusion node's results go: the plan of each step (skeletons, markers, what
/// they say of bodies, REP-155's ids per fused frame) and its sinks.
pub struct FusionOutputs {
    sinks: Sinks,
    bodies: BodyPlanner,
    bones: Vec<(usize, usize)>,
    markers: bool,
    /// The plan in hand (reused).
    plan: Plan,
    /// Each fused frame's newest skeletons, for REP-155's tracked ids (reused).
    frame: Skeleton3DArray,
    /// The skeletons of this lag, kept for the caller ([`FusionOutputs::keeping`]).
    keep: Option<(u32, Vec<Skeleton3D>)>,
}

impl FusionOutputs {
    /// The configured outputs (`[outputs]`: skeletons, markers, body frames on `/tf`,
    /// REP-155's tracked ids) of `node`'s skeletons.
    pub fn open(
        config: &ServiceConfig,
        middleware: &mut Middleware,
        taps: &Taps,
        node: &FusionNode,
    ) -> Result<Self, ServiceError> {
        let skeletons = publishers(config, middleware, taps, &config.topics.skeletons, None)?;
        let markers = if config.outputs.markers {
            publishers(config, middleware, taps, &config.topics.markers, None)?
        } else {
            Publishers::default()
        };
        // The newest estimates: the least delay, as TF and REP-155's readers want.
        let bodies = configured_bodies(config, middleware, taps, node.joint_names(), 0)?;
        Ok(Self {
            markers: !markers.is_empty(),
            sinks: Sinks {
                skeletons,
                markers,
                tf: bodies.tf,
                hri: bodies.hri,
                ..Sinks::default()
            },
            bodies: bodies.planner,
            bones: node.bones(),
            plan: Plan::default(),
            frame: Skeleton3DArray::default(),
            keep: None,
        })
    }

    /// The same outputs, also keeping every skeleton of `lag` (to score a recording's
    /// run against its truth; a live run would keep them without bound).
    pub fn keeping(mut self, lag: u32) -> Self {
        self.keep = Some((lag, Vec::new()));
        self
    }

    /// The skeletons kept ([`FusionOutputs::keeping`]).
    pub fn kept(&mut self) -> Vec<Skeleton3D> {
        self.keep
            .as_mut()
            .map(|k| std::mem::take(&mut k.1))
            .unwrap_or_default()
    }

    /// Publishes `skeletons` (one fused frame's, or more), each stamped with its frame's
    /// time, and hands the vector back empty.
    fn publish(&mut self, skeletons: &mut Vec<Skeleton3D>) {
        let plan = &mut self.plan;
        for (i, s) in skeletons.iter().enumerate() {
            let stamp = u64::try_from(s.header.stamp.nanos()).unwrap_or(0);
            plan.order.push((Publication::Skeleton(i), stamp));
            if self.markers {
                let (k, markers) = plan.markers.add();
                *markers = skeleton_markers(s, &self.bones);
                plan.order.push((Publication::Markers(k), stamp));
            }
            if !self.bodies.is_empty() {
                self.bodies.plan(s, None, stamp, plan);
            }
            if let Some((lag, kept)) = &mut self.keep
                && s.lag == *lag
            {
                kept.push(s.clone());
            }
            if s.lag == 0 {
                if self.frame.sequence != s.sequence || self.frame.skeletons.is_empty() {
                    Self::plan_frame(&self.bodies, &mut self.frame, plan);
                    self.frame.header = Header {
                        stamp: s.header.stamp.clone(),
                        frame_id: s.header.frame_id.clone(),
                    };
                    self.frame.sequence = s.sequence;
                }
                self.frame.skeletons.push(s.clone());
            }
        }
        // The node hands over whole fused frames: the last one's ids go now.
        Self::plan_frame(&self.bodies, &mut self.frame, plan);
        plan.add_skeletons(skeletons);
        skeletons.clear();
        self.sinks.send(plan);
        plan.clear();
    }

    /// REP-155's tracked ids of the fused frame in hand.
    fn plan_frame(bodies: &BodyPlanner, frame: &mut Skeleton3DArray, plan: &mut Plan) {
        if !frame.skeletons.is_empty() {
            let stamp = u64::try_from(frame.header.stamp.nanos()).unwrap_or(0);
            if let Some(ids) = bodies.tracked(frame) {
                let (k, slot) = plan.tracked.add();
                *slot = ids;
                plan.order.push((Publication::Tracked(k), stamp));
            }
            frame.skeletons.clear();
        }
    }

    fn flush(&mut self) {
        Self::plan_frame(&self.bodies, &mut self.frame, &mut self.plan);
        self.sinks.send(&self.plan);
        self.plan.clear();
        self.sinks.flush();
    }

    fn failed(&self) -> u64 {
        self.sinks.failed()
    }
}

/// What the fusion node did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FusionReport {
    /// Heat-map messages taken, fused frames, skeletons, people.
    pub counters: FusionCounters,
    /// Messages refused, by kind.
    pub refused: Refusals,
    /// Each camera.
    pub cameras: Vec<CameraReport>,
    /// Seconds the loop ran.
    pub seconds: f64,
    /// The node's time per message taken (its share of the fused frames' work included).
    pub update: LatencySummary,
    /// Sends that failed.
    pub failed_sends: u64,
    /// Why an input stopped early, if one did.
    pub input_error: Option<String>,
    /// The refined skeletons against a room's truth (`posestream fuse --truth`).
    pub truth: Option<crate::mocap::rooms::SkeletonScores>,
}

/// Runs `node` on `input` until it ends (a recording) or `stop` is set (Ctrl-C), its
/// skeletons to `outputs`.
pub fn run_fusion(
    node: &mut FusionNode,
    mut input: FusionInput,
    outputs: &mut FusionOutputs,
    stop: &AtomicBool,
) -> FusionReport {
    let start = Instant::now();
    let mut out = Vec::new();
    let mut update = LatencyHistogram::default();
    let live_now = || i64::try_from(start.elapsed().as_nanos()).unwrap_or(i64::MAX);
    let mut handle = |node: &mut FusionNode, item: Item, now: i64, out: &mut Vec<Skeleton3D>| {
        let t = Instant::now();
        match item {
            // Refusals are counted and logged by the node.
            Item::Maps(c, m) => {
                let _ = node.heat_maps(c, &m, now, out);
            }
            Item::Info(c, m) => node.camera_info(c, &m),
            Item::Transforms(m, topic) => node.transforms(&m, topic),
        }
        update.record(t.elapsed());
    };
    if input.recorded {
        while !stop.load(Ordering::Relaxed) {
            let Some((item, stamp)) = input.next_recorded(node) else {
                break;
            };
            let now = i64::try_from(stamp).unwrap_or(i64::MAX);
            handle(node, item, now, &mut out);
            outputs.publish(&mut out);
        }
    } else {
        while !stop.load(Ordering::Relaxed) {
            let mut heard = false;
            for i in 0..input.feeds.len() {
                for _ in 0..PER_TURN {
                    let Some((item, _)) = input.poll(i, node) else {
                        break;
                    };
                    heard = true;
                    handle(node, item, live_now(), &mut out);
                    outputs.publish(&mut out);
                }
            }
            // Fused frames due by now go, whatever came (calibrations and transforms
            // make none due).
            node.step(live_now(), &mut out);
            outputs.publish(&mut out);
            if !heard {
                std::thread::sleep(IDLE);
            }
        }
    }
    node.finish(&mut out);
    outputs.publish(&mut out);
    outputs.flush();
    FusionReport {
        counters: node.counters().clone(),
        refused: node.refused().clone(),
        cameras: node.cameras(),
        seconds: start.elapsed().as_secs_f64(),
        update: update.summary(),
        failed_sends: outputs.failed(),
        input_error: input.error,
        truth: None,
    }
}
