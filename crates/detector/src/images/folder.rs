//! The image files of a folder (PNG, JPEG, GIF), in file-name order, as frames spaced
//! by a frame rate. A file that cannot be decoded is reported as a malformed message and
//! skipped; the frame numbers of the others stay those of their place in the folder, so
//! the estimator sees the gap.

use std::path::{Path, PathBuf};
use std::time::Duration;

use super::ImageFrame;
use posestream_base::{Received, Source, TransportError};
use posestream_msgs::limits::Limits;

/// File extensions read (lower case).
pub const EXTENSIONS: [&str; 4] = ["png", "jpg", "jpeg", "gif"];

/// The images of one folder.
#[derive(Debug)]
pub struct FolderSource {
    folder: PathBuf,
    files: Vec<PathBuf>,
    next: usize,
    fps: f64,
    frame_id: String,
    limits: Limits,
}

fn setup(path: &Path, reason: impl Into<String>) -> TransportError {
    super::setup_error("images", path, reason)
}

impl FolderSource {
    /// The image files of `folder` (not its subfolders), frames `1 / fps` seconds
    /// apart, with camera frame id `frame_id`. A folder without images is an error; a
    /// file beyond `limits` (bytes: `max_record_bytes`; pixels: `max_image_pixels`) is
    /// refused as malformed and skipped.
    pub fn open(
        folder: &Path,
        fps: f64,
        frame_id: &str,
        limits: &Limits,
    ) -> Result<Self, TransportError> {
        if !(fps.is_finite() && fps > 0.0) {
            return Err(setup(folder, format!("frame rate {fps} must be positive")));
        }
        let entries = std::fs::read_dir(folder).map_err(|e| setup(folder, e.to_string()))?;
        let mut files = Vec::new();
        for entry in entries {
            let path = entry.map_err(|e| setup(folder, e.to_string()))?.path();
            let image = path
                .extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()));
            if image && path.is_file() {
                files.push(path);
            }
        }
        if files.is_empty() {
            return Err(setup(
                folder,
                format!("no image files ({}) in it", EXTENSIONS.join(", ")),
            ));
        }
        files.sort();
        Ok(Self {
            folder: folder.to_path_buf(),
            files,
            next: 0,
            fps,
            frame_id: frame_id.to_string(),
            limits: limits.clone(),
        })
    }

    /// The files, in the order they are read.
    pub fn files(&self) -> &[PathBuf] {
        &self.files
    }
}

impl Source<ImageFrame> for FolderSource {
    fn recv(&mut self, _timeout: Duration) -> Result<Received<ImageFrame>, TransportError> {
        let Some(path) = self.files.get(self.next) else {
            return Ok(Received::Closed);
        };
        let index = self.next as u64;
        self.next += 1;
        let name = path
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
        let malformed = |reason: String| TransportError::Malformed {
            transport: "images",
            topic: self.folder.display().to_string(),
            reason: format!("{name}: {reason}"),
        };
        // Read through a bound: the file may grow while it is read.
        let limit = self.limits.max_record_bytes as u64;
        let bytes = posestream_base::files::read_capped(path, limit).map_err(|e| {
            if e.kind() == std::io::ErrorKind::InvalidData {
                malformed(format!("more than limits.max_record_bytes = {limit} bytes"))
            } else {
                malformed(e.to_string())
            }
        })?;
        let rgb = super::decode_bytes(&bytes, &self.limits).map_err(malformed)?;
        Ok(ImageFrame::from_file(
            index,
            self.fps,
            &self.frame_id,
            name,
            rgb,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn images_come_in_name_order_and_a_broken_file_is_skipped_with_an_error() {
        let dir = tempfile::tempdir().expect("dir");
        for (name, shade) in [("b.png", 20_u8), ("a.png", 10)] {
            image::RgbImage::from_pixel(4, 3, image::Rgb([shade, 0, 0]))
                .save(dir.path().join(name))
                .expect("save");
        }
        std::fs::write(dir.path().join("c.jpg"), b"not a jpeg").expect("write");
        std::fs::write(dir.path().join("notes.txt"), b"ignored").expect("write");
        let mut source =
            FolderSource::open(dir.path(), 10.0, "camera", &Limits::default()).expect("open");
        assert_eq!(source.files().len(), 3);
        let wait = Duration::ZERO;
        let Ok(Received::Message(a, stamp)) = source.recv(wait) else {
            panic!("first")
        };
        assert_eq!(
            (a.name.as_str(), a.rgb.get_pixel(0, 0)[0], stamp),
            ("a.png", 10, 0)
        );
        let Ok(Received::Message(b, stamp)) = source.recv(wait) else {
            panic!("second")
        };
        assert_eq!(
            (b.sequence, b.rgb.dimensions(), stamp),
            (1, (4, 3), 100_000_000)
        );
        assert!(matches!(
            source.recv(wait),
            Err(TransportError::Malformed { .. })
        ));
        assert!(matches!(source.recv(wait), Ok(Received::Closed)));
    }

    #[test]
    fn a_folder_without_images_or_a_missing_one_is_an_error() {
        let dir = tempfile::tempdir().expect("dir");
        let empty =
            FolderSource::open(dir.path(), 30.0, "c", &Limits::default()).expect_err("empty");
        assert!(empty.to_string().contains("no image files"), "{empty}");
        assert!(
            FolderSource::open(&dir.path().join("nope"), 30.0, "c", &Limits::default()).is_err()
        );
        assert!(FolderSource::open(dir.path(), 0.0, "c", &Limits::default()).is_err());
    }
}
