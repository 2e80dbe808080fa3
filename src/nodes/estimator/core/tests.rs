//! The decision core, tested once for both drivers: every input with a fake clock (the
//! times are given, as a driver gives them).

use std::path::Path;

use super::*;
use crate::msgs::sensor::CameraInfo;
use crate::msgs::{HeatMaps, SkeletonState, Units};
use crate::nodes::publish::{Plan, Planner, Publication};
use crate::nodes::{EstimatorNode, ServiceConfig};
use crate::transport::{Received, TransportError};

const FRAME_NS: u64 = 33_333_333;

fn node() -> EstimatorNode {
    let config =
        ServiceConfig::load(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/default.toml"))
            .expect("config");
    EstimatorNode::from_service_config(&config).expect("node")
}

/// The shipped byebye recording's heat maps (one person, track 1).
fn frames() -> Vec<HeatMaps> {
    crate::recording::read_topic(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("recordings/byebye.mcap"),
        "/posestream/heatmaps",
    )
    .expect("reads")
    .into_iter()
    .map(|(_, m)| m)
    .collect()
}

/// The skeletons a plan sends, in order.
fn skeletons(plan: &Plan) -> Vec<&crate::msgs::Skeleton3D> {
    plan.order
        .iter()
        .filter_map(|(p, _)| match p {
            Publication::Skeleton(i) => plan.skeletons.get(*i).map(|s| &**s),
            _ => None,
        })
        .collect()
}

/// Frame `i` of `frames` at time `i` frames on the clock (its stamp the same).
fn feed(core: &mut EstimatorCore<'_>, frames: &[HeatMaps], n: usize, plan: &mut Plan) {
    for (i, m) in frames.iter().take(n).enumerate() {
        let now = i as u64 * FRAME_NS;
        core.step(Input::Frame(&m.view(), now), now, plan);
    }
}

#[test]
fn a_track_without_a_frame_for_the_gap_on_the_clock_ends_with_its_estimates_owed() {
    let frames = frames();
    let mut node = node();
    let gap_ns = (node.settings().max_gap_seconds * 1e9) as u64;
    let lag = node.settings().lag;
    let mut planner = Planner::new(node.bones(), false);
    let mut core = EstimatorCore::new(&mut node, &mut planner);
    let mut plan = Plan::default();
    feed(&mut core, &frames, 20, &mut plan);
    let last = 19 * FRAME_NS;
    core.recycle(&mut plan);
    // Quiet within the gap: nothing ends.
    core.step(Input::Quiet, last + gap_ns / 2, &mut plan);
    assert!(skeletons(&plan).is_empty());
    // Quiet past it: the track ends, its owed (refined) estimates out, the last lost.
    core.step(Input::Quiet, last + gap_ns + 1, &mut plan);
    let ended = skeletons(&plan);
    assert!(
        !ended.is_empty() && ended.len() <= 2 * (lag + 1),
        "the estimates the lag still owed: {}",
        ended.len()
    );
    assert!(ended.iter().all(|s| s.state == SkeletonState::Lost as u8));
    core.recycle(&mut plan);
    // Nothing more ends later.
    core.step(Input::Quiet, last + 10 * gap_ns, &mut plan);
    assert!(skeletons(&plan).is_empty());
}

#[test]
fn the_clock_of_a_replay_is_its_stamps_and_a_quiet_input_moves_it_not() {
    let frames = frames();
    let mut clock = Clock::of(false);
    let view = frames[0].view();
    assert_eq!(clock.now(&Input::Frame(&view, 5 * FRAME_NS)), 5 * FRAME_NS);
    assert_eq!(clock.now(&Input::Quiet), 5 * FRAME_NS);
    // A stamp from before (another pass's) does not take it back.
    assert_eq!(clock.now(&Input::Frame(&view, FRAME_NS)), 5 * FRAME_NS);
    // Live: wall time, moving on its own.
    let mut wall = Clock::of(true);
    let a = wall.now(&Input::Quiet);
    std::thread::sleep(std::time::Duration::from_millis(2));
    assert!(wall.now(&Input::Quiet) > a);
}

#[test]
fn a_calibration_is_taken_before_the_frames_after_it() {
    let frames = frames();
    let mut node = node();
    let mut planner = Planner::new(node.bones(), false);
    let mut core = EstimatorCore::new(&mut node, &mut planner);
    let mut plan = Plan::default();
    feed(&mut core, &frames, 1, &mut plan);
    assert!(
        skeletons(&plan)
            .iter()
            .all(|s| s.units == Units::Dictionary as u8),
        "no camera known yet"
    );
    core.recycle(&mut plan);
    let info = CameraInfo {
        width: 1920,
        height: 1080,
        k: [1000.0, 0.0, 960.0, 0.0, 1000.0, 540.0, 0.0, 0.0, 1.0],
        ..CameraInfo::default()
    };
    core.step(Input::Calibration(&info), FRAME_NS, &mut plan);
    let view = frames[1].view();
    core.step(Input::Frame(&view, FRAME_NS), FRAME_NS, &mut plan);
    let after = skeletons(&plan);
    assert!(!after.is_empty());
    assert!(after.iter().all(|s| s.units == Units::Metres as u8));
}

#[test]
fn a_quiet_input_completes_the_image_and_its_arrays_go() {
    let frames = frames();
    let mut node = node();
    let mut planner = Planner::new(node.bones(), false).with_arrays(true);
    let mut core = EstimatorCore::new(&mut node, &mut planner);
    let mut plan = Plan::default();
    feed(&mut core, &frames, 3, &mut plan);
    core.recycle(&mut plan);
    // The third image's arrays wait for its end: the next image, or a quiet input.
    core.step(Input::Quiet, 3 * FRAME_NS, &mut plan);
    let arrays = plan
        .order
        .iter()
        .filter(|(p, _)| matches!(p, Publication::Array(_)))
        .count();
    assert!(arrays >= 1, "{:?}", plan.order);
}

#[test]
fn what_a_source_gives_is_counted_or_ends_the_loop() {
    let mut node = node();
    let mut planner = Planner::new(node.bones(), false);
    let mut core = EstimatorCore::new(&mut node, &mut planner);
    let mut plan = Plan::default();
    let refused = TransportError::BeyondLimits {
        transport: "test",
        topic: "/t".into(),
        reason: "too large".into(),
    };
    assert_eq!(core.received(Err(refused), 0, &mut plan), Flow::Continue);
    assert_eq!(
        core.received(Ok(Received::Idle), 0, &mut plan),
        Flow::Continue
    );
    assert_eq!(
        core.received(Ok(Received::Message((), 0)), 0, &mut plan),
        Flow::Continue
    );
    assert_eq!(core.received(Ok(Received::Closed), 0, &mut plan), Flow::End);
    let broken = TransportError::Broken {
        transport: "test",
        topic: "/t".into(),
        reason: "cut".into(),
    };
    assert_eq!(core.received(Err(broken), 0, &mut plan), Flow::End);
    let report = core.report(&crate::nodes::publish::Sinks::default());
    assert_eq!(report.refused.of("beyond-limits"), 1);
    assert!(report.input_error.is_some_and(|e| e.contains("cut")));
}

#[test]
fn refused_messages_hold_no_idle_track_open() {
    let frames = frames();
    let mut node = node();
    let gap_ns = (node.settings().max_gap_seconds * 1e9) as u64;
    let mut planner = Planner::new(node.bones(), false);
    let mut core = EstimatorCore::new(&mut node, &mut planner);
    let mut plan = Plan::default();
    feed(&mut core, &frames, 20, &mut plan);
    core.recycle(&mut plan);
    let refused = TransportError::Malformed {
        transport: "test",
        topic: "/t".into(),
        reason: "bad".into(),
    };
    // A flood of refused messages, every 10 ms past the last frame taken.
    let last = 19 * FRAME_NS;
    let mut ended = 0;
    for k in 1..=200 {
        core.step(Input::Refused(&refused), last + k * 10_000_000, &mut plan);
        ended += skeletons(&plan).len();
        core.recycle(&mut plan);
        if k * 10_000_000 <= gap_ns {
            assert_eq!(ended, 0, "ended before the gap");
        }
    }
    assert!(
        ended > 0,
        "the track outlived the gap under a flood of refusals"
    );
}

#[test]
fn a_replayed_frame_after_a_gap_ends_the_tracks_before_it_is_taken() {
    let frames = frames();
    let mut node = node();
    let gap_ns = (node.settings().max_gap_seconds * 1e9) as u64;
    let mut planner = Planner::new(node.bones(), false);
    let mut core = EstimatorCore::new(&mut node, &mut planner);
    let mut plan = Plan::default();
    feed(&mut core, &frames, 20, &mut plan);
    core.recycle(&mut plan);
    // The stamps jump over a quiet spell longer than the gap (a replay's clock).
    let later = 19 * FRAME_NS + gap_ns + FRAME_NS;
    let view = frames[20].view();
    core.step(Input::Frame(&view, later), later, &mut plan);
    let out = skeletons(&plan);
    let lost = out
        .iter()
        .filter(|s| s.state == SkeletonState::Lost as u8)
        .count();
    assert!(lost > 0, "the old track's owed estimates, lost");
    // The old track's estimates come before the new frame's.
    let first_new = out
        .iter()
        .position(|s| s.state != SkeletonState::Lost as u8);
    assert!(first_new.is_none_or(|i| i >= lost));
}
