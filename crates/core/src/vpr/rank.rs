//! One query, end to end: SCAL over the eligible store, the corroborating
//! layers and the evidence against on its top K, calibration, fusion,
//! ordering and selection.
//!
//! This is the only place that knows the order of the layers; each layer is
//! a pure function of its own inputs. Layers switched off by [`Layers`]
//! contribute empty evidence, so ablations run the same code path. Every
//! ranked candidate keeps all of its evidence (`S_s`, `S_o`, `S_t`, `E_t`,
//! the matched pairs) so that a person can see why it was proposed.

use std::cmp::Ordering;
use std::time::{Duration, Instant};

use crate::engine::filter::RowFilter;
use crate::keyframe::Features;
use crate::vpr::calibration::NullModel;
use crate::vpr::contradiction::{contradiction, Contradiction};
use crate::vpr::drift::DriftEvidence;
use crate::vpr::feedback::VerdictEffect;
use crate::vpr::fusion::{corroboration, fuse, fuse_with_contradiction};
use crate::vpr::memory::KeyframeMemory;
use crate::vpr::ogtl::{ogtl, text_profile_in, OgtlResult};
use crate::vpr::osrl::{osrl, OsrlResult};
use crate::vpr::params::{Calibration, Layers, VprParams};
use crate::vpr::scal::{ScalHit, ScalQuery};
use crate::vpr::scan::{scal_scan, ScalScan};

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
    /// Evidence against (`X_t`, `X_o`, `C`); empty when the layer is off.
    pub contradiction: Contradiction,
    /// `B`.
    pub corroboration: f32,
    /// The query's null distribution (the same for every candidate).
    pub null: NullModel,
    /// The scene score the fusion starts from: `c_s` calibrated against
    /// the null (`calibration = "null"`), or `S_s` itself (`raw`).
    pub scene_confidence: f32,
    /// The paper's `Λ = S_s + (1 − S_s) B`, whatever the calibration.
    pub raw_score: f32,
    /// The score the threshold applies to and candidates are ordered by:
    /// `scene_confidence (1 − C) + (1 − scene_confidence) B`, then changed
    /// by SLAM's verdicts where any apply ([`feedback`](crate::vpr::feedback)).
    pub score: f32,
    /// What the verdicts did to `score` (nothing until
    /// [`feedback::apply`](crate::vpr::feedback::apply) runs).
    pub verdict: VerdictEffect,
    /// The drift envelope's measure of a candidate of the query's own map
    /// ([`drift`](crate::vpr::drift)); `None` for other maps, a query
    /// without a stored keyframe, or before the rule runs.
    pub drift: Option<DriftEvidence>,
}

/// Puts candidates in their final order (after their scores changed).
pub fn sort_ranked(ranked: &mut [RankedCandidate]) {
    ranked.sort_unstable_by(by_fused_score);
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
pub fn rank<M, E>(
    params: &VprParams,
    layers: Layers,
    query: &QueryObservation,
    memory: &M,
    eligible: &E,
) -> Vec<RankedCandidate>
where
    M: KeyframeMemory + ?Sized,
    E: RowFilter + ?Sized,
{
    rank_timed(params, layers, query, memory, eligible).candidates
}

/// What [`rank_timed`] returns.
#[derive(Debug, Clone, Default)]
pub struct Ranking {
    /// The top K by SCAL, with all of their evidence, best first.
    pub candidates: Vec<RankedCandidate>,
    /// Time spent per layer.
    pub times: StageTimes,
    /// Stored rows that passed eligibility.
    pub eligible: usize,
}

/// Wall time spent in each layer by one [`rank_timed`] call.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StageTimes {
    /// The SCAL scan over every eligible row, with the null model.
    pub scal: Duration,
    /// OSRL on the top K.
    pub osrl: Duration,
    /// OGTL and the contradiction layer on the top K, text profiles
    /// included.
    pub ogtl: Duration,
    /// Corroboration, calibration, fusion and the final sort.
    pub fusion: Duration,
    /// The rules on top of the ranking and the selection: views turned
    /// away, SLAM's verdicts, the operating point
    /// ([`crate::query::answer`]; zero when only the ranking ran).
    pub rules: Duration,
}

impl StageTimes {
    /// `(stage name, time)` pairs, in pipeline order.
    pub fn stages(&self) -> [(&'static str, Duration); 5] {
        [
            ("scal", self.scal),
            ("osrl", self.osrl),
            ("ogtl", self.ogtl),
            ("fusion", self.fusion),
            ("rules", self.rules),
        ]
    }
}

/// [`rank`], also reporting the time spent in each layer (reading the clock
/// is the only side effect).
pub fn rank_timed<M, E>(
    params: &VprParams,
    layers: Layers,
    query: &QueryObservation,
    memory: &M,
    eligible: &E,
) -> Ranking
where
    M: KeyframeMemory + ?Sized,
    E: RowFilter + ?Sized,
{
    if query.history.is_empty() {
        return Ranking::default();
    }
    let scal_query = ScalQuery {
        history: query.history.clone(),
    };
    let clock = Instant::now();
    let scan = scal_scan(params, &scal_query, memory, eligible);
    rank_scanned(params, layers, query, memory, scan, clock.elapsed())
}

/// The layers after SCAL over the hits of a pass already made (`scan`,
/// which took `scal_time`): [`rank_timed`]'s second half, for a pass made
/// in pieces ([`crate::query`]).
pub fn rank_scanned<M>(
    params: &VprParams,
    layers: Layers,
    query: &QueryObservation,
    memory: &M,
    scan: ScalScan,
    scal_time: Duration,
) -> Ranking
where
    M: KeyframeMemory + ?Sized,
{
    let mut times = StageTimes {
        scal: scal_time,
        ..StageTimes::default()
    };
    let Some(current) = query.history.first() else {
        return Ranking::default();
    };
    let ScalScan {
        hits,
        null,
        eligible,
    } = scan;
    let query_objects = &current.objects;
    // The query side of OGTL is computed once, not once per candidate.
    let clock = Instant::now();
    let query_profile = (layers.ogtl || layers.contradiction)
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
            let cand_profile = query_profile
                .as_ref()
                .map(|_| text_profile_in(cand_objects, memory, params));
            let text = match (&query_profile, &cand_profile) {
                (Some(qp), Some(cp)) if layers.ogtl => {
                    ogtl(query_objects, qp, cand_objects, cp, params)
                }
                _ => OgtlResult::default(),
            };
            let against = match (&query_profile, &cand_profile) {
                (Some(qp), Some(cp)) if layers.contradiction => {
                    contradiction(query_objects, qp, cand_objects, cp, params)
                }
                _ => Contradiction::default(),
            };
            times.ogtl += clock.elapsed();
            let clock = Instant::now();
            let b = corroboration(objects.score, text.score, text.evidence_weight, params);
            let scene_confidence = match params.calibration {
                Calibration::Null => null.calibrate(scene.score, params),
                Calibration::Raw => scene.score,
            };
            let score = fuse_with_contradiction(scene_confidence, b, against.score);
            let raw_score = fuse(scene.score, b);
            times.fusion += clock.elapsed();
            RankedCandidate {
                row: scene.row,
                score,
                raw_score,
                scene_confidence,
                null,
                scene,
                objects,
                text,
                contradiction: against,
                corroboration: b,
                verdict: Default::default(),
                drift: None,
            }
        })
        .collect();
    let clock = Instant::now();
    ranked.sort_unstable_by(by_fused_score);
    times.fusion += clock.elapsed();
    Ranking {
        candidates: ranked,
        times,
        eligible,
    }
}

/// The candidates with `score > threshold` (strict), at most `max`, in the
/// given (ranked) order. A threshold of 0 keeps every ranked candidate,
/// those scoring 0 included: calibrated scores at or below the query's null
/// median are exactly 0, and a client that asks for no threshold (the
/// evaluation over `--server`, a person looking at a ranking) wants the
/// whole ranking.
pub fn select(ranked: Vec<RankedCandidate>, threshold: f32, max: usize) -> Vec<RankedCandidate> {
    ranked
        .into_iter()
        .filter(|c| threshold <= 0.0 || c.score > threshold)
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
    /// "b214"); row 1: s_e = 0.8, no sign, but a small billboard far from
    /// it that reads "EXIT" (its OCR reads, so a sign's absence counts).
    fn store() -> VecMemory {
        let mut m = VecMemory::new(2);
        let sign = with_texts(object("sign", 1.0, 0.5, 0.5, 0.1), &[("B-214", 1.0)]);
        let exit = with_texts(object("billboard", 1.0, 0.9, 0.9, 0.002), &[("EXIT", 1.0)]);
        m.push(features(&[0.6, 0.8], &[], vec![sign]), None);
        m.push(features(&[0.8, 0.6], &[], vec![exit]), None);
        m
    }

    fn query() -> Features {
        let sign = with_texts(object("sign", 1.0, 0.5, 0.5, 0.1), &[("b214", 1.0)]);
        features(&[1.0, 0.0], &[], vec![sign])
    }

    /// The paper's raw rule, so that the scores are the hand-computed `Λ`
    /// (a two-row store is too small for a calibrated null).
    fn raw() -> VprParams {
        VprParams {
            calibration: Calibration::Raw,
            ..VprParams::default()
        }
    }

    fn run(layers: Layers) -> Vec<RankedCandidate> {
        let m = store();
        let q = query();
        rank(
            &raw(),
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
        // Row 1: S_s = 0.8, B = 0, but the query's distinctive sign (D
        // 0.666667, area 0.1) has no counterpart in a frame that read text
        // (the billboard's EXIT, too small to count itself): X_o = 1,
        // C = g_xo · 1 = 0.5, Λ = 0.8 · (1 − 0.5) = 0.4; the paper's Λ = 0.8.
        let r = run(Layers::FULL);
        assert_eq!(r.len(), 2);
        assert_eq!(r[0].row, 0);
        assert!(close(r[0].scene.score, 0.6));
        assert!(close(r[0].objects.score, 1.0));
        assert!(close(r[0].text.score, 1.0));
        assert!(close(r[0].text.evidence_weight, 0.666667));
        assert!(close(r[0].corroboration, 0.316667));
        assert!(close(r[0].score, 0.726667));
        assert_eq!(r[0].contradiction, Contradiction::default());
        assert_eq!(r[0].objects.matches.len(), 1);
        assert_eq!(r[0].text.matches.len(), 1);
        assert_eq!(r[1].row, 1);
        assert_eq!(r[1].contradiction.absence, 1.0);
        assert!(close(r[1].contradiction.score, 0.5));
        assert!(close(r[1].score, 0.4));
        assert!(close(r[1].raw_score, 0.8));
        // Only row 0 passes τ_s = 0.7.
        assert_eq!(select(r, 0.7, 5).len(), 1);
        // The paper's full method: evidence for only, row 1 first at 0.8.
        let paper = run(Layers::FULL_SUPPORT_ONLY);
        assert_eq!(paper[0].row, 1);
        assert!(close(paper[0].score, 0.8));
        assert!(close(paper[1].score, 0.726667));
        assert_eq!(select(paper, 0.7, 5).len(), 2);
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

    /// One stored keyframe (s_e = 0.6) with a sign reading "AAAA 1111"; the
    /// query's sign at the same place reads `text`.
    fn look_alike(text: &str, layers: Layers) -> RankedCandidate {
        let mut m = VecMemory::new(2);
        let stored = with_texts(object("sign", 1.0, 0.5, 0.5, 0.1), &[("AAAA 1111", 1.0)]);
        m.push(features(&[0.6, 0.8], &[], vec![stored]), None);
        let q = features(
            &[1.0, 0.0],
            &[],
            vec![with_texts(
                object("sign", 1.0, 0.5, 0.5, 0.1),
                &[(text, 1.0)],
            )],
        );
        let query = QueryObservation { history: vec![&q] };
        rank(&raw(), layers, &query, &m, &|_| true).remove(0)
    }

    #[test]
    fn contradicting_text_lowers_the_score_by_hand() {
        // Matching text: S_o = 1, S_t = 1, E_t = 0.833333 (D of "AAAA 1111");
        // B = 0.15 + 0.25 · 0.833333 = 0.358333; C = 0;
        // Λ = 0.6 + 0.4 · 0.358333 = 0.743333.
        let same = look_alike("AAAA 1111", Layers::FULL);
        assert!(close(same.corroboration, 0.358333));
        assert_eq!(same.contradiction.score, 0.0);
        assert!(close(same.score, 0.743333));
        assert!(close(same.raw_score, 0.743333));
        // Contradicting text "BBBB 2222": S_str = 0.111111 → S_t = 0.111111,
        // B = 0.15 + 0.25 · 0.833333 · 0.111111 = 0.173148; the paper's
        // Λ = 0.6 + 0.4 · 0.173148 = 0.669259 (it only fails to rise).
        // X_t = 0.833333 · 0.777778 = 0.648148 = C;
        // Λ = 0.6 · (1 − 0.648148) + 0.4 · 0.173148 = 0.280370.
        let other = look_alike("BBBB 2222", Layers::FULL);
        assert!(close(other.corroboration, 0.173148));
        assert!(close(other.contradiction.text, 0.648148));
        assert!(close(other.score, 0.280370), "{}", other.score);
        assert!(close(other.raw_score, 0.669259));
        assert!(other.score < same.score);
        // The ablation without the evidence against is the paper's fusion.
        let paper = look_alike("BBBB 2222", Layers::FULL_SUPPORT_ONLY);
        assert_eq!(paper.contradiction, Contradiction::default());
        assert!(close(paper.score, 0.669259));
    }

    #[test]
    fn calibrated_scores_by_hand() {
        // Eleven rows with s_e = 0.50, 0.52, ..., 0.70 and one at 0.94:
        // twelve eligible, median (upper middle, index 6) 0.62.
        // c_s of the best = (0.94 − 0.62) / 0.38 = 0.842105.
        let mut m = VecMemory::new(2);
        let mut push = |c: f32| {
            m.push(features(&[c, (1.0 - c * c).sqrt()], &[], vec![]), None);
        };
        for i in 0..11 {
            push(0.50 + 0.02 * i as f32);
        }
        push(0.94);
        let q = features(&[1.0, 0.0], &[], vec![]);
        let query = QueryObservation { history: vec![&q] };
        let r = rank(&VprParams::default(), Layers::FULL, &query, &m, &|_| true);
        assert_eq!(r[0].row, 11);
        assert_eq!(r[0].null.samples, 12);
        assert!(close(r[0].null.location, 0.62));
        assert!(close(r[0].scene_confidence, 0.842105));
        assert!(close(r[0].score, 0.842105));
        assert!(close(r[0].raw_score, 0.94));
        // Rows at or below the median score 0.
        assert!(r
            .iter()
            .filter(|c| c.scene.score <= 0.62 + 1e-6)
            .all(|c| c.score == 0.0));
        // Fewer eligible rows than null_min_samples (10): nothing stands out.
        let few = rank(&VprParams::default(), Layers::FULL, &query, &m, &|row| {
            row >= 3
        });
        assert_eq!(few[0].null.samples, 9);
        assert!(few.iter().all(|c| c.score == 0.0));
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
            contradiction: Contradiction::default(),
            corroboration: 0.0,
            null: NullModel::default(),
            scene_confidence: s_s,
            raw_score: score,
            score,
            verdict: Default::default(),
            drift: None,
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
        assert_eq!(rows(select(ranked.clone(), 0.99, 5)), Vec::<usize>::new());
        // Threshold 0: the whole ranking, zero scores included.
        let mut with_zero = ranked;
        with_zero.push(candidate(6, 0.5, 0.0));
        assert_eq!(rows(select(with_zero, 0.0, 10)), vec![0, 1, 2, 3, 4, 5, 6]);
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
                prop_assert!(c.raw_score >= c.scene.score);
                prop_assert!((0.0..=1.0).contains(&c.scene_confidence));
                prop_assert!(c.score >= c.scene_confidence * (1.0 - c.contradiction.score) - 1e-6);
                prop_assert!((0.0..=1.0).contains(&c.contradiction.score));
                prop_assert!((0.0..=1.0).contains(&c.corroboration));
                prop_assert!((0.0..=1.0).contains(&c.objects.score));
                prop_assert!((0.0..=1.0).contains(&c.text.score));
                prop_assert!((0.0..=1.0).contains(&c.text.evidence_weight));
            }
            prop_assert!(full.windows(2).all(|w| w[0].score >= w[1].score));

            // SCAL only: the score is the (calibrated) scene score exactly,
            // the paper's Λ is S_s, and the candidates are SCAL's top K.
            let scal = rank(&params, Layers::SCAL, &query, &m, &|_| true);
            for c in &scal {
                prop_assert_eq!(c.score, c.scene_confidence);
                prop_assert_eq!(c.raw_score, c.scene.score);
            }
            let mut a: Vec<usize> = full.iter().map(|c| c.row).collect();
            let mut b: Vec<usize> = scal.iter().map(|c| c.row).collect();
            a.sort_unstable();
            b.sort_unstable();
            prop_assert_eq!(a, b);
        }
    }
}
