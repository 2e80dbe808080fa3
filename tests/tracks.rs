//! Several people at once in the estimator node: a window per track, tracks that end
//! when their person leaves, a bound on how many run at once.

mod common;

use common::{recording, root};
use posestream::msgs::{HeatMaps, Skeleton3D, SkeletonState};
use posestream::nodes::{EstimatorNode, ServiceConfig};

fn config() -> ServiceConfig {
    let mut c = ServiceConfig::load(root().join("config/default.toml")).expect("config");
    c.outputs.ros2 = false;
    c
}

fn node() -> EstimatorNode {
    EstimatorNode::from_config(&config().estimator).expect("node")
}

fn frames(name: &str) -> Vec<HeatMaps> {
    common::messages(&recording(name), "/posestream/heatmaps")
}

/// Two people in the same images: byebye's frames as track `a`, kick's as track `b`
/// with byebye's sequence numbers and capture times, `n` images.
fn two_people(a: u32, b: u32, n: usize) -> (Vec<HeatMaps>, Vec<HeatMaps>) {
    let first = frames("byebye.mcap");
    let second = frames("kick.mcap");
    assert!(first.len() >= n && second.len() >= n);
    let mut one = Vec::new();
    let mut two = Vec::new();
    for (x, y) in first.into_iter().zip(second).take(n) {
        let mut x = x;
        let mut y = y;
        x.track_id = a;
        y.track_id = b;
        y.sequence = x.sequence;
        y.header.stamp = x.header.stamp.clone();
        one.push(x);
        two.push(y);
    }
    (one, two)
}

/// What a node alone with `frames` publishes.
fn alone(frames: &[HeatMaps]) -> Vec<Skeleton3D> {
    let mut node = node();
    let mut out = Vec::new();
    for m in frames {
        node.handle(m, &mut out).expect("frame");
    }
    node.finish(&mut out);
    out
}

fn of_track(out: &[Skeleton3D], id: u32) -> Vec<Skeleton3D> {
    out.iter().filter(|s| s.track_id == id).cloned().collect()
}

fn summary(out: &[Skeleton3D]) -> Vec<(u32, u64, u32, u8)> {
    out.iter()
        .map(|s| (s.track_id, s.sequence, s.lag, s.state))
        .collect()
}

#[test]
fn two_people_in_the_same_images_never_reset_each_others_windows() {
    // Track ids at both ends of their range (0 is an unknown id): a detector's
    // numbering that wrapped.
    let (a, b) = (u32::MAX, 1);
    let (one, two) = two_people(a, b, 80);
    let mut node = node();
    let mut out = Vec::new();
    for (x, y) in one.iter().zip(&two) {
        node.handle(x, &mut out).expect("first person");
        node.handle(y, &mut out).expect("second person");
        assert_eq!(node.tracks(), 2);
    }
    node.finish(&mut out);
    // Each person's skeletons are exactly those of a node that saw only them.
    let (want_a, want_b) = (alone(&one), alone(&two));
    assert_eq!(want_a.len(), 80 + 80, "{:?}", summary(&want_a));
    assert_eq!(of_track(&out, a), want_a, "{:?}", summary(&out));
    assert_eq!(of_track(&out, b), want_b);
    let c = node.counters();
    assert_eq!((c.tracks, c.resets, c.frames), (2, 0, 160), "{c:?}");
    assert_eq!(node.malformed(), 0);
}

#[test]
fn a_person_who_leaves_ends_with_their_owed_estimates_and_the_other_goes_on() {
    let (one, two) = two_people(1, 2, 90);
    let lag = config().estimator.window.lag as u32;
    let mut node = node();
    let mut out = Vec::new();
    let mut ended_at = None;
    for (i, (x, y)) in one.iter().zip(&two).enumerate() {
        node.handle(x, &mut out).expect("first person");
        // The second person leaves after 20 images.
        if i < 20 {
            node.handle(y, &mut out).expect("second person");
        }
        if ended_at.is_none() && out.iter().any(|s| s.state == SkeletonState::Lost as u8) {
            ended_at = Some(i);
        }
    }
    node.finish(&mut out);
    // Their track ended once the first person's images were more than the window's
    // `max_gap_seconds` (1 s, 30 frames) past their last one, with the refined
    // estimates still owed (frames 10..20, lag < L, state lost).
    let ended_at = ended_at.expect("the track ended");
    let stamp = |m: &HeatMaps| m.header.stamp.nanos();
    let gone = (stamp(&one[ended_at]) - stamp(&two[19])) as f64 * 1e-9;
    let before = (stamp(&one[ended_at - 1]) - stamp(&two[19])) as f64 * 1e-9;
    assert!(gone > 1.0 && before <= 1.0, "{gone} s, {before} s");
    let left = of_track(&out, 2);
    let lost: Vec<_> = left
        .iter()
        .filter(|s| s.state == SkeletonState::Lost as u8)
        .collect();
    assert_eq!(lost.len(), lag as usize, "{:?}", summary(&left));
    assert!(
        lost.iter()
            .all(|s| s.lag < lag && (10..20).contains(&s.sequence))
    );
    // Nothing of theirs was lost or changed, and the first person never noticed.
    assert_eq!(left, alone(&two[..20]));
    assert_eq!(of_track(&out, 1), alone(&one));
    assert_eq!(node.counters().tracks, 2);
}

#[test]
fn more_people_than_max_tracks_are_refused_and_counted() {
    let (one, two) = two_people(1, 2, 40);
    let (_, three) = two_people(1, 3, 40);
    let mut node = node().with_max_tracks(2);
    let mut out = Vec::new();
    for ((x, y), z) in one.iter().zip(&two).zip(&three) {
        node.handle(x, &mut out).expect("first person");
        node.handle(y, &mut out).expect("second person");
        let e = node
            .handle(z, &mut out)
            .expect_err("a third is one too many");
        assert!(e.to_string().contains("at most 2"), "{e}");
        assert_eq!(node.tracks(), 2);
    }
    node.finish(&mut out);
    assert_eq!(node.refused().of("too-many-tracks"), 40);
    assert_eq!(of_track(&out, 1), alone(&one));
    assert_eq!(of_track(&out, 2), alone(&two));
    assert!(of_track(&out, 3).is_empty());
}

#[test]
fn a_track_id_seen_again_after_its_track_ended_is_a_new_track() {
    // One person, lost for 2 s (no frame), then found again under the same id: the old
    // track ends with its owed estimates, a new one starts.
    let mut frames = frames("byebye.mcap");
    frames.truncate(60);
    for m in &mut frames[30..] {
        m.header.stamp = posestream::msgs::Time::from_nanos(m.header.stamp.nanos() + 2_000_000_000);
    }
    let mut node = node();
    let mut out = Vec::new();
    for m in &frames {
        node.handle(m, &mut out).expect("frame");
    }
    node.finish(&mut out);
    let c = node.counters();
    assert_eq!((c.tracks, c.resets), (2, 1), "{c:?}");
    let lost = out
        .iter()
        .filter(|s| s.state == SkeletonState::Lost as u8)
        .count();
    assert_eq!(lost, 20, "{:?}", summary(&out));
}

/// A recording of `people` (each one's heat maps, image by image), as a detector
/// publishing one message per person would have made it.
fn recording_of(path: &std::path::Path, people: &[&[HeatMaps]]) {
    let mut rec = posestream::recording::Recorder::create(path).expect("create");
    for i in 0..people[0].len() {
        for person in people {
            let m = &person[i];
            let t = m.header.stamp.nanos() as u64;
            rec.write(&config().topics.heatmaps, t, m).expect("write");
        }
    }
    rec.finish().expect("finish");
}

#[test]
fn each_image_s_people_are_recorded_together_and_independent_clients_read_them() {
    use posestream::msgs::Skeleton3DArray;
    use posestream::nodes::config::ReplayRate;
    use posestream::nodes::replay::{ReplayOptions, replay};
    let dir = tempfile::tempdir().expect("tempdir");
    let (input, output) = (dir.path().join("two.mcap"), dir.path().join("out.mcap"));
    let (one, two) = two_people(4, 9, 80);
    recording_of(&input, &[&one, &two]);
    let options = ReplayOptions {
        record: Some(output.clone()),
        rosbag2: false,
        rate: ReplayRate::Fast,
        paced_for_live: false,
    };
    let stop = std::sync::atomic::AtomicBool::new(false);
    let report = replay(&config(), &input, &options, &stop).expect("replay");
    assert_eq!((report.counters.tracks, report.counters.resets), (2, 0));
    let skeletons: Vec<Skeleton3D> = common::messages(&output, "/posestream/skeletons");
    assert_eq!(of_track(&skeletons, 4), alone(&one));
    assert_eq!(of_track(&skeletons, 9), alone(&two));
    let arrays: Vec<Skeleton3DArray> = common::messages(&output, "/posestream/skeleton_arrays");
    // One array per image and lag: 80 newest, 70 refined while tracking, 10 owed at
    // the end; each holds both people, with the image's stamp, sequence and lag.
    assert_eq!(arrays.len(), 80 + 70 + 10);
    let mut seen = Vec::new();
    for a in &arrays {
        let tracks: Vec<u32> = a.skeletons.iter().map(|s| s.track_id).collect();
        assert_eq!(tracks, [4, 9], "image {} lag {}", a.sequence, a.lag);
        for s in &a.skeletons {
            assert_eq!((s.sequence, s.lag), (a.sequence, a.lag));
            assert_eq!(s.header, a.header);
            seen.push(s.clone());
        }
    }
    // Every skeleton is in exactly one array.
    let key = |s: &Skeleton3D| (s.track_id, s.sequence, s.lag);
    let mut want = skeletons.clone();
    want.sort_by_key(key);
    seen.sort_by_key(key);
    assert_eq!(seen, want);
    // Python's mcap-ros2-support decodes the arrays from the recording's own schema.
    let py = common::python_client("read_recording.py", &[output.to_str().expect("utf-8")]);
    assert_eq!(
        py["schemas"]["/posestream/skeleton_arrays"],
        "posestream_msgs/msg/Skeleton3DArray"
    );
    let decoded = py["arrays"].as_array().expect("arrays");
    assert_eq!(decoded.len(), arrays.len());
    for (d, a) in decoded.iter().zip(&arrays) {
        assert_eq!(d["sequence"], a.sequence);
        assert_eq!(d["lag"], a.lag);
        assert_eq!(d["tracks"], serde_json::json!([4, 9]));
        let positions: Vec<f64> =
            serde_json::from_value(d["first_positions"].clone()).expect("f64");
        assert_eq!(positions, a.skeletons[0].positions);
    }
}

#[test]
fn a_person_found_again_and_again_never_fills_the_tracks() {
    // A single-person detector that loses and finds its person on every second frame
    // takes a new id each time: 20 ids within 1.3 s. The tracks it leaves behind end
    // when the node needs their room; no frame is refused.
    let mut frames = frames("byebye.mcap");
    frames.truncate(40);
    for (i, m) in frames.iter_mut().enumerate() {
        m.track_id = (i / 2) as u32 + 1;
    }
    let mut node = node();
    let mut out = Vec::new();
    for m in &frames {
        node.handle(m, &mut out).expect("no frame refused");
        assert!(node.tracks() <= posestream::nodes::DEFAULT_MAX_TRACKS);
    }
    node.finish(&mut out);
    assert_eq!(node.malformed(), 0);
    assert_eq!(node.counters().tracks, 20);
    assert_eq!(node.counters().frames, 40);
}

#[test]
fn a_late_duplicate_from_another_time_ends_no_one() {
    // A frame of person 1 sent again, long after and stamped 5 s away: late for its
    // track (dropped, counted), it must not end person 2's track.
    let (one, two) = two_people(1, 2, 60);
    let mut node = node();
    let mut out = Vec::new();
    for (i, (x, y)) in one.iter().zip(&two).enumerate() {
        node.handle(x, &mut out).expect("first person");
        node.handle(y, &mut out).expect("second person");
        if i == 30 {
            let mut again = one[20].clone();
            again.header.stamp =
                posestream::msgs::Time::from_nanos(again.header.stamp.nanos() + 5_000_000_000);
            node.handle(&again, &mut out).expect("counted as late");
        }
    }
    node.finish(&mut out);
    let c = node.counters();
    assert_eq!((c.tracks, c.late), (2, 1), "{c:?}");
    assert_eq!(of_track(&out, 2), alone(&two));
}

// Issue 46: heat maps from a detector without tracking (every person's `track_id` 0).

/// [`two_people`] with the second person's crop boxes 600 px to the right of the
/// first's (two people apart in the image), both with id `id`.
fn two_people_apart(id: u32, n: usize) -> (Vec<HeatMaps>, Vec<HeatMaps>) {
    let (one, mut two) = two_people(id, id, n);
    for m in &mut two {
        m.crop_x += 600.0;
    }
    (one, two)
}

/// Each person's skeletons in `out`, by the track that published the first frame of
/// `first` (the positions of its first newest estimate).
fn track_of(out: &[Skeleton3D], want: &[Skeleton3D]) -> u32 {
    let first = want.iter().find(|s| s.lag == 0).expect("a newest estimate");
    out.iter()
        .find(|s| s.lag == 0 && s.sequence == first.sequence && s.positions == first.positions)
        .map(|s| s.track_id)
        .expect("the person's first estimate")
}

/// Strips the id of both people's messages and feeds them to a node, the two of each
/// image in the order `order(i)` gives (true: the first person first); returns the
/// node's skeletons with each person's track id put back to its true one (`a` for the
/// first, `b` for the second), and the node.
fn without_ids(order: impl Fn(usize) -> bool) -> (EstimatorNode, Vec<Skeleton3D>, u32, u32) {
    let (one, two) = two_people_apart(0, 80);
    let mut node = node();
    let mut out = Vec::new();
    for (i, (x, y)) in one.iter().zip(&two).enumerate() {
        let (first, second) = if order(i) { (x, y) } else { (y, x) };
        node.handle(first, &mut out).expect("first");
        node.handle(second, &mut out).expect("second");
    }
    node.finish(&mut out);
    let (want_a, want_b) = (alone(&with_id(&one, 1)), alone(&with_id(&two, 2)));
    let (a, b) = (track_of(&out, &want_a), track_of(&out, &want_b));
    (node, out, a, b)
}

fn with_id(frames: &[HeatMaps], id: u32) -> Vec<HeatMaps> {
    frames
        .iter()
        .map(|m| HeatMaps {
            track_id: id,
            ..m.clone()
        })
        .collect()
}

/// The skeletons of `track` as a node alone with them gives them, its id replaced by
/// `id` for comparison.
fn as_track(out: &[Skeleton3D], track: u32, id: u32) -> Vec<Skeleton3D> {
    of_track(out, track)
        .into_iter()
        .map(|s| Skeleton3D { track_id: id, ..s })
        .collect()
}

#[test]
fn two_people_without_ids_are_two_tracks_in_either_order_with_the_estimates_of_true_ids() {
    let (one, two) = two_people_apart(0, 80);
    let want_a = alone(&with_id(&one, 1));
    let want_b = alone(&with_id(&two, 2));
    for (name, order) in [
        (
            "first person first",
            Box::new(|_| true) as Box<dyn Fn(usize) -> bool>,
        ),
        ("alternating", Box::new(|i| i % 2 == 0)),
    ] {
        let (node, out, a, b) = without_ids(order);
        assert_ne!(a, b, "{name}");
        // Two tracks, made by the node, with the ids it gives (from 2^31).
        assert_eq!(node.tracks_from_unknown_ids(), 2, "{name}");
        assert!(a >= 1 << 31 && b >= 1 << 31, "{name}: {a} {b}");
        assert_eq!(node.counters().late, 0, "{name}");
        assert_eq!(node.malformed(), 0, "{name}");
        // Each person's skeletons are exactly those of a node that saw only them under
        // a true id: the errors of true ids.
        assert_eq!(as_track(&out, a, 1), want_a, "{name}");
        assert_eq!(as_track(&out, b, 2), want_b, "{name}");
        assert_eq!(out.len(), want_a.len() + want_b.len(), "{name}");
    }
}

#[test]
fn a_second_message_of_one_image_with_the_same_id_is_refused_by_name() {
    // A detector that gives both people id 5: the second of each image is refused as
    // a duplicate (before: taken as a late frame of the first), the first estimated.
    let (one, two) = two_people_apart(5, 30);
    let mut node = node();
    let mut out = Vec::new();
    for (x, y) in one.iter().zip(&two) {
        node.handle(x, &mut out).expect("first");
        let e = node.handle(y, &mut out).expect_err("a duplicate");
        assert!(e.to_string().contains("duplicate id in one image"), "{e}");
    }
    node.finish(&mut out);
    assert_eq!(node.refused().of("duplicate-id"), 30);
    assert_eq!(node.counters().late, 0);
    assert_eq!(out, alone(&one));
}

#[test]
fn a_stream_mixing_ids_and_no_ids_keeps_the_given_ids_and_tracks_the_rest() {
    // Person 1 with id 7, person 2 without: two tracks, 7 and the node's first.
    let (one, two) = two_people_apart(7, 60);
    let two = with_id(&two, 0);
    let mut node = node();
    let mut out = Vec::new();
    for (x, y) in one.iter().zip(&two) {
        // The one without an id first: held until its image is complete.
        node.handle(y, &mut out).expect("without an id");
        node.handle(x, &mut out).expect("with an id");
    }
    node.finish(&mut out);
    assert_eq!(node.tracks_from_unknown_ids(), 1);
    let ids: std::collections::BTreeSet<u32> = out.iter().map(|s| s.track_id).collect();
    assert_eq!(ids, [7, (1 << 31) + 1].into());
    assert_eq!(of_track(&out, 7), alone(&one));
    assert_eq!(as_track(&out, (1 << 31) + 1, 2), alone(&with_id(&two, 2)));
}
