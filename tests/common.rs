//! Shared helpers of the integration tests.
#![allow(dead_code, reason = "each test binary uses some of the helpers")]

use posestream::LoadDictionary;
use std::path::PathBuf;

use nalgebra::{Rotation3, Vector3};
use posestream::Dictionary;
use posestream::npy::{self, Array};

/// `../shared` beside the repository.
pub fn shared() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared")
}

/// The authors' K128 dictionary.
pub fn k128() -> PathBuf {
    shared().join("reference/monocap-dicts/poseDict-all-K128.mat")
}

/// A parity fixture folder.
pub fn fixture(name: &str) -> PathBuf {
    shared().join("reference/parity").join(name)
}

/// Reads an f64 array.
pub fn read(path: PathBuf) -> Array<f64> {
    npy::read(&path).unwrap_or_else(|e| panic!("{e}"))
}

/// Frames of a pose built from 3 bases, seen under known rotations (noise-free).
pub fn three_basis_sequence(dict: &Dictionary, frames: usize) -> (Vec<f64>, Vec<f64>) {
    let p = dict.num_joints();
    let mut c = vec![0.0; dict.num_bases()];
    c[1] = 0.9;
    c[4] = 0.5;
    c[6] = 0.7;
    let s = dict.compose(&c);
    let (mut xy, mut truth) = (Vec::new(), Vec::new());
    for t in 0..frames {
        let r = Rotation3::from_euler_angles(0.3, 0.8 + 0.02 * t as f64, -0.2);
        for j in 0..p {
            let q = r * Vector3::new(s[j], s[p + j], s[2 * p + j]);
            xy.extend([q.x + 10.0, q.y - 4.0]);
            truth.extend([q.x, q.y, q.z]);
        }
    }
    (xy, truth)
}

/// The first `k` bases of the authors' K128 dictionary.
pub fn small_dictionary(k: usize) -> Dictionary {
    let full = Dictionary::load(k128()).expect("dictionary");
    let n = 3 * full.num_joints();
    Dictionary::new(
        full.skeleton().clone(),
        full.bases()[..k * n].to_vec(),
        full.mean().to_vec(),
    )
    .expect("sub-dictionary")
}

/// The repository root.
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The messages of `topic` in the recording at `path`, without their log times.
pub fn messages<M: posestream::msgs::RosMessage>(path: &std::path::Path, topic: &str) -> Vec<M> {
    posestream::recording::read_topic(path, topic)
        .unwrap_or_else(|e| panic!("{}: {topic}: {e}", path.display()))
        .into_iter()
        .map(|(_, m)| m)
        .collect()
}

/// A shipped recording.
pub fn recording(name: &str) -> PathBuf {
    root().join("recordings").join(name)
}

/// The shipped recordings of synthetic heat maps.
pub const RECORDINGS: [&str; 3] = ["byebye.mcap", "kick.mcap", "wave-left-hand.mcap"];

/// The Python interpreter of the independent clients: `$POSESTREAM_PYTHON` (set by
/// `.ci/run` to its virtual environment) or `python3`.
pub fn python() -> String {
    std::env::var("POSESTREAM_PYTHON").unwrap_or_else(|_| "python3".into())
}

/// LiteRT's `libLiteRt.so` in the Python environment of the clients (the
/// `ai-edge-litert` wheel `.ci/run` installs).
pub fn litert_library() -> std::path::PathBuf {
    let out = std::process::Command::new(python())
        .args([
            "-c",
            "import ai_edge_litert, os; print(os.path.join(os.path.dirname(ai_edge_litert.__file__), 'libLiteRt.so'))",
        ])
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", python()));
    assert!(
        out.status.success(),
        "ai-edge-litert is not installed (.ci/run installs it): {}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::path::PathBuf::from(String::from_utf8_lossy(&out.stdout).trim())
}

/// Runs `tests/python/<script>` with `args`; returns its stdout parsed as JSON. Panics
/// with the client's stderr when it fails (for instance when the PyPI packages are
/// missing: `.ci/run` installs them).
pub fn python_client(script: &str, args: &[&str]) -> serde_json::Value {
    let out = std::process::Command::new(python())
        .arg(root().join("tests/python").join(script))
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", python()));
    assert!(
        out.status.success(),
        "{script} failed (the Python clients need `pip install mcap mcap-ros2-support rosbags`, which .ci/run does):\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{script} output: {e}"))
}

/// Runs `program` with `args` (in the repository root) to its end, stdout and stderr
/// captured, and measures the peak resident memory of the process (kB) with
/// `tests/python/peak_memory.py`. Returns the exit code (`None`: killed by a signal), the
/// output and the peak.
pub fn peak_memory_run(
    program: &std::path::Path,
    args: &[&str],
    envs: &[(&str, &str)],
) -> (Option<i32>, std::process::Output, u64) {
    let dir = tempfile::tempdir().expect("tempdir");
    let report = dir.path().join("peak.json");
    let out = std::process::Command::new(python())
        .current_dir(root())
        .arg(root().join("tests/python/peak_memory.py"))
        .arg(&report)
        .arg(program)
        .args(args)
        .envs(envs.iter().copied())
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", python()));
    let text = std::fs::read_to_string(&report)
        .unwrap_or_else(|e| panic!("peak_memory.py wrote no report ({e}): {out:?}"));
    let v: serde_json::Value = serde_json::from_str(&text).expect("json");
    let code = v["returncode"].as_i64().expect("returncode");
    let peak = v["maxrss_kb"].as_u64().expect("maxrss_kb");
    ((code >= 0).then_some(code as i32), out, peak)
}

/// Starts a named thread (the project's rule: no unnamed threads, `clippy.toml`).
pub fn spawn<T: Send + 'static>(
    name: &str,
    f: impl FnOnce() -> T + Send + 'static,
) -> std::thread::JoinHandle<T> {
    std::thread::Builder::new()
        .name(name.to_string())
        .spawn(f)
        .expect("a thread")
}
