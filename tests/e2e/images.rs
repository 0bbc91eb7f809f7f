//! Images through the real models: keyframes and queries sent as camera
//! images, perceived by the server's ONNX models (EfficientNet-Lite0 GeM
//! descriptor and ImageNet scene context, PP-OCRv5 text), then ranked.

use std::collections::BTreeMap;
use std::io::Cursor;
use std::path::Path;

use humem_server::proto;

use crate::harness::{datasets, Server};

/// An encoded image as the API takes it.
pub(crate) fn image(data: Vec<u8>) -> proto::Image {
    proto::Image {
        encoding: proto::image::Encoding::Unspecified as i32,
        data,
        ..Default::default()
    }
}

pub(crate) fn keyframe(robot: &str, id: u64, content: proto::Image) -> proto::Keyframe {
    proto::Keyframe {
        robot_id: robot.into(),
        session_id: "s".into(),
        keyframe_id: Some(id),
        frame_id: Some(id),
        timestamp: id as f64,
        map_id: Some(0),
        // No odometry: every keyframe at the origin, as a client without
        // poses sends them.
        pose: Some(crate::scenes::pose(0.0)),
        content: Some(proto::keyframe::Content::Image(content)),
    }
}

/// Black text on a white board, as a PNG.
pub(crate) fn rendered_text(lines: &[&str]) -> Vec<u8> {
    let font_path = "/usr/share/fonts/truetype/dejavu/DejaVuSans-Bold.ttf";
    let font = ab_glyph::FontVec::try_from_vec(
        std::fs::read(font_path).expect("DejaVu fonts (Debian fonts-dejavu-core)"),
    )
    .unwrap();
    let mut img = image::RgbImage::from_pixel(640, 480, image::Rgb([235, 235, 228]));
    for (i, line) in lines.iter().enumerate() {
        imageproc::drawing::draw_text_mut(
            &mut img,
            image::Rgb([20, 20, 30]),
            60,
            80 + 140 * i as i32,
            ab_glyph::PxScale::from(72.0),
            &font,
            line,
        );
    }
    let mut png = Vec::new();
    img.write_to(&mut Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    png
}

fn texts(features: &proto::Features) -> Vec<String> {
    features
        .objects
        .iter()
        .flat_map(|o| o.texts.iter().map(|t| t.text.clone()))
        .collect()
}

#[tokio::test(flavor = "multi_thread")]
async fn rendered_text_is_read_back_and_grounds_a_match() {
    let dir = tempfile::tempdir().unwrap();
    // A one-keyframe store has no null to calibrate against (fewer than
    // `null_min_samples` eligible keyframes answer nothing): this test is
    // about the text, so it uses the paper's raw rule.
    let server = Server::start_with(
        dir.path(),
        &[
            "HUMEM_PERCEPTION__ENABLED=true",
            "HUMEM_VPR__CALIBRATION=raw",
        ],
    );
    let mut client = server.client().await;

    let board = rendered_text(&["EXIT 12B", "Gate B-214"]);
    let reply = client
        .insert(proto::InsertRequest {
            keyframe: Some(keyframe("r", 1, image(board.clone()))),
        })
        .await
        .unwrap()
        .into_inner();
    let features = reply.features.expect("features of the image");
    assert_eq!(
        texts(&features),
        vec!["EXIT 12B".to_string(), "Gate B-214".to_string()]
    );
    assert!(features.objects.iter().all(|o| o.class_name == "sign"));
    // The first line sits in the upper part of the image, the second below.
    assert!(features.objects[0].y < features.objects[1].y);
    assert_eq!(features.global_descriptor.len(), 1280);
    assert!(!features.scene.is_empty());
    let stages: Vec<&str> = reply.timings.iter().map(|t| t.stage.as_str()).collect();
    assert_eq!(stages, ["decode", "descriptor", "ocr_det", "ocr_rec"]);

    // The same board seen again (as JPEG, from another robot) is found, and
    // the text on it is part of the evidence.
    let jpeg = {
        let img = image::load_from_memory(&board).unwrap().to_rgb8();
        let mut out = Vec::new();
        img.write_to(&mut Cursor::new(&mut out), image::ImageFormat::Jpeg)
            .unwrap();
        out
    };
    let reply = client
        .query(proto::QueryRequest {
            robot_id: "other".into(),
            frame_id: Some(0),
            content: Some(proto::query_request::Content::Image(image(jpeg))),
            ..Default::default()
        })
        .await
        .unwrap()
        .into_inner();
    let top = &reply.candidates[0];
    assert_eq!(top.keyframe_id, 1);
    let evidence = top.evidence.as_ref().unwrap();
    assert!(
        evidence
            .text_matches
            .iter()
            .any(|m| m.candidate_text == "EXIT 12B"),
        "{evidence:?}"
    );
    let stages: Vec<&str> = reply.timings.iter().map(|t| t.stage.as_str()).collect();
    assert_eq!(
        stages,
        [
            "decode",
            "descriptor",
            "ocr_det",
            "ocr_rec",
            "scal",
            "osrl",
            "ogtl",
            "fusion",
            "rules"
        ]
    );

    // Raw frames as SLAM systems hold them work too; garbage does not.
    // ITU-R 601 luma, as OpenCV makes ORB-SLAM3's grey frames.
    let rgb = image::load_from_memory(&board).unwrap().to_rgb8();
    let raw = proto::Image {
        encoding: proto::image::Encoding::Gray8 as i32,
        width: rgb.width(),
        height: rgb.height(),
        data: rgb
            .pixels()
            .map(|p| humem_perception::image::luma(p.0))
            .collect(),
        stride: 0,
    };
    let reply = client
        .insert(proto::InsertRequest {
            keyframe: Some(keyframe("r", 2, raw)),
        })
        .await
        .unwrap()
        .into_inner();
    let grey_features = reply.features.unwrap();
    assert_eq!(texts(&grey_features)[0], "EXIT 12B");
    // The appearance thumbnail (64x48 signed bytes) is made from grey
    // anyway, so the colour image and its grey pixels give the same one.
    assert_eq!(features.appearance.len(), 3072);
    assert_eq!(grey_features.appearance, features.appearance);
    let status = client
        .insert(proto::InsertRequest {
            keyframe: Some(keyframe(
                "r",
                3,
                image(b"definitely not a picture".to_vec()),
            )),
        })
        .await
        .unwrap_err();
    assert_eq!(status.code(), tonic::Code::InvalidArgument);
    assert_eq!(
        status.message(),
        "keyframe.image.data: neither JPEG nor PNG; set encoding for raw pixels"
    );
}

#[tokio::test(flavor = "multi_thread")]
async fn a_real_shop_sign_is_read() {
    let Some(datasets) = datasets() else { return };
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start_with_models(dir.path());
    let photo = std::fs::read(datasets.join("town-dev/loop/sequence/000156.jpg")).unwrap();
    let reply = server
        .client()
        .await
        .insert(proto::InsertRequest {
            keyframe: Some(keyframe("town", 156, image(photo))),
        })
        .await
        .unwrap()
        .into_inner();
    let read = texts(&reply.features.unwrap()).join(" | ");
    // The sign says "QUARRY LAUNDRY 49", in perspective on a facade.
    assert!(read.to_uppercase().contains("LAUNDRY"), "read: {read}");
}

/// Ground truth of a `loop` data set: query index → earlier matching indices.
fn loop_ground_truth(dir: &Path) -> (BTreeMap<u64, Vec<u64>>, u64) {
    let text = std::fs::read_to_string(dir.join("ground_truth.json")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    let matches = json["matches"]
        .as_object()
        .unwrap()
        .iter()
        .map(|(q, refs)| {
            let refs = refs
                .as_array()
                .unwrap()
                .iter()
                .map(|r| r.as_u64().unwrap())
                .collect();
            (q.parse().unwrap(), refs)
        })
        .collect();
    (matches, json["min_frame_gap"].as_u64().unwrap_or(100))
}

/// Recall@1, Recall@5 and MRR (over the top 5) of ranked answers.
fn recall(answers: &[(Vec<u64>, Vec<u64>)]) -> (f64, f64, f64) {
    let n = answers.len() as f64;
    let rank =
        |(ranked, truth): &(Vec<u64>, Vec<u64>)| ranked.iter().position(|c| truth.contains(c));
    let r1 = answers.iter().filter(|a| rank(a) == Some(0)).count() as f64 / n;
    let r5 = answers
        .iter()
        .filter(|a| rank(a).is_some_and(|r| r < 5))
        .count() as f64
        / n;
    let mrr = answers
        .iter()
        .map(|a| rank(a).map_or(0.0, |r| 1.0 / (r + 1) as f64))
        .sum::<f64>()
        / n;
    (r1, r5, mrr)
}

#[tokio::test(flavor = "multi_thread")]
async fn rtabmap_loop_revisits_are_recognised_from_images() {
    let Some(datasets) = datasets() else { return };
    let set = datasets.join("rtabmap-loop");
    let (truth, min_gap) = loop_ground_truth(&set);
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start_with_models(dir.path());
    let mut client = server.client().await;

    // The SLAM way: each frame is inserted as a keyframe, then asked about,
    // so only earlier frames can answer.
    let mut full = Vec::new();
    let mut scal = Vec::new();
    for index in 0..84u64 {
        let photo = std::fs::read(set.join(format!("sequence/{index:06}.jpg"))).unwrap();
        client
            .insert(proto::InsertRequest {
                keyframe: Some(keyframe("rtabmap", index, image(photo))),
            })
            .await
            .unwrap();
        let Some(refs) = truth.get(&index) else {
            continue;
        };
        for (layers, answers) in [
            (proto::Layers::Full, &mut full),
            (proto::Layers::Scal, &mut scal),
        ] {
            let reply = client
                .query(proto::QueryRequest {
                    robot_id: "rtabmap".into(),
                    session_id: "s".into(),
                    keyframe_id: Some(index),
                    min_frame_gap: Some(min_gap),
                    threshold: Some(0.0),
                    layers: layers as i32,
                    ..Default::default()
                })
                .await
                .unwrap()
                .into_inner();
            let ranked = reply.candidates.iter().map(|c| c.keyframe_id).collect();
            answers.push((ranked, refs.clone()));
        }
    }
    let (r1, r5, mrr) = recall(&full);
    let (s1, s5, smrr) = recall(&scal);
    eprintln!(
        "rtabmap-loop over gRPC, {} queries, min gap {min_gap}:",
        full.len()
    );
    eprintln!("  full  R@1 {r1:.3}  R@5 {r5:.3}  MRR {mrr:.3}");
    eprintln!("  SCAL  R@1 {s1:.3}  R@5 {s5:.3}  MRR {smrr:.3}");
    assert_eq!(full.len(), truth.len());
    // The GeM descriptor of these models alone reaches R@1 0.955 here
    // (measured in Python); the service must not lose that.
    assert!(s1 >= 0.95, "SCAL R@1 {s1:.3}");
    assert!(r1 >= 0.95, "full R@1 {r1:.3}");
}

/// The OCR's first look (`perception.ocr.preview_long_side`): a board
/// with text is still read, and an image without text skips the full
/// detection and recognition.
#[tokio::test]
async fn the_first_look_skips_images_without_text_and_reads_the_rest() {
    use humem_perception::batcher::BatchConfig;
    use humem_perception::config::{OcrConfig, PerceptionConfig};
    use humem_perception::ocr::{ctc::Dictionary, Ocr, OcrModels, OcrTimes};
    use humem_perception::runtime;
    use std::sync::Arc;

    let mut perception = PerceptionConfig {
        models_dir: crate::harness::models_dir(),
        ..PerceptionConfig::default()
    };
    if !perception.models_dir.join("lib").is_dir() {
        eprintln!("skipped: models not installed (scripts/setup-models.sh)");
        return;
    }
    let config = OcrConfig {
        preview_long_side: 256,
        ..OcrConfig::default()
    };
    perception.ocr = Some(config.clone());
    let env = runtime::environment(&perception.onnxruntime_library()).unwrap();
    let options = perception.session_options();
    let sessions = vec![(
        runtime::session(&env, &perception.resolve(&config.detector), options).unwrap(),
        runtime::session(&env, &perception.resolve(&config.recognizer), options).unwrap(),
    )];
    let dictionary = Arc::new(Dictionary::load(&perception.resolve(&config.dictionary)).unwrap());
    let models = OcrModels::new(sessions, &config, dictionary).unwrap();
    let ocr = Ocr::new(
        models,
        &config,
        BatchConfig {
            max_batch: 1,
            max_wait: std::time::Duration::ZERO,
            queue: 8,
        },
        &humem_core::observe::unobserved(),
    );
    let decode = |png: Vec<u8>| Arc::new(image::load_from_memory(&png).unwrap().to_rgb8());

    let mut times = OcrTimes::default();
    let lines = ocr
        .read(
            decode(rendered_text(&["EXIT 42", "MAIN ST"])),
            None,
            &mut times,
        )
        .await
        .unwrap();
    assert!(!times.skipped, "text found at first look");
    let read: Vec<String> = lines.iter().map(|l| l.text.to_uppercase()).collect();
    assert!(
        read.iter().any(|t| t.contains("EXIT")) && read.iter().any(|t| t.contains("MAIN")),
        "{read:?}"
    );

    let mut times = OcrTimes::default();
    let lines = ocr
        .read(decode(rendered_text(&[])), None, &mut times)
        .await
        .unwrap();
    assert!(times.skipped && lines.is_empty(), "{lines:?}");
}

/// `[perception.reuse]` through the service: a keyframe that shows what its
/// session's last read keyframe showed gets that read's text without OCR
/// running (no `ocr_det` stage, counted by the metric); another robot's
/// session, a different view, the `max_carried` bound and a reset of the
/// session each make it read afresh.
#[tokio::test(flavor = "multi_thread")]
async fn a_similar_keyframe_of_the_same_session_carries_the_text_over() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start_with(
        dir.path(),
        &[
            "HUMEM_PERCEPTION__ENABLED=true",
            "HUMEM_PERCEPTION__REUSE__MAX_CARRIED=1",
            "HUMEM_PERCEPTION__REUSE__MIN_SIMILARITY=0.9",
        ],
    );
    let client = server.client().await;
    let insert = |robot: &'static str, id: u64, png: Vec<u8>| {
        let mut client = client.clone();
        async move {
            let reply = client
                .insert(proto::InsertRequest {
                    keyframe: Some(keyframe(robot, id, image(png))),
                })
                .await
                .unwrap()
                .into_inner();
            let stages: Vec<String> = reply.timings.iter().map(|t| t.stage.clone()).collect();
            (
                texts(&reply.features.unwrap()),
                stages.contains(&"ocr_det".into()),
            )
        }
    };
    let carried = |server: &Server| {
        Server::sample(&server.scrape(), "humem_perception_objects_carried_total").unwrap()
    };
    let exit = rendered_text(&["EXIT 42", "MAIN ST"]);
    let exit_again = {
        // The same board, a little brighter: the thumbnail is patch-normalised.
        let mut img = image::load_from_memory(&exit).unwrap().to_rgb8();
        img.pixels_mut()
            .for_each(|p| p.0 = p.0.map(|v| v.saturating_add(10)));
        let mut png = Vec::new();
        img.write_to(&mut Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        png
    };
    let cedar = rendered_text(&["CEDAR AVE"]);

    let (first, read) = insert("r", 1, exit.clone()).await;
    assert!(read, "nothing to carry yet");
    assert!(first.iter().any(|t| t.contains("EXIT")), "{first:?}");
    assert_eq!(carried(&server), 0.0);

    let (second, read) = insert("r", 2, exit_again.clone()).await;
    assert!(!read, "carried, not read");
    assert_eq!(second, first);
    assert_eq!(carried(&server), 1.0);

    // max_carried = 1: the next similar keyframe is read again.
    let (_, read) = insert("r", 3, exit.clone()).await;
    assert!(read, "at most one keyframe in a row is carried");
    // Another robot's session has no read to carry.
    let (_, read) = insert("other", 1, exit_again).await;
    assert!(read, "sessions do not share reads");
    // A different view is read.
    let (third, read) = insert("r", 4, cedar).await;
    assert!(read);
    assert!(third.iter().any(|t| t.contains("CEDAR")), "{third:?}");
    assert_eq!(carried(&server), 1.0);

    // Once carried again, then the session is reset: its next keyframe is
    // read afresh, not served from a read of erased keyframes.
    let (_, read) = insert("r", 5, rendered_text(&["CEDAR AVE"])).await;
    assert!(!read);
    assert_eq!(carried(&server), 2.0);
    let (_, read) = insert("r", 6, exit.clone()).await;
    assert!(read);
    client
        .clone()
        .reset_session(proto::ResetSessionRequest {
            robot_id: "r".into(),
            session_id: "s".into(),
        })
        .await
        .unwrap();
    let (_, read) = insert("r", 7, exit).await;
    assert!(read, "the reset session's read was forgotten");
    assert_eq!(carried(&server), 2.0);
}
