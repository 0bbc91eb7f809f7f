//! The evaluation protocol's bookkeeping, shared by every method (in
//! process, through a service, the ORB baseline): which queries a run asks
//! ([`Selection`]) and what each method answered ([`Samples`]), summarised
//! the same way for all of them.
//!
//! Queries are the eligible ones, at most `--max-queries` at evenly spaced
//! indices; queries without a valid match (a loop's first pass, a query
//! nothing matches) are chosen the same way and scored for precision only,
//! since that is where false alarms come from. Latency is measured on 30
//! evenly spaced queries after 10 warm-ups. A leaf module, so that every
//! method can use it without taking in the run.

use std::collections::BTreeMap;
use std::time::Duration;

use crate::dataset::Dataset;
use crate::metrics;
use crate::precision::{self, OperatingPoint, ScoredQuery};
use crate::report::MethodResult;
use crate::truth::Kind;

/// What one method gave under one condition, before it is summarised.
#[derive(Debug, Default)]
pub struct Samples {
    /// Per query with a match: the ranked reference indices and the valid matches.
    pub answers: Vec<(Vec<usize>, Vec<usize>)>,
    /// Per query, with a match or not: the ranked scores and valid flags.
    pub scored: Vec<ScoredQuery>,
    /// Latency of each timed query.
    pub latencies: Vec<Duration>,
    /// Milliseconds per stage, summed over the timed queries.
    pub stage_ms: BTreeMap<String, f64>,
}

impl Samples {
    /// Records one query's ranking: `(reference index, score)` best first,
    /// and its valid matches (`None`: the query has none).
    pub fn record(&mut self, ranked: &[(usize, f32)], matches: Option<&Vec<usize>>) {
        let valid = |r: &usize| matches.is_some_and(|m| m.contains(r));
        if let Some(m) = matches {
            self.answers
                .push((ranked.iter().map(|&(r, _)| r).collect(), m.clone()));
        }
        self.scored.push(ScoredQuery {
            ranked: ranked.iter().map(|(r, s)| (*s, valid(r))).collect(),
            has_match: matches.is_some_and(|m| !m.is_empty()),
            threshold: None,
        });
    }

    /// Recall, latency, stage times and precision at `point` from the
    /// samples, under the name `method`.
    pub fn summarise(self, method: &str, point: OperatingPoint) -> MethodResult {
        let count = self.latencies.len().max(1) as f64;
        MethodResult {
            method: method.to_string(),
            precision: precision::precision(&self.scored, point),
            retrieval: metrics::retrieval(&self.answers),
            latency: metrics::latency(&self.latencies),
            stages_ms: self
                .stage_ms
                .into_iter()
                .map(|(k, v)| (k, v / count))
                .collect(),
        }
    }
}

/// The queries of one run.
#[derive(Debug, Clone, PartialEq)]
pub struct Selection {
    /// Queries with a valid match (recall and precision), sorted.
    pub with_match: Vec<usize>,
    /// Queries without one (precision only), sorted.
    pub without_match: Vec<usize>,
    /// Queries of `with_match` whose latency is measured.
    pub timed: Vec<usize>,
}

impl Selection {
    /// At most `at_most` evenly spaced queries of each kind (all with
    /// `None`); the latency sample is taken from those with a match. A loop
    /// query needs at least one eligible reference (index `>= gap`).
    pub fn new(dataset: &Dataset, at_most: Option<usize>) -> Selection {
        let pick = |v: &[usize]| match at_most {
            Some(k) => metrics::evenly_spaced(v, k),
            None => v.to_vec(),
        };
        let with: Vec<usize> = dataset.matches.keys().copied().collect();
        let first = match dataset.kind {
            Kind::Loop => dataset.min_frame_gap,
            Kind::Pairs => 0,
        };
        let without: Vec<usize> = (first..dataset.queries.len())
            .filter(|q| !dataset.matches.contains_key(q))
            .collect();
        let with_match = pick(&with);
        let (_, timed_positions) = metrics::latency_sample_indices(with_match.len(), 10, 30);
        let timed = timed_positions.iter().map(|&n| with_match[n]).collect();
        Selection {
            with_match,
            without_match: pick(&without),
            timed,
        }
    }

    /// Every selected query, sorted.
    pub fn all(&self) -> Vec<usize> {
        let mut all: Vec<usize> = self
            .with_match
            .iter()
            .chain(&self.without_match)
            .copied()
            .collect();
        all.sort_unstable();
        all
    }

    /// Whether query `q` is in the latency sample.
    pub fn is_timed(&self, q: usize) -> bool {
        self.timed.contains(&q)
    }
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;

    fn dataset(kind: Kind, matches: &[(usize, Vec<usize>)]) -> Dataset {
        let images: Vec<PathBuf> = (0..10).map(|i| PathBuf::from(format!("{i}.png"))).collect();
        Dataset {
            name: "toy".into(),
            kind,
            queries: images.clone(),
            references: images,
            matches: matches.iter().cloned().collect(),
            min_frame_gap: 5,
            truth_source: "ground_truth.json".into(),
        }
    }

    #[test]
    fn a_loop_selects_queries_from_the_gap_on() {
        let d = dataset(Kind::Loop, &[(6, vec![1]), (8, vec![2])]);
        let s = Selection::new(&d, None);
        assert_eq!(s.with_match, [6, 8]);
        // Queries before the gap have nothing to match and are left out.
        assert_eq!(s.without_match, [5, 7, 9]);
        assert_eq!(s.all(), [5, 6, 7, 8, 9]);
        assert!(s.timed.iter().all(|q| s.with_match.contains(q)));
        assert!(s.is_timed(s.timed[0]) && !s.is_timed(5));
    }

    #[test]
    fn pairs_select_evenly_spaced_queries_of_each_kind() {
        let d = dataset(Kind::Pairs, &[(0, vec![0]), (3, vec![3]), (9, vec![9])]);
        let s = Selection::new(&d, Some(2));
        assert_eq!(s.with_match, [0, 9]);
        assert_eq!(s.without_match, [1, 8]);
        assert_eq!(s.all(), [0, 1, 8, 9]);
    }

    #[test]
    fn samples_keep_answers_only_for_queries_with_a_match() {
        let mut samples = Samples::default();
        samples.record(&[(3, 0.9), (1, 0.5)], Some(&vec![1]));
        samples.record(&[(2, 0.7)], None);
        assert_eq!(samples.answers, [(vec![3, 1], vec![1])]);
        assert_eq!(samples.scored.len(), 2);
        assert_eq!(samples.scored[0].ranked, [(0.9, false), (0.5, true)]);
        assert!(samples.scored[0].has_match);
        assert_eq!(samples.scored[1].ranked, [(0.7, false)]);
        assert!(!samples.scored[1].has_match);

        samples.latencies = vec![Duration::from_millis(10), Duration::from_millis(30)];
        samples.stage_ms.insert("rank".into(), 8.0);
        let point = OperatingPoint {
            threshold: 0.6,
            max_candidates: 5,
        };
        let result = samples.summarise("Full", point);
        assert_eq!(result.method, "Full");
        // Stage times are means over the timed queries.
        assert_eq!(result.stages_ms["rank"], 4.0);
        assert_eq!(result.latency.mean_ms, 20.0);
        assert_eq!(
            (result.retrieval.recall_at_1, result.retrieval.recall_at_5),
            (0.0, 1.0)
        );
        assert_eq!(result.retrieval.mrr, 0.5);
        assert_eq!(result.precision.queries, 2);
    }
}
