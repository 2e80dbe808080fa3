//! What the estimator reads beside its heat maps: the camera's calibration
//! (`sensor_msgs/CameraInfo`) and, with the floor from TF, transforms (`/tf_static`,
//! `/tf`). Both are rare and small next to the heat maps; the solver takes what waits
//! in them before each frame, on its own thread, so a frame is estimated with the
//! calibration and floor that came before it.

use std::time::Duration;

use crate::msgs::sensor::CameraInfo;
use crate::msgs::tf::TFMessage;
use crate::nodes::EstimatorNode;
use crate::transport::{Received, Source, TransportError};

/// Messages taken from one source before a frame, at most: a peer flooding `/tf` (or
/// the camera-info topic) delays the frame by this many messages, not without bound (the
/// rest wait for the next frame, DDS's history keeping the newest).
const MESSAGES_PER_FRAME: usize = 64;

/// The estimator's inputs beside its heat maps.
#[derive(Default)]
pub struct SideInputs {
    /// The camera's calibration (`topics.camera_info`).
    pub camera: Option<Box<dyn Source<CameraInfo>>>,
    /// Transforms (`topics.tf_static`, `topics.tf`), read with the floor from TF.
    pub transforms: Vec<Box<dyn Source<TFMessage>>>,
}

impl SideInputs {
    /// Only the camera's calibration.
    pub fn camera(camera: Option<Box<dyn Source<CameraInfo>>>) -> Self {
        Self {
            camera,
            transforms: Vec::new(),
        }
    }

    /// Hands `node` what waits in each input (refusals counted by the node); an input
    /// that closed or broke is not read again (a warning says why).
    pub fn take(&mut self, node: &mut EstimatorNode) {
        if let Some(source) = &mut self.camera
            && !drain(
                source.as_mut(),
                node,
                MESSAGES_PER_FRAME,
                "camera info",
                |node, info| {
                    // Counted and logged by the node if refused.
                    let _ = node.camera_info(info);
                },
            )
        {
            self.camera = None;
        }
        self.transforms.retain_mut(|source| {
            drain(
                source.as_mut(),
                node,
                MESSAGES_PER_FRAME,
                "transforms",
                EstimatorNode::transforms,
            )
        });
    }
}

/// Takes up to `most` waiting messages of `source` into `node`; false when the source is
/// closed or broken.
fn drain<M>(
    source: &mut dyn Source<M>,
    node: &mut EstimatorNode,
    most: usize,
    what: &str,
    take: impl Fn(&mut EstimatorNode, &M),
) -> bool {
    for _ in 0..most {
        match source.recv(Duration::ZERO) {
            Ok(Received::Message(m, _)) => take(node, &m),
            Ok(Received::Idle) => return true,
            Ok(Received::Closed) => return false,
            Err(e @ (TransportError::Malformed { .. } | TransportError::BeyondLimits { .. })) => {
                node.count_refused(&e)
            }
            Err(e) => {
                tracing::warn!("{what}: {e}; no more is read");
                return false;
            }
        }
    }
    true
}
