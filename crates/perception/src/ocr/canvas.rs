//! The text detector's input for one region of an image.
//!
//! DBNet is fully convolutional, so the region keeps the camera's aspect
//! ratio: it is scaled so that its long side is the configured length, and
//! each side is padded up to the next multiple of 32 (the network's
//! stride). A 512x288 camera at long side 512 gives exactly 512x288, with
//! nothing wasted on padding; the old fixed 640x480 letterbox spent 25 % of
//! its input on padding for that camera and upscaled the rest by 1.25.
//! Inputs of one camera share one shape, so they still batch together;
//! the model runs one tensor per shape (see [`super::super::model`]).
//!
//! [`crop`], the pixels of a region, is here too: the region's input starts
//! with it, and the parent module cuts text lines with it, so it sits in
//! this child rather than the child reaching up for it.

use image::RgbImage;

use super::super::geometry::Rect;
use super::super::image::{append_chw, resize, Channels};
use super::super::model::Planes;

const MEAN: [f32; 3] = [0.485, 0.456, 0.406];
const STD: [f32; 3] = [0.229, 0.224, 0.225];
/// The detector's stride: input sides are multiples of it.
const STRIDE: u32 = 32;

/// Where a region sits in the detector's input.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    /// Input pixels per image pixel.
    pub scale: f32,
    /// The scaled region's size, at the input's top-left corner.
    pub scaled: [u32; 2],
    /// The input's size: `scaled`, each side rounded up to a multiple of 32.
    pub input: [u32; 2],
}

impl Placement {
    /// The placement of a `width` x `height` region at `long_side`.
    pub fn new(width: f32, height: f32, long_side: u32) -> Placement {
        let scale = long_side as f32 / width.max(height).max(1.0);
        let scaled = [
            ((width * scale).round() as u32).clamp(1, long_side),
            ((height * scale).round() as u32).clamp(1, long_side),
        ];
        Placement {
            scale,
            scaled,
            input: scaled.map(|s| s.div_ceil(STRIDE) * STRIDE),
        }
    }
}

/// The normalised detector input of `region` of `image` (BGR, ImageNet
/// mean and deviation, as PaddleOCR feeds it), zero (the mean) in the
/// padding.
pub fn detector_input(image: &RgbImage, region: Rect, long_side: u32) -> (Planes, Placement) {
    let placement = Placement::new(region.width(), region.height(), long_side);
    let [fw, fh] = placement.scaled;
    let resized = resize(&crop(image, region), fw, fh);
    let mut planes = Vec::with_capacity(3 * (fw * fh) as usize);
    append_chw(&resized, Channels::Bgr, MEAN, STD, &mut planes);
    let scaled = Planes {
        width: fw as usize,
        height: fh as usize,
        data: planes,
    };
    let [iw, ih] = placement.input.map(|s| s as usize);
    (padded(&scaled, iw, ih), placement)
}

/// `planes` at the top-left of a `width` x `height` input, zero (the mean)
/// elsewhere; what does not fit is cut off.
pub fn padded(planes: &Planes, width: usize, height: usize) -> Planes {
    let mut data = vec![0.0f32; 3 * width * height];
    let w = planes.width.min(width);
    for c in 0..3 {
        for y in 0..planes.height.min(height) {
            let src = &planes.data[(c * planes.height + y) * planes.width..][..w];
            data[(c * height + y) * width..][..w].copy_from_slice(src);
        }
    }
    Planes {
        width,
        height,
        data,
    }
}

/// The pixels of `rect` (clamped) as an image.
pub fn crop(image: &RgbImage, rect: Rect) -> RgbImage {
    let x0 = rect.x0.max(0.0).floor() as u32;
    let y0 = rect.y0.max(0.0).floor() as u32;
    let x1 = (rect.x1.ceil() as u32).clamp(x0 + 1, image.width());
    let y1 = (rect.y1.ceil() as u32).clamp(y0 + 1, image.height());
    image::imageops::crop_imm(image, x0, y0, x1 - x0, y1 - y0).to_image()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_aspect_is_kept_and_padded_to_the_stride() {
        let p = Placement::new(512.0, 288.0, 512);
        assert_eq!((p.scale, p.scaled, p.input), (1.0, [512, 288], [512, 288]));
        let p = Placement::new(512.0, 288.0, 640);
        assert_eq!((p.scaled, p.input), ([640, 360], [640, 384]));
        // A standing region: the long side is the height.
        let p = Placement::new(100.0, 400.0, 320);
        assert_eq!((p.scale, p.scaled, p.input), (0.8, [80, 320], [96, 320]));
        // Degenerate regions stay at least one pixel.
        let p = Placement::new(1000.0, 0.2, 64);
        assert_eq!((p.scaled, p.input), ([64, 1], [64, 32]));
    }

    #[test]
    fn region_fills_the_top_left_and_padding_is_the_mean() {
        let image = RgbImage::from_pixel(100, 50, image::Rgb([255, 255, 255]));
        let region = Rect {
            x0: 0.0,
            y0: 0.0,
            x1: 100.0,
            y1: 50.0,
        };
        let (planes, placement) = detector_input(&image, region, 64);
        assert_eq!(placement.scaled, [64, 32]);
        assert_eq!((planes.width, planes.height), (64, 32));
        // White is (1 − mean) / std in every plane.
        let white_b = (1.0 - MEAN[0]) / STD[0];
        assert!((planes.data[0] - white_b).abs() < 1e-5);
        let (planes, _) = detector_input(&image, region, 96);
        // 96x48 padded to 96x64: row 50 is padding.
        assert_eq!((planes.width, planes.height), (96, 64));
        assert_eq!(planes.data[50 * 96], 0.0);
        assert!((planes.data[47 * 96] - white_b).abs() < 1e-5);
    }
}
