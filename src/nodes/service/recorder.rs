//! The recorder service (`posestream record`): topics of the graph into a recording,
//! round-robin.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crate::transport::{Message, Received, Sink, Source, TransportError};

/// One topic of a recorder: takes a message (waiting up to the given time) and writes
/// it; true if one was recorded ([`record_step`]).
pub type RecordStep = Box<dyn FnMut(Duration) -> Result<bool, TransportError> + Send>;

/// Runs the recorder `steps` (topic name, step) round-robin until `stop`, `duration` or
/// `max_messages`; returns the messages recorded per topic.
pub fn run_recorder(
    sources: &mut [(String, RecordStep)],
    stop: &AtomicBool,
    duration: Option<Duration>,
    max_messages: Option<u64>,
) -> Vec<(String, u64)> {
    let start = Instant::now();
    let mut counts = vec![0_u64; sources.len()];
    let step = Duration::from_millis(10);
    'outer: while !stop.load(Ordering::Relaxed) {
        if duration.is_some_and(|d| start.elapsed() >= d) {
            break;
        }
        for (i, (name, take)) in sources.iter_mut().enumerate() {
            match take(step) {
                Ok(true) => counts[i] += 1,
                Ok(false) => {}
                Err(e) => tracing::warn!("{name}: {e}"),
            }
            if max_messages.is_some_and(|m| counts.iter().sum::<u64>() >= m) {
                break 'outer;
            }
        }
    }
    sources.iter().map(|(n, _)| n.clone()).zip(counts).collect()
}

/// A recorder step for one topic: takes a message of `source` (waiting up to the given
/// time) and writes it to `sink`; true if one was recorded.
pub fn record_step<M: Message>(
    mut source: impl Source<M> + 'static,
    mut sink: impl Sink<M> + 'static,
) -> RecordStep {
    Box::new(move |wait| match source.recv(wait)? {
        Received::Message(m, stamp) => {
            // DDS gives no log time of its own: use the reception time, as rosbag2 does.
            let now = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(stamp, |d| u64::try_from(d.as_nanos()).unwrap_or(stamp));
            sink.send(&m, now)?;
            Ok(true)
        }
        Received::Idle | Received::Closed => Ok(false),
    })
}
