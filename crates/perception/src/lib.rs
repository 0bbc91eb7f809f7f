//! Perception: a camera image in, a semantic keyframe's features out.
//!
//! The configured ONNX models run through ONNX Runtime (`ort`), each behind
//! a batcher so that concurrent requests share inferences: the global
//! descriptor and scene context (one inference when one model gives both),
//! and OCR, whose text regions become `sign` objects when no object
//! detector is configured; and the appearance thumbnail, computed from the
//! pixels without a model. Decoding and resizing run on tokio's blocking
//! pool, inference on each model's own threads; the async runtime only
//! waits. Knows nothing of gRPC.
//!
//! - [`config`]: the `[perception]` section, which models run and how;
//! - [`runtime`]: ONNX Runtime, loaded once, and sessions on it;
//! - [`error`]: the errors of loading ([`runtime::RuntimeError`]) and of
//!   checking ([`check::CheckError`]) a model, which hold each other;
//! - [`signature`]: a model's declared inputs and outputs ([`signature::Io`]);
//! - [`batcher`]: concurrent requests for one model gathered into batches;
//! - [`model`]: one ONNX model over images, as a batch model;
//! - `whole_image`: what the descriptor and scene models are fed and what
//!   is read from them, shared with the checks;
//! - [`image`]: decoding JPEG, PNG and raw frames to RGB, resizing and
//!   normalising to a model's input;
//! - [`appearance`]: the appearance thumbnail, computed without a model;
//! - [`geometry`]: the axis-aligned rectangle the detectors share;
//! - [`objects`]: the object detector role (a YOLO export), letterboxing
//!   and objects in image pixels;
//! - [`yolo`]: decoding YOLO outputs, NMS and instance masks;
//! - [`ocr`]: PP-OCRv5 text detection and recognition;
//! - [`check`]: every model's inputs and outputs against its
//!   configuration (at load, and with one image by `humem models check`);
//! - [`reuse`]: objects and text carried over between similar keyframes
//!   of one stream instead of detected and read again;
//! - [`cpu`]: the nice value perception's threads run at, and the CPU
//!   time the process uses.
//!
//! The modules are layered: each uses only modules below it, never its
//! parent (this root) or a module that uses it back. Types that several
//! modules share (errors, signatures) sit in leaf modules of their own,
//! and the root only assembles the roles into [`Perception`].

pub mod appearance;
pub mod batcher;
pub mod check;
pub mod config;
pub mod cpu;
pub mod error;
pub mod geometry;
pub mod image;
pub mod model;
pub mod objects;
pub mod ocr;
pub mod reuse;
pub mod runtime;
pub mod signature;
mod whole_image;
pub mod yolo;

use std::sync::Arc;
use std::time::{Duration, Instant};

use ::image::RgbImage;
use humem_core::observe::SharedObserver;

use batcher::{BatchError, Batcher};
use config::{ImageModelConfig, PerceptionConfig};
use humem_core::keyframe::{Features, ObjectObservation, TextObservation};
use image::{EncodedImage, ImageError};
use model::ImageModel;
use objects::Detector;
use ocr::{Ocr, OcrModels, OcrTimes};
use runtime::RuntimeError;
use signature::Io;
use whole_image::{model_input, top_classes};

/// An image as received, owning its bytes.
#[derive(Debug, Clone)]
pub struct ImageInput {
    /// How `data` is encoded.
    pub encoding: image::Encoding,
    /// The file's bytes, or the raw pixel rows.
    pub data: Vec<u8>,
    /// Width in pixels; raw encodings only.
    pub width: u32,
    /// Height in pixels; raw encodings only.
    pub height: u32,
    /// Bytes per row; raw encodings only, 0 = tightly packed.
    pub stride: u32,
}

impl ImageInput {
    /// A JPEG or PNG file's bytes (the format is recognised).
    pub fn file(data: Vec<u8>) -> ImageInput {
        ImageInput {
            encoding: image::Encoding::Auto,
            data,
            width: 0,
            height: 0,
            stride: 0,
        }
    }

    fn encoded(&self) -> EncodedImage<'_> {
        EncodedImage {
            encoding: self.encoding,
            data: &self.data,
            width: self.width,
            height: self.height,
            stride: self.stride,
        }
    }
}

/// Features made from an image, with the time each stage took.
#[derive(Debug, Clone)]
pub struct Extracted {
    /// The keyframe's features.
    pub features: Features,
    /// `(stage, time)` in the order measured: `decode`, `descriptor`,
    /// `scene`, `detector`, `ocr_det`, `ocr_rec` (stages that did not run
    /// on their own are left out).
    pub timings: Vec<(&'static str, Duration)>,
    /// The objects were carried over from an earlier keyframe of the
    /// stream ([`reuse`]): no detector or OCR ran for this image.
    pub objects_carried: bool,
}

/// Why an image could not be turned into features.
#[derive(Debug, Clone, thiserror::Error)]
pub enum PerceptionError {
    /// The client's image is unusable.
    #[error(transparent)]
    Image(#[from] ImageError),
    /// A model is overloaded, stopped or failed.
    #[error(transparent)]
    Model(#[from] BatchError),
    /// A model's output is not what its role needs.
    #[error("{0}")]
    Output(String),
}

/// A graph check of a whole-image role ([`check::graph`]).
type GraphCheck = fn(&Io, &PerceptionConfig) -> Result<check::Facts, check::CheckError>;

/// One model over whole images, with its preprocessing.
#[derive(Clone)]
struct ImageRole {
    batcher: Batcher<ImageModel>,
    config: ImageModelConfig,
}

/// The loaded models.
#[derive(Clone)]
pub struct Perception {
    /// Gives the descriptor, and the scene when `scene_in_global`.
    global: ImageRole,
    scene_in_global: bool,
    /// A separate scene model.
    scene: Option<ImageRole>,
    ocr: Option<Ocr>,
    detector: Option<Detector>,
    text_object_class: String,
    scene_top_k: usize,
    /// Whether the appearance thumbnail is kept in the features.
    appearance: bool,
    /// The last read of each stream, where objects may be carried over.
    reuse: Option<Arc<reuse::ObjectReuse>>,
    /// The descriptor's length, where its graph fixes it.
    descriptor_len: Option<usize>,
}

impl Perception {
    /// Loads ONNX Runtime and every configured model, refusing a model
    /// whose graph does not fit its configuration ([`check::graph`]).
    pub fn load(config: &PerceptionConfig, scene_top_k: usize) -> Result<Perception, RuntimeError> {
        Self::load_observed(config, scene_top_k, humem_core::observe::unobserved())
    }

    /// [`Perception::load`], with every model's queue depth and batch sizes
    /// reported to `observer` (queues named by model role).
    ///
    /// The models are loaded on a thread at `config.nice`
    /// ([`cpu::run_at_nice`]), so that their inference threads run at
    /// that priority.
    pub fn load_observed(
        config: &PerceptionConfig,
        scene_top_k: usize,
        observer: SharedObserver,
    ) -> Result<Perception, RuntimeError> {
        cpu::run_at_nice(config.nice, || {
            Self::load_models(config, scene_top_k, observer)
        })
        .map_err(|e| RuntimeError::Priority {
            nice: config.nice,
            message: e.to_string(),
        })?
    }

    fn load_models(
        config: &PerceptionConfig,
        scene_top_k: usize,
        observer: SharedObserver,
    ) -> Result<Perception, RuntimeError> {
        let env = runtime::environment(&config.onnxruntime_library())?;
        let options = config.session_options();
        let batching = config.batching();
        let workers = config.workers.max(1);

        let scene_in_global = config
            .scene
            .as_ref()
            .is_some_and(|s| s.shares_input_with(&config.descriptor));
        let mut descriptor_len = None;
        let mut load_role =
            |name: &'static str, m: &ImageModelConfig, outputs: Vec<String>, fits: GraphCheck| {
                let path = config.model_file(&m.model, m.precision())?;
                let models = (0..workers)
                    .map(|worker| {
                        let session =
                            runtime::session(&env, &path, m.precision().options(options))?;
                        if worker == 0 {
                            let facts = fits(&Io::of(&session), config)
                                .map_err(|e| RuntimeError::Check(Box::new(e)))?;
                            descriptor_len = descriptor_len.or(facts.descriptor_len);
                        }
                        ImageModel::new(
                            name,
                            session,
                            &m.input,
                            &outputs,
                            Some([m.width as usize, m.height as usize]),
                        )
                    })
                    .collect::<Result<Vec<_>, RuntimeError>>()?;
                tracing::info!(role = name, model = %path.display(), "model loaded");
                Ok::<_, RuntimeError>(ImageRole {
                    batcher: Batcher::spawn(name, models, batching, observer.clone()),
                    config: m.clone(),
                })
            };
        let mut global_outputs = vec![config.descriptor.output.clone()];
        if scene_in_global {
            global_outputs.extend(config.scene.as_ref().map(|s| s.output.clone()));
        }
        let global = load_role(
            "descriptor",
            &config.descriptor,
            global_outputs,
            |io, config| check::graph::descriptor(io, config, &[]),
        )?;
        let scene = match &config.scene {
            Some(s) if !scene_in_global => Some(load_role(
                "scene",
                s,
                vec![s.output.clone()],
                check::graph::scene,
            )?),
            _ => None,
        };
        let ocr = match &config.ocr {
            None => None,
            Some(ocr_config) => {
                let dictionary_path = config.resolve(&ocr_config.dictionary);
                let dictionary = ocr::ctc::Dictionary::load(&dictionary_path).map_err(|e| {
                    RuntimeError::Model {
                        path: dictionary_path.clone(),
                        message: e.to_string(),
                    }
                })?;
                let detector_path =
                    config.model_file(&ocr_config.detector, ocr_config.detector_precision)?;
                let recognizer_path =
                    config.model_file(&ocr_config.recognizer, ocr_config.recognizer_precision)?;
                let sessions = (0..workers)
                    .map(|worker| {
                        let pair = (
                            runtime::session(
                                &env,
                                &detector_path,
                                ocr_config.detector_precision.options(options),
                            )?,
                            runtime::session(
                                &env,
                                &recognizer_path,
                                ocr_config.recognizer_precision.options(options),
                            )?,
                        );
                        if worker == 0 {
                            check::graph::ocr_detector(&Io::of(&pair.0), config)
                                .and_then(|_| {
                                    check::graph::ocr_recognizer(
                                        &Io::of(&pair.1),
                                        config,
                                        ocr_config,
                                        dictionary.len(),
                                    )
                                })
                                .map_err(|e| RuntimeError::Check(Box::new(e)))?;
                        }
                        Ok(pair)
                    })
                    .collect::<Result<Vec<_>, RuntimeError>>()?;
                let models = OcrModels::new(sessions, ocr_config, Arc::new(dictionary))?;
                tracing::info!(
                    role = "ocr",
                    detector = %detector_path.display(),
                    recognizer = %recognizer_path.display(),
                    "models loaded"
                );
                Some(Ocr::new(models, ocr_config, batching, &observer))
            }
        };
        let detector = config
            .detector
            .as_ref()
            .map(|d| Detector::load(&env, config, d, batching, &observer))
            .transpose()?;
        Ok(Perception {
            global,
            scene_in_global,
            scene,
            ocr,
            detector,
            text_object_class: config
                .ocr
                .as_ref()
                .map(|o| o.text_object_class.clone())
                .unwrap_or_default(),
            scene_top_k,
            appearance: config.appearance,
            reuse: reuse::ObjectReuse::new(&config.reuse).map(Arc::new),
            descriptor_len,
        })
    }

    /// The descriptor's length, where its graph fixes it (`None`: known
    /// only from an image).
    pub fn descriptor_len(&self) -> Option<usize> {
        self.descriptor_len
    }

    /// Forgets the last read of `stream`, so that its next image is read
    /// afresh (its keyframes were erased).
    pub fn forget_stream(&self, stream: &str) {
        if let Some(reuse) = &self.reuse {
            reuse.forget(stream);
        }
    }

    /// Turns an image into features: descriptor, scene distribution, and
    /// objects with their text.
    pub async fn extract(&self, input: ImageInput) -> Result<Extracted, PerceptionError> {
        self.extract_in(input, None).await
    }

    /// [`Perception::extract`] for an image of `stream` (any name of one
    /// camera's sequence of keyframes, e.g. a robot's session): where
    /// `perception.reuse` allows, the objects of the stream's last read are
    /// carried over instead of detected and read again ([`reuse`]).
    pub async fn extract_in(
        &self,
        input: ImageInput,
        stream: Option<&str>,
    ) -> Result<Extracted, PerceptionError> {
        let mut timings = Vec::new();
        let started = Instant::now();
        let global_config = self.global.config.clone();
        let scene_config = self.scene.as_ref().map(|s| s.config.clone());
        let reuse = self.reuse.as_ref().zip(stream);
        let with_appearance = self.appearance || reuse.is_some();
        let (image, global_input, scene_input, thumbnail) =
            tokio::task::spawn_blocking(move || {
                let image = image::decode(&input.encoded())?;
                let global_input = model_input(&image, &global_config);
                let scene_input = scene_config.map(|c| model_input(&image, &c));
                let thumbnail = if with_appearance {
                    appearance::thumbnail(&image)
                } else {
                    Vec::new()
                };
                Ok::<_, ImageError>((Arc::new(image), global_input, scene_input, thumbnail))
            })
            .await
            .map_err(|e| PerceptionError::Output(format!("decoding task failed: {e}")))??;
        timings.push(("decode", started.elapsed()));

        let global = self.global.batcher.infer(global_input);
        let scene = async {
            match (&self.scene, scene_input) {
                (Some(role), Some(input)) => role.batcher.infer(input).await.map(Some),
                _ => Ok(None),
            }
        };
        let carried = reuse.and_then(|(reuse, stream)| reuse.carry(stream, &thumbnail));
        let objects_carried = carried.is_some();
        let objects = async {
            match carried {
                Some(objects) => Ok((objects, Vec::new())),
                None => self.objects(image.clone()).await,
            }
        };
        let (global, scene, objects) = tokio::join!(global, scene, objects);
        let global = global?;
        let scene = scene?;
        let (objects, object_timings) = objects?;
        if let (Some((reuse, stream)), false) = (reuse, objects_carried) {
            reuse.remember(stream, thumbnail.clone(), objects.clone());
        }
        let thumbnail = if self.appearance {
            thumbnail
        } else {
            Vec::new()
        };
        timings.push(("descriptor", global.inference + global.queued));

        let mut outputs = global.output.0.into_iter();
        let descriptor = descriptor(outputs.next())?;
        let scene_probs = if self.scene_in_global {
            outputs.next()
        } else if let Some(scene) = scene {
            timings.push(("scene", scene.inference + scene.queued));
            scene.output.0.into_iter().next()
        } else {
            None
        };
        timings.extend(object_timings);
        Ok(Extracted {
            features: Features {
                descriptor,
                scene: scene_probs
                    .map(|(_, p)| top_classes(&p, self.scene_top_k))
                    .unwrap_or_default(),
                objects,
                appearance: thumbnail,
            },
            timings,
            objects_carried,
        })
    }
}

impl Perception {
    /// The objects of an image with the text read on them: the detector's
    /// objects, with OCR inside those of text-bearing classes, or, without a
    /// detector, the text regions themselves as objects.
    async fn objects(
        &self,
        image: Arc<RgbImage>,
    ) -> Result<(Vec<ObjectObservation>, Vec<(&'static str, Duration)>), PerceptionError> {
        let (w, h) = (image.width() as f32, image.height() as f32);
        let normalised = |[x, y]: [f32; 2], area: f32| {
            (
                [(x / w).clamp(0.0, 1.0), (y / h).clamp(0.0, 1.0)],
                (area / (w * h)).clamp(0.0, 1.0),
            )
        };
        let mut timings = Vec::new();
        let Some(detector) = &self.detector else {
            let Some(ocr) = &self.ocr else {
                return Ok((Vec::new(), timings));
            };
            let mut times = OcrTimes::default();
            let lines = ocr.read(image.clone(), None, &mut times).await?;
            timings.push(("ocr_det", times.detection));
            timings.push(("ocr_rec", times.recognition));
            let objects = lines
                .into_iter()
                .map(|line| {
                    let (centroid, area) = normalised(line.rect.center(), line.rect.area());
                    ObjectObservation {
                        class_name: self.text_object_class.clone(),
                        confidence: line.detection_score.clamp(0.0, 1.0),
                        centroid,
                        area,
                        texts: vec![TextObservation {
                            text: line.text,
                            confidence: line.confidence.clamp(0.0, 1.0),
                        }],
                    }
                })
                .collect();
            return Ok((objects, timings));
        };

        let (detected, took) = detector.detect(image.clone()).await?;
        timings.push(("detector", took));
        // Text is read inside every text-bearing object, all at once.
        let reads = detected.iter().map(|object| {
            let image = image.clone();
            async move {
                let mut times = OcrTimes::default();
                let lines = match &self.ocr {
                    Some(ocr) if detector.reads_text_on(&object.class_name) => {
                        ocr.read(image, Some(object.rect), &mut times).await?
                    }
                    _ => Vec::new(),
                };
                Ok::<_, BatchError>((lines, times))
            }
        });
        let reads = futures::future::join_all(reads).await;
        let mut slowest = OcrTimes::default();
        let mut objects = Vec::with_capacity(detected.len());
        for (object, read) in detected.into_iter().zip(reads) {
            let (lines, times) = read?;
            slowest.detection = slowest.detection.max(times.detection);
            slowest.recognition = slowest.recognition.max(times.recognition);
            let (centroid, area) = normalised(object.centroid, object.area);
            objects.push(ObjectObservation {
                class_name: object.class_name,
                confidence: object.confidence,
                centroid,
                area,
                texts: lines
                    .into_iter()
                    .map(|l| TextObservation {
                        text: l.text,
                        confidence: l.confidence.clamp(0.0, 1.0),
                    })
                    .collect(),
            });
        }
        if self.ocr.is_some() {
            timings.push(("ocr_det", slowest.detection));
            timings.push(("ocr_rec", slowest.recognition));
        }
        Ok((objects, timings))
    }
}

/// The L2-normalised descriptor of a model output.
fn descriptor(output: Option<(Vec<usize>, Vec<f32>)>) -> Result<Vec<f32>, PerceptionError> {
    let (_, values) =
        output.ok_or_else(|| PerceptionError::Output("descriptor model gave no output".into()))?;
    let norm = values.iter().map(|v| v * v).sum::<f32>().sqrt();
    if values.is_empty() || !norm.is_finite() || norm <= 0.0 {
        return Err(PerceptionError::Output(
            "descriptor model gave an empty, zero or non-finite descriptor".into(),
        ));
    }
    Ok(values.iter().map(|v| v / norm).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn descriptors_are_normalised_and_checked() {
        assert_eq!(
            descriptor(Some((vec![2], vec![3.0, 4.0]))).unwrap(),
            vec![0.6, 0.8]
        );
        assert!(descriptor(Some((vec![2], vec![0.0, 0.0]))).is_err());
        assert!(descriptor(None).is_err());
    }
}
