//! What `humem eval` reports: its numbers per method and condition
//! ([`EvalReport`], the JSON of `--json` and `results.json`), and the tables
//! made of them (the terminal's and `summary.md`'s).
//!
//! The report is plain data, apart from the run that fills it, so that the
//! charts ([`crate::plots`]) and the tables read it without taking in the
//! run; the tables are text only (writing files is the run's).

use std::collections::BTreeMap;

use serde::Serialize;

use crate::args::ObjectSource;
use crate::metrics::{LatencyStats, Retrieval};
use crate::precision::Precision;
use crate::replay_rows::{self, ReplayRow};

/// One method's numbers under one condition.
#[derive(Debug, Clone, Serialize)]
pub struct MethodResult {
    /// The method's name: a layer configuration (`Full`, `SCAL`, …) or
    /// `ORB-BoW`.
    pub method: String,
    /// Recall@1, Recall@5 and MRR over the queries with a match.
    #[serde(flatten)]
    pub retrieval: Retrieval,
    /// Latency over the timed queries.
    pub latency: LatencyStats,
    /// Mean milliseconds per stage over the timed queries.
    pub stages_ms: BTreeMap<String, f64>,
    /// At the operating point, over the queries with and without a match.
    pub precision: Precision,
}

/// All methods under one condition.
#[derive(Debug, Clone, Serialize)]
pub struct ConditionResult {
    /// `clean`, or the degradation applied to the queries (e.g. `B15`).
    pub condition: String,
    /// One result per method, in the table's order.
    pub results: Vec<MethodResult>,
}

/// The whole run.
#[derive(Debug, Clone, Serialize)]
pub struct EvalReport {
    /// The data set's folder name.
    pub dataset: String,
    /// `pairs` or `loop`.
    pub kind: String,
    /// Where the ground truth came from (`ground_truth.json` or the poses).
    pub truth: String,
    /// Reference images in the database.
    pub references: usize,
    /// Queries with a valid match scored for recall.
    pub queries: usize,
    /// `loop` only: the frame gap candidates had to keep.
    pub min_frame_gap: Option<usize>,
    /// Queries without a valid match scored for precision.
    pub queries_without_match: usize,
    /// The operating point: threshold on the score (calibrated unless
    /// `vpr.calibration = "raw"`) and most candidates returned.
    pub threshold: f32,
    /// The score calibration, `null` or `raw`.
    pub calibration: String,
    /// Most candidates returned per query at the operating point.
    pub max_candidates: usize,
    /// Where the objects came from: `models` or `annotations`.
    pub objects: ObjectSource,
    /// Whether every image was sent as grey pixels.
    pub grey: bool,
    /// One entry per condition, `clean` first.
    pub conditions: Vec<ConditionResult>,
    /// `--replay-verdicts`: the stream without and with verdicts.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub verdict_replay: Option<Vec<ReplayRow>>,
}

fn rows(report: &EvalReport) -> Vec<String> {
    let mut rows = Vec::new();
    for c in &report.conditions {
        for r in &c.results {
            rows.push(format!(
                "| {} | {} | {:.3} | {:.3} | {:.3} | {:.1} | {:.1} | {:.1} |",
                c.condition,
                r.method,
                r.retrieval.recall_at_1,
                r.retrieval.recall_at_5,
                r.retrieval.mrr,
                r.latency.mean_ms,
                r.latency.median_ms,
                r.latency.p95_ms
            ));
        }
    }
    rows
}

fn precision_rows(report: &EvalReport) -> Vec<String> {
    let mut rows = Vec::new();
    for c in &report.conditions {
        for r in &c.results {
            let p = &r.precision;
            rows.push(format!(
                "| {} | {} | {} | {} | {} | {} | {} ({:.1} %) | {:.3} | {:.3} | {:.3} |",
                c.condition,
                r.method,
                p.queries,
                p.queries - p.with_match,
                p.answered,
                p.false_top,
                p.false_no_match,
                p.false_alarm_rate * 100.0,
                p.candidate_precision,
                p.recall_at_threshold,
                p.recall_at_full_precision,
            ));
        }
    }
    rows
}

const HEADER: &str = "| condition | method | R@1 | R@5 | MRR | mean ms | median ms | p95 ms |\n| --- | --- | --- | --- | --- | --- | --- | --- |";

const PRECISION_HEADER: &str = "| condition | method | queries | without match | answered | false top-1 | false alarms (no match) | candidate precision | recall at threshold | recall at 100 % precision |\n| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |";

fn operating_point(report: &EvalReport) -> String {
    format!(
        "operating point: {} calibration, threshold {:.2}, at most {} candidates; {} queries without a match scored for precision (ORB-BoW answers every query)",
        report.calibration, report.threshold, report.max_candidates, report.queries_without_match
    )
}

pub(crate) fn print_table(report: &EvalReport) {
    println!(
        "{} ({}, {} references, {} queries, ground truth from {})",
        report.dataset, report.kind, report.references, report.queries, report.truth
    );
    println!("{HEADER}");
    for row in rows(report) {
        println!("{row}");
    }
    println!("\n{}", operating_point(report));
    println!("{PRECISION_HEADER}");
    for row in precision_rows(report) {
        println!("{row}");
    }
    if let Some(rows) = &report.verdict_replay {
        println!("\n{}", replay_heading(report));
        print!("{}", replay_rows::table(rows));
    }
}

fn replay_heading(report: &EvalReport) -> String {
    format!(
        "Streamed as the ORB-SLAM3 plugin streams, the ground truth as geometric verification (Full, at the {}):",
        operating_point(report)
    )
}

pub(crate) fn markdown(report: &EvalReport) -> String {
    let mut md = format!(
        "# HuMem evaluation: {}\n\n{} data set, {} references, {} queries (evenly spaced among the eligible ones), ground truth from {}{}.\nLatency: 30 evenly spaced queries after 10 warm-ups, perception without decoding plus ranking.\n\n{HEADER}\n",
        report.dataset,
        report.kind,
        report.references,
        report.queries,
        report.truth,
        report
            .min_frame_gap
            .map(|g| format!(", minimum frame gap {g}"))
            .unwrap_or_default()
    );
    for row in rows(report) {
        md.push_str(&row);
        md.push('\n');
    }
    md.push_str(&format!(
        "\nPrecision at the {}.\n\n{PRECISION_HEADER}\n",
        operating_point(report)
    ));
    for row in precision_rows(report) {
        md.push_str(&row);
        md.push('\n');
    }
    if let Some(rows) = &report.verdict_replay {
        md.push_str(&format!(
            "\n{}\n\n{}",
            replay_heading(report),
            replay_rows::table(rows)
        ));
    }
    md.push_str(
        "\n![Recall@1 against median latency](accuracy_latency.png)\n\n![Recall per condition](recall_per_condition.png)\n\n![Precision against recall](precision_recall.png)\n",
    );
    md
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::precision::{OperatingPoint, ScoredQuery};

    /// Precision over one answered query with a valid top and one answered
    /// without a match (a false alarm), at threshold 0.4: the charts' tests
    /// use it too.
    pub(crate) fn one_hit_one_false_alarm() -> Precision {
        crate::precision::precision(
            &[
                ScoredQuery {
                    ranked: vec![(0.9, true)],
                    has_match: true,
                    threshold: None,
                },
                ScoredQuery {
                    ranked: vec![(0.5, false)],
                    has_match: false,
                    threshold: None,
                },
            ],
            OperatingPoint {
                threshold: 0.4,
                max_candidates: 5,
            },
        )
    }

    fn result(method: &str) -> MethodResult {
        MethodResult {
            method: method.into(),
            retrieval: Retrieval {
                queries: 1,
                recall_at_1: 0.6,
                recall_at_5: 0.8,
                mrr: 0.65,
            },
            latency: LatencyStats {
                samples: 30,
                mean_ms: 40.0,
                median_ms: 38.0,
                p95_ms: 61.04,
            },
            stages_ms: BTreeMap::new(),
            precision: one_hit_one_false_alarm(),
        }
    }

    fn report() -> EvalReport {
        EvalReport {
            dataset: "toy".into(),
            kind: "loop".into(),
            truth: "ground_truth.json".into(),
            references: 10,
            queries: 1,
            min_frame_gap: Some(50),
            queries_without_match: 1,
            threshold: 0.4,
            calibration: "null".into(),
            max_candidates: 5,
            objects: ObjectSource::Models,
            grey: false,
            verdict_replay: None,
            conditions: vec![
                ConditionResult {
                    condition: "clean".into(),
                    results: vec![result("Full")],
                },
                ConditionResult {
                    condition: "B15".into(),
                    results: vec![result("ORB-BoW")],
                },
            ],
        }
    }

    #[test]
    fn a_row_per_method_and_condition_in_order() {
        assert_eq!(
            rows(&report()),
            [
                "| clean | Full | 0.600 | 0.800 | 0.650 | 40.0 | 38.0 | 61.0 |",
                "| B15 | ORB-BoW | 0.600 | 0.800 | 0.650 | 40.0 | 38.0 | 61.0 |",
            ]
        );
        assert_eq!(
            precision_rows(&report())[0],
            "| clean | Full | 2 | 1 | 2 | 1 | 1 (100.0 %) | 0.500 | 1.000 | 1.000 |"
        );
        // As many columns as the headers have.
        let columns = |line: &str| line.matches('|').count();
        assert_eq!(
            columns(&rows(&report())[0]),
            columns(HEADER.lines().next().unwrap())
        );
        assert_eq!(
            columns(&precision_rows(&report())[1]),
            columns(PRECISION_HEADER.lines().next().unwrap())
        );
    }

    #[test]
    fn the_operating_point_names_threshold_and_candidates() {
        assert_eq!(
            operating_point(&report()),
            "operating point: null calibration, threshold 0.40, at most 5 candidates; 1 queries without a match scored for precision (ORB-BoW answers every query)"
        );
    }

    #[test]
    fn the_summary_holds_both_tables_and_the_charts() {
        let md = markdown(&report());
        assert!(
            md.starts_with("# HuMem evaluation: toy\n\nloop data set, 10 references, 1 queries")
        );
        assert!(md.contains("ground truth from ground_truth.json, minimum frame gap 50.\n"));
        for row in rows(&report()).iter().chain(&precision_rows(&report())) {
            assert!(md.contains(&format!("{row}\n")), "{row} missing from\n{md}");
        }
        assert!(md.contains(HEADER) && md.contains(PRECISION_HEADER));
        // No replay: no replay heading.
        assert!(!md.contains("Streamed as the ORB-SLAM3 plugin streams"));
        assert!(md.ends_with("![Precision against recall](precision_recall.png)\n"));
    }
}
