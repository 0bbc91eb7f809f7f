//! `humem models check` and the server's start against models shaped like
//! the exports users make: small random-weight graphs written at test time
//! by tools/make_test_models.py (EigenPlaces-, Places365-, YOLO-seg- and
//! ViT/14-like), run through the real binary and ONNX Runtime. Each fits
//! its right configuration; each deliberately wrong configuration is
//! refused with the model, the tensor and what was expected.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::harness::{models_dir, repo_root, Server};

/// ImageNet normalisation, and fp32: a `[perception.descriptor]` section
/// keeps the default's `precision = "int8"` unless it says otherwise.
const IMAGENET: &str =
    "mean = [0.485, 0.456, 0.406]\nstd = [0.229, 0.224, 0.225]\nprecision = \"fp32\"\n";

/// The test graphs, written into a temporary folder; `None` (the test is
/// skipped, saying so) where the models are not installed.
fn graphs() -> Option<tempfile::TempDir> {
    let python = models_dir().join(".venv/bin/python");
    if !models_dir().join("lib").is_dir() || !python.exists() {
        eprintln!("skipped: models not installed (scripts/setup-models.sh)");
        return None;
    }
    let dir = tempfile::tempdir().unwrap();
    crate::harness::output_of(
        Command::new(python)
            .arg(repo_root().join("tools/make_test_models.py"))
            .arg(dir.path()),
    );
    Some(dir)
}

fn eigenplaces(dir: &Path) -> String {
    format!(
        "[perception.descriptor]\nmodel = \"{}\"\ninput = \"image\"\nwidth = 512\nheight = 384\n{IMAGENET}output = \"descriptor\"\n",
        dir.join("eigenplaces_like.onnx").display()
    )
}

fn places365(dir: &Path, classes: usize) -> String {
    format!(
        "[perception.scene]\nmodel = \"{}\"\ninput = \"image\"\nwidth = 224\nheight = 224\n{IMAGENET}output = \"scene\"\noutput_len = {classes}\n",
        dir.join("places365_like.onnx").display()
    )
}

fn yolo_seg(dir: &Path, size: u32, classes: &str, masks: bool) -> String {
    format!(
        "[perception.detector]\nmodel = \"{}\"\nsize = {size}\nlayout = \"anchors\"\nclasses = [{classes}]\n{}text_classes = [\"billboard\"]\n",
        dir.join("yolo_seg_like.onnx").display(),
        if masks { "masks_output = \"output1\"\n" } else { "" }
    )
}

const FIVE_CLASSES: &str =
    "\"building\", \"fence\", \"street_light\", \"billboard\", \"traffic_sign\"";

fn vit(dir: &Path, width: u32, multiple: bool) -> String {
    format!(
        "[perception.descriptor]\nmodel = \"{}\"\ninput = \"pixel_values\"\nwidth = {width}\nheight = 168\n{IMAGENET}output = \"embedding\"\n{}",
        dir.join("vit_like.onnx").display(),
        if multiple { "input_multiple = 14\n" } else { "" }
    )
}

/// `humem models check` with `toml` as the configuration (none if empty)
/// and `data` as the store: (success, stdout, stderr).
fn check(toml: &str, data: &Path) -> (bool, String, String) {
    let mut command = Command::new(env!("CARGO_BIN_EXE_humem"));
    let file = tempfile::NamedTempFile::new().unwrap();
    if !toml.is_empty() {
        std::fs::write(file.path(), toml).unwrap();
        command.arg("--config").arg(file.path());
    }
    let out = command
        .args(["models", "check"])
        .env("RUST_LOG", "warn,ort::logging=error")
        .env("HUMEM_PERCEPTION__MODELS_DIR", models_dir())
        .env("HUMEM_STORE__DATA_DIR", data)
        .env_remove("HUMEM_CONFIG")
        .output()
        .expect("running humem models check");
    (
        out.status.success(),
        String::from_utf8(out.stdout).unwrap(),
        String::from_utf8(out.stderr).unwrap(),
    )
}

fn assert_fits(toml: &str, data: &Path, expected: &[&str]) -> String {
    let (ok, out, err) = check(toml, data);
    assert!(ok, "refused:\n{out}\n{err}");
    for text in expected {
        assert!(out.contains(text), "{text:?} missing from\n{out}");
    }
    out
}

/// A store whose recorded descriptor length is `dim`, left by a server
/// that ran on it.
fn store_of(dim: usize) -> tempfile::TempDir {
    let data = tempfile::tempdir().unwrap();
    let server = Server::start_with(
        data.path(),
        &[&format!("HUMEM_STORE__DESCRIPTOR_DIM={dim}")],
    );
    assert!(server.terminate().success());
    data
}

#[test]
fn the_shipped_models_fit() {
    if graphs().is_none() {
        return;
    }
    let data = store_of(1280);
    assert_fits(
        "",
        data.path(),
        &[
            "1280-value descriptors",
            "perception.descriptor  ok",
            "output \"descriptor\": 1280 values",
            "perception.scene  ok",
            "one inference gives both",
            "perception.ocr.detector  ok",
            "perception.ocr.recognizer  ok",
            // The synthetic picture's sign, read through both OCR models.
            "read \"HUMEM\"",
            "all 4 models fit the configuration",
        ],
    );
}

#[test]
fn graphs_shaped_like_the_exports_fit() {
    let Some(dir) = graphs() else { return };
    let dir = dir.path();
    let data = tempfile::tempdir().unwrap();
    let config = format!(
        "{}{}{}",
        eigenplaces(dir),
        places365(dir, 365),
        yolo_seg(dir, 320, FIVE_CLASSES, true)
    );
    assert_fits(
        &config,
        data.path(),
        &[
            "input   image f32 [n, 3, 384, 512]",
            "output \"descriptor\": 512 values, norm 1.0000",
            "output \"scene\": 365 classes",
            "input   images f32 [batch, 3, height, width]",
            "output \"output0\": [1, 41, 2100]",
            "output \"output1\": [1, 32, 80, 80] prototype masks",
            "objects kept",
            "all 5 models fit the configuration",
        ],
    );
    assert_fits(
        &vit(dir, 224, true),
        data.path(),
        &[
            "input   pixel_values f32 [n, 3, h, w]",
            "224x168 image",
            "output \"embedding\": 384 values",
        ],
    );
    assert!(
        !data.path().join("conf").exists(),
        "the check created a store"
    );
}

#[test]
fn wrong_configurations_are_refused_with_model_tensor_and_expectation() {
    let Some(dir) = graphs() else { return };
    let dir = dir.path();
    let empty = tempfile::tempdir().unwrap();
    let store_1280 = store_of(1280);
    let cases: Vec<(&str, String, &Path, Vec<&str>)> = vec![
        (
            "descriptor length against store.descriptor_dim",
            format!("[store]\ndescriptor_dim = 256\n{}", eigenplaces(dir)),
            empty.path(),
            vec![
                "perception.descriptor:",
                "output \"descriptor\"",
                "256 values per image (store.descriptor_dim)",
                "found 512 values per image",
            ],
        ),
        (
            "descriptor length against an existing store",
            eigenplaces(dir),
            store_1280.path(),
            vec![
                "perception.descriptor:",
                "output \"descriptor\"",
                "1280 values per image (the store in",
                "found 512 values per image",
            ],
        ),
        (
            "ViT input not a multiple of its patch",
            vit(dir, 230, true),
            empty.path(),
            vec![
                "perception.descriptor:",
                "input \"pixel_values\"",
                "width and height multiples of 14 (perception.descriptor.input_multiple)",
                "found 230x168",
            ],
        ),
        (
            "ViT input not a multiple of its patch, nothing configured",
            vit(dir, 230, false),
            empty.path(),
            vec![
                "perception.descriptor:",
                "running one 230x168 image through input \"pixel_values\" failed",
                "set input_multiple",
            ],
        ),
        (
            "scene class count",
            format!("{}{}", eigenplaces(dir), places365(dir, 1000)),
            empty.path(),
            vec![
                "perception.scene:",
                "output \"scene\"",
                "1000 values per image (perception.scene.output_len)",
                "found 365 values per image",
            ],
        ),
        (
            "descriptor pointing at the detector graph",
            eigenplaces(dir).replace("eigenplaces_like", "yolo_seg_like"),
            empty.path(),
            vec![
                "perception.descriptor:",
                "the graph has no input \"image\"",
                "images f32 [batch, 3, height, width]",
            ],
        ),
        (
            "descriptor pointing at the detector graph, names as the detector's",
            eigenplaces(dir)
                .replace("eigenplaces_like", "yolo_seg_like")
                .replace("\"image\"", "\"images\"")
                .replace("\"descriptor\"", "\"output0\"")
                .replace("width = 512\nheight = 384", "width = 320\nheight = 320"),
            empty.path(),
            vec![
                "perception.descriptor:",
                "output \"output0\"",
                "[N, D]: one descriptor per image (rank 2)",
                "found [batch, 41, anchors] (rank 3)",
            ],
        ),
        (
            "missing file",
            eigenplaces(dir).replace("eigenplaces_like", "no_such_model"),
            empty.path(),
            vec!["perception.descriptor:", "no_such_model.onnx does not exist"],
        ),
        (
            "detector class list",
            yolo_seg(dir, 320, "\"building\", \"fence\", \"billboard\"", true),
            empty.path(),
            vec![
                "perception.detector:",
                "output \"output0\"",
                "4 box values + 3 classes (perception.detector.classes) + 32 mask coefficients (output1) = 39 channels",
                "found [batch, 41, anchors] (41 channels; that is 5 classes)",
            ],
        ),
        (
            "detector size not a multiple of the stride",
            yolo_seg(dir, 330, FIVE_CLASSES, true),
            empty.path(),
            vec![
                "perception.detector:",
                "input \"images\"",
                "multiple of 32",
                "perception.detector.size = 330",
            ],
        ),
        (
            "segment export without masks_output",
            yolo_seg(dir, 320, FIVE_CLASSES, false),
            empty.path(),
            vec![
                "perception.detector:",
                "output \"output0\"",
                "= 9 channels",
                "set masks_output",
            ],
        ),
    ];
    for (case, toml, data, expected) in cases {
        let (ok, out, err) = check(&toml, data);
        assert!(!ok, "{case}: accepted\n{out}");
        assert!(out.contains("DOES NOT FIT"), "{case}:\n{out}");
        for text in expected {
            assert!(err.contains(text), "{case}: {text:?} missing from\n{err}");
        }
    }
}

/// `humem serve` with `toml`: waits for it to exit (it must, within a
/// minute) and returns its stderr.
fn serve_refused(toml: &str, data: &Path) -> String {
    let file = tempfile::NamedTempFile::new().unwrap();
    std::fs::write(file.path(), toml).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_humem"))
        .arg("--config")
        .arg(file.path())
        .args(["serve", "--listen", "127.0.0.1:0", "--data-dir"])
        .arg(data)
        .env("RUST_LOG", "warn,ort::logging=error")
        .env("HUMEM_PERCEPTION__ENABLED", "true")
        .env("HUMEM_PERCEPTION__MODELS_DIR", models_dir())
        .env("HUMEM_METRICS__LISTEN", "127.0.0.1:0")
        .env_remove("HUMEM_CONFIG")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("starting humem serve");
    let deadline = Instant::now() + Duration::from_secs(60);
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if Instant::now() > deadline {
            child.kill().ok();
            panic!("humem serve started with a model that does not fit");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let mut err = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut err).unwrap();
    assert!(!status.success(), "{err}");
    err
}

#[test]
fn serve_refuses_a_model_that_does_not_fit() {
    let Some(dir) = graphs() else { return };
    let dir = dir.path();
    let data = tempfile::tempdir().unwrap();
    let data = data.path();
    // The graph itself: refused as the model loads.
    let err = serve_refused(&vit(dir, 230, true), data);
    for text in [
        "perception.descriptor:",
        "input \"pixel_values\"",
        "multiples of 14",
    ] {
        assert!(err.contains(text), "{text:?} missing from\n{err}");
    }
    // The store's length: refused once both are open.
    let err = serve_refused(
        &format!("[store]\ndescriptor_dim = 256\n{}", eigenplaces(dir)),
        data,
    );
    for text in [
        "perception.descriptor:",
        "output \"descriptor\"",
        "256 values per image (store.descriptor_dim)",
    ] {
        assert!(err.contains(text), "{text:?} missing from\n{err}");
    }
}
