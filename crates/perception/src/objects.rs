//! The object detector role: an Ultralytics YOLO detect or segment export,
//! batched like every model, with the geometry HuMem needs.
//!
//! Images are letterboxed into the export's square input the way
//! Ultralytics does (aspect kept, centred, padded with grey 114, RGB scaled
//! to [0, 1]). Outputs are decoded for either layout (`[1, 4 + nc (+ 32), A]`
//! with NMS, or the NMS-free `[1, N, 6 (+ 32)]`), restricted to the
//! configured static classes, and each object's centroid and area come from
//! its mask when the export has prototype masks, else from its box; all are
//! mapped back to the original image's pixels.

use std::sync::Arc;
use std::time::Duration;

use image::RgbImage;

use super::batcher::{BatchConfig, BatchError, Batcher};
use super::config::{DetectorConfig, PerceptionConfig, YoloLayout};
use super::geometry::Rect;
use super::image::resize;
use super::model::{ImageModel, Planes};
use super::runtime::{self, RuntimeError};
use super::signature::Io;
use super::yolo::{self, Layout};
use humem_core::observe::SharedObserver;

/// Grey of Ultralytics' letterbox padding.
const PAD: u8 = 114;

/// An object found in an image, in the image's pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct DetectedObject {
    /// The class, one of the configured class names.
    pub class_name: String,
    /// The detector's score, in [0, 1].
    pub confidence: f32,
    /// The box, clamped to the image.
    pub rect: Rect,
    /// `[x, y]` centre of the mask, or of the box without masks, in pixels.
    pub centroid: [f32; 2],
    /// Pixels² covered (mask or box).
    pub area: f32,
}

/// Where an image sits in the letterboxed input.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Letterbox {
    /// Input pixels per image pixel (the same on both axes).
    pub scale: f32,
    /// `[x, y]` padding before the image in the input, in input pixels.
    pub pad: [f32; 2],
}

impl Letterbox {
    /// Where a `width` × `height` image sits in a `size` × `size` input:
    /// scaled to fit, aspect kept, centred (padding rounded down).
    pub fn new(width: u32, height: u32, size: u32) -> Letterbox {
        let scale = (size as f32 / width as f32).min(size as f32 / height as f32);
        let (w, h) = (width as f32 * scale, height as f32 * scale);
        Letterbox {
            scale,
            pad: [
                ((size as f32 - w) / 2.0).floor(),
                ((size as f32 - h) / 2.0).floor(),
            ],
        }
    }

    /// An input-pixel point in image pixels.
    pub fn to_image(&self, [x, y]: [f32; 2]) -> [f32; 2] {
        [
            (x - self.pad[0]) / self.scale,
            (y - self.pad[1]) / self.scale,
        ]
    }
}

/// The letterboxed, `[0, 1]`-scaled CHW input of `image`.
pub fn letterbox_input(image: &RgbImage, size: u32) -> (Planes, Letterbox) {
    let lb = Letterbox::new(image.width(), image.height(), size);
    let w = ((image.width() as f32 * lb.scale).round() as u32).clamp(1, size);
    let h = ((image.height() as f32 * lb.scale).round() as u32).clamp(1, size);
    let resized = resize(image, w, h);
    let mut canvas = RgbImage::from_pixel(size, size, image::Rgb([PAD; 3]));
    image::imageops::replace(
        &mut canvas,
        &resized,
        i64::from(lb.pad[0] as u32),
        i64::from(lb.pad[1] as u32),
    );
    let n = (size * size) as usize;
    let mut data = vec![0.0f32; 3 * n];
    for (i, p) in canvas.pixels().enumerate() {
        for c in 0..3 {
            data[c * n + i] = f32::from(p.0[c]) / 255.0;
        }
    }
    let side = size as usize;
    (
        Planes {
            width: side,
            height: side,
            data,
        },
        lb,
    )
}

/// The detector: its batcher and configuration.
#[derive(Clone)]
pub struct Detector {
    batcher: Batcher<ImageModel>,
    config: DetectorConfig,
}

impl Detector {
    /// Loads one session per worker.
    pub fn load(
        env: &ort::environment::Environment,
        perception: &PerceptionConfig,
        config: &DetectorConfig,
        batching: BatchConfig,
        observer: &SharedObserver,
    ) -> Result<Detector, RuntimeError> {
        let path = perception.model_file(&config.model, config.precision)?;
        let mut outputs = vec![config.output.clone()];
        outputs.extend(config.masks_output.clone());
        let models = (0..perception.workers.max(1))
            .map(|worker| {
                let options = config.precision.options(perception.session_options());
                let session = runtime::session(env, &path, options)?;
                if worker == 0 {
                    crate::check::graph::detector(&Io::of(&session), perception, config)
                        .map_err(|e| RuntimeError::Check(Box::new(e)))?;
                }
                let size = config.size as usize;
                ImageModel::new(
                    "detector",
                    session,
                    &config.input,
                    &outputs,
                    Some([size, size]),
                )
            })
            .collect::<Result<Vec<_>, RuntimeError>>()?;
        tracing::info!(role = "detector", model = %path.display(), "model loaded");
        Ok(Detector {
            batcher: Batcher::spawn("detector", models, batching, observer.clone()),
            config: config.clone(),
        })
    }

    /// Whether text is read on objects of this class.
    pub fn reads_text_on(&self, class_name: &str) -> bool {
        self.config.text_classes.is_empty()
            || self.config.text_classes.iter().any(|c| c == class_name)
    }

    /// The objects in `image` and the time the detector took.
    pub async fn detect(
        &self,
        image: Arc<RgbImage>,
    ) -> Result<(Vec<DetectedObject>, Duration), BatchError> {
        let size = self.config.size;
        let (width, height) = (image.width(), image.height());
        let (input, letterbox) = tokio::task::spawn_blocking(move || letterbox_input(&image, size))
            .await
            .map_err(|e| error(format!("detector preprocessing failed: {e}")))?;
        let inferred = self.batcher.infer(input).await?;
        let took = inferred.inference + inferred.queued;
        let mut outputs = inferred.output.0.into_iter();
        let (shape, values) = outputs
            .next()
            .ok_or_else(|| error("detector gave no output".into()))?;
        let masks = outputs.next();
        let objects = self
            .objects(&shape, &values, masks.as_ref(), letterbox, [width, height])
            .map_err(|e| error(e.to_string()))?;
        Ok((objects, took))
    }

    /// Decodes one image's outputs (shapes without the batch axis).
    pub fn objects(
        &self,
        shape: &[usize],
        values: &[f32],
        masks: Option<&(Vec<usize>, Vec<f32>)>,
        letterbox: Letterbox,
        size: [u32; 2],
    ) -> Result<Vec<DetectedObject>, yolo::YoloError> {
        decode_objects(&self.config, shape, values, masks, letterbox, size)
    }
}

/// Decodes one image's outputs (shapes without the batch axis) of the
/// detector configured by `c`: detections of the kept classes, suppressed
/// and mapped back to the `width` × `height` image through `letterbox`.
pub fn decode_objects(
    c: &DetectorConfig,
    shape: &[usize],
    values: &[f32],
    masks: Option<&(Vec<usize>, Vec<f32>)>,
    letterbox: Letterbox,
    [width, height]: [u32; 2],
) -> Result<Vec<DetectedObject>, yolo::YoloError> {
    let num_masks = masks.map_or(0, |(s, _)| s.first().copied().unwrap_or(0));
    let layout = match c.layout {
        YoloLayout::Anchors => Layout::Anchors,
        YoloLayout::EndToEnd => Layout::EndToEnd,
    };
    let mut batch_shape = vec![1];
    batch_shape.extend_from_slice(shape);
    let mut detections = yolo::decode(
        values,
        &batch_shape,
        layout,
        c.classes.len(),
        num_masks,
        c.confidence,
    )?;
    if layout == Layout::Anchors {
        detections = yolo::nms(detections, c.iou, c.max_objects);
    }
    detections.truncate(c.max_objects);
    let size = c.size as usize;
    let (w, h) = (width as f32, height as f32);
    let mut objects = Vec::new();
    for det in detections {
        let class_name = &c.classes[det.class_id];
        if !c.keep.is_empty() && !c.keep.contains(class_name) {
            continue;
        }
        let [x0, y0] = letterbox.to_image([det.rect.x0, det.rect.y0]);
        let [x1, y1] = letterbox.to_image([det.rect.x1, det.rect.y1]);
        let rect = Rect { x0, y0, x1, y1 }.clamp(w, h);
        if rect.width() <= 0.0 || rect.height() <= 0.0 {
            continue;
        }
        let from_mask = masks.and_then(|(mshape, protos)| match mshape[..] {
            [nm, mh, mw] => yolo::mask_stats(protos, [nm, mh, mw], &det, [size, size]),
            _ => None,
        });
        let (centroid, area) = match from_mask {
            Some(m) => (
                letterbox.to_image(m.centroid),
                m.area / (letterbox.scale * letterbox.scale),
            ),
            None => (rect.center(), rect.area()),
        };
        objects.push(DetectedObject {
            class_name: class_name.clone(),
            confidence: det.score.clamp(0.0, 1.0),
            rect,
            centroid: [centroid[0].clamp(0.0, w), centroid[1].clamp(0.0, h)],
            area: area.clamp(0.0, w * h),
        });
    }
    Ok(objects)
}

fn error(message: String) -> BatchError {
    BatchError::Runtime(RuntimeError::Run {
        model: "detector".into(),
        message,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn letterbox_keeps_aspect_and_centres() {
        // 200x100 into 64: scale 0.32, 64x32, padded 16 above and below.
        let lb = Letterbox::new(200, 100, 64);
        assert!((lb.scale - 0.32).abs() < 1e-6);
        assert_eq!(lb.pad, [0.0, 16.0]);
        assert_eq!(lb.to_image([32.0, 32.0]), [100.0, 50.0]);
        let image = RgbImage::from_pixel(200, 100, image::Rgb([255, 0, 0]));
        let (Planes { data, .. }, _) = letterbox_input(&image, 64);
        // Red plane: padding grey at the top row, image red in the middle.
        assert!((data[0] - 114.0 / 255.0).abs() < 1e-6);
        assert_eq!(data[32 * 64 + 32], 1.0);
        // Green plane in the middle: 0.
        assert_eq!(data[64 * 64 + 32 * 64 + 32], 0.0);
    }
}
