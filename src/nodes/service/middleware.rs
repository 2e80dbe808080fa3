//! The estimator's input from the middleware ([`EstimatorInput`]), and the estimator
//! node served over it ([`serve_estimator`]: ROS 2 on the tokio driver, iceoryx2 on the
//! blocking one).

use std::sync::atomic::AtomicBool;

use crate::floor::FloorSource;
use crate::msgs::HeatMaps;
use crate::msgs::sensor::CameraInfo;
use crate::msgs::tf::{TFMessage, TfTopic};
use crate::nodes::config::{ServiceConfig, Transport};
use crate::nodes::drivers::side_inputs::{SideInputs, TransformSource};
use crate::nodes::drivers::{run_estimator_on_runtime_with, run_estimator_with};
use crate::nodes::errors::ServiceError;
use crate::nodes::estimator::EstimatorNode;
use crate::nodes::estimator::core::EstimatorReport;
use crate::nodes::middleware::Middleware;
use crate::nodes::publish::outputs::EstimatorOutputs;
use crate::transport::ros2::{QosSettings, Ros2Source};
use crate::transport::{FrameSource, Source, TransportError};

impl Middleware {
    /// The estimator's heat maps from `transport`: a ROS 2 subscription awaited on a
    /// runtime; iceoryx2 samples lent where they are, their scores read in shared
    /// memory by a blocking loop (docs/services.md, "Where the I/O runs").
    pub fn estimator_input(
        &mut self,
        config: &ServiceConfig,
        transport: Transport,
    ) -> Result<EstimatorInput, TransportError> {
        Ok(match transport {
            Transport::Ros2 => {
                let ros = self.ros()?;
                let heatmaps = Box::new(ros.source::<HeatMaps>(&config.topics.heatmaps)?);
                let camera: Box<dyn Source<CameraInfo>> =
                    Box::new(ros.source::<CameraInfo>(&config.topics.camera_info)?);
                EstimatorInput::Awaited {
                    heatmaps,
                    side: SideInputs::camera(Some(camera)),
                }
            }
            Transport::Iceoryx2 => EstimatorInput::Lent(
                Box::new(
                    self.shm()?
                        .heatmaps_source(&config.iceoryx2.heatmaps, &config.limits)?,
                ),
                SideInputs::default(),
            ),
        })
    }

    /// With the floor from TF (`[estimator.metric.floor] source = "tf"`), subscriptions
    /// to `topics.tf_static` (latched: reliable, transient local, as tf2's static
    /// listener asks, so that transforms published before this node started arrive)
    /// and `topics.tf` (reliable, volatile). They need ROS 2: without it (an estimator
    /// reading iceoryx2 that publishes nothing on ROS 2) a warning says the floor waits
    /// for nothing, and none is opened. Empty for the other floor sources.
    pub fn transform_sources(
        &mut self,
        config: &ServiceConfig,
    ) -> Result<Vec<TransformSource>, TransportError> {
        if config.estimator.metric.floor.source != FloorSource::Tf {
            return Ok(Vec::new());
        }
        let Some(ros) = self.ros.as_mut() else {
            tracing::warn!(
                "[estimator.metric.floor] source = \"tf\" reads {} and {} over ROS 2, which \
                 this node does not use (iceoryx2 in, no ROS 2 out): no floor; set \
                 [outputs] ros2 = true, or the floor in the configuration (source = \"config\")",
                config.topics.tf_static,
                config.topics.tf
            );
            return Ok(Vec::new());
        };
        Ok(vec![
            (
                TfTopic::Static,
                Box::new(ros.source_with::<TFMessage>(
                    &config.topics.tf_static,
                    &QosSettings::tf_static_listener(),
                )?),
            ),
            (
                TfTopic::Dynamic,
                Box::new(
                    ros.source_with::<TFMessage>(&config.topics.tf, &QosSettings::tf_listener())?,
                ),
            ),
        ])
    }
}

/// Where the estimator node's heat maps come from, and so how its loop waits
/// ([`serve_estimator`]).
pub enum EstimatorInput {
    /// Messages awaited on a tokio runtime ([`run_estimator_on_runtime_with`]),
    /// and what is read beside them.
    Awaited {
        /// The heat maps.
        heatmaps: Box<Ros2Source<HeatMaps>>,
        /// The camera's calibration (`topics.camera_info`) and transforms.
        side: SideInputs,
    },
    /// Frames lent by a blocking source ([`run_estimator_with`]), and
    /// what is read beside them.
    Lent(Box<dyn FrameSource>, SideInputs),
}

/// The estimator node over its configured input ([`EstimatorInput`]): ROS 2 on the tokio
/// driver, iceoryx2 on the blocking one.
pub fn serve_estimator(
    node: &mut EstimatorNode,
    input: EstimatorInput,
    outputs: &mut EstimatorOutputs,
    stop: &AtomicBool,
) -> Result<EstimatorReport, ServiceError> {
    match input {
        EstimatorInput::Awaited { mut heatmaps, side } => {
            run_estimator_on_runtime_with(node, &mut *heatmaps, side, true, outputs, stop)
        }
        EstimatorInput::Lent(mut source, mut side) => Ok(run_estimator_with(
            node,
            &mut source,
            &mut side,
            outputs,
            stop,
        )),
    }
}
