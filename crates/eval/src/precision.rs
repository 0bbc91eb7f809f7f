//! Precision at the operating point: what a SLAM system would be sent.
//!
//! Recall@K says whether the right place is ranked high; a loop closer also
//! needs to know what happens at the threshold it runs with: how many
//! queries get an answer at all, how many of those answers are wrong (false
//! alarms, the closures that bend a map), how many of the returned
//! candidates are true places, and how much recall is left when no false
//! answer may pass (recall at 100 % precision, the standard loop-closure
//! figure). Queries without any valid match count here, since that is where
//! false alarms come from.
//!
//! Like [`super::metrics`], everything is a pure function of plain values
//! (scores, valid flags), so each figure is pinned by hand-computed tests.

use serde::Serialize;

/// What one query was answered with, as seen at the operating point.
#[derive(Debug, Clone, PartialEq)]
pub struct ScoredQuery {
    /// Candidates in ranked order: `(score, is a valid match)`.
    pub ranked: Vec<(f32, bool)>,
    /// Whether any valid match exists for this query (ranked or not).
    pub has_match: bool,
    /// The threshold this query was answered at, where it was not the
    /// operating point's (a store's adapted threshold when it was asked,
    /// `vpr.verdicts.adapt_threshold`); None: the operating point's.
    pub threshold: Option<f32>,
}

/// The operating point: what passes to the client.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OperatingPoint {
    /// Candidates strictly above this score are returned.
    pub threshold: f32,
    /// At most this many are returned.
    pub max_candidates: usize,
}

/// Precision figures of one method.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Precision {
    /// Queries scored, with or without a valid match.
    pub queries: usize,
    /// Of those, the queries that have a valid match.
    pub with_match: usize,
    /// Queries with at least one candidate above the threshold.
    pub answered: usize,
    /// Answered queries whose top candidate is not a valid match.
    pub false_top: usize,
    /// Answered queries that have no valid match at all.
    pub false_no_match: usize,
    /// `false_no_match` over the queries without a valid match (0 if none).
    pub false_alarm_rate: f64,
    /// Answered queries with a match whose top candidate is valid, over the
    /// queries with a match: recall at the operating point.
    pub recall_at_threshold: f64,
    /// Valid returned candidates over all returned candidates (1 if none
    /// was returned: nothing false was sent).
    pub candidate_precision: f64,
    /// Candidates returned in all.
    pub candidates: usize,
    /// The largest recall over queries with a match that any threshold on
    /// the top-1 score reaches with no false top-1 answered.
    pub recall_at_full_precision: f64,
    /// The precision–recall curve over the top-1 score: one point per
    /// distinct top-1 score, highest first.
    pub curve: Vec<CurvePoint>,
    /// Every query's top-1 answer `[score, valid, has a match]`, in query
    /// order (queries with no candidate left out), so that another
    /// threshold can be evaluated from the JSON (`tools/operating_point.py`).
    pub tops: Vec<(f32, bool, bool)>,
}

/// One point of the precision–recall curve.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CurvePoint {
    /// Queries whose top-1 score is at least this are answered.
    pub threshold: f32,
    /// Valid top-1 answers over queries with a match.
    pub recall: f64,
    /// Valid top-1 answers over answered queries.
    pub precision: f64,
}

/// The figures of `queries` at `point`.
///
/// The sweep for the curve and for recall at 100 % precision answers a
/// query when its top-1 score is at least the swept value, so queries whose
/// top scores tie are answered together: a tie between a valid and a false
/// top-1 ends the 100 %-precision prefix before both. Queries with no
/// candidate at all are never answered.
pub fn precision(queries: &[ScoredQuery], point: OperatingPoint) -> Precision {
    let with_match = queries.iter().filter(|q| q.has_match).count();
    let without_match = queries.len() - with_match;
    let (mut answered, mut false_top, mut false_no_match) = (0, 0, 0);
    let (mut returned, mut valid_returned, mut true_top) = (0, 0, 0);
    for q in queries {
        let sent: Vec<bool> = q
            .ranked
            .iter()
            .filter(|(score, _)| *score > q.threshold.unwrap_or(point.threshold))
            .take(point.max_candidates)
            .map(|&(_, valid)| valid)
            .collect();
        let Some(&top_valid) = sent.first() else {
            continue;
        };
        answered += 1;
        returned += sent.len();
        valid_returned += sent.iter().filter(|&&v| v).count();
        if top_valid {
            true_top += 1;
        } else {
            false_top += 1;
        }
        false_no_match += usize::from(!q.has_match);
    }

    // Sweep: top-1 scores from the highest down, tied scores together.
    let mut tops: Vec<(f32, bool)> = queries
        .iter()
        .filter_map(|q| q.ranked.first().copied())
        .collect();
    tops.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut curve = Vec::new();
    let (mut tp, mut seen, mut full) = (0usize, 0usize, 0.0f64);
    let mut clean = true;
    let mut i = 0;
    while i < tops.len() {
        let score = tops[i].0;
        while i < tops.len() && tops[i].0 == score {
            tp += usize::from(tops[i].1);
            seen += 1;
            i += 1;
        }
        let recall = ratio(tp, with_match);
        if seen > tp {
            clean = false;
        }
        if clean {
            full = recall;
        }
        curve.push(CurvePoint {
            threshold: score,
            recall,
            precision: ratio(tp, seen),
        });
    }

    Precision {
        queries: queries.len(),
        with_match,
        answered,
        false_top,
        false_no_match,
        false_alarm_rate: ratio(false_no_match, without_match),
        recall_at_threshold: ratio(true_top, with_match),
        candidate_precision: if returned == 0 {
            1.0
        } else {
            valid_returned as f64 / returned as f64
        },
        candidates: returned,
        recall_at_full_precision: full,
        curve,
        tops: queries
            .iter()
            .filter_map(|q| {
                q.ranked
                    .first()
                    .map(|&(score, valid)| (score, valid, q.has_match))
            })
            .collect(),
    }
}

fn ratio(a: usize, b: usize) -> f64 {
    if b == 0 {
        0.0
    } else {
        a as f64 / b as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn q(ranked: &[(f32, bool)], has_match: bool) -> ScoredQuery {
        ScoredQuery {
            ranked: ranked.to_vec(),
            has_match,
            threshold: None,
        }
    }

    const POINT: OperatingPoint = OperatingPoint {
        threshold: 0.5,
        max_candidates: 2,
    };

    /// Six queries, four with a match.
    fn sample() -> Vec<ScoredQuery> {
        vec![
            // A: top valid at 0.9; sent 0.9 (valid), 0.6 (false).
            q(&[(0.9, true), (0.6, false), (0.55, true)], true),
            // B: top false at 0.8 though a match exists; sent 0.8, 0.7 (valid).
            q(&[(0.8, false), (0.7, true)], true),
            // C: no match, top 0.7 (false alarm); sent one.
            q(&[(0.7, false), (0.4, false)], false),
            // D: match, top valid 0.6; sent one.
            q(&[(0.6, true), (0.5, false)], true),
            // E: match, top valid but below the threshold: not answered.
            q(&[(0.45, true)], true),
            // F: no match, nothing ranked.
            q(&[], false),
        ]
    }

    #[test]
    fn operating_point_by_hand() {
        let p = precision(&sample(), POINT);
        assert_eq!(p.queries, 6);
        assert_eq!(p.with_match, 4);
        // A, B, C, D answered.
        assert_eq!(p.answered, 4);
        // B and C have a false top.
        assert_eq!(p.false_top, 2);
        // C has no match at all: 1 of the 2 queries without a match.
        assert_eq!(p.false_no_match, 1);
        assert_eq!(p.false_alarm_rate, 0.5);
        // Valid tops answered: A, D → 2 of 4.
        assert_eq!(p.recall_at_threshold, 0.5);
        // Sent: A 2 (1 valid), B 2 (1 valid), C 1 (0), D 1 (1) → 3 / 6.
        assert_eq!(p.candidates, 6);
        assert_eq!(p.candidate_precision, 0.5);
        assert_eq!(
            p.tops,
            vec![
                (0.9, true, true),
                (0.8, false, true),
                (0.7, false, false),
                (0.6, true, true),
                (0.45, true, true),
            ]
        );
    }

    /// A query answered at its own (adapted) threshold: C at 0.75 sends
    /// nothing (no false alarm left), E at 0.4 is answered (its valid 0.45).
    #[test]
    fn per_query_thresholds_by_hand() {
        let mut queries = sample();
        queries[2].threshold = Some(0.75);
        queries[4].threshold = Some(0.4);
        let p = precision(&queries, POINT);
        assert_eq!(p.answered, 4);
        assert_eq!(p.false_no_match, 0);
        assert_eq!(p.false_alarm_rate, 0.0);
        // Valid tops answered: A, D, E → 3 of 4.
        assert_eq!(p.recall_at_threshold, 0.75);
        // Sent: A 2 (1 valid), B 2 (1), D 1 (1), E 1 (1) → 4 / 6.
        assert_eq!(p.candidates, 6);
        assert!((p.candidate_precision - 4.0 / 6.0).abs() < 1e-12);
    }

    #[test]
    fn full_precision_recall_and_curve_by_hand() {
        let p = precision(&sample(), POINT);
        // Tops sorted: 0.9 A valid, 0.8 B false, 0.7 C false, 0.6 D valid,
        // 0.45 E valid. The prefix without a false top is {A}: 1 of 4.
        assert_eq!(p.recall_at_full_precision, 0.25);
        let points: Vec<(f32, f64, f64)> = p
            .curve
            .iter()
            .map(|c| (c.threshold, c.recall, c.precision))
            .collect();
        assert_eq!(
            points,
            vec![
                (0.9, 0.25, 1.0),
                (0.8, 0.25, 0.5),
                (0.7, 0.25, 1.0 / 3.0),
                (0.6, 0.5, 0.5),
                (0.45, 0.75, 0.6),
            ]
        );
    }

    #[test]
    fn ties_end_the_clean_prefix() {
        // Two tops tie at 0.8, one valid and one false: only the 0.9 one counts.
        let qs = vec![
            q(&[(0.9, true)], true),
            q(&[(0.8, true)], true),
            q(&[(0.8, false)], false),
        ];
        let p = precision(&qs, POINT);
        assert_eq!(p.recall_at_full_precision, 0.5);
        assert_eq!(p.curve.len(), 2);
        assert_eq!(p.curve[1].precision, 2.0 / 3.0);
    }

    #[test]
    fn degenerate_inputs() {
        let p = precision(&[], POINT);
        assert_eq!((p.queries, p.answered, p.candidates), (0, 0, 0));
        assert_eq!(p.candidate_precision, 1.0);
        assert_eq!(p.false_alarm_rate, 0.0);
        assert_eq!(p.recall_at_full_precision, 0.0);
        assert!(p.curve.is_empty());
        // Every answer right: recall at 100 % precision is the plain recall.
        let qs = vec![q(&[(0.9, true)], true), q(&[(0.2, true)], true)];
        let p = precision(&qs, POINT);
        assert_eq!(p.recall_at_full_precision, 1.0);
        assert_eq!(p.recall_at_threshold, 0.5);
        assert_eq!(p.false_alarm_rate, 0.0);
    }
}
