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
fn lifts_heat_maps_to_metres_with_intrinsics_and_boxes() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let path = |name: &str| tmp.path().join(name).to_string_lossy().into_owned();
    // The s0 heat maps (64 x 64) as crops of 256 x 256 image pixels at (300, 100).
    let boxes: Vec<f64> = (0..60).flat_map(|_| [300.0, 100.0, 256.0, 256.0]).collect();
    npy::write(&tmp.path().join("boxes.npy"), &[60, 4], &boxes).expect("write");
    std::fs::write(
        tmp.path().join("K.json"),
        r#"{"K": [[1000, 0, 640], [0, 1000, 360], [0, 0, 1]]}"#,
    )
    .expect("write");
    let heat = fixture("synthetic-s0").join("heatmaps.npy");
    let o = lift(&[
        "--dict",
        &k128().to_string_lossy(),
        "--heatmaps",
        &heat.to_string_lossy(),
        "--intrinsics",
        &path("K.json"),
        "--boxes",
        &path("boxes.npy"),
        "--mean-limb-length",
        "0.25",
        "--out",
        &path("S.npy"),
        "--out-2d",
        &path("W.npy"),
        "--out-proj",
        &path("P.npy"),
        "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s: Array<f64> = npy::read(&tmp.path().join("S.npy")).expect("poses");
    let w: Array<f64> = npy::read(&tmp.path().join("W.npy")).expect("2d");
    let proj: Array<f64> = npy::read(&tmp.path().join("P.npy")).expect("projection");
    assert_eq!(s.shape, vec![60, 17, 3]);
    // In front of the camera, and 2D outputs in image pixels inside the boxes.
    assert!(s.data.chunks_exact(3).all(|q| q[2] > 0.5));
    assert!(
        w.data
            .chunks_exact(2)
            .all(|q| (299.5..555.5).contains(&q[0]) && (99.5..355.5).contains(&q[1]))
    );
    let reprojection = posestream::accuracy::mean_error_2d(&proj.data, &w.data);
    assert!(reprojection < 2.0, "reprojection {reprojection} px");
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json summary");
    assert!(summary["perspective"]["mean_iterations"].as_f64() > Some(1.0));
}

#[test]
fn bad_inputs_give_one_error_line_and_no_panic() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let path = |name: &str| tmp.path().join(name).to_string_lossy().into_owned();
    let out = path("S.npy");
    let heat = fixture("synthetic-s0")
        .join("heatmaps.npy")
        .to_string_lossy()
        .into_owned();
    let bytes = std::fs::read(fixture("synthetic-s0").join("keypoints.npy")).expect("read");
    std::fs::write(path("trunc.npy"), &bytes[..200]).expect("write");
    std::fs::write(path("empty.npy"), b"").expect("write");
    npy::write(
        tmp.path().join("nan.npy").as_path(),
        &[1, 17, 2],
        &[f64::NAN; 34],
    )
    .expect("write");
    npy::write(
        tmp.path().join("joints.npy").as_path(),
        &[2, 15, 2],
        &[1.0; 60],
    )
    .expect("write");
    npy::write(
        tmp.path().join("zero.npy").as_path(),
        &[1, 17, 8, 8],
        &[0.0; 17 * 64],
    )
    .expect("write");
    std::fs::write(path("d.mat"), b"MATLAB 5.0 MAT-file, nonsense").expect("write");
    std::fs::write(
        path("K.json"),
        r#"{"fx": 1000, "fy": 1000, "cx": 640, "cy": 360}"#,
    )
    .expect("write");
    std::fs::write(
        path("K-neg.json"),
        r#"{"fx": -1000, "fy": 1000, "cx": 640, "cy": 360}"#,
    )
    .expect("write");
    std::fs::write(path("K-bad.json"), r#"{"fx": 1000"#).expect("write");
    npy::write(
        tmp.path().join("boxes3.npy").as_path(),
        &[60, 3],
        &[10.0; 180],
    )
    .expect("write");
    npy::write(
        tmp.path().join("boxes1.npy").as_path(),
        &[1, 4],
        &[0.0, 0.0, 64.0, 64.0],
    )
    .expect("write");
    let flat: Vec<f64> = (0..60).flat_map(|_| [0.0, 0.0, 0.0, 64.0]).collect();
    npy::write(tmp.path().join("boxes0.npy").as_path(), &[60, 4], &flat).expect("write");
    let d = k128().to_string_lossy().into_owned();
    let kp = |file: &str| vec!["--dict".into(), d.clone(), "--keypoints".into(), path(file)];
    let hm = |file: &str| vec!["--dict".into(), d.clone(), "--heatmaps".into(), file.into()];
    let with = |mut a: Vec<String>, more: &[&str]| {
        a.extend(more.iter().map(|s| s.to_string()));
        a
    };
    let s0_keypoints = fixture("synthetic-s0")
        .join("keypoints.npy")
        .to_string_lossy()
        .into_owned();
    let cases: Vec<(&str, Vec<String>)> = vec![
        (
            "heat maps as keypoints",
            vec![
                "--dict".into(),
                d.clone(),
                "--keypoints".into(),
                heat.clone(),
            ],
        ),
        ("truncated file", kp("trunc.npy")),
        ("empty file", kp("empty.npy")),
        ("NaN", kp("nan.npy")),
        ("wrong joint count", kp("joints.npy")),
        ("all-zero heat maps", hm(&path("zero.npy"))),
        (
            "unreadable dictionary",
            vec![
                "--dict".into(),
                path("d.mat"),
                "--heatmaps".into(),
                heat.clone(),
            ],
        ),
        ("negative alpha", with(kp("joints.npy"), &["--alpha", "-1"])),
        (
            "malformed intrinsics",
            with(kp("joints.npy"), &["--intrinsics", &path("K-bad.json")]),
        ),
        (
            "negative focal length",
            with(kp("joints.npy"), &["--intrinsics", &path("K-neg.json")]),
        ),
        (
            "missing intrinsics file",
            with(kp("joints.npy"), &["--intrinsics", &path("none.json")]),
        ),
        (
            "zero limb length",
            with(
                vec![
                    "--dict".into(),
                    d.clone(),
                    "--keypoints".into(),
                    s0_keypoints.clone(),
                ],
                &["--intrinsics", &path("K.json"), "--mean-limb-length", "0"],
            ),
        ),
        (
            "heat maps without boxes",
            with(hm(&heat), &["--intrinsics", &path("K.json")]),
        ),
        (
            "boxes of 3 values",
            with(
                hm(&heat),
                &[
                    "--intrinsics",
                    &path("K.json"),
                    "--boxes",
                    &path("boxes3.npy"),
                ],
            ),
        ),
        (
            "one box for 60 frames",
            with(
                hm(&heat),
                &[
                    "--intrinsics",
                    &path("K.json"),
                    "--boxes",
                    &path("boxes1.npy"),
                ],
            ),
        ),
        (
            "zero-width boxes",
            with(
                hm(&heat),
                &[
                    "--intrinsics",
                    &path("K.json"),
                    "--boxes",
                    &path("boxes0.npy"),
                ],
            ),
        ),
    ];
    for (name, args) in cases {
        let r = lift(
            &with(args, &["--out", &out])
                .iter()
                .map(String::as_str)
                .collect::<Vec<_>>(),
        );
        let stderr = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success(), "{name}: succeeded");
        assert!(!stderr.contains("panicked"), "{name}: {stderr}");
        assert_eq!(stderr.trim().lines().count(), 1, "{name}: {stderr}");
        assert!(
            stderr.starts_with("posestream: error: "),
            "{name}: {stderr}"
        );
        assert!(
            !std::path::Path::new(&out).exists(),
            "{name}: wrote an output"
        );
    }
}

/// `--duration` of the service commands: a value that is not a finite number of seconds
/// in its domain is refused by the argument parser (exit 2, naming the option), before
/// anything starts. `1e30` panicked (`record`: exit 101 and a `.partial` left; `estimator`:
/// its timer thread died and it ran on until a signal), `nan` and `inf` meant "forever".
#[test]
fn a_duration_out_of_its_domain_is_refused_before_anything_starts() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("out.mcap");
    for value in ["1e30", "nan", "inf", "1e10"] {
        for args in [
            vec!["estimator", "--duration", value],
            vec!["record", "--duration", value, out.to_str().expect("utf-8")],
        ] {
            let mut child = Command::new(env!("CARGO_BIN_EXE_posestream"))
                .args(&args)
                .current_dir(common::root())
                .stdout(std::process::Stdio::null())
                .stderr(std::process::Stdio::piped())
                .spawn()
                .expect("posestream");
            let until = std::time::Instant::now() + std::time::Duration::from_secs(10);
            while child.try_wait().expect("wait").is_none() && std::time::Instant::now() < until {
                std::thread::sleep(std::time::Duration::from_millis(50));
            }
            let _ = child.kill();
            let output = child.wait_with_output().expect("output");
            let stderr = String::from_utf8_lossy(&output.stderr);
            assert_eq!(output.status.code(), Some(2), "{args:?}: {stderr}");
            assert!(stderr.contains("--duration"), "{args:?}: {stderr}");
            assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
        }
    }
    assert_eq!(
        std::fs::read_dir(dir.path()).expect("dir").count(),
        0,
        "files left"
    );
}

/// `eval --only` with a name no held-out file has: one error line naming it (and the
/// `--max-files-per-action` cap that may have hidden the file), no evaluation, no panic;
/// an empty name (every file) is refused.
#[test]
fn eval_only_a_name_no_file_has_is_one_clear_error() {
    for (extra, cap) in [(vec![], false), (vec!["--max-files-per-action", "1"], true)] {
        let output = Command::new(env!("CARGO_BIN_EXE_posestream"))
            .args(["eval", "--no-scenes", "--only", "no-such-take\u{1F600}"])
            .args(&extra)
            .current_dir(common::root())
            .output()
            .expect("posestream");
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success(), "{stderr}");
        assert!(stderr.contains("no-such-take"), "{stderr}");
        assert_eq!(stderr.contains("--max-files-per-action"), cap, "{stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
        assert!(output.stdout.is_empty(), "no tables");
    }
    // An empty name would match every file: refused, not a full evaluation.
    let output = Command::new(env!("CARGO_BIN_EXE_posestream"))
        .args(["eval", "--no-scenes", "--only", ""])
        .current_dir(common::root())
        .output()
        .expect("posestream");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "{stderr}");
    assert!(stderr.contains("--only"), "{stderr}");
    assert!(output.stdout.is_empty(), "no tables");
}
