//! What the estimator reads beside its heat maps: the camera's calibration
//! (`sensor_msgs/CameraInfo`) and, with the floor from TF, transforms (`/tf_static`,
//! `/tf`). Both are rare and small next to the heat maps; a driver moves what waits in
//! them to the estimator's core before each input (on the core's thread), so a frame is
//! estimated with the calibration and floor that came before it.

use std::time::Duration;

use crate::msgs::sensor::CameraInfo;
use crate::msgs::tf::{TFMessage, TfTopic};
use crate::nodes::estimator::core::Input;
use crate::transport::{Received, Source};

/// Messages taken from one source before a frame, at most: a peer flooding `/tf` (or
/// the camera-info topic) delays the frame by this many messages, not without bound (the
/// rest wait for the next frame, DDS's history keeping the newest).
const MESSAGES_PER_FRAME: usize = 64;

/// A source of transforms, and the topic it reads (`/tf_static`, `/tf`).
pub type TransformSource = (TfTopic, Box<dyn Source<TFMessage>>);

/// The estimator's inputs beside its heat maps.
#[derive(Default)]
pub struct SideInputs {
    /// The camera's calibration (`topics.camera_info`).
    pub camera: Option<Box<dyn Source<CameraInfo>>>,
    /// Transforms (`topics.tf_static`, `topics.tf`), read with the floor from TF, each
    /// with its topic.
    pub transforms: Vec<TransformSource>,
}

impl SideInputs {
    /// Only the camera's calibration.
    pub fn camera(camera: Option<Box<dyn Source<CameraInfo>>>) -> Self {
        Self {
            camera,
            transforms: Vec::new(),
        }
    }

    /// Moves what waits in each input to the node's core through `step` (as
    /// [`Input::Calibration`], [`Input::Transforms`], a refused message as
    /// [`Input::Refused`]); an input that closed or broke is not read again (a warning
    /// says why).
    pub fn take(&mut self, step: &mut dyn FnMut(Input<'_>)) {
        if let Some(source) = &mut self.camera
            && !drain(source.as_mut(), "camera info", step, |m| {
                Input::Calibration(m)
            })
        {
            self.camera = None;
        }
        self.transforms.retain_mut(|(topic, source)| {
            drain(source.as_mut(), "transforms", step, |m| {
                Input::Transforms(m, *topic)
            })
        });
    }
}

/// Moves up to [`MESSAGES_PER_FRAME`] waiting messages of `source` to `step`; false when
/// the source is closed or broken.
fn drain<M>(
    source: &mut dyn Source<M>,
    what: &str,
    step: &mut dyn FnMut(Input<'_>),
    input: impl Fn(&M) -> Input<'_>,
) -> bool {
    for _ in 0..MESSAGES_PER_FRAME {
        match source.recv(Duration::ZERO) {
            Ok(Received::Message(m, _)) => step(input(&m)),
            Ok(Received::Idle) => return true,
            Ok(Received::Closed) => return false,
            Err(e) if e.refusal().is_some() => step(Input::Refused(&e)),
            Err(e) => {
                tracing::warn!("{what}: {e}; no more is read");
                return false;
            }
        }
    }
    true
}
