//! The nodes as services: the loops that move messages between sources, the
//! [`EstimatorNode`](super::EstimatorNode) and sinks (blocking, [`loops`]; with their
//! I/O on a tokio runtime, [`runtime`]; what the estimator reads beside its heat maps,
//! [`side_inputs`]), and the wiring that builds those ends from the
//! configuration ([`wiring`]), and what is said of bodies rather than skeletons (frames
//! on `/tf`, REP-155's topics: [`bodies`]), and the fusion node's loop over several cameras
//! ([`fusion`]). What backend each end is
//! comes from the configuration; the loops do not know.

pub mod bodies;
pub mod fusion;
pub mod loops;
pub mod runtime;
pub mod side_inputs;
pub mod wiring;

pub use loops::*;
pub use runtime::*;
pub use side_inputs::SideInputs;
pub use wiring::*;

use crate::nodes::SetupError;
use crate::recording::RecordingError;
use crate::transport::TransportError;

/// Why a service could not start or had to stop.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    /// The estimator could not be set up.
    #[error(transparent)]
    Setup(#[from] SetupError),
    /// A transport could not be set up, or broke.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// The output recording could not be written.
    #[error(transparent)]
    Recording(#[from] RecordingError),
    /// The node's I/O runtime could not start.
    #[error("cannot start the I/O runtime: {0}")]
    Runtime(std::io::Error),
    /// A thread of the pipeline panicked.
    #[error("the {0} thread stopped unexpectedly")]
    Thread(&'static str),
    /// An output is one of the inputs.
    #[error(transparent)]
    OutputIsInput(#[from] crate::files::OutputIsInput),
    /// The input broke part way (a corrupt recording): the outputs are left as they
    /// were; what was recorded before is kept in the recording's `.partial` file.
    #[error("{reason}{}", kept.as_ref().map(|k| format!("; what was recorded before is in {}", k.display())).unwrap_or_default())]
    Input {
        /// What was wrong with the input.
        reason: String,
        /// The output recording's temporary file, if recording.
        kept: Option<std::path::PathBuf>,
    },
}
