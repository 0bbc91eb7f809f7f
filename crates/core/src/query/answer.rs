//! One query over an index held as it is: the eligible rows ranked, the
//! rules on top of the ranking, the selection (see [the parent
//! module](super) for the order of the rules and why they live here).

use std::collections::BTreeSet;
use std::time::Instant;

use crate::index::{Index, RowEligibility};
use crate::keyframe::SessionKey;
use crate::verdict::unix_now;
use crate::vpr::drift::DriftEvidence;
use crate::vpr::eligibility::QueryContext;
use crate::vpr::feedback::{self, squared_distance, Place, PlacedVerdict};
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
/// of the ranking and selects the candidates (see the module doc). The
/// whole query reads `index` as it is; [`answer_releasing`](super::answer_releasing)
/// lets a pass over a large store go of the index between pieces.
pub fn answer(index: &Index, params: &VprParams, query: &IndexQuery) -> Answer {
    let eligible = eligibility(index, query);
    let ranking = rank_timed(params, query.layers, &query.observation, index, &eligible);
    answer_ranked(index, params, query, ranking)
}

/// The query's eligibility rule on `index`'s rows, as `query` asks to scan
/// them.
pub(super) fn eligibility<'i>(index: &'i Index, query: &IndexQuery) -> RowEligibility<'i> {
    let eligible = index.eligibility(&query.context);
    let eligible = if query.partitioned {
        eligible
    } else {
        eligible.without_partition()
    };
    if query.exact {
        eligible.exact()
    } else {
        eligible
    }
}

/// The rules on top of a ranking, then the selection.
pub(super) fn answer_ranked(
    index: &Index,
    params: &VprParams,
    query: &IndexQuery,
    ranking: Ranking,
) -> Answer {
    let Ranking {
        candidates: mut ranked,
        mut times,
        eligible: eligible_count,
    } = ranking;
    let clock = Instant::now();
    leave_out_turned_away(index, params, query.stored_row, &mut ranked);
    lower_beyond_drift(index, params, query.stored_row, &mut ranked);
    let now = unix_now();
    apply_verdicts(index, params, query.stored_row, &mut ranked, now);
    leave_out_rivals_beyond_drift(params, &mut ranked);
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

/// Measures every candidate of the query's own map against the drift
/// envelope ([`drift`](crate::vpr::drift)), records what it found in the
/// candidate's evidence, lowers the scores of those lying farther from
/// the query than `vpr.max_drift_ratio` of the path between them plus the
/// map's same-place radius allows, and puts them back in order. A query
/// without a stored keyframe keeps them all, unmeasured; so do candidates
/// of other maps.
pub fn lower_beyond_drift(
    index: &Index,
    params: &VprParams,
    stored_row: Option<usize>,
    ranked: &mut [RankedCandidate],
) {
    let Some(query_row) = stored_row else {
        return;
    };
    let rows: Vec<usize> = ranked.iter().map(|r| r.row).collect();
    let paths = index.track_paths(query_row, &rows);
    if paths.iter().all(Option::is_none) {
        return;
    }
    let query = index.meta(query_row);
    let radius = params.verdicts.radius(index.map_spacing(&query.map_key()));
    let mut lowered = false;
    for (candidate, path) in ranked.iter_mut().zip(paths) {
        candidate.drift = path.map(|path| {
            let at = index.meta(candidate.row).pose.translation;
            let distance = squared_distance(query.pose.translation, at).sqrt();
            DriftEvidence::new(distance, path, radius, params.max_drift_ratio)
        });
        if let Some(drift) = candidate.drift.filter(|d| d.penalty > 0.0) {
            candidate.score -= drift.penalty;
            lowered = true;
        }
    }
    if lowered {
        sort_ranked(ranked);
    }
}

/// Leaves out, where `vpr.leave_out_rivals_beyond_drift` is on, every
/// candidate of the query's own map beyond the drift envelope that ranks
/// below one within it ([`drift`](crate::vpr::drift)): the map already
/// explains the query by a place its drift allows. Runs on the final
/// order (after the verdicts), so a rival that outranks every allowed
/// candidate stays, lowered as the envelope lowered it; candidates of
/// other maps and unmeasured ones are never touched.
pub fn leave_out_rivals_beyond_drift(params: &VprParams, ranked: &mut Vec<RankedCandidate>) {
    if !params.leave_out_rivals_beyond_drift {
        return;
    }
    let mut explained = false;
    ranked.retain(|candidate| match candidate.drift {
        Some(drift) if drift.beyond() => !explained,
        Some(_) => {
            explained = true;
            true
        }
        None => true,
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

    /// A map driven along straight segments: keyframe `i` at
    /// `positions[i]`, every descriptor alike, so every earlier keyframe is
    /// ranked and only the rules decide.
    fn map_along(positions: &[[f64; 3]]) -> Index {
        let mut index = Index::new(2);
        for (id, &translation) in positions.iter().enumerate() {
            index.upsert(SemanticKeyframe {
                key: drive().keyframe(id as u64),
                frame_id: id as u64,
                timestamp: id as f64,
                map_id: 0,
                pose: Pose {
                    translation,
                    ..Pose::default()
                },
                features: Features {
                    descriptor: vec![0.6, 0.8],
                    ..Features::default()
                },
            });
        }
        index
    }

    /// 141 keyframes 1.5 m apart, 105 m east and back to the start (210 m
    /// driven), then the query's keyframe at `query`.
    fn out_and_back(query: [f64; 3]) -> Vec<[f64; 3]> {
        let east = (0..=70).map(|i| [1.5 * f64::from(i), 0.0, 0.0]);
        let west = (1..=70).map(|i| [105.0 - 1.5 * f64::from(i), 0.0, 0.0]);
        east.chain(west).chain([query]).collect()
    }

    /// The drift evidence of keyframe `id` among `answer`'s candidates,
    /// which must hold it.
    fn drift_of(answer: &Answer, index: &Index, id: u64) -> DriftEvidence {
        answer
            .candidates
            .iter()
            .find(|c| index.meta(c.row).key.keyframe_id == id)
            .unwrap_or_else(|| panic!("keyframe {id} is proposed"))
            .drift
            .expect("a candidate of the query's map is measured")
    }

    /// The row of the drive's last keyframe (erasures move rows).
    fn last_row(index: &Index) -> usize {
        (0..index.len())
            .max_by_key(|&row| index.meta(row).key.keyframe_id)
            .unwrap()
    }

    fn drive() -> SessionKey {
        SessionKey {
            robot_id: "r".into(),
            session_id: "s".into(),
        }
    }

    /// The answer to the drive's last keyframe (the highest id) as a loop
    /// query over its own map, with a frame gap of `gap`.
    fn loop_answer(index: &Index, params: &VprParams, gap: u64) -> Answer {
        let row = last_row(index);
        let mut query = query_of(index, row, true);
        query.context.scope = Scope::SameMap;
        query.context.min_frame_gap = gap;
        query.layers = Layers::SCAL;
        let current = index.keyframe(row).features;
        query.observation.history = vec![&current];
        answer(index, params, &query)
    }

    fn ids(answer: &Answer, index: &Index) -> Vec<u64> {
        let mut ids: Vec<u64> = answer
            .candidates
            .iter()
            .map(|c| index.meta(c.row).key.keyframe_id)
            .collect();
        ids.sort_unstable();
        ids
    }

    /// The score of keyframe `id` in `answer`, which must hold it.
    fn score_of(answer: &Answer, index: &Index, id: u64) -> f32 {
        answer
            .candidates
            .iter()
            .find(|c| index.meta(c.row).key.keyframe_id == id)
            .unwrap_or_else(|| panic!("keyframe {id} is ranked"))
            .score
    }

    fn envelope_off() -> VprParams {
        VprParams {
            max_drift_ratio: crate::vpr::drift::OFF_RATIO,
            ..VprParams::default()
        }
    }

    /// A drive 105 m east in 1.5 m steps and 105 m back west to its
    /// start, then a query 40 m north of it: keyframe 0 lies 40 m away
    /// after 250 m of path and loses the whole penalty, which takes it
    /// below a threshold it passed with the envelope off; a query 3 m
    /// north of the start instead is a revisit and keeps its score, with
    /// the envelope's numbers in its evidence.
    #[test]
    fn a_look_alike_40_m_away_after_210_m_is_lowered_out_and_a_revisit_kept() {
        use crate::vpr::drift::PENALTY;
        let away = map_along(&out_and_back([0.0, 40.0, 0.0]));
        let params = VprParams::default();
        let on = loop_answer(&away, &params, 100);
        let off = loop_answer(&away, &envelope_off(), 100);
        // Spacing 1.5 m, radius 3 spacings = 4.5 m; keyframe 0 lies 40 m
        // away after 210 m + 40 m: allowance 0.05 · 250 + 4.5 = 17 m, and
        // 40 m is past twice the ratio (29.5 m): the whole penalty.
        let look_alike = drift_of(&on, &away, 0);
        assert!((look_alike.allowance - 17.0).abs() < 1e-9);
        assert_eq!(look_alike.penalty, PENALTY);
        let (lowered, unlowered) = (score_of(&on, &away, 0), score_of(&off, &away, 0));
        assert!((unlowered - lowered - PENALTY).abs() < 1e-6);
        // At a threshold it passed by less than the penalty it is out
        // (raw scores: every keyframe looks alike here, so each one's
        // calibrated score is its null median, 0).
        let raw = |p: VprParams| VprParams {
            calibration: crate::vpr::params::Calibration::Raw,
            ..p
        };
        let unlowered = score_of(&loop_answer(&away, &raw(envelope_off()), 100), &away, 0);
        assert!(unlowered > PENALTY, "{unlowered}");
        let mut query = query_of(&away, last_row(&away), true);
        query.context.scope = Scope::SameMap;
        query.context.min_frame_gap = 100;
        query.layers = Layers::SCAL;
        let current = away.keyframe(last_row(&away)).features;
        query.observation.history = vec![&current];
        query.threshold = Some(unlowered - PENALTY / 2.0);
        assert!(!ids(&answer(&away, &raw(params.clone()), &query), &away).contains(&0));
        assert!(ids(&answer(&away, &raw(envelope_off()), &query), &away).contains(&0));
        // Back at the start instead (3 m off): untouched, with evidence.
        let back = map_along(&out_and_back([0.0, 3.0, 0.0]));
        let on = loop_answer(&back, &params, 100);
        let drift = drift_of(&on, &back, 0);
        assert!((drift.distance - 3.0).abs() < 1e-9);
        assert!((drift.path - 213.0).abs() < 1e-9, "{}", drift.path);
        assert!((drift.ratio() - 3.0 / 213.0).abs() < 1e-12);
        assert!((drift.allowance - (10.65 + 4.5)).abs() < 1e-9);
        assert_eq!(drift.penalty, 0.0);
        let off = loop_answer(&back, &envelope_off(), 100);
        assert_eq!(score_of(&on, &back, 0), score_of(&off, &back, 0));
    }

    /// The same drive in units 37 times smaller gives the same answers.
    #[test]
    fn a_store_scaled_by_1_over_37_answers_alike() {
        let positions = out_and_back([0.0, 12.0, 0.0]);
        let scaled: Vec<[f64; 3]> = positions.iter().map(|p| p.map(|x| x / 37.0)).collect();
        let (metric, small) = (map_along(&positions), map_along(&scaled));
        // Alike with the rivals beyond the envelope left out too.
        let leave_out = VprParams {
            leave_out_rivals_beyond_drift: true,
            ..VprParams::default()
        };
        let (a, b) = (
            loop_answer(&metric, &leave_out, 100),
            loop_answer(&small, &leave_out, 100),
        );
        assert_eq!(ids(&a, &metric), ids(&b, &small));
        let params = VprParams::default();
        let a = loop_answer(&metric, &params, 100);
        let b = loop_answer(&small, &params, 100);
        assert_eq!(ids(&a, &metric), ids(&b, &small));
        // Keyframe 0: 12 m after 222 m, within 15.6 m. Keyframe 10 (15 m
        // east): 19.21 m after 207 m, 4.36 m past 14.85 m of a 10.35 m
        // ramp. Keyframe 19 (28.5 m east): 30.92 m after 193.5 m, past
        // twice the ratio (23.85 m).
        assert_eq!(drift_of(&a, &metric, 0).penalty, 0.0);
        let p10 = drift_of(&a, &metric, 10).penalty;
        let expected = 0.1 * ((15f64.hypot(12.0) - 14.85) / 10.35) as f32;
        assert!((p10 - expected).abs() < 1e-6, "{p10} against {expected}");
        assert_eq!(drift_of(&a, &metric, 19).penalty, 0.1);
        for (x, y) in a.candidates.iter().zip(&b.candidates) {
            assert_eq!(x.score, y.score);
            let (x, y) = (x.drift.unwrap(), y.drift.unwrap());
            assert!((x.ratio() - y.ratio()).abs() < 1e-9);
            assert!((x.penalty - y.penalty).abs() < 1e-6);
        }
    }

    /// A loop closure's pose update moves the query's keyframe back onto
    /// its first visit: the candidate lowered before keeps its score after.
    #[test]
    fn a_pose_update_that_closes_a_loop_changes_the_decision() {
        let mut index = map_along(&out_and_back([0.0, 40.0, 0.0]));
        let params = VprParams::default();
        let before = loop_answer(&index, &params, 100);
        assert_eq!(drift_of(&before, &index, 0).penalty, 0.1);
        let mut corrected = index.keyframe(last_row(&index));
        corrected.pose.translation = [0.0, 1.0, 0.0];
        index.upsert(corrected);
        let after = loop_answer(&index, &params, 100);
        assert_eq!(drift_of(&after, &index, 0).penalty, 0.0);
        assert!(score_of(&after, &index, 0) > score_of(&before, &index, 0));
    }

    /// Erasing keyframes in the middle of the track keeps the path whole:
    /// it runs straight over the gap, and the decision stays.
    #[test]
    fn erasures_keep_the_chain() {
        let mut index = map_along(&out_and_back([0.0, 3.0, 0.0]));
        for id in 30..40 {
            index.remove(&drive().keyframe(id));
        }
        let answer = loop_answer(&index, &VprParams::default(), 100);
        // Keyframes 30–39 lay on the straight eastward leg: the straight
        // line over them is as long as they were.
        assert!((drift_of(&answer, &index, 0).path - 213.0).abs() < 1e-9);
        let k29 = index.row_of(&drive().keyframe(29)).unwrap();
        let paths = index.track_paths(last_row(&index), &[k29]);
        assert!((paths[0].unwrap() - (213.0 - 29.0 * 1.5)).abs() < 1e-9);
    }

    /// A query 3 m north of the drive's start: the keyframes near the
    /// start are revisits within the envelope and rank first; those
    /// farther along the eastward leg lie beyond it, lowered below them,
    /// and are left out (kept, lowered, with the rule off). A query 40 m
    /// north has no candidate within the envelope: the rule leaves its
    /// ranking as it was.
    #[test]
    fn rivals_beyond_the_envelope_below_a_revisit_are_left_out() {
        let leave_out = VprParams {
            leave_out_rivals_beyond_drift: true,
            ..VprParams::default()
        };
        let keep = VprParams::default();
        let back = map_along(&out_and_back([0.0, 3.0, 0.0]));
        let (on, off) = (
            loop_answer(&back, &leave_out, 100),
            loop_answer(&back, &keep, 100),
        );
        let beyond = |a: &Answer| {
            a.candidates
                .iter()
                .filter(|c| c.drift.expect("measured").beyond())
                .count()
        };
        let within = |a: &Answer| {
            a.candidates
                .iter()
                .filter(|c| !c.drift.expect("measured").beyond())
                .map(|c| c.row)
                .collect::<Vec<_>>()
        };
        assert!(beyond(&off) > 0);
        assert_eq!(beyond(&on), 0);
        assert!(!within(&on).is_empty());
        assert_eq!(within(&on), within(&off));
        assert_eq!(on.candidates[0].row, off.candidates[0].row);

        let away = map_along(&out_and_back([0.0, 40.0, 0.0]));
        let rows = |a: &Answer| a.candidates.iter().map(|c| c.row).collect::<Vec<_>>();
        let (on, off) = (
            loop_answer(&away, &leave_out, 100),
            loop_answer(&away, &keep, 100),
        );
        assert!(!on.candidates.is_empty());
        assert_eq!(rows(&on), rows(&off));
    }
}
