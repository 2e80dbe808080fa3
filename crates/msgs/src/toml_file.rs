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

/// The largest TOML file read: configuration is small, and a path to something endless
/// (`/dev/zero`) must not be read into memory.
pub const MAX_TOML_BYTES: u64 = 4 << 20;

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
    use std::io::Read;
    let mut text = String::new();
    std::fs::File::open(path)
        .and_then(|f| f.take(MAX_TOML_BYTES + 1).read_to_string(&mut text))
        .map_err(io)?;
    if text.len() as u64 > MAX_TOML_BYTES {
        return Err(io(std::io::Error::other(format!(
            "longer than {MAX_TOML_BYTES} bytes: not a configuration file"
        ))));
    }
    Ok(std::borrow::Cow::Owned(text))
}

/// Deserialises TOML text (`path` names it in errors).
pub fn parse_toml<T: DeserializeOwned>(text: &str, path: &Path) -> Result<T, ConfigError> {
    toml::from_str(text).map_err(|source| ConfigError::Toml {
        path: path.to_path_buf(),
        source,
    })
}
