//! Metres for streamed estimates: the perspective adjustment
//! ([`crate::solver::perspective`], the paper's last stage) of one [`FrameEstimate`] at a
//! time, after the window, and a 3D standard deviation for each joint.
//!
//! The window's estimate of a frame is centred and in the dictionary's units. With the
//! camera's [`Intrinsics`] and the map from the frame's heat-map pixels to image pixels
//! (its crop box), [`MetricStep::adjust`] places the person in the camera frame, in
//! metres: the weak fit scaled so that the skeleton's mean bone length is
//! [`PerspectiveParams::mean_limb_length`], put at the depth where its image has the
//! fitted size, then refined under the pinhole camera (per-joint depths on the rays, a
//! similarity fit whose scale becomes depth, the coefficients against the rays).
//!
//! **Uncertainty** (per axis, metres). Two sources, independent:
//! - the 2D spread of the E-step (`keypoint_std`, image pixels) moved to the joint's
//!   depth: `s_l = z_j s_px / f` on x and y, and the same on z (the depth of a joint
//!   relative to the body is no better known than its image position);
//! - the metric scale: the person's true mean bone length differs from the assumed one
//!   by a relative standard deviation `scale_std`, and a scene scaled about the camera
//!   centre gives the same image, so every joint moves along its ray: `P_j scale_std`
//!   on each axis (`z_j scale_std` in depth: the largest term at a distance).
//!
//! `s_x^2 = s_l^2 + (x_j r)^2`, `s_y^2 = s_l^2 + (y_j r)^2`, `s_z^2 = s_l^2 + (z_j r)^2`
//! with `r = scale_std`. How often the true error lies within 1 and 2 of these is
//! measured on synthetic data (`tests/metric.rs`, docs/metric.md).

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::camera::Intrinsics;
use crate::dictionary::Dictionary;
use crate::error::EstimateError;
use crate::estimator::Estimator;
use crate::floor::{BodyScale, FloorModel, FloorSettings, FloorStd};
use crate::solver::perspective::{
    self, PerspectiveFit, PerspectiveParams, PerspectiveWorkspace, start_from_weak_fit,
};
use crate::streaming::FrameEstimate;
use posestream_base::PixelMap;
use posestream_base::{OutOfDomain, check_range, check_real};

/// Settings of the metric step (`[estimator.metric]`). The perspective adjustment's
/// keys are listed here again rather than flattened from [`PerspectiveParams`]: serde
/// cannot refuse unknown keys of a flattened struct ([`MetricSettings::perspective`]
/// gives them back).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MetricSettings {
    /// The camera, `[fx, fy, cx, cy]` in pixels of the images the heat maps' crop boxes
    /// are in; empty: no metric step (skeletons in dictionary units).
    pub intrinsics: Vec<f64>,
    /// Mean bone length of the skeleton, metres: sets the metric scale
    /// ([`PerspectiveParams::mean_limb_length`]).
    pub mean_limb_length: f64,
    /// Relative standard deviation of the metric scale: how far a person's mean bone
    /// length may be from `mean_limb_length`, as a fraction (0.1: 10 %).
    pub scale_std: f64,
    /// Without the floor, the placed skeleton is scaled about the camera centre by this
    /// (its image unchanged): a fitted pose is flatter in depth than the person, so at the
    /// person's bone length it projects larger and the size match puts it too far.
    /// Measured on the training walks (`posestream scenes --distances --train`, no floor,
    /// the subjects' true size): depth +6.4 %, so 1 / 1.064.
    pub depth_correction: f64,
    /// A skeleton placed by its size (`METRIC_SIZE`): its `position_std` (the 2D spread
    /// along the rays and `scale_std`, composed) times this (see `floor.std_factor` for
    /// one placed by the floor). 0.8: on the training walks 71 % of the per-axis errors
    /// fell within it at the size prior, 73 % with the subjects' true size (95 and 91 %
    /// within 2).
    pub std_factor: f64,
    /// L1 weight of the perspective C-step ([`PerspectiveParams::alpha`]).
    pub alpha: f64,
    /// Iterations per frame at most ([`PerspectiveParams::max_iterations`]).
    pub max_iterations: usize,
    /// APG steps per C-step ([`PerspectiveParams::apg_steps`]).
    pub apg_steps: usize,
    /// Relative tolerance ([`PerspectiveParams::tolerance`]).
    pub tolerance: f64,
    /// The floor, and people's size from their feet on it (`[estimator.metric.floor]`).
    pub floor: FloorSettings,
}

/// The size prior: an adult's mean bone length over the skeleton's bones, metres, and its
/// relative spread. Adults' mean stature, men and women pooled, is about 1.65 m (NCD Risk
/// Factor Collaboration, "A century of trends in adult human height", eLife 2016), with a
/// spread of about 9 cm (5.5 %) derived from about 7 cm within each sex and the gap
/// between them; the motion capture's training takes (three actors) have a mean bone
/// length of 0.141 of their stature (0.2235 m on 1.57-1.61 m, head top to floor). The
/// spread rounds 5.5 % up for the proportions, which differ between people too.
pub const POPULATION_MEAN_LIMB: f64 = 0.233;
/// The size prior's relative spread ([`POPULATION_MEAN_LIMB`]).
pub const POPULATION_SIZE_STD: f64 = 0.06;

impl Default for MetricSettings {
    fn default() -> Self {
        let p = PerspectiveParams::default();
        Self {
            intrinsics: Vec::new(),
            mean_limb_length: POPULATION_MEAN_LIMB,
            scale_std: POPULATION_SIZE_STD,
            depth_correction: 0.94,
            std_factor: 0.8,
            alpha: p.alpha,
            // With momentum (`perspective`), 35 matched 100 without it.
            max_iterations: 35,
            apg_steps: p.apg_steps,
            tolerance: p.tolerance,
            floor: FloorSettings::default(),
        }
    }
}

impl MetricSettings {
    /// Checks every value is in its domain.
    pub fn check(&self) -> Result<(), OutOfDomain> {
        if !self.intrinsics.is_empty() {
            self.camera_checked().map_err(|message| {
                OutOfDomain::new(
                    "intrinsics",
                    "[] or [fx, fy, cx, cy] with fx, fy > 0, all finite",
                    format!("{:?} ({message})", self.intrinsics),
                )
            })?;
        }
        check_real("mean_limb_length", self.mean_limb_length, 0.0, 10.0, true)?;
        check_real("scale_std", self.scale_std, 0.0, 1.0, false)?;
        check_real("depth_correction", self.depth_correction, 0.5, 2.0, false)?;
        check_real("std_factor", self.std_factor, 0.0, 10.0, true)?;
        check_real("alpha", self.alpha, 0.0, 1e3, false)?;
        check_range("max_iterations", self.max_iterations, 1, 100_000)?;
        check_range("apg_steps", self.apg_steps, 1, 10_000)?;
        check_real("tolerance", self.tolerance, 0.0, 1.0, true)?;
        self.floor.check().map_err(|e| e.within("floor"))
    }

    /// The camera, if one is configured.
    pub fn camera(&self) -> Option<Intrinsics> {
        self.camera_checked().ok()
    }

    fn camera_checked(&self) -> Result<Intrinsics, String> {
        match self.intrinsics[..] {
            [fx, fy, cx, cy] => Intrinsics::new(fx, fy, cx, cy),
            _ => Err(format!("{} values", self.intrinsics.len())),
        }
    }

    /// The perspective adjustment's parameters.
    pub fn perspective(&self) -> PerspectiveParams {
        PerspectiveParams {
            mean_limb_length: self.mean_limb_length,
            alpha: self.alpha,
            max_iterations: self.max_iterations,
            apg_steps: self.apg_steps,
            tolerance: self.tolerance,
            momentum: true,
        }
    }
}

/// The relative std of a floor-given scale at least: the contacts' spread, measured
/// over the last frames, is no better than the feet's 2D positions.
const MIN_FLOOR_SCALE_STD: f64 = 0.01;

/// A frame in metres, written by [`MetricStep::adjust`] (buffers reused).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MetricPose {
    /// Joint positions, metres, camera frame (x right, y down, z forward): `[x, y, z]`
    /// per joint.
    pub positions: Vec<f64>,
    /// Standard deviation of each joint's position per axis, metres: `[x, y, z]` per
    /// joint (module docs).
    pub position_std: Vec<f64>,
    /// The 2D joints the adjustment fitted, image pixels: `[u, v]` per joint.
    pub keypoints: Vec<f64>,
    /// Standard deviation of each 2D joint, image pixels.
    pub keypoint_std: Vec<f64>,
    /// The perspective projection of `positions`, image pixels: `[u, v]` per joint.
    pub projected: Vec<f64>,
    /// Depth of the body's centroid, metres.
    pub depth: f64,
    /// Where the metric scale came from.
    pub source: PlacedBy,
    /// The root (the pelvis), camera frame, metres, placed by the assumed size whatever
    /// `source` is: what the floor is learnt from ([`crate::learnt_floor`]).
    pub root_at_size: Vector3<f64>,
    /// The person's size, metres of mean bone length: placed by the floor, the median of
    /// their contacts' scales with the fitted pose's flatness in depth undone
    /// ([`MetricSettings::depth_correction`]: the placed skeleton's bones are that much
    /// shorter); by the size, the assumed one.
    pub size: f64,
}

/// The floor under a person, for [`MetricStep::adjust`].
#[derive(Debug)]
pub struct OnFloor<'a> {
    /// The floor.
    pub floor: &'a FloorModel,
    /// The person's scale from their contacts.
    pub scale: &'a mut BodyScale,
    /// Their heat maps come from a look in this image (`frames_since_look` 0), not
    /// carried over from an earlier one with the body's expected motion: only then are
    /// their feet evidence of a contact.
    pub looked: bool,
    /// How far off the floor may be (a learnt one's deviations; `None`: exact). A person
    /// placed by it is that much less certain: its relative spread at their distance
    /// ([`FloorStd::distance`]) composes with their `position_std`.
    pub std: Option<FloorStd>,
}

/// Where a metric pose's scale came from (`Skeleton3D.metric_source`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PlacedBy {
    /// The assumed body size ([`MetricSettings::mean_limb_length`]).
    #[default]
    Size = 1,
    /// The person's feet on the floor, over their last frames ([`BodyScale`]).
    Floor = 2,
}

/// The perspective adjustment of streamed estimates, one frame at a time; see the
/// module docs. Its buffers are kept from frame to frame.
#[derive(Debug, Clone)]
pub struct MetricStep {
    dict: Dictionary,
    gram_max: f64,
    settings: MetricSettings,
    params: PerspectiveParams,
    ws: PerspectiveWorkspace,
    weights: Vec<f64>,
    shape: Vec<f64>,
    fit: Option<PerspectiveFit>,
    /// The joints that stand on the floor (the ankles).
    feet: Vec<usize>,
    /// The root and the top of the torso (the thorax, else the neck): its lean.
    root: usize,
    torso_top: Option<usize>,
}

impl MetricStep {
    /// A step for the estimates of `estimator`'s dictionary.
    pub fn new(estimator: &Estimator, settings: MetricSettings) -> Result<Self, EstimateError> {
        settings.check()?;
        let params = settings.perspective();
        params.validate()?;
        let dict = estimator.dictionary().clone();
        Ok(Self {
            gram_max: estimator.basis_gram_max(),
            params,
            weights: vec![1.0; dict.num_joints()],
            shape: vec![0.0; 3 * dict.num_joints()],
            feet: dict.skeleton().feet(),
            root: dict.skeleton().root(),
            torso_top: dict.skeleton().torso_top(),
            dict,
            settings,
            ws: PerspectiveWorkspace::default(),
            fit: None,
        })
    }

    /// The settings.
    pub fn settings(&self) -> &MetricSettings {
        &self.settings
    }

    /// The perspective adjustment's iterations on the last estimate adjusted.
    pub fn iterations(&self) -> usize {
        self.fit.as_ref().map_or(0, |f| f.iterations)
    }

    /// Writes estimate `e` in metres into `out`: `to_image` maps its heat-map pixels to
    /// image pixels (the crop box), `camera` is the camera's. With a floor ([`OnFloor`]),
    /// a foot the evidence puts on it (its contact) is noted in the person's
    /// [`BodyScale`] and the pose scaled about the camera centre by the frame's factor,
    /// else the person's ([`PlacedBy::Floor`]); without, or before any contact, it keeps
    /// the assumed size. An error (the pose has no size, or the result is not finite)
    /// leaves `out` to be ignored.
    pub fn adjust(
        &mut self,
        e: &FrameEstimate,
        to_image: &PixelMap,
        camera: &Intrinsics,
        floor: Option<OnFloor<'_>>,
        out: &mut MetricPose,
    ) -> Result<(), EstimateError> {
        let p = self.dict.num_joints();
        if e.offset.len() == 3 * p {
            if e.offset != self.dict.offset() {
                // The track's shape beyond the dictionary, as the window composed it.
                self.dict.set_offset(&e.offset);
            }
        } else if self.dict.has_offset() {
            // An estimate without one: the paper's model.
            self.shape.fill(0.0);
            self.dict.set_offset(&self.shape);
        }
        out.keypoints.clear();
        out.keypoints.extend(
            e.keypoints
                .chunks_exact(2)
                .flat_map(|xy| to_image.apply(xy[0], xy[1])),
        );
        let units_to_image = PixelMap {
            scale: to_image.scale.map(|s| s * e.pixels_per_unit),
            offset: to_image.offset,
        };
        let params = &self.params;
        let zero_size = || EstimateError::ZeroSize { frame: 0 };
        let started = start_from_weak_fit(&self.dict, &e.fit, &units_to_image, camera, params)
            .ok_or_else(zero_size)?;
        // The previous frame's fit keeps its vectors: written over.
        let fit = match &mut self.fit {
            Some(fit) => {
                fit.coefficients.clone_from(&started.coefficients);
                fit.metres_per_unit = started.metres_per_unit;
                fit.rotation = started.rotation;
                fit.translation = started.translation;
                fit
            }
            None => self.fit.insert(started),
        };
        perspective::adjust_frame(
            &self.dict,
            self.gram_max,
            camera,
            &out.keypoints,
            &self.weights,
            fit,
            params,
            &mut self.ws,
        );
        out.positions.clear();
        out.projected.clear();
        out.position_std.clear();
        out.keypoint_std.clear();
        let shape = &mut self.shape;
        self.dict.compose_into(&fit.coefficients, shape);
        // On the floor: upright, then the scale that stands the person on it.
        let (factor, scale_std, floor_std) = match floor {
            Some(OnFloor {
                floor,
                scale,
                looked,
                std,
            }) => {
                if let Some(top) = self.torso_top {
                    upright(fit, shape, self.root, top, floor);
                }
                let contact = Contact {
                    feet: &self.feet,
                    ankle_height: self.settings.floor.ankle_height * self.settings.mean_limb_length,
                    max_scale: self.settings.floor.max_scale,
                };
                let keypoints = &out.keypoints;
                match contact.scale(
                    fit, shape, keypoints, camera, floor, e.sequence, scale, looked,
                ) {
                    Some((factor, spread, median)) => {
                        out.source = PlacedBy::Floor;
                        out.size = median / self.settings.depth_correction
                            * self.settings.mean_limb_length;
                        // The floor's own uncertainty where the person stands.
                        let floor_std = std.map_or(0.0, |s| {
                            let root = floor.to_floor(&(joint(fit, shape, self.root) * factor));
                            s.distance(floor, root.x.hypot(root.y))
                        });
                        (factor, spread, floor_std)
                    }
                    None => {
                        out.source = PlacedBy::Size;
                        out.size = self.settings.mean_limb_length;
                        (self.settings.depth_correction, self.settings.scale_std, 0.0)
                    }
                }
            }
            None => {
                out.source = PlacedBy::Size;
                out.size = self.settings.mean_limb_length;
                (self.settings.depth_correction, self.settings.scale_std, 0.0)
            }
        };
        out.root_at_size = joint(fit, shape, self.root) * self.settings.depth_correction;
        let focal = camera.focal();
        let px = to_image.mean_scale();
        // Placed by the floor, the composed spread is scaled to what the errors were on
        // the training walks (`FloorSettings::std_factor`).
        let std_factor = match out.source {
            PlacedBy::Floor => self.settings.floor.std_factor,
            PlacedBy::Size => self.settings.std_factor,
        };
        for j in 0..p {
            let q = joint(fit, shape, j) * factor;
            out.positions.extend_from_slice(q.as_slice());
            out.projected.extend(camera.project(&q));
            let s_px = e.keypoint_std.get(j).copied().unwrap_or(0.0) * px;
            out.keypoint_std.push(s_px);
            let lateral = q.z.abs() * s_px / focal;
            for v in [q.x, q.y, q.z] {
                let spread = lateral.hypot(v * scale_std).hypot(v * floor_std);
                out.position_std.push(std_factor * spread);
            }
        }
        out.depth = fit.translation.z * factor;
        let finite = [&out.positions, &out.position_std, &out.projected]
            .iter()
            .all(|v| v.iter().all(|x| x.is_finite()));
        if finite {
            Ok(())
        } else {
            Err(EstimateError::Parameter(
                "the metric pose has non-finite values".into(),
            ))
        }
    }
}

/// Joint `j` of `shape` (the fit's coefficients composed) placed by `fit`, metres.
fn joint(fit: &PerspectiveFit, shape: &[f64], j: usize) -> Vector3<f64> {
    let p = shape.len() / 3;
    fit.rotation * Vector3::new(shape[j], shape[p + j], shape[2 * p + j]) * fit.metres_per_unit
        + fit.translation
}

/// A torso leaning toward or away from the camera by at most this much (radians) is
/// stood upright on the floor; one leaning further (a person bending) keeps the rest.
const UPRIGHT_LEAN: f64 = 25.0 * std::f64::consts::PI / 180.0;

/// Turns the fitted body about its root so that its torso (root to `top`) leans toward
/// or away from the camera by [`UPRIGHT_LEAN`] less (upright when it leaned less). That
/// lean is what one image shows least (it is along the rays), and the fit gets it wrong
/// under a camera looking down: on `posestream scenes --distances` the roots of the two
/// scenes whose cameras look 15 and 30 degrees down came out 2.0 and 3.3 % of the
/// distance too far (mean) without this, -0.4 and +0.8 % with it. Sideways lean, which
/// the image shows, is kept.
fn upright(fit: &mut PerspectiveFit, shape: &[f64], root: usize, top: usize, floor: &FloorModel) {
    let base = joint(fit, shape, root);
    let torso = joint(fit, shape, top) - base;
    let up = floor.up();
    // The horizontal direction away from the camera, and the lean along it.
    let Some(away) = (Vector3::z() - up * up.z).try_normalize(1e-9) else {
        return;
    };
    let lean = torso.dot(&away).atan2(torso.dot(&up));
    let turn = lean.signum() * (lean.abs() - UPRIGHT_LEAN).max(0.0) - lean;
    let axis = nalgebra::Unit::new_normalize(up.cross(&away));
    let r = nalgebra::Rotation3::from_axis_angle(&axis, turn).into_inner();
    fit.rotation = r * fit.rotation;
    fit.translation = base - r * (base - fit.translation);
}

/// Where a person's feet meet the floor.
struct Contact<'a> {
    /// The ankles.
    feet: &'a [usize],
    /// An ankle's height on the floor at the assumed size, metres.
    ankle_height: f64,
    /// Contacts beyond this factor of the assumed size are not trusted.
    max_scale: f64,
}

/// A foot stands still (may be on the floor) while it moves less than this share of the
/// person's height in the image a frame: a walker's swing foot moves about 0.035 a frame
/// at 30 frames/s, a jumping one more; the heat maps' noise about 0.01.
const STILL_FOOT: f64 = 0.04;
/// Once a person has this many contacts since their track began (or resumed: then too
/// their size kept is checked against these), a frame's own contact is trusted only up to
/// `CONTACT_GATE` spreads above their median (at least `MIN_CONTACT_GATE` in `ln`): a
/// foot on a step, or still at a jump's top, is above the floor, and its ray meets the
/// floor further away than the foot (cameras look down on feet), so its factor is too
/// large. Only that side is gated: a factor below the median is taken, so that a median
/// made of a person's first, poorly fitted frames can move.
const GATE_AFTER: usize = 10;
const CONTACT_GATE: f64 = 3.0;
const MIN_CONTACT_GATE: f64 = 0.06;

impl Contact<'_> {
    /// The factor that stands the fitted body (its size the assumed one) on the floor
    /// and its relative std: this frame's own contact when it has a trusted one (noted
    /// in `scale`), else the person's median over their last contacts (their size, kept
    /// through frames without a contact); `None` before any contact. A contact is a foot
    /// the evidence puts on the floor: still in the image against the nearest of the 3
    /// frames before (a foot kicked forward or taking off is not), the one whose observed ray meets the floor
    /// nearest (the other is lifted or further), and, once the person has contacts, its
    /// factor not far above their median (a foot on a step or at a jump's top is not).
    /// With the factor and its spread, the median itself (the person's size).
    #[allow(clippy::too_many_arguments, reason = "one frame's inputs")]
    fn scale(
        &self,
        fit: &PerspectiveFit,
        shape: &[f64],
        keypoints: &[f64],
        camera: &Intrinsics,
        floor: &FloorModel,
        sequence: u64,
        scale: &mut BodyScale,
        looked: bool,
    ) -> Option<(f64, f64, f64)> {
        let foot = |j: usize| [keypoints[2 * j], keypoints[2 * j + 1]];
        // The person's height in the image: how far a foot may move and stand still.
        let (lo, hi) = keypoints
            .chunks_exact(2)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p[1]), hi.max(p[1]))
            });
        let still = STILL_FOOT * (hi - lo).max(1.0);
        let candidate = self
            .feet
            .iter()
            .enumerate()
            .filter(|&(k, &j)| {
                looked
                    && scale
                        .foot_speed(sequence, k, foot(j))
                        .is_some_and(|v| v <= still)
            })
            .filter_map(|(_, &j)| {
                let ray = camera.ray(keypoints[2 * j], keypoints[2 * j + 1]);
                let t = floor.scale_to(&ray, self.ankle_height)?;
                Some((ray.z * t, joint(fit, shape, j).z))
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(seen, fitted)| seen / fitted)
            .filter(|f| *f <= self.max_scale && f * self.max_scale >= 1.0);
        // The person's median before this frame, only when there is a contact to gate,
        // and once they have contacts of their own since their track began (a person back
        // under their id keeps their size, [`BodyScale::suspend`], unless their new
        // contacts say otherwise: below).
        let own = candidate.filter(|f| {
            scale.fresh() < GATE_AFTER
                || scale.estimate().is_none_or(|m| {
                    f.ln() - m.factor.ln() <= (CONTACT_GATE * m.spread).max(MIN_CONTACT_GATE)
                })
        });
        // Carried-over heat maps moved with the body: their feet say nothing.
        if looked {
            scale.note_feet(sequence, self.feet.iter().map(|&j| foot(j)));
        }
        match own {
            Some(f) => scale.note(sequence, f),
            // A refined estimate takes back its newest estimate's contact.
            None => scale.forget(sequence),
        }
        // Back under their id: their first contacts since decide whether the size kept
        // is theirs (an id given again to someone else, or a restarted detector's).
        if own.is_some()
            && scale.fresh() == GATE_AFTER
            && let (Some(kept), Some(fresh)) = (scale.kept_median(), scale.fresh_median())
            && (fresh.ln() - kept.ln()).abs() > MIN_CONTACT_GATE
        {
            scale.keep_fresh();
        }
        let median = scale.estimate()?;
        // A frame's own factor strays from the median by the contacts' spread.
        Some((
            own.unwrap_or(median.factor),
            median.spread.max(MIN_FLOOR_SCALE_STD),
            median.factor,
        ))
    }
}
