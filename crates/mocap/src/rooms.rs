//! Scoring a rendered room ([`crate::synth::room`]): each person's views fused by
//! [`FusedWindow`], and each camera alone (the streaming window and the metric step, as
//! the single-camera service runs them) moved to the world frame by its extrinsics.
//! Errors are in the world frame with no alignment, at each estimator's refined lag; the
//! people's views are given (who is who across cameras is not scored here).

use std::time::Instant;

use nalgebra::Point3;
use posestream_math::Estimator;
use posestream_math::error::EstimateError;
use posestream_math::fusion::{FusedEstimate, FusedWindow, FusionSettings, ViewMaps};
use posestream_math::metric::{MetricPose, MetricSettings, MetricStep};
use posestream_math::skeleton::Skeleton;
use posestream_math::streaming::{FrameEstimate, FrameMaps, Scores, WindowEstimator};

use crate::synth::room::Room;

/// Errors of one estimator over a room's people.
#[derive(Debug, Default, Clone)]
pub struct Errors {
    /// Frames scored.
    pub frames: usize,
    /// Sum of the frames' MPJPE, metres.
    pub mpjpe: f64,
    /// Sum of the frames' root errors, metres.
    pub root: f64,
    /// Frames estimated from one view.
    pub monocular: usize,
}

impl Errors {
    /// Adds a frame: its true and estimated joints (`[x, y, z]` per joint, metres).
    pub fn add(&mut self, truth: &[f64], joints: &[f64], root: usize) {
        let p = truth.len() / 3;
        let mut e = 0.0;
        for j in 0..p {
            e += dist(&truth[3 * j..3 * j + 3], &joints[3 * j..3 * j + 3]);
        }
        self.frames += 1;
        self.mpjpe += e / p as f64;
        self.root += dist(
            &truth[3 * root..3 * root + 3],
            &joints[3 * root..3 * root + 3],
        );
    }

    fn mean(&self, v: f64) -> f64 {
        if self.frames == 0 {
            f64::NAN
        } else {
            1000.0 * v / self.frames as f64
        }
    }

    /// Mean MPJPE, millimetres (NaN without frames).
    pub fn mpjpe_mm(&self) -> f64 {
        self.mean(self.mpjpe)
    }

    /// Mean root (pelvis) error, millimetres (NaN without frames).
    pub fn root_mm(&self) -> f64 {
        self.mean(self.root)
    }
}

fn dist(a: &[f64], b: &[f64]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// What a room measured.
pub struct RoomScores {
    /// The fused estimates at the fusion's lag.
    pub fused: Errors,
    /// The fused estimates at once (lag 0).
    pub fused_newest: Errors,
    /// Each camera alone, at the window's lag.
    pub single: Vec<Errors>,
    /// Seconds spent in the fused window's updates.
    pub seconds: f64,
    /// Person-frames pushed to it.
    pub person_frames: usize,
    /// Each person's mean bone length as fused, metres.
    pub sizes: Vec<f64>,
}

/// One person of a room through a [`FusedWindow`].
#[derive(Debug, Clone)]
pub struct Fused {
    /// Every estimate, as pushed out.
    pub estimates: Vec<FusedEstimate>,
    /// Seconds spent in the window's updates.
    pub seconds: f64,
    /// Frames pushed.
    pub frames: usize,
    /// The person's mean bone length as fused at the end, metres.
    pub mean_limb_length: f64,
}

/// Fuses person `person` of `room`: each frame, the views of the cameras that sent an
/// image then, with their time offsets (`time_offsets`; false: as if every camera took
/// its image at the frame's time).
pub fn fuse(
    room: &Room,
    person: usize,
    estimator: &Estimator,
    fusion: &FusionSettings,
    time_offsets: bool,
) -> Result<Fused, EstimateError> {
    let mut window = FusedWindow::new(estimator, room.view_cameras(), fusion.clone())?;
    let mut out = Fused {
        estimates: Vec::new(),
        seconds: 0.0,
        frames: 0,
        mean_limb_length: 0.0,
    };
    let mut views = Vec::new();
    for t in 0..room.frames() {
        views.clear();
        for (c, seen) in room.seen.iter().enumerate() {
            let s = &seen[person];
            let Some(dt) = s.dt[t] else { continue };
            let maps = &s.maps.maps;
            let n = maps.joints * maps.height * maps.width;
            views.push(ViewMaps {
                view: c,
                dt: if time_offsets { dt } else { 0.0 },
                to_image: s.boxes[t].pixel_map(maps.width, maps.height),
                height: maps.height,
                width: maps.width,
                values: Scores::F32(&maps.values[t * n..(t + 1) * n]),
            });
        }
        let started = Instant::now();
        window.push(room.frame_ns(t), &views, &mut out.estimates)?;
        out.seconds += started.elapsed().as_secs_f64();
        out.frames += 1;
    }
    out.mean_limb_length = window.mean_limb_length();
    Ok(out)
}

/// Scores `room`: its people fused with `fusion`, and seen by each camera alone through
/// `window` (fresh per person and camera) and the metric step with `metric` (its camera
/// set to each camera's).
pub fn score(
    room: &Room,
    skel: &Skeleton,
    estimator: &Estimator,
    window: &WindowEstimator,
    metric: &MetricSettings,
    fusion: &FusionSettings,
) -> Result<RoomScores, EstimateError> {
    let p = skel.len();
    let root = skel.root();
    let cameras = room.view_cameras();
    let mut result = RoomScores {
        fused: Errors::default(),
        fused_newest: Errors::default(),
        single: vec![Errors::default(); cameras.len()],
        seconds: 0.0,
        person_frames: 0,
        sizes: Vec::new(),
    };
    for (i, person) in room.people.iter().enumerate() {
        let truth = |t: usize| &person.positions[3 * p * t..3 * p * (t + 1)];
        let fused = fuse(room, i, estimator, fusion, true)?;
        result.seconds += fused.seconds;
        result.person_frames += fused.frames;
        let estimates = fused.estimates;
        for e in &estimates {
            let t = room.frame_at(e.stamp_ns);
            if e.lag == fusion.lag {
                result.fused.add(truth(t), &e.joints, root);
                result.fused.monocular += usize::from(e.monocular);
            } else if e.lag == 0 {
                result.fused_newest.add(truth(t), &e.joints, root);
            }
        }
        result.sizes.push(fused.mean_limb_length);
        // Each camera alone.
        for (c, seen) in room.seen.iter().enumerate() {
            let s = &seen[i];
            let mut w = window.fresh()?;
            let k = room.intrinsics[c];
            let mut metric = MetricStep::new(
                estimator,
                MetricSettings {
                    intrinsics: vec![k.fx, k.fy, k.cx, k.cy],
                    ..metric.clone()
                },
            )?;
            let mut out: Vec<FrameEstimate> = Vec::new();
            let mut pose = MetricPose::default();
            let lag = window.settings().lag;
            let maps = &s.maps.maps;
            for t in 0..person.frames {
                if s.dt[t].is_none() {
                    continue;
                }
                out.clear();
                w.push(
                    &FrameMaps::of(maps, t, t as u64, room.frame_ns(t)),
                    &mut out,
                )?;
                for e in &out {
                    if e.lag != lag {
                        continue;
                    }
                    let ft = e.sequence as usize;
                    let to_image = s.boxes[ft].pixel_map(maps.width, maps.height);
                    if metric.adjust(e, &to_image, &k, None, &mut pose).is_err() {
                        continue;
                    }
                    let world: Vec<f64> = pose
                        .positions
                        .chunks_exact(3)
                        .flat_map(|q| {
                            let w = room.cameras[c].transform_point(&Point3::new(q[0], q[1], q[2]));
                            [w.x, w.y, w.z]
                        })
                        .collect();
                    result.single[c].add(truth(ft), &world, root);
                }
            }
        }
    }
    Ok(result)
}
