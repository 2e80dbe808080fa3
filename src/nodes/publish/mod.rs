//! What the nodes publish, planned once and sent by either driver:
//!
//! - [`plan`]: a step's messages in the order they go out ([`Plan`]);
//! - [`planner`]: the estimator's plan of each step ([`Planner`]: skeletons, markers,
//!   images' arrays and markers, bodies);
//! - [`bodies`]: what is said of bodies ([`BodyPlanner`]: frames on `/tf`, REP-155);
//! - [`floor`]: the learnt floor with its covariance ([`FloorPlanner`]);
//! - [`publishers`]: one message type's publishers on every output ([`Publishers`]);
//! - [`body_topics`]: REP-155's body topics, made and retired as people come and go;
//! - [`sinks`]: a node's publishers, a plan sent to them ([`Sinks::send`],
//!   [`Sinks::send_async`]);
//! - [`taps`]: what sees everything a process publishes (the output recording, the live
//!   view);
//! - [`configured`]: one topic's publishers and the bodies' as configured;
//! - [`outputs`]: the estimator's outputs as configured ([`EstimatorOutputs`]).

pub mod bodies;
pub mod body_topics;
pub mod configured;
pub mod floor;
pub mod outputs;
pub mod plan;
pub mod planner;
pub mod publishers;
pub mod sinks;
pub mod taps;

pub use bodies::{Bodies, BodyPlanner};
pub use body_topics::{HriSinks, MAX_BODIES_MADE, MAX_BODY_TOPICS, RETIRE_AFTER, TopicMaker};
pub use floor::FloorPlanner;
pub use outputs::{EstimatorOutputs, SkeletonLayout};
pub use plan::{Plan, Publication};
pub use planner::Planner;
pub use publishers::Publishers;
pub use sinks::Sinks;
pub use taps::{Taps, live_view, output_recording};
