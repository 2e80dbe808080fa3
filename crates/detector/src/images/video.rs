//! A video file, decoded by the `ffmpeg` program (Debian package `ffmpeg`) into raw RGB
//! frames on a pipe; `ffprobe` gives the size and frame rate first. Any container and
//! codec ffmpeg reads will do. A video cut short ends the source with the frames read
//! so far and an error saying so.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::time::Duration;

use super::ImageFrame;
use posestream_base::{Received, Source, TransportError};
use posestream_msgs::limits::Limits;

/// One video being decoded.
#[derive(Debug)]
pub struct VideoSource {
    path: PathBuf,
    child: Child,
    stdout: ChildStdout,
    stderr: Option<std::thread::JoinHandle<String>>,
    width: u32,
    height: u32,
    fps: f64,
    next: u64,
    frame_id: String,
    done: bool,
}

fn setup(path: &Path, reason: impl Into<String>) -> TransportError {
    super::setup_error("video", path, reason)
}

fn program_error(program: &str, e: std::io::Error) -> String {
    if e.kind() == std::io::ErrorKind::NotFound {
        format!("`{program}` not found: install ffmpeg (Debian: apt install ffmpeg)")
    } else {
        format!("cannot run `{program}`: {e}")
    }
}

/// Width, height and frames per second of the first video stream of `path`.
pub fn probe(path: &Path) -> Result<(u32, u32, f64), TransportError> {
    // A regular file only: a device or a FIFO would keep ffprobe waiting.
    if let Err(e) = posestream_base::files::open_regular(path) {
        let why = match e.kind() {
            std::io::ErrorKind::NotFound => "no such file".to_string(),
            _ => e.to_string(),
        };
        return Err(setup(path, why));
    }
    let out = Command::new("ffprobe")
        .args(["-v", "error", "-select_streams", "v:0"])
        .args(["-show_entries", "stream=width,height,r_frame_rate"])
        .args(["-of", "csv=p=0"])
        .arg(path)
        .output()
        .map_err(|e| setup(path, program_error("ffprobe", e)))?;
    let text = String::from_utf8_lossy(&out.stdout);
    let fields: Vec<&str> = text.trim().split(',').collect();
    let parsed = match fields.as_slice() {
        [w, h, rate] => {
            let fps = match rate.split_once('/') {
                Some((n, d)) => n
                    .parse::<f64>()
                    .ok()
                    .zip(d.parse::<f64>().ok())
                    .map(|(n, d)| n / d),
                None => rate.parse().ok(),
            };
            w.parse().ok().zip(h.parse().ok()).zip(fps)
        }
        _ => None,
    };
    match parsed {
        Some(((w, h), fps)) if w > 0 && h > 0 && fps.is_finite() && fps > 0.0 => Ok((w, h, fps)),
        _ => Err(setup(
            path,
            format!(
                "not a video ffprobe can read: {}",
                String::from_utf8_lossy(&out.stderr).trim()
            ),
        )),
    }
}

impl VideoSource {
    /// Starts decoding `path`; frames get camera frame id `frame_id`. A video whose
    /// frames are beyond `limits` (pixels) is refused.
    pub fn open(path: &Path, frame_id: &str, limits: &Limits) -> Result<Self, TransportError> {
        let (width, height, fps) = probe(path)?;
        limits
            .image(u64::from(width), u64::from(height))
            .map_err(|e| setup(path, e.to_string()))?;
        let mut child = Command::new("ffmpeg")
            .args(["-nostdin", "-v", "error", "-i"])
            .arg(path)
            .args([
                "-map", "0:v:0", "-f", "rawvideo", "-pix_fmt", "rgb24", "pipe:1",
            ])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| setup(path, program_error("ffmpeg", e)))?;
        let (Some(stdout), Some(mut err)) = (child.stdout.take(), child.stderr.take()) else {
            return Err(setup(path, "ffmpeg's pipes are missing"));
        };
        // Drained on its own thread so that a chatty decoder cannot block on it.
        // Kept to its first 64 kB: a decoder that complains about every frame of a
        // broken file must not grow it without bound.
        let stderr = std::thread::Builder::new()
            .name("ffmpeg-stderr".into())
            .spawn(move || {
                let mut text = Vec::new();
                let _ = err.by_ref().take(64 << 10).read_to_end(&mut text);
                let _ = std::io::copy(&mut err, &mut std::io::sink());
                String::from_utf8_lossy(&text).into_owned()
            })
            .map_err(|e| {
                let _ = child.kill();
                let _ = child.wait();
                setup(path, format!("cannot start a thread: {e}"))
            })?;
        Ok(Self {
            path: path.to_path_buf(),
            child,
            stdout,
            stderr: Some(stderr),
            width,
            height,
            fps,
            next: 0,
            frame_id: frame_id.to_string(),
            done: false,
        })
    }

    /// Frame size, pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// Frames per second.
    pub fn fps(&self) -> f64 {
        self.fps
    }

    fn broken(&self, reason: String) -> TransportError {
        TransportError::Broken {
            transport: "video",
            topic: self.path.display().to_string(),
            reason,
        }
    }

    /// Waits for ffmpeg; an error if it failed.
    fn finish(&mut self) -> Result<(), TransportError> {
        self.done = true;
        let status = self.child.wait().map_err(|e| self.broken(e.to_string()))?;
        let stderr = self
            .stderr
            .take()
            .and_then(|h| h.join().ok())
            .unwrap_or_default();
        if status.success() {
            Ok(())
        } else {
            Err(self.broken(format!("ffmpeg failed ({status}): {}", stderr.trim())))
        }
    }
}

impl Source<ImageFrame> for VideoSource {
    fn recv(&mut self, _timeout: Duration) -> Result<Received<ImageFrame>, TransportError> {
        if self.done {
            return Ok(Received::Closed);
        }
        let size = self.width as usize * self.height as usize * 3;
        let mut bytes = vec![0_u8; size];
        let mut filled = 0;
        while filled < size {
            match self.stdout.read(&mut bytes[filled..]) {
                Ok(0) => break,
                Ok(n) => filled += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(self.broken(e.to_string())),
            }
        }
        if filled < size {
            self.finish()?;
            if filled > 0 {
                return Err(self.broken(format!(
                    "the last frame is cut short ({filled} of {size} bytes)"
                )));
            }
            return Ok(Received::Closed);
        }
        let rgb = image::RgbImage::from_raw(self.width, self.height, bytes)
            .ok_or_else(|| self.broken("frame size".into()))?;
        let index = self.next;
        self.next += 1;
        Ok(ImageFrame::from_file(
            index,
            self.fps,
            &self.frame_id,
            format!("frame {index}"),
            rgb,
        ))
    }
}

impl Drop for VideoSource {
    fn drop(&mut self) {
        if !self.done {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_device_or_a_link_to_one_is_named_for_what_it_is() {
        let dir = tempfile::tempdir().expect("tempdir");
        let link = dir.path().join("zero.mp4");
        std::os::unix::fs::symlink("/dev/zero", &link).expect("link");
        let e = probe(&link).expect_err("a device").to_string();
        assert!(e.contains("character device"), "{e}");
        let e = probe(&dir.path().join("none.mp4"))
            .expect_err("missing")
            .to_string();
        assert!(e.contains("no such file"), "{e}");
    }
}
