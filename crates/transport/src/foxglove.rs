//! A live view: the Foxglove WebSocket protocol (`foxglove.websocket.v1`, served by the
//! `foxglove` crate's server), so the Foxglove app shows what a node publishes with no ROS
//! installation. Each topic is a channel with the same schema and encoding as a
//! recording's (`ros2msg` definitions, CDR messages), so what the app shows live is what
//! it shows from a recording, and a layout works for both.
//!
//! The server is read-only for its clients: it advertises none of the protocol's
//! capabilities (no client publishing, parameters or services), so a viewer can
//! subscribe to channels and nothing else. The `foxglove` crate names the protocol
//! `foxglove.sdk.v1` (as foxglove_bridge 3.x does; the messages are those of
//! `foxglove.websocket.v1`).
//!
//! What a viewer costs is bounded: a message is encoded only while a viewer is subscribed
//! to its channel, and none over [`LiveView::MAX_MESSAGE_BYTES`] is shown (counted);
//! each viewer has a queue of [`LiveView::BACKLOG`] messages, and when a viewer falls
//! behind the server drops its oldest ones (the viewer stays connected and is not told).
//! The crate's server takes any number of clients, so the address a user names is ours
//! ([`pass_viewers`]): a connection is passed on to the server (listening on the loopback
//! interface) once it has sent its whole WebSocket upgrade request within
//! [`LiveView::HANDSHAKE`], while fewer than [`LiveView::MAX_VIEWERS`] viewers are
//! connected; the others are closed and counted ([`LiveView::refused`]). So at most
//! `MAX_VIEWERS x BACKLOG x MAX_MESSAGE_BYTES` are queued for viewers, whatever they do.

use std::collections::BTreeMap;
use std::marker::PhantomData;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use foxglove::{ChannelBuilder, Context, PartialMetadata, RawChannel, Schema, WebSocketServer};

use super::{EncodedSink, Message, Sink, TransportError};

const TRANSPORT: &str = "foxglove";

/// The default address: the local machine only (docs/services.md, "Live view in Foxglove": what a remote viewer can do).
pub const DEFAULT_ADDRESS: &str = "127.0.0.1:8765";

/// A Foxglove WebSocket server and its channels, one per topic. Clones share them.
#[derive(Clone)]
pub struct LiveView {
    inner: Arc<Inner>,
}

struct Inner {
    context: Arc<Context>,
    channels: Mutex<BTreeMap<String, Arc<RawChannel>>>,
    address: SocketAddr,
    refused: Arc<AtomicU64>,
    /// Messages not shown for their size.
    oversized: Arc<AtomicU64>,
    server: Mutex<Option<foxglove::WebSocketServerHandle>>,
    // The server's tasks run here; dropped last.
    runtime: Mutex<Option<tokio::runtime::Runtime>>,
}

impl LiveView {
    /// Messages queued for one viewer at most (the oldest are dropped beyond).
    pub const BACKLOG: usize = 32;

    /// The largest message shown (encoded); larger ones are counted and not shown.
    pub const MAX_MESSAGE_BYTES: usize = 2 << 20;

    /// How long a new connection may take to send its WebSocket upgrade request.
    pub const HANDSHAKE: std::time::Duration = std::time::Duration::from_secs(5);

    /// Connections waiting for their upgrade request at once, at most (more are closed).
    pub const MAX_PENDING: usize = 64;

    /// Viewers connected at once at most; more are closed at once and counted.
    pub const MAX_VIEWERS: usize = 8;

    /// Serves the protocol on `address` (port 0: any free port, see
    /// [`LiveView::address`]), on a runtime of one thread of its own.
    pub fn serve(address: SocketAddr) -> Result<Self, TransportError> {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name("foxglove")
            .enable_all()
            .build()
            .map_err(|e| setup(address, e.to_string()))?;
        // The address the user named: ours, so that viewers are counted.
        let front = runtime
            .block_on(tokio::net::TcpListener::bind(address))
            .map_err(|e| setup(address, bind_error(address, &e)))?;
        let bound = front
            .local_addr()
            .map_err(|e| setup(address, e.to_string()))?;
        let context = Context::new();
        let handle = WebSocketServer::new()
            .name(format!("posestream {}", env!("CARGO_PKG_VERSION")))
            .bind("127.0.0.1", 0)
            .context(&context)
            .message_backlog_size(Self::BACKLOG)
            .tokio_runtime(runtime.handle())
            .start_blocking()
            .map_err(|e| setup(address, e.to_string()))?;
        let inner = SocketAddr::from(([127, 0, 0, 1], handle.port()));
        let refused = Arc::new(AtomicU64::new(0));
        runtime.spawn(pass_viewers(front, inner, refused.clone()));
        let oversized = Arc::new(AtomicU64::new(0));
        Ok(Self {
            inner: Arc::new(Inner {
                context,
                channels: Mutex::new(BTreeMap::new()),
                address: bound,
                refused,
                oversized,
                server: Mutex::new(Some(handle)),
                runtime: Mutex::new(Some(runtime)),
            }),
        })
    }

    /// Connections closed because [`LiveView::MAX_VIEWERS`] were open, or that sent no
    /// upgrade request in time.
    pub fn refused(&self) -> u64 {
        self.inner.refused.load(Ordering::Relaxed)
    }

    /// Messages not shown because they were over [`LiveView::MAX_MESSAGE_BYTES`].
    pub fn oversized(&self) -> u64 {
        self.inner.oversized.load(Ordering::Relaxed)
    }

    /// Where it serves (the port chosen when asked for port 0).
    pub fn address(&self) -> SocketAddr {
        self.inner.address
    }

    /// Clients connected now.
    pub fn clients(&self) -> usize {
        self.inner
            .server
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .as_ref()
            .map_or(0, foxglove::WebSocketServerHandle::client_count)
    }

    /// The channel of `topic` for messages of type `M` (made on first use; a topic
    /// keeps the type it was made with).
    fn channel<M: Message>(&self, topic: &str) -> Result<Arc<RawChannel>, TransportError> {
        let mut channels = self
            .inner
            .channels
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        if let Some(c) = channels.get(topic) {
            if c.schema().is_some_and(|s| s.name != M::NAME) {
                return Err(TransportError::Setup {
                    transport: TRANSPORT,
                    what: topic.to_string(),
                    reason: format!(
                        "the topic carries {}, not {}",
                        c.schema().map_or("", |s| s.name.as_str()),
                        M::NAME
                    ),
                });
            }
            return Ok(c.clone());
        }
        let channel = ChannelBuilder::new(topic)
            .context(&self.inner.context)
            .message_encoding("cdr")
            .schema(Schema::new(
                M::NAME,
                "ros2msg",
                M::full_definition().into_bytes(),
            ))
            .build_raw()
            .map_err(|e| TransportError::Setup {
                transport: TRANSPORT,
                what: topic.to_string(),
                reason: e.to_string(),
            })?;
        channels.insert(topic.to_string(), channel.clone());
        Ok(channel)
    }

    /// A sink of messages of type `M` on `topic`.
    pub fn sink<M: Message>(&self, topic: &str) -> Result<LiveSink<M>, TransportError> {
        Ok(LiveSink {
            channel: self.channel::<M>(topic)?,
            buffer: Vec::new(),
            oversized: self.inner.oversized.clone(),
            _message: PhantomData,
        })
    }

    /// Sends an encoded message of type `M` (CDR, as read from a recording) on `topic`,
    /// without decoding it.
    pub fn send_encoded<M: Message>(
        &self,
        topic: &str,
        stamp_ns: u64,
        data: &[u8],
    ) -> Result<(), TransportError> {
        let channel = self.channel::<M>(topic)?;
        if !channel.has_sinks() {
            return Ok(());
        }
        if data.len() > Self::MAX_MESSAGE_BYTES {
            self.inner.oversized.fetch_add(1, Ordering::Relaxed);
            return Ok(());
        }
        channel.log_with_meta(data, PartialMetadata::with_log_time(stamp_ns));
        Ok(())
    }

    /// Stops serving: clients are disconnected. Dropping the last clone does the same.
    pub fn stop(&self) {
        if let Some(server) = self
            .inner
            .server
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .take()
        {
            let _ = server.stop();
        }
        self.inner
            .channels
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clear();
    }
}

impl Drop for Inner {
    fn drop(&mut self) {
        if let Some(server) = self
            .server
            .get_mut()
            .unwrap_or_else(|e| e.into_inner())
            .take()
        {
            let _ = server.stop();
        }
        if let Some(runtime) = self
            .runtime
            .get_mut()
            .unwrap_or_else(|e| e.into_inner())
            .take()
        {
            runtime.shutdown_background();
        }
    }
}

/// What binding `address` failed with, said so that the fix is plain.
fn bind_error(address: SocketAddr, e: &std::io::Error) -> String {
    match e.kind() {
        std::io::ErrorKind::AddrInUse => format!(
            "the address is in use (another posestream or Foxglove bridge?): choose another \
             port, e.g. --foxglove {}",
            SocketAddr::new(address.ip(), address.port().wrapping_add(1).max(1024))
        ),
        std::io::ErrorKind::AddrNotAvailable => format!(
            "{} is not an address of this machine: --foxglove 0.0.0.0:{} serves on all of \
             them (`ip -brief addr` lists them)",
            address.ip(),
            address.port()
        ),
        std::io::ErrorKind::PermissionDenied => format!(
            "{e}: ports below 1024 need privileges; choose another, e.g. --foxglove {}",
            SocketAddr::new(address.ip(), 8765)
        ),
        _ => e.to_string(),
    }
}

/// Accepts viewers on `front` and passes each to the server on `server` once it has sent
/// its whole upgrade request within [`LiveView::HANDSHAKE`], while fewer than
/// [`LiveView::MAX_VIEWERS`] are connected; closes (and counts) the others. Connections
/// still sending their request are [`LiveView::MAX_PENDING`] at most.
async fn pass_viewers(front: tokio::net::TcpListener, server: SocketAddr, refused: Arc<AtomicU64>) {
    let viewers = Arc::new(tokio::sync::Semaphore::new(LiveView::MAX_VIEWERS));
    let pending = Arc::new(tokio::sync::Semaphore::new(LiveView::MAX_PENDING));
    loop {
        let (mut viewer, from) = match front.accept().await {
            Ok(v) => v,
            Err(e) => {
                // Out of file descriptors and the like: wait, then go on.
                tracing::debug!("live view: accepting a viewer: {e}");
                tokio::time::sleep(std::time::Duration::from_millis(100)).await;
                continue;
            }
        };
        let Ok(waiting) = pending.clone().try_acquire_owned() else {
            refuse(
                &refused,
                from,
                "too many connections are still to say what they are",
            );
            continue;
        };
        let (viewers, refused) = (viewers.clone(), refused.clone());
        tokio::spawn(async move {
            let asked = tokio::time::timeout(LiveView::HANDSHAKE, upgrade_request(&mut viewer));
            let complete = matches!(asked.await, Ok(Ok(true)));
            drop(waiting);
            if !complete {
                refuse(
                    &refused,
                    from,
                    "it sent no WebSocket upgrade request in time",
                );
                return;
            }
            let Ok(_slot) = viewers.try_acquire_owned() else {
                let why = format!("{} viewers are connected", LiveView::MAX_VIEWERS);
                refuse(&refused, from, &why);
                return;
            };
            if let Ok(mut upstream) = tokio::net::TcpStream::connect(server).await {
                let _ = tokio::io::copy_bidirectional(&mut viewer, &mut upstream).await;
            }
        });
    }
}

/// Waits until `viewer` has sent a whole HTTP request head (up to a blank line), at most
/// 16 kB, without taking it off the socket (the server reads it). True when it came.
async fn upgrade_request(viewer: &mut tokio::net::TcpStream) -> std::io::Result<bool> {
    let mut head = vec![0_u8; 16 << 10];
    loop {
        let n = viewer.peek(&mut head).await?;
        if n == 0 {
            return Ok(false);
        }
        if head[..n].windows(4).any(|w| w == b"\r\n\r\n") {
            return Ok(true);
        }
        if n == head.len() {
            return Ok(false);
        }
        // More is on its way: wait a little instead of peeking at the same bytes again.
        tokio::time::sleep(std::time::Duration::from_millis(10)).await;
    }
}

/// Counts a refused connection; says so (with why) the first time.
fn refuse(refused: &AtomicU64, from: SocketAddr, why: &str) {
    if refused.fetch_add(1, Ordering::Relaxed) == 0 {
        tracing::warn!(
            "live view: closed the connection of {from}: {why} (further ones are counted, \
             not logged)"
        );
    }
}

fn setup(address: SocketAddr, reason: String) -> TransportError {
    TransportError::Setup {
        transport: TRANSPORT,
        what: format!("a Foxglove WebSocket server on {address}"),
        reason,
    }
}

/// Messages of type `M` on one channel of a [`LiveView`]: encoded (CDR, into a buffer
/// reused from message to message) only while a client is subscribed.
pub struct LiveSink<M> {
    channel: Arc<RawChannel>,
    buffer: Vec<u8>,
    oversized: Arc<AtomicU64>,
    _message: PhantomData<fn(M)>,
}

impl<M> LiveSink<M> {
    /// Whether a viewer is subscribed now (what is sent otherwise goes nowhere).
    pub fn wanted(&self) -> bool {
        self.channel.has_sinks()
    }

    /// A handle that tells [`LiveSink::wanted`] from elsewhere (another thread), so a
    /// message costly to make (an image to compress) is made only while watched.
    pub fn watcher(&self) -> Watcher {
        Watcher(self.channel.clone())
    }
}

/// Whether a viewer watches a channel now ([`LiveSink::watcher`]).
#[derive(Clone)]
pub struct Watcher(Arc<RawChannel>);

impl Watcher {
    /// Whether a viewer is subscribed now.
    pub fn wanted(&self) -> bool {
        self.0.has_sinks()
    }
}

impl<M: Message> Sink<M> for LiveSink<M> {
    fn send(&mut self, message: &M, stamp_ns: u64) -> Result<(), TransportError> {
        if !self.channel.has_sinks() {
            return Ok(());
        }
        self.buffer.clear();
        posestream_msgs::encode_into(message, &mut self.buffer).map_err(|e| {
            TransportError::Send {
                transport: TRANSPORT,
                topic: self.channel.topic().to_string(),
                reason: e.to_string(),
            }
        })?;
        if self.buffer.len() > LiveView::MAX_MESSAGE_BYTES {
            self.oversized.fetch_add(1, Ordering::Relaxed);
            return Ok(());
        }
        self.channel
            .log_with_meta(&self.buffer, PartialMetadata::with_log_time(stamp_ns));
        Ok(())
    }
}

impl<M: Message> EncodedSink<M> for LiveSink<M> {
    fn wanted(&self) -> bool {
        self.channel.has_sinks()
    }

    fn send_encoded(&mut self, data: &[u8], stamp_ns: u64) -> Result<(), TransportError> {
        if !self.channel.has_sinks() {
            return Ok(());
        }
        if data.len() > LiveView::MAX_MESSAGE_BYTES {
            self.oversized.fetch_add(1, Ordering::Relaxed);
            return Ok(());
        }
        self.channel
            .log_with_meta(data, PartialMetadata::with_log_time(stamp_ns));
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use std::io::Write;

    /// Polls `f` for up to 5 s until it holds.
    fn eventually(f: impl Fn() -> bool) -> bool {
        (0..250).any(|_| {
            std::thread::sleep(std::time::Duration::from_millis(20));
            f()
        })
    }

    fn upgrade(address: SocketAddr) -> std::net::TcpStream {
        let mut s = std::net::TcpStream::connect(address).expect("connects");
        write!(
            s,
            "GET / HTTP/1.1\r\nHost: {address}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
             Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\
             Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"
        )
        .expect("writes");
        s
    }

    #[test]
    fn viewers_beyond_the_cap_and_silent_connections_are_closed_and_counted() {
        let live = LiveView::serve("127.0.0.1:0".parse().expect("address")).expect("serves");
        let address = live.address();
        assert_ne!(address.port(), 0);
        // Connections that never say what they are do not hold the viewers' places.
        let silent: Vec<std::net::TcpStream> = (0..LiveView::MAX_VIEWERS)
            .map(|_| std::net::TcpStream::connect(address).expect("connects"))
            .collect();
        let viewers: Vec<std::net::TcpStream> = (0..LiveView::MAX_VIEWERS + 2)
            .map(|_| upgrade(address))
            .collect();
        assert!(eventually(|| live.refused() == 2), "{}", live.refused());
        assert!(eventually(|| live.clients() == LiveView::MAX_VIEWERS));
        // The silent ones are closed once the handshake's time is up.
        std::thread::sleep(LiveView::HANDSHAKE);
        let all = 2 + LiveView::MAX_VIEWERS as u64;
        assert!(eventually(|| live.refused() == all), "{}", live.refused());
        // A viewer gone makes room for another.
        drop(viewers);
        assert!(eventually(|| live.clients() == 0));
        let _again = upgrade(address);
        assert!(eventually(|| live.clients() == 1));
        assert_eq!(live.refused(), all);
        drop(silent);
        live.stop();
    }

    #[test]
    fn binding_errors_name_the_fix() {
        let taken = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
        let e = LiveView::serve(taken.local_addr().expect("address"))
            .err()
            .expect("in use");
        assert!(e.to_string().contains("--foxglove 127.0.0.1:"), "{e}");
        let v6 = bind_error(
            "[::1]:9000".parse().expect("address"),
            &std::io::Error::from(std::io::ErrorKind::AddrInUse),
        );
        assert!(v6.contains("--foxglove [::1]:9001"), "{v6}");
        let elsewhere = LiveView::serve("10.253.254.1:8765".parse().expect("address"))
            .err()
            .expect("not ours");
        assert!(
            elsewhere.to_string().contains("0.0.0.0:8765"),
            "{elsewhere}"
        );
    }
}
