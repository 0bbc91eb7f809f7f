//! The appearance thumbnail of an image (SeqSLAM's patch normalisation).
//!
//! The image goes to grey (ITU-R 601 luma, as Pillow and OpenCV compute it,
//! so a `GRAY8` camera and a colour one give the same thumbnail), is
//! squashed to 64×48 and every 8×8 patch is normalised to zero mean and
//! unit deviation: what is left is where a place is lighter or darker than
//! around it, which survives exposure, fog and night better than a CNN
//! trained on daylight photos. The similarity and its place in the score
//! are `vpr::appearance`'s.

use fast_image_resize as fir;
use image::RgbImage;

use super::image::luma;
use humem_core::vpr::appearance::{HEIGHT, LEN, PATCH, SCALE, WIDTH};

/// Added to a patch's deviation (grey levels, 0..255) before dividing by
/// it, so that the sensor noise of a flat patch (sky, fog, a wall) is not
/// stretched to full contrast.
const NOISE_FLOOR: f32 = 4.0;

/// The thumbnail of `image`: [`LEN`] values, row-major.
pub fn thumbnail(image: &RgbImage) -> Vec<i8> {
    let grey: Vec<u8> = image.pixels().map(|p| luma(p.0)).collect();
    let src = fir::images::ImageRef::new(image.width(), image.height(), &grey, fir::PixelType::U8)
        .expect("a grey buffer of width x height bytes");
    let mut small = fir::images::Image::new(WIDTH as u32, HEIGHT as u32, fir::PixelType::U8);
    let options = fir::ResizeOptions::new()
        .resize_alg(fir::ResizeAlg::Convolution(fir::FilterType::Bilinear));
    fir::Resizer::new()
        .resize(&src, &mut small, &options)
        .expect("source and destination are both U8");
    normalise_patches(small.buffer())
}

/// Each [`PATCH`]² block of a `WIDTH × HEIGHT` grey image as z-scores,
/// quantised to `i8`.
fn normalise_patches(grey: &[u8]) -> Vec<i8> {
    debug_assert_eq!(grey.len(), LEN);
    let mut out = vec![0i8; LEN];
    for py in (0..HEIGHT).step_by(PATCH) {
        for px in (0..WIDTH).step_by(PATCH) {
            let pixels =
                || (py..py + PATCH).flat_map(move |y| (px..px + PATCH).map(move |x| y * WIDTH + x));
            let n = (PATCH * PATCH) as f32;
            let mean = pixels().map(|i| f32::from(grey[i])).sum::<f32>() / n;
            let var = pixels()
                .map(|i| (f32::from(grey[i]) - mean).powi(2))
                .sum::<f32>()
                / n;
            let scale = SCALE / (var.sqrt() + NOISE_FLOOR);
            for i in pixels() {
                out[i] = ((f32::from(grey[i]) - mean) * scale)
                    .round()
                    .clamp(-127.0, 127.0) as i8;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use humem_core::vpr::appearance::{norm, similarity};

    #[test]
    fn patches_are_normalised_and_flat_ones_stay_flat() {
        // Left half of every patch 100, right half 140: mean 120, std 20,
        // z = ±20 / (20 + 4), stored as ±round(32 × 20 / 24) = ±27.
        let grey: Vec<u8> = (0..LEN)
            .map(|i| {
                if i % WIDTH % PATCH < PATCH / 2 {
                    100
                } else {
                    140
                }
            })
            .collect();
        let t = normalise_patches(&grey);
        assert_eq!((t[0], t[PATCH - 1]), (-27, 27));
        assert!(normalise_patches(&vec![77u8; LEN]).iter().all(|&v| v == 0));
    }

    #[test]
    fn exposure_does_not_change_the_thumbnail_much_and_places_differ() {
        let scene = |gain: f32, offset: f32, shift: u32| {
            RgbImage::from_fn(320, 240, |x, y| {
                let v = (((x + shift) / 10 + y / 15) % 5) as f32 * 40.0 + 30.0;
                let v = (v * gain + offset).clamp(0.0, 255.0) as u8;
                image::Rgb([v, v, v])
            })
        };
        let day = thumbnail(&scene(1.0, 0.0, 0));
        let dusk = thumbnail(&scene(0.4, 10.0, 0));
        let elsewhere = thumbnail(&scene(1.0, 0.0, 25));
        let sim = |a: &[i8], b: &[i8]| similarity((a, norm(a)), (b, norm(b)));
        assert_eq!(day.len(), LEN);
        assert!(sim(&day, &dusk) > 0.9, "{}", sim(&day, &dusk));
        assert!(
            sim(&day, &elsewhere) < sim(&day, &dusk) - 0.3,
            "{}",
            sim(&day, &elsewhere)
        );
    }
}
