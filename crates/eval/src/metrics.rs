//! Retrieval metrics and latency statistics of `humem eval`.
//!
//! These are the numbers the paper reports (docs/evaluation.md, "the
//! protocol"): Recall@1, Recall@5 and MRR over queries that have at least one
//! valid match, at most 100 of them taken at evenly spaced indices; latency
//! as mean, median and p95 of 30 evenly spaced queries after 10 warm-ups.
//!
//! Everything here is a pure function of plain slices (candidate ids,
//! durations), with no knowledge of images, the service or the data-set
//! layout, so that each formula can be pinned by hand-computed tests and the
//! harness only has to collect rankings and timings. Degenerate input (no
//! queries, no samples, fewer queries than asked for) gives zeros or shorter
//! selections, never a panic.

use std::collections::HashSet;
use std::time::Duration;

use serde::Serialize;

/// 0-based rank of the first candidate in `ranked` that is one of `matches`,
/// or `None` when no valid match was ranked.
pub fn first_hit_rank(ranked: &[usize], matches: &[usize]) -> Option<usize> {
    // A set keeps this linear for long rankings; tiny match lists would be
    // as fast with `contains`, but the set costs little either way.
    let valid: HashSet<usize> = matches.iter().copied().collect();
    ranked.iter().position(|c| valid.contains(c))
}

/// Retrieval quality over a set of queries.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Retrieval {
    /// Number of queries scored.
    pub queries: usize,
    /// Share of queries whose first valid match is ranked first.
    pub recall_at_1: f64,
    /// Share of queries whose first valid match is within the top five.
    pub recall_at_5: f64,
    /// Mean reciprocal rank: mean of 1/(rank + 1) with a 0-based rank, 0 for
    /// a query with no valid match in its ranking.
    pub mrr: f64,
}

/// Scores `results`, one `(ranked candidate ids, valid match ids)` per query.
///
/// Recall@K is the share of queries whose first valid match has 0-based rank
/// `< K` (the paper's "ranks ≤ K" with 1-based ranks). A query whose ranking
/// holds no valid match counts as a miss for every K and adds 0 to the MRR.
/// No queries give all zeros.
pub fn retrieval(results: &[(Vec<usize>, Vec<usize>)]) -> Retrieval {
    let n = results.len();
    if n == 0 {
        return Retrieval {
            queries: 0,
            recall_at_1: 0.0,
            recall_at_5: 0.0,
            mrr: 0.0,
        };
    }
    let (mut hits_1, mut hits_5, mut rr_sum) = (0usize, 0usize, 0.0f64);
    for (ranked, matches) in results {
        if let Some(rank) = first_hit_rank(ranked, matches) {
            hits_1 += usize::from(rank < 1);
            hits_5 += usize::from(rank < 5);
            rr_sum += 1.0 / (rank as f64 + 1.0);
        }
    }
    let n_f = n as f64;
    Retrieval {
        queries: n,
        recall_at_1: hits_1 as f64 / n_f,
        recall_at_5: hits_5 as f64 / n_f,
        mrr: rr_sum / n_f,
    }
}

/// At most `at_most` items of `eligible`, taken at evenly spaced positions.
///
/// `eligible` is sorted and deduplicated first; call its length `n` and let
/// `k = at_most`. When `n <= k` all items are returned. Otherwise the items at
/// positions `round(i·(n−1)/(k−1))` for `i` in `0..k` are returned (rounding
/// half up, in exact integer arithmetic), so the first and last items are
/// always included when `k >= 2`; `k = 1` gives the first item and `k = 0`
/// nothing. As `n > k`, the step `(n−1)/(k−1)` exceeds 1 and the positions
/// are strictly increasing, so the result is sorted with no duplicates and
/// has exactly `k` items.
pub fn evenly_spaced(eligible: &[usize], at_most: usize) -> Vec<usize> {
    let mut sorted = eligible.to_vec();
    sorted.sort_unstable();
    sorted.dedup();
    let (n, k) = (sorted.len(), at_most);
    if n <= k {
        return sorted;
    }
    match k {
        0 => Vec::new(),
        1 => vec![sorted[0]],
        _ => {
            let (span, steps) = ((n - 1) as u128, (k - 1) as u128);
            let mut picked: Vec<usize> = (0..k as u128)
                // round(i·span/steps) = floor((2·i·span + steps) / (2·steps))
                .map(|i| ((2 * i * span + steps) / (2 * steps)) as usize)
                .map(|pos| sorted[pos.min(n - 1)])
                .collect();
            picked.dedup();
            picked
        }
    }
}

/// Latency summary, in milliseconds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LatencyStats {
    /// Number of timed samples.
    pub samples: usize,
    /// Arithmetic mean.
    pub mean_ms: f64,
    /// Median; the mean of the two middle samples for an even count.
    pub median_ms: f64,
    /// 95th percentile by the nearest-rank method.
    pub p95_ms: f64,
}

/// Mean, median and p95 of `samples`; all zeros when there are none.
///
/// The p95 uses the nearest-rank method: with the samples sorted ascending,
/// it is the sample of 1-based rank `ceil(0.95·n)`, so it is always an
/// observed value (for the paper's 30 samples, the 29th smallest).
pub fn latency(samples: &[Duration]) -> LatencyStats {
    let n = samples.len();
    if n == 0 {
        return LatencyStats {
            samples: 0,
            mean_ms: 0.0,
            median_ms: 0.0,
            p95_ms: 0.0,
        };
    }
    let mut ms: Vec<f64> = samples.iter().map(|d| d.as_secs_f64() * 1e3).collect();
    ms.sort_unstable_by(f64::total_cmp);
    let mean_ms = ms.iter().sum::<f64>() / n as f64;
    let median_ms = if n % 2 == 1 {
        ms[n / 2]
    } else {
        (ms[n / 2 - 1] + ms[n / 2]) / 2.0
    };
    // ceil(95·n / 100) in integers, so 0.95·n is never mis-rounded; n ≥ 1
    // makes the rank ≥ 1, and it never exceeds n.
    let rank = (95 * n as u128).div_ceil(100) as usize;
    let p95_ms = ms[rank.clamp(1, n) - 1];
    LatencyStats {
        samples: n,
        mean_ms,
        median_ms,
        p95_ms,
    }
}

/// Picks the warm-up and timed queries among `n` queries (indices `0..n`):
/// the paper's "30 evenly spaced queries after 10 warm-ups".
///
/// The rule: take `s = evenly_spaced(0..n, warmup + timed)`. When `s` holds
/// all `warmup + timed` picks, its first `warmup` items are the warm-ups and
/// the remaining `timed` items are timed. When there are fewer queries than
/// that, `s` is all of `0..n` and is split in the same proportion, the
/// warm-ups rounded up (`w = min(warmup, ceil(|s|·warmup / (warmup + timed)))`),
/// so that a short data set still warms up before it is timed and still gets
/// some timed samples. The two lists are disjoint, sorted, and every
/// warm-up precedes every timed query; `n = 0` gives two empty lists.
pub fn latency_sample_indices(n: usize, warmup: usize, timed: usize) -> (Vec<usize>, Vec<usize>) {
    let total = warmup.saturating_add(timed);
    let all: Vec<usize> = (0..n).collect();
    let selection = evenly_spaced(&all, total);
    let w = if selection.len() >= total {
        warmup
    } else {
        // |s| < total here, so the product fits comfortably in u128.
        let share = (selection.len() as u128 * warmup as u128).div_ceil(total as u128);
        (share as usize).min(warmup)
    };
    let w = w.min(selection.len());
    let timed_part = selection[w..].to_vec();
    let mut warm = selection;
    warm.truncate(w);
    (warm, timed_part)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-12
    }

    #[test]
    fn first_hit_rank_finds_the_first_valid_match() {
        assert_eq!(first_hit_rank(&[7, 3, 9], &[9, 3]), Some(1));
        assert_eq!(first_hit_rank(&[7, 3, 9], &[7]), Some(0));
        assert_eq!(first_hit_rank(&[7, 3, 9], &[1, 2]), None);
        assert_eq!(first_hit_rank(&[], &[1]), None);
        assert_eq!(first_hit_rank(&[1, 2], &[]), None);
    }

    #[test]
    fn retrieval_by_hand_with_hits_at_ranks_0_4_5_and_a_miss() {
        let results = vec![
            // first valid match at rank 0 (a second valid one further down)
            (vec![10, 11, 12, 13, 14, 15], vec![10, 14]),
            // rank 4: the last slot that counts for Recall@5
            (vec![20, 21, 22, 23, 24, 25], vec![24, 99]),
            // rank 5: just outside Recall@5
            (vec![30, 31, 32, 33, 34, 35], vec![35]),
            // a miss: the valid match is not in the ranking
            (vec![40, 41, 42], vec![49]),
        ];
        let r = retrieval(&results);
        assert_eq!(r.queries, 4);
        assert!(close(r.recall_at_1, 1.0 / 4.0));
        assert!(close(r.recall_at_5, 2.0 / 4.0));
        // (1/1 + 1/5 + 1/6 + 0) / 4 = (30 + 6 + 5) / 30 / 4 = 41/120
        assert!(close(r.mrr, 41.0 / 120.0), "{}", r.mrr);
    }

    #[test]
    fn retrieval_with_all_first_hits_at_rank_0() {
        let results = vec![(vec![1, 2], vec![1]), (vec![5, 6, 7], vec![5, 7])];
        let r = retrieval(&results);
        assert_eq!(r.queries, 2);
        assert!(close(r.recall_at_1, 1.0));
        assert!(close(r.recall_at_5, 1.0));
        assert!(close(r.mrr, 1.0));
    }

    #[test]
    fn retrieval_of_nothing_is_zero() {
        let r = retrieval(&[]);
        assert_eq!(
            r,
            Retrieval {
                queries: 0,
                recall_at_1: 0.0,
                recall_at_5: 0.0,
                mrr: 0.0
            }
        );
        let all_missed = retrieval(&[(vec![], vec![3]), (vec![1], vec![2])]);
        assert_eq!(all_missed.queries, 2);
        assert_eq!(all_missed.mrr, 0.0);
        assert_eq!(all_missed.recall_at_5, 0.0);
    }

    #[test]
    fn retrieval_serialises_with_field_names() {
        let r = retrieval(&[(vec![1], vec![1])]);
        let json = serde_json::to_value(r).unwrap();
        assert_eq!(json["queries"], 1);
        assert_eq!(json["recall_at_1"], 1.0);
        assert_eq!(json["mrr"], 1.0);
    }

    #[test]
    fn evenly_spaced_takes_all_when_few() {
        // 3 eligible, up to 10 wanted: all of them, sorted and deduplicated.
        assert_eq!(evenly_spaced(&[30, 10, 20], 10), vec![10, 20, 30]);
        assert_eq!(evenly_spaced(&[5, 5, 1], 10), vec![1, 5]);
        let hundred: Vec<usize> = (0..100).collect();
        assert_eq!(evenly_spaced(&hundred, 100), hundred);
        assert!(evenly_spaced(&[], 5).is_empty());
        assert!(evenly_spaced(&[1, 2], 0).is_empty());
        assert_eq!(evenly_spaced(&[4, 2, 9], 1), vec![2]);
    }

    #[test]
    fn evenly_spaced_100_of_250() {
        let eligible: Vec<usize> = (0..250).map(|i| 1000 + 3 * i).collect();
        let picked = evenly_spaced(&eligible, 100);
        assert_eq!(picked.len(), 100);
        assert_eq!(picked[0], 1000);
        assert_eq!(*picked.last().unwrap(), 1000 + 3 * 249);
        assert!(picked.windows(2).all(|w| w[0] < w[1]));
        // position round(i·249/99): i = 1 → 2.515 → 3, i = 2 → 5.03 → 5,
        // i = 50 → 125.76 → 126.
        assert_eq!(picked[1], 1000 + 3 * 3);
        assert_eq!(picked[2], 1000 + 3 * 5);
        assert_eq!(picked[50], 1000 + 3 * 126);
    }

    #[test]
    fn evenly_spaced_3_of_10_by_hand() {
        // positions round(i·9/2) = 0, round(4.5) = 5, 9
        let eligible: Vec<usize> = (100..110).collect();
        assert_eq!(evenly_spaced(&eligible, 3), vec![100, 105, 109]);
        assert_eq!(evenly_spaced(&eligible, 2), vec![100, 109]);
    }

    #[test]
    fn latency_on_known_samples() {
        let ms = |v: &[u64]| {
            v.iter()
                .map(|&m| Duration::from_millis(m))
                .collect::<Vec<_>>()
        };
        let s = latency(&ms(&[40, 10, 30, 20]));
        assert_eq!(s.samples, 4);
        assert!(close(s.mean_ms, 25.0));
        assert!(close(s.median_ms, 25.0));
        // nearest rank ceil(0.95·4) = 4 → the largest
        assert!(close(s.p95_ms, 40.0));

        let s = latency(&ms(&[5, 1, 3]));
        assert!(close(s.mean_ms, 3.0));
        assert!(close(s.median_ms, 3.0));
        assert!(close(s.p95_ms, 5.0));

        // 1..=20 ms: ceil(0.95·20) = 19 → 19 ms; median (10 + 11) / 2.
        let twenty: Vec<u64> = (1..=20).collect();
        let s = latency(&ms(&twenty));
        assert!(close(s.median_ms, 10.5));
        assert!(close(s.mean_ms, 10.5));
        assert!(close(s.p95_ms, 19.0));

        // The paper's 30: ceil(28.5) = 29 → the 29th smallest.
        let thirty: Vec<u64> = (1..=30).map(|i| i * 2).collect();
        assert!(close(latency(&ms(&thirty)).p95_ms, 58.0));

        // Sub-millisecond precision is kept.
        let s = latency(&[Duration::from_micros(1500)]);
        assert!(close(s.mean_ms, 1.5) && close(s.median_ms, 1.5) && close(s.p95_ms, 1.5));
    }

    #[test]
    fn latency_of_nothing_is_zero() {
        let s = latency(&[]);
        assert_eq!(s.samples, 0);
        assert_eq!((s.mean_ms, s.median_ms, s.p95_ms), (0.0, 0.0, 0.0));
    }

    #[test]
    fn latency_sample_indices_paper_setting() {
        let (warm, timed) = latency_sample_indices(418, 10, 30);
        assert_eq!(warm.len(), 10);
        assert_eq!(timed.len(), 30);
        assert_eq!(warm[0], 0);
        assert_eq!(*timed.last().unwrap(), 417);
        assert!(warm.last() < timed.first());
        // Same picks as one evenly spaced selection of 40.
        let all: Vec<usize> = (0..418).collect();
        let joined: Vec<usize> = warm.iter().chain(&timed).copied().collect();
        assert_eq!(joined, evenly_spaced(&all, 40));
    }

    #[test]
    fn latency_sample_indices_small_n() {
        assert_eq!(latency_sample_indices(0, 10, 30), (vec![], vec![]));
        // 1 query: ceil(1·10/40) = 1 warm-up, nothing left to time.
        assert_eq!(latency_sample_indices(1, 10, 30), (vec![0], vec![]));
        // 10 queries: ceil(100/40) = 3 warm-ups, 7 timed.
        assert_eq!(
            latency_sample_indices(10, 10, 30),
            (vec![0, 1, 2], vec![3, 4, 5, 6, 7, 8, 9])
        );
        // Exactly 40: 10 + 30.
        let (w, t) = latency_sample_indices(40, 10, 30);
        assert_eq!(w, (0..10).collect::<Vec<_>>());
        assert_eq!(t, (10..40).collect::<Vec<_>>());
        // No warm-ups asked for.
        assert_eq!(latency_sample_indices(3, 0, 30), (vec![], vec![0, 1, 2]));
        assert_eq!(latency_sample_indices(3, 0, 0), (vec![], vec![]));
        assert_eq!(latency_sample_indices(5, 2, 0), (vec![0, 4], vec![]));
        // Huge counts do not overflow.
        let (w, t) = latency_sample_indices(3, usize::MAX, usize::MAX);
        assert_eq!(w.len() + t.len(), 3);
    }

    proptest! {
        #[test]
        fn evenly_spaced_properties(
            eligible in proptest::collection::vec(0usize..10_000, 0..400),
            k in 0usize..150,
        ) {
            let picked = evenly_spaced(&eligible, k);
            let mut distinct = eligible.clone();
            distinct.sort_unstable();
            distinct.dedup();
            prop_assert_eq!(picked.len(), k.min(distinct.len()));
            prop_assert!(picked.windows(2).all(|w| w[0] < w[1]));
            prop_assert!(picked.iter().all(|p| distinct.binary_search(p).is_ok()));
            if k >= 2 && !distinct.is_empty() {
                prop_assert_eq!(picked.first(), distinct.first());
                prop_assert_eq!(picked.last(), distinct.last());
            }
        }

        #[test]
        fn latency_sample_indices_properties(n in 0usize..200, warmup in 0usize..20, timed in 0usize..50) {
            let (w, t) = latency_sample_indices(n, warmup, timed);
            prop_assert!(w.len() <= warmup && t.len() <= timed);
            prop_assert_eq!(w.len() + t.len(), n.min(warmup + timed));
            let joined: Vec<usize> = w.iter().chain(&t).copied().collect();
            prop_assert!(joined.windows(2).all(|p| p[0] < p[1]));
            prop_assert!(joined.iter().all(|&i| i < n));
        }

        #[test]
        fn latency_order_statistics_are_bounded(v in proptest::collection::vec(0u64..1_000_000, 1..100)) {
            let samples: Vec<Duration> = v.iter().map(|&us| Duration::from_micros(us)).collect();
            let s = latency(&samples);
            let lo = *v.iter().min().unwrap() as f64 / 1e3;
            let hi = *v.iter().max().unwrap() as f64 / 1e3;
            prop_assert!(lo - 1e-9 <= s.median_ms && s.median_ms <= s.p95_ms + 1e-9);
            prop_assert!(s.p95_ms <= hi + 1e-9 && lo - 1e-9 <= s.mean_ms && s.mean_ms <= hi + 1e-9);
        }
    }
}
