//! What a person looks like, for telling people apart where their boxes cannot: colour
//! histograms of two parts of the body (torso and legs), in a space that a change of
//! light moves little (hue and saturation for coloured pixels; grey levels for the
//! colourless ones, which in a black-and-white film are all of them), compared by the
//! Bhattacharyya distance.
//!
//! Written here rather than taken from a re-identification network: none ships in a
//! registry package under a permissive licence in a form the project's runtimes load
//! (docs/image-detector.md, "Who comes back"), and a histogram costs microseconds where a
//! network would cost a landmark run per person.
//!
//! Independent of any model: a part is a box in image pixels (the image detector places
//! them from the landmarks). Each part is sampled on at most
//! [`SAMPLES_PER_SIDE`]² pixels whatever its size, so a descriptor's cost and size are
//! bounded; a part with fewer than [`MIN_SAMPLES`] pixels inside the image has no
//! histogram, and a person with neither part has no descriptor.

use image::RgbImage;

/// Hue bins of the coloured pixels.
const HUE_BINS: usize = 8;
/// Saturation bins of the coloured pixels.
const SATURATION_BINS: usize = 2;
/// Grey-level bins of the colourless pixels.
const GREY_BINS: usize = 8;
/// Bins of a part's histogram.
pub const BINS: usize = HUE_BINS * SATURATION_BINS + GREY_BINS;
/// A part is sampled on at most this many pixels a side.
pub const SAMPLES_PER_SIDE: u32 = 24;
/// A part with fewer pixels inside the image has no histogram.
pub const MIN_SAMPLES: usize = 12;
/// Pixels less saturated than this (HSV's S) are colourless: their hue is noise.
const GREY_SATURATION: f32 = 0.2;
/// Pixels darker than this (HSV's V) are colourless too.
const DARK_VALUE: f32 = 0.15;

/// A part's colour histogram, summing to 1.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Histogram([f32; BINS]);

impl Histogram {
    /// The histogram of `region` (`[x0, y0, x1, y1]`, image pixels) of `image`; `None`
    /// when fewer than [`MIN_SAMPLES`] of its pixels lie inside the image (or the
    /// region is not finite).
    pub fn of(image: &RgbImage, region: [f64; 4]) -> Option<Self> {
        let (w, h) = (f64::from(image.width()), f64::from(image.height()));
        if !region.iter().all(|v| v.is_finite()) {
            return None;
        }
        let x0 = region[0].max(0.0);
        let y0 = region[1].max(0.0);
        let x1 = region[2].min(w);
        let y1 = region[3].min(h);
        if x1 - x0 < 1.0 || y1 - y0 < 1.0 {
            return None;
        }
        // At most SAMPLES_PER_SIDE columns and rows, at the middles of equal strips.
        let columns = ((x1 - x0) as u32).clamp(1, SAMPLES_PER_SIDE);
        let rows = ((y1 - y0) as u32).clamp(1, SAMPLES_PER_SIDE);
        if ((columns * rows) as usize) < MIN_SAMPLES {
            return None;
        }
        let mut bins = [0.0f32; BINS];
        for r in 0..rows {
            let y = y0 + (y1 - y0) * (f64::from(r) + 0.5) / f64::from(rows);
            for c in 0..columns {
                let x = x0 + (x1 - x0) * (f64::from(c) + 0.5) / f64::from(columns);
                // Inside the image by the clamps above: x < w, y < h.
                let p = image.get_pixel(x as u32, y as u32).0;
                bins[bin(p)] += 1.0;
            }
        }
        let total = (columns * rows) as f32;
        for b in &mut bins {
            *b /= total;
        }
        Some(Self(bins))
    }

    /// Bhattacharyya distance, `sqrt(1 - sum sqrt(p q))`: 0 for equal histograms, 1 for
    /// disjoint ones.
    pub fn distance(&self, other: &Self) -> f64 {
        let overlap: f32 = self
            .0
            .iter()
            .zip(&other.0)
            .map(|(p, q)| (p * q).sqrt())
            .sum();
        f64::from((1.0 - overlap).max(0.0)).sqrt()
    }

    /// Moves this histogram `rate` (0 to 1) of the way to `other`.
    fn blend(&mut self, other: &Self, rate: f32) {
        for (a, b) in self.0.iter_mut().zip(&other.0) {
            *a += rate * (b - *a);
        }
    }
}

/// The bin of an RGB pixel: coloured pixels by hue and saturation, the others by grey
/// level.
fn bin(p: [u8; 3]) -> usize {
    let [r, g, b] = p.map(|v| f32::from(v) / 255.0);
    let max = r.max(g).max(b);
    let min = r.min(g).min(b);
    let chroma = max - min;
    let saturation = if max > 0.0 { chroma / max } else { 0.0 };
    if saturation < GREY_SATURATION || max < DARK_VALUE {
        let grey = (max * GREY_BINS as f32) as usize;
        return HUE_BINS * SATURATION_BINS + grey.min(GREY_BINS - 1);
    }
    // Hue in [0, 6).
    let hue = if max == r {
        ((g - b) / chroma).rem_euclid(6.0)
    } else if max == g {
        (b - r) / chroma + 2.0
    } else {
        (r - g) / chroma + 4.0
    };
    let h = ((hue / 6.0 * HUE_BINS as f32) as usize).min(HUE_BINS - 1);
    let s = (((saturation - GREY_SATURATION) / (1.0 - GREY_SATURATION) * SATURATION_BINS as f32)
        as usize)
        .min(SATURATION_BINS - 1);
    h * SATURATION_BINS + s
}

/// A person's look: the histograms of their torso and legs, either may be missing
/// (out of the image, too small).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Appearance {
    /// Shoulders to hips.
    pub torso: Option<Histogram>,
    /// Hips to shins.
    pub legs: Option<Histogram>,
}

impl Appearance {
    /// The look of the parts `torso` and `legs` (`[x0, y0, x1, y1]`, image pixels) of
    /// `image`; `None` when neither has a histogram.
    pub fn of(image: &RgbImage, torso: [f64; 4], legs: [f64; 4]) -> Option<Self> {
        let a = Self {
            torso: Histogram::of(image, torso),
            legs: Histogram::of(image, legs),
        };
        (a.torso.is_some() || a.legs.is_some()).then_some(a)
    }

    /// The mean Bhattacharyya distance of the parts both have (0 to 1); `None` when
    /// they share none.
    pub fn distance(&self, other: &Self) -> Option<f64> {
        let pairs = [(&self.torso, &other.torso), (&self.legs, &other.legs)];
        let (sum, n) = pairs
            .iter()
            .filter_map(|(a, b)| Some(a.as_ref()?.distance(b.as_ref()?)))
            .fold((0.0, 0u32), |(s, n), d| (s + d, n + 1));
        (n > 0).then(|| sum / f64::from(n))
    }

    /// Moves this look `rate` (0 to 1) of the way to `seen` (a part this one lacks is
    /// taken as seen).
    pub fn blend(&mut self, seen: &Self, rate: f32) {
        for (mine, new) in [(&mut self.torso, &seen.torso), (&mut self.legs, &seen.legs)] {
            match (mine.as_mut(), new) {
                (Some(m), Some(n)) => m.blend(n, rate),
                (None, Some(n)) => *mine = Some(*n),
                _ => {}
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn filled(w: u32, h: u32, f: impl Fn(u32, u32) -> [u8; 3]) -> RgbImage {
        RgbImage::from_fn(w, h, |x, y| image::Rgb(f(x, y)))
    }

    #[test]
    fn the_same_colours_are_near_and_other_colours_far() {
        // A red shirt over blue trousers, twice, and a green shirt over grey.
        let a = filled(
            40,
            80,
            |_, y| if y < 40 { [200, 30, 30] } else { [30, 30, 180] },
        );
        let b = filled(40, 80, |_, y| {
            if y < 40 {
                [40, 160, 40]
            } else {
                [120, 120, 120]
            }
        });
        let torso = [5.0, 5.0, 35.0, 35.0];
        let legs = [5.0, 45.0, 35.0, 75.0];
        let look_a = Appearance::of(&a, torso, legs).expect("a look");
        let look_b = Appearance::of(&b, torso, legs).expect("a look");
        assert_eq!(look_a.distance(&look_a), Some(0.0));
        assert!(look_a.distance(&look_b).expect("shared parts") > 0.9);
    }

    #[test]
    fn a_change_of_light_moves_a_coloured_look_little() {
        let bright = filled(
            40,
            40,
            |x, _| if x < 20 { [200, 40, 40] } else { [40, 40, 200] },
        );
        let dim = filled(
            40,
            40,
            |x, _| if x < 20 { [110, 22, 22] } else { [22, 22, 110] },
        );
        let part = [0.0, 0.0, 40.0, 40.0];
        let d = Histogram::of(&bright, part)
            .expect("histogram")
            .distance(&Histogram::of(&dim, part).expect("histogram"));
        assert!(d < 0.05, "{d}");
    }

    #[test]
    fn hostile_parts_give_no_look_or_a_bounded_one() {
        let one = filled(1, 1, |_, _| [0, 0, 0]);
        let part = [0.0, 0.0, 1.0, 1.0];
        assert_eq!(Appearance::of(&one, part, part), None);
        let image = filled(200, 200, |x, y| [(x % 256) as u8, (y % 256) as u8, 0]);
        for (bad, some) in [
            ([f64::NAN, 0.0, 10.0, 10.0], false),
            ([0.0, 0.0, f64::INFINITY, 10.0], false),
            ([250.0, 250.0, 260.0, 260.0], false),
            ([10.0, 10.0, 0.0, 0.0], false),
            ([0.0, 0.0, 2.0, 2.0], false),
            ([-1e300, -1e300, 1e300, 1e300], true),
            ([199.0, 0.0, 200.0, 200.0], true),
        ] {
            let h = Histogram::of(&image, bad);
            assert_eq!(h.is_some(), some, "{bad:?}");
            if let Some(h) = h {
                // The part within the image, sampled on at most SAMPLES_PER_SIDE² pixels
                // (the sums of 1/n each).
                assert!((h.0.iter().sum::<f32>() - 1.0).abs() < 1e-5);
            }
        }
        // An all-black crop: one grey bin, a distance from itself of 0.
        let black = filled(30, 30, |_, _| [0, 0, 0]);
        let look =
            Appearance::of(&black, [0.0, 0.0, 30.0, 30.0], [0.0, 0.0, 30.0, 30.0]).expect("a look");
        assert_eq!(look.distance(&look), Some(0.0));
        assert_eq!(
            look.torso.expect("torso").0[HUE_BINS * SATURATION_BINS],
            1.0
        );
    }

    #[test]
    fn blending_moves_towards_what_is_seen_and_fills_missing_parts() {
        let red = filled(20, 20, |_, _| [200, 30, 30]);
        let blue = filled(20, 20, |_, _| [30, 30, 200]);
        let part = [0.0, 0.0, 20.0, 20.0];
        let mut look = Appearance {
            torso: Histogram::of(&red, part),
            legs: None,
        };
        let seen = Appearance::of(&blue, part, part).expect("a look");
        let before = look.distance(&seen).expect("torso shared");
        look.blend(&seen, 0.5);
        assert!(look.distance(&seen).expect("shared") < before);
        assert_eq!(look.legs, seen.legs);
    }
}
