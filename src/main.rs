//! The `posestream` command line.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

mod cli;

use clap::{Args, Parser, Subcommand};
use posestream::BvhError;
use posestream::mocap::{MappingError, SplitError};
use posestream::npy::{self, Array};
use posestream::solver::coefficients::CoefficientSolver;
use posestream::solver::perspective::PerspectiveParams;
use posestream::{
    ArrayError, CameraError, CropBox, Dictionary, DictionaryError, Estimate, EstimateError,
    Estimator, HeatMaps, InitMethod, Intrinsics, Keypoints, Params, PixelMap, metrics,
};

/// Monocular 3D human pose estimation (Zhou et al., CVPR 2016).
#[derive(Debug, Parser)]
#[command(name = "posestream", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
#[allow(clippy::large_enum_variant)] // parsed once
enum Command {
    /// Lift a sequence of 2D keypoints or heat maps (NPY) to 3D poses (NPY).
    Lift(LiftArgs),
    /// Run the estimator on the reference parity fixtures and compare with the
    /// reference implementation's results.
    Parity(ParityArgs),
    /// Learn a pose dictionary from motion capture (BVH) by non-negative sparse coding.
    LearnDict(cli::learn::LearnArgs),
    /// Make a test sequence from motion capture: 3D truth in a camera frame, 2D joints,
    /// crop boxes and heat maps with a seeded error model (NPY).
    Synth(cli::synth::SynthArgs),
    /// Evaluate the estimator on held-out motion capture: markdown tables mirroring the
    /// paper's Tables 1-4.
    Eval(cli::eval::EvalArgs),
    /// Replay a recording (MCAP) of heat maps through the streaming estimator; record
    /// the skeletons to MCAP.
    Replay(cli::replay::ReplayArgs),
    /// The detector node: publish heat maps (replayed from a recording, or from camera
    /// images through the image detector) on the configured outputs (ROS 2, iceoryx2, a
    /// recording).
    Detector(cli::service::DetectorArgs),
    /// The estimator node: heat maps from ROS 2 or iceoryx2 in, skeletons and markers
    /// out on the configured outputs.
    Estimator(cli::service::EstimatorArgs),
    /// Detector and estimator in one process (in-memory channel), results on the
    /// configured outputs.
    Run(cli::service::RunArgs),
    /// Record ROS 2 topics to an MCAP file (rosbag2-compatible).
    Record(cli::service::RecordArgs),
    /// The image detector's models (MediaPipe BlazePose): fetch, check, rewrite.
    Models(cli::models::ModelsArgs),
    /// Pictures of a run on images: each image with its heat maps and 2D skeleton,
    /// beside the 3D skeleton from a novel view (PNG of one frame, or GIF).
    Render(cli::render::RenderArgs),
}

#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
struct LiftArgs {
    /// Pose dictionary: the authors' .mat or posestream's .json.
    #[arg(long)]
    dict: PathBuf,
    /// 2D keypoints (F, p, 2), pixels, x right, y down.
    #[arg(
        long,
        conflicts_with = "heatmaps",
        required_unless_present = "heatmaps"
    )]
    keypoints: Option<PathBuf>,
    /// Per-joint confidence (F, p) in [0, 1] for --keypoints; 0 = not observed.
    #[arg(long, requires = "keypoints")]
    confidence: Option<PathBuf>,
    /// Heat maps (F, p, h, w); pixel (row r, col c) is centred at x = c, y = r.
    #[arg(long)]
    heatmaps: Option<PathBuf>,
    /// Output 3D poses (F, p, 3): camera frame (x right, y down, z forward), dictionary
    /// joint order; dictionary units, centred, or with --intrinsics metres at the body's
    /// position.
    #[arg(long)]
    out: PathBuf,
    /// Output 2D joints (F, p, 2) the model was fitted to (heat maps: the EM's expected
    /// joints, in heat-map pixels).
    #[arg(long)]
    out_2d: Option<PathBuf>,
    /// Output reprojected 2D joints (F, p, 2) of the 3D model.
    #[arg(long)]
    out_proj: Option<PathBuf>,
    /// Output per-joint 2D variance (F, p), pixels^2 (heat maps only).
    #[arg(long, requires = "heatmaps")]
    out_var: Option<PathBuf>,
    /// Print a JSON summary (frames, iterations, objective, time) on stdout.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    solver: SolverArgs,
    #[command(flatten)]
    perspective: PerspectiveArgs,
}

/// The perspective adjustment: metric poses under a pinhole camera.
#[derive(Debug, Args)]
struct PerspectiveArgs {
    /// Camera intrinsics (JSON: {"fx", "fy", "cx", "cy"} or {"K": 3 x 3 rows}, pixels).
    /// Turns on the perspective adjustment: --out then holds metres in the camera frame
    /// (absolute position) and every 2D output is in image pixels. Keypoints must then be
    /// in image pixels; heat maps need --boxes.
    #[arg(long)]
    intrinsics: Option<PathBuf>,
    /// Crop box of each frame's heat maps (F, 4): x0, y0, width, height in image pixels.
    #[arg(long, requires_all = ["intrinsics", "heatmaps"])]
    boxes: Option<PathBuf>,
    /// Mean bone length of the skeleton, metres (sets the metric scale).
    #[arg(long, default_value_t = PerspectiveParams::default().mean_limb_length)]
    mean_limb_length: f64,
    /// L1 weight of the perspective C-step (units of --alpha).
    #[arg(long, default_value_t = PerspectiveParams::default().alpha)]
    perspective_alpha: f64,
    /// Iterations of the perspective adjustment per frame at most.
    #[arg(long, default_value_t = PerspectiveParams::default().max_iterations)]
    perspective_iterations: usize,
    /// APG steps per perspective C-step.
    #[arg(long, default_value_t = PerspectiveParams::default().apg_steps)]
    perspective_apg_steps: usize,
}

impl PerspectiveArgs {
    fn params(&self) -> PerspectiveParams {
        PerspectiveParams {
            mean_limb_length: self.mean_limb_length,
            alpha: self.perspective_alpha,
            max_iterations: self.perspective_iterations,
            apg_steps: self.perspective_apg_steps,
            ..PerspectiveParams::default()
        }
    }
}

#[derive(Debug, Args)]
struct SolverArgs {
    /// L1 weight on the coefficients.
    #[arg(long, default_value_t = Params::default().alpha)]
    alpha: f64,
    /// Temporal smoothness of the coefficients.
    #[arg(long, default_value_t = Params::default().beta)]
    beta: f64,
    /// Temporal smoothness of the rotations.
    #[arg(long, default_value_t = Params::default().gamma)]
    gamma: f64,
    /// E-step Gaussian std (normalised units; a heat map is 6 units high).
    #[arg(long, default_value_t = Params::default().sigma)]
    sigma: f64,
    /// Turn temporal smoothness off (beta = gamma = 0).
    #[arg(long)]
    no_smooth: bool,
    /// Initialisation: convex+robust+refine, convex+refine or altern [default: convex+robust+refine
    /// for keypoints, altern for heat maps].
    #[arg(long)]
    init: Option<InitMethod>,
    /// C-step solver: active-set (Newton steps on the active coefficients), cd
    /// (coordinate descent) or apg (accelerated proximal gradient, the paper's).
    #[arg(long, default_value = "active-set")]
    c_solver: CoefficientSolver,
    /// Outlier threshold of the robust convex initialisation (normalised units).
    #[arg(long, default_value_t = Params::default().robust_threshold)]
    robust_threshold: f64,
    /// Heat-map joints whose peak is not above this are left out of the initialisation.
    #[arg(long, default_value_t = Params::default().visibility_threshold)]
    visibility_threshold: f64,
    /// EM iterations at most.
    #[arg(long, default_value_t = Params::default().max_em_iterations)]
    max_em_iterations: usize,
    /// Block-coordinate rounds of Algorithm 1 on keypoints at most.
    #[arg(long, default_value_t = Params::default().max_rounds)]
    max_rounds: usize,
    /// Block-coordinate rounds per EM M-step at most (heat maps).
    #[arg(long, default_value_t = Params::default().max_em_rounds)]
    max_em_rounds: usize,
    /// APG steps (or CD sweeps) per C-step at most.
    #[arg(long, default_value_t = Params::default().max_apg_steps)]
    max_apg_steps: usize,
    /// Newton steps of the active-set C-step per round at most.
    #[arg(long, default_value_t = Params::default().max_newton_steps)]
    max_newton_steps: usize,
    /// Newton sweeps per R-step at most.
    #[arg(long, default_value_t = Params::default().max_rotation_sweeps)]
    max_rotation_sweeps: usize,
    /// Iterations of the per-frame initialisation at most.
    #[arg(long, default_value_t = Params::default().max_init_iterations)]
    max_init_iterations: usize,
    /// Relative tolerance of the stopping rules.
    #[arg(long, default_value_t = Params::default().tolerance)]
    tolerance: f64,
}

impl SolverArgs {
    fn params(&self) -> Params {
        let p = Params {
            alpha: self.alpha,
            beta: self.beta,
            gamma: self.gamma,
            sigma: self.sigma,
            robust_threshold: self.robust_threshold,
            visibility_threshold: self.visibility_threshold,
            max_em_iterations: self.max_em_iterations,
            max_rounds: self.max_rounds,
            max_em_rounds: self.max_em_rounds,
            max_apg_steps: self.max_apg_steps,
            max_newton_steps: self.max_newton_steps,
            max_rotation_sweeps: self.max_rotation_sweeps,
            max_init_iterations: self.max_init_iterations,
            tolerance: self.tolerance,
            init: self.init,
            coefficient_solver: self.c_solver,
            ..Params::default()
        };
        if self.no_smooth {
            p.without_smoothness()
        } else {
            p
        }
    }
}

#[derive(Debug, Args)]
struct ParityArgs {
    /// Folder of parity fixtures (each with keypoints.npy, heatmaps.npy, gt_3d.npy,
    /// gt_2d_heatmap.npy, reference/summary.json).
    #[arg(long, default_value = "../shared/reference/parity")]
    fixtures: PathBuf,
    /// Pose dictionary the fixtures were made with.
    #[arg(
        long,
        default_value = "../shared/reference/monocap-dicts/poseDict-all-K128.mat"
    )]
    dict: PathBuf,
    #[command(flatten)]
    solver: SolverArgs,
}

/// Everything that can stop the command, one line each.
#[derive(Debug, thiserror::Error)]
pub(crate) enum CliError {
    #[error(transparent)]
    Dictionary(#[from] DictionaryError),
    #[error(transparent)]
    Array(#[from] ArrayError),
    #[error("{0}")]
    Input(String),
    #[error(transparent)]
    Estimate(#[from] EstimateError),
    #[error(transparent)]
    Camera(#[from] CameraError),
    #[error(transparent)]
    Bvh(#[from] BvhError),
    #[error(transparent)]
    Mapping(#[from] MappingError),
    #[error(transparent)]
    Split(#[from] SplitError),
    #[error(transparent)]
    Recording(#[from] posestream::recording::RecordingError),
    #[error("{path}: {source}")]
    Json {
        path: PathBuf,
        source: serde_json::Error,
    },
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .init();
    install_panic_hook();
    ignore_file_size_signal();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Lift(args) => lift(&args),
        Command::Parity(args) => parity(&args),
        Command::LearnDict(args) => cli::learn::run(&args),
        Command::Synth(args) => cli::synth::run(&args),
        Command::Eval(args) => cli::eval::run(&args),
        Command::Replay(args) => cli::replay::run(&args),
        Command::Detector(args) => cli::service::detector(&args),
        Command::Estimator(args) => cli::service::estimator(&args),
        Command::Run(args) => cli::service::run(&args),
        Command::Record(args) => cli::service::record(&args),
        Command::Models(args) => cli::models::run(&args),
        Command::Render(args) => cli::render::render(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("posestream: error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// Panics print one line at error level saying where (the first of each place; later
/// ones at debug level): input errors are values, so a panic is a bug, and the services
/// catch it per message and go on (`nodes::EstimatorNode::handle`).
fn install_panic_hook() {
    static SEEN: std::sync::Mutex<std::collections::BTreeSet<String>> =
        std::sync::Mutex::new(std::collections::BTreeSet::new());
    std::panic::set_hook(Box::new(|info| {
        let location = info
            .location()
            .map_or_else(|| "an unknown place".to_string(), |l| l.to_string());
        let message = posestream::error::panic_text(info.payload());
        let first = SEEN
            .lock()
            .map(|mut seen| seen.insert(location.clone()))
            .unwrap_or(true);
        let thread = std::thread::current()
            .name()
            .map(|n| format!(" (thread {n})"))
            .unwrap_or_default();
        // A dependency's parser failing on a bad file: the caller reports the file.
        if posestream::error::panic_is_contained() {
            tracing::debug!("contained panic at {location}{thread}: {message}");
        } else if first {
            tracing::error!("panic at {location}{thread}: {message}");
        } else {
            tracing::debug!("panic at {location}{thread}: {message}");
        }
    }));
}

/// A full file-size budget (`ulimit -f`) makes writes fail with `EFBIG`, which the
/// recorder reports, instead of killing the process with `SIGXFSZ`.
fn ignore_file_size_signal() {
    // SAFETY: setting a signal's disposition to "ignore" at start-up, before any other
    // thread exists, has no memory-safety preconditions.
    #[allow(unsafe_code)]
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
}

fn input_error(path: &Path, e: EstimateError) -> CliError {
    CliError::Input(format!("{}: {e}", path.display()))
}

fn read_keypoints(path: &Path, p: usize) -> Result<Array<f64>, CliError> {
    let kp: Array<f64> = npy::read(path)?;
    npy::expect_shape(&kp, path, &[None, None, Some(2)], "(F, p, 2)")?;
    if kp.shape[1] != p {
        return Err(input_error(
            path,
            EstimateError::JointCount {
                expected: p,
                found: kp.shape[1],
            },
        ));
    }
    Ok(kp)
}

fn read_heatmaps(path: &Path, p: usize) -> Result<HeatMaps, CliError> {
    let hm: Array<f32> = npy::read(path)?;
    npy::expect_shape(&hm, path, &[None, None, None, None], "(F, p, h, w)")?;
    let (f, j, h, w) = (hm.shape[0], hm.shape[1], hm.shape[2], hm.shape[3]);
    if j != p {
        return Err(input_error(
            path,
            EstimateError::JointCount {
                expected: p,
                found: j,
            },
        ));
    }
    let mut maps = HeatMaps::new(f, j, h, w, hm.data).map_err(|e| input_error(path, e))?;
    maps.clip_negatives();
    Ok(maps)
}

fn lift(args: &LiftArgs) -> Result<(), CliError> {
    let dict = Dictionary::load(&args.dict)?;
    let p = dict.num_joints();
    let estimator = Estimator::new(dict, args.solver.params())?;
    // Read everything before the (long) solve, so bad input fails at once.
    let perspective = match &args.perspective.intrinsics {
        Some(path) => {
            let params = args.perspective.params();
            params.validate()?;
            Some((Intrinsics::load(path)?, params))
        }
        None => None,
    };
    let boxes = match &args.perspective.boxes {
        Some(path) => Some(read_boxes(path)?),
        None => None,
    };
    if perspective.is_some() && args.heatmaps.is_some() && boxes.is_none() {
        return Err(CliError::Input(
            "--intrinsics with --heatmaps needs --boxes (the crop of each frame's heat maps)"
                .into(),
        ));
    }
    let mut map_size = None;
    let estimate: Estimate = if let Some(path) = &args.keypoints {
        let kp = read_keypoints(path, p)?;
        let confidence = match &args.confidence {
            Some(cpath) => {
                let c: Array<f64> = npy::read(cpath)?;
                npy::expect_shape(
                    &c,
                    cpath,
                    &[Some(kp.shape[0]), Some(p)],
                    &format!("({}, {p})", kp.shape[0]),
                )?;
                if let Some(i) = c.data.iter().position(|v| !(0.0..=1.0).contains(v)) {
                    return Err(CliError::Input(format!(
                        "{}: confidence of frame {}, joint {} is {}, expected a value in [0, 1]",
                        cpath.display(),
                        i / p,
                        i % p,
                        c.data[i]
                    )));
                }
                Some(c.data)
            }
            None => None,
        };
        estimator
            .lift_keypoints(&Keypoints {
                joints: p,
                xy: kp.data,
                confidence,
            })
            .map_err(|e| input_error(path, e))?
    } else if let Some(path) = &args.heatmaps {
        let maps = read_heatmaps(path, p)?;
        if let Some(b) = &boxes {
            if b.len() != maps.frames {
                return Err(CliError::Input(format!(
                    "{}: {} crop boxes for {} frames of heat maps",
                    args.perspective.boxes.as_deref().unwrap_or(path).display(),
                    b.len(),
                    maps.frames
                )));
            }
        }
        map_size = Some((maps.width, maps.height));
        estimator
            .lift_heatmaps(&maps)
            .map_err(|e| input_error(path, e))?
    } else {
        return Err(CliError::Input(
            "one of --keypoints or --heatmaps is required".into(),
        ));
    };
    let f = estimate.report.frames;
    let mut summary = serde_json::to_value(&estimate.report).map_err(|source| CliError::Json {
        path: args.out.clone(),
        source,
    })?;
    let mut seconds = estimate.report.seconds;
    // What is written: the weak-perspective estimate, or its perspective adjustment.
    let (poses, keypoints, projected, variance) = match &perspective {
        Some((camera, params)) => {
            let to_image: Vec<PixelMap> = match (&boxes, map_size) {
                (Some(b), Some((w, h))) => b.iter().map(|b| b.pixel_map(w, h)).collect(),
                _ => vec![PixelMap::IDENTITY; f],
            };
            let metric = estimator.adjust_perspective(&estimate, camera, &to_image, params)?;
            let variance = estimate.variance.map(|var| {
                var.iter()
                    .enumerate()
                    .map(|(i, v)| to_image[i / p].variance(*v))
                    .collect()
            });
            seconds += metric.seconds;
            let n = metric.fits.len() as f64;
            summary["perspective"] = serde_json::json!({
                "mean_iterations": metric.fits.iter().map(|f| f.iterations as f64).sum::<f64>() / n,
                "mean_ray_distance_m": metric.fits.iter().map(|f| f.ray_distance).sum::<f64>() / n,
                "mean_reprojection_px": metrics::mean_error_2d(&metric.projected, &metric.keypoints),
                "seconds": metric.seconds,
            });
            (metric.poses, metric.keypoints, metric.projected, variance)
        }
        None => (
            estimate.poses,
            estimate.keypoints,
            estimate.projected,
            estimate.variance,
        ),
    };
    npy::write(&args.out, &[f, p, 3], &poses)?;
    if let Some(path) = &args.out_2d {
        npy::write(path, &[f, p, 2], &keypoints)?;
    }
    if let Some(path) = &args.out_proj {
        npy::write(path, &[f, p, 2], &projected)?;
    }
    if let (Some(path), Some(var)) = (&args.out_var, &variance) {
        npy::write(path, &[f, p], var)?;
    }
    tracing::info!(frames = f, seconds, "lifted");
    if args.json {
        summary["seconds"] = seconds.into();
        summary["seconds_per_frame"] = (seconds / f as f64).into();
        summary["joints"] = p.into();
        println!("{summary}");
    }
    Ok(())
}

/// Crop boxes (F, 4): x0, y0, width, height, image pixels.
fn read_boxes(path: &Path) -> Result<Vec<CropBox>, CliError> {
    let b: Array<f64> = npy::read(path)?;
    npy::expect_shape(&b, path, &[None, Some(4)], "(F, 4)")?;
    b.data
        .chunks_exact(4)
        .enumerate()
        .map(|(t, v)| {
            CropBox::new(v[0], v[1], v[2], v[3])
                .map_err(|e| CliError::Input(format!("{}: box {t}: {e}", path.display())))
        })
        .collect()
}

fn parity(args: &ParityArgs) -> Result<(), CliError> {
    let dict = Dictionary::load(&args.dict)?;
    let p = dict.num_joints();
    let estimator = Estimator::new(dict, args.solver.params())?;
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(&args.fixtures)
        .map_err(|source| ArrayError::Io {
            path: args.fixtures.clone(),
            source,
        })?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|d| d.join("gt_3d.npy").is_file())
        .collect();
    dirs.sort();
    println!(
        "| fixture | input | P-MPJPE | reference best | 2D error (px) | reference 2D | s/frame | reference default s/frame |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for dir in dirs {
        let name = dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let gt: Array<f64> = npy::read(&dir.join("gt_3d.npy"))?;
        let gt2: Array<f64> = npy::read(&dir.join("gt_2d_heatmap.npy"))?;
        let summary_path = dir.join("reference/summary.json");
        let summary: serde_json::Value = std::fs::read(&summary_path)
            .map_err(|source| {
                CliError::Array(ArrayError::Io {
                    path: summary_path.clone(),
                    source,
                })
            })
            .and_then(|b| {
                serde_json::from_slice(&b).map_err(|source| CliError::Json {
                    path: summary_path.clone(),
                    source,
                })
            })?;
        let best = |input: &str, key: &str| -> Option<f64> {
            summary
                .as_object()?
                .values()
                .filter(|m| m["input"] == input)
                .filter_map(|m| m[key].as_f64())
                .fold(None, |a: Option<f64>, v| Some(a.map_or(v, |a| a.min(v))))
        };
        // The reference's default mode (convex+robust+refine): the speed yardstick.
        let default_mode = |input: &str, key: &str| -> Option<f64> {
            summary
                .as_object()?
                .values()
                .find(|m| m["input"] == input && m["init"] == "convex+robust+refine")?[key]
                .as_f64()
        };
        let fmt = |v: Option<f64>, d: usize| v.map_or("-".to_string(), |v| format!("{v:.d$}"));
        if summary
            .as_object()
            .is_some_and(|o| o.values().any(|m| m["input"] == "keypoints.npy"))
        {
            let kp = read_keypoints(&dir.join("keypoints.npy"), p)?;
            let e = estimator.lift_keypoints(&Keypoints {
                joints: p,
                xy: kp.data,
                confidence: None,
            })?;
            println!(
                "| {name} | keypoints | {:.4} | {} | - | - | {:.4} | {} |",
                metrics::p_mpjpe(&e.poses, &gt.data, p),
                fmt(best("keypoints.npy", "p_mpjpe"), 4),
                e.report.seconds / e.report.frames as f64,
                fmt(default_mode("keypoints.npy", "seconds_per_frame"), 3),
            );
        }
        let maps = read_heatmaps(&dir.join("heatmaps.npy"), p)?;
        let e = estimator.lift_heatmaps(&maps)?;
        println!(
            "| {name} | heat maps | {:.4} | {} | {:.4} | {} | {:.4} | {} |",
            metrics::p_mpjpe(&e.poses, &gt.data, p),
            fmt(best("heatmaps.npy", "p_mpjpe"), 4),
            metrics::mean_error_2d(&e.keypoints, &gt2.data),
            fmt(best("heatmaps.npy", "err2d_px"), 4),
            e.report.seconds / e.report.frames as f64,
            fmt(default_mode("heatmaps.npy", "seconds_per_frame"), 3),
        );
    }
    Ok(())
}
