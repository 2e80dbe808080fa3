//! Subcommands beyond `lift` and `parity`.

pub mod eval;
pub mod learn;
pub mod models;
pub mod render;
pub mod replay;
pub mod service;
pub mod synth;

pub(crate) use super::CliError;

use indicatif::{ProgressBar, ProgressStyle};

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
