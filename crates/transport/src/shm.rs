//! iceoryx2 shared memory: zero-copy publish-subscribe between processes on one machine.
//!
//! Two services (names in `[iceoryx2]` of the configuration):
//! - skeletons: a fixed-size [`SkeletonSample`] per message;
//! - heat maps: a slice of `f32` scores (joint-major, row-major maps) behind a
//!   [`HeatMapsHeader`] user header.
//!
//! Both are `#[repr(C)]` plain data (no pointers), so C, C++ and Python clients read
//! them with a struct of the same layout; `msgs/SHARED_MEMORY.md` documents it (a test
//! checks the offsets there) and
//! `tests/transport.rs` reads our skeletons with the Python `iceoryx2` binding.
//! Unused joint slots and name bytes are zero; names are NUL-padded UTF-8.

// The payload types must implement iceoryx2's `ZeroCopySend`, an unsafe trait (its
// contract: self-contained, no pointers, `#[repr(C)]`), through its derive macro. This is
// the crate's only unsafe code; the types below hold only integers, floats and arrays
// of them.
#![allow(unsafe_code, reason = "iceoryx2's ZeroCopySend derive (see above)")]

use std::time::{Duration, Instant};

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use serde::{Deserialize, Serialize};

use super::{FrameSource, Received, Sink, Source, TransportError};
use posestream_msgs::limits::Limits;
use posestream_msgs::{Header, HeatMapEncoding, HeatMaps, HeatMapsView, Skeleton3D, Time};

const TRANSPORT: &str = "iceoryx2";

/// Joints a shared-memory message can hold at most.
pub const MAX_JOINTS: usize = 32;
/// Bytes of a joint name (NUL-padded UTF-8).
pub const NAME_BYTES: usize = 24;
/// Bytes of a frame id (NUL-padded UTF-8).
pub use posestream_msgs::names::FRAME_ID_BYTES;
/// Samples a subscriber holds before the oldest is overwritten (every client opening
/// the services must ask for at most this many).
pub const SUBSCRIBER_BUFFER: usize = 16;

/// `[iceoryx2]` in the configuration: service names.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ShmSettings {
    /// Service of the skeletons.
    pub skeletons: String,
    /// Service of the heat maps.
    pub heatmaps: String,
}

impl ShmSettings {
    /// Checks every value is in its domain; the error names the key (`[iceoryx2]`).
    pub fn check(&self) -> Result<(), posestream_base::OutOfDomain> {
        for (key, name) in [("skeletons", &self.skeletons), ("heatmaps", &self.heatmaps)] {
            if name.is_empty() || name.len() > 255 || name.contains('\0') {
                return Err(posestream_base::OutOfDomain::new(
                    key,
                    "a service name of 1 to 255 bytes",
                    format!("{name:?}"),
                ));
            }
        }
        Ok(())
    }
}

impl Default for ShmSettings {
    fn default() -> Self {
        Self {
            skeletons: "posestream/skeletons".into(),
            heatmaps: "posestream/heatmaps".into(),
        }
    }
}

/// One [`Skeleton3D`] in shared memory (fixed size, 3,688 bytes, alignment 8).
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("posestream::SkeletonSample")]
pub struct SkeletonSample {
    /// Capture time of the frame described, nanoseconds since the epoch.
    pub stamp_ns: i64,
    /// Sequence number of the frame described.
    pub sequence: u64,
    /// The person tracked.
    pub track_id: u32,
    /// Joints used (the first `joints` entries of every array).
    pub joints: u32,
    /// Frames after this one seen before it was estimated.
    pub lag: u32,
    /// `Skeleton3D::state`.
    pub state: u8,
    /// `Skeleton3D::units`.
    pub units: u8,
    /// `Skeleton3D::metric_source`.
    pub metric_source: u8,
    /// `Skeleton3D::frames_since_look`, at most 255 (more: 255).
    pub frames_since_look: u8,
    /// Camera frame id.
    pub frame_id: [u8; FRAME_ID_BYTES],
    /// Joint names.
    pub joint_names: [[u8; NAME_BYTES]; MAX_JOINTS],
    /// `[x, y, z]` per joint.
    pub positions: [f64; 3 * MAX_JOINTS],
    /// Standard deviation per joint and axis, `[x, y, z]` per joint.
    pub position_std: [f64; 3 * MAX_JOINTS],
    /// Expected 2D joints `[u, v]`, image pixels.
    pub keypoints: [f64; 2 * MAX_JOINTS],
    /// Standard deviation per 2D joint.
    pub keypoint_std: [f64; MAX_JOINTS],
    /// Reprojection `[u, v]`, image pixels.
    pub projected: [f64; 2 * MAX_JOINTS],
    /// `Skeleton3D::mean_bone_length`, metres (0: not estimated).
    pub mean_bone_length: f64,
}

/// The header of a heat-map slice (fixed size, 904 bytes, alignment 8).
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("posestream::HeatMapsHeader")]
pub struct HeatMapsHeader {
    /// Capture time, nanoseconds since the epoch.
    pub stamp_ns: i64,
    /// The detector's frame number.
    pub sequence: u64,
    /// The person tracked.
    pub track_id: u32,
    /// Maps (joints) in the slice.
    pub joints: u32,
    /// Map rows.
    pub height: u32,
    /// Map columns.
    pub width: u32,
    /// Crop box in image pixels: left, top, width, height.
    pub crop: [f64; 4],
    /// Camera frame id.
    pub frame_id: [u8; FRAME_ID_BYTES],
    /// Joint names.
    pub joint_names: [[u8; NAME_BYTES]; MAX_JOINTS],
    /// `HeatMaps::frames_since_look`.
    pub frames_since_look: u32,
    /// Zero.
    pub reserved: u32,
}

fn error(
    topic: &str,
    kind: fn(&'static str, String, String) -> TransportError,
    e: impl ToString,
) -> TransportError {
    kind(TRANSPORT, topic.to_string(), e.to_string())
}

fn send_error(t: &'static str, topic: String, reason: String) -> TransportError {
    TransportError::Send {
        transport: t,
        topic,
        reason,
    }
}

fn broken(t: &'static str, topic: String, reason: String) -> TransportError {
    TransportError::Broken {
        transport: t,
        topic,
        reason,
    }
}

fn malformed(t: &'static str, topic: String, reason: String) -> TransportError {
    TransportError::Malformed {
        transport: t,
        topic,
        reason,
    }
}

fn beyond_limits(t: &'static str, topic: String, reason: String) -> TransportError {
    TransportError::BeyondLimits {
        transport: t,
        topic,
        reason,
    }
}

fn setup(what: &str, e: impl ToString) -> TransportError {
    TransportError::Setup {
        transport: TRANSPORT,
        what: what.to_string(),
        reason: e.to_string(),
    }
}

/// `s` into a NUL-padded field (an error if it does not fit).
fn pack<const N: usize>(s: &str, what: &str) -> Result<[u8; N], String> {
    let mut out = [0_u8; N];
    if s.len() > N || s.as_bytes().contains(&0) {
        return Err(format!(
            "{what} {s:?} is longer than {N} bytes or holds a NUL"
        ));
    }
    out[..s.len()].copy_from_slice(s.as_bytes());
    Ok(out)
}

/// A NUL-padded field back into a string.
fn unpack(bytes: &[u8], what: &str) -> Result<String, String> {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    String::from_utf8(bytes[..end].to_vec()).map_err(|_| format!("{what} is not UTF-8"))
}

fn pack_names(names: &[String]) -> Result<[[u8; NAME_BYTES]; MAX_JOINTS], String> {
    if names.len() > MAX_JOINTS {
        return Err(format!("{} joints, at most {MAX_JOINTS}", names.len()));
    }
    let mut out = [[0_u8; NAME_BYTES]; MAX_JOINTS];
    for (o, n) in out.iter_mut().zip(names) {
        *o = pack(n, "joint name")?;
    }
    Ok(out)
}

/// [`unpack`] into `out`, reusing its buffer.
fn unpack_into(bytes: &[u8], what: &str, out: &mut String) -> Result<(), String> {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    let text = std::str::from_utf8(&bytes[..end]).map_err(|_| format!("{what} is not UTF-8"))?;
    out.clear();
    out.push_str(text);
    Ok(())
}

/// [`unpack_names`] into `out`, reusing its strings.
fn unpack_names_into(
    names: &[[u8; NAME_BYTES]],
    joints: usize,
    out: &mut Vec<String>,
) -> Result<(), String> {
    let names = names
        .get(..joints)
        .ok_or_else(|| format!("{joints} joints, at most {MAX_JOINTS}"))?;
    out.truncate(joints);
    out.resize_with(joints, String::new);
    for (o, n) in out.iter_mut().zip(names) {
        unpack_into(n, "joint name", o)?;
    }
    Ok(())
}

fn unpack_names(names: &[[u8; NAME_BYTES]], joints: usize) -> Result<Vec<String>, String> {
    names
        .get(..joints)
        .ok_or_else(|| format!("{joints} joints, at most {MAX_JOINTS}"))?
        .iter()
        .map(|n| unpack(n, "joint name"))
        .collect()
}

/// Copies `src` into the first entries of `dst` after checking it holds `per_joint`
/// values per joint.
fn put(
    dst: &mut [f64],
    src: &[f64],
    joints: usize,
    per_joint: usize,
    what: &str,
) -> Result<(), String> {
    if src.len() != joints * per_joint {
        return Err(format!("{what}: {} values for {joints} joints", src.len()));
    }
    dst[..src.len()].copy_from_slice(src);
    Ok(())
}

impl SkeletonSample {
    /// The sample of a message (an error if it has more than [`MAX_JOINTS`] joints,
    /// inconsistent array sizes or names too long).
    pub fn from_message(m: &Skeleton3D) -> Result<Self, String> {
        let p = m.joint_names.len();
        let mut s = Self {
            stamp_ns: m.header.stamp.nanos(),
            sequence: m.sequence,
            track_id: m.track_id,
            joints: p as u32,
            lag: m.lag,
            state: m.state,
            units: m.units,
            metric_source: m.metric_source,
            frames_since_look: m.frames_since_look.min(255) as u8,
            frame_id: pack(&m.header.frame_id, "frame id")?,
            joint_names: pack_names(&m.joint_names)?,
            positions: [0.0; 3 * MAX_JOINTS],
            position_std: [0.0; 3 * MAX_JOINTS],
            keypoints: [0.0; 2 * MAX_JOINTS],
            keypoint_std: [0.0; MAX_JOINTS],
            projected: [0.0; 2 * MAX_JOINTS],
            mean_bone_length: m.mean_bone_length,
        };
        put(&mut s.positions, &m.positions, p, 3, "positions")?;
        put(&mut s.position_std, &m.position_std, p, 3, "position_std")?;
        put(&mut s.keypoints, &m.keypoints, p, 2, "keypoints")?;
        put(&mut s.keypoint_std, &m.keypoint_std, p, 1, "keypoint_std")?;
        put(&mut s.projected, &m.projected, p, 2, "projected")?;
        Ok(s)
    }

    /// The message of a sample.
    pub fn to_message(&self) -> Result<Skeleton3D, String> {
        let p = self.joints as usize;
        if p > MAX_JOINTS {
            return Err(format!("{p} joints, at most {MAX_JOINTS}"));
        }
        Ok(Skeleton3D {
            header: Header {
                stamp: Time::from_nanos(self.stamp_ns),
                frame_id: unpack(&self.frame_id, "frame id")?,
            },
            sequence: self.sequence,
            track_id: self.track_id,
            joint_names: unpack_names(&self.joint_names, p)?,
            units: self.units,
            positions: self.positions[..3 * p].to_vec(),
            position_std: self.position_std[..3 * p].to_vec(),
            keypoints: self.keypoints[..2 * p].to_vec(),
            keypoint_std: self.keypoint_std[..p].to_vec(),
            projected: self.projected[..2 * p].to_vec(),
            lag: self.lag,
            state: self.state,
            metric_source: self.metric_source,
            // Not in the fixed-size sample (msgs/SHARED_MEMORY.md): a fused skeleton's
            // views go over ROS 2 and recordings only.
            views: Vec::new(),
            frames_since_look: u32::from(self.frames_since_look),
            mean_bone_length: self.mean_bone_length,
        })
    }
}

impl Default for HeatMapsHeader {
    fn default() -> Self {
        Self {
            stamp_ns: 0,
            sequence: 0,
            track_id: 0,
            joints: 0,
            height: 0,
            width: 0,
            crop: [0.0; 4],
            frame_id: [0; FRAME_ID_BYTES],
            joint_names: [[0; NAME_BYTES]; MAX_JOINTS],
            frames_since_look: 0,
            reserved: 0,
        }
    }
}

impl HeatMapsHeader {
    /// The header of a message.
    pub fn from_message(m: &HeatMaps) -> Result<Self, String> {
        Ok(Self {
            stamp_ns: m.header.stamp.nanos(),
            sequence: m.sequence,
            track_id: m.track_id,
            joints: m.joint_names.len() as u32,
            height: m.height,
            width: m.width,
            crop: [m.crop_x, m.crop_y, m.crop_width, m.crop_height],
            frame_id: pack(&m.header.frame_id, "frame id")?,
            joint_names: pack_names(&m.joint_names)?,
            frames_since_look: m.frames_since_look,
            reserved: 0,
        })
    }
}

/// The iceoryx2 nodes on this machine whose process died without cleaning up (killed).
/// Their shared-memory resources are reclaimed when any process creates a node (as
/// every posestream node does at start), so after a restart this is 0.
pub fn dead_nodes() -> Result<usize, TransportError> {
    let mut dead = 0;
    Node::<ipc_threadsafe::Service>::list(Config::global_config(), |state| {
        if matches!(state, NodeState::Dead(_)) {
            dead += 1;
        }
        CallbackProgression::Continue
    })
    .map_err(|e| setup("the list of nodes", format!("{e:?}")))?;
    Ok(dead)
}

/// An iceoryx2 node: makes the shared-memory publishers and subscribers.
pub struct Shm {
    node: Node<ipc_threadsafe::Service>,
}

type SkeletonService = iceoryx2::service::port_factory::publish_subscribe::PortFactory<
    ipc_threadsafe::Service,
    SkeletonSample,
    (),
>;
type HeatMapsService = iceoryx2::service::port_factory::publish_subscribe::PortFactory<
    ipc_threadsafe::Service,
    [f32],
    HeatMapsHeader,
>;

impl Shm {
    /// A node of this process. iceoryx2's own log shows errors only, unless its
    /// `IOX2_LOG_LEVEL` says otherwise (it otherwise warns that no iceoryx2 config file
    /// exists, which is the normal case).
    pub fn new() -> Result<Self, TransportError> {
        set_log_level_from_env_or(LogLevel::Error);
        let node = NodeBuilder::new()
            // The process's own Ctrl-C handling stays in charge.
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc_threadsafe::Service>()
            .map_err(|e| setup("a node", e))?;
        Ok(Self { node })
    }

    fn service_name(name: &str) -> Result<ServiceName, TransportError> {
        ServiceName::new(name).map_err(|e| setup(&format!("service {name}"), format!("{e:?}")))
    }

    fn skeleton_service(&self, name: &str) -> Result<SkeletonService, TransportError> {
        self.node
            .service_builder(&Self::service_name(name)?)
            .publish_subscribe::<SkeletonSample>()
            .subscriber_max_buffer_size(SUBSCRIBER_BUFFER)
            .open_or_create()
            .map_err(|e| setup(&format!("service {name}"), e))
    }

    fn heatmaps_service(&self, name: &str) -> Result<HeatMapsService, TransportError> {
        self.node
            .service_builder(&Self::service_name(name)?)
            .publish_subscribe::<[f32]>()
            .user_header::<HeatMapsHeader>()
            .subscriber_max_buffer_size(SUBSCRIBER_BUFFER)
            .open_or_create()
            .map_err(|e| setup(&format!("service {name}"), e))
    }

    /// A publisher of skeletons on service `name`.
    pub fn skeleton_sink(&self, name: &str) -> Result<ShmSkeletonSink, TransportError> {
        let service = self.skeleton_service(name)?;
        let publisher = service
            .publisher_builder()
            .create()
            .map_err(|e| setup(&format!("a publisher on {name}"), e))?;
        Ok(ShmSkeletonSink {
            publisher,
            name: name.to_string(),
            _service: service,
        })
    }

    /// A subscriber to skeletons on service `name`.
    pub fn skeleton_source(&self, name: &str) -> Result<ShmSkeletonSource, TransportError> {
        let service = self.skeleton_service(name)?;
        let subscriber = service
            .subscriber_builder()
            .buffer_size(SUBSCRIBER_BUFFER)
            .create()
            .map_err(|e| setup(&format!("a subscriber on {name}"), e))?;
        Ok(ShmSkeletonSource {
            subscriber,
            name: name.to_string(),
            _service: service,
        })
    }

    /// A publisher of heat maps on service `name`.
    pub fn heatmaps_sink(&self, name: &str) -> Result<ShmHeatMapsSink, TransportError> {
        let service = self.heatmaps_service(name)?;
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(17 * 64 * 64)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| setup(&format!("a publisher on {name}"), e))?;
        Ok(ShmHeatMapsSink {
            publisher,
            name: name.to_string(),
            values: Vec::new(),
            _service: service,
        })
    }

    /// A subscriber to heat maps on service `name` (samples beyond `limits` refused).
    pub fn heatmaps_source(
        &self,
        name: &str,
        limits: &Limits,
    ) -> Result<ShmHeatMapsSource, TransportError> {
        let service = self.heatmaps_service(name)?;
        let subscriber = service
            .subscriber_builder()
            .buffer_size(SUBSCRIBER_BUFFER)
            .create()
            .map_err(|e| setup(&format!("a subscriber on {name}"), e))?;
        Ok(ShmHeatMapsSource {
            subscriber,
            name: name.to_string(),
            limits: limits.clone(),
            text: SampleText::default(),
            _service: service,
        })
    }
}

/// Publishes [`Skeleton3D`] as [`SkeletonSample`].
pub struct ShmSkeletonSink {
    publisher: Publisher<ipc_threadsafe::Service, SkeletonSample, ()>,
    name: String,
    _service: SkeletonService,
}

impl Sink<Skeleton3D> for ShmSkeletonSink {
    fn send(&mut self, message: &Skeleton3D, _stamp_ns: u64) -> Result<(), TransportError> {
        let sample =
            SkeletonSample::from_message(message).map_err(|e| error(&self.name, send_error, e))?;
        let slot = self
            .publisher
            .loan_uninit()
            .map_err(|e| error(&self.name, send_error, e))?;
        slot.write_payload(sample)
            .send()
            .map_err(|e| error(&self.name, send_error, e))?;
        Ok(())
    }
}

/// Waits for `receive` to yield, polling (shared memory has no socket to block on):
/// spins briefly, then sleeps in short steps until `timeout`.
fn poll<T>(
    timeout: Duration,
    mut receive: impl FnMut() -> Result<Option<T>, TransportError>,
) -> Result<Option<T>, TransportError> {
    let start = Instant::now();
    loop {
        if let Some(v) = receive()? {
            return Ok(Some(v));
        }
        let waited = start.elapsed();
        if waited >= timeout {
            return Ok(None);
        }
        if waited < Duration::from_micros(50) {
            std::hint::spin_loop();
        } else {
            std::thread::sleep(Duration::from_micros(100).min(timeout - waited));
        }
    }
}

/// Takes [`Skeleton3D`] from [`SkeletonSample`]s.
pub struct ShmSkeletonSource {
    subscriber: Subscriber<ipc_threadsafe::Service, SkeletonSample, ()>,
    name: String,
    _service: SkeletonService,
}

impl ShmSkeletonSource {
    /// The next sample as it lies in shared memory, if one is there (no waiting): the
    /// zero-copy path for latency-critical readers.
    pub fn try_receive_sample(&mut self) -> Result<Option<SkeletonSample>, TransportError> {
        let sample = self
            .subscriber
            .receive()
            .map_err(|e| error(&self.name, broken, e))?;
        Ok(sample.map(|s| *s.payload()))
    }
}

impl Source<Skeleton3D> for ShmSkeletonSource {
    /// The stamp is the frame's capture time. A service never closes.
    fn recv(&mut self, timeout: Duration) -> Result<Received<Skeleton3D>, TransportError> {
        let name = self.name.clone();
        match poll(timeout, || self.try_receive_sample())? {
            Some(s) => {
                let m = s.to_message().map_err(|e| error(&name, malformed, e))?;
                Ok(Received::Message(m, u64::try_from(s.stamp_ns).unwrap_or(0)))
            }
            None => Ok(Received::Idle),
        }
    }
}

/// Publishes [`HeatMaps`] as an `f32` slice with a [`HeatMapsHeader`] (u8-quantised
/// messages are expanded: shared memory needs no bandwidth saving).
pub struct ShmHeatMapsSink {
    publisher: Publisher<ipc_threadsafe::Service, [f32], HeatMapsHeader>,
    name: String,
    values: Vec<f32>,
    _service: HeatMapsService,
}

impl Sink<HeatMaps> for ShmHeatMapsSink {
    fn send(&mut self, message: &HeatMaps, _stamp_ns: u64) -> Result<(), TransportError> {
        let header =
            HeatMapsHeader::from_message(message).map_err(|e| error(&self.name, send_error, e))?;
        message
            .values_into(&mut self.values)
            .map_err(|e| error(&self.name, send_error, e))?;
        let mut slot = self
            .publisher
            .loan_slice_uninit(self.values.len())
            .map_err(|e| error(&self.name, send_error, e))?;
        *slot.user_header_mut() = header;
        slot.write_from_slice(&self.values)
            .send()
            .map_err(|e| error(&self.name, send_error, e))?;
        Ok(())
    }
}

/// Takes [`HeatMaps`] (f32 encoding) from the heat-map service; samples beyond the
/// [`Limits`] are refused before anything is copied. As a [`FrameSource`] it lends each
/// sample's scores where they are, in shared memory.
pub struct ShmHeatMapsSource {
    subscriber: Subscriber<ipc_threadsafe::Service, [f32], HeatMapsHeader>,
    name: String,
    limits: Limits,
    text: SampleText,
    _service: HeatMapsService,
}

/// The joint names and frame id of a sample, unpacked into buffers reused from sample
/// to sample.
#[derive(Debug, Default)]
pub struct SampleText {
    names: Vec<String>,
    frame_id: String,
}

/// Why a shared-memory heat-map sample was not taken.
#[derive(Debug, thiserror::Error)]
pub enum SampleError {
    /// Its header declares sizes beyond the limits.
    #[error(transparent)]
    Limit(#[from] posestream_msgs::limits::LimitError),
    /// Its header and payload disagree, or its names are not UTF-8.
    #[error("{0}")]
    Malformed(String),
}

/// The [`HeatMaps`] message of a shared-memory sample (a copy of [`sample_view`]).
pub fn heatmaps_from_sample(
    h: &HeatMapsHeader,
    payload: &[f32],
    limits: &Limits,
) -> Result<HeatMaps, SampleError> {
    let mut text = SampleText::default();
    Ok(sample_view(h, payload, limits, &mut text)?.to_message())
}

/// A shared-memory sample as a borrowed frame: the scores stay in the sample, the names
/// are unpacked into `text`'s buffers (no allocation once they have held such names).
/// The header's sizes are the publisher's claim: they are checked against `limits`
/// (checked arithmetic) and against the payload's length first.
pub fn sample_view<'a>(
    h: &HeatMapsHeader,
    payload: &'a [f32],
    limits: &Limits,
    text: &'a mut SampleText,
) -> Result<HeatMapsView<'a>, SampleError> {
    let joints = h.joints as usize;
    if joints > MAX_JOINTS {
        return Err(SampleError::Malformed(format!(
            "{joints} joints, at most {MAX_JOINTS}"
        )));
    }
    let expected =
        limits.heatmap_values(u64::from(h.joints), u64::from(h.height), u64::from(h.width))?;
    if payload.len() != expected {
        return Err(SampleError::Malformed(format!(
            "{} scores for {joints} joints x {} x {}",
            payload.len(),
            h.height,
            h.width
        )));
    }
    unpack_names_into(&h.joint_names, joints, &mut text.names).map_err(SampleError::Malformed)?;
    unpack_into(&h.frame_id, "frame id", &mut text.frame_id).map_err(SampleError::Malformed)?;
    Ok(HeatMapsView {
        stamp_ns: h.stamp_ns,
        frame_id: &text.frame_id,
        sequence: h.sequence,
        track_id: h.track_id,
        joint_names: &text.names,
        height: h.height,
        width: h.width,
        crop: h.crop,
        encoding: HeatMapEncoding::Float32.code(),
        values: payload,
        quantized_values: &[],
        quantization_scale: 0.0,
        frames_since_look: h.frames_since_look,
    })
}

impl FrameSource for ShmHeatMapsSource {
    fn recv_frame(
        &mut self,
        timeout: Duration,
        take: &mut dyn FnMut(&HeatMapsView<'_>, u64),
    ) -> Result<Received<()>, TransportError> {
        let (subscriber, limits, name) = (&self.subscriber, &self.limits, &self.name);
        let text = &mut self.text;
        let got = poll(timeout, || {
            let Some(sample) = subscriber.receive().map_err(|e| error(name, broken, e))? else {
                return Ok(None);
            };
            let h = sample.user_header();
            let stamp = u64::try_from(h.stamp_ns).unwrap_or(0);
            match sample_view(h, sample.payload(), limits, text) {
                Ok(view) => {
                    take(&view, stamp);
                    Ok(Some(stamp))
                }
                Err(e @ SampleError::Limit(_)) => Err(error(name, beyond_limits, e)),
                Err(e) => Err(error(name, malformed, e)),
            }
        })?;
        Ok(match got {
            Some(stamp) => Received::Message((), stamp),
            None => Received::Idle,
        })
    }

    fn recv_input(
        &mut self,
        timeout: Duration,
        take: &mut dyn FnMut(crate::Lent<'_>, u64),
    ) -> Result<Received<()>, TransportError> {
        crate::frames_only(self, timeout, take)
    }
}

impl Source<HeatMaps> for ShmHeatMapsSource {
    /// [`FrameSource::recv_frame`], the lent frame copied into a message.
    fn recv(&mut self, timeout: Duration) -> Result<Received<HeatMaps>, TransportError> {
        let mut message = None;
        Ok(
            match self.recv_frame(timeout, &mut |view, _| message = Some(view.to_message()))? {
                Received::Message((), stamp) => match message {
                    Some(m) => Received::Message(m, stamp),
                    None => Received::Idle,
                },
                Received::Idle => Received::Idle,
                Received::Closed => Received::Closed,
            },
        )
    }
}

#[cfg(test)]
mod tests;
