//! The nodes as services: what each process is wired to ([`wiring`]: its middleware,
//! the output recording and live view; the estimator's input, [`middleware`]; the
//! detector's, [`detector_input`]),
//! both nodes in one process ([`pipeline`]), the recorder ([`recorder`]), and the fusion
//! node's loop over several cameras ([`fusion`]). What backend each end is comes from the
//! configuration; the drivers (`nodes::drivers`) and the decision cores do not know.
//!
//! The drivers and the estimator's outputs are re-exported here, where the services were
//! found before they had modules of their own.

pub mod detector_input;
pub mod fusion;
pub mod middleware;
pub mod pipeline;
pub mod recorder;
pub mod wiring;

pub use crate::nodes::drivers::{
    DetectorReport, DetectorSide, POLL, SideInputs, pace, run_detector, run_detector_on_runtime,
    run_estimator, run_estimator_on_runtime, run_estimator_on_runtime_with, run_estimator_with,
};
pub use crate::nodes::errors::ServiceError;
pub use crate::nodes::estimator::EstimatorReport;
pub use crate::nodes::middleware::Middleware;
pub use crate::nodes::publish::{
    Bodies, EstimatorOutputs, HriSinks, MAX_BODIES_MADE, MAX_BODY_TOPICS, Publishers, RETIRE_AFTER,
    Taps, TopicMaker, live_view, output_recording,
};
pub use detector_input::{
    DetectorInput, RecordedHeatMaps, detector_input, detector_outputs, detector_transport,
    recording_source,
};
pub use middleware::{EstimatorInput, serve_estimator};
pub use pipeline::{PipelineReport, Stages, run_pipeline};
pub use recorder::{RecordStep, record_step, run_recorder};
pub use wiring::{Recorded, Wiring};
