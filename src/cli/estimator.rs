//! `posestream estimator`: the estimator node as a service.

use std::path::PathBuf;

use clap::Args;
use posestream::nodes::config::Transport;
use posestream::nodes::service::{self, EstimatorOutputs, Middleware, run_estimator};
use posestream::nodes::{EstimatorNode, ServiceConfig};

use super::CliError;
use super::service::{conclude, print, stop_after, stop_flag};

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
pub fn run(args: &EstimatorArgs) -> Result<(), CliError> {
    let config = ServiceConfig::load(&args.config)?;
    let stop = stop_flag();
    let input = args.input.unwrap_or(config.estimator.input);
    let mut node = EstimatorNode::from_service_config(&config)?;
    let mut middleware = Middleware::open(&config, Some(input))?;
    let recorder = service::output_recording(&config)?;
    let mut outputs =
        EstimatorOutputs::open(&config, &mut middleware, recorder.as_ref(), node.bones())?;
    let mut source = middleware.heatmaps_source(&config, input)?;
    stop_after(args.duration, &stop);
    let report = run_estimator(&mut node, &mut source, &mut outputs, &stop);
    drop(outputs);
    let concluded = conclude(recorder, report.input_error.as_deref());
    print(args.json, &report)?;
    concluded
}
