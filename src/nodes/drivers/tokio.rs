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
//! wait on (inputs, timers, ROS 2 publishers that wait for room without blocking).

use std::cell::Cell;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use tokio::sync::mpsc;

use super::POLL;
use super::blocking::step;
use crate::msgs::HeatMaps;
use crate::nodes::EstimatorNode;
use crate::nodes::drivers::side_inputs::SideInputs;
use crate::nodes::errors::ServiceError;
use crate::nodes::estimator::{Clock, EstimatorCore, EstimatorReport, Flow, Input};
use crate::nodes::publish::{EstimatorOutputs, Plan};
use crate::transport::recycle::Recycler;
use crate::transport::runtime::AsyncSource;
use crate::transport::{Received, TransportError};

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
    let recycler = source.recycler();
    let EstimatorOutputs { planner, sinks } = outputs;
    let core = std::thread::scope(|scope| {
        let solver = std::thread::Builder::new()
            .name("solver".into())
            .spawn_scoped(scope, move || {
                let mut core = EstimatorCore::new(node, planner);
                let inputs = Inputs {
                    clock: Clock::of(live),
                    side: &mut side,
                    recycler,
                };
                solve(&mut core, inputs, work_rx, plans, sent_rx);
                core
            })
            .map_err(|_| ServiceError::Thread("solver"))?;
        let input = async move {
            // When something came last: the quiet timer says so after POLL of nothing.
            let last = Cell::new(Instant::now());
            let reading = async {
                // A stop ends the wait for the next message (a source in the middle of
                // one is cut off there: see `AsyncSource::next`).
                let stopping = stopped(stop);
                tokio::pin!(stopping);
                loop {
                    let got = tokio::select! {
                        // A source that always has a message does not delay a stop.
                        biased;
                        () = &mut stopping => return,
                        got = source.next() => got,
                    };
                    last.set(Instant::now());
                    // The solver gone (it ended, or panicked) ends the input.
                    if work.send(Work::Got(got)).await.is_err() {
                        return;
                    }
                }
            };
            tokio::select! {
                () = reading => {}
                () = quiet(&last, &work) => {}
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

/// What the solver thread reads besides its work: the clock, the side inputs, and where
/// frames go back to once handled.
struct Inputs<'s> {
    clock: Clock,
    side: &'s mut SideInputs,
    recycler: Option<Recycler<HeatMaps>>,
}

/// The solver thread: each input through `core`, its plans to `plans`, until the input
/// ends; then the tracks' last estimates.
fn solve(
    core: &mut EstimatorCore<'_>,
    inputs: Inputs<'_>,
    mut work: mpsc::Receiver<Work>,
    plans: mpsc::Sender<Plan>,
    sent: std::sync::mpsc::Receiver<Plan>,
) {
    let Inputs {
        mut clock,
        side,
        recycler,
    } = inputs;
    let (mut plan, mut spare) = (Plan::default(), Vec::new());
    while let Some(next) = work.blocking_recv() {
        while let Ok(mut p) = sent.try_recv() {
            core.recycle(&mut p);
            spare.push(p);
        }
        side.take(&mut |input| step(core, &mut clock, input, &mut plan));
        let got = match next {
            Work::Got(got) => got.map(|r| {
                r.map(|maps, stamp| {
                    step(
                        core,
                        &mut clock,
                        Input::Frame(&maps.view(), stamp),
                        &mut plan,
                    );
                    if let Some(recycler) = &recycler {
                        recycler.put(maps);
                    }
                })
            }),
            Work::Quiet => Ok(Received::Idle),
        };
        let flow = core.received(got, clock.now(&Input::Quiet), &mut plan);
        if plan.is_empty() {
            core.recycle(&mut plan);
        } else {
            let next = spare.pop().unwrap_or_default();
            if plans
                .blocking_send(std::mem::replace(&mut plan, next))
                .is_err()
            {
                return;
            }
        }
        if flow == Flow::End {
            break;
        }
    }
    core.close(&mut plan);
    // The output gone (it cannot be, short of a panic) loses only these.
    let _ = plans.blocking_send(plan);
}

/// Offers the solver a [`Work::Quiet`] every [`POLL`] in which nothing came (since
/// `last`; a full channel gives it work enough). Returns once the solver is gone (it
/// ended, or panicked), so that a quiet input does not hide that.
async fn quiet(last: &Cell<Instant>, work: &mpsc::Sender<Work>) {
    let mut tick = tokio::time::interval(POLL);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tick.tick().await;
        if last.get().elapsed() >= POLL
            && let Err(mpsc::error::TrySendError::Closed(_)) = work.try_send(Work::Quiet)
        {
            return;
        }
    }
}

/// Returns once `stop` is set, looking every [`POLL`].
pub(super) async fn stopped(stop: &AtomicBool) {
    let mut tick = tokio::time::interval(POLL);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    while !stop.load(Ordering::Relaxed) {
        tick.tick().await;
    }
}

/// A runtime on this thread, with timers.
pub(super) fn runtime() -> Result<tokio::runtime::Runtime, ServiceError> {
    tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
        .map_err(ServiceError::Runtime)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_quiet_timer_ends_when_the_solver_is_gone() {
        let (work, solver) = mpsc::channel::<Work>(1);
        drop(solver);
        let last = Cell::new(Instant::now());
        let ended = runtime()
            .expect("runtime")
            .block_on(async { tokio::time::timeout(POLL * 10, quiet(&last, &work)).await });
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
    fn the_quiet_timer_says_nothing_while_messages_come() {
        let (work, mut solver) = mpsc::channel::<Work>(8);
        let last = Cell::new(Instant::now());
        runtime().expect("runtime").block_on(async {
            let feeding = async {
                for _ in 0..10 {
                    tokio::time::sleep(POLL / 4).await;
                    last.set(Instant::now());
                }
            };
            tokio::select! {
                () = feeding => {}
                () = quiet(&last, &work) => {}
            }
        });
        assert!(
            solver.try_recv().is_err(),
            "a quiet input while messages came"
        );
    }
}
