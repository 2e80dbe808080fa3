//! One conformance suite for every transport backend (in-memory, MCAP, ROS 2, iceoryx2
//! shared memory), and independent clients on the wire: Python `cyclonedds` subscribes
//! to our ROS 2 skeletons.

mod common;

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use posestream::msgs::HeatMaps;
use posestream::msgs::{Header, Skeleton3D, Time};
use posestream::transport::mcap::{McapSource, SharedRecorder};
use posestream::transport::memory;
use posestream::transport::ros2::{Ros2, RosSettings};
use posestream::transport::runtime::{AsyncSource, Blocking};
use posestream::transport::shm::Shm;
use posestream::transport::{FrameSource, Received, Sink, Source, TransportError};

/// A skeleton whose every field depends on `seq`.
fn skeleton(seq: u64) -> Skeleton3D {
    let p = 17;
    let f = seq as f64;
    Skeleton3D {
        header: Header {
            stamp: Time::from_nanos(1_700_000_000_000_000_000 + seq as i64 * 33_333_333),
            frame_id: format!("camera_{seq}"),
        },
        sequence: seq,
        track_id: 7,
        joint_names: (0..p).map(|j| format!("joint{j}")).collect(),
        units: 1,
        positions: (0..3 * p).map(|i| f + i as f64 * 0.25).collect(),
        position_std: (0..3 * p).map(|i| 0.01 * (i as f64 + f)).collect(),
        keypoints: (0..2 * p).map(|i| 100.0 + f + i as f64).collect(),
        keypoint_std: (0..p).map(|i| 1.5 + i as f64).collect(),
        projected: (0..2 * p).map(|i| 101.0 + f - i as f64).collect(),
        lag: (seq % 11) as u32,
        state: (seq % 3) as u8,
        metric_source: 1 + (seq % 2) as u8,
        // Not in iceoryx2's fixed-size sample (one camera's skeletons have none).
        views: Vec::new(),
        frames_since_look: (seq % 3) as u32,
        mean_bone_length: 0.2 + 0.001 * f,
    }
}

/// A DDS domain of our own per test process and test (0..=232), so concurrent runs on
/// one machine do not hear each other.
fn domain(offset: u16) -> u16 {
    (std::process::id() % 100) as u16 + 100 + offset
}

fn loopback(domain: u16, node: &str) -> Ros2 {
    Ros2::new(&RosSettings {
        domain_id: domain,
        localhost_only: true,
        node_name: node.into(),
        ..RosSettings::default()
    })
    .expect("ROS 2 participant")
}

/// Receives until `n` messages arrived, the source closed, or `limit` passed.
fn receive(source: &mut dyn Source<Skeleton3D>, n: usize, limit: Duration) -> Vec<Skeleton3D> {
    let start = Instant::now();
    let mut got = Vec::new();
    while got.len() < n && start.elapsed() < limit {
        match source.recv(Duration::from_millis(50)).expect("recv") {
            Received::Message(m, _) => got.push(m),
            Received::Idle => {}
            Received::Closed => break,
        }
    }
    got
}

/// Waits until the live `source` hears `sink` (discovery): probes until one arrives,
/// then drains what is still in flight.
fn connect(sink: &mut dyn Sink<Skeleton3D>, source: &mut dyn Source<Skeleton3D>, domain: u16) {
    let probe = skeleton(u64::MAX);
    let start = Instant::now();
    loop {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "discovery failed on domain {domain}"
        );
        sink.send(&probe, 0).expect("send");
        if let Received::Message(..) = source.recv(Duration::from_millis(50)).expect("recv") {
            break;
        }
    }
    while let Received::Message(..) = source.recv(Duration::from_millis(300)).expect("recv") {}
}

/// The conformance suite: what goes into a sink comes out of the source, every
/// message, in order, equal; then the source has nothing more.
fn conformance(
    name: &str,
    sink: &mut dyn Sink<Skeleton3D>,
    end: impl FnOnce() -> Box<dyn Source<Skeleton3D>>,
    source: Option<&mut dyn Source<Skeleton3D>>,
) {
    let sent: Vec<Skeleton3D> = (0..8).map(skeleton).collect();
    for (i, s) in sent.iter().enumerate() {
        sink.send(s, 1_000 + i as u64).expect("send");
    }
    sink.flush().expect("flush");
    let mut late;
    let source: &mut dyn Source<Skeleton3D> = match source {
        Some(s) => s,
        None => {
            late = end();
            &mut *late
        }
    };
    let got = receive(source, sent.len(), Duration::from_secs(10));
    assert_eq!(
        got.len(),
        sent.len(),
        "{name}: {} of {} arrived",
        got.len(),
        sent.len()
    );
    assert_eq!(got, sent, "{name}: not equal or out of order");
    match source.recv(Duration::from_millis(200)).expect("recv") {
        Received::Message(m, _) => panic!("{name}: an extra message {}", m.sequence),
        Received::Idle | Received::Closed => {}
    }
}

#[test]
fn memory_channel_passes_the_conformance_suite() {
    let (mut sink, mut source) = memory::channel(16);
    conformance(
        "memory",
        &mut sink,
        || unreachable!("live"),
        Some(&mut source),
    );
}

#[test]
fn memory_channel_closes_when_every_sender_is_gone() {
    let (sink, mut source) = memory::channel::<Skeleton3D>(4);
    drop(sink);
    assert_eq!(
        source.recv(Duration::from_millis(10)).expect("recv"),
        Received::Closed
    );
}

#[test]
fn mcap_recording_passes_the_conformance_suite() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("skeletons.mcap");
    let recorder = SharedRecorder::create(&path).expect("recorder");
    let mut sink = recorder.sink::<Skeleton3D>("/posestream/skeletons");
    // Another topic in the same file must not leak into the source.
    let mut other = recorder.sink::<Skeleton3D>("/posestream/ground_truth");
    other.send(&skeleton(99), 1).expect("send");
    conformance(
        "mcap",
        &mut sink,
        || {
            recorder.finish().expect("finish");
            Box::new(McapSource::<Skeleton3D>::open(&path, "/posestream/skeletons").expect("open"))
        },
        None,
    );
}

#[test]
fn ros2_topic_passes_the_conformance_suite_on_loopback() {
    let d = domain(0);
    let publisher = loopback(d, "conformance_pub");
    let subscriber = loopback(d, "conformance_sub");
    let mut source = subscriber
        .source::<Skeleton3D>("/posestream/skeletons")
        .expect("subscription");
    let mut sink = publisher
        .sink::<Skeleton3D>("/posestream/skeletons")
        .expect("publisher");
    connect(&mut sink, &mut source, d);
    conformance(
        "ros2",
        &mut sink,
        || unreachable!("live"),
        Some(&mut source),
    );
}

/// An awaited source ([`AsyncSource`]) driven as a blocking one, so that the
/// conformance suite runs on it: each `recv` awaits the next message on a runtime of its
/// own, for at most the timeout.
struct Awaited<S>(S, tokio::runtime::Runtime);

impl<S: AsyncSource<Skeleton3D>> Awaited<S> {
    fn new(source: S) -> Self {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .build()
            .expect("runtime");
        Self(source, runtime)
    }
}

impl<S: AsyncSource<Skeleton3D>> Source<Skeleton3D> for Awaited<S> {
    fn recv(&mut self, timeout: Duration) -> Result<Received<Skeleton3D>, TransportError> {
        let Self(source, runtime) = self;
        runtime.block_on(async {
            tokio::time::timeout(timeout, source.next())
                .await
                .unwrap_or(Ok(Received::Idle))
        })
    }
}

#[test]
fn awaited_sources_pass_the_conformance_suite() {
    // A blocking source on a thread of its own, handing over to the runtime.
    let (mut sink, source) = memory::channel(16);
    let mut awaited = Awaited::new(Blocking::spawn("memory", source, 4).expect("thread"));
    conformance(
        "awaited memory",
        &mut sink,
        || unreachable!("live"),
        Some(&mut awaited),
    );
    drop(sink);
    assert_eq!(
        awaited.recv(Duration::from_secs(1)).expect("recv"),
        Received::Closed,
        "the channel closed: so does the awaited source"
    );
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("skeletons.mcap");
    let recorder = SharedRecorder::create(&path).expect("recorder");
    let mut sink = recorder.sink::<Skeleton3D>("/posestream/skeletons");
    conformance(
        "awaited mcap",
        &mut sink,
        || {
            recorder.finish().expect("finish");
            let source = McapSource::<Skeleton3D>::open(&path, "/posestream/skeletons");
            Box::new(Awaited::new(
                Blocking::spawn("mcap", source.expect("open"), 4).expect("thread"),
            ))
        },
        None,
    );
    // A ROS 2 subscription, awaited natively (ros2-client's async API).
    let d = domain(3);
    let publisher = loopback(d, "awaited_pub");
    let subscriber = loopback(d, "awaited_sub");
    let mut source = Awaited::new(
        subscriber
            .source::<Skeleton3D>("/posestream/skeletons")
            .expect("subscription"),
    );
    let mut sink = publisher
        .sink::<Skeleton3D>("/posestream/skeletons")
        .expect("publisher");
    connect(&mut sink, &mut source, d);
    conformance(
        "awaited ros2",
        &mut sink,
        || unreachable!("live"),
        Some(&mut source),
    );
}

/// A source that refuses its first message, then has one, then breaks.
struct Refusing(u32);

impl Source<Skeleton3D> for Refusing {
    fn recv(&mut self, _: Duration) -> Result<Received<Skeleton3D>, TransportError> {
        self.0 += 1;
        let topic = "test".to_string();
        match self.0 {
            1 => Err(TransportError::Malformed {
                transport: "test",
                topic,
                reason: "refused".into(),
            }),
            2 => Ok(Received::Idle),
            3 => Ok(Received::Message(skeleton(3), 3)),
            4 => Err(TransportError::Broken {
                transport: "test",
                topic,
                reason: "cut".into(),
            }),
            n => panic!("asked again ({n}) after the source broke"),
        }
    }
}

#[test]
fn a_blocking_source_awaited_goes_on_after_a_refusal_and_ends_where_it_breaks() {
    let mut source = Awaited::new(Blocking::spawn("refusing", Refusing(0), 1).expect("thread"));
    let wait = Duration::from_secs(5);
    assert!(matches!(
        source.recv(wait),
        Err(TransportError::Malformed { .. })
    ));
    assert_eq!(
        source.recv(wait).expect("recv"),
        Received::Message(skeleton(3), 3)
    );
    assert!(matches!(
        source.recv(wait),
        Err(TransportError::Broken { .. })
    ));
    // The thread ended there (asked again, the source would panic): closed.
    assert_eq!(source.recv(wait).expect("recv"), Received::Closed);
}

/// A source that has one message, then panics.
struct Panicking(u32);

impl Source<Skeleton3D> for Panicking {
    fn recv(&mut self, _: Duration) -> Result<Received<Skeleton3D>, TransportError> {
        self.0 += 1;
        match self.0 {
            1 => Ok(Received::Message(skeleton(1), 1)),
            _ => panic!("the source's own bug"),
        }
    }
}

#[test]
fn a_blocking_source_whose_thread_panics_is_broken_not_closed() {
    let mut source = Awaited::new(Blocking::spawn("panicking", Panicking(0), 1).expect("thread"));
    let wait = Duration::from_secs(5);
    assert_eq!(
        source.recv(wait).expect("recv"),
        Received::Message(skeleton(1), 1)
    );
    // A panic is not the end of the input: whoever reads on must not take the
    // recording as complete.
    match source.recv(wait) {
        Err(TransportError::Broken { reason, .. }) => {
            assert!(reason.contains("the source's own bug"), "{reason}");
        }
        other => panic!("expected a broken source, got {other:?}"),
    }
    assert_eq!(source.recv(wait).expect("recv"), Received::Closed);
}

/// An iceoryx2 service name of our own per test process and test.
fn service(name: &str) -> String {
    format!("posestream-test/{}/{name}", std::process::id())
}

#[test]
fn iceoryx2_skeletons_pass_the_conformance_suite() {
    let shm = Shm::new().expect("node");
    let name = service("skeletons");
    let mut source = shm.skeleton_source(&name).expect("subscriber");
    let mut sink = shm.skeleton_sink(&name).expect("publisher");
    conformance(
        "iceoryx2",
        &mut sink,
        || unreachable!("live"),
        Some(&mut source),
    );
}

#[test]
fn iceoryx2_heat_maps_arrive_equal() {
    let shm = Shm::new().expect("node");
    let name = service("heatmaps");
    let mut source = shm
        .heatmaps_source(&name, &posestream::limits::Limits::default())
        .expect("subscriber");
    let mut sink = shm.heatmaps_sink(&name).expect("publisher");
    let (p, h, w) = (3, 8, 5);
    let values: Vec<f32> = (0..p * h * w).map(|i| i as f32 * 0.5).collect();
    let sent = HeatMaps::from_values(
        Header {
            stamp: Time::from_nanos(123_456_789),
            frame_id: "camera".into(),
        },
        42,
        vec!["a".into(), "b".into(), "c".into()],
        h as u32,
        w as u32,
        posestream::CropBox::new(10.0, 20.0, 64.0, 64.0).expect("crop"),
        &values,
        posestream::msgs::HeatMapEncoding::Float32,
    );
    sink.send(&sent, 0).expect("send");
    match source.recv(Duration::from_secs(5)).expect("recv") {
        Received::Message(got, stamp) => {
            assert_eq!(got, sent);
            assert_eq!(stamp, 123_456_789);
        }
        other => panic!("{other:?}"),
    }
    // Lent where it is (the scores read in shared memory): the same frame.
    sink.send(&sent, 0).expect("send");
    let mut lent = None;
    let got = source
        .recv_frame(Duration::from_secs(5), &mut |view, stamp| {
            assert_eq!(view.values.len(), p * h * w);
            lent = Some((view.to_message(), stamp));
        })
        .expect("recv");
    assert_eq!(got, Received::Message((), 123_456_789));
    assert_eq!(lent, Some((sent.clone(), 123_456_789)));
    // A message that does not fit the layout is refused at the sender.
    let mut too_many = sent.clone();
    too_many.joint_names = vec!["j".into(); 33];
    assert!(sink.send(&too_many, 0).is_err());
}

/// The Python `iceoryx2` binding reads our shared-memory skeletons with the documented
/// C layout.
#[test]
fn iceoryx2_python_client_reads_our_skeletons() {
    let name = service("python-skeletons");
    let client = PythonSubscriber::start(
        "shm_skeleton_subscriber.py",
        &[&name, "5", "30"],
        "iceoryx2",
    );
    let shm = Shm::new().expect("node");
    let sink = shm.skeleton_sink(&name).expect("publisher");
    let decoded = client.collect_while_publishing(sink, Duration::from_millis(20));
    decoded.iter().for_each(assert_is_our_skeleton);
}

/// Python `cyclonedds` (an independent DDS implementation, written against the `.msg`
/// files) receives and decodes the skeletons we publish on ROS 2.
#[test]
fn cyclonedds_python_client_decodes_our_ros2_skeletons() {
    let d = domain(1);
    let client = PythonSubscriber::start(
        "ros2_skeleton_subscriber.py",
        &[&d.to_string(), "/posestream/skeletons", "5", "40"],
        "cyclonedds",
    );
    let ros = loopback(d, "skeleton_pub");
    let sink = ros
        .sink::<Skeleton3D>("/posestream/skeletons")
        .expect("publisher");
    // Publish until the client has what it needs (discovery takes a moment).
    let decoded = client.collect_while_publishing(sink, Duration::from_millis(50));
    drop(ros);
    decoded.iter().for_each(assert_is_our_skeleton);
}

/// `cyclonedds ls` and other DDS tools list our participant by its node's full name
/// (RustDDS, patched, announces it: it used to go unnamed).
#[test]
fn dds_tools_see_our_participant_by_its_node_s_name() {
    let d = domain(5);
    let ros = loopback(d, "named_by_test");
    let seen = common::python_client(
        "participant_names.py",
        &[&d.to_string(), "/named_by_test", "30"],
    );
    drop(ros);
    let names = seen["names"].as_array().expect("names");
    assert!(
        names.iter().any(|n| n == "/named_by_test"),
        "announced names: {seen}"
    );
}

/// A matched reliable reader that stops acknowledging (its process stopped) fills the
/// writer's reliable window. An awaited publish then fails after the 100 ms the
/// blocking send waits, as that one does. (RustDDS's own async wait looks at its limit
/// only when something wakes it, about every 3 s here: 3 s per publish, for as long as
/// the reader stays matched, held a node's output, its solver and its stop.)
#[test]
fn an_awaited_publish_gives_up_on_a_reader_that_stopped_acknowledging() {
    let d = domain(4);
    let topic = "/posestream/stalled";
    let mut client = PythonSubscriber::start(
        "ros2_skeleton_subscriber.py",
        &[&d.to_string(), topic, "1000000", "60"],
        "cyclonedds",
    );
    let ros = loopback(d, "stalled_pub");
    let mut sink = ros.sink::<Skeleton3D>(topic).expect("publisher");
    // Publish until the client has one: matched both ways.
    let matched = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let publishing = {
        let matched = matched.clone();
        common::spawn("publisher", move || {
            let mut seq = 0;
            while !matched.load(std::sync::atomic::Ordering::Relaxed) && seq < 600 {
                let _ = sink.send(&skeleton(seq), 0);
                seq += 1;
                std::thread::sleep(Duration::from_millis(50));
            }
            sink
        })
    };
    let first = client.lines.next();
    matched.store(true, std::sync::atomic::Ordering::Relaxed);
    let sink = publishing.join().expect("publisher");
    assert!(matches!(first, Some(Ok(_))), "the client received nothing");
    let stopped = Command::new("kill")
        .args(["-STOP", &client.child.id().to_string()])
        .status()
        .expect("kill");
    assert!(stopped.success());
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
        .expect("runtime");
    // RustDDS lets 8192 samples go unacknowledged (its reliable window, not the
    // history depth); past them a publish waits for room. Well within the reader's
    // lease (10 s): publish until 10 publishes have failed. The outer limit, 2 s, is
    // also what wakes RustDDS's wait: without a limit of our own, a publish ends only
    // there.
    let (mut sent_before, mut failed, mut longest) = (0, 0, Duration::ZERO);
    for seq in 1000..20_000 {
        let began = Instant::now();
        let sent = runtime.block_on(async {
            tokio::time::timeout(Duration::from_secs(2), sink.send_async(&skeleton(seq))).await
        });
        match sent {
            Ok(Ok(())) if failed == 0 => sent_before += 1,
            Ok(Ok(())) => {}
            Ok(Err(TransportError::Send { .. })) => {
                failed += 1;
                longest = longest.max(began.elapsed());
            }
            Ok(Err(e)) => panic!("unexpected error {e}"),
            Err(_) => panic!("publish {seq} still waiting after 2 s for a reader that stopped"),
        }
        if failed == 10 {
            break;
        }
    }
    drop(client);
    // The failures came once RustDDS's window was full, not from a slow start.
    assert!(
        failed > 0 && sent_before >= 8000,
        "{sent_before} sent, then {failed} failed: the window did not fill, the test proves nothing"
    );
    assert!(
        longest < Duration::from_millis(500),
        "a publish to a full window took {longest:?} to fail (the limit is 100 ms)"
    );
}

/// A Python client printing `ready`, then one JSON line per message it decoded. Killed
/// when dropped (a test that fails must not leave it, stopped or running).
struct PythonSubscriber {
    child: std::process::Child,
    lines: std::io::Lines<BufReader<std::process::ChildStdout>>,
}

impl Drop for PythonSubscriber {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl PythonSubscriber {
    fn start(script: &str, args: &[&str], package: &str) -> Self {
        let mut child = Command::new(common::python())
            .arg(common::root().join("tests/python").join(script))
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("python");
        let mut lines = BufReader::new(child.stdout.take().expect("stdout")).lines();
        let ready = lines.next().and_then(Result::ok).unwrap_or_default();
        assert_eq!(
            ready, "ready",
            "the {package} client did not start (`pip install {package}`, which .ci/run does)"
        );
        Self { child, lines }
    }

    /// Publishes `skeleton(0..)` every `period` until the client exits; its messages.
    fn collect_while_publishing(
        mut self,
        mut sink: impl Sink<Skeleton3D> + 'static,
        period: Duration,
    ) -> Vec<serde_json::Value> {
        let publishing = common::spawn("publisher", move || {
            for seq in 0..600 {
                if sink.send(&skeleton(seq), 0).is_err() {
                    break;
                }
                std::thread::sleep(period);
            }
        });
        let decoded: Vec<serde_json::Value> = self
            .lines
            .by_ref()
            .map(|l| serde_json::from_str(&l.expect("line")).expect("json"))
            .collect();
        let status = self.child.wait().expect("wait");
        let _ = publishing.join();
        assert!(
            status.success(),
            "the client got {} messages",
            decoded.len()
        );
        assert!(decoded.len() >= 5);
        decoded
    }
}

/// Every field a client decoded equals what [`skeleton`] sent.
fn assert_is_our_skeleton(v: &serde_json::Value) {
    let want = skeleton(v["sequence"].as_u64().expect("sequence"));
    assert_eq!(v["stamp"][0], want.header.stamp.sec);
    assert_eq!(v["stamp"][1], want.header.stamp.nanosec);
    assert_eq!(v["frame_id"], want.header.frame_id.as_str());
    assert_eq!(v["track_id"], want.track_id);
    assert_eq!(v["units"], want.units);
    assert_eq!(v["lag"], want.lag);
    assert_eq!(v["state"], want.state);
    assert_eq!(v["metric_source"], want.metric_source);
    assert_eq!(v["frames_since_look"], want.frames_since_look);
    assert_eq!(v["mean_bone_length"], want.mean_bone_length);
    let names: Vec<String> = v["joint_names"]
        .as_array()
        .expect("names")
        .iter()
        .map(|s| s.as_str().expect("str").to_string())
        .collect();
    assert_eq!(names, want.joint_names);
    let f64s = |k: &str| -> Vec<f64> {
        v[k].as_array()
            .expect(k)
            .iter()
            .map(|x| x.as_f64().expect("f64"))
            .collect()
    };
    assert_eq!(f64s("positions"), want.positions);
    assert_eq!(f64s("position_std"), want.position_std);
    assert_eq!(f64s("keypoints"), want.keypoints);
    assert_eq!(f64s("keypoint_std"), want.keypoint_std);
    assert_eq!(f64s("projected"), want.projected);
}

/// The Fast DDS peer (`tests/fastdds/`): configured and built once per target folder with
/// CMake against Debian's `libfastrtps-dev`, types from `fastddsgen` (which `.ci/run`
/// installs).
fn fastdds_peer() -> std::path::PathBuf {
    let build = common::root().join("target/fastdds-interop");
    let run = |program: &str, args: &[&str]| {
        let out = Command::new(program)
            .args(args)
            .current_dir(&build)
            .output()
            .unwrap_or_else(|e| {
                panic!("cannot run {program} ({e}): the Fast DDS peer needs cmake, g++, libfastrtps-dev and fastddsgen (Debian; .ci/run installs them)")
            });
        assert!(
            out.status.success(),
            "{program} {args:?} failed:\n{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    };
    std::fs::create_dir_all(&build).expect("build folder");
    let source = common::root().join("tests/fastdds");
    run(
        "cmake",
        &[
            "-S",
            source.to_str().expect("utf-8"),
            "-B",
            ".",
            // Unoptimised: it only has to keep up with a camera, and builds in half the
            // time (CI's budget).
            "-DCMAKE_BUILD_TYPE=",
        ],
    );
    run("cmake", &["--build", ".", "-j", "2"]);
    build.join("interop")
}

/// eProsima Fast DDS, the DDS of a default ROS 2 install, as the peer on both ends: a
/// C++ publisher (types generated from IDL written from our `.msg` files) drives
/// `posestream estimator` with byebye's heat maps, and a C++ subscriber receives every
/// skeleton, `/tf` and REP-155 message the estimator published (its recording says how
/// many), bit for bit where it sums them; and it hears our participant leave.
#[test]
fn a_fast_dds_peer_drives_our_estimator_and_receives_everything_it_publishes() {
    let peer = fastdds_peer();
    let d = domain(6);
    let dir = tempfile::tempdir().expect("dir");
    // The heat maps, as the C++ publisher reads them: length, then CDR.
    let maps: Vec<HeatMaps> =
        common::messages(&common::recording("byebye.mcap"), "/posestream/heatmaps");
    let mut file = Vec::new();
    for m in &maps {
        let bytes = posestream::msgs::encode(m).expect("encodes");
        file.extend_from_slice(&(bytes.len() as u32).to_le_bytes());
        file.extend_from_slice(&bytes);
    }
    let input = dir.path().join("heatmaps.bin");
    std::fs::write(&input, file).expect("write");
    let bodies: std::collections::BTreeSet<String> =
        maps.iter().map(|m| format!("b{}", m.track_id)).collect();
    // The subscriber first.
    let mut sub_args = vec!["sub".to_string(), d.to_string(), "60".into()];
    sub_args.extend(bodies.iter().cloned());
    let mut subscriber = Command::new(&peer)
        .args(&sub_args)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("fast dds subscriber");
    let mut sub_lines = BufReader::new(subscriber.stdout.take().expect("stdout")).lines();
    assert_eq!(
        sub_lines.next().and_then(Result::ok).as_deref(),
        Some("ready")
    );
    // The estimator, recording what it publishes, on ordinary discovery (multicast).
    let out = dir.path().join("estimator.mcap");
    let config = dir.path().join("estimator.toml");
    std::fs::write(
        &config,
        format!(
            "[ros]\ndomain_id = {d}\nwait_for_subscribers = 0.0\n[outputs]\nrecord = \"{}\"\n",
            out.display()
        ),
    )
    .expect("config");
    let estimator = Command::new(env!("CARGO_BIN_EXE_posestream"))
        .args([
            "estimator",
            "--config",
            config.to_str().expect("utf-8"),
            "--json",
        ])
        .current_dir(common::root())
        .env_remove("ROS_DOMAIN_ID")
        .env_remove("ROS_LOCALHOST_ONLY")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("estimator");
    // The camera's calibration (metres, and the images' size REP-155's messages need),
    // from a node of ours, until the estimator is done.
    let crop = maps[0].crop().expect("crop");
    let (w, h) = (
        (crop.x0 + crop.width).ceil() as u32 + 200,
        (crop.y0 + crop.height).ceil() as u32 + 200,
    );
    let camera = Ros2::new(&RosSettings {
        domain_id: d,
        node_name: "camera".into(),
        ..RosSettings::default()
    })
    .expect("camera node");
    let info = posestream::msgs::sensor::CameraInfo {
        header: Header {
            stamp: Time::from_nanos(0),
            frame_id: "camera".into(),
        },
        width: w,
        height: h,
        k: [
            800.0,
            0.0,
            f64::from(w) / 2.0,
            0.0,
            800.0,
            f64::from(h) / 2.0,
            0.0,
            0.0,
            1.0,
        ],
        ..Default::default()
    };
    let calibrating = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(true));
    let calibration = {
        let calibrating = calibrating.clone();
        let mut sink = camera
            .sink::<posestream::msgs::sensor::CameraInfo>("/camera/camera_info")
            .expect("camera_info");
        common::spawn("camera", move || {
            while calibrating.load(std::sync::atomic::Ordering::Relaxed) {
                let _ = sink.send(&info, 0);
                std::thread::sleep(Duration::from_millis(50));
            }
        })
    };
    // Let the calibration reach the estimator before the first heat maps.
    std::thread::sleep(Duration::from_secs(3));
    let published = Command::new(&peer)
        .args(["pub", &d.to_string(), input.to_str().expect("utf-8")])
        .output()
        .expect("fast dds publisher");
    let published: serde_json::Value =
        serde_json::from_slice(&published.stdout).unwrap_or_else(|e| {
            panic!(
                "publisher's json ({e}; {}): {}",
                published.status,
                String::from_utf8_lossy(&published.stderr)
            )
        });
    assert_eq!(published["matched"], true, "{published}");
    assert_eq!(published["published"], maps.len(), "{published}");
    // The estimator has what it needs; it ends the track and stops cleanly.
    std::thread::sleep(Duration::from_secs(2));
    calibrating.store(false, std::sync::atomic::Ordering::Relaxed);
    calibration.join().expect("camera");
    let stopped = Command::new("kill")
        .args(["-INT", &estimator.id().to_string()])
        .status()
        .expect("kill");
    assert!(stopped.success());
    let report = estimator.wait_with_output().expect("estimator");
    assert!(report.status.success());
    let report: serde_json::Value = serde_json::from_slice(&report.stdout).expect("json");
    // Every heat map from Fast DDS was taken.
    assert_eq!(report["frames"], maps.len(), "{report}");
    let heard = sub_lines
        .next()
        .and_then(Result::ok)
        .expect("the subscriber's line");
    let _ = subscriber.wait();
    drop(camera);
    let heard: serde_json::Value = serde_json::from_str(&heard).expect("json");
    // What the estimator published, from its recording.
    let mut per_topic = std::collections::BTreeMap::<String, usize>::new();
    for m in posestream::recording::RecordingReader::open(&out).expect("recording") {
        *per_topic.entry(m.expect("message").topic).or_default() += 1;
    }
    let recorded = |topic: &str| per_topic.get(topic).copied().unwrap_or(0);
    let skeletons: Vec<Skeleton3D> = common::messages(&out, "/posestream/skeletons");
    assert_eq!(skeletons.len(), 2 * maps.len(), "{report}");
    assert!(
        skeletons.iter().any(|s| s.units == 1),
        "no skeleton in metres"
    );
    let counts = &heard["counts"];
    assert_eq!(counts["/posestream/skeletons"], skeletons.len(), "{heard}");
    assert_eq!(
        heard["sequence_sum"],
        skeletons.iter().map(|s| s.sequence).sum::<u64>(),
        "{heard}"
    );
    for topic in ["/tf", "/humans/bodies/tracked"] {
        assert!(recorded(topic) > 0, "{topic}");
        assert_eq!(counts[topic], recorded(topic), "{topic}: {heard}");
    }
    for body in &bodies {
        for what in ["roi", "skeleton2d"] {
            let topic = format!("/humans/bodies/{body}/{what}");
            assert!(recorded(&topic) > 0, "{topic}");
            assert_eq!(counts[&topic], recorded(&topic), "{topic}: {heard}");
        }
    }
    // Our participant, by its node's name, and its departure understood (not its lease
    // running out).
    let ours: Vec<&serde_json::Value> = heard["participants"]
        .as_array()
        .expect("participants")
        .iter()
        .filter(|p| p["name"] == "/posestream_estimator")
        .collect();
    assert_eq!(ours.len(), 1, "{heard}");
    assert_eq!(ours[0]["left"], "removed", "{heard}");
}
