//! posestream's own dictionary format: one JSON document.
//!
//! ```json
//! {
//!   "format": "posestream-dictionary",
//!   "version": 1,
//!   "joints": ["pelvis", "l-hip", ...],          // p names, the pose order
//!   "parents": [null, 0, ...],                     // 0-based parent index, null for the root
//!   "torso": [0, 1, 4, ...],                       // 0-based joints used for alignment
//!   "axes": "x right, y down, z forward",          // free text
//!   "bases": [[[x...p], [y...p], [z...p]], ...],   // k bases, each 3 rows of p values
//!   "mean": [[x...p], [y...p], [z...p]],
//!   "source": "...", "license": "..."              // optional provenance
//! }
//! ```

use std::path::Path;

use serde::{Deserialize, Serialize};

use posestream_math::Dictionary;
use posestream_math::skeleton::Skeleton;

use crate::error::DictionaryError;

/// Magic value of the `format` field.
pub const FORMAT: &str = "posestream-dictionary";

/// The JSON document, field for field.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DictionaryFile {
    /// Always [`FORMAT`].
    pub format: String,
    /// Format version, 1.
    pub version: u32,
    /// Joint names in pose order.
    pub joints: Vec<String>,
    /// Parent of each joint (0-based), `null` for the root.
    pub parents: Vec<Option<usize>>,
    /// Torso joints (0-based).
    pub torso: Vec<usize>,
    /// Axis convention, free text.
    #[serde(default)]
    pub axes: Option<String>,
    /// `k` bases of 3 rows x p joints.
    pub bases: Vec<[Vec<f64>; 3]>,
    /// Mean shape, 3 rows x p joints.
    pub mean: [Vec<f64>; 3],
    /// Where the dictionary comes from.
    #[serde(default)]
    pub source: Option<String>,
    /// Licence of the dictionary (inherited from its training data).
    #[serde(default)]
    pub license: Option<String>,
}

/// Loads a JSON dictionary.
pub fn load(path: &Path) -> Result<Dictionary, DictionaryError> {
    let text = super::read_file(path).map_err(|source| DictionaryError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    from_bytes(&text, path)
}

/// Parses a JSON dictionary held in memory (`path` names it in errors).
pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Dictionary, DictionaryError> {
    let file: DictionaryFile =
        serde_json::from_slice(bytes).map_err(|source| DictionaryError::Json {
            path: path.to_path_buf(),
            source,
        })?;
    from_file(file, path)
}

/// Converts the parsed document; `path` names it in errors.
pub fn from_file(file: DictionaryFile, path: &Path) -> Result<Dictionary, DictionaryError> {
    let shape = |detail: String| DictionaryError::Shape {
        path: path.to_path_buf(),
        detail,
    };
    if file.format != FORMAT || file.version != 1 {
        return Err(shape(format!(
            "format `{}` version {} is not `{FORMAT}` version 1",
            file.format, file.version
        )));
    }
    let p = file.joints.len();
    let skeleton = Skeleton::new(file.joints, file.parents, file.torso).map_err(|detail| {
        DictionaryError::Skeleton {
            path: path.to_path_buf(),
            detail,
        }
    })?;
    let mut bases = Vec::with_capacity(file.bases.len() * 3 * p);
    for (i, b) in file.bases.iter().enumerate() {
        for row in b {
            if row.len() != p {
                return Err(shape(format!(
                    "basis {i} has a row of {} values, expected {p}",
                    row.len()
                )));
            }
            bases.extend_from_slice(row);
        }
    }
    let mut mean = Vec::with_capacity(3 * p);
    for row in &file.mean {
        if row.len() != p {
            return Err(shape(format!(
                "mean has a row of {} values, expected {p}",
                row.len()
            )));
        }
        mean.extend_from_slice(row);
    }
    Dictionary::new(skeleton, bases, mean).map_err(shape)
}

/// The document for `dict`, ready to serialise.
pub fn to_file(
    dict: &Dictionary,
    source: Option<String>,
    license: Option<String>,
) -> DictionaryFile {
    let p = dict.num_joints();
    let rows = |block: &[f64]| -> [Vec<f64>; 3] {
        [
            block[..p].to_vec(),
            block[p..2 * p].to_vec(),
            block[2 * p..].to_vec(),
        ]
    };
    DictionaryFile {
        format: FORMAT.into(),
        version: 1,
        joints: dict.skeleton().joints.clone(),
        parents: dict.skeleton().parents.clone(),
        torso: dict.skeleton().torso.clone(),
        axes: Some("x right, y down, z forward".into()),
        bases: dict.bases().chunks_exact(3 * p).map(rows).collect(),
        mean: rows(dict.mean()),
        source,
        license,
    }
}

/// Writes `dict` as JSON.
pub fn save(
    dict: &Dictionary,
    path: &Path,
    source: Option<String>,
    license: Option<String>,
) -> Result<(), DictionaryError> {
    let doc = to_file(dict, source, license);
    let text = serde_json::to_vec_pretty(&doc).map_err(|source| DictionaryError::Json {
        path: path.to_path_buf(),
        source,
    })?;
    crate::files::write_output(path, &[], &text).map_err(|e| DictionaryError::Io {
        path: path.to_path_buf(),
        source: match e {
            crate::files::OutputError::Io { source, .. } => source,
            other => std::io::Error::other(other.to_string()),
        },
    })
}
