//! `posestream replay`: a recording's heat maps through the estimator, skeletons to a
//! new recording.

use std::path::PathBuf;

use clap::Args;
use posestream::nodes::config::ReplayRate;
use posestream::nodes::replay::{ReplayOptions, replay};

use super::CliError;
use super::service::stop_flag;

/// Options of `replay`.
#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// The recording (MCAP) holding heat-map messages (default: the demo recording
    /// built into the binary).
    #[arg(default_value = "builtin:recordings/byebye.mcap")]
    pub input: PathBuf,
    /// The service configuration (`--config FILE`).
    #[command(flatten)]
    pub config: super::config::ConfigArgs,
    /// The live view (`--foxglove`).
    #[command(flatten)]
    pub live: super::config::LiveArgs,
    /// Record the skeletons (and the input's ground truth) to this MCAP file.
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// Also write a rosbag2 `metadata.yaml` next to the recording.
    #[arg(long, requires = "record")]
    pub rosbag2: bool,
    /// Pace (overrides the configuration's `replay.rate`; with `--foxglove`, recorded
    /// unless given here).
    #[arg(long, value_enum)]
    pub rate: Option<ReplayRate>,
    /// Stop at the recording's first damaged part, with an error (default: skip what
    /// cannot be read and replay the rest; sets `replay.strict`).
    #[arg(long)]
    pub strict: bool,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs `replay`. Ctrl-C stops it and still finalises the output.
pub fn run(args: &ReplayArgs) -> Result<(), CliError> {
    let mut config = args.config.load()?;
    args.live.apply(&mut config);
    config.replay.strict |= args.strict;
    let stop = stop_flag();
    let options = ReplayOptions {
        record: args.record.clone(),
        rosbag2: args.rosbag2,
        rate: args.rate.unwrap_or(config.replay.rate),
        paced_for_live: false,
    };
    let mut options = options;
    if args.rate.is_none() && args.live.foxglove.is_some() && options.rate != ReplayRate::Recorded {
        // A live view is watched: at the recorded pace unless asked otherwise.
        options.rate = ReplayRate::Recorded;
        options.paced_for_live = true;
    }
    let report = replay(&config, &args.input, &options, &stop)?;
    if args.json {
        let text = serde_json::to_string_pretty(&report).map_err(|source| CliError::Json {
            path: args.input.clone(),
            source,
        })?;
        println!("{text}");
    } else {
        let c = report.counters;
        println!(
            "{} frames -> {} skeletons in {:.2} s ({:.0} frames/s); {} refused, {} late, {} missing, {} without evidence, {} resets",
            report.frames,
            report.skeletons,
            report.seconds,
            report.frames_per_second,
            report.malformed,
            c.late,
            c.missing,
            c.empty,
            c.resets
        );
        if report.unknown_id_tracks > 0 {
            println!(
                "{} tracks made for people whose heat maps came without an id (track_id 0)",
                report.unknown_id_tracks
            );
        }
        let u = report.update;
        println!(
            "estimator update per frame: median {:.2} ms, p99 {:.2} ms, max {:.2} ms",
            u.median_ms, u.p99_ms, u.max_ms
        );
        if let Some(out) = &report.output {
            println!("skeletons -> {}", out.display());
        }
    }
    if let Some(t) = &report.truncated {
        eprintln!("posestream: warning: {t}");
    }
    if let Some(skips) = &report.skipped {
        eprintln!(
            "posestream: warning: {}: damaged parts skipped, every readable message replayed: {} \
             (--strict stops at the first; `posestream recover` writes a clean copy)",
            args.input.display(),
            skips.summary()
        );
    }
    Ok(())
}
