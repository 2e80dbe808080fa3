//! `posestream scenes --rooms`: people in rooms seen by several cameras, fused against
//! single-view. Each room is rendered by [`posestream::synth::room`] (held-out takes:
//! walks, and from room 11 kicks, punches, a bow, a wave, a dash; one room's joints
//! defined as another detector's, one camera's given pose 2 degrees off; static cameras
//! around the room, each with its own clock, the heat maps' error model, people hiding
//! each other); each person's views are fused by
//! [`FusedWindow`] and, apart, estimated by each camera alone (the streaming window and
//! the metric step, as the service does) and moved to the world frame by that camera's
//! extrinsics. Errors are in the world frame with no alignment, at the refined lag
//! (10 frames) for both, each person's views given; then again with each camera's
//! track ids scrambled and the tracks matched into people by geometry (IDF1, people
//! found, their MPJPE). Beside them the triangulation baseline
//! ([`posestream::fusion::Triangulator`]: no model, each joint's peaks triangulated and a
//! 5-frame median), which the fusion has to beat.

use posestream::fusion::{
    FusionSettings, TriangulationSettings, ViewCamera, ViewResidual, suspects,
};
use posestream::metres::MetricSettings;
use posestream::mocap::{Bvh, MappedSequence, SkeletonMapping, rooms};
use posestream::streaming::WindowEstimator;
use posestream::synth::room::{self, RoomCamera};
use posestream::synth::{self, ErrorModel, Placement};
use posestream::{Estimator, Skeleton};

use super::ScenesArgs;
use crate::cli::CliError;

/// A room: its cameras and people (a take and its placement relative to the first).
struct RoomSpec {
    name: &'static str,
    cameras: fn() -> Vec<RoomCamera>,
    people: &'static [(&'static str, Placement)],
    /// The joints as the heat maps (and the truth) define them: moved off the
    /// dictionary's by these body-frame offsets ([`synth::redefined`]; none: its own).
    definition: &'static [(&'static str, [f64; 3])],
    /// A camera whose pose the estimators are given turned about the vertical by so many
    /// degrees (its calibration gone wrong), the rest as they are.
    misplaced: Option<(usize, f64)>,
}

/// Another detector's joints: the hips and pelvis a few centimetres lower, wider and
/// further forward than the motion capture's joint centres, the shoulders higher and
/// wider, the neck forward, the head's top lower (`[left, up, forward]`, metres).
const ANOTHER_DETECTORS: &[(&str, [f64; 3])] = &[
    ("pelvis", [0.0, -0.04, 0.02]),
    ("l-hip", [0.03, -0.03, 0.02]),
    ("r-hip", [-0.03, -0.03, 0.02]),
    ("l-shoulder", [0.02, 0.02, 0.0]),
    ("r-shoulder", [-0.02, 0.02, 0.0]),
    ("neck", [0.0, 0.0, 0.03]),
    ("head-top", [0.0, -0.03, 0.02]),
];

const STILL: Placement = Placement {
    ahead: 0.0,
    left: 0.0,
    turn_deg: 0.0,
    velocity: [0.0, 0.0],
};

const fn at(ahead: f64, left: f64, turn_deg: f64) -> Placement {
    Placement {
        ahead,
        left,
        turn_deg,
        velocity: [0.0, 0.0],
    }
}

const FRAME: f64 = 1.0 / 30.0;

const ROOMS: [RoomSpec; 17] = [
    RoomSpec {
        name: "2 cameras at 90 degrees, 5 m; one person",
        cameras: || vec![RoomCamera::at(30.0, 5.0), RoomCamera::at(120.0, 5.0)],
        people: &[("dataset-1_walk-left_proud_001.bvh", STILL)],
        definition: &[],
        misplaced: None,
    },
    RoomSpec {
        name: "2 cameras at 90 degrees, 9 m; two people",
        cameras: || vec![RoomCamera::at(30.0, 9.0), RoomCamera::at(120.0, 9.0)],
        people: &[
            ("dataset-1_walk_proud_002.bvh", STILL),
            ("dataset-1_walk-left_proud_001.bvh", at(2.0, 1.0, 180.0)),
        ],
        definition: &[],
        misplaced: None,
    },
    RoomSpec {
        name: "3 cameras, 5 m; two people",
        cameras: || RoomCamera::ring(3, 20.0, 5.0),
        people: &[
            ("dataset-1_walk-left_proud_001.bvh", STILL),
            ("dataset-1_walk-right_proud_001.bvh", at(1.5, 1.0, 0.0)),
        ],
        definition: &[],
        misplaced: None,
    },
    RoomSpec {
        name: "4 cameras, 6 m; four people",
        cameras: || RoomCamera::ring(4, 45.0, 6.0),
        people: &[
            ("dataset-1_walk-left_proud_001.bvh", STILL),
            ("dataset-1_walk-right_proud_001.bvh", at(1.5, 1.0, 0.0)),
            ("dataset-1_walk_proud_001.bvh", at(-1.5, 0.5, 90.0)),
            ("dataset-1_walk-back_proud_001.bvh", at(0.5, -1.5, 0.0)),
        ],
        definition: &[],
        misplaced: None,
    },
    RoomSpec {
        name: "3 cameras, 6 m; two people crossing 0.6 m apart",
        cameras: || RoomCamera::ring(3, 20.0, 6.0),
        people: &[
            ("dataset-1_walk-left_proud_001.bvh", STILL),
            ("dataset-1_walk-right_proud_001.bvh", at(0.6, 3.0, 0.0)),
        ],
        definition: &[],
        misplaced: None,
    },
    RoomSpec {
        name: "3 cameras, 10 m; two people",
        cameras: || RoomCamera::ring(3, 20.0, 10.0),
        people: &[
            ("dataset-1_walk_proud_002.bvh", STILL),
            ("dataset-1_walk-left_proud_001.bvh", at(2.0, 1.0, 180.0)),
        ],
        definition: &[],
        misplaced: None,
    },
    RoomSpec {
        name: "4 cameras, 12 m; three people",
        cameras: || RoomCamera::ring(4, 45.0, 12.0),
        people: &[
            ("dataset-1_walk_proud_002.bvh", STILL),
            ("dataset-1_walk-left_proud_001.bvh", at(2.0, 1.0, 180.0)),
            ("dataset-1_walk-right_proud_001.bvh", at(-1.0, -2.0, 0.0)),
        ],
        definition: &[],
        misplaced: None,
    },
    RoomSpec {
        name: "3 cameras unsynchronised (+1/2, -1/3 frame, 3 ms jitter), one at 15 frames/s; two people",
        cameras: || {
            let mut c = RoomCamera::ring(3, 20.0, 5.0);
            c[1].offset_s = 0.5 * FRAME;
            c[1].jitter_s = 0.003;
            c[2].offset_s = -FRAME / 3.0;
            c[2].jitter_s = 0.003;
            c[2].every = 2;
            c
        },
        people: &[
            ("dataset-1_walk-left_proud_001.bvh", STILL),
            ("dataset-1_walk-right_proud_001.bvh", at(1.5, 1.0, 0.0)),
        ],
        definition: &[],
        misplaced: None,
    },
    RoomSpec {
        name: "3 cameras, one silent from 3 to 6 s; two people",
        cameras: || {
            let mut c = RoomCamera::ring(3, 20.0, 5.0);
            c[0].dropped = Some([3.0, 6.0]);
            c
        },
        people: &[
            ("dataset-1_walk-left_proud_001.bvh", STILL),
            ("dataset-1_walk-right_proud_001.bvh", at(1.5, 1.0, 0.0)),
        ],
        definition: &[],
        misplaced: None,
    },
    RoomSpec {
        name: "1 camera (fusion with one view), 5 m; one person",
        cameras: || vec![RoomCamera::at(30.0, 5.0)],
        people: &[("dataset-1_walk-left_proud_001.bvh", STILL)],
        definition: &[],
        misplaced: None,
    },
    // Not walking: held-out actions (config/splits/bandai-namco.toml: kick, punch,
    // byebye) and style (proud: a bow), the dictionary trained on none of them.
    RoomSpec {
        name: "3 cameras, 5 m; one kicks, one punches",
        cameras: || RoomCamera::ring(3, 20.0, 5.0),
        people: &[
            ("dataset-1_kick_normal_001.bvh", STILL),
            ("dataset-1_punch_normal_002.bvh", at(1.5, 1.0, 0.0)),
        ],
        definition: &[],
        misplaced: None,
    },
    RoomSpec {
        name: "2 cameras at 90 degrees, 5 m; one kicks",
        cameras: || vec![RoomCamera::at(30.0, 5.0), RoomCamera::at(120.0, 5.0)],
        people: &[("dataset-1_kick_normal_001.bvh", STILL)],
        definition: &[],
        misplaced: None,
    },
    RoomSpec {
        name: "4 cameras, 6 m; one bows, one waves goodbye",
        cameras: || RoomCamera::ring(4, 45.0, 6.0),
        people: &[
            ("dataset-1_bow_proud_001.bvh", STILL),
            ("dataset-1_byebye_proud_001.bvh", at(1.0, 1.0, 180.0)),
        ],
        definition: &[],
        misplaced: None,
    },
    RoomSpec {
        name: "3 cameras, 5 m; one dashes, one punches",
        cameras: || RoomCamera::ring(3, 20.0, 5.0),
        people: &[
            ("dataset-1_dash_proud_001.bvh", STILL),
            ("dataset-1_punch_normal_001.bvh", at(1.5, 1.0, 0.0)),
        ],
        definition: &[],
        misplaced: None,
    },
    RoomSpec {
        name: "3 cameras, 5 m; joints defined off the dictionary's (another detector's hips, pelvis, shoulders, neck, head); one kicks, one punches",
        cameras: || RoomCamera::ring(3, 20.0, 5.0),
        people: &[
            ("dataset-1_kick_normal_001.bvh", STILL),
            ("dataset-1_punch_normal_002.bvh", at(1.5, 1.0, 0.0)),
        ],
        definition: ANOTHER_DETECTORS,
        misplaced: None,
    },
    RoomSpec {
        name: "3 cameras, 5 m, camera 1's given pose turned 2 degrees; one kicks, one punches",
        cameras: || RoomCamera::ring(3, 20.0, 5.0),
        people: &[
            ("dataset-1_kick_normal_001.bvh", STILL),
            ("dataset-1_punch_normal_002.bvh", at(1.5, 1.0, 0.0)),
        ],
        definition: &[],
        misplaced: Some((1, 2.0)),
    },
    RoomSpec {
        name: "4 cameras, 6 m; three people side by side 0.5 m apart: a bow, a wave, a guide",
        cameras: || RoomCamera::ring(4, 45.0, 6.0),
        people: &[
            ("dataset-1_bow_proud_001.bvh", STILL),
            ("dataset-1_byebye_proud_001.bvh", at(0.0, 0.5, 0.0)),
            ("dataset-1_guide_proud_001.bvh", at(0.0, -0.5, 0.0)),
        ],
        definition: &[],
        misplaced: None,
    },
];

/// Checks room `index` (1-based) is one of the rooms (`--room`), before any work.
pub fn check_room(index: usize) -> Result<(), CliError> {
    spec_of(index).map(|_| ())
}

/// Room `index` (1-based), or a usage error naming the rooms there are.
fn spec_of(index: usize) -> Result<&'static RoomSpec, CliError> {
    ROOMS.get(index.wrapping_sub(1)).ok_or_else(|| {
        CliError::Usage(format!(
            "--room {index}: there are rooms 1 to {}",
            ROOMS.len()
        ))
    })
}

/// The calibration the estimators of `spec` are given for `room`: its own, with the
/// misplaced camera's pose turned.
fn given_cameras(spec: &RoomSpec, room: &room::Room) -> Vec<ViewCamera> {
    let mut cameras = room.view_cameras();
    if let Some((c, degrees)) = spec.misplaced
        && let Some(camera) = cameras.get_mut(c)
    {
        turn_about_vertical(camera, degrees);
    }
    cameras
}

/// Turns `camera` in place about the world's vertical by `degrees` (its calibration
/// gone wrong).
fn turn_about_vertical(camera: &mut ViewCamera, degrees: f64) {
    let turn = nalgebra::UnitQuaternion::from_axis_angle(
        &nalgebra::Vector3::z_axis(),
        degrees.to_radians(),
    );
    camera.world_from_camera.rotation = turn * camera.world_from_camera.rotation;
}

/// The takes the rooms are made of (checked before a long run needs them).
pub fn takes() -> impl Iterator<Item = &'static str> {
    ROOMS
        .iter()
        .flat_map(|room| room.people.iter().map(|(file, _)| *file))
}

/// The markdown of every room.
pub fn markdown(args: &ScenesArgs) -> Result<String, CliError> {
    let config = args.config.load()?;
    let mapping = SkeletonMapping::load(&args.mapping)?;
    let skel = mapping.layout.clone();
    let dict = posestream::msgs::shipped::load_dictionary(&config.estimator.dictionary)?;
    let estimator = Estimator::new(dict, config.estimator.params.clone())?;
    let window = WindowEstimator::new(estimator.clone(), config.estimator.window.clone())?;
    // The fusion sees people's size where two cameras see them: it assumes the
    // configuration's (0.25 m) like a user's; each camera alone is given the subjects'.
    let fusion = config.estimator.fusion.clone();
    let mut out = String::new();
    out.push_str(&format!(
        "Rooms (`posestream scenes --rooms`): held-out takes (walks; from room 11 kicks, punches, a bow, a wave, a dash, a guide's gesture; room 15's joints defined as another detector's, room 16's camera 1 given 2 degrees off), heat maps with the error model, people hiding each other. \
         World frame, no alignment, refined estimates (lag {} fused, {} single-view); the people's views are given. \
         Assumed size: fused {} m (the configuration's: two cameras see the size), each camera alone {} m (the subjects', its best case).\n\n",
        fusion.lag, config.estimator.window.lag, fusion.mean_limb_length, args.mean_limb_length
    ));
    out.push_str("| room | fused MPJPE mm | root mm | at once (lag 0) mm | best single-view mm | ratio | triangulated mm | fused / triangulated | fused within 1 / 2 std | each camera alone mm | one view only | fitted bone length m | fused ms per person-frame | matched by geometry: IDF1, people found, MPJPE mm |\n");
    out.push_str("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for (index, spec) in (1..).zip(&ROOMS) {
        if args.room.is_some_and(|only| only != index) {
            continue;
        }
        let people = load_people(args, &mapping, &skel, spec)?;
        let cameras = (spec.cameras)();
        let room = room::render(&people, &skel, &cameras, &ErrorModel::default(), 1.2, 0.2)
            .map_err(|e| CliError::Failed(format!("{}: {e}", spec.name)))?;
        let metric = MetricSettings {
            mean_limb_length: args.mean_limb_length,
            ..MetricSettings::default()
        };
        let given = given_cameras(spec, &room);
        let r = rooms::score(&room, &given, &skel, &estimator, &window, &metric, &fusion)?;
        let singles: Vec<f64> = r.single.iter().map(|e| e.mpjpe_mm()).collect();
        let best = singles.iter().cloned().fold(f64::INFINITY, f64::min);
        let fused = r.fused.mpjpe_mm();
        let baseline = rooms::triangulated(&room, &given, &skel, &TriangulationSettings::default());
        let (baseline_mm, baseline_ratio) = if baseline.frames == 0 {
            ("-".to_string(), "-".to_string())
        } else {
            let mm = baseline.mpjpe_mm();
            (format!("{mm:.0}"), format!("{:.3}", fused / mm))
        };
        let matched = rooms::fuse_matched(&room, &given, &estimator, &fusion, &fusion.matching)?;
        let matched_errors = rooms::score_matched(&room, &skel, &matched, fusion.lag);
        out.push_str(&format!(
            "| {} | {:.0} | {:.0} | {:.0} | {:.0} | {:.2} | {} | {} | {:.1} / {:.1} % | {} | {:.0} % | {} | {:.2} | {:.3}, {} of {}, {:.0} |\n",
            spec.name,
            fused,
            r.fused.root_mm(),
            r.fused_newest.mpjpe_mm(),
            best,
            fused / best,
            baseline_mm,
            baseline_ratio,
            100.0 * r.fused.within_share()[0],
            100.0 * r.fused.within_share()[1],
            singles
                .iter()
                .map(|v| format!("{v:.0}"))
                .collect::<Vec<_>>()
                .join(" / "),
            100.0 * r.fused.monocular as f64 / r.fused.frames.max(1) as f64,
            r.sizes
                .iter()
                .map(|v| format!("{v:.3}"))
                .collect::<Vec<_>>()
                .join(" / "),
            1000.0 * r.seconds / r.person_frames.max(1) as f64,
            matched.idf1,
            matched.ids,
            room.people.len(),
            matched_errors.mpjpe_mm(),
        ));
    }
    if args.room.is_none() {
        out.push_str(&wrong_extrinsics(
            args, &mapping, &skel, &estimator, &fusion,
        )?);
    }
    Ok(out)
}

/// The room of three cameras at 5 m with two people, fused once with the true
/// extrinsics and once with camera 1's turned and moved: each camera's residual, the
/// cameras named, the fused error.
fn wrong_extrinsics(
    args: &ScenesArgs,
    mapping: &SkeletonMapping,
    skel: &Skeleton,
    estimator: &Estimator,
    fusion: &FusionSettings,
) -> Result<String, CliError> {
    let spec = &ROOMS[2];
    let people = load_people(args, mapping, skel, spec)?;
    let room = room::render(
        &people,
        skel,
        &(spec.cameras)(),
        &ErrorModel::default(),
        1.2,
        0.2,
    )
    .map_err(|e| CliError::Failed(format!("{}: {e}", spec.name)))?;
    let mut text = format!(
        "\nWrong extrinsics ({}): each camera's mean residual (the distance of its heat maps' joints from the fused poses' projections, a fraction of the person's box), the cameras `fusion::extrinsics` names, the fused MPJPE.\n\n\
         | extrinsics given | residual per camera | named | fused MPJPE mm |\n|---|---|---|---|\n",
        spec.name
    );
    let truth = room.view_cameras();
    let cases: [(&str, f64, f64); 3] = [
        ("as they are", 0.0, 0.0),
        ("camera 1 turned 1 degree, moved 5 cm", 1.0, 0.05),
        ("camera 1 turned 3 degrees, moved 10 cm", 3.0, 0.10),
    ];
    for (name, degrees, metres) in cases {
        let mut cameras = truth.clone();
        turn_about_vertical(&mut cameras[1], degrees);
        cameras[1].world_from_camera.translation.vector += nalgebra::Vector3::new(metres, 0.0, 0.0);
        let mut residuals = vec![ViewResidual::default(); cameras.len()];
        let mut errors = rooms::Errors::default();
        for person in 0..room.people.len() {
            let fused = rooms::fuse_with(&room, &cameras, person, estimator, fusion, true)?;
            for (r, o) in residuals.iter_mut().zip(&fused.residuals) {
                r.merge(o);
            }
            let p = skel.len();
            for e in fused.estimates.iter().filter(|e| e.lag == fusion.lag) {
                let t = room.frame_at(e.stamp_ns);
                errors.add(
                    &room.people[person].positions[3 * p * t..3 * p * (t + 1)],
                    &e.joints,
                    skel.root(),
                );
            }
        }
        let named = suspects(&residuals, &fusion.extrinsics);
        text.push_str(&format!(
            "| {name} | {} | {:?} | {:.0} |\n",
            residuals
                .iter()
                .map(|r| format!("{:.3}", r.mean()))
                .collect::<Vec<_>>()
                .join(" / "),
            named,
            errors.mpjpe_mm()
        ));
    }
    Ok(text)
}

fn load_people(
    args: &ScenesArgs,
    mapping: &SkeletonMapping,
    skel: &Skeleton,
    spec: &RoomSpec,
) -> Result<Vec<MappedSequence>, CliError> {
    let mut takes = Vec::new();
    for (file, _) in spec.people {
        let path = args.data.join(file);
        let bvh = Bvh::load(&path)?;
        takes.push(mapping.apply(&bvh, &path.display().to_string())?);
    }
    let frames = takes.iter().map(|s| s.frames).min().unwrap_or(0);
    for (t, (file, _)) in takes.iter_mut().zip(spec.people) {
        *t = t.frames_from(0, frames).ok_or_else(|| {
            CliError::Failed(format!(
                "{}: no frames (a room's takes need some)",
                args.data.join(file).display()
            ))
        })?;
    }
    let first = takes[0].clone();
    takes
        .iter()
        .zip(spec.people)
        .enumerate()
        .map(|(i, (take, (_, placement)))| {
            let placed = match i {
                0 => first.clone(),
                _ => synth::place(&first, take, skel, placement).map_err(CliError::Failed)?,
            };
            if spec.definition.is_empty() {
                Ok(placed)
            } else {
                synth::redefined(&placed, skel, spec.definition).map_err(CliError::Failed)
            }
        })
        .collect()
}

/// Writes room `index` (1-based, of the table `--rooms` prints) as the cameras of a
/// deployment would send it, to the recording `path`: per camera `cam<c>`, its heat maps
/// (`/cam<c><topics.heatmaps>`, `uint8`, frame id `cam<c>`, stamped and logged at its own
/// capture times, track ids its own: they agree with no other camera's) and its
/// calibration (`/cam<c><topics.camera_info>`, with every image); the cameras' poses
/// under `world` once on `topics.tf_static`; each person's truth in the world frame on
/// `topics.ground_truth`. Beside it, `<path>.toml`: the configuration `posestream fuse`
/// reads it with. Returns what it wrote, for people.
pub fn record(args: &ScenesArgs, index: usize, path: &std::path::Path) -> Result<String, CliError> {
    use posestream::msgs::tf::{TFMessage, TransformStamped};
    use posestream::msgs::{
        Header, HeatMapEncoding, HeatMaps, Skeleton3D, SkeletonState, Time, Units,
    };
    use posestream::nodes::config::FusionConfig;
    use posestream::recording::Recorder;

    let spec = spec_of(index)?;
    let config = args.config.load()?;
    let topics = &config.topics;
    let mapping = SkeletonMapping::load(&args.mapping)?;
    let skel = mapping.layout.clone();
    let people = load_people(args, &mapping, &skel, spec)?;
    let cameras = (spec.cameras)();
    let room = room::render(&people, &skel, &cameras, &ErrorModel::default(), 1.2, 0.2)
        .map_err(|e| CliError::Failed(format!("{}: {e}", spec.name)))?;
    // Capture times start 1 s after the epoch: a camera ahead of the room's clock
    // stamps no frame before it.
    const START_NS: i64 = 1_000_000_000;
    let frame_ns = |t: usize, dt: f64| START_NS + room.frame_ns(t) + (dt * 1e9).round() as i64;
    let mut rec = Recorder::create(path)?;
    let world = Header {
        stamp: Time::from_nanos(0),
        frame_id: "world".into(),
    };
    // The calibration a deployment is given (a misplaced camera's pose as it was
    // measured, not as it is).
    let given: Vec<_> = given_cameras(spec, &room)
        .iter()
        .map(|c| c.world_from_camera)
        .collect();
    let poses = TFMessage {
        transforms: given
            .iter()
            .enumerate()
            .map(|(c, pose)| {
                let (q, x) = (pose.rotation, pose.translation.vector);
                TransformStamped::new(
                    world.clone(),
                    format!("cam{c}"),
                    [x.x, x.y, x.z],
                    [q.i, q.j, q.k, q.w],
                )
            })
            .collect(),
    };
    // Before any camera's first frame (one ahead of the room's clock stamps it earlier).
    rec.write(&topics.tf_static, 0, &poses)?;
    // Every message in capture-time order, as they would arrive.
    let mut order: Vec<(i64, usize, usize, usize)> = Vec::new();
    for (c, seen) in room.seen.iter().enumerate() {
        for (i, s) in seen.iter().enumerate() {
            for (t, dt) in s.dt.iter().enumerate() {
                if let Some(dt) = dt {
                    order.push((frame_ns(t, *dt), c, i, t));
                }
            }
        }
    }
    order.sort_unstable();
    let mut last_info = vec![None; room.cameras.len()];
    for &(stamp, c, i, t) in &order {
        let header = Header {
            stamp: Time::from_nanos(stamp),
            frame_id: format!("cam{c}"),
        };
        let name = format!("cam{c}");
        let (maps_topic, info_topic) = FusionConfig::camera_topics(&name, topics);
        if last_info[c] != Some(stamp) {
            let info = crate::cli::synth::camera_info(
                header.clone(),
                &room.intrinsics[c],
                cameras[c].image_size,
            );
            rec.write(&info_topic, stamp as u64, &info)?;
            last_info[c] = Some(stamp);
        }
        let s = &room.seen[c][i];
        let maps = &s.maps.maps;
        let n = maps.joints * maps.height * maps.width;
        let mut message = HeatMaps::from_values(
            header,
            t as u64,
            skel.joints.clone(),
            maps.height as u32,
            maps.width as u32,
            s.boxes[t],
            &maps.values[t * n..(t + 1) * n],
            HeatMapEncoding::Uint8,
        );
        // Each camera numbers people its own way.
        message.track_id = 1 + ((3 * i + 5 * c + 11) % 97) as u32;
        rec.write(&maps_topic, stamp as u64, &message)?;
    }
    let p = skel.len();
    for t in 0..room.frames() {
        let stamp = START_NS + room.frame_ns(t);
        for (i, person) in room.people.iter().enumerate() {
            let truth = Skeleton3D {
                header: Header {
                    stamp: Time::from_nanos(stamp),
                    frame_id: "world".into(),
                },
                sequence: t as u64,
                track_id: i as u32 + 1,
                joint_names: skel.joints.clone(),
                units: Units::Metres as u8,
                positions: person.positions[3 * p * t..3 * p * (t + 1)].to_vec(),
                position_std: vec![0.0; 3 * p],
                state: SkeletonState::Tracking as u8,
                ..Skeleton3D::default()
            };
            rec.write(&topics.ground_truth, stamp as u64, &truth)?;
        }
    }
    rec.finish()?;
    let names: Vec<String> = (0..room.cameras.len())
        .map(|c| format!("\"cam{c}\""))
        .collect();
    let intrinsics: String = room
        .intrinsics
        .iter()
        .enumerate()
        .map(|(c, k)| {
            format!(
                "cam{c} = [{:?}, {:?}, {:?}, {:?}]\n",
                k.fx, k.fy, k.cx, k.cy
            )
        })
        .collect();
    let poses: String = given
        .iter()
        .enumerate()
        .map(|(c, pose)| {
            let (q, x) = (pose.rotation, pose.translation.vector);
            format!(
                "cam{c} = [{}, {}, {}, {}, {}, {}, {}]\n",
                x.x, x.y, x.z, q.i, q.j, q.k, q.w
            )
        })
        .collect();
    let toml = format!(
        "# `posestream fuse --config {0}.toml --recording {0}`: room {index}, {1}.\n\
         # The cameras' poses come from the recording's {2}; with extrinsics = \"config\"\n\
         # the [fusion.poses] below are used instead (the same), and [fusion.intrinsics]\n\
         # are the cameras' CameraInfo (which the recording also holds).\n\
         [fusion]\ncameras = [{3}]\n\n[fusion.poses]\n{4}\n[fusion.intrinsics]\n{5}",
        path.display(),
        spec.name,
        topics.tf_static,
        names.join(", "),
        poses,
        intrinsics
    );
    let config_path = std::path::PathBuf::from(format!("{}.toml", path.display()));
    posestream::files::write_output(&config_path, &[], toml.as_bytes())?;
    Ok(format!(
        "room {index} ({}): {} cameras, {} people, {} frames -> {}\nthe fusion's configuration -> {}\n",
        spec.name,
        room.cameras.len(),
        room.people.len(),
        room.frames(),
        path.display(),
        config_path.display()
    ))
}
