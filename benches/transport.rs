//! One skeleton message from a publisher to a subscriber in the same process: the hop
//! latency of each transport (publish, deliver, receive and decode a `Skeleton3D` of 17
//! joints), each waited on by a blocking call and on a tokio runtime. Then a frame
//! through the estimator node over ROS 2, its loop blocking or on the runtime: heat maps
//! published, received, solved, and the frame's newest skeleton published and received.
//! ROS 2 runs on loopback in domains of its own.

use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use std::sync::atomic::{AtomicBool, Ordering};

use posestream::msgs::{Header, HeatMaps, Skeleton3D, Time};
use posestream::nodes::service::{
    EstimatorOutputs, Publishers, run_estimator, run_estimator_on_runtime,
};
use posestream::nodes::{EstimatorNode, ServiceConfig};
use posestream::recording::read_topic;
use posestream::transport::ros2::{Ros2, RosSettings};
use posestream::transport::runtime::{AsyncSource, Blocking};
use posestream::transport::shm::Shm;
use posestream::transport::{Lend, Received, Sink, Source};

fn skeleton(seq: u64) -> Skeleton3D {
    let p = 17;
    Skeleton3D {
        header: Header {
            stamp: Time::from_nanos(seq as i64),
            frame_id: "camera".into(),
        },
        sequence: seq,
        joint_names: (0..p).map(|j| format!("joint{j}")).collect(),
        positions: vec![0.5; 3 * p],
        position_std: vec![0.01; 3 * p],
        keypoints: vec![100.0; 2 * p],
        keypoint_std: vec![1.0; p],
        projected: vec![100.0; 2 * p],
        ..Skeleton3D::default()
    }
}

/// Sends one message and waits until it arrives.
fn hop(sink: &mut dyn Sink<Skeleton3D>, source: &mut dyn Source<Skeleton3D>, m: &Skeleton3D) {
    sink.send(m, 0).expect("send");
    loop {
        match source.recv(Duration::from_secs(5)).expect("recv") {
            Received::Message(got, _) if got.sequence == m.sequence => return,
            Received::Message(..) => {}
            Received::Idle | Received::Closed => panic!("lost a message"),
        }
    }
}

/// As [`hop`], the message awaited on `runtime`.
fn hop_awaited(
    runtime: &tokio::runtime::Runtime,
    sink: &mut dyn Sink<Skeleton3D>,
    source: &mut impl AsyncSource<Skeleton3D>,
    m: &Skeleton3D,
) {
    sink.send(m, 0).expect("send");
    runtime.block_on(async {
        loop {
            match source.next().await.expect("recv") {
                Received::Message(got, _) if got.sequence == m.sequence => return,
                Received::Message(..) => {}
                Received::Idle | Received::Closed => panic!("lost a message"),
            }
        }
    })
}

fn settings(domain: u16, node: &str) -> RosSettings {
    RosSettings {
        domain_id: domain,
        localhost_only: true,
        node_name: node.into(),
        ..RosSettings::default()
    }
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
        .expect("runtime")
}

fn bench(c: &mut Criterion) {
    hops(c);
    node(c, false);
    node(c, true);
}

/// A frame through the estimator node over ROS 2: its loop blocking (`run_estimator`)
/// or on a runtime (`run_estimator_on_runtime`).
fn node(c: &mut Criterion, on_runtime: bool) {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let config = ServiceConfig::load(root.join("config/default.toml")).expect("config");
    let frames: Vec<HeatMaps> =
        read_topic::<HeatMaps>(&root.join("recordings/byebye.mcap"), "/posestream/heatmaps")
            .expect("reads")
            .into_iter()
            .map(|(_, m)| m)
            .collect();
    let domain = (std::process::id() % 80) as u16 + 130 + u16::from(on_runtime);
    let mut node = EstimatorNode::from_config(&config.estimator).expect("node");
    let server = Ros2::new(&settings(domain, "estimator")).expect("ros2");
    let client = Ros2::new(&settings(domain, "client")).expect("ros2");
    let (maps_topic, skeletons_topic) = ("/posestream/heatmaps", "/posestream/skeletons");
    let input = server.source::<HeatMaps>(maps_topic).expect("subscription");
    let mut skeletons = Publishers::default();
    skeletons.add_ros2(
        "ros2",
        server
            .sink::<Skeleton3D>(skeletons_topic)
            .expect("publisher"),
    );
    let mut outputs = EstimatorOutputs::new(skeletons, Publishers::default(), node.bones());
    let mut maps = client.sink::<HeatMaps>(maps_topic).expect("publisher");
    let mut heard = client
        .source::<Skeleton3D>(skeletons_topic)
        .expect("subscription");
    let stop = AtomicBool::new(false);
    // Frame `i`: the recording's frames over and over, numbered on, 30 frames/s.
    let frame = |i: u64| {
        let mut m = frames[i as usize % frames.len()].clone();
        m.sequence = i;
        m.header.stamp = Time::from_nanos(i as i64 * 33_333_333);
        m
    };
    std::thread::scope(|scope| {
        let stop = &stop;
        let node = &mut node;
        let outputs = &mut outputs;
        scope.spawn(move || {
            if on_runtime {
                run_estimator_on_runtime(node, input, outputs, stop).expect("runs");
            } else {
                run_estimator(node, &mut Lend(input), outputs, stop);
            }
        });
        // Sends frame `i` and waits for its newest skeleton.
        let mut through = |i: u64, patience: Duration| -> bool {
            maps.send(&frame(i), 0).expect("send");
            let until = Instant::now() + patience;
            while Instant::now() < until {
                if let Received::Message(s, _) = heard.recv(patience).expect("recv")
                    && s.sequence == i
                    && s.lag == 0
                {
                    return true;
                }
            }
            false
        };
        // Discovery: frames until one comes through.
        let start = Instant::now();
        let mut i = 0;
        while !through(i, Duration::from_millis(100)) {
            assert!(
                start.elapsed() < Duration::from_secs(30),
                "discovery failed"
            );
            i += 1;
        }
        let name = if on_runtime {
            "estimator node over ROS 2, on the runtime (frame in, its skeleton out)"
        } else {
            "estimator node over ROS 2, blocking (frame in, its skeleton out)"
        };
        c.bench_function(name, |b| {
            b.iter(|| {
                i += 1;
                assert!(through(i, Duration::from_secs(5)), "lost frame {i}");
            })
        });
        stop.store(true, Ordering::Relaxed);
    });
}

/// The transports' hops, waited on by a blocking call and on a runtime.
fn hops(c: &mut Criterion) {
    let runtime = runtime();
    let shm = Shm::new().expect("iceoryx2");
    let name = format!("posestream-bench/{}/skeletons", std::process::id());
    let mut source = shm.skeleton_source(&name).expect("subscriber");
    let mut sink = shm.skeleton_sink(&name).expect("publisher");
    let mut seq = 0;
    c.bench_function("iceoryx2 hop (Skeleton3D, 17 joints)", |b| {
        b.iter(|| {
            seq += 1;
            hop(&mut sink, &mut source, &skeleton(seq));
        })
    });
    // The same source on a thread of its own, handing over to the runtime.
    let mut source = Blocking::spawn("bench", source, 4).expect("thread");
    c.bench_function("iceoryx2 hop, awaited (Skeleton3D, 17 joints)", |b| {
        b.iter(|| {
            seq += 1;
            hop_awaited(&runtime, &mut sink, &mut source, &skeleton(seq));
        })
    });

    let domain = (std::process::id() % 90) as u16 + 120;
    let publisher = Ros2::new(&settings(domain, "posestream")).expect("ros2");
    let subscriber = Ros2::new(&settings(domain, "bench_sub")).expect("ros2");
    let topic = "/posestream/skeletons";
    let mut source = subscriber
        .source::<Skeleton3D>(topic)
        .expect("subscription");
    let mut sink = publisher.sink::<Skeleton3D>(topic).expect("publisher");
    // Discovery: probe until one arrives.
    let start = Instant::now();
    loop {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "discovery failed"
        );
        sink.send(&skeleton(0), 0).expect("send");
        if let Received::Message(..) = source.recv(Duration::from_millis(50)).expect("recv") {
            break;
        }
    }
    while let Received::Message(..) = source.recv(Duration::from_millis(200)).expect("recv") {}
    c.bench_function("ROS 2 hop on loopback (Skeleton3D, 17 joints)", |b| {
        b.iter(|| {
            seq += 1;
            hop(&mut sink, &mut source, &skeleton(seq));
        })
    });
    c.bench_function(
        "ROS 2 hop on loopback, awaited (Skeleton3D, 17 joints)",
        |b| {
            b.iter(|| {
                seq += 1;
                hop_awaited(&runtime, &mut sink, &mut source, &skeleton(seq));
            })
        },
    );
}

criterion_group!(benches, bench);
criterion_main!(benches);
