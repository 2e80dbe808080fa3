//! One person's track in the estimator node ([`Track`]): its window and what is
//! remembered of its frames until their last estimates are out ([`FrameInfo`]); the
//! skeleton messages written of its estimates ([`release`]).

use std::collections::VecDeque;

use super::metres::{Metric, learn_floor, metric_pose};
use crate::floor::BodyScale;
use crate::metres::MetricPose;
use crate::msgs::{self, Skeleton3D, Time, Units};
use crate::nodes::errors::{NodeError, Refusals};
use crate::streaming::{Estimates, FrameEstimate, TrackState, WindowEstimator};
use posestream_base::PixelMap;

/// What the estimator node needs to remember of a frame until its last estimate is out.
#[derive(Debug, Clone)]
pub(super) struct FrameInfo {
    pub(super) sequence: u64,
    pub(super) to_image: PixelMap,
    /// The heat maps' size (columns, rows).
    pub(super) map_size: (f64, f64),
    pub(super) frame_id: String,
    /// The heat maps' `frames_since_look` (0: a look in this image).
    pub(super) frames_since_look: u32,
}

/// One person's track in the estimator node: its window and what the node remembers of
/// its frames until their last estimates are out.
pub(super) struct Track {
    pub(super) id: u32,
    pub(super) window: WindowEstimator,
    pub(super) frames: VecDeque<FrameInfo>,
    /// Capture time of the newest frame the window took.
    pub(super) last_stamp_ns: i64,
    /// Its frame number.
    pub(super) last_sequence: u64,
    /// When it took it, in frames the node took (the least recent one makes room).
    pub(super) last_taken: u64,
    /// A duplicate of its id in one image was warned about.
    pub(super) duplicate_warned: bool,
    /// The person's size from their feet on the floor (with a floor).
    pub(super) scale: BodyScale,
}

/// Frames a track remembers at most: those an estimate can still come for (the window
/// and the lag), and one more.
pub(super) fn frames_kept(window: &WindowEstimator) -> usize {
    let settings = window.settings();
    settings.size + settings.lag + 1
}

/// Turns a track's estimates into messages (written over `spare` ones); forgets frames
/// no estimate can need any more. An estimate with non-finite values is counted, not
/// published.
#[allow(
    clippy::too_many_arguments,
    reason = "disjoint borrows of the node's fields, so that a track is borrowed beside them"
)]
pub(super) fn release(
    track: &mut Track,
    estimates: &Estimates,
    joint_names: &[String],
    mut metric: Option<&mut Metric>,
    spare: &mut Vec<Skeleton3D>,
    refused: &mut Refusals,
    out: &mut Vec<Skeleton3D>,
) {
    let keep = frames_kept(&track.window);
    for e in estimates.iter() {
        let Some(info) = track.frames.iter().rev().find(|f| f.sequence == e.sequence) else {
            continue;
        };
        let metres = match metric.as_deref_mut() {
            Some(m) => match metric_pose(
                m,
                e,
                &info.to_image,
                info.map_size,
                &mut track.scale,
                info.frames_since_look == 0,
            ) {
                Ok(()) => Some(&m.pose),
                Err(error) => {
                    m.failures += 1;
                    tracing::debug!(
                        "frame {}: no metric pose ({error}); published in dictionary units",
                        e.sequence
                    );
                    None
                }
            },
            None => None,
        };
        let mut message = spare.pop().unwrap_or_default();
        write_skeleton(&mut message, e, info, joint_names, track.id, metres);
        let placed = metres.is_some();
        if placed && let Some(m) = metric.as_deref_mut() {
            learn_floor(m, track.id, e.lag);
        }
        if message.is_finite() {
            out.push(message);
        } else {
            spare.push(message);
            let e = NodeError::NonFiniteOutput {
                sequence: e.sequence,
            };
            refused.note(e.kind(), &e);
        }
    }
    while track.frames.len() > keep {
        track.frames.pop_front();
    }
}

/// The message of one estimate, written over `m` (its buffers reused): in metres when
/// `metres` is the estimate's metric pose, in dictionary units otherwise.
pub(super) fn write_skeleton(
    m: &mut Skeleton3D,
    e: &FrameEstimate,
    info: &FrameInfo,
    joint_names: &[String],
    track_id: u32,
    metres: Option<&MetricPose>,
) {
    let map = info.to_image;
    let to_image = |xy: &[f64], out: &mut Vec<f64>| {
        out.clear();
        out.extend(xy.chunks_exact(2).flat_map(|p| map.apply(p[0], p[1])));
    };
    m.header.stamp = Time::from_nanos(e.stamp_ns);
    m.header.frame_id.clone_from(&info.frame_id);
    m.sequence = e.sequence;
    m.track_id = track_id;
    // Element by element, so that each name's buffer is reused.
    m.joint_names.truncate(joint_names.len());
    let reused = m.joint_names.len();
    for (d, s) in m.joint_names.iter_mut().zip(joint_names) {
        d.clone_from(s);
    }
    m.joint_names.extend_from_slice(&joint_names[reused..]);
    if let Some(metres) = metres {
        m.units = Units::Metres as u8;
        m.metric_source = match metres.source {
            crate::metres::PlacedBy::Size => msgs::MetricSource::Size,
            crate::metres::PlacedBy::Floor => msgs::MetricSource::Floor,
        } as u8;
        m.positions.clone_from(&metres.positions);
        m.position_std.clone_from(&metres.position_std);
        m.keypoints.clone_from(&metres.keypoints);
        m.keypoint_std.clone_from(&metres.keypoint_std);
        m.projected.clone_from(&metres.projected);
        m.mean_bone_length = metres.size;
    } else {
        m.units = Units::Dictionary as u8;
        m.metric_source = msgs::MetricSource::None as u8;
        m.mean_bone_length = 0.0;
        m.positions.clone_from(&e.pose);
        m.position_std.clone_from(&e.pose_std);
        to_image(&e.keypoints, &mut m.keypoints);
        m.keypoint_std.clear();
        m.keypoint_std
            .extend(e.keypoint_std.iter().map(|s| s * map.mean_scale()));
        to_image(&e.projected, &mut m.projected);
    }
    m.lag = e.lag as u32;
    m.frames_since_look = info.frames_since_look;
    m.state = match e.state {
        TrackState::Initialising => msgs::SkeletonState::Initialising,
        TrackState::Tracking => msgs::SkeletonState::Tracking,
        TrackState::Lost => msgs::SkeletonState::Lost,
    } as u8;
}
