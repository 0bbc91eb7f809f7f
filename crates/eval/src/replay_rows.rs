//! The rows of `humem eval --replay-verdicts` and their tables: what one
//! pass over one visit class found (false alarms, recall, candidate
//! precision, the verdicts sent) and the measures of its candidates (the
//! drift envelope's `r`, the spread of the top matches' positions), true
//! and false ones apart.
//!
//! A leaf below [`verdict_replay`](super::verdict_replay), which fills the
//! rows, so that the report prints them without the replay's machinery.

use serde::Serialize;

/// One row of the replay table.
#[derive(Debug, Clone, Serialize)]
pub struct ReplayRow {
    /// `without verdicts` or `with verdicts`.
    pub pass: String,
    /// `1`, `2`, … (see the module doc) or `all`.
    pub visit: String,
    /// Queries in the group.
    pub queries: usize,
    /// Of those, queries with a true place.
    pub with_match: usize,
    /// Queries without a true place that were answered (any candidate above
    /// the threshold), over those queries.
    pub false_alarm_rate: f64,
    /// Answered false alarms.
    pub false_alarms: usize,
    /// Recall@1 over the queries with a true place, whatever the threshold.
    pub recall_at_1: f64,
    /// Queries with a true place whose top candidate is true and above the
    /// threshold, over those queries.
    pub recall_at_threshold: f64,
    /// True candidates over candidates sent to verification.
    pub candidate_precision: f64,
    /// Candidates sent to verification (= verdicts reported, with verdicts).
    pub candidates: usize,
    /// Verdicts that were rejections of true places (geometry's misses).
    pub wrong_rejections: usize,
    /// The false alarms themselves, in stream order: which queries without
    /// a true place were answered, and by what.
    pub false_alarm_list: Vec<FalseAlarm>,
    /// `r` of the candidates sent of the query's own map (the drift
    /// envelope's distance over the path along the map's track, poses as
    /// stored when the query was asked), true and false ones apart: what
    /// the envelope has to separate.
    pub drift_ratios: TrueAndFalse,
    /// The spread of the stored positions of the top [`SPREAD_OF_TOP`]
    /// candidates (root mean square distance from their centroid, map
    /// units) of every query whose top candidate passed the threshold,
    /// apart by whether that top candidate is true: the pose spread of the
    /// top matches as evidence of uncertainty (SUE, Zaffar et al.).
    pub top_spread: TrueAndFalse,
    /// Every query asked and its whole ranking, by query frame (the
    /// `all` row only; empty in the others): what `--json` gives for
    /// judging another rule on the same answers without a second run.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub answers: Vec<ReplayAnswer>,
}

/// One query of a replay and its ranking.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReplayAnswer {
    /// The query's frame index.
    pub query: usize,
    /// Which visit of its place (1: no earlier true place where it looked).
    pub visit: usize,
    /// The store's threshold when it was asked.
    pub threshold: f32,
    /// The candidates, best first: frame index, score, the drift
    /// envelope's `r` (a candidate of the query's own map) and whether
    /// the ground truth calls it a true place.
    pub ranked: Vec<(usize, f32, Option<f64>, bool)>,
}

/// Candidates whose positions [`ReplayRow::top_spread`] spreads.
pub const SPREAD_OF_TOP: usize = 5;

/// A measure of candidates, true and false ones apart.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct TrueAndFalse {
    /// Of the true candidates, ascending.
    pub true_candidates: Vec<f64>,
    /// Of the false candidates, ascending.
    pub false_candidates: Vec<f64>,
}

impl TrueAndFalse {
    pub(crate) fn push(&mut self, truth: bool, value: f64) {
        if truth {
            self.true_candidates.push(value);
        } else {
            self.false_candidates.push(value);
        }
    }

    pub(crate) fn extend(&mut self, other: &TrueAndFalse) {
        self.true_candidates.extend(&other.true_candidates);
        self.false_candidates.extend(&other.false_candidates);
    }

    pub(crate) fn sorted(&self) -> TrueAndFalse {
        let mut sorted = self.clone();
        sorted.true_candidates.sort_by(f64::total_cmp);
        sorted.false_candidates.sort_by(f64::total_cmp);
        sorted
    }

    pub(crate) fn is_empty(&self) -> bool {
        self.true_candidates.is_empty() && self.false_candidates.is_empty()
    }

    /// `min / median / 95th percentile / max` of `values` (ascending).
    fn summary(values: &[f64]) -> String {
        if values.is_empty() {
            return "–".into();
        }
        let at = |q: f64| values[((values.len() - 1) as f64 * q).round() as usize];
        format!(
            "{:.3} / {:.3} / {:.3} / {:.3}",
            values[0],
            at(0.5),
            at(0.95),
            values[values.len() - 1]
        )
    }
}

/// One query without a true place that was answered: what to look at
/// when a replay's false alarms are too many (a look-alike place, a near
/// miss just outside the truth's radius, a view across a junction).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FalseAlarm {
    /// The query's frame index.
    pub query: usize,
    /// Its top candidate's frame index (a reference's, in a pairs set).
    pub candidate: u64,
    /// The candidate's score.
    pub score: f32,
    /// The threshold it was above.
    pub threshold: f32,
    /// Distance between the two stored positions: metres where the data
    /// set has poses, the stand-in line's otherwise.
    pub distance: f64,
}

/// The rows as a Markdown table.
pub fn table(rows: &[ReplayRow]) -> String {
    let mut out = String::from(
        "| pass | visit | queries | with a true place | false alarms | R@1 | recall at threshold | candidate precision | candidates (verdicts) | true places rejected |\n| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n",
    );
    for r in rows {
        out.push_str(&format!(
            "| {} | {} | {} | {} | {} ({:.1} %) | {:.3} | {:.3} | {:.3} | {} | {} |\n",
            r.pass,
            r.visit,
            r.queries,
            r.with_match,
            r.false_alarms,
            100.0 * r.false_alarm_rate,
            r.recall_at_1,
            r.recall_at_threshold,
            r.candidate_precision,
            r.candidates,
            r.wrong_rejections
        ));
    }
    let listed: Vec<String> = rows
        .iter()
        .filter(|r| r.visit == "all" && !r.false_alarm_list.is_empty())
        .map(|r| format!("- {}: {}\n", r.pass, false_alarm_line(&r.false_alarm_list)))
        .collect();
    if !listed.is_empty() {
        out.push_str(
            "\nFalse alarms (query frame → its top candidate: score, distance between them):\n",
        );
        out.extend(listed);
    }
    out.push_str(&apart(
        rows,
        "Distance over path, r, of the candidates sent",
        |r| &r.drift_ratios,
    ));
    out.push_str(&apart(
        rows,
        "Spread of the top 5 candidates' positions (map units) of the queries answered, by their top candidate",
        |r| &r.top_spread,
    ));
    out
}

/// A table of one measure of the `all` rows, true and false candidates
/// apart (min / median / 95th percentile / max); empty where no row has
/// one.
fn apart(rows: &[ReplayRow], title: &str, measure: impl Fn(&ReplayRow) -> &TrueAndFalse) -> String {
    let measured: Vec<&ReplayRow> = rows
        .iter()
        .filter(|r| r.visit == "all" && !measure(r).is_empty())
        .collect();
    if measured.is_empty() {
        return String::new();
    }
    let mut out = format!("\n{title} (min / median / 95th percentile / max):\n\n| pass | true | of them | false | of them |\n| --- | --- | --- | --- | --- |\n");
    for r in measured {
        let m = measure(r);
        out.push_str(&format!(
            "| {} | {} | {} | {} | {} |\n",
            r.pass,
            m.true_candidates.len(),
            TrueAndFalse::summary(&m.true_candidates),
            m.false_candidates.len(),
            TrueAndFalse::summary(&m.false_candidates)
        ));
    }
    out
}

/// `191 → 40: 0.371, 47.7 m; …`.
fn false_alarm_line(alarms: &[FalseAlarm]) -> String {
    alarms
        .iter()
        .map(|f| {
            format!(
                "{} → {}: {:.3}, {:.1} m",
                f.query, f.candidate, f.score, f.distance
            )
        })
        .collect::<Vec<_>>()
        .join("; ")
}
