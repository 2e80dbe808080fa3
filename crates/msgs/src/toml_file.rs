//! Reading the project's TOML configuration files (skeleton mappings, splits); a
//! `builtin:NAME` path reads the file shipped in the binary ([`crate::shipped`]).

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;

/// A TOML file could not be read or does not fit its schema.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is not valid TOML, or has unknown, missing or mistyped keys.
    #[error("{path}: {source}")]
    Toml {
        /// The file.
        path: PathBuf,
        /// The parser's message (with the offending line).
        source: toml::de::Error,
    },
    /// The document's shape is wrong where serde would say something unhelpful (a
    /// section written as an array of tables).
    #[error("{path}: {reason}")]
    Shape {
        /// The file.
        path: PathBuf,
        /// What is wrong and how to write it.
        reason: String,
    },
    /// A value is outside its domain.
    #[error("{path}: {source}")]
    Domain {
        /// The file.
        path: PathBuf,
        /// The key, its domain and the value found.
        source: posestream_base::OutOfDomain,
    },
}

/// The largest TOML file read: configuration is small (the shipped one about 22 kB), and
/// parsing costs tens of times a file's size, so a long one is refused unread.
pub const MAX_TOML_BYTES: u64 = 1 << 20;

/// Reads and deserialises a TOML file (or a shipped one, `builtin:NAME`).
pub fn load_toml<T: DeserializeOwned>(path: &Path) -> Result<T, ConfigError> {
    parse_toml(&read_toml(path)?, path)
}

/// Reads a TOML file's text (or a shipped one's), at most [`MAX_TOML_BYTES`].
pub fn read_toml(path: &Path) -> Result<std::borrow::Cow<'static, str>, ConfigError> {
    let io = |source| ConfigError::Io {
        path: path.to_path_buf(),
        source,
    };
    if crate::shipped::find(path).is_some() {
        return crate::shipped::read_to_string(path).map_err(io);
    }
    posestream_base::files::read_capped_string(path, MAX_TOML_BYTES)
        .map(std::borrow::Cow::Owned)
        .map_err(io)
}

/// Deserialises TOML text (`path` names it in errors).
pub fn parse_toml<T: DeserializeOwned>(text: &str, path: &Path) -> Result<T, ConfigError> {
    toml::from_str(text).map_err(|source| ConfigError::Toml {
        path: path.to_path_buf(),
        source,
    })
}
