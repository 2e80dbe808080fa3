//! The plain baseline the fusion is measured against: no model at all. Each joint's
//! heat-map peaks triangulated across the views that see it (a DLT weighted by the
//! peak's height), all of them when they agree (every view's reprojection within
//! [`TriangulationSettings::agree_px`] pixels), else the pair of views that agrees
//! best; then each joint's coordinates the median of [`TriangulationSettings::median_frames`]
//! frames centred on the one put out (so it comes out that many frames' half late).
//!
//! What a lab script does with calibrated cameras and a 2D detector's peaks; the fusion
//! (dictionary, smoothness, size) has to beat it where the views agree.

use nalgebra::{Matrix4, SymmetricEigen, Vector3, Vector4};
use serde::{Deserialize, Serialize};

use super::camera::ViewCamera;

/// How the baseline triangulates and smooths.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TriangulationSettings {
    /// Every view's reprojection within this (pixels): all views are used; else the
    /// pair of views whose worse reprojection is smallest.
    pub agree_px: f64,
    /// Frames of the centred median per joint coordinate (odd; 1: none).
    pub median_frames: usize,
    /// Peaks scoring this or less are no view of the joint.
    pub min_score: f64,
}

impl Default for TriangulationSettings {
    fn default() -> Self {
        Self {
            agree_px: 15.0,
            median_frames: 5,
            min_score: 0.0,
        }
    }
}

/// One view of a joint: its camera, the peak (image pixels) and the peak's height.
#[derive(Debug, Clone, Copy)]
pub struct PeakView {
    /// The camera.
    pub camera: ViewCamera,
    /// The peak, image pixels.
    pub pixel: [f64; 2],
    /// The peak's height (the DLT's weight).
    pub score: f64,
}

/// The weighted DLT point of `views` (two or more), world frame; `None` when the views
/// leave it undetermined (parallel rays, fewer than two views, non-finite values) or
/// it lies behind one of the cameras.
pub fn dlt(views: &[PeakView]) -> Option<Vector3<f64>> {
    if views.len() < 2 {
        return None;
    }
    let mut normal = Matrix4::<f64>::zeros();
    for v in views {
        let k = &v.camera.intrinsics;
        // Normalised image coordinates (K^-1 applied): the rows are on the scale of the
        // rays, not of the pixels.
        let x = (v.pixel[0] - k.cx) / k.fx;
        let y = (v.pixel[1] - k.cy) / k.fy;
        let pose = v.camera.world_from_camera.inverse();
        let r = pose.rotation.to_rotation_matrix();
        let t = pose.translation.vector;
        let row = |i: usize| Vector4::new(r[(i, 0)], r[(i, 1)], r[(i, 2)], t[i]);
        let (p1, p2, p3) = (row(0), row(1), row(2));
        for a in [p3 * x - p1, p3 * y - p2] {
            normal += v.score * a * a.transpose();
        }
    }
    if !normal.iter().all(|v| v.is_finite()) {
        return None;
    }
    // Bounded iterations: a decomposition that does not converge is no point.
    let eig = SymmetricEigen::try_new(normal, f64::EPSILON, 200)?;
    let (mut smallest, mut second) = (0, 1);
    for i in 0..4 {
        if eig.eigenvalues[i] < eig.eigenvalues[smallest] {
            smallest = i;
        }
    }
    if smallest == second {
        second = 0;
    }
    for i in 0..4 {
        if i != smallest && eig.eigenvalues[i] < eig.eigenvalues[second] {
            second = i;
        }
    }
    // A second direction nearly as good: the rays leave the point undetermined.
    if eig.eigenvalues[second] <= 1e-12 * eig.eigenvalues.max().max(f64::MIN_POSITIVE) {
        return None;
    }
    let h = eig.eigenvectors.column(smallest);
    if h[3].abs() < 1e-12 {
        return None;
    }
    let point = Vector3::new(h[0], h[1], h[2]) / h[3];
    let in_front = views.iter().all(|v| v.camera.to_camera(&point).z > 0.0);
    (in_front && point.iter().all(|v| v.is_finite())).then_some(point)
}

/// The largest reprojection distance (pixels) of `point` over `views` (infinite when it
/// is behind one of them).
pub(super) fn worst_reprojection(point: &Vector3<f64>, views: &[PeakView]) -> f64 {
    views
        .iter()
        .map(|v| match v.camera.project(point) {
            Some(([u, w], _)) => (u - v.pixel[0]).hypot(w - v.pixel[1]),
            None => f64::INFINITY,
        })
        .fold(0.0, f64::max)
}

/// One joint from its `views`: all of them when every reprojection is within
/// `agree_px`, else the best-agreeing pair's point; `None` with fewer than two views or
/// no determined point.
pub fn robust_point(views: &[PeakView], agree_px: f64) -> Option<Vector3<f64>> {
    let all = dlt(views)?;
    if views.len() == 2 || worst_reprojection(&all, views) <= agree_px {
        return Some(all);
    }
    let mut best: Option<(f64, Vector3<f64>)> = None;
    for a in 0..views.len() {
        for b in a + 1..views.len() {
            let pair = [views[a], views[b]];
            let Some(p) = dlt(&pair) else { continue };
            let worst = worst_reprojection(&p, &pair);
            if best.is_none_or(|(w, _)| worst < w) {
                best = Some((worst, p));
            }
        }
    }
    best.map(|(_, p)| p).or(Some(all))
}

/// The baseline over a stream of frames: each pushed frame's joints triangulated, the
/// frame `median_frames / 2` back put out as the centred median per joint coordinate.
/// A joint no view pair determined in a frame is left out of that frame's median; a
/// joint determined in none of the median's frames keeps its last value. Buffers are
/// kept: pushing allocates nothing once the window is full.
#[derive(Debug, Clone)]
pub struct Triangulator {
    settings: TriangulationSettings,
    joints: usize,
    /// The newest `median_frames` frames' points, oldest first (`None`: undetermined).
    frames: std::collections::VecDeque<Vec<Option<Vector3<f64>>>>,
    /// Each joint's last value put out.
    last: Vec<Option<Vector3<f64>>>,
    values: Vec<f64>,
    views: Vec<PeakView>,
}

impl Triangulator {
    /// A baseline for people of `joints` joints.
    pub fn new(joints: usize, settings: TriangulationSettings) -> Self {
        let settings = TriangulationSettings {
            median_frames: settings.median_frames.max(1),
            ..settings
        };
        Self {
            settings,
            joints,
            frames: std::collections::VecDeque::with_capacity(settings.median_frames),
            last: vec![None; joints],
            values: Vec::with_capacity(settings.median_frames),
            views: Vec::new(),
        }
    }

    /// Frames between a pushed frame and its output.
    pub fn lag(&self) -> usize {
        self.settings.median_frames / 2
    }

    /// Starts over (a new person, or a jump in time).
    pub fn reset(&mut self) {
        self.frames.clear();
        self.last.fill(None);
    }

    /// Pushes a frame: per view, its camera and its peaks (`[u, v, score]` per joint,
    /// image pixels, as [`super::matching::peaks_into`] gives them). Writes the joints
    /// (`[x, y, z]` per joint, world frame) of the frame [`Self::lag`] back into `out`
    /// and returns true once that frame exists and every joint has a value.
    pub fn push(&mut self, views: &[(&ViewCamera, &[[f64; 3]])], out: &mut Vec<f64>) -> bool {
        let mut frame = if self.frames.len() == self.settings.median_frames {
            self.frames.pop_front().unwrap_or_default()
        } else {
            Vec::with_capacity(self.joints)
        };
        frame.clear();
        for j in 0..self.joints {
            self.views.clear();
            for (camera, peaks) in views {
                let Some(&[u, v, score]) = peaks.get(j) else {
                    continue;
                };
                if score > self.settings.min_score && u.is_finite() && v.is_finite() {
                    self.views.push(PeakView {
                        camera: **camera,
                        pixel: [u, v],
                        score,
                    });
                }
            }
            frame.push(robust_point(&self.views, self.settings.agree_px));
        }
        self.frames.push_back(frame);
        let centre = self.lag();
        if self.frames.len() <= centre {
            return false;
        }
        out.clear();
        let mut whole = true;
        for j in 0..self.joints {
            let mut value = Vector3::zeros();
            let mut any = false;
            for k in 0..3 {
                self.values.clear();
                self.values
                    .extend(self.frames.iter().filter_map(|f| f[j].map(|p| p[k])));
                let Some(m) = median(&mut self.values) else {
                    break;
                };
                value[k] = m;
                any = true;
            }
            let value = if any { Some(value) } else { self.last[j] };
            self.last[j] = value;
            match value {
                Some(p) => out.extend([p.x, p.y, p.z]),
                None => {
                    whole = false;
                    out.extend([f64::NAN; 3]);
                }
            }
        }
        whole
    }
}

/// The median of `values` (the two middle ones' mean for an even count; sorted in
/// place), `None` when empty.
pub(super) fn median(values: &mut [f64]) -> Option<f64> {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    match n {
        0 => None,
        _ if !n.is_multiple_of(2) => Some(values[n / 2]),
        _ => Some(0.5 * (values[n / 2 - 1] + values[n / 2])),
    }
}

#[cfg(test)]
mod tests {
    use super::super::camera::ring;
    use super::*;

    fn peak(camera: &ViewCamera, p: &Vector3<f64>, noise: [f64; 2]) -> PeakView {
        let ([u, v], _) = camera.project(p).expect("in front");
        PeakView {
            camera: *camera,
            pixel: [u + noise[0], v + noise[1]],
            score: 1.0,
        }
    }

    #[test]
    fn exact_peaks_give_the_point_back() {
        let cams = ring(3, 5.0);
        for c in &cams {
            assert!(
                c.to_camera(&Vector3::new(0.0, 0.0, 1.0)).z > 4.0,
                "looks at the room"
            );
        }
        let p = Vector3::new(0.3, -0.2, 1.4);
        let views: Vec<PeakView> = cams.iter().map(|c| peak(c, &p, [0.0; 2])).collect();
        let got = dlt(&views).expect("determined");
        assert!((got - p).norm() < 1e-9, "{got} against {p}");
        assert!(dlt(&views[..1]).is_none(), "one view determines nothing");
    }

    #[test]
    fn one_wrong_view_is_outvoted_by_the_pair_that_agrees() {
        let cams = ring(3, 5.0);
        let p = Vector3::new(0.1, 0.2, 1.0);
        // The third camera's peak is a swapped joint 60 px away.
        let views = [
            peak(&cams[0], &p, [1.0, -1.0]),
            peak(&cams[1], &p, [-1.0, 0.5]),
            peak(&cams[2], &p, [60.0, 0.0]),
        ];
        let all = dlt(&views).expect("determined");
        let robust = robust_point(&views, 15.0).expect("determined");
        assert!(
            (all - p).norm() > 0.05,
            "the wrong view drags all three: {}",
            (all - p).norm()
        );
        assert!(
            (robust - p).norm() < 0.01,
            "the pair holds: {}",
            (robust - p).norm()
        );
    }

    #[test]
    fn the_median_removes_a_one_frame_jump_and_lags_by_half_its_frames() {
        let cams = ring(2, 5.0);
        let p = Vector3::new(0.0, 0.0, 1.2);
        let mut t = Triangulator::new(1, TriangulationSettings::default());
        assert_eq!(t.lag(), 2);
        let mut out = Vec::new();
        let mut got = Vec::new();
        for frame in 0..7 {
            // Frame 3 jumps 0.5 m.
            let q = if frame == 3 {
                p + Vector3::new(0.5, 0.0, 0.0)
            } else {
                p
            };
            let peaks: Vec<[f64; 3]> = cams
                .iter()
                .map(|c| {
                    let ([u, v], _) = c.project(&q).expect("in front");
                    [u, v, 1.0]
                })
                .collect();
            let views: Vec<(&ViewCamera, &[[f64; 3]])> = cams
                .iter()
                .zip(&peaks)
                .map(|(c, pk)| (c, std::slice::from_ref(pk)))
                .collect();
            if t.push(&views, &mut out) {
                got.push(Vector3::new(out[0], out[1], out[2]));
            }
        }
        // Frames 0-4 come out (frames 2-6 pushed), none with the jump.
        assert_eq!(got.len(), 5);
        for g in got {
            assert!((g - p).norm() < 1e-6, "{g}");
        }
    }

    #[test]
    fn nothing_seen_twice_gives_no_frame_and_never_panics() {
        let cams = ring(2, 5.0);
        let mut t = Triangulator::new(2, TriangulationSettings::default());
        let mut out = Vec::new();
        let nan = [[f64::NAN, 1.0, 1.0], [1.0, 2.0, 0.0]];
        let short: [[f64; 3]; 0] = [];
        for _ in 0..6 {
            let views: Vec<(&ViewCamera, &[[f64; 3]])> = vec![(&cams[0], &nan), (&cams[1], &short)];
            assert!(!t.push(&views, &mut out));
        }
        assert_eq!(out.len(), 6);
        assert!(out.iter().all(|v| v.is_nan()));
    }
}
