//! A YOLO detector configured by file: tiny ONNX models shaped like
//! Ultralytics exports, with known outputs (tools/make_tiny_yolo.py), run
//! through the real server, so decoding, NMS, masks and the mapping back
//! to the image are checked end to end.

use std::io::Cursor;
use std::path::Path;
use std::process::Command;

use humem_server::proto;

use crate::harness::{models_dir, Server};

/// Generates the tiny models into `dir`.
fn tiny_models(dir: &Path) {
    let status = Command::new(models_dir().join(".venv/bin/python"))
        .arg(crate::harness::repo_root().join("tools/make_tiny_yolo.py"))
        .arg(dir)
        .status()
        .expect("running tools/make_tiny_yolo.py with the models venv");
    assert!(status.success());
}

fn config(dir: &Path, model: &str, layout: &str, masks: bool) -> std::path::PathBuf {
    let path = dir.join(format!("{model}.toml"));
    let masks = if masks {
        "masks_output = \"output1\"\n"
    } else {
        ""
    };
    std::fs::write(
        &path,
        format!(
            "[perception.detector]\nmodel = \"{}\"\nsize = 64\nlayout = \"{layout}\"\n\
             classes = [\"building\", \"billboard\", \"pole\"]\nkeep = [\"building\", \"billboard\"]\n\
             text_classes = [\"billboard\"]\n{masks}",
            dir.join(format!("{model}.onnx")).display()
        ),
    )
    .unwrap();
    path
}

/// A 128x128 grey picture: letterboxed into 64x64 at scale 0.5, no padding.
fn picture() -> proto::Image {
    let img = image::RgbImage::from_pixel(128, 128, image::Rgb([90, 120, 150]));
    let mut png = Vec::new();
    img.write_to(&mut Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    proto::Image {
        data: png,
        ..Default::default()
    }
}

async fn objects_of(server: &Server) -> Vec<proto::ObjectObservation> {
    let keyframe = proto::Keyframe {
        robot_id: "r".into(),
        keyframe_id: Some(1),
        frame_id: Some(1),
        map_id: Some(0),
        pose: Some(crate::scenes::pose(0.0)),
        content: Some(proto::keyframe::Content::Image(picture())),
        ..Default::default()
    };
    let reply = server
        .client()
        .await
        .insert(proto::InsertRequest {
            keyframe: Some(keyframe),
        })
        .await
        .unwrap()
        .into_inner();
    let stages: Vec<&str> = reply.timings.iter().map(|t| t.stage.as_str()).collect();
    assert_eq!(
        stages,
        ["decode", "descriptor", "detector", "ocr_det", "ocr_rec"]
    );
    reply.features.unwrap().objects
}

fn close(a: f32, b: f32) -> bool {
    (a - b).abs() < 1e-4
}

#[tokio::test(flavor = "multi_thread")]
async fn segment_export_objects_come_from_masks() {
    let dir = tempfile::tempdir().unwrap();
    tiny_models(dir.path());
    let config = config(dir.path(), "yolo_seg_anchors", "anchors", true);
    let data = tempfile::tempdir().unwrap();
    let server = Server::start_with(
        data.path(),
        &[
            "--config",
            config.to_str().unwrap(),
            "HUMEM_PERCEPTION__ENABLED=true",
        ],
    );
    let objects = objects_of(&server).await;
    // Anchor 1 overlaps anchor 0 (IoU 0.70) and is suppressed; anchor 3 is
    // under the confidence threshold; class "pole" would not be kept anyway.
    assert_eq!(objects.len(), 2, "{objects:?}");
    let (building, billboard) = (&objects[0], &objects[1]);
    assert_eq!(building.class_name, "building");
    assert!(close(building.confidence, 0.9));
    // The building's mask is the top half of its box: 16x8 input pixels,
    // centroid (16, 12), i.e. (32, 24) and 512 px² in the 128x128 picture.
    assert!(
        close(building.x, 0.25) && close(building.y, 0.1875),
        "{building:?}"
    );
    assert!(close(building.area, 512.0 / 16384.0), "{building:?}");
    assert_eq!(billboard.class_name, "billboard");
    assert!(
        close(billboard.x, 0.75) && close(billboard.y, 0.625),
        "{billboard:?}"
    );
    assert!(close(billboard.area, 2048.0 / 16384.0), "{billboard:?}");
}

#[tokio::test(flavor = "multi_thread")]
async fn end_to_end_export_objects_come_from_boxes() {
    let dir = tempfile::tempdir().unwrap();
    tiny_models(dir.path());
    let config = config(dir.path(), "yolo_end_to_end", "end_to_end", false);
    let data = tempfile::tempdir().unwrap();
    let server = Server::start_with(
        data.path(),
        &[
            "--config",
            config.to_str().unwrap(),
            "HUMEM_PERCEPTION__ENABLED=true",
        ],
    );
    let objects = objects_of(&server).await;
    assert_eq!(objects.len(), 2, "{objects:?}");
    // Boxes (8, 8, 24, 24) and (40, 24, 56, 56) in the input: centres
    // (16, 16) and (48, 40), areas 256 and 512, doubled into the picture.
    assert!(close(objects[0].x, 0.25) && close(objects[0].y, 0.25));
    assert!(close(objects[0].area, 1024.0 / 16384.0));
    assert!(close(objects[1].x, 0.75) && close(objects[1].y, 0.625));
    assert!(close(objects[1].area, 2048.0 / 16384.0));
}
