//! The estimator's outputs as configured: what it publishes of each skeleton
//! ([`Planner`]) and where that goes ([`Sinks`]).

use super::bodies::Bodies;
use super::planner::Planner;
use super::publishers::Publishers;
use super::sinks::Sinks;
use crate::floor::FloorSource;
use crate::msgs::visualization::ImageMarker;
use crate::msgs::{MarkerArray, Skeleton3D, Skeleton3DArray};
use crate::nodes::config::ServiceConfig;
use crate::nodes::errors::ServiceError;
use crate::nodes::latency::FrameClock;
use crate::nodes::middleware::Middleware;
use crate::nodes::publish::configured::{configured_bodies, publishers, publishers_with};
use crate::nodes::publish::taps::Taps;
use crate::transport::Sink;
use crate::transport::ros2::QosSettings;

/// What a node publishes skeletons of: their joints, the bones drawn between them, and the
/// lag whose skeletons describe bodies.
pub trait SkeletonLayout {
    /// The joints of every skeleton, in order.
    fn joint_names(&self) -> &[String];
    /// The bones (joint index pairs), for drawing.
    fn bones(&self) -> Vec<(usize, usize)>;
    /// The lag whose skeletons describe bodies (`/tf`, REP-155): the newest estimates
    /// when they are published (the least delay, as TF and HRI consumers want), else the
    /// refined ones.
    fn body_lag(&self) -> u32;
}

/// Where the estimator's results go: the plan of each step ([`Planner`], on the node's
/// thread) and the publishers it is sent to ([`Sinks`], on the I/O's).
pub struct EstimatorOutputs {
    /// What is published of each skeleton.
    pub planner: Planner,
    /// Where it goes.
    pub sinks: Sinks,
}

impl EstimatorOutputs {
    /// Outputs to these publishers (skeletons of a dictionary whose bones are `bones`;
    /// no markers when `markers` is empty).
    pub fn new(
        skeletons: Publishers<Skeleton3D>,
        markers: Publishers<MarkerArray>,
        bones: Vec<(usize, usize)>,
    ) -> Self {
        Self {
            planner: Planner::new(bones, !markers.is_empty()),
            sinks: Sinks {
                skeletons,
                markers,
                ..Sinks::default()
            },
        }
    }

    /// The same outputs, noting on `clock` when each newest (lag 0) skeleton went out.
    pub fn with_clock(mut self, clock: Option<FrameClock>) -> Self {
        self.sinks.clock = clock;
        self
    }

    /// The same outputs, also sending the skeletons of each image together to `arrays`.
    pub fn with_arrays(mut self, arrays: Publishers<Skeleton3DArray>) -> Self {
        self.planner = self.planner.with_arrays(!arrays.is_empty());
        self.sinks.arrays = arrays;
        self
    }

    /// The same outputs, also drawing the skeletons of each image of lag `lag` over it.
    pub fn with_image_markers(mut self, markers: Publishers<ImageMarker>, lag: u32) -> Self {
        self.planner = self.planner.with_image_markers(!markers.is_empty(), lag);
        self.sinks.image_markers = markers;
        self
    }

    /// The same outputs, also describing bodies ([`Bodies`]: frames, REP-155 topics).
    pub fn with_bodies(mut self, bodies: Bodies) -> Self {
        self.planner.bodies = bodies.planner;
        self.sinks.tf = bodies.tf;
        self.sinks.hri = bodies.hri;
        self
    }

    /// The same outputs, stamped at release ([`Planner::stamped_at_release`]).
    pub fn stamped_at_release(mut self) -> Self {
        self.planner = self.planner.stamped_at_release();
        self
    }

    /// Skeletons sent so far.
    pub fn skeletons_sent(&self) -> u64 {
        self.sinks.skeletons.sent
    }

    /// The configured outputs of `node`'s skeletons.
    pub fn open(
        config: &ServiceConfig,
        middleware: &mut Middleware,
        taps: &Taps,
        node: &impl SkeletonLayout,
    ) -> Result<Self, ServiceError> {
        let shm_sink = match (&middleware.shm, config.outputs.iceoryx2) {
            (Some(shm), true) => Some(
                shm.skeleton_sink(&config.iceoryx2.skeletons)
                    .map(|s| Box::new(s) as Box<dyn Sink<Skeleton3D>>),
            ),
            _ => None,
        };
        let skeletons = publishers(config, middleware, taps, &config.topics.skeletons, shm_sink)?;
        let (markers, overlay) = if config.outputs.markers {
            (
                publishers(config, middleware, taps, &config.topics.markers, None)?,
                publishers(config, middleware, taps, &config.topics.image_markers, None)?,
            )
        } else {
            (Publishers::default(), Publishers::default())
        };
        let arrays = if config.outputs.arrays {
            publishers(
                config,
                middleware,
                taps,
                &config.topics.skeleton_arrays,
                None,
            )?
        } else {
            Publishers::default()
        };
        let lag = node.body_lag();
        let mut bodies = configured_bodies(config, middleware, taps, node.joint_names(), lag)?;
        let floor = &config.estimator.metric.floor;
        match floor.source {
            FloorSource::None => {}
            // The robot's floor frame: its tree holds it.
            FloorSource::Tf => bodies = bodies.with_floor(&floor.frame, false),
            FloorSource::Config | FloorSource::Learnt if !floor.published_frame.is_empty() => {
                bodies = bodies.with_floor(&floor.published_frame, true)
            }
            FloorSource::Config | FloorSource::Learnt => {}
        }
        let mut outputs = Self::new(skeletons, markers, node.bones())
            .with_arrays(arrays)
            .with_image_markers(overlay, lag)
            .with_bodies(bodies);
        if floor.source == FloorSource::Learnt && !floor.published_frame.is_empty() {
            let latched = QosSettings::latched();
            outputs.planner = outputs.planner.with_learnt_floor(&floor.published_frame);
            outputs.sinks.floor = publishers_with(
                config,
                middleware,
                taps,
                &config.topics.floor,
                None,
                Some(&latched),
            )?;
        }
        Ok(outputs)
    }
}
