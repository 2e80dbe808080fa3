//! Reader for the authors' MATLAB dictionaries (MonoCap release): `B` (3k x p; rows
//! 3i..3i+2 are basis i), `mu` (3 x p), `skel.tree(i).name`, `skel.tree(i).children`
//! (1-based) and `skel.torso` (1-based).

use std::path::Path;

use matrw::MatVariable;

use posestream_math::Dictionary;
use posestream_math::skeleton::Skeleton;

use crate::error::DictionaryError;

/// Loads a MATLAB v5/v7 dictionary file.
pub fn load(path: &Path) -> Result<Dictionary, DictionaryError> {
    let bytes = super::read_file(path).map_err(|source| DictionaryError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    from_bytes(&bytes, path)
}

/// Parses a MATLAB dictionary from memory; `path` names it in errors.
///
/// The MAT reader (`matrw` 0.1) panics on some malformed inputs, while parsing (a
/// truncated deflate stream) and in its accessors (`not implemented` for some variable
/// kinds; found by fuzzing): the whole reading is one contained region, and a panic in it
/// is reported as a malformed file.
pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Dictionary, DictionaryError> {
    posestream_base::contain_panics(|| read(bytes, path)).unwrap_or_else(|_| {
        Err(DictionaryError::Mat {
            path: path.to_path_buf(),
            reason: "malformed file".into(),
        })
    })
}

fn read(bytes: &[u8], path: &Path) -> Result<Dictionary, DictionaryError> {
    let missing = |what: &str| DictionaryError::Missing {
        path: path.to_path_buf(),
        what: what.to_string(),
    };
    let shape = |detail: String| DictionaryError::Shape {
        path: path.to_path_buf(),
        detail,
    };
    let normalised = normalise_header(bytes);
    let bytes = normalised.as_deref().unwrap_or(bytes);
    let file = matrw::load_matfile_from_u8(bytes).map_err(|e| DictionaryError::Mat {
        path: path.to_path_buf(),
        reason: one_line(&e.to_string()),
    })?;
    if !file.contains("B") {
        return Err(missing("B"));
    }
    let b = &file["B"];
    let (rows, p) = matrix_dims(b).ok_or_else(|| missing("B"))?;
    if rows == 0 || rows % 3 != 0 || p == 0 {
        return Err(shape(format!("B is {rows} x {p}, expected 3k x p")));
    }
    let b_colmajor = b.to_vec_f64().ok_or_else(|| missing("B"))?;
    let k = rows / 3;
    // Column-major (3k x p) to k row-major blocks of 3 x p.
    let mut bases = vec![0.0; 3 * k * p];
    for j in 0..p {
        for r in 0..rows {
            let (i, d) = (r / 3, r % 3);
            bases[i * 3 * p + d * p + j] = b_colmajor[j * rows + r];
        }
    }
    let mean = if file.contains("mu") {
        let mu = &file["mu"];
        if matrix_dims(mu) != Some((3, p)) {
            return Err(shape(format!("mu is {:?}, expected 3 x {p}", mu.dim())));
        }
        let v = mu.to_vec_f64().ok_or_else(|| missing("mu"))?;
        let mut m = vec![0.0; 3 * p];
        for j in 0..p {
            for d in 0..3 {
                m[d * p + j] = v[j * 3 + d];
            }
        }
        m
    } else {
        vec![0.0; 3 * p]
    };
    if !file.contains("skel") {
        return Err(missing("skel"));
    }
    let skeleton = read_skeleton(&file["skel"], p, path)?;
    Dictionary::new(skeleton, bases, mean).map_err(|detail| {
        if detail.contains("non-finite") {
            DictionaryError::NonFinite {
                path: path.to_path_buf(),
                what: "B or mu".into(),
            }
        } else {
            shape(detail)
        }
    })
}

/// The MAT 5 header's first 116 bytes are free text: MATLAB writes
/// `MATLAB 5.0 MAT-file, Platform: ...`, Octave `MATLAB 5.0 MAT-file, written by Octave`,
/// scipy's `savemat` `MATLAB 5.0 MAT-file Platform: ...` (no comma). What identifies a
/// MAT 5 file is the version 0x0100 and the endian indicator `IM`/`MI` at bytes 124-127;
/// `matrw` insists on the comma, so a MAT 5 file with another text gets MATLAB's prefix
/// (in a copy) before it is parsed.
fn normalise_header(bytes: &[u8]) -> Option<Vec<u8>> {
    const PREFIX: &[u8] = b"MATLAB 5.0 MAT-file, ";
    let flags = bytes.get(124..128)?;
    let mat5 = matches!(flags, [0x00, 0x01, b'I', b'M'] | [0x01, 0x00, b'M', b'I']);
    if !mat5 || bytes.starts_with(PREFIX) {
        return None;
    }
    let mut copy = bytes.to_vec();
    copy[..PREFIX.len()].copy_from_slice(PREFIX);
    Some(copy)
}

/// The reader's (multi-line, colourised) message as one plain line: the first line that
/// names an error, else the first line.
fn one_line(msg: &str) -> String {
    let mut plain = String::with_capacity(msg.len());
    let mut chars = msg.chars();
    while let Some(c) = chars.next() {
        if c == '\u{1b}' {
            // Skip an ANSI escape sequence up to its final letter.
            for d in chars.by_ref() {
                if d.is_ascii_alphabetic() {
                    break;
                }
            }
        } else {
            plain.push(c);
        }
    }
    let lines: Vec<&str> = plain
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect();
    let line = lines
        .iter()
        .find(|l| l.contains("Error:"))
        .or(lines.first())
        .copied()
        .unwrap_or("malformed file");
    line.trim_start_matches(|c: char| c.is_ascii_digit() || c == ':' || c == ' ')
        .to_string()
}

fn matrix_dims(v: &MatVariable) -> Option<(usize, usize)> {
    match v {
        MatVariable::NumericArray(_) => match v.dim().as_slice() {
            [r, c] => Some((*r, *c)),
            _ => None,
        },
        _ => None,
    }
}

fn read_skeleton(skel: &MatVariable, p: usize, path: &Path) -> Result<Skeleton, DictionaryError> {
    let missing = |what: &str| DictionaryError::Missing {
        path: path.to_path_buf(),
        what: what.to_string(),
    };
    let fields = skel.fieldnames().ok_or_else(|| missing("skel"))?;
    if !fields.iter().any(|f| f == "tree") {
        return Err(missing("skel.tree"));
    }
    let tree = &skel["tree"];
    let n = tree.dim().iter().product::<usize>();
    if n != p {
        return Err(DictionaryError::Shape {
            path: path.to_path_buf(),
            detail: format!("skel.tree has {n} joints but B has {p}"),
        });
    }
    let mut joints = Vec::with_capacity(p);
    let mut parents = vec![None; p];
    for j in 0..p {
        let node = &tree[j];
        let name: String = node["name"]
            .to_vec::<char>()
            .ok_or_else(|| missing("skel.tree.name"))?
            .into_iter()
            .collect();
        joints.push(name);
        let children = match &node["children"] {
            MatVariable::NumericArray(_) => node["children"].to_vec_f64().unwrap_or_default(),
            _ => Vec::new(),
        };
        for c in children {
            let ci = c as usize;
            if c < 1.0 || ci > p || c.fract() != 0.0 {
                return Err(DictionaryError::Skeleton {
                    path: path.to_path_buf(),
                    detail: format!("joint {} lists child {c}", j + 1),
                });
            }
            if parents[ci - 1].is_some() {
                return Err(DictionaryError::Skeleton {
                    path: path.to_path_buf(),
                    detail: format!("joint {ci} has two parents"),
                });
            }
            parents[ci - 1] = Some(j);
        }
    }
    let torso = if fields.iter().any(|f| f == "torso") {
        skel["torso"]
            .to_vec_f64()
            .unwrap_or_default()
            .into_iter()
            .map(|t| (t as usize).wrapping_sub(1))
            .collect()
    } else {
        Vec::new()
    };
    Skeleton::new(joints, parents, torso).map_err(|detail| DictionaryError::Skeleton {
        path: path.to_path_buf(),
        detail,
    })
}
