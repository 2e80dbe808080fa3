//! The joint layout of a pose: names, the parent tree, torso joints and left/right pairs.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// Joint names, the kinematic tree and the joints used for torso alignment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Skeleton {
    /// Joint names, in the order of every pose array.
    pub joints: Vec<String>,
    /// Parent of each joint; `None` for the root.
    pub parents: Vec<Option<usize>>,
    /// Joints used to align poses on the torso (0-based).
    pub torso: Vec<usize>,
}

impl Skeleton {
    /// Builds a skeleton and checks that `parents` forms a single tree over the joints.
    pub fn new(
        joints: Vec<String>,
        parents: Vec<Option<usize>>,
        torso: Vec<usize>,
    ) -> Result<Self, String> {
        let p = joints.len();
        if p == 0 {
            return Err("no joints".into());
        }
        if parents.len() != p {
            return Err(format!("{} parents for {} joints", parents.len(), p));
        }
        let roots = parents.iter().filter(|q| q.is_none()).count();
        if roots != 1 {
            return Err(format!("expected one root joint, found {roots}"));
        }
        for (j, q) in parents.iter().enumerate() {
            if let Some(q) = *q
                && q >= p
            {
                return Err(format!("joint {j} has parent index {q} out of range"));
            }
        }
        // Every joint must reach the root in fewer than p steps (no cycles).
        for start in 0..p {
            let mut j = start;
            let mut steps = 0;
            while let Some(q) = parents[j] {
                j = q;
                steps += 1;
                if steps > p {
                    return Err(format!("joint {start} is on a cycle"));
                }
            }
        }
        if let Some(&t) = torso.iter().find(|&&t| t >= p) {
            return Err(format!("torso joint index {t} out of range"));
        }
        Ok(Self {
            joints,
            parents,
            torso,
        })
    }

    /// Number of joints.
    pub fn len(&self) -> usize {
        self.joints.len()
    }

    /// True when the skeleton has no joints (never, for a validated skeleton).
    pub fn is_empty(&self) -> bool {
        self.joints.is_empty()
    }

    /// The root joint (the one without a parent).
    pub fn root(&self) -> usize {
        self.parents.iter().position(|q| q.is_none()).unwrap_or(0)
    }

    /// Index of the joint called `name`.
    pub fn index_of(&self, name: &str) -> Option<usize> {
        self.joints.iter().position(|j| j == name)
    }

    /// The bones as (parent, child) pairs.
    pub fn bones(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.parents
            .iter()
            .enumerate()
            .filter_map(|(j, q)| q.map(|q| (q, j)))
    }

    /// The left/right pairs whose both joints are torso joints.
    pub fn torso_pairs(&self) -> Vec<(usize, usize)> {
        self.left_right_pairs()
            .into_iter()
            .filter(|(l, r)| self.torso.contains(l) && self.torso.contains(r))
            .collect()
    }

    /// The horizontal unit direction a pose faces, for world axes with z up (`frame`:
    /// `[x, y, z]` per joint), from its torso's left-to-right direction: facing `f` and up
    /// `z` make the body's right `f x z`. `None` without left/right torso joints or when
    /// they line up vertically.
    pub fn facing(&self, frame: &[f64]) -> Option<Vector3<f64>> {
        let at = |j: usize| Vector3::new(frame[3 * j], frame[3 * j + 1], frame[3 * j + 2]);
        let right: Vector3<f64> = self.torso_pairs().iter().map(|&(l, r)| at(r) - at(l)).sum();
        let right = Vector3::new(right.x, right.y, 0.0).try_normalize(1e-9)?;
        Some(Vector3::z().cross(&right))
    }

    /// The joints a standing person's weight is on (their ankles): the default layout's
    /// `l-ankle` and `r-ankle` (the authors' `ltibia` and `rtibia`), or, in another
    /// layout, joints whose name says ankle or foot.
    pub fn feet(&self) -> Vec<usize> {
        if is_default_layout(&self.joints) {
            return vec![3, 6];
        }
        self.joints
            .iter()
            .enumerate()
            .filter(|(_, name)| {
                let lower = name.to_ascii_lowercase();
                lower.contains("ankle") || lower.contains("foot")
            })
            .map(|(j, _)| j)
            .collect()
    }

    /// The top of the torso: the thorax (the authors' name too), else the neck.
    pub fn torso_top(&self) -> Option<usize> {
        self.index_of("thorax").or_else(|| self.index_of("neck"))
    }

    /// Left/right joint pairs, found by name: `l`/`r` prefixes (`lhumerus`/`rhumerus`,
    /// `l-knee`/`r-knee`) or `left`/`right` (`LeftArm`/`RightArm`).
    pub fn left_right_pairs(&self) -> Vec<(usize, usize)> {
        let mut pairs = Vec::new();
        for (i, name) in self.joints.iter().enumerate() {
            let lower = name.to_ascii_lowercase();
            let counterpart = if let Some(rest) = lower.strip_prefix("left") {
                format!("right{rest}")
            } else if let Some(rest) = lower.strip_prefix('l') {
                format!("r{rest}")
            } else {
                continue;
            };
            if let Some(j) = self
                .joints
                .iter()
                .position(|n| n.to_ascii_lowercase() == counterpart)
            {
                pairs.push((i, j));
            }
        }
        pairs
    }
}

/// The default layout's joint names: the 17-joint order of the authors' dictionaries.
pub const DEFAULT_JOINTS: [&str; 17] = [
    "pelvis",
    "l-hip",
    "l-knee",
    "l-ankle",
    "r-hip",
    "r-knee",
    "r-ankle",
    "spine",
    "thorax",
    "neck",
    "head-top",
    "l-shoulder",
    "l-elbow",
    "l-wrist",
    "r-shoulder",
    "r-elbow",
    "r-wrist",
];

/// The same joints as named in the authors' `.mat` dictionaries (CMU bone names; the
/// joint is the bone's end).
pub const AUTHORS_JOINTS: [&str; 17] = [
    "root",
    "lhipjoint",
    "lfemur",
    "ltibia",
    "rhipjoint",
    "rfemur",
    "rtibia",
    "spine",
    "thorax",
    "jaw",
    "head",
    "lclaivcle",
    "lhumerus",
    "lhand",
    "rclavicle",
    "rhumerus",
    "rhand",
];

/// The authors' 17-joint layout: names [`DEFAULT_JOINTS`], their tree and torso joints.
pub fn default_layout() -> Skeleton {
    let parents = vec![
        None,
        Some(0),
        Some(1),
        Some(2),
        Some(0),
        Some(4),
        Some(5),
        Some(0),
        Some(7),
        Some(8),
        Some(9),
        Some(8),
        Some(11),
        Some(12),
        Some(8),
        Some(14),
        Some(15),
    ];
    let joints = DEFAULT_JOINTS.iter().map(|s| s.to_string()).collect();
    // The layout is a constant tree; `new` cannot fail on it.
    Skeleton::new(joints, parents, vec![0, 1, 4, 7, 8, 11, 14]).unwrap_or_else(|e| {
        unreachable!("default layout: {e}");
    })
}

/// True when `names` are the default layout's joints, by posestream's names or the
/// authors' (so the authors' dictionaries fit data mapped to the default layout).
pub fn is_default_layout(names: &[String]) -> bool {
    names.len() == DEFAULT_JOINTS.len()
        && (names.iter().zip(DEFAULT_JOINTS).all(|(a, b)| a == b)
            || names.iter().zip(AUTHORS_JOINTS).all(|(a, b)| a == b))
}

/// True when two layouts name the same joints in the same order (allowing the authors'
/// names for the default layout).
pub fn same_layout(a: &[String], b: &[String]) -> bool {
    a == b || (is_default_layout(a) && is_default_layout(b))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn rejects_cycles_and_several_roots() {
        assert!(Skeleton::new(names(&["a", "b"]), vec![Some(1), Some(0)], vec![]).is_err());
        assert!(Skeleton::new(names(&["a", "b"]), vec![None, None], vec![]).is_err());
        assert!(Skeleton::new(names(&["a", "b"]), vec![None, Some(5)], vec![]).is_err());
        assert!(Skeleton::new(names(&["a", "b"]), vec![None, Some(0)], vec![2]).is_err());
    }

    #[test]
    fn finds_left_right_pairs_by_name() {
        let s = Skeleton::new(
            names(&["root", "lhip", "rhip", "LeftArm", "RightArm", "spine"]),
            vec![None, Some(0), Some(0), Some(5), Some(5), Some(0)],
            vec![0],
        )
        .expect("valid");
        assert_eq!(s.left_right_pairs(), vec![(1, 2), (3, 4)]);
        assert_eq!(s.bones().count(), 5);
        assert_eq!(s.root(), 0);
    }
}
