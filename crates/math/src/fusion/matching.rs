//! Who is who across cameras: each camera's tracks (its detector's ids, which agree with
//! no other camera's) grouped into people by geometry alone.
//!
//! Each frame, for every camera's track ([`TrackObservation`]: its heat maps' peaks as
//! image points):
//! 1. a track bound to a person stays bound while the person's last fused pose, projected
//!    into the track's camera, lands on the track's peaks (the mean distance within
//!    [`MatchSettings::reprojection_gate`] of the track's box size), or its peaks' rays
//!    meet the rays of the person's tracks in other cameras this frame (the joints' ray
//!    distances, median, within [`MatchSettings::ray_gate`] metres); a track neither
//!    test can measure (too few peaks) stays bound;
//! 2. an unbound track joins the person it fits best by the same two tests (one track
//!    per camera and person: a new one replaces an ended one; a camera's tracks and the
//!    people assigned best pair first, on the better of the two normalised costs);
//! 3. tracks still unbound are grouped by their rays, pair by pair across cameras (best
//!    pairs first, every member of a group consistent with the others); each group is a
//!    new person, seen by one camera if alone (a monocular person, until another camera's
//!    track joins it).
//!
//! People whose tracks have all ended for [`MatchSettings::forget_seconds`] are
//! forgotten.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::ViewCamera;
use crate::heatmaps::argmax;
use posestream_base::PixelMap;
use posestream_base::{OutOfDomain, check_real};

/// Settings of the matching (`[estimator.fusion.matching]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MatchSettings {
    /// A person's pose reprojects onto a track when the mean distance of its joints from
    /// the track's peaks is within this fraction of the track's box size.
    pub reprojection_gate: f64,
    /// Two tracks in two cameras see one person when the median distance between their
    /// joints' rays is within this, metres.
    pub ray_gate: f64,
    /// A peak above this counts.
    pub peak_threshold: f64,
    /// A person none of whose tracks has been seen for this long is forgotten, seconds.
    pub forget_seconds: f64,
    /// People known at once at most: tracks that would make more get nobody.
    pub max_people: usize,
}

impl Default for MatchSettings {
    fn default() -> Self {
        Self {
            reprojection_gate: 0.2,
            ray_gate: 0.2,
            peak_threshold: 0.1,
            forget_seconds: 1.0,
            max_people: 12,
        }
    }
}

impl MatchSettings {
    /// Checks every value is in its domain.
    pub fn check(&self) -> Result<(), OutOfDomain> {
        check_real("reprojection_gate", self.reprojection_gate, 0.0, 10.0, true)?;
        check_real("ray_gate", self.ray_gate, 0.0, 100.0, true)?;
        check_real("peak_threshold", self.peak_threshold, 0.0, 1e30, false)?;
        check_real("forget_seconds", self.forget_seconds, 0.0, 3600.0, true)?;
        posestream_base::check_range("max_people", self.max_people, 1, 10_000)
    }
}

/// One camera's track in one frame.
#[derive(Debug, Clone, Copy)]
pub struct TrackObservation<'a> {
    /// The camera.
    pub view: usize,
    /// The camera's id of the track (its detector's; meaningless to other cameras).
    pub track: u64,
    /// Its heat maps' peaks, image pixels, and their scores: `[u, v, score]` per joint.
    pub peaks: &'a [[f64; 3]],
    /// The size of its box, pixels (its crop's larger side).
    pub box_size: f64,
}

/// A person of the matching.
#[derive(Debug, Clone, PartialEq)]
struct Person {
    id: u64,
    /// `(view, track)` bound to the person.
    tracks: Vec<(usize, u64)>,
    last_seen_ns: i64,
    /// The last fused pose, world frame (`[x, y, z]` per joint; empty before one).
    pose: Vec<f64>,
}

/// Groups the cameras' tracks into people (module docs).
#[derive(Debug, Clone)]
pub struct Matcher {
    settings: MatchSettings,
    people: Vec<Person>,
    next_id: u64,
    /// Step 1's tracks that their pose no longer fits: `(track, person)`.
    doubtful: Vec<(usize, usize)>,
}

impl Matcher {
    /// An empty matcher.
    pub fn new(settings: MatchSettings) -> Result<Self, OutOfDomain> {
        settings.check()?;
        Ok(Self {
            settings,
            people: Vec::new(),
            next_id: 1,
            doubtful: Vec::new(),
        })
    }

    /// Notes person `id`'s fused pose (world frame, `[x, y, z]` per joint): what the next
    /// frames' tracks are matched against.
    pub fn set_pose(&mut self, id: u64, joints: &[f64]) {
        if let Some(p) = self.people.iter_mut().find(|p| p.id == id) {
            p.pose.clear();
            p.pose.extend_from_slice(joints);
        }
    }

    /// The people known.
    pub fn people(&self) -> impl Iterator<Item = u64> + '_ {
        self.people.iter().map(|p| p.id)
    }

    /// Forgets everyone (time started again); the ids go on from where they were, so no
    /// id is given twice.
    pub fn forget_all(&mut self) {
        self.people.clear();
        self.doubtful.clear();
    }

    /// Matches one frame's tracks: `out[i]` is the person of `tracks[i]`. Tracks of one
    /// camera with the same id are refused (the second is given no person: `None`).
    pub fn assign(
        &mut self,
        stamp_ns: i64,
        cameras: &[ViewCamera],
        tracks: &[TrackObservation<'_>],
        out: &mut Vec<Option<u64>>,
    ) {
        out.clear();
        out.resize(tracks.len(), None);
        // Time going back further than people are remembered (a replay looping, a
        // clock reset): nobody seen "later" stays.
        let forget = (self.settings.forget_seconds * 1e9) as i64;
        if self
            .people
            .iter()
            .any(|p| p.last_seen_ns.saturating_sub(stamp_ns) > forget)
        {
            self.people.clear();
        }
        let valid: Vec<bool> = tracks
            .iter()
            .enumerate()
            .map(|(i, t)| {
                t.view < cameras.len()
                    && !tracks[..i]
                        .iter()
                        .any(|o| o.view == t.view && o.track == t.track)
            })
            .collect();
        // 1. Bound tracks that still fit: first by their person's pose, then the others
        //    by their rays against every track kept so far. A track neither test can
        //    measure (too few peaks) stays where it is.
        self.doubtful.clear();
        for (i, t) in tracks.iter().enumerate() {
            if !valid[i] {
                continue;
            }
            let Some(k) = self
                .people
                .iter()
                .position(|p| p.tracks.contains(&(t.view, t.track)))
            else {
                continue;
            };
            match self.reprojection_cost(k, &tracks[i], cameras) {
                Some(c) if c > 1.0 => self.doubtful.push((i, k)),
                _ => out[i] = Some(self.people[k].id),
            }
        }
        for d in 0..self.doubtful.len() {
            let (i, k) = self.doubtful[d];
            let t = &tracks[i];
            if self
                .ray_cost(k, i, tracks, out, cameras)
                .is_some_and(|c| c <= 1.0)
            {
                out[i] = Some(self.people[k].id);
            } else {
                self.people[k].tracks.retain(|&b| b != (t.view, t.track));
            }
        }
        // One track per camera and person (bindings from before the rule, or a track
        // back beside its replacement): the first kept, the others go to steps 2-3.
        for i in 0..tracks.len() {
            let Some(id) = out[i] else { continue };
            if (0..i).any(|o| out[o] == Some(id) && tracks[o].view == tracks[i].view) {
                out[i] = None;
                if let Some(p) = self.people.iter_mut().find(|p| p.id == id) {
                    p.tracks.retain(|&b| b != (tracks[i].view, tracks[i].track));
                }
            }
        }
        // 2. Unbound tracks to known people, camera by camera.
        let mut views: Vec<usize> = tracks.iter().map(|t| t.view).collect();
        views.sort_unstable();
        views.dedup();
        for &v in &views {
            let free: Vec<usize> = (0..tracks.len())
                .filter(|&i| valid[i] && out[i].is_none() && tracks[i].view == v)
                .collect();
            let open: Vec<usize> = (0..self.people.len())
                .filter(|&k| {
                    !(0..tracks.len())
                        .any(|i| tracks[i].view == v && out[i] == Some(self.people[k].id))
                })
                .collect();
            if free.is_empty() || open.is_empty() {
                continue;
            }
            let mut pairs = Vec::new();
            for &i in &free {
                for &k in &open {
                    let c = self.cost(k, i, tracks, out, cameras);
                    if c <= 1.0 {
                        pairs.push((c, i, k));
                    }
                }
            }
            // Best pairs first (for the few tracks and people of a camera, as good as
            // the optimal assignment and simpler).
            pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
            let (mut used_i, mut used_k) = (Vec::new(), Vec::new());
            for (_, i, k) in pairs {
                if used_i.contains(&i) || used_k.contains(&k) {
                    continue;
                }
                used_i.push(i);
                used_k.push(k);
                out[i] = Some(self.people[k].id);
                // One track per camera and person: this one replaces an ended one.
                let person = &mut self.people[k];
                person.tracks.retain(|&(view, _)| view != tracks[i].view);
                person.tracks.push((tracks[i].view, tracks[i].track));
            }
        }
        // 3. New people from what is left, grouped by their rays.
        let left: Vec<usize> = (0..tracks.len())
            .filter(|&i| valid[i] && out[i].is_none())
            .collect();
        let mut pairs = Vec::new();
        for (a, &i) in left.iter().enumerate() {
            for &j in &left[a + 1..] {
                if tracks[i].view == tracks[j].view {
                    continue;
                }
                if let Some(d) = self.ray_distance(&tracks[i], &tracks[j], cameras)
                    && d <= self.settings.ray_gate
                {
                    pairs.push((d, i, j));
                }
            }
        }
        pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut groups: Vec<Vec<usize>> = Vec::new();
        let group_of =
            |groups: &Vec<Vec<usize>>, i: usize| groups.iter().position(|g| g.contains(&i));
        for (_, i, j) in pairs {
            match (group_of(&groups, i), group_of(&groups, j)) {
                (None, None) => groups.push(vec![i, j]),
                (Some(g), None) | (None, Some(g)) => {
                    let new = if group_of(&groups, i).is_some() { j } else { i };
                    let fits = groups[g].iter().all(|&m| {
                        tracks[m].view != tracks[new].view
                            && self
                                .ray_distance(&tracks[m], &tracks[new], cameras)
                                .is_some_and(|d| d <= self.settings.ray_gate)
                    });
                    if fits {
                        groups[g].push(new);
                    }
                }
                (Some(_), Some(_)) => {}
            }
        }
        for &i in &left {
            if group_of(&groups, i).is_none() {
                groups.push(vec![i]);
            }
        }
        for g in groups {
            if self.people.len() >= self.settings.max_people {
                break;
            }
            let id = self.next_id;
            self.next_id += 1;
            for &i in &g {
                out[i] = Some(id);
            }
            self.people.push(Person {
                id,
                tracks: g
                    .iter()
                    .map(|&i| (tracks[i].view, tracks[i].track))
                    .collect(),
                last_seen_ns: stamp_ns,
                pose: Vec::new(),
            });
        }
        // Seen now; forgotten after a while unseen.
        for p in &mut self.people {
            if out.contains(&Some(p.id)) {
                p.last_seen_ns = stamp_ns;
            }
        }
        self.people
            .retain(|p| stamp_ns.saturating_sub(p.last_seen_ns) <= forget && !p.tracks.is_empty());
    }

    /// How well track `i` fits person `k`, normalised so that 1 is the gate: the better
    /// of [`Self::reprojection_cost`] and [`Self::ray_cost`]; infinite when neither can
    /// be measured.
    fn cost(
        &self,
        k: usize,
        i: usize,
        tracks: &[TrackObservation<'_>],
        out: &[Option<u64>],
        cameras: &[ViewCamera],
    ) -> f64 {
        let a = self.reprojection_cost(k, &tracks[i], cameras);
        let b = self.ray_cost(k, i, tracks, out, cameras);
        a.into_iter().chain(b).fold(f64::INFINITY, f64::min)
    }

    /// Person `k`'s last pose reprojected onto track `t`: the mean distance of its joints
    /// from the peaks over the gate (`reprojection_gate` of the box); `None` without a
    /// pose or with too few peaks.
    fn reprojection_cost(
        &self,
        k: usize,
        t: &TrackObservation<'_>,
        cameras: &[ViewCamera],
    ) -> Option<f64> {
        let person = &self.people[k];
        if person.pose.is_empty() {
            return None;
        }
        let e = reprojection(
            &person.pose,
            t,
            &cameras[t.view],
            self.settings.peak_threshold,
        )?;
        Some(e / (self.settings.reprojection_gate * t.box_size.max(1.0)))
    }

    /// Track `i`'s rays against those of person `k`'s tracks matched this frame in other
    /// cameras (`out`): the smallest median ray distance over the gate; `None` without
    /// such a track or with too few joints both see.
    fn ray_cost(
        &self,
        k: usize,
        i: usize,
        tracks: &[TrackObservation<'_>],
        out: &[Option<u64>],
        cameras: &[ViewCamera],
    ) -> Option<f64> {
        let id = self.people[k].id;
        let t = &tracks[i];
        tracks
            .iter()
            .enumerate()
            .filter(|&(o, other)| o != i && other.view != t.view && out[o] == Some(id))
            .filter_map(|(_, other)| self.ray_distance(t, other, cameras))
            .map(|d| d / self.settings.ray_gate)
            .reduce(f64::min)
    }

    /// The median over joints both tracks see of the distance between their rays,
    /// metres; `None` with fewer than 4 such joints or when a joint's closest points lie
    /// behind a camera.
    fn ray_distance(
        &self,
        a: &TrackObservation<'_>,
        b: &TrackObservation<'_>,
        cameras: &[ViewCamera],
    ) -> Option<f64> {
        let (ca, cb) = (&cameras[a.view], &cameras[b.view]);
        let (oa, ob) = (ca.centre(), cb.centre());
        let thr = self.settings.peak_threshold;
        let mut d: Vec<f64> = Vec::with_capacity(a.peaks.len());
        for (pa, pb) in a.peaks.iter().zip(b.peaks) {
            if !(is_peak(pa[2], thr) && is_peak(pb[2], thr)) {
                continue;
            }
            let (da, db) = (ca.ray(pa[0], pa[1]), cb.ray(pb[0], pb[1]));
            d.push(ray_gap(oa, da, ob, db)?);
        }
        if d.len() < 4 {
            return None;
        }
        d.sort_by(f64::total_cmp);
        Some(d[d.len() / 2])
    }
}

/// The peaks of one track's maps (`p` maps of `height x width`, row-major), image
/// pixels through `to_image`, with their scores: `[u, v, score]` per joint, into `out`
/// (empty when `maps` is not whole maps of that size).
pub fn peaks_into(
    maps: &[f32],
    height: usize,
    width: usize,
    to_image: &PixelMap,
    out: &mut Vec<[f64; 3]>,
) {
    out.clear();
    // Maps that do not fill whole `height x width` maps give no peaks.
    let Some(n) = height
        .checked_mul(width)
        .filter(|&n| n > 0 && maps.len().is_multiple_of(n))
    else {
        return;
    };
    for map in maps.chunks_exact(n) {
        let (x, y, score) = argmax(map, width);
        let [u, v] = to_image.apply(x, y);
        out.push([u, v, f64::from(score)]);
    }
}

/// A score above the threshold (a NaN score is no peak).
fn is_peak(score: f64, threshold: f64) -> bool {
    score > threshold
}

/// The distance between two rays (origins `o`, unit directions `d`) at their closest
/// points; `None` when those lie behind either origin. Parallel rays: their distance.
fn ray_gap(oa: Vector3<f64>, da: Vector3<f64>, ob: Vector3<f64>, db: Vector3<f64>) -> Option<f64> {
    let w = oa - ob;
    let b = da.dot(&db);
    let denom = 1.0 - b * b;
    if denom < 1e-9 {
        return Some((w - da * da.dot(&w)).norm());
    }
    let (dw_a, dw_b) = (da.dot(&w), db.dot(&w));
    let s = (b * dw_b - dw_a) / denom;
    let t = (dw_b - b * dw_a) / denom;
    if s <= 0.0 || t <= 0.0 {
        return None;
    }
    Some(((oa + da * s) - (ob + db * t)).norm())
}

/// Mean distance (pixels) of a world pose's projection from a track's peaks; `None`
/// with fewer than 4 peaks in front of the camera.
fn reprojection(
    pose: &[f64],
    t: &TrackObservation<'_>,
    camera: &ViewCamera,
    thr: f64,
) -> Option<f64> {
    let (mut sum, mut n) = (0.0, 0);
    for (j, peak) in t.peaks.iter().enumerate() {
        if !is_peak(peak[2], thr) || 3 * j + 2 >= pose.len() {
            continue;
        }
        let p = Vector3::new(pose[3 * j], pose[3 * j + 1], pose[3 * j + 2]);
        let Some(([u, v], _)) = camera.project(&p) else {
            continue;
        };
        sum += (u - peak[0]).hypot(v - peak[1]);
        n += 1;
    }
    (n >= 4).then(|| sum / n as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Intrinsics;
    use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion};

    fn camera(at: Vector3<f64>) -> ViewCamera {
        // Looking at the origin, image down along world -z.
        let forward = (-at).normalize();
        let right = forward.cross(&Vector3::z()).normalize();
        let down = forward.cross(&right);
        let r = nalgebra::Matrix3::from_columns(&[right, down, forward]);
        ViewCamera {
            intrinsics: Intrinsics::new(800.0, 800.0, 640.0, 480.0).expect("valid"),
            world_from_camera: Isometry3::from_parts(
                Translation3::from(at),
                UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix_unchecked(
                    r,
                )),
            ),
        }
    }

    /// A stick figure of 8 joints standing at `x, y`.
    fn figure(x: f64, y: f64) -> Vec<f64> {
        (0..8)
            .flat_map(|j| {
                [
                    x + 0.1 * (j % 2) as f64,
                    y + 0.05 * (j % 3) as f64,
                    0.2 * j as f64,
                ]
            })
            .collect()
    }

    /// A track of camera `view` with these peaks and a 300-pixel box.
    fn seen(view: usize, track: u64, peaks: &[[f64; 3]]) -> TrackObservation<'_> {
        TrackObservation {
            view,
            track,
            peaks,
            box_size: 300.0,
        }
    }

    fn peaks(cam: &ViewCamera, pose: &[f64]) -> Vec<[f64; 3]> {
        pose.chunks_exact(3)
            .map(|q| {
                let ([u, v], _) = cam
                    .project(&Vector3::new(q[0], q[1], q[2]))
                    .expect("in front");
                [u, v, 1.0]
            })
            .collect()
    }

    #[test]
    fn rays_that_meet_are_apart_by_nothing_and_skew_ones_by_their_gap() {
        let o = Vector3::zeros();
        let p = Point3::new(1.0, 2.0, 3.0).coords;
        let ob = Vector3::new(4.0, 0.0, 0.0);
        let gap = ray_gap(o, p.normalize(), ob, (p - ob).normalize()).expect("in front");
        assert!(gap < 1e-12);
        // Two skew lines 0.5 apart along z.
        let gap =
            ray_gap(o, Vector3::x(), Vector3::new(1.0, -1.0, 0.5), Vector3::y()).expect("in front");
        assert!((gap - 0.5).abs() < 1e-12);
        // Closest points behind a camera: not a meeting.
        assert!(ray_gap(o, Vector3::x(), Vector3::new(-1.0, -1.0, 0.5), Vector3::y()).is_none());
    }

    #[test]
    fn a_person_one_camera_sees_first_is_joined_by_the_second_cameras_track() {
        let cams = [
            camera(Vector3::new(5.0, 0.0, 2.0)),
            camera(Vector3::new(0.0, 5.0, 2.0)),
        ];
        let (a, b) = (figure(0.0, 0.0), figure(1.5, -1.0));
        let mut m = Matcher::new(MatchSettings::default()).expect("settings");
        let mut out = Vec::new();
        // Frame 0: camera 0 sees both (ids 7, 9); camera 1 nobody yet.
        let (pa0, pb0) = (peaks(&cams[0], &a), peaks(&cams[0], &b));
        let tracks = [seen(0, 7, &pa0), seen(0, 9, &pb0)];
        m.assign(0, &cams, &tracks, &mut out);
        let (ida, idb) = (out[0].expect("a"), out[1].expect("b"));
        assert_ne!(ida, idb);
        m.set_pose(ida, &a);
        m.set_pose(idb, &b);
        // Frame 1: camera 1 sees them too, under its own ids (in the other order).
        let (pa1, pb1) = (peaks(&cams[1], &a), peaks(&cams[1], &b));
        let tracks = [
            seen(0, 7, &pa0),
            seen(0, 9, &pb0),
            seen(1, 2, &pb1),
            seen(1, 1, &pa1),
        ];
        m.assign(1, &cams, &tracks, &mut out);
        assert_eq!(out, [Some(ida), Some(idb), Some(idb), Some(ida)]);
        assert_eq!(m.people().count(), 2);
        // A track id given twice by one camera: the second gets nobody.
        let tracks = [seen(0, 7, &pa0), seen(0, 7, &pb0)];
        m.assign(2, &cams, &tracks, &mut out);
        assert_eq!(out, [Some(ida), None]);
    }

    #[test]
    fn two_cameras_new_tracks_of_one_person_make_one_person_and_of_two_two() {
        let cams = [
            camera(Vector3::new(5.0, 0.0, 2.0)),
            camera(Vector3::new(0.0, 5.0, 2.0)),
        ];
        let (a, b) = (figure(0.0, 0.0), figure(1.5, -1.0));
        let (pa0, pb0, pa1, pb1) = (
            peaks(&cams[0], &a),
            peaks(&cams[0], &b),
            peaks(&cams[1], &a),
            peaks(&cams[1], &b),
        );
        let tracks = [
            seen(0, 1, &pa0),
            seen(1, 1, &pb1),
            seen(0, 2, &pb0),
            seen(1, 2, &pa1),
        ];
        let mut m = Matcher::new(MatchSettings::default()).expect("settings");
        let mut out = Vec::new();
        m.assign(0, &cams, &tracks, &mut out);
        assert_eq!(out[0], out[3]);
        assert_eq!(out[1], out[2]);
        assert_ne!(out[0], out[1]);
    }

    #[test]
    fn odd_tracks_get_nobody_or_a_person_of_their_own_and_the_unseen_are_forgotten() {
        let cams = [
            camera(Vector3::new(5.0, 0.0, 2.0)),
            camera(Vector3::new(0.0, 5.0, 2.0)),
        ];
        let a = figure(0.0, 0.0);
        let pa0 = peaks(&cams[0], &a);
        let few = &pa0[..2];
        let nan = vec![[f64::NAN, f64::NAN, 1.0]; 8];
        let tracks = [
            // A camera the rig does not have.
            seen(5, 1, &pa0),
            // Two peaks only, and NaN peaks: unmeasurable, a person of their own.
            seen(1, 3, few),
            TrackObservation {
                view: 0,
                track: 4,
                peaks: &nan,
                box_size: f64::NAN,
            },
        ];
        let mut m = Matcher::new(MatchSettings::default()).expect("settings");
        let mut out = Vec::new();
        m.assign(0, &cams, &tracks, &mut out);
        assert_eq!(out[0], None);
        assert!(out[1].is_some() && out[2].is_some() && out[1] != out[2]);
        // Unseen for longer than `forget_seconds`: forgotten.
        m.assign(2_000_000_000, &cams, &[], &mut out);
        assert_eq!(m.people().count(), 0);
    }

    #[test]
    fn a_track_back_beside_its_replacement_does_not_give_a_person_two_of_one_camera() {
        let cams = [
            camera(Vector3::new(5.0, 0.0, 2.0)),
            camera(Vector3::new(0.0, 5.0, 2.0)),
        ];
        let a = figure(0.0, 0.0);
        let pa = peaks(&cams[0], &a);
        let obs = |track| seen(0, track, &pa);
        let mut m = Matcher::new(MatchSettings::default()).expect("settings");
        let mut out = Vec::new();
        m.assign(0, &cams, &[obs(7)], &mut out);
        let id = out[0].expect("a person");
        m.set_pose(id, &a);
        // Track 7 ends, 8 takes its place, then 7 comes back beside 8.
        m.assign(1, &cams, &[obs(8)], &mut out);
        assert_eq!(out, [Some(id)]);
        m.assign(2, &cams, &[obs(8), obs(7)], &mut out);
        assert_eq!(out[0], Some(id));
        assert_ne!(out[1], Some(id), "two tracks of one camera on one person");
    }

    #[test]
    fn people_stay_bounded_when_the_clock_stands_still_and_are_dropped_when_it_goes_back() {
        let cams = [camera(Vector3::new(5.0, 0.0, 2.0))];
        let pa = peaks(&cams[0], &figure(0.0, 0.0));
        let mut m = Matcher::new(MatchSettings::default()).expect("settings");
        let mut out = Vec::new();
        // A new track id every call at one time, nothing to match it by.
        for track in 0..1000 {
            m.assign(0, &cams, &[seen(0, track, &pa)], &mut out);
        }
        assert_eq!(m.people().count(), MatchSettings::default().max_people);
        assert_eq!(out, [None], "beyond the cap: nobody");
        // Seen at 10 s, then time goes back to 0: forgotten.
        let mut m = Matcher::new(MatchSettings::default()).expect("settings");
        m.assign(10_000_000_000, &cams, &[seen(0, 1, &pa)], &mut out);
        m.assign(0, &cams, &[], &mut out);
        assert_eq!(m.people().count(), 0);
        // NaN scores are no peaks; maps that are not whole maps give none.
        let mut p = Vec::new();
        peaks_into(
            &[0.0; 10],
            3,
            3,
            &posestream_base::PixelMap::IDENTITY,
            &mut p,
        );
        assert!(p.is_empty());
        peaks_into(
            &[0.0; 9],
            usize::MAX,
            2,
            &posestream_base::PixelMap::IDENTITY,
            &mut p,
        );
        assert!(p.is_empty());
    }
}
