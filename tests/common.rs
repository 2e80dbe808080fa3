//! Shared helpers of the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

use posestream::npy::{self, Array};

/// `../shared` beside the repository.
pub fn shared() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared")
}

/// The authors' K128 dictionary.
pub fn k128() -> PathBuf {
    shared().join("reference/monocap-dicts/poseDict-all-K128.mat")
}

/// A parity fixture folder.
pub fn fixture(name: &str) -> PathBuf {
    shared().join("reference/parity").join(name)
}

/// Reads an f64 array.
pub fn read(path: PathBuf) -> Array<f64> {
    npy::read(&path).unwrap_or_else(|e| panic!("{e}"))
}
