//! The OCR pair, checked together: the recogniser reads a line the
//! detector found, and needs the dictionary its classes index.

use std::sync::Arc;

use image::RgbImage;

use super::graph;
use super::report::ModelReport;
use super::run;
use crate::config::{OcrConfig, PerceptionConfig};
use crate::error::{CheckError, RuntimeError};
use crate::ocr::{self, ctc::Dictionary, LineRecognizer};
use crate::signature::Io;

/// Reports for `perception.ocr.detector` and `perception.ocr.recognizer`.
pub(super) fn check_ocr(
    env: &ort::environment::Environment,
    config: &PerceptionConfig,
    ocr_config: &OcrConfig,
    image: &RgbImage,
) -> Vec<ModelReport> {
    let mut det = ModelReport::new("perception.ocr.detector", ocr_config.detector_precision);
    let mut rec = ModelReport::new("perception.ocr.recognizer", ocr_config.recognizer_precision);

    let detector = det
        .load(env, config, &ocr_config.detector)
        .and_then(|session| {
            let io = Io::of(&session);
            det.facts(graph::ocr_detector(&io, config))?;
            let input = io
                .inputs
                .first()
                .map(|t| t.name.clone())
                .unwrap_or_default();
            let net = ocr::text_detector(session).map_err(|error| CheckError::Load {
                model: det.model.to_string(),
                error,
            });
            Some((det.record(net)?, input))
        });

    let dictionary_path = config.resolve(&ocr_config.dictionary);
    let dictionary = Dictionary::load(&dictionary_path).map_err(|e| CheckError::Load {
        model: rec.model.to_string(),
        error: RuntimeError::Model {
            path: dictionary_path.clone(),
            message: format!("perception.ocr.dictionary: {e}"),
        },
    });
    let recognizer = rec.record(dictionary).and_then(|dictionary| {
        let session = rec.load(env, config, &ocr_config.recognizer)?;
        let io = Io::of(&session);
        rec.facts(graph::ocr_recognizer(
            &io,
            config,
            ocr_config,
            dictionary.len(),
        ))?;
        let input = io
            .inputs
            .first()
            .map(|t| t.name.clone())
            .unwrap_or_default();
        let net = LineRecognizer::new(session, ocr_config.line_height, Arc::new(dictionary))
            .map_err(|error| CheckError::Load {
                model: rec.model.to_string(),
                error,
            });
        Some((rec.record(net)?, input))
    });

    let mut first_line = None;
    if let Some((mut net, input)) = detector {
        if let Some((lines, quads)) =
            det.record(run::text_boxes(&mut net, &input, ocr_config, image))
        {
            det.ran = lines;
            first_line = quads.first().copied();
        }
    }
    if let Some((mut net, input)) = recognizer {
        if first_line.is_none() {
            rec.notes
                .push("no text box to read: a strip across the image's middle is read".into());
        }
        let read = run::read_line(&mut net, &input, ocr_config, image, first_line);
        rec.ran = rec.record(read).unwrap_or_default();
    }
    vec![det, rec]
}
