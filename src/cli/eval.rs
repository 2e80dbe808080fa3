//! `posestream eval`: the paper's tables on held-out motion capture.

use std::path::PathBuf;

use clap::Args;
use posestream::Dictionary;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use posestream::Params;
use posestream::evaluation::{self, Case, DictionaryResults, Evaluator, Settings};
use posestream::mocap::split::list_bvh;
use posestream::mocap::{Bvh, MotionName, SkeletonMapping, Split};
use posestream::skeleton::same_layout;

use super::{CliError, progress_bar};

/// Options of `eval`.
#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Skeleton mapping of the BVH files.
    #[arg(long, default_value = "builtin:skeletons/bandai-namco.toml")]
    pub mapping: PathBuf,
    /// Train/test split: its held-out files are evaluated.
    #[arg(long, default_value = "builtin:splits/bandai-namco.toml")]
    pub split: PathBuf,
    /// BVH files or folders.
    #[arg(
        long,
        num_args = 1..,
        default_values = ["../shared/data/mocap/bandai-namco-1", "../shared/data/mocap/bandai-namco-2"]
    )]
    pub data: Vec<PathBuf>,
    /// Dictionaries to compare (label=path or path), in the layout of the mapping.
    #[arg(
        long,
        num_args = 1..,
        default_values = [
            "ours K128=builtin:dictionaries/default-k128.json",
            "authors' K128=../shared/reference/monocap-dicts/poseDict-all-K128.mat"
        ]
    )]
    pub dict: Vec<String>,
    /// Frames per sequence at most.
    #[arg(long, default_value_t = Settings::default().max_frames)]
    pub max_frames: usize,
    /// Held-out files per action at most (0 = all).
    #[arg(long, default_value_t = 0)]
    pub max_files_per_action: usize,
    /// Seed of the synthetic detector's error model.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Write the markdown here as well as to stdout.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Folder of the takes of the people-in-the-room scenes (`posestream scenes`, run
    /// after the tables with its defaults; its section ends the markdown).
    #[arg(long, default_value = "../shared/data/mocap/bandai-namco-1")]
    pub scenes_data: PathBuf,
    /// Leave the people-in-the-room scenes out (and the rooms seen by several cameras,
    /// fused against each camera alone, which follow them).
    #[arg(long)]
    pub no_scenes: bool,
    /// Evaluate the split's training files instead of its held-out ones (to calibrate
    /// settings without looking at the held-out motion).
    #[arg(long)]
    pub train: bool,
    /// Evaluate only the files whose name contains one of these (each keeps its index in
    /// the list the other options select, so with the same --data, --train,
    /// --max-files-per-action and --seed its camera and error seed are those of the run
    /// without --only: reproduces one take's rows).
    #[arg(long, num_args = 1..)]
    pub only: Vec<String>,
    /// Worker threads (each evaluates whole files; ms/frame is per worker, so more
    /// workers than idle cores inflate it).
    #[arg(long, default_value_t = std::thread::available_parallelism().map_or(1, |n| n.get()))]
    pub jobs: usize,
}

/// Runs `eval`.
pub fn run(args: &EvalArgs) -> Result<(), CliError> {
    if args.max_frames == 0 {
        return Err(CliError::Usage("--max-frames must be at least 1".into()));
    }
    for data in &args.data {
        super::data_at(data, "the motion capture (BVH) to evaluate on", "--data")?;
    }
    // The scenes run after the tables: their takes are checked first.
    let scenes = if args.no_scenes {
        None
    } else {
        Some(super::scenes::ScenesArgs::with(
            &args.mapping,
            &args.scenes_data,
        )?)
    };
    let mapping = SkeletonMapping::load(&args.mapping)?;
    let split = Split::load(&args.split)?;
    let mut dicts = Vec::new();
    for spec in &args.dict {
        let (label, path) = match spec.split_once('=') {
            Some((l, p)) => (l.to_string(), PathBuf::from(p)),
            None => (spec.clone(), PathBuf::from(spec)),
        };
        let d = posestream::msgs::shipped::load_dictionary(&path)?;
        if !same_layout(&d.skeleton().joints, &mapping.layout.joints) {
            return Err(CliError::Usage(format!(
                "{}: its joints ({}) are not the mapping's layout ({})",
                path.display(),
                d.skeleton().joints.join(", "),
                mapping.layout.joints.join(", ")
            )));
        }
        dicts.push((label, d));
    }
    let mut per_action = std::collections::BTreeMap::<String, usize>::new();
    // Each file with its index in the whole list (its camera and error seed).
    let files: Vec<(usize, PathBuf)> = list_bvh(&args.data)?
        .into_iter()
        .filter(|f| split.is_test(f) != args.train)
        .filter(|f| {
            let action = MotionName::parse(f).map_or_else(String::new, |m| m.content);
            let n = per_action.entry(action).or_default();
            *n += 1;
            args.max_files_per_action == 0 || *n <= args.max_files_per_action
        })
        .enumerate()
        .filter(|(_, f)| {
            let name = f
                .file_name()
                .map(|n| n.to_string_lossy())
                .unwrap_or_default();
            args.only.is_empty() || args.only.iter().any(|o| name.contains(o.as_str()))
        })
        .collect();
    if args.only.iter().any(String::is_empty) {
        return Err(CliError::Usage(
            "--only \"\" would match every file: name part of a take".into(),
        ));
    }
    if files.is_empty() && !args.only.is_empty() && !per_action.is_empty() {
        return Err(CliError::Nothing(format!(
            "no {} file's name contains {}{}",
            if args.train { "training" } else { "held-out" },
            args.only
                .iter()
                .map(|o| format!("{:?}", o.chars().take(80).collect::<String>()))
                .collect::<Vec<_>>()
                .join(" or "),
            if args.max_files_per_action > 0 {
                format!(
                    " among the first {} of each action (--max-files-per-action)",
                    args.max_files_per_action
                )
            } else {
                String::new()
            }
        )));
    }
    if files.is_empty() {
        return Err(CliError::Nothing(if args.train {
            "the split has no training files".into()
        } else {
            "the split holds out no files".into()
        }));
    }
    let settings = Settings {
        max_frames: args.max_frames,
        errors: posestream::synth::ErrorModel {
            seed: args.seed,
            ..Default::default()
        },
        // A training run's per-action table lists every action it saw.
        actions: if args.train {
            Vec::new()
        } else {
            split.test_contents.clone()
        },
        training: args.train,
        ..Settings::default()
    };
    // Each dictionary under the paper's model (the reference's behaviour) and under
    // posestream's, in the same run.
    let models = [
        ("paper", Params::reference()),
        ("posestream", Params::default()),
    ];
    let specs: Vec<(String, &Dictionary, &Params)> = dicts
        .iter()
        .flat_map(|(label, d)| {
            models
                .iter()
                .map(move |(model, params)| (format!("{label}, {model}"), d, params))
        })
        .collect();
    let jobs = args.jobs.max(1).min(files.len());
    let bar = progress_bar(files.len(), "evaluating");
    let next = AtomicUsize::new(0);
    let failed = AtomicBool::new(false);
    // Workers take files in turn; each keeps its own evaluators (one case at a time: a
    // case's heat maps are large), merged at the end.
    let per_worker: Vec<Result<Vec<DictionaryResults>, CliError>> = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..jobs)
            .map(|_| {
                scope.spawn(|| {
                    // A worker that fails stops the others at their next file.
                    let result: Result<Vec<DictionaryResults>, CliError> = (|| {
                        let mut evaluators = specs
                            .iter()
                            .map(|(label, d, params)| Evaluator::new(label, d, params, &settings))
                            .collect::<Result<Vec<_>, _>>()?;
                        loop {
                            if failed.load(Ordering::Relaxed) {
                                break;
                            }
                            let Some((i, file)) = files.get(next.fetch_add(1, Ordering::Relaxed))
                            else {
                                break;
                            };
                            let i = *i;
                            let bvh = Bvh::load(file)?;
                            let seq = mapping.apply(&bvh, &file.display().to_string())?;
                            let name = file
                                .file_stem()
                                .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
                            let action =
                                MotionName::parse(file).map_or_else(|| name.clone(), |m| m.content);
                            let case = Case::new(name, action, &seq, &mapping.layout, &settings, i)
                                .map_err(|e| {
                                    CliError::Failed(format!("{}: {e}", file.display()))
                                })?;
                            for ev in &mut evaluators {
                                ev.add(&case)?;
                            }
                            bar.inc(1);
                        }
                        Ok(evaluators
                            .into_iter()
                            .map(|e| e.results().clone())
                            .collect())
                    })();
                    if result.is_err() {
                        failed.store(true, Ordering::Relaxed);
                    }
                    result
                })
            })
            .collect();
        workers
            .into_iter()
            .map(|w| {
                w.join().unwrap_or_else(|_| {
                    Err(CliError::Failed("an evaluation worker panicked".into()))
                })
            })
            .collect()
    });
    bar.finish();
    let mut results: Vec<DictionaryResults> = Vec::new();
    for worker in per_worker {
        let worker = worker?;
        if results.is_empty() {
            results = worker;
        } else {
            for (mine, theirs) in results.iter_mut().zip(&worker) {
                mine.merge(theirs);
            }
        }
    }
    let tables = evaluation::markdown(&results, &settings);
    print!("{tables}");
    // The tables are written before the scenes run: a failure there keeps them.
    write_results(args, &split, &tables)?;
    if let Some(scenes) = &scenes {
        let people = super::scenes::markdown(scenes)?;
        print!("{people}");
        write_results(args, &split, &format!("{tables}{people}"))?;
        let stand = super::scenes::distances::markdown(scenes)?;
        print!("{stand}");
        write_results(args, &split, &format!("{tables}{people}{stand}"))?;
        // Several cameras: each person's views fused against each camera alone.
        let rooms = format!(
            "\n## Several cameras (`posestream scenes --rooms`)\n\n{}",
            super::scenes::rooms::markdown(scenes)?
        );
        print!("{rooms}");
        write_results(args, &split, &format!("{tables}{people}{stand}{rooms}"))?;
    }
    Ok(())
}

/// Writes `text` under its header to `--out`, if given.
fn write_results(args: &EvalArgs, split: &Split, text: &str) -> Result<(), CliError> {
    if let Some(path) = &args.out {
        let options: Vec<String> = std::env::args().skip(1).collect();
        let command = format!("posestream {}", options.join(" "));
        let doc = format!(
            "# Results\n\nGenerated by `{command}` (`posestream eval --help` lists the options) \
from the {} files of `{}`: contents {} and styles {} are held out entirely (Table 2 \
shows the held-out contents). Dictionaries: {}.\n\n{text}",
            if args.train { "training" } else { "held-out" },
            args.split.display(),
            split.test_contents.join(", "),
            split.test_styles.join(", "),
            args.dict.join("; ")
        );
        posestream::files::write_output(path, &[args.split.as_path()], doc.as_bytes())?;
    }
    Ok(())
}
