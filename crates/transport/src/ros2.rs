//! ROS 2 topics over DDS, through `ros2-client` (pure Rust: no ROS installation).
//!
//! Wire facts (checked by `tests/transport.rs` with an independent client, Python
//! `cyclonedds`): a message type `posestream_msgs/msg/Skeleton3D` travels as the DDS
//! type `posestream_msgs::msg::dds_::Skeleton3D_`, topic `/posestream/skeletons` as the
//! DDS topic `rt/posestream/skeletons`, payload CDR (XCDR1) little-endian. Reliability
//! and durability must be compatible between publisher and subscriber
//! ([`QosSettings`]).
//!
//! The domain is [`RosSettings::domain_id`] unless `ROS_DOMAIN_ID` is set;
//! [`RosSettings::localhost_only`] (or `ROS_LOCALHOST_ONLY=1`, or
//! `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`) keeps DDS on the loopback interface.
//! [`SecuritySettings`] joins with DDS Security from an SROS2 keystore (feature
//! `security`).

use std::net::{IpAddr, Ipv4Addr};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use ros2_client::dds::rustdds::DomainParticipantBuilder;
use ros2_client::dds::rustdds::mio1::{Events, Interest, Poll, Token};
use ros2_client::qos::{Durability, History, Reliability, WhenFull};
use ros2_client::{
    Context, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher, QosProfile,
    Subscription,
};
use serde::{Deserialize, Serialize};

use super::recycle::{Recycler, Reuse};
use super::runtime::AsyncSource;
use super::{Message, Received, Sink, Source, TransportError};
use posestream_base::{OutOfDomain, check_range, check_real};
pub use posestream_msgs::names::check_topic_name;
use posestream_msgs::names::is_ros_token;

mod security;
pub use security::{ENCLAVE_FILES, SecuritySettings};

const TRANSPORT: &str = "ros2";

/// After a subscription is discovered, how long until both ends have matched.
const MATCH_SETTLE: Duration = Duration::from_millis(500);

/// The least wait for a subscriber's discovery under DDS Security: authentication comes
/// first and takes seconds (a user's trial on 2 busy cores: a detector's default 2 s ran
/// out ~0.6 s before the match, and 16 of 121 frames went to nobody).
const SECURE_DISCOVERY_WAIT: Duration = Duration::from_secs(10);

/// The same under DDS Security: after discovery the two ends still exchange their
/// endpoints' keys, and a sample sent before they arrive is dropped (RustDDS: "Could not
/// find a remote EndpointCryptoHandle").
const SECURE_MATCH_SETTLE: Duration = Duration::from_millis(2000);

/// How long a publish waits for room in a full reliable history before it fails.
const FULL_WAIT: Duration = Duration::from_millis(100);

/// How long after its last message a publisher's flush waits: DDS sends and resends in
/// the background, and a participant dropped at once loses what went last (measured: a
/// Fast DDS subscriber missed the 10 estimates an estimator stopped with Ctrl-C sent as
/// it stopped). ros2-client gives no access to the writer's `wait_for_acknowledgments`,
/// so a bounded wait stands in for it.
const LINGER: Duration = Duration::from_millis(500);

/// `[ros]` in the configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RosSettings {
    /// DDS domain (0-232); the environment variable `ROS_DOMAIN_ID` overrides it.
    pub domain_id: u16,
    /// Keep DDS traffic on the loopback interface (also set by `ROS_LOCALHOST_ONLY=1` or
    /// `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`).
    pub localhost_only: bool,
    /// Node name; empty: the command's (`posestream_detector`, `posestream_estimator`,
    /// `posestream_recorder`; `posestream` for `run`), so that two nodes of one graph are
    /// not named alike. The DDS participant is announced by the node's full name too.
    pub node_name: String,
    /// Node namespace (absolute).
    pub namespace: String,
    /// Seconds the detector node waits, before its first frame, for a subscriber of its
    /// heat maps (an estimator) to be discovered, so that the first frames are not
    /// published to nobody (at least 10 under DDS Security); 0: no wait.
    pub wait_for_subscribers: f64,
    /// Quality of service of every topic.
    pub qos: QosSettings,
    /// DDS Security (SROS2 keystores): off unless asked for.
    pub security: SecuritySettings,
}

impl Default for RosSettings {
    fn default() -> Self {
        Self {
            domain_id: 0,
            localhost_only: false,
            node_name: String::new(),
            namespace: "/".into(),
            wait_for_subscribers: 2.0,
            qos: QosSettings::default(),
            security: SecuritySettings::default(),
        }
    }
}

/// `[ros.qos]`: the ROS 2 QoS profile of the service's topics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct QosSettings {
    /// `reliable` (retransmit; a slow reader slows the writer) or `best-effort`.
    pub reliability: ReliabilityKind,
    /// `volatile` (only live messages) or `transient-local` (late joiners get the
    /// last `depth` messages).
    pub durability: DurabilityKind,
    /// History depth (keep last N).
    pub depth: usize,
}

impl Default for QosSettings {
    fn default() -> Self {
        Self {
            reliability: ReliabilityKind::Reliable,
            durability: DurabilityKind::Volatile,
            depth: 10,
        }
    }
}

/// ROS 2 reliability.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ReliabilityKind {
    /// Retransmit lost samples.
    Reliable,
    /// Drop lost samples.
    BestEffort,
}

/// ROS 2 durability.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DurabilityKind {
    /// Only samples published while the reader is there.
    Volatile,
    /// The writer keeps its history for late readers.
    TransientLocal,
}

impl RosSettings {
    /// Checks every value is in its domain; the error names the key (`[ros]`).
    pub fn check(&self) -> Result<(), OutOfDomain> {
        // DDS maps domain ids to UDP ports: 232 is the largest that fits (ROS 2's range).
        check_range("domain_id", self.domain_id, 0, 232)?;
        check_range("qos.depth", self.qos.depth, 1, 10_000)?;
        check_real(
            "wait_for_subscribers",
            self.wait_for_subscribers,
            0.0,
            3600.0,
            false,
        )?;
        if !self.node_name.is_empty() && !is_ros_token(&self.node_name) {
            return Err(OutOfDomain::new(
                "node_name",
                "a ROS name (letters, digits and _, not starting with a digit) or empty",
                format!("{:?}", self.node_name),
            ));
        }
        if self.namespace != "/" {
            check_topic_name("namespace", &self.namespace).map_err(|_| {
                OutOfDomain::new(
                    "namespace",
                    "an absolute ROS 2 namespace (/ or /a/b_c: letters, digits, _ and single /)",
                    format!("{:?}", self.namespace),
                )
            })?;
        }
        Ok(())
    }
}

impl QosSettings {
    /// What tf2's static listener asks of `/tf_static` (`tf2_ros::StaticListenerQoS`):
    /// reliable, transient local (transforms published before the reader joined arrive),
    /// the last 100.
    pub fn tf_static_listener() -> Self {
        Self {
            reliability: ReliabilityKind::Reliable,
            durability: DurabilityKind::TransientLocal,
            depth: 100,
        }
    }

    /// A topic whose newest message stands until the next, as a map's or `/tf_static`'s:
    /// reliable, transient local (a subscriber that joins later gets it), the last one.
    pub fn latched() -> Self {
        Self {
            reliability: ReliabilityKind::Reliable,
            durability: DurabilityKind::TransientLocal,
            depth: 1,
        }
    }

    /// What tf2's listener asks of `/tf` (`tf2_ros::DynamicListenerQoS`): reliable,
    /// volatile, the last 100.
    pub fn tf_listener() -> Self {
        Self {
            reliability: ReliabilityKind::Reliable,
            durability: DurabilityKind::Volatile,
            depth: 100,
        }
    }

    /// The `ros2-client` profile.
    pub fn profile(&self) -> QosProfile {
        let profile = QosProfile::publisher_default()
            .history(History::KeepLast {
                depth: self.depth.max(1),
            })
            .durability(match self.durability {
                DurabilityKind::Volatile => Durability::Volatile,
                DurabilityKind::TransientLocal => Durability::TransientLocal,
            });
        match self.reliability {
            ReliabilityKind::Reliable => profile.reliability(Reliability::Reliable {
                when_full: WhenFull::Wait(FULL_WAIT),
            }),
            ReliabilityKind::BestEffort => profile.reliability(Reliability::BestEffort),
        }
    }
}

impl RosSettings {
    /// Names the node `name` unless the configuration names it.
    pub fn or_named(&mut self, name: &str) {
        if self.node_name.is_empty() {
            self.node_name = name.to_string();
        }
    }

    /// The node's name (`posestream` when none was given).
    pub fn node(&self) -> &str {
        if self.node_name.is_empty() {
            "posestream"
        } else {
            &self.node_name
        }
    }

    /// The node's full name, `/namespace/name`.
    pub fn full_node_name(&self) -> String {
        format!("{}/{}", self.namespace.trim_end_matches('/'), self.node())
    }

    /// The domain: `ROS_DOMAIN_ID` if set, else the configured one. A malformed or
    /// out-of-range `ROS_DOMAIN_ID` is an error, not silently ignored.
    pub fn effective_domain(&self) -> Result<u16, TransportError> {
        self.domain_with(std::env::var("ROS_DOMAIN_ID").ok().as_deref())
    }

    /// The domain given the value of `ROS_DOMAIN_ID` (`None`: unset).
    pub fn domain_with(&self, env: Option<&str>) -> Result<u16, TransportError> {
        let domain = match env.map(str::trim) {
            Some(v) if !v.is_empty() => v.parse::<u16>().map_err(|_| {
                setup_error("the domain", format!("ROS_DOMAIN_ID={v:?} is not a number"))
            })?,
            _ => self.domain_id,
        };
        if domain > 232 {
            return Err(setup_error(
                "the domain",
                format!("domain id {domain} is out of 0..=232"),
            ));
        }
        Ok(domain)
    }

    /// Whether DDS stays on the loopback interface.
    pub fn effective_localhost_only(&self) -> bool {
        let env = |k: &str| std::env::var(k).unwrap_or_default();
        self.localhost_only
            || env("ROS_LOCALHOST_ONLY").trim() == "1"
            || env("ROS_AUTOMATIC_DISCOVERY_RANGE")
                .trim()
                .eq_ignore_ascii_case("localhost")
    }
}

fn setup_error(what: impl ToString, reason: impl ToString) -> TransportError {
    TransportError::Setup {
        transport: TRANSPORT,
        what: what.to_string(),
        reason: reason.to_string(),
    }
}

/// A ROS 2 participant and node: makes publishers and subscriptions. Clones share the
/// node, so that publishers can be made while a loop runs (REP-155's topics per body).
#[derive(Clone)]
pub struct Ros2 {
    node: Arc<Mutex<Node>>,
    qos: QosProfile,
    domain: u16,
    /// Joined with DDS Security.
    secure: bool,
    // Dropping the context shuts DDS down: keep it as long as the node.
    _context: Context,
}

impl Ros2 {
    /// Joins the domain as node `settings.node_name`.
    pub fn new(settings: &RosSettings) -> Result<Self, TransportError> {
        let domain = settings.effective_domain()?;
        // Named, so that DDS tools (`cyclonedds ls`, Fast DDS's monitor) list it by the
        // node's name (RustDDS patched: vendor/rustdds/PATCHES.md).
        let mut builder =
            DomainParticipantBuilder::new(domain).with_entity_name(settings.full_node_name());
        if settings.effective_localhost_only() {
            builder = builder.with_only_networks([IpAddr::V4(Ipv4Addr::LOCALHOST)]);
        }
        let enclave = settings
            .security
            .enclave_dir(&settings.full_node_name(), |k| std::env::var(k).ok())?;
        if let Some(enclave) = &enclave {
            if settings.effective_localhost_only() {
                // Measured: a secured subscriber decrypted none of a secured writer's
                // unfragmented samples on loopback only (vendor/rustdds/PATCHES.md).
                return Err(setup_error(
                    "DDS Security",
                    "not with localhost_only (or ROS_LOCALHOST_ONLY=1 / \
                     ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST): RustDDS's security loses \
                     every unfragmented message on loopback only; use ordinary networking",
                ));
            }
            builder = security::secure(builder, enclave)?;
            tracing::info!(enclave = %enclave.display(), "DDS Security on");
        }
        let participant = builder
            .build()
            .map_err(|e| setup_error(format!("a participant in domain {domain}"), e))?;
        let context = Context::from_domain_participant(participant)
            .map_err(|e| setup_error("the ROS 2 context", e))?;
        let name = NodeName::new(&settings.namespace, settings.node()).map_err(|e| {
            setup_error(
                format!("node {}", settings.full_node_name()),
                format!("{e:?}"),
            )
        })?;
        let node = context
            .new_node(name, NodeOptions::new().enable_rosout(false))
            .map_err(|e| setup_error("the node", e))?;
        Ok(Self {
            node: Arc::new(Mutex::new(node)),
            qos: settings.qos.profile(),
            domain,
            secure: enclave.is_some(),
            _context: context,
        })
    }

    /// The DDS domain joined.
    pub fn domain(&self) -> u16 {
        self.domain
    }

    fn node(&self) -> MutexGuard<'_, Node> {
        // Nothing is left half-done under the lock: go on after a panic elsewhere.
        self.node.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Subscriptions to `topic` that DDS discovery has seen so far (any node, this
    /// process included).
    pub fn subscriptions(&self, topic: &str) -> usize {
        self.node().subscription_count(topic)
    }

    /// How long to wait for discovery to see a subscriber, given the configured wait: at
    /// least 10 s under DDS Security, whose authentication comes first.
    pub fn discovery_wait(&self, configured: Duration) -> Duration {
        if self.secure {
            configured.max(SECURE_DISCOVERY_WAIT)
        } else {
            configured
        }
    }

    /// How long after discovery sees a new subscription both ends take to match (0.5 s;
    /// 2 s under DDS Security, which exchanges the endpoints' keys after discovery).
    pub fn match_settle(&self) -> Duration {
        if self.secure {
            SECURE_MATCH_SETTLE
        } else {
            MATCH_SETTLE
        }
    }

    /// Waits up to `timeout` for DDS discovery to see a subscription to `topic`, then
    /// [`Self::match_settle`] for both ends to finish matching (the reader must also have
    /// matched this writer before it takes samples). Whether one was seen.
    pub fn wait_for_subscriptions(&self, topic: &str, timeout: Duration) -> bool {
        let deadline = std::time::Instant::now() + timeout;
        while self.subscriptions(topic) == 0 {
            if std::time::Instant::now() >= deadline {
                return false;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        std::thread::sleep(self.match_settle());
        true
    }

    /// Publishers on `topic` that DDS discovery has seen so far.
    pub fn publishers(&self, topic: &str) -> usize {
        self.node().publisher_count(topic)
    }

    fn topic<M: Message>(
        &self,
        node: &mut Node,
        topic: &str,
    ) -> Result<ros2_client::dds::rustdds::Topic, TransportError> {
        let name = topic_name(topic)?;
        let (package, type_name) = type_name::<M>()?;
        node.create_topic(&name, MessageTypeName::new(package, type_name), &self.qos)
            .map_err(|e| setup_error(format!("topic {topic}"), e))
    }

    /// A publisher of `M` on `topic` (e.g. `/posestream/skeletons`).
    pub fn sink<M: Message>(&self, topic: &str) -> Result<Ros2Sink<M>, TransportError> {
        self.publisher(topic, self.qos.clone())
    }

    /// A publisher of `M` on `topic` with a QoS of its own (a topic whose convention is
    /// not the service's: a latched one, [`QosSettings::latched`]).
    pub fn sink_with<M: Message>(
        &self,
        topic: &str,
        qos: &QosSettings,
    ) -> Result<Ros2Sink<M>, TransportError> {
        self.publisher(topic, qos.profile())
    }

    fn publisher<M: Message>(
        &self,
        topic: &str,
        qos: QosProfile,
    ) -> Result<Ros2Sink<M>, TransportError> {
        let mut node = self.node();
        let t = self.topic::<M>(&mut node, topic)?;
        let publisher = node
            .create_publisher::<Shared<M>>(&t, Some(qos))
            .map_err(|e| setup_error(format!("a publisher on {topic}"), e))?;
        Ok(Ros2Sink {
            publisher,
            topic: topic.to_string(),
            last_sent: Mutex::new(None),
        })
    }

    /// A subscription to `M` on `topic`, with the node's QoS (`[ros.qos]`).
    pub fn source<M: Message>(&self, topic: &str) -> Result<Ros2Source<M>, TransportError> {
        self.subscribe(topic, self.qos.clone())
    }

    /// A subscription to `M` on `topic` with a QoS of its own (a topic whose convention
    /// is not the service's: `/tf_static`, [`QosSettings::tf_static_listener`]).
    pub fn source_with<M: Message>(
        &self,
        topic: &str,
        qos: &QosSettings,
    ) -> Result<Ros2Source<M>, TransportError> {
        self.subscribe(topic, qos.profile())
    }

    fn subscribe<M: Message>(
        &self,
        topic: &str,
        qos: QosProfile,
    ) -> Result<Ros2Source<M>, TransportError> {
        let mut node = self.node();
        let t = self.topic::<M>(&mut node, topic)?;
        let mut subscription = node
            .create_subscription::<M>(&t, Some(qos))
            .map_err(|e| setup_error(format!("a subscription to {topic}"), e))?;
        let poll = Poll::new().map_err(|e| setup_error("a poller", e))?;
        poll.registry()
            .register(&mut subscription, Token(0), Interest::READABLE)
            .map_err(|e| setup_error("a poller", e))?;
        Ok(Ros2Source {
            subscription,
            poll,
            events: Events::with_capacity(4),
            topic: topic.to_string(),
            recycler: Recycler::default(),
        })
    }
}

/// `/a/b` as a ROS name (namespace `/a`, base `b`).
fn topic_name(topic: &str) -> Result<Name, TransportError> {
    let bad = |reason: String| setup_error(format!("topic {topic}"), reason);
    if !topic.starts_with('/') {
        return Err(bad(
            "topic names here are absolute: they start with `/`".into()
        ));
    }
    let (namespace, base) = topic.rsplit_once('/').unwrap_or(("/", topic));
    let namespace = if namespace.is_empty() { "/" } else { namespace };
    Name::new(namespace, base).map_err(|e| bad(format!("{e:?}")))
}

/// `pkg/msg/Type` into `(pkg, Type)`.
fn type_name<M: Message>() -> Result<(&'static str, &'static str), TransportError> {
    let mut parts = M::NAME.split('/');
    match (parts.next(), parts.next(), parts.next(), parts.next()) {
        (Some(p), Some("msg"), Some(t), None) => Ok((p, t)),
        _ => Err(setup_error(
            format!("type {}", M::NAME),
            "not of the form pkg/msg/Type",
        )),
    }
}

/// A message shared with the publisher that serialises it: ros2-client takes what it
/// publishes by value, and an `Arc` of a message the caller keeps is passed without
/// copying it (the DDS writer serialises it at once and drops its handle).
#[derive(Debug)]
struct Shared<M>(Arc<M>);

impl<M: Serialize> Serialize for Shared<M> {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        self.0.serialize(serializer)
    }
}

/// Publishes `M` on a ROS 2 topic.
pub struct Ros2Sink<M: Message> {
    publisher: Publisher<Shared<M>>,
    topic: String,
    /// When a message went last ([`Sink::flush`] lets DDS deliver it).
    last_sent: Mutex<Option<std::time::Instant>>,
}

impl<M: Message> Ros2Sink<M> {
    /// A failed send on this topic.
    fn failed(&self, reason: String) -> TransportError {
        TransportError::Send {
            transport: TRANSPORT,
            topic: self.topic.clone(),
            reason,
        }
    }

    /// Publishes on a runtime: where [`Sink::send`] blocks the thread while a reliable
    /// history is full (up to 100 ms, then fails), this waits for room as long without
    /// blocking the runtime, then fails the same way. (RustDDS's own async wait looks
    /// at its time limit only when woken, and a matched reader that stops
    /// acknowledging never wakes it: the limit is kept here.)
    pub async fn send_async(&self, message: &M) -> Result<(), TransportError> {
        self.send_shared_async(&Arc::new(message.clone())).await
    }

    /// [`Ros2Sink::send_async`] of a message the caller keeps: not copied.
    pub async fn send_shared_async(&self, message: &Arc<M>) -> Result<(), TransportError> {
        self.sent_now();
        let publishing = self.publisher.async_publish(Shared(message.clone()));
        match tokio::time::timeout(FULL_WAIT, publishing).await {
            Ok(sent) => sent.map_err(|e| self.failed(e.to_string())),
            Err(_) => Err(self.failed(format!(
                "no room for the message in {} ms (readers behind on acknowledgements, or \
                 the network on sending)",
                FULL_WAIT.as_millis()
            ))),
        }
    }
}

impl<M: Message> Ros2Sink<M> {
    /// [`Sink::send`] of a message the caller keeps: not copied.
    pub fn send_shared(&self, message: &Arc<M>) -> Result<(), TransportError> {
        self.sent_now();
        self.publisher
            .publish(Shared(message.clone()))
            .map_err(|e| self.failed(e.to_string()))
    }

    fn sent_now(&self) {
        *self.last_sent.lock().unwrap_or_else(|e| e.into_inner()) = Some(std::time::Instant::now());
    }
}

impl<M: Message> Sink<M> for Ros2Sink<M> {
    /// Publishes (the stamp travels in the message's header; DDS adds its own).
    fn send(&mut self, message: &M, _stamp_ns: u64) -> Result<(), TransportError> {
        self.send_shared(&Arc::new(message.clone()))
    }

    /// Waits until [`LINGER`] after the last message, so that DDS delivers it before the
    /// participant may go.
    fn flush(&mut self) -> Result<(), TransportError> {
        let last = *self.last_sent.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(last) = last {
            std::thread::sleep(LINGER.saturating_sub(last.elapsed()));
        }
        Ok(())
    }
}

/// Takes `M` from a ROS 2 topic.
pub struct Ros2Source<M: Message> {
    subscription: Subscription<M>,
    poll: Poll,
    events: Events,
    topic: String,
    /// Messages handed back, decoded over ([`Ros2Source::recycler`]).
    recycler: Recycler<M>,
}

impl<M: Message> Source<M> for Ros2Source<M> {
    /// Waits for a sample; the stamp is the source timestamp DDS attached (ns since the
    /// epoch), or 0 without one. A topic never closes: no [`Received::Closed`].
    fn recv(&mut self, timeout: Duration) -> Result<Received<M>, TransportError> {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            match self.subscription.take_seed(Reuse(self.recycler.clone())) {
                Ok(Some(taken)) => return Ok(self.stamped(taken)),
                Ok(None) => {}
                Err(e) => return Err(self.malformed(e)),
            }
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            if left.is_zero() {
                return Ok(Received::Idle);
            }
            // Edge-triggered: a wake-up means "something arrived since the last take". A
            // signal (Ctrl-C) interrupts the wait: take again, it is no broken input.
            match self.poll.poll(&mut self.events, Some(left)) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => {
                    return Err(TransportError::Broken {
                        transport: TRANSPORT,
                        topic: self.topic.clone(),
                        reason: format!("poll: {e}"),
                    });
                }
            }
        }
    }
}

impl<M: Message> Ros2Source<M> {
    /// Where the messages taken are handed back once used: the next ones are decoded
    /// over them (no allocation for a message of a size seen before).
    pub fn recycler(&self) -> Recycler<M> {
        self.recycler.clone()
    }

    fn stamped(&self, taken: (M, ros2_client::MessageInfo)) -> Received<M> {
        let (m, info) = taken;
        let stamp = info
            .source_timestamp()
            .map_or(0, |t| u64::try_from(t.to_nanos()).unwrap_or(0));
        Received::Message(m, stamp)
    }

    fn malformed(&self, e: impl std::fmt::Display) -> TransportError {
        TransportError::Malformed {
            transport: TRANSPORT,
            topic: self.topic.clone(),
            reason: e.to_string(),
        }
    }
}

impl<M: Message + Sync> AsyncSource<M> for Ros2Source<M> {
    /// Waits for a sample on the runtime (`ros2-client`'s `async_take`); stamped as by
    /// [`Source::recv`].
    async fn next(&mut self) -> Result<Received<M>, TransportError> {
        let taken = {
            let stream = self
                .subscription
                .async_stream_seed(Reuse(self.recycler.clone()));
            futures_util::pin_mut!(stream);
            futures_util::StreamExt::next(&mut stream).await
        };
        match taken {
            Some(Ok(taken)) => Ok(self.stamped(taken)),
            Some(Err(e)) => Err(self.malformed(e)),
            None => Ok(Received::Closed),
        }
    }

    fn recycler(&self) -> Option<Recycler<M>> {
        Some(self.recycler.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ros_domain_id_overrides_the_configured_domain_and_must_be_valid() {
        let s = RosSettings {
            domain_id: 7,
            ..RosSettings::default()
        };
        assert_eq!(s.domain_with(None).ok(), Some(7));
        assert_eq!(s.domain_with(Some("")).ok(), Some(7));
        assert_eq!(s.domain_with(Some(" 42 ")).ok(), Some(42));
        assert!(s.domain_with(Some("abc")).is_err());
        assert!(s.domain_with(Some("233")).is_err());
        let bad = RosSettings {
            domain_id: 300,
            ..RosSettings::default()
        };
        assert!(bad.domain_with(None).is_err());
    }

    #[test]
    fn topic_and_type_names_map_to_ros_names() {
        assert!(topic_name("/posestream/skeletons").is_ok());
        assert!(topic_name("/top").is_ok());
        assert!(topic_name("relative").is_err());
        assert_eq!(
            type_name::<posestream_msgs::Skeleton3D>().ok(),
            Some(("posestream_msgs", "Skeleton3D"))
        );
    }
}
