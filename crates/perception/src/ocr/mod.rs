//! OCR with PP-OCRv5: text detection (DBNet) then line recognition (CRNN
//! with CTC), each batched across concurrent requests.
//!
//! Detection runs on a region (the whole image, or an object's box) at the
//! camera's aspect ratio, its long side scaled to the configured length
//! ([`canvas`]); regions of one shape batch together. Each detected line is
//! cropped from the full-resolution image, its contrast stretched, scaled
//! to the recogniser's line height and read; lines of a batch are padded to
//! the widest, as PaddleOCR does. PaddleOCR's models were trained
//! on OpenCV's BGR images with ImageNet normalisation for detection and
//! `(v − 0.5) / 0.5` for recognition; that is what they are fed here.
//!
//! The submodules use nothing of this one: [`crop`], which both this
//! module and the detector's input need, is [`canvas`]'s, re-exported.

pub mod canvas;
pub mod ctc;
pub mod db;

use std::sync::Arc;
use std::time::Duration;

use image::RgbImage;
use imageproc::geometric_transformations::{warp_into, Border, Interpolation, Projection};
use ort::session::Session;
use ort::value::TensorRef;

use super::batcher::{BatchError, BatchModel, Batcher};
use super::config::OcrConfig;
use super::geometry::Rect;
use super::image::{append_chw, resize, stretch_contrast, Channels};
use super::model::ImageModel;
use super::runtime::RuntimeError;
pub use canvas::crop;
use ctc::{Decoded, Dictionary};

const REC_MEAN: [f32; 3] = [0.5; 3];
const REC_STD: [f32; 3] = [0.5; 3];

/// One line of text read in an image.
#[derive(Debug, Clone, PartialEq)]
pub struct TextLine {
    /// Where the line is, in the image's pixels.
    pub rect: Rect,
    /// Detection score of the region.
    pub detection_score: f32,
    /// The text read.
    pub text: String,
    /// Recognition confidence.
    pub confidence: f32,
}

/// Time spent in each OCR stage for one request.
#[derive(Debug, Clone, Copy, Default)]
pub struct OcrTimes {
    /// Text detection: queueing plus inference.
    pub detection: Duration,
    /// Line recognition: the slowest line's queueing plus inference.
    pub recognition: Duration,
    /// The first look at the preview size found no text, and the
    /// detection at full size was skipped.
    pub skipped: bool,
}

/// The recogniser as a batch model: lines of one height and any width,
/// padded to the widest of the batch, decoded with CTC.
pub struct LineRecognizer {
    session: Session,
    input: String,
    output: String,
    height: usize,
    dictionary: Arc<Dictionary>,
}

/// A normalised line image: `[3, height, width]` values and its width.
pub struct LineInput {
    /// Width in pixels (the height is the recogniser's line height).
    pub width: usize,
    /// The three planes in BGR order, each row-major.
    pub data: Vec<f32>,
}

impl LineRecognizer {
    /// Wraps a recogniser session (its first input and first output) that
    /// reads lines `height` pixels high into `dictionary`'s characters.
    pub fn new(
        session: Session,
        height: u32,
        dictionary: Arc<Dictionary>,
    ) -> Result<LineRecognizer, RuntimeError> {
        let (input, output) = io_names(&session, "ocr recognizer")?;
        Ok(LineRecognizer {
            session,
            input,
            output,
            height: height as usize,
            dictionary,
        })
    }

    fn error(&self, message: impl Into<String>) -> RuntimeError {
        RuntimeError::Run {
            model: "ocr recognizer".into(),
            message: message.into(),
        }
    }
}

impl BatchModel for LineRecognizer {
    type Input = LineInput;
    type Output = Decoded;

    fn run(&mut self, lines: Vec<LineInput>) -> Result<Vec<Decoded>, RuntimeError> {
        let n = lines.len();
        let width = lines.iter().map(|l| l.width).max().unwrap_or(0);
        let h = self.height;
        // Pad each line on the right with zeros (mid-grey once normalised).
        let mut data = vec![0.0f32; n * 3 * h * width];
        for (i, line) in lines.iter().enumerate() {
            if line.data.len() != 3 * h * line.width {
                return Err(self.error("line input has the wrong size"));
            }
            for c in 0..3 {
                for y in 0..h {
                    let src = &line.data[(c * h + y) * line.width..][..line.width];
                    let dst = ((i * 3 + c) * h + y) * width;
                    data[dst..dst + line.width].copy_from_slice(src);
                }
            }
        }
        let tensor = TensorRef::from_array_view(([n, 3, h, width], data.as_slice()))
            .map_err(|e| self.error(e.to_string()))?;
        let input = self.input.clone();
        let outputs = self
            .session
            .run(ort::inputs![input => tensor])
            .map_err(|e| RuntimeError::Run {
                model: "ocr recognizer".into(),
                message: e.to_string(),
            })?;
        let (shape, probs) = outputs[self.output.as_str()]
            .try_extract_tensor::<f32>()
            .map_err(|e| RuntimeError::Run {
                model: "ocr recognizer".into(),
                message: e.to_string(),
            })?;
        let dims: Vec<usize> = shape.iter().map(|&d| d.max(0) as usize).collect();
        let fail = |message: String| RuntimeError::Run {
            model: "ocr recognizer".into(),
            message,
        };
        let [batch, steps, classes] = dims[..] else {
            return Err(fail(format!("output shape {dims:?}, expected [N, T, C]")));
        };
        if batch != n || classes != self.dictionary.len() {
            return Err(fail(format!(
                "output shape {dims:?} does not fit {n} lines and a dictionary of {}",
                self.dictionary.len()
            )));
        }
        Ok((0..n)
            .map(|i| {
                let item = &probs[i * steps * classes..(i + 1) * steps * classes];
                ctc::decode(item, steps, classes, &self.dictionary)
            })
            .collect())
    }
}

/// Text detection and recognition, batched.
#[derive(Clone)]
pub struct Ocr {
    detector: Batcher<ImageModel>,
    recognizer: Batcher<LineRecognizer>,
    config: OcrConfig,
    params: db::DbParams,
}

/// Sessions for the OCR models, one per worker.
pub struct OcrModels {
    /// The text detector (DBNet), one per worker.
    pub detectors: Vec<ImageModel>,
    /// The line recogniser, one per worker.
    pub recognizers: Vec<LineRecognizer>,
}

impl OcrModels {
    /// Wraps loaded sessions: `sessions` gives a (detector, recognizer) pair
    /// per worker.
    pub fn new(
        sessions: Vec<(Session, Session)>,
        config: &OcrConfig,
        dictionary: Arc<Dictionary>,
    ) -> Result<OcrModels, RuntimeError> {
        let mut detectors = Vec::new();
        let mut recognizers = Vec::new();
        for (det, rec) in sessions {
            detectors.push(text_detector(det)?);
            recognizers.push(LineRecognizer::new(
                rec,
                config.line_height,
                dictionary.clone(),
            )?);
        }
        Ok(OcrModels {
            detectors,
            recognizers,
        })
    }
}

/// Wraps a text detector session (its first input and first output), a
/// fully convolutional model that takes any size.
pub fn text_detector(session: Session) -> Result<ImageModel, RuntimeError> {
    let (input, output) = io_names(&session, "ocr detector")?;
    ImageModel::new("ocr detector", session, &input, &[output], None)
}

/// The names of a session's first input and first output.
fn io_names(session: &Session, model: &str) -> Result<(String, String), RuntimeError> {
    let first = |names: Vec<String>, what: &str| {
        names.into_iter().next().ok_or_else(|| RuntimeError::Run {
            model: model.into(),
            message: format!("has no {what}"),
        })
    };
    Ok((
        first(
            session
                .inputs()
                .iter()
                .map(|i| i.name().to_string())
                .collect(),
            "input",
        )?,
        first(
            session
                .outputs()
                .iter()
                .map(|o| o.name().to_string())
                .collect(),
            "output",
        )?,
    ))
}

impl Ocr {
    /// Starts the detector's and the recogniser's batchers (queues `ocr-det`
    /// and `ocr-rec`, reported to `observer`).
    pub fn new(
        models: OcrModels,
        config: &OcrConfig,
        batching: super::batcher::BatchConfig,
        observer: &humem_core::observe::SharedObserver,
    ) -> Ocr {
        Ocr {
            detector: Batcher::spawn("ocr-det", models.detectors, batching, observer.clone()),
            recognizer: Batcher::spawn("ocr-rec", models.recognizers, batching, observer.clone()),
            config: config.clone(),
            params: db::DbParams::default(),
        }
    }

    /// Reads the text in `region` of `image` (the whole image if `None`):
    /// lines in reading order, those read with too little confidence dropped.
    pub async fn read(
        &self,
        image: Arc<RgbImage>,
        region: Option<Rect>,
        times: &mut OcrTimes,
    ) -> Result<Vec<TextLine>, BatchError> {
        let (w, h) = (image.width() as f32, image.height() as f32);
        let region = region
            .unwrap_or(Rect {
                x0: 0.0,
                y0: 0.0,
                x1: w,
                y1: h,
            })
            .clamp(w, h);
        if region.width() < 4.0 || region.height() < 4.0 {
            return Ok(Vec::new());
        }
        // A first look at the preview size: where it finds no text, the
        // detection at full size would find little, and is skipped.
        let preview = self.config.preview_long_side;
        if preview > 0 && preview < self.config.detector_long_side {
            let glimpse = self.detect(&image, region, preview, times).await?;
            if glimpse.is_empty() {
                times.skipped = true;
                return Ok(Vec::new());
            }
        }
        let found = self
            .detect(&image, region, self.config.detector_long_side, times)
            .await?;
        if found.is_empty() {
            return Ok(Vec::new());
        }

        let (lh, max_w) = (self.config.line_height, self.config.max_line_width);
        let line_inputs = {
            let quads: Vec<[[f32; 2]; 4]> = found.iter().map(|(_, q, _)| *q).collect();
            tokio::task::spawn_blocking(move || {
                quads
                    .iter()
                    .map(|&q| line_input(&image, q, lh, max_w))
                    .collect::<Vec<_>>()
            })
            .await
            .map_err(|e| runtime(format!("text line preprocessing failed: {e}")))?
        };
        // All lines are queued at once, so they share recogniser batches.
        let reads =
            futures::future::join_all(line_inputs.into_iter().map(|l| self.recognizer.infer(l)))
                .await;
        let mut lines = Vec::new();
        let mut slowest = Duration::ZERO;
        for ((rect, _, score), read) in found.into_iter().zip(reads) {
            let read = read?;
            slowest = slowest.max(read.inference + read.queued);
            let Decoded { text, confidence } = read.output;
            tracing::debug!(?rect, score, %text, confidence, "text line");
            if !text.is_empty() && confidence >= self.config.min_confidence {
                lines.push(TextLine {
                    rect,
                    detection_score: score,
                    text,
                    confidence,
                });
            }
        }
        times.recognition += slowest;
        Ok(lines)
    }

    /// The text boxes found in `region` of `image` with the detector's
    /// input at `long_side`: image-pixel rectangles, quads and scores.
    async fn detect(
        &self,
        image: &Arc<RgbImage>,
        region: Rect,
        long_side: u32,
        times: &mut OcrTimes,
    ) -> Result<Vec<Found>, BatchError> {
        let (w, h) = (image.width() as f32, image.height() as f32);
        let (det_input, placement) = {
            let image = image.clone();
            tokio::task::spawn_blocking(move || canvas::detector_input(&image, region, long_side))
                .await
                .map_err(|e| runtime(format!("text detection preprocessing failed: {e}")))?
        };
        let detected = self.detector.infer(det_input).await?;
        times.detection += detected.inference + detected.queued;
        let Some((shape, prob)) = detected.output.0.into_iter().next() else {
            return Ok(Vec::new());
        };
        let (mh, mw) = match shape[..] {
            [1, mh, mw] | [mh, mw] => (mh, mw),
            _ => return Err(runtime(format!("text detection output shape {shape:?}"))),
        };
        // The map has the input's size; map pixels back to image pixels.
        let [iw, ih] = placement.input.map(|s| s as f32);
        let (sx, sy) = (
            iw / mw as f32 / placement.scale,
            ih / mh as f32 / placement.scale,
        );
        let mut boxes = db::text_boxes(&prob, mw, mh, &self.params);
        boxes.truncate(self.config.max_lines);
        let to_image = |[x, y]: [f32; 2]| [x * sx + region.x0, y * sy + region.y0];
        let found: Vec<Found> = boxes
            .into_iter()
            .map(|b| {
                let r = b.rect.scale(sx, sy);
                let r = Rect {
                    x0: r.x0 + region.x0,
                    y0: r.y0 + region.y0,
                    x1: r.x1 + region.x0,
                    y1: r.y1 + region.y0,
                };
                (r.clamp(w, h), b.quad.map(to_image), b.score)
            })
            .filter(|(r, _, _)| r.width() >= 2.0 && r.height() >= 2.0)
            .collect();
        Ok(found)
    }
}

/// A detected text box: its rectangle and quad in image pixels, and its
/// score.
type Found = (Rect, [[f32; 2]; 4], f32);

fn runtime(message: String) -> BatchError {
    BatchError::Runtime(RuntimeError::Run {
        model: "ocr".into(),
        message,
    })
}

/// A text line cut out along its (possibly rotated) box `quad` (corners
/// top-left, top-right, bottom-right, bottom-left, image pixels), turned
/// upright if it stands (as PaddleOCR does), and scaled to the
/// recogniser's height keeping its aspect ratio, up to `max_width`.
pub fn line_input(image: &RgbImage, quad: [[f32; 2]; 4], height: u32, max_width: u32) -> LineInput {
    let dist = |a: [f32; 2], b: [f32; 2]| (a[0] - b[0]).hypot(a[1] - b[1]);
    let cw = dist(quad[0], quad[1])
        .max(dist(quad[3], quad[2]))
        .round()
        .max(1.0);
    let ch = dist(quad[0], quad[3])
        .max(dist(quad[1], quad[2]))
        .round()
        .max(1.0);
    let target = [(0.0, 0.0), (cw, 0.0), (cw, ch), (0.0, ch)];
    let mut line = RgbImage::new(cw as u32, ch as u32);
    match Projection::from_control_points(quad.map(|[x, y]| (x, y)), target) {
        Some(projection) => warp_into(
            image,
            projection,
            Interpolation::Bilinear,
            Border::Replicate,
            &mut line,
        ),
        None => {
            // A degenerate quadrilateral: fall back to its bounds.
            let xs = quad.map(|p| p[0]);
            let ys = quad.map(|p| p[1]);
            let bounds = Rect {
                x0: xs.iter().copied().fold(f32::INFINITY, f32::min),
                y0: ys.iter().copied().fold(f32::INFINITY, f32::min),
                x1: xs.iter().copied().fold(f32::NEG_INFINITY, f32::max),
                y1: ys.iter().copied().fold(f32::NEG_INFINITY, f32::max),
            };
            line = crop(
                image,
                bounds.clamp(image.width() as f32, image.height() as f32),
            );
        }
    }
    // Dim or foggy signs read better at full contrast; 2 % of the pixels
    // may clip at either end.
    stretch_contrast(&mut line, 0.02, 0.98);
    if line.height() as f32 >= 1.5 * line.width() as f32 {
        line = image::imageops::rotate270(&line);
    }
    let aspect = line.width() as f32 / line.height().max(1) as f32;
    let width = ((height as f32 * aspect).round() as u32).clamp(height / 2, max_width);
    let resized = resize(&line, width, height);
    let mut data = Vec::with_capacity(3 * (width * height) as usize);
    append_chw(&resized, Channels::Bgr, REC_MEAN, REC_STD, &mut data);
    LineInput {
        width: width as usize,
        data,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slanted_lines_are_cut_out_upright() {
        // A white image with a dark parallelogram band rising to the right.
        let mut image = RgbImage::from_pixel(200, 120, image::Rgb([255, 255, 255]));
        let quad = [[20.0, 60.0], [180.0, 20.0], [180.0, 50.0], [20.0, 90.0]];
        for y in 0..120u32 {
            for x in 20..180u32 {
                let top = 60.0 - 40.0 * (x as f32 - 20.0) / 160.0;
                if (y as f32) >= top + 5.0 && (y as f32) < top + 25.0 {
                    image.put_pixel(x, y, image::Rgb([0, 0, 0]));
                }
            }
        }
        let line = line_input(&image, quad, 48, 480);
        // Cut along the band, the line is about 165 x 30, so ~264 wide at 48.
        assert!((250..=280).contains(&line.width), "width {}", line.width);
        // Its middle rows are dark along the whole width (the band is
        // straight once cut out), its first row is light.
        let plane = &line.data[..48 * line.width];
        let row_mean = |y: usize| {
            plane[y * line.width..(y + 1) * line.width]
                .iter()
                .sum::<f32>()
                / line.width as f32
        };
        assert!(row_mean(24) < -0.8, "middle row {}", row_mean(24));
        assert!(row_mean(1) > 0.8, "top row {}", row_mean(1));
    }

    #[test]
    fn standing_lines_are_turned() {
        let image = RgbImage::from_pixel(100, 300, image::Rgb([128, 128, 128]));
        let quad = [[40.0, 10.0], [60.0, 10.0], [60.0, 290.0], [40.0, 290.0]];
        let line = line_input(&image, quad, 48, 480);
        assert!(line.width > 48 * 5, "width {}", line.width);
    }
}
