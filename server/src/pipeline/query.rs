//! One query over the index, as the service asks it: resolve what the
//! query is (the features it sent or the stored keyframe it names), its
//! context and its temporal history; hand that to the core once
//! ([`humem_core::query::answer`]: eligibility, the scan and the paper's
//! layers, the rules on top, the selection); and spell out the evidence of
//! each selected candidate (the classes and strings behind its matches).
//!
//! It runs under the index's read lock on a blocking thread (an exact pass
//! over a large store takes the lock afresh for each piece of rows, so the
//! writer is not held up by it: [`run_releasing`]); it allocates only for
//! the query's own history and the returned candidates.

use std::ops::Deref;
use std::time::Duration;

use super::request::{InvalidField, Observation, QuerySpec};
use humem_core::index::Index;
use humem_core::keyframe::{Features, KeyframeKey, ObjectObservation, Pose};
use humem_core::query::{self, IndexQuery};
use humem_core::vpr::calibration::NullModel;
use humem_core::vpr::contradiction::{Contradiction, MissingObject, TextConflict};
use humem_core::vpr::drift::DriftEvidence;
use humem_core::vpr::eligibility::{QueryContext, Scope};
use humem_core::vpr::feedback::VerdictEffect;
use humem_core::vpr::memory::KeyframeMemory;
use humem_core::vpr::ogtl::TextMatch;
use humem_core::vpr::operating_point::OperatingPoint;
use humem_core::vpr::osrl::ObjectMatch;
use humem_core::vpr::params::VprParams;
use humem_core::vpr::rank::{QueryObservation, RankedCandidate};
use humem_core::vpr::scal::ScalHit;

/// Why a query cannot be answered.
#[derive(Debug, thiserror::Error)]
pub enum QueryError {
    /// A field is wrong in a way only the index reveals (descriptor
    /// length, a frame or map id the stored keyframe cannot supply).
    #[error(transparent)]
    Invalid(#[from] InvalidField),
    /// The query names a keyframe that is not stored and sends no features
    /// to stand in for it.
    #[error("keyframe {} of robot {:?}, session {:?} is not stored, and the query sends no features", .0.keyframe_id, .0.robot_id, .0.session_id)]
    NotStored(KeyframeKey),
}

/// A matched object pair, with its class.
#[derive(Debug, Clone)]
pub struct ObjectPair {
    /// The pair's indices and scores (`M_o`, `G`).
    pub matched: ObjectMatch,
    /// Class of the query object.
    pub class_name: String,
}

/// A matched string pair, with the strings.
#[derive(Debug, Clone)]
pub struct TextPair {
    /// The pair's indices and scores (`S_str`, `M_T`, `D_T`).
    pub matched: TextMatch,
    /// The query's string.
    pub query_text: String,
    /// The candidate's string.
    pub candidate_text: String,
}

/// A pair of disagreeing distinctive texts, with the strings.
#[derive(Debug, Clone)]
pub struct ConflictPair {
    /// The pair's indices, agreement and disagreement `κ`.
    pub conflict: TextConflict,
    /// The query's string of the best-agreeing pair.
    pub query_text: String,
    /// The candidate's string of that pair.
    pub candidate_text: String,
}

/// A missing distinctive object, with its class.
#[derive(Debug, Clone)]
pub struct MissingPair {
    /// Which side lacks it, its index and its weight in `X_o`.
    pub missing: MissingObject,
    /// Class of the missing object.
    pub class_name: String,
}

/// A selected candidate and why.
#[derive(Debug, Clone)]
pub struct Candidate {
    /// The stored keyframe proposed: robot, session and keyframe id.
    pub key: KeyframeKey,
    /// Its source-frame id.
    pub frame_id: u64,
    /// Its timestamp, in seconds.
    pub timestamp: f64,
    /// Its atlas map id within its session.
    pub map_id: u64,
    /// Its stored camera pose in that map.
    pub pose: Pose,
    /// The score the threshold applied to (see `humem_core::vpr::rank::RankedCandidate`).
    pub score: f32,
    /// The paper's Λ.
    pub raw_score: f32,
    /// `c_s` (calibrated) or `S_s` (raw calibration).
    pub scene_confidence: f32,
    /// The query's null distribution (`m`, the median `S_s`, and its sample
    /// count), the same for every candidate.
    pub null: NullModel,
    /// SCAL evidence: `S_s`, `s_e`, `C_cat` and the temporal depth.
    pub scene: ScalHit,
    /// `S_o` ∈ [0, 1], the object-layout score; 0 when OSRL is off.
    pub object_score: f32,
    /// `S_t` ∈ [0, 1], the object-grounded text score; 0 when OGTL is off.
    pub text_score: f32,
    /// `E_t` ∈ [0, 1], the distinctiveness weight of the text evidence.
    pub text_distinctiveness: f32,
    /// `B = clip(g_o S_o + g_t E_t S_t, 0, 1)`, the combined corroboration.
    pub corroboration: f32,
    /// Matched object pairs (OSRL), by query object.
    pub object_matches: Vec<ObjectPair>,
    /// Matched string pairs on matched objects (OGTL).
    pub text_matches: Vec<TextPair>,
    /// `X_t`, `X_o` and `C` (the pairs are spelled out below).
    pub contradiction: Contradiction,
    /// Object pairs whose distinctive texts disagree, with the strings.
    pub text_conflicts: Vec<ConflictPair>,
    /// Distinctive objects without a counterpart, with their classes.
    pub missing_objects: Vec<MissingPair>,
    /// What SLAM's verdicts did to the score.
    pub verdict: VerdictEffect,
    /// The drift envelope's distance, path and allowance, for a candidate
    /// of the query's own map (`humem_core::vpr::drift`).
    pub drift: Option<DriftEvidence>,
}

/// The answer to a query.
#[derive(Debug, Clone, Default)]
pub struct QueryOutcome {
    /// Candidates scoring above the threshold (every ranked one for a
    /// threshold of 0), best first, at most `top_n`.
    pub candidates: Vec<Candidate>,
    /// Stored keyframes that passed eligibility and scope.
    pub eligible: u64,
    /// Predecessor keyframes used for temporal context, most recent first.
    pub used_predecessors: Vec<u64>,
    /// Time per stage.
    pub timings: Vec<(&'static str, Duration)>,
    /// The threshold applied to the candidates' scores: the request's, or
    /// else the store's operating point.
    pub threshold: f32,
    /// The store's operating point when the query ran (what a request
    /// naming no threshold gets).
    pub operating_point: OperatingPoint,
}

/// Runs a validated query against the index: what the query shows, its
/// context and temporal history, then ranking, selection and the evidence
/// of each candidate.
pub fn run(
    index: &Index,
    params: &VprParams,
    spec: &QuerySpec,
) -> Result<QueryOutcome, QueryError> {
    run_scanning(index, || index, params, spec, true)
}

/// [`run`] over an index shared with a writer: `first` is a hold of it
/// and `read` takes another. An exact pass over a large store lets the
/// index go between pieces of rows
/// ([`humem_core::query::answer_releasing`]), so that the writer and the
/// other queries do not wait for the whole pass.
pub fn run_releasing<G, R>(
    first: G,
    read: R,
    params: &VprParams,
    spec: &QuerySpec,
) -> Result<QueryOutcome, QueryError>
where
    G: Deref<Target = Index>,
    R: Fn() -> G,
{
    run_scanning(first, read, params, spec, true)
}

/// [`run`] with a scan of every stored row, even when the query may see
/// only a few maps: the same answer, at the cost of the whole store. The
/// reference `humem bench scan` measures and checks the partitioned scan
/// against.
pub fn run_full_scan(
    index: &Index,
    params: &VprParams,
    spec: &QuerySpec,
) -> Result<QueryOutcome, QueryError> {
    run_scanning(index, || index, params, spec, false)
}

fn run_scanning<G, R>(
    index: G,
    read: R,
    params: &VprParams,
    spec: &QuerySpec,
    partitioned: bool,
) -> Result<QueryOutcome, QueryError>
where
    G: Deref<Target = Index>,
    R: Fn() -> G,
{
    let stored_row = spec
        .keyframe_id
        .and_then(|keyframe_id| index.row_of(&spec.session.keyframe(keyframe_id)));
    let current = current_features(&index, spec, stored_row)?;
    let context = query_context(&index, spec, stored_row)?;
    let predecessor_rows = predecessor_rows(&index, params, spec, stored_row);
    let predecessors: Vec<Features> = predecessor_rows
        .iter()
        .map(|&row| index.keyframe(row).features)
        .collect();
    let used_predecessors = predecessor_rows
        .iter()
        .map(|&row| index.meta(row).key.keyframe_id)
        .collect();
    let mut history = vec![&current];
    history.extend(predecessors.iter());
    let (index, answer) = query::answer_releasing(
        index,
        read,
        params,
        &IndexQuery {
            observation: QueryObservation { history },
            context,
            layers: spec.layers,
            stored_row,
            threshold: spec.threshold,
            top_n: spec.top_n,
            partitioned,
            exact: spec.exact,
        },
    );
    Ok(QueryOutcome {
        candidates: answer
            .candidates
            .into_iter()
            .map(|r| candidate(&index, &current, r))
            .collect(),
        eligible: answer.eligible as u64,
        used_predecessors,
        timings: answer.times.stages().to_vec(),
        threshold: answer.threshold,
        operating_point: answer.operating_point,
    })
}

/// What the query shows: the features it sent, or else those of the stored
/// keyframe it names; checked against the store's descriptor length.
fn current_features(
    index: &Index,
    spec: &QuerySpec,
    stored_row: Option<usize>,
) -> Result<Features, QueryError> {
    let sent = match &spec.observation {
        Some(Observation::Features(features)) => Some(features),
        Some(Observation::Image(_, field)) => {
            return Err(InvalidField {
                field: field.clone(),
                reason: "images must be turned into features before ranking".into(),
            }
            .into())
        }
        None => None,
    };
    let current = match (sent, stored_row) {
        (Some(features), _) => features.clone(),
        (None, Some(row)) => index.keyframe(row).features,
        (None, None) => {
            return Err(QueryError::NotStored(
                spec.session.keyframe(spec.keyframe_id.unwrap_or_default()),
            ))
        }
    };
    if index.dim() != 0 && current.descriptor.len() != index.dim() {
        return Err(InvalidField {
            field: "features.global_descriptor".into(),
            reason: format!(
                "has {} values but this store holds {}-value descriptors",
                current.descriptor.len(),
                index.dim()
            ),
        }
        .into());
    }
    Ok(current)
}

/// Who asks and where, for eligibility: frame and map ids as sent, or else
/// those of the stored keyframe the query names.
fn query_context(
    index: &Index,
    spec: &QuerySpec,
    stored_row: Option<usize>,
) -> Result<QueryContext, QueryError> {
    let stored_meta = stored_row.map(|row| index.meta(row));
    let frame_id = spec
        .frame_id
        .or(stored_meta.map(|m| m.frame_id))
        .ok_or_else(|| InvalidField {
            field: "frame_id".into(),
            reason: "required unless keyframe_id names a stored keyframe".into(),
        })?;
    let map_id = spec.map_id.or(stored_meta.map(|m| m.map_id));
    let map_id = match (&spec.scope, map_id) {
        (Scope::SameMap | Scope::OtherMaps, None) => {
            return Err(InvalidField {
                field: "map_id".into(),
                reason: "required for SCOPE_SAME_MAP and SCOPE_OTHER_MAPS unless keyframe_id names a stored keyframe".into(),
            }
            .into())
        }
        (_, map_id) => map_id.unwrap_or_default(),
    };
    Ok(QueryContext {
        session: spec.session.clone(),
        keyframe_id: spec.keyframe_id,
        frame_id,
        map_id,
        min_frame_gap: spec.min_frame_gap,
        scope: spec.scope.clone(),
        readable_robots: spec.readable_robots.clone(),
    })
}

/// Temporal context: the rows of the predecessors the client names, or else
/// the stored predecessors of the query keyframe, most recent first, as many
/// as the temporal weights use.
fn predecessor_rows(
    index: &Index,
    params: &VprParams,
    spec: &QuerySpec,
    stored_row: Option<usize>,
) -> Vec<usize> {
    let depth = params.alpha.len().saturating_sub(1);
    if spec.predecessor_ids.is_empty() {
        std::iter::successors(stored_row, |&row| index.predecessor(row))
            .skip(1)
            .take(depth)
            .collect()
    } else {
        spec.predecessor_ids
            .iter()
            .filter_map(|&keyframe_id| index.row_of(&spec.session.keyframe(keyframe_id)))
            .take(depth)
            .collect()
    }
}

/// A selected candidate with its evidence spelled out: the classes and
/// strings behind every matched, conflicting or missing object.
fn candidate(index: &Index, current: &Features, r: RankedCandidate) -> Candidate {
    let meta = index.meta(r.row);
    let cand_objects = index.objects(r.row);
    let text_conflicts = r
        .contradiction
        .conflicts
        .iter()
        .map(|&conflict| ConflictPair {
            query_text: text_of(&current.objects, conflict.query_object, conflict.query_text),
            candidate_text: text_of(
                cand_objects,
                conflict.candidate_object,
                conflict.candidate_text,
            ),
            conflict,
        })
        .collect();
    let missing_objects = r
        .contradiction
        .missing
        .iter()
        .map(|&missing| MissingPair {
            class_name: if missing.in_query {
                &current.objects[missing.object]
            } else {
                &cand_objects[missing.object]
            }
            .class_name
            .clone(),
            missing,
        })
        .collect();
    Candidate {
        key: meta.key.clone(),
        frame_id: meta.frame_id,
        timestamp: meta.timestamp,
        map_id: meta.map_id,
        pose: meta.pose,
        score: r.score,
        raw_score: r.raw_score,
        scene_confidence: r.scene_confidence,
        null: r.null,
        scene: r.scene,
        object_score: r.objects.score,
        text_score: r.text.score,
        text_distinctiveness: r.text.evidence_weight,
        corroboration: r.corroboration,
        object_matches: r
            .objects
            .matches
            .into_iter()
            .map(|m| ObjectPair {
                class_name: current.objects[m.query_object].class_name.clone(),
                matched: m,
            })
            .collect(),
        text_matches: r
            .text
            .matches
            .into_iter()
            .map(|m| TextPair {
                query_text: text_of(&current.objects, m.query_object, m.query_text),
                candidate_text: text_of(cand_objects, m.candidate_object, m.candidate_text),
                matched: m,
            })
            .collect(),
        contradiction: r.contradiction,
        text_conflicts,
        missing_objects,
        verdict: r.verdict,
        drift: r.drift,
    }
}

/// String `text` of object `object`, as evidence names it.
fn text_of(objects: &[ObjectObservation], object: usize, text: usize) -> String {
    objects[object].texts[text].text.clone()
}

#[cfg(test)]
mod tests {
    use super::*;
    use humem_core::keyframe::{Features, SemanticKeyframe, SessionKey};

    /// A keyframe of session "s" looking along `yaw_deg` (about the map's
    /// z axis), with one descriptor for all, so that only the viewpoint
    /// rule tells them apart.
    fn looking(id: u64, map_id: u64, yaw_deg: f64) -> SemanticKeyframe {
        let h = yaw_deg.to_radians() / 2.0;
        SemanticKeyframe {
            key: SessionKey {
                robot_id: "r".into(),
                session_id: "s".into(),
            }
            .keyframe(id),
            frame_id: id,
            timestamp: id as f64,
            map_id,
            // All at one place: only the view decides.
            pose: Pose {
                translation: [0.0; 3],
                rotation: [h.cos(), 0.0, 0.0, h.sin()],
            },
            features: Features {
                descriptor: vec![0.5; 4],
                ..Features::default()
            },
        }
    }

    /// The ids every stored keyframe of `index` is answered with for
    /// keyframe 100, over every map, at threshold 0.
    fn answered(index: &Index, params: &VprParams) -> Vec<u64> {
        let spec = QuerySpec {
            session: SessionKey {
                robot_id: "r".into(),
                session_id: "s".into(),
            },
            map_id: None,
            frame_id: None,
            keyframe_id: Some(100),
            observation: None,
            predecessor_ids: Vec::new(),
            scope: Scope::AllMaps,
            readable_robots: None,
            min_frame_gap: 10,
            top_n: 50,
            threshold: Some(0.0),
            layers: humem_core::vpr::params::Layers::FULL,
            kind: super::super::request::QueryKind::LoopClosure,
            exact: false,
        };
        let mut ids: Vec<u64> = run(index, params, &spec)
            .unwrap()
            .candidates
            .iter()
            .map(|c| c.key.keyframe_id)
            .collect();
        ids.sort_unstable();
        ids
    }

    /// Keyframe 100 looks along 0°. In its map: 0 at 90° (left out), 1 at
    /// 59° and 2 at −30° (kept), 3 at 180° (left out); in map 1: 4 at 90°
    /// (kept: another map's frame says nothing about this one's). Twenty
    /// more keyframes at 0° give the null its samples.
    #[test]
    fn candidates_of_the_query_map_turned_away_from_it_are_left_out() {
        let mut index = Index::new(4);
        for (id, map, yaw) in [
            (0, 0, 90.0),
            (1, 0, 59.0),
            (2, 0, -30.0),
            (3, 0, 180.0),
            (4, 1, 90.0),
        ] {
            index.upsert(looking(id, map, yaw));
        }
        for id in 10..30 {
            index.upsert(looking(id, 0, 0.0));
        }
        index.upsert(looking(100, 0, 0.0));
        let params = VprParams::default();
        let kept = answered(&index, &params);
        assert!(!kept.contains(&0) && !kept.contains(&3), "{kept:?}");
        assert!(
            kept.contains(&1) && kept.contains(&2) && kept.contains(&4),
            "{kept:?}"
        );
        let off = VprParams {
            max_view_change_deg: humem_core::vpr::viewpoint::OFF_DEG,
            ..VprParams::default()
        };
        let all = answered(&index, &off);
        assert!(all.contains(&0) && all.contains(&3), "{all:?}");
        assert_eq!(all.len(), kept.len() + 2);
    }
}
