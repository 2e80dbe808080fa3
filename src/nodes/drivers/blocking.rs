//! The blocking driver: a loop that waits on a lending source (iceoryx2 samples read
//! where they are, a recording) and moves what comes to the estimator's core, and the
//! core's plans to an [`Outlet`]: the sinks, on this thread ([`run_estimator_with`]), or
//! the runtime's sending (the tokio driver runs the same loop on its solver thread).

use std::sync::atomic::{AtomicBool, Ordering};

use super::POLL;
use super::side_inputs::SideInputs;
use crate::nodes::estimator::EstimatorNode;
use crate::nodes::estimator::core::{Clock, EstimatorCore, EstimatorReport, Flow, Input};
use crate::nodes::publish::{EstimatorOutputs, Plan, Sinks};
use crate::transport::FrameSource;

/// Where a driver's plans go.
pub(super) trait Outlet {
    /// Sends `plan` (it comes back empty, to be written over); false once nothing takes
    /// plans any more.
    fn send(&mut self, core: &mut EstimatorCore<'_>, plan: &mut Plan) -> bool;
}

impl Outlet for Sinks {
    fn send(&mut self, core: &mut EstimatorCore<'_>, plan: &mut Plan) -> bool {
        Sinks::send(self, plan);
        core.recycle(plan);
        true
    }
}

/// The loop: what `source` lends (and what waits in `side`, taken before each input, or
/// after a wait that lent nothing) through `core`, its plans to `outlet`, until the source ends or
/// `stop` is set; then the tracks' last estimates.
pub(super) fn drive(
    core: &mut EstimatorCore<'_>,
    mut clock: Clock,
    source: &mut dyn FrameSource,
    side: &mut SideInputs,
    outlet: &mut dyn Outlet,
    stop: &AtomicBool,
) {
    let mut plan = Plan::default();
    while !stop.load(Ordering::Relaxed) {
        let mut lent_any = false;
        let got = source.recv_input(POLL, &mut |lent, stamp| {
            side.take(&mut |input| step(core, &mut clock, input, &mut plan));
            step(core, &mut clock, Input::lent(lent, stamp), &mut plan);
            lent_any = true;
        });
        if !lent_any {
            side.take(&mut |input| step(core, &mut clock, input, &mut plan));
        }
        let flow = core.received(got, clock.now(&Input::Quiet), &mut plan);
        if plan.is_empty() {
            core.recycle(&mut plan);
        } else if !outlet.send(core, &mut plan) {
            return;
        }
        if flow == Flow::End {
            break;
        }
    }
    core.close(&mut plan);
    outlet.send(core, &mut plan);
}

/// One input to the core at its time on `clock`.
fn step(core: &mut EstimatorCore<'_>, clock: &mut Clock, input: Input<'_>, plan: &mut Plan) {
    let now = clock.now(&input);
    core.step(input, now, plan);
}

/// Heat maps from `source` through `node` to `outputs`, until the source closes or
/// `stop` is set, on this thread; what waits in `side` (the camera's calibration and
/// transforms beside a source that does not carry them) is taken before each input. Each
/// frame is handled where the source lends it (an iceoryx2 sample is not copied before
/// the window).
pub fn run_estimator_with(
    node: &mut EstimatorNode,
    source: &mut dyn FrameSource,
    side: &mut SideInputs,
    outputs: &mut EstimatorOutputs,
    stop: &AtomicBool,
) -> EstimatorReport {
    let clock = Clock::of(source.live());
    let EstimatorOutputs { planner, sinks } = outputs;
    let mut core = EstimatorCore::new(node, planner);
    drive(&mut core, clock, source, side, sinks, stop);
    sinks.flush();
    core.report(sinks)
}

/// [`run_estimator_with`] with nothing beside the frames.
pub fn run_estimator(
    node: &mut EstimatorNode,
    source: &mut dyn FrameSource,
    outputs: &mut EstimatorOutputs,
    stop: &AtomicBool,
) -> EstimatorReport {
    run_estimator_with(node, source, &mut SideInputs::default(), outputs, stop)
}
