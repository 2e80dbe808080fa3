//! A live view: the Foxglove WebSocket protocol (`foxglove.websocket.v1`, served by the
//! `foxglove` crate's server), so the Foxglove app shows what a node publishes with no ROS
//! installation. Each topic is a channel with the same schema and encoding as a
//! recording's (`ros2msg` definitions, CDR messages), so what the app shows live is what
//! it shows from a recording, and a layout works for both.
//!
//! The server is read-only for its clients: it advertises none of the protocol's
//! capabilities (no client publishing, parameters or services), so a viewer can
//! subscribe to channels and nothing else. A message is encoded only while a client is
//! subscribed to its channel. Each client has a bounded backlog
//! ([`LiveView::BACKLOG`] messages); a client that falls further behind is disconnected
//! by the server, so a slow or stalled viewer never holds up a node. The crate's server
//! takes any number of clients, so the address a user names is ours: connections are
//! accepted there and passed to the server (listening on the loopback interface) while
//! fewer than [`LiveView::MAX_VIEWERS`] are open; more are closed at once and counted
//! ([`LiveView::refused`]), so the viewers' backlogs are bounded together.

use std::collections::BTreeMap;
use std::marker::PhantomData;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use foxglove::{ChannelBuilder, Context, PartialMetadata, RawChannel, Schema, WebSocketServer};

use super::{Message, Sink, TransportError};

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
    server: Mutex<Option<foxglove::WebSocketServerHandle>>,
    // The server's tasks run here; dropped last.
    runtime: Mutex<Option<tokio::runtime::Runtime>>,
}

impl LiveView {
    /// Messages queued for one client at most before the server disconnects it.
    pub const BACKLOG: usize = 256;

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
            .map_err(|e| match e.kind() {
                std::io::ErrorKind::AddrInUse => setup(
                    address,
                    format!(
                        "the address is in use (another posestream or Foxglove bridge?): \
                         choose another port, e.g. --foxglove {}:{}",
                        address.ip(),
                        address.port().wrapping_add(1).max(1024)
                    ),
                ),
                _ => setup(address, e.to_string()),
            })?;
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
        Ok(Self {
            inner: Arc::new(Inner {
                context,
                channels: Mutex::new(BTreeMap::new()),
                address: bound,
                refused,
                server: Mutex::new(Some(handle)),
                runtime: Mutex::new(Some(runtime)),
            }),
        })
    }

    /// Connections closed at once because [`LiveView::MAX_VIEWERS`] were open.
    pub fn refused(&self) -> u64 {
        self.inner.refused.load(Ordering::Relaxed)
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
        if channel.has_sinks() {
            channel.log_with_meta(data, PartialMetadata::with_log_time(stamp_ns));
        }
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

/// Accepts viewers on `front` and passes each to the server on `server` while fewer than
/// [`LiveView::MAX_VIEWERS`] are connected; closes (and counts) the others.
async fn pass_viewers(front: tokio::net::TcpListener, server: SocketAddr, refused: Arc<AtomicU64>) {
    let open = Arc::new(tokio::sync::Semaphore::new(LiveView::MAX_VIEWERS));
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
        let Ok(permit) = open.clone().try_acquire_owned() else {
            if refused.fetch_add(1, Ordering::Relaxed) == 0 {
                tracing::warn!(
                    "live view: {} viewers connected already: {from} and later ones are \
                     closed (counted)",
                    LiveView::MAX_VIEWERS
                );
            }
            drop(viewer);
            continue;
        };
        tokio::spawn(async move {
            if let Ok(mut upstream) = tokio::net::TcpStream::connect(server).await {
                let _ = tokio::io::copy_bidirectional(&mut viewer, &mut upstream).await;
            }
            drop(permit);
        });
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
    _message: PhantomData<fn(M)>,
}

impl<M> LiveSink<M> {
    /// Whether a client is subscribed now (what is sent otherwise goes nowhere): a
    /// message costly to make (an image to compress) is made only then.
    pub fn wanted(&self) -> bool {
        self.channel.has_sinks()
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
        self.channel
            .log_with_meta(&self.buffer, PartialMetadata::with_log_time(stamp_ns));
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn viewers_beyond_the_cap_are_closed_and_counted() {
        let live = LiveView::serve("127.0.0.1:0".parse().expect("address")).expect("serves");
        let address = live.address();
        assert_ne!(address.port(), 0);
        let held: Vec<std::net::TcpStream> = (0..LiveView::MAX_VIEWERS + 3)
            .map(|_| std::net::TcpStream::connect(address).expect("connects"))
            .collect();
        for _ in 0..100 {
            if live.refused() == 3 {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        assert_eq!(live.refused(), 3);
        // One closed: room for one more.
        drop(held);
        std::thread::sleep(std::time::Duration::from_millis(200));
        let _again = std::net::TcpStream::connect(address).expect("connects");
        std::thread::sleep(std::time::Duration::from_millis(100));
        assert_eq!(live.refused(), 3);
        live.stop();
    }

    #[test]
    fn a_port_in_use_names_the_option_that_moves_it() {
        let taken = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
        let e = LiveView::serve(taken.local_addr().expect("address"))
            .err()
            .expect("in use");
        assert!(e.to_string().contains("--foxglove 127.0.0.1:"), "{e}");
    }
}
