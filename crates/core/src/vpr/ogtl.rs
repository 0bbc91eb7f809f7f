//! OGTL, the Object-Grounded Textual Landmark Layer: text counts as a
//! landmark only where it is read on a compatible object.
//!
//! Two OCR strings are compared only when their objects share a class and
//! sit in compatible places (`G ≥ τ_g`), so "EXIT" on a door across the
//! street does not vouch for "EXIT" here. Each string is weighted by its
//! distinctiveness, computed once per keyframe into a [`TextProfile`] so the
//! query side is done once per query rather than once per candidate; the
//! layer runs on SCAL's top K only.

use crate::keyframe::ObjectObservation;
use crate::numeric::clip01;
use crate::vpr::memory::KeyframeMemory;
use crate::vpr::osrl::spatial_kernel;
use crate::vpr::params::VprParams;
use crate::vpr::text::{distinctiveness, string_similarity};

/// Distinctiveness of every string of a keyframe, per object.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TextProfile {
    /// `D_T(u)` of `objects[i].texts[u]` at `per_object[i][u]`.
    pub per_object: Vec<Vec<f32>>,
    /// `D̄`, mean distinctiveness over all strings; `None` without text.
    pub mean: Option<f32>,
}

impl TextProfile {
    /// `D_T(u)` of string `u` of object `object` (0 if absent).
    pub fn distinctiveness(&self, object: usize, text: usize) -> f32 {
        self.per_object
            .get(object)
            .and_then(|d| d.get(text))
            .copied()
            .unwrap_or(0.0)
    }

    /// `w_q = max_u D_T(u)`: the weight of an object is that of its most
    /// distinctive string (0 without text).
    pub fn object_weight(&self, object: usize) -> f32 {
        self.per_object
            .get(object)
            .map_or(0.0, |d| d.iter().copied().fold(0.0, f32::max))
    }
}

/// The [`TextProfile`] of `objects`, with rarity from `document_frequency`
/// over `documents` stored keyframes (see [`distinctiveness`]).
pub fn text_profile(
    objects: &[ObjectObservation],
    document_frequency: &dyn Fn(&str) -> u32,
    documents: u32,
    params: &VprParams,
) -> TextProfile {
    let per_object: Vec<Vec<f32>> = objects
        .iter()
        .map(|o| {
            o.texts
                .iter()
                .map(|t| distinctiveness(&t.text, document_frequency, documents, params))
                .collect()
        })
        .collect();
    let count = per_object.iter().map(Vec::len).sum::<usize>();
    let mean = (count > 0).then(|| per_object.iter().flatten().sum::<f32>() / count as f32);
    TextProfile { per_object, mean }
}

/// [`text_profile`] with rarity from the store's document frequencies.
pub fn text_profile_in<M: KeyframeMemory + ?Sized>(
    objects: &[ObjectObservation],
    memory: &M,
    params: &VprParams,
) -> TextProfile {
    text_profile(
        objects,
        &|s| memory.text_document_frequency(s),
        memory.keyframe_count(),
        params,
    )
}

/// One matched string pair.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TextMatch {
    /// Index of the object among the query's objects.
    pub query_object: usize,
    /// Index of the matched object among the candidate's objects.
    pub candidate_object: usize,
    /// Index into the query object's texts (`u`).
    pub query_text: usize,
    /// Index into the candidate object's texts (`v`).
    pub candidate_text: usize,
    /// `S_str(u, v)`.
    pub similarity: f32,
    /// `M_T(u, v) = S_str(u, v) p_u p_v`.
    pub score: f32,
    /// `D_T(u)`.
    pub distinctiveness: f32,
}

/// OGTL evidence for one candidate.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct OgtlResult {
    /// `S_t` ∈ [0, 1].
    pub score: f32,
    /// `E_t = sqrt(D̄_Q D̄_C)` ∈ [0, 1].
    pub evidence_weight: f32,
    /// For each text-bearing query object, the best `v` of each of its
    /// strings on its best gated candidate object (pairs with `M_T > 0`).
    pub matches: Vec<TextMatch>,
}

/// The best candidate string `(v, S_str, M_T)` for each query string `u`.
type BestTexts = Vec<Option<(usize, f32, f32)>>;

/// `S_T(q, c) = Σ_u D_T(u) max_v M_T(u, v) / Σ_u D_T(u)` (0 if `Σ D = 0`),
/// with the arg-max of each `u`.
fn object_text_score(
    q: &ObjectObservation,
    q_index: usize,
    q_profile: &TextProfile,
    c: &ObjectObservation,
) -> (f32, BestTexts) {
    let (mut num, mut den) = (0.0f32, 0.0f32);
    let mut best = Vec::with_capacity(q.texts.len());
    for (u, tu) in q.texts.iter().enumerate() {
        let d = q_profile.distinctiveness(q_index, u);
        let mut top: Option<(usize, f32, f32)> = None;
        for (v, tv) in c.texts.iter().enumerate() {
            let s = string_similarity(&tu.text, &tv.text);
            let m = s * clip01(tu.confidence) * clip01(tv.confidence);
            if top.is_none_or(|(_, _, m0)| m > m0) {
                top = Some((v, s, m));
            }
        }
        num += d * top.map_or(0.0, |(_, _, m)| m);
        den += d;
        best.push(top);
    }
    let score = if den > 0.0 { clip01(num / den) } else { 0.0 };
    (score, best)
}

/// OGTL for one candidate.
///
/// Gate `Γ = 1[class_q = class_c] · 1[G(q, c) ≥ τ_g]`. For each text-bearing
/// query object `q`, `S_T* = max_{c gated} S_T(q, c)`; then
/// `S_t = Σ_q w_q S_T* / Σ_q w_q` with `w_q = max_u D_T(u)` (0 if the sum is
/// 0), and `E_t = sqrt(D̄_Q D̄_C)` (0 if either side has no text).
pub fn ogtl(
    query_objects: &[ObjectObservation],
    query_profile: &TextProfile,
    cand_objects: &[ObjectObservation],
    cand_profile: &TextProfile,
    params: &VprParams,
) -> OgtlResult {
    let evidence_weight = match (query_profile.mean, cand_profile.mean) {
        (Some(a), Some(b)) => clip01((a * b).sqrt()),
        _ => 0.0,
    };

    let (mut num, mut den) = (0.0f32, 0.0f32);
    let mut matches = Vec::new();
    for (qi, q) in query_objects.iter().enumerate() {
        if q.texts.is_empty() {
            continue;
        }
        let w = query_profile.object_weight(qi);
        den += w;
        let mut best: Option<(usize, f32, BestTexts)> = None;
        for (ci, c) in cand_objects.iter().enumerate() {
            let gated = c.class_name == q.class_name
                && !c.texts.is_empty()
                && spatial_kernel(q, c, params) >= params.tau_g;
            if !gated {
                continue;
            }
            let (s, texts) = object_text_score(q, qi, query_profile, c);
            if best.as_ref().is_none_or(|(_, s0, _)| s > *s0) {
                best = Some((ci, s, texts));
            }
        }
        let Some((ci, s, texts)) = best else { continue };
        if s <= 0.0 {
            continue;
        }
        num += w * s;
        for (u, top) in texts.into_iter().enumerate() {
            if let Some((v, similarity, score)) = top.filter(|&(_, _, m)| m > 0.0) {
                matches.push(TextMatch {
                    query_object: qi,
                    candidate_object: ci,
                    query_text: u,
                    candidate_text: v,
                    similarity,
                    score,
                    distinctiveness: query_profile.distinctiveness(qi, u),
                });
            }
        }
    }
    let score = if den > 0.0 { clip01(num / den) } else { 0.0 };
    OgtlResult {
        score,
        evidence_weight,
        matches,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vpr::memory::VecMemory;
    use crate::vpr::testing::{close, features, object, objects_strategy, with_texts};
    use proptest::prelude::*;

    fn rare(_: &str) -> u32 {
        0
    }

    fn profile(objects: &[ObjectObservation]) -> TextProfile {
        text_profile(objects, &rare, 0, &VprParams::default())
    }

    fn run(q: &[ObjectObservation], c: &[ObjectObservation]) -> OgtlResult {
        ogtl(q, &profile(q), c, &profile(c), &VprParams::default())
    }

    #[test]
    fn profile_values() {
        // D("B-214") = 0.666667, D("EXIT") = 0.023333; D̄ = 0.345.
        let objs = [
            with_texts(
                object("sign", 1.0, 0.5, 0.5, 0.1),
                &[("B-214", 1.0), ("EXIT", 1.0)],
            ),
            object("building", 1.0, 0.5, 0.5, 0.1),
        ];
        let p = profile(&objs);
        assert!(close(p.distinctiveness(0, 0), 0.666667));
        assert!(close(p.distinctiveness(0, 1), 0.023333));
        assert!(close(p.object_weight(0), 0.666667));
        assert_eq!(p.object_weight(1), 0.0);
        assert_eq!(p.distinctiveness(5, 5), 0.0);
        assert!(close(p.mean.unwrap(), 0.345));
        assert_eq!(profile(&objs[1..]).mean, None);
    }

    #[test]
    fn profile_from_memory_uses_document_frequency() {
        // 20 keyframes, "b 214" in 2 of them: r = ln(10)/ln(20) = 0.768622;
        // D = 0.666667 · (0.5 + 0.384311) = 0.589541.
        let mut m = VecMemory::new(1);
        for i in 0..20 {
            let texts: &[(&str, f32)] = if i < 2 { &[("B 214", 1.0)] } else { &[] };
            let o = with_texts(object("sign", 1.0, 0.5, 0.5, 0.1), texts);
            m.push(features(&[1.0], &[], vec![o]), None);
        }
        let q = [with_texts(
            object("sign", 1.0, 0.5, 0.5, 0.1),
            &[("b-214", 1.0)],
        )];
        let p = text_profile_in(&q, &m, &VprParams::default());
        assert!(close(p.distinctiveness(0, 0), 0.589541), "{:?}", p);
    }

    #[test]
    fn gate_at_tau_g() {
        // Same class, no area change: G = exp(−8 dx²).
        // dx = 0.25: G = exp(−0.5) = 0.606531 ≥ 0.6 → compared, S_t = 1.
        // dx = 0.26: G = exp(−0.5408) = 0.582264 < 0.6 → not compared, S_t = 0.
        let q = [with_texts(
            object("sign", 1.0, 0.5, 0.5, 0.1),
            &[("B-214", 1.0)],
        )];
        let near = [with_texts(
            object("sign", 1.0, 0.75, 0.5, 0.1),
            &[("B-214", 1.0)],
        )];
        let far = [with_texts(
            object("sign", 1.0, 0.76, 0.5, 0.1),
            &[("B-214", 1.0)],
        )];
        assert!(close(run(&q, &near).score, 1.0));
        assert_eq!(run(&q, &far).score, 0.0);
        // Different class at the same place: not compared either.
        let other = [with_texts(
            object("building", 1.0, 0.5, 0.5, 0.1),
            &[("B-214", 1.0)],
        )];
        assert_eq!(run(&q, &other).score, 0.0);
        // E_t does not depend on the gate: sqrt(0.666667²) = 0.666667.
        assert!(close(run(&q, &far).evidence_weight, 0.666667));
    }

    #[test]
    fn s_t_and_e_t_small_case() {
        // Query: sign q0 with "B-214" (D 0.666667, p 1) and "EXIT" (D 0.023333,
        // p 1); building q1 with "Rue de la Paix 12" (D 1.0).
        // Candidate: sign c0 at the same place with "b214" (p 0.9, D 0.666667),
        // and a far sign c1 with "B-214" (G ≈ 0, gated out).
        //
        // S_str("B-214", "b214") = C = 1 → M_T = 0.9; "EXIT" vs "b214" → 0.
        // S_T(q0, c0) = (0.666667 · 0.9 + 0.023333 · 0) / 0.69 = 0.869565.
        // q1 has no gated candidate: S_T* = 0.
        // S_t = (0.666667 · 0.869565 + 1.0 · 0) / (0.666667 + 1.0) = 0.347826.
        // D̄_Q = (0.666667 + 0.023333 + 1.0) / 3 = 0.563333, D̄_C = 0.666667;
        // E_t = sqrt(0.563333 · 0.666667) = 0.612826.
        let q = [
            with_texts(
                object("sign", 1.0, 0.5, 0.5, 0.1),
                &[("B-214", 1.0), ("EXIT", 1.0)],
            ),
            with_texts(
                object("building", 1.0, 0.2, 0.5, 0.4),
                &[("Rue de la Paix 12", 1.0)],
            ),
        ];
        let c = [
            with_texts(object("sign", 1.0, 0.5, 0.5, 0.1), &[("b214", 0.9)]),
            with_texts(object("sign", 1.0, 0.0, 0.0, 0.1), &[("B-214", 1.0)]),
        ];
        let r = run(&q, &c);
        assert!(close(r.score, 0.347826), "{}", r.score);
        assert!(close(r.evidence_weight, 0.612826), "{}", r.evidence_weight);
        assert_eq!(r.matches.len(), 1);
        let m = r.matches[0];
        assert_eq!(
            (
                m.query_object,
                m.candidate_object,
                m.query_text,
                m.candidate_text
            ),
            (0, 0, 0, 0)
        );
        assert!(close(m.similarity, 1.0));
        assert!(close(m.score, 0.9));
        assert!(close(m.distinctiveness, 0.666667));
    }

    #[test]
    fn best_gated_candidate_object_wins() {
        // Two gated candidate signs: "EXIT 12b" (S_str 0.875 with "EXIT 12")
        // and "EXIT 12" (1.0). The exact one is chosen: S_t = 1.
        let q = [with_texts(
            object("sign", 1.0, 0.5, 0.5, 0.1),
            &[("EXIT 12", 1.0)],
        )];
        let c = [
            with_texts(object("sign", 1.0, 0.5, 0.5, 0.1), &[("exit 12b", 1.0)]),
            with_texts(object("sign", 1.0, 0.55, 0.5, 0.1), &[("EXIT 12", 1.0)]),
        ];
        let r = run(&q, &c);
        assert!(close(r.score, 1.0));
        assert_eq!(r.matches[0].candidate_object, 1);
    }

    #[test]
    fn no_text_anywhere() {
        let q = [object("sign", 1.0, 0.5, 0.5, 0.1)];
        assert_eq!(run(&q, &q), OgtlResult::default());
        assert_eq!(run(&[], &[]), OgtlResult::default());
    }

    proptest! {
        #[test]
        fn scores_in_unit_interval(q in objects_strategy(5), c in objects_strategy(5)) {
            let r = run(&q, &c);
            prop_assert!((0.0..=1.0).contains(&r.score));
            prop_assert!((0.0..=1.0).contains(&r.evidence_weight));
            for m in &r.matches {
                prop_assert!(m.score > 0.0 && m.score <= 1.0);
            }
        }

        #[test]
        fn invariant_under_permutation(
            (q, qp) in objects_strategy(5).prop_flat_map(|q| (Just(q.clone()), Just(q).prop_shuffle())),
            (c, cp) in objects_strategy(5).prop_flat_map(|c| (Just(c.clone()), Just(c).prop_shuffle())),
        ) {
            let a = run(&q, &c);
            let b = run(&qp, &cp);
            prop_assert!((a.score - b.score).abs() < 1e-5, "{} vs {}", a.score, b.score);
            prop_assert!((a.evidence_weight - b.evidence_weight).abs() < 1e-5);
        }
    }
}
