//! The middleware of a process ([`Middleware`]): a ROS 2 node and an iceoryx2 node,
//! each only if used.

use crate::nodes::config::{ServiceConfig, Transport};
use crate::nodes::errors::ServiceError;
use crate::transport::TransportError;
use crate::transport::ros2::Ros2;
use crate::transport::shm::Shm;

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

    pub(crate) fn shm(&self) -> Result<&Shm, TransportError> {
        self.shm.as_ref().ok_or_else(|| missing("iceoryx2"))
    }
}

fn missing(transport: &'static str) -> TransportError {
    TransportError::Setup {
        transport,
        what: "the node".into(),
        reason: "not opened (enable it in [outputs] or as the input)".into(),
    }
}
