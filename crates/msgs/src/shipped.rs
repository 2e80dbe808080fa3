//! The files posestream ships inside its binary, so that an installed `posestream` runs
//! from any directory without the checkout: the pose dictionary, the detector's channel
//! mapping, the skeleton mappings and split of the motion-capture tools, and the demo
//! recording. A path `builtin:NAME` anywhere a file is read (configuration keys,
//! command-line options) names one of them; `NAME` is the file's path in the repository
//! below `config/` (or `recordings/` for recordings), so `builtin:dictionaries/default-k128.json`
//! is `config/dictionaries/default-k128.json` as it was when the binary was built.
//!
//! The files are embedded with `include_bytes!` rather than installed beside the binary:
//! `cargo install` installs binaries only, and a path beside the binary breaks when it is
//! copied alone (a container, a robot's image).

use crate::formats::LoadDictionary;
use std::path::Path;

/// The prefix of a shipped file's path.
pub const PREFIX: &str = crate::files::BUILTIN;

/// One shipped file.
#[derive(Debug)]
pub struct Shipped {
    /// Its name after [`PREFIX`].
    pub name: &'static str,
    /// Its contents.
    pub bytes: &'static [u8],
    /// What it is, for listings.
    pub about: &'static str,
}

impl Shipped {
    /// Its path as configuration writes it (`builtin:NAME`).
    pub fn path(&self) -> String {
        format!("{PREFIX}{}", self.name)
    }
}

macro_rules! shipped {
    ($($name:literal from $file:literal: $about:literal),* $(,)?) => {
        /// Every shipped file.
        pub static FILES: &[Shipped] = &[$(Shipped {
            name: $name,
            bytes: include_bytes!(concat!(env!("CARGO_MANIFEST_DIR"), "/../../", $file)),
            about: $about,
        }),*];
    };
}

shipped! {
    "dictionaries/default-k128.json" from "config/dictionaries/default-k128.json":
        "the pose dictionary (128 bases, learnt from Bandai-Namco motion capture)",
    "detectors/blazepose.toml" from "config/detectors/blazepose.toml":
        "BlazePose's landmarks to the dictionary's joints",
    "skeletons/bandai-namco.toml" from "config/skeletons/bandai-namco.toml":
        "Bandai-Namco BVH joints to the dictionary's joints",
    "skeletons/cmu.toml" from "config/skeletons/cmu.toml":
        "CMU (cgspeed) BVH joints to the dictionary's joints",
    "splits/bandai-namco.toml" from "config/splits/bandai-namco.toml":
        "the held-out files of the evaluation",
    "recordings/byebye.mcap" from "recordings/byebye.mcap":
        "the demo: 121 frames of heat maps of a person waving goodbye, with the truth",
}

/// The shipped configuration (`config/default.toml`): every key with its default value
/// and a comment.
pub const DEFAULT_CONFIG: &str = include_str!(concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../config/default.toml"
));

/// A `builtin:` path that names no shipped file.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("no such built-in file (built in: {known})")]
pub struct UnknownShipped {
    /// The path asked for.
    pub path: String,
    /// The shipped files' paths.
    pub known: String,
}

impl From<UnknownShipped> for std::io::Error {
    fn from(e: UnknownShipped) -> Self {
        std::io::Error::new(std::io::ErrorKind::NotFound, e.to_string())
    }
}

/// What `path` names: `None` for an ordinary file, the shipped file for `builtin:NAME`,
/// or an error when `NAME` is none of them.
pub fn find(path: &Path) -> Option<Result<&'static Shipped, UnknownShipped>> {
    let name = path.to_str()?.strip_prefix(PREFIX)?;
    Some(FILES.iter().find(|f| f.name == name).ok_or_else(|| {
        UnknownShipped {
            path: path.display().to_string(),
            known: FILES
                .iter()
                .map(Shipped::path)
                .collect::<Vec<_>>()
                .join(", "),
        }
    }))
}

/// The largest file [`read`] reads from the file system.
const MAX_FILE_BYTES: u64 = 64 << 20;

/// Reads `path`: a shipped file's bytes for `builtin:NAME`, else the file's (a regular
/// file of at most 64 MiB, [`posestream_base::files::read_capped`]).
pub fn read(path: &Path) -> std::io::Result<std::borrow::Cow<'static, [u8]>> {
    match find(path) {
        Some(found) => Ok(std::borrow::Cow::Borrowed(found?.bytes)),
        None => {
            posestream_base::files::read_capped(path, MAX_FILE_BYTES).map(std::borrow::Cow::Owned)
        }
    }
}

/// Reads `path` as text (UTF-8), shipped or not.
pub fn read_to_string(path: &Path) -> std::io::Result<std::borrow::Cow<'static, str>> {
    let invalid = |e| std::io::Error::new(std::io::ErrorKind::InvalidData, e);
    match read(path)? {
        std::borrow::Cow::Borrowed(b) => std::str::from_utf8(b)
            .map(std::borrow::Cow::Borrowed)
            .map_err(invalid),
        std::borrow::Cow::Owned(b) => String::from_utf8(b)
            .map(std::borrow::Cow::Owned)
            .map_err(|e| invalid(e.utf8_error())),
    }
}

/// Loads a pose dictionary: a shipped one (`builtin:dictionaries/NAME.json`) or a file
/// ([`LoadDictionary::load`]: `.json` or the authors' `.mat`).
pub fn load_dictionary(
    path: &Path,
) -> Result<posestream_math::Dictionary, crate::error::DictionaryError> {
    match find(path) {
        Some(found) => {
            let shipped = found.map_err(|e| crate::error::DictionaryError::Io {
                path: path.to_path_buf(),
                source: e.into(),
            })?;
            crate::formats::dictionary_json::from_bytes(shipped.bytes, path)
        }
        None => <posestream_math::Dictionary as LoadDictionary>::load(path),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_paths_name_the_shipped_files_and_others_are_files() {
        let dict = find(Path::new("builtin:dictionaries/default-k128.json"))
            .expect("a builtin path")
            .expect("shipped");
        assert!(dict.bytes.starts_with(b"{"));
        assert!(find(Path::new("config/dictionaries/default-k128.json")).is_none());
        assert!(find(Path::new("builtin")).is_none());
        let unknown = find(Path::new("builtin:dictionaries/k256.json"))
            .expect("a builtin path")
            .expect_err("not shipped");
        assert!(
            unknown
                .to_string()
                .contains("builtin:recordings/byebye.mcap"),
            "{unknown}"
        );
        let e = read(Path::new("builtin:nothing")).expect_err("not shipped");
        assert_eq!(e.kind(), std::io::ErrorKind::NotFound);
        assert_eq!(
            read_to_string(Path::new("builtin:detectors/blazepose.toml"))
                .expect("text")
                .as_ref()
                .as_bytes(),
            find(Path::new("builtin:detectors/blazepose.toml"))
                .and_then(Result::ok)
                .expect("shipped")
                .bytes
        );
    }

    #[test]
    fn the_shipped_dictionary_loads_as_its_file_does() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let shipped =
            load_dictionary(Path::new("builtin:dictionaries/default-k128.json")).expect("loads");
        let file =
            load_dictionary(&root.join("config/dictionaries/default-k128.json")).expect("loads");
        assert_eq!(shipped.bases(), file.bases());
        assert_eq!(shipped.skeleton().joints, file.skeleton().joints);
        let e = load_dictionary(Path::new("builtin:dictionaries/k7.json")).expect_err("unknown");
        assert!(e.to_string().contains("no such built-in file"), "{e}");
    }
}
