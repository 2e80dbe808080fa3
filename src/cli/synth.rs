//! `posestream synth`: a test sequence (ground truth, 2D joints, crop boxes, heat maps)
//! from a BVH file seen by a virtual camera.

use std::path::PathBuf;

use clap::Args;
use posestream::mocap::{Bvh, SkeletonMapping};
use posestream::msgs::sensor::CameraInfo;
use posestream::msgs::tf::{TFMessage, TransformStamped};
use posestream::msgs::{self, Header, HeatMapEncoding, Skeleton3D, SkeletonState, Time, Units};
use posestream::nodes::config::Topics;
use posestream::npy;
use posestream::recording::Recorder;
use posestream::synth::motion::{self, Motion};
use posestream::synth::{self, CameraSpec, ErrorModel, Placement, Projection, heatmaps};

use super::CliError;

/// The virtual camera.
#[derive(Debug, Clone, Args)]
pub struct CameraArgs {
    /// Distance from the body's root, metres.
    #[arg(long, default_value_t = CameraSpec::default().distance)]
    pub distance: f64,
    /// Azimuth, degrees (0 = in front of the body as it first faces, 90 = its left).
    #[arg(long, default_value_t = CameraSpec::default().azimuth_deg)]
    pub azimuth: f64,
    /// Elevation above the root, degrees.
    #[arg(long, default_value_t = CameraSpec::default().elevation_deg)]
    pub elevation: f64,
    /// Orbit speed, degrees per second.
    #[arg(long, default_value_t = CameraSpec::default().orbit_deg_per_s)]
    pub orbit: f64,
    /// Projection model.
    #[arg(long, value_parser = super::choice::choice::<Projection>(), default_value = "pinhole")]
    pub projection: Projection,
    /// Focal length, pixels (orthographic: focal / distance pixels per metre).
    #[arg(long, default_value_t = CameraSpec::default().focal)]
    pub focal: f64,
    /// Image width and height, pixels (square).
    #[arg(long, default_value_t = CameraSpec::default().image_size[0])]
    pub image_size: f64,
    /// Keep the camera where the first frame puts it instead of following the body.
    #[arg(long)]
    pub static_camera: bool,
    /// The camera's height above the floor, metres: it then stands `--distance` from
    /// the first person horizontally, looking level and `--tilt` down (instead of
    /// `--elevation`), and the recording places it over the floor on `/tf_static`
    /// (`/tf` each frame while it follows the body), frame `map`.
    #[arg(long)]
    pub camera_height: Option<f64>,
    /// With `--camera-height`: degrees the camera looks down from level.
    #[arg(long, default_value_t = 0.0, requires = "camera_height")]
    pub tilt: f64,
}

impl CameraArgs {
    /// The camera these options describe.
    pub fn spec(&self) -> CameraSpec {
        CameraSpec {
            distance: self.distance,
            azimuth_deg: self.azimuth,
            elevation_deg: self.elevation,
            orbit_deg_per_s: self.orbit,
            projection: self.projection,
            focal: self.focal,
            image_size: [self.image_size, self.image_size],
            follow: !self.static_camera,
            height: self.camera_height,
            tilt_deg: self.tilt,
        }
    }
}

/// The heat maps' error model.
#[derive(Debug, Clone, Args)]
pub struct ErrorArgs {
    /// Heat-map size, cells (square).
    #[arg(long, default_value_t = ErrorModel::default().size[0])]
    pub map_size: usize,
    /// Localisation noise, cells (standard deviation).
    #[arg(long, default_value_t = ErrorModel::default().noise)]
    pub noise: f64,
    /// Peak width, cells (standard deviation).
    #[arg(long, default_value_t = ErrorModel::default().blob)]
    pub blob: f64,
    /// Probability per frame and left/right pair that a swap starts.
    #[arg(long, default_value_t = ErrorModel::default().swap_rate)]
    pub swap_rate: f64,
    /// Probability per frame and joint that an occlusion starts.
    #[arg(long, default_value_t = ErrorModel::default().occlusion_rate)]
    pub occlusion_rate: f64,
    /// Probability per frame and joint that the joint goes missing.
    #[arg(long, default_value_t = ErrorModel::default().missing_rate)]
    pub missing_rate: f64,
    /// Frames a swap, occlusion or missing joint lasts.
    #[arg(long, default_value_t = ErrorModel::default().episode_frames)]
    pub episode_frames: usize,
    /// Background noise amplitude.
    #[arg(long, default_value_t = ErrorModel::default().background)]
    pub background: f64,
    /// Seed of the error model.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

impl ErrorArgs {
    /// The model these options describe.
    pub fn model(&self) -> ErrorModel {
        ErrorModel {
            size: [self.map_size, self.map_size],
            noise: self.noise,
            blob: self.blob,
            swap_rate: self.swap_rate,
            occlusion_rate: self.occlusion_rate,
            missing_rate: self.missing_rate,
            episode_frames: self.episode_frames,
            background: self.background,
            seed: self.seed,
        }
    }
}

/// Options of `synth`.
#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
pub struct SynthArgs {
    /// The motion (BVH). Repeated: several people in one scene, seen by the camera the
    /// first one places (each later one placed by a `--place`).
    #[arg(long, required = true, num_args = 1)]
    pub bvh: Vec<PathBuf>,
    /// Where the second, third, ... person starts and goes, relative to the first's
    /// start as it first faces: `ahead,left[,turn[,ahead_speed,left_speed]]` (metres,
    /// degrees counter-clockwise, metres per second). One per `--bvh` after the first.
    #[arg(long, value_parser = placement)]
    pub place: Vec<Placement>,
    /// What each person does beyond the take (none given: as captured; else one per
    /// `--bvh`, in order): `captured`, `step:HEIGHT,UP[,DOWN]`, `jump:HEIGHT,EVERY`,
    /// `crouch:DEPTH,EVERY`, `kneel:AT,HOLD` or `sit:AT,HOLD` (metres, seconds; made
    /// from the take, see `synth::motion`).
    #[arg(long, value_parser = Motion::parse)]
    pub motion: Vec<Motion>,
    /// Skeleton mapping of the BVH (config/skeletons/*.toml).
    #[arg(long)]
    pub mapping: PathBuf,
    /// Output folder (several people: a folder `person-<i>` each).
    #[arg(long)]
    pub out: PathBuf,
    /// First frame.
    #[arg(long, default_value_t = 0)]
    pub start: usize,
    /// Frames (0 = to the end; several people: to the end of the shortest take).
    #[arg(long, default_value_t = 0)]
    pub frames: usize,
    /// Seconds each take lasts, played forward, then backward, and so on (no jump in
    /// place or pose; at most 60; shorter than the take: cut): longer scenes from short
    /// takes. After `--start` and `--frames`, before `--motion`; a `--place` speed goes
    /// on the whole time.
    #[arg(long, value_name = "SECONDS")]
    pub loop_to: Option<f64>,
    /// Also write an MCAP recording (rosbag2-compatible) of the heat maps on
    /// `/posestream/heatmaps`, the ground truth on `/posestream/ground_truth` (track id
    /// = person) and a pinhole camera's `sensor_msgs/CameraInfo` on `/camera/camera_info`
    /// (with `--camera-height`, the camera over the floor on `/tf_static` or `/tf`).
    #[arg(long)]
    pub mcap: Option<PathBuf>,
    /// Heat maps in the recording as u8 with a scale (4x smaller) instead of f32.
    #[arg(long, requires = "mcap")]
    pub quantize: bool,
    /// Crop box side, times the joints' larger extent.
    #[arg(long, default_value_t = 1.25)]
    pub margin: f64,
    /// Several people: do not let them hide each other (by default a joint behind
    /// another person's limb gets that limb's peak, and only a weak one of its own).
    #[arg(long)]
    pub no_hiding: bool,
    #[command(flatten)]
    pub camera: CameraArgs,
    #[command(flatten)]
    pub errors: ErrorArgs,
}

/// `--place`: `ahead,left[,turn[,ahead_speed,left_speed]]`, every number finite.
fn placement(text: &str) -> Result<Placement, String> {
    let v: Vec<f64> = text
        .split(',')
        .map(|x| x.trim().parse::<f64>().map_err(|e| format!("{x:?}: {e}")))
        .collect::<Result<_, _>>()?;
    if v.iter().any(|x| !x.is_finite() || x.abs() > 1e4) {
        return Err("every number must be finite, at most 1e4 in size".into());
    }
    match v[..] {
        [ahead, left] => Ok(Placement {
            ahead,
            left,
            turn_deg: 0.0,
            velocity: [0.0; 2],
        }),
        [ahead, left, turn_deg] => Ok(Placement {
            ahead,
            left,
            turn_deg,
            velocity: [0.0; 2],
        }),
        [ahead, left, turn_deg, va, vl] => Ok(Placement {
            ahead,
            left,
            turn_deg,
            velocity: [va, vl],
        }),
        _ => Err("expected ahead,left[,turn[,ahead_speed,left_speed]]".into()),
    }
}

/// `--loop-to` at most, seconds: a person's heat maps are held in memory (64 x 64 cells
/// of 17 joints: 17 MB a second at 30 frames/s).
const MAX_LOOP_S: f64 = 60.0;
/// `--loop-to` at most, frames (60 s at 120 frames/s).
const MAX_LOOP_FRAMES: f64 = 7200.0;

/// The width of a body part (a bone: arms about 10 cm, legs 15, the trunk 30), metres,
/// when people hide each other.
const LIMB_WIDTH: f64 = 0.2;

/// One person of the scene, seen by the camera.
struct Person {
    view: synth::View,
    /// Its error model (its own seed).
    model: ErrorModel,
    frame_time: f64,
    boxes: Vec<posestream::CropBox>,
    rendered: heatmaps::RenderedMaps,
}

/// Runs `synth`.
pub fn run(args: &SynthArgs) -> Result<(), CliError> {
    if !(args.margin.is_finite() && args.margin >= 1.0) {
        return Err(CliError::Usage(format!(
            "--margin must be >= 1, got {}",
            args.margin
        )));
    }
    if args.place.len() + 1 != args.bvh.len() {
        return Err(CliError::Usage(format!(
            "{} --bvh need {} --place (one per person after the first), got {}",
            args.bvh.len(),
            args.bvh.len() - 1,
            args.place.len()
        )));
    }
    if !args.motion.is_empty() && args.motion.len() != args.bvh.len() {
        return Err(CliError::Usage(format!(
            "{} --bvh need none or {} --motion (one per person), got {}",
            args.bvh.len(),
            args.bvh.len(),
            args.motion.len()
        )));
    }
    let cam = args.camera.spec();
    cam.validate().map_err(CliError::Usage)?;
    let model = args.errors.model();
    model.validate().map_err(CliError::Usage)?;
    let mapping = SkeletonMapping::load(&args.mapping)?;
    let len = if args.frames == 0 {
        usize::MAX
    } else {
        args.frames
    };
    let mut takes = Vec::new();
    for path in &args.bvh {
        let bvh = Bvh::load(path)?;
        let seq = mapping.apply(&bvh, &path.display().to_string())?;
        let seq = seq.frames_from(args.start, len).ok_or_else(|| {
            CliError::Usage(format!(
                "--start {} is past the last frame of {} ({} frames)",
                args.start,
                path.display(),
                seq.frames
            ))
        })?;
        takes.push(seq);
    }
    let frames = takes.iter().map(|s| s.frames).min().unwrap_or(0);
    for t in &mut takes {
        *t = t.frames_from(0, frames).expect("every take has frames");
    }
    let skel = &mapping.layout;
    if let Some(seconds) = args.loop_to {
        if !(seconds > 0.0 && seconds <= MAX_LOOP_S) {
            return Err(CliError::Usage(format!(
                "--loop-to must be in (0, {MAX_LOOP_S}] seconds, got {seconds}"
            )));
        }
        for take in &mut takes {
            let frames = (seconds / take.frame_time).round();
            if frames.is_nan() || !(1.0..=MAX_LOOP_FRAMES).contains(&frames) {
                return Err(CliError::Usage(format!(
                    "--loop-to {seconds} s is {frames} frames of {} s: not 1 to {MAX_LOOP_FRAMES}",
                    take.frame_time
                )));
            }
            *take = motion::ping_pong(take, frames as usize);
        }
    }
    for (take, motion) in takes.iter_mut().zip(&args.motion) {
        *take = motion::apply(take, skel, motion).map_err(CliError::Failed)?;
    }
    let first = takes[0].clone();
    let mut views = Vec::new();
    for (i, take) in takes.iter().enumerate() {
        let placed = match i {
            0 => first.clone(),
            _ => synth::place(&first, take, skel, &args.place[i - 1]).map_err(CliError::Failed)?,
        };
        let view = synth::view_from(&first, &placed, skel, &cam).map_err(|e| match i {
            0 => CliError::Failed(e),
            // A later person: say which, and that its --place put it there.
            _ => CliError::Failed(format!(
                "person {i} ({}, --place {:?}): {e}",
                args.bvh[i].display(),
                args.place[i - 1]
            )),
        })?;
        views.push((view, take.frame_time));
    }
    // People hide each other: each joint behind another's body part (20 cm wide).
    let just_views: Vec<synth::View> = views.iter().map(|(v, _)| v.clone()).collect();
    let hidden = if views.len() > 1 && !args.no_hiding {
        synth::hidden_by_others(
            &just_views,
            skel,
            &|z| cam.pixels_per_metre(z),
            0.5 * LIMB_WIDTH,
        )
    } else {
        vec![Vec::new(); views.len()]
    };
    let mut people = Vec::new();
    for (i, ((view, frame_time), hidden)) in views.into_iter().zip(&hidden).enumerate() {
        let boxes = synth::crop_boxes(&view.image_2d, view.joints, args.margin);
        // Each person's detector errors drawn apart.
        let model = ErrorModel {
            seed: model.seed.wrapping_add(i as u64),
            ..model.clone()
        };
        let rendered = heatmaps::render_hidden(&view.image_2d, &boxes, skel, &model, hidden)?;
        people.push(Person {
            view,
            model,
            frame_time,
            boxes,
            rendered,
        });
    }
    for (i, person) in people.iter().enumerate() {
        let dir = if people.len() == 1 {
            args.out.clone()
        } else {
            args.out.join(format!("person-{i}"))
        };
        write_npy(args, &dir, person, &cam, &mapping.name, skel)?;
    }
    if let Some(path) = &args.mcap {
        write_recording(args, path, &people, &cam, skel)?;
    }
    for (i, person) in people.iter().enumerate() {
        let e = &person.rendered.episodes;
        println!(
            "person {i}: {} frames of {} joints (swapped {}, occluded {}, missing {}, hidden by others {} joint-frames)",
            person.view.frames, person.view.joints, e.swapped, e.occluded, e.missing, e.hidden
        );
    }
    println!("-> {}", args.out.display());
    Ok(())
}

/// A person's NPY files, `meta.json` and (pinhole) `intrinsics.json` in `dir`.
fn write_npy(
    args: &SynthArgs,
    dir: &std::path::Path,
    person: &Person,
    cam: &CameraSpec,
    mapping: &str,
    skel: &posestream::Skeleton,
) -> Result<(), CliError> {
    let (view, boxes, rendered, model) =
        (&person.view, &person.boxes, &person.rendered, &person.model);
    let (f, p) = (view.frames, view.joints);
    std::fs::create_dir_all(dir).map_err(|e| CliError::create(dir, e))?;
    let out = |name: &str| dir.join(name);
    npy::write(&out("gt_3d.npy"), &[f, p, 3], &view.camera_3d)?;
    npy::write(&out("keypoints.npy"), &[f, p, 2], &view.image_2d)?;
    let flat: Vec<f64> = boxes
        .iter()
        .flat_map(|b| [b.x0, b.y0, b.width, b.height])
        .collect();
    npy::write(&out("boxes.npy"), &[f, 4], &flat)?;
    let [h, w] = model.size;
    npy::write(&out("heatmaps.npy"), &[f, p, h, w], &rendered.maps.values)?;
    npy::write(&out("gt_2d_heatmap.npy"), &[f, p, 2], &rendered.truth)?;
    let k = cam.intrinsics();
    let sources: Vec<String> = args.bvh.iter().map(|b| b.display().to_string()).collect();
    let meta = serde_json::json!({
        "source": if sources.len() == 1 { serde_json::json!(sources[0]) } else { serde_json::json!(sources) },
        "placements": args.place,
        "motions": args.motion,
        "mapping": mapping,
        "joints": skel.joints,
        "frames": f,
        "loop_to": args.loop_to,
        "start": args.start,
        "frame_time": person.frame_time,
        "camera": cam,
        "error_model": model,
        "episodes": rendered.episodes,
        "units": "gt_3d: metres, camera frame (x right, y down, z forward); keypoints, boxes: image pixels; gt_2d_heatmap: heat-map cells",
    });
    let write_json = |name: &str, v: &serde_json::Value| {
        let text = serde_json::to_string_pretty(v).map_err(|source| CliError::Json {
            path: out(name),
            source,
        })?;
        let inputs: Vec<&std::path::Path> = args.bvh.iter().map(PathBuf::as_path).collect();
        posestream::files::write_output(&out(name), &inputs, text.as_bytes())
            .map_err(CliError::from)
    };
    write_json("meta.json", &meta)?;
    if cam.projection == Projection::Pinhole {
        write_json(
            "intrinsics.json",
            &serde_json::json!({"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy}),
        )?;
    }
    Ok(())
}

/// The frame the recording places the camera in (`--camera-height`): the motion
/// capture's world, `z = 0` its floor.
pub const FLOOR_FRAME: &str = "map";

/// The recording: per image, the camera's calibration (pinhole), then each person's
/// heat maps and truth (track id = person).
fn write_recording(
    args: &SynthArgs,
    path: &std::path::Path,
    people: &[Person],
    cam: &CameraSpec,
    skel: &posestream::Skeleton,
) -> Result<(), CliError> {
    let topics = Topics::default();
    let mut rec = Recorder::create(path)?;
    let [h, w] = args.errors.model().size;
    let p = skel.len();
    let n = p * h * w;
    let encoding = if args.quantize {
        HeatMapEncoding::Uint8
    } else {
        HeatMapEncoding::Float32
    };
    let k = cam.intrinsics();
    let frames = people[0].view.frames;
    let frame_time = people[0].frame_time;
    for t in 0..frames {
        let stamp_ns = (t as f64 * frame_time * 1e9).round() as i64;
        let header = Header {
            stamp: Time::from_nanos(stamp_ns),
            frame_id: "camera".into(),
        };
        // The camera over the floor: once when it stands still, each frame when it
        // follows the body.
        if cam.height.is_some() && (t == 0 || cam.follow) {
            let pose = &people[0].view.cameras[t];
            let (q, x) = (pose.rotation, pose.translation.vector);
            let tf = TFMessage {
                transforms: vec![TransformStamped::new(
                    Header {
                        stamp: header.stamp.clone(),
                        frame_id: FLOOR_FRAME.into(),
                    },
                    header.frame_id.clone(),
                    [x.x, x.y, x.z],
                    [q.i, q.j, q.k, q.w],
                )],
            };
            let topic = if cam.follow {
                &topics.tf
            } else {
                &topics.tf_static
            };
            rec.write(topic, stamp_ns as u64, &tf)?;
        }
        if cam.projection == Projection::Pinhole {
            // The calibration with every image, as a camera driver publishes it.
            let info = camera_info(header.clone(), &k, cam.image_size);
            rec.write(&topics.camera_info, stamp_ns as u64, &info)?;
        }
        for (i, person) in people.iter().enumerate() {
            let view = &person.view;
            let mut maps = msgs::HeatMaps::from_values(
                header.clone(),
                t as u64,
                skel.joints.clone(),
                h as u32,
                w as u32,
                person.boxes[t],
                &person.rendered.maps.values[t * n..(t + 1) * n],
                encoding,
            );
            // People numbered from 1: 0 is an unknown id (HeatMaps.msg).
            maps.track_id = i as u32 + 1;
            let truth = Skeleton3D {
                header: header.clone(),
                sequence: t as u64,
                track_id: i as u32 + 1,
                joint_names: skel.joints.clone(),
                units: Units::Metres as u8,
                positions: view.camera_3d[3 * p * t..3 * p * (t + 1)].to_vec(),
                position_std: vec![0.0; 3 * p],
                keypoints: view.image_2d[2 * p * t..2 * p * (t + 1)].to_vec(),
                keypoint_std: vec![0.0; p],
                projected: view.image_2d[2 * p * t..2 * p * (t + 1)].to_vec(),
                state: SkeletonState::Tracking as u8,
                ..Skeleton3D::default()
            };
            rec.write(&topics.heatmaps, stamp_ns as u64, &maps)?;
            rec.write(&topics.ground_truth, stamp_ns as u64, &truth)?;
        }
    }
    rec.finish()?;
    println!("recording -> {}", path.display());
    Ok(())
}

/// The `CameraInfo` of a pinhole camera of intrinsics `k` over images of `size` (columns,
/// rows), as a camera driver publishes it (no distortion).
pub(crate) fn camera_info(
    header: Header,
    k: &posestream::Intrinsics,
    size: [f64; 2],
) -> CameraInfo {
    CameraInfo {
        header,
        width: size[0].round() as u32,
        height: size[1].round() as u32,
        k: [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [
            k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
        ],
        ..CameraInfo::default()
    }
}
