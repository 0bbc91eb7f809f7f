//! One query over the index, from the eligible rows to the selected
//! candidates.
//!
//! The scan and the paper's layers rank the eligible rows
//! ([`rank_timed`]); the rules on top of them that need the index itself
//! come next, in this order: views of the query's own map turned away from
//! it are left out ([`viewpoint`]), SLAM's verdicts change the scores
//! ([`feedback`]), and the store's operating point gives the threshold
//! unless the query names one; then the candidates are selected.
//!
//! It lives in the core, beside the ranking, so that a query goes down once
//! and comes back once: the server resolves what the query is before (the
//! features it sent or the stored keyframe it names, its context and
//! temporal history) and spells the evidence out after, and never steps in
//! between the scan and the selection. The rules' time is booked as the
//! `rules` stage of [`StageTimes`].

use std::collections::BTreeSet;
use std::time::Instant;

use crate::index::Index;
use crate::keyframe::SessionKey;
use crate::verdict::unix_now;
use crate::vpr::eligibility::QueryContext;
use crate::vpr::feedback::{self, Place, PlacedVerdict};
use crate::vpr::operating_point::OperatingPoint;
use crate::vpr::params::{Layers, VprParams};
use crate::vpr::rank::{
    rank_timed, select, sort_ranked, QueryObservation, RankedCandidate, Ranking, StageTimes,
};
use crate::vpr::viewpoint;

/// A query, resolved into what the index needs.
#[derive(Debug, Clone)]
pub struct IndexQuery<'a> {
    /// The current observation and its predecessors, most recent first.
    pub observation: QueryObservation<'a>,
    /// Who asks and where: eligibility's scope, read access and frame gap.
    pub context: QueryContext,
    /// Which corroborating layers run.
    pub layers: Layers,
    /// The row of the stored keyframe the query is, when it is one: its
    /// pose and place are what the view rule and the verdicts compare the
    /// candidates with. `None` (an image or features alone) leaves both
    /// rules to what needs no query place.
    pub stored_row: Option<usize>,
    /// The threshold the request names; `None`: the store's operating
    /// point.
    pub threshold: Option<f32>,
    /// Most candidates returned.
    pub top_n: usize,
    /// Whether the scan may visit only the rows of the maps the query may
    /// see, where the index names them (the service's way). `false` scans
    /// every row: the same answer at the cost of the whole store, the
    /// reference `humem bench scan` checks the partitioned scan against.
    pub partitioned: bool,
    /// Whether the answer must come from a pass over every eligible row,
    /// never from the neighbour graph's candidates (as `vpr.exact` does
    /// for every query).
    pub exact: bool,
}

/// What one query over the index found.
#[derive(Debug, Clone)]
pub struct Answer {
    /// The selected candidates, best first, with all of their evidence.
    pub candidates: Vec<RankedCandidate>,
    /// Stored rows that passed eligibility.
    pub eligible: usize,
    /// Time per stage, the rules' included.
    pub times: StageTimes,
    /// The threshold applied: the query's, or else the operating point's.
    pub threshold: f32,
    /// The store's operating point when the query ran.
    pub operating_point: OperatingPoint,
}

/// Ranks the index's eligible rows for `query`, applies the rules on top
/// of the ranking and selects the candidates (see the module doc).
pub fn answer(index: &Index, params: &VprParams, query: &IndexQuery) -> Answer {
    let eligible = index.eligibility(&query.context);
    let eligible = if query.partitioned {
        eligible
    } else {
        eligible.without_partition()
    };
    let eligible = if query.exact {
        eligible.exact()
    } else {
        eligible
    };
    let Ranking {
        candidates: mut ranked,
        mut times,
        eligible: eligible_count,
    } = rank_timed(params, query.layers, &query.observation, index, &eligible);
    let clock = Instant::now();
    leave_out_turned_away(index, params, query.stored_row, &mut ranked);
    let now = unix_now();
    apply_verdicts(index, params, query.stored_row, &mut ranked, now);
    let operating_point = index.operating_point(params, now);
    let threshold = query.threshold.unwrap_or(operating_point.threshold);
    let candidates = select(ranked, threshold, query.top_n);
    times.rules = clock.elapsed();
    Answer {
        candidates,
        eligible: eligible_count,
        times,
        threshold,
        operating_point,
    }
}

/// Leaves out the candidates of the query's own map whose camera is
/// turned further from the query's than `vpr.max_view_change_deg`
/// ([`viewpoint`]); a query without a stored keyframe keeps them all.
pub fn leave_out_turned_away(
    index: &Index,
    params: &VprParams,
    stored_row: Option<usize>,
    ranked: &mut Vec<RankedCandidate>,
) {
    let Some(query) = stored_row.map(|row| index.meta(row)) else {
        return;
    };
    if params.max_view_change_deg >= viewpoint::OFF_DEG {
        return;
    }
    ranked.retain(|r| {
        let candidate = index.meta(r.row);
        !candidate.same_map(query)
            || !viewpoint::turned_away(params.max_view_change_deg, &query.pose, &candidate.pose)
    });
}

/// Changes the ranked candidates' scores by SLAM's stored verdicts
/// ([`feedback`]) and puts them back in order. The query's place is its
/// stored keyframe's, when it is one.
///
/// Which verdicts are looked at: for a query with a place and the place
/// graph off (the default), only a verdict with one end at the query's
/// place can apply to any of its candidates (the penalty and the own
/// support link the query's place with a candidate's), so only the
/// verdicts naming a keyframe near it are fetched ([`Index::keyframes_near`]):
/// the cost follows the verdicts at this place, not every verdict of a
/// session that has driven for months. Otherwise (the place graph links
/// candidates' places with each other), those naming a keyframe of the
/// query's or a candidate's session.
pub fn apply_verdicts(
    index: &Index,
    params: &VprParams,
    stored_row: Option<usize>,
    ranked: &mut [RankedCandidate],
    now: f64,
) {
    let book = index.verdicts();
    if !params.verdicts.enabled || book.is_empty() || ranked.is_empty() {
        return;
    }
    let query = stored_row.map(|row| index.place_of_row(row));
    let candidates: Vec<Place> = ranked.iter().map(|r| index.place_of_row(r.row)).collect();
    let near_only = query.is_some() && !params.verdicts.place_graph;
    let placed = placed_verdicts(index, params, query.as_ref(), &candidates, near_only, now);
    if placed.is_empty() {
        return;
    }
    let mut scores: Vec<f32> = ranked.iter().map(|r| r.score).collect();
    let effects = feedback::apply(
        &params.verdicts,
        query.as_ref(),
        &candidates,
        &mut scores,
        &placed,
    );
    for ((r, score), effect) in ranked.iter_mut().zip(scores).zip(effects) {
        r.score = score;
        r.verdict = effect;
    }
    sort_ranked(ranked);
}

/// The verdicts a query looks at, placed: those naming a keyframe near the
/// query's place (`near_only`, which needs a `query`), or else those naming
/// a keyframe of the query's or a candidate's session.
fn placed_verdicts<'a>(
    index: &'a Index,
    params: &VprParams,
    query: Option<&Place>,
    candidates: &[Place],
    near_only: bool,
    now: f64,
) -> Vec<PlacedVerdict<'a>> {
    let book = index.verdicts();
    let looked_at = match query {
        Some(q) if near_only => book.naming(index.keyframes_near(q, &params.verdicts)),
        _ => {
            let sessions: BTreeSet<SessionKey> = query
                .into_iter()
                .chain(candidates)
                .map(|p| p.key.session())
                .collect();
            book.touching(&sessions)
        }
    };
    looked_at
        .into_iter()
        .filter_map(|v| PlacedVerdict::new(v, &params.verdicts, now, |k| index.place(k)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::keyframe::{Features, Pose, SemanticKeyframe};
    use crate::synthetic::Rng;
    use crate::verdict::{Verdict, VerificationKind};
    use crate::vpr::eligibility::Scope;

    /// Two sessions driving laps of a 60 m line (two maps in the first),
    /// and a thousand verdicts on random pairs of them.
    fn index_with_verdicts() -> Index {
        let mut index = Index::new(4);
        let key = |session: &str, id: u64| {
            SessionKey {
                robot_id: "r".into(),
                session_id: session.into(),
            }
            .keyframe(id)
        };
        let mut keys = Vec::new();
        for (session, n) in [("a", 240u64), ("b", 120)] {
            for id in 0..n {
                let k = key(session, id);
                index.upsert(SemanticKeyframe {
                    key: k.clone(),
                    frame_id: id,
                    timestamp: id as f64,
                    map_id: u64::from(session == "a" && id >= 200),
                    pose: Pose {
                        translation: [(id % 60) as f64, 0.0, 0.0],
                        ..Pose::default()
                    },
                    features: Features {
                        descriptor: vec![0.5; 4],
                        ..Features::default()
                    },
                });
                keys.push(k);
            }
        }
        let mut rng = Rng::new(3);
        for i in 0..1000 {
            let q = &keys[rng.next() as usize % keys.len()];
            let c = &keys[rng.next() as usize % keys.len()];
            index.record_verdict(Verdict {
                query: q.clone(),
                candidate: c.clone(),
                kind: VerificationKind::Loop,
                accepted: rng.next().is_multiple_of(3),
                relative: None,
                score: Some(0.5),
                inliers: 0,
                reported_at: f64::from(i),
            });
        }
        index
    }

    /// Without the place graph, the verdicts near the query's place are
    /// all that apply: the effects equal those over the sessions' verdicts,
    /// for every query and a spread of candidates.
    #[test]
    fn verdicts_near_the_query_are_all_that_apply() {
        let index = index_with_verdicts();
        let params = VprParams::default();
        let mut rng = Rng::new(9);
        let mut touched = 0;
        for q_row in 0..index.len() {
            let query = index.place_of_row(q_row);
            let candidates: Vec<Place> = (0..8)
                .map(|_| index.place_of_row(rng.next() as usize % index.len()))
                .collect();
            let effects = |near_only| {
                let placed =
                    placed_verdicts(&index, &params, Some(&query), &candidates, near_only, 1e3);
                let mut scores = vec![0.5f32; candidates.len()];
                let effects = feedback::apply(
                    &params.verdicts,
                    Some(&query),
                    &candidates,
                    &mut scores,
                    &placed,
                );
                (effects, scores)
            };
            let near = effects(true);
            assert_eq!(near, effects(false), "query row {q_row}");
            touched += near
                .0
                .iter()
                .filter(|e| e.rejections + e.acceptances > 0)
                .count();
        }
        assert!(
            touched > 100,
            "the verdicts must apply somewhere: {touched}"
        );
    }

    /// A query for the stored keyframe `row` of `index`, over every map,
    /// at threshold 0.
    fn query_of<'a>(index: &Index, row: usize, partitioned: bool) -> IndexQuery<'a> {
        let meta = index.meta(row);
        IndexQuery {
            observation: QueryObservation {
                history: Vec::new(),
            },
            context: QueryContext {
                session: meta.key.session(),
                keyframe_id: Some(meta.key.keyframe_id),
                frame_id: meta.frame_id,
                map_id: meta.map_id,
                min_frame_gap: 0,
                scope: Scope::AllMaps,
                readable_robots: None,
            },
            layers: Layers::FULL,
            stored_row: Some(row),
            threshold: Some(0.0),
            top_n: 50,
            exact: false,
            partitioned,
        }
    }

    /// The answer selects, times the rules apart from the layers, and
    /// returns the same candidates whether or not the scan is partitioned;
    /// a named threshold is applied as given, the operating point
    /// otherwise.
    #[test]
    fn an_answer_selects_from_the_ranking_and_times_its_rules() {
        let index = index_with_verdicts();
        let params = VprParams::default();
        let row = index
            .row_of(
                &SessionKey {
                    robot_id: "r".into(),
                    session_id: "a".into(),
                }
                .keyframe(230),
            )
            .unwrap();
        let current = index.keyframe(row).features;
        let mut query = query_of(&index, row, true);
        query.observation.history = vec![&current];
        let parted = answer(&index, &params, &query);
        query.partitioned = false;
        let full = answer(&index, &params, &query);
        let rows = |a: &Answer| a.candidates.iter().map(|c| c.row).collect::<Vec<_>>();
        assert!(!parted.candidates.is_empty() && parted.candidates.len() <= 50);
        assert_eq!(rows(&parted), rows(&full));
        assert_eq!(parted.threshold, 0.0);
        assert!(parted
            .times
            .stages()
            .iter()
            .any(|(name, _)| *name == "rules"));
        assert!(parted
            .candidates
            .windows(2)
            .all(|w| w[0].score >= w[1].score));

        query.threshold = None;
        let at_operating_point = answer(&index, &params, &query);
        assert_eq!(
            at_operating_point.threshold,
            at_operating_point.operating_point.threshold
        );
    }
}
