//! The live view's door: the address a user names, in front of the `foxglove` crate's
//! server (which listens on the loopback interface and takes any number of clients with
//! `tungstenite`'s limits: 64 MiB messages, pongs queued without bound). What a viewer
//! can cost is bounded here, by the bytes it sends, before the server sees them:
//!
//! - a connection has [`LiveView::HANDSHAKE`] to send its whole request head (at most
//!   [`wire::MAX_HEAD`]); at most [`LiveView::MAX_PENDING`] are waiting at once, and a new
//!   one displaces the one waiting longest, so slow heads cannot keep viewers out;
//! - a head that is not an upgrade to the protocol gets its HTTP status (426 for a page
//!   request, 400, 405, 431), a viewer beyond [`LiveView::MAX_VIEWERS`] a 503, and the
//!   connection is closed: a place is held only by an upgrade the server made (101), and
//!   freed when the connection ends for any reason;
//! - a viewer's frames are read header by header ([`wire::Frames`]): a message over
//!   [`wire::MAX_VIEWER_MESSAGE`] or a frame that breaks the protocol ends the viewer
//!   before its payload reaches the server;
//! - pings not yet answered are at most [`LiveView::MAX_UNANSWERED`], and a viewer that
//!   takes nothing for [`LiveView::STALLED`] is dropped: a viewer that does not read ends
//!   instead of queueing pongs or messages;
//! - the door pings each viewer every [`LiveView::KEEPALIVE`] (between the server's
//!   frames) and ends one that has not answered when the next ping is due: an idle
//!   connection that does not answer holds no place for long.

use std::collections::VecDeque;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};
use tokio::sync::{Notify, OwnedSemaphorePermit, Semaphore};

use super::LiveView;
use super::wire::{self, Frames, Refusal, Seen};

/// What the door refused and ended, counted.
#[derive(Debug, Default)]
pub(super) struct Counts {
    /// Connections closed before they became viewers.
    pub refused: AtomicU64,
    /// Viewers ended by the door (a refused frame, pings unanswered, not reading).
    pub dropped: AtomicU64,
}

impl Counts {
    /// Counts a refused connection; says so (with why) the first time.
    fn refuse(&self, from: SocketAddr, why: &dyn std::fmt::Display) {
        if self.refused.fetch_add(1, Ordering::Relaxed) == 0 {
            tracing::warn!(
                "live view: closed the connection of {from}: {why} (further ones are counted, \
                 not logged)"
            );
        }
    }

    /// Counts a viewer ended by the door; says so (with why) the first time.
    fn drop_viewer(&self, from: SocketAddr, why: &dyn std::fmt::Display) {
        if self.dropped.fetch_add(1, Ordering::Relaxed) == 0 {
            tracing::warn!(
                "live view: ended the viewer at {from}: {why} (further ones are counted, \
                 not logged)"
            );
        }
    }
}

/// Connections still sending their request head, oldest first, each with a bell that
/// tells it to give up its place.
#[derive(Default)]
struct Waiting {
    queue: Mutex<VecDeque<(u64, Arc<Notify>)>>,
}

impl Waiting {
    /// Takes a place for connection `id`, displacing the one waiting longest when all
    /// [`LiveView::MAX_PENDING`] are taken.
    fn enter(&self, id: u64) -> Arc<Notify> {
        let bell = Arc::new(Notify::new());
        let mut queue = self.queue.lock().unwrap_or_else(|e| e.into_inner());
        if queue.len() >= LiveView::MAX_PENDING
            && let Some((_, oldest)) = queue.pop_front()
        {
            oldest.notify_one();
        }
        queue.push_back((id, bell.clone()));
        bell
    }

    fn leave(&self, id: u64) {
        let mut queue = self.queue.lock().unwrap_or_else(|e| e.into_inner());
        queue.retain(|(i, _)| *i != id);
    }
}

/// Accepts connections on `front` and passes each that becomes a viewer to the server on
/// `server` (the module's doc says how).
pub(super) async fn pass_viewers(
    front: tokio::net::TcpListener,
    server: SocketAddr,
    counts: Arc<Counts>,
) {
    let viewers = Arc::new(Semaphore::new(LiveView::MAX_VIEWERS));
    let waiting = Arc::new(Waiting::default());
    for id in 0_u64.. {
        let (viewer, from) = match front.accept().await {
            Ok(v) => v,
            Err(e) => {
                // Out of file descriptors and the like: wait, then go on.
                tracing::debug!("live view: accepting a viewer: {e}");
                tokio::time::sleep(std::time::Duration::from_millis(100)).await;
                continue;
            }
        };
        let bell = waiting.enter(id);
        let (viewers, waiting, counts) = (viewers.clone(), waiting.clone(), counts.clone());
        tokio::spawn(async move {
            let admitted = tokio::select! {
                admitted = tokio::time::timeout(
                    LiveView::HANDSHAKE,
                    admit(viewer, server, &viewers),
                ) => admitted,
                () = bell.notified() => {
                    waiting.leave(id);
                    counts.refuse(from, &"newer connections came while it was still sending its request");
                    return;
                }
            };
            waiting.leave(id);
            match admitted {
                Ok(Ok(admitted)) => {
                    if let Err(why) = relay(admitted).await {
                        counts.drop_viewer(from, &why);
                    }
                }
                Ok(Err(why)) => counts.refuse(from, &why),
                Err(_) => counts.refuse(from, &"it sent no WebSocket upgrade request in time"),
            }
        });
    }
}

/// A viewer the server upgraded, with its place and the bytes either side sent after
/// the heads.
struct Admitted {
    viewer: TcpStream,
    upstream: TcpStream,
    _place: OwnedSemaphorePermit,
    from_viewer: Vec<u8>,
    from_server: Vec<u8>,
}

/// Reads the viewer's request head, answers a refusal with its status, takes a viewer's
/// place and has the server upgrade the connection.
async fn admit(
    mut viewer: TcpStream,
    server: SocketAddr,
    viewers: &Arc<Semaphore>,
) -> Result<Admitted, Refusal> {
    let (head, rest) = match read_head(&mut viewer).await {
        Ok(Some(read)) => read,
        Ok(None) => {
            return Err(Refusal::Frame(
                "it closed before its request head ended".into(),
            ));
        }
        Err(refusal) => return Err(answer(&mut viewer, refusal).await),
    };
    if let Err(refusal) = wire::check_request(&head) {
        return Err(answer(&mut viewer, refusal).await);
    }
    let Ok(place) = viewers.clone().try_acquire_owned() else {
        return Err(answer(&mut viewer, wire::full(LiveView::MAX_VIEWERS)).await);
    };
    let gone = |e: std::io::Error| Refusal::Frame(format!("the server behind the door: {e}"));
    let mut upstream = TcpStream::connect(server).await.map_err(gone)?;
    upstream.write_all(&head).await.map_err(gone)?;
    let (response, from_server) = match read_head(&mut upstream).await {
        Ok(Some(read)) => read,
        _ => {
            return Err(Refusal::Frame(
                "the server did not answer the upgrade".into(),
            ));
        }
    };
    // The server's answer goes to the viewer whatever it is; only an upgrade keeps a place.
    let _ = viewer.write_all(&response).await;
    if !wire::upgraded(&response) {
        let _ = viewer.shutdown().await;
        return Err(Refusal::Frame("the server refused the upgrade".into()));
    }
    Ok(Admitted {
        viewer,
        upstream,
        _place: place,
        from_viewer: rest,
        from_server,
    })
}

/// Writes a refusal's HTTP response and closes; gives the refusal back.
async fn answer(viewer: &mut TcpStream, refusal: Refusal) -> Refusal {
    let _ = viewer.write_all(&refusal.response()).await;
    let _ = viewer.shutdown().await;
    refusal
}

/// Reads an HTTP head (up to its blank line, at most [`wire::MAX_HEAD`]) and what came
/// after it in the same reads; `None` when the peer closed first.
async fn read_head(stream: &mut TcpStream) -> Result<Option<(Vec<u8>, Vec<u8>)>, Refusal> {
    let mut bytes = Vec::with_capacity(1024);
    let mut chunk = [0_u8; 2048];
    loop {
        let n = match stream.read(&mut chunk).await {
            Ok(0) | Err(_) => return Ok(None),
            Ok(n) => n,
        };
        bytes.extend_from_slice(&chunk[..n]);
        if let Some(end) = wire::head_end(&bytes)? {
            let rest = bytes.split_off(end);
            return Ok(Some((bytes, rest)));
        }
    }
}

/// Relays an upgraded viewer's frames both ways until either side ends or the viewer
/// breaks a limit (the error says which).
async fn relay(admitted: Admitted) -> Result<(), Refusal> {
    let Admitted {
        viewer,
        upstream,
        _place,
        from_viewer,
        from_server,
    } = admitted;
    let unanswered = AtomicI64::new(0);
    let ping = Keepalive::default();
    // A small send buffer: a viewer that reads slowly makes room often, so a write
    // waits on the viewer's pace, not on megabytes of kernel buffer draining.
    let _ = socket2::SockRef::from(&viewer).set_send_buffer_size(VIEWER_SEND_BUFFER);
    let (viewer_in, viewer_out) = viewer.into_split();
    let (server_in, server_out) = upstream.into_split();
    let inbound = inbound(viewer_in, server_out, from_viewer, &unanswered, &ping);
    let outbound = outbound(server_in, viewer_out, from_server, &unanswered, &ping);
    tokio::pin!(inbound, outbound);
    tokio::select! {
        // The viewer done sending (its half closed, or a refusal): the server's answers
        // still go to it until the server closes.
        ended = &mut inbound => match ended {
            Ok(()) => outbound.await,
            refused => refused,
        },
        ended = &mut outbound => ended,
    }
}

/// The door's last ping to a viewer: its payload (a number the viewer cannot know before
/// it reads the ping), and whether a pong with it came back.
#[derive(Default)]
struct Keepalive {
    payload: AtomicU64,
    answered: AtomicBool,
}

impl Keepalive {
    /// A pong's payload came from the viewer.
    fn pong(&self, payload: u64) {
        if payload == self.payload.load(Ordering::Relaxed) {
            self.answered.store(true, Ordering::Relaxed);
        }
    }

    /// The next ping's frame (server to viewer: final, opcode 9, unmasked, 8 bytes), its
    /// payload remembered and no answer to it yet; whether the last one was answered.
    fn next(
        &self,
        hasher: &std::collections::hash_map::RandomState,
        count: u64,
    ) -> ([u8; 10], bool) {
        use std::hash::BuildHasher;
        let payload = hasher.hash_one((count, std::time::Instant::now()));
        let answered = self.answered.swap(false, Ordering::Relaxed);
        self.payload.store(payload, Ordering::Relaxed);
        let mut frame = [0x89, 0x08, 0, 0, 0, 0, 0, 0, 0, 0];
        frame[2..].copy_from_slice(&payload.to_be_bytes());
        (frame, answered)
    }
}

/// The kernel's send buffer for a viewer's socket, bytes.
const VIEWER_SEND_BUFFER: usize = 128 << 10;

/// The viewer's bytes to the server, `first` (read with its head) first, each frame's
/// header checked and its pings and pongs counted before its bytes are passed on (the
/// server passes over the pongs answering the door's pings, as RFC 6455 has it).
async fn inbound(
    mut from: OwnedReadHalf,
    mut to: OwnedWriteHalf,
    first: Vec<u8>,
    unanswered: &AtomicI64,
    ping: &Keepalive,
) -> Result<(), Refusal> {
    let mut frames = Frames::from_viewer();
    let (mut chunk, mut n) = buffer(first, 16 << 10);
    loop {
        if n == 0 {
            n = from.read(&mut chunk).await.unwrap_or(0);
            if n == 0 {
                let _ = to.shutdown().await;
                return Ok(());
            }
        }
        let mut seen = Seen::default();
        frames.scan(&chunk[..n], &mut seen)?;
        if let Some(payload) = seen.pong_payload {
            ping.pong(payload);
        }
        let pings = i64::from(seen.pings);
        if unanswered.fetch_add(pings, Ordering::Relaxed) + pings > LiveView::MAX_UNANSWERED {
            return Err(Refusal::Frame(format!(
                "more than {} pings unanswered (it does not read)",
                LiveView::MAX_UNANSWERED
            )));
        }
        if to.write_all(&chunk[..n]).await.is_err() {
            return Ok(());
        }
        n = 0;
    }
}

/// The server's bytes to the viewer, `first` first, its pongs counted, and between its
/// frames the door's pings, one every [`LiveView::KEEPALIVE`], each with a payload of its
/// own: a viewer that has not sent the last one's back (RFC 6455 5.5.3) when the next is
/// due is ended (pongs sent ahead, or without reading, answer nothing), as is one that
/// takes nothing for [`LiveView::STALLED`].
async fn outbound(
    mut from: OwnedReadHalf,
    mut to: OwnedWriteHalf,
    first: Vec<u8>,
    unanswered: &AtomicI64,
    ping: &Keepalive,
) -> Result<(), Refusal> {
    let hasher = std::collections::hash_map::RandomState::new();
    let mut frames = Frames::from_server();
    let (mut chunk, mut n) = buffer(first, 64 << 10);
    let (mut pinged, mut next_ping) = (0_u64, tokio::time::Instant::now() + LiveView::KEEPALIVE);
    loop {
        if n == 0 {
            // A ping only between the server's frames (reading is cancel-safe).
            let read = if frames.at_boundary() {
                tokio::select! {
                    read = from.read(&mut chunk) => Some(read),
                    () = tokio::time::sleep_until(next_ping) => None,
                }
            } else {
                Some(from.read(&mut chunk).await)
            };
            let Some(read) = read else {
                let (frame, answered) = ping.next(&hasher, pinged);
                if pinged > 0 && !answered {
                    return Err(Refusal::Frame(format!(
                        "it answered no ping within {} s",
                        LiveView::KEEPALIVE.as_secs()
                    )));
                }
                if !write_within(&mut to, &frame).await? {
                    return Ok(());
                }
                pinged += 1;
                next_ping = tokio::time::Instant::now() + LiveView::KEEPALIVE;
                continue;
            };
            n = read.unwrap_or(0);
            if n == 0 {
                return Ok(());
            }
        }
        let mut seen = Seen::default();
        frames.scan(&chunk[..n], &mut seen)?;
        unanswered.fetch_sub(i64::from(seen.pongs), Ordering::Relaxed);
        if !write_within(&mut to, &chunk[..n]).await? {
            return Ok(());
        }
        n = 0;
    }
}

/// Writes `bytes` to a viewer, each write taking some of them within
/// [`LiveView::STALLED`] (a slow reader makes progress); false when the viewer is gone.
async fn write_within(to: &mut OwnedWriteHalf, bytes: &[u8]) -> Result<bool, Refusal> {
    let mut written = 0;
    while written < bytes.len() {
        match tokio::time::timeout(LiveView::STALLED, to.write(&bytes[written..])).await {
            Ok(Ok(0) | Err(_)) => return Ok(false),
            Ok(Ok(taken)) => written += taken,
            Err(_) => {
                return Err(Refusal::Frame(format!(
                    "it took nothing for {} s (it does not read)",
                    LiveView::STALLED.as_secs()
                )));
            }
        }
    }
    Ok(true)
}

/// A relay's buffer of at least `size` bytes holding `first` at its start, and how many
/// of its bytes those are.
fn buffer(mut first: Vec<u8>, size: usize) -> (Vec<u8>, usize) {
    let n = first.len();
    first.resize(n.max(size), 0);
    (first, n)
}
