//! `posestream parity`: the estimator on the reference parity fixtures, compared with
//! the authors' MATLAB results (docs/speed.md).

use std::path::PathBuf;

use clap::Args;
use posestream::npy::{self, Array};
use posestream::{ArrayError, Estimator, Keypoints, accuracy};

use super::CliError;
use super::lift::{read_heatmaps, read_keypoints};
use super::solver_args::SolverArgs;

/// Options of `parity`.
#[derive(Debug, Args)]
pub struct ParityArgs {
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

/// Runs `parity`.
pub fn run(args: &ParityArgs) -> Result<(), CliError> {
    super::data_at(
        &args.fixtures,
        "the parity fixtures (inputs and the authors' outputs)",
        "--fixtures",
    )?;
    super::data_at(
        &args.dict,
        "the authors' dictionary the fixtures were made with",
        "--dict",
    )?;
    let dict = posestream::msgs::shipped::load_dictionary(&args.dict)?;
    let p = dict.num_joints();
    // Parity is with the authors' release: the paper's model.
    let reference = posestream::Params::reference();
    let params = posestream::Params {
        adaptation: reference.adaptation,
        confidence_spread: reference.confidence_spread,
        swap_prior: reference.swap_prior,
        start_from_window: reference.start_from_window,
        ..args.solver.params()
    };
    let estimator = Estimator::new(dict, params)?;
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
                accuracy::p_mpjpe(&e.poses, &gt.data, p),
                fmt(best("keypoints.npy", "p_mpjpe"), 4),
                e.report.seconds / e.report.frames as f64,
                fmt(default_mode("keypoints.npy", "seconds_per_frame"), 3),
            );
        }
        let maps = read_heatmaps(&dir.join("heatmaps.npy"), p)?;
        let e = estimator.lift_heatmaps(&maps)?;
        println!(
            "| {name} | heat maps | {:.4} | {} | {:.4} | {} | {:.4} | {} |",
            accuracy::p_mpjpe(&e.poses, &gt.data, p),
            fmt(best("heatmaps.npy", "p_mpjpe"), 4),
            accuracy::mean_error_2d(&e.keypoints, &gt2.data),
            fmt(best("heatmaps.npy", "err2d_px"), 4),
            e.report.seconds / e.report.frames as f64,
            fmt(default_mode("heatmaps.npy", "seconds_per_frame"), 3),
        );
    }
    Ok(())
}
