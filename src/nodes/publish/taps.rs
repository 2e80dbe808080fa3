//! What sees every message a process publishes besides the middleware ([`Taps`]): the
//! output recording (`[outputs] record`) and the live view (`[outputs] foxglove`).

use crate::nodes::config::ServiceConfig;
use crate::nodes::errors::ServiceError;
use crate::nodes::publish::Publishers;
use crate::transport::foxglove::LiveView;
use crate::transport::mcap::SharedRecorder;
use crate::transport::{Message, TransportError};

/// The recording of `[outputs] record`, if configured (refused if it is one of the
/// detector's inputs).
pub fn output_recording(config: &ServiceConfig) -> Result<Option<SharedRecorder>, ServiceError> {
    let path = &config.outputs.record;
    if path.as_os_str().is_empty() {
        return Ok(None);
    }
    crate::files::check_output(
        path,
        &[&config.detector.recording, &config.detector.images.path],
    )?;
    Ok(Some(SharedRecorder::create(path)?))
}

/// What sees every message a process publishes, besides the middleware: the output
/// recording (`[outputs] record`) and the live view (`[outputs] foxglove`).
#[derive(Clone, Default)]
pub struct Taps {
    /// The output recording, once started.
    pub recorder: Option<SharedRecorder>,
    /// The Foxglove WebSocket server.
    pub live: Option<LiveView>,
}

impl Taps {
    /// Adds each tap's sink of `M` on `topic` to `out` (as sinks of bytes: they share one
    /// encoding of each message).
    pub fn add_to<M: Message>(
        &self,
        out: &mut Publishers<M>,
        topic: &str,
    ) -> Result<(), TransportError> {
        if let Some(r) = &self.recorder {
            out.add_encoded(format!("mcap {topic}"), Box::new(r.sink::<M>(topic)));
        }
        if let Some(live) = &self.live {
            out.add_encoded(
                format!("foxglove {topic}"),
                Box::new(live.sink::<M>(topic)?),
            );
        }
        Ok(())
    }

    /// Each tap's sink of `M` on `topic`, as one.
    pub fn publishers<M: Message>(&self, topic: &str) -> Result<Publishers<M>, TransportError> {
        let mut out = Publishers::default();
        self.add_to(&mut out, topic)?;
        Ok(out)
    }

    /// Sends an encoded message of type `M` (CDR, as read from a recording) on `topic`
    /// to each tap, without decoding it; the first failure is returned, after every tap
    /// was tried.
    pub fn send_encoded<M: Message>(
        &self,
        topic: &str,
        stamp_ns: u64,
        data: &[u8],
    ) -> Result<(), TransportError> {
        let recorded = self
            .recorder
            .as_ref()
            .map_or(Ok(()), |r| r.write_encoded::<M>(topic, stamp_ns, data));
        let live = self
            .live
            .as_ref()
            .map_or(Ok(()), |l| l.send_encoded::<M>(topic, stamp_ns, data));
        recorded.and(live)
    }
}

/// The live view of `[outputs] foxglove`, if configured: serving from now on.
pub fn live_view(config: &ServiceConfig) -> Result<Option<LiveView>, TransportError> {
    let address = config.outputs.foxglove.trim();
    if address.is_empty() {
        return Ok(None);
    }
    let address =
        crate::nodes::config::socket_address(address).map_err(|reason| TransportError::Setup {
            transport: "foxglove",
            what: format!("a Foxglove WebSocket server on {address}"),
            reason,
        })?;
    let live = LiveView::serve(address)?;
    tracing::info!(
        target: "posestream::live",
        "Foxglove live view on ws://{} (Foxglove app: Open connection, Foxglove WebSocket; \
         layout: docs/foxglove-layout.json)",
        live.address()
    );
    Ok(Some(live))
}
