//! Who comes back: the looks of ended tracks, remembered for a while and bounded in
//! number, and the cost of a newcomer being someone lost or remembered (their looks'
//! distance, gated by where that person could have gone since they were last seen).

use std::collections::VecDeque;

use super::centre_side;
use crate::appearance::Appearance;
use posestream_base::CropBox;

/// A newcomer's box side may be this factor off the person's last box and still be
/// them (nearer or farther from the camera).
const SIZE_RATIO: f64 = 1.6;
/// Where a person may be after `s` seconds gone: within `REACH_BASE + REACH_PER_SECOND *
/// s` of their box's side from where they were last seen (walking covers about their
/// box's side a second).
const REACH_BASE: f64 = 0.75;
const REACH_PER_SECOND: f64 = 1.0;
/// The part of a newcomer's cost that is how far they are from where the person was
/// (over the reach): nearer wins between two alike.
const MOVE_WEIGHT: f64 = 0.1;

/// An ended track that may come back.
#[derive(Debug, Clone)]
pub(super) struct Remembered {
    pub(super) id: u32,
    /// Its place in the order of births.
    pub(super) born: u64,
    /// Where it was last seen, and when (ns).
    pub(super) region: CropBox,
    pub(super) seen_ns: u64,
    pub(super) look: Appearance,
}

/// The ended tracks remembered, oldest first.
#[derive(Debug, Clone, Default)]
pub(super) struct Memory {
    people: VecDeque<Remembered>,
}

impl Memory {
    /// Forgets everyone.
    pub(super) fn clear(&mut self) {
        self.people.clear();
    }

    /// Forgets those last seen more than `seconds` before `now_ns`.
    pub(super) fn forget_before(&mut self, now_ns: u64, seconds: f64) {
        let kept_ns = seconds * 1e9;
        self.people
            .retain(|r| (now_ns.saturating_sub(r.seen_ns) as f64) <= kept_ns);
    }

    /// Remembers `person`, forgetting the oldest while more than `capacity` are
    /// remembered; returns how many were forgotten (a capacity of 0 remembers nobody).
    pub(super) fn remember(&mut self, person: Remembered, capacity: usize) -> u64 {
        self.people.push_back(person);
        let mut forgotten = 0;
        while self.people.len() > capacity {
            self.people.pop_front();
            forgotten += 1;
        }
        forgotten
    }

    /// Whether `id` is remembered.
    pub(super) fn holds(&self, id: u32) -> bool {
        self.people.iter().any(|r| r.id == id)
    }

    /// The remembered person a newcomer looking like `look` at `region` (now) most
    /// likely is, and the cost ([`cost`]); `None` if nobody passes the gates.
    pub(super) fn best(
        &self,
        look: &Appearance,
        region: &CropBox,
        now_ns: u64,
        gate: f64,
    ) -> Option<(usize, f64)> {
        self.people
            .iter()
            .enumerate()
            .filter_map(|(i, r)| {
                let c = cost(&r.look, &r.region, r.seen_ns, look, region, now_ns, gate)?;
                Some((i, c))
            })
            .min_by(|a, b| a.1.total_cmp(&b.1))
    }

    /// Takes the `i`th remembered person out (they came back).
    pub(super) fn take(&mut self, i: usize) -> Option<Remembered> {
        self.people.remove(i)
    }

    /// How many are remembered.
    pub(super) fn len(&self) -> usize {
        self.people.len()
    }
}

/// The cost of a newcomer looking like `look` at `region` (at `now_ns`) being a person
/// who looked like `model` and was last seen at `last` (at `seen_ns`): their looks'
/// distance plus a little of how far they moved; `None` where the looks are more than
/// `gate` apart, the boxes' sizes unlike, or the newcomer farther than the person could
/// have gone.
pub(super) fn cost(
    model: &Appearance,
    last: &CropBox,
    seen_ns: u64,
    look: &Appearance,
    region: &CropBox,
    now_ns: u64,
    gate: f64,
) -> Option<f64> {
    let distance = model.distance(look)?;
    if distance.is_nan() || gate.is_nan() || distance > gate {
        return None;
    }
    let (ax, ay, a_side) = centre_side(last);
    let (bx, by, b_side) = centre_side(region);
    let ratio = b_side / a_side;
    if !(1.0 / SIZE_RATIO..=SIZE_RATIO).contains(&ratio) {
        return None;
    }
    let seconds = now_ns.saturating_sub(seen_ns) as f64 * 1e-9;
    let reach = a_side.max(b_side) * (REACH_BASE + REACH_PER_SECOND * seconds);
    let moved = (bx - ax).hypot(by - ay);
    if moved.is_nan() || moved > reach {
        return None;
    }
    Some(distance + MOVE_WEIGHT * moved / reach)
}
