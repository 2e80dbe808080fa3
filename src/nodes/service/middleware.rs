//! The middleware of a process ([`Middleware`]: a ROS 2 node and an iceoryx2 node, each
//! only if used), and the estimator's input from it ([`EstimatorInput`]).

use super::ServiceError;
use super::side_inputs::SideInputs;
use crate::floor::FloorSource;
use crate::msgs::HeatMaps;
use crate::msgs::sensor::CameraInfo;
use crate::msgs::tf::TFMessage;
use crate::nodes::config::{ServiceConfig, Transport};
use crate::transport::ros2::{QosSettings, Ros2, Ros2Source};
use crate::transport::shm::Shm;
use crate::transport::{FrameSource, Source, TransportError};

/// The middleware of a process: a ROS 2 node and an iceoryx2 node, each only if used.
#[derive(Default)]
pub struct Middleware {
    /// The ROS 2 participant and node.
    pub ros: Option<Ros2>,
    /// The iceoryx2 node.
    pub shm: Option<Shm>,
}

impl Middleware {
    /// Opens what `config` (plus `extra`, a transport a node reads from) needs.
    pub fn open(config: &ServiceConfig, extra: Option<Transport>) -> Result<Self, ServiceError> {
        let ros = config.outputs.ros2 || extra == Some(Transport::Ros2);
        let shm = config.outputs.iceoryx2 || extra == Some(Transport::Iceoryx2);
        Ok(Self {
            ros: ros.then(|| Ros2::new(&config.ros)).transpose()?,
            shm: shm.then(Shm::new).transpose()?,
        })
    }

    pub(crate) fn ros(&mut self) -> Result<&mut Ros2, TransportError> {
        self.ros.as_mut().ok_or_else(|| missing("ros2"))
    }

    fn shm(&self) -> Result<&Shm, TransportError> {
        self.shm.as_ref().ok_or_else(|| missing("iceoryx2"))
    }

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
    ) -> Result<Vec<Box<dyn Source<TFMessage>>>, TransportError> {
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
            Box::new(ros.source_with::<TFMessage>(
                &config.topics.tf_static,
                &QosSettings::tf_static_listener(),
            )?),
            Box::new(ros.source_with::<TFMessage>(&config.topics.tf, &QosSettings::tf_listener())?),
        ])
    }
}

/// Where the estimator node's heat maps come from, and so how its loop waits
/// ([`serve_estimator`](super::serve_estimator)).
pub enum EstimatorInput {
    /// Messages awaited on a tokio runtime ([`run_estimator_on_runtime`](super::run_estimator_on_runtime)),
    /// and what is read beside them.
    Awaited {
        /// The heat maps.
        heatmaps: Box<Ros2Source<HeatMaps>>,
        /// The camera's calibration (`topics.camera_info`) and transforms.
        side: SideInputs,
    },
    /// Frames lent by a blocking source ([`run_estimator`](super::run_estimator)), and
    /// what is read beside them.
    Lent(Box<dyn FrameSource>, SideInputs),
}

fn missing(transport: &'static str) -> TransportError {
    TransportError::Setup {
        transport,
        what: "the node".into(),
        reason: "not opened (enable it in [outputs] or as the input)".into(),
    }
}
