//! The streaming update allocates nothing once warm: a counting global allocator over
//! 1,000 frames of a shipped recording, after a warm-up.
//!
//! What is counted: every allocation and reallocation on the test's thread
//! - while a frame is pushed through the window (`WindowEstimator::push_into`: the
//!   frame copied into the window's ring, its initialisation, the local EM, the window
//!   EM in parts) and its estimates emitted into reused buffers;
//! - while the estimator node handles a decoded `HeatMaps` message, f32 or u8 (the
//!   checks against the limits and the dictionary's joints, the message's scores lent to
//!   the window, the window's update) and writes its `Skeleton3D` messages over those
//!   it was handed back (`EstimatorNode::recycle`).
//!
//! - while an iceoryx2 sample is received and lent to the node (`FrameSource`: its
//!   scores read in shared memory, its names unpacked into reused strings) and
//!   handled as above.
//!
//! - from the wire to the window: a ROS 2 heat-map message taken from its subscription
//!   (decoded over a message handed back: `Ros2Source::recycler`) and handled as above,
//!   and a recorded one decoded from its bytes (`msgs::decode_into`) and handled: at most
//!   two allocations a frame (a u8 frame's bytes are read whole).
//!
//! - a skeleton published to ROS 2 from a plan: shared with the DDS writer, not copied
//!   (what is left is RustDDS's serialisation).
//!
//! Not counted: encoding the skeletons (the transports' serialisation builds their
//! buffers), publishing the samples, markers, and what DDS does on threads of its own.
//! `POSESTREAM_ALLOC_TRACE=1` prints a backtrace of the first allocations, to find where
//! they come from.

#![allow(unsafe_code, reason = "a global allocator is unsafe to implement")]

mod common;

use posestream::LoadDictionary;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::{Cell, RefCell};

use common::{recording, root};
use posestream::msgs::{self, HeatMapEncoding, Time};
use posestream::nodes::EstimatorNode;
use posestream::recording::read_topic;
use posestream::streaming::{Estimates, FrameMaps, StreamSettings, WindowEstimator};
use posestream::transport::shm::Shm;
use posestream::transport::{FrameSource, Received, Sink};
use posestream::{Dictionary, Estimator, Params};

struct Counting;

thread_local! {
    static ARMED: Cell<bool> = const { Cell::new(false) };
    static COUNT: Cell<u64> = const { Cell::new(0) };
    static TRACES: RefCell<Vec<String>> = const { RefCell::new(Vec::new()) };
}

fn note() {
    let armed = ARMED.try_with(|a| a.replace(false)).unwrap_or(false);
    if !armed {
        return;
    }
    let _ = COUNT.try_with(|c| c.set(c.get() + 1));
    if std::env::var_os("POSESTREAM_ALLOC_TRACE").is_some() {
        let trace = std::backtrace::Backtrace::force_capture().to_string();
        let _ = TRACES.try_with(|t| {
            let mut t = t.borrow_mut();
            if t.len() < 400 {
                t.push(trace);
            }
        });
    }
    let _ = ARMED.try_with(|a| a.set(true));
}

// SAFETY: every call forwards to `System` with the caller's arguments unchanged; the
// counting touches only const-initialised thread-locals and allocates only while
// disarmed.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note();
        // SAFETY: forwarded as received.
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note();
        // SAFETY: forwarded as received.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note();
        // SAFETY: forwarded as received.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded as received.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Allocations made by `f` on this thread.
fn count(f: impl FnOnce()) -> u64 {
    COUNT.with(|c| c.set(0));
    ARMED.with(|a| a.set(true));
    f();
    ARMED.with(|a| a.set(false));
    COUNT.with(|c| c.get())
}

/// The heat maps of the shipped `byebye.mcap`.
fn byebye() -> Vec<msgs::HeatMaps> {
    read_topic(&recording("byebye.mcap"), "/posestream/heatmaps")
        .expect("reads")
        .into_iter()
        .map(|(_, m)| m)
        .collect()
}

/// A window over the shipped dictionary, with the default settings.
fn window() -> WindowEstimator {
    let dict =
        Dictionary::load(root().join("config/dictionaries/default-k128.json")).expect("dictionary");
    let estimator = Estimator::new(dict, Params::default()).expect("estimator");
    WindowEstimator::new(estimator, StreamSettings::default()).expect("window")
}

#[test]
fn a_warm_window_update_allocates_nothing_over_1000_frames() {
    let messages = byebye();
    let frames: Vec<Vec<f32>> = messages
        .iter()
        .map(|m| {
            let mut v = Vec::new();
            m.values_into(&mut v).expect("values");
            v
        })
        .collect();
    let (h, w) = (messages[0].height as usize, messages[0].width as usize);
    let mut window = window();
    let mut out = Estimates::default();
    let push = |s: u64, window: &mut WindowEstimator, out: &mut Estimates| {
        let values = &frames[s as usize % frames.len()];
        let frame = FrameMaps {
            sequence: s,
            stamp_ns: s as i64 * 33_333_333,
            height: h,
            width: w,
            values: values.into(),
        };
        out.clear();
        window.push_into(&frame, out).expect("a good frame");
    };
    // Warm-up: the window fills, every buffer reaches its size.
    let warm = 2 * frames.len() as u64;
    for s in 0..warm {
        push(s, &mut window, &mut out);
    }
    let mut emitted = 0;
    let allocations = count(|| {
        for s in warm..warm + 1000 {
            push(s, &mut window, &mut out);
            emitted += out.len();
        }
    });
    TRACES.with(|t| {
        for trace in t.borrow().iter() {
            eprintln!("allocation at:\n{trace}");
        }
    });
    assert_eq!(emitted, 2000, "two estimates per frame");
    assert_eq!(allocations, 0, "allocations over 1000 warm frames");
}

#[test]
fn a_warm_estimator_node_allocates_nothing_over_1000_messages() {
    let recorded = byebye();
    for encoding in [HeatMapEncoding::Float32, HeatMapEncoding::Uint8] {
        // The recording's frames in this encoding.
        let mut messages: Vec<msgs::HeatMaps> = recorded
            .iter()
            .map(|m| {
                let mut values = Vec::new();
                m.values_into(&mut values).expect("values");
                let mut made = msgs::HeatMaps::from_values(
                    m.header.clone(),
                    m.sequence,
                    m.joint_names.clone(),
                    m.height,
                    m.width,
                    m.crop().expect("crop"),
                    &values,
                    encoding,
                );
                // A tracked person's id (0 is an unknown id, which the node's tracker
                // assigns: that path allocates, docs/streaming.md).
                made.track_id = m.track_id;
                made
            })
            .collect();
        let window = window();
        let mut node = EstimatorNode::new(window);
        let mut out = Vec::new();
        let frames = messages.len() as u64;
        let mut handle = |s: u64, node: &mut EstimatorNode, out: &mut Vec<msgs::Skeleton3D>| {
            let m = &mut messages[(s % frames) as usize];
            m.sequence = s;
            m.header.stamp = Time::from_nanos(s as i64 * 33_333_333);
            node.handle(m, out).expect("a good message");
        };
        let warm = 2 * frames;
        for s in 0..warm {
            handle(s, &mut node, &mut out);
            node.recycle(&mut out);
        }
        let mut emitted = 0;
        let allocations = count(|| {
            for s in warm..warm + 1000 {
                handle(s, &mut node, &mut out);
                emitted += out.len();
                node.recycle(&mut out);
            }
        });
        TRACES.with(|t| {
            for trace in t.borrow_mut().drain(..) {
                eprintln!("allocation at:\n{trace}");
            }
        });
        assert_eq!(emitted, 2000, "{encoding:?}: two skeletons per message");
        assert_eq!(
            allocations, 0,
            "{encoding:?}: allocations over 1000 warm messages"
        );
    }
}

#[test]
fn iceoryx2_frames_reach_the_window_without_an_allocation() {
    let messages = byebye();
    let shm = Shm::new().expect("iceoryx2 node");
    let name = format!("posestream/test/allocations-{}", std::process::id());
    let limits = posestream::limits::Limits::default();
    let mut source = shm.heatmaps_source(&name, &limits).expect("subscriber");
    let mut sink = shm.heatmaps_sink(&name).expect("publisher");
    let window = window();
    let mut node = EstimatorNode::new(window);
    let mut out = Vec::new();
    let frames = messages.len() as u64;
    let warm = 2 * frames;
    let (mut allocations, mut emitted) = (0, 0);
    for s in 0..warm + 1000 {
        let mut m = messages[(s % frames) as usize].clone();
        m.sequence = s;
        m.header.stamp = Time::from_nanos(s as i64 * 33_333_333);
        sink.send(&m, 0).expect("publish");
        let mut receive = || {
            let mut handle = |frame: &msgs::HeatMapsView<'_>, _| {
                node.handle_view(frame, &mut out).expect("a good frame");
            };
            let got = source
                .recv_frame(std::time::Duration::from_secs(5), &mut handle)
                .expect("receive");
            assert!(matches!(got, Received::Message(..)), "{got:?}");
        };
        if s < warm {
            receive();
        } else {
            allocations += count(receive);
            emitted += out.len();
        }
        node.recycle(&mut out);
    }
    TRACES.with(|t| {
        for trace in t.borrow_mut().drain(..) {
            eprintln!("allocation at:\n{trace}");
        }
    });
    assert_eq!(emitted, 2000, "two skeletons per frame");
    assert_eq!(allocations, 0, "allocations over 1000 warm frames");
}

/// The byebye frames in `encoding`, each with a tracked person's id.
fn frames_in(encoding: HeatMapEncoding) -> Vec<msgs::HeatMaps> {
    byebye()
        .iter()
        .map(|m| {
            let mut values = Vec::new();
            m.values_into(&mut values).expect("values");
            let mut made = msgs::HeatMaps::from_values(
                m.header.clone(),
                m.sequence,
                m.joint_names.clone(),
                m.height,
                m.width,
                m.crop().expect("crop"),
                &values,
                encoding,
            );
            made.track_id = m.track_id;
            made
        })
        .collect()
}

#[test]
fn a_recorded_frame_costs_at_most_two_allocations_from_the_file_to_the_window() {
    use posestream::recording::{RecordedMessage, Recorder, RecordingReader};
    let dir = tempfile::tempdir().expect("temp dir");
    for encoding in [HeatMapEncoding::Float32, HeatMapEncoding::Uint8] {
        // A recording of the frames in this encoding, stamped in order.
        let frames = frames_in(encoding);
        let n = frames.len() as u64;
        let (warm, counted) = (2 * n, 1000);
        let path = dir.path().join(format!("{encoding:?}.mcap"));
        let mut recorder = Recorder::create(&path).expect("recording");
        for s in 0..warm + counted {
            let mut m = frames[(s % n) as usize].clone();
            m.sequence = s;
            m.header.stamp = Time::from_nanos(s as i64 * 33_333_333);
            recorder
                .write("/posestream/heatmaps", s * 33_333_333, &m)
                .expect("write");
        }
        recorder.finish().expect("finish");
        // Read on past damage, as a replay does by default; then strictly.
        for salvaging in [true, false] {
            let reader = RecordingReader::open(&path).expect("opens");
            let mut reader = if salvaging {
                reader.salvaging().expect("salvaging")
            } else {
                reader
            };
            let mut node = EstimatorNode::new(window());
            let (mut out, mut record) = (Vec::new(), RecordedMessage::default());
            let mut frame = msgs::HeatMaps::default();
            let mut take = |node: &mut EstimatorNode, out: &mut Vec<_>| {
                reader
                    .next_message_into(&mut record)
                    .expect("a message")
                    .expect("read");
                msgs::decode_into(&record.data, &mut frame).expect("decodes");
                node.handle(&frame, out).expect("a good frame");
            };
            for _ in 0..warm {
                take(&mut node, &mut out);
                node.recycle(&mut out);
            }
            let (mut allocations, mut emitted) = (0, 0);
            for _ in 0..counted {
                allocations += count(|| take(&mut node, &mut out));
                emitted += out.len();
                node.recycle(&mut out);
            }
            TRACES.with(|t| {
                for trace in t.borrow_mut().drain(..) {
                    eprintln!("allocation at:\n{trace}");
                }
            });
            assert_eq!(emitted, 2000, "{encoding:?}: two skeletons per frame");
            eprintln!(
                "{encoding:?}, salvaging {salvaging}: {allocations} allocations over {counted} \
                 recorded frames, file to window"
            );
            assert!(
                allocations <= 2 * counted,
                "{encoding:?}, salvaging {salvaging}: {allocations} allocations over {counted} frames"
            );
        }
    }
}

#[test]
fn a_ros2_frame_costs_at_most_two_allocations_from_the_wire_to_the_window() {
    for (i, encoding) in [HeatMapEncoding::Float32, HeatMapEncoding::Uint8]
        .into_iter()
        .enumerate()
    {
        ros2_frames(encoding, (std::process::id() % 100) as u16 + 120 + i as u16);
    }
}

/// 1,000 warm frames in `encoding` over ROS 2 on `domain`: at most two allocations each
/// from the subscription to the window.
fn ros2_frames(encoding: HeatMapEncoding, domain: u16) {
    use posestream::transport::Source;
    use posestream::transport::ros2::{Ros2, RosSettings};
    let participant = |node: &str| {
        Ros2::new(&RosSettings {
            domain_id: domain,
            localhost_only: true,
            node_name: node.into(),
            ..RosSettings::default()
        })
        .expect("ROS 2 participant")
    };
    let (publisher, subscriber) = (
        participant("allocations_pub"),
        participant("allocations_sub"),
    );
    let topic = "/posestream/heatmaps";
    let mut source = subscriber
        .source::<msgs::HeatMaps>(topic)
        .expect("subscription");
    let mut sink = publisher.sink::<msgs::HeatMaps>(topic).expect("publisher");
    let recycler = source.recycler();
    let frames = frames_in(encoding);
    let n = frames.len() as u64;
    let message = |s: u64| {
        let mut m = frames[(s % n) as usize].clone();
        m.sequence = s;
        m.header.stamp = Time::from_nanos(s as i64 * 33_333_333);
        m
    };
    // Discovery: probe until the subscription hears the publisher.
    let start = std::time::Instant::now();
    loop {
        assert!(start.elapsed().as_secs() < 30, "discovery failed");
        sink.send(&message(0), 0).expect("send");
        if let Received::Message(m, _) = source
            .recv(std::time::Duration::from_millis(50))
            .expect("recv")
        {
            recycler.put(m);
            break;
        }
    }
    while let Received::Message(m, _) = source
        .recv(std::time::Duration::from_millis(300))
        .expect("recv")
    {
        recycler.put(m);
    }
    let mut node = EstimatorNode::new(window());
    let mut out = Vec::new();
    let warm = 2 * n;
    let (mut allocations, mut emitted) = (0, 0);
    for s in 1..warm + 1000 {
        sink.send(&message(s), 0).expect("send");
        let mut receive = || {
            let got = source
                .recv(std::time::Duration::from_secs(5))
                .expect("receive");
            let Received::Message(m, _) = got else {
                panic!("frame {s} not received: {got:?}");
            };
            node.handle(&m, &mut out).expect("a good frame");
            recycler.put(m);
        };
        if s < warm {
            receive();
        } else {
            allocations += count(receive);
            emitted += out.len();
        }
        node.recycle(&mut out);
    }
    TRACES.with(|t| {
        for trace in t.borrow_mut().drain(..) {
            eprintln!("allocation at:\n{trace}");
        }
    });
    assert_eq!(emitted, 2000, "{encoding:?}: two skeletons per frame");
    eprintln!("{encoding:?}: {allocations} allocations over 1000 ROS 2 frames");
    assert!(
        allocations <= 2 * 1000,
        "{encoding:?}: {allocations} allocations over 1000 warm frames from ROS 2"
    );
}

#[test]
fn a_skeleton_goes_to_ros2_without_a_copy() {
    use posestream::nodes::publish::Publishers;
    use posestream::transport::ros2::{Ros2, RosSettings};
    use std::sync::Arc;
    let ros = Ros2::new(&RosSettings {
        domain_id: (std::process::id() % 100) as u16 + 125,
        localhost_only: true,
        node_name: "allocations_out".into(),
        ..RosSettings::default()
    })
    .expect("ROS 2 participant");
    let mut publishers = Publishers::<msgs::Skeleton3D>::default();
    publishers.add_ros2(
        "ros2",
        ros.sink("/posestream/test/skeletons").expect("publisher"),
    );
    // A skeleton as the estimator writes it: 17 joint names, positions, keypoints.
    let mut node = EstimatorNode::new(window());
    let mut out = Vec::new();
    for m in byebye().iter().take(20) {
        node.handle(m, &mut out).expect("a good frame");
    }
    let skeleton = Arc::new(out.pop().expect("a skeleton"));
    let runs = 200;
    for _ in 0..20 {
        publishers.publish_shared(&skeleton, 0);
        publishers.publish(&skeleton, 0);
    }
    let shared = count(|| {
        for _ in 0..runs {
            publishers.publish_shared(&skeleton, 0);
        }
    });
    let copied = count(|| {
        for _ in 0..runs {
            publishers.publish(&skeleton, 0);
        }
    });
    TRACES.with(|t| t.borrow_mut().clear());
    eprintln!(
        "to ROS 2, per skeleton: {} allocations shared, {} copied",
        shared / runs,
        copied / runs
    );
    // A copy is a new message: every joint name and array allocated again.
    let names = skeleton.joint_names.len() as u64;
    assert!(
        copied >= shared + names * runs,
        "shared {shared}, copied {copied} allocations over {runs} skeletons"
    );
}
