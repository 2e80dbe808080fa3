//! The floor learnt from people walking, when no calibration says where it is
//! (`[estimator.metric.floor] source = "learnt"`).
//!
//! A standing or walking person's pelvis stays at one height over the floor (3.95 mean
//! bone lengths on the training takes, +-2 cm while walking). Placed by the assumed body
//! size ([`crate::metres`]), a person's roots lie on a plane whose tilt is the floor's (a
//! scale about the camera centre keeps planes' normals) and whose distance from the camera
//! is the floor's times that person's size error. The root is used, not the ankles: it is
//! what the size places best (the fitted pose, flatter in depth than the person, draws
//! its ankles toward the root's depth, which tilts their plane toward the image plane: a
//! 30 degree camera looked 26.7 degrees down from the ankles). [`FloorLearner`] keeps the
//! roots of the last [`LearningSettings::points`] person-frames and fits one up direction
//! by iteratively reweighted least squares (Tukey's biweight on the residuals, their scale
//! from the median absolute deviation, at most 5 % of the camera's distance from the
//! plane: a misplaced frame weighs nothing): with an offset of each person's own when
//! each person's roots span an area (the tilt then exact whatever their sizes), else one
//! plane for everyone (people walking on lines: the tilt across the lines comes from
//! where the people are). The camera's height is the people's median (the body-size
//! prior, averaged over the people seen). The fit's uncertainty is the jackknife's over
//! ten blocks of consecutive points (a tenth of the points kept: half a second of two
//! people at the first fit, six seconds once 3600 are kept): its spread, not the size
//! prior's error nor a bias of the placed roots, which it does not see. The height's and
//! pitch's reported deviations add those ([`LearningSettings::size_std`], `PITCH_BIAS`);
//! the roll's is the fit's alone (a roll learnt 1.7 degrees off had one of 0.3).
//!
//! A fit is trusted ([`LearningState::Accepted`]) only when it is consistent (the
//! people's heights of the camera agree within what body sizes differ by: not people on
//! two levels, as on stairs or a balcony, nor someone sitting; most roots on their
//! plane), spread (the roots span an area, not one line, which would leave the roll about
//! it unknown), certain (the fit's deviations of height, pitch and roll within their
//! limits) and plausible (a
//! camera above the floor, not upside down); otherwise it is rejected or still learning,
//! and the metric step keeps the assumed size.

use std::collections::HashMap;

use nalgebra::{Matrix3, Rotation3, SymmetricEigen, UnitQuaternion, Vector3};

use crate::floor::FloorModel;

/// Blocks of the jackknife.
const BLOCKS: usize = 10;
/// Reweighting rounds of a fit, and of a jackknife refit (started from the fit).
const ROUNDS: usize = 10;
const REFIT_ROUNDS: usize = 4;
/// The residuals' scale is at least this (metres): roots placed by the assumed size are
/// not more exact than this, and a zero spread would weigh everything else out.
const MIN_SCALE: f64 = 0.02;
/// A root's coordinates at most, metres.
const MAX_DISTANCE: f64 = 1e4;
/// A person's points needed for their height of the camera to count in the consistency
/// check.
const MIN_PERSON_POINTS: usize = 60;
/// What the jackknife does not see of the pitch, degrees: `PITCH_BIAS.0 + PITCH_BIAS.1 *
/// |pitch|`, composed with it. The roots placed by the assumed size stand relatively
/// further the further they are (the fit's depth error grows with distance), which tilts
/// their plane toward level, more the more the camera looks down: on the training walks
/// looped to 30 s (`posestream scenes --distances --train`) cameras 0, 15 and 30 degrees
/// down were learnt 0.19, 0.67 and 0.75 degrees less down, with jackknife deviations of
/// 0.09-0.33.
const PITCH_BIAS: (f64, f64) = (0.2, 0.03);
/// Tukey's biweight constant, in the residuals' scale.
const TUKEY: f64 = 4.685;
/// The residuals' scale at most, as a fraction of the camera's distance from the plane
/// (5 %: people's sizes differ by about twice that, and their planes with them).
const MAX_SCALE: f64 = 0.05;

/// How the floor is learnt and when it is trusted.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LearningSettings {
    /// Person-frames (the root of each) kept: the newest replace the oldest.
    pub points: usize,
    /// Person-frames needed before a fit is tried.
    pub min_points: usize,
    /// A fit every this many person-frames.
    pub refit_every: usize,
    /// Height of a standing or walking person's root (the pelvis) above the floor,
    /// metres (at the assumed size).
    pub root_height_m: f64,
    /// Points within 3 residual scales of their person's plane needed, as a fraction
    /// (below: rejected).
    pub min_inliers: f64,
    /// The people's heights of the camera may lie this far (a fraction) from their
    /// median: body sizes differ by about this much (beyond: people on more than one
    /// level, rejected).
    pub max_height_spread: f64,
    /// The roots' spread on the floor along its narrower direction, metres (below:
    /// still learning).
    pub min_spread: f64,

    /// The relative spread of people's sizes about the assumed one (the metric step's
    /// `scale_std`): the camera's height is learnt as well as the assumed size fits the
    /// people seen, so its reported standard deviation composes this share of it with
    /// the fit's. Not divided by the people's number: the people in one place need not
    /// be independent draws of the population.
    pub size_std: f64,
    /// The fit's standard deviation of the height at most, as a fraction of it.
    pub max_height_std: f64,
    /// Pitch's and roll's standard deviations at most, degrees.
    pub max_angle_std: f64,
}

impl Default for LearningSettings {
    fn default() -> Self {
        Self {
            points: 3600,
            min_points: 300,
            refit_every: 30,
            root_height_m: 0.92,
            min_inliers: 0.8,
            max_height_spread: 0.2,
            min_spread: 0.1,
            size_std: crate::metres::POPULATION_SIZE_STD,
            max_height_std: 0.03,
            max_angle_std: 2.0,
        }
    }
}

/// A plane fitted to the roots: the floor's up in the camera frame, and the camera's
/// height over the floor (the people's median), with the lowest and highest person's.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Plane {
    up: Vector3<f64>,
    height: f64,
    /// The camera's height as the person placing it lowest and highest sees it (people
    /// with [`MIN_PERSON_POINTS`] at least).
    heights: (f64, f64),
    /// The residuals' robust scale, metres.
    scale: f64,
    /// Points within 3 scales, as a fraction.
    inliers: f64,
    /// The roots' spread along the floor's narrower direction, metres.
    spread: f64,
}

/// The learnt floor and how sure of it the learner is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LearntFloor {
    /// The floor under the camera.
    pub model: FloorModel,
    /// Standard deviation of the camera's height, metres: the fit's and the size
    /// prior's ([`LearningSettings::size_std`] of it), composed.
    pub height_std: f64,
    /// The fit's share of it, metres (the jackknife's: what more people-frames reduce).
    pub height_fit_std: f64,
    /// Pitch's, degrees: the fit's and the bias it does not see (`PITCH_BIAS`), composed.
    pub pitch_std: f64,
    /// The fit's share of it, degrees.
    pub pitch_fit_std: f64,
    /// Roll's, degrees.
    pub roll_std: f64,
    /// Person-frames it was fitted to.
    pub points: usize,
    /// Of them within 3 residual scales of the plane, as a fraction.
    pub inliers: f64,
    /// The residuals' robust scale, metres.
    pub residual: f64,
    /// The roots' spread along the floor's narrower direction, metres.
    pub spread: f64,
    /// The camera's height as the person placing it lowest and highest sees it, metres.
    pub heights: (f64, f64),
}

/// Where learning stands.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum LearningState {
    /// Not enough person-frames yet, or the fit not spread or certain enough.
    #[default]
    Learning,
    /// The floor is trusted ([`FloorLearner::floor`]).
    Accepted,
    /// The newest fit is not to be trusted.
    Rejected(Rejection),
}

/// Why a fit was rejected.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Rejection {
    /// Too few roots on their person's plane (`inliers`: their fraction): placed
    /// inconsistently.
    Inconsistent {
        /// The fraction on the plane.
        inliers: f64,
    },
    /// People's roots on planes further apart than body sizes explain: people on more
    /// than one level (stairs, a balcony), or someone sitting. The camera's height as the
    /// lowest and the highest person place it, metres.
    Levels {
        /// The lowest.
        low: f64,
        /// The highest.
        high: f64,
    },
    /// A camera below the floor, or rolled or pitched beyond what a camera watching
    /// people is (degrees).
    Implausible {
        /// Height, metres.
        height: f64,
        /// Pitch, degrees.
        pitch: f64,
        /// Roll, degrees.
        roll: f64,
    },
}

impl std::fmt::Display for Rejection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Inconsistent { inliers } => write!(
                f,
                "only {:.0} % of the roots on their plane",
                100.0 * inliers
            ),
            Self::Levels { low, high } => write!(
                f,
                "people on different levels, or not all standing, or placed too far apart in \
                 depth: each sees the camera at a height of its own, {low:.2} to {high:.2} m"
            ),
            Self::Implausible {
                height,
                pitch,
                roll,
            } => write!(
                f,
                "an implausible camera: {height:.2} m high, pitch {pitch:.1}, roll {roll:.1} degrees"
            ),
        }
    }
}

/// The floor learnt from the roots of people walking; see the module docs. Its buffers
/// are allocated once.
#[derive(Debug, Clone)]
pub struct FloorLearner {
    settings: LearningSettings,
    /// The root (the pelvis) of each person-frame, camera frame, metres (a ring, oldest
    /// at `next` once full).
    roots: Vec<Vector3<f64>>,
    /// Whose they are (the track of each).
    ids: Vec<u32>,
    next: usize,
    since_fit: usize,
    /// The points kept in a fit, their residuals and weights (reused).
    lower: Vec<Vector3<f64>>,
    residuals: Vec<f64>,
    sorted: Vec<f64>,
    weights: Vec<f64>,
    /// The person of each point (an index into `people`), the people's weighted sums,
    /// and each id's index (reused).
    person: Vec<usize>,
    people: Vec<Person>,
    slots: HashMap<u32, usize>,
    state: LearningState,
    floor: Option<LearntFloor>,
    /// The newest fit, trusted or not.
    newest: Option<LearntFloor>,
}

impl FloorLearner {
    /// A learner with nothing seen.
    pub fn new(settings: LearningSettings) -> Self {
        let n = settings.points.max(1);
        Self {
            settings,
            roots: Vec::with_capacity(n),
            ids: Vec::with_capacity(n),
            next: 0,
            since_fit: 0,
            lower: Vec::with_capacity(n),
            residuals: Vec::with_capacity(n),
            sorted: Vec::with_capacity(n),
            weights: Vec::with_capacity(n),
            person: Vec::with_capacity(n),
            people: Vec::new(),
            slots: HashMap::new(),
            state: LearningState::Learning,
            floor: None,
            newest: None,
        }
    }

    /// Where learning stands.
    pub fn state(&self) -> LearningState {
        self.state
    }

    /// The floor, while a fit is trusted.
    pub fn floor(&self) -> Option<&LearntFloor> {
        self.floor.as_ref()
    }

    /// The newest fit, trusted or not (what was rejected, or is still uncertain).
    pub fn newest(&self) -> Option<&LearntFloor> {
        self.newest.as_ref()
    }

    /// Person-frames kept.
    pub fn points(&self) -> usize {
        self.roots.len()
    }

    /// Takes the root (the pelvis) of one person-frame of person `id` (camera frame,
    /// metres, placed by the assumed size); fits again when due. True when the trusted
    /// floor changed (a new fit trusted, or the one trusted dropped).
    pub fn note(&mut self, id: u32, root: Vector3<f64>) -> bool {
        // Finite and within 10 km: a root beyond is no person's (and its square would
        // overflow the fit).
        if !root.iter().all(|v| v.is_finite() && v.abs() < MAX_DISTANCE) {
            return false;
        }
        if self.roots.len() < self.settings.points.max(1) {
            self.roots.push(root);
            self.ids.push(id);
        } else {
            self.roots[self.next] = root;
            self.ids[self.next] = id;
            self.next = (self.next + 1) % self.roots.len();
        }
        self.since_fit += 1;
        if self.roots.len() < self.settings.min_points.max(BLOCKS * 3)
            || self.since_fit < self.settings.refit_every
        {
            return false;
        }
        self.since_fit = 0;
        self.refit()
    }

    /// Fits the plane to the points kept, with its jackknife, and decides whether to
    /// trust it; true when the trusted floor changed.
    fn refit(&mut self) -> bool {
        let before = self.floor.is_some();
        let start = self.newest.map_or(-Vector3::y(), |f| f.model.up());
        let n = self.roots.len();
        // An offset per person when each person's own roots span an area (their tilt
        // exact whatever their sizes); else one plane for everyone (people walking on
        // lines: the tilt across the lines from the people's places).
        let own = self
            .fit(start, ROUNDS, None, true)
            .filter(|p| p.spread >= self.settings.min_spread);
        let per_person = own.is_some();
        let Some(plane) = own.or_else(|| self.fit(start, ROUNDS, None, false)) else {
            // Nothing to fit (every point weighed out): what was trusted stays.
            return self.no_fit();
        };
        // The jackknife: each block of consecutive points (in the order they came) left
        // out in turn.
        let mut values = [[0.0; 3]; BLOCKS];
        let mut fitted = 0;
        for (b, v) in values.iter_mut().enumerate() {
            let block = (b * n / BLOCKS, (b + 1) * n / BLOCKS);
            if let Some(p) = self.fit(plane.up, REFIT_ROUNDS, Some(block), per_person)
                && let Some(m) = model(&p)
            {
                let (pitch, roll) = m.pitch_roll();
                *v = [p.height, pitch, roll];
                fitted += 1;
            }
        }
        let Some(model) = model(&plane) else {
            return self.no_fit();
        };
        let std = |k: usize| {
            if fitted < BLOCKS {
                return f64::INFINITY;
            }
            let mean = values.iter().map(|v| v[k]).sum::<f64>() / BLOCKS as f64;
            let ss = values.iter().map(|v| (v[k] - mean).powi(2)).sum::<f64>();
            ((BLOCKS - 1) as f64 / BLOCKS as f64 * ss).sqrt()
        };
        let height = model.height();
        let learnt = LearntFloor {
            model,
            height_std: std(0).hypot(self.settings.size_std * height),
            height_fit_std: std(0),
            pitch_std: std(1).hypot(PITCH_BIAS.0 + PITCH_BIAS.1 * model.pitch_roll().0.abs()),
            pitch_fit_std: std(1),
            roll_std: std(2),
            points: n,
            inliers: plane.inliers,
            residual: plane.scale,
            spread: plane.spread,
            heights: plane.heights,
        };
        self.newest = Some(learnt);
        // A fit still uncertain leaves the floor trusted before as it was (a gap in the
        // people seen does not drop it); one trusted replaces it; one rejected drops it.
        match self.judge(&learnt) {
            LearningState::Accepted => {
                self.state = LearningState::Accepted;
                self.floor = Some(learnt);
                true
            }
            LearningState::Learning if before => false,
            state => {
                self.state = state;
                self.floor = None;
                before
            }
        }
    }

    /// A refit that gave no plane (every point weighed out): what was trusted stays;
    /// false (the trusted floor did not change).
    fn no_fit(&mut self) -> bool {
        self.newest = None;
        self.state = if self.floor.is_some() {
            LearningState::Accepted
        } else {
            LearningState::Learning
        };
        false
    }

    /// Whether `f` is to be trusted.
    fn judge(&self, f: &LearntFloor) -> LearningState {
        let s = &self.settings;
        let (pitch, roll) = f.model.pitch_roll();
        let height = f.model.height();
        let (low, high) = f.heights;
        if low < (1.0 - s.max_height_spread) * height || high > (1.0 + s.max_height_spread) * height
        {
            return LearningState::Rejected(Rejection::Levels { low, high });
        }
        if f.inliers < s.min_inliers {
            return LearningState::Rejected(Rejection::Inconsistent { inliers: f.inliers });
        }
        if !(0.1..=50.0).contains(&height) || roll.abs() > 45.0 || !(-45.0..=85.0).contains(&pitch)
        {
            return LearningState::Rejected(Rejection::Implausible {
                height,
                pitch,
                roll,
            });
        }
        let certain = f.height_fit_std <= s.max_height_std * height
            && f.pitch_fit_std <= s.max_angle_std
            && f.roll_std <= s.max_angle_std;
        if f.spread >= s.min_spread && certain {
            LearningState::Accepted
        } else {
            LearningState::Learning
        }
    }

    /// The plane through the roots by reweighted least squares (the first round plain
    /// least squares, then Tukey's weights on the residuals), its up on the side of
    /// `start` (the previous fit's, or the camera's up when level): one up, and an
    /// offset per person (`per_person`) or one for everyone; the points of `left_out` (a
    /// range in arrival order) left out.
    fn fit(
        &mut self,
        start: Vector3<f64>,
        rounds: usize,
        left_out: Option<(usize, usize)>,
        per_person: bool,
    ) -> Option<Plane> {
        let n = self.roots.len();
        // Arrival order: the ring's oldest first.
        let oldest = if n < self.settings.points.max(1) {
            0
        } else {
            self.next
        };
        let kept = |i: usize| left_out.is_none_or(|(a, b)| i < a || i >= b);
        // The points kept, and their people (dense indices).
        self.lower.clear();
        self.person.clear();
        self.people.clear();
        self.slots.clear();
        for i in (0..n).filter(|&i| kept(i)) {
            let j = (oldest + i) % n;
            let next = self.people.len();
            let k = *self.slots.entry(self.ids[j]).or_insert(next);
            if k == next {
                self.people.push(Person::new());
            }
            self.lower.push(self.roots[j]);
            self.person.push(k);
        }
        if self.lower.len() < 3 {
            return None;
        }
        let mut up = start;
        let mut plane = None;
        for round in 0..rounds {
            self.weights.clear();
            if round == 0 {
                self.weights.resize(self.lower.len(), 1.0);
            } else {
                let c = TUKEY * self.residual_scale(&up);
                self.weights.extend(self.residuals.iter().map(|r| {
                    let u = r / c;
                    if u.abs() < 1.0 {
                        (1.0 - u * u).powi(2)
                    } else {
                        0.0
                    }
                }));
            }
            // Each person's weighted mean; the scatter about them (or about everyone's).
            for p in &mut self.people {
                (p.weight, p.sum, p.points) = (0.0, Vector3::zeros(), 0);
            }
            for ((q, &k), w) in self.lower.iter().zip(&self.person).zip(&self.weights) {
                let p = &mut self.people[k];
                p.weight += w;
                p.sum += q * *w;
                p.points += 1;
            }
            let total: f64 = self.people.iter().map(|p| p.weight).sum();
            if total <= 0.0 {
                return None;
            }
            let global = self.people.iter().map(|p| p.sum).sum::<Vector3<f64>>() / total;
            let mut cov = Matrix3::zeros();
            for ((q, &k), &w) in self.lower.iter().zip(&self.person).zip(&self.weights) {
                // A point weighed out adds nothing (not even 0 x inf).
                if w > 0.0 {
                    let p = &self.people[k];
                    let centre = if per_person { p.sum / p.weight } else { global };
                    let d = q - centre;
                    cov += d * d.transpose() * w;
                }
            }
            cov /= total;
            let eigen = SymmetricEigen::new(cov);
            let mut order = [0, 1, 2];
            order.sort_by(|&i, &j| eigen.eigenvalues[i].total_cmp(&eigen.eigenvalues[j]));
            let mut normal: Vector3<f64> = eigen.eigenvectors.column(order[0]).into_owned();
            if !normal.iter().all(|v| v.is_finite()) {
                return None;
            }
            // Up on the prior's side (not the side the camera is on: a camera below the
            // people's roots is one too).
            if normal.dot(&start) < 0.0 {
                normal = -normal;
            }
            up = normal;
            for p in &mut self.people {
                if p.weight > 0.0 {
                    p.own = up.dot(&(p.sum / p.weight));
                    p.offset = if per_person { p.own } else { up.dot(&global) };
                }
            }
            // The camera's height: the people's, median over points (a person counts as
            // often as they were seen); the lowest and highest of those seen enough.
            self.sorted.clear();
            self.sorted.extend(
                self.person
                    .iter()
                    .map(|&k| self.settings.root_height_m - self.people[k].offset),
            );
            let height = median_in_place(&mut self.sorted);
            let heights = self
                .people
                .iter()
                .filter(|p| p.points >= MIN_PERSON_POINTS && p.weight > 0.0)
                .map(|p| self.settings.root_height_m - p.own)
                .fold(None, |range: Option<(f64, f64)>, h| {
                    Some(range.map_or((h, h), |(lo, hi)| (lo.min(h), hi.max(h))))
                })
                .unwrap_or((height, height));
            plane = Some(Plane {
                up,
                height,
                heights,
                scale: MIN_SCALE,
                inliers: 0.0,
                spread: eigen.eigenvalues[order[1]].max(0.0).sqrt(),
            });
        }
        let mut plane = plane?;
        plane.scale = self.residual_scale(&plane.up);
        let within = self
            .residuals
            .iter()
            .filter(|r| r.abs() < 3.0 * plane.scale)
            .count();
        plane.inliers = within as f64 / self.lower.len() as f64;
        Some(plane)
    }

    /// The residuals of the points from their person's plane along `up` (into
    /// `residuals`), and their robust scale: from the median absolute deviation, at least
    /// [`MIN_SCALE`] and at most [`MAX_SCALE`] of the camera's distance from the plane
    /// (people on two levels would otherwise widen it until one plane takes both).
    fn residual_scale(&mut self, up: &Vector3<f64>) -> f64 {
        self.residuals.clear();
        self.residuals.extend(
            self.lower
                .iter()
                .zip(&self.person)
                .map(|(q, &k)| up.dot(q) - self.people[k].offset),
        );
        self.sorted.clear();
        self.sorted.extend(self.residuals.iter().map(|r| r.abs()));
        let mad = median_in_place(&mut self.sorted);
        self.sorted.clear();
        self.sorted
            .extend(self.people.iter().map(|p| p.offset.abs()));
        let distance = median_in_place(&mut self.sorted);
        (1.4826 * mad).min(MAX_SCALE * distance).max(MIN_SCALE)
    }
}

/// One person's share of a fit.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Person {
    /// Their roots' offset along up in the fit (theirs, or everyone's).
    offset: f64,
    /// Their own (their weighted mean's).
    own: f64,
    /// Their weights, weighted sum of points, and points.
    weight: f64,
    sum: Vector3<f64>,
    points: usize,
}

impl Person {
    fn new() -> Self {
        Self {
            offset: 0.0,
            own: 0.0,
            weight: 0.0,
            sum: Vector3::zeros(),
            points: 0,
        }
    }
}

/// The camera's pose over the plane: the floor frame's z its up, its x the camera's
/// forward along the floor.
fn model(plane: &Plane) -> Option<FloorModel> {
    let up = plane.up;
    let x = (Vector3::z() - up * up.z).try_normalize(1e-9)?;
    let y = up.cross(&x);
    let rows = Matrix3::from_rows(&[x.transpose(), y.transpose(), up.transpose()]);
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(rows));
    FloorModel::new(rotation, Vector3::new(0.0, 0.0, plane.height)).ok()
}

fn median_in_place(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    *m
}

#[cfg(test)]
mod tests;
