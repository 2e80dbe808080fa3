//! One skeleton message from a publisher to a subscriber in the same process: the hop
//! latency of each transport (publish, deliver, receive and decode a `Skeleton3D` of 17
//! joints). ROS 2 runs on loopback in a domain of its own.

use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use posestream::msgs::{Header, Skeleton3D, Time};
use posestream::transport::ros2::{Ros2, RosSettings};
use posestream::transport::shm::Shm;
use posestream::transport::{Received, Sink, Source};

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
        position_std: vec![0.01; p],
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

fn bench(c: &mut Criterion) {
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

    let settings = RosSettings {
        domain_id: (std::process::id() % 90) as u16 + 120,
        localhost_only: true,
        ..RosSettings::default()
    };
    let mut publisher = Ros2::new(&settings).expect("ros2");
    let mut subscriber = Ros2::new(&RosSettings {
        node_name: "bench_sub".into(),
        ..settings.clone()
    })
    .expect("ros2");
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
}

criterion_group!(benches, bench);
criterion_main!(benches);
