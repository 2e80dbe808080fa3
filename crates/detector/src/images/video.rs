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

/// What `ffprobe -of json` says of a file's first video stream.
#[derive(serde::Deserialize)]
struct Probed {
    #[serde(default)]
    streams: Vec<ProbedStream>,
}

#[derive(serde::Deserialize)]
struct ProbedStream {
    width: Option<u32>,
    height: Option<u32>,
    r_frame_rate: Option<String>,
    #[serde(default)]
    side_data_list: Vec<SideData>,
}

#[derive(serde::Deserialize)]
struct SideData {
    rotation: Option<f64>,
}

/// Width, height and frames per second of the frames ffmpeg decodes from `json`
/// (ffprobe's): a stream turned a quarter (a phone's video, its rotation in side data)
/// is decoded turned, so its width and height swap.
fn probed(json: &[u8]) -> Option<(u32, u32, f64)> {
    let probed: Probed = serde_json::from_slice(json).ok()?;
    let stream = probed.streams.into_iter().next()?;
    let rate = stream.r_frame_rate?;
    let fps = match rate.split_once('/') {
        Some((n, d)) => n.parse::<f64>().ok()? / d.parse::<f64>().ok()?,
        None => rate.parse().ok()?,
    };
    let (w, h) = (stream.width?, stream.height?);
    let quarter = stream
        .side_data_list
        .iter()
        .filter_map(|d| d.rotation)
        .any(|r| (r.rem_euclid(180.0) - 90.0).abs() < 1.0);
    let (w, h) = if quarter { (h, w) } else { (w, h) };
    (w > 0 && h > 0 && fps.is_finite() && fps > 0.0).then_some((w, h, fps))
}

/// Width, height and frames per second of the first video stream of `path`, as ffmpeg
/// decodes it.
pub fn probe(path: &Path) -> Result<(u32, u32, f64), TransportError> {
    // A regular file only: a device or a FIFO would keep ffprobe waiting.
    if let Err(e) = posestream_base::files::open_regular(path) {
        let why = match e.kind() {
            std::io::ErrorKind::NotFound => "no such file".to_string(),
            _ => e.to_string(),
        };
        return Err(setup(path, why));
    }
    // JSON: the CSV form repeats a line per program (MPEG-TS) and adds side data.
    let out = Command::new("ffprobe")
        .args(["-v", "error", "-select_streams", "v:0"])
        .args([
            "-show_entries",
            "stream=width,height,r_frame_rate:stream_side_data=rotation",
        ])
        .args(["-of", "json"])
        .arg(path)
        .output()
        .map_err(|e| setup(path, program_error("ffprobe", e)))?;
    probed(&out.stdout).ok_or_else(|| {
        let stderr = String::from_utf8_lossy(&out.stderr);
        let why = match stderr.trim() {
            "" => "no video stream",
            text => text,
        };
        setup(path, format!("not a video ffprobe can read: {why}"))
    })
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

    /// `ffmpeg` makes `name` in `dir` from a test pattern with `more` arguments.
    fn made(dir: &Path, name: &str, more: &[&str]) -> PathBuf {
        let path = dir.join(name);
        let status = Command::new("ffmpeg")
            .args([
                "-v",
                "error",
                "-f",
                "lavfi",
                "-i",
                "testsrc=size=64x48:rate=10:duration=1",
            ])
            .args(more)
            .arg(&path)
            .status()
            .expect("ffmpeg runs");
        assert!(status.success(), "{name}");
        path
    }

    #[test]
    fn mpeg_ts_and_a_phone_s_turned_video_are_read_at_the_size_ffmpeg_decodes() {
        // Found by trying: an MPEG-TS file's probe printed its stream once per program
        // and a turned one's a side-data field, and both were refused with no reason;
        // a turned video is decoded turned (48 x 64 here).
        let dir = tempfile::tempdir().expect("tempdir");
        let ts = made(dir.path(), "a.ts", &[]);
        assert_eq!(probe(&ts).expect("MPEG-TS"), (64, 48, 10.0));
        let plain = made(dir.path(), "plain.mp4", &[]);
        let turned = dir.path().join("turned.mp4");
        let status = Command::new("ffmpeg")
            .args(["-v", "error", "-i"])
            .arg(&plain)
            .args(["-c", "copy", "-metadata:s:v:0", "rotate=90"])
            .arg(&turned)
            .status()
            .expect("ffmpeg runs");
        assert!(status.success());
        assert_eq!(probe(&turned).expect("turned"), (48, 64, 10.0));
        let mut video = VideoSource::open(&turned, "camera", &Limits::default()).expect("opens");
        let Ok(Received::Message(frame, _)) = video.recv(Duration::from_secs(10)) else {
            panic!("a frame")
        };
        assert_eq!(frame.rgb.dimensions(), (48, 64));
        // Sound only: one clear reason.
        let sound = dir.path().join("sound.wav");
        let status = Command::new("ffmpeg")
            .args(["-v", "error", "-f", "lavfi", "-i", "sine=duration=1"])
            .arg(&sound)
            .status()
            .expect("ffmpeg runs");
        assert!(status.success());
        let e = probe(&sound).expect_err("no video").to_string();
        assert!(e.contains("no video stream"), "{e}");
    }
}
