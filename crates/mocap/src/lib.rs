//! Motion capture: reading BVH files ([`bvh`]), mapping their skeletons onto a pose
//! layout ([`mapping`]) and splitting a collection into training and held-out files
//! ([`split`]); synthetic heat maps from poses ([`synth`]); and scoring the
//! estimator against motion capture ([`evaluation`]).

pub mod bvh;
pub mod error;
pub mod evaluation;
pub mod mapping;
pub mod rooms;
pub mod split;
pub mod synth;

pub use bvh::Bvh;
pub use error::BvhError;
pub use mapping::{MappedSequence, SkeletonMapping, SkeletonMappingError};
pub use split::{MotionName, Split, SplitError};
