//! `humem eval` on a real data set: the JSON has every field, in range.

use std::process::Command;

use crate::harness::{datasets, models_dir};

#[test]
fn eval_on_gardens_daynight_reports_every_number() {
    let Some(datasets) = datasets() else { return };
    let out_dir = tempfile::tempdir().unwrap();
    let json = out_dir.path().join("eval.json");
    let report = out_dir.path().join("report");
    let output = Command::new(env!("CARGO_BIN_EXE_humem"))
        .args(["eval", "--ablation", "--degrade", "B15/D80", "--dataset"])
        .arg(datasets.join("gardens-daynight"))
        .arg("--json")
        .arg(&json)
        .arg("--report")
        .arg(&report)
        .env("HUMEM_PERCEPTION__MODELS_DIR", models_dir())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(stdout.contains("| clean | Full |"), "{stdout}");

    let value: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(value["dataset"], "gardens-daynight");
    assert_eq!(value["kind"], "pairs");
    assert_eq!(value["queries"], 10);
    let conditions = value["conditions"].as_array().unwrap();
    assert_eq!(conditions.len(), 2);
    assert_eq!(conditions[1]["condition"], "B15/D80");
    for condition in conditions {
        let results = condition["results"].as_array().unwrap();
        let methods: Vec<&str> = results
            .iter()
            .map(|r| r["method"].as_str().unwrap())
            .collect();
        assert_eq!(methods, ["SCAL", "SCAL+OSRL", "SCAL+OGTL", "Full"]);
        for r in results {
            let get = |k: &str| {
                r[k].as_f64()
                    .unwrap_or_else(|| panic!("{k} missing in {r}"))
            };
            let (r1, r5, mrr) = (get("recall_at_1"), get("recall_at_5"), get("mrr"));
            assert!((0.0..=1.0).contains(&r1) && r1 <= r5 && r5 <= 1.0, "{r}");
            assert!(mrr >= r1 && mrr <= 1.0, "{r}");
            let latency = &r["latency"];
            let ms = |k: &str| latency[k].as_f64().unwrap();
            assert!(
                ms("mean_ms") > 0.0 && ms("median_ms") > 0.0 && ms("p95_ms") >= ms("median_ms")
            );
            assert!(r["stages_ms"]["descriptor"].as_f64().unwrap() > 0.0, "{r}");
        }
    }
    let summary = std::fs::read_to_string(report.join("summary.md")).unwrap();
    assert!(summary.contains("| B15/D80 | SCAL |"), "{summary}");
}
