//! `posestream fuse`: the fusion node. Several calibrated cameras' heat maps (each
//! camera's detector anywhere on the network, or a recording of them) in, one skeleton
//! per person out, in the world frame.

use std::path::PathBuf;
use std::time::Duration;

use clap::Args;
use posestream::Estimator;
use posestream::mocap::rooms;
use posestream::msgs::Skeleton3D;
use posestream::nodes::config::Transport;
use posestream::nodes::config::{FusionConfig, ServiceConfig};
use posestream::nodes::fusion::FusionNode;
use posestream::nodes::service::Wiring;
use posestream::nodes::service::fusion::{FusionInput, FusionOutputs, FusionReport, run_fusion};
use posestream::transport::mcap::McapSource;
use posestream::transport::{Received, Source};

use super::CliError;
use super::service::{Summary, print, stop_after, stop_flag};

/// Options of `fuse`.
#[derive(Debug, Args)]
pub struct FuseArgs {
    /// The service configuration (`--config FILE`): `[fusion]` names the cameras.
    #[command(flatten)]
    pub config: super::config::ConfigArgs,
    /// Read the cameras' topics from this recording (MCAP) instead of ROS 2, as fast as
    /// the node takes them.
    #[arg(long, value_name = "FILE")]
    pub recording: Option<PathBuf>,
    /// Also record everything published to this MCAP file (overrides `outputs.record`).
    #[arg(long, value_name = "FILE")]
    pub record: Option<PathBuf>,
    /// With `--recording` of a room (`posestream scenes --rooms --record`): score the
    /// refined skeletons against the recording's truth (`topics.ground_truth`, world
    /// frame), in the report.
    #[arg(long, requires = "recording")]
    pub truth: bool,
    /// Stop after this many seconds, 0 to 1e9 (default: until Ctrl-C, or the
    /// recording's end).
    #[arg(long, value_parser = super::service::seconds)]
    pub duration: Option<Duration>,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs `fuse`.
pub fn run(args: &FuseArgs) -> Result<(), CliError> {
    let mut config = args.config.load()?;
    config.ros.or_named("posestream_fusion");
    if let Some(record) = &args.record {
        config.outputs.record = record.clone();
    }
    if config.fusion.cameras.is_empty() {
        return Err(CliError::Usage(
            "no cameras to fuse: name them in the configuration's [fusion] cameras \
             (docs/fusion.md, \"The service\")"
                .into(),
        ));
    }
    // The output would replace an input (the recording, the configuration) when
    // finished.
    if !config.outputs.record.as_os_str().is_empty() {
        let inputs: Vec<&std::path::Path> = [&args.recording, &args.config.config]
            .into_iter()
            .flatten()
            .map(|p| p.as_path())
            .collect();
        posestream::files::check_output(&config.outputs.record, &inputs)
            .map_err(|e| CliError::Usage(e.to_string()))?;
    }
    // The truth first: a run that cannot be scored is not started.
    let truth = match args.recording.as_ref().filter(|_| args.truth) {
        Some(path) => Some(read_truth(&config, path)?),
        None => None,
    };
    let stop = stop_flag();
    let dict = posestream::msgs::shipped::load_dictionary(&config.estimator.dictionary)?;
    let estimator = Estimator::new(dict, config.estimator.params.clone())?;
    let mut node = FusionNode::new(
        estimator,
        &config.fusion,
        config.estimator.fusion.clone(),
        config.limits.clone(),
    )?;
    let extra = args.recording.is_none().then_some(Transport::Ros2);
    let mut wiring = Wiring::open(&config, extra)?;
    wiring.start_recording(&config)?;
    let input = match &args.recording {
        Some(path) => FusionInput::recording(&config, path)?,
        None => FusionInput::ros2(&config, &mut wiring.middleware)?,
    };
    let mut outputs = FusionOutputs::open(&config, &mut wiring.middleware, &wiring.taps, &node)?;
    if args.truth {
        outputs = outputs.keeping(node.lag());
    }
    stop_after(args.duration, &stop);
    let mut report = run_fusion(&mut node, input, &mut outputs, &stop);
    if let Some(truth) = &truth {
        report.truth = Some(rooms::score_skeletons(
            truth,
            &outputs.kept(),
            node.lag(),
            node.root(),
        ));
    }
    drop(outputs);
    let concluded = wiring.conclude(report.input_error.as_deref());
    // A recording none of whose cameras' heat maps could be read (damaged past reading,
    // or of other topics) is an error, not a report of zeros.
    if let Some(path) = &args.recording
        && report.counters.frames == 0
        && report.refused.total() == 0
        && report.input_error.is_none()
        && !stop.load(std::sync::atomic::Ordering::Relaxed)
    {
        concluded?;
        let topics: Vec<String> = config
            .fusion
            .cameras
            .iter()
            .map(|name| FusionConfig::camera_topics(name, &config.topics).0)
            .collect();
        return Err(CliError::Failed(format!(
            "{}: no heat maps could be read on the cameras' topics ({}): nothing to fuse \
             (the warnings above say what the recording holds, and what was damaged)",
            path.display(),
            topics.join(", ")
        )));
    }
    print(args.json, &report)?;
    concluded.map(|_| ()).map_err(CliError::from)
}

impl Summary for FusionReport {
    fn summary(&self) -> String {
        let c = &self.counters;
        let mut text = format!(
            "{} heat-map messages -> {} fused frames, {} skeletons of {} people ({} camera \
             tracks matched to nobody, {} frames replaced by a nearer one, {} restarts); \
             {} refused {:?}; update median {:.2} ms, p99 {:.2} ms; {} failed sends",
            c.frames,
            c.fused,
            c.skeletons,
            c.people,
            c.unmatched,
            c.superseded,
            c.restarts,
            self.refused.total(),
            self.refused,
            self.update.median_ms,
            self.update.p99_ms,
            self.failed_sends
        );
        for cam in &self.cameras {
            text.push_str(&format!(
                "\ncamera {} ({}): {} frames, {} used{}; residual {}{}",
                cam.name,
                if cam.frame_id.is_empty() {
                    "?"
                } else {
                    &cam.frame_id
                },
                cam.frames,
                cam.used,
                if cam.calibrated {
                    ""
                } else {
                    ", not calibrated"
                },
                cam.residual.map_or("-".to_string(), |r| format!(
                    "{r:.3} over {} frames",
                    cam.residual_frames
                )),
                if cam.suspect {
                    " -- its extrinsics disagree with the others' (wrong pose?)"
                } else {
                    ""
                }
            ));
        }
        if let Some(t) = &self.truth {
            text.push_str(&format!(
                "\nagainst the truth: {} skeletons, MPJPE {:.0} mm, root {:.0} mm, {} from one \
                 camera, {} with no true person",
                t.frames, t.mpjpe_mm, t.root_mm, t.monocular, t.unscored
            ));
        }
        if let Some(e) = &self.input_error {
            text.push_str(&format!("\ninput ended early: {e}"));
        }
        text
    }
}

/// The truth of a room's recording (`topics.ground_truth`), read as the inputs are (past
/// damage unless `replay.strict`): one error if there is none, or it is in another frame
/// than the skeletons'.
fn read_truth(config: &ServiceConfig, path: &std::path::Path) -> Result<Vec<Skeleton3D>, CliError> {
    let topic = &config.topics.ground_truth;
    let failed = |e: &dyn std::fmt::Display| CliError::Failed(format!("--truth: {e}"));
    let mut source = config
        .replay
        .source(
            McapSource::<Skeleton3D>::open_with_limit(path, topic, config.limits.max_record_bytes)
                .map_err(|e| failed(&e))?,
        )
        .map_err(|e| failed(&e))?;
    let mut truth = Vec::new();
    loop {
        match source.recv(Duration::ZERO) {
            Ok(Received::Message(m, _)) => truth.push(m),
            Ok(Received::Idle) => {}
            Ok(Received::Closed) => break,
            // What was read before the damage is kept, as for the inputs.
            Err(e) if !truth.is_empty() && !config.replay.strict => {
                tracing::warn!("--truth: {e}; scored against the truth read before it");
                break;
            }
            Err(e) => return Err(failed(&e)),
        }
    }
    let world = config.fusion.world_frame.trim_start_matches('/');
    match truth.first() {
        None => Err(CliError::Usage(format!(
            "--truth: {} has no truth on {topic} (a room written by `posestream scenes \
             --rooms --record` has)",
            path.display()
        ))),
        Some(t) if t.header.frame_id.trim_start_matches('/') != world => {
            Err(CliError::Usage(format!(
                "--truth: the truth is in frame {:?}, the skeletons in {world:?} \
                 ([fusion] world_frame)",
                t.header.frame_id
            )))
        }
        Some(_) => Ok(truth),
    }
}
