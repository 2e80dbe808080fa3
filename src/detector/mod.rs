//! The image detector's side of the estimator: turning a network's heat maps into the
//! [`crate::HeatMaps`] layout of the dictionary's joints ([`mapping`]).

pub mod mapping;
