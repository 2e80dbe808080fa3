//! `posestream run`: detector and estimator in one process.

use std::path::PathBuf;

use clap::Args;
use posestream::nodes::service;

use super::CliError;
use super::service::{DetectorNodeArgs, print, stop_flag};

/// Options of `run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// The configuration, the source and the live view.
    #[command(flatten)]
    pub node: DetectorNodeArgs,
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
    let mut config = args.node.load()?;
    if let Some(r) = &args.record {
        config.outputs.record = r.clone();
    }
    if let Some(on) = args.ros2 {
        config.outputs.ros2 = on;
    }
    let stop = stop_flag();
    let report = service::run_pipeline(&config, &stop)?;
    print(args.json, &report)?;
    match report.recording_error {
        Some(e) => Err(CliError::Failed(e)),
        None => Ok(()),
    }
}
