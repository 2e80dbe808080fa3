//! `posestream scenes`: people in one room, evaluated end to end. Each scene is made by
//! `synth` (held-out motion capture takes placed in a room, a static pinhole camera, the
//! heat maps' error model, people hiding each other, ground truth in metres in the
//! camera frame); the heat maps lose their ids and each image's people come in a
//! rotating order; posestream's tracker (the image detector's, default settings)
//! associates the exact crop boxes each frame; the estimator replays them in metres.
//! Per person: MPJPE in the camera frame (no alignment), root-aligned MPJPE, P-MPJPE,
//! root position and depth error, the share of per-axis errors within 1 and 2
//! `position_std`; per scene: id switches, IDF1, the estimator's frames per second.

pub mod distances;
pub mod rooms;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use clap::{Args, Parser};
use pathfinding::kuhn_munkres::kuhn_munkres;
use pathfinding::matrix::Matrix;
use posestream::CropBox;
use posestream::accuracy::p_mpjpe;
use posestream::detector::tracker::{Observation, Tracker, TrackingSettings, iou};
use posestream::msgs::sensor::CameraInfo;
use posestream::msgs::tf::TFMessage;
use posestream::msgs::{HeatMaps, Skeleton3D, SkeletonState, Units};
use posestream::nodes::config::{ReplayRate, Topics};
use posestream::nodes::replay::{ReplayOptions, replay};
use posestream::recording::{Recorder, read_topic};

use super::CliError;
use super::synth::SynthArgs;

/// Options of `scenes`.
#[derive(Debug, Args)]
pub struct ScenesArgs {
    /// The service configuration (`--config FILE`).
    #[command(flatten)]
    pub config: super::config::ConfigArgs,
    /// Skeleton mapping of the BVH files.
    #[arg(long, default_value = "builtin:skeletons/bandai-namco.toml")]
    pub mapping: PathBuf,
    /// Folder of the held-out takes (Bandai-Namco dataset 1).
    #[arg(long, default_value = "../shared/data/mocap/bandai-namco-1")]
    pub data: PathBuf,
    /// The metric step's mean limb length, metres (the takes' subjects': 0.2235).
    #[arg(long, default_value_t = 0.2235)]
    pub mean_limb_length: f64,
    /// Scratch folder for the scenes' recordings.
    #[arg(long, default_value = "target/scenes")]
    pub work: PathBuf,
    /// Write the markdown here as well as to stdout.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Where people stand instead: walking takes at 2-15 m from cameras 1.2-3 m high,
    /// placed with and without the floor, per distance band.
    #[arg(long)]
    pub distances: bool,
    /// With `--distances`: the training takes' walks (style `normal`) instead of the
    /// held-out ones (`proud`): what the metric step's constants were measured on.
    #[arg(long, requires = "distances")]
    pub train: bool,
    /// Rooms seen by several cameras instead: each person's views fused against each
    /// camera alone (`docs/results.md`).
    #[arg(long, conflicts_with_all = ["distances", "train"])]
    pub rooms: bool,
    /// With `--rooms`: instead of the tables, write room `--room` as its cameras would
    /// send it to this recording (MCAP: each camera's heat maps and calibration, the
    /// cameras' poses on /tf_static, the truth), and beside it FILE.toml, the
    /// configuration `posestream fuse` reads it with.
    // `conflicts_with` too: clap does not enforce `requires` beside `--distances`,
    // which conflicts with `--rooms` (the distances ran, `--room` ignored).
    #[arg(
        long,
        value_name = "FILE",
        requires = "rooms",
        conflicts_with = "distances"
    )]
    pub record: Option<PathBuf>,
    /// With `--rooms`: only this room (1-based, as `--rooms` lists them); with
    /// `--record`, the room written (default 3).
    #[arg(long, requires = "rooms", conflicts_with = "distances")]
    pub room: Option<usize>,
}

/// A scene: its name and people, the first placed by the camera (5 m in front of it),
/// the others by `synth --place` (`ahead,left,turn,ahead_speed,left_speed`).
struct Scene {
    name: &'static str,
    people: &'static [(&'static str, &'static str)],
}

const SCENES: [Scene; 3] = [
    Scene {
        name: "two people, one passing behind the other",
        people: &[
            ("dataset-1_kick_normal_001.bvh", ""),
            ("dataset-1_byebye_normal_001.bvh", "-1.0,2.0,0,0,-0.4"),
        ],
    },
    Scene {
        name: "two people, one passing in front of the other",
        people: &[
            ("dataset-1_punch_normal_001.bvh", ""),
            ("dataset-1_byebye_normal_001.bvh", "1.5,2.0,0,0,-0.4"),
        ],
    },
    Scene {
        name: "three people, two crossing in front of the third",
        people: &[
            ("dataset-1_kick_normal_001.bvh", ""),
            ("dataset-1_byebye_normal_001.bvh", "1.0,2.0,0,0,-0.4"),
            ("dataset-1_punch_normal_001.bvh", "1.5,-2.0,0,0,0.4"),
        ],
    },
];

#[derive(Parser)]
pub(super) struct SynthCommand {
    #[command(flatten)]
    pub(super) args: SynthArgs,
}

/// One person's errors over their refined (lag 10) skeletons.
#[derive(Debug, Default)]
struct PersonErrors {
    frames: usize,
    mpjpe: f64,
    root_aligned: f64,
    p_mpjpe: f64,
    root: f64,
    depth: f64,
    within: [usize; 2],
    axes: usize,
}

impl PersonErrors {
    fn add(&mut self, e: &FrameError) {
        self.frames += 1;
        self.mpjpe += e.mpjpe;
        self.root_aligned += e.root_aligned;
        self.p_mpjpe += e.p_mpjpe;
        self.root += e.root;
        self.depth += e.depth.abs();
        self.within[0] += e.within[0];
        self.within[1] += e.within[1];
        self.axes += e.axes;
    }
}

/// One skeleton's errors against the truth, metres (camera frame).
#[derive(Debug, Clone, Default)]
pub(super) struct FrameError {
    /// The true person (track id of the truth).
    pub person: u32,
    /// The frame.
    pub sequence: u64,
    /// The true root's distance from the camera.
    pub distance: f64,
    pub mpjpe: f64,
    pub root_aligned: f64,
    pub p_mpjpe: f64,
    /// The root's position error.
    pub root: f64,
    /// The root's depth error, signed, relative to its true depth (+: too far).
    pub depth: f64,
    /// Per-axis errors within 1 and 2 `position_std`, of `axes`.
    pub within: [usize; 2],
    pub axes: usize,
    /// The skeleton's mean bone length over its bones, and the truth's.
    pub limb: f64,
    pub true_limb: f64,
    /// The person's size the skeleton says (`Skeleton3D::mean_bone_length`; 0: none).
    pub size: f64,
}

/// What the tracker did in a scene.
#[derive(Debug)]
pub(super) struct Tracking {
    /// Per true person, the tracker id of each frame it was reported in.
    given: BTreeMap<u32, Vec<u32>>,
    /// True boxes (all frames, all people).
    truth_boxes: usize,
    /// Boxes the tracker reported.
    reported: usize,
    /// The most two people's boxes overlapped (IoU).
    closest: f64,
    /// Of the boxes reported, those of people who waited for a look (their maps
    /// carried over).
    carried: usize,
}

impl Tracking {
    fn id_switches(&self) -> usize {
        self.given
            .values()
            .map(|ids| ids.windows(2).filter(|w| w[0] != w[1]).count())
            .sum()
    }

    /// IDF1 and the best one-to-one map from tracker ids to true ones.
    pub(super) fn idf1(&self) -> (f64, BTreeMap<u32, u32>) {
        let truths: Vec<u32> = self.given.keys().copied().collect();
        let mut tracks: Vec<u32> = self.given.values().flatten().copied().collect();
        tracks.sort_unstable();
        tracks.dedup();
        if truths.is_empty() || tracks.is_empty() {
            return (0.0, BTreeMap::new());
        }
        let n = truths.len().max(tracks.len());
        let count = |t: usize, k: usize| -> i64 {
            match (truths.get(t), tracks.get(k)) {
                (Some(a), Some(b)) => self.given[a].iter().filter(|&&x| x == *b).count() as i64,
                _ => 0,
            }
        };
        let weights = Matrix::from_fn(n, n, |(t, k)| count(t, k));
        let (matched, columns) = kuhn_munkres(&weights);
        let map = columns
            .iter()
            .enumerate()
            .filter(|&(t, &k)| t < truths.len() && k < tracks.len() && count(t, k) > 0)
            .map(|(t, &k)| (tracks[k], truths[t]))
            .collect();
        let idtp = matched as f64;
        (2.0 * idtp / (self.truth_boxes + self.reported) as f64, map)
    }
}

/// Strips the ids of `input`'s heat maps, shuffles each image's people, gives them the
/// tracker's ids (`settings`, as the image detector's: with `looks_per_frame` set, the
/// people its schedule has no look for wait, their newest maps carried over as the
/// detector carries them) and writes them (with the camera, and its place over the
/// floor) to `output`.
pub(super) fn track(
    input: &Path,
    output: &Path,
    topics: &Topics,
    settings: &TrackingSettings,
) -> Result<Tracking, CliError> {
    let maps = read_topic::<HeatMaps>(input, "/posestream/heatmaps")?;
    let infos = read_topic::<CameraInfo>(input, "/camera/camera_info")?;
    let transforms = read_topic::<TFMessage>(input, &topics.tf_static)?;
    let mut images: BTreeMap<u64, Vec<HeatMaps>> = BTreeMap::new();
    for (t, m) in maps {
        images.entry(t).or_default().push(m);
    }
    let mut tracker = Tracker::new(settings.clone(), 0.5);
    let mut rec = Recorder::create(output)?;
    // The camera over the floor, when the scene has one.
    for (t, tf) in &transforms {
        rec.write(&topics.tf_static, *t, tf)?;
    }
    let mut tracking = Tracking {
        given: BTreeMap::new(),
        truth_boxes: 0,
        reported: 0,
        closest: 0.0,
        carried: 0,
    };
    // Each track's newest maps written, the box its person filled then, and who they
    // were.
    let mut newest: BTreeMap<u32, (HeatMaps, CropBox, u32)> = BTreeMap::new();
    let mut height = 0.0;
    for (n, (t, people)) in images.iter_mut().enumerate() {
        let turn = n % people.len().max(1);
        people.rotate_left(turn);
        tracking.truth_boxes += people.len();
        let truth: Vec<u32> = people.iter().map(|m| m.track_id).collect();
        let observations: Vec<Observation> = people
            .iter()
            .map(|m| m.crop().map(|region| Observation { region, score: 1.0 }))
            .collect::<Result<_, _>>()
            .map_err(|e| CliError::Usage(format!("{}: a crop box: {e}", input.display())))?;
        for (a, o) in observations.iter().enumerate() {
            for b in &observations[a + 1..] {
                tracking.closest = tracking.closest.max(iou(&o.region, &b.region));
            }
        }
        for (_, info) in infos.iter().filter(|(u, _)| u == t) {
            rec.write(&topics.camera_info, *t, info)?;
            height = f64::from(info.height);
        }
        // As the image detector's frame: the schedule, then the boxes.
        let ids = tracker.scheduled_frame_of_boxes(&observations, height);
        for (k, id) in ids.into_iter().enumerate() {
            let Some(id) = id else {
                continue;
            };
            tracking.given.entry(truth[k]).or_default().push(id);
            tracking.reported += 1;
            let mut m = people[k].clone();
            m.track_id = id;
            rec.write(&topics.heatmaps, *t, &m)?;
            newest.insert(id, (m, observations[k].region, truth[k]));
        }
        // Those who waited: their newest maps, moved as they are expected to have moved.
        for (id, now, waited) in tracker.carried() {
            let Some((m, person, who)) = newest.get_mut(&id) else {
                continue;
            };
            tracking.given.entry(*who).or_default().push(id);
            tracking.reported += 1;
            tracking.carried += 1;
            let crop = m
                .crop()
                .map_err(|e| CliError::Usage(format!("a crop box: {e}")))?;
            let moved = crop.moved_as(person, &now);
            (m.crop_x, m.crop_y) = (moved.x0, moved.y0);
            *person = now;
            m.frames_since_look = waited;
            m.sequence = people[0].sequence;
            m.header = people[0].header.clone();
            rec.write(&topics.heatmaps, *t, m)?;
        }
        newest.retain(|id, _| tracker.is_live(*id));
    }
    rec.finish()?;
    Ok(tracking)
}

/// The errors of `skeletons` (ids already the true ones) at `lag` against `truth`, one
/// per skeleton scored (in frame order per person); and how many of them were not in
/// metres (not scored). `bones` are the layout's.
pub(super) fn frame_errors(
    skeletons: &[Skeleton3D],
    truth: &[(u64, Skeleton3D)],
    lag: u32,
    bones: &[(usize, usize)],
) -> (Vec<FrameError>, usize) {
    let truth: BTreeMap<(u32, u64), &Skeleton3D> = truth
        .iter()
        .map(|(_, g)| ((g.track_id, g.sequence), g))
        .collect();
    let mut out = Vec::new();
    let mut not_metric = 0;
    let mut scored = std::collections::BTreeSet::new();
    let at = |v: &[f64], j: usize| [v[3 * j], v[3 * j + 1], v[3 * j + 2]];
    let dist = |a: [f64; 3], b: [f64; 3]| {
        ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
    };
    let limb = |v: &[f64]| {
        let total: f64 = bones.iter().map(|&(a, b)| dist(at(v, a), at(v, b))).sum();
        total / bones.len().max(1) as f64
    };
    for s in skeletons
        .iter()
        .filter(|s| s.lag == lag && s.state != SkeletonState::Lost as u8)
    {
        // At lag 0 with both outputs, the newest and the lagged estimate are one.
        if !scored.insert((s.track_id, s.sequence)) {
            continue;
        }
        if s.units != Units::Metres as u8 {
            not_metric += 1;
            continue;
        }
        let Some(g) = truth.get(&(s.track_id, s.sequence)) else {
            continue;
        };
        let (p, q) = (&s.positions, &g.positions);
        let joints = p.len() / 3;
        if joints == 0 || q.len() != p.len() {
            continue;
        }
        let mut e = FrameError {
            person: s.track_id,
            sequence: s.sequence,
            ..FrameError::default()
        };
        let (p0, q0) = (at(p, 0), at(q, 0));
        for j in 0..joints {
            let (a, b) = (at(p, j), at(q, j));
            e.mpjpe += dist(a, b) / joints as f64;
            let ra = [a[0] - p0[0], a[1] - p0[1], a[2] - p0[2]];
            let rb = [b[0] - q0[0], b[1] - q0[1], b[2] - q0[2]];
            e.root_aligned += dist(ra, rb) / joints as f64;
            for axis in 0..3 {
                let std = s
                    .position_std
                    .get(3 * j + axis)
                    .copied()
                    .unwrap_or(f64::NAN);
                let z = (a[axis] - b[axis]).abs() / std;
                e.within[0] += usize::from(z <= 1.0);
                e.within[1] += usize::from(z <= 2.0);
                e.axes += 1;
            }
        }
        e.p_mpjpe = p_mpjpe(p, q, joints);
        e.root = dist(p0, q0);
        e.depth = (p0[2] - q0[2]) / q0[2];
        e.distance = dist(q0, [0.0; 3]);
        e.limb = limb(p);
        e.true_limb = limb(q);
        e.size = s.mean_bone_length;
        out.push(e);
    }
    (out, not_metric)
}

/// Per person, the sums of [`frame_errors`].
fn errors(
    skeletons: &[Skeleton3D],
    truth: &[(u64, Skeleton3D)],
    lag: u32,
) -> (BTreeMap<u32, PersonErrors>, usize) {
    let (frames, not_metric) = frame_errors(skeletons, truth, lag, &[]);
    let mut out: BTreeMap<u32, PersonErrors> = BTreeMap::new();
    for e in &frames {
        out.entry(e.person).or_default().add(e);
    }
    (out, not_metric)
}

/// Runs `scenes`.
pub fn run(args: &ScenesArgs) -> Result<(), CliError> {
    // Where the markdown goes, before minutes of work: its folder must be there.
    if let Some(out) = &args.out {
        let folder = out.parent().filter(|p| !p.as_os_str().is_empty());
        if folder.is_some_and(|f| !f.is_dir()) {
            return Err(CliError::Usage(format!(
                "--out {}: its folder does not exist",
                out.display()
            )));
        }
    }
    if let Some(room) = args.room {
        rooms::check_room(room)?;
    }
    super::data_at(
        &args.data,
        "the held-out takes the scenes are made of",
        "--data",
    )?;
    let text = if let Some(path) = &args.record {
        rooms::record(args, args.room.unwrap_or(3), path)?
    } else if args.rooms {
        rooms::markdown(args)?
    } else if args.distances {
        distances::markdown(args)?
    } else {
        markdown(args)?
    };
    print!("{text}");
    if let Some(out) = &args.out {
        posestream::files::write_output(out, &[], text.as_bytes())?;
    }
    Ok(())
}

#[derive(Parser)]
struct ScenesCommand {
    #[command(flatten)]
    args: ScenesArgs,
}

impl ScenesArgs {
    /// The defaults, with the takes in `data` and the skeleton mapping `mapping`
    /// (`eval` runs the scenes with them); an error when a scene's take is not there or
    /// does not read, the configuration does not load or the scratch folder cannot be
    /// made (checked before `eval`'s long tables).
    pub fn with(mapping: &Path, data: &Path) -> Result<Self, CliError> {
        let argv = [
            "scenes".into(),
            "--mapping".into(),
            mapping.as_os_str().to_owned(),
            "--data".into(),
            data.as_os_str().to_owned(),
        ];
        let args = ScenesCommand::try_parse_from(argv)
            .map_err(|e| CliError::Usage(e.to_string()))?
            .args;
        // The people-in-the-room scenes' takes, the walks of `--distances` and the
        // rooms'.
        let takes = SCENES
            .iter()
            .flat_map(|scene| scene.people.iter().map(|(file, _)| *file))
            .chain(distances::takes())
            .chain(rooms::takes());
        for file in takes {
            let take = args.data.join(file);
            if !take.is_file() {
                return Err(CliError::Usage(format!(
                    "the scenes need {} (--scenes-data; --no-scenes leaves them out)",
                    take.display()
                )));
            }
            posestream::mocap::Bvh::load(&take)?;
        }
        args.config.load()?;
        std::fs::create_dir_all(&args.work).map_err(|source| CliError::File {
            path: args.work.clone(),
            source,
        })?;
        Ok(args)
    }
}

/// The scenes evaluated: a markdown section (`## People in the room`).
pub fn markdown(args: &ScenesArgs) -> Result<String, CliError> {
    let mut config = args.config.load()?;
    config.estimator.metric.mean_limb_length = args.mean_limb_length;
    config.outputs.ros2 = false;
    config
        .validate()
        .map_err(|e| CliError::Usage(format!("--mean-limb-length: {e}")))?;
    std::fs::create_dir_all(&args.work).map_err(|source| CliError::File {
        path: args.work.clone(),
        source,
    })?;
    let mut text = format!(
        "## People in the room (`posestream scenes`)\n\n\
         Synthetic scenes of held-out takes (`synth`: a static pinhole camera, focal 1000 px, \
         the first person 5 m in front of it; the heat maps' error model), the heat maps' \
         ids removed and each image's people in a rotating order, ids from posestream's \
         tracker (default settings) associating the exact crop boxes each frame, the \
         streaming estimator in metres (mean limb length {} m). Errors of the refined \
         (lag {}) skeletons, metres, camera frame. People hide each other as `synth` \
         models it (a joint behind another's limb peaks on that limb).\n\n",
        args.mean_limb_length, config.estimator.window.lag
    );
    for (i, scene) in SCENES.iter().enumerate() {
        let dir = args.work.join(format!("scene-{i}"));
        let recording = dir.join("scene.mcap");
        let mut argv: Vec<String> = vec!["synth".into(), "--mapping".into()];
        argv.push(args.mapping.display().to_string());
        for (file, place) in scene.people {
            argv.push("--bvh".into());
            argv.push(args.data.join(file).display().to_string());
            if !place.is_empty() {
                argv.push(format!("--place={place}"));
            }
        }
        argv.extend(["--static-camera".into(), "--out".into()]);
        argv.push(dir.join("seq").display().to_string());
        argv.push("--mcap".into());
        argv.push(recording.display().to_string());
        let synth = SynthCommand::try_parse_from(&argv)
            .map_err(|e| CliError::Usage(format!("scene {i}: {e}")))?;
        super::synth::run(&synth.args)?;
        let tracked = dir.join("tracked.mcap");
        let tracking = track(
            &recording,
            &tracked,
            &config.topics,
            &config.detector.images.tracking,
        )?;
        let (idf1, to_truth) = tracking.idf1();
        let options = ReplayOptions {
            record: Some(dir.join("skeletons.mcap")),
            rosbag2: false,
            rate: ReplayRate::Fast,
            paced_for_live: false,
        };
        let began = Instant::now();
        let report = replay(&config, &tracked, &options, &AtomicBool::new(false))?;
        let fps = report.frames as f64 / began.elapsed().as_secs_f64().max(1e-9);
        let all = read_topic::<Skeleton3D>(&dir.join("skeletons.mcap"), &config.topics.skeletons)?;
        let total = all.len();
        let skeletons: Vec<Skeleton3D> = all
            .into_iter()
            .filter_map(|(_, mut s)| {
                s.track_id = *to_truth.get(&s.track_id)?;
                Some(s)
            })
            .collect();
        let unattributed = total - skeletons.len();
        let truth = read_topic::<Skeleton3D>(&recording, "/posestream/ground_truth")?;
        let lag = u32::try_from(config.estimator.window.lag).unwrap_or(u32::MAX);
        let (per_person, not_metric) = errors(&skeletons, &truth, lag);
        if per_person.is_empty() {
            return Err(CliError::Nothing(format!(
                "scene {i}: no refined (lag {lag}) skeletons in metres: the configuration's \
                 estimator.window must publish them"
            )));
        }
        text.push_str(&format!(
            "### {}\n\nTracker: {} id switches, IDF1 {:.3} ({} of {} true boxes reported, {} of \
             them carried over; \
             two people's boxes overlapped by IoU {:.2} at most); \
             estimator {} tracks, {} resets, {:.0} frames/s (all people, replay as fast as it goes); \
             skeletons of no person's id (not scored) {}, not in metres (not scored) {}.\n\n\
             | person | take | frames | MPJPE | root-aligned | P-MPJPE | root | depth | within 1 / 2 std |\n\
             |---|---|---:|---:|---:|---:|---:|---:|---:|\n",
            scene.name,
            tracking.id_switches(),
            idf1,
            tracking.reported,
            tracking.truth_boxes,
            tracking.carried,
            tracking.closest,
            report.counters.tracks,
            report.counters.resets,
            fps,
            unattributed,
            not_metric,
        ));
        for (person, (file, _)) in scene.people.iter().enumerate() {
            let take = file
                .trim_start_matches("dataset-1_")
                .trim_end_matches(".bvh");
            // synth numbers people from 1.
            match per_person.get(&(person as u32 + 1)) {
                Some(e) if e.frames > 0 => {
                    let f = e.frames as f64;
                    let axes = e.axes.max(1) as f64;
                    text.push_str(&format!(
                        "| {person} | {take} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.1} % | {:.0} % / {:.0} % |\n",
                        e.frames,
                        e.mpjpe / f,
                        e.root_aligned / f,
                        e.p_mpjpe / f,
                        e.root / f,
                        100.0 * e.depth / f,
                        100.0 * e.within[0] as f64 / axes,
                        100.0 * e.within[1] as f64 / axes,
                    ));
                }
                _ => text.push_str(&format!("| {person} | {take} | 0 | | | | | | |\n")),
            }
        }
        text.push('\n');
    }
    Ok(text)
}
