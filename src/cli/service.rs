//! What the service commands (`detector`, `estimator`, `run`, `record`) share beyond
//! their wiring (`nodes::service::Wiring`): where the detector's frames come from,
//! stopping on a signal, and printing reports. Each reads the service configuration (`--config`),
//! stops cleanly on Ctrl-C (outputs finalised) and prints a report (`--json` for
//! machines).

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::time::Duration;

use clap::Args;
use posestream::nodes::ServiceConfig;
use posestream::nodes::config::{DetectorSource, ReplayRate};
use posestream::nodes::service;
use serde::Serialize;

use super::CliError;

/// A flag set by Ctrl-C (SIGINT), SIGTERM or SIGHUP: the command then stops and still
/// finalises its outputs. The signal also ends a read of a user's file under way
/// (`posestream_base::files::stop`); a second signal ends the process at once (exit
/// status 130), leaving an output being written under its `.partial` name.
pub(crate) fn stop_flag() -> Arc<AtomicBool> {
    static SIGNALS: AtomicU32 = AtomicU32::new(0);
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    // Without a handler (one is installed already), the signal simply ends the process.
    let _ = ctrlc::set_handler(move || {
        if SIGNALS.fetch_add(1, Ordering::Relaxed) > 0 {
            eprintln!("posestream: a second signal: ending at once");
            std::process::exit(130);
        }
        posestream::base::files::stop::request();
        flag.store(true, Ordering::Relaxed);
    });
    stop
}

/// The most `--duration` may say: 1e9 s, about 31 years.
const MAX_SECONDS: f64 = 1e9;

/// `--duration`'s parser: a finite number of seconds from 0 to [`MAX_SECONDS`]; anything
/// else (NaN, infinite, negative, beyond) is refused with the domain, before the command
/// starts.
pub(crate) fn seconds(text: &str) -> Result<Duration, String> {
    let domain = || format!("expected seconds from 0 to {MAX_SECONDS:e}");
    let value: f64 = text.parse().map_err(|_| domain())?;
    if !(0.0..=MAX_SECONDS).contains(&value) {
        return Err(domain());
    }
    Ok(Duration::from_secs_f64(value))
}

/// Sets `stop` after `duration`, if given.
pub(crate) fn stop_after(duration: Option<Duration>, stop: &Arc<AtomicBool>) {
    if let Some(duration) = duration {
        let stop = stop.clone();
        let _ = std::thread::Builder::new()
            .name("timer".into())
            .spawn(move || {
                std::thread::sleep(duration);
                stop.store(true, Ordering::Relaxed);
            });
    }
}

/// A report's one-paragraph summary for people (`--json` prints all of it).
pub(crate) trait Summary {
    /// The summary.
    fn summary(&self) -> String;
}

impl Summary for service::EstimatorReport {
    fn summary(&self) -> String {
        let (c, u) = (self.counters, self.update);
        let mut text = format!(
            "{} frames -> {} skeletons; update median {:.2} ms, p99 {:.2} ms; \
             {} malformed, {} late, {} missing, {} resets, {} failed sends",
            self.frames,
            self.skeletons,
            u.median_ms,
            u.p99_ms,
            self.malformed,
            c.late,
            c.missing,
            c.resets,
            self.failed_sends
        );
        if self.unknown_id_tracks > 0 {
            text.push_str(&format!(
                "; {} tracks made for people without an id (track_id 0)",
                self.unknown_id_tracks
            ));
        }
        if self.tf_evicted > 0 {
            text.push_str(&format!(
                "; {} transforms dropped from the full TF buffer (the least recently sent)",
                self.tf_evicted
            ));
        }
        if let Some(e) = &self.input_error {
            text.push_str(&format!("\ninput ended early: {e}"));
        }
        text
    }
}

impl Summary for service::DetectorReport {
    fn summary(&self) -> String {
        let mut text = format!(
            "published {} heat-map messages; {} malformed skipped, {} failed sends",
            self.published, self.malformed, self.failed_sends
        );
        if let Some(s) = &self.images {
            text.push_str(&format!(
                "\nimages: {} frames, {} with people ({} person-frames), {} without; \
                 {} tracks confirmed ({} re-acquisitions); \
                 {} landmark runs on {}, {:.1} ms each; the person detectors found someone in {} of {} searches",
                s.frames,
                s.detected,
                s.people,
                s.no_person,
                s.tracks.confirmed,
                s.tracks.reacquisitions,
                s.network_runs,
                match s.runtime {
                    posestream::detector::Runtime::Litert => "LiteRT",
                    _ => "tract",
                },
                s.mean_network_ms(),
                s.detector_hits,
                s.searches
            ));
        }
        if let Some(e) = &self.input_error {
            text.push_str(&format!("\ninput ended early: {e}"));
        }
        text
    }
}

impl Summary for service::PipelineReport {
    fn summary(&self) -> String {
        let mut text = format!(
            "detector: {}\nestimator: {}\n{:.2} s, {:.1} frames/s",
            self.detector.summary(),
            self.estimator.summary(),
            self.seconds,
            self.frames_per_second
        );
        if let Some(f) = self.streaming_frames_per_second {
            text.push_str(&format!(" ({f:.1} from the first image)"));
        }
        if let Some(l) = &self.latency {
            text.push_str(&format!(
                "\nlatency, image to newest skeleton: median {:.1} ms, p99 {:.1} ms",
                l.median_ms, l.p99_ms
            ));
        }
        if let Some(st) = &self.stages {
            text.push_str(&format!(
                "\nper image: getting it (reading, decoding, waiting) {:.1} ms; {:.2} landmark runs of {:.1} ms; \
                 {:.2} person-detector runs of {:.1} ms; {:.2} pedestrian-detector runs of {:.1} ms; \
                 estimator update median {:.2} ms",
                st.image_ms,
                st.landmark_runs_per_image,
                st.landmark_ms,
                st.person_detector_runs_per_image,
                st.person_detector_ms,
                st.pedestrian_detector_runs_per_image,
                st.pedestrian_detector_ms,
                st.estimator_update_median_ms
            ));
        }
        if let Some(r) = &self.recording {
            text.push_str(&format!("\nrecorded -> {}", r.path.display()));
        }
        text
    }
}

/// Prints `report`: as JSON, or its summary.
pub(crate) fn print<T: Serialize + Summary>(json: bool, report: &T) -> Result<(), CliError> {
    if json {
        let text = serde_json::to_string_pretty(report)
            .map_err(|e| CliError::Failed(format!("cannot write the report: {e}")))?;
        println!("{text}");
    } else {
        println!("{}", report.summary());
    }
    Ok(())
}

/// What the detector's commands (`detector`, `run`) are given: the service configuration
/// (`--config FILE`), the source, and the live view (`--foxglove`).
#[derive(Debug, Args)]
pub struct DetectorNodeArgs {
    /// The service configuration (`--config FILE`).
    #[command(flatten)]
    pub config: super::config::ConfigArgs,
    /// The source.
    #[command(flatten)]
    pub source: SourceArgs,
    /// The live view (`--foxglove`).
    #[command(flatten)]
    pub live: super::config::LiveArgs,
}

impl DetectorNodeArgs {
    /// The configuration with the source and the live view applied.
    pub fn load(&self) -> Result<posestream::nodes::ServiceConfig, CliError> {
        let mut config = self.config.load()?;
        self.live.apply(&mut config);
        self.source.apply(&mut config);
        Ok(config)
    }
}

/// Where the detector's frames come from (each overrides `[detector]`).
#[derive(Debug, Args)]
pub struct SourceArgs {
    /// Replay the heat maps of this recording (source `recording`).
    #[arg(long, group = "frames")]
    pub recording: Option<PathBuf>,
    /// Run the image detector on the image files of this folder (source `images`).
    #[arg(long, group = "frames")]
    pub images: Option<PathBuf>,
    /// Run the image detector on this video file (source `video`; needs ffmpeg).
    #[arg(long, group = "frames")]
    pub video: Option<PathBuf>,
    /// Where to look for the person first: `x,y,width,height` in image pixels
    /// (overrides `detector.images.person_box`).
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    pub person_box: Option<Vec<f64>>,
    /// Landmark model (overrides `detector.images.model`).
    #[arg(long, value_parser = super::choice::choice::<posestream::models::LandmarkModel>())]
    pub model: Option<posestream::models::LandmarkModel>,
    /// What runs the models (overrides `detector.images.runtime`; default `auto`: LiteRT
    /// when `posestream models fetch` has set it up, else tract).
    #[arg(long, value_parser = super::choice::choice::<posestream::detector::Runtime>())]
    pub runtime: Option<posestream::detector::Runtime>,
    /// Pace of a replayed recording (overrides `detector.rate`).
    #[arg(long, value_enum)]
    pub rate: Option<ReplayRate>,
    /// Times a replayed recording is played, 0 for ever (overrides `detector.repeat`).
    #[arg(long)]
    pub repeat: Option<u64>,
    /// Stop at a recording's first damaged part, with an error (default: skip what
    /// cannot be read, use the rest and warn; sets `replay.strict`).
    #[arg(long)]
    pub strict: bool,
}

impl SourceArgs {
    /// Applies the options to `config`.
    pub(crate) fn apply(&self, config: &mut ServiceConfig) {
        let d = &mut config.detector;
        if let Some(p) = &self.recording {
            d.source = DetectorSource::Recording;
            d.recording = p.clone();
        }
        if let Some(p) = &self.images {
            d.source = DetectorSource::Images;
            d.images.path = p.clone();
        }
        if let Some(p) = &self.video {
            d.source = DetectorSource::Video;
            d.images.path = p.clone();
        }
        if let Some(b) = &self.person_box {
            d.images.person_box = b.clone();
        }
        if let Some(m) = self.model {
            d.images.model = m;
        }
        if let Some(r) = self.runtime {
            d.images.runtime = r;
        }
        if let Some(rate) = self.rate {
            d.rate = rate;
        }
        if let Some(times) = self.repeat {
            d.repeat = times;
        }
        config.replay.strict |= self.strict;
    }
}
