//! The graph checks: a model's declared inputs and outputs against what its
//! role's configuration says and what HuMem feeds it and reads from it.
//!
//! Pure functions of an [`Io`] (read from a loaded session) and the
//! configuration, so they cost nothing at start and are tested without a
//! model. An axis the graph leaves dynamic is accepted wherever HuMem can
//! feed it; a shape the graph does not declare at all (some quantised
//! exports) is noted and left to the one-image run of `humem models check`.
//!
//! What a check is given ([`Expected`]) and what it finds besides errors
//! ([`Facts`]) are defined here; the graph's own description ([`Io`],
//! [`Tensor`], [`Dim`]) lives in [`crate::signature`] and is re-exported,
//! so that the loaders can read a graph without depending on the checks.

use crate::config::{DetectorConfig, ImageModelConfig, OcrConfig, PerceptionConfig, YoloLayout};
use crate::error::CheckError;
use crate::signature::Kind;
pub use crate::signature::{Dim, Io, Tensor};

/// YOLO's largest stride: a detector whose input size is dynamic needs a
/// size that is a multiple of it (its feature pyramid concatenates maps of
/// strides 8 to 32).
pub const YOLO_STRIDE: u32 = 32;

/// A length an output must have, and the setting or store it comes from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Expected {
    /// Values per image.
    pub len: usize,
    /// Where the expectation comes from (`store.descriptor_dim`, `the
    /// store in ./data`).
    pub source: String,
}

/// What a graph check found besides mismatches.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Facts {
    /// The descriptor's length, where the graph fixes it.
    pub descriptor_len: Option<usize>,
    /// Worth knowing, not wrong: a shape the graph does not declare, an
    /// output that looks unused.
    pub notes: Vec<String>,
}

/// Checks of one model's tensors, naming the model in every error.
struct Model<'a> {
    name: &'a str,
    io: &'a Io,
    /// Images per inference (`perception.max_batch` resolved).
    batch: usize,
}

impl Model<'_> {
    fn find(&self, kind: Kind, name: &str) -> Result<&Tensor, CheckError> {
        let tensors = match kind {
            Kind::Input => &self.io.inputs,
            Kind::Output => &self.io.outputs,
        };
        tensors
            .iter()
            .find(|t| t.name == name)
            .ok_or_else(|| CheckError::Missing {
                model: self.name.to_string(),
                kind,
                tensor: name.to_string(),
                found: Io::list(tensors),
            })
    }

    fn first(&self, kind: Kind) -> Result<&Tensor, CheckError> {
        let tensors = match kind {
            Kind::Input => &self.io.inputs,
            Kind::Output => &self.io.outputs,
        };
        tensors.first().ok_or_else(|| CheckError::Missing {
            model: self.name.to_string(),
            kind,
            tensor: "(the first)".into(),
            found: "none".into(),
        })
    }

    fn mismatch(
        &self,
        kind: Kind,
        tensor: &Tensor,
        expected: impl Into<String>,
        found: impl Into<String>,
    ) -> CheckError {
        CheckError::Mismatch {
            model: self.name.to_string(),
            kind,
            tensor: tensor.name.clone(),
            expected: expected.into(),
            found: found.into(),
        }
    }

    /// The only input, by name (or the first, for `None`), float32, with
    /// `rank` axes if the graph declares them, and a batch axis that takes
    /// `self.batch` images.
    fn input(&self, name: Option<&str>, rank: usize, layout: &str) -> Result<Tensor, CheckError> {
        let input = match name {
            Some(name) => self.find(Kind::Input, name)?,
            None => self.first(Kind::Input)?,
        };
        if let Some(other) = self.io.inputs.iter().find(|t| t.name != input.name) {
            return Err(self.mismatch(
                Kind::Input,
                other,
                format!("absent: HuMem feeds one input, {:?}", input.name),
                format!("inputs {}", Io::list(&self.io.inputs)),
            ));
        }
        self.float(Kind::Input, input)?;
        self.ranked(Kind::Input, input, rank, layout)?;
        self.batch_axis(Kind::Input, input)?;
        Ok(input.clone())
    }

    /// An output by name (or the first, for `None`): float32, with `rank`
    /// axes and a batch axis if the graph declares them.
    fn output(&self, name: Option<&str>, rank: usize, layout: &str) -> Result<Tensor, CheckError> {
        let output = match name {
            Some(name) => self.find(Kind::Output, name)?,
            None => self.first(Kind::Output)?,
        };
        self.float(Kind::Output, output)?;
        self.ranked(Kind::Output, output, rank, layout)?;
        self.batch_axis(Kind::Output, output)?;
        Ok(output.clone())
    }

    fn float(&self, kind: Kind, tensor: &Tensor) -> Result<(), CheckError> {
        if tensor.element == "f32" {
            return Ok(());
        }
        let what = match kind {
            Kind::Input => "HuMem feeds float32",
            Kind::Output => "HuMem reads float32",
        };
        Err(self.mismatch(
            kind,
            tensor,
            format!("f32 elements ({what})"),
            format!("{} elements", tensor.element),
        ))
    }

    fn ranked(
        &self,
        kind: Kind,
        tensor: &Tensor,
        rank: usize,
        layout: &str,
    ) -> Result<(), CheckError> {
        match &tensor.dims {
            Some(dims) if dims.len() != rank => Err(self.mismatch(
                kind,
                tensor,
                format!("{layout} (rank {rank})"),
                format!("{} (rank {})", tensor.shape(), dims.len()),
            )),
            _ => Ok(()),
        }
    }

    fn batch_axis(&self, kind: Kind, tensor: &Tensor) -> Result<(), CheckError> {
        match dim(tensor, 0).and_then(Dim::fixed) {
            Some(1) if self.batch > 1 => Err(self.mismatch(
                kind,
                tensor,
                format!(
                    "a dynamic batch axis (perception.max_batch resolves to {}: images are stacked; export with a dynamic batch or set max_batch = 1)",
                    self.batch
                ),
                format!("{} (batch fixed at 1)", tensor.shape()),
            )),
            Some(n) if n != 1 => Err(self.mismatch(
                kind,
                tensor,
                "a dynamic batch axis, or 1",
                format!("{} (batch fixed at {n})", tensor.shape()),
            )),
            _ => Ok(()),
        }
    }

    /// An NCHW image input of `[width, height]`: 3 channels, fixed sides
    /// equal to the configured ones, and every side a multiple of
    /// `multiple` (from `multiple_key`) when above 1. Returns whether the
    /// sides are dynamic.
    fn image(
        &self,
        input: &Tensor,
        [width, height]: [u32; 2],
        size_key: &str,
        multiple: Option<(u32, String)>,
    ) -> Result<bool, CheckError> {
        let Some(dims) = &input.dims else {
            return Ok(true);
        };
        if let Some(c) = dims[1].fixed().filter(|&c| c != 3) {
            return Err(self.mismatch(
                Kind::Input,
                input,
                "[N, 3, H, W]: 3 colour planes",
                format!("{} ({c} channels)", input.shape()),
            ));
        }
        for (axis, side, want) in [(2, "height", height), (3, "width", width)] {
            if let Some(n) = dims[axis].fixed().filter(|&n| n != want as usize) {
                return Err(self.mismatch(
                    Kind::Input,
                    input,
                    format!("{side} {want} ({size_key})"),
                    format!("{} ({side} fixed at {n})", input.shape()),
                ));
            }
        }
        if let Some((m, source)) = multiple.filter(|(m, _)| *m > 1) {
            if width % m != 0 || height % m != 0 {
                return Err(self.mismatch(
                    Kind::Input,
                    input,
                    format!("width and height multiples of {m} ({source})"),
                    format!("{width}x{height} ({size_key})"),
                ));
            }
        }
        Ok(dims[2].fixed().is_none() || dims[3].fixed().is_none())
    }

    /// The last axis of a `[N, len]` output against every expected length.
    fn length(
        &self,
        output: &Tensor,
        expected: &[Expected],
        facts: &mut Facts,
    ) -> Result<Option<usize>, CheckError> {
        let Some(len) = dim(output, 1) else {
            facts.notes.push(format!(
                "output {:?} declares no shape: its length is checked by running an image",
                output.name
            ));
            return Ok(None);
        };
        let Some(len) = len.fixed() else {
            facts.notes.push(format!(
                "output {:?} has a dynamic length: checked by running an image",
                output.name
            ));
            return Ok(None);
        };
        lengths_fit(self.name, &output.name, len, &output.shape(), expected)?;
        Ok(Some(len))
    }
}

fn dim(tensor: &Tensor, axis: usize) -> Option<&Dim> {
    tensor.dims.as_ref().and_then(|d| d.get(axis))
}

/// `len` values per image of output `tensor` of `model` against every
/// expected length; `found` says where `len` comes from.
pub fn lengths_fit(
    model: &str,
    tensor: &str,
    len: usize,
    found: &str,
    expected: &[Expected],
) -> Result<(), CheckError> {
    match expected.iter().find(|e| e.len != len) {
        Some(e) => Err(CheckError::Mismatch {
            model: model.to_string(),
            kind: Kind::Output,
            tensor: tensor.to_string(),
            expected: format!("{} values per image ({})", e.len, e.source),
            found: format!("{len} values per image: {found}"),
        }),
        None => Ok(()),
    }
}

/// Images per inference for `config`.
fn batch(config: &PerceptionConfig) -> usize {
    config.batching().max_batch
}

/// The image input of a whole-image model (descriptor or scene).
fn image_input(model: &Model, m: &ImageModelConfig, facts: &mut Facts) -> Result<(), CheckError> {
    let input = model.input(Some(&m.input), 4, "[N, 3, H, W] (NCHW)")?;
    let dynamic = model.image(
        &input,
        [m.width, m.height],
        &format!("{}.width/height", model.name),
        Some((m.input_multiple, format!("{}.input_multiple", model.name))),
    )?;
    if dynamic && m.input_multiple <= 1 {
        facts.notes.push(format!(
            "input {:?} {}: any size runs; if the model needs multiples of a patch (a ViT), set input_multiple",
            input.name,
            input.shape()
        ));
    }
    Ok(())
}

/// What one model's output must be, beyond its name: the configured
/// `output_len` and the other expectations.
fn expectations(model: &str, m: &ImageModelConfig, others: &[Expected]) -> Vec<Expected> {
    let mut all: Vec<Expected> = m
        .output_len
        .map(|len| Expected {
            len,
            source: format!("{model}.output_len"),
        })
        .into_iter()
        .collect();
    all.extend_from_slice(others);
    all
}

/// The descriptor model (`perception.descriptor`): its image input and its
/// output `[N, D]`, `D` against `output_len` and `expected` (the store's
/// length); with the scene output too when one inference gives both.
pub fn descriptor(
    io: &Io,
    config: &PerceptionConfig,
    expected: &[Expected],
) -> Result<Facts, CheckError> {
    let name = "perception.descriptor";
    let model = Model {
        name,
        io,
        batch: batch(config),
    };
    let m = &config.descriptor;
    let mut facts = Facts::default();
    image_input(&model, m, &mut facts)?;
    let output = model.output(Some(&m.output), 2, "[N, D]: one descriptor per image")?;
    facts.descriptor_len = model.length(&output, &expectations(name, m, expected), &mut facts)?;
    if let Some(scene) = config
        .scene
        .as_ref()
        .filter(|s| s.shares_input_with(&config.descriptor))
    {
        let shared = scene_output(io, config, scene)?;
        facts.notes.extend(shared.notes);
    }
    Ok(facts)
}

/// A separate scene model (`perception.scene`): its image input and output.
pub fn scene(io: &Io, config: &PerceptionConfig) -> Result<Facts, CheckError> {
    let Some(m) = &config.scene else {
        return Ok(Facts::default());
    };
    let model = Model {
        name: "perception.scene",
        io,
        batch: batch(config),
    };
    let mut facts = Facts::default();
    image_input(&model, m, &mut facts)?;
    let output = scene_output(io, config, m)?;
    facts.notes.extend(output.notes);
    Ok(facts)
}

/// The scene output `[N, C]`, `C` against `output_len`.
fn scene_output(
    io: &Io,
    config: &PerceptionConfig,
    m: &ImageModelConfig,
) -> Result<Facts, CheckError> {
    let name = "perception.scene";
    let model = Model {
        name,
        io,
        batch: batch(config),
    };
    let mut facts = Facts::default();
    let output = model.output(
        Some(&m.output),
        2,
        "[N, C]: class probabilities or logits per image",
    )?;
    model.length(&output, &expectations(name, m, &[]), &mut facts)?;
    Ok(facts)
}

/// The object detector (`perception.detector`): a square image input of
/// `size` (a multiple of [`YOLO_STRIDE`] when dynamic), the detections
/// output in the configured layout with `4 + classes (+ masks)` channels
/// or `6 (+ masks)` columns, and the prototype masks when configured.
pub fn detector(
    io: &Io,
    config: &PerceptionConfig,
    d: &DetectorConfig,
) -> Result<Facts, CheckError> {
    let model = Model {
        name: "perception.detector",
        io,
        batch: batch(config),
    };
    let mut facts = Facts::default();
    let input = model.input(Some(&d.input), 4, "[N, 3, size, size] (NCHW)")?;
    let dynamic = model.image(&input, [d.size, d.size], "perception.detector.size", None)?;
    if dynamic && !d.size.is_multiple_of(YOLO_STRIDE) {
        return Err(model.mismatch(
            Kind::Input,
            &input,
            format!(
                "a size that is a multiple of {YOLO_STRIDE} (YOLO's largest stride), as its height and width are dynamic"
            ),
            format!("perception.detector.size = {}", d.size),
        ));
    }
    // Mask coefficients per detection, where known.
    let nm = match &d.masks_output {
        Some(name) => {
            let masks = model.output(Some(name), 4, "[N, masks, mask height, mask width]")?;
            dim(&masks, 1).and_then(Dim::fixed)
        }
        None => {
            if let Some(protos) = io
                .outputs
                .iter()
                .find(|t| t.name != d.output && t.dims.as_ref().is_some_and(|d| d.len() == 4))
            {
                facts.notes.push(format!(
                    "output {protos} looks like prototype masks: masks_output = {:?} would take objects' centroid and area from their masks",
                    protos.name
                ));
            }
            Some(0)
        }
    };
    let layout = match d.layout {
        YoloLayout::Anchors => "[N, 4 + classes (+ masks), anchors] (layout \"anchors\")",
        YoloLayout::EndToEnd => "[N, detections, 6 (+ masks)] (layout \"end_to_end\")",
    };
    let output = model.output(Some(&d.output), 3, layout)?;
    let (axis, base, what) = match d.layout {
        YoloLayout::Anchors => (
            1,
            4 + d.classes.len(),
            format!(
                "4 box values + {} classes (perception.detector.classes)",
                d.classes.len()
            ),
        ),
        YoloLayout::EndToEnd => (2, 6, "6 values (x1, y1, x2, y2, score, class)".to_string()),
    };
    let (Some(found), Some(nm)) = (dim(&output, axis).and_then(Dim::fixed), nm) else {
        return Ok(facts);
    };
    if found != base + nm {
        let channels = if d.layout == YoloLayout::Anchors {
            "channels"
        } else {
            "columns"
        };
        let masks = match &d.masks_output {
            Some(name) => format!(" + {nm} mask coefficients ({name})"),
            None => " (no masks_output)".into(),
        };
        let mut hint = String::new();
        if d.layout == YoloLayout::Anchors && dim(&output, 2).and_then(Dim::fixed) == Some(6 + nm) {
            hint = "; its last axis fits layout \"end_to_end\"".into();
        } else if d.layout == YoloLayout::Anchors && found > 4 + nm {
            let classes = found - 4 - nm;
            hint = format!("; that is {classes} classes");
            if d.masks_output.is_none() && classes > 32 {
                hint += &format!(
                    ", or {} and the 32 mask coefficients of a segment export: set masks_output",
                    classes - 32
                );
            }
        }
        return Err(model.mismatch(
            Kind::Output,
            &output,
            format!("{what}{masks} = {} {channels}", base + nm),
            format!("{} ({found} {channels}{hint})", output.shape()),
        ));
    }
    Ok(facts)
}

/// The text detector (`perception.ocr.detector`): one image input whose
/// height and width are dynamic (regions keep their aspect ratio), and a
/// probability map `[N, 1, H, W]` as its first output.
pub fn ocr_detector(io: &Io, config: &PerceptionConfig) -> Result<Facts, CheckError> {
    let model = Model {
        name: "perception.ocr.detector",
        io,
        batch: batch(config),
    };
    let input = model.input(None, 4, "[N, 3, H, W] (NCHW)")?;
    if let Some(dims) = &input.dims {
        if dims[2].fixed().is_some() || dims[3].fixed().is_some() {
            return Err(model.mismatch(
                Kind::Input,
                &input,
                "dynamic height and width (each region is fed at its own aspect ratio, sides padded to multiples of 32)",
                input.shape(),
            ));
        }
        model.image(&input, [32, 32], "perception.ocr.detector_long_side", None)?;
    }
    let output = model.first(Kind::Output)?;
    model.float(Kind::Output, output)?;
    if let Some(dims) = &output.dims {
        let fits = match &dims[..] {
            [_, c, _, _] => c.fixed().is_none_or(|c| c == 1),
            [_, _, _] => true,
            _ => false,
        };
        if !fits {
            return Err(model.mismatch(
                Kind::Output,
                output,
                "[N, 1, H, W]: a text probability map",
                output.shape(),
            ));
        }
    }
    Ok(Facts::default())
}

/// The line recogniser (`perception.ocr.recognizer`): one image input of
/// height `line_height` and dynamic width, and `[N, T, C]` probabilities
/// with one class per entry of the dictionary (`dictionary_len`).
pub fn ocr_recognizer(
    io: &Io,
    config: &PerceptionConfig,
    ocr: &OcrConfig,
    dictionary_len: usize,
) -> Result<Facts, CheckError> {
    let model = Model {
        name: "perception.ocr.recognizer",
        io,
        batch: batch(config),
    };
    let mut facts = Facts::default();
    let input = model.input(None, 4, "[N, 3, line height, W] (NCHW)")?;
    if let Some(dims) = &input.dims {
        if dims[3].fixed().is_some() {
            return Err(model.mismatch(
                Kind::Input,
                &input,
                "a dynamic width (lines are read at their own width, up to perception.ocr.max_line_width)",
                input.shape(),
            ));
        }
        model.image(
            &input,
            [0, ocr.line_height],
            "perception.ocr.line_height",
            None,
        )?;
    }
    let output = model.output(None, 3, "[N, T, C]: class probabilities per time step")?;
    match dim(&output, 2).and_then(Dim::fixed) {
        Some(classes) if classes != dictionary_len => {
            return Err(model.mismatch(
                Kind::Output,
                &output,
                format!(
                    "{dictionary_len} classes, one per entry of perception.ocr.dictionary {} (blank included)",
                    ocr.dictionary.display()
                ),
                format!("{} ({classes} classes)", output.shape()),
            ));
        }
        Some(_) => {}
        None => facts.notes.push(format!(
            "output {:?} {}: its class count is checked by running a line",
            output.name,
            output.shape()
        )),
    }
    Ok(facts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::DetectorConfig;
    use std::path::PathBuf;

    fn tensor(name: &str, dims: &[i64]) -> Tensor {
        Tensor {
            name: name.into(),
            element: "f32".into(),
            dims: Some(
                dims.iter()
                    .map(|&d| match d {
                        -1 => Dim::Dynamic("n".into()),
                        d => Dim::Fixed(d as usize),
                    })
                    .collect(),
            ),
        }
    }

    fn io(inputs: Vec<Tensor>, outputs: Vec<Tensor>) -> Io {
        Io { inputs, outputs }
    }

    fn eigenplaces() -> PerceptionConfig {
        let mut config = PerceptionConfig::default();
        config.descriptor.input = "image".into();
        config.descriptor.output = "descriptor".into();
        config.descriptor.model = PathBuf::from("eigenplaces.onnx");
        config.descriptor.width = 512;
        config.descriptor.height = 384;
        config.scene = None;
        config
    }

    #[test]
    fn a_fitting_descriptor_gives_its_length() {
        let graph = io(
            vec![tensor("image", &[-1, 3, 384, 512])],
            vec![tensor("descriptor", &[-1, 512])],
        );
        let facts = descriptor(&graph, &eigenplaces(), &[]).unwrap();
        assert_eq!(facts.descriptor_len, Some(512));
    }

    #[test]
    fn descriptor_mismatches_name_model_tensor_and_expectation() {
        let graph = io(
            vec![tensor("image", &[-1, 3, 384, 512])],
            vec![tensor("descriptor", &[-1, 512])],
        );
        let store = [Expected {
            len: 256,
            source: "store.descriptor_dim".into(),
        }];
        let e = descriptor(&graph, &eigenplaces(), &store)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("perception.descriptor")
                && e.contains("\"descriptor\"")
                && e.contains("256 values per image (store.descriptor_dim)"),
            "{e}"
        );

        let mut config = eigenplaces();
        config.descriptor.width = 640;
        let e = descriptor(&graph, &config, &[]).unwrap_err().to_string();
        assert!(
            e.contains("input \"image\"") && e.contains("width 640"),
            "{e}"
        );

        let mut config = eigenplaces();
        config.descriptor.input = "pixel_values".into();
        let e = descriptor(&graph, &config, &[]).unwrap_err().to_string();
        assert!(e.contains("no input \"pixel_values\""), "{e}");

        let mut half = graph.clone();
        half.inputs[0].element = "f16".into();
        let e = descriptor(&half, &eigenplaces(), &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains("f32 elements") && e.contains("f16"), "{e}");

        // One image per inference at a fixed batch of 1 is fine on a CPU,
        // not with batches of 8.
        let mut single = graph.clone();
        single.inputs[0] = tensor("image", &[1, 3, 384, 512]);
        single.outputs[0] = tensor("descriptor", &[1, 512]);
        descriptor(&single, &eigenplaces(), &[]).unwrap();
        let mut config = eigenplaces();
        config.max_batch = 8;
        let e = descriptor(&single, &config, &[]).unwrap_err().to_string();
        assert!(e.contains("dynamic batch axis"), "{e}");
    }

    #[test]
    fn a_patch_multiple_is_enforced() {
        let graph = io(
            vec![tensor("image", &[-1, 3, -1, -1])],
            vec![tensor("descriptor", &[-1, 384])],
        );
        let mut config = eigenplaces();
        config.descriptor.input_multiple = 14;
        config.descriptor.width = 224;
        config.descriptor.height = 168;
        descriptor(&graph, &config, &[]).unwrap();
        config.descriptor.width = 230;
        let e = descriptor(&graph, &config, &[]).unwrap_err().to_string();
        assert!(
            e.contains("multiples of 14 (perception.descriptor.input_multiple)")
                && e.contains("230x168"),
            "{e}"
        );
    }

    #[test]
    fn scene_class_counts_are_checked() {
        let mut config = eigenplaces();
        let mut places = config.descriptor.clone();
        places.model = PathBuf::from("places.onnx");
        places.output = "scene".into();
        places.output_len = Some(1000);
        config.scene = Some(places);
        let graph = io(
            vec![tensor("image", &[-1, 3, 384, 512])],
            vec![tensor("scene", &[-1, 365])],
        );
        let e = scene(&graph, &config).unwrap_err().to_string();
        assert!(
            e.contains("perception.scene")
                && e.contains("\"scene\"")
                && e.contains("1000 values per image (perception.scene.output_len)")
                && e.contains("365"),
            "{e}"
        );
    }

    fn yolo(classes: usize, masks: bool) -> DetectorConfig {
        DetectorConfig {
            model: PathBuf::from("yolo.onnx"),
            input: "images".into(),
            size: 640,
            layout: YoloLayout::Anchors,
            classes: (0..classes).map(|i| format!("c{i}")).collect(),
            keep: Vec::new(),
            output: "output0".into(),
            masks_output: masks.then(|| "output1".into()),
            confidence: 0.25,
            iou: 0.45,
            max_objects: 64,
            text_classes: Vec::new(),
            precision: Default::default(),
        }
    }

    #[test]
    fn yolo_channels_count_classes_and_masks() {
        let graph = io(
            vec![tensor("images", &[-1, 3, -1, -1])],
            vec![
                tensor("output0", &[-1, 41, -1]),
                tensor("output1", &[-1, 32, -1, -1]),
            ],
        );
        let config = PerceptionConfig::default();
        detector(&graph, &config, &yolo(5, true)).unwrap();
        let e = detector(&graph, &config, &yolo(3, true))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("perception.detector")
                && e.contains("\"output0\"")
                && e.contains("3 classes")
                && e.contains("39 channels"),
            "{e}"
        );
        let e = detector(&graph, &config, &yolo(5, false))
            .unwrap_err()
            .to_string();
        assert!(e.contains("set masks_output"), "{e}");
        let mut odd = yolo(5, true);
        odd.size = 330;
        let e = detector(&graph, &config, &odd).unwrap_err().to_string();
        assert!(
            e.contains("\"images\"") && e.contains("multiple of 32"),
            "{e}"
        );
    }

    #[test]
    fn undeclared_shapes_are_left_to_the_run() {
        let mut output = tensor("probs", &[]);
        output.dims = None;
        let graph = io(vec![tensor("x", &[-1, 3, 48, -1])], vec![output]);
        let config = PerceptionConfig::default();
        let ocr = OcrConfig::default();
        let facts = ocr_recognizer(&graph, &config, &ocr, 100).unwrap();
        assert_eq!(facts.notes.len(), 1, "{:?}", facts.notes);
        let graph = io(
            vec![tensor("x", &[-1, 3, 48, -1])],
            vec![tensor("probs", &[-1, -1, 99])],
        );
        let e = ocr_recognizer(&graph, &config, &ocr, 100)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("100 classes") && e.contains("(99 classes)"),
            "{e}"
        );
    }
}
