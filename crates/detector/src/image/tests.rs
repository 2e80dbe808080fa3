//! The image detector's unit tests: the geometry of looks, the search's tiles, the
//! settings' domains.

use super::ImageSettings;
use super::looks::{
    BODY_LANDMARKS, FACE_LANDMARKS, Look, around, confirms, head_box, head_jump, masks_for, part_of,
};
use super::search::a_tile_too;
use posestream_base::CropBox;

fn square(x: f64, y: f64, side: f64) -> CropBox {
    CropBox::new(x, y, side, side).expect("box")
}

/// A look whose face landmarks lie in `face` (corners and centre).
fn look_with_face(face: CropBox) -> Look {
    let (x, y, w) = (face.x0, face.y0, face.width);
    let mut points = vec![[x + 0.5 * w, y + 0.5 * w]; BODY_LANDMARKS];
    points[1] = [x, y];
    points[2] = [x + w, y + w];
    Look {
        crop: square(0.0, 0.0, 1000.0),
        pose_flag: 1.0,
        next_box: None,
        spread: 0.5,
        face: head_box(&points[..FACE_LANDMARKS]),
        points,
        logits: Vec::new(),
        seconds: 0.0,
    }
}

/// A look whose body landmarks run down a vertical line from `top` to `bottom` at `x`.
fn look_along(x: f64, top: f64, bottom: f64) -> Look {
    let mut l = look_with_face(square(x, top, 1.0));
    let n = l.points.len();
    for (k, p) in l.points.iter_mut().enumerate() {
        *p = [x, top + (bottom - top) * k as f64 / (n - 1) as f64];
    }
    l
}

#[test]
fn while_nobody_is_followed_a_tile_is_searched_in_one_search_of_three() {
    // Searches in a row while nobody is followed: a tile on the 1st, 4th, 7th...
    let tiles: Vec<bool> = (1..=7).map(|n| a_tile_too(false, n)).collect();
    assert_eq!(tiles, [true, false, false, true, false, false, true]);
    // While someone is followed: every search.
    assert!((0..5).all(|n| a_tile_too(true, n)));
}

#[test]
fn a_small_skeleton_on_someones_legs_is_a_part_of_them_not_a_person() {
    let whole = look_along(100.0, 0.0, 300.0);
    // Legs: the lower half, inside the body.
    assert!(part_of(&whole, &look_along(105.0, 150.0, 300.0)));
    // Not a part: as tall as the person, beside them, or bigger.
    assert!(!part_of(&whole, &look_along(100.0, 20.0, 300.0)));
    assert!(!part_of(&whole, &look_along(200.0, 150.0, 300.0)));
    assert!(!part_of(&look_along(105.0, 150.0, 300.0), &whole));
}

#[test]
fn around_a_body_is_what_of_the_crop_lies_outside_it_grown_by_a_margin() {
    let crop = square(0.0, 0.0, 200.0);
    let body = CropBox::new(80.0, 20.0, 40.0, 160.0).expect("box");
    let strips = around(&body, &crop);
    // Margin 16 px across, 8 above and below: left, right, top, bottom strips.
    assert_eq!(strips.len(), 4, "{strips:?}");
    assert!((strips[0].width - 64.0).abs() < 1e-9);
    assert!((strips[1].x0 - 136.0).abs() < 1e-9 && (strips[1].width - 64.0).abs() < 1e-9);
    assert!((strips[2].height - 12.0).abs() < 1e-9);
    assert!((strips[3].y0 - 188.0).abs() < 1e-9);
    // A body filling the crop leaves nothing to black out.
    let full = CropBox::new(-50.0, -50.0, 300.0, 300.0).expect("box");
    assert!(around(&full, &crop).is_empty());
}

#[test]
fn pedestrian_settings_outside_their_domain_are_refused_by_name() {
    for (threshold, tiles) in [(0.0, 2), (f32::NAN, 2), (1.5, 2), (0.3, 0), (0.3, 9)] {
        let settings = ImageSettings {
            pedestrian_threshold: threshold,
            pedestrian_tiles: tiles,
            ..ImageSettings::default()
        };
        let err = settings.check().expect_err("refused");
        assert!(err.to_string().contains("pedestrian_"), "{err}");
    }
    assert!(ImageSettings::default().check().is_ok());
}

#[test]
fn motion_settings_outside_their_domain_are_refused_by_name() {
    for bad in [f64::NAN, f64::INFINITY, -1.0, 0.0, 1e300] {
        let settings = ImageSettings {
            motion_min_height: bad,
            ..ImageSettings::default()
        };
        let err = settings.check().expect_err("refused");
        assert!(
            err.to_string().contains("motion_min_height"),
            "{bad}: {err}"
        );
    }
    assert!(ImageSettings::default().check().is_ok());
}

#[test]
fn a_head_is_twice_the_face_landmarks_extent_around_their_centre() {
    let h = head_box(&[[100.0, 200.0], [140.0, 220.0], [120.0, 210.0]]).expect("head");
    assert_eq!((h.x0, h.y0, h.width, h.height), (80.0, 170.0, 80.0, 80.0));
    assert!(head_box(&[[f64::NAN, 0.0]]).is_none());
}

#[test]
fn other_heads_are_masked_but_one_overlapping_the_persons_own() {
    let own = square(100.0, 100.0, 50.0);
    let near = square(130.0, 120.0, 50.0);
    let far = square(500.0, 100.0, 50.0);
    assert_eq!(masks_for(Some(&own), [near, far].into_iter()), vec![far]);
    assert!(masks_for(None, [near, far].into_iter()).is_empty());
}

#[test]
fn a_head_jumps_only_far_and_onto_someone_elses() {
    let before = square(100.0, 100.0, 50.0);
    let other = square(400.0, 100.0, 60.0);
    let moved = square(130.0, 110.0, 50.0);
    let onto_other = square(405.0, 105.0, 50.0);
    let far_away = square(900.0, 100.0, 50.0);
    assert!(!head_jump(&before, &moved, [&other].into_iter()));
    assert!(head_jump(&before, &onto_other, [&other].into_iter()));
    // Far, but onto nobody followed: small faces jitter that much.
    assert!(!head_jump(&before, &far_away, [&other].into_iter()));
    assert!(!head_jump(&before, &onto_other, std::iter::empty()));
}

#[test]
fn a_low_score_box_is_confirmed_only_by_a_face_of_like_size_inside_its_head() {
    let head = square(100.0, 100.0, 60.0);
    // The look's head is twice the landmarks' extent: a 30 px face gives 60 px.
    let same = look_with_face(square(115.0, 115.0, 30.0));
    let none = std::iter::empty;
    assert!(confirms(Some(&head), &same, none()));
    let elsewhere = look_with_face(square(300.0, 115.0, 30.0));
    assert!(!confirms(Some(&head), &elsewhere, none()));
    // On someone's body (a hand held out): a part of them.
    let someone = look_with_face(square(50.0, 50.0, 200.0));
    assert!(!confirms(Some(&head), &same, [&someone].into_iter()));
    let huge = look_with_face(square(30.0, 30.0, 200.0));
    assert!(
        !confirms(Some(&head), &huge, none()),
        "centre inside, 6.7 x the size"
    );
    assert!(!confirms(None, &same, none()));
}
