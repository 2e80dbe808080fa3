//! A train/test split of a motion collection by whole file (`config/splits/*.toml`).
//!
//! File names follow `<dataset>_<content>_<style>_<take>.bvh` (the Bandai-Namco naming);
//! a file is held out when its content or its style is listed.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use posestream_msgs::toml_file::{ConfigError, load_toml};

/// Loading a split or listing motion files failed.
#[derive(Debug, thiserror::Error)]
pub enum SplitError {
    /// A file or folder could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The split file could not be read or has unknown keys.
    #[error("split: {0}")]
    Config(#[from] ConfigError),
    /// No BVH file was found.
    #[error("no .bvh files in {0}")]
    Empty(String),
}

/// Which files are held out.
#[derive(Debug, Clone, PartialEq, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Split {
    /// Contents (actions) held out entirely.
    #[serde(default)]
    pub test_contents: Vec<String>,
    /// Styles held out entirely.
    #[serde(default)]
    pub test_styles: Vec<String>,
}

/// Content and style of a motion file, from its name.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MotionName {
    /// The action (`walk`, `punch`, ...).
    pub content: String,
    /// The manner (`normal`, `proud`, ...).
    pub style: String,
}

impl MotionName {
    /// Parses `<dataset>_<content>_<style>_<take>`; `None` for other names.
    pub fn parse(path: &Path) -> Option<Self> {
        let stem = path.file_stem()?.to_str()?;
        let fields: Vec<&str> = stem.split('_').collect();
        (fields.len() == 4).then(|| Self {
            content: fields[1].to_string(),
            style: fields[2].to_string(),
        })
    }
}

impl Split {
    /// Loads a split file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, SplitError> {
        Ok(load_toml(path.as_ref())?)
    }

    /// True when the file is held out. Files whose names do not parse are training files.
    pub fn is_test(&self, path: &Path) -> bool {
        MotionName::parse(path).is_some_and(|m| {
            self.test_contents.contains(&m.content) || self.test_styles.contains(&m.style)
        })
    }
}

/// The `.bvh` files of `inputs`: folders are listed (sorted), files kept as given.
pub fn list_bvh(inputs: &[PathBuf]) -> Result<Vec<PathBuf>, SplitError> {
    let mut files = Vec::new();
    for input in inputs {
        if input.is_dir() {
            let entries = std::fs::read_dir(input).map_err(|source| SplitError::Io {
                path: input.clone(),
                source,
            })?;
            let mut found: Vec<PathBuf> = entries
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("bvh")))
                .collect();
            found.sort();
            files.extend(found);
        } else {
            files.push(input.clone());
        }
    }
    if files.is_empty() {
        let names: Vec<String> = inputs.iter().map(|p| p.display().to_string()).collect();
        return Err(SplitError::Empty(names.join(", ")));
    }
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn holds_out_by_content_or_style() {
        let split = Split {
            test_contents: vec!["kick".into()],
            test_styles: vec!["proud".into()],
        };
        let f = |s: &str| PathBuf::from(format!("dir/{s}.bvh"));
        assert!(split.is_test(&f("dataset-1_kick_normal_001")));
        assert!(split.is_test(&f("dataset-1_walk_proud_001")));
        assert!(!split.is_test(&f("dataset-1_walk-back_normal_001")));
        assert!(!split.is_test(&f("other")));
    }
}
