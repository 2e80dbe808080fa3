//! Unit tests of `tracker`.

use super::*;
use crate::appearance::Appearance;

fn square(cx: f64, cy: f64, side: f64) -> CropBox {
    CropBox {
        x0: cx - 0.5 * side,
        y0: cy - 0.5 * side,
        width: side,
        height: side,
    }
}

fn seen_at(t: &mut Tracker, boxes: &[CropBox]) -> Vec<(u32, CropBox)> {
    let obs: Vec<Observation> = boxes
        .iter()
        .map(|&region| Observation { region, score: 0.9 })
        .collect();
    let mut out: Vec<(u32, CropBox)> = t
        .frame_of_boxes(&obs)
        .into_iter()
        .zip(boxes)
        .filter_map(|(id, b)| Some((id?, *b)))
        .collect();
    // Oldest first, as `end` reports them.
    let order: Vec<u32> = t.tracks.iter().map(|t| t.id).collect();
    out.sort_by_key(|(id, _)| order.iter().position(|o| o == id));
    out
}

fn settings() -> TrackingSettings {
    TrackingSettings::default()
}

#[test]
fn two_people_walking_keep_their_ids_in_any_order() {
    let mut t = Tracker::new(settings(), 0.5);
    let mut ids = None;
    for f in 0..50 {
        let a = square(100.0 + 4.0 * f64::from(f), 200.0, 120.0);
        let b = square(500.0 - 3.0 * f64::from(f), 220.0, 100.0);
        let boxes = if f % 2 == 0 { [a, b] } else { [b, a] };
        let out = seen_at(&mut t, &boxes);
        assert_eq!(out.len(), 2, "frame {f}");
        let id_of = |bx: CropBox| out.iter().find(|(_, r)| *r == bx).expect("seen").0;
        let now = (id_of(a), id_of(b));
        assert_ne!(now.0, now.1);
        assert_eq!(*ids.get_or_insert(now), now, "frame {f}");
    }
    assert_eq!(t.stats().births, 2);
}

#[test]
fn a_newcomer_is_reported_after_birth_frames_and_a_leaver_ends_after_lost_frames() {
    let mut t = Tracker::new(settings(), 0.5);
    let a = square(100.0, 100.0, 80.0);
    assert_eq!(seen_at(&mut t, &[a]).len(), 1, "first frame: at once");
    let b = square(400.0, 100.0, 80.0);
    assert_eq!(seen_at(&mut t, &[a, b]).len(), 1, "b is tentative");
    assert_eq!(seen_at(&mut t, &[a, b]).len(), 2, "b confirmed");
    // b leaves: kept for lost_frames, then ended.
    for _ in 0..30 {
        assert_eq!(seen_at(&mut t, &[a]).len(), 1);
    }
    assert_eq!(t.len(), 2);
    seen_at(&mut t, &[a]);
    assert_eq!(t.len(), 1);
    assert_eq!(t.stats().deaths, 1);
    // A one-frame flicker never becomes a track.
    seen_at(&mut t, &[a, square(700.0, 100.0, 80.0)]);
    seen_at(&mut t, &[a]);
    assert_eq!((t.len(), t.stats().confirmed), (1, 2));
}

#[test]
fn a_person_hidden_for_a_while_comes_back_with_their_id_where_their_velocity_took_them() {
    let mut t = Tracker::new(settings(), 0.5);
    let at = |f: u32| square(100.0 + 10.0 * f64::from(f), 300.0, 100.0);
    let mut id = 0;
    for f in 0..10 {
        id = seen_at(&mut t, &[at(f)])[0].0;
    }
    // Hidden 12 frames (120 px: no overlap with where they were).
    for _ in 10..22 {
        assert!(seen_at(&mut t, &[]).is_empty());
    }
    let back = seen_at(&mut t, &[at(22)]);
    assert_eq!(back, vec![(id, at(22))]);
    assert_eq!(t.stats().reacquisitions, 1);
    assert_eq!(t.stats().births, 1);
}

#[test]
fn a_low_score_box_reacquires_or_is_only_a_candidate_for_a_new_track() {
    let mut t = Tracker::new(settings(), 0.5);
    let a = square(100.0, 100.0, 80.0);
    let id = seen_at(&mut t, &[a])[0].0;
    t.begin();
    assert!(t.end().is_empty(), "missed");
    t.begin();
    let weak = [
        Observation {
            region: a,
            score: 0.3,
        },
        Observation {
            region: square(400.0, 100.0, 80.0),
            score: 0.3,
        },
    ];
    assert_eq!(
        t.associate(&weak),
        vec![Assignment::Track(id), Assignment::Candidate]
    );
    t.seen(id, a);
    t.end();
    // Boxes alone (no second opinion): a low score starts nobody.
    let weak = [Observation {
        region: square(400.0, 100.0, 80.0),
        score: 0.3,
    }];
    assert_eq!(t.frame_of_boxes(&weak), vec![None]);
    assert_eq!(t.len(), 1);
}

#[test]
fn a_duplicate_is_a_miss_a_box_on_a_seen_person_starts_nobody_and_room_is_bounded() {
    let mut t = Tracker::new(
        TrackingSettings {
            max_people: 2,
            ..settings()
        },
        0.5,
    );
    let a = square(100.0, 100.0, 80.0);
    let b = square(300.0, 100.0, 80.0);
    let c = square(500.0, 100.0, 80.0);
    let out = seen_at(&mut t, &[a, b, c]);
    assert_eq!(out.len(), 2);
    assert_eq!(t.stats().no_room, 1);
    // The caller found both followed tracks on one person: the second is a miss.
    t.begin();
    t.seen(out[0].0, a);
    t.duplicate(out[1].0);
    // A second box on the person seen is not a newcomer.
    let near = Observation {
        region: square(104.0, 100.0, 80.0),
        score: 0.9,
    };
    assert_eq!(t.associate(&[near]), vec![Assignment::Ignored]);
    let after = t.end();
    assert_eq!(after, vec![(out[0].0, a)]);
    assert_eq!((t.stats().duplicates, t.len()), (1, 2));
}

#[test]
fn a_lost_person_coming_back_keeps_their_place_from_a_newcomer() {
    // max_people 2: A followed, B lost; B comes back beside a confident newcomer C.
    let mut t = Tracker::new(
        TrackingSettings {
            max_people: 2,
            ..settings()
        },
        0.5,
    );
    let (a, b, c) = (
        square(100.0, 100.0, 80.0),
        square(300.0, 100.0, 80.0),
        square(500.0, 100.0, 80.0),
    );
    let ids = seen_at(&mut t, &[a, b]);
    seen_at(&mut t, &[a]);
    for order in [[b, c], [c, b]] {
        let mut u = t.clone();
        u.begin();
        u.seen(ids[0].0, a);
        let obs: Vec<Observation> = order
            .iter()
            .map(|&region| Observation { region, score: 0.9 })
            .collect();
        let what = u.associate(&obs);
        let b_at = order.iter().position(|r| *r == b).expect("b");
        assert_eq!(what[b_at], Assignment::Track(ids[1].0), "{order:?}");
        assert_eq!(what[1 - b_at], Assignment::Ignored, "no room for C");
        // Even a caller that tries to start C first finds no room.
        assert_eq!(u.born(c), None);
        u.seen(ids[1].0, b);
        let out = u.end();
        assert_eq!(out, vec![(ids[0].0, a), (ids[1].0, b)]);
        assert_eq!(u.len(), 2);
    }
}

#[test]
fn a_box_matched_to_a_person_seen_starts_nobody_even_when_it_overlaps_little() {
    let mut t = Tracker::new(settings(), 0.5);
    let a = square(100.0, 100.0, 100.0);
    let id = seen_at(&mut t, &[a])[0].0;
    t.begin();
    t.seen(id, a);
    // IoU about 0.33: within the match gate, under duplicate_iou.
    let off = Observation {
        region: square(150.0, 100.0, 100.0),
        score: 0.9,
    };
    assert_eq!(t.associate(&[off]), vec![Assignment::Ignored]);
}

#[test]
fn the_detector_is_wanted_every_detect_every_frames_while_people_are_followed() {
    let mut t = Tracker::new(settings(), 0.5);
    let a = square(100.0, 100.0, 80.0);
    let id = seen_at(&mut t, &[a])[0].0;
    let mut wanted = Vec::new();
    for f in 1..=25 {
        t.begin();
        t.seen(id, a);
        if t.wants_detections() {
            wanted.push(f);
            t.associate(&[]);
        }
        t.end();
    }
    assert_eq!(wanted, vec![10, 20]);
}

#[test]
fn two_people_crossing_keep_their_ids() {
    let mut t = Tracker::new(settings(), 0.5);
    let mut first = None;
    for f in 0..60 {
        // One walks right in front of the other, who walks left: their boxes
        // coincide in the middle.
        let x = f64::from(f);
        let a = square(100.0 + 8.0 * x, 300.0, 160.0);
        let b = square(580.0 - 8.0 * x, 290.0, 140.0);
        let out = seen_at(&mut t, &[b, a]);
        let id_a = out.iter().find(|(_, r)| *r == a).map(|p| p.0);
        let id_b = out.iter().find(|(_, r)| *r == b).map(|p| p.0);
        let now = (id_a.expect("a"), id_b.expect("b"));
        assert_eq!(*first.get_or_insert(now), now, "frame {f}");
    }
}

#[test]
fn a_followed_box_moves_with_its_velocity_but_keeps_its_size() {
    // Landmark boxes that grow feed back into the next look: extrapolating the
    // size made a box on zidane.jpg grow 13 % a frame until its person was lost.
    let mut t = Tracker::new(settings(), 0.5);
    let id = seen_at(&mut t, &[square(100.0, 100.0, 100.0)])[0].0;
    t.begin();
    t.seen(id, square(110.0, 100.0, 110.0));
    t.end();
    let (_, next) = t.predictions().next().expect("followed");
    assert_eq!(next.width, 110.0);
    assert!(next.x0 + 0.5 * next.width > 110.0, "moved on: {next:?}");
}

#[test]
fn a_low_threshold_above_the_confident_one_drops_no_confident_box() {
    // Found by trying hostile settings: low_threshold 0.9 over detection 0.5 made
    // every box under 0.9 unusable, confident ones included.
    let mut t = Tracker::new(
        TrackingSettings {
            low_threshold: 0.9,
            ..settings()
        },
        0.5,
    );
    let seen = Observation {
        region: square(100.0, 100.0, 80.0),
        score: 0.6,
    };
    assert_eq!(t.frame_of_boxes(&[seen]).len(), 1);
    assert!(t.frame_of_boxes(&[seen])[0].is_some());
}

#[test]
fn ids_wrap_around_and_skip_live_ones() {
    let mut t = Tracker::new(settings(), 0.5);
    t.next_id = u32::MAX;
    let ids: Vec<u32> = seen_at(
        &mut t,
        &[square(100.0, 100.0, 80.0), square(400.0, 100.0, 80.0)],
    )
    .into_iter()
    .map(|(id, _)| id)
    .collect();
    // 0 is no id (HeatMaps' "unknown").
    assert_eq!(ids, vec![u32::MAX, 1]);
    t.next_id = u32::MAX;
    t.begin();
    assert_eq!(t.born(square(700.0, 100.0, 80.0)), Some(2));
}

#[test]
fn out_of_domain_settings_name_their_key() {
    let bad = TrackingSettings {
        max_people: 0,
        ..settings()
    };
    assert!(bad.check().unwrap_err().to_string().contains("max_people"));
    let bad = TrackingSettings {
        match_iou: f64::NAN,
        ..settings()
    };
    assert!(bad.check().unwrap_err().to_string().contains("match_iou"));
    for (key, bad) in [
        (
            "reid_seconds",
            TrackingSettings {
                reid_seconds: f64::NAN,
                ..settings()
            },
        ),
        (
            "reid_seconds",
            TrackingSettings {
                reid_seconds: -1.0,
                ..settings()
            },
        ),
        (
            "reid_seconds",
            TrackingSettings {
                reid_seconds: f64::INFINITY,
                ..settings()
            },
        ),
        (
            "reid_capacity",
            TrackingSettings {
                reid_capacity: usize::MAX,
                ..settings()
            },
        ),
        (
            "reid_distance",
            TrackingSettings {
                reid_distance: 1.5,
                ..settings()
            },
        ),
        (
            "reid_distance",
            TrackingSettings {
                reid_distance: -1e-300,
                ..settings()
            },
        ),
    ] {
        let e = bad.check().expect_err(key).to_string();
        assert!(e.contains(key), "{e}");
    }
    assert!(settings().check().is_ok());
}

/// A look of one flat colour on torso and legs.
fn look(rgb: [u8; 3]) -> Appearance {
    let image = ::image::RgbImage::from_pixel(20, 20, ::image::Rgb(rgb));
    let part = [0.0, 0.0, 20.0, 20.0];
    Appearance::of(&image, part, part).expect("a look")
}

/// One frame at `stamp_ns`: each of `people` (box and look) followed if its track
/// was seen in the frame before, else a newcomer by its look. Returns their ids.
fn frame_of_looks(t: &mut Tracker, stamp_ns: u64, people: &[(CropBox, Appearance)]) -> Vec<u32> {
    t.begin_at(stamp_ns);
    let followed: Vec<(u32, CropBox)> = t.predictions().collect();
    let mut ids = Vec::new();
    for (region, l) in people {
        let id = match followed.iter().find(|(_, p)| iou(p, region) > 0.3) {
            Some(&(id, _)) => {
                t.seen(id, *region);
                Some(id)
            }
            None => t.born_like(*region, Some(l)),
        };
        if let Some(id) = id {
            t.looked_like(id, l);
            ids.push(id);
        }
    }
    t.end();
    ids
}

const SECOND: u64 = 1_000_000_000;

#[test]
fn a_person_gone_three_seconds_comes_back_with_their_id_and_a_stranger_does_not() {
    // 30 frames/s; red walks right and leaves view for 3 s (lost after `lost_frames`,
    // then remembered); blue stays. Red comes back near where they left; a green
    // stranger comes in at the same place a moment later.
    let mut t = Tracker::new(settings(), 0.5);
    let (red, blue, green) = (
        look([200, 30, 30]),
        look([30, 30, 200]),
        look([30, 200, 30]),
    );
    let frame = |n: u64| n * SECOND / 30;
    let blue_at = square(100.0, 300.0, 100.0);
    let mut first = None;
    for n in 0..60 {
        let red_at = square(300.0 + 2.0 * n as f64, 300.0, 100.0);
        let ids = frame_of_looks(&mut t, frame(n), &[(red_at, red), (blue_at, blue)]);
        assert_eq!(*first.get_or_insert(ids.clone()), ids, "frame {n}");
    }
    let [red_id, blue_id] = first.expect("seen")[..] else {
        panic!("two people")
    };
    for n in 60..150 {
        assert_eq!(
            frame_of_looks(&mut t, frame(n), &[(blue_at, blue)]),
            [blue_id]
        );
    }
    assert!(!t.is_live(red_id), "ended after lost_frames");
    assert_eq!(t.remembered(), 1);
    let back = square(440.0, 305.0, 96.0);
    let ids = frame_of_looks(&mut t, frame(150), &[(blue_at, blue), (back, red)]);
    assert_eq!(ids, [blue_id, red_id], "red is back with their id");
    assert_eq!(t.stats().reidentified, 1);
    // Gone again, and a stranger where they were: a new id, never theirs.
    for n in 151..200 {
        frame_of_looks(&mut t, frame(n), &[(blue_at, blue)]);
    }
    let ids = frame_of_looks(&mut t, frame(200), &[(blue_at, blue), (back, green)]);
    assert_eq!(ids.len(), 2);
    assert!(ids[1] != red_id && ids[1] != blue_id, "{ids:?}");
    // Too far from where they were for the time gone: not them.
    let far = square(2000.0, 300.0, 100.0);
    let ids = frame_of_looks(
        &mut t,
        frame(201),
        &[(blue_at, blue), (back, green), (far, red)],
    );
    assert!(!ids.contains(&red_id), "{ids:?}");
}

#[test]
fn a_lost_person_found_far_from_their_expected_box_gets_their_id_back_by_their_look() {
    // Red is lost for 20 frames (still a live track) and found 110 px from where their
    // box was expected, where boxes alone would not have them (no overlap).
    let mut t = Tracker::new(settings(), 0.5);
    let (red, blue) = (look([200, 30, 30]), look([30, 30, 200]));
    let frame = |n: u64| n * SECOND / 30;
    let mut red_id = None;
    for n in 0..20 {
        let ids = frame_of_looks(&mut t, frame(n), &[(square(300.0, 300.0, 100.0), red)]);
        assert_eq!(*red_id.get_or_insert(ids[0]), ids[0]);
    }
    for n in 20..40 {
        assert!(frame_of_looks(&mut t, frame(n), &[]).is_empty());
    }
    let red_id = red_id.expect("seen");
    assert!(t.is_live(red_id));
    let back = square(410.0, 300.0, 100.0);
    assert_eq!(iou(&back, &square(300.0, 300.0, 100.0)), 0.0);
    // A blue stranger near there first gets a new id; red then gets theirs.
    let stranger = square(410.0, 420.0, 100.0);
    let ids = frame_of_looks(&mut t, frame(40), &[(stranger, blue), (back, red)]);
    assert!(ids[0] != red_id, "{ids:?}");
    assert_eq!(ids[1], red_id);
    assert_eq!(t.stats().reidentified, 1);
    assert_eq!(t.stats().reacquisitions, 1);
    // With `reid_distance` 0 nobody is found again by their look, not even one that
    // looks the very same (distance 0).
    let mut off = Tracker::new(
        TrackingSettings {
            reid_distance: 0.0,
            ..settings()
        },
        0.5,
    );
    let first = frame_of_looks(&mut off, 0, &[(square(300.0, 300.0, 100.0), red)]);
    for n in 1..20 {
        frame_of_looks(&mut off, frame(n), &[]);
    }
    let again = frame_of_looks(&mut off, frame(20), &[(square(300.0, 300.0, 100.0), red)]);
    assert!(
        first != again && off.stats().reidentified == 0,
        "{first:?} {again:?}"
    );
}

#[test]
fn a_forgotten_person_is_a_newcomer_and_the_memory_stays_bounded() {
    let mut t = Tracker::new(
        TrackingSettings {
            reid_capacity: 8,
            lost_frames: 0,
            ..settings()
        },
        0.5,
    );
    let red = look([200, 30, 30]);
    // Thousands of people each seen for two frames, then gone.
    for n in 0..4000u64 {
        let at = square(100.0 + (n % 50) as f64 * 200.0, 300.0, 100.0);
        frame_of_looks(&mut t, 2 * n * SECOND / 30, &[(at, red)]);
        frame_of_looks(&mut t, (2 * n + 1) * SECOND / 30, &[(at, red)]);
        assert!(t.remembered() <= 8);
    }
    assert!(t.stats().forgotten > 0);
    // After `reid_seconds`, nobody is remembered.
    t.begin_at(10_000 * SECOND);
    assert_eq!(t.remembered(), 0);
    t.end();
    // The same spot came round every 3.3 s, but those there were forgotten for want
    // of room, and the others were too far for the time gone: nobody came back.
    assert_eq!(t.stats().reidentified, 0);
    // A clock that runs backwards (or a stamp left unset) moves on a frame.
    t.begin_at(0);
    assert_eq!(t.now_ns, 10_000 * SECOND + FRAME_NS);
    t.end();
    t.begin_at(0);
    assert_eq!(t.now_ns, 10_000 * SECOND + 2 * FRAME_NS);
}
