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
    /// A value is outside its domain.
    #[error("{path}: {source}")]
    Domain {
        /// The file.
        path: PathBuf,
        /// The key, its domain and the value found.
        source: posestream_math::error::OutOfDomain,
    },
}

/// Reads and deserialises a TOML file (or a shipped one, `builtin:NAME`).
pub fn load_toml<T: DeserializeOwned>(path: &Path) -> Result<T, ConfigError> {
    let text = crate::shipped::read_to_string(path).map_err(|source| ConfigError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_toml(&text, path)
}

/// Deserialises TOML text (`path` names it in errors).
pub fn parse_toml<T: DeserializeOwned>(text: &str, path: &Path) -> Result<T, ConfigError> {
    toml::from_str(text).map_err(|source| ConfigError::Toml {
        path: path.to_path_buf(),
        source,
    })
}
