//! The estimator's unit tests.

use super::*;
use crate::solver::normalise::heatmap_scale;

/// The window's initialisation puts a left/right pair back in the track's order
/// when its peaks jumped to each other's places (a detector's swap), not when two
/// limbs merely cross in the image (the pair's peaks near each other, a little
/// nearer each other's previous place): that put a kick on the mirrored side.
#[test]
fn a_swap_is_put_back_and_two_limbs_crossing_are_not() {
    let skeleton = crate::skeleton::default_layout();
    let p = skeleton.len();
    let basis: Vec<f64> = (0..3 * p).map(|i| ((i * 7) % 11) as f64 / 11.0).collect();
    let dict = Dictionary::new(skeleton, basis, vec![0.0; 3 * p]).expect("dictionary");
    let &(l, r) = dict.left_right_pairs().first().expect("a left/right pair");
    let est = Estimator::new(dict, Params::default()).expect("estimator");
    let (h, w) = (64, 64);
    let scale = heatmap_scale(h);
    // Every joint in its own column of row 40, the pair at columns 10 and 20.
    let home = |j: usize| -> usize {
        if j == l {
            10
        } else if j == r {
            20
        } else {
            24 + j
        }
    };
    let previous: Vec<f64> = (0..p)
        .flat_map(|j| [home(j) as f64 / scale, 40.0 / scale])
        .collect();
    // (left's column, right's column, put back?), summed squared distances swapped
    // against as they are: a clean swap 0 against 200; a swap with noise 25 against
    // 85 (put back under a margin up to 3.4); crossing 41 against 61 (put back under
    // a margin of 1).
    for (cl, cr, back) in [(20, 10, true), (17, 14, true), (16, 15, false)] {
        let mut maps = vec![0.0_f32; p * h * w];
        for j in 0..p {
            let c = if j == l {
                cl
            } else if j == r {
                cr
            } else {
                home(j)
            };
            maps[j * h * w + 40 * w + c] = 1.0;
        }
        let (mut xy, mut visible) = (vec![0.0; 2 * p], vec![false; p]);
        let pairs = est.dictionary().left_right_pairs().len();
        let (mut reference, mut runs) = (previous.clone(), vec![0; pairs]);
        let mut fit = FrameFit::zero(est.dictionary().num_bases());
        est.initialise_from_argmax(
            |j| &maps[j * h * w..(j + 1) * h * w],
            w,
            scale,
            &mut xy,
            &mut visible,
            est.params(),
            Some((&mut reference, &mut runs)),
            &mut InitWorkspace::default(),
            &mut fit,
        );
        let left = (xy[2 * l] * scale).round() as usize;
        assert_eq!(left, if back { cr } else { cl }, "{cl}, {cr}");
        // The track's reference follows the frame, as put back.
        assert_eq!(reference, xy, "{cl}, {cr}");
    }
}
