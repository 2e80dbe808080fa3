//! The hand-off between the tokio driver's runtime and its solver thread: what the
//! runtime reads ([`feed`]: the source's messages, and a quiet input when none came for
//! a while) goes to the solver through a bounded channel, where [`Handed`] lends it to
//! the blocking driver's loop as a source would; the loop's plans go back through
//! [`Handing`], and come back once sent, to be written over.

use std::cell::Cell;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use tokio::sync::mpsc;

use super::blocking::Outlet;
use super::{POLL, stopped};
use crate::msgs::{HeatMaps, HeatMapsView};
use crate::nodes::estimator::core::EstimatorCore;
use crate::nodes::publish::Plan;
use crate::transport::recycle::Recycler;
use crate::transport::runtime::AsyncSource;
use crate::transport::{FrameSource, Lent, Received, TransportError};
use posestream_base::ended;

/// Inputs (or plans) waiting between the runtime and the solver at most.
pub(super) const CHANNEL: usize = 4;

/// What the runtime hands the solver.
pub(super) enum Work {
    /// What the source gave.
    Got(Result<Received<HeatMaps>, TransportError>),
    /// Nothing came for a while.
    Quiet,
}

/// Reads `source` into `work` until it ends, `stop` is set or the solver is gone (it
/// ended, or panicked), offering a [`Work::Quiet`] while no message comes. Dropping
/// `work` after it ends the solver's loop.
pub(super) async fn feed(
    mut source: impl AsyncSource<HeatMaps>,
    work: mpsc::Sender<Work>,
    stop: &AtomicBool,
) {
    // Since when the reader has waited for a message (kept over refused ones; none
    // while it hands one over): the quiet timer says so after POLL of it.
    let waiting = Cell::new(None);
    let reading = async {
        // A stop ends the wait for the next message (a source in the middle of one is
        // cut off there: see `AsyncSource::next`).
        let stopping = stopped(stop);
        tokio::pin!(stopping);
        let mut since = Instant::now();
        loop {
            waiting.set(Some(since));
            let got = tokio::select! {
                // A source that always has a message does not delay a stop.
                biased;
                () = &mut stopping => return,
                got = source.next() => got,
            };
            waiting.set(None);
            let message = matches!(got, Ok(Received::Message(..)));
            let end = ended(&got);
            // The solver gone ends the input; so does the source's end (it is not
            // asked again).
            if work.send(Work::Got(got)).await.is_err() || end {
                return;
            }
            if message {
                since = Instant::now();
            }
        }
    };
    tokio::select! {
        () = reading => {}
        () = quiet(&waiting, &work) => {}
    }
}

/// What the runtime hands the solver, as a lending source: each frame lent, then given
/// back to the source's recycler (when it has one; a frame whose scores take more than
/// the given bytes, one the node refuses as too large, is freed instead); whether the
/// source is live.
pub(super) struct Handed(
    pub(super) mpsc::Receiver<Work>,
    pub(super) Option<(Recycler<HeatMaps>, usize)>,
    pub(super) bool,
);

impl FrameSource for Handed {
    /// Waits for the runtime (it says when the input is quiet: `Idle`).
    fn recv_frame(
        &mut self,
        _timeout: Duration,
        take: &mut dyn FnMut(&HeatMapsView<'_>, u64),
    ) -> Result<Received<()>, TransportError> {
        match self.0.blocking_recv() {
            None => Ok(Received::Closed),
            Some(Work::Quiet) => Ok(Received::Idle),
            Some(Work::Got(got)) => got.map(|r| {
                r.map(|maps, stamp| {
                    take(&maps.view(), stamp);
                    if let Some((recycler, keep)) = &self.1
                        && maps.values.capacity() * 4 + maps.quantized_values.capacity() <= *keep
                    {
                        recycler.put(maps);
                    }
                })
            }),
        }
    }

    fn recv_input(
        &mut self,
        timeout: Duration,
        take: &mut dyn FnMut(Lent<'_>, u64),
    ) -> Result<Received<()>, TransportError> {
        crate::transport::frames_only(self, timeout, take)
    }

    fn live(&self) -> bool {
        self.2
    }
}

/// The solver's plans handed to the runtime's sending, and those sent coming back.
pub(super) struct Handing(
    pub(super) mpsc::Sender<Plan>,
    pub(super) std::sync::mpsc::Receiver<Plan>,
    pub(super) Vec<Plan>,
);

impl Outlet for Handing {
    fn send(&mut self, core: &mut EstimatorCore<'_>, plan: &mut Plan) -> bool {
        while let Ok(mut sent) = self.1.try_recv() {
            core.recycle(&mut sent);
            self.2.push(sent);
        }
        let next = self.2.pop().unwrap_or_default();
        // The output gone (it cannot be, short of a panic) ends the loop.
        self.0.blocking_send(std::mem::replace(plan, next)).is_ok()
    }
}

/// Offers the solver a [`Work::Quiet`] every [`POLL`] while the reader has waited for a
/// message that long (`waiting`: since when; a refused one does not restart it, and no
/// quiet input overtakes a message being handed over; a full channel gives the solver
/// work enough). Returns once the solver is gone (it ended, or panicked), so that a quiet
/// input does not hide that.
async fn quiet(waiting: &Cell<Option<Instant>>, work: &mpsc::Sender<Work>) {
    let mut tick = tokio::time::interval(POLL);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tick.tick().await;
        if waiting.get().is_some_and(|since| since.elapsed() >= POLL)
            && let Err(mpsc::error::TrySendError::Closed(_)) = work.try_send(Work::Quiet)
        {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nodes::drivers::runtime;

    #[test]
    fn the_quiet_timer_ends_when_the_solver_is_gone() {
        let (work, solver) = mpsc::channel::<Work>(1);
        drop(solver);
        let waiting = Cell::new(Some(Instant::now()));
        let ended = runtime()
            .expect("runtime")
            .block_on(async { tokio::time::timeout(POLL * 10, quiet(&waiting, &work)).await });
        assert!(
            ended.is_ok(),
            "the timer ticks on for a solver that is gone"
        );
    }

    #[test]
    fn the_quiet_timer_says_nothing_while_messages_come_or_one_is_handed_over() {
        let (work, mut solver) = mpsc::channel::<Work>(8);
        let waiting = Cell::new(Some(Instant::now()));
        runtime().expect("runtime").block_on(async {
            let feeding = async {
                for _ in 0..10 {
                    tokio::time::sleep(POLL / 4).await;
                    waiting.set(Some(Instant::now()));
                }
                // A message handed over for longer than POLL (the solver behind): no
                // quiet input overtakes it.
                waiting.set(None);
                tokio::time::sleep(POLL * 3).await;
            };
            tokio::select! {
                () = feeding => {}
                () = quiet(&waiting, &work) => {}
            }
        });
        assert!(
            solver.try_recv().is_err(),
            "a quiet input while messages came"
        );
    }

    #[test]
    fn the_quiet_timer_speaks_after_a_wait_without_messages() {
        let (work, mut solver) = mpsc::channel::<Work>(8);
        let waiting = Cell::new(Some(Instant::now()));
        runtime().expect("runtime").block_on(async {
            tokio::select! {
                () = tokio::time::sleep(POLL * 3) => {}
                () = quiet(&waiting, &work) => {}
            }
        });
        assert!(matches!(solver.try_recv(), Ok(Work::Quiet)));
    }
}
