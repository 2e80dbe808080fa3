//! Person boxes and crops: the square [`CropBox`] the landmark model looks at, where it
//! comes from (the whole image, an explicit box, the previous frame's landmarks), and
//! the resampling of that box of the image into the model's input.

use posestream_base::CropBox;

/// The square box centred on the image whose side is the image's longer side (the
/// image letterboxed): where to look when nothing better is known.
pub fn whole_image_box(width: u32, height: u32) -> CropBox {
    let side = f64::from(width.max(height).max(1));
    CropBox {
        x0: 0.5 * (f64::from(width) - side),
        y0: 0.5 * (f64::from(height) - side),
        width: side,
        height: side,
    }
}

/// The square box around `b` (same centre, side = the longer side).
pub fn squared(b: &CropBox) -> CropBox {
    let side = b.width.max(b.height);
    CropBox {
        x0: b.x0 + 0.5 * (b.width - side),
        y0: b.y0 + 0.5 * (b.height - side),
        width: side,
        height: side,
    }
}

/// Square tiles covering `area` where people look bigger than in the whole: `n` along
/// its longer side (each `1.25 / n` of it, overlapping), as many along the shorter as
/// cover it (centred when one is enough); none for `n <= 1`.
pub fn tiles(area: &CropBox, n: u32) -> Vec<CropBox> {
    if n <= 1 {
        return Vec::new();
    }
    let long = area.width.max(area.height);
    let side = (1.25 * long / f64::from(n)).min(long);
    let starts = |origin: f64, length: f64| -> Vec<f64> {
        if length <= side {
            return vec![origin + 0.5 * (length - side)];
        }
        let count = ((length - side) / (0.8 * side)).ceil() as usize + 1;
        let step = (length - side) / (count - 1) as f64;
        (0..count).map(|k| origin + k as f64 * step).collect()
    };
    let (xs, ys) = (starts(area.x0, area.width), starts(area.y0, area.height));
    ys.iter()
        .flat_map(|&y0| {
            xs.iter().map(move |&x0| CropBox {
                x0,
                y0,
                width: side,
                height: side,
            })
        })
        .collect()
}

/// MediaPipe's person box from two alignment keypoints, image pixels: `centre` (the
/// hips' midpoint) and `scale` (a point whose distance to the centre is the radius of
/// the circle holding the body). The box is square, centred on `centre`, its side the
/// circle's diameter times 1.25 (as MediaPipe's `RectTransformationCalculator`). Unlike
/// MediaPipe the box is not rotated upright: crops stay axis-aligned. `None` for a box
/// smaller than `min_side` pixels or a non-finite one.
pub fn box_from_alignment(centre: [f64; 2], scale: [f64; 2], min_side: f64) -> Option<CropBox> {
    let radius = (scale[0] - centre[0]).hypot(scale[1] - centre[1]);
    let side = 2.0 * radius * 1.25;
    if !(side.is_finite() && side >= min_side && centre.iter().all(|v| v.is_finite())) {
        return None;
    }
    Some(CropBox {
        x0: centre[0] - 0.5 * side,
        y0: centre[1] - 0.5 * side,
        width: side,
        height: side,
    })
}

/// [`crop_input`] with values in [-1, 1] (the person detectors' input; outside the
/// image is -1).
pub fn crop_input_signed(rgb: &image::RgbImage, b: &CropBox, size: usize, out: &mut Vec<f32>) {
    crop_input(rgb, b, size, out);
    for v in out.iter_mut() {
        *v = 2.0 * *v - 1.0;
    }
}

/// Resamples box `b` of `rgb` (bilinear) into `out`: `size x size x 3`, row-major, values
/// in [0, 1]; outside the image is black (0), as MediaPipe's letterboxing. Input pixel
/// `(u, v)` is the image point `b.x0 + (u + 0.5) * b.width / size - 0.5` (pixel centres).
pub fn crop_input(rgb: &image::RgbImage, b: &CropBox, size: usize, out: &mut Vec<f32>) {
    crop_input_sized(rgb, b, [size, size], out);
}

/// [`crop_input`] into `columns x rows x 3` (`[columns, rows]`): box `b` stretched to
/// that size (give it the same aspect to keep people's).
pub fn crop_input_sized(
    rgb: &image::RgbImage,
    b: &CropBox,
    [columns, rows_out]: [usize; 2],
    out: &mut Vec<f32>,
) {
    out.clear();
    out.resize(columns * rows_out * 3, 0.0);
    let (w, h) = (rgb.width() as i64, rgb.height() as i64);
    let raw = rgb.as_raw();
    let (sx, sy) = (b.width / columns as f64, b.height / rows_out as f64);
    // Per output column: the two source columns (None outside the image) and the
    // weight of the second; the same for rows.
    let taps = |origin: f64,
                step: f64,
                limit: i64,
                size: usize|
     -> Vec<(Option<usize>, Option<usize>, f32)> {
        (0..size)
            .map(|u| {
                let x = origin + (u as f64 + 0.5) * step - 0.5;
                let x0 = x.floor() as i64;
                let inside = |v: i64| (0..limit).contains(&v).then_some(v as usize);
                (inside(x0), inside(x0 + 1), (x - x.floor()) as f32)
            })
            .collect()
    };
    let size = columns;
    let columns = taps(b.x0, sx, w, columns);
    let rows = taps(b.y0, sy, h, rows_out);
    let row_len = w as usize * 3;
    let sample = |row: Option<usize>, col: Option<usize>, c: usize| -> f32 {
        match (row, col) {
            (Some(r), Some(k)) => f32::from(raw[r * row_len + k * 3 + c]),
            _ => 0.0,
        }
    };
    for (v, &(r0, r1, fy)) in rows.iter().enumerate() {
        if r0.is_none() && r1.is_none() {
            continue;
        }
        let line = &mut out[v * size * 3..(v + 1) * size * 3];
        for (px, &(c0, c1, fx)) in line.chunks_exact_mut(3).zip(&columns) {
            if c0.is_none() && c1.is_none() {
                continue;
            }
            for (c, value) in px.iter_mut().enumerate() {
                let top = sample(r0, c0, c) * (1.0 - fx) + sample(r0, c1, c) * fx;
                let bottom = sample(r1, c0, c) * (1.0 - fx) + sample(r1, c1, c) * fx;
                *value = (top * (1.0 - fy) + bottom * fy) * (1.0 / 255.0);
            }
        }
    }
}

/// Blacks out `region` (image pixels) in `out`, the `size x size x 3` input
/// [`crop_input`] made of box `b`: another person's face, so that a single-person model
/// looking at a box that holds two people locks on the one it was given. Input pixels
/// whose centres fall inside `region` become 0, as outside the image.
pub fn mask_input(out: &mut [f32], b: &CropBox, size: usize, region: &CropBox) {
    let finite = [b.x0, b.y0, b.width, b.height, region.x0, region.y0]
        .into_iter()
        .chain([region.width, region.height])
        .all(f64::is_finite);
    if !finite || out.len() != size * size * 3 || b.width <= 0.0 || b.height <= 0.0 {
        return;
    }
    // Input pixel u covers image x = b.x0 + (u + 0.5) * step - 0.5 at its centre.
    let span = |origin: f64, step: f64, lo: f64, extent: f64| {
        let first = ((lo + 0.5 - origin) / step - 0.5).ceil().max(0.0);
        let last = ((lo + extent + 0.5 - origin) / step - 0.5)
            .floor()
            .min(size as f64 - 1.0);
        (first.is_finite() && last.is_finite() && first <= last)
            .then_some((first as usize, last as usize))
    };
    let (sx, sy) = (b.width / size as f64, b.height / size as f64);
    let (Some((u0, u1)), Some((v0, v1))) = (
        span(b.x0, sx, region.x0, region.width),
        span(b.y0, sy, region.y0, region.height),
    ) else {
        return;
    };
    for v in v0..=v1 {
        out[(v * size + u0) * 3..(v * size + u1 + 1) * 3].fill(0.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_masked_region_is_black_in_the_input_and_nothing_else_is() {
        let rgb = image::RgbImage::from_pixel(100, 100, image::Rgb([255, 255, 255]));
        let b = CropBox::new(0.0, 0.0, 100.0, 100.0).expect("box");
        let mut input = Vec::new();
        crop_input(&rgb, &b, 10, &mut input);
        // Image x in [20, 40): input columns 2 and 3 (centres 25, 35); rows 5..=9.
        let region = CropBox::new(20.0, 50.0, 20.0, 80.0).expect("region");
        mask_input(&mut input, &b, 10, &region);
        for v in 0..10 {
            for u in 0..10 {
                let black = (2..=3).contains(&u) && v >= 5;
                let value = input[(v * 10 + u) * 3];
                assert_eq!(value == 0.0, black, "pixel ({u}, {v}) = {value}");
            }
        }
        // Outside the box, or of no size: nothing changes.
        let before = input.clone();
        mask_input(
            &mut input,
            &b,
            10,
            &CropBox::new(200.0, 0.0, 10.0, 10.0).expect("far"),
        );
        assert_eq!(input, before);
    }

    #[test]
    fn the_whole_image_box_is_a_centred_square() {
        let b = whole_image_box(640, 480);
        assert_eq!((b.x0, b.y0, b.width, b.height), (0.0, -80.0, 640.0, 640.0));
        let s = squared(&CropBox::new(10.0, 20.0, 30.0, 50.0).expect("box"));
        assert_eq!((s.x0, s.y0, s.width, s.height), (0.0, 20.0, 50.0, 50.0));
    }

    #[test]
    fn tiles_overlap_and_cover_the_area() {
        let area = CropBox::new(0.0, 0.0, 1280.0, 720.0).expect("box");
        assert!(tiles(&area, 1).is_empty());
        let t = tiles(&area, 2);
        // 800-px squares: two across (0 and 480), one down, centred.
        assert_eq!(t.len(), 2);
        assert_eq!((t[0].x0, t[1].x0, t[0].y0), (0.0, 480.0, -40.0));
        assert_eq!(t[0].width, 800.0);
        let portrait = CropBox::new(0.0, 0.0, 810.0, 1080.0).expect("box");
        let t = tiles(&portrait, 3);
        // 450-px squares: 3 down, 2 across, reaching the far edges.
        assert_eq!(t.len(), 6, "{t:?}");
        let last = t[t.len() - 1];
        assert_eq!(
            (last.x0 + last.width, last.y0 + last.height),
            (810.0, 1080.0)
        );
    }

    #[test]
    fn the_alignment_box_is_centred_on_the_hips_and_holds_the_circle() {
        let b = box_from_alignment([100.0, 200.0], [100.0, 120.0], 8.0).expect("box");
        assert_eq!((b.width, b.x0, b.y0), (200.0, 0.0, 100.0));
        assert!(box_from_alignment([1.0, 1.0], [1.0, 2.0], 8.0).is_none());
        assert!(box_from_alignment([f64::NAN, 1.0], [1.0, 90.0], 8.0).is_none());
    }

    #[test]
    fn a_crop_of_the_image_itself_reproduces_it_and_outside_is_black() {
        let mut rgb = image::RgbImage::new(4, 4);
        for (x, y, p) in rgb.enumerate_pixels_mut() {
            *p = image::Rgb([(x * 60) as u8, (y * 60) as u8, 255]);
        }
        let mut out = Vec::new();
        let same = CropBox::new(0.0, 0.0, 4.0, 4.0).expect("box");
        crop_input(&rgb, &same, 4, &mut out);
        assert!((out[(2 * 4 + 3) * 3] - 180.0 / 255.0).abs() < 1e-6);
        assert!((out[(2 * 4 + 3) * 3 + 1] - 120.0 / 255.0).abs() < 1e-6);
        // A box twice the image, centred: the image fills the middle half.
        let big = CropBox::new(-2.0, -2.0, 8.0, 8.0).expect("box");
        crop_input(&rgb, &big, 8, &mut out);
        assert_eq!(out[2], 0.0, "the corner is outside");
        assert!(
            (out[(4 * 8 + 4) * 3 + 2] - 1.0).abs() < 1e-6,
            "the middle is inside"
        );
    }
}
