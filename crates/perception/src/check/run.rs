//! One image through each model, with HuMem's own preprocessing and
//! decoding, reporting what came out.
//!
//! The graph checks cannot see everything: an undeclared output shape, a
//! dynamic size the network cannot actually take, a descriptor of NaNs. A
//! run can. Each function here takes a loaded session, feeds it the input
//! HuMem would build from `image` (resized and normalised, letterboxed for
//! the detector, a text region and a cut-out line for OCR) and decodes the
//! output as the serving path does.

use std::time::Instant;

use image::RgbImage;
use ort::session::Session;

use super::graph::{self, Expected};
use crate::batcher::BatchModel;
use crate::config::{DetectorConfig, ImageModelConfig, OcrConfig, PerceptionConfig};
use crate::error::{CheckError, RuntimeError};
use crate::geometry::Rect;
use crate::model::{ImageModel, Outputs};
use crate::objects::{self, letterbox_input};
use crate::ocr::{self, db, LineRecognizer};
use crate::signature::{Dim, Io, Kind};
use crate::whole_image::{model_input, top_classes};

/// A text box's corners in image pixels: top-left, top-right,
/// bottom-right, bottom-left.
type Quad = [[f32; 2]; 4];

/// A hint for a run that failed on a graph whose sides are dynamic.
const DYNAMIC_HINT: &str = "; the graph's height and width are dynamic, but not every size runs: if the model needs multiples of a patch (a ViT), set input_multiple and a size that fits";

fn run_error(
    model: &str,
    tensor: &str,
    [w, h]: [u32; 2],
    e: RuntimeError,
    hint: &str,
) -> CheckError {
    let message = match e {
        RuntimeError::Run { message, .. } => message,
        other => other.to_string(),
    };
    CheckError::Run {
        model: model.to_string(),
        tensor: tensor.to_string(),
        size: format!("{w}x{h}"),
        message: format!("{}{hint}", message.trim_end()),
    }
}

fn millis(started: Instant) -> String {
    format!("{:.1} ms", started.elapsed().as_secs_f64() * 1e3)
}

/// Runs a whole-image model (descriptor or scene) on `image`, reading
/// `outputs`.
fn image_model(
    model: &str,
    session: Session,
    m: &ImageModelConfig,
    outputs: &[String],
    image: &RgbImage,
) -> Result<(Outputs, String), CheckError> {
    let dynamic = Io::of(&session).inputs.iter().any(|t| {
        t.name == m.input
            && t.dims
                .as_ref()
                .is_some_and(|d| d.iter().skip(2).any(|d| matches!(d, Dim::Dynamic(_))))
    });
    let hint = if dynamic && m.input_multiple <= 1 {
        DYNAMIC_HINT
    } else {
        ""
    };
    let size = [m.width, m.height];
    let fail = |e| run_error(model, &m.input, size, e, hint);
    let mut net = ImageModel::new(
        model,
        session,
        &m.input,
        outputs,
        Some([m.width as usize, m.height as usize]),
    )
    .map_err(fail)?;
    let started = Instant::now();
    let out = net.run(vec![model_input(image, m)]).map_err(fail)?;
    let took = millis(started);
    let out = out.into_iter().next().ok_or_else(|| {
        fail(RuntimeError::Run {
            model: model.into(),
            message: "no output".into(),
        })
    })?;
    Ok((out, took))
}

/// The descriptor (and, when one inference gives both, the scene): its
/// length against `output_len` and `expected`, its norm before HuMem's L2
/// normalisation. Returns the descriptor's lines and the scene's.
pub fn descriptor(
    session: Session,
    config: &PerceptionConfig,
    expected: &[Expected],
    image: &RgbImage,
) -> Result<(Vec<String>, Vec<String>), CheckError> {
    let name = "perception.descriptor";
    let m = &config.descriptor;
    let shared = config
        .scene
        .as_ref()
        .filter(|s| s.shares_input_with(&config.descriptor));
    let mut outputs = vec![m.output.clone()];
    outputs.extend(shared.map(|s| s.output.clone()));
    let (out, took) = image_model(name, session, m, &outputs, image)?;
    let mut out = out.0.into_iter();
    let (shape, values) = out.next().unwrap_or_default();
    let mut all = expected.to_vec();
    all.extend(m.output_len.map(|len| Expected {
        len,
        source: format!("{name}.output_len"),
    }));
    let line = descriptor_line(name, &m.output, &shape, &values, &all)?;
    let lines = vec![format!("{}x{} image in {took}", m.width, m.height), line];
    let scene = match (shared, out.next()) {
        (Some(s), Some((shape, values))) => vec![scene_line(s, &shape, &values)?],
        _ => Vec::new(),
    };
    Ok((lines, scene))
}

/// What a descriptor output says: its length (checked against `expected`)
/// and its norm, or why it is unusable.
fn descriptor_line(
    model: &str,
    tensor: &str,
    shape: &[usize],
    values: &[f32],
    expected: &[Expected],
) -> Result<String, CheckError> {
    let found = format!("[1, {}] from one image", dims(shape));
    graph::lengths_fit(model, tensor, values.len(), &found, expected)?;
    let norm = values.iter().map(|v| v * v).sum::<f32>().sqrt();
    if values.is_empty() || !norm.is_finite() || norm <= 0.0 {
        return Err(CheckError::Mismatch {
            model: model.into(),
            kind: Kind::Output,
            tensor: tensor.into(),
            expected: "a finite, non-zero descriptor".into(),
            found: if norm.is_finite() {
                "all zeros".into()
            } else {
                "NaN or infinite values".into()
            },
        });
    }
    Ok(format!(
        "output {tensor:?}: {} values, norm {norm:.4} (HuMem L2-normalises it)",
        values.len()
    ))
}

fn dims(shape: &[usize]) -> String {
    let all: Vec<String> = shape.iter().map(usize::to_string).collect();
    all.join(", ")
}

/// A separate scene model on `image`.
pub fn scene(
    session: Session,
    config: &PerceptionConfig,
    image: &RgbImage,
) -> Result<Vec<String>, CheckError> {
    let Some(m) = &config.scene else {
        return Ok(Vec::new());
    };
    let (out, took) = image_model(
        "perception.scene",
        session,
        m,
        std::slice::from_ref(&m.output),
        image,
    )?;
    let (shape, values) = out.0.into_iter().next().unwrap_or_default();
    Ok(vec![
        format!("{}x{} image in {took}", m.width, m.height),
        scene_line(m, &shape, &values)?,
    ])
}

/// What a scene output says: its class count (against `output_len`) and
/// its three most probable classes, as HuMem ranks them.
fn scene_line(m: &ImageModelConfig, shape: &[usize], values: &[f32]) -> Result<String, CheckError> {
    let name = "perception.scene";
    let expected: Vec<Expected> = m
        .output_len
        .map(|len| Expected {
            len,
            source: format!("{name}.output_len"),
        })
        .into_iter()
        .collect();
    let found = format!("[1, {}] from one image", dims(shape));
    graph::lengths_fit(name, &m.output, values.len(), &found, &expected)?;
    let top = top_classes(values, 3);
    if top.is_empty() {
        return Err(CheckError::Mismatch {
            model: name.into(),
            kind: Kind::Output,
            tensor: m.output.clone(),
            expected: "finite class probabilities or logits".into(),
            found: "no usable value".into(),
        });
    }
    let top: Vec<String> = top
        .iter()
        .map(|c| format!("{} ({:.3})", c.class_id, c.probability))
        .collect();
    Ok(format!(
        "output {:?}: {} classes, most probable {}",
        m.output,
        values.len(),
        top.join(", ")
    ))
}

/// The detector on `image`, letterboxed and decoded as served: objects of
/// the kept classes.
pub fn detector(
    session: Session,
    d: &DetectorConfig,
    image: &RgbImage,
) -> Result<Vec<String>, CheckError> {
    let name = "perception.detector";
    let fail = |e| run_error(name, &d.input, [d.size, d.size], e, "");
    let mut outputs = vec![d.output.clone()];
    outputs.extend(d.masks_output.clone());
    let size = d.size as usize;
    let mut net =
        ImageModel::new(name, session, &d.input, &outputs, Some([size, size])).map_err(fail)?;
    let (planes, letterbox) = letterbox_input(image, d.size);
    let started = Instant::now();
    let out = net.run(vec![planes]).map_err(fail)?;
    let took = millis(started);
    let mut out = out
        .into_iter()
        .next()
        .map(|o| o.0)
        .unwrap_or_default()
        .into_iter();
    let (shape, values) = out.next().unwrap_or_default();
    let masks = out.next();
    let found = objects::decode_objects(
        d,
        &shape,
        &values,
        masks.as_ref(),
        letterbox,
        [image.width(), image.height()],
    )
    .map_err(|e| CheckError::Mismatch {
        model: name.into(),
        kind: Kind::Output,
        tensor: d.output.clone(),
        expected: format!("the {:?} layout with {} classes", d.layout, d.classes.len()),
        found: e.to_string(),
    })?;
    let mut lines = vec![format!("{0}x{0} letterboxed image in {took}", d.size)];
    lines.push(format!("output {:?}: [1, {}]", d.output, dims(&shape)));
    if let (Some(name), Some((shape, _))) = (&d.masks_output, &masks) {
        lines.push(format!(
            "output {name:?}: [1, {}] prototype masks",
            dims(shape)
        ));
    }
    let mut kept: Vec<String> = found
        .iter()
        .take(5)
        .map(|o| format!("{} {:.2}", o.class_name, o.confidence))
        .collect();
    if found.len() > 5 {
        kept.push("…".into());
    }
    lines.push(format!(
        "{} objects kept (confidence > {}, at most {}){}{}",
        found.len(),
        d.confidence,
        d.max_objects,
        if kept.is_empty() { "" } else { ": " },
        kept.join(", ")
    ));
    Ok(lines)
}

/// The text detector on the whole of `image`: its input size and the text
/// boxes it finds, as image-pixel quads, best first.
pub fn text_boxes(
    net: &mut ImageModel,
    input: &str,
    ocr: &OcrConfig,
    image: &RgbImage,
) -> Result<(Vec<String>, Vec<Quad>), CheckError> {
    let name = "perception.ocr.detector";
    let (w, h) = (image.width() as f32, image.height() as f32);
    let whole = Rect {
        x0: 0.0,
        y0: 0.0,
        x1: w,
        y1: h,
    };
    let (planes, placement) = ocr::canvas::detector_input(image, whole, ocr.detector_long_side);
    let fail = |e| run_error(name, input, placement.input, e, "");
    let started = Instant::now();
    let out = net.run(vec![planes]).map_err(fail)?;
    let took = millis(started);
    let (shape, prob) = out
        .into_iter()
        .next()
        .and_then(|o| o.0.into_iter().next())
        .unwrap_or_default();
    let (mh, mw) = match shape[..] {
        [1, mh, mw] | [mh, mw] => (mh, mw),
        _ => {
            return Err(CheckError::Mismatch {
                model: name.into(),
                kind: Kind::Output,
                tensor: "(its first)".into(),
                expected: "[N, 1, H, W]: a text probability map".into(),
                found: format!("[1, {}] from one image", dims(&shape)),
            })
        }
    };
    let boxes = db::text_boxes(&prob, mw, mh, &db::DbParams::default());
    let [iw, ih] = placement.input.map(|s| s as f32);
    let (sx, sy) = (
        iw / mw as f32 / placement.scale,
        ih / mh as f32 / placement.scale,
    );
    let quads: Vec<Quad> = boxes
        .iter()
        .take(ocr.max_lines)
        .map(|b| b.quad.map(|[x, y]| [x * sx, y * sy]))
        .collect();
    let [iw, ih] = placement.input;
    Ok((
        vec![
            format!(
                "{iw}x{ih} image (long side {}) in {took}",
                ocr.detector_long_side
            ),
            format!(
                "probability map [1, {}]: {} text boxes",
                dims(&shape),
                quads.len()
            ),
        ],
        quads,
    ))
}

/// The line recogniser on the line `quad` of `image` (or, without one, a
/// strip across its middle), decoded with the dictionary.
pub fn read_line(
    net: &mut LineRecognizer,
    input: &str,
    ocr: &OcrConfig,
    image: &RgbImage,
    quad: Option<Quad>,
) -> Result<Vec<String>, CheckError> {
    let (w, h) = (image.width() as f32, image.height() as f32);
    let quad = quad.unwrap_or([
        [0.0, h * 0.45],
        [w, h * 0.45],
        [w, h * 0.55],
        [0.0, h * 0.55],
    ]);
    let line = ocr::line_input(image, quad, ocr.line_height, ocr.max_line_width);
    let size = [line.width as u32, ocr.line_height];
    let started = Instant::now();
    let read = net
        .run(vec![line])
        .map_err(|e| run_error("perception.ocr.recognizer", input, size, e, ""))?;
    let took = millis(started);
    let decoded = read.into_iter().next().unwrap_or_default();
    Ok(vec![
        format!("{}x{} line in {took}", size[0], size[1]),
        format!(
            "read {:?} (confidence {:.2}; lines under {} are dropped)",
            decoded.text, decoded.confidence, ocr.min_confidence
        ),
    ])
}
