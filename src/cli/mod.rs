//! The command line: one file per subcommand, each with its options (`XArgs`) and its
//! handler (`run`); [`CliError`] for everything that stops a command.

pub mod detector;
pub mod error;
pub mod estimator;
pub mod eval;
pub mod learn;
pub mod lift;
pub mod models;
pub mod parity;
pub mod process;
pub mod record;
pub mod render;
pub mod replay;
pub mod run;
pub mod scenes;
pub mod service;
pub mod solver_args;
pub mod synth;

pub use error::CliError;

use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};

/// Monocular 3D human pose estimation (Zhou et al., CVPR 2016).
#[derive(Debug, Parser)]
#[command(name = "posestream", version, about)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
#[allow(
    clippy::large_enum_variant,
    reason = "parsed once; boxing buys nothing"
)]
enum Command {
    /// Lift a sequence of 2D keypoints or heat maps (NPY) to 3D poses (NPY).
    Lift(lift::LiftArgs),
    /// Run the estimator on the reference parity fixtures and compare with the
    /// reference implementation's results.
    Parity(parity::ParityArgs),
    /// Learn a pose dictionary from motion capture (BVH) by non-negative sparse coding.
    LearnDict(learn::LearnArgs),
    /// Make a test sequence from motion capture: 3D truth in a camera frame, 2D joints,
    /// crop boxes and heat maps with a seeded error model (NPY).
    Synth(synth::SynthArgs),
    /// Evaluate the estimator on held-out motion capture: markdown tables mirroring the
    /// paper's Tables 1-4.
    Eval(eval::EvalArgs),
    /// Evaluate people in one room end to end: synthetic scenes of held-out takes, ids
    /// from the tracker, the estimator in metres (per person errors, id switches, IDF1).
    Scenes(scenes::ScenesArgs),
    /// Replay a recording (MCAP) of heat maps through the streaming estimator; record
    /// the skeletons to MCAP.
    Replay(replay::ReplayArgs),
    /// The detector node: publish heat maps (replayed from a recording, or from camera
    /// images through the image detector) on the configured outputs (ROS 2, iceoryx2, a
    /// recording).
    Detector(detector::DetectorArgs),
    /// The estimator node: heat maps from ROS 2 or iceoryx2 in, skeletons and markers
    /// out on the configured outputs.
    Estimator(estimator::EstimatorArgs),
    /// Detector and estimator in one process (in-memory channel), results on the
    /// configured outputs.
    Run(run::RunArgs),
    /// Record ROS 2 topics to an MCAP file (rosbag2-compatible).
    Record(record::RecordArgs),
    /// The image detector's models (MediaPipe BlazePose): fetch, check, rewrite.
    Models(models::ModelsArgs),
    /// Pictures of a run on images: each image with its heat maps and 2D skeleton,
    /// beside the 3D skeleton from a novel view (PNG of one frame, or GIF).
    Render(render::RenderArgs),
}

impl Cli {
    /// Runs the subcommand.
    pub fn run(self) -> Result<(), CliError> {
        match self.command {
            Command::Lift(args) => lift::run(&args),
            Command::Parity(args) => parity::run(&args),
            Command::LearnDict(args) => learn::run(&args),
            Command::Synth(args) => synth::run(&args),
            Command::Eval(args) => eval::run(&args),
            Command::Scenes(args) => scenes::run(&args),
            Command::Replay(args) => replay::run(&args),
            Command::Detector(args) => detector::run(&args),
            Command::Estimator(args) => estimator::run(&args),
            Command::Run(args) => run::run(&args),
            Command::Record(args) => record::run(&args),
            Command::Models(args) => models::run(&args),
            Command::Render(args) => render::run(&args),
        }
    }
}

/// Progress bar for `n` steps of `what`, on stderr.
pub fn progress_bar(n: usize, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(n as u64);
    bar.set_style(
        ProgressStyle::with_template("{msg:>12} [{bar:40}] {pos}/{len} {elapsed_precise}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_message(what.to_string());
    bar
}
