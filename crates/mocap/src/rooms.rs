//! Scoring a rendered room ([`crate::synth::room`]): each person's views fused by
//! [`FusedWindow`], and each camera alone (the streaming window and the metric step, as
//! the single-camera service runs them) moved to the world frame by its extrinsics.
//! Errors are in the world frame with no alignment, at each estimator's refined lag; the
//! people's views are given (who is who across cameras is not scored here).

use std::collections::BTreeMap;
use std::time::Instant;

use nalgebra::Point3;
use posestream_base::Scores;
use posestream_math::Estimator;
use posestream_math::accuracy::mpjpe;
use posestream_math::error::EstimateError;
use posestream_math::fusion::{
    FusedEstimate, FusedWindow, FusionSettings, MatchSettings, Matcher, TrackObservation,
    TriangulationSettings, Triangulator, ViewCamera, ViewMaps, ViewResidual,
};
use posestream_math::metres::{MetricPose, MetricSettings, MetricStep};
use posestream_math::skeleton::Skeleton;
use posestream_math::streaming::{FrameEstimate, FrameMaps, WindowEstimator};

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
    /// Per-axis errors within 1 and 2 of the estimate's standard deviations, of `axes`
    /// (frames added with [`Errors::add_with_std`]).
    pub within: [usize; 2],
    /// Per-axis errors counted in `within`.
    pub axes: usize,
}

impl Errors {
    /// Adds a frame: its true and estimated joints (`[x, y, z]` per joint, metres).
    pub fn add(&mut self, truth: &[f64], joints: &[f64], root: usize) {
        let at = 3 * root..3 * root + 3;
        self.frames += 1;
        self.mpjpe += mpjpe(joints, truth);
        self.root += mpjpe(&joints[at.clone()], &truth[at]);
    }

    /// [`Errors::add`], and each joint's per-axis errors against `std` (metres, one per
    /// joint, per axis) for [`Errors::within_share`].
    pub fn add_with_std(&mut self, truth: &[f64], joints: &[f64], std: &[f64], root: usize) {
        self.add(truth, joints, root);
        for (j, (t, e)) in truth
            .chunks_exact(3)
            .zip(joints.chunks_exact(3))
            .enumerate()
        {
            let s = std.get(j).copied().unwrap_or(f64::NAN);
            for axis in 0..3 {
                let z = (t[axis] - e[axis]).abs() / s;
                self.within[0] += usize::from(z <= 1.0);
                self.within[1] += usize::from(z <= 2.0);
                self.axes += 1;
            }
        }
    }

    /// The shares of per-axis errors within 1 and 2 standard deviations (NaN without
    /// any: a calibrated estimate has 0.68 and 0.95).
    pub fn within_share(&self) -> [f64; 2] {
        self.within.map(|w| {
            if self.axes == 0 {
                f64::NAN
            } else {
                w as f64 / self.axes as f64
            }
        })
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
    /// Each camera's residuals against the person's fused poses.
    pub residuals: Vec<ViewResidual>,
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
    fuse_with(
        room,
        &room.view_cameras(),
        person,
        estimator,
        fusion,
        time_offsets,
    )
}

/// [`fuse`] through `cameras` instead of the room's own (extrinsics gone wrong, say).
pub fn fuse_with(
    room: &Room,
    cameras: &[ViewCamera],
    person: usize,
    estimator: &Estimator,
    fusion: &FusionSettings,
    time_offsets: bool,
) -> Result<Fused, EstimateError> {
    let mut window = FusedWindow::new(estimator, cameras.to_vec(), fusion.clone())?;
    let mut out = Fused {
        estimates: Vec::new(),
        seconds: 0.0,
        frames: 0,
        mean_limb_length: 0.0,
        residuals: Vec::new(),
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
    out.residuals = window.residuals().to_vec();
    Ok(out)
}

/// Every person of `room` through the triangulation baseline ([`Triangulator`]: each
/// joint's peaks triangulated, a centred temporal median) with the calibration
/// `cameras` (the room's own: [`Room::view_cameras`]), the cameras' views taken as if at
/// the frame's time: its errors, a frame counted once every joint has a value (none
/// with one camera).
pub fn triangulated(
    room: &Room,
    cameras: &[ViewCamera],
    skel: &Skeleton,
    settings: &TriangulationSettings,
) -> Errors {
    let p = skel.len();
    let root = skel.root();
    let mut errors = Errors::default();
    // One per camera of the room (a calibration of another rig: its cameras in turn).
    let mut peaks: Vec<Vec<[f64; 3]>> = vec![Vec::new(); room.seen.len().max(cameras.len())];
    let mut out = Vec::new();
    for (i, person) in room.people.iter().enumerate() {
        let mut baseline = Triangulator::new(p, *settings);
        let lag = baseline.lag();
        for t in 0..room.frames() {
            let mut seen = Vec::with_capacity(cameras.len());
            for (c, s) in room.seen.iter().map(|seen| &seen[i]).enumerate() {
                peaks[c].clear();
                if s.dt[t].is_some() {
                    s.peaks_into(t, &mut peaks[c]);
                }
            }
            for (c, camera) in cameras.iter().enumerate() {
                if !peaks[c].is_empty() {
                    seen.push((camera, peaks[c].as_slice()));
                }
            }
            if baseline.push(&seen, &mut out) {
                let t = t - lag;
                errors.add(&person.positions[3 * p * t..3 * p * (t + 1)], &out, root);
            }
        }
    }
    errors
}

/// Scores `room`: its people fused with `fusion`, and seen by each camera alone through
/// `window` (fresh per person and camera) and the metric step with `metric` (its camera
/// set to each camera's), both given the calibration `cameras` (the room's own:
/// [`Room::view_cameras`]; a camera's pose gone wrong, say).
pub fn score(
    room: &Room,
    cameras: &[ViewCamera],
    skel: &Skeleton,
    estimator: &Estimator,
    window: &WindowEstimator,
    metric: &MetricSettings,
    fusion: &FusionSettings,
) -> Result<RoomScores, EstimateError> {
    same_rig(room, cameras)?;
    let p = skel.len();
    let root = skel.root();
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
        let fused = fuse_with(room, cameras, i, estimator, fusion, true)?;
        result.seconds += fused.seconds;
        result.person_frames += fused.frames;
        let estimates = fused.estimates;
        for e in &estimates {
            let t = room.frame_at(e.stamp_ns);
            if e.lag == fusion.lag {
                result
                    .fused
                    .add_with_std(truth(t), &e.joints, &e.joint_std, root);
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
                            let w = cameras[c]
                                .world_from_camera
                                .transform_point(&Point3::new(q[0], q[1], q[2]));
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

/// Refuses a calibration of another number of cameras than the room's.
fn same_rig(room: &Room, cameras: &[ViewCamera]) -> Result<(), EstimateError> {
    if cameras.len() == room.seen.len() {
        Ok(())
    } else {
        Err(EstimateError::Parameter(format!(
            "{} cameras calibrated for a room of {}",
            cameras.len(),
            room.seen.len()
        )))
    }
}

/// Every person of a room, the cameras' tracks matched into people by
/// [`Matcher`] (each camera's track ids scrambled: they agree with no other camera's),
/// each person fused by a window of their own.
#[derive(Debug, Clone)]
pub struct Matched {
    /// Per matched person id, their estimates.
    pub estimates: BTreeMap<u64, Vec<FusedEstimate>>,
    /// IDF1 over the camera-track-frames: the share whose matched person is the one
    /// its true person is mapped to (one-to-one, the mapping that agrees most; a track
    /// given no person counts against it).
    pub idf1: f64,
    /// The true person of each matched id (the mapping of `idf1`).
    pub truth_of: BTreeMap<u64, usize>,
    /// Camera-track-frames matched.
    pub observations: usize,
    /// Distinct matched ids.
    pub ids: usize,
}

/// The track id camera `view` gives person `person`: scrambled per camera.
fn track_id(view: usize, person: usize) -> u64 {
    (1000 * view + (7 * person + 3 * view) % 101) as u64
}

/// Matches and fuses every person of `room` (module docs of [`Matched`]) with the
/// calibration `cameras`.
pub fn fuse_matched(
    room: &Room,
    cameras: &[ViewCamera],
    estimator: &Estimator,
    fusion: &FusionSettings,
    matching: &MatchSettings,
) -> Result<Matched, EstimateError> {
    same_rig(room, cameras)?;
    let mut matcher =
        Matcher::new(matching.clone()).map_err(|e| EstimateError::Parameter(e.to_string()))?;
    let mut windows: BTreeMap<u64, FusedWindow> = BTreeMap::new();
    let mut estimates: BTreeMap<u64, Vec<FusedEstimate>> = BTreeMap::new();
    // (true person, matched id) per camera-track-frame.
    let mut pairs: Vec<(usize, u64)> = Vec::new();
    let mut peaks: Vec<Vec<[f64; 3]>> = Vec::new();
    let mut ids = Vec::new();
    let mut out = Vec::new();
    // Camera-track-frames given no person (misses of IDF1).
    let mut unmatched = 0;
    for t in 0..room.frames() {
        // Every camera's tracks this frame.
        let mut who: Vec<(usize, usize)> = Vec::new();
        for (c, seen) in room.seen.iter().enumerate() {
            for (i, s) in seen.iter().enumerate() {
                if s.dt[t].is_some() {
                    who.push((c, i));
                }
            }
        }
        peaks.resize(who.len(), Vec::new());
        for (k, &(c, i)) in who.iter().enumerate() {
            room.seen[c][i].peaks_into(t, &mut peaks[k]);
        }
        let observations: Vec<TrackObservation<'_>> = who
            .iter()
            .enumerate()
            .map(|(k, &(c, i))| TrackObservation {
                view: c,
                track: track_id(c, i),
                peaks: &peaks[k],
                box_size: room.seen[c][i].boxes[t]
                    .width
                    .max(room.seen[c][i].boxes[t].height),
            })
            .collect();
        matcher.assign(room.frame_ns(t), cameras, &observations, &mut ids);
        for (k, id) in ids.iter().enumerate() {
            match id {
                Some(id) => pairs.push((who[k].1, *id)),
                None => unmatched += 1,
            }
        }
        let mut people: Vec<u64> = ids.iter().flatten().copied().collect();
        people.sort_unstable();
        people.dedup();
        for id in people {
            let views: Vec<ViewMaps<'_>> = who
                .iter()
                .zip(&ids)
                .filter(|(_, m)| **m == Some(id))
                .map(|(&(c, i), _)| {
                    let s = &room.seen[c][i];
                    let maps = &s.maps.maps;
                    let n = maps.joints * maps.height * maps.width;
                    ViewMaps {
                        view: c,
                        dt: s.dt[t].unwrap_or(0.0),
                        to_image: s.boxes[t].pixel_map(maps.width, maps.height),
                        height: maps.height,
                        width: maps.width,
                        values: Scores::F32(&maps.values[t * n..(t + 1) * n]),
                    }
                })
                .collect();
            let window = match windows.entry(id) {
                std::collections::btree_map::Entry::Occupied(e) => e.into_mut(),
                std::collections::btree_map::Entry::Vacant(e) => e.insert(FusedWindow::new(
                    estimator,
                    cameras.to_vec(),
                    fusion.clone(),
                )?),
            };
            out.clear();
            window.push(room.frame_ns(t), &views, &mut out)?;
            if let Some(newest) = out.iter().find(|e| e.lag == 0) {
                matcher.set_pose(id, &newest.joints);
            }
            estimates.entry(id).or_default().append(&mut out);
        }
        let known: Vec<u64> = matcher.people().collect();
        windows.retain(|id, _| known.contains(id));
    }
    // IDF1: the one-to-one mapping of true people to ids that agrees most (best pairs
    // first: never more than the optimal, so the figure is conservative).
    let mut counts: BTreeMap<(usize, u64), usize> = BTreeMap::new();
    for &pair in &pairs {
        *counts.entry(pair).or_default() += 1;
    }
    let mut ranked: Vec<((usize, u64), usize)> = counts.into_iter().collect();
    ranked.sort_by_key(|r| std::cmp::Reverse(r.1));
    let mut truth_of = BTreeMap::new();
    let mut agree = 0;
    for ((person, id), n) in ranked {
        if truth_of.contains_key(&id) || truth_of.values().any(|&p| p == person) {
            continue;
        }
        truth_of.insert(id, person);
        agree += n;
    }
    Ok(Matched {
        idf1: agree as f64 / (pairs.len() + unmatched).max(1) as f64,
        ids: estimates.len(),
        observations: pairs.len() + unmatched,
        estimates,
        truth_of,
    })
}

/// Scores the fused estimates of a matched room at `lag`: each id's against the true
/// person it is mapped to (ids mapped to nobody are left out, and counted by IDF1).
pub fn score_matched(room: &Room, skel: &Skeleton, matched: &Matched, lag: usize) -> Errors {
    let p = skel.len();
    let mut errors = Errors::default();
    for (id, estimates) in &matched.estimates {
        let Some(&person) = matched.truth_of.get(id) else {
            continue;
        };
        let seq = &room.people[person];
        for e in estimates.iter().filter(|e| e.lag == lag) {
            let t = room.frame_at(e.stamp_ns);
            errors.add(
                &seq.positions[3 * p * t..3 * p * (t + 1)],
                &e.joints,
                skel.root(),
            );
            errors.monocular += usize::from(e.monocular);
        }
    }
    errors
}

/// What [`score_skeletons`] measured.
#[derive(Debug, Default, Clone, serde::Serialize)]
pub struct SkeletonScores {
    /// Skeletons scored (at the lag asked for).
    pub frames: usize,
    /// Their mean MPJPE against the truth, millimetres.
    pub mpjpe_mm: f64,
    /// Their mean root (pelvis) error, millimetres.
    pub root_mm: f64,
    /// Of them, those one camera alone placed (`views` of one).
    pub monocular: usize,
    /// Skeletons with no true person at their time.
    pub unscored: usize,
}

/// Scores recorded fused skeletons (`posestream fuse`) of lag `lag` against a room's
/// truth (`posestream scenes --rooms --record`, world frame): each against the true
/// person nearest it (mean joint distance) at the truth frame nearest its stamp, in the
/// world frame with no alignment. `root` is the skeleton's root joint.
pub fn score_skeletons(
    truth: &[posestream_msgs::Skeleton3D],
    fused: &[posestream_msgs::Skeleton3D],
    lag: u32,
    root: usize,
) -> SkeletonScores {
    // The truth by stamp.
    let mut at: BTreeMap<i64, Vec<&posestream_msgs::Skeleton3D>> = BTreeMap::new();
    for t in truth {
        at.entry(t.header.stamp.nanos()).or_default().push(t);
    }
    let mut errors = Errors::default();
    let mut unscored = 0;
    for s in fused.iter().filter(|s| s.lag == lag) {
        let stamp = s.header.stamp.nanos();
        let before = at.range(..=stamp).next_back();
        let after = at.range(stamp..).next();
        let nearest = match (before, after) {
            (Some(b), Some(a)) if stamp - b.0 <= a.0 - stamp => Some(b.1),
            (_, Some(a)) => Some(a.1),
            (Some(b), None) => Some(b.1),
            (None, None) => None,
        };
        let person = nearest.and_then(|people| {
            people
                .iter()
                .filter(|t| t.positions.len() == s.positions.len())
                .min_by(|a, b| {
                    mpjpe(&a.positions, &s.positions).total_cmp(&mpjpe(&b.positions, &s.positions))
                })
        });
        match person {
            Some(t) if 3 * root + 3 <= s.positions.len() => {
                errors.add(&t.positions, &s.positions, root);
                errors.monocular += usize::from(s.views.len() == 1);
            }
            _ => unscored += 1,
        }
    }
    SkeletonScores {
        frames: errors.frames,
        mpjpe_mm: errors.mpjpe_mm(),
        root_mm: errors.root_mm(),
        monocular: errors.monocular,
        unscored,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_share_within_one_and_two_std_counts_each_axis() {
        let mut e = Errors::default();
        assert!(e.within_share()[0].is_nan(), "nothing counted yet");
        // Two joints of std 0.1 m: errors per axis 0.05 (within 1), 0.15 (within 2),
        // 0.3 (neither); the second joint's std is NaN (never within).
        let truth = [0.0; 6];
        let joints = [0.05, 0.15, 0.3, 0.0, 0.0, 0.0];
        e.add_with_std(&truth, &joints, &[0.1, f64::NAN], 0);
        assert_eq!((e.within, e.axes), ([1, 2], 6));
        assert_eq!(e.frames, 1);
    }
}
