//! The live view (`--foxglove`) against viewers that attack it, on the release binary: a
//! ping flood that never reads its pongs, messages of tens of MiB, connections that hold
//! viewers' places without becoming viewers. The process stays under the hostile-input
//! memory budget, each attacker is answered (an HTTP status) or ended, and a good viewer
//! is still served afterwards. `POSESTREAM_BIN` runs the same against another build.

mod common;

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Peak resident memory the attacks may cost the whole process (kB).
const MEMORY_BUDGET_KB: u64 = 200 * 1024;

fn binary() -> PathBuf {
    std::env::var_os("POSESTREAM_BIN")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_BIN_EXE_posestream")))
}

/// The demo recording played for ever, shown live on `port`.
fn serve(port: u16) -> Child {
    let mut child = Command::new(binary())
        .current_dir(common::root())
        .args([
            "run",
            "--recording",
            "builtin:recordings/byebye.mcap",
            "--repeat",
            "0",
            "--ros2",
            "false",
            "--foxglove",
            &format!("127.0.0.1:{port}"),
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("starts");
    for _ in 0..300 {
        if TcpStream::connect(("127.0.0.1", port)).is_ok() {
            return child;
        }
        if let Ok(Some(status)) = child.try_wait() {
            panic!("posestream ended before serving: {status}");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    panic!("nothing listens on {port} after 30 s");
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .expect("bind")
        .local_addr()
        .expect("address")
        .port()
}

/// The process's peak resident memory so far (kB), from `/proc`.
fn peak_kb(child: &Child) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{}/status", child.id())).expect("status");
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .expect("VmHWM")
}

fn request(port: u16, protocol: &str) -> String {
    format!(
        "GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
         Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\
         Sec-WebSocket-Protocol: {protocol}\r\n\r\n"
    )
}

/// Sends `head` and reads the response's status line (the first line), with a timeout.
fn status_of(port: u16, head: &str) -> (TcpStream, String) {
    let mut s = TcpStream::connect(("127.0.0.1", port)).expect("connects");
    s.set_read_timeout(Some(Duration::from_secs(10)))
        .expect("timeout");
    s.write_all(head.as_bytes()).expect("writes");
    let mut line = Vec::new();
    let mut byte = [0_u8; 1];
    while !line.ends_with(b"\r\n") {
        match s.read(&mut byte) {
            Ok(1) => line.push(byte[0]),
            _ => break,
        }
    }
    (s, String::from_utf8_lossy(&line).trim().to_string())
}

/// A viewer upgraded to the protocol (status 101).
fn viewer(port: u16) -> TcpStream {
    let (s, status) = status_of(port, &request(port, "foxglove.sdk.v1"));
    assert!(status.starts_with("HTTP/1.1 101"), "{status}");
    s
}

/// A masked client frame (zero key) with `payload_len` bytes.
fn frame(fin: bool, opcode: u8, payload_len: usize, with_payload: bool) -> Vec<u8> {
    let mut f = vec![u8::from(fin) << 7 | opcode];
    if payload_len < 126 {
        f.push(0x80 | payload_len as u8);
    } else {
        f.push(0x80 | 127);
        f.extend_from_slice(&(payload_len as u64).to_be_bytes());
    }
    f.extend_from_slice(&[0; 4]);
    if with_payload {
        f.resize(f.len() + payload_len, b' ');
    }
    f
}

/// Sends `message` as a text message in `fragments` frames; whether the connection was
/// ended while it was sent.
fn send_message(s: &mut TcpStream, message: &[u8], fragments: usize) -> bool {
    s.set_write_timeout(Some(Duration::from_secs(5)))
        .expect("timeout");
    let size = message.len().div_ceil(fragments);
    for (i, part) in message.chunks(size).enumerate() {
        let last = (i + 1) * size >= message.len();
        let mut f = frame(last, if i == 0 { 0x1 } else { 0x0 }, part.len(), false);
        f.extend_from_slice(part);
        if s.write_all(&f).is_err() {
            return true;
        }
    }
    false
}

/// Writes `chunk` until `total` bytes are written or the connection is ended; whether it
/// was ended (a write failed, or nothing could be written for 5 s).
fn flood(s: &mut TcpStream, chunk: &[u8], total: usize) -> bool {
    s.set_write_timeout(Some(Duration::from_secs(5)))
        .expect("timeout");
    let mut sent = 0;
    while sent < total {
        if s.write_all(chunk).is_err() {
            return true;
        }
        sent += chunk.len();
    }
    false
}

/// Whether the peer closes `s` within `within` (reads whatever comes until the end).
fn closed_within(s: &mut TcpStream, within: Duration) -> bool {
    s.set_read_timeout(Some(Duration::from_millis(200)))
        .expect("timeout");
    let start = Instant::now();
    let mut sink = vec![0_u8; 64 << 10];
    while start.elapsed() < within {
        match s.read(&mut sink) {
            Ok(0) => return true,
            Ok(_) => {}
            Err(e)
                if e.kind() == std::io::ErrorKind::WouldBlock
                    || e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(_) => return true,
        }
    }
    false
}

#[test]
fn hostile_viewers_are_answered_or_ended_within_the_memory_budget() {
    let port = free_port();
    let mut child = serve(port);
    let outcome = std::panic::catch_unwind(|| {
        // Pings, never reading a pong: 2 M of them (about 260 MB) would queue as many pongs.
        let mut pinger = viewer(port);
        let pings: Vec<u8> = (0..1000)
            .flat_map(|_| frame(true, 0x9, 125, true))
            .collect();
        assert!(
            flood(&mut pinger, &pings, 2000 * pings.len()),
            "a viewer that never reads its pongs was not ended"
        );
        // A `subscribe` of about 2.7 M channels (60 MiB) in four fragments: ended at the
        // first fragment's header.
        let mut subscribe = b"{\"op\":\"subscribe\",\"subscriptions\":[".to_vec();
        let mut id = 0_u32;
        while subscribe.len() < 60 << 20 {
            id += 1;
            subscribe.extend_from_slice(format!("{{\"id\":{id},\"channelId\":1}},").as_bytes());
        }
        subscribe.pop();
        subscribe.extend_from_slice(b"]}");
        let mut big = viewer(port);
        assert!(
            send_message(&mut big, &subscribe, 4)
                || closed_within(&mut big, Duration::from_secs(5)),
            "a 60 MiB message was taken"
        );
        // Small fragments that add up to 4 MiB.
        let mut many = viewer(port);
        assert!(
            send_message(&mut many, &vec![b' '; 4 << 20], 64)
                || closed_within(&mut many, Duration::from_secs(5)),
            "4 MiB in fragments were taken"
        );

        // Connections that are not viewers do not hold a viewer's place: each is
        // answered with its status and closed.
        let mut held = Vec::new();
        for _ in 0..8 {
            let (mut s, status) = status_of(
                port,
                &format!("GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n"),
            );
            assert!(status.starts_with("HTTP/1.1 426"), "{status}");
            assert!(
                closed_within(&mut s, Duration::from_secs(5)),
                "a page request kept open"
            );
            held.push(s);
        }
        for _ in 0..8 {
            let (mut s, status) = status_of(port, &request(port, "something.else"));
            assert!(status.starts_with("HTTP/1.1 400"), "{status}");
            assert!(
                closed_within(&mut s, Duration::from_secs(5)),
                "a refused upgrade kept open"
            );
            held.push(s);
        }
        // Partial heads, more than the connections that may wait: a good viewer still
        // comes in at once.
        let partial: Vec<TcpStream> = (0..80)
            .map(|_| {
                let mut s = TcpStream::connect(("127.0.0.1", port)).expect("connects");
                s.write_all(b"GET / HTTP/1.1\r\nHost: x\r\n")
                    .expect("writes");
                s
            })
            .collect();
        std::thread::sleep(Duration::from_millis(300));
        let started = Instant::now();
        let good: Vec<TcpStream> = (0..8).map(|_| viewer(port)).collect();
        assert!(
            started.elapsed() < Duration::from_secs(3),
            "{:?}",
            started.elapsed()
        );
        // A ninth is told why it is refused.
        let (_, status) = status_of(port, &request(port, "foxglove.sdk.v1"));
        assert!(status.starts_with("HTTP/1.1 503"), "{status}");
        drop(good);
        drop(partial);
        drop(held);
        // Places come back when viewers leave.
        std::thread::sleep(Duration::from_millis(500));
        let _again = viewer(port);
        let peak = peak_kb(&child);
        assert!(peak < MEMORY_BUDGET_KB, "peak {peak} kB");
        peak
    });
    let _ = child.kill();
    let out = child.wait_with_output().expect("waits");
    match outcome {
        Ok(peak) => eprintln!("peak resident memory {peak} kB"),
        Err(e) => {
            eprintln!(
                "posestream's stderr:\n{}",
                String::from_utf8_lossy(&out.stderr)
            );
            std::panic::resume_unwind(e);
        }
    }
}
