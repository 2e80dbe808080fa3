//! The nodes of the service: thin adapters between messages ([`crate::msgs`]) and the
//! math ([`crate::streaming`]). Nothing here solves anything.
//!
//! - [`EstimatorNode`]: heat-map messages in, [`Skeleton3D`] messages out;
//! - [`replay`]: a recording's heat maps through the estimator loop, skeletons to a
//!   recording;
//! - [`service`]: the detector, estimator, pipeline and recorder loops over any
//!   transport ([`crate::transport`]), and their wiring from the configuration;
//! - [`markers`]: skeletons as `visualization_msgs/MarkerArray`, and over each image;
//! - [`arrays`]: the skeletons of one image together (`Skeleton3DArray`);
//! - [`camera`]: the calibration assumed for images without one (`CameraInfo`);
//! - [`frames`]: each person's body and joint frames for `/tf`;
//! - [`hri`]: skeletons as REP-155 (ROS4HRI) bodies: ids, regions, 2D skeletons;
//! - [`shown_images`]: the camera images as the Foxglove live view shows them;
//! - [`unknown_ids`]: ids for people whose heat maps came without one;
//! - [`fusion`]: several calibrated cameras' heat maps in, one skeleton per person out.

pub mod arrays;
pub mod camera;
pub mod config;
pub mod drivers;
pub mod errors;
pub mod estimator;
pub mod frames;
pub mod fusion;
pub mod hri;
pub mod images;
pub mod latency;
pub mod markers;
pub mod middleware;
pub mod priority;
pub mod publish;
pub mod replay;
pub mod service;
pub mod shown_images;
pub mod tf_buffer;
pub mod unknown_ids;

pub use config::DEFAULT_MAX_TRACKS;
pub use config::ServiceConfig;
pub use errors::{NodeError, Refusals, ServiceError, SetupError};
pub use estimator::{EstimatorNode, FloorReport, MetricTiming, calibration};
