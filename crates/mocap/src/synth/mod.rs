//! Synthetic test sequences from motion capture: a camera looking at a mapped BVH
//! sequence ([`view`]), square crop boxes around the body ([`crop_boxes`]) and heat maps
//! with the failure modes of real detectors ([`heatmaps::render`]).
//!
//! World axes are those of [`MappedSequence`](crate::MappedSequence): metres,
//! z up. The camera frame is x right, y down, z forward, as everywhere in posestream.

pub mod heatmaps;
pub mod motion;
pub mod room;

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use crate::MappedSequence;
use posestream_base::CropBox;
use posestream_math::camera::Intrinsics;
use posestream_math::skeleton::Skeleton;

pub use heatmaps::{ErrorModel, RenderedMaps};

/// How the camera projects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Projection {
    /// Parallel projection at `focal / distance` pixels per metre (the same image size as
    /// the pinhole camera at the body's distance).
    Orthographic,
    /// A pinhole camera with the given focal length.
    Pinhole,
}

/// Where the camera is and how it sees.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    /// Distance from the body's root (pelvis), metres.
    pub distance: f64,
    /// Azimuth around the vertical, degrees: 0 = in front of the body as it faces in the
    /// first frame, 90 = at its left.
    pub azimuth_deg: f64,
    /// Elevation above the root's height, degrees.
    pub elevation_deg: f64,
    /// Orbit speed, degrees per second (azimuth grows with time).
    pub orbit_deg_per_s: f64,
    /// Projection model.
    pub projection: Projection,
    /// Focal length, pixels.
    pub focal: f64,
    /// Image width and height, pixels (the principal point is the centre).
    pub image_size: [f64; 2],
    /// Follow the body: the camera keeps its place relative to the root's current
    /// horizontal position (a dolly); otherwise it stays where the first frame puts it.
    pub follow: bool,
    /// The camera's height above the floor (the motion capture's `z = 0`), metres: it
    /// then stands `distance` from the root horizontally, looking level and `tilt_deg`
    /// down, and `elevation_deg` is not used. `None`: it looks at the root from
    /// `elevation_deg` above it.
    #[serde(default)]
    pub height: Option<f64>,
    /// With a `height`: degrees the camera looks down from level.
    #[serde(default)]
    pub tilt_deg: f64,
}

impl Default for CameraSpec {
    fn default() -> Self {
        Self {
            distance: 5.0,
            azimuth_deg: 0.0,
            elevation_deg: 10.0,
            orbit_deg_per_s: 0.0,
            projection: Projection::Pinhole,
            focal: 1000.0,
            image_size: [1000.0, 1000.0],
            follow: true,
            height: None,
            tilt_deg: 0.0,
        }
    }
}

impl CameraSpec {
    /// Checks the values.
    pub fn validate(&self) -> Result<(), String> {
        let finite = [
            self.distance,
            self.azimuth_deg,
            self.elevation_deg,
            self.orbit_deg_per_s,
            self.focal,
            self.image_size[0],
            self.image_size[1],
            self.height.unwrap_or(1.0),
            self.tilt_deg,
        ];
        if finite.iter().any(|v| !v.is_finite()) {
            return Err("camera values must be finite".into());
        }
        if self.distance <= 0.0 || self.focal <= 0.0 {
            return Err("camera distance and focal length must be positive".into());
        }
        if self.elevation_deg.abs() >= 90.0 {
            return Err("camera elevation must lie strictly between -90 and 90 degrees".into());
        }
        // What a floor under the camera may be (the estimator's `FloorModel`: 1 cm to
        // 1 km).
        if self.height.is_some_and(|h| !(0.01..=1000.0).contains(&h)) {
            return Err("camera height must lie between 0.01 and 1000 m above the floor".into());
        }
        if self.tilt_deg.abs() >= 90.0 {
            return Err("camera tilt must lie strictly between -90 and 90 degrees".into());
        }
        if self.image_size.iter().any(|&v| v < 1.0) {
            return Err("image size must be at least 1 x 1".into());
        }
        Ok(())
    }

    /// The pinhole intrinsics (also the orthographic camera's image centre and scale).
    pub fn intrinsics(&self) -> Intrinsics {
        centred(self.focal, self.image_size)
    }
}

/// A pinhole camera of focal length `focal` (pixels) with its principal point at the
/// centre of an image of `size` (width, height) pixels.
fn centred(focal: f64, size: [f64; 2]) -> Intrinsics {
    Intrinsics {
        fx: focal,
        fy: focal,
        cx: 0.5 * size[0],
        cy: 0.5 * size[1],
    }
}

/// A sequence seen by a camera.
#[derive(Debug, Clone, PartialEq)]
pub struct View {
    /// Joints per frame.
    pub joints: usize,
    /// Frames.
    pub frames: usize,
    /// Joint positions in the camera frame, metres: `[x, y, z]` per joint, frame-major.
    pub camera_3d: Vec<f64>,
    /// Their images, pixels: `[x, y]` per joint, frame-major.
    pub image_2d: Vec<f64>,
    /// The camera frame in the world (the motion capture's axes, z up, `z = 0` the
    /// floor), per frame.
    pub cameras: Vec<nalgebra::Isometry3<f64>>,
}

/// Which joints of each person another person hides, frame by frame: a joint is hidden
/// when its image lies within `half_width` metres (in the image at the bone's depth:
/// `pixels_per_metre(depth)`) of a bone of another person that is nearer the camera
/// there (by 5 cm at least). Per person, per frame and joint (`frames x joints`): the
/// point of the hiding bone nearest the joint's image (pixels), or `None`.
pub fn hidden_by_others(
    views: &[View],
    skeleton: &Skeleton,
    pixels_per_metre: &dyn Fn(f64) -> f64,
    half_width: f64,
) -> Vec<Vec<Option<[f64; 2]>>> {
    let bones: Vec<(usize, usize)> = skeleton.bones().collect();
    views
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let p = v.joints;
            let mut out = vec![None; v.frames * p];
            for t in 0..v.frames {
                for j in 0..p {
                    let at = t * p + j;
                    let q = [v.image_2d[2 * at], v.image_2d[2 * at + 1]];
                    let z = v.camera_3d[3 * at + 2];
                    let mut best: Option<(f64, [f64; 2])> = None;
                    for (k, o) in views.iter().enumerate() {
                        if k == i || t >= o.frames || o.joints != p {
                            continue;
                        }
                        for &(a, b) in &bones {
                            let (ia, ib) = (t * p + a, t * p + b);
                            let pa = [o.image_2d[2 * ia], o.image_2d[2 * ia + 1]];
                            let pb = [o.image_2d[2 * ib], o.image_2d[2 * ib + 1]];
                            let (za, zb) = (o.camera_3d[3 * ia + 2], o.camera_3d[3 * ib + 2]);
                            let d = [pb[0] - pa[0], pb[1] - pa[1]];
                            let len2 = d[0] * d[0] + d[1] * d[1];
                            let s = if len2 > 0.0 {
                                (((q[0] - pa[0]) * d[0] + (q[1] - pa[1]) * d[1]) / len2)
                                    .clamp(0.0, 1.0)
                            } else {
                                0.0
                            };
                            let c = [pa[0] + s * d[0], pa[1] + s * d[1]];
                            let zc = za + s * (zb - za);
                            if !(zc > 0.0 && zc < z - 0.05) {
                                continue;
                            }
                            let reach = pixels_per_metre(zc) * half_width;
                            let dist = (q[0] - c[0]).hypot(q[1] - c[1]);
                            if dist < reach && best.is_none_or(|(bd, _)| dist < bd) {
                                best = Some((dist, c));
                            }
                        }
                    }
                    out[at] = best.map(|(_, c)| c);
                }
            }
            out
        })
        .collect()
}

impl CameraSpec {
    /// Image pixels per metre at depth `z` (orthographic: the same at every depth).
    pub fn pixels_per_metre(&self, z: f64) -> f64 {
        match self.projection {
            Projection::Pinhole => self.focal / z.max(1e-6),
            Projection::Orthographic => self.focal / self.distance,
        }
    }
}

/// Projects a mapped sequence through the camera.
pub fn view(seq: &MappedSequence, skeleton: &Skeleton, cam: &CameraSpec) -> Result<View, String> {
    view_from(seq, seq, skeleton, cam)
}

/// Projects `seq` through the camera that `cam` places relative to `anchor` (another
/// person of the same scene, whose frames it must have): everyone in a scene is seen by
/// the camera of its first person.
pub fn view_from(
    anchor: &MappedSequence,
    seq: &MappedSequence,
    skeleton: &Skeleton,
    cam: &CameraSpec,
) -> Result<View, String> {
    cam.validate()?;
    let p = seq.joints;
    if p != skeleton.len() || seq.frames == 0 || anchor.joints != p || anchor.frames < seq.frames {
        return Err("the sequence does not match the layout or has no frames".into());
    }
    let root = skeleton.root();
    let root_at =
        |t: usize| Vector3::from_column_slice(&anchor.positions[3 * (t * p + root)..][..3]);
    let front = skeleton
        .facing(&anchor.positions[..3 * p])
        .ok_or("the layout has no left/right torso joints to tell where the body faces")?;
    let left = Vector3::z().cross(&front);
    let first_root = root_at(0);
    let k = cam.intrinsics();
    let mut camera_3d = Vec::with_capacity(seq.frames * p * 3);
    let mut image_2d = Vec::with_capacity(seq.frames * p * 2);
    let mut cameras = Vec::with_capacity(seq.frames);
    for t in 0..seq.frames {
        let az = (cam.azimuth_deg + cam.orbit_deg_per_s * t as f64 * seq.frame_time).to_radians();
        let target = if cam.follow { root_at(t) } else { first_root };
        let level = front * az.cos() + left * az.sin();
        let (centre, forward) = match cam.height {
            Some(height) => {
                let tilt = cam.tilt_deg.to_radians();
                let centre = Vector3::new(target.x, target.y, height) + level * cam.distance;
                (centre, -level * tilt.cos() - Vector3::z() * tilt.sin())
            }
            None => {
                let el = cam.elevation_deg.to_radians();
                let target = Vector3::new(target.x, target.y, first_root.z);
                let dir = level * el.cos() + Vector3::z() * el.sin();
                (target + dir * cam.distance, -dir)
            }
        };
        let right = forward.cross(&Vector3::z()).normalize();
        let down = forward.cross(&right);
        let r = Matrix3::from_rows(&[right.transpose(), down.transpose(), forward.transpose()]);
        cameras.push(nalgebra::Isometry3::from_parts(
            centre.into(),
            nalgebra::UnitQuaternion::from_rotation_matrix(
                &nalgebra::Rotation3::from_matrix_unchecked(r.transpose()),
            ),
        ));
        for j in 0..p {
            let w = Vector3::from_column_slice(&seq.positions[3 * (t * p + j)..][..3]);
            let c = r * (w - centre);
            camera_3d.extend([c.x, c.y, c.z]);
            let uv = match cam.projection {
                Projection::Pinhole => {
                    if c.z <= 1e-6 {
                        return Err(format!(
                            "frame {t}: joint {} is behind the camera (move it further away)",
                            skeleton.joints[j]
                        ));
                    }
                    k.project(&c)
                }
                Projection::Orthographic => {
                    let s = cam.focal / cam.distance;
                    [k.cx + s * c.x, k.cy + s * c.y]
                }
            };
            image_2d.extend(uv);
        }
    }
    Ok(View {
        joints: p,
        frames: seq.frames,
        camera_3d,
        image_2d,
        cameras,
    })
}

/// Where another person of a scene starts and how they move, relative to the first
/// person's start: in the first person's horizontal frame as it first faces (`ahead`
/// along its facing direction, `left` to its left), metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Placement {
    /// Start, metres ahead of the first person's root.
    pub ahead: f64,
    /// Start, metres to the first person's left.
    pub left: f64,
    /// Facing, degrees counter-clockwise from the first person's facing.
    pub turn_deg: f64,
    /// A walk on top of the take's own motion, metres per second: `[ahead, left]`.
    pub velocity: [f64; 2],
}

/// `person` moved into the scene of `first`: turned and placed by `placement`, its own
/// motion kept (heights too), plus the placement's walk. Both must have the same frame
/// time; the result has `person`'s frames.
pub fn place(
    first: &MappedSequence,
    person: &MappedSequence,
    skeleton: &Skeleton,
    placement: &Placement,
) -> Result<MappedSequence, String> {
    let p = skeleton.len();
    if first.joints != p || person.joints != p || first.frames == 0 || person.frames == 0 {
        return Err("the sequences do not match the layout or have no frames".into());
    }
    if (first.frame_time - person.frame_time).abs() > 1e-9 {
        return Err(format!(
            "frame times differ: {} s and {} s",
            first.frame_time, person.frame_time
        ));
    }
    let facing = |seq: &MappedSequence| {
        skeleton
            .facing(&seq.positions[..3 * p])
            .ok_or("the layout has no left/right torso joints to tell where the body faces")
    };
    let (front, own) = (facing(first)?, facing(person)?);
    let left = Vector3::z().cross(&front);
    let root = skeleton.root();
    let root0 = |seq: &MappedSequence| Vector3::from_column_slice(&seq.positions[3 * root..][..3]);
    let (anchor, start) = (root0(first), root0(person));
    // The yaw that turns the person's facing onto the first's, then `turn_deg` more.
    let yaw = front.y.atan2(front.x) - own.y.atan2(own.x) + placement.turn_deg.to_radians();
    let turn = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), yaw);
    let at = anchor + front * placement.ahead + left * placement.left;
    let walk = front * placement.velocity[0] + left * placement.velocity[1];
    let mut positions = Vec::with_capacity(person.positions.len());
    for t in 0..person.frames {
        let shift = Vector3::new(at.x, at.y, 0.0) + walk * (t as f64 * person.frame_time);
        for j in 0..p {
            let w = Vector3::from_column_slice(&person.positions[3 * (t * p + j)..][..3]);
            let local = Vector3::new(w.x - start.x, w.y - start.y, w.z);
            let q = turn * local + shift;
            positions.extend([q.x, q.y, q.z]);
        }
    }
    Ok(MappedSequence {
        joints: p,
        frames: person.frames,
        frame_time: person.frame_time,
        positions,
    })
}

/// `seq` with its joints defined the way another detector's would be: each named joint
/// moved by its offset (metres) in the body's frame of that frame — `[left, up,
/// forward]`, left along the hips (right hip to left), up from the pelvis to the top of
/// the torso (made square to left), forward their cross product. Heat maps rendered
/// from it, and the truth scored against, place the joints a few centimetres off the
/// dictionary's definition. Unknown joint names, or a layout without hips or torso
/// top, are an error.
pub fn redefined(
    seq: &MappedSequence,
    skeleton: &Skeleton,
    offsets: &[(&str, [f64; 3])],
) -> Result<MappedSequence, String> {
    let p = skeleton.len();
    if seq.joints != p {
        return Err("the sequence does not match the layout".into());
    }
    let index = |name: &str| {
        skeleton
            .index_of(name)
            .ok_or_else(|| format!("the layout has no joint {name:?}"))
    };
    let (l_hip, r_hip, root) = (index("l-hip")?, index("r-hip")?, skeleton.root());
    let top = skeleton
        .torso_top()
        .ok_or("the layout has no torso top to tell up from")?;
    let moves: Vec<(usize, Vector3<f64>)> = offsets
        .iter()
        .map(|(name, o)| Ok((index(name)?, Vector3::from(*o))))
        .collect::<Result<_, String>>()?;
    let mut out = seq.clone();
    let mut moved = Vec::with_capacity(moves.len());
    for frame in out.positions.chunks_exact_mut(3 * p) {
        let at = |j: usize| Vector3::from_column_slice(&frame[3 * j..3 * j + 3]);
        let Some(left) = (at(l_hip) - at(r_hip)).try_normalize(1e-9) else {
            continue;
        };
        let up = at(top) - at(root);
        let Some(up) = (up - left * left.dot(&up)).try_normalize(1e-9) else {
            continue;
        };
        let basis = Matrix3::from_columns(&[left, up, left.cross(&up)]);
        moved.clear();
        moved.extend(moves.iter().map(|(j, o)| (*j, at(*j) + basis * o)));
        for (j, q) in &moved {
            frame[3 * j..3 * j + 3].copy_from_slice(q.as_slice());
        }
    }
    Ok(out)
}

/// A square box per frame around the joints' images, `margin` times their larger extent.
pub fn crop_boxes(image_2d: &[f64], joints: usize, margin: f64) -> Vec<CropBox> {
    image_2d
        .chunks_exact(2 * joints)
        .map(|f| {
            let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
            for q in f.chunks_exact(2) {
                for a in 0..2 {
                    lo[a] = lo[a].min(q[a]);
                    hi[a] = hi[a].max(q[a]);
                }
            }
            let side = ((hi[0] - lo[0]).max(hi[1] - lo[1]) * margin).max(1.0);
            let centre = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])];
            CropBox {
                x0: centre[0] - 0.5 * side,
                y0: centre[1] - 0.5 * side,
                width: side,
                height: side,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mapping::default_layout;

    /// A standing figure facing world -y (its left at +x).
    fn standing(frames: usize) -> MappedSequence {
        let skel = default_layout();
        let mut one = Vec::new();
        for name in &skel.joints {
            let side = if name.starts_with("l-") {
                0.15
            } else if name.starts_with("r-") {
                -0.15
            } else {
                0.0
            };
            let z = match name.split('-').next_back().unwrap_or("") {
                "ankle" => 0.1,
                "knee" => 0.5,
                "hip" | "pelvis" => 0.9,
                "spine" => 1.1,
                "thorax" | "shoulder" => 1.4,
                "neck" => 1.5,
                "top" => 1.7,
                "elbow" => 1.15,
                _ => 0.9,
            };
            one.extend([side, 0.0, z]);
        }
        MappedSequence {
            joints: skel.len(),
            frames,
            frame_time: 0.1,
            positions: one.repeat(frames),
        }
    }

    #[test]
    fn another_definition_moves_joints_in_the_bodys_own_frame() {
        let skel = default_layout();
        let seq = standing(2);
        // Facing -y: left is +x, up +z, forward -y.
        let moved = redefined(
            &seq,
            &skel,
            &[
                ("l-hip", [0.03, -0.04, 0.0]),
                ("r-hip", [-0.03, -0.04, 0.0]),
                ("pelvis", [0.0, 0.0, 0.02]),
            ],
        )
        .expect("redefined");
        let at = |s: &MappedSequence, t: usize, name: &str| {
            let j = skel.index_of(name).expect("joint");
            Vector3::from_column_slice(&s.positions[3 * (t * skel.len() + j)..][..3])
        };
        for t in 0..2 {
            assert!(
                (at(&moved, t, "l-hip") - at(&seq, t, "l-hip") - Vector3::new(0.03, 0.0, -0.04))
                    .norm()
                    < 1e-12
            );
            assert!(
                (at(&moved, t, "r-hip") - at(&seq, t, "r-hip") - Vector3::new(-0.03, 0.0, -0.04))
                    .norm()
                    < 1e-12
            );
            assert!(
                (at(&moved, t, "pelvis") - at(&seq, t, "pelvis") - Vector3::new(0.0, -0.02, 0.0))
                    .norm()
                    < 1e-12
            );
            assert_eq!(at(&moved, t, "l-knee"), at(&seq, t, "l-knee"));
        }
        assert!(redefined(&seq, &skel, &[("tail", [0.0; 3])]).is_err());
    }

    #[test]
    fn a_camera_in_front_sees_the_left_side_on_the_image_right() {
        let skel = default_layout();
        let seq = standing(3);
        let front = skel.facing(&seq.positions).expect("faces");
        assert!((front + Vector3::y()).norm() < 1e-12);
        let cam = CameraSpec {
            elevation_deg: 0.0,
            ..CameraSpec::default()
        };
        let v = view(&seq, &skel, &cam).expect("view");
        let l = skel.index_of("l-hip").expect("joint");
        let r = skel.index_of("r-hip").expect("joint");
        let top = skel.index_of("head-top").expect("joint");
        // Facing the camera, the body's left is on the image's right; the head is up.
        assert!(v.image_2d[2 * l] > v.image_2d[2 * r]);
        assert!(v.image_2d[2 * top + 1] < v.image_2d[1]);
        // The pelvis is straight ahead at the given distance.
        assert!((v.camera_3d[2] - 5.0).abs() < 1e-9 && v.camera_3d[0].abs() < 1e-9);
        // Orbiting 90 deg/s for 1 s (10 frames of 0.1 s) shows the body's left side.
        let seq = standing(11);
        let cam = CameraSpec {
            orbit_deg_per_s: 90.0,
            elevation_deg: 0.0,
            ..CameraSpec::default()
        };
        let v = view(&seq, &skel, &cam).expect("view");
        let at = |t: usize, j: usize| v.camera_3d[3 * (t * 17 + j) + 2];
        assert!(at(10, l) < at(10, r), "the left hip is nearer the camera");
        let boxes = crop_boxes(&v.image_2d, 17, 1.2);
        assert_eq!(boxes.len(), 11);
        assert!((boxes[0].width - boxes[0].height).abs() < 1e-12);
    }

    #[test]
    fn a_camera_at_a_height_looks_down_its_tilt_and_places_itself_over_the_floor() {
        let skel = default_layout();
        let seq = standing(3);
        let cam = CameraSpec {
            height: Some(2.0),
            tilt_deg: 20.0,
            distance: 4.0,
            ..CameraSpec::default()
        };
        let v = view(&seq, &skel, &cam).expect("view");
        let pose = v.cameras[0];
        // The camera stands 2 m above the floor, 4 m from the root horizontally.
        assert!((pose.translation.z - 2.0).abs() < 1e-12);
        let root = Vector3::from_column_slice(&seq.positions[..3]);
        let away = pose.translation.vector - root;
        assert!((away.x.hypot(away.y) - 4.0).abs() < 1e-9);
        // Its optical axis points 20 degrees below level.
        let forward = pose.rotation * Vector3::z();
        assert!(
            (forward.z + 20f64.to_radians().sin()).abs() < 1e-12,
            "{forward:?}"
        );
        // The camera-frame truth is the world seen from that pose.
        for j in 0..17 {
            let c = Vector3::from_column_slice(&v.camera_3d[3 * j..3 * j + 3]);
            let w = Vector3::from_column_slice(&seq.positions[3 * j..3 * j + 3]);
            assert!((pose * nalgebra::Point3::from(c) - nalgebra::Point3::from(w)).norm() < 1e-9);
        }
        for height in [-1.0, 0.0, 0.005, 1001.0, 1e308] {
            let bad = CameraSpec {
                height: Some(height),
                ..CameraSpec::default()
            };
            assert!(bad.validate().is_err(), "{height}");
        }
    }

    #[test]
    fn a_person_right_behind_another_is_hidden_by_them_and_not_the_other_way() {
        let skel = default_layout();
        let cam = CameraSpec {
            elevation_deg: 0.0,
            ..CameraSpec::default()
        };
        let near = view(&standing(2), &skel, &cam).expect("view");
        // The same figure 1 m further from the camera, straight behind; and one far
        // to the side.
        let shift = |v: &View, dx: f64, dz: f64| {
            let mut camera_3d = v.camera_3d.clone();
            for p in camera_3d.chunks_exact_mut(3) {
                p[0] += dx;
                p[2] += dz;
            }
            let image_2d = camera_3d
                .chunks_exact(3)
                .flat_map(|p| [500.0 + 1000.0 * p[0] / p[2], 500.0 + 1000.0 * p[1] / p[2]])
                .collect();
            View {
                camera_3d,
                image_2d,
                ..v.clone()
            }
        };
        let near = shift(&near, 0.0, 0.0);
        let behind = shift(&near, 0.0, 1.0);
        let aside = shift(&near, 3.0, 1.0);
        let hidden = hidden_by_others(&[near, behind, aside], &skel, &|z| 1000.0 / z, 0.06);
        let count = |h: &[Option<[f64; 2]>]| h.iter().filter(|x| x.is_some()).count();
        assert_eq!(count(&hidden[0]), 0, "nobody is in front of the nearest");
        assert!(
            count(&hidden[1]) > 2 * 17 / 2,
            "most of the one behind: {}",
            count(&hidden[1])
        );
        assert_eq!(count(&hidden[2]), 0, "nobody in front of the one aside");
    }
}
