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
//! it (`handoff`), its plans handed back to the runtime: the two drivers
//! share the core and the loop, and differ in how they wait (a quiet input comes from the
//! runtime's timer here, from the source's own timeout there) and in the send call.

use std::sync::atomic::AtomicBool;

use tokio::sync::mpsc;

use super::blocking::drive;
use super::handoff::{CHANNEL, Handed, Handing, Work, feed};
use super::runtime;
use super::side_inputs::SideInputs;
use crate::msgs::HeatMaps;
use crate::nodes::errors::ServiceError;
use crate::nodes::estimator::EstimatorNode;
use crate::nodes::estimator::core::{Clock, EstimatorCore, EstimatorReport};
use crate::nodes::publish::{EstimatorOutputs, Plan};
use crate::transport::runtime::AsyncSource;

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
    source: impl AsyncSource<HeatMaps>,
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
        // Its end drops `work`, which ends the solver: it ends the tracks, sends its
        // last plan.
        let input = feed(source, work, stop);
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
