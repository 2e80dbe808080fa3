//! The `posestream` command line: sets up logging, parses, dispatches (`cli`).

use std::process::ExitCode;

use clap::Parser;

mod cli;

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                // A Foxglove viewer's misbehaviour (a failed handshake, a message on no
                // channel, a connection reset) is the viewer's, and a remote one could fill
                // the log with it: the server's lines only when asked for (RUST_LOG); the
                // live view says where it serves (`posestream::live`).
                .unwrap_or_else(|_| {
                    tracing_subscriber::EnvFilter::new("warn,foxglove=off,posestream::live=info")
                }),
        )
        .init();
    cli::process::install_panic_hook();
    cli::process::ignore_file_size_signal();
    // Every file a command reads is one of its inputs: no output is written onto it.
    posestream::base::files::inputs::remember();
    match cli::Cli::parse().run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("posestream: error: {e}");
            ExitCode::FAILURE
        }
    }
}
