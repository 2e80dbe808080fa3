//! The wiring of a service process from its configuration ([`Wiring`]): its middleware,
//! its output recording and live view, each node's ends, and how the outputs are
//! finished when the loop ends. `run_pipeline` and the `detector`, `estimator` and
//! `fuse` commands all wire themselves through it.

use std::time::Duration;

use super::detector_input::{DetectorInput, detector_input, detector_outputs};
use super::middleware::EstimatorInput;
use crate::msgs::HeatMaps;
use crate::msgs::sensor::CameraInfo;
use crate::msgs::tf::{TFMessage, TfTopic};
use crate::nodes::config::{DetectorSource, ServiceConfig, Transport};
use crate::nodes::drivers::TransformSource;
use crate::nodes::errors::ServiceError;
use crate::nodes::estimator::EstimatorNode;
use crate::nodes::frames::is_body_transform;
use crate::nodes::middleware::Middleware;
use crate::nodes::publish::configured::publishers;
use crate::nodes::publish::taps::{Taps, live_view, output_recording};
use crate::nodes::publish::{EstimatorOutputs, Publishers};
use crate::recording::RecordingSummary;
use crate::transport::{Message, Received, Source, TransportError};

/// A wiring dropped without [`Wiring::conclude`] (a setup that failed after the
/// recording started, a thread that died): a recording with nothing in it is removed;
/// one with messages is kept under its temporary name, which a warning names.
impl Drop for Wiring {
    fn drop(&mut self) {
        let Some(recorder) = self.taps.recorder.take() else {
            return;
        };
        if recorder.messages() == 0 {
            recorder.abandon();
            return;
        }
        match recorder.finish_partial() {
            Ok(kept) => tracing::warn!(
                "the run ended early: what was recorded is in {}",
                kept.display()
            ),
            Err(e) => tracing::warn!("the run ended early: {e}"),
        }
    }
}

/// What a service process is wired to: its middleware (ROS 2, iceoryx2, each only if
/// used), its output recording (`[outputs] record`) and live view (`[outputs]
/// foxglove`). Each node's ends come from it; when the loop is over,
/// [`Wiring::conclude`] finishes the recording.
pub struct Wiring {
    /// The middleware.
    pub middleware: Middleware,
    /// The output recording, once started ([`Wiring::start_recording`]), and the live
    /// view.
    pub taps: Taps,
}

impl Wiring {
    /// Opens the middleware `config` needs, plus `extra`: the transport a node reads
    /// from.
    pub fn open(config: &ServiceConfig, extra: Option<Transport>) -> Result<Self, ServiceError> {
        Ok(Self {
            middleware: Middleware::open(config, extra)?,
            taps: Taps {
                recorder: None,
                live: live_view(config)?,
            },
        })
    }

    /// Waits up to `[ros] wait_for_subscribers` for DDS discovery to see a subscriber of
    /// `topic` (then for both ends to match), when publishing on ROS 2: so that the first
    /// messages do not go to nobody. Says so when it stops waiting: a warning when one
    /// was `expected` (the detector's estimator), else a note (`run`'s optional
    /// consumers).
    pub fn wait_for_subscribers(&self, config: &ServiceConfig, topic: &str, expected: bool) {
        if config.outputs.ros2
            && config.ros.wait_for_subscribers > 0.0
            && let Some(ros) = self.middleware.ros.as_ref()
        {
            let wait = ros.discovery_wait(Duration::from_secs_f64(config.ros.wait_for_subscribers));
            if !ros.wait_for_subscriptions(topic, wait) {
                if expected {
                    tracing::warn!(
                        "no subscriber of {topic} after {wait:?}: publishing anyway \
                         (start `posestream estimator` with the same ROS_DOMAIN_ID to \
                         receive them; `ros2 topic info {topic}` lists who does)"
                    );
                } else {
                    tracing::info!("no subscriber of {topic} after {wait:?}: publishing anyway");
                }
            }
        }
    }

    /// Starts the output recording, if one is configured (after the inputs are set up;
    /// a setup that fails later drops the wiring, which removes the empty recording).
    pub fn start_recording(&mut self, config: &ServiceConfig) -> Result<(), ServiceError> {
        self.taps.recorder = output_recording(config)?;
        Ok(())
    }

    /// The publishers of `node`'s skeletons.
    pub fn estimator_outputs(
        &mut self,
        config: &ServiceConfig,
        node: &EstimatorNode,
    ) -> Result<EstimatorOutputs, ServiceError> {
        EstimatorOutputs::open(config, &mut self.middleware, &self.taps, node)
    }

    /// The detector node's heat-map publishers.
    pub fn detector_outputs(
        &mut self,
        config: &ServiceConfig,
    ) -> Result<Publishers<HeatMaps>, ServiceError> {
        detector_outputs(config, &mut self.middleware, &self.taps)
    }

    /// The detector node's configured input, its threads at least `nice` nice
    /// (`[detector] nice` where an estimator shares the process, else 0).
    pub fn detector_input(
        &mut self,
        config: &ServiceConfig,
        nice: u8,
    ) -> Result<DetectorInput, ServiceError> {
        detector_input(config, &mut self.middleware, self.taps.live.as_ref(), nice)
    }

    /// A live camera's own calibration (the `ros2` source's `topics.camera_info`), for
    /// an estimator in the process; `None` for other sources.
    pub fn camera_calibration(
        &mut self,
        config: &ServiceConfig,
    ) -> Result<Option<Box<dyn Source<CameraInfo>>>, ServiceError> {
        if config.detector.source != DetectorSource::Ros2 {
            return Ok(None);
        }
        let ros = self.middleware.ros()?;
        Ok(Some(Box::new(
            ros.source::<CameraInfo>(&config.topics.camera_info)?,
        )))
    }

    /// The configured publishers of the camera's calibration (`topics.camera_info`: ROS 2
    /// and the output recording).
    pub fn camera_outputs(
        &mut self,
        config: &ServiceConfig,
    ) -> Result<Publishers<CameraInfo>, ServiceError> {
        publishers(
            config,
            &mut self.middleware,
            &self.taps,
            &config.topics.camera_info,
            None,
        )
    }

    /// The estimator node's heat maps from `transport` ([`Middleware::estimator_input`])
    /// and what it reads beside them ([`Self::transform_sources`]), what is read beside
    /// recorded as it is read (so start the recording first).
    pub fn estimator_input(
        &mut self,
        config: &ServiceConfig,
        transport: Transport,
    ) -> Result<EstimatorInput, ServiceError> {
        let mut input = self.middleware.estimator_input(config, transport)?;
        let transforms = self.transform_sources(config)?;
        let camera_sink = self
            .taps
            .publishers::<CameraInfo>(&config.topics.camera_info)?;
        match &mut input {
            EstimatorInput::Awaited { side, .. } | EstimatorInput::Lent(_, side) => {
                side.transforms = transforms;
                // The calibration read is recorded too.
                side.camera = side.camera.take().map(|source| {
                    Box::new(Recorded {
                        source,
                        sink: camera_sink,
                    }) as Box<dyn Source<CameraInfo>>
                });
            }
        }
        Ok(input)
    }

    /// [`Middleware::transform_sources`], each recorded as it is read (to its topic of
    /// the output recording, so that a replay of the recording has the floor too).
    pub fn transform_sources(
        &mut self,
        config: &ServiceConfig,
    ) -> Result<Vec<TransformSource>, ServiceError> {
        let sources = self.middleware.transform_sources(config)?;
        sources
            .into_iter()
            .map(|(kind, source)| {
                let topic = match kind {
                    TfTopic::Static => &config.topics.tf_static,
                    TfTopic::Dynamic => &config.topics.tf,
                };
                let recorded = Box::new(RecordedTransforms {
                    source,
                    sink: self.taps.publishers::<TFMessage>(topic)?,
                    kept: TFMessage::default(),
                }) as Box<dyn Source<TFMessage>>;
                Ok((kind, recorded))
            })
            .collect()
    }

    /// Finishes the output recording after the loop ended: in place if the input held
    /// (its summary returned); if the input broke (`input_error`), left under its
    /// temporary name, which the one error names, so that a failed run replaces no
    /// existing output.
    pub fn conclude(
        mut self,
        input_error: Option<&str>,
    ) -> Result<Option<RecordingSummary>, ServiceError> {
        if let Some(live) = self.taps.live.take() {
            live.stop();
        }
        match (input_error, self.taps.recorder.take()) {
            (None, Some(r)) => Ok(Some(r.finish()?)),
            (None, None) => Ok(None),
            (Some(reason), recorder) => Err(ServiceError::Input {
                reason: reason.to_string(),
                kept: recorder.map(|r| r.finish_partial()).transpose()?,
            }),
        }
    }
}

/// A source whose messages are also published to taps as they are read (the output
/// recording): what the estimator read beside its heat maps, kept for a replay.
pub struct Recorded<M: Message> {
    /// Where the messages come from.
    pub source: Box<dyn Source<M>>,
    /// Where they are written as well.
    pub sink: Publishers<M>,
}

impl<M: Message> Source<M> for Recorded<M> {
    fn recv(&mut self, timeout: Duration) -> Result<Received<M>, TransportError> {
        let received = self.source.recv(timeout)?;
        if let Received::Message(message, stamp) = &received {
            // A failure is logged once and counted; the estimator still reads it.
            self.sink.publish(message, *stamp);
        }
        Ok(received)
    }
}

/// Transforms read from the graph, recorded as they are read, people's frames left out
/// (posestream's own, heard back on `/tf`, are recorded once already, by its publisher).
struct RecordedTransforms {
    source: Box<dyn Source<TFMessage>>,
    sink: Publishers<TFMessage>,
    /// The transforms recorded of the message in hand (reused).
    kept: TFMessage,
}

impl Source<TFMessage> for RecordedTransforms {
    fn recv(&mut self, timeout: Duration) -> Result<Received<TFMessage>, TransportError> {
        let received = self.source.recv(timeout)?;
        if let Received::Message(message, stamp) = &received {
            self.kept.transforms.clear();
            self.kept.transforms.extend(
                message
                    .transforms
                    .iter()
                    .filter(|t| !is_body_transform(&t.header.frame_id, &t.child_frame_id))
                    .cloned(),
            );
            if !self.kept.transforms.is_empty() {
                // A failure is logged once and counted; the estimator still reads it.
                self.sink.publish(&self.kept, *stamp);
            }
        }
        Ok(received)
    }
}
