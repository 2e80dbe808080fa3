//! The floor under the camera, and a person's size learnt from where their feet touch it.
//!
//! From one camera a person twice as large and twice as far gives the same image: the
//! metric step ([`crate::metres`]) places a skeleton of an assumed size, so its distance
//! is off by as much as the person's size is (and by the fitted pose's flatness in depth,
//! a bias of its own: a flatter pose projects larger, so it is put further away). Feet on
//! a known floor fix it: the ankle in contact lies on the plane through its ray, and
//! scaling the scene about the camera centre (which changes no image) by the factor that
//! puts it there gives the body's position and size at once.
//!
//! - [`FloorModel`]: the camera's pose over the floor (a plane, `z = 0` of a floor frame,
//!   REP-103 axes: x forward, y left, z up), from a transform (a TF tree's
//!   `floor_frame -> camera frame`) or from a height, pitch and roll
//!   ([`FloorModel::from_height_pitch_roll`]).
//! - [`BodyScale`]: one person's scale factors from their contacts over a window of
//!   frames, its median and spread ([`BodyScale::estimate`]).

use nalgebra::{Rotation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use posestream_base::{OutOfDomain, check_range, check_real};

/// Where the floor comes from (`[estimator.metric.floor] source`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FloorSource {
    /// No floor: the metric scale is the assumed body size's.
    #[default]
    None,
    /// The height, pitch and roll of [`FloorSettings`].
    Config,
    /// The transform from [`FloorSettings::frame`] to the images' camera frame, read from
    /// `/tf_static` and `/tf` (a live ROS 2 graph's or a recording's).
    Tf,
    /// Learnt from the roots of people standing and walking ([`crate::learnt_floor`]):
    /// its tilt, and its height as well as the assumed body size fits the people seen.
    Learnt,
}

/// Settings of the floor (`[estimator.metric.floor]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FloorSettings {
    /// Where the floor comes from.
    pub source: FloorSource,
    /// `config`: the camera's optical centre above the floor, metres.
    pub height: f64,
    /// `config`: the camera's pitch, degrees, positive looking down.
    pub pitch: f64,
    /// `config`: its roll about the optical axis, degrees, positive turning the camera's
    /// top to its right (REP-103's roll of the camera's body frame, x forward).
    pub roll: f64,
    /// `tf`: the floor frame (`z = 0` is the floor, z up: REP-105's `base_footprint`, or
    /// `map` on a flat floor).
    pub frame: String,
    /// `config` and `learnt`: the floor frame posestream publishes on `/tf`, under the
    /// camera frame (the people's footprints under it); empty: none. Not one of a
    /// robot's own REP-105 frames, which have parents of their own.
    pub published_frame: String,
    /// An ankle on the floor is this far above it, in mean bone lengths of the person
    /// (the ankle joint, not the sole; it grows with the body): the training takes'
    /// ankles stand 0.117 m high on a mean bone length of 0.2235 m.
    pub ankle_height: f64,
    /// Frames of contacts a person's size is estimated over (the median of their scale
    /// factors).
    pub contact_frames: usize,
    /// A contact is trusted only when its scale factor lies within this factor of 1 (the
    /// assumed size): 1.5 takes people from 1/1.5 to 1.5 times the assumed size. (A foot
    /// off the floor is told by its own evidence: `crate::metres`.)
    pub max_scale: f64,
    /// `learnt`: a standing or walking person's root (the pelvis) is this far above the
    /// floor, in mean bone lengths (the training takes': 0.883 m on 0.2235 m).
    pub root_height: f64,
    /// A skeleton placed by the floor: its `position_std` (the 2D spread along the rays,
    /// the contacts' spread and a learnt floor's own at the person's distance, composed)
    /// times this. 0.55: on the training walks 69 % of the per-axis errors fell within
    /// 0.55 of the composed standard deviation at the size 0.25 m, 67 % at the size prior
    /// (their tails are heavier than a normal distribution's: 89 and 88 % within 2).
    pub std_factor: f64,
}

impl Default for FloorSettings {
    fn default() -> Self {
        Self {
            source: FloorSource::None,
            height: 0.0,
            pitch: 0.0,
            roll: 0.0,
            frame: "base_footprint".into(),
            published_frame: "posestream_floor".into(),
            ankle_height: 0.52,
            contact_frames: 60,
            max_scale: 1.5,
            root_height: 3.95,
            std_factor: 0.55,
        }
    }
}

impl FloorSettings {
    /// Checks every value is in its domain (the `config` floor's too, when it is the
    /// source).
    pub fn check(&self) -> Result<(), OutOfDomain> {
        if self.source == FloorSource::Config {
            FloorModel::from_height_pitch_roll(self.height, self.pitch, self.roll)?;
        }
        if self.source == FloorSource::Tf && !valid_frame_id(&self.frame) {
            return Err(OutOfDomain::new(
                "frame",
                "a TF frame id (letters, digits, _ and /)",
                format!("{:?}", self.frame),
            ));
        }
        let published = self.published_frame.trim_start_matches('/');
        if !self.published_frame.is_empty()
            && (!valid_frame_id(&self.published_frame) || ROBOT_FRAMES.contains(&published))
        {
            return Err(OutOfDomain::new(
                "published_frame",
                "empty, or a TF frame id (letters, digits, _ and /) that is not one of a \
                 robot's own (map, odom, earth, base_link, base_footprint): it is published \
                 under the camera frame",
                format!("{:?}", self.published_frame),
            ));
        }
        check_real("ankle_height", self.ankle_height, 0.0, 2.0, false)?;
        check_range("contact_frames", self.contact_frames, 1, 10_000)?;
        check_real("max_scale", self.max_scale, 1.0, 10.0, true)?;
        check_real("root_height", self.root_height, 0.5, 20.0, false)?;
        check_real("std_factor", self.std_factor, 0.0, 10.0, true)
    }

    /// The floor of the `config` source (`None` for the others).
    pub fn configured(&self) -> Option<FloorModel> {
        match self.source {
            FloorSource::Config => {
                FloorModel::from_height_pitch_roll(self.height, self.pitch, self.roll).ok()
            }
            FloorSource::None | FloorSource::Tf | FloorSource::Learnt => None,
        }
    }
}

/// REP-105's frames: a robot's own, with parents of their own.
const ROBOT_FRAMES: [&str; 5] = ["map", "odom", "earth", "base_link", "base_footprint"];

/// A TF frame id: not empty, at most 256 bytes, ASCII letters, digits, `_` and `/`.
pub fn valid_frame_id(id: &str) -> bool {
    !id.is_empty()
        && id.len() <= 256
        && id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'/')
}

/// The camera's pose over a flat floor: the camera frame (x right, y down, z forward) in
/// a floor frame whose `z = 0` is the floor, z up.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FloorModel {
    /// The camera frame's axes in the floor frame.
    rotation: UnitQuaternion<f64>,
    /// The camera's centre in the floor frame (`z`: its height).
    translation: Vector3<f64>,
    /// The floor's up direction in the camera frame.
    up: Vector3<f64>,
}

/// How far off a floor may be: a learnt floor's standard deviations (a floor from the
/// configuration or TF is taken as exact).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FloorStd {
    /// The camera's height, metres.
    pub height: f64,
    /// Its pitch, radians.
    pub pitch: f64,
}

impl FloorStd {
    /// The relative standard deviation of the distance to a point of `floor` that is
    /// `horizontal` metres from the point under the camera: the point's ray meets the
    /// floor at `d = h / tan(angle)`, so a height off by `dh` moves it by `dh / h` of
    /// itself, a pitch off by `da` by `da (h^2 + d^2) / (h d)` (grazing rays the most).
    /// At most 1 (a point under the camera, whose distance no pitch error moves much,
    /// is where the formula runs away).
    pub fn distance(&self, floor: &FloorModel, horizontal: f64) -> f64 {
        let h = floor.height();
        let d = horizontal.max(1e-3);
        (self.height / h)
            .hypot(self.pitch * (h * h + d * d) / (h * d))
            .min(1.0)
    }
}

/// The camera frame (x right, y down, z forward) in its body frame (x forward, y left,
/// z up): the `camera_link -> camera_optical_frame` rotation of REP-103.
fn optical_in_body() -> Rotation3<f64> {
    Rotation3::from_matrix_unchecked(nalgebra::Matrix3::new(
        0.0, 0.0, 1.0, //
        -1.0, 0.0, 0.0, //
        0.0, -1.0, 0.0,
    ))
}

impl FloorModel {
    /// The floor of a camera frame placed in the floor frame by `rotation` (the camera
    /// frame's axes) and `translation` (its centre): refused when a value is not finite
    /// or the camera is not above the floor (by 1 cm at least, 1 km at most).
    pub fn new(
        rotation: UnitQuaternion<f64>,
        translation: Vector3<f64>,
    ) -> Result<Self, OutOfDomain> {
        let finite = rotation.coords.iter().chain(translation.iter());
        if !finite.clone().all(|v| v.is_finite()) {
            return Err(OutOfDomain::new(
                "floor transform",
                "finite",
                format!(
                    "rotation {:?}, translation {:?}",
                    rotation.coords, translation
                ),
            ));
        }
        check_real("height", translation.z, 0.01, 1000.0, false)?;
        let up = rotation.inverse() * Vector3::z();
        Ok(Self {
            rotation,
            translation,
            up,
        })
    }

    /// The floor under a camera `height` metres above it, pitched down by `pitch_deg`
    /// and rolled by `roll_deg` (REP-103's roll and pitch of the camera's body frame;
    /// the floor frame's x is the camera's heading).
    pub fn from_height_pitch_roll(
        height: f64,
        pitch_deg: f64,
        roll_deg: f64,
    ) -> Result<Self, OutOfDomain> {
        check_real("pitch", pitch_deg, -90.0, 90.0, true)?;
        check_real("roll", roll_deg, -180.0, 180.0, false)?;
        let body = Rotation3::from_euler_angles(roll_deg.to_radians(), pitch_deg.to_radians(), 0.0);
        let rotation = UnitQuaternion::from_rotation_matrix(&(body * optical_in_body()));
        Self::new(rotation, Vector3::new(0.0, 0.0, height))
    }

    /// The camera's height above the floor, metres.
    pub fn height(&self) -> f64 {
        self.translation.z
    }

    /// The floor's up direction in the camera frame (a unit vector).
    pub fn up(&self) -> Vector3<f64> {
        self.up
    }

    /// The camera frame's axes in the floor frame.
    pub fn rotation(&self) -> UnitQuaternion<f64> {
        self.rotation
    }

    /// The camera's centre in the floor frame.
    pub fn translation(&self) -> Vector3<f64> {
        self.translation
    }

    /// The camera's pitch and roll, degrees (as [`FloorModel::from_height_pitch_roll`]
    /// takes them).
    pub fn pitch_roll(&self) -> (f64, f64) {
        let body = self.rotation.to_rotation_matrix() * optical_in_body().inverse();
        let (roll, pitch, _) = body.euler_angles();
        (pitch.to_degrees(), roll.to_degrees())
    }

    /// Height above the floor of a point in the camera frame, metres.
    pub fn height_of(&self, p: &Vector3<f64>) -> f64 {
        self.up.dot(p) + self.translation.z
    }

    /// A point of the camera frame in the floor frame.
    pub fn to_floor(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * p + self.translation
    }

    /// The factor `t > 0` that puts `t p` (a point in the camera frame, on its ray)
    /// `above` metres over the floor; `None` when no point of that ray in front of the
    /// camera is (a ray at or above the horizon).
    pub fn scale_to(&self, p: &Vector3<f64>, above: f64) -> Option<f64> {
        let rate = self.up.dot(p);
        let t = (above - self.translation.z) / rate;
        (t.is_finite() && t > 0.0 && p.z * t > 0.0).then_some(t)
    }
}

/// One person's scale factors from floor contacts over the last frames
/// ([`FloorSettings::contact_frames`]): the factor that moves a skeleton of the assumed
/// size along the rays onto the floor, one per frame (a frame's refined estimate
/// replaces its first one). Its buffers are allocated once.
#[derive(Debug, Clone, Default)]
pub struct BodyScale {
    /// `(frame sequence, ln factor)`, oldest first.
    contacts: std::collections::VecDeque<(u64, f64)>,
    capacity: usize,
    scratch: Vec<f64>,
    /// `(frame sequence, its feet in the image)`, oldest first (at most `FEET_FRAMES`):
    /// a foot on the floor stands still.
    feet: std::collections::VecDeque<(u64, [[f64; 2]; MAX_FEET])>,
    /// Of `contacts`, the newest this many were noted since the person's track began
    /// (or resumed, [`BodyScale::suspend`]).
    fresh: usize,
}

/// Feet a [`BodyScale`] follows at most (a skeleton's ankles: 2).
pub const MAX_FEET: usize = 4;
/// Frames of feet a [`BodyScale`] keeps (more than the lag between a frame's first
/// estimate and its refined one, so that each finds the frame before it).
const FEET_FRAMES: usize = 64;
/// A foot's speed is measured against a frame at most this many frames before.
const FEET_GAP: u64 = 3;

/// A person's scale factor and its relative spread ([`BodyScale::estimate`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScaleEstimate {
    /// The median factor.
    pub factor: f64,
    /// The factors' relative spread about it (1.4826 times their median absolute
    /// deviation in `ln`): how far one frame's may be.
    pub spread: f64,
    /// Contacts it is made of.
    pub contacts: usize,
}

impl BodyScale {
    /// Keeps the last `frames` contacts.
    pub fn new(frames: usize) -> Self {
        let capacity = frames.max(1);
        Self {
            contacts: std::collections::VecDeque::with_capacity(capacity + 1),
            capacity,
            scratch: Vec::with_capacity(capacity + 1),
            feet: std::collections::VecDeque::with_capacity(FEET_FRAMES + 1),
            fresh: 0,
        }
    }

    /// The person's track ended: their feet are forgotten, their contacts kept (their
    /// size, for when they come back under their id), counted as not fresh.
    pub fn suspend(&mut self) {
        self.feet.clear();
        self.fresh = 0;
    }

    /// Contacts noted since the track began or resumed ([`BodyScale::suspend`]).
    pub fn fresh(&self) -> usize {
        self.fresh
    }

    /// Forgets the contacts kept from before the track resumed (they were of someone
    /// else given the same id, or the person changed).
    pub fn keep_fresh(&mut self) {
        while self.contacts.len() > self.fresh {
            self.contacts.pop_front();
        }
    }

    /// The median factor of the contacts kept from before the track resumed (`None`:
    /// none).
    pub fn kept_median(&mut self) -> Option<f64> {
        let old = self.contacts.len() - self.fresh;
        self.median_of(0..old)
    }

    /// The median factor of the fresh contacts (`None`: none).
    pub fn fresh_median(&mut self) -> Option<f64> {
        let old = self.contacts.len() - self.fresh;
        self.median_of(old..self.contacts.len())
    }

    /// The median factor of contacts `range` (`None`: an empty range).
    fn median_of(&mut self, range: std::ops::Range<usize>) -> Option<f64> {
        if range.is_empty() {
            return None;
        }
        self.scratch.clear();
        self.scratch.extend(self.contacts.range(range).map(|c| c.1));
        Some(median(&mut self.scratch).exp())
    }

    /// Forgets every contact (a new person).
    pub fn clear(&mut self) {
        self.contacts.clear();
        self.feet.clear();
        self.fresh = 0;
    }

    /// How fast foot `k` (of [`BodyScale::note_feet`]'s) moved into `xy` (image pixels)
    /// at frame `sequence`: pixels per frame since the nearest earlier frame noted, at
    /// most `FEET_GAP` before; `None` without one.
    pub fn foot_speed(&self, sequence: u64, k: usize, xy: [f64; 2]) -> Option<f64> {
        if k >= MAX_FEET {
            return None;
        }
        let (before, feet) = self
            .feet
            .iter()
            .rev()
            .find(|(s, _)| *s < sequence && sequence - *s <= FEET_GAP)?;
        let d = (xy[0] - feet[k][0]).hypot(xy[1] - feet[k][1]);
        let speed = d / (sequence - before) as f64;
        speed.is_finite().then_some(speed)
    }

    /// Notes frame `sequence`'s feet in the image (the first [`MAX_FEET`]); a frame
    /// noted again (its refined estimate) replaces its first.
    pub fn note_feet(&mut self, sequence: u64, feet: impl Iterator<Item = [f64; 2]>) {
        let mut at = [[f64::NAN; 2]; MAX_FEET];
        for (slot, xy) in at.iter_mut().zip(feet) {
            *slot = xy;
        }
        if let Some(slot) = self.feet.iter_mut().rev().find(|(s, _)| *s == sequence) {
            slot.1 = at;
            return;
        }
        // Numbers that went back past what is kept: a restarted numbering, whose frames
        // the old ones would hide (the person's contacts, their size, stay).
        if self
            .feet
            .back()
            .is_some_and(|(newest, _)| *newest > sequence.saturating_add(FEET_FRAMES as u64))
        {
            self.feet.clear();
        }
        // In frame order (a refined estimate's frame is older than the newest's).
        let place = self.feet.partition_point(|(s, _)| *s < sequence);
        self.feet.insert(place, (sequence, at));
        while self.feet.len() > FEET_FRAMES {
            self.feet.pop_front();
        }
    }

    /// Forgets frame `sequence`'s contact, if one was noted among the last few (its
    /// refined estimate found none).
    pub fn forget(&mut self, sequence: u64) {
        let n = self.contacts.len();
        if let Some(i) = (n.saturating_sub(64)..n)
            .rev()
            .find(|&i| self.contacts[i].0 == sequence)
        {
            self.contacts.remove(i);
            if i >= n - self.fresh.min(n) {
                self.fresh -= 1;
            }
        }
    }

    /// Notes frame `sequence`'s factor (positive and finite; others are ignored): it
    /// replaces one noted for the same frame among the last few.
    pub fn note(&mut self, sequence: u64, factor: f64) {
        if !(factor > 0.0 && factor.is_finite()) {
            return;
        }
        let value = factor.ln();
        if let Some(slot) = self
            .contacts
            .iter_mut()
            .rev()
            .take(64)
            .find(|(s, _)| *s == sequence)
        {
            slot.1 = value;
            return;
        }
        self.contacts.push_back((sequence, value));
        self.fresh += 1;
        while self.contacts.len() > self.capacity {
            self.contacts.pop_front();
        }
        self.fresh = self.fresh.min(self.contacts.len());
    }

    /// The median factor and spread of the contacts noted, `None` without any.
    pub fn estimate(&mut self) -> Option<ScaleEstimate> {
        let n = self.contacts.len();
        if n == 0 {
            return None;
        }
        self.scratch.clear();
        self.scratch.extend(self.contacts.iter().map(|c| c.1));
        let centre = median(&mut self.scratch);
        for v in &mut self.scratch {
            *v = (*v - centre).abs();
        }
        let mad = median(&mut self.scratch);
        Some(ScaleEstimate {
            factor: centre.exp(),
            spread: 1.4826 * mad,
            contacts: n,
        })
    }
}

/// The median of `v` (reordered), `v` not empty.
fn median(v: &mut [f64]) -> f64 {
    let n = v.len();
    let (_, hi, _) = v.select_nth_unstable_by(n / 2, f64::total_cmp);
    let hi = *hi;
    if n % 2 == 1 {
        hi
    } else {
        let lo = v[..n / 2].iter().copied().fold(f64::NEG_INFINITY, f64::max);
        0.5 * (lo + hi)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_resumed_person_keeps_their_contacts_and_counts_fresh_ones_apart() {
        let mut scale = BodyScale::new(60);
        for s in 0..20 {
            scale.note(s, 1.0);
        }
        assert_eq!(scale.fresh(), 20);
        assert_eq!(scale.kept_median(), None);
        scale.suspend();
        assert_eq!((scale.fresh(), scale.fresh_median()), (0, None));
        for s in 100..105 {
            scale.note(s, 1.2);
        }
        // A refined estimate's contact taken back is no longer fresh.
        scale.forget(104);
        assert_eq!(scale.fresh(), 4);
        assert!((scale.kept_median().unwrap() - 1.0).abs() < 1e-12);
        assert!((scale.fresh_median().unwrap() - 1.2).abs() < 1e-12);
        assert_eq!(scale.estimate().unwrap().contacts, 24);
        scale.keep_fresh();
        assert_eq!(scale.estimate().unwrap().contacts, 4);
        assert_eq!(scale.kept_median(), None);
        // Past the capacity the oldest go, fresh or not.
        let mut small = BodyScale::new(3);
        small.note(0, 1.0);
        small.suspend();
        for s in 1..6 {
            small.note(s, 2.0);
        }
        assert_eq!((small.fresh(), small.estimate().unwrap().contacts), (3, 3));
    }

    #[test]
    fn level_camera_sees_the_floor_below_the_horizon() {
        let floor = FloorModel::from_height_pitch_roll(1.5, 0.0, 0.0).unwrap();
        // Up is the camera's -y.
        assert!((floor.up() - Vector3::new(0.0, -1.0, 0.0)).norm() < 1e-12);
        // A point 1.5 m below the camera, 4 m ahead, is on the floor.
        assert!(floor.height_of(&Vector3::new(0.3, 1.5, 4.0)).abs() < 1e-12);
        // Its ray scaled onto the floor: the point itself.
        let ray = Vector3::new(0.3, 1.5, 4.0) / 4.0;
        let t = floor.scale_to(&ray, 0.0).unwrap();
        assert!((t - 4.0).abs() < 1e-12);
        // At or above the horizon: never.
        assert_eq!(floor.scale_to(&Vector3::new(0.0, -0.1, 1.0), 0.0), None);
        assert_eq!(floor.scale_to(&Vector3::new(0.0, 0.0, 1.0), 0.0), None);
        // To the floor frame: x forward, y left, z up.
        let q = floor.to_floor(&Vector3::new(0.3, 1.5, 4.0));
        assert!((q - Vector3::new(4.0, -0.3, 0.0)).norm() < 1e-12);
    }

    #[test]
    fn a_floor_s_deviations_move_a_point_on_it_as_its_ray_says() {
        let (h, d) = (2.0, 6.0);
        let floor = FloorModel::from_height_pitch_roll(h, 10.0, 0.0).unwrap();
        // The height: by its share of the height, wherever the point is.
        let height = FloorStd {
            height: 0.1,
            pitch: 0.0,
        };
        assert!((height.distance(&floor, d) - 0.05).abs() < 1e-12);
        // The pitch: as the ray's angle below the horizon moves the point it meets.
        let da = 1e-4;
        let pitch = FloorStd {
            height: 0.0,
            pitch: da,
        };
        let angle = (h / d).atan();
        let moved = h / (angle - da).tan() / d - 1.0;
        assert!((pitch.distance(&floor, d) / moved - 1.0).abs() < 1e-3);
        // Under the camera, bounded.
        let degree = FloorStd {
            height: 0.0,
            pitch: 1f64.to_radians(),
        };
        assert_eq!(degree.distance(&floor, 0.0), 1.0);
    }

    #[test]
    fn pitch_and_roll_round_trip_and_tilt_the_up_vector() {
        let floor = FloorModel::from_height_pitch_roll(2.0, 20.0, -5.0).unwrap();
        let (pitch, roll) = floor.pitch_roll();
        assert!((pitch - 20.0).abs() < 1e-9 && (roll + 5.0).abs() < 1e-9);
        assert!((floor.up().norm() - 1.0).abs() < 1e-12);
        // Looking down: the optical axis points down (up . forward < 0).
        let down_only = FloorModel::from_height_pitch_roll(2.0, 20.0, 0.0).unwrap();
        let up = down_only.up();
        assert!((up.z + 20f64.to_radians().sin()).abs() < 1e-12, "{up:?}");
        assert!((up.y + 20f64.to_radians().cos()).abs() < 1e-12, "{up:?}");
        // The optical axis hits the floor at height / sin(pitch).
        let t = down_only.scale_to(&Vector3::z(), 0.0).unwrap();
        assert!((t - 2.0 / 20f64.to_radians().sin()).abs() < 1e-9);
        // Positive roll turns the camera's top to its right: up leans to the image's -x.
        let rolled = FloorModel::from_height_pitch_roll(2.0, 0.0, 10.0).unwrap();
        assert!(rolled.up().x < 0.0, "{:?}", rolled.up());
    }

    #[test]
    fn refuses_cameras_not_above_the_floor_and_bad_values() {
        assert!(FloorModel::from_height_pitch_roll(0.0, 0.0, 0.0).is_err());
        assert!(FloorModel::from_height_pitch_roll(-1.0, 0.0, 0.0).is_err());
        assert!(FloorModel::from_height_pitch_roll(f64::NAN, 0.0, 0.0).is_err());
        assert!(FloorModel::from_height_pitch_roll(1.0, 95.0, 0.0).is_err());
        assert!(FloorModel::from_height_pitch_roll(1.0, 0.0, f64::INFINITY).is_err());
        let q = UnitQuaternion::identity();
        assert!(FloorModel::new(q, Vector3::new(0.0, f64::NAN, 1.0)).is_err());
        let s = FloorSettings {
            source: FloorSource::Tf,
            frame: "bad frame".into(),
            ..FloorSettings::default()
        };
        assert!(s.check().is_err());
        let s = FloorSettings {
            source: FloorSource::Config,
            height: 0.0,
            ..FloorSettings::default()
        };
        assert!(s.check().is_err());
        assert!(FloorSettings::default().check().is_ok());
    }

    #[test]
    fn body_scale_is_the_median_and_a_frame_noted_again_replaces_its_first() {
        let mut b = BodyScale::new(5);
        assert_eq!(b.estimate(), None);
        for (s, f) in [(0, 1.0), (1, 1.1), (2, 0.9), (3, 5.0), (4, 1.05)] {
            b.note(s, f);
        }
        let e = b.estimate().unwrap();
        assert!((e.factor - 1.05).abs() < 1e-12, "{e:?}");
        assert_eq!(e.contacts, 5);
        // Frame 3's refined estimate replaces its outlier.
        b.note(3, 1.0);
        let e = b.estimate().unwrap();
        assert!((e.factor - 1.0).abs() < 1e-12, "{e:?}");
        assert!(e.spread > 0.0 && e.spread < 0.2, "{e:?}");
        // Bad factors are ignored; the oldest leave.
        b.note(5, f64::NAN);
        b.note(6, -1.0);
        assert_eq!(b.estimate().unwrap().contacts, 5);
        for s in 7..20 {
            b.note(s, 2.0);
        }
        assert!((b.estimate().unwrap().factor - 2.0).abs() < 1e-12);
        b.clear();
        assert_eq!(b.estimate(), None);
    }

    #[test]
    fn a_foot_s_speed_is_against_the_nearest_earlier_frame_noted_refined_or_not() {
        let mut b = BodyScale::new(5);
        assert_eq!(b.foot_speed(3, 0, [0.0, 0.0]), None);
        // Frames 10 and 11's newest estimates, then frame 10's refined one.
        b.note_feet(10, [[100.0, 200.0], [140.0, 200.0]].into_iter());
        b.note_feet(11, [[100.0, 200.0], [150.0, 196.0]].into_iter());
        b.note_feet(10, [[101.0, 200.0], [140.0, 200.0]].into_iter());
        assert_eq!(b.foot_speed(11, 0, [101.0, 200.0]), Some(0.0));
        assert_eq!(b.foot_speed(12, 1, [150.0, 200.0]), Some(4.0));
        // Two frames on: per frame; more than FEET_GAP frames: none; no such foot: none.
        assert_eq!(b.foot_speed(13, 1, [150.0, 204.0]), Some(4.0));
        assert_eq!(b.foot_speed(11 + FEET_GAP + 1, 0, [0.0, 0.0]), None);
        assert_eq!(b.foot_speed(12, MAX_FEET, [0.0, 0.0]), None);
        // A foot never noted (one of three with two noted): none, not a NaN.
        b.note_feet(20, [[0.0, 0.0]].into_iter());
        assert_eq!(b.foot_speed(21, 1, [0.0, 0.0]), None);
        // A numbering that starts again: the old frames go, the new ones are measured.
        b.note_feet(3, [[0.0, 0.0]; 2].into_iter());
        b.note_feet(4, [[1.0, 0.0]; 2].into_iter());
        assert_eq!(b.foot_speed(4, 0, [1.0, 0.0]), Some(1.0));
        // Bounded; forgotten with the person.
        for s in 100..1000 {
            b.note_feet(s, [[0.0, 0.0]; 2].into_iter());
        }
        assert_eq!(b.feet.len(), FEET_FRAMES);
        b.clear();
        assert_eq!(b.foot_speed(1001, 0, [0.0, 0.0]), None);
    }
}
