//! Per-frame latency in a fixed-size histogram: percentiles over any number of frames in
//! bounded memory (10 µs bins up to 100 ms, or [`LatencyHistogram::coarse`]: 100 µs bins
//! up to 1 s; slower frames land in the last bin and `max` keeps their exact value).

use std::time::Duration;

use serde::Serialize;

const BIN_NS: u64 = 10_000;
const BINS: usize = 10_000;

/// A histogram of durations.
#[derive(Debug, Clone)]
pub struct LatencyHistogram {
    bin_ns: u64,
    bins: Vec<u32>,
    count: u64,
    total_ns: u128,
    max_ns: u64,
}

impl Default for LatencyHistogram {
    fn default() -> Self {
        Self {
            bin_ns: BIN_NS,
            bins: vec![0; BINS],
            count: 0,
            total_ns: 0,
            max_ns: 0,
        }
    }
}

/// Summary of a [`LatencyHistogram`], milliseconds (percentiles to the bin's upper
/// edge, 0.01 ms).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct LatencySummary {
    /// Durations recorded.
    pub count: u64,
    /// Mean.
    pub mean_ms: f64,
    /// Median.
    pub median_ms: f64,
    /// 99th percentile.
    pub p99_ms: f64,
    /// Largest.
    pub max_ms: f64,
}

impl LatencyHistogram {
    /// A histogram of 100 µs bins up to 1 s (an image's way through the whole pipeline).
    pub fn coarse() -> Self {
        Self {
            bin_ns: 10 * BIN_NS,
            ..Self::default()
        }
    }

    /// Records one duration.
    pub fn record(&mut self, d: Duration) {
        let ns = u64::try_from(d.as_nanos()).unwrap_or(u64::MAX);
        let bin = usize::try_from(ns / self.bin_ns)
            .unwrap_or(BINS)
            .min(BINS - 1);
        self.bins[bin] = self.bins[bin].saturating_add(1);
        self.count += 1;
        self.total_ns += u128::from(ns);
        self.max_ns = self.max_ns.max(ns);
    }

    /// The smallest bin edge (ms) at or below which a fraction `q` of the durations lie.
    fn quantile_ms(&self, q: f64) -> f64 {
        let rank = ((q * self.count as f64).ceil() as u64).max(1);
        let mut seen = 0_u64;
        for (i, &n) in self.bins.iter().enumerate() {
            seen += u64::from(n);
            if seen >= rank {
                let edge = (i as u64 + 1) * self.bin_ns;
                return edge.min(self.max_ns) as f64 * 1e-6;
            }
        }
        self.max_ns as f64 * 1e-6
    }

    /// Count, mean, median, 99th percentile and maximum.
    pub fn summary(&self) -> LatencySummary {
        if self.count == 0 {
            return LatencySummary::default();
        }
        LatencySummary {
            count: self.count,
            mean_ms: self.total_ns as f64 / self.count as f64 * 1e-6,
            median_ms: self.quantile_ms(0.5),
            p99_ms: self.quantile_ms(0.99),
            max_ms: self.max_ns as f64 * 1e-6,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_follow_the_recorded_durations() {
        let mut h = LatencyHistogram::default();
        assert_eq!(h.summary(), LatencySummary::default());
        // 1..=100 ms in 1 ms steps, plus one far beyond the last bin.
        for ms in 1..=100 {
            h.record(Duration::from_millis(ms));
        }
        h.record(Duration::from_secs(3));
        let s = h.summary();
        assert_eq!(s.count, 101);
        assert!((s.median_ms - 51.0).abs() <= 0.011, "{s:?}");
        assert!((s.p99_ms - 100.0).abs() <= 0.011, "{s:?}");
        assert!((s.max_ms - 3000.0).abs() < 1e-9, "{s:?}");
        assert!(
            (s.mean_ms - (5050.0 + 3000.0) / 101.0).abs() < 1e-9,
            "{s:?}"
        );
    }
}

/// When each image came in, for the latency from an image to its newest skeletons
/// (`posestream run`): the image side notes each image's capture time as it takes the
/// decoded image ([`FrameClock::image_in`]); the output side, publishing a newest
/// (lag 0) skeleton of that capture time, records the time since
/// ([`FrameClock::skeleton_out`]). Cloned handles share it; it remembers the last
/// [`FrameClock::REMEMBERED`] images.
#[derive(Debug, Clone, Default)]
pub struct FrameClock(std::sync::Arc<std::sync::Mutex<ClockInner>>);

#[derive(Debug)]
struct ClockInner {
    taken: std::collections::VecDeque<(i64, std::time::Instant)>,
    latency: LatencyHistogram,
    /// When the first image came in.
    first_in: Option<std::time::Instant>,
}

impl Default for ClockInner {
    fn default() -> Self {
        Self {
            taken: std::collections::VecDeque::with_capacity(FrameClock::REMEMBERED),
            latency: LatencyHistogram::coarse(),
            first_in: None,
        }
    }
}

impl FrameClock {
    /// Images remembered at most.
    pub const REMEMBERED: usize = 64;

    fn lock(&self) -> std::sync::MutexGuard<'_, ClockInner> {
        self.0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// The image captured at `stamp_ns` came in now.
    pub fn image_in(&self, stamp_ns: i64) {
        let mut inner = self.lock();
        let now = std::time::Instant::now();
        inner.first_in.get_or_insert(now);
        if inner.taken.len() == Self::REMEMBERED {
            inner.taken.pop_front();
        }
        inner.taken.push_back((stamp_ns, now));
    }

    /// A newest skeleton of the image captured at `stamp_ns` goes out now: its latency
    /// is recorded (one per person).
    pub fn skeleton_out(&self, stamp_ns: i64) {
        let mut inner = self.lock();
        let taken = inner
            .taken
            .iter()
            .rev()
            .find(|(s, _)| *s == stamp_ns)
            .map(|(_, t)| *t);
        if let Some(t) = taken {
            inner.latency.record(t.elapsed());
        }
    }

    /// The latencies so far.
    pub fn summary(&self) -> LatencySummary {
        self.lock().latency.summary()
    }

    /// When the first image came in (`None` before one did).
    pub fn first_in(&self) -> Option<std::time::Instant> {
        self.lock().first_in
    }
}
