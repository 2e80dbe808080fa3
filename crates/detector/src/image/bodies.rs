//! The whole-body person detector of the searches, NanoDet ([`crate::models::nanodet`]):
//! the converted model for the images' aspect (or the configured size), loaded when a
//! scene of that aspect begins, kept while the image size stays.

use std::path::PathBuf;

use crate::models::litert::LiteRt;
use crate::models::nanodet::{InputSize, NanoDetNetwork, SIZES};
use crate::models::nanodet_fetch::{cached_nanodet, checked_nanodet};

use super::DetectorError;
use crate::models::landmarks::NetworkError;
use posestream_base::CropBox;

/// NanoDet for the current scene, and how to load it for another.
pub(super) struct Bodies {
    dir: PathBuf,
    /// LiteRT (`None`: tract runs it).
    runtime: Option<LiteRt>,
    /// Threads of a LiteRT run.
    threads: usize,
    /// The configured size (`None`: per the images' aspect).
    fixed: Option<InputSize>,
    loaded: Option<NanoDetNetwork>,
}

impl Bodies {
    /// NanoDet from the model cache `dir`, if its files are there (else a warning and
    /// `None`: people are searched by their faces and where they move only).
    pub(super) fn new(
        dir: PathBuf,
        runtime: Option<LiteRt>,
        threads: usize,
        fixed: Option<InputSize>,
    ) -> Result<Option<Self>, DetectorError> {
        let sizes: Vec<InputSize> = fixed.map_or(SIZES.to_vec(), |s| vec![s]);
        for &size in &sizes {
            let path = cached_nanodet(&dir, size);
            if let Some(what) = posestream_base::files::what_is(&path) {
                return Err(DetectorError::NotAModel { path, what });
            }
            if !path.is_file() {
                tracing::warn!(
                    "the person detector is not fetched ({} is missing: `posestream models fetch` \
                     fetches it): people far away or seen from behind are found where they move only",
                    path.display()
                );
                return Ok(None);
            }
        }
        Ok(Some(Self {
            dir,
            runtime,
            threads,
            fixed,
            loaded: None,
        }))
    }

    /// The network for images of `width x height` loaded, now if the size it needs is
    /// not the one loaded (a scene's first frame waits for it once).
    pub(super) fn prepare(&mut self, width: u32, height: u32) -> Result<(), DetectorError> {
        let size = self
            .fixed
            .unwrap_or_else(|| InputSize::for_image(width, height));
        if self.loaded.as_ref().is_none_or(|n| n.size() != size) {
            self.loaded = None;
            // One file for both runtimes, checked as fetched before either parses it.
            let path = checked_nanodet(&self.dir, size).map_err(|reason| {
                let context = format!("loading {}", cached_nanodet(&self.dir, size).display());
                DetectorError::Network(match self.runtime {
                    Some(_) => NetworkError::LiteRt { context, reason },
                    None => NetworkError::Tract { context, reason },
                })
            })?;
            let began = std::time::Instant::now();
            self.loaded = Some(match &self.runtime {
                Some(runtime) => NanoDetNetwork::load_litert(runtime, &path, size, self.threads)?,
                None => NanoDetNetwork::load(&path, size)?,
            });
            if let Some(network) = &self.loaded {
                network.warm_up()?;
            }
            tracing::debug!(
                "person detector for {size} loaded in {:.0} ms",
                began.elapsed().as_secs_f64() * 1e3
            );
        }
        Ok(())
    }

    /// The network [`Self::prepare`] loaded.
    pub(super) fn loaded(&self) -> Option<&NanoDetNetwork> {
        self.loaded.as_ref()
    }
}

/// The box around `area` with `size`'s aspect (same centre): `area` letterboxed.
pub(super) fn letterboxed(area: &CropBox, size: InputSize) -> CropBox {
    let aspect = size.width as f64 / size.height as f64;
    let (mut width, mut height) = (area.width, area.height);
    if width / height > aspect {
        height = width / aspect;
    } else {
        width = height * aspect;
    }
    CropBox {
        x0: area.x0 + 0.5 * (area.width - width),
        y0: area.y0 + 0.5 * (area.height - height),
        width,
        height,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_area_is_letterboxed_to_the_inputs_aspect() {
        let area = CropBox {
            x0: 0.0,
            y0: 0.0,
            width: 640.0,
            height: 360.0,
        };
        let b = letterboxed(&area, SIZES[3]);
        assert_eq!((b.x0, b.width), (0.0, 640.0));
        assert!((b.height - 640.0 * 256.0 / 416.0).abs() < 1e-9);
        assert!((b.y0 + 0.5 * b.height - 180.0).abs() < 1e-9);
        let tall = letterboxed(&area, SIZES[0]);
        assert_eq!((tall.width, tall.height), (640.0, 640.0));
        assert_eq!(tall.y0, -140.0);
    }
}
