//! What the live view's door reads of a connection's bytes: the HTTP upgrade request
//! ([`check_request`]), the server's answer to it ([`upgraded`]) and the WebSocket frames
//! both ways ([`Frames`]), checked and counted without decoding a message.
//!
//! Written here rather than taken from `tungstenite` (which the `foxglove` crate's server
//! behind the door uses) because the door forwards bytes as they come and the server
//! decodes them: the door needs each frame's header and nothing else, so it never holds a
//! message, and it can refuse a frame from its header before its payload has arrived.
//! The HTTP head is parsed by `httparse`. Both are pure functions of the bytes, fuzzed
//! (`fuzz/fuzz_targets/live_view.rs`).

/// The longest HTTP head (request or response) read; longer ones are refused (431).
pub const MAX_HEAD: usize = 16 << 10;

/// The largest frame payload, and the largest message (the sum of its fragments), that a
/// viewer may send. A viewer's messages are `subscribe` / `unsubscribe` requests (JSON),
/// a few dozen bytes per channel; 1 MiB holds tens of thousands of channels.
pub const MAX_VIEWER_MESSAGE: u64 = 1 << 20;

/// The subprotocols the server behind the door speaks (the `foxglove` crate's names).
pub const SUBPROTOCOLS: [&str; 2] = ["foxglove.sdk.v1", "foxglove.sdk.v1.1"];

/// Why a request or a frame was refused: an HTTP status for a request, a reason for a
/// frame (the connection is then closed).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Refusal {
    /// The request is not a WebSocket upgrade to the Foxglove protocol.
    #[error("{status} {reason}: {detail}")]
    Request {
        /// The HTTP status answered.
        status: u16,
        /// Its reason phrase.
        reason: &'static str,
        /// What was wrong, said to the client in the response's body.
        detail: String,
    },
    /// A frame that breaks the protocol or the door's limits.
    #[error("{0}")]
    Frame(String),
}

impl Refusal {
    fn request(status: u16, reason: &'static str, detail: impl Into<String>) -> Self {
        Self::Request {
            status,
            reason,
            detail: detail.into(),
        }
    }

    /// The HTTP response that says this refusal (a request's status, or 400), closing the
    /// connection.
    pub fn response(&self) -> Vec<u8> {
        let (status, reason, detail) = match self {
            Self::Request {
                status,
                reason,
                detail,
            } => (*status, *reason, detail.as_str()),
            Self::Frame(detail) => (400, "Bad Request", detail.as_str()),
        };
        let body = format!("{detail}\n");
        let mut head = format!(
            "HTTP/1.1 {status} {reason}\r\nContent-Type: text/plain; charset=utf-8\r\n\
             Content-Length: {}\r\nConnection: close\r\n",
            body.len()
        );
        if status == 426 {
            head.push_str("Upgrade: websocket\r\nSec-WebSocket-Version: 13\r\n");
        }
        if status == 503 {
            head.push_str("Retry-After: 5\r\n");
        }
        head.push_str("\r\n");
        head.push_str(&body);
        head.into_bytes()
    }
}

/// The 503 answered when every viewer's place is taken.
pub fn full(viewers: usize) -> Refusal {
    Refusal::request(
        503,
        "Service Unavailable",
        format!("{viewers} viewers are connected, the most this live view serves; try later"),
    )
}

/// Where the head in `bytes` ends (just past its blank line, CRLF or bare LF), if it is
/// all there. A head longer than [`MAX_HEAD`] is refused (431); a TLS handshake (a
/// client of `wss://`) at once.
pub fn head_end(bytes: &[u8]) -> Result<Option<usize>, Refusal> {
    if bytes.first() == Some(&0x16) {
        return Err(Refusal::request(
            400,
            "Bad Request",
            "a TLS handshake: the live view speaks plain ws://, not wss://",
        ));
    }
    let within = &bytes[..bytes.len().min(MAX_HEAD)];
    let crlf = within
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .map(|i| i + 4);
    let lf = within.windows(2).position(|w| w == b"\n\n").map(|i| i + 2);
    match crlf.into_iter().chain(lf).min() {
        Some(end) => Ok(Some(end)),
        None if bytes.len() >= MAX_HEAD => Err(Refusal::request(
            431,
            "Request Header Fields Too Large",
            format!("the request head is longer than {MAX_HEAD} bytes"),
        )),
        None => Ok(None),
    }
}

/// Checks a whole request head (`head`, up to its blank line): a WebSocket upgrade
/// (RFC 6455 section 4.2.1) that offers one of [`SUBPROTOCOLS`]. Anything else is refused
/// with the status that says why: a plain page request gets 426 and where to open the
/// view instead.
pub fn check_request(head: &[u8]) -> Result<(), Refusal> {
    let mut headers = [httparse::EMPTY_HEADER; 64];
    let mut request = httparse::Request::new(&mut headers);
    match request.parse(head) {
        Ok(httparse::Status::Complete(_)) => {}
        Ok(httparse::Status::Partial) => {
            return Err(Refusal::request(
                400,
                "Bad Request",
                "an incomplete request head",
            ));
        }
        Err(httparse::Error::TooManyHeaders) => {
            return Err(Refusal::request(
                431,
                "Request Header Fields Too Large",
                "more than 64 header fields",
            ));
        }
        Err(e) => {
            return Err(Refusal::request(
                400,
                "Bad Request",
                format!("not an HTTP request ({e})"),
            ));
        }
    }
    if request.version != Some(1) {
        return Err(Refusal::request(
            505,
            "HTTP Version Not Supported",
            "a WebSocket upgrade is an HTTP/1.1 request",
        ));
    }
    if request.method != Some("GET") {
        return Err(Refusal::request(
            405,
            "Method Not Allowed",
            "only a GET HTTP/1.1 WebSocket upgrade is served",
        ));
    }
    let headers: &[httparse::Header<'_>] = request.headers;
    let values = |name: &'static str| header_values(headers, name);
    let has_token =
        |name: &'static str, token: &str| values(name).any(|v| v.eq_ignore_ascii_case(token));
    if !has_token("upgrade", "websocket") || !has_token("connection", "upgrade") {
        return Err(Refusal::request(
            426,
            "Upgrade Required",
            "this is a Foxglove live view: open it in the Foxglove app (Open connection, \
             Foxglove WebSocket) at ws://this-address",
        ));
    }
    if !values("sec-websocket-version").any(|v| v == "13") {
        return Err(Refusal::request(
            426,
            "Upgrade Required",
            "WebSocket version 13 only",
        ));
    }
    // The key is 16 random bytes in base64: 24 characters.
    if values("sec-websocket-key")
        .filter(|v| v.len() == 24)
        .count()
        != 1
    {
        return Err(Refusal::request(
            400,
            "Bad Request",
            "no Sec-WebSocket-Key of 16 bytes in base64",
        ));
    }
    if !values("sec-websocket-protocol").any(|v| SUBPROTOCOLS.contains(&v)) {
        return Err(Refusal::request(
            400,
            "Bad Request",
            format!(
                "no subprotocol this live view speaks offered (Sec-WebSocket-Protocol: {})",
                SUBPROTOCOLS.join(" or ")
            ),
        ));
    }
    Ok(())
}

/// The comma-separated values of every header `name` (case-insensitive), trimmed.
fn header_values<'a>(
    headers: &'a [httparse::Header<'a>],
    name: &'static str,
) -> impl Iterator<Item = &'a str> {
    headers
        .iter()
        .filter(move |h| h.name.eq_ignore_ascii_case(name))
        .flat_map(|h| std::str::from_utf8(h.value).unwrap_or("").split(','))
        .map(str::trim)
}

/// Whether a server's response head says the upgrade was made (status 101).
pub fn upgraded(head: &[u8]) -> bool {
    let mut headers = [httparse::EMPTY_HEADER; 64];
    let mut response = httparse::Response::new(&mut headers);
    matches!(response.parse(head), Ok(httparse::Status::Complete(_))) && response.code == Some(101)
}

/// What one stretch of frames held: the control frames the door counts.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct Seen {
    /// Ping frames.
    pub pings: u32,
    /// Pong frames.
    pub pongs: u32,
    /// A close frame came.
    pub close: bool,
    /// The payload of the last pong whose 8 bytes ended here (unmasked): what the door
    /// put in its ping, when the viewer read it.
    pub pong_payload: Option<u64>,
}

/// WebSocket frames (RFC 6455 section 5.2) in one direction, read header by header from
/// bytes as they arrive, payloads skipped: a frame is refused from its header when it
/// breaks the protocol (an extension's bits, which none was negotiated for; an unknown
/// opcode; a viewer's frame unmasked or a server's masked; a fragmented or long control
/// frame; a continuation of nothing) or when a viewer's message outgrows
/// [`MAX_VIEWER_MESSAGE`].
#[derive(Debug, Clone)]
pub struct Frames {
    from_viewer: bool,
    header: [u8; 14],
    have: usize,
    payload_left: u64,
    /// Bytes of the data message being sent in fragments, while one is.
    message: Option<u64>,
    /// An 8-byte pong's payload as it comes: its bytes so far (unmasked), how many, and
    /// its frame's masking key.
    pong: Option<([u8; 8], usize, [u8; 4])>,
}

impl Frames {
    /// A viewer's frames: masked, each message at most [`MAX_VIEWER_MESSAGE`].
    pub fn from_viewer() -> Self {
        Self::new(true)
    }

    /// The server's frames: unmasked; any size (the server caps its own messages).
    pub fn from_server() -> Self {
        Self::new(false)
    }

    fn new(from_viewer: bool) -> Self {
        Self {
            from_viewer,
            header: [0; 14],
            have: 0,
            payload_left: 0,
            message: None,
            pong: None,
        }
    }

    /// Whether the bytes read so far end a frame (none is half read): a control frame of
    /// our own may be put in here (RFC 6455 5.5: also between a message's fragments).
    pub fn at_boundary(&self) -> bool {
        self.have == 0 && self.payload_left == 0
    }

    /// Reads `bytes`, the next ones of the stream; adds the control frames whose headers
    /// end in them to `seen`. After a refusal the stream is not to be read further.
    pub fn scan(&mut self, mut bytes: &[u8], seen: &mut Seen) -> Result<(), Refusal> {
        while !bytes.is_empty() {
            if self.payload_left > 0 {
                let skip = usize::try_from(self.payload_left)
                    .map_or(bytes.len(), |left| left.min(bytes.len()));
                if let Some((payload, have, mask)) = self.pong.as_mut() {
                    for &b in &bytes[..skip] {
                        payload[*have] = b ^ mask[*have % 4];
                        *have += 1;
                    }
                    if *have == 8 {
                        seen.pong_payload = Some(u64::from_be_bytes(*payload));
                        self.pong = None;
                    }
                }
                bytes = &bytes[skip..];
                self.payload_left -= skip as u64;
                continue;
            }
            let needed = self.header_len();
            let take = (needed - self.have).min(bytes.len());
            self.header[self.have..self.have + take].copy_from_slice(&bytes[..take]);
            self.have += take;
            bytes = &bytes[take..];
            // The length's size is known from the second byte: look again.
            if self.have == needed && self.header_len() == needed {
                self.frame(seen)?;
                self.have = 0;
            }
        }
        Ok(())
    }

    /// The header's length as far as its first two bytes tell (2 until they are here).
    fn header_len(&self) -> usize {
        if self.have < 2 {
            return 2;
        }
        let length = match self.header[1] & 0x7f {
            126 => 2,
            127 => 8,
            _ => 0,
        };
        let mask = if self.header[1] & 0x80 != 0 { 4 } else { 0 };
        2 + length + mask
    }

    /// Checks the complete header in `self.header` and counts it.
    fn frame(&mut self, seen: &mut Seen) -> Result<(), Refusal> {
        let refuse = |why: String| Err(Refusal::Frame(why));
        let (b0, b1) = (self.header[0], self.header[1]);
        let fin = b0 & 0x80 != 0;
        let opcode = b0 & 0x0f;
        if b0 & 0x70 != 0 {
            return refuse("a frame with an extension's bits set (none was negotiated)".into());
        }
        let masked = b1 & 0x80 != 0;
        if masked != self.from_viewer {
            return refuse(if self.from_viewer {
                "an unmasked frame from a viewer".into()
            } else {
                "a masked frame from the server".into()
            });
        }
        let length = match b1 & 0x7f {
            126 => u64::from(u16::from_be_bytes([self.header[2], self.header[3]])),
            127 => {
                let mut eight = [0_u8; 8];
                eight.copy_from_slice(&self.header[2..10]);
                let length = u64::from_be_bytes(eight);
                if length >> 63 != 0 {
                    return refuse("a frame length with its top bit set".into());
                }
                length
            }
            short => u64::from(short),
        };
        match opcode {
            0x8..=0xa => {
                if !fin || length > 125 {
                    return refuse("a fragmented or over-long control frame".into());
                }
                match opcode {
                    0x8 => seen.close = true,
                    0x9 => seen.pings = seen.pings.saturating_add(1),
                    _ => {
                        seen.pongs = seen.pongs.saturating_add(1);
                        // A viewer's pong of 8 bytes may answer the door's ping.
                        if self.from_viewer && length == 8 {
                            let at = self.header_len() - 4;
                            let mut mask = [0_u8; 4];
                            mask.copy_from_slice(&self.header[at..at + 4]);
                            self.pong = Some(([0; 8], 0, mask));
                        }
                    }
                }
            }
            0x0..=0x2 => {
                let so_far = match (opcode, self.message) {
                    (0x0, Some(so_far)) => so_far,
                    (0x0, None) => return refuse("a continuation frame of no message".into()),
                    (_, Some(_)) => {
                        return refuse("a new message before the last one's final frame".into());
                    }
                    (_, None) => 0,
                };
                let total = so_far.saturating_add(length);
                if self.from_viewer && total > MAX_VIEWER_MESSAGE {
                    return refuse(format!(
                        "a message of more than {MAX_VIEWER_MESSAGE} bytes from a viewer"
                    ));
                }
                self.message = (!fin).then_some(total);
            }
            other => return refuse(format!("a frame with the unknown opcode {other:#x}")),
        }
        self.payload_left = length;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A viewer's frame: masked with a zero key (the payload unchanged).
    fn viewer_frame(fin: bool, opcode: u8, payload_len: usize) -> Vec<u8> {
        let mut f = vec![u8::from(fin) << 7 | opcode];
        match payload_len {
            0..=125 => f.push(0x80 | payload_len as u8),
            126..=0xffff => {
                f.push(0x80 | 126);
                f.extend_from_slice(&(payload_len as u16).to_be_bytes());
            }
            _ => {
                f.push(0x80 | 127);
                f.extend_from_slice(&(payload_len as u64).to_be_bytes());
            }
        }
        f.extend_from_slice(&[0; 4]);
        f.resize(f.len() + payload_len, b'x');
        f
    }

    fn upgrade_request(protocol: &str) -> String {
        format!(
            "GET / HTTP/1.1\r\nHost: h\r\nUpgrade: websocket\r\nConnection: keep-alive, Upgrade\r\n\
             Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\
             Sec-WebSocket-Protocol: {protocol}\r\n\r\n"
        )
    }

    #[test]
    fn an_upgrade_to_the_protocol_passes_and_anything_else_gets_its_status() {
        assert_eq!(
            check_request(upgrade_request("foxglove.sdk.v1").as_bytes()),
            Ok(())
        );
        assert_eq!(
            check_request(upgrade_request("x, foxglove.sdk.v1.1").as_bytes()),
            Ok(())
        );
        let status = |head: &str| match check_request(head.as_bytes()) {
            Err(Refusal::Request { status, .. }) => status,
            other => panic!("{other:?}"),
        };
        assert_eq!(status("GET / HTTP/1.1\r\nHost: h\r\n\r\n"), 426);
        assert_eq!(status(&upgrade_request("foxglove.websocket.v2")), 400);
        assert_eq!(
            status(&upgrade_request("foxglove.sdk.v1").replace("GET", "POST")),
            405
        );
        assert_eq!(
            status(&upgrade_request("foxglove.sdk.v1").replace(": 13", ": 8")),
            426
        );
        assert_eq!(status("\x01\x03\x01 not HTTP\r\n\r\n"), 400);
        assert_eq!(
            status(&upgrade_request("foxglove.sdk.v1").replace("HTTP/1.1", "HTTP/1.0")),
            505
        );
        assert!(head_end(b"\x16\x03\x01\x02\x00").is_err(), "TLS");
        assert_eq!(head_end(b"GET / HTTP/1.1\nHost: h\n\nrest"), Ok(Some(24)));
        let many = format!("GET / HTTP/1.1\r\n{}\r\n", "A: b\r\n".repeat(65));
        assert_eq!(status(&many), 431);
        let response = String::from_utf8(
            check_request(b"GET / HTTP/1.1\r\n\r\n")
                .unwrap_err()
                .response(),
        )
        .expect("text");
        assert!(
            response.starts_with("HTTP/1.1 426 Upgrade Required\r\n"),
            "{response}"
        );
        assert!(response.contains("Foxglove app"), "{response}");
    }

    #[test]
    fn a_head_ends_at_its_blank_line_within_the_limit() {
        assert_eq!(head_end(b"GET / HTTP/1.1\r\n"), Ok(None));
        assert_eq!(head_end(b"GET / HTTP/1.1\r\n\r\nrest"), Ok(Some(18)));
        assert!(head_end(&vec![b'a'; MAX_HEAD]).is_err());
        assert!(upgraded(
            b"HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\n\r\n"
        ));
        assert!(!upgraded(b"HTTP/1.1 400 Bad Request\r\n\r\n"));
    }

    #[test]
    fn frames_are_counted_across_any_split_of_the_stream() {
        let mut stream = Vec::new();
        for _ in 0..3 {
            stream.extend(viewer_frame(true, 0x9, 4));
        }
        stream.extend(viewer_frame(false, 0x1, 70_000));
        // A pong of 8 bytes: its payload read (this one's masking key is all zeros).
        stream.extend(viewer_frame(true, 0xa, 8));
        stream.extend(viewer_frame(true, 0x0, 300));
        stream.extend(viewer_frame(true, 0x8, 2));
        for chunk in [1, 2, 3, 7, 4096, stream.len()] {
            let (mut frames, mut seen) = (Frames::from_viewer(), Seen::default());
            for piece in stream.chunks(chunk) {
                frames.scan(piece, &mut seen).expect("valid");
            }
            assert_eq!(
                seen,
                Seen {
                    pings: 3,
                    pongs: 1,
                    close: true,
                    pong_payload: Some(u64::from_be_bytes(*b"xxxxxxxx")),
                },
                "chunks of {chunk}"
            );
        }
    }

    #[test]
    fn a_viewer_message_over_the_limit_is_refused_from_its_header() {
        let refused = |stream: &[u8]| {
            Frames::from_viewer()
                .scan(stream, &mut Seen::default())
                .is_err()
        };
        let big = MAX_VIEWER_MESSAGE as usize + 1;
        // The header alone is enough: no payload has to arrive.
        assert!(refused(&viewer_frame(true, 0x1, big)[..14]));
        // Fragments that add up beyond it, each small.
        let half = MAX_VIEWER_MESSAGE as usize / 2 + 1;
        let mut two = viewer_frame(false, 0x2, half);
        two.extend(viewer_frame(true, 0x0, half));
        assert!(refused(&two));
        assert!(!refused(&viewer_frame(
            true,
            0x1,
            MAX_VIEWER_MESSAGE as usize
        )));
        // Breaking the protocol.
        assert!(refused(&[0x81, 0x05, b'h', b'e', b'l', b'l', b'o'])); // unmasked
        assert!(refused(&viewer_frame(true, 0x3, 1))); // unknown opcode
        assert!(refused(&viewer_frame(false, 0x9, 1))); // fragmented ping
        assert!(refused(&viewer_frame(true, 0x9, 126))); // long ping
        assert!(refused(&viewer_frame(true, 0x0, 1))); // continuation of nothing
        assert!(refused(&[0xc1, 0x80, 0, 0, 0, 0])); // compressed (RSV1)
        let mut interleaved = viewer_frame(false, 0x1, 1);
        interleaved.extend(viewer_frame(true, 0x1, 1));
        assert!(refused(&interleaved));
        let mut top = vec![0x82, 0x80 | 127, 0x80, 0, 0, 0, 0, 0, 0, 0];
        top.extend([0; 4]);
        assert!(refused(&top));
        // The server's frames are unmasked, and not capped.
        let mut server = Frames::from_server();
        let mut seen = Seen::default();
        server
            .scan(&[0x8a, 0x00, 0x82, 126, 0x01, 0x00], &mut seen)
            .expect("valid");
        assert_eq!(seen.pongs, 1);
        assert!(
            Frames::from_server()
                .scan(&[0x8a, 0x80, 0, 0, 0, 0], &mut seen)
                .is_err()
        );
    }
}
