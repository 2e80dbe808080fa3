//! Motion capture: reading BVH files ([`bvh`]), mapping their skeletons onto a pose
//! layout ([`mapping`]) and splitting a collection into training and held-out files
//! ([`split`]).

pub mod bvh;
pub mod mapping;
pub mod split;

pub use bvh::Bvh;
pub use mapping::{MappedSequence, MappingError, SkeletonMapping};
pub use split::{MotionName, Split, SplitError};
