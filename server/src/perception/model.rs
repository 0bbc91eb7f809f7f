//! One ONNX model over fixed-size images, as a [`BatchModel`].
//!
//! The descriptor, scene, detector and text-detection models all take a
//! batch of equally sized, normalised CHW images and return one or more
//! tensors with the batch as their first axis. This wraps a session so
//! that the batcher can stack its inputs into one `[N, 3, H, W]` tensor and
//! split every output back per image. Preprocessing happens in the caller,
//! on many threads, so the model's worker only runs the network.

use ort::session::Session;
use ort::value::TensorRef;

use super::batcher::BatchModel;
use super::runtime::RuntimeError;

/// The tensors one image got from a model, one per configured output, each
/// with its shape without the batch axis.
#[derive(Debug, Clone, PartialEq)]
pub struct Outputs(pub Vec<(Vec<usize>, Vec<f32>)>);

/// A session over `[N, 3, height, width]` float inputs.
pub struct ImageModel {
    pub name: String,
    session: Session,
    input: String,
    outputs: Vec<String>,
    width: usize,
    height: usize,
}

impl ImageModel {
    /// Wraps `session`; checks that it has the named input and outputs.
    pub fn new(
        name: &str,
        session: Session,
        input: &str,
        outputs: &[String],
        [width, height]: [usize; 2],
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
            width,
            height,
        })
    }

    /// Values in one input image: `3 × height × width`.
    pub fn input_len(&self) -> usize {
        3 * self.width * self.height
    }

    fn error(&self, message: impl Into<String>) -> RuntimeError {
        RuntimeError::Run {
            model: self.name.clone(),
            message: message.into(),
        }
    }
}

impl BatchModel for ImageModel {
    type Input = Vec<f32>;
    type Output = Outputs;

    fn run(&mut self, inputs: Vec<Vec<f32>>) -> Result<Vec<Outputs>, RuntimeError> {
        let n = inputs.len();
        let per_image = self.input_len();
        if let Some(bad) = inputs.iter().find(|i| i.len() != per_image) {
            return Err(self.error(format!(
                "input of {} values, expected {per_image}",
                bad.len()
            )));
        }
        let data: Vec<f32> = if n == 1 {
            inputs.into_iter().next().unwrap_or_default()
        } else {
            inputs.concat()
        };
        let shape = [n, 3, self.height, self.width];
        let tensor = TensorRef::from_array_view((shape, data.as_slice()))
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
