//! `posestream learn-dict`: a pose dictionary from motion capture.

use std::path::PathBuf;

use clap::Args;
use posestream::dictionary::learn::{LearnParams, learn, normalise_poses};
use posestream::mocap::split::list_bvh;
use posestream::mocap::{Bvh, SkeletonMapping, Split};
use posestream::msgs::formats::dictionary_json as json;

use super::{CliError, progress_bar};

/// Options of `learn-dict`.
#[derive(Debug, Args)]
pub struct LearnArgs {
    /// Skeleton mapping of the BVH files (config/skeletons/*.toml).
    #[arg(long)]
    pub mapping: PathBuf,
    /// BVH files or folders of them.
    #[arg(long, required = true, num_args = 1..)]
    pub data: Vec<PathBuf>,
    /// Train/test split (config/splits/*.toml): only its training files are used.
    #[arg(long)]
    pub split: Option<PathBuf>,
    /// Use every n-th frame of each file.
    #[arg(long, default_value_t = 3)]
    pub stride: usize,
    /// Number of basis poses.
    #[arg(long, default_value_t = LearnParams::default().atoms)]
    pub atoms: usize,
    /// L1 weight on the codes.
    #[arg(long, default_value_t = LearnParams::default().lambda)]
    pub lambda: f64,
    /// Outer iterations (one dictionary step each).
    #[arg(long, default_value_t = LearnParams::default().iterations)]
    pub iterations: usize,
    /// Code steps per outer iteration.
    #[arg(long, default_value_t = LearnParams::default().coding_steps)]
    pub coding_steps: usize,
    /// Licence recorded in the dictionary (inherited from the data).
    #[arg(
        long,
        default_value = "CC BY-NC 4.0 (inherited from the training motion data)"
    )]
    pub license: String,
    /// Output dictionary (posestream JSON).
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs `learn-dict`.
pub fn run(args: &LearnArgs) -> Result<(), CliError> {
    if args.stride == 0 {
        return Err(CliError::Usage("--stride must be at least 1".into()));
    }
    let inputs: Vec<&std::path::Path> = [Some(&args.mapping), args.split.as_ref()]
        .into_iter()
        .flatten()
        .map(PathBuf::as_path)
        .collect();
    posestream::files::check_output(&args.out, &inputs)
        .map_err(posestream::files::OutputError::from)?;
    let mapping = SkeletonMapping::load(&args.mapping)?;
    let split = match &args.split {
        Some(path) => Split::load(path)?,
        None => Split::default(),
    };
    let files: Vec<PathBuf> = list_bvh(&args.data)?
        .into_iter()
        .filter(|f| !split.is_test(f))
        .collect();
    if files.is_empty() {
        return Err(CliError::Nothing(
            "the split leaves no training files".into(),
        ));
    }
    let bar = progress_bar(files.len(), "reading");
    let mut world = Vec::new();
    for file in &files {
        let bvh = Bvh::load(file)?;
        let seq = mapping.apply(&bvh, &file.display().to_string())?;
        let n = 3 * seq.joints;
        for frame in seq.positions.chunks_exact(n).step_by(args.stride) {
            world.extend_from_slice(frame);
        }
        bar.inc(1);
    }
    bar.finish();
    let skeleton = mapping.layout.clone();
    let poses = normalise_poses(&skeleton, &world).ok_or_else(|| {
        CliError::Failed(
            "cannot normalise the poses: a pose without spread, or a layout without left/right torso joints"
                .into(),
        )
    })?;
    let params = LearnParams {
        atoms: args.atoms,
        lambda: args.lambda,
        iterations: args.iterations,
        coding_steps: args.coding_steps,
    };
    let bar = progress_bar(args.iterations, "learning");
    let (dict, report) = learn(skeleton, &poses, &params, |_, objective| {
        bar.set_message(format!("obj {objective:.1}"));
        bar.inc(1);
    })
    .map_err(CliError::Failed)?;
    bar.finish();
    let source = format!(
        "posestream learn-dict: {} atoms, lambda {}, {} iterations, {} poses (every {} frame) from {} files mapped by {}",
        args.atoms,
        args.lambda,
        args.iterations,
        report.poses,
        args.stride,
        files.len(),
        mapping.name
    );
    json::save(&dict, &args.out, Some(source), Some(args.license.clone()))?;
    println!(
        "{} poses from {} files: mean joint error {:.4} (normalised units), relative error {:.4}, mean active atoms {:.2}",
        report.poses,
        files.len(),
        report.mean_joint_error,
        report.relative_error,
        report.mean_active_atoms
    );
    println!("wrote {}", args.out.display());
    Ok(())
}
