//! A node survives any single message: a panic injected into the handling of one frame
//! (`--features fault-injection`, `POSESTREAM_INJECT_PANIC_AT`) is caught, logged once at
//! error level saying where, counted, and the track is reset; the stream goes on.

mod common;

use std::process::Command;

use common::recording;
use posestream::msgs::Skeleton3D;
use posestream::recording::read_topic;

#[test]
fn a_panic_in_one_frame_resets_the_track_and_the_stream_goes_on() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("out.mcap");
    let run = Command::new(env!("CARGO_BIN_EXE_posestream"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env("POSESTREAM_INJECT_PANIC_AT", "50")
        .args(["replay", "--json", "--record"])
        .arg(&out)
        .arg(recording("byebye.mcap"))
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{stderr}");
    // One line at error level says where it panicked.
    let panics: Vec<&str> = stderr.lines().filter(|l| l.contains("panic at")).collect();
    assert_eq!(panics.len(), 1, "{stderr}");
    assert!(
        panics[0].contains("ERROR") && panics[0].contains("src/nodes/estimator/mod.rs:"),
        "{stderr}"
    );
    assert!(panics[0].contains("injected panic"), "{stderr}");
    let report: serde_json::Value = serde_json::from_slice(&run.stdout).expect("json");
    assert_eq!(report["frames"], 121);
    assert_eq!(report["refused"]["panic"], 1, "{report}");
    // Frames 0..50 were one track; the node reset it and frames 51.. start another.
    assert_eq!(report["counters"]["tracks"], 2, "{report}");
    let skeletons: Vec<(u64, Skeleton3D)> =
        read_topic(&out, "/posestream/skeletons").expect("reads");
    let newest: Vec<u64> = skeletons
        .iter()
        .filter(|(_, s)| s.lag == 0 && s.state != posestream::msgs::SkeletonState::Lost as u8)
        .map(|(_, s)| s.sequence)
        .collect();
    assert_eq!(newest.len(), 120, "every frame but the one that panicked");
    assert!(!newest.contains(&50));
    assert!(newest.contains(&51) && newest.contains(&120));
}
