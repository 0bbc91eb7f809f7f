//! What the whole-image roles (descriptor and scene) are fed and what is
//! read from them: the normalised input of an image for its model's
//! configuration, and the most probable scene classes of an output.
//!
//! The serving path (the crate root) and `humem models check`
//! ([`crate::check::run`]) must do exactly the same here, so both use this
//! one module, which sits below them.

use image::RgbImage;

use humem_core::keyframe::SceneClass;

use crate::config::ImageModelConfig;
use crate::image::{append_chw, resize, Channels};
use crate::model::Planes;

/// The normalised input of an image model.
pub(crate) fn model_input(image: &RgbImage, config: &ImageModelConfig) -> Planes {
    let resized = resize(image, config.width, config.height);
    let mut data = Vec::with_capacity(3 * (config.width * config.height) as usize);
    append_chw(&resized, Channels::Rgb, config.mean, config.std, &mut data);
    Planes {
        width: config.width as usize,
        height: config.height as usize,
        data,
    }
}

/// The `k` most probable classes of a probability vector. Outputs that are
/// not probabilities (negative values or a sum above 1) are treated as
/// logits and go through a softmax first.
pub(crate) fn top_classes(values: &[f32], k: usize) -> Vec<SceneClass> {
    let finite = values.iter().all(|v| v.is_finite());
    if !finite || values.is_empty() {
        return Vec::new();
    }
    let sum: f32 = values.iter().sum();
    let probs: Vec<f32> = if values.iter().any(|&v| v < 0.0) || sum > 1.001 {
        let max = values.iter().copied().fold(f32::MIN, f32::max);
        let exp: Vec<f32> = values.iter().map(|v| (v - max).exp()).collect();
        let total: f32 = exp.iter().sum();
        exp.iter().map(|e| e / total).collect()
    } else {
        values.to_vec()
    };
    let mut classes: Vec<SceneClass> = probs
        .iter()
        .enumerate()
        .filter(|(_, &p)| p > 0.0)
        .map(|(i, &p)| SceneClass {
            class_id: i as u32,
            probability: p.min(1.0),
        })
        .collect();
    classes.sort_by(|a, b| {
        b.probability
            .total_cmp(&a.probability)
            .then(a.class_id.cmp(&b.class_id))
    });
    classes.truncate(k);
    classes
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn top_classes_keeps_the_most_probable() {
        let classes = top_classes(&[0.1, 0.6, 0.0, 0.3], 2);
        assert_eq!(
            classes,
            vec![
                SceneClass {
                    class_id: 1,
                    probability: 0.6
                },
                SceneClass {
                    class_id: 3,
                    probability: 0.3
                }
            ]
        );
        // Logits: softmax of (0, ln 3) = (0.25, 0.75).
        let classes = top_classes(&[0.0, 3f32.ln(), -30.0], 5);
        assert_eq!(classes[0].class_id, 1);
        assert!((classes[0].probability - 0.75).abs() < 1e-5);
        assert!(top_classes(&[f32::NAN], 3).is_empty());
    }
}
