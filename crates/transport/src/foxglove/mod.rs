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
//! The crate's server takes any number of clients, with no bound on what a client sends
//! it, so the address a user names is a door of ours in front of it (`door.rs`): a
//! connection becomes a viewer only by a WebSocket upgrade to the protocol within
//! [`LiveView::HANDSHAKE`], while fewer than [`LiveView::MAX_VIEWERS`] are connected
//! (anything else gets its HTTP status and is closed, [`LiveView::refused`]); a viewer's
//! messages are at most [`wire::MAX_VIEWER_MESSAGE`], its unanswered pings at most
//! [`LiveView::MAX_UNANSWERED`], a viewer that stops reading is ended after
//! [`LiveView::STALLED`], and one that answers none of the door's pings (one every
//! [`LiveView::KEEPALIVE`]) before the next is due ([`LiveView::dropped`]). So at most `MAX_VIEWERS x BACKLOG x
//! MAX_MESSAGE_BYTES` are queued for viewers and `MAX_VIEWERS x MAX_VIEWER_MESSAGE` come
//! from them, whatever they do (docs/limits.md, "Live view").

use std::collections::BTreeMap;
use std::marker::PhantomData;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use foxglove::{ChannelBuilder, Context, PartialMetadata, RawChannel, Schema, WebSocketServer};

use super::{EncodedSink, Message, Sink, TransportError};

mod door;
pub mod wire;

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
    door: Arc<door::Counts>,
    /// Messages not shown for their size.
    oversized: Arc<AtomicU64>,
    server: Mutex<Option<foxglove::WebSocketServerHandle>>,
    // The server's tasks run here; dropped last.
    runtime: Mutex<Option<tokio::runtime::Runtime>>,
}

impl LiveView {
    /// Messages queued for one viewer at most (the oldest are dropped beyond).
    pub const BACKLOG: usize = 16;

    /// The largest message shown (encoded); larger ones are counted and not shown.
    pub const MAX_MESSAGE_BYTES: usize = 1 << 20;

    /// How long a new connection may take to send its WebSocket upgrade request.
    pub const HANDSHAKE: std::time::Duration = std::time::Duration::from_secs(5);

    /// Connections waiting for their upgrade request at once, at most (a new one
    /// displaces the one waiting longest).
    pub const MAX_PENDING: usize = 64;

    /// Pings a viewer may have sent that the server has not answered yet (beyond, the
    /// viewer is ended: it does not read its pongs).
    pub const MAX_UNANSWERED: i64 = 16;

    /// How often the door pings each viewer; a viewer that has not answered the last ping
    /// when the next is due is ended (it does not read, or is gone), so an idle
    /// connection holds a viewer's place no longer than twice this.
    pub const KEEPALIVE: std::time::Duration = std::time::Duration::from_secs(5);

    /// How long a viewer may take nothing that is sent to it before it is ended.
    pub const STALLED: std::time::Duration = std::time::Duration::from_secs(10);

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
        let door = Arc::new(door::Counts::default());
        runtime.spawn(door::pass_viewers(front, inner, door.clone()));
        let oversized = Arc::new(AtomicU64::new(0));
        Ok(Self {
            inner: Arc::new(Inner {
                context,
                channels: Mutex::new(BTreeMap::new()),
                address: bound,
                door,
                oversized,
                server: Mutex::new(Some(handle)),
                runtime: Mutex::new(Some(runtime)),
            }),
        })
    }

    /// Connections closed before they became viewers: [`LiveView::MAX_VIEWERS`] were
    /// open, they sent no upgrade request in time (or were displaced by newer ones while
    /// [`LiveView::MAX_PENDING`] waited), or what they sent was not an upgrade to the
    /// protocol.
    pub fn refused(&self) -> u64 {
        self.inner.door.refused.load(Ordering::Relaxed)
    }

    /// Viewers ended by the door: a message over [`wire::MAX_VIEWER_MESSAGE`] or a frame
    /// that breaks the protocol, more than [`LiveView::MAX_UNANSWERED`] pings unanswered,
    /// or nothing read for [`LiveView::STALLED`].
    pub fn dropped(&self) -> u64 {
        self.inner.door.dropped.load(Ordering::Relaxed)
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

    /// Reads what the door sends a viewer for `for_` and answers each of its pings with
    /// its payload (a masked pong), as a browser does; false if the door closed the
    /// connection.
    fn answer_pings(s: &mut std::net::TcpStream, for_: std::time::Duration) -> bool {
        use std::io::Read;
        let end = std::time::Instant::now() + for_;
        s.set_read_timeout(Some(std::time::Duration::from_millis(100)))
            .expect("timeout");
        let (mut stream, mut head_done) = (Vec::new(), false);
        let mut buf = [0_u8; 64 << 10];
        while std::time::Instant::now() < end {
            match s.read(&mut buf) {
                Ok(0) => return false,
                Ok(n) => stream.extend_from_slice(&buf[..n]),
                Err(_) => continue,
            }
            // The upgrade's response head comes first, then the server's frames.
            if !head_done {
                match wire::head_end(&stream) {
                    Ok(Some(at)) => {
                        stream.drain(..at);
                        head_done = true;
                    }
                    _ => continue,
                }
            }
            while let Some(&[b0, b1]) = stream.get(..2) {
                let (len, at) = match b1 & 0x7f {
                    126 => match stream.get(2..4) {
                        Some(l) => (u16::from_be_bytes([l[0], l[1]]) as usize, 4),
                        None => break,
                    },
                    127 => match stream.get(2..10) {
                        Some(l) => (u64::from_be_bytes(l.try_into().expect("8")) as usize, 10),
                        None => break,
                    },
                    short => (short as usize, 2),
                };
                let Some(payload) = stream.get(at..at + len) else {
                    break;
                };
                if b0 & 0x0f == 0x9 {
                    let mask = [1_u8, 2, 3, 4];
                    let mut pong = vec![0x8a, 0x80 | len as u8];
                    pong.extend_from_slice(&mask);
                    pong.extend(payload.iter().enumerate().map(|(i, b)| b ^ mask[i % 4]));
                    s.write_all(&pong).expect("pong");
                }
                stream.drain(..at + len);
            }
        }
        true
    }

    /// A viewer's empty pong (masked), answering nothing.
    const EMPTY_PONG: [u8; 6] = [0x8a, 0x80, 1, 2, 3, 4];

    #[test]
    fn idle_viewers_that_answer_no_ping_give_their_places_back() {
        let live = LiveView::serve("127.0.0.1:0".parse().expect("address")).expect("serves");
        let address = live.address();
        // Seven upgrade and then neither read nor answer (three of them after sending
        // pongs ahead, to no ping); one answers the door's pings.
        let idle: Vec<std::net::TcpStream> = (0..LiveView::MAX_VIEWERS - 1)
            .map(|i| {
                let mut s = upgrade(address);
                if i < 3 {
                    std::thread::sleep(std::time::Duration::from_millis(200));
                    for _ in 0..100 {
                        s.write_all(&EMPTY_PONG).expect("pong");
                    }
                }
                s
            })
            .collect();
        let mut alive = upgrade(address);
        assert!(eventually(|| live.clients() == LiveView::MAX_VIEWERS));
        let _ninth = upgrade(address);
        assert!(eventually(|| live.refused() == 1), "{}", live.refused());
        // Within two pings' time the silent ones are ended; the one answering stays.
        assert!(answer_pings(
            &mut alive,
            2 * LiveView::KEEPALIVE + std::time::Duration::from_secs(1)
        ));
        assert!(eventually(|| live.clients() == 1), "{}", live.clients());
        assert_eq!(live.dropped(), LiveView::MAX_VIEWERS as u64 - 1);
        let _tenth = upgrade(address);
        assert!(eventually(|| live.clients() == 2));
        assert!(answer_pings(&mut alive, std::time::Duration::from_secs(1)));
        drop(idle);
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
