//! The `posestream lift` command: outputs, and one clear error line for bad input.

mod common;

use std::process::Command;

use common::{fixture, k128};
use posestream::npy::{self, Array};

fn lift(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_posestream"))
        .arg("lift")
        .args(args)
        .output()
        .expect("run posestream")
}

#[test]
fn lifts_keypoints_to_an_npy_of_poses() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let out = tmp.path().join("S.npy");
    let kp = fixture("synthetic-s1").join("keypoints.npy");
    let o = lift(&[
        "--dict",
        k128().to_str().unwrap_or_default(),
        "--keypoints",
        kp.to_str().unwrap_or_default(),
        "--out",
        out.to_str().unwrap_or_default(),
        "--init",
        "altern",
        "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s: Array<f64> = npy::read(&out).expect("output");
    assert_eq!(s.shape, vec![60, 17, 3]);
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json summary");
    assert_eq!(summary["frames"], 60);
    assert_eq!(summary["init"], "altern");
}

#[test]
fn bad_inputs_give_one_error_line_and_no_panic() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let out = tmp.path().join("S.npy");
    let heat = fixture("synthetic-s0").join("heatmaps.npy");
    let truncated = tmp.path().join("trunc.npy");
    let bytes = std::fs::read(fixture("synthetic-s0").join("keypoints.npy")).expect("read");
    std::fs::write(&truncated, &bytes[..200]).expect("write");
    let empty = tmp.path().join("empty.npy");
    std::fs::write(&empty, b"").expect("write");
    let nan = tmp.path().join("nan.npy");
    npy::write(&nan, &[1, 17, 2], &[f64::NAN; 34]).expect("write");
    let joints = tmp.path().join("joints.npy");
    npy::write(&joints, &[2, 15, 2], &[1.0; 60]).expect("write");
    let zero_maps = tmp.path().join("zero.npy");
    npy::write(&zero_maps, &[1, 17, 8, 8], &[0.0; 17 * 64]).expect("write");
    let bad_dict = tmp.path().join("d.mat");
    std::fs::write(&bad_dict, b"MATLAB 5.0 MAT-file, nonsense").expect("write");
    let d = k128();
    let d = d.to_str().unwrap_or_default();
    let o = out.to_str().unwrap_or_default();
    let cases: Vec<Vec<&str>> = vec![
        vec![
            "--dict",
            d,
            "--keypoints",
            heat.to_str().unwrap_or_default(),
            "--out",
            o,
        ],
        vec![
            "--dict",
            d,
            "--keypoints",
            truncated.to_str().unwrap_or_default(),
            "--out",
            o,
        ],
        vec![
            "--dict",
            d,
            "--keypoints",
            empty.to_str().unwrap_or_default(),
            "--out",
            o,
        ],
        vec![
            "--dict",
            d,
            "--keypoints",
            nan.to_str().unwrap_or_default(),
            "--out",
            o,
        ],
        vec![
            "--dict",
            d,
            "--keypoints",
            joints.to_str().unwrap_or_default(),
            "--out",
            o,
        ],
        vec![
            "--dict",
            d,
            "--heatmaps",
            zero_maps.to_str().unwrap_or_default(),
            "--out",
            o,
        ],
        vec![
            "--dict",
            bad_dict.to_str().unwrap_or_default(),
            "--heatmaps",
            heat.to_str().unwrap_or_default(),
            "--out",
            o,
        ],
        vec![
            "--dict",
            d,
            "--keypoints",
            joints.to_str().unwrap_or_default(),
            "--out",
            o,
            "--alpha",
            "-1",
        ],
    ];
    for args in cases {
        let r = lift(&args);
        let stderr = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success(), "{args:?} succeeded");
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
        assert_eq!(stderr.trim().lines().count(), 1, "{args:?}: {stderr}");
        assert!(
            stderr.starts_with("posestream: error: "),
            "{args:?}: {stderr}"
        );
        assert!(!out.exists(), "{args:?} wrote an output");
    }
}
