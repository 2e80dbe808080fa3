//! The wiring of a service process from its configuration: the middleware it needs
//! ([`Middleware`]), the output recording, the publishers of each node's results, the
//! detector's input, and how the outputs are finished when the loop ends ([`Wiring`]).
//! `run_pipeline` and the `detector` and `estimator` commands all wire themselves
//! through [`Wiring`].

use std::path::Path;
use std::time::Duration;

use super::ServiceError;
pub use super::bodies::{Bodies, TopicMaker};
use super::side_inputs::SideInputs;
use crate::detector::{DetectorStats, ImageDetector};
use crate::floor::{FloorModel, FloorSource};
use crate::msgs::sensor::CameraInfo;
use crate::msgs::tf::TFMessage;
use crate::msgs::visualization::ImageMarker;
use crate::msgs::{HeatMaps, MarkerArray, Skeleton3D, Skeleton3DArray, SkeletonState};
use crate::nodes::EstimatorNode;
use crate::nodes::SetupError;
use crate::nodes::arrays::ImageArrays;
use crate::nodes::camera::CameraTap;
use crate::nodes::config::{DetectorSource, ReplayRate, ServiceConfig, Transport};
use crate::nodes::frames::is_body_transform;
use crate::nodes::images::{ImageHeatMaps, SharedStats, image_frames};
use crate::nodes::latency::FrameClock;
use crate::nodes::markers::{image_markers, skeleton_markers};
use crate::nodes::shown_images::shown_images_topic;
use crate::recording::RecordingSummary;
use crate::transport::foxglove::LiveView;
use crate::transport::mcap::{McapSource, SharedRecorder};
use crate::transport::ros2::{QosSettings, Ros2, Ros2Sink, Ros2Source};
use crate::transport::shm::Shm;
use crate::transport::{FrameSource, Message, Received, Sink, Source, TransportError};

/// The middleware of a process: a ROS 2 node and an iceoryx2 node, each only if used.
#[derive(Default)]
pub struct Middleware {
    /// The ROS 2 participant and node.
    pub ros: Option<Ros2>,
    /// The iceoryx2 node.
    pub shm: Option<Shm>,
}

impl Middleware {
    /// Opens what `config` (plus `extra`, a transport a node reads from) needs.
    pub fn open(config: &ServiceConfig, extra: Option<Transport>) -> Result<Self, ServiceError> {
        let ros = config.outputs.ros2 || extra == Some(Transport::Ros2);
        let shm = config.outputs.iceoryx2 || extra == Some(Transport::Iceoryx2);
        Ok(Self {
            ros: ros.then(|| Ros2::new(&config.ros)).transpose()?,
            shm: shm.then(Shm::new).transpose()?,
        })
    }

    pub(crate) fn ros(&mut self) -> Result<&mut Ros2, TransportError> {
        self.ros.as_mut().ok_or_else(|| missing("ros2"))
    }

    fn shm(&self) -> Result<&Shm, TransportError> {
        self.shm.as_ref().ok_or_else(|| missing("iceoryx2"))
    }

    /// The estimator's heat maps from `transport`: a ROS 2 subscription awaited on a
    /// runtime; iceoryx2 samples lent where they are, their scores read in shared
    /// memory by a blocking loop (docs/services.md, "Where the I/O runs").
    pub fn estimator_input(
        &mut self,
        config: &ServiceConfig,
        transport: Transport,
    ) -> Result<EstimatorInput, TransportError> {
        Ok(match transport {
            Transport::Ros2 => {
                let ros = self.ros()?;
                let heatmaps = Box::new(ros.source::<HeatMaps>(&config.topics.heatmaps)?);
                let camera: Box<dyn Source<CameraInfo>> =
                    Box::new(ros.source::<CameraInfo>(&config.topics.camera_info)?);
                EstimatorInput::Awaited {
                    heatmaps,
                    side: SideInputs::camera(Some(camera)),
                }
            }
            Transport::Iceoryx2 => EstimatorInput::Lent(
                Box::new(
                    self.shm()?
                        .heatmaps_source(&config.iceoryx2.heatmaps, &config.limits)?,
                ),
                SideInputs::default(),
            ),
        })
    }

    /// With the floor from TF (`[estimator.metric.floor] source = "tf"`), subscriptions
    /// to `topics.tf_static` (latched: reliable, transient local, as tf2's static
    /// listener asks, so that transforms published before this node started arrive)
    /// and `topics.tf` (reliable, volatile). They need ROS 2: without it (an estimator
    /// reading iceoryx2 that publishes nothing on ROS 2) a warning says the floor waits
    /// for nothing, and none is opened. Empty for the other floor sources.
    pub fn transform_sources(
        &mut self,
        config: &ServiceConfig,
    ) -> Result<Vec<Box<dyn Source<TFMessage>>>, TransportError> {
        if config.estimator.metric.floor.source != FloorSource::Tf {
            return Ok(Vec::new());
        }
        let Some(ros) = self.ros.as_mut() else {
            tracing::warn!(
                "[estimator.metric.floor] source = \"tf\" reads {} and {} over ROS 2, which \
                 this node does not use (iceoryx2 in, no ROS 2 out): no floor; set \
                 [outputs] ros2 = true, or the floor in the configuration (source = \"config\")",
                config.topics.tf_static,
                config.topics.tf
            );
            return Ok(Vec::new());
        };
        Ok(vec![
            Box::new(ros.source_with::<TFMessage>(
                &config.topics.tf_static,
                &QosSettings::tf_static_listener(),
            )?),
            Box::new(ros.source_with::<TFMessage>(&config.topics.tf, &QosSettings::tf_listener())?),
        ])
    }
}

/// Where the estimator node's heat maps come from, and so how its loop waits
/// ([`serve_estimator`](super::serve_estimator)).
pub enum EstimatorInput {
    /// Messages awaited on a tokio runtime ([`run_estimator_on_runtime`](super::run_estimator_on_runtime)),
    /// and what is read beside them.
    Awaited {
        /// The heat maps.
        heatmaps: Box<Ros2Source<HeatMaps>>,
        /// The camera's calibration (`topics.camera_info`) and transforms.
        side: SideInputs,
    },
    /// Frames lent by a blocking source ([`run_estimator`](super::run_estimator)), and
    /// what is read beside them.
    Lent(Box<dyn FrameSource>, SideInputs),
}

fn missing(transport: &'static str) -> TransportError {
    TransportError::Setup {
        transport,
        what: "the node".into(),
        reason: "not opened (enable it in [outputs] or as the input)".into(),
    }
}

/// Publishers of one message type on every configured output. A failed send is counted;
/// the first failure of each sink is logged (a full disk under a recording fails every
/// later write too), and the other sinks go on.
pub struct Publishers<M: Message> {
    /// Each sink with its name and whether a failure of it was logged.
    sinks: Vec<(String, Output<M>, bool)>,
    /// Messages handed to every sink.
    pub sent: u64,
    /// Sends that failed (per sink).
    pub failed: u64,
}

/// One sink of [`Publishers`]: ROS 2 apart, for its async publishing.
enum Output<M: Message> {
    Ros2(Box<Ros2Sink<M>>),
    Other(Box<dyn Sink<M>>),
}

impl<M: Message> Output<M> {
    fn sink(&mut self) -> &mut dyn Sink<M> {
        match self {
            Output::Ros2(s) => s.as_mut(),
            Output::Other(s) => s.as_mut(),
        }
    }
}

impl<M: Message> Default for Publishers<M> {
    fn default() -> Self {
        Self {
            sinks: Vec::new(),
            sent: 0,
            failed: 0,
        }
    }
}

impl<M: Message> Publishers<M> {
    /// Adds a sink, named for the logs.
    pub fn add(&mut self, name: impl Into<String>, sink: Box<dyn Sink<M>>) {
        self.sinks.push((name.into(), Output::Other(sink), false));
    }

    /// Adds a ROS 2 publisher, named for the logs ([`Publishers::publish_async`] awaits
    /// room in its history instead of blocking).
    pub fn add_ros2(&mut self, name: impl Into<String>, sink: Ros2Sink<M>) {
        self.sinks
            .push((name.into(), Output::Ros2(Box::new(sink)), false));
    }

    /// Sinks configured.
    pub fn len(&self) -> usize {
        self.sinks.len()
    }

    /// True without sinks.
    pub fn is_empty(&self) -> bool {
        self.sinks.is_empty()
    }

    /// Sends to every sink.
    pub fn publish(&mut self, message: &M, stamp_ns: u64) {
        self.sent += 1;
        for (name, sink, logged) in &mut self.sinks {
            if let Err(e) = sink.sink().send(message, stamp_ns) {
                self.failed += 1;
                Self::failure(name, logged, &e);
            }
        }
    }

    /// Sends to every sink on a runtime: as [`Publishers::publish`], a ROS 2 publisher
    /// awaited instead of blocking while its reliable history is full.
    pub async fn publish_async(&mut self, message: &M, stamp_ns: u64) {
        self.sent += 1;
        for (name, sink, logged) in &mut self.sinks {
            let sent = match sink {
                Output::Ros2(s) => s.send_async(message).await,
                Output::Other(s) => s.send(message, stamp_ns),
            };
            if let Err(e) = sent {
                self.failed += 1;
                Self::failure(name, logged, &e);
            }
        }
    }

    /// Sends to every sink, the message given up to the last one (added last: the
    /// in-memory channel moves it instead of copying it).
    pub fn publish_owned(&mut self, message: M, stamp_ns: u64) {
        self.sent += 1;
        let Some(((last_name, last, last_logged), others)) = self.sinks.split_last_mut() else {
            return;
        };
        for (name, sink, logged) in others {
            if let Err(e) = sink.sink().send(&message, stamp_ns) {
                self.failed += 1;
                Self::failure(name, logged, &e);
            }
        }
        if let Err(e) = last.sink().send_owned(message, stamp_ns) {
            self.failed += 1;
            Self::failure(last_name, last_logged, &e);
        }
    }

    /// Flushes every sink.
    pub fn flush(&mut self) {
        for (name, sink, logged) in &mut self.sinks {
            if let Err(e) = sink.sink().flush() {
                self.failed += 1;
                Self::failure(name, logged, &e);
            }
        }
    }

    fn failure(name: &str, logged: &mut bool, e: &TransportError) {
        // A sink closed by an earlier failure (reported then) is only counted.
        if !*logged && !matches!(e, TransportError::Closed { .. }) {
            *logged = true;
            tracing::warn!("{name}: {e} (further failures of this output are counted, not logged)");
        } else {
            tracing::debug!("{name}: {e}");
        }
    }
}

/// The recording of `[outputs] record`, if configured (refused if it is one of the
/// detector's inputs).
pub fn output_recording(config: &ServiceConfig) -> Result<Option<SharedRecorder>, ServiceError> {
    let path = &config.outputs.record;
    if path.as_os_str().is_empty() {
        return Ok(None);
    }
    crate::files::check_output(
        path,
        &[&config.detector.recording, &config.detector.images.path],
    )?;
    Ok(Some(SharedRecorder::create(path)?))
}

/// What sees every message a process publishes, besides the middleware: the output
/// recording (`[outputs] record`) and the live view (`[outputs] foxglove`).
#[derive(Clone, Default)]
pub struct Taps {
    /// The output recording, once started.
    pub recorder: Option<SharedRecorder>,
    /// The Foxglove WebSocket server.
    pub live: Option<LiveView>,
}

impl Taps {
    /// Adds each tap's sink of `M` on `topic` to `out`.
    pub fn add_to<M: Message>(
        &self,
        out: &mut Publishers<M>,
        topic: &str,
    ) -> Result<(), TransportError> {
        if let Some(r) = &self.recorder {
            out.add(format!("mcap {topic}"), Box::new(r.sink::<M>(topic)));
        }
        if let Some(live) = &self.live {
            out.add(
                format!("foxglove {topic}"),
                Box::new(live.sink::<M>(topic)?),
            );
        }
        Ok(())
    }

    /// Each tap's sink of `M` on `topic`, as one.
    pub fn publishers<M: Message>(&self, topic: &str) -> Result<Publishers<M>, TransportError> {
        let mut out = Publishers::default();
        self.add_to(&mut out, topic)?;
        Ok(out)
    }

    /// Sends an encoded message of type `M` (CDR, as read from a recording) on `topic`
    /// to each tap, without decoding it; the first failure is returned, after every tap
    /// was tried.
    pub fn send_encoded<M: Message>(
        &self,
        topic: &str,
        stamp_ns: u64,
        data: &[u8],
    ) -> Result<(), TransportError> {
        let recorded = self
            .recorder
            .as_ref()
            .map_or(Ok(()), |r| r.write_encoded::<M>(topic, stamp_ns, data));
        let live = self
            .live
            .as_ref()
            .map_or(Ok(()), |l| l.send_encoded::<M>(topic, stamp_ns, data));
        recorded.and(live)
    }
}

/// The live view of `[outputs] foxglove`, if configured: serving from now on.
pub fn live_view(config: &ServiceConfig) -> Result<Option<LiveView>, TransportError> {
    let address = config.outputs.foxglove.trim();
    if address.is_empty() {
        return Ok(None);
    }
    let address =
        crate::nodes::config::socket_address(address).map_err(|reason| TransportError::Setup {
            transport: "foxglove",
            what: format!("a Foxglove WebSocket server on {address}"),
            reason,
        })?;
    let live = LiveView::serve(address)?;
    tracing::info!(
        target: "posestream::live",
        "Foxglove live view on ws://{} (Foxglove app: Open connection, Foxglove WebSocket; \
         layout: docs/foxglove-layout.json)",
        live.address()
    );
    Ok(Some(live))
}

/// The configured descriptions of bodies (`[outputs] tf`, `hri`) of skeletons of
/// `joint_names` at `lag`.
pub(super) fn configured_bodies(
    config: &ServiceConfig,
    middleware: &mut Middleware,
    taps: &Taps,
    joint_names: &[String],
    lag: u32,
) -> Result<Bodies, ServiceError> {
    let tf = if config.outputs.tf {
        publishers(config, middleware, taps, &config.topics.tf, None)?
    } else {
        Publishers::default()
    };
    let hri = config.outputs.hri.then(|| {
        let maker = TopicMaker {
            ros: middleware.ros.clone().filter(|_| config.outputs.ros2),
            taps: taps.clone(),
        };
        (
            config.topics.hri_bodies.clone(),
            maker,
            config.outputs.hri_roi,
        )
    });
    Bodies::new(joint_names, lag, tf, hri)
}

/// Publishers of `M` on `topic` / `service` for every configured output.
pub(super) fn publishers<M: Message>(
    config: &ServiceConfig,
    middleware: &mut Middleware,
    taps: &Taps,
    topic: &str,
    shm: Option<Result<Box<dyn Sink<M>>, TransportError>>,
) -> Result<Publishers<M>, ServiceError> {
    let mut out = Publishers::default();
    if config.outputs.ros2 {
        let ros = middleware.ros()?;
        out.add_ros2(format!("ros2 {topic}"), ros.sink::<M>(topic)?);
    }
    if let Some(sink) = shm {
        out.add(format!("iceoryx2 {topic}"), sink?);
    }
    taps.add_to(&mut out, topic)?;
    Ok(out)
}

/// Where the estimator's results go.
pub struct EstimatorOutputs {
    /// Skeletons.
    pub skeletons: Publishers<Skeleton3D>,
    /// Markers (empty when `[outputs] markers` is off).
    pub markers: Publishers<MarkerArray>,
    /// The skeletons of each image together (empty when `[outputs] arrays` is off).
    pub arrays: Publishers<Skeleton3DArray>,
    /// Each image's skeletons drawn over it (empty when `[outputs] markers` is off), of
    /// the arrays of lag `overlay_lag`; the message reused.
    pub image_markers: Publishers<ImageMarker>,
    overlay_lag: u32,
    overlay: ImageMarker,
    /// Frames on `/tf` and REP-155 body topics.
    pub bodies: Bodies,
    /// Groups the skeletons into arrays, when there are array publishers or REP-155's
    /// tracked ids are published.
    grouping: ImageArrays,
    /// Arrays ready to be sent (reused).
    ready: Vec<Skeleton3DArray>,
    /// Notes when each newest skeleton goes out (latency from its image).
    clock: Option<FrameClock>,
    bones: Vec<(usize, usize)>,
    /// Send each skeleton stamped with the time of the frame that released it (a
    /// replay's log time) instead of its own frame's stamp.
    stamp_at_release: bool,
    /// The stamp of the frame handled last, with `stamp_at_release`.
    released_at: u64,
}

impl EstimatorOutputs {
    /// Outputs to these publishers (skeletons of a dictionary whose bones are `bones`;
    /// no markers when `markers` is empty).
    pub fn new(
        skeletons: Publishers<Skeleton3D>,
        markers: Publishers<MarkerArray>,
        bones: Vec<(usize, usize)>,
    ) -> Self {
        Self {
            skeletons,
            markers,
            arrays: Publishers::default(),
            image_markers: Publishers::default(),
            overlay_lag: 0,
            overlay: ImageMarker::default(),
            bodies: Bodies::default(),
            grouping: ImageArrays::default(),
            ready: Vec::new(),
            clock: None,
            bones,
            stamp_at_release: false,
            released_at: 0,
        }
    }

    /// The same outputs, noting on `clock` when each newest (lag 0) skeleton went out.
    pub fn with_clock(mut self, clock: Option<FrameClock>) -> Self {
        self.clock = clock;
        self
    }

    /// The same outputs, also sending the skeletons of each image together to `arrays`
    /// ([`ImageArrays`]).
    pub fn with_arrays(mut self, arrays: Publishers<Skeleton3DArray>) -> Self {
        self.arrays = arrays;
        self
    }

    /// The same outputs, also drawing the skeletons of each image over it
    /// ([`image_markers`]), those of lag `lag` (the image's newest estimate, or the
    /// refined one when only those are published).
    pub fn with_image_markers(mut self, markers: Publishers<ImageMarker>, lag: u32) -> Self {
        self.image_markers = markers;
        self.overlay_lag = lag;
        self
    }

    /// The same outputs, also describing bodies ([`Bodies`]: frames, REP-155 topics).
    pub fn with_bodies(mut self, bodies: Bodies) -> Self {
        self.bodies = bodies;
        self
    }

    /// Whether skeletons are grouped by image (for arrays, or REP-155's tracked ids).
    fn grouped(&self) -> bool {
        !self.arrays.is_empty() || !self.image_markers.is_empty() || self.bodies.hri.is_some()
    }

    /// Flushes every output.
    pub fn flush(&mut self) {
        self.skeletons.flush();
        self.markers.flush();
        self.arrays.flush();
        self.image_markers.flush();
        self.bodies.flush();
    }

    /// Sends that failed, on every output.
    pub fn failed_sends(&self) -> u64 {
        self.skeletons.failed
            + self.markers.failed
            + self.arrays.failed
            + self.image_markers.failed
            + self.bodies.failed()
    }

    /// The same outputs, sending each skeleton stamped with the time of the frame that
    /// released it (its source's stamp: a recording's log time), as a recorder of the
    /// live topic would have logged it; the estimates still owed at the end, with the
    /// last frame's. Without it, each skeleton goes with its own frame's stamp.
    pub fn stamped_at_release(mut self) -> Self {
        self.stamp_at_release = true;
        self
    }

    /// The source's stamp of the frame being handled.
    pub(super) fn frame_stamp(&mut self, stamp_ns: u64) {
        self.released_at = stamp_ns;
    }

    /// The configured outputs of `node`'s skeletons.
    pub fn open(
        config: &ServiceConfig,
        middleware: &mut Middleware,
        taps: &Taps,
        node: &EstimatorNode,
    ) -> Result<Self, ServiceError> {
        let shm_sink = match (&middleware.shm, config.outputs.iceoryx2) {
            (Some(shm), true) => Some(
                shm.skeleton_sink(&config.iceoryx2.skeletons)
                    .map(|s| Box::new(s) as Box<dyn Sink<Skeleton3D>>),
            ),
            _ => None,
        };
        let skeletons = publishers(config, middleware, taps, &config.topics.skeletons, shm_sink)?;
        let (markers, overlay) = if config.outputs.markers {
            (
                publishers(config, middleware, taps, &config.topics.markers, None)?,
                publishers(config, middleware, taps, &config.topics.image_markers, None)?,
            )
        } else {
            (Publishers::default(), Publishers::default())
        };
        let arrays = if config.outputs.arrays {
            publishers(
                config,
                middleware,
                taps,
                &config.topics.skeleton_arrays,
                None,
            )?
        } else {
            Publishers::default()
        };
        // The newest estimates when the window publishes them, else the refined ones.
        let settings = node.settings();
        let lag = match settings.outputs {
            crate::streaming::Outputs::Lagged => settings.lag as u32,
            _ => 0,
        };
        let mut bodies = configured_bodies(config, middleware, taps, node.joint_names(), lag)?;
        let floor = &config.estimator.metric.floor;
        match floor.source {
            FloorSource::None => {}
            // The robot's floor frame: its tree holds it.
            FloorSource::Tf => bodies = bodies.with_floor(&floor.frame, false),
            FloorSource::Config | FloorSource::Learnt if !floor.published_frame.is_empty() => {
                bodies = bodies.with_floor(&floor.published_frame, true)
            }
            FloorSource::Config | FloorSource::Learnt => {}
        }
        Ok(Self::new(skeletons, markers, node.bones())
            .with_arrays(arrays)
            .with_image_markers(overlay, lag)
            .with_bodies(bodies))
    }

    /// Publishes the node's skeletons, released by a heat-map message of `image_ns` (its
    /// capture time and frame number; `None`: by none, as when a track ends at the end
    /// of the stream), and hands them back to it to be reused. The previous image's
    /// arrays go first when this is another image.
    pub(super) fn publish(
        &mut self,
        image_ns: Option<(i64, u64)>,
        skeletons: &mut Vec<Skeleton3D>,
        node: &mut EstimatorNode,
    ) {
        if self.grouped() && (image_ns.is_some() || !skeletons.is_empty()) {
            self.grouping.add(image_ns, skeletons, &mut self.ready);
            self.send_arrays();
        }
        let image_size = node.image_size();
        self.bodies.set_floor(node.floor());
        for s in skeletons.iter() {
            let stamp = self.stamp(s);
            self.skeletons.publish(s, stamp);
            // Its latency: the skeleton out, before what is drawn or derived from it.
            self.note_latency(s);
            if !self.markers.is_empty() {
                self.markers
                    .publish(&skeleton_markers(s, &self.bones), stamp);
            }
            if !self.bodies.is_empty() {
                self.bodies.publish(s, image_size, stamp);
            }
        }
        node.recycle(skeletons);
    }

    /// Sends the arrays of an image that may not be complete yet (the input went quiet,
    /// or ends).
    pub(super) fn flush_arrays(&mut self) {
        if self.grouping.is_pending() {
            self.grouping.flush(&mut self.ready);
            self.send_arrays();
        }
    }

    /// [`EstimatorOutputs::flush_arrays`] on a runtime.
    pub(super) async fn flush_arrays_async(&mut self) {
        if self.grouping.is_pending() {
            self.grouping.flush(&mut self.ready);
            self.send_arrays_async().await;
        }
    }

    fn send_arrays(&mut self) {
        for a in &self.ready {
            let stamp = self.array_stamp(a);
            if !self.arrays.is_empty() {
                self.arrays.publish(a, stamp);
            }
            if !self.image_markers.is_empty() && a.lag == self.overlay_lag {
                image_markers(a, &self.bones, &mut self.overlay);
                self.image_markers.publish(&self.overlay, stamp);
            }
            self.bodies.tracked(a, stamp);
        }
        self.grouping.recycle(&mut self.ready);
    }

    async fn send_arrays_async(&mut self) {
        let ready = std::mem::take(&mut self.ready);
        for a in &ready {
            let stamp = self.array_stamp(a);
            if !self.arrays.is_empty() {
                self.arrays.publish_async(a, stamp).await;
            }
            if !self.image_markers.is_empty() && a.lag == self.overlay_lag {
                image_markers(a, &self.bones, &mut self.overlay);
                self.image_markers.publish_async(&self.overlay, stamp).await;
            }
            self.bodies.tracked_async(a, stamp).await;
        }
        self.ready = ready;
        self.grouping.recycle(&mut self.ready);
    }

    /// The stamp an array is sent with (as its skeletons' are).
    fn array_stamp(&self, array: &Skeleton3DArray) -> u64 {
        if self.stamp_at_release {
            self.released_at
        } else {
            u64::try_from(array.header.stamp.nanos()).unwrap_or(0)
        }
    }

    /// Publishes skeletons on a runtime ([`Publishers::publish_async`]), as
    /// [`EstimatorOutputs::publish`] does (`image_size` and `floor`: the node's, when
    /// known).
    pub(super) async fn publish_async(
        &mut self,
        image_ns: Option<(i64, u64)>,
        skeletons: &[Skeleton3D],
        image_size: Option<(f64, f64)>,
        floor: Option<FloorModel>,
    ) {
        if self.grouped() && (image_ns.is_some() || !skeletons.is_empty()) {
            self.grouping.add(image_ns, skeletons, &mut self.ready);
            self.send_arrays_async().await;
        }
        self.bodies.set_floor(floor);
        for s in skeletons {
            let stamp = self.stamp(s);
            self.skeletons.publish_async(s, stamp).await;
            // Its latency: the skeleton out, before what is drawn or derived from it.
            self.note_latency(s);
            if !self.markers.is_empty() {
                let markers = skeleton_markers(s, &self.bones);
                self.markers.publish_async(&markers, stamp).await;
            }
            if !self.bodies.is_empty() {
                self.bodies.publish_async(s, image_size, stamp).await;
            }
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

    /// The stamp `skeleton` is sent with.
    fn stamp(&self, skeleton: &Skeleton3D) -> u64 {
        if self.stamp_at_release {
            self.released_at
        } else {
            u64::try_from(skeleton.header.stamp.nanos()).unwrap_or(0)
        }
    }
}

/// The detector's configured heat-map publishers (`[outputs]`).
pub fn detector_outputs(
    config: &ServiceConfig,
    middleware: &mut Middleware,
    taps: &Taps,
) -> Result<Publishers<HeatMaps>, ServiceError> {
    let shm_sink = match (&middleware.shm, config.outputs.iceoryx2) {
        (Some(shm), true) => Some(
            shm.heatmaps_sink(&config.iceoryx2.heatmaps)
                .map(|s| Box::new(s) as Box<dyn Sink<HeatMaps>>),
        ),
        _ => None,
    };
    publishers(config, middleware, taps, &config.topics.heatmaps, shm_sink)
}

/// The replay source of the detector: the heat maps of a recording, played
/// `detector.repeat` times.
pub fn recording_source(
    config: &ServiceConfig,
    path: &Path,
) -> Result<RecordedHeatMaps, TransportError> {
    Ok(RecordedHeatMaps(
        config
            .replay
            .source(McapSource::open_with_limit(
                path,
                &config.topics.heatmaps,
                config.limits.max_record_bytes,
            )?)?
            .repeat(config.detector.repeat),
    ))
}

/// The heat maps of a recording, each pass of a repeated one a track of its own (its
/// track ids offset by the pass), as a detector seeing the scene again would number it.
pub struct RecordedHeatMaps(McapSource<HeatMaps>);

impl Source<HeatMaps> for RecordedHeatMaps {
    fn recv(&mut self, timeout: Duration) -> Result<Received<HeatMaps>, TransportError> {
        Ok(match self.0.recv(timeout)? {
            Received::Message(mut m, stamp) => {
                m.track_id = m.track_id.wrapping_add(self.0.pass() as u32);
                Received::Message(m, stamp)
            }
            other => other,
        })
    }
}

/// The detector node's input: heat maps from the configured source.
pub struct DetectorInput {
    /// The heat maps.
    pub source: Box<dyn Source<HeatMaps>>,
    /// The image detector's counters (image sources).
    pub stats: Option<SharedStats>,
    /// The pace: `detector.rate` for a recording of heat maps; image sources go as fast
    /// as the model (a camera paces itself).
    pub rate: ReplayRate,
    /// The calibration assumed for images from files (`detector.images.field_of_view`),
    /// for the outputs ([`Wiring::camera_outputs`]) and an estimator in the process.
    pub camera: Option<CameraTap>,
    /// When each image came in (image sources), for the latency to its skeletons.
    pub clock: Option<FrameClock>,
}

impl DetectorInput {
    /// The image detector's counters now.
    pub fn stats_now(stats: &Option<SharedStats>) -> Option<DetectorStats> {
        stats.as_ref().and_then(|s| s.lock().ok().map(|s| *s))
    }
}

/// The detector's configured source (`detector.source`): the heat maps of
/// `detector.recording`, or the image detector on the configured images (its model
/// and mapping loaded, for the joints of `estimator.dictionary`).
pub fn detector_input(
    config: &ServiceConfig,
    middleware: &mut Middleware,
    live: Option<&LiveView>,
    nice: u8,
) -> Result<DetectorInput, ServiceError> {
    if config.detector.source == DetectorSource::Recording {
        return Ok(DetectorInput {
            source: Box::new(recording_source(config, &config.detector.recording)?),
            stats: None,
            rate: config.detector.rate,
            camera: None,
            clock: None,
        });
    }
    let dictionary = crate::msgs::shipped::load_dictionary(&config.estimator.dictionary)
        .map_err(SetupError::Dictionary)?;
    // Loaded on a thread made `nice` first: the threads its models start (LiteRT's)
    // inherit it; rayon's workers, which run the models in parallel, are made so too.
    // The main thread's stack size: compiling the models may want more than a spawned
    // thread's 2 MiB.
    let joints = &dictionary.skeleton().joints;
    let detector = std::thread::scope(|scope| {
        std::thread::Builder::new()
            .name("detector-load".into())
            .stack_size(8 << 20)
            .spawn_scoped(scope, || {
                crate::nodes::priority::detector_threads_at_least(nice);
                ImageDetector::load(&config.detector.images, joints)
            })
            .map_err(|_| ServiceError::Thread("detector-load"))?
            .join()
            .map_err(|_| ServiceError::Thread("detector-load"))
    })?
    .map_err(SetupError::Detector)?;
    let frames = image_frames(config, middleware.ros.as_mut())?;
    let encoding = config.detector.images.encoding.message_encoding();
    let mut source = ImageHeatMaps::new(frames, detector, encoding).with_nice(nice);
    if let Some(live) = live {
        source = source.with_shown_images(live.sink(&shown_images_topic(config))?);
    }
    // Files carry no calibration: a camera is assumed (a real one has its own).
    let fov = config.detector.images.field_of_view;
    let from_files = matches!(
        config.detector.source,
        DetectorSource::Images | DetectorSource::Video
    );
    let mut camera = (from_files && fov > 0.0).then(CameraTap::default);
    if let Some(tap) = &camera {
        source = source.with_assumed_camera(fov, tap.clone());
    }
    // A recording of a camera: its own calibration channel, read beside the images.
    if config.detector.source == DetectorSource::ImageRecording {
        let tap = CameraTap::default();
        let recorded = config
            .replay
            .source(McapSource::<CameraInfo>::open_with_limit(
                &config.detector.images.path,
                &config.topics.camera_info,
                config.limits.max_record_bytes,
            )?)?;
        source = source.with_recorded_camera(Box::new(recorded), tap.clone());
        camera = Some(tap);
    }
    let clock = FrameClock::default();
    let source = source.with_clock(clock.clone());
    Ok(DetectorInput {
        stats: Some(source.stats()),
        source: Box::new(source),
        rate: ReplayRate::Fast,
        camera,
        clock: Some(clock),
    })
}

/// The transport the detector's source needs opened, beyond the outputs.
pub fn detector_transport(config: &ServiceConfig) -> Option<Transport> {
    (config.detector.source == DetectorSource::Ros2).then_some(Transport::Ros2)
}

/// A wiring dropped without [`Wiring::conclude`] (a setup that failed after the
/// recording started, a thread that died): a recording with nothing in it is removed;
/// one with messages is kept under its temporary name, which a warning names.
impl Drop for Wiring {
    fn drop(&mut self) {
        let Some(recorder) = self.taps.recorder.take() else {
            return;
        };
        if recorder.messages() == 0 {
            recorder.abandon();
            return;
        }
        match recorder.finish_partial() {
            Ok(kept) => tracing::warn!(
                "the run ended early: what was recorded is in {}",
                kept.display()
            ),
            Err(e) => tracing::warn!("the run ended early: {e}"),
        }
    }
}

/// What a service process is wired to: its middleware (ROS 2, iceoryx2, each only if
/// used), its output recording (`[outputs] record`) and live view (`[outputs]
/// foxglove`). Each node's ends come from it; when the loop is over,
/// [`Wiring::conclude`] finishes the recording.
pub struct Wiring {
    /// The middleware.
    pub middleware: Middleware,
    /// The output recording, once started ([`Wiring::start_recording`]), and the live
    /// view.
    pub taps: Taps,
}

impl Wiring {
    /// Opens the middleware `config` needs, plus `extra`: the transport a node reads
    /// from.
    pub fn open(config: &ServiceConfig, extra: Option<Transport>) -> Result<Self, ServiceError> {
        Ok(Self {
            middleware: Middleware::open(config, extra)?,
            taps: Taps {
                recorder: None,
                live: live_view(config)?,
            },
        })
    }

    /// Waits up to `[ros] wait_for_subscribers` for DDS discovery to see a subscriber of
    /// `topic` (then for both ends to match), when publishing on ROS 2: so that the first
    /// messages do not go to nobody. Says so when it stops waiting: a warning when one
    /// was `expected` (the detector's estimator), else a note (`run`'s optional
    /// consumers).
    pub fn wait_for_subscribers(&self, config: &ServiceConfig, topic: &str, expected: bool) {
        if config.outputs.ros2
            && config.ros.wait_for_subscribers > 0.0
            && let Some(ros) = self.middleware.ros.as_ref()
        {
            let wait = ros.discovery_wait(Duration::from_secs_f64(config.ros.wait_for_subscribers));
            if !ros.wait_for_subscriptions(topic, wait) {
                if expected {
                    tracing::warn!(
                        "no subscriber of {topic} after {wait:?}: publishing anyway \
                         (start `posestream estimator` with the same ROS_DOMAIN_ID to \
                         receive them; `ros2 topic info {topic}` lists who does)"
                    );
                } else {
                    tracing::info!("no subscriber of {topic} after {wait:?}: publishing anyway");
                }
            }
        }
    }

    /// Starts the output recording, if one is configured (after the inputs are set up;
    /// a setup that fails later drops the wiring, which removes the empty recording).
    pub fn start_recording(&mut self, config: &ServiceConfig) -> Result<(), ServiceError> {
        self.taps.recorder = output_recording(config)?;
        Ok(())
    }

    /// The publishers of `node`'s skeletons.
    pub fn estimator_outputs(
        &mut self,
        config: &ServiceConfig,
        node: &EstimatorNode,
    ) -> Result<EstimatorOutputs, ServiceError> {
        EstimatorOutputs::open(config, &mut self.middleware, &self.taps, node)
    }

    /// The detector node's heat-map publishers.
    pub fn detector_outputs(
        &mut self,
        config: &ServiceConfig,
    ) -> Result<Publishers<HeatMaps>, ServiceError> {
        detector_outputs(config, &mut self.middleware, &self.taps)
    }

    /// The detector node's configured input, its threads at least `nice` nice
    /// (`[detector] nice` where an estimator shares the process, else 0).
    pub fn detector_input(
        &mut self,
        config: &ServiceConfig,
        nice: u8,
    ) -> Result<DetectorInput, ServiceError> {
        detector_input(config, &mut self.middleware, self.taps.live.as_ref(), nice)
    }

    /// A live camera's own calibration (the `ros2` source's `topics.camera_info`), for
    /// an estimator in the process; `None` for other sources.
    pub fn camera_calibration(
        &mut self,
        config: &ServiceConfig,
    ) -> Result<Option<Box<dyn Source<CameraInfo>>>, ServiceError> {
        if config.detector.source != DetectorSource::Ros2 {
            return Ok(None);
        }
        let ros = self.middleware.ros()?;
        Ok(Some(Box::new(
            ros.source::<CameraInfo>(&config.topics.camera_info)?,
        )))
    }

    /// The configured publishers of the camera's calibration (`topics.camera_info`: ROS 2
    /// and the output recording).
    pub fn camera_outputs(
        &mut self,
        config: &ServiceConfig,
    ) -> Result<Publishers<CameraInfo>, ServiceError> {
        publishers(
            config,
            &mut self.middleware,
            &self.taps,
            &config.topics.camera_info,
            None,
        )
    }

    /// The estimator node's heat maps from `transport` ([`Middleware::estimator_input`])
    /// and what it reads beside them ([`Self::transform_sources`]), what is read beside
    /// recorded as it is read (so start the recording first).
    pub fn estimator_input(
        &mut self,
        config: &ServiceConfig,
        transport: Transport,
    ) -> Result<EstimatorInput, ServiceError> {
        let mut input = self.middleware.estimator_input(config, transport)?;
        let transforms = self.transform_sources(config)?;
        let camera_sink = self
            .taps
            .publishers::<CameraInfo>(&config.topics.camera_info)?;
        match &mut input {
            EstimatorInput::Awaited { side, .. } | EstimatorInput::Lent(_, side) => {
                side.transforms = transforms;
                // The calibration read is recorded too.
                side.camera = side.camera.take().map(|source| {
                    Box::new(Recorded {
                        source,
                        sink: camera_sink,
                    }) as Box<dyn Source<CameraInfo>>
                });
            }
        }
        Ok(input)
    }

    /// [`Middleware::transform_sources`], each recorded as it is read (to its topic of
    /// the output recording, so that a replay of the recording has the floor too).
    pub fn transform_sources(
        &mut self,
        config: &ServiceConfig,
    ) -> Result<Vec<Box<dyn Source<TFMessage>>>, ServiceError> {
        let sources = self.middleware.transform_sources(config)?;
        let topics = [&config.topics.tf_static, &config.topics.tf];
        sources
            .into_iter()
            .zip(topics)
            .map(|(source, topic)| {
                Ok(Box::new(RecordedTransforms {
                    source,
                    sink: self.taps.publishers::<TFMessage>(topic)?,
                    kept: TFMessage::default(),
                }) as Box<dyn Source<TFMessage>>)
            })
            .collect()
    }

    /// Finishes the output recording after the loop ended: in place if the input held
    /// (its summary returned); if the input broke (`input_error`), left under its
    /// temporary name, which the one error names, so that a failed run replaces no
    /// existing output.
    pub fn conclude(
        mut self,
        input_error: Option<&str>,
    ) -> Result<Option<RecordingSummary>, ServiceError> {
        if let Some(live) = self.taps.live.take() {
            live.stop();
        }
        match (input_error, self.taps.recorder.take()) {
            (None, Some(r)) => Ok(Some(r.finish()?)),
            (None, None) => Ok(None),
            (Some(reason), recorder) => Err(ServiceError::Input {
                reason: reason.to_string(),
                kept: recorder.map(|r| r.finish_partial()).transpose()?,
            }),
        }
    }
}

/// A source whose messages are also published to taps as they are read (the output
/// recording): what the estimator read beside its heat maps, kept for a replay.
pub struct Recorded<M: Message> {
    /// Where the messages come from.
    pub source: Box<dyn Source<M>>,
    /// Where they are written as well.
    pub sink: Publishers<M>,
}

impl<M: Message> Source<M> for Recorded<M> {
    fn recv(&mut self, timeout: Duration) -> Result<Received<M>, TransportError> {
        let received = self.source.recv(timeout)?;
        if let Received::Message(message, stamp) = &received {
            // A failure is logged once and counted; the estimator still reads it.
            self.sink.publish(message, *stamp);
        }
        Ok(received)
    }
}

/// Transforms read from the graph, recorded as they are read, people's frames left out
/// (posestream's own, heard back on `/tf`, are recorded once already, by its publisher).
struct RecordedTransforms {
    source: Box<dyn Source<TFMessage>>,
    sink: Publishers<TFMessage>,
    /// The transforms recorded of the message in hand (reused).
    kept: TFMessage,
}

impl Source<TFMessage> for RecordedTransforms {
    fn recv(&mut self, timeout: Duration) -> Result<Received<TFMessage>, TransportError> {
        let received = self.source.recv(timeout)?;
        if let Received::Message(message, stamp) = &received {
            self.kept.transforms.clear();
            self.kept.transforms.extend(
                message
                    .transforms
                    .iter()
                    .filter(|t| !is_body_transform(&t.header.frame_id, &t.child_frame_id))
                    .cloned(),
            );
            if !self.kept.transforms.is_empty() {
                // A failure is logged once and counted; the estimator still reads it.
                self.sink.publish(&self.kept, *stamp);
            }
        }
        Ok(received)
    }
}
