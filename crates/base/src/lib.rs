//! # posestream-base
//!
//! What every layer of posestream shares, and nothing that is a layer's own; it imports
//! no posestream crate:
//!
//! - [`domain`]: configured values against their domains ([`OutOfDomain`],
//!   [`check_range`], [`check_real`]);
//! - [`panics`]: a dependency's panic on outside data contained at the call
//!   ([`contain_panics`]), the text of a panic ([`panic_text`]);
//! - [`files`]: reading a user's file: regular files only, at most a format's cap,
//!   ended by a signal's [`files::stop`];
//! - [`frame`]: the geometry and scores of one frame of heat maps ([`CropBox`],
//!   [`PixelMap`], [`Scores`]);
//! - [`ports`]: the traits every transport implements ([`Source`], [`Sink`]), what a
//!   source [`Received`], and the [`TransportError`] with its refusal kind.

pub mod domain;
pub mod files;
pub mod frame;
pub mod panics;
pub mod ports;

pub use domain::{OutOfDomain, check_range, check_real};
pub use frame::{CropBox, PixelMap, Scores};
pub use panics::{contain_panics, panic_is_contained, panic_text};
pub use ports::{Received, Sink, Source, TransportError, ended};
