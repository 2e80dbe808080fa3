//! The blocking driver: a loop that waits on a lending source (iceoryx2 samples read
//! where they are, a recording) and moves what comes to the estimator's core, then its
//! plan to the sinks, on this thread.

use std::sync::atomic::{AtomicBool, Ordering};

use super::POLL;
use super::side_inputs::SideInputs;
use crate::nodes::EstimatorNode;
use crate::nodes::estimator::{Clock, EstimatorCore, EstimatorReport, Flow, Input};
use crate::nodes::publish::{EstimatorOutputs, Plan};
use crate::transport::FrameSource;

/// Heat maps from `source` through `node` to `outputs`, until the source closes or
/// `stop` is set; what waits in `side` (the camera's calibration and transforms beside a
/// source that does not carry them) is taken before each wait. Each frame is handled
/// where the source lends it (an iceoryx2 sample is not copied before the window).
pub fn run_estimator_with(
    node: &mut EstimatorNode,
    source: &mut dyn FrameSource,
    side: &mut SideInputs,
    outputs: &mut EstimatorOutputs,
    stop: &AtomicBool,
) -> EstimatorReport {
    let mut clock = Clock::of(source.live());
    let EstimatorOutputs { planner, sinks } = outputs;
    let mut core = EstimatorCore::new(node, planner);
    let mut plan = Plan::default();
    while !stop.load(Ordering::Relaxed) {
        side.take(&mut |input| step(&mut core, &mut clock, input, &mut plan));
        let got = source.recv_input(POLL, &mut |lent, stamp| {
            step(&mut core, &mut clock, Input::lent(lent, stamp), &mut plan)
        });
        let flow = core.received(got, clock.now(&Input::Quiet), &mut plan);
        sinks.send(&plan);
        core.recycle(&mut plan);
        if flow == Flow::End {
            break;
        }
    }
    core.close(&mut plan);
    sinks.send(&plan);
    core.recycle(&mut plan);
    sinks.flush();
    core.report(sinks)
}

/// One input to the core at its time on `clock`.
pub(super) fn step(
    core: &mut EstimatorCore<'_>,
    clock: &mut Clock,
    input: Input<'_>,
    plan: &mut Plan,
) {
    let now = clock.now(&input);
    core.step(input, now, plan);
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
