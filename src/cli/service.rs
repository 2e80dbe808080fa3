//! `posestream detector`, `estimator`, `run` and `record`: the nodes as services.
//! Each reads the service configuration (`--config`), stops cleanly on Ctrl-C (outputs
//! finalised) and prints a report (`--json` for machines).

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use clap::Args;
use posestream::msgs::{HeatMaps, MarkerArray, Skeleton3D};
use posestream::nodes::config::{DetectorSource, ReplayRate, Transport};
use posestream::nodes::service::{
    self, EstimatorOutputs, Middleware, record_step, run_detector, run_estimator,
};
use posestream::nodes::{EstimatorNode, ServiceConfig};
use posestream::recording::write_rosbag2_metadata;
use posestream::transport::mcap::SharedRecorder;
use posestream::transport::ros2::Ros2;
use serde::Serialize;

use super::CliError;

fn load(path: &PathBuf) -> Result<ServiceConfig, CliError> {
    ServiceConfig::load(path).map_err(|e| CliError::Input(e.to_string()))
}

/// A flag set by Ctrl-C (SIGINT), SIGTERM or SIGHUP: the command then stops and still
/// finalises its outputs.
pub(crate) fn stop_flag() -> Arc<AtomicBool> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    // Without a handler (one is installed already), the signal simply ends the process.
    let _ = ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed));
    stop
}

fn err(e: impl ToString) -> CliError {
    CliError::Input(e.to_string())
}

/// A report's one-paragraph summary for people (`--json` prints all of it).
trait Summary {
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
                "\nimages: {} frames, {} with a person, {} without; {} tracks; \
                 {} landmark runs, {:.1} ms each; person detector found someone {} of {} times",
                s.frames,
                s.detected,
                s.no_person,
                s.acquisitions,
                s.network_runs,
                s.mean_network_ms(),
                s.detector_hits,
                s.detector_runs
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
            "detector: {}\nestimator: {}\n{:.2} s",
            self.detector.summary(),
            self.estimator.summary(),
            self.seconds
        );
        if let Some(r) = &self.recording {
            text.push_str(&format!("\nrecorded -> {}", r.path.display()));
        }
        text
    }
}

impl Summary for RecordReport {
    fn summary(&self) -> String {
        let counts: Vec<String> = self
            .messages
            .iter()
            .map(|(t, n)| format!("{t}: {n}"))
            .collect();
        format!("{} -> {}", counts.join(", "), self.output.display())
    }
}

fn print<T: Serialize + Summary>(json: bool, report: &T) -> Result<(), CliError> {
    if json {
        let text = serde_json::to_string_pretty(report).map_err(err)?;
        println!("{text}");
    } else {
        println!("{}", report.summary());
    }
    Ok(())
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
    #[arg(long, value_enum)]
    pub model: Option<posestream::models::LandmarkModel>,
    /// Pace of a replayed recording (overrides `detector.rate`).
    #[arg(long, value_enum)]
    pub rate: Option<ReplayRate>,
    /// Times a replayed recording is played, 0 for ever (overrides `detector.repeat`).
    #[arg(long)]
    pub repeat: Option<u64>,
}

impl SourceArgs {
    /// Applies the options to `config`.
    fn apply(&self, config: &mut ServiceConfig) {
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
        if let Some(rate) = self.rate {
            d.rate = rate;
        }
        if let Some(times) = self.repeat {
            d.repeat = times;
        }
    }
}

/// Options of `detector`.
#[derive(Debug, Args)]
pub struct DetectorArgs {
    /// Service configuration.
    #[arg(long, default_value = "config/default.toml")]
    pub config: PathBuf,
    /// The source.
    #[command(flatten)]
    pub source: SourceArgs,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs `detector`: heat maps from the configured source (a recording replayed, or the
/// image detector on images) published to `[outputs]`.
pub fn detector(args: &DetectorArgs) -> Result<(), CliError> {
    let mut config = load(&args.config)?;
    args.source.apply(&mut config);
    let stop = stop_flag();
    let mut middleware =
        Middleware::open(&config, service::detector_transport(&config)).map_err(err)?;
    let input = service::detector_input(&config, &mut middleware).map_err(err)?;
    let recorder = service::output_recording(&config).map_err(err)?;
    let mut sinks =
        service::detector_outputs(&config, &mut middleware, recorder.as_ref()).map_err(err)?;
    if sinks.is_empty() {
        return Err(err(
            "no outputs: enable ros2, iceoryx2 or record in [outputs]",
        ));
    }
    let service::DetectorInput {
        mut source,
        stats,
        rate,
    } = input;
    let mut report = run_detector(&mut source, &mut sinks, rate, &stop);
    report.images = service::DetectorInput::stats_now(&stats);
    drop(sinks);
    let concluded = conclude(recorder, report.input_error.as_deref());
    print(args.json, &report)?;
    concluded
}

/// Finishes the output recording, if any, after the service's loop ended: in place if
/// the input held; if it broke, left under its temporary name, named in the one error
/// (exit 1), so that a failed run replaces no existing output.
fn conclude(recorder: Option<SharedRecorder>, input_error: Option<&str>) -> Result<(), CliError> {
    match (input_error, recorder) {
        (None, Some(r)) => r.finish().map(|_| ())?,
        (None, None) => {}
        (Some(e), None) => return Err(err(e)),
        (Some(e), Some(r)) => {
            let kept = r.finish_partial()?;
            return Err(err(format!(
                "{e}; what was recorded before is in {}",
                kept.display()
            )));
        }
    }
    Ok(())
}

/// Options of `estimator`.
#[derive(Debug, Args)]
pub struct EstimatorArgs {
    /// Service configuration.
    #[arg(long, default_value = "config/default.toml")]
    pub config: PathBuf,
    /// Where to read heat maps (overrides `estimator.input`).
    #[arg(long, value_enum)]
    pub input: Option<Transport>,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long)]
    pub duration: Option<f64>,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs `estimator`: heat maps from ROS 2 or iceoryx2, skeletons to `[outputs]`.
pub fn estimator(args: &EstimatorArgs) -> Result<(), CliError> {
    let config = load(&args.config)?;
    let stop = stop_flag();
    let input = args.input.unwrap_or(config.estimator.input);
    let mut node = EstimatorNode::from_service_config(&config).map_err(err)?;
    let mut middleware = Middleware::open(&config, Some(input)).map_err(err)?;
    let recorder = service::output_recording(&config).map_err(err)?;
    let mut outputs =
        EstimatorOutputs::open(&config, &mut middleware, recorder.as_ref(), node.bones())
            .map_err(err)?;
    let mut source = middleware.heatmaps_source(&config, input).map_err(err)?;
    stop_after(args.duration, &stop);
    let report = run_estimator(&mut node, &mut source, &mut outputs, &stop);
    drop(outputs);
    let concluded = conclude(recorder, report.input_error.as_deref());
    print(args.json, &report)?;
    concluded
}

/// Sets `stop` after `seconds`, if given.
fn stop_after(seconds: Option<f64>, stop: &Arc<AtomicBool>) {
    if let Some(s) = seconds.filter(|s| s.is_finite() && *s >= 0.0) {
        let stop = stop.clone();
        let _ = std::thread::Builder::new()
            .name("timer".into())
            .spawn(move || {
                std::thread::sleep(Duration::from_secs_f64(s));
                stop.store(true, Ordering::Relaxed);
            });
    }
}

/// Options of `run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// Service configuration.
    #[arg(long, default_value = "config/default.toml")]
    pub config: PathBuf,
    /// The source.
    #[command(flatten)]
    pub source: SourceArgs,
    /// Record the outputs (and the heat maps) to this MCAP file (overrides
    /// `outputs.record`).
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// Publish on ROS 2 (overrides `outputs.ros2`).
    #[arg(long)]
    pub ros2: Option<bool>,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs `run`: detector and estimator in one process.
pub fn run(args: &RunArgs) -> Result<(), CliError> {
    let mut config = load(&args.config)?;
    args.source.apply(&mut config);
    if let Some(r) = &args.record {
        config.outputs.record = r.clone();
    }
    if let Some(on) = args.ros2 {
        config.outputs.ros2 = on;
    }
    let stop = stop_flag();
    let report = service::run_pipeline(&config, &stop).map_err(err)?;
    print(args.json, &report)?;
    match report.recording_error {
        Some(e) => Err(err(e)),
        None => Ok(()),
    }
}

/// Options of `record`.
#[derive(Debug, Args)]
pub struct RecordArgs {
    /// Output recording (MCAP).
    pub out: PathBuf,
    /// Service configuration (topics, ROS 2 domain and QoS).
    #[arg(long, default_value = "config/default.toml")]
    pub config: PathBuf,
    /// Topics to record.
    #[arg(long, value_enum, value_delimiter = ',', default_values = ["skeletons", "markers"])]
    pub topics: Vec<RecordTopic>,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long)]
    pub duration: Option<f64>,
    /// Stop after this many messages.
    #[arg(long)]
    pub count: Option<u64>,
    /// Also write a rosbag2 `metadata.yaml` next to the recording.
    #[arg(long)]
    pub rosbag2: bool,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// A topic `record` can take.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum RecordTopic {
    /// `topics.heatmaps` (posestream_msgs/HeatMaps).
    Heatmaps,
    /// `topics.skeletons` (posestream_msgs/Skeleton3D).
    Skeletons,
    /// `topics.markers` (visualization_msgs/MarkerArray).
    Markers,
}

#[derive(Debug, Serialize)]
struct RecordReport {
    messages: Vec<(String, u64)>,
    output: PathBuf,
}

/// Runs `record`: ROS 2 topics into an MCAP recording.
pub fn record(args: &RecordArgs) -> Result<(), CliError> {
    let config = load(&args.config)?;
    let stop = stop_flag();
    let mut ros = Ros2::new(&config.ros).map_err(err)?;
    let recorder = SharedRecorder::create(&args.out)?;
    let mut steps = Vec::new();
    for topic in &args.topics {
        let t = &config.topics;
        let step = match topic {
            RecordTopic::Heatmaps => (
                t.heatmaps.clone(),
                record_step(
                    ros.source::<HeatMaps>(&t.heatmaps).map_err(err)?,
                    recorder.sink::<HeatMaps>(&t.heatmaps),
                ),
            ),
            RecordTopic::Skeletons => (
                t.skeletons.clone(),
                record_step(
                    ros.source::<Skeleton3D>(&t.skeletons).map_err(err)?,
                    recorder.sink::<Skeleton3D>(&t.skeletons),
                ),
            ),
            RecordTopic::Markers => (
                t.markers.clone(),
                record_step(
                    ros.source::<MarkerArray>(&t.markers).map_err(err)?,
                    recorder.sink::<MarkerArray>(&t.markers),
                ),
            ),
        };
        steps.push(step);
    }
    let duration = args
        .duration
        .filter(|d| d.is_finite() && *d >= 0.0)
        .map(Duration::from_secs_f64);
    let messages = service::run_recorder(&mut steps, &stop, duration, args.count);
    drop(steps);
    let summary = recorder.finish()?;
    if args.rosbag2 {
        write_rosbag2_metadata(&summary)?;
    }
    print(
        args.json,
        &RecordReport {
            messages,
            output: summary.path,
        },
    )
}
