//! The files the math is loaded from: pose dictionaries (posestream's JSON,
//! [`dictionary_json`], and the authors' MATLAB files, [`dictionary_mat`]) and camera
//! intrinsics ([`intrinsics`]). The math crate opens no file: a [`Dictionary`] or an
//! [`Intrinsics`] comes from a file through [`LoadDictionary::load`] and
//! [`LoadIntrinsics::load`] (or from a built-in file: [`crate::shipped`]).

pub mod dictionary_json;
pub mod dictionary_mat;
pub mod intrinsics;

use std::path::Path;

use posestream_math::Dictionary;
#[cfg(doc)]
use posestream_math::camera::Intrinsics;

use crate::error::DictionaryError;

pub use intrinsics::LoadIntrinsics;

/// The largest dictionary or intrinsics file read (a dictionary of 1,024 bases of 100
/// joints in JSON is about 10 MB).
pub const MAX_FILE_BYTES: u64 = 64 << 20;

/// Reads a user's file whole: the one place the formats here read from the file system
/// (a regular file only, at most [`MAX_FILE_BYTES`]: [`posestream_base::files`]).
pub(crate) fn read_file(path: &Path) -> std::io::Result<Vec<u8>> {
    posestream_base::files::read_capped(path, MAX_FILE_BYTES)
}

/// A [`Dictionary`] loaded from a file.
pub trait LoadDictionary: Sized {
    /// Loads a dictionary, choosing the format by extension (`.mat` or `.json`).
    fn load(path: impl AsRef<Path>) -> Result<Self, DictionaryError>;
}

impl LoadDictionary for Dictionary {
    fn load(path: impl AsRef<Path>) -> Result<Self, DictionaryError> {
        let path = path.as_ref();
        match path.extension().and_then(|e| e.to_str()) {
            Some(e) if e.eq_ignore_ascii_case("mat") => dictionary_mat::load(path),
            Some(e) if e.eq_ignore_ascii_case("json") => dictionary_json::load(path),
            _ => Err(DictionaryError::UnknownFormat {
                path: path.to_path_buf(),
            }),
        }
    }
}
