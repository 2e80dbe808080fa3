//! `posestream estimator`: the estimator node as a service.

use std::time::Duration;

use clap::Args;
use posestream::nodes::EstimatorNode;
use posestream::nodes::config::Transport;
use posestream::nodes::service::{Wiring, serve_estimator};

use super::CliError;
use super::service::{print, stop_after, stop_flag};

/// Options of `estimator`.
#[derive(Debug, Args)]
pub struct EstimatorArgs {
    /// The service configuration (`--config FILE`).
    #[command(flatten)]
    pub config: super::config::ConfigArgs,
    /// The live view (`--foxglove`).
    #[command(flatten)]
    pub live: super::config::LiveArgs,
    /// Where to read heat maps (overrides `estimator.input`).
    #[arg(long, value_enum)]
    pub input: Option<Transport>,
    /// Stop after this many seconds, 0 to 1e9 (default: until Ctrl-C).
    #[arg(long, value_parser = super::service::seconds)]
    pub duration: Option<Duration>,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs `estimator`: heat maps from ROS 2 or iceoryx2, skeletons to `[outputs]`.
pub fn run(args: &EstimatorArgs) -> Result<(), CliError> {
    let mut config = args.config.load()?;
    args.live.apply(&mut config);
    config.ros.or_named("posestream_estimator");
    let stop = stop_flag();
    let input = args.input.unwrap_or(config.estimator.input);
    let mut node = EstimatorNode::from_service_config(&config)?;
    let mut wiring = Wiring::open(&config, Some(input))?;
    // The recording first: what the input reads beside the heat maps is recorded.
    wiring.start_recording(&config)?;
    let source = wiring.estimator_input(&config, input)?;
    let mut outputs = wiring.estimator_outputs(&config, &node)?;
    stop_after(args.duration, &stop);
    // The input is dropped in the loop, the outputs here: before the middleware under them.
    let report = serve_estimator(&mut node, source, &mut outputs, &stop)?;
    drop(outputs);
    let concluded = wiring.conclude(report.input_error.as_deref());
    print(args.json, &report)?;
    concluded.map(|_| ()).map_err(CliError::from)
}
