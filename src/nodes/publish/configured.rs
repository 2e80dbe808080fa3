//! Publishers as configured (`[outputs]`): one topic's on every output ([`publishers`]),
//! and what is said of bodies ([`configured_bodies`]).

use super::bodies::Bodies;
use super::body_topics::TopicMaker;
use super::publishers::Publishers;
use super::taps::Taps;
use crate::nodes::config::ServiceConfig;
use crate::nodes::errors::ServiceError;
use crate::nodes::middleware::Middleware;
use crate::transport::ros2::QosSettings;
use crate::transport::{Message, Sink, TransportError};

/// The configured descriptions of bodies (`[outputs] tf`, `hri`) of skeletons of
/// `joint_names` at `lag`.
pub fn configured_bodies(
    config: &ServiceConfig,
    middleware: &mut Middleware,
    taps: &Taps,
    joint_names: &[String],
    lag: u32,
) -> Result<Bodies, ServiceError> {
    let tf = if config.outputs.tf {
        publishers(config, middleware, taps, &config.topics.tf, None)?
    } else {
        Publishers::default()
    };
    let hri = config.outputs.hri.then(|| {
        let maker = TopicMaker {
            ros: middleware.ros.clone().filter(|_| config.outputs.ros2),
            taps: taps.clone(),
        };
        (
            config.topics.hri_bodies.clone(),
            maker,
            config.outputs.hri_roi,
        )
    });
    Bodies::new(joint_names, lag, tf, hri)
}

/// Publishers of `M` on `topic` / `service` for every configured output.
pub fn publishers<M: Message>(
    config: &ServiceConfig,
    middleware: &mut Middleware,
    taps: &Taps,
    topic: &str,
    shm: Option<Result<Box<dyn Sink<M>>, TransportError>>,
) -> Result<Publishers<M>, ServiceError> {
    publishers_with(config, middleware, taps, topic, shm, None)
}

/// [`publishers`], the ROS 2 one with QoS `qos` (`None`: the node's, `[ros.qos]`).
pub fn publishers_with<M: Message>(
    config: &ServiceConfig,
    middleware: &mut Middleware,
    taps: &Taps,
    topic: &str,
    shm: Option<Result<Box<dyn Sink<M>>, TransportError>>,
    qos: Option<&QosSettings>,
) -> Result<Publishers<M>, ServiceError> {
    let mut out = Publishers::default();
    if config.outputs.ros2 {
        let ros = middleware.ros()?;
        let sink = match qos {
            Some(qos) => ros.sink_with::<M>(topic, qos)?,
            None => ros.sink::<M>(topic)?,
        };
        out.add_ros2(format!("ros2 {topic}"), sink);
    }
    if let Some(sink) = shm {
        out.add(format!("iceoryx2 {topic}"), sink?);
    }
    taps.add_to(&mut out, topic)?;
    Ok(out)
}
