//! Unit tests of `learnt_floor`.

use super::*;

/// Roots of people walking over the floor of `truth` (camera frame): walkers
/// crossing the view at 3-10 m, each on a line of their own swaying sideways, each
/// scaled about the camera centre by their own size error (`sizes`), their floor
/// `level` metres up, their root bobbing 2 cm and with a little noise.
fn walkers(
    truth: &FloorModel,
    sizes: &[f64],
    frames: usize,
    level: &[f64],
) -> Vec<(u32, Vector3<f64>)> {
    let inverse =
        nalgebra::Isometry3::from_parts(truth.translation().into(), truth.rotation()).inverse();
    let mut out = Vec::new();
    let mut noise = 0x9e37_79b9_u64;
    let mut rand = move || {
        noise ^= noise << 13;
        noise ^= noise >> 7;
        noise ^= noise << 17;
        (noise % 10_000) as f64 / 10_000.0 - 0.5
    };
    for t in 0..frames {
        for (k, size) in sizes.iter().enumerate() {
            let phase = t as f64 / 30.0;
            let ahead = 6.5 + 3.5 * (0.3 * phase + k as f64).sin();
            let left = -2.0 + 2.0 * k as f64 + 0.5 * (0.2 * phase).cos();
            let bob = 0.02 * (6.0 * phase).sin();
            let z = level.get(k).copied().unwrap_or(0.0);
            // A person `size` times too small for the assumed size has their root
            // that much lower.
            let root = nalgebra::Point3::new(
                ahead,
                left,
                z + LearningSettings::default().root_height_m / size + bob,
            );
            let camera = (inverse * root).coords * *size;
            out.push((
                k as u32,
                camera + Vector3::new(rand(), rand(), rand()) * 0.04,
            ));
        }
    }
    out
}

fn learn(points: &[(u32, Vector3<f64>)]) -> FloorLearner {
    let mut l = FloorLearner::new(LearningSettings::default());
    for (id, p) in points {
        l.note(*id, *p);
    }
    l
}

#[test]
fn learns_a_tilted_rolled_floor_from_two_walkers_and_how_sure_it_is() {
    let truth = FloorModel::from_height_pitch_roll(2.5, 20.0, 5.0).expect("floor");
    let l = learn(&walkers(&truth, &[1.0, 1.0], 900, &[]));
    assert_eq!(l.state(), LearningState::Accepted, "{:?}", l.newest());
    let f = l.floor().expect("a floor");
    let (pitch, roll) = f.model.pitch_roll();
    assert!((f.model.height() - 2.5).abs() < 0.05, "{f:?}");
    assert!(
        (pitch - 20.0).abs() < 1.0 && (roll - 5.0).abs() < 1.0,
        "{pitch} {roll}"
    );
    assert!(f.height_fit_std > 0.0 && f.height_fit_std < 0.075, "{f:?}");
    // The reported one adds the size prior's 6 %.
    let prior = crate::metres::POPULATION_SIZE_STD * f.model.height();
    assert!(
        (f.height_std - f.height_fit_std.hypot(prior)).abs() < 1e-12,
        "{f:?}"
    );
    assert!(f.inliers > 0.9, "{f:?}");
}

#[test]
fn a_size_error_scales_the_height_but_keeps_the_tilt() {
    let truth = FloorModel::from_height_pitch_roll(2.0, 15.0, 0.0).expect("floor");
    let l = learn(&walkers(&truth, &[1.12, 1.12], 900, &[]));
    let f = l.floor().expect("a floor");
    let (pitch, _) = f.model.pitch_roll();
    assert!((f.model.height() / 2.0 - 1.12).abs() < 0.03, "{f:?}");
    assert!((pitch - 15.0).abs() < 1.0, "{pitch}");
    // As reported: 12 % off is 1.8 standard deviations of a 6 % prior (of 2.24 m).
    let off = (f.model.height() - 2.0) / f.height_std;
    assert!(off > 1.6 && off < 2.0, "{off} {f:?}");
}

#[test]
fn people_of_different_sizes_agree_on_the_tilt_and_average_the_height() {
    let truth = FloorModel::from_height_pitch_roll(2.0, 25.0, -4.0).expect("floor");
    let l = learn(&walkers(&truth, &[0.92, 1.1], 900, &[]));
    assert_eq!(l.state(), LearningState::Accepted, "{:?}", l.newest());
    let f = l.floor().expect("a floor");
    let (pitch, roll) = f.model.pitch_roll();
    assert!(
        (pitch - 25.0).abs() < 1.0 && (roll + 4.0).abs() < 1.0,
        "{pitch} {roll}"
    );
    let (low, high) = f.heights;
    assert!(
        (low / 2.0 - 0.92).abs() < 0.03 && (high / 2.0 - 1.1).abs() < 0.03,
        "{f:?}"
    );
    // The median over points: one of the two people's.
    assert!(
        (f.model.height() - low).abs() < 1e-9 || (f.model.height() - high).abs() < 1e-9,
        "{f:?}"
    );
}

#[test]
fn people_on_two_levels_are_rejected_and_nothing_is_trusted() {
    let truth = FloorModel::from_height_pitch_roll(2.5, 20.0, 0.0).expect("floor");
    let l = learn(&walkers(&truth, &[1.0, 1.0], 900, &[0.0, 0.8]));
    assert!(
        matches!(l.state(), LearningState::Rejected(Rejection::Levels { .. })),
        "{:?} {:?}",
        l.state(),
        l.newest()
    );
    assert!(l.floor().is_none());
}

#[test]
fn one_walker_on_one_line_is_still_learning() {
    let truth = FloorModel::from_height_pitch_roll(2.0, 10.0, 0.0).expect("floor");
    // Walking straight toward the camera and back: the roll about that line is not
    // seen.
    let inverse =
        nalgebra::Isometry3::from_parts(truth.translation().into(), truth.rotation()).inverse();
    let points: Vec<(u32, Vector3<f64>)> = (0..900)
        .map(|t| {
            let ahead = 6.0 + 3.0 * (t as f64 / 60.0).sin();
            (
                1,
                (inverse
                    * nalgebra::Point3::new(ahead, 0.0, LearningSettings::default().root_height_m))
                .coords,
            )
        })
        .collect();
    let l = learn(&points);
    assert_eq!(l.state(), LearningState::Learning, "{:?}", l.newest());
    assert!(l.floor().is_none());
    // A fit was made, and found too narrow.
    let newest = l.newest().expect("a fit");
    assert!(newest.spread < 0.1, "{newest:?}");
}

#[test]
fn a_camera_below_the_people_s_pelvises_learns_too() {
    // A small robot's camera 0.6 m up, looking 5 degrees up at people.
    let truth = FloorModel::from_height_pitch_roll(0.6, -5.0, 0.0).expect("floor");
    let l = learn(&walkers(&truth, &[1.0, 1.0], 900, &[]));
    assert_eq!(l.state(), LearningState::Accepted, "{:?}", l.newest());
    let f = l.floor().expect("a floor");
    let (pitch, roll) = f.model.pitch_roll();
    assert!((f.model.height() - 0.6).abs() < 0.03, "{f:?}");
    assert!(
        (pitch + 5.0).abs() < 1.0 && roll.abs() < 1.0,
        "{pitch} {roll}"
    );
}

#[test]
fn a_trusted_floor_stays_through_a_gap_and_huge_roots_are_not_taken() {
    let truth = FloorModel::from_height_pitch_roll(2.5, 20.0, 0.0).expect("floor");
    let mut l = learn(&walkers(&truth, &[1.0, 1.0], 900, &[]));
    let trusted = *l.floor().expect("a floor");
    assert!(!l.note(1, Vector3::new(1e300, 0.0, 1.0)));
    assert!(!l.note(1, Vector3::new(2e4, 0.0, 1.0)));
    assert_eq!(l.floor(), Some(&trusted));
}

#[test]
fn too_few_or_non_finite_points_give_no_fit() {
    let mut l = FloorLearner::new(LearningSettings::default());
    for _ in 0..100 {
        assert!(!l.note(1, Vector3::new(0.0, 1.0, 5.0)));
    }
    assert!(!l.note(1, Vector3::new(f64::NAN, 1.0, 5.0)));
    assert_eq!(l.points(), 100);
    assert_eq!(l.state(), LearningState::Learning);
}
