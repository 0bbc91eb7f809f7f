//! One ONNX model over images, as a [`BatchModel`].
//!
//! The descriptor, scene, detector and text-detection models all take a
//! batch of normalised CHW images and return one or more tensors with the
//! batch as their first axis. This wraps a session so that the batcher can
//! stack its inputs into `[N, 3, H, W]` tensors and split every output back
//! per image. Most models take one fixed size; a fully convolutional one
//! (text detection) takes any size, so a batch is run as one tensor per
//! shape among its images. Preprocessing happens in the caller, on many
//! threads, so the model's worker only runs the network.

use std::collections::BTreeMap;

use ort::session::Session;
use ort::value::TensorRef;

use super::batcher::BatchModel;
use super::runtime::RuntimeError;

/// The tensors one image got from a model, one per configured output, each
/// with its shape without the batch axis.
#[derive(Debug, Clone, PartialEq)]
pub struct Outputs(pub Vec<(Vec<usize>, Vec<f32>)>);

/// One normalised image: `3 × height × width` planar values.
#[derive(Debug, Clone, PartialEq)]
pub struct Planes {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// The three colour planes one after the other, in the model's channel
    /// order, each row-major.
    pub data: Vec<f32>,
}

/// A session over `[N, 3, height, width]` float inputs.
pub struct ImageModel {
    /// The model's role, as named in errors (`descriptor`, `detector`, …).
    pub name: String,
    session: Session,
    input: String,
    outputs: Vec<String>,
    /// `[width, height]` every input must have; `None`: any.
    size: Option<[usize; 2]>,
}

impl ImageModel {
    /// Wraps `session`; checks that it has the named input and outputs.
    /// `size` (`[width, height]`) is the one input size the model takes, or
    /// `None` for a fully convolutional model that takes any.
    pub fn new(
        name: &str,
        session: Session,
        input: &str,
        outputs: &[String],
        size: Option<[usize; 2]>,
    ) -> Result<ImageModel, RuntimeError> {
        let error = |message: String| RuntimeError::Run {
            model: name.to_string(),
            message,
        };
        if !session.inputs().iter().any(|i| i.name() == input) {
            let names: Vec<_> = session
                .inputs()
                .iter()
                .map(|i| i.name().to_string())
                .collect();
            return Err(error(format!("has no input {input:?} (inputs: {names:?})")));
        }
        for output in outputs {
            if !session.outputs().iter().any(|o| o.name() == output) {
                let names: Vec<_> = session
                    .outputs()
                    .iter()
                    .map(|o| o.name().to_string())
                    .collect();
                return Err(error(format!(
                    "has no output {output:?} (outputs: {names:?})"
                )));
            }
        }
        Ok(ImageModel {
            name: name.to_string(),
            session,
            input: input.to_string(),
            outputs: outputs.to_vec(),
            size,
        })
    }

    fn error(&self, message: impl Into<String>) -> RuntimeError {
        RuntimeError::Run {
            model: self.name.clone(),
            message: message.into(),
        }
    }

    /// Runs one tensor of equally sized images.
    fn run_shape(
        &mut self,
        [width, height]: [usize; 2],
        images: &[&Planes],
    ) -> Result<Vec<Outputs>, RuntimeError> {
        let n = images.len();
        let data: Vec<f32> = if n == 1 {
            images[0].data.clone()
        } else {
            images.iter().flat_map(|i| i.data.iter().copied()).collect()
        };
        let tensor = TensorRef::from_array_view(([n, 3, height, width], data.as_slice()))
            .map_err(|e| self.error(e.to_string()))?;
        let input_name = self.input.clone();
        let results = self
            .session
            .run(ort::inputs![input_name => tensor])
            .map_err(|e| RuntimeError::Run {
                model: self.name.clone(),
                message: e.to_string(),
            })?;
        let mut per_item: Vec<Outputs> = (0..n).map(|_| Outputs(Vec::new())).collect();
        for name in &self.outputs {
            let (shape, values) =
                results[name.as_str()]
                    .try_extract_tensor::<f32>()
                    .map_err(|e| RuntimeError::Run {
                        model: self.name.clone(),
                        message: format!("output {name}: {e}"),
                    })?;
            let dims: Vec<usize> = shape.iter().map(|&d| d.max(0) as usize).collect();
            if dims.first() != Some(&n) {
                return Err(RuntimeError::Run {
                    model: self.name.clone(),
                    message: format!("output {name} has shape {dims:?}, expected batch {n} first"),
                });
            }
            let item_len = values.len() / n;
            for (i, out) in per_item.iter_mut().enumerate() {
                out.0.push((
                    dims[1..].to_vec(),
                    values[i * item_len..(i + 1) * item_len].to_vec(),
                ));
            }
        }
        Ok(per_item)
    }
}

impl BatchModel for ImageModel {
    type Input = Planes;
    type Output = Outputs;

    fn run(&mut self, inputs: Vec<Planes>) -> Result<Vec<Outputs>, RuntimeError> {
        // Indices of the inputs of each shape, in order.
        let mut shapes: BTreeMap<[usize; 2], Vec<usize>> = BTreeMap::new();
        for (i, image) in inputs.iter().enumerate() {
            let size = [image.width, image.height];
            if image.data.len() != 3 * image.width * image.height {
                return Err(self.error(format!(
                    "input of {} values for {}x{}",
                    image.data.len(),
                    image.width,
                    image.height
                )));
            }
            if let Some(expected) = self.size.filter(|&e| e != size) {
                return Err(self.error(format!(
                    "input of {}x{}, expected {}x{}",
                    size[0], size[1], expected[0], expected[1]
                )));
            }
            shapes.entry(size).or_default().push(i);
        }
        let mut outputs: Vec<Option<Outputs>> = vec![None; inputs.len()];
        for (size, indices) in shapes {
            let images: Vec<&Planes> = indices.iter().map(|&i| &inputs[i]).collect();
            for (i, out) in indices.into_iter().zip(self.run_shape(size, &images)?) {
                outputs[i] = Some(out);
            }
        }
        Ok(outputs.into_iter().flatten().collect())
    }
}
