//! `posestream config`: the effective service configuration, and `--config` as the
//! service commands take it ([`ConfigArgs`]).

use std::path::PathBuf;

use clap::Args;
use posestream::msgs::shipped;
use posestream::msgs::toml_file::{ConfigError, parse_toml, read_toml};
use posestream::nodes::ServiceConfig;
use posestream::nodes::config::ENVIRONMENT_OVERRIDES;

use super::CliError;

/// `--config FILE`, as every service command takes it.
#[derive(Debug, Args)]
pub struct ConfigArgs {
    /// Service configuration: a TOML file whose keys overlay the built-in defaults
    /// (`posestream config` prints the result).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
}

impl ConfigArgs {
    /// The built-in configuration overlaid with the file's keys.
    pub fn load(&self) -> Result<ServiceConfig, ConfigError> {
        ServiceConfig::load_or_default(self.config.as_deref())
    }
}

/// `--foxglove [ADDR:PORT]`: a live view in the Foxglove app.
#[derive(Debug, Args)]
pub struct LiveArgs {
    /// Serve everything published, live, to the Foxglove app (the Foxglove WebSocket
    /// protocol; viewers can only subscribe) on ADDR:PORT, 127.0.0.1:8765 when given
    /// alone (overrides `outputs.foxglove`).
    #[arg(
        long,
        value_name = "ADDR:PORT",
        num_args = 0..=1,
        default_missing_value = posestream::transport::foxglove::DEFAULT_ADDRESS,
        value_parser = live_address
    )]
    pub foxglove: Option<String>,
}

impl LiveArgs {
    /// Applies the option to `config`.
    pub fn apply(&self, config: &mut ServiceConfig) {
        if let Some(address) = &self.foxglove {
            config.outputs.foxglove = address.clone();
        }
    }
}

/// `--foxglove`'s parser: an address to serve on, checked before the command starts.
fn live_address(text: &str) -> Result<String, String> {
    posestream::nodes::config::socket_address(text)
        .map(|_| text.trim().to_string())
        .map_err(|expected| {
            format!(
                "{expected}; a path after --foxglove is taken for its address: put the path \
                 first, or write --foxglove=127.0.0.1:8765"
            )
        })
}

/// Options of `config`.
#[derive(Debug, Args)]
pub struct ConfigCommandArgs {
    /// The file to overlay on the built-in defaults.
    #[command(flatten)]
    pub config: ConfigArgs,
    /// Print the shipped configuration file itself (every key, its default and what it
    /// does), to start a file of one's own from.
    #[arg(long, conflicts_with = "config")]
    pub defaults: bool,
    /// List the files built into the binary (`builtin:NAME` paths).
    #[arg(long, conflicts_with_all = ["config", "defaults"])]
    pub builtin: bool,
}

/// Runs `config`: the effective configuration as TOML, each key with where its value
/// came from, then the environment variables set that override keys.
pub fn run(args: &ConfigCommandArgs) -> Result<(), CliError> {
    if args.defaults {
        print!("{}", shipped::DEFAULT_CONFIG);
        return Ok(());
    }
    if args.builtin {
        for f in shipped::FILES {
            println!("{:<42} {:>8} bytes  {}", f.path(), f.bytes.len(), f.about);
        }
        return Ok(());
    }
    let config = args.config.load()?;
    let file = match &args.config.config {
        Some(path) => {
            let text = read_toml(path)?;
            let table: toml::Table = parse_toml(&text, path)?;
            Some((path.clone(), table))
        }
        None => None,
    };
    let text = config
        .annotated(file.as_ref().map(|(p, t)| (p.as_path(), t)))
        .map_err(|e| CliError::Failed(format!("cannot write the configuration: {e}")))?;
    println!(
        "# The effective configuration: built-in defaults{}.",
        match &file {
            Some((p, _)) => format!(" overlaid with {}", p.display()),
            None => String::new(),
        }
    );
    print!("{text}");
    let set: Vec<String> = ENVIRONMENT_OVERRIDES
        .iter()
        .filter_map(|(var, key)| {
            std::env::var(var)
                .ok()
                .filter(|v| !v.is_empty())
                .map(|v| format!("# {var}={v:?} overrides {key}"))
        })
        .collect();
    if !set.is_empty() {
        println!("\n# Set in the environment, applied when a node starts:");
        for line in set {
            println!("{line}");
        }
    }
    Ok(())
}
