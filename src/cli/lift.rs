//! `posestream lift`: a sequence of 2D keypoints or heat maps (NPY) to 3D poses (NPY).

use posestream::LoadIntrinsics;
use std::path::{Path, PathBuf};

use clap::Args;
use posestream::npy::{self, Array};
use posestream::solver::perspective::PerspectiveParams;
use posestream::{
    ArrayError, CropBox, Estimate, EstimateError, Estimator, HeatMapSequence, Intrinsics,
    Keypoints, PixelMap, accuracy,
};

use super::CliError;
use super::solver_args::SolverArgs;

/// Options of `lift`.
#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
pub struct LiftArgs {
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
pub struct PerspectiveArgs {
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
    /// The perspective adjustment's parameters these options give.
    pub fn params(&self) -> PerspectiveParams {
        PerspectiveParams {
            mean_limb_length: self.mean_limb_length,
            alpha: self.perspective_alpha,
            max_iterations: self.perspective_iterations,
            apg_steps: self.perspective_apg_steps,
            ..PerspectiveParams::default()
        }
    }
}

/// Keypoints (F, p, 2) of `p` joints.
pub(super) fn read_keypoints(path: &Path, p: usize) -> Result<Array<f64>, CliError> {
    let kp: Array<f64> = npy::read(path)?;
    npy::expect_shape(&kp, path, &[None, None, Some(2)], "(F, p, 2)")?;
    if kp.shape[1] != p {
        return Err(CliError::in_file(
            path,
            EstimateError::JointCount {
                expected: p,
                found: kp.shape[1],
            },
        ));
    }
    Ok(kp)
}

/// Heat maps (F, p, h, w) of `p` joints, negatives clipped.
pub(super) fn read_heatmaps(path: &Path, p: usize) -> Result<HeatMapSequence, CliError> {
    let hm: Array<f32> = npy::read(path)?;
    npy::expect_shape(&hm, path, &[None, None, None, None], "(F, p, h, w)")?;
    let (f, j, h, w) = (hm.shape[0], hm.shape[1], hm.shape[2], hm.shape[3]);
    if j != p {
        return Err(CliError::in_file(
            path,
            EstimateError::JointCount {
                expected: p,
                found: j,
            },
        ));
    }
    let mut maps =
        HeatMapSequence::new(f, j, h, w, hm.data).map_err(|e| CliError::in_file(path, e))?;
    maps.clip_negatives();
    Ok(maps)
}

/// Runs `lift`.
pub fn run(args: &LiftArgs) -> Result<(), CliError> {
    let inputs: Vec<&std::path::Path> = [
        Some(&args.dict),
        args.keypoints.as_ref(),
        args.confidence.as_ref(),
        args.heatmaps.as_ref(),
        args.perspective.intrinsics.as_ref(),
        args.perspective.boxes.as_ref(),
    ]
    .into_iter()
    .flatten()
    .map(PathBuf::as_path)
    .collect();
    let outputs: Vec<&Path> = [
        Some(&args.out),
        args.out_2d.as_ref(),
        args.out_proj.as_ref(),
        args.out_var.as_ref(),
    ]
    .into_iter()
    .flatten()
    .map(PathBuf::as_path)
    .collect();
    for (i, out) in outputs.iter().enumerate() {
        posestream::files::check_target(out, &inputs)?;
        posestream::files::check_distinct(out, &outputs[..i])?;
    }
    let dict = posestream::msgs::shipped::load_dictionary(&args.dict)?;
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
        return Err(CliError::Usage(
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
                    return Err(ArrayError::Domain {
                        path: cpath.clone(),
                        detail: format!(
                            "confidence of frame {}, joint {} is {}, expected a value in [0, 1]",
                            i / p,
                            i % p,
                            c.data[i]
                        ),
                    }
                    .into());
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
            .map_err(|e| CliError::in_file(path, e))?
    } else if let Some(path) = &args.heatmaps {
        let maps = read_heatmaps(path, p)?;
        if let Some(b) = &boxes
            && b.len() != maps.frames
        {
            return Err(ArrayError::Domain {
                path: args
                    .perspective
                    .boxes
                    .clone()
                    .unwrap_or_else(|| path.clone()),
                detail: format!(
                    "{} crop boxes for {} frames of heat maps",
                    b.len(),
                    maps.frames
                ),
            }
            .into());
        }
        map_size = Some((maps.width, maps.height));
        estimator
            .lift_heatmaps(&maps)
            .map_err(|e| CliError::in_file(path, e))?
    } else {
        return Err(CliError::Usage(
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
                "mean_reprojection_px": accuracy::mean_error_2d(&metric.projected, &metric.keypoints),
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
            CropBox::new(v[0], v[1], v[2], v[3]).map_err(|e| {
                CliError::from(ArrayError::Domain {
                    path: path.to_path_buf(),
                    detail: format!("box {t}: {e}"),
                })
            })
        })
        .collect()
}
