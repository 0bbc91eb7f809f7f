//! Model checks: before a user's model meets a robot.
//!
//! A model exported by hand can load and still not fit: another input
//! name, a fixed size that is not the configured one, a ViT whose sides
//! must be multiples of its patch, 1000 scene classes where 365 were meant,
//! a descriptor length the store does not hold, a segment export configured
//! without its masks. Each of these fails late (at the first image, or
//! silently as garbage) unless it is looked for. This module looks for
//! them:
//!
//! - [`graph`]: each role's declared inputs and outputs (names, element
//!   types, ranks, fixed and dynamic axes, multiples of a patch or stride,
//!   lengths) against its configuration and what HuMem feeds and reads.
//!   Pure and cheap: [`crate::Perception::load`] runs them on the sessions it
//!   loads, so the server refuses a mismatch at start;
//! - [`run`]: one image through each model, reporting what came out
//!   (descriptor length and norm, top scene classes, objects, text boxes
//!   and the text read), which catches what a graph does not declare;
//! - [`check_models`]: both for every configured model, for
//!   `humem models check`, each model's outcome a [`ModelReport`]
//!   ([`report`]); the OCR pair's in `text`.
//!
//! The types the checks share live below them, never here: the graph's
//! signature in [`crate::signature`], the errors in [`crate::error`], what
//! a graph check expects and finds in [`graph`]. This module runs the
//! checks in order, draws the synthetic picture `humem models check` runs
//! when given none, and re-exports those types under `check::`.
//!
//! Every error names the model (`perception.descriptor`, …), the tensor and
//! what was expected against what was found.

pub mod graph;
pub mod report;
pub mod run;
mod text;

use image::RgbImage;

use crate::config::PerceptionConfig;
pub use crate::error::CheckError;
use crate::runtime;
pub use crate::signature::{Dim, Io, Kind, Tensor};
pub use graph::{Expected, Facts};
pub use report::ModelReport;

/// 5x7 glyphs of the sign's word, a row per byte (bit 4 leftmost).
const GLYPHS: [[u8; 7]; 5] = [
    [0x11, 0x11, 0x11, 0x1f, 0x11, 0x11, 0x11], // H
    [0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0e], // U
    [0x11, 0x1b, 0x15, 0x15, 0x11, 0x11, 0x11], // M
    [0x1f, 0x10, 0x10, 0x1e, 0x10, 0x10, 0x1f], // E
    [0x11, 0x1b, 0x15, 0x15, 0x11, 0x11, 0x11], // M
];

/// Whether pixel `(x, y)` is ink of the sign's word "HUMEM": 5x7 glyphs
/// scaled 5 times, 10 pixels apart, from `(237, 312)`.
fn ink(x: u32, y: u32) -> bool {
    const SCALE: u32 = 5;
    let (Some(dx), Some(dy)) = (x.checked_sub(237), y.checked_sub(312)) else {
        return false;
    };
    let (glyph, gx, gy) = (dx / 35, dx % 35 / SCALE, dy / SCALE);
    glyph < 5 && gx < 5 && gy < 7 && GLYPHS[glyph as usize][gy as usize] & (0x10 >> gx) != 0
}

/// A synthetic 640x480 street-like picture: sky, a building with windows,
/// a light sign reading "HUMEM", a road. Deterministic, so two checks of
/// one model print the same.
pub fn synthetic_image() -> RgbImage {
    RgbImage::from_fn(640, 480, |x, y| {
        let sign = (200..440).contains(&x) && (300..360).contains(&y);
        let building = (40..600).contains(&x) && (80..300).contains(&y);
        let window = building && (x % 60) < 30 && (y % 50) < 25;
        let rgb = if sign && ink(x, y) {
            [20, 20, 30]
        } else if sign {
            [235, 235, 220]
        } else if window {
            [60, 90, 130]
        } else if building {
            [150, 110, 90]
        } else if y < 240 {
            [110 + (y / 4) as u8, 160 + (y / 8) as u8, 230]
        } else {
            [90 + (x / 16) as u8, 90, 95]
        };
        image::Rgb(rgb)
    })
}

/// Checks every configured model: loads it, checks its graph against the
/// configuration and `expected` descriptor lengths (the store's), and runs
/// `image` through it. Errors only where ONNX Runtime itself cannot be
/// loaded; each model's own outcome is in its report.
pub fn check_models(
    config: &PerceptionConfig,
    expected: &[Expected],
    image: &RgbImage,
) -> Result<Vec<ModelReport>, CheckError> {
    let env =
        runtime::environment(&config.onnxruntime_library()).map_err(|error| CheckError::Load {
            model: "ONNX Runtime (perception.onnxruntime)".into(),
            error,
        })?;
    let mut reports = Vec::new();

    let shared_scene = config
        .scene
        .as_ref()
        .is_some_and(|s| s.shares_input_with(&config.descriptor));
    let mut descriptor = ModelReport::new("perception.descriptor", config.descriptor.precision());
    let mut scene_lines = Vec::new();
    if let Some(session) = descriptor.load(&env, config, &config.descriptor.model) {
        let io = descriptor.io.clone().unwrap_or_else(|| Io::of(&session));
        if descriptor
            .facts(graph::descriptor(&io, config, expected))
            .is_some()
        {
            let ran = run::descriptor(session, config, expected, image);
            if let Some((lines, scene)) = descriptor.record(ran) {
                descriptor.ran = lines;
                scene_lines = scene;
            }
        }
    }
    reports.push(descriptor);

    if let Some(s) = &config.scene {
        let mut scene = ModelReport::new("perception.scene", s.precision());
        if shared_scene {
            scene.file = config.model_file(&s.model, s.precision()).ok();
            scene.notes.push(
                "same file and input as perception.descriptor: one inference gives both".into(),
            );
            scene.ran = scene_lines;
        } else if let Some(session) = scene.load(&env, config, &s.model) {
            let io = scene.io.clone().unwrap_or_else(|| Io::of(&session));
            if scene.facts(graph::scene(&io, config)).is_some() {
                let ran = run::scene(session, config, image);
                scene.ran = scene.record(ran).unwrap_or_default();
            }
        }
        reports.push(scene);
    }

    if let Some(d) = &config.detector {
        let mut detector = ModelReport::new("perception.detector", d.precision);
        if let Some(session) = detector.load(&env, config, &d.model) {
            let io = detector.io.clone().unwrap_or_else(|| Io::of(&session));
            if detector.facts(graph::detector(&io, config, d)).is_some() {
                let ran = run::detector(session, d, image);
                detector.ran = detector.record(ran).unwrap_or_default();
            }
        }
        reports.push(detector);
    }

    if let Some(ocr) = &config.ocr {
        reports.extend(text::check_ocr(&env, config, ocr, image));
    }
    Ok(reports)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_synthetic_picture_has_a_sign_with_dark_letters() {
        let image = synthetic_image();
        assert_eq!(image.dimensions(), (640, 480));
        let ink = image
            .enumerate_pixels()
            .filter(|(_, _, p)| p.0 == [20, 20, 30])
            .count();
        // "HUMEM": 5x7 glyphs of 17, 15, 18, 18 and 18 dots, 25 px² each.
        assert_eq!(ink, (17 + 15 + 18 + 18 + 18) * 25);
        // The first glyph's top-left dot, and the paper around it.
        assert_eq!(image.get_pixel(237, 312).0, [20, 20, 30]);
        assert_eq!(image.get_pixel(236, 312).0, [235, 235, 220]);
    }
}
