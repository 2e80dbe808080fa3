//! The detector's drivers: heat maps from its source (the image detector with its
//! frames, or a recording) to its publishers, paced to their stamps
//! ([`ReplayRate::Recorded`]) or as fast as they come. One [`Pacer`] decides for both: a
//! blocking loop ([`run_detector`]) and the source on a thread of its own with the pacing
//! and publishing on a runtime ([`DetectorSide`], [`run_detector_on_runtime`]).

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use serde::Serialize;

use super::{POLL, due_wait, pace, runtime, stopped};
use crate::detector::DetectorStats;
use crate::msgs::HeatMaps;
use crate::nodes::config::ReplayRate;
use crate::nodes::errors::Refusals;
use crate::nodes::errors::ServiceError;
use crate::nodes::estimator::Flow;
use crate::nodes::publish::Publishers;
use crate::transport::runtime::{AsyncSource, Blocking};
use crate::transport::{Received, Source, TransportError};

/// Heat maps waiting between the detector's thread and the runtime at most.
const CHANNEL: usize = 4;

/// What the detector service did.
#[derive(Debug, Clone, Serialize)]
pub struct DetectorReport {
    /// Heat-map messages published.
    pub published: u64,
    /// Messages of the source that could not be read (skipped).
    pub malformed: u64,
    /// Sends that failed.
    pub failed_sends: u64,
    /// Why the source ended early, if it did.
    pub input_error: Option<String>,
    /// The image detector's counters (image sources only).
    pub images: Option<DetectorStats>,
}

/// The detector's decisions: which of what its source gives is published, and when.
struct Pacer {
    rate: ReplayRate,
    /// The wall time of the first message and its stamp, for the pace.
    first: Option<(Instant, u64)>,
    refused: Refusals,
    input_error: Option<String>,
}

impl Pacer {
    fn new(rate: ReplayRate) -> Self {
        Self {
            rate,
            first: None,
            refused: Refusals::default(),
            input_error: None,
        }
    }

    /// The message to publish of what the source gave, if any; a refused one is counted,
    /// and a closed or broken source ends the loop (the reason kept for the report).
    fn received(
        &mut self,
        got: Result<Received<HeatMaps>, TransportError>,
    ) -> (Option<(HeatMaps, u64)>, Flow) {
        match got {
            Ok(Received::Message(maps, stamp)) => (Some((maps, stamp)), Flow::Continue),
            Ok(Received::Idle) => (None, Flow::Continue),
            Ok(Received::Closed) => (None, Flow::End),
            Err(e) => match e.refusal() {
                Some(kind) => {
                    self.refused.note(kind, &e);
                    (None, Flow::Continue)
                }
                None => {
                    // Reported by the caller, from the report.
                    self.input_error = Some(e.to_string());
                    (None, Flow::End)
                }
            },
        }
    }

    /// When the message stamped `stamp` is due: after how long from when (none: at once).
    fn due(&mut self, stamp: u64) -> Option<(Instant, Duration)> {
        if self.rate != ReplayRate::Recorded {
            return None;
        }
        let (start, first) = *self.first.get_or_insert((Instant::now(), stamp));
        Some((start, Duration::from_nanos(stamp.saturating_sub(first))))
    }

    fn report(self, sinks: &Publishers<HeatMaps>) -> DetectorReport {
        DetectorReport {
            published: sinks.sent,
            malformed: self.refused.total(),
            failed_sends: sinks.failed,
            input_error: self.input_error,
            images: None,
        }
    }
}

/// Heat maps from `source` to `sinks`, at the pace of their stamps
/// ([`ReplayRate::Recorded`]) or as fast as the sinks take them, until the source
/// closes or `stop` is set.
pub fn run_detector(
    source: &mut dyn Source<HeatMaps>,
    sinks: &mut Publishers<HeatMaps>,
    rate: ReplayRate,
    stop: &AtomicBool,
) -> DetectorReport {
    let mut pacer = Pacer::new(rate);
    while !stop.load(Ordering::Relaxed) {
        let (message, flow) = pacer.received(source.recv(POLL));
        if let Some((maps, stamp)) = message {
            if let Some((start, due)) = pacer.due(stamp)
                && !pace(start, due, stop)
            {
                break;
            }
            sinks.publish_owned(maps, stamp);
        }
        if flow == Flow::End {
            break;
        }
    }
    sinks.flush();
    pacer.report(sinks)
}

/// The detector's side on a runtime, as an [`AsyncSource`] of heat maps: the frames of
/// a source running on a thread of its own ([`Blocking`]), paced and published to
/// `sinks` as they are taken ([`Pacer`], as in [`run_detector`]).
pub struct DetectorSide<'a> {
    source: Blocking<HeatMaps>,
    sinks: Publishers<HeatMaps>,
    pacer: Pacer,
    stop: &'a AtomicBool,
}

impl<'a> DetectorSide<'a> {
    /// Starts `source` on a thread of its own (named `posestream-detector`).
    pub fn spawn(
        source: impl Source<HeatMaps> + 'static,
        sinks: Publishers<HeatMaps>,
        rate: ReplayRate,
        stop: &'a AtomicBool,
    ) -> Result<Self, ServiceError> {
        Ok(Self {
            source: Blocking::spawn("detector", source, CHANNEL)?,
            sinks,
            pacer: Pacer::new(rate),
            stop,
        })
    }

    /// What the detector did so far (its source's thread ended, its sinks flushed:
    /// call once the side is done).
    pub fn conclude(mut self) -> DetectorReport {
        // The source's thread ends before the sinks and the middleware under them.
        drop(self.source);
        self.sinks.flush();
        self.pacer.report(&self.sinks)
    }
}

impl AsyncSource<HeatMaps> for DetectorSide<'_> {
    async fn next(&mut self) -> Result<Received<HeatMaps>, TransportError> {
        loop {
            let (message, flow) = self.pacer.received(self.source.next().await);
            if let Some((maps, stamp)) = message {
                if let Some((start, due)) = self.pacer.due(stamp) {
                    while let Some(wait) = due_wait(start, due, self.stop) {
                        tokio::time::sleep(wait).await;
                    }
                    if self.stop.load(Ordering::Relaxed) {
                        return Ok(Received::Closed);
                    }
                }
                self.sinks.publish_async(&maps, stamp).await;
                return Ok(Received::Message(maps, stamp));
            }
            if flow == Flow::End {
                return Ok(Received::Closed);
            }
        }
    }
}

/// Heat maps from `source` to `sinks`, as [`run_detector`] does (the same report), with
/// the source on a thread of its own and the pacing and publishing on a tokio runtime
/// on this thread ([`DetectorSide`]). Errors only if the runtime or the source's thread
/// cannot start.
pub fn run_detector_on_runtime(
    source: impl Source<HeatMaps> + 'static,
    sinks: Publishers<HeatMaps>,
    rate: ReplayRate,
    stop: &AtomicBool,
) -> Result<DetectorReport, ServiceError> {
    let runtime = runtime()?;
    let mut side = DetectorSide::spawn(source, sinks, rate, stop)?;
    runtime.block_on(async {
        let reading = async { while let Ok(Received::Message(..)) = side.next().await {} };
        tokio::select! {
            () = reading => {}
            () = stopped(stop) => {}
        }
    });
    Ok(side.conclude())
}
