//! Motions the motion capture lacks, made from a take it has (`synth --motion`): a person
//! who climbs onto a step, jumps, crouches, kneels or sits. The captured arms, head and
//! torso keep moving as captured; what changes is the body's height over the floor and
//! the legs, bent by two-bone inverse kinematics (thigh and shin keep their captured
//! lengths, the knee bends toward where the person faces).
//!
//! These are made by hand because no take of the collection does them; they are meant
//! for where people stand (`posestream scenes --distances`), not for learning poses. What
//! they leave out: no take-off lean, a platform or chair that hides nothing, the feet's
//! contact with a step as sudden as the step's 0.4 s rise.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::MappedSequence;
use posestream_math::skeleton::Skeleton;

/// Gravity, metres per second squared.
const G: f64 = 9.81;
/// A kneeling knee's centre above the floor, metres (the kneecap's radius).
const KNEE_ON_FLOOR: f64 = 0.06;
/// Seconds to climb a step, or go down to kneel or sit (and back up).
const RISE_S: f64 = 0.4;
const SETTLE_S: f64 = 1.0;
/// A jump's crouch before take-off and after landing: metres and seconds.
const JUMP_CROUCH: (f64, f64) = (0.15, 0.3);

/// A motion made from a take.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Motion {
    /// As captured.
    Captured,
    /// Onto a step at `up` seconds, off it at `down` (never when `None`): the whole
    /// body lifted.
    Step {
        /// The step's height, metres.
        height: f64,
        /// Seconds when the climb starts.
        up: f64,
        /// Seconds when the way down starts.
        down: Option<f64>,
    },
    /// Jumps from 1 s on, each with a crouch before take-off and after landing.
    Jump {
        /// The feet's lift at the top, metres.
        height: f64,
        /// Seconds from one take-off to the next.
        every: f64,
    },
    /// Squats, the feet where they were captured.
    Crouch {
        /// How far the pelvis goes down, metres.
        depth: f64,
        /// Seconds from one squat to the next.
        every: f64,
    },
    /// Kneels on both knees (thighs upright, shins flat behind), then stands again.
    Kneel {
        /// Seconds when the way down starts (it takes 1 s).
        at: f64,
        /// Seconds down.
        hold: f64,
    },
    /// Sits on a chair (thighs level, shins upright, feet on the floor), then stands
    /// again.
    Sit {
        /// Seconds when the way down starts (it takes 1 s).
        at: f64,
        /// Seconds seated.
        hold: f64,
    },
}

impl Motion {
    /// The motion's short name (`captured`, `step`, `jump`, ...).
    pub fn name(&self) -> &'static str {
        match self {
            Motion::Captured => "captured",
            Motion::Step { .. } => "step",
            Motion::Jump { .. } => "jump",
            Motion::Crouch { .. } => "crouch",
            Motion::Kneel { .. } => "kneel",
            Motion::Sit { .. } => "sit",
        }
    }

    /// Parses `captured`, `step:HEIGHT,UP[,DOWN]`, `jump:HEIGHT,EVERY`,
    /// `crouch:DEPTH,EVERY`, `kneel:AT,HOLD` or `sit:AT,HOLD` (metres, seconds).
    pub fn parse(text: &str) -> Result<Self, String> {
        let (kind, args) = text.split_once(':').unwrap_or((text, ""));
        let v: Vec<f64> = if args.is_empty() {
            Vec::new()
        } else {
            args.split(',')
                .map(|x| x.trim().parse::<f64>().map_err(|e| format!("{x:?}: {e}")))
                .collect::<Result<_, _>>()?
        };
        if v.iter().any(|x| !x.is_finite() || *x < 0.0 || *x > 1e4) {
            return Err(format!("{text:?}: every number must be in [0, 1e4]"));
        }
        let positive = |x: f64, what: &str| {
            if x > 0.0 {
                Ok(x)
            } else {
                Err(format!("{text:?}: {what} must be > 0"))
            }
        };
        let motion = match (kind, &v[..]) {
            ("captured", []) => Motion::Captured,
            ("step", &[height, _, ..]) if height > 2.0 => {
                return Err(format!("{text:?}: a step of {height} m: at most 2 m"));
            }
            ("step", &[height, up]) => Motion::Step {
                height,
                up,
                down: None,
            },
            ("step", &[height, up, down]) if down >= up + RISE_S => Motion::Step {
                height,
                up,
                down: Some(down),
            },
            ("jump", &[height, every]) if height <= 1.0 => Motion::Jump {
                height: positive(height, "the height")?,
                every,
            },
            ("crouch", &[depth, every]) if every >= 0.5 => Motion::Crouch { depth, every },
            ("kneel", &[at, hold]) => Motion::Kneel { at, hold },
            ("sit", &[at, hold]) => Motion::Sit { at, hold },
            _ => {
                return Err(format!(
                    "{text:?}: expected captured, step:HEIGHT,UP[,DOWN] (DOWN at least \
                     {RISE_S} s after UP), jump:HEIGHT,EVERY (HEIGHT at most 1 m), \
                     crouch:DEPTH,EVERY (EVERY at least 0.5 s), kneel:AT,HOLD or sit:AT,HOLD"
                ));
            }
        };
        if let Motion::Jump { height, every } = motion
            && every < flight(height) + 2.0 * JUMP_CROUCH.1
        {
            return Err(format!(
                "{text:?}: a {height} m jump needs {:.2} s between jumps at least",
                flight(height) + 2.0 * JUMP_CROUCH.1
            ));
        }
        Ok(motion)
    }
}

/// Seconds in the air of a jump whose feet rise `height` metres.
fn flight(height: f64) -> f64 {
    2.0 * (2.0 * height / G).sqrt()
}

/// 0 before `t = 0`, 1 after `t = 1`, smooth between.
fn ease(t: f64) -> f64 {
    let t = t.clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// How far a kneel or sit has gone at `s` seconds: 0 standing, 1 down.
fn settled(s: f64, at: f64, hold: f64) -> f64 {
    ease((s - at) / SETTLE_S) * (1.0 - ease((s - at - SETTLE_S - hold) / SETTLE_S))
}

/// The legs of a layout: `(hip, knee, ankle)` left and right.
fn legs(skeleton: &Skeleton) -> Result<[(usize, usize, usize); 2], String> {
    let j = |name: &str| {
        skeleton
            .index_of(name)
            .ok_or_else(|| format!("the layout has no joint {name:?} to bend the legs"))
    };
    Ok([
        (j("l-hip")?, j("l-knee")?, j("l-ankle")?),
        (j("r-hip")?, j("r-knee")?, j("r-ankle")?),
    ])
}

/// The knee of a leg from `hip` to `ankle` with bones `thigh` and `shin`, bent toward
/// `toward` (horizontal): the ankle pulled in when the leg cannot reach it.
fn bend(
    hip: Vector3<f64>,
    ankle: Vector3<f64>,
    thigh: f64,
    shin: f64,
    toward: Vector3<f64>,
) -> (Vector3<f64>, Vector3<f64>) {
    let reach = ankle - hip;
    let d = reach.norm();
    let Some(u) = reach.try_normalize(1e-9) else {
        return (hip + Vector3::new(0.0, 0.0, -thigh), ankle);
    };
    let d_ok = d.clamp((thigh - shin).abs() + 1e-6, thigh + shin - 1e-6);
    let ankle = hip + u * d_ok;
    let along = (thigh * thigh - shin * shin + d_ok * d_ok) / (2.0 * d_ok);
    let across = (thigh * thigh - along * along).max(0.0).sqrt();
    let side = (toward - u * toward.dot(&u))
        .try_normalize(1e-9)
        .unwrap_or_else(|| u.cross(&Vector3::z()).normalize());
    (hip + u * along + side * across, ankle)
}

/// `seq` played forward, then backward, and so on, to `frames` frames: a longer take
/// with no jump in place or pose (the motion runs backward from each end: a walker walks
/// back the way they came, facing on). `frames` 0 or a take of one frame: unchanged.
pub fn ping_pong(seq: &MappedSequence, frames: usize) -> MappedSequence {
    let n = seq.frames;
    if frames == 0 || n < 2 {
        return seq.clone();
    }
    let row = 3 * seq.joints;
    let period = 2 * (n - 1);
    let mut positions = Vec::with_capacity(frames * row);
    for t in 0..frames {
        let u = t % period;
        let i = if u < n { u } else { period - u };
        positions.extend_from_slice(&seq.positions[i * row..(i + 1) * row]);
    }
    MappedSequence {
        frames,
        positions,
        ..seq.clone()
    }
}

/// `seq` moved as `motion` says (`Captured`: unchanged).
pub fn apply(
    seq: &MappedSequence,
    skeleton: &Skeleton,
    motion: &Motion,
) -> Result<MappedSequence, String> {
    let p = skeleton.len();
    if seq.joints != p {
        return Err("the sequence does not match the layout".into());
    }
    if *motion == Motion::Captured {
        return Ok(seq.clone());
    }
    let legs = legs(skeleton)?;
    let mut out = seq.clone();
    // Where the body faces: the previous frame's where a frame does not tell.
    let mut facing = Vector3::x();
    for t in 0..seq.frames {
        let s = t as f64 * seq.frame_time;
        let frame = &mut out.positions[3 * p * t..3 * p * (t + 1)];
        let at = |f: &[f64], j: usize| Vector3::from_column_slice(&f[3 * j..3 * j + 3]);
        facing = skeleton.facing(frame).unwrap_or(facing);
        let hip_z = 0.5 * (at(frame, legs[0].0).z + at(frame, legs[1].0).z);
        // The thigh and shin of each leg as captured in this frame.
        let bones = legs.map(|(h, k, a)| {
            (
                (at(frame, k) - at(frame, h)).norm(),
                (at(frame, a) - at(frame, k)).norm(),
            )
        });
        let (thigh, shin) = (
            0.5 * (bones[0].0 + bones[1].0),
            0.5 * (bones[0].1 + bones[1].1),
        );
        // How far the body goes down (positive) or up, and where each ankle goes.
        let (lift, ankles): (f64, [Option<Vector3<f64>>; 2]) = match *motion {
            Motion::Captured => (0.0, [None; 2]),
            Motion::Step { height, up, down } => {
                let down = down.map_or(1.0, |down| 1.0 - ease((s - down) / RISE_S));
                let h = height * ease((s - up) / RISE_S) * down;
                (h, [None; 2])
            }
            Motion::Jump { height, every } => {
                let (crouch, crouch_s) = JUMP_CROUCH;
                let air = flight(height);
                // Take-off at 1 s + k every; the crouch before it and after landing.
                let phase = (s - 1.0 + crouch_s).rem_euclid(every) - crouch_s;
                let h = if s < 1.0 - crouch_s {
                    0.0
                } else if phase < 0.0 {
                    -crouch * (std::f64::consts::PI * (phase + crouch_s) / crouch_s).sin()
                } else if phase < air {
                    let v0 = (2.0 * G * height).sqrt();
                    v0 * phase - 0.5 * G * phase * phase
                } else if phase < air + crouch_s {
                    -crouch * (std::f64::consts::PI * (phase - air) / crouch_s).sin()
                } else {
                    0.0
                };
                if h >= 0.0 {
                    (h, [None; 2])
                } else {
                    // Crouching on the floor: the feet stay, the legs bend.
                    (h, legs.map(|(_, _, a)| Some(at(frame, a))))
                }
            }
            Motion::Crouch { depth, every } => {
                // The legs must reach the feet: the hips stay above them by the bones'
                // difference and 5 cm.
                let ankle_z = at(frame, legs[0].2).z.max(at(frame, legs[1].2).z);
                if hip_z - depth < ankle_z + (thigh - shin).abs() + 0.05 {
                    return Err(format!(
                        "crouch: {depth} m is deeper than the legs bend (the hips are {:.2} m \
                         above the feet at {s:.2} s)",
                        hip_z - ankle_z
                    ));
                }
                let d = 0.5 * depth * (1.0 - (std::f64::consts::TAU * s / every).cos());
                (-d, legs.map(|(_, _, a)| Some(at(frame, a))))
            }
            Motion::Kneel { at: start, hold } => {
                let w = settled(s, start, hold);
                // Thighs upright over knees on the floor, shins flat behind.
                let down = (hip_z - (KNEE_ON_FLOOR + thigh)).max(0.0) * w;
                // Each ankle as high as captured (the foot's own height over the floor).
                let ankles = legs.map(|(h, _, a)| {
                    let (hip, ankle) = (at(frame, h), at(frame, a));
                    let back = (shin * shin - (ankle.z - KNEE_ON_FLOOR).powi(2))
                        .max(0.0)
                        .sqrt();
                    let kneel = Vector3::new(hip.x, hip.y, ankle.z) - facing * back;
                    Some(ankle.lerp(&kneel, w))
                });
                (-down, ankles)
            }
            Motion::Sit { at: start, hold } => {
                let w = settled(s, start, hold);
                // Hips at a seat: thighs level, shins upright to the feet, as high as
                // captured.
                let ankle_z = 0.5 * (at(frame, legs[0].2).z + at(frame, legs[1].2).z);
                let down = (hip_z - (ankle_z + shin)).max(0.0) * w;
                let ankles = legs.map(|(h, _, a)| {
                    let (hip, ankle) = (at(frame, h), at(frame, a));
                    let sit = Vector3::new(hip.x, hip.y, ankle.z) + facing * thigh;
                    Some(ankle.lerp(&sit, w))
                });
                (-down, ankles)
            }
        };
        let lower: [bool; 2] = [ankles[0].is_some(), ankles[1].is_some()];
        for j in 0..p {
            let own_leg = legs
                .iter()
                .zip(lower)
                .any(|(&(_, k, a), bent)| bent && (j == k || j == a));
            if !own_leg {
                frame[3 * j + 2] += lift;
            }
        }
        for (((h, k, a), ankle), (thigh, shin)) in legs.into_iter().zip(ankles).zip(bones) {
            let Some(ankle) = ankle else { continue };
            let (knee, ankle) = bend(at(frame, h), ankle, thigh, shin, facing);
            frame[3 * k..3 * k + 3].copy_from_slice(knee.as_slice());
            frame[3 * a..3 * a + 3].copy_from_slice(ankle.as_slice());
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A person standing still, facing +x: the default 17-joint layout, hips 0.9 m up.
    fn standing(frames: usize) -> (MappedSequence, Skeleton) {
        let skeleton = posestream_math::skeleton::default_layout();
        let p = skeleton.len();
        let mut frame = vec![0.0; 3 * p];
        let mut put = |name: &str, v: [f64; 3]| {
            let j = skeleton.index_of(name).unwrap();
            frame[3 * j..3 * j + 3].copy_from_slice(&v);
        };
        // Left is +y for a person facing +x.
        put("pelvis", [0.0, 0.0, 0.9]);
        put("l-hip", [0.0, 0.1, 0.9]);
        put("l-knee", [0.02, 0.1, 0.5]);
        put("l-ankle", [0.0, 0.1, 0.1]);
        put("r-hip", [0.0, -0.1, 0.9]);
        put("r-knee", [0.02, -0.1, 0.5]);
        put("r-ankle", [0.0, -0.1, 0.1]);
        put("spine", [0.0, 0.0, 1.1]);
        put("thorax", [0.0, 0.0, 1.4]);
        put("neck", [0.0, 0.0, 1.5]);
        put("head-top", [0.0, 0.0, 1.7]);
        put("l-shoulder", [0.0, 0.2, 1.4]);
        put("l-elbow", [0.0, 0.25, 1.1]);
        put("l-wrist", [0.0, 0.25, 0.85]);
        put("r-shoulder", [0.0, -0.2, 1.4]);
        put("r-elbow", [0.0, -0.25, 1.1]);
        put("r-wrist", [0.0, -0.25, 0.85]);
        let seq = MappedSequence {
            joints: p,
            frames,
            frame_time: 1.0 / 30.0,
            positions: frame.repeat(frames),
        };
        (seq, skeleton)
    }

    fn joint(seq: &MappedSequence, t: usize, j: usize) -> Vector3<f64> {
        let p = seq.joints;
        Vector3::from_column_slice(&seq.positions[3 * (p * t + j)..][..3])
    }

    /// Every bone keeps its captured length in every frame.
    fn bones_kept(before: &MappedSequence, after: &MappedSequence, skeleton: &Skeleton) {
        for t in 0..after.frames {
            for (a, b) in skeleton.bones() {
                let l0 = (joint(before, t, a) - joint(before, t, b)).norm();
                let l1 = (joint(after, t, a) - joint(after, t, b)).norm();
                assert!(
                    (l0 - l1).abs() < 1e-6,
                    "frame {t} bone {a}-{b}: {l0} -> {l1}"
                );
            }
        }
    }

    #[test]
    fn ping_pong_runs_the_take_back_and_forth_without_a_jump() {
        let seq = MappedSequence {
            joints: 1,
            frames: 3,
            frame_time: 0.1,
            positions: vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 2.0, 0.0, 0.0],
        };
        let long = ping_pong(&seq, 8);
        let x: Vec<f64> = long.positions.chunks(3).map(|p| p[0]).collect();
        assert_eq!(x, [0.0, 1.0, 2.0, 1.0, 0.0, 1.0, 2.0, 1.0]);
        assert_eq!((long.frames, long.joints, long.frame_time), (8, 1, 0.1));
        // Shorter than the take: its first frames; nothing to loop: unchanged.
        assert_eq!(ping_pong(&seq, 2).positions, seq.positions[..6]);
        assert_eq!(ping_pong(&seq, 0), seq);
    }

    #[test]
    fn parses_each_motion_and_refuses_the_rest() {
        assert_eq!(Motion::parse("captured"), Ok(Motion::Captured));
        assert_eq!(
            Motion::parse("step:0.4,2"),
            Ok(Motion::Step {
                height: 0.4,
                up: 2.0,
                down: None
            })
        );
        assert!(matches!(
            Motion::parse("step:0.4,2,4"),
            Ok(Motion::Step { .. })
        ));
        assert!(matches!(Motion::parse("sit:1,2"), Ok(Motion::Sit { .. })));
        for bad in [
            "",
            "fly:1",
            "step:0.4",
            "step:0.4,2,2.1",
            "step:1e4,1",
            "jump:0.4,0.5",
            "jump:0,2",
            "jump:1.5,9",
            "crouch:0.3,0",
            "crouch:0.3,1e-320",
            "kneel:1,-2",
            "sit:1,NaN",
            "sit:1,inf",
            "captured:1",
        ] {
            assert!(Motion::parse(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn a_step_lifts_the_whole_body_and_a_jump_follows_gravity() {
        let (seq, skel) = standing(150);
        let stepped = apply(&seq, &skel, &Motion::parse("step:0.4,1,3").unwrap()).unwrap();
        let ankle = skel.index_of("l-ankle").unwrap();
        assert!((joint(&stepped, 0, ankle).z - 0.1).abs() < 1e-12);
        assert!((joint(&stepped, 60, ankle).z - 0.5).abs() < 1e-12);
        assert!((joint(&stepped, 120, ankle).z - 0.1).abs() < 1e-12);
        bones_kept(&seq, &stepped, &skel);

        let jumped = apply(&seq, &skel, &Motion::parse("jump:0.3,2").unwrap()).unwrap();
        bones_kept(&seq, &jumped, &skel);
        let heights: Vec<f64> = (0..150).map(|t| joint(&jumped, t, ankle).z - 0.1).collect();
        let top = heights.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        // The top of the flight at 1 s + half of it, sampled at 30 frames/s.
        assert!((top - 0.3).abs() < 0.01, "{top}");
        // Standing before the first crouch; feet never below where they were.
        assert!(heights[..20].iter().all(|h| h.abs() < 1e-12));
        assert!(heights.iter().all(|h| *h > -1e-9), "{heights:?}");
        // The crouch before take-off lowers the pelvis, not the feet.
        let pelvis = skel.index_of("pelvis").unwrap();
        assert!(joint(&jumped, 27, pelvis).z < 0.85);
    }

    #[test]
    fn crouching_kneeling_and_sitting_keep_the_bones_and_put_the_body_down() {
        let (seq, skel) = standing(210);
        let pelvis = skel.index_of("pelvis").unwrap();
        let (lk, la) = (
            skel.index_of("l-knee").unwrap(),
            skel.index_of("l-ankle").unwrap(),
        );
        let crouched = apply(&seq, &skel, &Motion::parse("crouch:0.4,2").unwrap()).unwrap();
        bones_kept(&seq, &crouched, &skel);
        // Bottom of the squat at 1 s: pelvis 0.4 m down, feet where they were, knee
        // forward of them.
        assert!((joint(&crouched, 30, pelvis).z - 0.5).abs() < 1e-9);
        assert!((joint(&crouched, 30, la) - joint(&seq, 30, la)).norm() < 1e-9);
        assert!(joint(&crouched, 30, lk).x > 0.2);

        // Deeper than the legs bend: refused.
        assert!(apply(&seq, &skel, &Motion::parse("crouch:0.8,2").unwrap()).is_err());

        let knelt = apply(&seq, &skel, &Motion::parse("kneel:1,2").unwrap()).unwrap();
        bones_kept(&seq, &knelt, &skel);
        // Down from 2 s to 4 s: knees on the floor, shins flat behind.
        for t in [70, 100] {
            assert!((joint(&knelt, t, lk).z - KNEE_ON_FLOOR).abs() < 1e-6);
            assert!((joint(&knelt, t, la).z - 0.1).abs() < 1e-6);
            assert!(joint(&knelt, t, la).x < -0.3);
        }
        assert!((joint(&knelt, 200, pelvis).z - 0.9).abs() < 1e-9);

        let sat = apply(&seq, &skel, &Motion::parse("sit:1,2").unwrap()).unwrap();
        bones_kept(&seq, &sat, &skel);
        // Seated: knees level with the hips, ankles on the floor under the knees.
        let hip = skel.index_of("l-hip").unwrap();
        assert!((joint(&sat, 90, lk).z - joint(&sat, 90, hip).z).abs() < 1e-6);
        assert!((joint(&sat, 90, la).z - 0.1).abs() < 1e-6);
        assert!((joint(&sat, 90, la).x - joint(&sat, 90, lk).x).abs() < 1e-6);
    }
}
