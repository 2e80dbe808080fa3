//! Camera intrinsics as a JSON file: `{"fx", "fy", "cx", "cy"}` or `{"K": 3 x 3 rows}`
//! ([`from_json`]), loaded by [`LoadIntrinsics::load`].

use std::path::Path;

use posestream_math::camera::Intrinsics;
use serde::Deserialize;

use crate::error::CameraError;

/// The JSON forms [`LoadIntrinsics::load`] accepts.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
enum IntrinsicsFile {
    /// `{"fx": 1000, "fy": 1000, "cx": 640, "cy": 360}`.
    Named(NamedIntrinsics),
    /// `{"K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]}` (a row-major 3 x 3 matrix).
    Matrix(MatrixIntrinsics),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct NamedIntrinsics {
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MatrixIntrinsics {
    #[serde(rename = "K")]
    k: Vec<Vec<f64>>,
}

/// Parses intrinsics JSON: either `{"fx", "fy", "cx", "cy"}` or `{"K": 3 x 3 rows}` with
/// zero skew and a last row `[0, 0, 1]`.
pub fn from_json(text: &str) -> Result<Intrinsics, String> {
    let file: IntrinsicsFile = serde_json::from_str(text).map_err(|_| {
        "expected {\"fx\", \"fy\", \"cx\", \"cy\"} or {\"K\": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]}"
            .to_string()
    })?;
    match file {
        IntrinsicsFile::Named(n) => Intrinsics::new(n.fx, n.fy, n.cx, n.cy),
        IntrinsicsFile::Matrix(m) => {
            if m.k.len() != 3 || m.k.iter().any(|row| row.len() != 3) {
                return Err("K must be 3 rows of 3 numbers".into());
            }
            let k = &m.k;
            if k[0][1] != 0.0 || k[1][0] != 0.0 || k[2] != [0.0, 0.0, 1.0] {
                return Err(
                    "K must have zero skew and last row [0, 0, 1] (a pinhole camera)".into(),
                );
            }
            Intrinsics::new(k[0][0], k[1][1], k[0][2], k[1][2])
        }
    }
}

/// [`Intrinsics`] loaded from a file.
pub trait LoadIntrinsics: Sized {
    /// Reads a JSON file (see [`from_json`]).
    fn load(path: impl AsRef<Path>) -> Result<Self, CameraError>;
}

impl LoadIntrinsics for Intrinsics {
    fn load(path: impl AsRef<Path>) -> Result<Self, CameraError> {
        let path = path.as_ref();
        let bytes = super::read_file(path).map_err(|source| CameraError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let text = String::from_utf8(bytes).map_err(|_| CameraError::Io {
            path: path.to_path_buf(),
            source: std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                "stream did not contain valid UTF-8",
            ),
        })?;
        from_json(&text).map_err(|detail| CameraError::Invalid {
            path: path.to_path_buf(),
            detail,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn intrinsics_parse_both_forms_and_reject_bad_values() {
        let a = from_json(r#"{"fx": 800, "fy": 810, "cx": 320, "cy": 240}"#).expect("named");
        let b = from_json(r#"{"K": [[800, 0, 320], [0, 810, 240], [0, 0, 1]]}"#).expect("matrix");
        assert_eq!(a, b);
        let p = Vector3::new(0.3, -0.2, 2.0);
        let [u, v] = a.project(&p);
        let r = a.ray(u, v) * p.z;
        assert!((r - p).norm() < 1e-12);
        for bad in [
            r#"{"fx": -1, "fy": 800, "cx": 0, "cy": 0}"#,
            r#"{"fx": 800, "fy": 800, "cx": 0}"#,
            r#"{"fx": 800, "fy": 800, "cx": 0, "cy": 0, "skew": 1}"#,
            r#"{"K": [[800, 0, 320], [0, 800, 240]]}"#,
            r#"{"K": [[800, 1, 320], [0, 800, 240], [0, 0, 1]]}"#,
            r#"[1, 2, 3]"#,
        ] {
            assert!(from_json(bad).is_err(), "{bad}");
        }
    }
}
