//! The nodes with their I/O on a tokio runtime. The estimator
//! ([`run_estimator_on_runtime`]): the input, the idle timer and the publishing wait on
//! one runtime thread, and the math runs on a thread of its own, fed through bounded
//! channels:
//!
//! ```text
//!  runtime (this thread)                      thread "solver"
//!  source ─► input ──► work (bounded, 4) ───► EstimatorNode ─┐
//!            timer ─┘                                         │
//!  sinks ◄── output ◄── skeletons (bounded, 4) ◄──────────────┘
//!                  └──► spent messages back to the node (reused)
//! ```
//!
//! A full channel makes the side before it wait: a slow solver slows the reading, a
//! slow output slows the solver, as the blocking loop ([`run_estimator`]) does. What
//! the runtime adds is a place for more than one thing to wait on (inputs, timers,
//! publishers that wait for room without blocking); what it costs is one hand-over
//! between threads per frame and per batch of skeletons (docs/services.md, "Where the
//! I/O runs").
//!
//! The detector ([`run_detector_on_runtime`]): its source (the image detector with its
//! frames, or a recording) runs on a thread of its own ([`Blocking`]); the runtime
//! paces the heat maps and publishes them.
//!
//! [`run_estimator`]: super::run_estimator

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use tokio::sync::mpsc;

use super::side_inputs::SideInputs;
use super::{
    DetectorReport, EstimatorInput, EstimatorOutputs, EstimatorReport, POLL, Publishers,
    ServiceError, due_wait,
};
use crate::floor::FloorModel;
use crate::msgs::{HeatMaps, Skeleton3D};
use crate::nodes::config::ReplayRate;
use crate::nodes::latency::LatencyHistogram;
use crate::nodes::{EstimatorNode, Refusals};
use crate::transport::runtime::{AsyncSource, Blocking};
use crate::transport::{Received, TransportError};

/// Frames (or batches of skeletons) waiting between the runtime and the solver at most.
const CHANNEL: usize = 4;

/// What the runtime hands the solver.
enum Work {
    /// A heat-map message and its source's stamp.
    Frame(HeatMaps, u64),
    /// A message the source refused.
    Refused(TransportError),
    /// Time to look at the idle track (every [`POLL`]).
    Tick,
}

/// An interval of [`POLL`] whose late ticks are not made up for.
fn every_poll() -> tokio::time::Interval {
    let mut tick = tokio::time::interval(POLL);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    tick
}

/// Returns once `stop` is set, looking every [`POLL`].
async fn stopped(stop: &AtomicBool) {
    let mut tick = every_poll();
    while !stop.load(Ordering::Relaxed) {
        tick.tick().await;
    }
}

/// Offers the solver a [`Work::Tick`] (its idle timer) every [`POLL`]: a full channel
/// gives it work enough. Returns once the solver is gone (it panicked), so that a
/// quiet input does not hide that.
async fn ticking(ticks: &mpsc::Sender<Work>) {
    let mut tick = every_poll();
    loop {
        tick.tick().await;
        if let Err(mpsc::error::TrySendError::Closed(_)) = ticks.try_send(Work::Tick) {
            return;
        }
    }
}

/// Skeletons released by one frame, with that frame's stamp.
struct Batch {
    skeletons: Vec<Skeleton3D>,
    released_at: u64,
    /// Capture time and frame number of the image whose heat maps released them
    /// (`None`: released by no message, as at the end).
    image: Option<(i64, u64)>,
    /// The images' size, when the node knows it (REP-155's image messages need it).
    image_size: Option<(f64, f64)>,
    /// The floor the skeletons stand on, when the node knows it (their footprints).
    floor: Option<FloorModel>,
}

/// What the solver thread counted.
struct Solved {
    frames: u64,
    latency: LatencyHistogram,
}

/// Heat maps from `source` through `node` to `outputs`, as [`run_estimator`] does (the
/// same report; a live track idle for the window's `max_gap_seconds` is finished), with
/// the I/O on a tokio runtime on this thread and `node` on a thread named `solver`.
/// Errors only if the runtime cannot start or the solver thread dies.
///
/// [`run_estimator`]: super::run_estimator
pub fn run_estimator_on_runtime(
    node: &mut EstimatorNode,
    source: impl AsyncSource<HeatMaps>,
    outputs: &mut EstimatorOutputs,
    stop: &AtomicBool,
) -> Result<EstimatorReport, ServiceError> {
    run_estimator_on_runtime_with(node, source, SideInputs::default(), outputs, stop)
}

/// [`run_estimator_on_runtime`], the node also taking what comes in `side` (the
/// camera's calibration, transforms): the solver thread takes what waits there before
/// each frame.
pub fn run_estimator_on_runtime_with(
    node: &mut EstimatorNode,
    mut source: impl AsyncSource<HeatMaps>,
    side: SideInputs,
    outputs: &mut EstimatorOutputs,
    stop: &AtomicBool,
) -> Result<EstimatorReport, ServiceError> {
    let runtime = runtime()?;
    let (work, work_rx) = mpsc::channel::<Work>(CHANNEL);
    let (done, mut done_rx) = mpsc::channel::<Batch>(CHANNEL);
    let (spent, spent_rx) = std::sync::mpsc::channel::<Vec<Skeleton3D>>();
    let (solved, input_error) = std::thread::scope(|scope| {
        let node = &mut *node;
        let solver = std::thread::Builder::new()
            .name("solver".into())
            .spawn_scoped(scope, move || solve(node, side, work_rx, done, spent_rx))
            .map_err(|_| ServiceError::Thread("solver"))?;
        let input = async move {
            let ticks = work.clone();
            let reading = async {
                // A stop ends the wait for the next message (a source in the middle of
                // one, pacing or publishing it, is cut off there: see
                // `AsyncSource::next`); a message already taken still goes to the
                // solver.
                let stopping = stopped(stop);
                tokio::pin!(stopping);
                loop {
                    let got = tokio::select! {
                        // A source that always has a message does not delay a stop.
                        biased;
                        () = &mut stopping => return None,
                        got = source.next() => got,
                    };
                    let next = match got {
                        Ok(Received::Message(maps, stamp)) => Work::Frame(maps, stamp),
                        Ok(Received::Idle) => continue,
                        Ok(Received::Closed) => return None,
                        Err(
                            e @ (TransportError::Malformed { .. }
                            | TransportError::BeyondLimits { .. }),
                        ) => Work::Refused(e),
                        // Reported by the caller, from the report.
                        Err(e) => return Some(e.to_string()),
                    };
                    // The solver gone (it panicked) ends the input; the join says why.
                    if work.send(next).await.is_err() {
                        return None;
                    }
                }
            };
            tokio::select! {
                input_error = reading => input_error,
                // The solver gone: the join below says why.
                () = ticking(&ticks) => None,
            }
            // Dropping the senders ends the solver: it finishes the track, closes `done`.
        };
        let output = async {
            loop {
                let batch = match tokio::time::timeout(POLL, done_rx.recv()).await {
                    Ok(Some(batch)) => batch,
                    Ok(None) => break,
                    // Nothing for a while: the image handled last is complete.
                    Err(_) => {
                        outputs.flush_arrays_async().await;
                        continue;
                    }
                };
                outputs.frame_stamp(batch.released_at);
                outputs
                    .publish_async(batch.image, &batch.skeletons, batch.image_size, batch.floor)
                    .await;
                // Back to the node, to be written over (the solver may be gone).
                let _ = spent.send(batch.skeletons);
            }
            outputs.flush_arrays_async().await;
            outputs.flush();
        };
        let (input_error, ()) = runtime.block_on(async { tokio::join!(input, output) });
        let solved = solver.join().map_err(|_| ServiceError::Thread("solver"))?;
        Ok::<_, ServiceError>((solved, input_error))
    })?;
    Ok(EstimatorReport {
        frames: solved.frames,
        malformed: node.malformed(),
        refused: node.refused().clone(),
        skeletons: outputs.skeletons.sent,
        failed_sends: outputs.failed_sends(),
        counters: node.counters(),
        metric_failures: node.metric_failures(),
        metric: node.metric_timing(),
        update: solved.latency.summary(),
        input_error,
        unknown_id_tracks: node.tracks_from_unknown_ids(),
        learnt_floor: node.learnt_floor(),
    })
}

/// The solver thread: each frame through `node`, the skeletons it releases to `done`,
/// until `work` closes; then the track's last estimates.
fn solve(
    node: &mut EstimatorNode,
    mut side: SideInputs,
    mut work: mpsc::Receiver<Work>,
    done: mpsc::Sender<Batch>,
    spent: std::sync::mpsc::Receiver<Vec<Skeleton3D>>,
) -> Solved {
    let idle_limit = Duration::from_secs_f64(node.settings().max_gap_seconds);
    let mut solved = Solved {
        frames: 0,
        latency: LatencyHistogram::default(),
    };
    // Emptied vectors of published batches, to carry the next ones.
    let mut vectors: Vec<Vec<Skeleton3D>> = Vec::new();
    let mut out = Vec::new();
    let (mut last_frame, mut open_track, mut released_at) = (Instant::now(), false, 0);
    let mut image = None;
    while let Some(next) = work.blocking_recv() {
        while let Ok(mut skeletons) = spent.try_recv() {
            node.recycle(&mut skeletons);
            vectors.push(skeletons);
        }
        match next {
            Work::Frame(maps, stamp) => {
                side.take(node);
                solved.frames += 1;
                released_at = stamp;
                image = Some((maps.header.stamp.nanos(), maps.sequence));
                let accepted = node.frames_accepted();
                let began = Instant::now();
                // A refused message is counted and logged by the node.
                let _ = node.handle_view(&maps.view(), &mut out);
                solved.latency.record(began.elapsed());
                // Only frames the window took keep a track alive.
                if node.frames_accepted() > accepted {
                    last_frame = Instant::now();
                    open_track = true;
                }
            }
            Work::Refused(e) => node.count_refused(&e),
            Work::Tick => {
                // A quiet input: the image handled last is complete (its people without
                // ids are given theirs and estimated).
                node.complete_image(&mut out);
                image = None;
            }
        }
        if open_track && last_frame.elapsed() > idle_limit {
            node.finish(&mut out);
            open_track = false;
        }
        if !out.is_empty() {
            let next = vectors.pop().unwrap_or_default();
            let skeletons = std::mem::replace(&mut out, next);
            if done
                .blocking_send(Batch {
                    skeletons,
                    released_at,
                    image,
                    image_size: node.image_size(),
                    floor: node.floor(),
                })
                .is_err()
            {
                break;
            }
        }
    }
    node.finish(&mut out);
    if !out.is_empty() {
        // The output gone (it cannot be, short of a panic) loses only these.
        let _ = done.blocking_send(Batch {
            skeletons: out,
            released_at,
            image: None,
            image_size: node.image_size(),
            floor: node.floor(),
        });
    }
    solved
}

/// The estimator node over its configured input ([`EstimatorInput`]): on the runtime
/// ([`run_estimator_on_runtime`]) or in a blocking loop ([`run_estimator`]).
///
/// [`run_estimator`]: super::run_estimator
pub fn serve_estimator(
    node: &mut EstimatorNode,
    input: EstimatorInput,
    outputs: &mut EstimatorOutputs,
    stop: &AtomicBool,
) -> Result<EstimatorReport, ServiceError> {
    match input {
        EstimatorInput::Awaited { mut heatmaps, side } => {
            run_estimator_on_runtime_with(node, &mut *heatmaps, side, outputs, stop)
        }
        EstimatorInput::Lent(mut source, mut side) => Ok(super::run_estimator_with(
            node,
            &mut source,
            &mut side,
            outputs,
            stop,
        )),
    }
}

/// The detector's side on a runtime, as an [`AsyncSource`] of heat maps: the frames of
/// a source running on a thread of its own ([`Blocking`]), paced to their stamps
/// ([`ReplayRate::Recorded`]) and published to `sinks` as they are taken. Messages the
/// source refuses are counted here, and a broken source ends it (the error is in the
/// report), as in the blocking detector loop.
pub struct DetectorSide<'a> {
    source: Blocking<HeatMaps>,
    sinks: Publishers<HeatMaps>,
    rate: ReplayRate,
    stop: &'a AtomicBool,
    /// The wall time of the first frame and its stamp, for the pace.
    first: Option<(Instant, u64)>,
    refused: Refusals,
    input_error: Option<String>,
}

impl<'a> DetectorSide<'a> {
    /// Starts `source` on a thread of its own (named `posestream-detector`).
    pub fn spawn(
        source: impl crate::transport::Source<HeatMaps> + 'static,
        sinks: Publishers<HeatMaps>,
        rate: ReplayRate,
        stop: &'a AtomicBool,
    ) -> Result<Self, ServiceError> {
        Ok(Self {
            source: Blocking::spawn("detector", source, CHANNEL)?,
            sinks,
            rate,
            stop,
            first: None,
            refused: Refusals::default(),
            input_error: None,
        })
    }

    /// What the detector did so far (its source's thread ended, its sinks flushed:
    /// call once the side is done).
    pub fn conclude(mut self) -> DetectorReport {
        // The source's thread ends before the sinks and the middleware under them.
        drop(self.source);
        self.sinks.flush();
        DetectorReport {
            published: self.sinks.sent,
            malformed: self.refused.total(),
            failed_sends: self.sinks.failed,
            input_error: self.input_error,
            images: None,
        }
    }
}

impl AsyncSource<HeatMaps> for DetectorSide<'_> {
    async fn next(&mut self) -> Result<Received<HeatMaps>, TransportError> {
        loop {
            match self.source.next().await {
                Ok(Received::Message(maps, stamp)) => {
                    if self.rate == ReplayRate::Recorded {
                        let (start, first) = *self.first.get_or_insert((Instant::now(), stamp));
                        let due = Duration::from_nanos(stamp.saturating_sub(first));
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
                Ok(Received::Idle) => {}
                Ok(Received::Closed) => return Ok(Received::Closed),
                Err(e @ TransportError::Malformed { .. }) => self.refused.note("undecodable", &e),
                Err(e @ TransportError::BeyondLimits { .. }) => {
                    self.refused.note("beyond-limits", &e)
                }
                Err(e) => {
                    // Reported by the caller, from the report.
                    self.input_error = Some(e.to_string());
                    return Ok(Received::Closed);
                }
            }
        }
    }
}

/// Heat maps from `source` to `sinks`, as [`run_detector`] does (the same report), with
/// the source on a thread of its own and the pacing and publishing on a tokio runtime
/// on this thread ([`DetectorSide`]). Errors only if the runtime or the source's thread
/// cannot start.
///
/// [`run_detector`]: super::run_detector
pub fn run_detector_on_runtime(
    source: impl crate::transport::Source<HeatMaps> + 'static,
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

/// A runtime on this thread, with timers.
fn runtime() -> Result<tokio::runtime::Runtime, ServiceError> {
    tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
        .map_err(ServiceError::Runtime)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_idle_timer_ends_when_the_solver_is_gone() {
        let (ticks, solver) = mpsc::channel::<Work>(1);
        drop(solver);
        let ended = runtime()
            .expect("runtime")
            .block_on(async { tokio::time::timeout(POLL * 10, ticking(&ticks)).await });
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
}
