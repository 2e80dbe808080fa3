//! The searches as a stage of their own ([`Searches::Stage`]): a thread with its own
//! detectors, fed the newest frame (a queue of one: a frame still waiting when a newer
//! one comes is dropped, and counted), whose newest sightings the frames take when they
//! are ready: a frame where someone is followed never waits for a search (one where
//! nobody is, with nothing else to do, waits for its own). A stage that
//! fails (a detector's error, a panic) ends the run with that error at the next frame.
//!
//! The frame's pixels are shared (`Arc`), never copied.

use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;

use super::looks::Sighting;
use super::search::{SearchRequest, SearchStats, Searcher};
use super::{DetectorError, DetectorStats};
use crate::images::ImageFrame;

/// Where the searches run.
pub(super) enum Searches {
    /// On the frame's thread, when the tracker wants boxes.
    Inline(Box<Searcher>),
    /// On a thread of their own, all the time (every other frame while someone waits
    /// for a look).
    Stage(Stage),
}

/// A search's result.
pub(super) struct Done {
    /// The frame it searched.
    pub frame: u64,
    /// What it found there.
    pub sightings: Vec<Sighting>,
    /// What it (and any result it replaced, never taken) cost.
    pub stats: SearchStats,
}

#[derive(Default)]
struct State {
    /// The newest frame not yet searched.
    job: Option<(Arc<ImageFrame>, SearchRequest)>,
    /// The newest result not yet taken.
    done: Option<Done>,
    /// Why the stage stopped, if it failed.
    failed: Option<String>,
    /// The frames dropped unsearched (a newer one came first).
    dropped: u64,
    stop: bool,
}

struct Shared {
    state: Mutex<State>,
    /// A job or the stop came.
    wake: Condvar,
    /// A result or a failure came.
    finished: Condvar,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        // A panic while holding the lock is the stage's own, caught below; the state
        // stays consistent (plain fields).
        self.state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

/// The search thread and what it shares with the frames.
pub(super) struct Stage {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

impl Stage {
    /// Starts the thread with `searcher` (its runs one after another).
    pub(super) fn start(mut searcher: Searcher) -> Result<Self, DetectorError> {
        searcher.parallel = false;
        let shared = Arc::new(Shared {
            state: Mutex::new(State::default()),
            wake: Condvar::new(),
            finished: Condvar::new(),
        });
        let theirs = shared.clone();
        let thread = std::thread::Builder::new()
            .name("posestream-search".into())
            .spawn(move || run(&theirs, &mut searcher))
            .map_err(|e| DetectorError::Settings(format!("cannot start the search thread: {e}")))?;
        Ok(Self {
            shared,
            thread: Some(thread),
        })
    }

    /// Gives `frame` to the stage (instead of a frame still waiting, which is dropped).
    pub(super) fn submit(&self, frame: Arc<ImageFrame>, request: SearchRequest) {
        let mut state = self.shared.lock();
        if state.job.replace((frame, request)).is_some() {
            state.dropped += 1;
        }
        drop(state);
        self.shared.wake.notify_one();
    }

    /// The newest result not yet taken, if any; the stage's failure as an error.
    pub(super) fn take(&self) -> Result<Option<Done>, DetectorError> {
        let mut state = self.shared.lock();
        if let Some(why) = &state.failed {
            return Err(DetectorError::SearchStage(why.clone()));
        }
        Ok(state.done.take())
    }

    /// Waits for the result of frame `frame` (or a later one).
    pub(super) fn wait_for(&self, frame: u64) -> Result<Done, DetectorError> {
        let mut state = self.shared.lock();
        loop {
            if let Some(why) = &state.failed {
                return Err(DetectorError::SearchStage(why.clone()));
            }
            if state.done.as_ref().is_some_and(|d| d.frame >= frame) {
                return Ok(state.done.take().expect("a result"));
            }
            state = self
                .shared
                .finished
                .wait(state)
                .unwrap_or_else(std::sync::PoisonError::into_inner);
        }
    }

    /// Frames dropped unsearched so far.
    pub(super) fn dropped(&self) -> u64 {
        self.shared.lock().dropped
    }
}

impl Drop for Stage {
    fn drop(&mut self) {
        self.shared.lock().stop = true;
        self.shared.wake.notify_all();
        if let Some(thread) = self.thread.take() {
            // A panic was caught in `run`: nothing more to say here.
            let _ = thread.join();
        }
    }
}

/// The thread: the newest frame searched, its result kept for the frames, until the
/// stop or a failure.
fn run(shared: &Shared, searcher: &mut Searcher) {
    loop {
        let (frame, request) = {
            let mut state = shared.lock();
            loop {
                if state.stop {
                    return;
                }
                if let Some(job) = state.job.take() {
                    break job;
                }
                state = shared
                    .wake
                    .wait(state)
                    .unwrap_or_else(std::sync::PoisonError::into_inner);
            }
        };
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            searcher.search(&frame, request)
        }));
        drop(frame);
        let mut state = shared.lock();
        match result {
            Ok(Ok((sightings, stats))) => {
                let stats = match state.done.take() {
                    Some(untaken) => stats.merged(&untaken.stats),
                    None => stats,
                };
                state.done = Some(Done {
                    frame: request.frame,
                    sightings,
                    stats,
                });
            }
            Ok(Err(e)) => state.failed = Some(e.to_string()),
            Err(panic) => {
                let what = panic
                    .downcast_ref::<&str>()
                    .map(|s| (*s).to_string())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "a panic".into());
                state.failed = Some(format!("the search thread panicked: {what}"));
            }
        }
        let failed = state.failed.is_some();
        drop(state);
        shared.finished.notify_all();
        if failed {
            return;
        }
    }
}

impl Searches {
    /// The sightings for frame `request.frame` of `frame`, if any, and whether they come
    /// from a search (else the tracker's schedule wants none this frame). Inline: a
    /// search now when `wanted`. Stage: this frame goes to the stage (but every other
    /// crowded frame the tracker does not want boxes for: `SearchRequest::crowded`), and
    /// the newest result ready is taken (a scene's first frame, and one where nobody is
    /// followed, waits for its own, and always goes to the stage).
    pub(super) fn sightings(
        &mut self,
        frame: &Arc<ImageFrame>,
        request: SearchRequest,
        wanted: bool,
        stats: &mut DetectorStats,
    ) -> Result<Option<Vec<Sighting>>, DetectorError> {
        match self {
            Self::Inline(searcher) => {
                if !wanted {
                    return Ok(None);
                }
                let (sightings, cost) = searcher.search(frame, request)?;
                cost.add_to(stats);
                Ok(Some(sightings))
            }
            Self::Stage(stage) => {
                // A crowded frame rests the stage every other frame, unless it is to
                // wait for its search (below) or the tracker wants boxes.
                let waits = request.scene_first || !request.followed;
                let rests = request.crowded && !waits && !wanted && request.frame % 2 == 1;
                if !rests {
                    stage.submit(frame.clone(), request);
                }
                // A frame where nobody is followed has nothing to do but wait for its
                // search (a file's frames would otherwise race past the searches).
                let done = if waits {
                    Some(stage.wait_for(request.frame)?)
                } else {
                    stage.take()?
                };
                stats.searches_dropped = stage.dropped();
                Ok(done.map(|d| {
                    d.stats.add_to(stats);
                    stats.search_lag_frames += request.frame.saturating_sub(d.frame);
                    d.sightings
                }))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(width: u32, sequence: u64) -> Arc<ImageFrame> {
        Arc::new(ImageFrame {
            sequence,
            stamp_ns: 0,
            frame_id: "camera".into(),
            name: format!("frame {sequence}"),
            rgb: image::RgbImage::new(width, 8),
        })
    }

    fn request(frame: u64, followed: bool) -> SearchRequest {
        SearchRequest {
            frame,
            scene_first: frame == 1,
            followed,
            crowded: false,
        }
    }

    #[test]
    fn frames_take_the_newest_search_and_a_dead_stage_ends_the_run() {
        // Without detectors a search finds the whole region: one sighting a frame.
        let searcher = Searcher {
            panic_at_width: Some(13),
            ..Searcher::default()
        };
        let mut searches = Searches::Stage(Stage::start(searcher).expect("starts"));
        let mut stats = DetectorStats::default();
        // A scene's first frame waits for its own search.
        let first = searches
            .sightings(&frame(16, 0), request(1, false), true, &mut stats)
            .expect("searched");
        assert_eq!(first.map(|s| s.len()), Some(1));
        assert_eq!(stats.searches, 1);
        // Frames where someone is followed never wait: what is ready, or nothing.
        for n in 2..49 {
            searches
                .sightings(&frame(16, n), request(n, true), false, &mut stats)
                .expect("no error");
        }
        // Nobody followed: the newest frame waits for its own search.
        let last = searches
            .sightings(&frame(16, 49), request(49, false), false, &mut stats)
            .expect("the newest frame is searched");
        assert_eq!(last.map(|s| s.len()), Some(1));
        // Every frame was searched or dropped for a newer one, never queued (a result
        // no frame took is counted with the next one's).
        assert_eq!(stats.searches + stats.searches_dropped, 49, "{stats:?}");
        // A search that panics: the frame waiting for it gets the error, and every one
        // after.
        let e = searches
            .sightings(&frame(13, 50), request(50, false), true, &mut stats)
            .expect_err("the stage died");
        assert!(e.to_string().contains("a search that dies"), "{e}");
        assert!(matches!(
            searches.sightings(&frame(16, 52), request(52, true), false, &mut stats),
            Err(DetectorError::SearchStage(_))
        ));
    }

    #[test]
    fn a_crowded_frame_rests_the_stage_every_other_frame_unless_boxes_are_wanted() {
        let mut searches = Searches::Stage(Stage::start(Searcher::default()).expect("starts"));
        let mut stats = DetectorStats::default();
        searches
            .sightings(&frame(16, 0), request(1, false), true, &mut stats)
            .expect("searched");
        // Crowded frames 2..=41: the odd ones rest (20 of them) but frame 11, whose
        // boxes the tracker wants.
        for n in 2..42 {
            let crowded = SearchRequest {
                crowded: true,
                ..request(n, true)
            };
            searches
                .sightings(&frame(16, n), crowded, n == 11, &mut stats)
                .expect("no error");
        }
        // Nobody followed: waits for its own search (submitted whatever the crowd).
        let last = SearchRequest {
            crowded: true,
            ..request(42, false)
        };
        searches
            .sightings(&frame(16, 42), last, false, &mut stats)
            .expect("the newest frame is searched");
        // Submitted: frame 1, the 20 even frames of 2..=41, frame 11 and frame 42.
        assert_eq!(stats.searches + stats.searches_dropped, 23, "{stats:?}");
    }
}
