//! `posestream scenes --distances`: where people stand. Scenes of held-out walking takes
//! (`synth`: a static camera 1-3 m above the floor looking level to 30 degrees down, its
//! place over the floor on `/tf_static`, people walking from 2 to 15 m away), their ids
//! removed and given by posestream's tracker as in `scenes`, replayed in three modes: no
//! floor with the assumed body size, no floor with the subjects' true size, and the floor
//! from TF with the assumed size. Per distance band of the true root: the root's error
//! relative to its distance (median over frames and people), the signed depth error, the
//! MPJPE in the camera frame, the body size from the skeleton's bones and the one it
//! says (`mean_bone_length`) against the subject's after 2 s, the share of per-axis errors within 1 and 2 `position_std`.

use std::path::Path;
use std::sync::atomic::AtomicBool;

use clap::Parser;
use posestream::floor::FloorSource;
use posestream::mocap::SkeletonMapping;
use posestream::msgs::{MetricSource, Skeleton3D};
use posestream::nodes::config::{ReplayRate, ServiceConfig};
use posestream::nodes::replay::{ReplayOptions, replay};
use posestream::recording::read_topic;
use posestream::synth::motion::Motion;

use super::{FrameError, ScenesArgs, SynthCommand, frame_errors, track};
use crate::cli::CliError;

/// A scene of people at several distances: the camera's height, tilt, and where it
/// stands from the first person (`synth --distance`, `--azimuth`), and the people (take,
/// `synth --place`, `synth --motion`; empty: none).
struct Walk {
    name: &'static str,
    height: f64,
    tilt: f64,
    distance: f64,
    azimuth: f64,
    people: &'static [(&'static str, &'static str, &'static str)],
}

/// Held-out walking takes (the `proud` style) seen from several heights and tilts.
const WALKS: [Walk; 4] = [
    Walk {
        name: "camera 1.2 m high, level: one walks away from 2.5 m, one backs away facing it",
        height: 1.2,
        tilt: 0.0,
        distance: 2.5,
        azimuth: 165.0,
        people: &[
            ("dataset-1_walk_proud_001.bvh", "", ""),
            ("dataset-1_walk-back_proud_001.bvh", "0,-1.5,180", ""),
        ],
    },
    Walk {
        name: "camera 2.2 m high, 15 degrees down: two walk away, side by side",
        height: 2.2,
        tilt: 15.0,
        distance: 3.0,
        azimuth: 195.0,
        people: &[
            ("dataset-1_walk_proud_002.bvh", "", ""),
            ("dataset-1_walk_proud_001.bvh", "-1.0,1.5", ""),
        ],
    },
    Walk {
        name: "camera 3 m high, 30 degrees down: two walk across, 4 and 7 m away",
        height: 3.0,
        tilt: 30.0,
        distance: 4.0,
        azimuth: 100.0,
        people: &[
            ("dataset-1_walk-left_proud_001.bvh", "", ""),
            ("dataset-1_walk-right_proud_001.bvh", "3.0,-3.0", ""),
        ],
    },
    Walk {
        name: "camera 1.5 m high, 5 degrees down: two walk across, 9 and 12 m away",
        height: 1.5,
        tilt: 5.0,
        distance: 9.0,
        azimuth: 80.0,
        people: &[
            ("dataset-1_walk_proud_001.bvh", "", ""),
            ("dataset-1_walk_proud_002.bvh", "0,-3.0,180", ""),
        ],
    },
];

/// People who do not just walk: held-out takes made to climb, jump, crouch, kneel and
/// sit (`synth --motion`: the collection has no such takes), 4 to 10 m from cameras at
/// three heights and tilts.
const MOVES: [Walk; 3] = [
    Walk {
        name: "camera 2 m high, 10 degrees down: one walks away from 4 m and climbs a 0.4 m \
               step and off it, one jumps 0.35 m high 7 m away",
        height: 2.0,
        tilt: 10.0,
        distance: 4.0,
        azimuth: 175.0,
        people: &[
            ("dataset-1_walk_proud_001.bvh", "", "step:0.4,1.5,4"),
            (
                "dataset-1_bye_proud_001.bvh",
                "3.0,-1.5,180",
                "jump:0.35,1.5",
            ),
        ],
    },
    Walk {
        name: "camera 1.4 m high, 5 degrees down: one squats 0.45 m deep 4.5 m away, one \
               kneels 7 m away",
        height: 1.4,
        tilt: 5.0,
        distance: 4.5,
        azimuth: 10.0,
        people: &[
            ("dataset-1_bye_proud_001.bvh", "", "crouch:0.45,2.5"),
            (
                "dataset-1_bye_proud_001.bvh",
                "-2.5,1.5,-20",
                "kneel:1.2,2.3",
            ),
        ],
    },
    Walk {
        name: "camera 2.5 m high, 20 degrees down: one sits 5 m away, one walks away from \
               7 m and climbs a 0.3 m step",
        height: 2.5,
        tilt: 20.0,
        distance: 5.0,
        azimuth: 0.0,
        people: &[
            ("dataset-1_bye_proud_001.bvh", "", "sit:1.2,2.3"),
            ("dataset-1_walk_proud_002.bvh", "-2.0,1.5,180", "step:0.3,1"),
        ],
    },
];

/// The takes of the scenes.
pub fn takes() -> impl Iterator<Item = &'static str> {
    WALKS
        .iter()
        .chain(&MOVES)
        .flat_map(|walk| walk.people.iter().map(|(file, _, _)| *file))
}

/// The take of a walk: the held-out one, or with `train` the training style's.
fn take(file: &str, train: bool) -> String {
    if train {
        file.replace("_proud_", "_normal_")
    } else {
        file.to_owned()
    }
}

/// The distance bands of the tables, metres (true root from the camera).
const BANDS: [(f64, f64); 4] = [(2.0, 4.0), (4.0, 7.0), (7.0, 10.0), (10.0, 15.0)];

/// How a replay places people.
struct Mode {
    name: &'static str,
    floor: FloorSource,
    /// The metric step's mean limb length: the subjects' (`--mean-limb-length`) when
    /// true, else the configuration's (the assumed size).
    true_size: bool,
}

const MODES: [Mode; 5] = [
    Mode {
        name: "no floor, assumed size",
        floor: FloorSource::None,
        true_size: false,
    },
    Mode {
        name: "no floor, true size",
        floor: FloorSource::None,
        true_size: true,
    },
    Mode {
        name: "floor from TF, assumed size",
        floor: FloorSource::Tf,
        true_size: false,
    },
    Mode {
        name: "floor learnt, assumed size",
        floor: FloorSource::Learnt,
        true_size: false,
    },
    Mode {
        name: "floor learnt, true size",
        floor: FloorSource::Learnt,
        true_size: true,
    },
];

/// A learnt floor at the end of a scene, against the camera's.
struct Learnt {
    scene: String,
    mode: &'static str,
    /// The camera's true height and pitch.
    truth: (f64, f64),
    report: Option<posestream::nodes::FloorReport>,
    /// Of the refined skeletons, those placed by the floor.
    on_floor: usize,
    refined: usize,
    /// Their root's error over its distance, median.
    placed_root: Option<f64>,
}

/// `scale_std` when the subjects' size is given: the spread of the depth error left with
/// the true size, measured on the training walks (68 % of the per-axis errors within
/// 0.348 of the standard deviation composed with 0.1).
const KNOWN_SIZE_SCALE_STD: f64 = 0.035;

/// Seconds the walks are looped to (`synth --loop-to`) to learn the floor: the training
/// and held-out takes last 4-11 s, and learning takes 300 person-frames before its first
/// fit.
const LEARN_SECONDS: f64 = 30.0;

/// Frames after a person's first before their size is scored (2 s at 30 frames/s).
const SIZE_AFTER_FRAMES: u64 = 60;

/// The distance scenes evaluated: a markdown section (`## Where people stand`).
pub fn markdown(args: &ScenesArgs) -> Result<String, CliError> {
    let base = args.config.load()?;
    // The bones of the skeletons scored: the mapping's layout (the truth's and the
    // dictionary's joints).
    let mapping = SkeletonMapping::load(&args.mapping)?;
    let bones = mapping.layout.bones().collect::<Vec<_>>();
    let mut errors: Vec<Vec<FrameError>> = vec![Vec::new(); MODES.len()];
    // The people who do not just walk: their motion's name, their frame's errors.
    let mut moved: Vec<Vec<(&'static str, FrameError)>> = vec![Vec::new(); MODES.len()];
    let mut learnt = Vec::new();
    // The training takes are too short for the moves. Each walk looped to
    // `LEARN_SECONDS` learns the floor too.
    let moves: &[Walk] = if args.train { &[] } else { &MOVES };
    let mut runs: Vec<(&Walk, Option<f64>)> =
        WALKS.iter().chain(moves).map(|w| (w, None)).collect();
    runs.extend(WALKS.iter().map(|w| (w, Some(LEARN_SECONDS))));
    for (i, (walk, looped)) in runs.into_iter().enumerate() {
        let dir = args.work.join(format!("walk-{i}"));
        let recording = dir.join("walk.mcap");
        synth(args, walk, looped, &dir, &recording)?;
        let tracked = dir.join("tracked.mcap");
        let tracking = track(
            &recording,
            &tracked,
            &base.topics,
            &base.detector.images.tracking,
        )?;
        let (_, to_truth) = tracking.idf1();
        // One person of one scene: ids of their own across scenes.
        let scene_id = |id: u32| id + 100 * i as u32;
        let truth: Vec<(u64, Skeleton3D)> =
            read_topic::<Skeleton3D>(&recording, "/posestream/ground_truth")?
                .into_iter()
                .map(|(t, mut g)| {
                    g.track_id = scene_id(g.track_id);
                    (t, g)
                })
                .collect();
        for (m, mode) in MODES.iter().enumerate() {
            // The looped scenes only learn the floor.
            if looped.is_some() && mode.floor != FloorSource::Learnt {
                continue;
            }
            let config = mode_config(&base, mode, args.mean_limb_length)?;
            let out = dir.join(format!("skeletons-{m}.mcap"));
            let options = ReplayOptions {
                record: Some(out.clone()),
                rosbag2: false,
                rate: ReplayRate::Fast,
                paced_for_live: false,
            };
            let report = replay(&config, &tracked, &options, &AtomicBool::new(false))?;
            let skeletons: Vec<Skeleton3D> =
                read_topic::<Skeleton3D>(&out, &config.topics.skeletons)?
                    .into_iter()
                    .filter_map(|(_, mut s)| {
                        s.track_id = scene_id(*to_truth.get(&s.track_id)?);
                        Some(s)
                    })
                    .collect();
            let lag = u32::try_from(config.estimator.window.lag).unwrap_or(u32::MAX);
            let (frames, _) = frame_errors(&skeletons, &truth, lag, &bones);
            for e in frames.into_iter().filter(|_| looped.is_none()) {
                // The truth's ids are people 1, 2, ... of the scene.
                let person = (e.person % 100) as usize;
                match walk.people.get(person.wrapping_sub(1)) {
                    Some((_, _, motion)) if !motion.is_empty() => {
                        let name = Motion::parse(motion).map_or("?", |m| m.name());
                        moved[m].push((name, e));
                    }
                    _ => errors[m].push(e),
                }
            }
            if mode.floor == FloorSource::Learnt {
                let refined = skeletons.iter().filter(|s| s.lag == lag);
                let placed: Vec<Skeleton3D> = refined
                    .clone()
                    .filter(|s| s.metric_source == MetricSource::Floor as u8)
                    .cloned()
                    .collect();
                let (placed, _) = frame_errors(&placed, &truth, lag, &bones);
                learnt.push(Learnt {
                    scene: match looped {
                        Some(seconds) => format!("{} (looped to {seconds:.0} s)", walk.name),
                        None => walk.name.to_owned(),
                    },
                    mode: mode.name,
                    truth: (walk.height, walk.tilt),
                    report: report.learnt_floor,
                    on_floor: refined
                        .clone()
                        .filter(|s| s.metric_source == MetricSource::Floor as u8)
                        .count(),
                    refined: refined.count(),
                    placed_root: (!placed.is_empty())
                        .then(|| median(placed.iter().map(|e| e.root / e.distance).collect())),
                });
            }
        }
    }
    let mut text = table(args, &base, &errors);
    if !args.train {
        text.push_str(&moves_table(&moved));
    }
    text.push_str(&learnt_table(&learnt));
    Ok(text)
}

/// The people who do not just walk (`MOVES`), 4 to 10 m away: per motion and mode.
fn moves_table(moved: &[Vec<(&'static str, FrameError)>]) -> String {
    let mut text = String::from(
        "People who do not just walk (held-out takes made to move, `synth --motion`): one \
         walks onto a 0.4 m step and off it, one onto a 0.3 m step (step), one jumps \
         0.35 m high every 1.5 s (jump), one squats 0.45 m deep every 2.5 s (crouch), one \
         kneels, one sits on a chair, each for 2.3 s; frames 4 to 10 m from the camera. \
         Columns as above.\n\n\
         | person | mode | frames | root | depth (signed) | MPJPE | root-aligned | within 1 / 2 std |\n\
         |---|---|---:|---:|---:|---:|---:|---:|\n",
    );
    for name in ["step", "jump", "crouch", "kneel", "sit"] {
        for (mode, frames) in MODES.iter().zip(moved) {
            let of: Vec<&FrameError> = frames
                .iter()
                .filter(|(n, e)| *n == name && e.distance >= 4.0 && e.distance < 10.0)
                .map(|(_, e)| e)
                .collect();
            if of.is_empty() {
                continue;
            }
            let n = of.len() as f64;
            let mean = |f: &dyn Fn(&FrameError) -> f64| of.iter().map(|e| f(e)).sum::<f64>() / n;
            let axes = of.iter().map(|e| e.axes).sum::<usize>().max(1) as f64;
            let within = |k: usize| of.iter().map(|e| e.within[k]).sum::<usize>() as f64;
            text.push_str(&format!(
                "| {name} | {} | {} | {:.1} % | {:+.1} % | {:.0} mm | {:.0} mm | {:.0} % / {:.0} % |\n",
                mode.name,
                of.len(),
                100.0 * median(of.iter().map(|e| e.root / e.distance).collect()),
                100.0 * mean(&|e| e.depth),
                1000.0 * mean(&|e| e.mpjpe),
                1000.0 * mean(&|e| e.root_aligned),
                100.0 * within(0) / axes,
                100.0 * within(1) / axes,
            ));
        }
    }
    text.push('\n');
    text
}

/// The floors learnt: per scene and mode, where learning stood at its end.
fn learnt_table(learnt: &[Learnt]) -> String {
    let mut text = String::from(
        "The floors learnt (`source = \"learnt\"`, each scene from nothing): where learning \
         stood at the scene's end, the camera's height and pitch against the truth (off: \
         the error in the reported standard deviations; the height's composes the fit's \
         with the size prior's, `scale_std` of it), the refined skeletons placed by the \
         floor (the others by the assumed size, while the floor was not yet trusted) and \
         their root's error over the distance (median).\n\n\
         | scene | mode | state | height (true) | off | pitch (true) | off | roll | inliers | on the floor | their root |\n\
         |---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    let pm = |v: Option<f64>, s: Option<f64>, unit: &str| match (v, s) {
        (Some(v), Some(s)) => format!("{v:.2} +- {s:.2}{unit}"),
        _ => "-".into(),
    };
    // The error in standard deviations.
    let off = |v: Option<f64>, s: Option<f64>, truth: f64| match (v, s) {
        (Some(v), Some(s)) if s > 0.0 && s.is_finite() => Some((v - truth) / s),
        _ => None,
    };
    let show = |z: Option<f64>| z.map_or("-".into(), |z| format!("{z:+.1}"));
    // Of the trusted floors, and of all fits: height and pitch within 2 std.
    let (mut fits, mut height_in, mut pitch_in) = (0, 0, 0);
    let (mut trusted, mut trusted_height, mut trusted_pitch) = (0, 0, 0);
    for l in learnt {
        let r = l.report.as_ref();
        let height = off(
            r.and_then(|r| r.height),
            r.and_then(|r| r.height_std),
            l.truth.0,
        );
        let pitch = off(
            r.and_then(|r| r.pitch),
            r.and_then(|r| r.pitch_std),
            l.truth.1,
        );
        if let (Some(h), Some(p)) = (height, pitch) {
            fits += 1;
            height_in += usize::from(h.abs() <= 2.0);
            pitch_in += usize::from(p.abs() <= 2.0);
            if r.is_some_and(|r| r.state == "accepted") {
                trusted += 1;
                trusted_height += usize::from(h.abs() <= 2.0);
                trusted_pitch += usize::from(p.abs() <= 2.0);
            }
        }
        text.push_str(&format!(
            "| {} | {} | {} | {} ({:.2} m) | {} | {} ({:.0}°) | {} | {} | {} | {} of {} | {} |\n",
            l.scene,
            l.mode,
            r.map_or("no camera", |r| r.state.as_str()),
            pm(r.and_then(|r| r.height), r.and_then(|r| r.height_std), " m"),
            l.truth.0,
            show(height),
            pm(r.and_then(|r| r.pitch), r.and_then(|r| r.pitch_std), "°"),
            l.truth.1,
            show(pitch),
            pm(r.and_then(|r| r.roll), r.and_then(|r| r.roll_std), "°"),
            r.and_then(|r| r.inliers)
                .map_or("-".into(), |i| format!("{:.0} %", 100.0 * i)),
            l.on_floor,
            l.refined,
            l.placed_root
                .map_or("-".into(), |e| format!("{:.1} %", 100.0 * e)),
        ));
    }
    text.push_str(&format!(
        "\nOf the {trusted} floors trusted, the height within 2 standard deviations of the \
         truth in {trusted_height}, the pitch in {trusted_pitch}; of all {fits} fits (those \
         rejected or still learning too), in {height_in} and {pitch_in}.\n\n"
    ));
    text
}

/// `synth` of one walk into `recording`.
fn synth(
    args: &ScenesArgs,
    walk: &Walk,
    looped: Option<f64>,
    dir: &Path,
    recording: &Path,
) -> Result<(), CliError> {
    let mut argv: Vec<String> = vec!["synth".into(), "--mapping".into()];
    argv.push(args.mapping.display().to_string());
    let moves = walk.people.iter().any(|(_, _, motion)| !motion.is_empty());
    for (file, place, motion) in walk.people {
        argv.push("--bvh".into());
        argv.push(args.data.join(take(file, args.train)).display().to_string());
        if !place.is_empty() {
            argv.push(format!("--place={place}"));
        }
        if moves {
            let motion = if motion.is_empty() {
                "captured"
            } else {
                motion
            };
            argv.push(format!("--motion={motion}"));
        }
    }
    argv.extend([
        "--static-camera".into(),
        format!("--camera-height={}", walk.height),
        format!("--tilt={}", walk.tilt),
        format!("--distance={}", walk.distance),
        format!("--azimuth={}", walk.azimuth),
        "--out".into(),
        dir.join("seq").display().to_string(),
        "--mcap".into(),
        recording.display().to_string(),
    ]);
    if let Some(seconds) = looped {
        argv.push(format!("--loop-to={seconds}"));
    }
    let synth = SynthCommand::try_parse_from(&argv)
        .map_err(|e| CliError::Usage(format!("{}: {e}", walk.name)))?;
    crate::cli::synth::run(&synth.args)?;
    // Only the recording is used: the NPY files go (hundreds of MB a scene).
    let seq = dir.join("seq");
    std::fs::remove_dir_all(&seq).map_err(|source| CliError::File { path: seq, source })
}

/// The configuration of one mode.
fn mode_config(
    base: &ServiceConfig,
    mode: &Mode,
    true_limb: f64,
) -> Result<ServiceConfig, CliError> {
    let mut config = base.clone();
    config.outputs.ros2 = false;
    if mode.true_size {
        config.estimator.metric.mean_limb_length = true_limb;
        // The size known: what is left is the depth's own error.
        config.estimator.metric.scale_std = KNOWN_SIZE_SCALE_STD;
    }
    config.estimator.metric.floor.source = mode.floor;
    config.estimator.metric.floor.frame = crate::cli::synth::FLOOR_FRAME.into();
    config
        .validate()
        .map_err(|e| CliError::Usage(format!("{}: {e}", mode.name)))?;
    Ok(config)
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// The tables: one row per mode and band.
fn table(args: &ScenesArgs, base: &ServiceConfig, errors: &[Vec<FrameError>]) -> String {
    let mut text = format!(
        "## Where people stand (`posestream scenes --distances{}`)\n\n\
         {} walking takes (`{}`), two people a scene, seen by a static camera \
         1.2-3 m above the floor, level to 30 degrees down (focal 1000 px), walking \
         between 2 and 15 m from it; ids from posestream's tracker; the refined (lag {}) \
         skeletons against the truth, camera frame. Assumed size: mean bone length {} m \
         (the configuration's); the subjects' is {} m. Root: the root's error over its \
         distance, median over frames and people; depth: the signed error of its depth, \
         mean (+: too far); bones: the skeleton's mean bone length against the subject's \
         after {SIZE_AFTER_FRAMES} frames (2 s), mean of the signed relative error; size: the \
         person's size the skeleton says (`mean_bone_length`) against the subject's mean \
         bone length after {SIZE_AFTER_FRAMES} frames, median of the relative error and mean \
         of the signed one.\n\n\
         | mode | distance | frames | root | depth (signed) | MPJPE | root-aligned | bones (signed) | size | size (signed) | within 1 / 2 std |\n\
         |---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
        if args.train { " --train" } else { "" },
        if args.train { "Training" } else { "Held-out" },
        if args.train { "normal" } else { "proud" },
        base.estimator.window.lag,
        base.estimator.metric.mean_limb_length,
        args.mean_limb_length,
    );
    for (mode, frames) in MODES.iter().zip(errors) {
        let first: std::collections::BTreeMap<u32, u64> =
            frames
                .iter()
                .fold(std::collections::BTreeMap::new(), |mut m, e| {
                    let s = m.entry(e.person).or_insert(e.sequence);
                    *s = (*s).min(e.sequence);
                    m
                });
        let bands = BANDS
            .iter()
            .map(|&(lo, hi)| (format!("{lo:.0}-{hi:.0} m"), lo, hi))
            .chain(std::iter::once(("all".to_string(), 0.0, f64::INFINITY)));
        for (band, lo, hi) in bands {
            let in_band: Vec<&FrameError> = frames
                .iter()
                .filter(|e| e.distance >= lo && e.distance < hi)
                .collect();
            if in_band.is_empty() {
                continue;
            }
            let n = in_band.len() as f64;
            let root = median(in_band.iter().map(|e| e.root / e.distance).collect());
            let depth = in_band.iter().map(|e| e.depth).sum::<f64>() / n;
            let mpjpe = in_band.iter().map(|e| e.mpjpe).sum::<f64>() / n;
            let after: Vec<&&FrameError> = in_band
                .iter()
                .filter(|e| e.sequence >= first[&e.person] + SIZE_AFTER_FRAMES)
                .collect();
            let bones = after
                .iter()
                .map(|e| e.limb / e.true_limb - 1.0)
                .sum::<f64>()
                / after.len().max(1) as f64;
            let sizes: Vec<f64> = after.iter().map(|e| e.size / e.true_limb - 1.0).collect();
            let signed_size = sizes.iter().sum::<f64>() / sizes.len().max(1) as f64;
            let size = median(sizes.iter().map(|s| s.abs()).collect());
            let aligned = in_band.iter().map(|e| e.root_aligned).sum::<f64>() / n;
            let axes = in_band.iter().map(|e| e.axes).sum::<usize>().max(1) as f64;
            let within = |k: usize| in_band.iter().map(|e| e.within[k]).sum::<usize>() as f64;
            let size = if sizes.is_empty() {
                "- | - | -".to_string()
            } else {
                format!(
                    "{:+.1} % | {:.1} % | {:+.1} %",
                    100.0 * bones,
                    100.0 * size,
                    100.0 * signed_size
                )
            };
            text.push_str(&format!(
                "| {} | {band} | {} | {:.1} % | {:+.1} % | {:.0} mm | {:.0} mm | {size} | {:.0} % / {:.0} % |\n",
                mode.name,
                in_band.len(),
                100.0 * root,
                100.0 * depth,
                1000.0 * mpjpe,
                1000.0 * aligned,
                100.0 * within(0) / axes,
                100.0 * within(1) / axes,
            ));
        }
    }
    text.push('\n');
    text
}
