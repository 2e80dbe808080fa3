//! The tokio driver: the input, the quiet timer and the sending wait on a runtime on
//! this thread; the estimator's core runs on a thread of its own (`solver`), fed through
//! bounded channels:
//!
//! ```text
//!  runtime (this thread)                   thread "solver"
//!  source ─► input ──► work (bounded, 4) ─► EstimatorCore ─┐
//!            quiet ─┘                                       │
//!  sinks ◄── send_async ◄── plans (bounded, 4) ◄────────────┘
//!                      └──► sent plans back to the core (reused)
//! ```
//!
//! A full channel makes the side before it wait: a slow core slows the reading, slow
//! sinks slow the core. What the runtime adds is a place for more than one thing to
//! wait on (inputs, timers, ROS 2 publishers that wait for room without blocking). The
//! solver runs the blocking driver's loop (`blocking::drive`) over what the runtime hands
//! it ([`Handed`]), its plans handed back to the runtime ([`Handing`]): the two drivers
//! share the core and the loop, and differ in how they wait (a quiet input comes from the
//! runtime's timer here, from the source's own timeout there) and in the send call.

use std::cell::Cell;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use tokio::sync::mpsc;

use super::blocking::{Outlet, drive};
use super::side_inputs::SideInputs;
use super::{POLL, runtime, stopped};
use crate::msgs::{HeatMaps, HeatMapsView};
use crate::nodes::errors::ServiceError;
use crate::nodes::estimator::EstimatorNode;
use crate::nodes::estimator::core::{Clock, EstimatorCore, EstimatorReport};
use crate::nodes::publish::{EstimatorOutputs, Plan};
use crate::transport::recycle::Recycler;
use crate::transport::runtime::AsyncSource;
use crate::transport::{FrameSource, Lent, Received, TransportError};
use posestream_base::ended;

/// Inputs (or plans) waiting between the runtime and the solver at most.
const CHANNEL: usize = 4;

/// What the runtime hands the solver.
enum Work {
    /// What the source gave.
    Got(Result<Received<HeatMaps>, TransportError>),
    /// Nothing came for a while.
    Quiet,
}

/// Heat maps from `source` through `node` to `outputs`, as the blocking driver does (the
/// same core, the same report), a live source's time on the wall clock.
pub fn run_estimator_on_runtime(
    node: &mut EstimatorNode,
    source: impl AsyncSource<HeatMaps>,
    outputs: &mut EstimatorOutputs,
    stop: &AtomicBool,
) -> Result<EstimatorReport, ServiceError> {
    run_estimator_on_runtime_with(node, source, SideInputs::default(), true, outputs, stop)
}

/// [`run_estimator_on_runtime`], the core also taking what waits in `side` (the camera's
/// calibration, transforms) before each input, on the clock of a `live` source (wall
/// time) or a replayed one (its stamps). Errors only if the runtime cannot start or the
/// solver thread dies.
pub fn run_estimator_on_runtime_with(
    node: &mut EstimatorNode,
    mut source: impl AsyncSource<HeatMaps>,
    mut side: SideInputs,
    live: bool,
    outputs: &mut EstimatorOutputs,
    stop: &AtomicBool,
) -> Result<EstimatorReport, ServiceError> {
    let runtime = runtime()?;
    let (work, work_rx) = mpsc::channel::<Work>(CHANNEL);
    let (plans, mut plans_rx) = mpsc::channel::<Plan>(CHANNEL);
    let (sent, sent_rx) = std::sync::mpsc::channel::<Plan>();
    // The frames handed back once handled: the source decodes the next ones over them.
    let keep = node.limits().max_message_bytes;
    let mut handed = Handed(work_rx, source.recycler().map(|r| (r, keep)), live);
    let EstimatorOutputs { planner, sinks } = outputs;
    let core = std::thread::scope(|scope| {
        let solver = std::thread::Builder::new()
            .name("solver".into())
            .spawn_scoped(scope, move || {
                let mut core = EstimatorCore::new(node, planner);
                let mut handing = Handing(plans, sent_rx, Vec::new());
                // The input's end (the channel closed) ends the loop, not a stop: what
                // was taken before is solved and sent.
                let go_on = AtomicBool::new(false);
                let clock = Clock::of(live);
                drive(
                    &mut core,
                    clock,
                    &mut handed,
                    &mut side,
                    &mut handing,
                    &go_on,
                );
                core
            })
            .map_err(|_| ServiceError::Thread("solver"))?;
        let input = async move {
            // Since when the reader has waited for a message (kept over refused ones;
            // none while it hands one over): the quiet timer says so after POLL of it.
            let waiting = Cell::new(None);
            let reading = async {
                // A stop ends the wait for the next message (a source in the middle of
                // one is cut off there: see `AsyncSource::next`).
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
                    // The solver gone (it ended, or panicked) ends the input; so does the
                    // source's end (it is not asked again).
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
            // Dropping the sender ends the solver: it ends the tracks, sends its last plan.
        };
        let output = async {
            while let Some(plan) = plans_rx.recv().await {
                sinks.send_async(&plan).await;
                // Back to the core, to be written over (the solver may be gone).
                let _ = sent.send(plan);
            }
            sinks.flush();
        };
        runtime.block_on(async { tokio::join!(input, output) });
        solver.join().map_err(|_| ServiceError::Thread("solver"))
    })?;
    Ok(core.report(&outputs.sinks))
}

/// What the runtime hands the solver, as a lending source: each frame lent, then given
/// back to the source's recycler (when it has one; a frame whose scores take more than
/// the given bytes, one the node refuses as too large, is freed instead); whether the
/// source is live.
struct Handed(
    mpsc::Receiver<Work>,
    Option<(Recycler<HeatMaps>, usize)>,
    bool,
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
struct Handing(
    mpsc::Sender<Plan>,
    std::sync::mpsc::Receiver<Plan>,
    Vec<Plan>,
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
    fn the_wait_for_a_stop_ends_once_it_is_set() {
        let stop = AtomicBool::new(true);
        let ended = runtime()
            .expect("runtime")
            .block_on(async { tokio::time::timeout(POLL * 10, stopped(&stop)).await });
        assert!(ended.is_ok());
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
