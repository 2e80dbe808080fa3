//! `posestream record`: ROS 2 topics to an MCAP recording (rosbag2-compatible).

use std::path::PathBuf;
use std::time::Duration;

use clap::Args;
use posestream::msgs::{HeatMaps, MarkerArray, Skeleton3D};
use posestream::nodes::service::{self, record_step};
use posestream::recording::write_rosbag2_metadata;
use posestream::transport::mcap::SharedRecorder;
use posestream::transport::ros2::Ros2;
use serde::Serialize;

use super::CliError;
use super::service::{Summary, print, stop_flag};

/// Options of `record`.
#[derive(Debug, Args)]
pub struct RecordArgs {
    /// Output recording (MCAP).
    pub out: PathBuf,
    /// The service configuration (`--config FILE`).
    #[command(flatten)]
    pub config: super::config::ConfigArgs,
    /// Topics to record.
    #[arg(long, value_enum, value_delimiter = ',', default_values = ["skeletons", "markers"])]
    pub topics: Vec<RecordTopic>,
    /// Stop after this many seconds, 0 to 1e9 (default: until Ctrl-C).
    #[arg(long, value_parser = super::service::seconds)]
    pub duration: Option<Duration>,
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
pub fn run(args: &RecordArgs) -> Result<(), CliError> {
    let mut config = args.config.load()?;
    config.ros.or_named("posestream_recorder");
    if args.rosbag2 {
        posestream::recording::check_rosbag2_metadata(&args.out, &[])?;
    }
    let stop = stop_flag();
    let ros = Ros2::new(&config.ros)?;
    let recorder = SharedRecorder::create(&args.out)?;
    let mut steps = Vec::new();
    for topic in &args.topics {
        let t = &config.topics;
        let step = match topic {
            RecordTopic::Heatmaps => (
                t.heatmaps.clone(),
                record_step(
                    ros.source::<HeatMaps>(&t.heatmaps)?,
                    recorder.sink::<HeatMaps>(&t.heatmaps),
                ),
            ),
            RecordTopic::Skeletons => (
                t.skeletons.clone(),
                record_step(
                    ros.source::<Skeleton3D>(&t.skeletons)?,
                    recorder.sink::<Skeleton3D>(&t.skeletons),
                ),
            ),
            RecordTopic::Markers => (
                t.markers.clone(),
                record_step(
                    ros.source::<MarkerArray>(&t.markers)?,
                    recorder.sink::<MarkerArray>(&t.markers),
                ),
            ),
        };
        steps.push(step);
    }
    let messages = service::run_recorder(&mut steps, &stop, args.duration, args.count);
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
