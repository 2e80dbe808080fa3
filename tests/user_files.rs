//! Users' files against the release binary: special files named where a file is read
//! (devices, FIFOs, links to them), outputs named onto inputs, a full disk. Each is one
//! clear error (exit 1) within the hostile-input memory budget and at once (a `timeout`
//! ends a run that would block: exit 124 fails the case), and no input is overwritten.
//! `POSESTREAM_BIN` runs the same against another build.

mod common;

use std::os::unix::fs::FileTypeExt;
use std::path::{Path, PathBuf};
use std::process::Command;

use common::{peak_memory_run, root};

/// Peak resident memory any hostile input may cost the process (kB).
const MEMORY_BUDGET_KB: u64 = 200 * 1024;

fn binary() -> PathBuf {
    std::env::var_os("POSESTREAM_BIN")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_BIN_EXE_posestream")))
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// Runs the binary for at most 20 s; asserts one error line containing `needle` (exit 1),
/// within the memory budget.
fn one_error(args: &[&str], needle: &str) -> String {
    let bin = binary();
    let mut all = vec!["20", s(&bin)];
    all.extend_from_slice(args);
    let (code, out, peak_kb) = peak_memory_run(Path::new("timeout"), &all, &[]);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(code, Some(1), "{args:?}: {stderr}");
    let lines: Vec<&str> = stderr.lines().collect();
    assert_eq!(lines.len(), 1, "{args:?}: {stderr}");
    assert!(
        lines[0].starts_with("posestream: error: ") && lines[0].contains(needle),
        "{args:?}: expected an error about {needle:?}: {stderr}"
    );
    assert!(
        peak_kb < MEMORY_BUDGET_KB,
        "{args:?}: peak {} MB",
        peak_kb / 1024
    );
    stderr
}

fn fifo(path: &Path) {
    let made = Command::new("mkfifo").arg(path).status().expect("mkfifo");
    assert!(made.success());
}

#[test]
fn devices_fifos_and_links_to_them_are_refused_where_a_file_is_read() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let zero_json = d.join("zero.json");
    let zero_npy = d.join("zero.npy");
    let zero_mcap = d.join("zero.mcap");
    for link in [&zero_json, &zero_npy, &zero_mcap] {
        std::os::unix::fs::symlink("/dev/zero", link).expect("link");
    }
    let pipe_json = d.join("pipe.json");
    let pipe_mcap = d.join("pipe.mcap");
    fifo(&pipe_json);
    fifo(&pipe_mcap);
    let k128 = common::k128();
    let kp = common::fixture("synthetic-s0").join("keypoints.npy");
    let out = d.join("S.npy");
    // The dictionary, from the configuration and on the command line.
    for (dictionary, what) in [(&zero_json, "character device"), (&pipe_json, "FIFO")] {
        let config = d.join("c.toml");
        std::fs::write(
            &config,
            format!("[estimator]\ndictionary = {:?}\n", s(dictionary)),
        )
        .expect("write");
        one_error(
            &["replay", "recordings/kick.mcap", "--config", s(&config)],
            what,
        );
        one_error(
            &[
                "lift",
                "--dict",
                s(dictionary),
                "--keypoints",
                s(&kp),
                "--out",
                s(&out),
            ],
            what,
        );
    }
    // Keypoints, a BVH, a recording.
    one_error(
        &[
            "lift",
            "--dict",
            s(&k128),
            "--keypoints",
            s(&zero_npy),
            "--out",
            s(&out),
        ],
        "character device",
    );
    one_error(
        &[
            "synth",
            "--bvh",
            "/dev/zero",
            "--mapping",
            "config/skeletons/bandai-namco.toml",
            "--out",
            s(&d.join("synth")),
        ],
        "character device",
    );
    one_error(&["replay", s(&zero_mcap)], "character device");
    one_error(&["replay", s(&pipe_mcap)], "FIFO");
    one_error(&["recover", s(&pipe_mcap), s(&d.join("r.mcap"))], "FIFO");
    // A configuration far beyond any real one is refused unread.
    let big = d.join("big.toml");
    std::fs::write(&big, format!("# {}\n", "x".repeat(3_400_000))).expect("write");
    one_error(
        &["replay", "recordings/kick.mcap", "--config", s(&big)],
        "longer than",
    );
    assert!(!out.exists());
}

#[test]
fn render_never_writes_onto_its_inputs_and_a_failed_render_keeps_the_old_picture() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let images = d.join("images");
    std::fs::create_dir(&images).expect("dir");
    let source = images.join("a.png");
    image::RgbImage::new(8, 8).save(&source).expect("png");
    let before = std::fs::read(&source).expect("read");
    let recording = d.join("run.mcap");
    std::fs::copy(root().join("recordings/kick.mcap"), &recording).expect("copy");
    let recorded = std::fs::read(&recording).expect("read");
    let link = d.join("link.png");
    std::os::unix::fs::symlink(&recording, &link).expect("symlink");
    let hard = d.join("hard.gif");
    std::fs::hard_link(&recording, &hard).expect("hard link");
    for output in [&source, &link, &hard] {
        one_error(
            &[
                "render",
                s(&recording),
                "--images",
                s(&images),
                "-o",
                s(output),
            ],
            "the output is an input",
        );
    }
    assert_eq!(std::fs::read(&source).expect("read"), before);
    assert_eq!(std::fs::read(&recording).expect("read"), recorded);
    // A render that fails (no skeletons in this recording) leaves the existing picture
    // and no temporary file.
    let old = d.join("old.png");
    std::fs::write(&old, b"an older picture").expect("write");
    one_error(
        &[
            "render",
            s(&recording),
            "--images",
            s(&images),
            "-o",
            s(&old),
        ],
        "no skeletons",
    );
    assert_eq!(std::fs::read(&old).expect("read"), b"an older picture");
    let names: Vec<String> = std::fs::read_dir(d)
        .expect("dir")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    assert!(!names.iter().any(|n| n.ends_with(".partial")), "{names:?}");
}

/// Runs `script` in a mount namespace of its own where `small` is a file system of
/// `size` (`200k`; no privileges needed); its output.
fn on_a_small_disk(small: &Path, size: &str, script: &str) -> std::process::Output {
    let script = format!(
        "mount -t tmpfs -o size={size} tmpfs {} && {script}",
        s(small)
    );
    Command::new("unshare")
        .args(["-rm", "sh", "-c", &script])
        .current_dir(root())
        .output()
        .expect("unshare")
}

#[test]
fn a_full_disk_is_named_as_such_and_what_is_kept_is_what_is_readable() {
    let dir = tempfile::tempdir().expect("tempdir");
    let small = dir.path().join("small");
    std::fs::create_dir(&small).expect("dir");
    let bin = binary();
    let recovered = dir.path().join("recovered.mcap");
    // The replay fails on the full disk; what its `.partial` file holds is read back on
    // the same disk (it goes with the namespace). 200 kB: no chunk completes; 400 kB:
    // some do.
    for (size, readable) in [("200k", false), ("400k", true)] {
        let _ = std::fs::remove_file(&recovered);
        let out = on_a_small_disk(
            &small,
            size,
            &format!(
                "{0} replay recordings/kick.mcap --record {1}/out.mcap; echo \"exit $?\" >&2; \
                 for p in {1}/*.partial; do {0} recover \"$p\" {2} --json; done",
                s(&bin),
                s(&small),
                s(&recovered)
            ),
        );
        let stderr = String::from_utf8_lossy(&out.stderr);
        let error = stderr
            .lines()
            .find(|l| l.starts_with("posestream: error: "))
            .unwrap_or_else(|| panic!("no error: {stderr}"));
        assert!(stderr.contains("exit 1"), "{stderr}");
        assert!(error.contains("no space left on the device"), "{stderr}");
        if !readable {
            assert!(error.contains("holds no readable message"), "{error}");
            continue;
        }
        // The count the error promises is the count read back.
        let promised: u64 = error
            .split_once(" messages, readable")
            .and_then(|(before, _)| before.rsplit(' ').next()?.parse().ok())
            .unwrap_or_else(|| panic!("a count: {error}"));
        assert!(promised > 0, "{error}");
        let report: serde_json::Value =
            serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{e}: {stderr}"));
        assert_eq!(report["messages"].as_u64(), Some(promised), "{report}");
    }
    // `recover` onto a full disk names its output, not a temporary file it removed.
    let out = on_a_small_disk(
        &small,
        "200k",
        &format!(
            "exec {} recover recordings/kick.mcap {}/r.mcap",
            s(&bin),
            s(&small)
        ),
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    let last = stderr.lines().last().expect("an error");
    assert!(
        last.starts_with("posestream: error: ")
            && last.contains("r.mcap")
            && last.contains("no space left on the device")
            && !last.contains(".partial"),
        "{stderr}"
    );
}

#[test]
fn no_command_writes_onto_a_file_it_read_or_onto_a_device_or_fifo() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    // The configuration a replay read is an input too.
    let config = d.join("c.toml");
    std::fs::write(&config, "[replay]\nstrict = false\n").expect("write");
    let before = std::fs::read(&config).expect("read");
    one_error(
        &[
            "replay",
            "recordings/kick.mcap",
            "--config",
            s(&config),
            "--record",
            s(&config),
        ],
        "the output is an input",
    );
    assert_eq!(std::fs::read(&config).expect("read"), before);
    // A take and its mapping, read by synth, are never its recording.
    let take = d.join("take.bvh");
    let data = common::shared().join("data/mocap/bandai-namco-1");
    let first = std::fs::read_dir(&data)
        .expect("mocap")
        .map(|e| e.expect("entry").path())
        .find(|p| p.extension().is_some_and(|e| e == "bvh"))
        .expect("a take");
    std::fs::copy(&first, &take).expect("copy");
    let taken = std::fs::read(&take).expect("read");
    one_error(
        &[
            "synth",
            "--bvh",
            s(&take),
            "--mapping",
            "config/skeletons/bandai-namco.toml",
            "--frames",
            "5",
            "--out",
            s(&d.join("synth")),
            "--mcap",
            s(&take),
        ],
        "the output is an input",
    );
    assert_eq!(std::fs::read(&take).expect("read"), taken);
    // A FIFO (or a device) named as an output is not replaced by a file.
    let pipe = d.join("pipe.npy");
    fifo(&pipe);
    let k128 = common::k128();
    let kp = common::fixture("synthetic-s0").join("keypoints.npy");
    one_error(
        &[
            "lift",
            "--dict",
            s(&k128),
            "--keypoints",
            s(&kp),
            "--out",
            s(&pipe),
        ],
        "not a regular file",
    );
    assert!(
        std::fs::symlink_metadata(&pipe)
            .expect("still there")
            .file_type()
            .is_fifo()
    );
}

#[test]
fn every_output_of_a_run_is_checked_before_the_work_and_each_is_its_own() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    // Two of lift's outputs on one file: refused before the solve, nothing written.
    let k128 = common::k128();
    let kp = common::fixture("synthetic-s0").join("keypoints.npy");
    let same = d.join("same.npy");
    one_error(
        &[
            "lift",
            "--dict",
            s(&k128),
            "--keypoints",
            s(&kp),
            "--out",
            s(&same),
            "--out-proj",
            s(&same),
        ],
        "another output of this run",
    );
    assert!(!same.exists());
    // A bag's metadata.yaml that cannot be written (a directory there): refused before
    // the copy, so the old copy stays as it was.
    let bag = d.join("bag");
    std::fs::create_dir_all(bag.join("metadata.yaml")).expect("mkdir");
    let copy = bag.join("copy.mcap");
    std::fs::write(&copy, b"an older copy").expect("write");
    let stderr = one_error(
        &["recover", "recordings/kick.mcap", s(&copy), "--rosbag2"],
        "metadata.yaml",
    );
    assert!(stderr.contains("not a regular file"), "{stderr}");
    assert_eq!(stderr.matches("metadata.yaml").count(), 1, "{stderr}");
    assert_eq!(std::fs::read(&copy).expect("read"), b"an older copy");
    let out = bag.join("out.mcap");
    one_error(
        &[
            "replay",
            "recordings/kick.mcap",
            "--record",
            s(&out),
            "--rosbag2",
        ],
        "not a regular file",
    );
    assert!(!out.exists());
}

#[test]
fn a_model_that_is_not_a_file_is_named_for_what_it_is() {
    // The models' paths directories: said as such, not "not found".
    let dir = tempfile::tempdir().expect("tempdir");
    let models = dir.path().join("models");
    for name in [
        "pose_detection",
        "pedestrian_detection",
        "pose_landmark_full",
        "pose_landmark_lite",
        "pose_landmark_heavy",
    ] {
        for ext in ["tflite", "tract.tflite"] {
            std::fs::create_dir_all(models.join(format!("{name}.{ext}"))).expect("mkdir");
        }
    }
    let images = dir.path().join("images");
    std::fs::create_dir_all(&images).expect("mkdir");
    let out = Command::new(binary())
        .current_dir(common::root())
        .env("POSESTREAM_MODELS", &models)
        .args(["run", "--images", s(&images), "--ros2", "false"])
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("a directory, not a regular file") && !stderr.contains("not found"),
        "{stderr}"
    );
}
