//! `humem eval` on a real data set: the JSON has every field, in range, the
//! report has its charts, and measuring through a running service gives the
//! same rankings as the in-process run.

use std::path::Path;
use std::process::Command;

use crate::harness::{datasets, models_dir, output_of, Server};

/// Runs `humem eval` on gardens-daynight with the ablation and B15/D80 into
/// `out`; returns the JSON and the table printed.
fn eval_gardens(datasets: &Path, out: &Path, extra: &[&str]) -> (serde_json::Value, String) {
    let json = out.join("eval.json");
    let stdout = output_of(
        Command::new(env!("CARGO_BIN_EXE_humem"))
            .args(["eval", "--ablation", "--degrade", "B15/D80", "--dataset"])
            .arg(datasets.join("gardens-daynight"))
            .arg("--json")
            .arg(&json)
            .arg("--report")
            .arg(out.join("report"))
            .args(extra)
            .env("HUMEM_PERCEPTION__MODELS_DIR", models_dir()),
    );
    let value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    (value, stdout)
}

/// (condition, method, R@1, R@5, MRR) of every row.
/// Recall and the precision figures of every method and condition.
fn recalls(value: &serde_json::Value) -> Vec<(String, String, Vec<String>)> {
    let mut rows = Vec::new();
    for c in value["conditions"].as_array().unwrap() {
        for r in c["results"].as_array().unwrap() {
            let p = &r["precision"];
            let figures = [
                &r["recall_at_1"],
                &r["recall_at_5"],
                &r["mrr"],
                &p["answered"],
                &p["false_top"],
                &p["candidate_precision"],
                &p["recall_at_full_precision"],
            ];
            rows.push((
                c["condition"].as_str().unwrap().to_string(),
                r["method"].as_str().unwrap().to_string(),
                // Scores cross the wire as f32: compare to 4 decimals.
                figures
                    .iter()
                    .map(|v| format!("{:.4}", v.as_f64().unwrap()))
                    .collect(),
            ));
        }
    }
    rows
}

#[test]
fn eval_on_gardens_daynight_reports_every_number() {
    let Some(datasets) = datasets() else { return };
    let out_dir = tempfile::tempdir().unwrap();
    let report = out_dir.path().join("report");
    let (value, stdout) = eval_gardens(&datasets, out_dir.path(), &[]);
    assert!(stdout.contains("| clean | Full |"), "{stdout}");

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
        assert_eq!(
            methods,
            [
                "SCAL",
                "SCAL+OSRL",
                "SCAL+OGTL",
                "Full (no C)",
                "Full",
                "ORB-BoW"
            ]
        );
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
            let first_stage = if r["method"] == "ORB-BoW" {
                "orb"
            } else {
                "descriptor"
            };
            assert!(r["stages_ms"][first_stage].as_f64().unwrap() > 0.0, "{r}");
            // Precision at the operating point: every query has a match here.
            let p = &r["precision"];
            let count = |k: &str| {
                p[k].as_u64()
                    .unwrap_or_else(|| panic!("{k} missing in {p}"))
            };
            assert_eq!((count("queries"), count("with_match")), (10, 10), "{p}");
            assert!(count("answered") <= 10 && count("false_top") <= count("answered"));
            assert_eq!(count("false_no_match"), 0);
            for k in [
                "candidate_precision",
                "recall_at_threshold",
                "recall_at_full_precision",
            ] {
                assert!((0.0..=1.0).contains(&p[k].as_f64().unwrap()), "{k}: {p}");
            }
            assert!(p["recall_at_full_precision"].as_f64() <= Some(r1), "{p}");
            assert_eq!(p["tops"].as_array().unwrap().len(), 10, "{p}");
            assert!(!p["curve"].as_array().unwrap().is_empty(), "{p}");
        }
    }
    assert_eq!(value["calibration"], "null");
    assert!(value["threshold"]
        .as_f64()
        .is_some_and(|t| t > 0.0 && t < 1.0));
    assert!(stdout.contains("recall at 100 % precision"), "{stdout}");
    let summary = std::fs::read_to_string(report.join("summary.md")).unwrap();
    assert!(summary.contains("| B15/D80 | SCAL |"), "{summary}");
    for chart in [
        "accuracy_latency",
        "recall_per_condition",
        "precision_recall",
    ] {
        assert!(summary.contains(&format!("({chart}.png)")), "{summary}");
        let png = image::open(report.join(format!("{chart}.png"))).unwrap();
        assert_eq!((png.width(), png.height()), (800, 520));
        assert!(report.join(format!("{chart}.svg")).is_file());
    }
}

#[test]
fn eval_through_the_service_ranks_as_the_library_does() {
    let Some(datasets) = datasets() else { return };
    let local_dir = tempfile::tempdir().unwrap();
    let (local, _) = eval_gardens(&datasets, local_dir.path(), &[]);

    let data = tempfile::tempdir().unwrap();
    let server = Server::start_with_models(data.path());
    let remote_dir = tempfile::tempdir().unwrap();
    let (remote, stdout) = eval_gardens(
        &datasets,
        remote_dir.path(),
        &["--server", server.url.as_str()],
    );
    // Same models, same features, same ranking code: the same numbers.
    assert_eq!(recalls(&remote), recalls(&local), "{stdout}");
    assert!(
        remote["conditions"][0]["results"][0]["latency"]["median_ms"]
            .as_f64()
            .is_some_and(|ms| ms > 0.0)
    );
    // The run removed what it stored.
    let stats = Command::new(env!("CARGO_BIN_EXE_humem"))
        .args(["stats", "--server", server.url.as_str()])
        .output()
        .unwrap();
    let stats: serde_json::Value = serde_json::from_slice(&stats.stdout).unwrap();
    // proto3 JSON leaves out a zero count.
    assert_eq!(stats.get("keyframes"), None, "{stats}");
}
