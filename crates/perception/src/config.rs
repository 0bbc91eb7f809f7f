//! What models perception runs, described as data.
//!
//! Each role (global descriptor, scene context, objects, OCR) names an ONNX
//! file, its input size and normalisation and the outputs to read, so that
//! the paper's models (EigenPlaces, Places365, a YOLO-seg, PP-OCRv5) replace
//! the defaults by editing this configuration only. Paths are relative to
//! `models_dir` unless absolute. The defaults are what
//! `scripts/setup-models.sh` installs.

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::batcher::BatchConfig;
use super::runtime::{ExecutionProvider, RuntimeError, SessionOptions};

/// Normalisation of EfficientNet-Lite: mean 127, std 128 on 0..255.
const LITE_MEAN: [f32; 3] = [127.0 / 255.0; 3];
const LITE_STD: [f32; 3] = [128.0 / 255.0; 3];
const EFFICIENTNET: &str = "efficientnet-lite0/efficientnet_lite0.onnx";
/// Input size of the default descriptor. Measured with the GeM descriptor
/// alone (R@1 on corridor / rtabmap-loop / gardens-daynight): 224x224 gives
/// 0.60 / 0.95 / 0.4, 384x288 gives 0.72 / 0.95 / 0.4, 512x384 gives
/// 0.73 / 0.93 / 0.2, at about 0.5x the cost of 512x384.
const DESCRIPTOR_SIZE: [u32; 2] = [384, 288];
/// Precision of the default descriptor (and scene) model: int8 keeps
/// parity (mean Full R@1 over the 8 dev sets 0.635 fp32, 0.666 int8, every
/// model int8) at 0.47x the core time (docs/using.md, "Quantised models").
const DESCRIPTOR_PRECISION: Precision = Precision::Int8;
/// Precision of the default text detector: fp32, since int8 lost text
/// recall (town-dev/loop 0.383 → 0.267).
const OCR_DETECTOR_PRECISION: Precision = Precision::Fp32;
/// Precision of the default line recogniser: fp32 (int8 with the int8
/// detector: text recall over the town sets 0.256 → 0.124).
const OCR_RECOGNIZER_PRECISION: Precision = Precision::Fp32;

/// Which version of a model runs: the fp32 file as configured, or its int8
/// quantisation beside it (`name.onnx` → `name.int8.onnx`, what
/// `scripts/setup-models.sh` makes for the shipped models and
/// `tools/quantize_models.py` for others).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// The configured file.
    #[default]
    Fp32,
    /// Its int8 (QDQ) quantisation.
    Int8,
}

impl Precision {
    /// `options` for a model of this precision.
    pub fn options(self, options: SessionOptions) -> SessionOptions {
        SessionOptions {
            int8: self == Precision::Int8,
            ..options
        }
    }

    /// The file of `model` at this precision.
    pub fn file(self, model: &Path) -> PathBuf {
        match self {
            Precision::Fp32 => model.to_path_buf(),
            Precision::Int8 => {
                let stem = model.file_stem().unwrap_or_default().to_string_lossy();
                model.with_file_name(format!("{stem}.int8.onnx"))
            }
        }
    }
}

/// The `[perception]` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PerceptionConfig {
    /// Load the models at start; without them only precomputed features are
    /// accepted and requests with images get FAILED_PRECONDITION.
    pub enabled: bool,
    /// Folder of the models (what scripts/setup-models.sh fills).
    pub models_dir: PathBuf,
    /// The ONNX Runtime shared library; default `ORT_DYLIB_PATH`, else
    /// `<models_dir>/lib/libonnxruntime.so`.
    pub onnxruntime: Option<PathBuf>,
    /// `cpu`, `cuda` or `tensorrt` (the last two need the cargo feature of
    /// the same name; the CPU is the fallback).
    pub provider: ExecutionProvider,
    /// Threads one inference may use; 0 = half the machine's cores (at
    /// least 1), since the descriptor and OCR models run at the same time
    /// and oversubscribed cores slowed both in `humem bench perception`.
    pub intra_threads: usize,
    /// Nice value of every perception thread (model workers and ONNX
    /// Runtime's pools), 0 to 19: above 0, the SLAM process beside it wins
    /// the cores whenever both want them (Linux; see [`crate::cpu`]).
    /// The gRPC service and the store keep their priority.
    pub nice: i32,
    /// Sessions (and worker threads) per model.
    pub workers: usize,
    /// Most images (or text lines) per inference; 0 = 1 on the CPU, 8 with
    /// a GPU provider. On a CPU a batch costs about as much per image as
    /// single inferences and only delays answers (see the perception
    /// benchmark in docs/benchmarks.md); GPUs are where batching pays.
    pub max_batch: usize,
    /// Longest a request waits for others to share its inference, in ms.
    pub max_wait_ms: u64,
    /// Most requests waiting per model before new ones are refused.
    pub queue: usize,
    /// The global descriptor model.
    pub descriptor: ImageModelConfig,
    /// The scene-context model; the same file and input as the descriptor
    /// means one inference gives both.
    pub scene: Option<ImageModelConfig>,
    /// The object detector (a YOLO detect or segment export); none: OCR
    /// text regions become objects of class `sign`.
    pub detector: Option<DetectorConfig>,
    /// Text detection and recognition.
    pub ocr: Option<OcrConfig>,
    /// Compute the appearance thumbnail of every image (no model; about
    /// 1 ms). It counts in the score with `vpr.appearance_weight`.
    pub appearance: bool,
    /// Objects and their text carried over between similar keyframes of
    /// one session instead of detected and read again ([`crate::reuse`]).
    pub reuse: crate::reuse::ReuseConfig,
}

impl Default for PerceptionConfig {
    fn default() -> Self {
        PerceptionConfig {
            enabled: true,
            models_dir: PathBuf::from("./models"),
            onnxruntime: None,
            provider: ExecutionProvider::Cpu,
            intra_threads: 0,
            nice: 0,
            workers: 1,
            max_batch: 0,
            max_wait_ms: 2,
            queue: 256,
            descriptor: efficientnet("descriptor"),
            scene: Some(efficientnet("scene")),
            detector: None,
            ocr: Some(OcrConfig::default()),
            appearance: true,
            reuse: crate::reuse::ReuseConfig::default(),
        }
    }
}

/// The default EfficientNet-Lite0, read at `output`.
fn efficientnet(output: &str) -> ImageModelConfig {
    ImageModelConfig {
        model: PathBuf::from(EFFICIENTNET),
        input: "image".into(),
        width: DESCRIPTOR_SIZE[0],
        height: DESCRIPTOR_SIZE[1],
        mean: LITE_MEAN,
        std: LITE_STD,
        output: output.into(),
        precision: None,
        input_multiple: 0,
        output_len: None,
    }
}

impl PerceptionConfig {
    /// The ONNX Runtime library to load: `onnxruntime`, else
    /// `ORT_DYLIB_PATH`, else the one under `models_dir`
    /// ([`crate::runtime::library_path`]).
    pub fn onnxruntime_library(&self) -> PathBuf {
        crate::runtime::library_path(self.onnxruntime.as_deref(), &self.models_dir)
    }

    /// `path` under `models_dir` unless it is absolute.
    pub fn resolve(&self, path: &Path) -> PathBuf {
        if path.is_absolute() {
            path.to_path_buf()
        } else {
            self.models_dir.join(path)
        }
    }

    /// The file of `model` at `precision`, resolved; an int8 file that is
    /// missing is named as such, with how to make it.
    pub fn model_file(&self, model: &Path, precision: Precision) -> Result<PathBuf, RuntimeError> {
        let path = self.resolve(&precision.file(model));
        if precision == Precision::Int8 && !path.exists() {
            return Err(RuntimeError::QuantizedMissing(path));
        }
        Ok(path)
    }

    /// How every model's requests are batched: `max_batch` resolved for the
    /// provider, `max_wait_ms` as a duration, a queue of at least 1.
    pub fn batching(&self) -> BatchConfig {
        BatchConfig {
            max_batch: match (self.max_batch, self.provider) {
                (0, ExecutionProvider::Cpu) => 1,
                (0, _) => 8,
                (n, _) => n,
            },
            max_wait: Duration::from_millis(self.max_wait_ms),
            queue: self.queue.max(1),
        }
    }

    /// The options of every model's sessions: the provider, and
    /// `intra_threads` with 0 resolved to half the machine's cores (`int8`
    /// false: each int8 model sets it, see [`Precision::options`]).
    pub fn session_options(&self) -> SessionOptions {
        SessionOptions {
            int8: false,
            provider: self.provider,
            intra_threads: match self.intra_threads {
                0 => std::thread::available_parallelism().map_or(1, |n| (n.get() / 2).max(1)),
                n => n,
            },
        }
    }

    /// Checks the settings that can be wrong without touching a file.
    pub fn validate(&self) -> Result<(), String> {
        let mut models = vec![("descriptor", &self.descriptor)];
        if let Some(scene) = &self.scene {
            models.push(("scene", scene));
        }
        for (role, m) in models {
            m.validate().map_err(|e| format!("perception.{role}.{e}"))?;
        }
        if let Some(ocr) = &self.ocr {
            ocr.validate().map_err(|e| format!("perception.ocr.{e}"))?;
        }
        if let Some(detector) = &self.detector {
            detector
                .validate()
                .map_err(|e| format!("perception.detector.{e}"))?;
        }
        self.reuse
            .validate()
            .map_err(|e| format!("perception.reuse.{e}"))?;
        if self.workers == 0 {
            return Err("perception.workers must be at least 1".into());
        }
        if !(0..=crate::cpu::MAX_NICE).contains(&self.nice) {
            return Err(format!(
                "perception.nice must be between 0 and {} (a lower priority only), not {}",
                crate::cpu::MAX_NICE,
                self.nice
            ));
        }
        Ok(())
    }
}

/// A model over one resized, normalised RGB image.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImageModelConfig {
    /// ONNX file.
    pub model: PathBuf,
    /// Input tensor name; the input is `[N, 3, height, width]` float RGB.
    pub input: String,
    /// Input width in pixels; the image is resized to it without keeping
    /// its aspect ratio.
    pub width: u32,
    /// Input height in pixels.
    pub height: u32,
    /// Per-channel normalisation `(v / 255 − mean) / std`.
    pub mean: [f32; 3],
    /// Per-channel divisor of that normalisation; must be positive.
    pub std: [f32; 3],
    /// Output tensor name: `[N, D]` descriptor, or `[N, C]` class
    /// probabilities for the scene role.
    pub output: String,
    /// `fp32` (the file as named) or `int8` (its quantisation beside it);
    /// unset: int8 for the shipped EfficientNet-Lite0 (measured to keep
    /// parity) and fp32 for any other model, which has no int8 file unless
    /// its user makes one ([`ImageModelConfig::precision`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub precision: Option<Precision>,
    /// `width` and `height` must be multiples of this, for a model whose
    /// graph takes any size but works only on whole patches (a ViT/14, e.g.
    /// DINOv2: 14); 0 or 1: any size. Checked when the model loads and by
    /// `humem models check`.
    #[serde(default)]
    pub input_multiple: u32,
    /// Values per image the output must have: the descriptor's length, or
    /// the scene model's class count (365 for Places365); unset: whatever
    /// the graph gives (the descriptor is still checked against
    /// `store.descriptor_dim` and a store's recorded length).
    #[serde(default)]
    pub output_len: Option<usize>,
}

impl ImageModelConfig {
    /// The precision that runs: the configured one, else int8 for the
    /// shipped EfficientNet-Lite0 and fp32 for any other model (a section
    /// that names a user's model without a precision must not go looking
    /// for an int8 file that was never made).
    pub fn precision(&self) -> Precision {
        self.precision
            .unwrap_or(if self.model == Path::new(EFFICIENTNET) {
                DESCRIPTOR_PRECISION
            } else {
                Precision::Fp32
            })
    }

    /// Same file and same input: one inference can serve both.
    pub fn shares_input_with(&self, other: &ImageModelConfig) -> bool {
        self.model == other.model
            && self.input == other.input
            && self.width == other.width
            && self.height == other.height
            && self.mean == other.mean
            && self.std == other.std
            && self.precision() == other.precision()
    }

    fn validate(&self) -> Result<(), String> {
        if !(16..=4096).contains(&self.width) || !(16..=4096).contains(&self.height) {
            return Err(format!(
                "width/height {}x{} outside 16..=4096",
                self.width, self.height
            ));
        }
        if self.std.iter().any(|&s| s.is_nan() || s <= 0.0) {
            return Err("std must be positive".into());
        }
        Ok(())
    }
}

/// Ultralytics YOLO output layouts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum YoloLayout {
    /// v8/v11 `[1, 4 + classes (+ 32 mask coefficients), anchors]`, needs NMS.
    Anchors,
    /// NMS-free `[1, N, 6 (+ 32)]`: x1, y1, x2, y2, score, class.
    EndToEnd,
}

/// The object detector.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectorConfig {
    /// ONNX file.
    pub model: PathBuf,
    /// Input tensor name (default `images`); the input is
    /// `[N, 3, size, size]` letterboxed RGB in [0, 1].
    #[serde(default = "default_image_input")]
    pub input: String,
    /// Square input side the export was made for (e.g. 640).
    pub size: u32,
    /// Which output layout the export has.
    pub layout: YoloLayout,
    /// Class names in the model's order.
    pub classes: Vec<String>,
    /// The static classes kept (others are dropped); their importance ω is
    /// `vpr.class_weights`. Empty: keep all.
    #[serde(default)]
    pub keep: Vec<String>,
    /// Detection output tensor name (default `output0`).
    #[serde(default = "default_detections_output")]
    pub output: String,
    /// Prototype masks output tensor name, for segment exports; none for
    /// detect exports.
    #[serde(default)]
    pub masks_output: Option<String>,
    /// Detections scoring at or below this are dropped (default 0.25).
    #[serde(default = "default_confidence")]
    pub confidence: f32,
    /// NMS threshold: a box whose IoU with a better box of its class
    /// exceeds this is dropped (default 0.45; `anchors` layout only).
    #[serde(default = "default_iou")]
    pub iou: f32,
    /// Most detections kept per image (default 64).
    #[serde(default = "default_max_objects")]
    pub max_objects: usize,
    /// Classes on which text is read (e.g. billboards, signs); empty: all.
    #[serde(default)]
    pub text_classes: Vec<String>,
    /// `fp32` (the file as named) or `int8` (its quantisation beside it).
    #[serde(default)]
    pub precision: Precision,
}

fn default_image_input() -> String {
    "images".into()
}
fn default_detections_output() -> String {
    "output0".into()
}
fn default_confidence() -> f32 {
    0.25
}
fn default_iou() -> f32 {
    0.45
}
fn default_max_objects() -> usize {
    64
}

impl DetectorConfig {
    fn validate(&self) -> Result<(), String> {
        if self.classes.is_empty() {
            return Err("classes must name the model's classes".into());
        }
        if let Some(k) = self.keep.iter().find(|k| !self.classes.contains(k)) {
            return Err(format!("keep names {k:?}, which is not in classes"));
        }
        if !(32..=4096).contains(&self.size) {
            return Err(format!("size {} outside 32..=4096", self.size));
        }
        Ok(())
    }
}

/// PP-OCR text detection and recognition.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OcrConfig {
    /// ONNX file of the text detector (DBNet).
    pub detector: PathBuf,
    /// ONNX file of the line recogniser (CRNN with CTC).
    pub recognizer: PathBuf,
    /// `fp32` or `int8` for the detector's file.
    pub detector_precision: Precision,
    /// `fp32` or `int8` for the recogniser's file.
    pub recognizer_precision: Precision,
    /// Character list index-aligned with the recogniser's classes.
    pub dictionary: PathBuf,
    /// Text detection input: the region (the whole image, or an object's
    /// box) keeps its aspect ratio and is scaled so that its long side is
    /// this many pixels; each side is then padded up to a multiple of 32.
    /// The camera's own width (512 for 512x288) reads what the pixels hold
    /// at the least cost; a larger value finds smaller text, slower.
    pub detector_long_side: u32,
    /// A first look for text at this long side (0: none): where the
    /// detector finds no text box at this size, the detection at
    /// `detector_long_side` and recognition are skipped. At 256 the look
    /// costs about a quarter of the full detection.
    pub preview_long_side: u32,
    /// Recogniser input height, in pixels (at least 8).
    pub line_height: u32,
    /// Widest recogniser input, in pixels: longer lines are squeezed to it.
    pub max_line_width: u32,
    /// Strings read with less confidence are dropped.
    pub min_confidence: f32,
    /// Most text lines read per image.
    pub max_lines: usize,
    /// Class of the objects made from text regions when no detector runs.
    pub text_object_class: String,
}

/// Default [`OcrConfig::detector_long_side`].
pub const DETECTOR_LONG_SIDE: u32 = 512;

/// Default [`OcrConfig::preview_long_side`]: no first look.
pub const PREVIEW_LONG_SIDE: u32 = 0;

impl Default for OcrConfig {
    fn default() -> Self {
        OcrConfig {
            detector: PathBuf::from("ocr/ppocrv5_det.onnx"),
            recognizer: PathBuf::from("ocr/ppocrv5_rec.onnx"),
            detector_precision: OCR_DETECTOR_PRECISION,
            recognizer_precision: OCR_RECOGNIZER_PRECISION,
            dictionary: PathBuf::from("ocr/ppocr_keys_v5.txt"),
            detector_long_side: DETECTOR_LONG_SIDE,
            preview_long_side: PREVIEW_LONG_SIDE,
            line_height: 48,
            max_line_width: 480,
            min_confidence: 0.5,
            max_lines: 32,
            text_object_class: "sign".into(),
        }
    }
}

impl OcrConfig {
    fn validate(&self) -> Result<(), String> {
        if !(32..=4096).contains(&self.detector_long_side) {
            return Err("detector_long_side must be between 32 and 4096".into());
        }
        if self.preview_long_side != 0
            && !(32..self.detector_long_side).contains(&self.preview_long_side)
        {
            return Err(
                "preview_long_side must be 0 (off) or from 32 to below detector_long_side".into(),
            );
        }
        if self.line_height < 8 || self.max_line_width < self.line_height {
            return Err(
                "line_height must be at least 8 and max_line_width at least line_height".into(),
            );
        }
        if !(0.0..=1.0).contains(&self.min_confidence) {
            return Err("min_confidence must be in [0, 1]".into());
        }
        Ok(())
    }
}
