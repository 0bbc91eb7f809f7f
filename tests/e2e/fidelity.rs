//! Descriptor fidelity: the server's decoding, resizing and normalisation
//! must give the descriptor the model gives with plain Python preprocessing
//! (`tools/reference_descriptor.py`: Pillow and ONNX Runtime), on real
//! pictures: scikit-image's samples (PNG and JPEG, colour and grey) from the
//! wheel `scripts/setup-models.sh` installs, and frames of every shared data
//! set when `../shared` is beside the checkout. A preprocessing slip (colour
//! order, filter, normalisation, decoding) costs recall without failing
//! anything else, so this compares the two at cosine ≥ 0.999, for the
//! fp32 network and its int8 quantisation alike.

use std::path::{Path, PathBuf};
use std::process::Command;

use humem_perception::config::{PerceptionConfig, Precision};
use humem_perception::{ImageInput, Perception};

use crate::harness::{datasets, models_dir};

const MIN_COSINE: f32 = 0.999;

/// The same bound for the int8 network: its quantised activations turn a
/// rounding difference in the input (resampling, the last bit of a
/// normalised value) into a step of one quantisation level, so Python's and
/// the server's identical preprocessing agree to 0.9963 at worst on these
/// pictures, where a wrong colour order or filter falls far below.
const MIN_COSINE_INT8: f32 = 0.995;

/// scikit-image's sample pictures used: photos, a grey one (`camera`) and
/// JPEGs.
const SAMPLES: &[&str] = &[
    "astronaut.png",
    "camera.png",
    "chelsea.png",
    "coffee.png",
    "motorcycle_left.png",
    "rocket.jpg",
    "retina.jpg",
    "hubble_deep_field.jpg",
];

/// Frames taken from each shared data set folder.
const PER_DATASET: usize = 4;

fn samples(into: &Path) -> Option<Vec<PathBuf>> {
    let wheel = std::fs::read_dir(models_dir().join("testdata"))
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .find(|p| p.extension().is_some_and(|e| e == "whl"))?;
    let members: Vec<String> = SAMPLES
        .iter()
        .map(|s| format!("skimage/data/{s}"))
        .collect();
    let status = Command::new("unzip")
        .arg("-q")
        .arg("-j")
        .arg("-o")
        .arg(&wheel)
        .args(&members)
        .arg("-d")
        .arg(into)
        .status()
        .expect("unzip (Debian unzip) runs");
    assert!(status.success(), "unzip {} failed", wheel.display());
    Some(SAMPLES.iter().map(|s| into.join(s)).collect())
}

/// A few frames of every image folder under the shared data sets.
fn dataset_frames() -> Vec<PathBuf> {
    let Some(root) = datasets() else {
        return Vec::new();
    };
    let mut folders = Vec::new();
    let mut stack = vec![root];
    while let Some(dir) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        for path in entries.filter_map(|e| e.ok().map(|e| e.path())) {
            // `*_objects` folders hold instance masks, not camera images.
            let masks = path
                .file_name()
                .is_some_and(|n| n.to_string_lossy().ends_with("_objects"));
            if path.is_dir() && !masks {
                stack.push(path.clone());
                folders.push(path);
            }
        }
    }
    folders.sort();
    let mut frames = Vec::new();
    for folder in folders {
        let mut images: Vec<PathBuf> = std::fs::read_dir(&folder)
            .into_iter()
            .flatten()
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                p.extension()
                    .is_some_and(|e| e == "jpg" || e == "png" || e == "jpeg")
            })
            .collect();
        images.sort();
        let step = (images.len() / PER_DATASET).max(1);
        frames.extend(images.into_iter().step_by(step).take(PER_DATASET));
    }
    frames
}

/// The Python reference's descriptors, in the order of `images`.
fn reference(python: &Path, model: &Path, [w, h]: [u32; 2], images: &[PathBuf]) -> Vec<Vec<f32>> {
    let script = crate::harness::repo_root().join("tools/reference_descriptor.py");
    let output = Command::new(python)
        .arg(script)
        .arg(model)
        .arg(format!("{w}x{h}"))
        .args(images)
        .output()
        .expect("the models venv's python runs");
    assert!(
        output.status.success(),
        "reference_descriptor.py failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    let lines: Vec<serde_json::Value> = String::from_utf8(output.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), images.len());
    lines
        .iter()
        .map(|l| {
            l["descriptor"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap() as f32)
                .collect()
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread")]
async fn descriptors_match_the_python_reference() {
    let models = models_dir();
    let python = models.join(".venv/bin/python");
    let defaults = PerceptionConfig::default();
    let model = models.join(&defaults.descriptor.model);
    if !model.exists() || !python.exists() {
        eprintln!(
            "skipped: {} or {} is absent (run scripts/setup-models.sh)",
            model.display(),
            python.display()
        );
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let Some(mut images) = samples(tmp.path()) else {
        eprintln!(
            "skipped: no scikit-image wheel in models/testdata (run scripts/setup-models.sh)"
        );
        return;
    };
    images.extend(dataset_frames());

    let default_size = [defaults.descriptor.width, defaults.descriptor.height];
    let mut sizes = vec![default_size];
    if default_size != [224, 224] {
        sizes.push([224, 224]);
    }
    let mut worst: Vec<(f32, String)> = Vec::new();
    // Both graphs: the int8 one is the same preprocessing, a different
    // network, checked against the reference run on that network.
    let runs = [Precision::Fp32, Precision::Int8]
        .into_iter()
        .flat_map(|p| sizes.iter().map(move |&size| (p, size)));
    for (precision, size) in runs {
        let mut config = PerceptionConfig {
            models_dir: models.clone(),
            scene: None,
            ocr: None,
            detector: None,
            ..PerceptionConfig::default()
        };
        config.descriptor.width = size[0];
        config.descriptor.height = size[1];
        config.descriptor.precision = Some(precision);
        let perception = Perception::load(&config, 5).expect("models load");
        let model = models.join(precision.file(&defaults.descriptor.model));
        let expected = reference(&python, &model, size, &images);
        for (path, want) in images.iter().zip(&expected) {
            let bytes = std::fs::read(path).unwrap();
            let got = perception
                .extract(ImageInput::file(bytes))
                .await
                .expect("extracts")
                .features
                .descriptor;
            let cosine: f32 = got.iter().zip(want).map(|(a, b)| a * b).sum();
            let label = format!("{precision:?} {}x{} {}", size[0], size[1], path.display());
            eprintln!("cos {cosine:.5} {label}");
            let bound = match precision {
                Precision::Fp32 => MIN_COSINE,
                Precision::Int8 => MIN_COSINE_INT8,
            };
            // How far above its bound: the failing ones are below 0.
            worst.push((cosine - bound, label));
        }
    }
    worst.sort_by(|a, b| a.0.total_cmp(&b.0));
    let failing: Vec<_> = worst.iter().filter(|(c, _)| *c < 0.0).collect();
    assert!(
        failing.is_empty(),
        "{} of {} descriptors differ from the Python reference (cosine below {MIN_COSINE}, int8 {MIN_COSINE_INT8}; shown as cosine minus bound): {failing:?}",
        failing.len(),
        worst.len()
    );
}
