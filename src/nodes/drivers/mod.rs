//! The drivers: they wait and move data, nothing else. Each node's behaviour is its
//! decision core's ([`crate::nodes::estimator::core`]); a driver moves what its sources
//! give to the core, with the time on its clock, and the core's plan to the sinks:
//!
//! - [`blocking`]: a loop on this thread over a lending source (iceoryx2 samples read
//!   where they are, recordings);
//! - [`tokio`]: the I/O on a tokio runtime (ROS 2), the core on a thread of its own
//!   (`handoff`: the channels' ends between them);
//! - [`detector`]: the detector's heat maps paced to their stamps and published, either
//!   way;
//! - [`side_inputs`]: what the estimator reads beside its heat maps (calibration,
//!   transforms), moved to the core before each input.

pub mod blocking;
pub mod detector;
mod handoff;
pub mod side_inputs;
pub mod tokio;

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crate::nodes::errors::ServiceError;

pub use blocking::{run_estimator, run_estimator_with};
pub use detector::{DetectorReport, DetectorSide, run_detector, run_detector_on_runtime};
pub use side_inputs::{SideInputs, TransformSource};
pub use tokio::{run_estimator_on_runtime, run_estimator_on_runtime_with};

/// How long a source is asked to wait before the loop checks for a stop.
pub const POLL: Duration = Duration::from_millis(100);

/// Waits until `due` after `start` (the pace of recorded stamps), waking at least every
/// [`POLL`] to look at `stop`; false if stopped while waiting.
pub fn pace(start: Instant, due: Duration, stop: &AtomicBool) -> bool {
    while let Some(wait) = due_wait(start, due, stop) {
        std::thread::sleep(wait);
    }
    !stop.load(Ordering::Relaxed)
}

/// How long to sleep next when waiting until `due` after `start` (at most [`POLL`], so
/// that `stop` is looked at); `None` once due or stopped.
pub fn due_wait(start: Instant, due: Duration, stop: &AtomicBool) -> Option<Duration> {
    let wait = due.checked_sub(start.elapsed())?;
    (!stop.load(Ordering::Relaxed)).then(|| wait.min(POLL))
}

/// Returns once `stop` is set, looking every [`POLL`].
pub(crate) async fn stopped(stop: &AtomicBool) {
    let mut tick = ::tokio::time::interval(POLL);
    tick.set_missed_tick_behavior(::tokio::time::MissedTickBehavior::Delay);
    while !stop.load(Ordering::Relaxed) {
        tick.tick().await;
    }
}

/// A runtime on this thread, with timers.
pub(crate) fn runtime() -> Result<::tokio::runtime::Runtime, ServiceError> {
    ::tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
        .map_err(ServiceError::Runtime)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_wait_for_a_stop_ends_once_it_is_set() {
        let stop = AtomicBool::new(true);
        let ended = runtime()
            .expect("runtime")
            .block_on(async { ::tokio::time::timeout(POLL * 10, stopped(&stop)).await });
        assert!(ended.is_ok());
    }
}
