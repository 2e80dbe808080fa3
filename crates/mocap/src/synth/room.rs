//! Rooms seen by several cameras: people placed as [`super::place`] places them, static
//! cameras around the room, each with its own clock (an offset from the room's frame
//! times, jitter, its own frame rate, frames it drops), each person's heat maps in each
//! camera rendered with the error model and the people in front of them.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use super::{ErrorModel, RenderedMaps, View, crop_boxes, heatmaps, hidden_by_others};
use crate::MappedSequence;
use posestream_base::CropBox;
use posestream_math::camera::Intrinsics;
use posestream_math::error::EstimateError;
use posestream_math::fusion::ViewCamera;
use posestream_math::fusion::matching::peaks_into;
use posestream_math::skeleton::Skeleton;

/// One camera of a room.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RoomCamera {
    /// Where it stands around the room's centre (the first person's first root), degrees
    /// counter-clockwise from where that person first faces.
    pub azimuth_deg: f64,
    /// Its horizontal distance from the centre, metres.
    pub distance: f64,
    /// Its height above the floor, metres; it looks at the centre 1 m above the floor.
    pub height: f64,
    /// Focal length, pixels.
    pub focal: f64,
    /// Image width and height, pixels (the principal point is the centre).
    pub image_size: [f64; 2],
    /// Its images are taken this long after the room's frame times, seconds.
    pub offset_s: f64,
    /// Standard deviation of each image's further time offset, seconds.
    pub jitter_s: f64,
    /// It takes every n-th frame of the room's (2: half the frame rate).
    pub every: usize,
    /// It sends nothing between these times, seconds from the start.
    pub dropped: Option<[f64; 2]>,
}

impl RoomCamera {
    /// A camera at `azimuth_deg`, `distance` m from the centre, 2.5 m high, a wide lens
    /// (600 px focal length over 1280 x 960: 94 degrees across), on the room's clock.
    pub fn at(azimuth_deg: f64, distance: f64) -> Self {
        Self {
            azimuth_deg,
            distance,
            height: 2.5,
            focal: 600.0,
            image_size: [1280.0, 960.0],
            offset_s: 0.0,
            jitter_s: 0.0,
            every: 1,
            dropped: None,
        }
    }

    /// `n` cameras [`RoomCamera::at`] `distance` m, evenly around the room from
    /// `first_deg`.
    pub fn ring(n: usize, first_deg: f64, distance: f64) -> Vec<Self> {
        (0..n)
            .map(|i| Self::at(first_deg + 360.0 * i as f64 / n as f64, distance))
            .collect()
    }

    /// Its pinhole intrinsics.
    pub fn intrinsics(&self) -> Intrinsics {
        super::centred(self.focal, self.image_size)
    }

    fn validate(&self) -> Result<(), String> {
        let finite = [
            self.azimuth_deg,
            self.distance,
            self.height,
            self.focal,
            self.offset_s,
            self.jitter_s,
        ];
        if finite.iter().any(|v| !v.is_finite()) {
            return Err("room camera values must be finite".into());
        }
        if !(self.distance > 0.2 && self.focal > 0.0 && self.height > 0.0) {
            return Err(
                "a room camera needs a distance above 0.2 m, a height and a focal length".into(),
            );
        }
        if self.every == 0 || self.jitter_s < 0.0 || self.offset_s.abs() > 1.0 {
            return Err(
                "a room camera takes every n >= 1 frames, jitter >= 0, offset within 1 s".into(),
            );
        }
        Ok(())
    }
}

/// What one camera saw of one person.
#[derive(Debug, Clone)]
pub struct Seen {
    /// The person as the camera saw them, at its capture times.
    pub view: View,
    /// The crop boxes (one per room frame).
    pub boxes: Vec<CropBox>,
    /// Their heat maps (one frame per room frame).
    pub maps: RenderedMaps,
    /// Per room frame: the camera's image time minus the room's frame time, seconds;
    /// `None` when the camera sent nothing then (its rate, a drop, or the person out of
    /// its image).
    pub dt: Vec<Option<f64>>,
}

impl Seen {
    /// The peaks of room frame `t`'s heat maps, image pixels, with their scores
    /// (`[u, v, score]` per joint, [`peaks_into`]), into `out`.
    pub fn peaks_into(&self, t: usize, out: &mut Vec<[f64; 3]>) {
        let maps = &self.maps.maps;
        let n = maps.joints * maps.height * maps.width;
        let to_image = self.boxes[t].pixel_map(maps.width, maps.height);
        peaks_into(
            &maps.values[t * n..(t + 1) * n],
            maps.height,
            maps.width,
            &to_image,
            out,
        );
    }
}

/// A room, rendered.
#[derive(Debug, Clone)]
pub struct Room {
    /// Each camera's frame in the world.
    pub cameras: Vec<Isometry3<f64>>,
    /// Their intrinsics.
    pub intrinsics: Vec<Intrinsics>,
    /// Per camera, per person.
    pub seen: Vec<Vec<Seen>>,
    /// The people, world frame, at the room's frame times.
    pub people: Vec<MappedSequence>,
}

impl Room {
    /// The cameras as the fusion takes them.
    pub fn view_cameras(&self) -> Vec<ViewCamera> {
        self.cameras
            .iter()
            .zip(&self.intrinsics)
            .map(|(pose, k)| ViewCamera {
                intrinsics: *k,
                world_from_camera: *pose,
            })
            .collect()
    }

    /// Frames of the room.
    pub fn frames(&self) -> usize {
        self.people.first().map_or(0, |s| s.frames)
    }

    /// The room's time of frame `t`, nanoseconds.
    pub fn frame_ns(&self, t: usize) -> i64 {
        (t as f64 * self.frame_time() * 1e9).round() as i64
    }

    /// The frame at time `stamp_ns`.
    pub fn frame_at(&self, stamp_ns: i64) -> usize {
        (stamp_ns as f64 * 1e-9 / self.frame_time()).round() as usize
    }

    fn frame_time(&self) -> f64 {
        self.people.first().map_or(1.0 / 30.0, |s| s.frame_time)
    }
}

/// A sequence at time `t` seconds: its frames linearly interpolated (clamped to its ends).
fn at_time(seq: &MappedSequence, t: f64, out: &mut Vec<f64>) {
    let n = 3 * seq.joints;
    let f = (t / seq.frame_time).clamp(0.0, (seq.frames - 1) as f64);
    let (a, b) = (f.floor() as usize, f.ceil() as usize);
    let s = f - a as f64;
    out.clear();
    out.extend(
        seq.positions[a * n..(a + 1) * n]
            .iter()
            .zip(&seq.positions[b * n..(b + 1) * n])
            .map(|(x, y)| x + s * (y - x)),
    );
}

/// The pose of a camera at `cam` around `centre`, facing `front` at azimuth 0.
fn camera_pose(cam: &RoomCamera, centre: Vector3<f64>, front: Vector3<f64>) -> Isometry3<f64> {
    let left = Vector3::z().cross(&front);
    let az = cam.azimuth_deg.to_radians();
    let level = front * az.cos() + left * az.sin();
    let position =
        Vector3::new(centre.x, centre.y, 0.0) + level * cam.distance + Vector3::z() * cam.height;
    let aim = Vector3::new(centre.x, centre.y, 1.0);
    let forward = (aim - position).normalize();
    let right = forward.cross(&Vector3::z()).normalize();
    let down = forward.cross(&right);
    let r = Matrix3::from_columns(&[right, down, forward]);
    Isometry3::from_parts(
        Translation3::from(position),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)),
    )
}

/// Renders a room: `people` (world frame, one frame time, the first the room's centre and
/// facing) seen by `cameras`, heat maps in crops of `margin` times each person's extent,
/// with `model` (seeded per camera and person) and people hiding each other (bones
/// `limb_width` m wide).
pub fn render(
    people: &[MappedSequence],
    skeleton: &Skeleton,
    cameras: &[RoomCamera],
    model: &ErrorModel,
    margin: f64,
    limb_width: f64,
) -> Result<Room, String> {
    let first = people.first().ok_or("a room needs a person")?;
    let p = skeleton.len();
    if people
        .iter()
        .any(|s| s.joints != p || s.frames != first.frames || s.frame_time != first.frame_time)
    {
        return Err("the people must share the layout, frame count and frame time".into());
    }
    cameras.iter().try_for_each(RoomCamera::validate)?;
    let front = skeleton
        .facing(&first.positions[..3 * p])
        .ok_or("the layout has no left/right torso joints")?;
    let root = skeleton.root();
    let centre = Vector3::from_column_slice(&first.positions[3 * root..3 * root + 3]);
    let frames = first.frames;
    let mut room = Room {
        cameras: Vec::new(),
        intrinsics: Vec::new(),
        seen: Vec::new(),
        people: people.to_vec(),
    };
    let mut at = Vec::new();
    for (c, cam) in cameras.iter().enumerate() {
        let pose = camera_pose(cam, centre, front);
        let k = cam.intrinsics();
        let mut rng = ChaCha8Rng::seed_from_u64(model.seed ^ (0x9e37_79b9 * (c as u64 + 1)));
        let jitter = Normal::new(0.0, cam.jitter_s.max(1e-12)).map_err(|e| e.to_string())?;
        let dts: Vec<f64> = (0..frames)
            .map(|_| {
                cam.offset_s
                    + if cam.jitter_s > 0.0 {
                        jitter.sample(&mut rng)
                    } else {
                        0.0
                    }
            })
            .collect();
        let mut views = Vec::new();
        for person in people {
            let mut view = View {
                joints: p,
                frames,
                camera_3d: Vec::with_capacity(3 * p * frames),
                image_2d: Vec::with_capacity(2 * p * frames),
                cameras: vec![pose; frames],
            };
            for (t, dt) in dts.iter().enumerate() {
                at_time(person, t as f64 * first.frame_time + dt, &mut at);
                for j in 0..p {
                    let w = Point3::new(at[3 * j], at[3 * j + 1], at[3 * j + 2]);
                    let q = pose.inverse_transform_point(&w).coords;
                    view.camera_3d.extend([q.x, q.y, q.z]);
                    // Behind the camera: far outside the image (not seen).
                    let uv = if q.z > 1e-3 {
                        k.project(&q)
                    } else {
                        [-1e6, -1e6]
                    };
                    view.image_2d.extend(uv);
                }
            }
            views.push(view);
        }
        let hidden = if people.len() > 1 {
            hidden_by_others(
                &views,
                skeleton,
                &|z| cam.focal / z.max(1e-6),
                0.5 * limb_width,
            )
        } else {
            vec![Vec::new(); people.len()]
        };
        let mut seen = Vec::new();
        for (i, (view, hidden)) in views.into_iter().zip(&hidden).enumerate() {
            let boxes = crop_boxes(&view.image_2d, p, margin);
            let model = ErrorModel {
                seed: model.seed.wrapping_add(1000 * c as u64 + i as u64),
                ..model.clone()
            };
            let maps = heatmaps::render_hidden(&view.image_2d, &boxes, skeleton, &model, hidden)
                .map_err(|e: EstimateError| e.to_string())?;
            let dt = (0..frames)
                .map(|t| {
                    let time = t as f64 * first.frame_time;
                    let dropped = cam.dropped.is_some_and(|[a, b]| time >= a && time < b);
                    let inside = view.image_2d[2 * t * p..2 * (t + 1) * p]
                        .chunks_exact(2)
                        .all(|q| {
                            q[0] >= 0.0
                                && q[1] >= 0.0
                                && q[0] < cam.image_size[0]
                                && q[1] < cam.image_size[1]
                        });
                    (t % cam.every == 0 && !dropped && inside).then_some(dts[t])
                })
                .collect();
            seen.push(Seen {
                view,
                boxes,
                maps,
                dt,
            });
        }
        room.cameras.push(pose);
        room.intrinsics.push(k);
        room.seen.push(seen);
    }
    Ok(room)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_room_camera_looks_at_the_centre_from_where_it_stands() {
        let cam = RoomCamera::at(90.0, 4.0);
        let pose = camera_pose(&cam, Vector3::new(1.0, 2.0, 0.9), Vector3::y());
        // Facing +y, the left is -x: azimuth 90 puts the camera there.
        let c = pose.translation.vector;
        assert!((c - Vector3::new(-3.0, 2.0, 2.5)).norm() < 1e-12, "{c:?}");
        // Its optical axis goes through the centre 1 m up; its image's down is world down.
        let aim = pose
            .inverse_transform_point(&Point3::new(1.0, 2.0, 1.0))
            .coords;
        assert!(aim.x.abs() < 1e-12 && aim.y.abs() < 1e-12 && aim.z > 0.0);
        let down = pose.rotation * Vector3::y();
        assert!(down.z < 0.0);
    }
}
