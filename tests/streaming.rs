//! The streaming estimator on the shipped recordings: close to the batch EM, robust to
//! gaps, late frames, restarts and malformed input, flat in memory.

mod common;

use common::{RECORDINGS, recording, root};
use posestream::LoadDictionary;
use posestream::accuracy;
use posestream::msgs::{self, Skeleton3D};
use posestream::nodes::{EstimatorNode, ServiceConfig};
use posestream::recording::read_topic;
use posestream::streaming::{FrameMaps, StreamSettings, TrackState, WindowEstimator};
use posestream::{Dictionary, Estimator, HeatMapSequence, Params};

/// The heat maps of a recording as one sequence, and its ground truth (metres).
fn load(name: &str) -> (HeatMapSequence, Vec<f64>, Vec<msgs::HeatMaps>) {
    let path = recording(name);
    let messages: Vec<msgs::HeatMaps> = read_topic(&path, "/posestream/heatmaps")
        .expect("reads")
        .into_iter()
        .map(|(_, m)| m)
        .collect();
    let truth: Vec<f64> = read_topic::<Skeleton3D>(&path, "/posestream/ground_truth")
        .expect("reads")
        .into_iter()
        .flat_map(|(_, m)| m.positions)
        .collect();
    let (h, w) = (messages[0].height as usize, messages[0].width as usize);
    let mut values = Vec::new();
    let mut frame = Vec::new();
    for m in &messages {
        m.values_into(&mut frame).expect("values");
        values.extend_from_slice(&frame);
    }
    // Not `HeatMapSequence::new`: the recordings have missing joints (all-zero maps), which the
    // E-step reads as "no observation" and `new` refuses.
    let maps = HeatMapSequence {
        frames: messages.len(),
        joints: 17,
        height: h,
        width: w,
        values,
    };
    (maps, truth, messages)
}

/// Held by the tests that allocate much (whole recordings) and by the one that watches
/// the process's resident memory, so that its figures are its own: tests of one file
/// run on threads of one process.
static MEMORY: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn memory_lock() -> std::sync::MutexGuard<'static, ()> {
    MEMORY.lock().unwrap_or_else(|e| e.into_inner())
}

fn estimator() -> Estimator {
    let dict =
        Dictionary::load(root().join("config/dictionaries/default-k128.json")).expect("dictionary");
    Estimator::new(dict, Params::default()).expect("estimator")
}

#[test]
fn streaming_stays_within_5_percent_of_the_batch_em_at_lag_10_and_15_percent_at_lag_0() {
    let _memory = memory_lock();
    let config = ServiceConfig::load(root().join("config/default.toml")).expect("config");
    assert_eq!(config.estimator.window.lag, 10);
    let p = 17;
    let (mut batch, mut lag10, mut lag0, mut frames) = (0.0, 0.0, 0.0, 0.0);
    for name in RECORDINGS {
        let (maps, truth, messages) = load(name);
        let f = maps.frames;
        // The batch EM from each frame's own start: one that does not start from the
        // window it is compared with (`Params::start_from_window`).
        let from_argmax = Estimator::new(
            estimator().dictionary().clone(),
            Params {
                start_from_window: false,
                ..Params::default()
            },
        )
        .expect("estimator");
        let est = from_argmax.lift_heatmaps(&maps).expect("batch");
        let mut node = EstimatorNode::from_config(&config.estimator).expect("node");
        let mut out = Vec::new();
        for m in &messages {
            node.handle(m, &mut out).expect("frame");
        }
        node.finish(&mut out);
        let (mut refined, mut newest) = (vec![f64::NAN; 3 * p * f], vec![f64::NAN; 3 * p * f]);
        let mut seen = vec![(0, 0); f];
        for s in &out {
            let t = s.sequence as usize;
            // The newest frame's estimate at once (lag 0), the refined one 10 frames
            // later; frames near the end get theirs when the stream ends, with a
            // shorter lag and the state `lost`.
            let lost = s.state == 2;
            if s.lag == 0 && !lost {
                newest[3 * p * t..3 * p * (t + 1)].copy_from_slice(&s.positions);
                seen[t].0 += 1;
            } else {
                refined[3 * p * t..3 * p * (t + 1)].copy_from_slice(&s.positions);
                seen[t].1 += 1;
                assert!(s.lag == 10 || (lost && t + 10 >= f), "{name} {t}");
            }
        }
        // Every frame once at lag 0 and once refined.
        assert!(seen.iter().all(|&s| s == (1, 1)), "{name}: {seen:?}");
        let e = |poses: &[f64]| 1000.0 * accuracy::p_mpjpe(poses, &truth, p);
        let (b, r, n) = (e(&est.poses), e(&refined), e(&newest));
        println!("{name}: batch {b:.1} mm, lag 10 {r:.1} mm, lag 0 {n:.1} mm");
        batch += b * f as f64;
        lag10 += r * f as f64;
        lag0 += n * f as f64;
        frames += f as f64;
    }
    let (b, r, n) = (batch / frames, lag10 / frames, lag0 / frames);
    println!(
        "all: batch {b:.1} mm, lag 10 {r:.1} mm ({:+.1} %), lag 0 {n:.1} mm ({:+.1} %)",
        100.0 * (r / b - 1.0),
        100.0 * (n / b - 1.0)
    );
    assert!(r <= 1.05 * b, "lag 10: {r} against batch {b}");
    assert!(n <= 1.15 * b, "lag 0: {n} against batch {b}");
}

/// The refined estimate has been solved together with every frame after it (the issue's
/// window schedule: with the window's EM only every `window_every` frames, most refined
/// estimates had seen at most 3 of their 10 later frames): change only the newest frame
/// and the estimate `lag` frames back changes with it, on every frame from the first
/// refined estimate of the track on (the window filling, then full).
#[test]
fn every_refined_estimate_has_seen_the_newest_frame() {
    let _memory = memory_lock();
    let (maps, _, _) = load("kick.mcap");
    // The lag pass (off by default since 4 local iterations over the newest 3 frames gave
    // about the same refined error without it at two thirds of the time;
    // docs/beyond-the-paper.md).
    let settings = StreamSettings {
        lag_iterations: 1,
        ..StreamSettings::default()
    };
    assert!(settings.window_every > settings.lag);
    assert!(settings.local_frames < settings.lag + 1);
    let (size, lag) = (settings.size, settings.lag);
    assert!(maps.frames > 2 * size, "{} frames", maps.frames);
    let mut w = WindowEstimator::new(estimator(), settings).expect("window");
    let frame = |t: usize, s: u64| FrameMaps::of(&maps, t, s, s as i64 * 33_333_333);
    let refined = |out: &[posestream::streaming::FrameEstimate]| {
        let e = out
            .iter()
            .find(|e| e.lag == lag)
            .expect("a refined estimate");
        e.pose.clone()
    };
    let (mut out, mut other) = (Vec::new(), Vec::new());
    let (mut compared, mut unmoved) = (0, Vec::new());
    for t in 0..maps.frames {
        let s = t as u64;
        if t < lag {
            w.push(&frame(t, s), &mut out).expect("frame");
            continue;
        }
        // The same window, but the newest frame's maps from another moment.
        let mut changed = w.clone();
        out.clear();
        other.clear();
        w.push(&frame(t, s), &mut out).expect("frame");
        changed
            .push(&frame((t + 40) % maps.frames, s), &mut other)
            .expect("frame");
        let (a, b) = (refined(&out), refined(&other));
        let moved = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        compared += 1;
        if moved < 1e-9 {
            unmoved.push(t);
        }
    }
    assert_eq!(compared, maps.frames - lag);
    assert!(
        unmoved.is_empty(),
        "refined estimates that did not see the newest frame: {unmoved:?}"
    );
}

/// A detector's left/right swap in the newest frame (the wrists' maps exchanged) is read
/// as a swap: with the swap model (the default `swap_prior`) the newest estimate's wrists
/// move less than 40 % as far from those of the maps as they are as in the paper's
/// E-step, which follows the maps to the other side (measured: 28 %).
#[test]
fn a_swapped_pair_of_maps_in_the_newest_frame_is_read_as_a_swap() {
    let _memory = memory_lock();
    let (maps, _, _) = load("kick.mcap");
    let dict = estimator().dictionary().clone();
    let &(l, r) = dict
        .left_right_pairs()
        .iter()
        .find(|&&(l, _)| dict.skeleton().joints[l].contains("wrist"))
        .expect("a wrist pair");
    let cells = maps.height * maps.width;
    let mut swapped = maps.clone();
    for t in 0..maps.frames {
        let at = |j: usize| (t * maps.joints + j) * cells;
        let (a, b) = (at(l), at(r));
        let (left, right) = swapped.values.split_at_mut(b);
        left[a..a + cells].swap_with_slice(&mut right[..cells]);
    }
    let mut moved = Vec::new();
    for prior in [Params::default().swap_prior, 0.0] {
        assert!(
            prior > 0.0 || !moved.is_empty(),
            "the default has the swap model on"
        );
        let params = Params {
            swap_prior: prior,
            ..Params::default()
        };
        let settings = StreamSettings::default();
        let mut w = WindowEstimator::new(
            Estimator::new(dict.clone(), params).expect("estimator"),
            settings.clone(),
        )
        .expect("window");
        let (mut out, mut other) = (Vec::new(), Vec::new());
        let newest = |out: &[posestream::streaming::FrameEstimate]| {
            out.iter().find(|e| e.lag == 0).expect("lag 0").pose.clone()
        };
        let (mut total, mut frames) = (0.0, 0.0);
        for t in 0..maps.frames {
            let s = t as u64;
            let stamp = s as i64 * 33_333_333;
            out.clear();
            if t < settings.size {
                w.push(&FrameMaps::of(&maps, t, s, stamp), &mut out)
                    .expect("frame");
                continue;
            }
            let mut changed = w.clone();
            other.clear();
            w.push(&FrameMaps::of(&maps, t, s, stamp), &mut out)
                .expect("frame");
            changed
                .push(&FrameMaps::of(&swapped, t, s, stamp), &mut other)
                .expect("frame");
            let (a, b) = (newest(&out), newest(&other));
            // The wrists' mean distance between the two estimates.
            let d = |j: usize| {
                (0..3)
                    .map(|i| (a[3 * j + i] - b[3 * j + i]).powi(2))
                    .sum::<f64>()
                    .sqrt()
            };
            total += (d(l) + d(r)) / 2.0;
            frames += 1.0;
        }
        moved.push(total / frames);
    }
    println!(
        "wrists moved by the swap: swap model {:.4}, paper's E-step {:.4}",
        moved[0], moved[1]
    );
    assert!(moved[0] < 0.4 * moved[1], "{moved:?}");
}

fn small_window() -> WindowEstimator {
    WindowEstimator::new(
        estimator(),
        StreamSettings {
            size: 6,
            lag: 2,
            max_gap_frames: 5,
            ..StreamSettings::default()
        },
    )
    .expect("window")
}

#[test]
fn gaps_late_frames_and_restarts_are_counted_and_every_frame_is_estimated_once() {
    let _memory = memory_lock();
    let (maps, _, _) = load("byebye.mcap");
    let mut w = small_window();
    let mut out = Vec::new();
    let ns = |s: u64| s as i64 * 33_333_333;
    let mut push = |w: &mut WindowEstimator, t: usize, seq: u64, stamp: i64| {
        w.push(&FrameMaps::of(&maps, t, seq, stamp), &mut out)
            .expect("frame");
    };
    for s in 0..12 {
        push(&mut w, s as usize, s, ns(s));
    }
    push(&mut w, 12, 9, ns(9)); // late
    push(&mut w, 12, 11, ns(11)); // repeated
    push(&mut w, 15, 15, ns(15)); // 3 frames dropped upstream: the track goes on
    push(&mut w, 16, 40, ns(40)); // a long gap: new track
    push(&mut w, 17, 41, ns(41));
    push(&mut w, 18, 0, ns(100)); // the detector restarted its numbering: new track
    let c = w.counters();
    assert_eq!(
        (c.late, c.missing, c.resets, c.tracks),
        (2, 3, 2, 3),
        "{c:?}"
    );
    assert_eq!(c.frames, 16);
    w.finish(&mut out);
    // Newest: lag 0 while the track runs; refined: lag 2, or owed when a track ends.
    let sequences = |refined: bool| -> Vec<u64> {
        out.iter()
            .filter(|e| {
                let lost = e.state == TrackState::Lost;
                if refined {
                    e.lag == 2 || lost
                } else {
                    e.lag == 0 && !lost
                }
            })
            .map(|e| e.sequence)
            .collect()
    };
    let accepted: Vec<u64> = (0..12).chain([15, 40, 41, 0]).collect();
    assert_eq!(sequences(false), accepted);
    let mut refined = sequences(true);
    refined.sort_unstable();
    let mut expected = accepted.clone();
    expected.sort_unstable();
    assert_eq!(refined, expected);
    // Tracks end with their owed estimates in state `lost`.
    let lost: Vec<u64> = out
        .iter()
        .filter(|e| e.state == TrackState::Lost)
        .map(|e| e.sequence)
        .collect();
    assert_eq!(lost, vec![11, 15, 40, 41, 0]);
    assert!(out.iter().all(|e| e.pose.iter().all(|v| v.is_finite())));
}

#[test]
fn malformed_frames_are_errors_that_leave_the_window_as_it_was() {
    let _memory = memory_lock();
    let (maps, _, _) = load("byebye.mcap");
    let mut w = small_window();
    let mut out = Vec::new();
    for t in 0..4 {
        w.push(&FrameMaps::of(&maps, t, t as u64, 0), &mut out)
            .expect("frame");
    }
    let n = maps.joints * maps.height * maps.width;
    let mut nan = maps.values[..n].to_vec();
    nan[100] = f32::NAN;
    let short = &maps.values[..n - 1];
    for (values, h) in [
        (&nan[..], maps.height),
        (short, maps.height),
        (&maps.values[..n], 32),
    ] {
        let frame = FrameMaps {
            sequence: 4,
            stamp_ns: 0,
            height: h,
            width: maps.width,
            values: values.into(),
        };
        assert!(w.push(&frame, &mut out).is_err());
    }
    assert_eq!(w.counters().malformed, 3);
    assert_eq!(w.len(), 4);
    w.push(&FrameMaps::of(&maps, 4, 4, 0), &mut out)
        .expect("the stream goes on");
    assert_eq!(w.len(), 5);
}

/// Resident memory, bytes (Linux).
fn resident() -> usize {
    let statm = std::fs::read_to_string("/proc/self/statm").unwrap_or_default();
    let pages: usize = statm
        .split_whitespace()
        .nth(1)
        .and_then(|v| v.parse().ok())
        .unwrap_or(0);
    pages * 4096
}

#[test]
fn ten_thousand_frames_keep_memory_flat() {
    let _memory = memory_lock();
    let (maps, _, _) = load("byebye.mcap");
    let mut w = small_window();
    let mut out = Vec::new();
    let mut after_warmup = 0;
    for s in 0..10_000_u64 {
        // Back and forth through the recording, as one long track.
        let period = 2 * maps.frames as u64 - 2;
        let phase = s % period;
        let t = if phase < maps.frames as u64 {
            phase
        } else {
            period - phase
        } as usize;
        w.push(&FrameMaps::of(&maps, t, s, s as i64 * 33_333_333), &mut out)
            .expect("frame");
        out.clear();
        if s == 1_000 {
            after_warmup = resident();
        }
    }
    let end = resident();
    println!("resident after 1,000 frames {after_warmup} B, after 10,000 {end} B");
    assert_eq!(w.counters().tracks, 1);
    assert!(
        end <= after_warmup + (1 << 20),
        "grew from {after_warmup} to {end} bytes"
    );
}
