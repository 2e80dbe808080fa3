//! `posestream detector`: the detector node as a service.

use clap::Args;
use posestream::nodes::service::{self, Wiring, run_detector_on_runtime};

use super::CliError;
use super::service::{DetectorNodeArgs, print, stop_flag};

/// Options of `detector`.
#[derive(Debug, Args)]
pub struct DetectorArgs {
    /// The configuration, the source and the live view.
    #[command(flatten)]
    pub node: DetectorNodeArgs,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs `detector`: heat maps from the configured source (a recording replayed, or the
/// image detector on images) published to `[outputs]`.
pub fn run(args: &DetectorArgs) -> Result<(), CliError> {
    let mut config = args.node.load()?;
    config.ros.or_named("posestream_detector");
    let stop = stop_flag();
    let mut wiring = Wiring::open(&config, service::detector_transport(&config))?;
    // Alone in its process: nothing of ours to yield to (`[detector] nice` is for `run`).
    let input = wiring.detector_input(&config, 0)?;
    wiring.start_recording(&config)?;
    let sinks = wiring.detector_outputs(&config)?;
    if sinks.is_empty() {
        return Err(CliError::Usage(
            "no outputs: enable ros2, iceoryx2 or record in [outputs]".into(),
        ));
    }
    let service::DetectorInput {
        source,
        stats,
        rate,
        camera,
        // The latency to skeletons is measured where the estimator runs too (`run`).
        clock: _,
    } = input;
    // Images from files: their assumed calibration goes out beside the heat maps (a
    // recording of a camera: its own).
    if let Some(tap) = &camera {
        tap.publish_to(wiring.camera_outputs(&config)?);
    }
    // No lost beginning: the first frames wait (a while) for a subscriber to match.
    wiring.wait_for_subscribers(&config, &config.topics.heatmaps, true);
    // The source and the sinks are dropped in the loop: before the middleware under them.
    let mut report = run_detector_on_runtime(source, sinks, rate, &stop)?;
    if let Some(tap) = &camera {
        tap.close();
    }
    report.images = service::DetectorInput::stats_now(&stats);
    let concluded = wiring.conclude(report.input_error.as_deref());
    print(args.json, &report)?;
    concluded.map(|_| ()).map_err(CliError::from)
}
