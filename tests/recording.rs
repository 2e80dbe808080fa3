//! MCAP recordings: round trips, cut-short files, killed and interrupted recorders,
//! malformed messages, and independent Python clients (mcap, mcap-ros2-support, rosbags).

mod common;

use std::process::{Command, Stdio};
use std::time::Duration;

use common::{python_client, recording};
use posestream::msgs::{self, Header, Skeleton3D, Time};
use posestream::recording::read_topic;
use posestream::recording::{Recorder, RecordingError, RecordingReader};

fn skeleton(sequence: u64) -> Skeleton3D {
    Skeleton3D {
        header: Header {
            stamp: Time::from_nanos(sequence as i64 * 1_000_000),
            frame_id: "camera".into(),
        },
        sequence,
        joint_names: vec!["a".into(), "b".into()],
        positions: (0..6).map(|i| i as f64 + sequence as f64).collect(),
        lag: 3,
        state: 1,
        ..Skeleton3D::default()
    }
}

#[test]
fn a_recording_reads_back_message_for_message() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("r.mcap");
    let mut rec = Recorder::create(&path).expect("create");
    for s in 0..500 {
        rec.write("/x", s * 1_000_000, &skeleton(s)).expect("write");
    }
    let summary = rec.finish().expect("finish");
    assert_eq!(
        summary.topics["/x"],
        ("posestream_msgs/msg/Skeleton3D".into(), 500)
    );
    let back: Vec<(u64, Skeleton3D)> = read_topic(&path, "/x").expect("reads");
    assert_eq!(back.len(), 500);
    for (s, (t, m)) in back.iter().enumerate() {
        assert_eq!(*t, s as u64 * 1_000_000);
        assert_eq!(*m, skeleton(s as u64));
    }
}

#[test]
fn a_cut_short_recording_yields_its_complete_chunks_then_an_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("r.mcap");
    let mut rec = Recorder::create(&path).expect("create");
    rec.set_flush_interval(None);
    for s in 0..300 {
        rec.write("/x", s, &skeleton(s)).expect("write");
        if s % 100 == 99 {
            rec.flush().expect("flush"); // a chunk per 100 messages
        }
    }
    rec.finish().expect("finish");
    let bytes = std::fs::read(&path).expect("read");
    let cut_path = dir.path().join("cut.mcap");
    let mut last = 0;
    for cut in (0..bytes.len()).step_by(97) {
        std::fs::write(&cut_path, &bytes[..cut]).expect("write");
        if cut == 0 {
            let empty = RecordingReader::open(&cut_path).err();
            assert!(
                matches!(empty, Some(RecordingError::NotMcap { .. })),
                "{empty:?}"
            );
            continue;
        }
        let mut reader = RecordingReader::open(&cut_path).expect("open");
        let mut n = 0;
        let mut ended = None;
        for m in reader.by_ref() {
            match m {
                Ok(m) => {
                    let s: Skeleton3D = msgs::decode(&m.data).expect("complete message");
                    assert_eq!(s, skeleton(n));
                    n += 1;
                }
                Err(e) => ended = Some(e),
            }
        }
        assert!(
            matches!(ended, Some(RecordingError::Truncated { .. })),
            "cut at {cut}: {ended:?}"
        );
        assert!(n % 100 == 0 && n >= last, "cut at {cut}: {n} messages");
        last = n;
    }
    assert_eq!(last, 300);
}

#[test]
fn python_clients_decode_a_replayed_recording_and_its_rosbag2_folder() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("bag_0.mcap");
    let status = Command::new(env!("CARGO_BIN_EXE_posestream"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(["replay", "recordings/byebye.mcap", "--rosbag2", "--record"])
        .arg(&out)
        .status()
        .expect("runs");
    assert!(status.success());
    let ours: Vec<(u64, Skeleton3D)> = read_topic(&out, "/posestream/skeletons").expect("reads");
    let mcap = python_client("read_recording.py", &[out.to_str().expect("utf-8")]);
    assert_eq!(mcap["topics"]["/posestream/skeletons"], ours.len());
    assert_eq!(mcap["topics"]["/posestream/ground_truth"], 121);
    assert_eq!(
        mcap["schemas"]["/posestream/skeletons"],
        "posestream_msgs/msg/Skeleton3D"
    );
    let first = &mcap["skeletons"][0];
    assert_eq!(first["sequence"], ours[0].1.sequence);
    assert_eq!(first["joint_names"][0], ours[0].1.joint_names[0]);
    let positions: Vec<f64> = serde_json::from_value(first["positions"].clone()).expect("f64");
    assert_eq!(positions, ours[0].1.positions);
    let bag = python_client(
        "read_recording.py",
        &["--rosbag2", dir.path().to_str().expect("utf-8")],
    );
    assert_eq!(bag["topics"]["/posestream/skeletons"], ours.len());
    assert_eq!(
        bag["first"]["/posestream/skeletons"]["type"],
        "posestream_msgs/msg/Skeleton3D"
    );
    // The input recording (heat maps, u8-quantised) decodes too.
    let input = python_client(
        "read_recording.py",
        &[recording("kick.mcap").to_str().expect("utf-8")],
    );
    assert_eq!(input["topics"]["/posestream/heatmaps"], 150);
    assert_eq!(input["heatmaps"][0]["quantized_values"], 17 * 64 * 64);
}

/// Starts a replay at the recorded pace (4 s) writing to `out`, waits `after`, sends
/// `signal`, and returns the exit status.
fn replay_and_signal(
    out: &std::path::Path,
    signal: &str,
    after: Duration,
) -> std::process::ExitStatus {
    let mut child = Command::new(env!("CARGO_BIN_EXE_posestream"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args([
            "replay",
            "recordings/byebye.mcap",
            "--rate",
            "recorded",
            "--record",
        ])
        .arg(out)
        .stdout(Stdio::null())
        .spawn()
        .expect("starts");
    std::thread::sleep(after);
    let status = Command::new("kill")
        .args([signal, &child.id().to_string()])
        .status()
        .expect("kill");
    assert!(status.success());
    child.wait().expect("waits")
}

#[test]
fn a_killed_recorder_leaves_every_complete_chunk_readable() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("killed.mcap");
    let status = replay_and_signal(&out, "-KILL", Duration::from_millis(2600));
    assert!(!status.success());
    // The output is renamed into place only when finished: a killed recorder leaves
    // its messages in `killed.mcap.PID.partial` beside it.
    assert!(!out.exists());
    let partial: Vec<_> = std::fs::read_dir(dir.path())
        .expect("list")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.to_string_lossy().ends_with(".partial"))
        .collect();
    assert_eq!(partial.len(), 1, "{partial:?}");
    let out = partial[0].clone();
    let mut reader = RecordingReader::open(&out).expect("open");
    let mut n = 0;
    let mut ended = None;
    for m in reader.by_ref() {
        match m {
            Ok(m) => {
                match m.schema.as_str() {
                    "posestream_msgs/msg/Skeleton3D" => {
                        msgs::decode::<Skeleton3D>(&m.data).expect("complete message");
                    }
                    "posestream_msgs/msg/Skeleton3DArray" => {
                        msgs::decode::<msgs::Skeleton3DArray>(&m.data).expect("complete message");
                    }
                    other => panic!("{other} on {}", m.topic),
                }
                n += 1;
            }
            Err(e) => ended = Some(e),
        }
    }
    // Chunks are flushed every second: after 2.6 s at least two are complete.
    println!("{n} messages before the cut: {ended:?}");
    assert!(n >= 60, "{n} messages");
    assert!(
        matches!(ended, Some(RecordingError::Truncated { .. })),
        "{ended:?}"
    );
    let py = python_client(
        "read_recording.py",
        &[out.to_str().expect("utf-8"), "--allow-truncated"],
    );
    let topics = py["topics"].as_object().expect("topics");
    let py_n: u64 = topics.values().map(|v| v.as_u64().unwrap_or(0)).sum();
    assert_eq!(py_n, n, "{py}");
}

#[test]
fn an_interrupted_replay_finalises_its_recording() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("interrupted.mcap");
    let status = replay_and_signal(&out, "-INT", Duration::from_millis(1500));
    assert!(status.success(), "{status:?}");
    let all: Vec<_> = RecordingReader::open(&out)
        .expect("open")
        .collect::<Result<Vec<_>, _>>()
        .expect("a complete recording");
    assert!(all.len() > 20 && all.len() < 363, "{} messages", all.len());
    let py = python_client("read_recording.py", &[out.to_str().expect("utf-8")]);
    assert!(py["error"].is_null());
}

#[test]
fn malformed_heat_map_messages_are_counted_and_skipped() {
    let dir = tempfile::tempdir().expect("tempdir");
    let input = dir.path().join("bad.mcap");
    let good: Vec<(u64, msgs::HeatMaps)> =
        read_topic(&recording("byebye.mcap"), "/posestream/heatmaps").expect("reads");
    let mut rec = Recorder::create(&input).expect("create");
    for (i, (t, m)) in good.iter().take(40).enumerate() {
        match i {
            10 => {
                let mut bytes = msgs::encode(m).expect("encodes");
                bytes.truncate(bytes.len() / 2);
                rec.write_encoded::<msgs::HeatMaps>("/posestream/heatmaps", *t, &bytes)
                    .expect("write");
            }
            20 => {
                let mut wrong = m.clone();
                wrong.joint_names[3] = "tail".into();
                rec.write("/posestream/heatmaps", *t, &wrong)
                    .expect("write");
            }
            30 => {
                let mut wrong = m.clone();
                wrong.quantized_values.truncate(100);
                rec.write("/posestream/heatmaps", *t, &wrong)
                    .expect("write");
            }
            _ => rec.write("/posestream/heatmaps", *t, m).expect("write"),
        }
    }
    rec.finish().expect("finish");
    let out = Command::new(env!("CARGO_BIN_EXE_posestream"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(["replay", "--json"])
        .arg(&input)
        .output()
        .expect("runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    assert_eq!(report["frames"], 40);
    assert_eq!(report["malformed"], 3);
    // Two estimates (newest and refined) for each of the 37 good frames.
    assert_eq!(report["skeletons"], 74);
}
