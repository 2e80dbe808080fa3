//! Unit tests of the window's ring of maps, its settings and its sweeps in parts.

use super::{MapRing, MapSource, Scores, StreamSettings, Sweep};

/// The ring holds the frames it has been given, not its capacity: a short track (a
/// batch EM's start over a one-frame sequence of large maps) must not cost a whole
/// window of maps. Full, it keeps its size; cleared and filled again, it grows no
/// further.
#[test]
fn the_map_ring_grows_with_its_frames_up_to_its_capacity() {
    let (joints, h, w) = (2, 4, 5);
    let n = joints * h * w;
    let mut ring = MapRing::default();
    ring.configure(30, joints, h, w);
    let frame: Vec<f32> = (0..n).map(|i| i as f32).collect();
    ring.push_back(&Scores::F32(&frame));
    assert_eq!(ring.values.len(), n, "one frame");
    assert_eq!(ring.moments.len(), joints);
    assert_eq!(ring.map(0, 1), &frame[h * w..2 * h * w]);
    for _ in 1..30 {
        ring.push_back(&Scores::F32(&frame));
    }
    assert_eq!(ring.values.len(), 30 * n);
    for _ in 0..40 {
        ring.pop_front();
        ring.push_back(&Scores::F32(&frame));
    }
    assert_eq!(ring.values.len(), 30 * n, "full: no growth");
    assert_eq!(ring.map(29, 0), &frame[..h * w]);
    ring.clear();
    ring.push_back(&Scores::F32(&frame));
    assert_eq!(ring.values.len(), 30 * n, "cleared: buffers kept");
}

/// The newest estimate's deviations get the whole factor, a refined one none, and
/// one with part of the lag's frames after it (a track's end) its share.
#[test]
fn the_newest_estimate_s_deviations_widen_by_its_factor() {
    let s = StreamSettings {
        newest_std_scale: 1.5,
        lag: 10,
        ..StreamSettings::default()
    };
    assert_eq!(s.newest_std_factor(0), 1.5);
    assert!((s.newest_std_factor(5) - 1.25).abs() < 1e-12);
    assert_eq!(s.newest_std_factor(10), 1.0);
    let no_lag = StreamSettings { lag: 0, ..s };
    assert_eq!(no_lag.newest_std_factor(0), 1.5);
}

/// Every frame in the window when a sweep begins, or arriving before its last part,
/// is in exactly one part, with a full window (which loses its oldest frame with
/// each new one) and with one still filling.
#[test]
fn the_parts_of_a_sweep_cover_each_frame_once() {
    for (size, start, parts) in [(30, 30, 3), (30, 12, 3), (30, 30, 5), (7, 7, 7), (30, 2, 2)] {
        // Frames by their number since the track began; the window holds the newest
        // `size` of them, `[first, newest)`; `first` frames have left it.
        let first = |newest: usize| newest.saturating_sub(size);
        let mut newest = start;
        let begun = first(newest);
        let mut sweep = Sweep {
            part: 0,
            parts,
            frames: newest - begun,
            dropped: begun,
        };
        let mut seen = vec![0; start + parts];
        loop {
            let f = first(newest);
            for t in sweep.next_part(newest - f, f) {
                seen[f + t] += 1;
            }
            if sweep.part == parts {
                break;
            }
            newest += 1;
        }
        let covered = &seen[begun..newest];
        assert!(
            covered.iter().all(|&times| times == 1),
            "window {size}, {start} frames, {parts} parts: {covered:?}"
        );
    }
}
