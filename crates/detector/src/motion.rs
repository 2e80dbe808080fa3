//! Where something moves: proposals for the landmark model from a fixed camera's
//! frame differences (`[detector.images] motion`).
//!
//! BlazePose's person detector finds people by their faces: on real footage of people
//! 5-15 m away, seen from above and often from behind, it found under half of them
//! (benches/footage: vtest.avi). A fixed camera's people are what moves: a running
//! average of the frames (grey, at most [`WIDTH`] px wide) is the background; pixels off
//! it by more than [`THRESHOLD`] grey levels, opened (specks removed) and dilated (a
//! body's parts joined), make blobs; a blob of a person's shape (at least
//! `min_height` px tall, taller than a quarter of its width) is proposed as a person
//! box, and a blob wider than one person is proposed as several side by side. The
//! landmark model then looks at each: only a pose it finds there (its presence flag) makes
//! a person, so a car or a shadow proposes, and is refused.
//!
//! When more than [`MOVED`] of the image changes at once (or [`MOVED_EDGE`] of its
//! edge), the camera moved (or the light changed): nothing is proposed and the
//! background restarts from that frame; proposals resume after [`STILL_FRAMES`] still
//! ones.
//! A moving camera therefore gets no proposals from here; its people come from the
//! person detector only.

use image::{GrayImage, Luma, RgbImage};
use imageproc::distance_transform::Norm;
use imageproc::region_labelling::{Connectivity, connected_components};
use posestream_base::CropBox;

/// The background is kept at most this wide (px).
pub const WIDTH: u32 = 384;
/// A pixel off the background by more than this (grey levels, 0-255) is moving.
pub const THRESHOLD: f32 = 18.0;
/// The background takes this share of each new frame (slower where something moves kept
/// people who stop in view longer, but left ghosts where they had stood, which cost
/// identities: IDF1 0.66 -> 0.48 on vtest.avi).
pub const ADAPTATION: f32 = 0.02;
/// More than this share of the image moving, or more than [`MOVED_EDGE`] of its edge
/// (a band of a tenth of its height all round, where people rarely fill the view): the
/// camera moved.
pub const MOVED: f64 = 0.25;
/// See [`MOVED`].
pub const MOVED_EDGE: f64 = 0.15;
/// Proposals start only after the camera has been still for this many frames (a camera
/// panning slowly changes less than [`MOVED`] between two frames).
pub const STILL_FRAMES: u64 = 10;
/// A person box's square crop: its side over the box's height, centred on the box
/// (MediaPipe's box from the alignment circle is 2.5 radii, about 1.4 heights).
pub const CROP_PER_HEIGHT: f64 = 1.4;
/// A blob wider than this many times its height holds several people side by side.
const ONE_PERSON_WIDTH: f64 = 0.4;

/// The running background and its scratch images (reused frame to frame).
#[derive(Debug, Default)]
pub struct Motion {
    background: Vec<f32>,
    grey: GrayImage,
    mask: GrayImage,
    /// Downscale factor of the kept images (full-size pixels per kept pixel).
    step: u32,
    size: (u32, u32),
    /// Frames since the background (re)started.
    frames: u64,
}

impl Motion {
    /// A motion model; it starts with the first frame it sees.
    pub fn new() -> Self {
        Self::default()
    }

    /// Takes `rgb` into the background and returns the person boxes proposed, image
    /// pixels, tallest first; none while the background is new (fewer than
    /// [`STILL_FRAMES`]) or when the camera moved.
    pub fn update(&mut self, rgb: &RgbImage, min_height: f64) -> Vec<CropBox> {
        let (w, h) = rgb.dimensions();
        if w == 0 || h == 0 {
            return Vec::new();
        }
        if self.size != (w, h) {
            self.size = (w, h);
            self.step = w.div_ceil(WIDTH).max(1);
            self.frames = 0;
        }
        let step = self.step;
        let (gw, gh) = (w / step, h / step);
        if gw < 2 || gh < 2 {
            // Too small or too flat to hold a person at this scale (and imageproc's
            // connected components panic on a 1 x 1 image).
            return Vec::new();
        }
        if self.grey.dimensions() != (gw, gh) {
            self.grey = GrayImage::new(gw, gh);
            self.mask = GrayImage::new(gw, gh);
        }
        // Grey, averaged over step x step blocks.
        let raw = rgb.as_raw();
        let area = (step * step) as f32;
        for gy in 0..gh {
            for gx in 0..gw {
                let mut sum = 0u64;
                for y in gy * step..(gy + 1) * step {
                    let row = (y * w) as usize * 3;
                    for x in gx * step..(gx + 1) * step {
                        let p = row + x as usize * 3;
                        // ITU-R BT.601 luma in integers.
                        sum += (77 * u64::from(raw[p])
                            + 150 * u64::from(raw[p + 1])
                            + 29 * u64::from(raw[p + 2]))
                            >> 8;
                    }
                }
                self.grey
                    .put_pixel(gx, gy, Luma([(sum as f32 / area) as u8]));
            }
        }
        let n = (gw * gh) as usize;
        if self.frames == 0 || self.background.len() != n {
            self.background.clear();
            self.background
                .extend(self.grey.as_raw().iter().map(|&v| f32::from(v)));
            self.frames = 1;
            return Vec::new();
        }
        let (mut moving, mut edge_moving, mut edge) = (0usize, 0usize, 0usize);
        let band = (gh / 10).max(1);
        for (i, ((b, &g), m)) in self
            .background
            .iter_mut()
            .zip(self.grey.as_raw())
            .zip(self.mask.iter_mut())
            .enumerate()
        {
            let g = f32::from(g);
            let on = (g - *b).abs() > THRESHOLD;
            moving += usize::from(on);
            let (x, y) = (i as u32 % gw, i as u32 / gw);
            if x < band || y < band || x + band >= gw || y + band >= gh {
                edge += 1;
                edge_moving += usize::from(on);
            }
            *m = if on { 255 } else { 0 };
            *b += ADAPTATION * (g - *b);
        }
        self.frames += 1;
        if moving as f64 > MOVED * n as f64 || edge_moving as f64 > MOVED_EDGE * edge as f64 {
            // The camera moved: start again from this frame.
            self.background.clear();
            self.background
                .extend(self.grey.as_raw().iter().map(|&v| f32::from(v)));
            self.frames = 1;
            return Vec::new();
        }
        if self.frames < STILL_FRAMES {
            return Vec::new();
        }
        imageproc::morphology::open_mut(&mut self.mask, Norm::LInf, 1);
        imageproc::morphology::dilate_mut(&mut self.mask, Norm::LInf, 3);
        let labels = connected_components(&self.mask, Connectivity::Eight, Luma([0u8]));
        // Each blob's extent, kept pixels.
        let mut extents: Vec<[u32; 4]> = Vec::new();
        for (x, y, l) in labels.enumerate_pixels() {
            let l = l[0] as usize;
            if l == 0 {
                continue;
            }
            if extents.len() < l {
                extents.resize(l, [u32::MAX, u32::MAX, 0, 0]);
            }
            let e = &mut extents[l - 1];
            e[0] = e[0].min(x);
            e[1] = e[1].min(y);
            e[2] = e[2].max(x + 1);
            e[3] = e[3].max(y + 1);
        }
        let s = f64::from(step);
        let mut boxes: Vec<CropBox> = Vec::new();
        for e in extents.iter().filter(|e| e[2] > e[0]) {
            let (x0, y0) = (f64::from(e[0]) * s, f64::from(e[1]) * s);
            let (bw, bh) = (f64::from(e[2] - e[0]) * s, f64::from(e[3] - e[1]) * s);
            if bh < min_height || bw * 0.25 > bh {
                continue;
            }
            // Several people side by side: one box per person's width.
            let people = (bw / (ONE_PERSON_WIDTH * bh)).round().max(1.0);
            let each = bw / people;
            for k in 0..people as usize {
                let cx = x0 + (k as f64 + 0.5) * each;
                let cy = y0 + 0.5 * bh;
                let side = CROP_PER_HEIGHT * bh;
                if let Ok(b) = CropBox::new(cx - 0.5 * side, cy - 0.5 * side, side, side) {
                    boxes.push(b);
                }
            }
        }
        boxes.sort_by(|a, b| b.height.total_cmp(&a.height));
        boxes
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(people: &[(u32, u32, u32, u32)]) -> RgbImage {
        let mut img = RgbImage::from_pixel(640, 480, image::Rgb([120, 130, 110]));
        for &(x, y, w, h) in people {
            for yy in y..y + h {
                for xx in x..x + w {
                    img.put_pixel(xx, yy, image::Rgb([20, 20, 30]));
                }
            }
        }
        img
    }

    #[test]
    fn a_moving_figure_is_proposed_where_it_is() {
        let mut m = Motion::new();
        for i in 0..STILL_FRAMES as u32 {
            let boxes = m.update(&scene(&[(100 + 5 * (i % 2), 200, 30, 90)]), 40.0);
            if u64::from(i) + 1 < STILL_FRAMES {
                assert!(boxes.is_empty());
            }
        }
        let boxes = m.update(&scene(&[(160, 200, 30, 90)]), 40.0);
        // The figure now (and where it stood: the background still holds it).
        let on_it = boxes.iter().any(|b| {
            let (cx, cy) = (b.x0 + b.width / 2.0, b.y0 + b.height / 2.0);
            (150.0..200.0).contains(&cx) && (220.0..270.0).contains(&cy) && b.width > 90.0
        });
        assert!(on_it, "{boxes:?}");
    }

    #[test]
    fn nothing_is_proposed_when_the_camera_moves_or_nothing_does() {
        let mut m = Motion::new();
        for _ in 0..5 {
            assert!(m.update(&scene(&[(100, 200, 30, 90)]), 40.0).is_empty());
        }
        // Everything changes at once.
        let mut other = scene(&[]);
        for p in other.pixels_mut() {
            *p = image::Rgb([250, 250, 250]);
        }
        assert!(m.update(&other, 40.0).is_empty());
        // Small specks and flat blobs are not people.
        let mut m = Motion::new();
        for _ in 0..STILL_FRAMES {
            m.update(&scene(&[]), 40.0);
        }
        assert!(
            m.update(&scene(&[(300, 300, 2, 2), (150, 150, 200, 20)]), 40.0)
                .is_empty()
        );
    }

    #[test]
    fn images_too_flat_or_empty_propose_nothing() {
        let mut m = Motion::new();
        for _ in 0..STILL_FRAMES + 2 {
            assert!(m.update(&RgbImage::new(1920, 2), 1.0).is_empty());
            assert!(m.update(&RgbImage::new(0, 0), 1.0).is_empty());
        }
        // A 1 x 1 video (imageproc's connected components panicked on its mask).
        let mut m = Motion::new();
        for _ in 0..STILL_FRAMES + 2 {
            let one = RgbImage::from_pixel(1, 1, image::Rgb([128; 3]));
            assert!(m.update(&one, 1.0).is_empty());
        }
    }

    #[test]
    fn people_side_by_side_are_proposed_each() {
        let mut m = Motion::new();
        for _ in 0..STILL_FRAMES {
            m.update(&scene(&[]), 40.0);
        }
        let boxes = m.update(&scene(&[(200, 150, 34, 100), (236, 150, 34, 100)]), 40.0);
        assert_eq!(boxes.len(), 2, "{boxes:?}");
    }
}
