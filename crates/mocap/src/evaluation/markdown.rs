//! The markdown tables of the results ([`markdown`]), as in `docs/results.md`.

use std::fmt::Write as _;

use super::{CALIBRATION_Z, DictionaryResults, Mean, Settings};

/// The markdown tables of the results.
pub fn markdown(results: &[DictionaryResults], settings: &Settings) -> String {
    let mut s = String::new();
    let (cases, frames) = results.first().map_or((0, 0), |r| (r.cases, r.frames));
    let _ = writeln!(
        s,
        "{} sequences: {cases}, {frames} frames (first {} frames of each file at most), \
each subject scaled to a mean bone length of {} m.\n",
        if settings.training {
            "Training"
        } else {
            "Held-out"
        },
        settings.max_frames,
        settings.limb_length
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
        "| dictionary | method | 3D P-MPJPE (mm) | median / 90th percentile frame (mm) | 2D error (px) | PCK@{} (%) | ms/frame |",
        settings.pck_threshold
    );
    let _ = writeln!(s, "|---|---|---:|---:|---:|---:|---:|");
    for r in results {
        for (m, sc) in &r.heatmaps {
            let _ = writeln!(
                s,
                "| {} | {} | {:.1} | {:.1} / {:.1} | {:.2} | {:.1} | {:.2} |",
                r.label,
                m,
                sc.p_mpjpe_mm.get(),
                sc.frame_quantile(0.5),
                sc.frame_quantile(0.9),
                sc.error_2d.get(),
                sc.pck.get(),
                1000.0 * sc.seconds_per_frame.get()
            );
        }
    }
    let _ = writeln!(
        s,
        "\n## Uncertainty: reliability of the per-joint standard deviations\n\nThe fraction of pose \
coordinates (x, y, z of every joint, after the similarity alignment of P-MPJPE, which scales the \
deviations too) whose error lies within z standard deviations, against a normal distribution's. \
Methods without deviations are left out.\n"
    );
    let mut heads: Vec<String> = CALIBRATION_Z
        .iter()
        .map(|(z, nominal)| format!("within {z:.2} std (normal: {nominal:.1} %)"))
        .collect();
    heads.push("x, y: within 1 / 2 std".into());
    heads.push("z: within 1 / 2 std".into());
    heads.push("factor on x, y / z std for 68.3 % within 1 std".into());
    heads.push("the same for 95.45 % within 2 std".into());
    let _ = writeln!(s, "| dictionary | method | {} |", heads.join(" | "));
    let _ = writeln!(s, "|---|---|{}", "---:|".repeat(heads.len()));
    for r in results {
        for (m, sc) in &r.heatmaps {
            if sc.ratios.is_empty() {
                continue;
            }
            let mut cells: Vec<String> = CALIBRATION_Z
                .iter()
                .map(|(z, _)| format!("{:.1} %", 100.0 * sc.ratios.within(*z)))
                .collect();
            for h in [&sc.lateral_ratios, &sc.depth_ratios] {
                cells.push(format!(
                    "{:.1} % / {:.1} %",
                    100.0 * h.within(1.0),
                    100.0 * h.within(2.0)
                ));
            }
            for (q, z) in [(0.6827, 1.0), (0.9545, 2.0)] {
                cells.push(format!(
                    "{:.2} / {:.2}",
                    sc.lateral_ratios.scale_for(q) / z,
                    sc.depth_ratios.scale_for(q) / z
                ));
            }
            let _ = writeln!(s, "| {} | {} | {} |", r.label, m, cells.join(" | "));
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
