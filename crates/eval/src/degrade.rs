//! The paper's synthetic degradations `Bℓ/Dd` for `humem eval`.
//!
//! docs/evaluation.md ("the protocol"): a line-motion blur of length `ℓ`
//! pixels, then exposure reduced to `(100 − d)%` of linear-light intensity.
//! Precisely, per 8-bit sRGB channel:
//!
//! 1. **Blur**: a horizontal, normalised box kernel of `ℓ` taps (the motion of
//!    a camera panning sideways), applied to the encoded 8-bit values as an
//!    image-space motion kernel usually is (e.g. OpenCV's `filter2D`). For
//!    odd `ℓ` the kernel is centred (offsets `−(ℓ−1)/2 ..= (ℓ−1)/2`); for even
//!    `ℓ` it reaches one pixel further left (offsets `−ℓ/2 ..= ℓ/2 − 1`, the
//!    anchor OpenCV uses). Pixels beyond the left and right edges repeat the
//!    edge pixel (clamp to edge), so a uniform image stays uniform and the
//!    sum of a row is preserved away from the edges. `ℓ` of 0 or 1 is no blur.
//! 2. **Darken**: the blurred value is decoded to linear light with the exact
//!    sRGB transfer function (IEC 61966-2-1), multiplied by `(100 − d)/100`,
//!    encoded back, and rounded to `u8` (the only rounding of the pipeline).
//!
//! The blur uses prefix sums, so its cost does not grow with `ℓ` and any
//! `ℓ` (even wider than the image) is safe; nothing here panics.

use std::fmt;
use std::str::FromStr;

use image::RgbImage;

/// A degradation `Bℓ/Dd`: blur length in pixels and darkening in percent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Degradation {
    /// Length of the horizontal motion blur, pixels (0 or 1: none).
    pub blur: u32,
    /// Share of linear-light intensity removed, percent (0..=100).
    pub darken: u32,
}

impl Degradation {
    /// Whether this leaves images unchanged (`B0/D0`, `B1/D0`).
    pub fn is_identity(&self) -> bool {
        self.blur <= 1 && self.darken == 0
    }
}

/// Why a degradation string was not understood.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "degradation {input:?}: {reason} (expected e.g. \"B15/D80\", \"B15\", \"D80\" or \"clean\")"
)]
pub struct ParseDegradationError {
    /// The text given.
    pub input: String,
    /// What is wrong with it.
    pub reason: String,
}

impl FromStr for Degradation {
    type Err = ParseDegradationError;

    /// Parses `Bℓ/Dd`, `Bℓ` or `Dd` (letters in either case, `d` at most
    /// 100), or `clean` for no degradation.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let err = |reason: String| ParseDegradationError {
            input: s.to_string(),
            reason,
        };
        let text = s.trim();
        if text.eq_ignore_ascii_case("clean") {
            return Ok(Degradation::default());
        }
        if text.is_empty() {
            return Err(err("empty".to_string()));
        }
        let parts: Vec<&str> = text.split('/').map(str::trim).collect();
        let (blur_part, dark_part) = match parts.as_slice() {
            [one] if one.starts_with(['B', 'b']) => (Some(*one), None),
            [one] if one.starts_with(['D', 'd']) => (None, Some(*one)),
            [b, d] if b.starts_with(['B', 'b']) && d.starts_with(['D', 'd']) => {
                (Some(*b), Some(*d))
            }
            [_] => return Err(err("must start with B (blur) or D (darken)".to_string())),
            [_, _] => {
                return Err(err(
                    "must be B<length>/D<percent>, in that order".to_string()
                ))
            }
            _ => return Err(err("more than one '/'".to_string())),
        };
        let number = |part: &str, what: &str| -> Result<u32, ParseDegradationError> {
            let digits = &part[1..];
            if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
                return Err(err(format!(
                    "{what} {part:?} needs a whole number after its letter"
                )));
            }
            digits
                .parse::<u32>()
                .map_err(|_| err(format!("{what} {part:?} is too large")))
        };
        let blur = blur_part
            .map(|p| number(p, "blur"))
            .transpose()?
            .unwrap_or(0);
        let darken = dark_part
            .map(|p| number(p, "darkening"))
            .transpose()?
            .unwrap_or(0);
        if darken > 100 {
            return Err(err(format!("darkening D{darken} is over 100%")));
        }
        Ok(Degradation { blur, darken })
    }
}

impl fmt::Display for Degradation {
    /// Always the full form, `B15/D80` (also `B0/D0` for none).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "B{}/D{}", self.blur, self.darken)
    }
}

/// The name of a condition in reports: `clean`, or the degradation.
pub fn condition_name(degradation: Option<&Degradation>) -> String {
    degradation.map_or_else(|| "clean".to_string(), |d| d.to_string())
}

/// The sRGB decoding function: encoded value in `[0, 1]` to linear light in
/// `[0, 1]`. Inputs outside `[0, 1]` are clamped, NaN gives 0.
pub fn srgb_to_linear(v: f32) -> f32 {
    let v = clamp_unit(v);
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// The sRGB encoding function: linear light in `[0, 1]` to an encoded value
/// in `[0, 1]`. Inputs outside `[0, 1]` are clamped, NaN gives 0.
pub fn linear_to_srgb(v: f32) -> f32 {
    let v = clamp_unit(v);
    if v <= 0.003_130_8 {
        v * 12.92
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

fn clamp_unit(v: f32) -> f32 {
    if v.is_nan() {
        0.0
    } else {
        v.clamp(0.0, 1.0)
    }
}

/// Applies `d` to `image`: the horizontal blur, then the darkening (see the
/// module documentation). The output has the size of the input.
pub fn apply(image: &RgbImage, d: &Degradation) -> RgbImage {
    let (w, h) = image.dimensions();
    if d.is_identity() || w == 0 || h == 0 {
        return image.clone();
    }
    let gain = (100 - d.darken.min(100)) as f32 / 100.0;
    let out_of = |v: f32| -> u8 {
        let v = if d.darken == 0 {
            v
        } else {
            linear_to_srgb(srgb_to_linear(v / 255.0) * gain) * 255.0
        };
        v.round().clamp(0.0, 255.0) as u8
    };
    let width = w as usize;
    let src = image.as_raw();
    let mut out = vec![0u8; src.len()];
    let blur = d.blur.max(1) as i64;
    // Window of output x: x + lo ..= x + hi.
    let (lo, hi) = (-(blur / 2), (blur - 1) / 2);
    let mut channel = vec![0u64; width];
    let mut prefix = vec![0u64; width + 1];
    for (row_in, row_out) in src
        .chunks_exact(width * 3)
        .zip(out.chunks_exact_mut(width * 3))
    {
        for c in 0..3 {
            for (x, v) in channel.iter_mut().enumerate() {
                *v = u64::from(row_in[3 * x + c]);
            }
            for x in 0..width {
                prefix[x + 1] = prefix[x] + channel[x];
            }
            for x in 0..width {
                let sum = window_sum(&channel, &prefix, x as i64 + lo, x as i64 + hi);
                let mean = (sum as f64 / blur as f64) as f32;
                row_out[3 * x + c] = out_of(mean);
            }
        }
    }
    RgbImage::from_raw(w, h, out).unwrap_or_else(|| image.clone())
}

/// Sum of `row[a..=b]` with indices clamped to the row (edge pixels repeat).
/// `row` is non-empty and `prefix[i]` is the sum of `row[..i]`.
fn window_sum(row: &[u64], prefix: &[u64], a: i64, b: i64) -> u64 {
    let last = row.len() as i64 - 1;
    let left = (b.min(-1) - a + 1).max(0) as u64;
    let right = (b - a.max(last + 1) + 1).max(0) as u64;
    let (i, j) = (a.max(0), b.min(last));
    let inner = if i <= j {
        prefix[j as usize + 1] - prefix[i as usize]
    } else {
        0
    };
    left * row[0] + right * row[last as usize] + inner
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::Rgb;
    use proptest::prelude::*;

    fn deg(blur: u32, darken: u32) -> Degradation {
        Degradation { blur, darken }
    }

    /// A `w`×`h` black image with one pixel of value `v` (all channels).
    fn impulse(w: u32, h: u32, x: u32, y: u32, v: u8) -> RgbImage {
        let mut img = RgbImage::new(w, h);
        img.put_pixel(x, y, Rgb([v, v, v]));
        img
    }

    fn uniform(w: u32, h: u32, v: [u8; 3]) -> RgbImage {
        RgbImage::from_pixel(w, h, Rgb(v))
    }

    #[test]
    fn parses_and_round_trips() {
        for (text, blur, darken) in [
            ("B15/D80", 15, 80),
            ("B0/D0", 0, 0),
            ("B35/D80", 35, 80),
            ("B35/D90", 35, 90),
            ("B15/D50", 15, 50),
            ("D100", 0, 100),
        ] {
            let d: Degradation = text.parse().unwrap();
            assert_eq!(d, deg(blur, darken), "{text}");
            assert_eq!(d.to_string().parse::<Degradation>().unwrap(), d);
        }
        assert_eq!(
            "B15/D80".parse::<Degradation>().unwrap().to_string(),
            "B15/D80"
        );
        assert_eq!("B15".parse::<Degradation>().unwrap(), deg(15, 0));
        assert_eq!("B15".parse::<Degradation>().unwrap().to_string(), "B15/D0");
        assert_eq!("D80".parse::<Degradation>().unwrap(), deg(0, 80));
        assert_eq!(" b15 / d80 ".parse::<Degradation>().unwrap(), deg(15, 80));
        assert_eq!("Clean".parse::<Degradation>().unwrap(), deg(0, 0));
    }

    #[test]
    fn rejects_malformed_strings_clearly() {
        for bad in [
            "",
            "X15",
            "B",
            "D",
            "B-1",
            "B+1",
            "D101",
            "B15/",
            "/D80",
            "B15/B20",
            "D80/B15",
            "B15D80",
            "B1.5",
            "B15/D80/D1",
            "B99999999999",
            "15/80",
        ] {
            let e = bad.parse::<Degradation>().unwrap_err();
            assert_eq!(e.input, bad);
            let text = e.to_string();
            assert!(text.contains("expected e.g. \"B15/D80\""), "{text}");
        }
        let e = "D101".parse::<Degradation>().unwrap_err();
        assert!(e.reason.contains("over 100%"), "{e}");
    }

    #[test]
    fn transfer_functions_by_hand() {
        assert_eq!(srgb_to_linear(0.0), 0.0);
        assert!((srgb_to_linear(1.0) - 1.0).abs() < 1e-6);
        assert!((srgb_to_linear(0.5) - 0.214_041_14).abs() < 1e-6);
        // Linear segment below the knee: 0.04 / 12.92.
        assert!((srgb_to_linear(0.04) - 0.04 / 12.92).abs() < 1e-9);
        assert!((linear_to_srgb(0.2) * 255.0 - 123.554_95).abs() < 1e-3);
        assert!((linear_to_srgb(0.002) - 0.002 * 12.92).abs() < 1e-9);
        // Clamped outside [0, 1].
        assert_eq!(srgb_to_linear(-1.0), 0.0);
        assert_eq!(srgb_to_linear(f32::NAN), 0.0);
        assert!((linear_to_srgb(2.0) - 1.0).abs() < 1e-6);
        // Every 8-bit value survives the round trip, and decoding is monotone.
        let mut previous = -1.0;
        for v in 0..=255u8 {
            let s = f32::from(v) / 255.0;
            let l = srgb_to_linear(s);
            assert!(l > previous);
            previous = l;
            assert_eq!((linear_to_srgb(l) * 255.0).round() as u8, v);
        }
    }

    #[test]
    fn darkening_scales_linear_light() {
        // Exact values (f64): 255 → linear 1.0 → ×0.2 → sRGB 123.555 → 124;
        // 128 → 0.215861 → 0.0431721 → 58.607 → 59; 64 → 0.0512695 →
        // 0.0102539 → 25.877 → 26; 200 at D50 → 0.288790 → 146.313 → 146;
        // 255 at D90 → 0.1 → 89.044 → 89.
        for (v, darken, expected) in [
            (255u8, 80, 124u8),
            (128, 80, 59),
            (64, 80, 26),
            (200, 50, 146),
            (255, 50, 188),
            (255, 90, 89),
            (0, 80, 0),
            (77, 100, 0),
            (255, 100, 0),
        ] {
            let img = uniform(4, 3, [v, v, v]);
            let out = apply(&img, &deg(0, darken));
            assert!(
                out.pixels().all(|p| p.0 == [expected; 3]),
                "{v} at D{darken}: {:?}",
                out.get_pixel(0, 0)
            );
        }
        // Channels are independent.
        let out = apply(&uniform(2, 2, [255, 128, 0]), &deg(0, 80));
        assert_eq!(out.get_pixel(1, 1).0, [124, 59, 0]);
    }

    #[test]
    fn d0_and_b0_b1_change_nothing() {
        let mut img = RgbImage::new(16, 4);
        for (i, p) in img.pixels_mut().enumerate() {
            let v = (i * 37 % 256) as u8;
            *p = Rgb([v, v.wrapping_mul(3), 255 - v]);
        }
        assert_eq!(apply(&img, &deg(0, 0)), img);
        assert_eq!(apply(&img, &deg(1, 0)), img);
        assert!(deg(1, 0).is_identity() && !deg(2, 0).is_identity() && !deg(0, 1).is_identity());
    }

    #[test]
    fn blurred_impulse_keeps_its_energy_over_exactly_l_pixels() {
        // Odd length: centred, 15 pixels of 255/15 = 17, sum 255.
        let out = apply(&impulse(40, 5, 20, 2, 255), &deg(15, 0));
        let row: Vec<u8> = (0..40).map(|x| out.get_pixel(x, 2).0[0]).collect();
        let lit: Vec<u32> = (0..40).filter(|&x| row[x as usize] > 0).collect();
        assert_eq!(lit, (13..=27).collect::<Vec<_>>());
        assert!(lit.iter().all(|&x| row[x as usize] == 17));
        assert_eq!(row.iter().map(|&v| u32::from(v)).sum::<u32>(), 255);
        // Other rows are untouched: the blur is horizontal only.
        for y in [0, 1, 3, 4] {
            assert!((0..40).all(|x| out.get_pixel(x, y).0 == [0, 0, 0]));
        }
        // Even length: offsets −3..=2, 6 pixels of round(42.5) = 43, so
        // the sum is 255 up to the rounding (±ℓ/2).
        let out = apply(&impulse(40, 1, 20, 0, 255), &deg(6, 0));
        let lit: Vec<u32> = (0..40).filter(|&x| out.get_pixel(x, 0).0[0] > 0).collect();
        assert_eq!(lit, (18..=23).collect::<Vec<_>>());
        let sum: u32 = (0..40).map(|x| u32::from(out.get_pixel(x, 0).0[0])).sum();
        assert!(sum.abs_diff(255) <= 3, "{sum}");
        // Length 35 on a 100-wide row.
        let out = apply(&impulse(100, 1, 50, 0, 255), &deg(35, 0));
        let lit = (0..100).filter(|&x| out.get_pixel(x, 0).0[0] > 0).count();
        assert_eq!(lit, 35);
        let sum: u32 = (0..100).map(|x| u32::from(out.get_pixel(x, 0).0[0])).sum();
        assert!(sum.abs_diff(255) <= 35 / 2, "{sum}");
    }

    #[test]
    fn blur_then_darken() {
        // 17 after the blur, then D80: linear 0.005605 × 0.2 → sRGB 3.69 → 4.
        let out = apply(&impulse(40, 1, 20, 0, 255), &deg(15, 80));
        let row: Vec<u8> = (0..40).map(|x| out.get_pixel(x, 0).0[0]).collect();
        assert!((13..=27).all(|x| row[x] == 4), "{row:?}");
        assert_eq!(row.iter().filter(|&&v| v > 0).count(), 15);
    }

    #[test]
    fn edges_are_clamped() {
        // 255 at x = 0, ℓ = 3: x = 0 sees (255, 255, 0) → 170, x = 1 sees
        // (255, 0, 0) → 85, x = 2 sees nothing.
        let out = apply(&impulse(6, 1, 0, 0, 255), &deg(3, 0));
        let row: Vec<u8> = (0..6).map(|x| out.get_pixel(x, 0).0[0]).collect();
        assert_eq!(row, vec![170, 85, 0, 0, 0, 0]);
        // Same at the right edge.
        let out = apply(&impulse(6, 1, 5, 0, 255), &deg(3, 0));
        let row: Vec<u8> = (0..6).map(|x| out.get_pixel(x, 0).0[0]).collect();
        assert_eq!(row, vec![0, 0, 0, 0, 85, 170]);
    }

    #[test]
    fn uniform_images_are_unchanged_by_blur() {
        for blur in [2, 3, 15, 35, 1000, u32::MAX] {
            let img = uniform(20, 3, [12, 200, 97]);
            assert_eq!(apply(&img, &deg(blur, 0)), img, "B{blur}");
        }
        // A row of two halves blurred far wider than the image tends to the
        // mean of its edge pixels.
        let mut img = RgbImage::new(4, 1);
        for x in 2..4 {
            img.put_pixel(x, 0, Rgb([200, 200, 200]));
        }
        let out = apply(&img, &deg(1_000_001, 0));
        assert!(out.pixels().all(|p| p.0[0].abs_diff(100) <= 1), "{out:?}");
    }

    #[test]
    fn empty_and_tiny_images() {
        let empty = RgbImage::new(0, 0);
        assert_eq!(apply(&empty, &deg(15, 80)).dimensions(), (0, 0));
        let one = uniform(1, 1, [255, 0, 128]);
        assert_eq!(apply(&one, &deg(35, 80)).get_pixel(0, 0).0, [124, 0, 59]);
    }

    proptest! {
        #[test]
        fn apply_keeps_size_and_never_brightens_uniform_rows(
            w in 1u32..24, h in 1u32..4, blur in 0u32..64, darken in 0u32..=100,
            seed in any::<u64>(),
        ) {
            let mut img = RgbImage::new(w, h);
            let mut s = seed;
            for p in img.pixels_mut() {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                let b = (s >> 33).to_le_bytes();
                *p = Rgb([b[0], b[1], b[2]]);
            }
            let out = apply(&img, &deg(blur, darken));
            prop_assert_eq!(out.dimensions(), img.dimensions());
            // Blur stays within each row's range; darkening only lowers it.
            for y in 0..h {
                for c in 0..3 {
                    let row: Vec<u8> = (0..w).map(|x| img.get_pixel(x, y).0[c]).collect();
                    let (lo, hi) = (*row.iter().min().unwrap(), *row.iter().max().unwrap());
                    for x in 0..w {
                        let v = out.get_pixel(x, y).0[c];
                        prop_assert!(v <= hi);
                        if darken == 0 {
                            prop_assert!(v >= lo);
                        }
                    }
                }
            }
        }

        #[test]
        fn parse_never_panics(s in "[BbDd0-9/ a-z]{0,12}") {
            if let Ok(d) = s.parse::<Degradation>() {
                prop_assert_eq!(d.to_string().parse::<Degradation>().unwrap(), d);
            }
        }
    }
}
