//! One query, end to end: SCAL over the eligible store, the corroborating
//! layers on its top K, fusion, ordering and selection.
//!
//! This is the only place that knows the order of the layers; each layer is
//! a pure function of its own inputs. Layers switched off by [`Layers`]
//! contribute empty evidence, so ablations run the same code path. Every
//! ranked candidate keeps all of its evidence (`S_s`, `S_o`, `S_t`, `E_t`,
//! the matched pairs) so that a person can see why it was proposed.

use std::cmp::Ordering;
use std::time::{Duration, Instant};

use crate::keyframe::Features;
use crate::vpr::fusion::{corroboration, fuse};
use crate::vpr::memory::KeyframeMemory;
use crate::vpr::ogtl::{ogtl, text_profile_in, OgtlResult};
use crate::vpr::osrl::{osrl, OsrlResult};
use crate::vpr::params::{Layers, VprParams};
use crate::vpr::scal::{scal_scores, ScalHit, ScalQuery};

/// The query: its current observation and recent predecessors.
#[derive(Debug, Clone, PartialEq)]
pub struct QueryObservation<'a> {
    /// `[0]` is the current observation (its objects are the query
    /// objects), then predecessors most recent first.
    pub history: Vec<&'a Features>,
}

/// A candidate with all of its evidence.
#[derive(Debug, Clone, PartialEq)]
pub struct RankedCandidate {
    /// Row in the [`KeyframeMemory`].
    pub row: usize,
    /// SCAL evidence (`S_s`, `s_e`, `C_cat`, depth).
    pub scene: ScalHit,
    /// OSRL evidence (`S_o`, matched objects); empty when the layer is off.
    pub objects: OsrlResult,
    /// OGTL evidence (`S_t`, `E_t`, matched strings); empty when off.
    pub text: OgtlResult,
    /// `B`.
    pub corroboration: f32,
    /// `Λ`.
    pub score: f32,
}

/// Final order: `Λ` descending, then `S_s` descending, then lower row.
fn by_fused_score(a: &RankedCandidate, b: &RankedCandidate) -> Ordering {
    b.score
        .total_cmp(&a.score)
        .then(b.scene.score.total_cmp(&a.scene.score))
        .then(a.row.cmp(&b.row))
}

/// Ranks the eligible rows of `memory` for `query`: SCAL top K, then OSRL
/// and OGTL (as enabled) on those K only, `B`, `Λ`, sorted by `Λ`.
pub fn rank<M: KeyframeMemory + ?Sized>(
    params: &VprParams,
    layers: Layers,
    query: &QueryObservation,
    memory: &M,
    eligible: &dyn Fn(usize) -> bool,
) -> Vec<RankedCandidate> {
    rank_timed(params, layers, query, memory, eligible).0
}

/// Wall time spent in each layer by one [`rank_timed`] call.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StageTimes {
    pub scal: Duration,
    pub osrl: Duration,
    pub ogtl: Duration,
    pub fusion: Duration,
}

impl StageTimes {
    /// `(stage name, time)` pairs, in pipeline order.
    pub fn stages(&self) -> [(&'static str, Duration); 4] {
        [
            ("scal", self.scal),
            ("osrl", self.osrl),
            ("ogtl", self.ogtl),
            ("fusion", self.fusion),
        ]
    }
}

/// [`rank`], also reporting the time spent in each layer (reading the clock
/// is the only side effect).
pub fn rank_timed<M: KeyframeMemory + ?Sized>(
    params: &VprParams,
    layers: Layers,
    query: &QueryObservation,
    memory: &M,
    eligible: &dyn Fn(usize) -> bool,
) -> (Vec<RankedCandidate>, StageTimes) {
    let mut times = StageTimes::default();
    let Some(current) = query.history.first() else {
        return (Vec::new(), times);
    };
    let scal_query = ScalQuery {
        history: query.history.clone(),
    };
    let clock = Instant::now();
    let hits = scal_scores(params, &scal_query, memory, eligible);
    times.scal = clock.elapsed();
    let query_objects = &current.objects;
    // The query side of OGTL is computed once, not once per candidate.
    let clock = Instant::now();
    let query_profile = layers
        .ogtl
        .then(|| text_profile_in(query_objects, memory, params));
    times.ogtl += clock.elapsed();

    let mut ranked: Vec<RankedCandidate> = hits
        .into_iter()
        .map(|scene| {
            let cand_objects = memory.objects(scene.row);
            let clock = Instant::now();
            let objects = if layers.osrl {
                osrl(query_objects, cand_objects, params)
            } else {
                OsrlResult::default()
            };
            times.osrl += clock.elapsed();
            let clock = Instant::now();
            let text = match &query_profile {
                Some(qp) => {
                    let cp = text_profile_in(cand_objects, memory, params);
                    ogtl(query_objects, qp, cand_objects, &cp, params)
                }
                None => OgtlResult::default(),
            };
            times.ogtl += clock.elapsed();
            let clock = Instant::now();
            let b = corroboration(objects.score, text.score, text.evidence_weight, params);
            let score = fuse(scene.score, b);
            times.fusion += clock.elapsed();
            RankedCandidate {
                row: scene.row,
                score,
                scene,
                objects,
                text,
                corroboration: b,
            }
        })
        .collect();
    let clock = Instant::now();
    ranked.sort_unstable_by(by_fused_score);
    times.fusion += clock.elapsed();
    (ranked, times)
}

/// The candidates with `Λ > threshold` (strict), at most `max`, in the
/// given (ranked) order.
pub fn select(ranked: Vec<RankedCandidate>, threshold: f32, max: usize) -> Vec<RankedCandidate> {
    ranked
        .into_iter()
        .filter(|c| c.score > threshold)
        .take(max)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vpr::memory::VecMemory;
    use crate::vpr::testing::{close, features, object, objects_strategy, unit_vector, with_texts};
    use proptest::prelude::*;

    /// Row 0: s_e = 0.6 with a sign identical to the query's ("B-214" vs
    /// "b214"); row 1: s_e = 0.8, no objects.
    fn store() -> VecMemory {
        let mut m = VecMemory::new(2);
        let sign = with_texts(object("sign", 1.0, 0.5, 0.5, 0.1), &[("B-214", 1.0)]);
        m.push(features(&[0.6, 0.8], &[], vec![sign]), None);
        m.push(features(&[0.8, 0.6], &[], vec![]), None);
        m
    }

    fn query() -> Features {
        let sign = with_texts(object("sign", 1.0, 0.5, 0.5, 0.1), &[("b214", 1.0)]);
        features(&[1.0, 0.0], &[], vec![sign])
    }

    fn run(layers: Layers) -> Vec<RankedCandidate> {
        let m = store();
        let q = query();
        rank(
            &VprParams::default(),
            layers,
            &QueryObservation { history: vec![&q] },
            &m,
            &|_| true,
        )
    }

    #[test]
    fn full_pipeline_by_hand() {
        // Row 0: S_s = 0.6; S_o = 1 (identical sign, confidences 1);
        // S_str = C = 1 → M_T = 1 → S_T = S_t = 1; D of both strings is
        // 0.666667 (store < 10 keyframes) → E_t = 0.666667.
        // B = 0.15 · 1 + 0.25 · 0.666667 · 1 = 0.316667;
        // Λ = 0.6 + 0.4 · 0.316667 = 0.726667.
        // Row 1: S_s = 0.8, B = 0 → Λ = 0.8, ranked first.
        let r = run(Layers::FULL);
        assert_eq!(r.len(), 2);
        assert_eq!(r[0].row, 1);
        assert!(close(r[0].score, 0.8));
        assert_eq!(r[1].row, 0);
        assert!(close(r[1].scene.score, 0.6));
        assert!(close(r[1].objects.score, 1.0));
        assert!(close(r[1].text.score, 1.0));
        assert!(close(r[1].text.evidence_weight, 0.666667));
        assert!(close(r[1].corroboration, 0.316667));
        assert!(close(r[1].score, 0.726667));
        assert_eq!(r[1].objects.matches.len(), 1);
        assert_eq!(r[1].text.matches.len(), 1);
        // Both pass τ_s = 0.7.
        assert_eq!(select(r, 0.7, 5).len(), 2);
    }

    #[test]
    fn ablations_are_configurations() {
        // SCAL only: Λ = S_s = 0.6, no evidence.
        let r = run(Layers::SCAL);
        let row0 = r.iter().find(|c| c.row == 0).unwrap();
        assert!(close(row0.score, 0.6));
        assert_eq!(row0.objects, OsrlResult::default());
        assert_eq!(row0.text, OgtlResult::default());
        // SCAL+OSRL: B = 0.15 → Λ = 0.6 + 0.4 · 0.15 = 0.66.
        let r = run(Layers::SCAL_OSRL);
        let row0 = r.iter().find(|c| c.row == 0).unwrap();
        assert!(close(row0.score, 0.66));
        assert_eq!(row0.text, OgtlResult::default());
        // SCAL+OGTL: B = 0.166667 → Λ = 0.6 + 0.4 · 0.166667 = 0.666667.
        let r = run(Layers::SCAL_OGTL);
        let row0 = r.iter().find(|c| c.row == 0).unwrap();
        assert!(close(row0.score, 0.666667));
        assert_eq!(row0.objects, OsrlResult::default());
    }

    #[test]
    fn empty_query_or_store() {
        let m = store();
        let none = QueryObservation { history: vec![] };
        assert!(rank(&VprParams::default(), Layers::FULL, &none, &m, &|_| true).is_empty());
        let q = query();
        let some = QueryObservation { history: vec![&q] };
        assert!(rank(&VprParams::default(), Layers::FULL, &some, &m, &|_| false).is_empty());
        let empty = VecMemory::new(2);
        assert!(
            rank(&VprParams::default(), Layers::FULL, &some, &empty, &|_| {
                true
            })
            .is_empty()
        );
    }

    fn candidate(row: usize, s_s: f32, score: f32) -> RankedCandidate {
        RankedCandidate {
            row,
            scene: ScalHit {
                row,
                score: s_s,
                cosine: s_s,
                scene_compatibility: None,
                depth: 1,
            },
            objects: OsrlResult::default(),
            text: OgtlResult::default(),
            corroboration: 0.0,
            score,
        }
    }

    #[test]
    fn order_ties_break_on_scene_score_then_row() {
        let mut v = [
            candidate(3, 0.6, 0.8),
            candidate(2, 0.8, 0.8),
            candidate(1, 0.6, 0.8),
            candidate(0, 0.5, 0.9),
        ];
        v.sort_by(by_fused_score);
        let rows: Vec<usize> = v.iter().map(|c| c.row).collect();
        assert_eq!(rows, vec![0, 2, 1, 3]);
    }

    #[test]
    fn selection_is_strict_and_bounded() {
        let ranked = vec![
            candidate(0, 0.9, 0.95),
            candidate(1, 0.9, 0.9),
            candidate(2, 0.8, 0.85),
            candidate(3, 0.7, 0.7000001),
            candidate(4, 0.7, 0.7),
            candidate(5, 0.6, 0.65),
        ];
        // Λ = 0.7 exactly is not > 0.7; 0.7000001 is.
        let rows = |v: Vec<RankedCandidate>| v.iter().map(|c| c.row).collect::<Vec<_>>();
        assert_eq!(rows(select(ranked.clone(), 0.7, 5)), vec![0, 1, 2, 3]);
        assert_eq!(rows(select(ranked.clone(), 0.7, 2)), vec![0, 1]);
        assert_eq!(rows(select(ranked.clone(), 0.7, 0)), Vec::<usize>::new());
        assert_eq!(rows(select(ranked, 0.99, 5)), Vec::<usize>::new());
    }

    fn store_strategy() -> impl Strategy<Value = VecMemory> {
        prop::collection::vec((unit_vector(3), objects_strategy(4), any::<bool>()), 0..30).prop_map(
            |rows| {
                let mut m = VecMemory::new(3);
                for (i, (d, objects, linked)) in rows.into_iter().enumerate() {
                    let pred = (linked && i > 0).then(|| i - 1);
                    m.push(features(&d, &[], objects), pred);
                }
                m
            },
        )
    }

    proptest! {
        #[test]
        fn ranked_scores_are_bounded_and_sorted(
            m in store_strategy(),
            d in unit_vector(3),
            objects in objects_strategy(4),
            k in 1usize..10,
        ) {
            let q = features(&d, &[], objects);
            let params = VprParams { top_k: k, ..VprParams::default() };
            let query = QueryObservation { history: vec![&q] };
            let full = rank(&params, Layers::FULL, &query, &m, &|_| true);
            prop_assert!(full.len() <= k);
            for c in &full {
                prop_assert!((0.0..=1.0).contains(&c.score));
                prop_assert!(c.score >= c.scene.score);
                prop_assert!((0.0..=1.0).contains(&c.corroboration));
                prop_assert!((0.0..=1.0).contains(&c.objects.score));
                prop_assert!((0.0..=1.0).contains(&c.text.score));
                prop_assert!((0.0..=1.0).contains(&c.text.evidence_weight));
            }
            prop_assert!(full.windows(2).all(|w| w[0].score >= w[1].score));

            // SCAL only: Λ = S_s exactly, same candidates as SCAL's top K.
            let scal = rank(&params, Layers::SCAL, &query, &m, &|_| true);
            for c in &scal {
                prop_assert_eq!(c.score, c.scene.score);
            }
            let mut a: Vec<usize> = full.iter().map(|c| c.row).collect();
            let mut b: Vec<usize> = scal.iter().map(|c| c.row).collect();
            a.sort_unstable();
            b.sort_unstable();
            prop_assert_eq!(a, b);
        }
    }
}
