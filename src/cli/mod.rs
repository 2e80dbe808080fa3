//! Subcommands beyond `lift` and `parity`.

pub mod eval;
pub mod learn;
pub mod synth;

pub(crate) use super::CliError;
