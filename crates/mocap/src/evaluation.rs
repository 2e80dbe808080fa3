//! The evaluation behind `posestream eval` and `docs/results.md`: held-out motion seen by
//! virtual cameras, lifted by the estimator, scored as in the paper's tables.
//!
//! - Table 1 (given 2D): orthographic projections, a static camera and one orbiting at
//!   15 deg/s; the single-frame initialisation against Algorithm 1; P-MPJPE in mm.
//! - Table 3 (heat maps): a pinhole camera 5 m away, heat maps from the synthetic detector
//!   ([`crate::synth::heatmaps`]); single-frame initialisation from the arg-max, the EM,
//!   and the EM without temporal smoothness; P-MPJPE in mm and the 2D error in pixels of
//!   a 256-pixel crop.
//! - Per action (Table 2 style) and PCK (Table 4 style) on the heat-map runs.
//!
//! Each sequence gets its own camera azimuth (`47 deg x` its index), so the set covers
//! many views. Each subject is scaled to a body of known size (mean bone length
//! [`Settings::limb_length`], 0.25 m) before the cameras see it.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::time::Instant;

use crate::MappedSequence;
use crate::synth::{self, CameraSpec, ErrorModel, Projection, RenderedMaps, View, heatmaps};
use posestream_math::dictionary::Dictionary;
use posestream_math::error::EstimateError;
use posestream_math::estimator::{Estimate, Estimator, Keypoints};
use posestream_math::metrics;
use posestream_math::skeleton::Skeleton;
use posestream_math::solver::Params;

/// What the evaluation runs on.
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    /// Frames per sequence at most (from the start).
    pub max_frames: usize,
    /// Orbit speed of the moving camera of Table 1, deg/s.
    pub orbit_deg_per_s: f64,
    /// The heat-map camera (azimuth is set per sequence).
    pub camera: CameraSpec,
    /// The synthetic detector's error model (seeded per sequence from its `seed`).
    pub errors: ErrorModel,
    /// PCK threshold, pixels of a 256-pixel crop.
    pub pck_threshold: f64,
    /// Crop box side, times the joints' extent.
    pub margin: f64,
    /// Mean bone length (metres, over the layout's tree) every held-out subject is scaled
    /// to, so that millimetres refer to a body of known size.
    pub limb_length: f64,
    /// Actions of the per-action table (the held-out contents); empty = every action.
    pub actions: Vec<String>,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            max_frames: 150,
            orbit_deg_per_s: 15.0,
            camera: CameraSpec::default(),
            errors: ErrorModel::default(),
            pck_threshold: 10.0,
            margin: 1.25,
            limb_length: posestream_math::solver::perspective::PerspectiveParams::default()
                .mean_limb_length,
            actions: Vec::new(),
        }
    }
}

/// One held-out sequence, prepared.
#[derive(Debug, Clone)]
pub struct Case {
    /// File stem.
    pub name: String,
    /// Action (content) of the file.
    pub action: String,
    /// Orthographic static view (Table 1).
    pub still: View,
    /// Orthographic orbiting view (Table 1).
    pub orbit: View,
    /// Pinhole view the heat maps were rendered from (Table 3).
    pub pinhole: View,
    /// Heat maps of the pinhole view.
    pub maps: RenderedMaps,
}

impl Case {
    /// Prepares the views and heat maps of a mapped sequence; `index` picks its azimuth
    /// and the error model's seed.
    pub fn new(
        name: String,
        action: String,
        seq: &MappedSequence,
        skeleton: &Skeleton,
        settings: &Settings,
        index: usize,
    ) -> Result<Self, String> {
        let mut seq = seq
            .frames_from(0, settings.max_frames)
            .ok_or("the sequence has no frames")?;
        let scale = settings.limb_length / mean_bone_length(&seq, skeleton);
        if !scale.is_finite() {
            return Err("the subject's bones have no length".into());
        }
        seq.positions.iter_mut().for_each(|v| *v *= scale);
        let azimuth = (47.0 * index as f64) % 360.0;
        let ortho = CameraSpec {
            azimuth_deg: azimuth,
            projection: Projection::Orthographic,
            orbit_deg_per_s: 0.0,
            ..settings.camera.clone()
        };
        let still = synth::view(&seq, skeleton, &ortho)?;
        let orbit = synth::view(
            &seq,
            skeleton,
            &CameraSpec {
                orbit_deg_per_s: settings.orbit_deg_per_s,
                ..ortho
            },
        )?;
        let pin = CameraSpec {
            azimuth_deg: azimuth,
            ..settings.camera.clone()
        };
        let pinhole = synth::view(&seq, skeleton, &pin)?;
        let boxes = synth::crop_boxes(&pinhole.image_2d, pinhole.joints, settings.margin);
        let errors = ErrorModel {
            seed: settings.errors.seed.wrapping_add(index as u64),
            ..settings.errors.clone()
        };
        let maps = heatmaps::render(&pinhole.image_2d, &boxes, skeleton, &errors)
            .map_err(|e| e.to_string())?;
        Ok(Self {
            name,
            action,
            still,
            orbit,
            pinhole,
            maps,
        })
    }
}

/// The mean bone length of a sequence over the skeleton's tree (its units).
pub fn mean_bone_length(seq: &MappedSequence, skeleton: &Skeleton) -> f64 {
    let mut total = Mean::default();
    for frame in seq.positions.chunks_exact(3 * seq.joints) {
        for (a, b) in skeleton.bones() {
            let d: f64 = (0..3)
                .map(|i| (frame[3 * a + i] - frame[3 * b + i]).powi(2))
                .sum();
            total.add(d.sqrt(), 1.0);
        }
    }
    total.get()
}

/// A running, frame-weighted mean.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Mean {
    sum: f64,
    weight: f64,
}

impl Mean {
    /// Adds `value` with weight `weight`.
    pub fn add(&mut self, value: f64, weight: f64) {
        self.sum += value * weight;
        self.weight += weight;
    }

    /// The mean (NaN when empty).
    pub fn get(&self) -> f64 {
        if self.weight > 0.0 {
            self.sum / self.weight
        } else {
            f64::NAN
        }
    }
}

/// Scores of one method over the cases.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Score {
    /// P-MPJPE, mm.
    pub p_mpjpe_mm: Mean,
    /// 2D error, pixels of a 256-pixel crop (heat maps only).
    pub error_2d: Mean,
    /// PCK, percent (heat maps only).
    pub pck: Mean,
    /// Seconds per frame.
    pub seconds_per_frame: Mean,
    /// P-MPJPE per action, mm.
    pub per_action: BTreeMap<String, Mean>,
}

/// The results of one dictionary.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DictionaryResults {
    /// Label of the dictionary.
    pub label: String,
    /// Table 1: (camera, method) -> score; camera "static" or "orbit", method "init" or
    /// "algorithm 1".
    pub given_2d: BTreeMap<(String, String), Score>,
    /// Table 3: method ("init (arg-max)", "EM", "EM, no smoothness") -> score.
    pub heatmaps: Vec<(String, Score)>,
    /// Frames evaluated.
    pub frames: usize,
    /// Sequences evaluated.
    pub cases: usize,
}

fn timed(
    f: impl FnOnce() -> Result<Estimate, EstimateError>,
) -> Result<(Estimate, f64), EstimateError> {
    let start = Instant::now();
    let e = f()?;
    Ok((e, start.elapsed().as_secs_f64()))
}

/// Scores one dictionary case by case (so that cases need not be held in memory).
#[derive(Debug, Clone)]
pub struct Evaluator {
    estimator: Estimator,
    flat: Estimator,
    pck_threshold: f64,
    results: DictionaryResults,
}

/// The heat-map methods of Table 3, in order.
pub const HEATMAP_METHODS: [&str; 3] = ["init (arg-max)", "EM", "EM, no smoothness"];

impl Evaluator {
    /// An evaluator of `dict` under `params` (and the same without smoothness).
    pub fn new(
        label: &str,
        dict: &Dictionary,
        params: &Params,
        settings: &Settings,
    ) -> Result<Self, EstimateError> {
        Ok(Self {
            estimator: Estimator::new(dict.clone(), params.clone())?,
            flat: Estimator::new(dict.clone(), params.clone().without_smoothness())?,
            pck_threshold: settings.pck_threshold,
            results: DictionaryResults {
                label: label.to_string(),
                heatmaps: HEATMAP_METHODS
                    .iter()
                    .map(|m| (m.to_string(), Score::default()))
                    .collect(),
                ..Default::default()
            },
        })
    }

    /// Runs every method on one case and adds its scores.
    pub fn add(&mut self, case: &Case) -> Result<(), EstimateError> {
        let p = case.pinhole.joints;
        let f = case.pinhole.frames as f64;
        for (camera, view) in [("static", &case.still), ("orbit", &case.orbit)] {
            let kp = Keypoints {
                joints: p,
                xy: view.image_2d.clone(),
                confidence: None,
            };
            for (method, run) in [
                ("init", timed(|| self.estimator.initialise_keypoints(&kp))?),
                ("algorithm 1", timed(|| self.estimator.lift_keypoints(&kp))?),
            ] {
                let s = self
                    .results
                    .given_2d
                    .entry((camera.to_string(), method.to_string()))
                    .or_default();
                let e = 1000.0 * metrics::p_mpjpe(&run.0.poses, &view.camera_3d, p);
                s.p_mpjpe_mm.add(e, f);
                s.seconds_per_frame.add(run.1 / f, f);
            }
        }
        let maps = &case.maps.maps;
        let runs = [
            timed(|| self.estimator.initialise_heatmaps(maps))?,
            timed(|| self.estimator.lift_heatmaps(maps))?,
            timed(|| self.flat.lift_heatmaps(maps))?,
        ];
        let to_256 = 256.0 / maps.height as f64;
        for (i, (est, seconds)) in runs.iter().enumerate() {
            let s = &mut self.results.heatmaps[i].1;
            let e = 1000.0 * metrics::p_mpjpe(&est.poses, &case.pinhole.camera_3d, p);
            s.p_mpjpe_mm.add(e, f);
            // The baseline's 2D answer is the arg-max itself; the others' is the model's
            // reprojection.
            let xy = if i == 0 {
                &est.keypoints
            } else {
                &est.projected
            };
            s.error_2d
                .add(to_256 * metrics::mean_error_2d(xy, &case.maps.truth), f);
            let pck = metrics::pck(xy, &case.maps.truth, self.pck_threshold / to_256);
            s.pck.add(100.0 * pck, f);
            s.seconds_per_frame.add(seconds / f, f);
            s.per_action
                .entry(case.action.clone())
                .or_default()
                .add(e, f);
        }
        self.results.frames += case.pinhole.frames;
        self.results.cases += 1;
        Ok(())
    }

    /// The scores so far.
    pub fn results(&self) -> &DictionaryResults {
        &self.results
    }
}

/// Runs every method of the tables with one dictionary over the cases.
pub fn evaluate(
    label: &str,
    dict: &Dictionary,
    params: &Params,
    cases: &[Case],
    settings: &Settings,
) -> Result<DictionaryResults, EstimateError> {
    let mut ev = Evaluator::new(label, dict, params, settings)?;
    for case in cases {
        ev.add(case)?;
    }
    Ok(ev.results)
}

/// The markdown tables of the results.
pub fn markdown(results: &[DictionaryResults], settings: &Settings) -> String {
    let mut s = String::new();
    let (cases, frames) = results.first().map_or((0, 0), |r| (r.cases, r.frames));
    let _ = writeln!(
        s,
        "Held-out sequences: {cases}, {frames} frames (first {} frames of each file at most), \
each subject scaled to a mean bone length of {} m.\n",
        settings.max_frames, settings.limb_length
    );
    let _ = writeln!(
        s,
        "## Table 1: given 2D joints, P-MPJPE (mm)\n\nOrthographic projection; a static camera and one orbiting at {} deg/s.\n",
        settings.orbit_deg_per_s
    );
    let _ = writeln!(
        s,
        "| dictionary | static: single frame | static: Algorithm 1 | orbit: single frame | orbit: Algorithm 1 |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|");
    for r in results {
        let g = |c: &str, m: &str| {
            r.given_2d
                .get(&(c.to_string(), m.to_string()))
                .map_or(f64::NAN, |s| s.p_mpjpe_mm.get())
        };
        let _ = writeln!(
            s,
            "| {} | {:.1} | {:.1} | {:.1} | {:.1} |",
            r.label,
            g("static", "init"),
            g("static", "algorithm 1"),
            g("orbit", "init"),
            g("orbit", "algorithm 1")
        );
    }
    let e = &settings.errors;
    let _ = writeln!(
        s,
        "\n## Table 3: heat maps\n\nPinhole camera at {} m, focal {} px; {}x{} heat maps in a square crop ({}x the body's extent). \
Error model: localisation noise {} cells, blob {} cells, swaps {}/frame/pair, occlusions {}/frame/joint, missing {}/frame/joint, \
episodes of {} frames, background {}. 2D error and PCK@{} px are in pixels of a 256-pixel crop; the single-frame row scores \
the arg-max itself, the others the model's reprojection.\n",
        settings.camera.distance,
        settings.camera.focal,
        e.size[0],
        e.size[1],
        settings.margin,
        e.noise,
        e.blob,
        e.swap_rate,
        e.occlusion_rate,
        e.missing_rate,
        e.episode_frames,
        e.background,
        settings.pck_threshold
    );
    let _ = writeln!(
        s,
        "| dictionary | method | 3D P-MPJPE (mm) | 2D error (px) | PCK@{} (%) | ms/frame |",
        settings.pck_threshold
    );
    let _ = writeln!(s, "|---|---|---:|---:|---:|---:|");
    for r in results {
        for (m, sc) in &r.heatmaps {
            let _ = writeln!(
                s,
                "| {} | {} | {:.1} | {:.2} | {:.1} | {:.2} |",
                r.label,
                m,
                sc.p_mpjpe_mm.get(),
                sc.error_2d.get(),
                sc.pck.get(),
                1000.0 * sc.seconds_per_frame.get()
            );
        }
    }
    let _ = writeln!(
        s,
        "\n## Table 2 style: heat maps, P-MPJPE (mm) per action\n"
    );
    let actions: Vec<String> = results
        .first()
        .and_then(|r| r.heatmaps.first())
        .map(|(_, sc)| {
            sc.per_action
                .keys()
                .filter(|a| settings.actions.is_empty() || settings.actions.contains(a))
                .cloned()
                .collect()
        })
        .unwrap_or_default();
    let _ = writeln!(s, "| dictionary | method | {} |", actions.join(" | "));
    let _ = writeln!(s, "|---|---|{}", "---:|".repeat(actions.len()));
    for r in results {
        for (m, sc) in &r.heatmaps {
            let cells: Vec<String> = actions
                .iter()
                .map(|a| format!("{:.1}", sc.per_action.get(a).map_or(f64::NAN, Mean::get)))
                .collect();
            let _ = writeln!(s, "| {} | {} | {} |", r.label, m, cells.join(" | "));
        }
    }
    let _ = writeln!(
        s,
        "\n## Table 4 style: PCK and time per frame\n\nPCK@{} px (256-pixel crop) on the heat-map sequences; wall time per frame of each stage on one core \
(single frame = the per-frame initialisation alone; EM includes its initialisation).\n",
        settings.pck_threshold
    );
    let _ = writeln!(s, "| dictionary | stage | PCK (%) | ms/frame |");
    let _ = writeln!(s, "|---|---|---:|---:|");
    for r in results {
        for ((camera, method), sc) in &r.given_2d {
            let _ = writeln!(
                s,
                "| {} | given 2D, {camera} camera: {method} | | {:.2} |",
                r.label,
                1000.0 * sc.seconds_per_frame.get()
            );
        }
        for (m, sc) in &r.heatmaps {
            let _ = writeln!(
                s,
                "| {} | heat maps: {m} | {:.1} | {:.2} |",
                r.label,
                sc.pck.get(),
                1000.0 * sc.seconds_per_frame.get()
            );
        }
    }
    s
}
