//! Skeleton mappings: how a BVH skeleton becomes a pose layout (`config/skeletons/*.toml`).
//!
//! ```toml
//! name = "bandai-namco"
//! up = "+y"               # the file axis that points up
//! metres_per_unit = 0.01  # file units (centimetres here) to metres
//!
//! [joints]                # one entry per layout joint
//! l-hip = { joint = "UpperLeg_L" }                     # one BVH joint
//! l-knee = { joint = ["LeftLeg", "LeftKnee"] }         # the first of these the file has
//! pelvis = { mean = ["UpperLeg_L", "UpperLeg_R"] }     # the mean of several
//! head-top = { extrapolate = ["Neck", "Head"], distance = 18.0 }  # beyond `Head` along
//!                                                      # the Neck->Head bone (file units;
//!                                                      # or `ratio` = bone lengths)
//! ```
//!
//! The layout is the authors' 17-joint order ([`default_layout`]) unless the file has a
//! `[layout]` table (`joints`, `parents` by name with `""` for the root, `torso`).
//! Every layout joint must be mapped; End Sites are named `<parent>_end`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use posestream_msgs::toml_file::{ConfigError, load_toml};

use nalgebra::{Rotation3, Vector3};
use serde::Deserialize;

use super::bvh::Bvh;
use posestream_math::skeleton::Skeleton;
pub use posestream_math::skeleton::{
    AUTHORS_JOINTS, DEFAULT_JOINTS, default_layout, is_default_layout, same_layout,
};

/// Loading or applying a skeleton mapping failed.
#[derive(Debug, thiserror::Error)]
pub enum SkeletonMappingError {
    /// The file could not be read or is not a valid mapping document.
    #[error("skeleton mapping: {0}")]
    Config(#[from] ConfigError),
    /// The mapping is inconsistent with its layout.
    #[error("skeleton mapping {path}: {detail}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        detail: String,
    },
    /// A BVH joint the mapping names is not in the file.
    #[error(
        "skeleton mapping {mapping} does not fit {bvh}: layout joint `{joint}` needs BVH joint {wanted}, which the file lacks (it has: {available})"
    )]
    MissingBvhJoint {
        /// The mapping file.
        mapping: String,
        /// The BVH file.
        bvh: String,
        /// The layout joint.
        joint: String,
        /// The name(s) looked for.
        wanted: String,
        /// The file's joints.
        available: String,
    },
}

/// One BVH joint name, or alternatives (the first the file has is used).
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
enum Names {
    One(String),
    Any(Vec<String>),
}

impl Names {
    fn list(&self) -> Vec<String> {
        match self {
            Self::One(s) => vec![s.clone()],
            Self::Any(v) => v.clone(),
        }
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct JointEntry {
    joint: Option<Names>,
    mean: Option<Vec<Names>>,
    extrapolate: Option<[Names; 2]>,
    ratio: Option<f64>,
    distance: Option<f64>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct LayoutEntry {
    joints: Vec<String>,
    parents: Vec<String>,
    torso: Vec<String>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct MappingFile {
    name: String,
    #[serde(default = "default_up")]
    up: String,
    metres_per_unit: f64,
    layout: Option<LayoutEntry>,
    joints: BTreeMap<String, JointEntry>,
}

fn default_up() -> String {
    "+y".into()
}

/// Where a layout joint comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum JointSource {
    /// One BVH joint (alternative names, first present wins).
    Joint(Vec<String>),
    /// The mean of several BVH joints.
    Mean(Vec<Vec<String>>),
    /// `to + ratio * (to - from)`, or `to + distance * unit(to - from)`.
    Extrapolate {
        /// Start of the bone.
        from: Vec<String>,
        /// End of the bone, where the extrapolation starts.
        to: Vec<String>,
        /// Bone lengths beyond `to` (exclusive with `distance`).
        ratio: Option<f64>,
        /// File units beyond `to`.
        distance: Option<f64>,
    },
}

/// A skeleton mapping: a layout and, per layout joint, its source in the BVH.
#[derive(Debug, Clone, PartialEq)]
pub struct SkeletonMapping {
    /// Name of the mapping (the BVH skeleton it is for).
    pub name: String,
    /// The layout poses are produced in.
    pub layout: Skeleton,
    /// Source of each layout joint, in layout order.
    pub sources: Vec<JointSource>,
    /// Rotation from the file's axes to posestream's world axes (z up).
    pub to_world: Rotation3<f64>,
    /// File units to metres.
    pub metres_per_unit: f64,
    /// The file this came from (for messages).
    pub origin: String,
}

/// Joint positions of a mapped BVH sequence.
#[derive(Debug, Clone, PartialEq)]
pub struct MappedSequence {
    /// Joints per frame (the layout's).
    pub joints: usize,
    /// Frames.
    pub frames: usize,
    /// Seconds per frame.
    pub frame_time: f64,
    /// Positions, metres, world axes (x, y horizontal, z up): `[x, y, z]` per joint,
    /// frame-major.
    pub positions: Vec<f64>,
}

impl MappedSequence {
    /// Frames `start .. start + len` (clipped to the sequence); `None` when `start` is
    /// past the last frame.
    pub fn frames_from(&self, start: usize, len: usize) -> Option<Self> {
        if start >= self.frames {
            return None;
        }
        let end = start.saturating_add(len).min(self.frames);
        let n = 3 * self.joints;
        Some(Self {
            frames: end - start,
            positions: self.positions[start * n..end * n].to_vec(),
            ..self.clone()
        })
    }
}

impl SkeletonMapping {
    /// Loads a mapping file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, SkeletonMappingError> {
        let path = path.as_ref();
        Self::from_file(load_toml(path)?, path)
    }

    /// Parses mapping text (`path` names it in errors).
    pub fn parse(text: &str, path: &Path) -> Result<Self, SkeletonMappingError> {
        Self::from_file(posestream_msgs::toml_file::parse_toml(text, path)?, path)
    }

    /// Checks a parsed mapping document; `path` names it in errors.
    fn from_file(file: MappingFile, path: &Path) -> Result<Self, SkeletonMappingError> {
        let invalid = |detail: String| SkeletonMappingError::Invalid {
            path: path.to_path_buf(),
            detail,
        };
        let layout = match &file.layout {
            None => default_layout(),
            Some(l) => custom_layout(l).map_err(invalid)?,
        };
        if !(file.metres_per_unit.is_finite() && file.metres_per_unit > 0.0) {
            return Err(invalid(format!(
                "metres_per_unit must be positive, got {}",
                file.metres_per_unit
            )));
        }
        let to_world = up_rotation(&file.up).ok_or_else(|| {
            invalid(format!(
                "up = `{}` is not one of +x, -x, +y, -y, +z, -z",
                file.up
            ))
        })?;
        if let Some(unknown) = file.joints.keys().find(|k| layout.index_of(k).is_none()) {
            return Err(invalid(format!(
                "`{unknown}` is not a joint of the layout ({})",
                layout.joints.join(", ")
            )));
        }
        let mut sources = Vec::with_capacity(layout.len());
        for name in &layout.joints {
            let entry = file
                .joints
                .get(name)
                .ok_or_else(|| invalid(format!("layout joint `{name}` is not mapped")))?;
            sources.push(joint_source(entry).map_err(|d| invalid(format!("`{name}`: {d}")))?);
        }
        Ok(Self {
            name: file.name,
            layout,
            sources,
            to_world,
            metres_per_unit: file.metres_per_unit,
            origin: path.display().to_string(),
        })
    }

    /// Maps every frame of `bvh` onto the layout (metres, world axes, z up).
    pub fn apply(&self, bvh: &Bvh, bvh_name: &str) -> Result<MappedSequence, SkeletonMappingError> {
        let resolve = |joint: &str, names: &[String]| {
            names.iter().find_map(|n| bvh.index_of(n)).ok_or_else(|| {
                SkeletonMappingError::MissingBvhJoint {
                    mapping: self.origin.clone(),
                    bvh: bvh_name.to_string(),
                    joint: joint.to_string(),
                    wanted: names
                        .iter()
                        .map(|n| format!("`{n}`"))
                        .collect::<Vec<_>>()
                        .join(" or "),
                    available: bvh
                        .joints
                        .iter()
                        .map(|j| j.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", "),
                }
            })
        };
        enum Resolved {
            Mean(Vec<usize>),
            Extrapolate(usize, usize, Option<f64>, Option<f64>),
        }
        let mut resolved = Vec::with_capacity(self.sources.len());
        for (name, source) in self.layout.joints.iter().zip(&self.sources) {
            resolved.push(match source {
                JointSource::Joint(n) => Resolved::Mean(vec![resolve(name, n)?]),
                JointSource::Mean(list) => Resolved::Mean(
                    list.iter()
                        .map(|n| resolve(name, n))
                        .collect::<Result<_, _>>()?,
                ),
                JointSource::Extrapolate {
                    from,
                    to,
                    ratio,
                    distance,
                } => Resolved::Extrapolate(
                    resolve(name, from)?,
                    resolve(name, to)?,
                    *ratio,
                    *distance,
                ),
            });
        }
        let frames = bvh.frames();
        let p = self.layout.len();
        let mut positions = Vec::with_capacity(frames * p * 3);
        let mut global = Vec::new();
        for t in 0..frames {
            bvh.positions_into(t, &mut global);
            for r in &resolved {
                let q = match r {
                    Resolved::Mean(list) => {
                        list.iter().map(|&i| global[i]).sum::<Vector3<f64>>() / list.len() as f64
                    }
                    Resolved::Extrapolate(from, to, ratio, distance) => {
                        let bone = global[*to] - global[*from];
                        let step = match (ratio, distance) {
                            (Some(r), _) => bone * *r,
                            (None, Some(d)) => bone.try_normalize(1e-12).unwrap_or_default() * *d,
                            (None, None) => Vector3::zeros(),
                        };
                        global[*to] + step
                    }
                };
                let w = self.to_world * q * self.metres_per_unit;
                positions.extend([w.x, w.y, w.z]);
            }
        }
        Ok(MappedSequence {
            joints: p,
            frames,
            frame_time: bvh.frame_time,
            positions,
        })
    }
}

fn joint_source(e: &JointEntry) -> Result<JointSource, String> {
    let kinds = [e.joint.is_some(), e.mean.is_some(), e.extrapolate.is_some()]
        .iter()
        .filter(|&&b| b)
        .count();
    if kinds != 1 {
        return Err("give exactly one of `joint`, `mean`, `extrapolate`".into());
    }
    let nonempty = |n: &Names| {
        let l = n.list();
        if l.is_empty() || l.iter().any(|s| s.is_empty()) {
            Err("an empty joint name".to_string())
        } else {
            Ok(l)
        }
    };
    if let Some(n) = &e.joint {
        if e.ratio.is_some() || e.distance.is_some() {
            return Err("`ratio`/`distance` only go with `extrapolate`".into());
        }
        return Ok(JointSource::Joint(nonempty(n)?));
    }
    if let Some(list) = &e.mean {
        if e.ratio.is_some() || e.distance.is_some() {
            return Err("`ratio`/`distance` only go with `extrapolate`".into());
        }
        if list.is_empty() {
            return Err("`mean` of no joints".into());
        }
        return Ok(JointSource::Mean(
            list.iter().map(nonempty).collect::<Result<_, _>>()?,
        ));
    }
    let [from, to] = e.extrapolate.as_ref().ok_or("no source")?;
    let finite = |v: Option<f64>| v.is_none_or(f64::is_finite);
    if e.ratio.is_some() == e.distance.is_some() || !finite(e.ratio) || !finite(e.distance) {
        return Err("`extrapolate` needs exactly one finite `ratio` or `distance`".into());
    }
    Ok(JointSource::Extrapolate {
        from: nonempty(from)?,
        to: nonempty(to)?,
        ratio: e.ratio,
        distance: e.distance,
    })
}

fn custom_layout(l: &LayoutEntry) -> Result<Skeleton, String> {
    let index = |name: &str| {
        l.joints
            .iter()
            .position(|j| j == name)
            .ok_or_else(|| format!("layout names unknown joint `{name}`"))
    };
    if l.parents.len() != l.joints.len() {
        return Err(format!(
            "layout has {} parents for {} joints",
            l.parents.len(),
            l.joints.len()
        ));
    }
    let parents = l
        .parents
        .iter()
        .map(|p| {
            if p.is_empty() {
                Ok(None)
            } else {
                index(p).map(Some)
            }
        })
        .collect::<Result<Vec<_>, _>>()?;
    let torso = l
        .torso
        .iter()
        .map(|t| index(t))
        .collect::<Result<Vec<_>, _>>()?;
    Skeleton::new(l.joints.clone(), parents, torso).map_err(|e| format!("layout: {e}"))
}

/// The rotation taking the named up axis to +z.
fn up_rotation(up: &str) -> Option<Rotation3<f64>> {
    let axis = match up {
        "+x" | "x" => Vector3::x(),
        "-x" => -Vector3::x(),
        "+y" | "y" => Vector3::y(),
        "-y" => -Vector3::y(),
        "+z" | "z" => Vector3::z(),
        "-z" => -Vector3::z(),
        _ => return None,
    };
    Some(
        Rotation3::rotation_between(&axis, &Vector3::z()).unwrap_or_else(|| {
            Rotation3::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
        }),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn up_rotations_take_the_axis_to_z() {
        for up in ["+x", "-x", "+y", "-y", "+z", "-z"] {
            let r = up_rotation(up).expect(up);
            let sign = if up.starts_with('-') { -1.0 } else { 1.0 };
            let axis = match &up[1..] {
                "x" => Vector3::x(),
                "y" => Vector3::y(),
                _ => Vector3::z(),
            } * sign;
            assert!((r * axis - Vector3::z()).norm() < 1e-12, "{up}");
        }
    }

    #[test]
    fn the_default_layout_is_the_authors_order() {
        let l = default_layout();
        assert_eq!(l.len(), 17);
        assert!(is_default_layout(&l.joints));
        let authors: Vec<String> = AUTHORS_JOINTS.iter().map(|s| s.to_string()).collect();
        assert!(same_layout(&l.joints, &authors));
        assert_eq!(l.left_right_pairs().len(), 6);
    }
}
