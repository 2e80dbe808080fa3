//! Real footage, scored: runs `posestream run` on each annotated clip
//! (`benches/footage/*.json`) and prints recall, precision, IDF1, id switches,
//! frames/s and latency per clip (the README's table; docs/evaluation.md#real-footage).
//!
//! ```sh
//! python3 tests/python/sample_media.py target/footage-media --footage   # the clips
//! cargo bench --bench footage -- [--runtime auto|tract|litert] [--config FILE] [--media DIR] [CLIP.json ...]
//! ```
//! `POSESTREAM_BIN=path/to/posestream` scores another build's binary on the same clips.
//! Not in CI (the clips are 14 MB and the runs minutes); `tests/images.rs` scores a
//! collage of photos with the same scorer.

#[path = "footage/score.rs"]
mod score;

use std::path::{Path, PathBuf};
use std::process::Command;

fn main() {
    let mut args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| a != "--bench")
        .collect();
    let mut take = |name: &str| -> Option<String> {
        let i = args.iter().position(|a| a == name)?;
        let value = args.get(i + 1).cloned();
        args.drain(i..(i + 2).min(args.len()));
        value
    };
    let runtime = take("--runtime");
    let config = take("--config");
    let media = PathBuf::from(take("--media").unwrap_or_else(|| "target/footage-media".into()));
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let clips: Vec<PathBuf> = if args.is_empty() {
        let mut v: Vec<PathBuf> = std::fs::read_dir(root.join("benches/footage"))
            .expect("benches/footage")
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "json"))
            .collect();
        v.sort();
        v
    } else {
        args.iter().map(PathBuf::from).collect()
    };
    // Another build's binary (`POSESTREAM_BIN`), to compare builds on the same clips.
    let binary = std::env::var_os("POSESTREAM_BIN")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_BIN_EXE_posestream")));
    let out = root.join("target/footage");
    std::fs::create_dir_all(&out).expect("target/footage");
    println!(
        "| clip | runtime | annotated frames | people per frame | recall | precision | IDF1 | id switches (worst per person per 200 frames) | motmetrics: IDF1, MOTA, switches, fragmentations | track ids | frames/s | latency p50 / p99 ms |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    for path in clips {
        let clip = score::Clip::load(&path).unwrap_or_else(|e| panic!("{e}"));
        let video = media.join(&clip.clip);
        assert!(
            video.is_file(),
            "{}: not there (python3 tests/python/sample_media.py {} --footage)",
            video.display(),
            media.display()
        );
        // The clip up to its last annotated frame (stream copy: the same pixels).
        let last = clip.frames.iter().map(|f| f.frame).max().unwrap_or(0);
        let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("clip");
        let ext = video.extension().and_then(|e| e.to_str()).unwrap_or("mp4");
        let cut = out.join(format!("{stem}-cut.{ext}"));
        let status = Command::new("ffmpeg")
            .args(["-v", "error", "-y", "-i"])
            .arg(&video)
            .args(["-c", "copy", "-frames:v", &(last + 1).to_string()])
            .arg(&cut)
            .status()
            .expect("ffmpeg runs");
        assert!(status.success(), "cutting {}", video.display());
        let recording = out.join(format!("{stem}.mcap"));
        let mut run = Command::new(&binary);
        run.args(["run", "--video"])
            .arg(&cut)
            .args(["--ros2", "false", "--json", "--record"])
            .arg(&recording);
        if let Some(r) = &runtime {
            run.args(["--runtime", r]);
        }
        if let Some(c) = &config {
            run.args(["--config", c]);
        }
        let output = run.output().expect("posestream runs");
        assert!(
            output.status.success(),
            "posestream run: {}",
            String::from_utf8_lossy(&output.stderr)
        );
        let report: serde_json::Value = serde_json::from_slice(&output.stdout).expect("report");
        let found =
            score::found_in_recording(&recording, clip.fps).unwrap_or_else(|e| panic!("{e}"));
        let s = score::score(&clip, &found);
        // The same skeletons scored by motmetrics (benches/footage/mot.py).
        let found_path = out.join(format!("{stem}-found.json"));
        let rows: Vec<serde_json::Value> = found
            .iter()
            .map(|f| serde_json::json!({"frame": f.frame, "track": f.track, "x": f.at.0, "y": f.at.1}))
            .collect();
        std::fs::write(&found_path, serde_json::to_string(&rows).expect("json")).expect("write");
        let mot = mot_metrics(&root.join("benches/footage/mot.py"), &path, &found_path);
        let mot_cell = mot.as_ref().map_or_else(
            || "(motmetrics: no figures)".to_string(),
            |m| {
                format!(
                    "{:.2}, {:.2}, {}, {}",
                    m["idf1"].as_f64().unwrap_or(f64::NAN),
                    m["mota"].as_f64().unwrap_or(f64::NAN),
                    m["num_switches"],
                    m["num_fragmentations"]
                )
            },
        );
        let track_ids = found
            .iter()
            .map(|f| f.track)
            .collect::<std::collections::BTreeSet<_>>()
            .len();
        println!(
            "| {} | {} | {} | {:.1} | {:.2} ({}/{}) | {:.2} ({} false) | {:.2} | {} ({:.1}) | {mot_cell} | {track_ids} | {:.1} | {:.0} / {:.0} |",
            clip.clip,
            report["detector"]["images"]["runtime"]
                .as_str()
                .unwrap_or("?"),
            s.frames,
            s.people_per_frame,
            s.recall,
            s.found,
            s.counted,
            s.precision,
            s.false_skeletons,
            s.idf1,
            s.id_switches,
            s.worst_switches_per_200,
            report["frames_per_second"].as_f64().unwrap_or(0.0),
            report["latency"]["median_ms"].as_f64().unwrap_or(0.0),
            report["latency"]["p99_ms"].as_f64().unwrap_or(0.0),
        );
        eprintln!(
            "{}: recall by height 60-80 px {}/{}, 80-100 px {}/{}, 100+ px {}/{}",
            clip.clip,
            s.by_height[0].0,
            s.by_height[0].1,
            s.by_height[1].0,
            s.by_height[1].1,
            s.by_height[2].0,
            s.by_height[2].1
        );
        let detail = serde_json::json!({ "clip": clip.clip, "scores": s, "motmetrics": mot, "report": report });
        std::fs::write(
            out.join(format!("{stem}.json")),
            serde_json::to_string_pretty(&detail).expect("json"),
        )
        .expect("write");
    }
}

/// `mot.py`'s figures for `clip` and `found` (JSON), by `$POSESTREAM_PYTHON` (else
/// `python3`); `None`, said on stderr, where it cannot run (motmetrics not installed).
fn mot_metrics(script: &Path, clip: &Path, found: &Path) -> Option<serde_json::Value> {
    let python = std::env::var("POSESTREAM_PYTHON").unwrap_or_else(|_| "python3".into());
    let out = Command::new(&python)
        .arg(script)
        .arg(clip)
        .arg(found)
        .output()
        .map_err(|e| eprintln!("{python}: {e}"))
        .ok()?;
    if !out.status.success() {
        let stderr = String::from_utf8_lossy(&out.stderr);
        let hint = if stderr.contains("No module named 'motmetrics'") {
            " (pip install motmetrics)"
        } else {
            ""
        };
        eprintln!(
            "{} did not run{hint}: {}",
            script.display(),
            stderr.lines().last().unwrap_or("")
        );
        return None;
    }
    serde_json::from_slice(&out.stdout)
        .map_err(|e| eprintln!("{}: not JSON: {e}", script.display()))
        .ok()
}
