//! `humem text-recall` on real rendered frames: a few frames of
//! `town-dev/loop` that drive past "COPPER GROCERY", read by the real OCR.

use std::process::Command;

use crate::harness::{datasets, models_dir, output_of};

#[test]
fn text_recall_reads_a_shop_sign_on_the_town_loop() {
    let Some(datasets) = datasets() else { return };
    let out = tempfile::tempdir().unwrap();
    let json = out.path().join("text.json");
    // Frames 60..70: the grocery's sign comes into view at 64 and is read
    // whole from 65 on; the frames before have no distinctive sign.
    let stdout = output_of(
        Command::new(env!("CARGO_BIN_EXE_humem"))
            .args(["text-recall", "--frames", "60..70", "--dataset"])
            .arg(datasets.join("town-dev/loop"))
            .arg("--json")
            .arg(&json)
            .env("HUMEM_PERCEPTION__MODELS_DIR", models_dir()),
    );
    assert!(stdout.contains("recall"), "{stdout}");
    let value: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let total = &value["total"];
    assert_eq!(total["frames"], 10, "{total}");
    let with_sign = total["frames_with_sign"].as_u64().unwrap();
    let read = total["frames_read"].as_u64().unwrap();
    assert!((4..=6).contains(&with_sign), "{total}");
    assert!(read >= 2 && read <= with_sign, "{total}");
    assert!(total["ocr_ms"].as_f64().unwrap() > 0.0, "{total}");
    assert_eq!(value["ocr"]["detector_long_side"], 512);
}
