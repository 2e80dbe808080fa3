//! The command line: one file per subcommand, each with its options (`XArgs`) and its
//! handler (`run`); [`CliError`] for everything that stops a command.

pub mod choice;
pub mod config;
pub mod detector;
pub mod error;
pub mod estimator;
pub mod eval;
pub mod fuse;
pub mod learn;
pub mod lift;
pub mod models;
pub mod parity;
pub mod process;
pub mod record;
pub mod recover;
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
    /// The fusion node: several calibrated cameras' heat maps (ROS 2, or a recording) in,
    /// one skeleton per person out, in the world frame.
    Fuse(fuse::FuseArgs),
    /// Detector and estimator in one process (in-memory channel), results on the
    /// configured outputs.
    Run(run::RunArgs),
    /// Record ROS 2 topics to an MCAP file (rosbag2-compatible).
    Record(record::RecordArgs),
    /// Write a clean, indexed copy of everything readable in a damaged recording.
    Recover(recover::RecoverArgs),
    /// The image detector's models (MediaPipe BlazePose): fetch, check, rewrite.
    Models(models::ModelsArgs),
    /// Pictures of a run on images: each image with its heat maps and 2D skeleton,
    /// beside the 3D skeleton from a novel view (PNG of one frame, or GIF).
    Render(render::RenderArgs),
    /// Print the effective service configuration (built-in defaults overlaid with
    /// `--config FILE`), each key with where its value came from.
    Config(config::ConfigCommandArgs),
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
            Command::Fuse(args) => fuse::run(&args),
            Command::Run(args) => run::run(&args),
            Command::Record(args) => record::run(&args),
            Command::Recover(args) => recover::run(&args),
            Command::Models(args) => models::run(&args),
            Command::Render(args) => render::run(&args),
            Command::Config(args) => config::run(&args),
        }
    }
}

/// Checks that `path`, the data a developer command reads (by default from `../shared`
/// beside the checkout), is there: else one error naming the option that points to it.
pub(crate) fn data_at(path: &std::path::Path, what: &str, option: &str) -> Result<(), CliError> {
    if path.exists() {
        return Ok(());
    }
    Err(CliError::Usage(format!(
        "{} not found: {what} ({option} PATH says where; the default is the project's \
         shared folder beside the checkout)",
        path.display()
    )))
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

/// The documentation a reader follows: every relative link of README.md and docs/*.md
/// leads to a file (and a heading of it), and every `posestream` command in their shell
/// blocks is accepted by this parser.
#[cfg(test)]
mod docs {
    use std::collections::BTreeSet;
    use std::path::{Path, PathBuf};

    use clap::Parser;

    use super::Cli;

    fn pages() -> Vec<PathBuf> {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let mut pages = vec![root.join("README.md")];
        let mut docs: Vec<PathBuf> = std::fs::read_dir(root.join("docs"))
            .expect("docs/")
            .map(|e| e.expect("entry").path())
            .filter(|p| p.extension().is_some_and(|e| e == "md"))
            .collect();
        docs.sort();
        pages.extend(docs);
        pages
    }

    /// Lines with their numbers.
    type Lines<'a> = Vec<(usize, &'a str)>;

    /// The lines outside code blocks, and the code blocks with their language, each with
    /// its line number.
    fn split(text: &str) -> (Lines<'_>, Vec<(String, Lines<'_>)>) {
        let mut prose = Vec::new();
        let mut blocks = Vec::new();
        let mut block: Option<(String, Vec<(usize, &str)>)> = None;
        for (i, line) in text.lines().enumerate() {
            let fence = line.trim_start().strip_prefix("```");
            match (fence, block.take()) {
                (Some(_), Some(b)) => blocks.push(b),
                (Some(lang), None) => block = Some((lang.trim().to_string(), Vec::new())),
                (None, Some(mut b)) => {
                    b.1.push((i + 1, line));
                    block = Some(b);
                }
                (None, None) => prose.push((i + 1, line)),
            }
        }
        (prose, blocks)
    }

    /// GitHub's anchors of a page's headings (lower case, punctuation but `-` and `_`
    /// dropped, spaces to `-`, repeats numbered).
    fn anchors(text: &str) -> BTreeSet<String> {
        let mut out = BTreeSet::new();
        for (_, line) in split(text).0 {
            let Some(title) = line.strip_prefix('#') else {
                continue;
            };
            let title = title.trim_start_matches('#').trim();
            let slug: String = title
                .to_lowercase()
                .chars()
                .filter(|c| c.is_alphanumeric() || *c == ' ' || *c == '-' || *c == '_')
                .map(|c| if c == ' ' { '-' } else { c })
                .collect();
            let mut candidate = slug.clone();
            let mut n = 0;
            while out.contains(&candidate) {
                n += 1;
                candidate = format!("{slug}-{n}");
            }
            out.insert(candidate);
        }
        out
    }

    /// The targets of the inline links `[text](target)` of a line.
    fn links(line: &str) -> Vec<String> {
        let mut out = Vec::new();
        let mut rest = line;
        while let Some(at) = rest.find("](") {
            let after = &rest[at + 2..];
            let Some(end) = after.find(')') else { break };
            let target = after[..end].split_whitespace().next().unwrap_or("");
            out.push(target.to_string());
            rest = &after[end..];
        }
        out
    }

    #[test]
    fn every_relative_link_leads_to_a_file_and_heading() {
        let mut broken = Vec::new();
        for page in pages() {
            let text = std::fs::read_to_string(&page).expect("read");
            let dir = page.parent().expect("dir");
            for (n, line) in split(&text).0 {
                // Code spans hold no links.
                let outside: String = line.split('`').step_by(2).collect::<Vec<_>>().join(" ");
                for target in links(&outside) {
                    if target.contains("://") || target.starts_with("mailto:") {
                        continue;
                    }
                    let (file, anchor) = target.split_once('#').unwrap_or((&target, ""));
                    let path = if file.is_empty() {
                        page.clone()
                    } else {
                        dir.join(file)
                    };
                    let place = format!("{}:{n}: {target}", page.display());
                    if !path.exists() {
                        broken.push(format!("{place}: no such file"));
                        continue;
                    }
                    if !anchor.is_empty() {
                        let target_text = std::fs::read_to_string(&path).unwrap_or_default();
                        if !anchors(&target_text).contains(anchor) {
                            broken.push(format!("{place}: no such heading"));
                        }
                    }
                }
            }
        }
        assert!(broken.is_empty(), "dead links:\n{}", broken.join("\n"));
    }

    /// A shell line's words up to its first operator (`|`, `&&`, `;`, `>`...), comment
    /// dropped, quotes honoured.
    fn words(line: &str) -> Vec<String> {
        let mut out = Vec::new();
        let mut word = String::new();
        let mut in_word = false;
        let mut quote: Option<char> = None;
        let mut chars = line.chars().peekable();
        while let Some(c) = chars.next() {
            match (quote, c) {
                (Some(q), c) if c == q => quote = None,
                (Some(_), c) => word.push(c),
                (None, '\'' | '"') => {
                    quote = Some(c);
                    in_word = true;
                }
                (None, '\\') => {
                    if let Some(n) = chars.next() {
                        word.push(n);
                        in_word = true;
                    }
                }
                (None, ' ' | '\t') => {
                    if in_word {
                        out.push(std::mem::take(&mut word));
                        in_word = false;
                    }
                }
                (None, '#') if !in_word => break,
                (None, '|' | ';' | '&' | '>' | '<') => break,
                (None, c) => {
                    word.push(c);
                    in_word = true;
                }
            }
        }
        if in_word {
            out.push(word);
        }
        out
    }

    #[test]
    fn every_command_in_the_docs_is_accepted_by_the_parser() {
        let mut refused = Vec::new();
        let mut checked = 0;
        for page in pages() {
            let text = std::fs::read_to_string(&page).expect("read");
            for (lang, lines) in split(&text).1 {
                if !matches!(lang.as_str(), "sh" | "bash" | "shell" | "console") {
                    continue;
                }
                // Continuation lines joined.
                let mut joined: Vec<(usize, String)> = Vec::new();
                let mut open = false;
                for (n, line) in lines {
                    let body = line.trim_end();
                    let (body, more) = match body.strip_suffix('\\') {
                        Some(b) => (b, true),
                        None => (body, false),
                    };
                    match (open, joined.last_mut()) {
                        (true, Some((_, text))) => {
                            text.push(' ');
                            text.push_str(body.trim());
                        }
                        _ => joined.push((n, body.trim().to_string())),
                    }
                    open = more;
                }
                for (n, line) in joined {
                    let mut w = words(line.trim_start_matches("$ "));
                    // Environment assignments before the command.
                    while w.first().is_some_and(|x| {
                        x.split_once('=').is_some_and(|(k, _)| {
                            !k.is_empty() && k.chars().all(|c| c.is_ascii_uppercase() || c == '_')
                        })
                    }) {
                        w.remove(0);
                    }
                    let args: Vec<String> = match w.first().map(String::as_str) {
                        Some("posestream") => w,
                        Some("cargo")
                            if w.get(1..4)
                                == Some(&["run".into(), "--release".into(), "--".into()]) =>
                        {
                            std::iter::once("posestream".to_string())
                                .chain(w.into_iter().skip(4))
                                .collect()
                        }
                        _ => continue,
                    };
                    checked += 1;
                    if let Err(e) = Cli::try_parse_from(&args) {
                        let first = e.to_string();
                        let first = first.lines().next().unwrap_or_default().to_string();
                        refused.push(format!("{}:{n}: {line}\n    {first}", page.display()));
                    }
                }
            }
        }
        assert!(checked > 20, "only {checked} commands found");
        assert!(
            refused.is_empty(),
            "commands the parser refuses:\n{}",
            refused.join("\n")
        );
    }

    #[test]
    fn the_checks_find_what_they_look_for() {
        assert_eq!(
            words("posestream run --video 'a b.mp4' --ros2 false # comment"),
            ["posestream", "run", "--video", "a b.mp4", "--ros2", "false"]
        );
        assert_eq!(
            words("posestream replay x.mcap | tee log"),
            ["posestream", "replay", "x.mcap"]
        );
        assert!(Cli::try_parse_from(["posestream", "replay", "--no-such-option"]).is_err());
        let a = anchors("# One\n## Live view in Foxglove\n```sh\n# not a heading\n```\n## One\n");
        assert!(
            a.contains("live-view-in-foxglove") && a.contains("one-1"),
            "{a:?}"
        );
        assert!(!a.contains("not-a-heading"));
        assert_eq!(
            links("see [a](b.md#c) and [d](https://x)"),
            ["b.md#c", "https://x"]
        );
    }
}
