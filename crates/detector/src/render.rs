//! Pictures of results, like the paper's Figures 3-4: the camera image with the heat
//! maps laid over it and the 2D skeleton drawn on it, beside the 3D skeleton seen from
//! a novel viewpoint. Pure drawing: a frame, its heat maps and its [`Skeleton3D`] in,
//! an RGB image out.

use image::{Rgb, RgbImage};
use imageproc::drawing::{draw_filled_circle_mut, draw_hollow_rect_mut, draw_line_segment_mut};
use imageproc::rect::Rect;

use posestream_msgs::{HeatMaps, Skeleton3D};

/// How a frame is drawn.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderSettings {
    /// Height of the picture, pixels (the camera image is scaled to it).
    pub height: u32,
    /// The 3D view's rotation about the vertical axis, degrees (0: the camera's view).
    pub azimuth_deg: f64,
    /// Its elevation, degrees (positive: from above).
    pub elevation_deg: f64,
    /// Opacity of the heat-map overlay at a score of 1.
    pub overlay: f32,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            height: 360,
            azimuth_deg: 60.0,
            elevation_deg: 15.0,
            overlay: 0.7,
        }
    }
}

const LEFT: Rgb<u8> = Rgb([60, 140, 255]);
const RIGHT: Rgb<u8> = Rgb([255, 90, 60]);
const CENTRE: Rgb<u8> = Rgb([80, 220, 80]);
const BOX: Rgb<u8> = Rgb([255, 255, 0]);
const BACKGROUND: Rgb<u8> = Rgb([24, 24, 28]);

/// The colour of the bone ending at joint `name`: left blue, right red, else green.
fn side_colour(name: &str) -> Rgb<u8> {
    if name.starts_with("l-") || name.starts_with("left") {
        LEFT
    } else if name.starts_with("r-") || name.starts_with("right") {
        RIGHT
    } else {
        CENTRE
    }
}

fn thick_line(img: &mut RgbImage, a: [f32; 2], b: [f32; 2], colour: Rgb<u8>, width: i32) {
    let r = width / 2;
    for dx in -r..=r {
        for dy in -r..=r {
            let (ox, oy) = (dx as f32, dy as f32);
            draw_line_segment_mut(img, (a[0] + ox, a[1] + oy), (b[0] + ox, b[1] + oy), colour);
        }
    }
}

/// Blends the heat maps over `img` (which shows the image at `scale` times its size):
/// each pixel of the crop box gets the largest score of any joint at its cell.
fn overlay_heatmaps(img: &mut RgbImage, maps: &HeatMaps, scale: f64, opacity: f32) {
    let mut values = Vec::new();
    let Ok(crop) = maps.crop() else { return };
    if maps.values_into(&mut values).is_err() {
        return;
    }
    let (mw, mh) = (maps.width as usize, maps.height as usize);
    let cells = mw * mh;
    let mut peak = vec![0.0_f32; cells];
    for map in values.chunks_exact(cells) {
        for (p, v) in peak.iter_mut().zip(map) {
            *p = p.max(*v);
        }
    }
    let (w, h) = img.dimensions();
    let x_range = ((crop.x0 * scale).max(0.0) as u32)
        ..(((crop.x0 + crop.width) * scale).min(f64::from(w)).max(0.0) as u32);
    let y_range = ((crop.y0 * scale).max(0.0) as u32)
        ..(((crop.y0 + crop.height) * scale).min(f64::from(h)).max(0.0) as u32);
    for y in y_range {
        let v = ((f64::from(y) / scale - crop.y0) / crop.height * mh as f64) as usize;
        for x in x_range.clone() {
            let u = ((f64::from(x) / scale - crop.x0) / crop.width * mw as f64) as usize;
            let a = opacity * peak[v.min(mh - 1) * mw + u.min(mw - 1)].clamp(0.0, 1.0);
            let p = img.get_pixel_mut(x, y);
            let hot = [255.0, 40.0 + 200.0 * a, 0.0];
            for (channel, h) in p.0.iter_mut().zip(hot) {
                *channel = (f32::from(*channel) * (1.0 - a) + h * a) as u8;
            }
        }
    }
    let to = |v: f64| (v * scale) as i32;
    let side = ((crop.width * scale) as u32).max(1);
    draw_hollow_rect_mut(
        img,
        Rect::at(to(crop.x0), to(crop.y0)).of_size(side, ((crop.height * scale) as u32).max(1)),
        BOX,
    );
}

/// The 2D skeleton (`keypoints`, image pixels) over `img`, shown at `scale`.
fn draw_skeleton_2d(img: &mut RgbImage, s: &Skeleton3D, bones: &[(usize, usize)], scale: f64) {
    let point = |j: usize| -> Option<[f32; 2]> {
        let (x, y) = (*s.keypoints.get(2 * j)?, *s.keypoints.get(2 * j + 1)?);
        (x.is_finite() && y.is_finite()).then_some([(x * scale) as f32, (y * scale) as f32])
    };
    for &(a, b) in bones {
        if let (Some(pa), Some(pb)) = (point(a), point(b)) {
            let name = s.joint_names.get(b).map_or("", String::as_str);
            thick_line(img, pa, pb, side_colour(name), 3);
        }
    }
    for j in 0..s.joint_names.len() {
        if let Some(p) = point(j) {
            draw_filled_circle_mut(img, (p[0] as i32, p[1] as i32), 3, Rgb([255, 255, 255]));
        }
    }
}

/// The 3D skeletons of one frame in a `side x side` panel, rotated by the settings'
/// azimuth and elevation about their centre, drawn orthographically (y down, as the
/// camera). Skeletons in metres stand where they are; others (each centred on itself)
/// side by side.
pub fn skeleton_view(
    skeletons: &[&Skeleton3D],
    bones: &[(usize, usize)],
    side: u32,
    settings: &RenderSettings,
) -> RgbImage {
    let mut img = RgbImage::from_pixel(side, side, BACKGROUND);
    let metric = skeletons
        .iter()
        .all(|s| s.units == posestream_msgs::Units::Metres as u8);
    let mut people: Vec<Vec<[f64; 3]>> = Vec::new();
    for s in skeletons {
        let joints: Vec<[f64; 3]> = s
            .positions
            .chunks_exact(3)
            .map(|p| [p[0], p[1], p[2]])
            .collect();
        if joints.is_empty() || joints.iter().flatten().any(|v| !v.is_finite()) {
            continue;
        }
        people.push(joints);
    }
    if !metric {
        let spacing = 2.2
            * people
                .iter()
                .flatten()
                .flatten()
                .fold(1e-9, |m: f64, v| m.max(v.abs()));
        for (i, joints) in people.iter_mut().enumerate() {
            let n = joints.len() as f64;
            let mean: [f64; 3] =
                std::array::from_fn(|k| joints.iter().map(|p| p[k]).sum::<f64>() / n);
            for p in joints.iter_mut() {
                p[0] += i as f64 * spacing - mean[0];
                p[1] -= mean[1];
                p[2] -= mean[2];
            }
        }
    }
    let all: Vec<[f64; 3]> = people.iter().flatten().copied().collect();
    if all.is_empty() {
        return img;
    }
    let n = all.len() as f64;
    let mean: [f64; 3] = std::array::from_fn(|k| all.iter().map(|p| p[k]).sum::<f64>() / n);
    let (az, el) = (
        settings.azimuth_deg.to_radians(),
        settings.elevation_deg.to_radians(),
    );
    let project = |p: &[f64; 3]| {
        let (x, y, z) = (p[0] - mean[0], p[1] - mean[1], p[2] - mean[2]);
        // About the vertical (y) axis, then tilted about x.
        let (x1, z1) = (x * az.cos() + z * az.sin(), -x * az.sin() + z * az.cos());
        let y1 = y * el.cos() - z1 * el.sin();
        [x1, y1]
    };
    let views: Vec<Vec<[f64; 2]>> = people
        .iter()
        .map(|joints| joints.iter().map(project).collect())
        .collect();
    let extent = views
        .iter()
        .flatten()
        .flat_map(|p| [p[0].abs(), p[1].abs()])
        .fold(1e-9, f64::max);
    let k = 0.42 * f64::from(side) / extent;
    let c = 0.5 * f64::from(side);
    let screen = |p: [f64; 2]| [(c + k * p[0]) as f32, (c + k * p[1]) as f32];
    // The floor under the lowest joint.
    let floor = views
        .iter()
        .flatten()
        .map(|p| p[1])
        .fold(f64::MIN, f64::max);
    let fy = (c + k * floor) as f32 + 6.0;
    draw_line_segment_mut(
        &mut img,
        (0.15 * side as f32, fy),
        (0.85 * side as f32, fy),
        Rgb([90, 90, 100]),
    );
    let names = skeletons
        .iter()
        .find(|s| !s.joint_names.is_empty())
        .map_or(&[][..], |s| s.joint_names.as_slice());
    for view in &views {
        for &(a, b) in bones {
            if let (Some(&pa), Some(&pb)) = (view.get(a), view.get(b)) {
                let name = names.get(b).map_or("", String::as_str);
                thick_line(&mut img, screen(pa), screen(pb), side_colour(name), 3);
            }
        }
        for p in view {
            let q = screen(*p);
            draw_filled_circle_mut(
                &mut img,
                (q[0] as i32, q[1] as i32),
                3,
                Rgb([255, 255, 255]),
            );
        }
    }
    img
}

/// One person of a frame to draw: their heat maps (if recorded) and skeleton.
#[derive(Debug, Clone, Copy)]
pub struct Person<'a> {
    /// The heat maps the skeleton came from.
    pub maps: Option<&'a HeatMaps>,
    /// The skeleton.
    pub skeleton: &'a Skeleton3D,
}

/// One frame: the image (scaled to the settings' height) with each person's heat maps
/// (if any) and 2D skeleton, beside their 3D skeletons from the novel view.
pub fn render_frame(
    image: &RgbImage,
    people: &[Person<'_>],
    bones: &[(usize, usize)],
    settings: &RenderSettings,
) -> RgbImage {
    let height = settings.height.max(16);
    let scale = f64::from(height) / f64::from(image.height().max(1));
    let width = ((f64::from(image.width()) * scale).round() as u32).max(1);
    let mut left =
        image::imageops::resize(image, width, height, image::imageops::FilterType::Triangle);
    for p in people {
        if let Some(m) = p.maps {
            overlay_heatmaps(&mut left, m, scale, settings.overlay);
        }
    }
    for p in people {
        draw_skeleton_2d(&mut left, p.skeleton, bones, scale);
    }
    let skeletons: Vec<&Skeleton3D> = people.iter().map(|p| p.skeleton).collect();
    let right = skeleton_view(&skeletons, bones, height, settings);
    let mut out = RgbImage::from_pixel(width + height, height, BACKGROUND);
    image::imageops::replace(&mut out, &left, 0, 0);
    image::imageops::replace(&mut out, &right, i64::from(width), 0);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn skeleton() -> Skeleton3D {
        Skeleton3D {
            joint_names: vec!["pelvis".into(), "l-hip".into(), "r-hip".into()],
            positions: vec![0.0, 0.0, 5.0, 1.0, 0.0, 5.0, -1.0, 0.0, 5.0],
            keypoints: vec![50.0, 50.0, 60.0, 50.0, 40.0, 50.0],
            ..Default::default()
        }
    }

    #[test]
    fn the_picture_holds_the_image_and_the_view_with_coloured_bones() {
        let image = RgbImage::from_pixel(200, 100, Rgb([0, 0, 0]));
        let bones = [(0, 1), (0, 2)];
        let settings = RenderSettings {
            height: 100,
            azimuth_deg: 0.0,
            elevation_deg: 0.0,
            overlay: 0.7,
        };
        let s = skeleton();
        let out = render_frame(
            &image,
            &[Person {
                maps: None,
                skeleton: &s,
            }],
            &bones,
            &settings,
        );
        assert_eq!(out.dimensions(), (300, 100));
        // The left hip's bone is blue in the image, right of the pelvis.
        assert_eq!(*out.get_pixel(55, 50), LEFT);
        assert_eq!(*out.get_pixel(45, 50), RIGHT);
        // The 3D view (camera view: no rotation) has them on the same sides.
        let blue = (200..300)
            .filter(|&x| *out.get_pixel(x, 50) == LEFT)
            .count();
        assert!(blue > 10, "{blue}");
        assert!((250..300).any(|x| *out.get_pixel(x, 50) == LEFT));
    }

    #[test]
    fn a_skeleton_with_nan_draws_an_empty_view_without_panicking() {
        let mut s = skeleton();
        s.positions[0] = f64::NAN;
        let view = skeleton_view(&[&s], &[(0, 1)], 50, &RenderSettings::default());
        assert!(view.pixels().all(|p| *p == BACKGROUND));
    }

    #[test]
    fn two_people_in_dictionary_units_stand_side_by_side() {
        let (a, b) = (skeleton(), skeleton());
        let front = RenderSettings {
            azimuth_deg: 0.0,
            elevation_deg: 0.0,
            ..RenderSettings::default()
        };
        let one = skeleton_view(&[&a], &[(0, 1), (0, 2)], 100, &front);
        let two = skeleton_view(&[&a, &b], &[(0, 1), (0, 2)], 100, &front);
        let white = |img: &RgbImage| img.pixels().filter(|p| **p == Rgb([255, 255, 255])).count();
        assert!(white(&two) > white(&one), "two people, more joints drawn");
    }
}
