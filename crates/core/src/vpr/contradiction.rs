//! Evidence against a candidate: distinctive text that disagrees, and
//! distinctive objects that are missing.
//!
//! OSRL and OGTL can only vouch for a place. In look-alike places (blocks
//! built from one template, identical corridors) the one thing that tells
//! them apart is often a single sign or object, and evidence that can only
//! raise a score cannot use it: a shop sign that reads differently in the two
//! frames merely fails to add. This layer measures that disagreement, and the
//! fusion subtracts it ([`super::fusion::fuse_with_contradiction`]).
//!
//! Both terms are deliberately conservative, since a false contradiction
//! drops a true loop closure:
//! - **Text** ([`text_contradiction`]): only objects of the same class in
//!   compatible places (the OGTL gate, `G ≥ τ_g`) whose texts are both
//!   distinctive are compared, and each pair counts with the lesser of the
//!   two distinctiveness weights and the read confidences, so a generic word
//!   or a doubtful read says little. A pair whose best strings agree closely
//!   (an OCR slip of a letter or two) counts as agreement.
//! - **Absence** ([`absence`]): a distinctive object (one with distinctive
//!   text) that the other frame should have seen, with no counterpart near
//!   its place there: no object of its class that is unread, reads the
//!   same, or reads another distinctive text (a disagreement, left to the
//!   text term); a sign there that reads only generic words is none.
//!   "Should have seen" is legibility where it was shown: the other frame
//!   read text near that place, so its OCR worked there and would have read
//!   this sign too; or size (at least `absence_min_area` of the image) in a
//!   frame whose OCR read some text elsewhere. A frame that read no text at
//!   all shows no sign that its OCR could read anything: at night the
//!   renders' signs are as bright and as contrasted as by day (so exposure
//!   and contrast do not tell), but bloom and sensor noise leave nothing
//!   legible, and the absence of every sign there is the camera's, not the
//!   place's. Requiring one of the two keeps OCR failures (night, fog, a
//!   sign too small to read in one frame) from counting as absences. It is
//!   looked for in both directions, since either frame may be the one that
//!   shows the extra sign.

use crate::keyframe::ObjectObservation;
use crate::numeric::clip01;
use crate::vpr::ogtl::TextProfile;
use crate::vpr::osrl::spatial_kernel;
use crate::vpr::params::VprParams;
use crate::vpr::text::{distinct_agreement, is_generic};

/// One pair of gated objects whose distinctive texts disagree.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TextConflict {
    /// Index of the object among the query's objects.
    pub query_object: usize,
    /// Index of its counterpart among the candidate's objects.
    pub candidate_object: usize,
    /// The query string of the best-agreeing pair of strings (`u*`).
    pub query_text: usize,
    /// The candidate string of that pair (`v*`).
    pub candidate_text: usize,
    /// `a = A(u*, v*)`, the best agreement of the two objects' strings.
    pub agreement: f32,
    /// `κ`, this pair's disagreement (see [`text_contradiction`]).
    pub conflict: f32,
}

/// One distinctive object with no counterpart on the other side.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MissingObject {
    /// `true`: a query object missing from the candidate; `false`: a
    /// candidate object missing from the query.
    pub in_query: bool,
    /// Index of the object on its own side.
    pub object: usize,
    /// Its weight `w p` in `X_o`.
    pub weight: f32,
}

/// The evidence against one candidate.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Contradiction {
    /// `X_t` ∈ [0, 1], disagreeing distinctive text.
    pub text: f32,
    /// `X_o` ∈ [0, 1], missing distinctive objects.
    pub absence: f32,
    /// `C = clip(g_xt X_t + g_xo X_o, 0, 1)`, what the fusion subtracts.
    pub score: f32,
    /// Object pairs whose texts were compared, with their disagreement
    /// (only those with `κ > 0`).
    pub conflicts: Vec<TextConflict>,
    /// Distinctive objects without a counterpart.
    pub missing: Vec<MissingObject>,
}

/// The disagreement of two strings of agreement `a`:
/// `d(a) = clip((τ_x − a) / τ_x, 0, 1)` with `τ_x` =
/// `params.contradiction_agreement`. At or above `τ_x` strings agree (OCR
/// slips keep `S_str` high); below it the disagreement grows linearly to 1
/// for strings with nothing in common.
pub fn disagreement(agreement: f32, params: &VprParams) -> f32 {
    let tau = params.contradiction_agreement;
    if tau <= 0.0 {
        return 0.0;
    }
    clip01((tau - agreement) / tau)
}

/// `X_t` for one candidate.
///
/// For each query object `q` with text and weight `w_q = max_u D_T(u) > 0`,
/// the gated candidate objects `c` (same class, with text, `G(q, c) ≥ τ_g`)
/// are compared by their best pair of strings,
/// `a(q, c) = max_{u,v} A(u, v)` with `A` the [`distinct_agreement`]
/// (`S_str` of what the two strings do not share);
/// the counterpart is the `c*` with the highest `a` (ties: lower index). The
/// pair weighs `ω_q = min(w_q, w_c*)` and disagrees by
/// `κ_q = d(a) · sqrt(p_u* p_v*)`. Then
/// `X_t = Σ_q ω_q κ_q / max(Σ_q ω_q, 1)` over the query objects that have a
/// counterpart (0 if none): agreeing distinctive signs balance a
/// disagreeing one, and the total weight caps what the texts can say, so
/// one pair of fully distinctive strings can reach 1 while a generic word
/// (ω ≈ 0.02) says next to nothing.
pub fn text_contradiction(
    query_objects: &[ObjectObservation],
    query_profile: &TextProfile,
    cand_objects: &[ObjectObservation],
    cand_profile: &TextProfile,
    params: &VprParams,
) -> (f32, Vec<TextConflict>) {
    let (mut num, mut den) = (0.0f32, 0.0f32);
    let mut conflicts = Vec::new();
    for (qi, q) in query_objects.iter().enumerate() {
        let w_q = query_profile.object_weight(qi);
        if q.texts.is_empty() || w_q <= 0.0 {
            continue;
        }
        // (c, u, v, a) of the best-agreeing gated counterpart.
        let mut best: Option<(usize, usize, usize, f32)> = None;
        for (ci, c) in cand_objects.iter().enumerate() {
            let gated = c.class_name == q.class_name
                && !c.texts.is_empty()
                && cand_profile.object_weight(ci) > 0.0
                && spatial_kernel(q, c, params) >= params.tau_g;
            if !gated {
                continue;
            }
            for (u, tu) in q.texts.iter().enumerate() {
                for (v, tv) in c.texts.iter().enumerate() {
                    let a = distinct_agreement(&tu.text, &tv.text);
                    if best.is_none_or(|(_, _, _, a0)| a > a0) {
                        best = Some((ci, u, v, a));
                    }
                }
            }
        }
        let Some((ci, u, v, a)) = best else { continue };
        let weight = w_q.min(cand_profile.object_weight(ci));
        let confidence =
            (clip01(q.texts[u].confidence) * clip01(cand_objects[ci].texts[v].confidence)).sqrt();
        let conflict = disagreement(a, params) * confidence;
        num += weight * conflict;
        den += weight;
        if conflict > 0.0 {
            conflicts.push(TextConflict {
                query_object: qi,
                candidate_object: ci,
                query_text: u,
                candidate_text: v,
                agreement: a,
                conflict,
            });
        }
    }
    (clip01(num / den.max(1.0)), conflicts)
}

/// Whether `o` has a counterpart in `other`: an object of its class at a
/// compatible place (`G ≥ τ_g`) that
/// - carries no text (unread: its identity is unknown, so it cannot speak
///   against `o`), or
/// - reads what `o` reads (some pair of their strings has
///   [`distinct_agreement`] `≥ τ_x`, partial reads included), or
/// - reads something else that is not only generic words: then the two
///   texts disagree, and that is [`text_contradiction`]'s to weigh, not
///   counted twice here.
///
/// A nearby object of the class that reads only generic words ("OPEN",
/// "STOP") where `o` reads something else is no counterpart: the place
/// holds a different sign.
fn has_counterpart(o: &ObjectObservation, other: &[ObjectObservation], params: &VprParams) -> bool {
    other.iter().any(|c| {
        c.class_name == o.class_name
            && spatial_kernel(o, c, params) >= params.tau_g
            && (c.texts.is_empty()
                || c.texts.iter().any(|v| {
                    !is_generic(&v.text, params)
                        || o.texts.iter().any(|u| {
                            distinct_agreement(&u.text, &v.text) >= params.contradiction_agreement
                        })
                }))
    })
}

/// Whether `other` should have seen `o`: `other` read text on an object
/// at a compatible place (`G ≥ τ_g`), so its OCR could read there; or `o`
/// covers at least `params.absence_min_area` of the image and `other`
/// read text somewhere (`other_reads`), so its OCR could read at all.
fn should_be_seen(
    o: &ObjectObservation,
    other: &[ObjectObservation],
    other_reads: bool,
    params: &VprParams,
) -> bool {
    (other_reads && o.area >= params.absence_min_area)
        || other
            .iter()
            .any(|c| !c.texts.is_empty() && spatial_kernel(o, c, params) >= params.tau_g)
}

/// The distinctive objects of `side` that `other` should have seen
/// ([`should_be_seen`]) and that have no counterpart there
/// ([`has_counterpart`]): `(index, w p)`, where `w` is the object's text
/// weight and `p` its confidence; also the total `w p` of the objects that
/// `other` should have seen, missing or not.
fn missing_from(
    side: &[ObjectObservation],
    profile: &TextProfile,
    other: &[ObjectObservation],
    params: &VprParams,
) -> (f32, Vec<(usize, f32)>) {
    let other_reads = other.iter().any(|c| !c.texts.is_empty());
    let mut total = 0.0f32;
    let mut missing = Vec::new();
    for (i, o) in side.iter().enumerate() {
        let w = profile.object_weight(i) * clip01(o.confidence);
        if w <= 0.0 || !should_be_seen(o, other, other_reads, params) {
            continue;
        }
        total += w;
        if !has_counterpart(o, other, params) {
            missing.push((i, w));
        }
    }
    (total, missing)
}

/// `X_o` for one candidate: in each direction, the weight of the missing
/// distinctive objects over the weight of the distinctive objects of that
/// side that the other should have seen (see [`missing_from`]); `X_o` is
/// the larger of the two (0 when there are none).
pub fn absence(
    query_objects: &[ObjectObservation],
    query_profile: &TextProfile,
    cand_objects: &[ObjectObservation],
    cand_profile: &TextProfile,
    params: &VprParams,
) -> (f32, Vec<MissingObject>) {
    let share = |(total, missing): &(f32, Vec<(usize, f32)>)| {
        if *total > 0.0 {
            missing.iter().map(|&(_, w)| w).sum::<f32>() / total
        } else {
            0.0
        }
    };
    let from_query = missing_from(query_objects, query_profile, cand_objects, params);
    let from_cand = missing_from(cand_objects, cand_profile, query_objects, params);
    let score = clip01(share(&from_query).max(share(&from_cand)));
    let list = |in_query: bool, m: Vec<(usize, f32)>| {
        m.into_iter().map(move |(object, weight)| MissingObject {
            in_query,
            object,
            weight,
        })
    };
    let missing = list(true, from_query.1)
        .chain(list(false, from_cand.1))
        .collect();
    (score, missing)
}

/// Both terms and `C` for one candidate.
pub fn contradiction(
    query_objects: &[ObjectObservation],
    query_profile: &TextProfile,
    cand_objects: &[ObjectObservation],
    cand_profile: &TextProfile,
    params: &VprParams,
) -> Contradiction {
    let (text, conflicts) = text_contradiction(
        query_objects,
        query_profile,
        cand_objects,
        cand_profile,
        params,
    );
    let (absence, missing) = absence(
        query_objects,
        query_profile,
        cand_objects,
        cand_profile,
        params,
    );
    Contradiction {
        text,
        absence,
        score: clip01(params.g_xt * text + params.g_xo * absence),
        conflicts,
        missing,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vpr::ogtl::text_profile;
    use crate::vpr::testing::{close, object, objects_strategy, with_texts};
    use proptest::prelude::*;

    fn rare(_: &str) -> u32 {
        0
    }

    fn profile(objects: &[ObjectObservation]) -> TextProfile {
        text_profile(objects, &rare, 0, &VprParams::default())
    }

    fn run(q: &[ObjectObservation], c: &[ObjectObservation]) -> Contradiction {
        contradiction(q, &profile(q), c, &profile(c), &VprParams::default())
    }

    fn sign(x: f32, area: f32, texts: &[(&str, f32)]) -> ObjectObservation {
        with_texts(object("sign", 1.0, x, 0.5, area), texts)
    }

    #[test]
    fn disagreement_ramp() {
        let p = VprParams::default();
        // τ_x = 0.5: (0.5 − 0.111111) / 0.5 = 0.777778; at or above 0.5: 0.
        assert!(close(disagreement(0.111111, &p), 0.777778));
        assert_eq!(disagreement(0.5, &p), 0.0);
        assert_eq!(disagreement(0.9, &p), 0.0);
        assert_eq!(disagreement(0.0, &p), 1.0);
        let off = VprParams {
            contradiction_agreement: 0.0,
            ..VprParams::default()
        };
        assert_eq!(disagreement(0.0, &off), 0.0);
    }

    #[test]
    fn disagreeing_distinctive_text_by_hand() {
        // "AAAA 1111" vs "BBBB 2222": Levenshtein 8 of 9 → L = 0.111111, no
        // shared token, no containment → a = 0.111111, d = 0.777778.
        // Confidences 1 and 0.81 → κ = 0.777778 · 0.9 = 0.7.
        // D of both strings: len 8 → base 0.3 + 0.5 · 8/12 + 0.2 = 0.833333.
        // X_t = 0.833333 · 0.7 / max(0.833333, 1) = 0.583333; nothing
        // missing → C = 0.583333.
        let q = [sign(0.5, 0.1, &[("AAAA 1111", 1.0)])];
        let c = [sign(0.5, 0.1, &[("BBBB 2222", 0.81)])];
        let r = run(&q, &c);
        assert!(close(r.text, 0.583333), "{r:?}");
        assert_eq!(r.absence, 0.0);
        assert!(close(r.score, 0.583333));
        assert_eq!(r.conflicts.len(), 1);
        assert!(close(r.conflicts[0].agreement, 0.111111));
        assert!(close(r.conflicts[0].conflict, 0.7));
        assert!(r.missing.is_empty());
    }

    #[test]
    fn agreement_and_ocr_slips_are_not_contradictions() {
        let q = [sign(0.5, 0.1, &[("AAAA 1111", 1.0)])];
        let same = [sign(0.5, 0.1, &[("aaaa-1111", 0.6)])];
        // One character dropped: "aaaa" is shared, "1111" vs "111" gives
        // L = 1 − 1/4 = 0.75 ≥ τ_x.
        let slip = [sign(0.5, 0.1, &[("AAAA 111", 1.0)])];
        assert_eq!(run(&q, &same), Contradiction::default());
        assert_eq!(run(&q, &slip), Contradiction::default());
    }

    #[test]
    fn generic_words_and_ungated_signs_say_little() {
        // A conflicting distinctive sign at x 0.2 and an agreeing "EXIT"
        // (D 0.023333) at x 0.8 (G between 0.2 and 0.8 is 0.056: not gated).
        // X_t = (0.833333 · 0.777778 + 0.023333 · 0) / max(0.856667, 1)
        //     = 0.648148.
        let q = [
            sign(0.2, 0.1, &[("AAAA 1111", 1.0)]),
            sign(0.8, 0.1, &[("EXIT", 1.0)]),
        ];
        let c = [
            sign(0.2, 0.1, &[("BBBB 2222", 1.0)]),
            sign(0.8, 0.1, &[("exit", 1.0)]),
        ];
        let r = run(&q, &c);
        assert!(close(r.text, 0.648148), "{}", r.text);
        // Generic text only on the other side: no distinctive pair → 0.
        let generic = [sign(0.2, 0.1, &[("EXIT", 1.0)])];
        let plain = VprParams {
            g_xo: 0.0,
            ..VprParams::default()
        };
        let r = contradiction(
            &q[..1],
            &profile(&q[..1]),
            &generic,
            &profile(&generic),
            &plain,
        );
        // EXIT's weight is 0.023333 > 0, so the pair is compared:
        // ω = 0.023333, a = L("aaaa 1111", "exit") = 1 − 9/9 = 0 → κ = 1;
        // X_t = 0.023333 · 1 / max(0.023333, 1) = 0.023333.
        assert!(close(r.text, 0.023333), "{}", r.text);
        // Far away (not gated): not compared at all.
        let far = [sign(0.9, 0.1, &[("BBBB 2222", 1.0)])];
        assert_eq!(run(&q[..1], &far).text, 0.0);
    }

    #[test]
    fn missing_distinctive_objects_by_hand() {
        // The query's sign (D 0.833333, p 1, area 0.05) has no sign near it
        // in a candidate frame whose OCR read a small EXIT far from it
        // (x 0.9 against 0.3: G ≈ 0.056, under τ_g; area 0.002, too small
        // to count either way): X_o = 1 → C = g_xo · 1 = 0.5.
        let q = [sign(0.3, 0.05, &[("AAAA 1111", 1.0)])];
        let elsewhere = [sign(0.9, 0.002, &[("EXIT", 1.0)])];
        let r = run(&q, &elsewhere);
        assert_eq!(r.absence, 1.0);
        assert!(close(r.score, 0.5));
        assert_eq!(r.missing.len(), 1);
        assert!(r.missing[0].in_query);
        assert_eq!(r.missing[0].object, 0);
        assert!(close(r.missing[0].weight, 0.833333));
        // The other way round: the candidate shows the extra sign.
        let r = run(&elsewhere, &q);
        assert_eq!(r.absence, 1.0);
        assert_eq!(r.missing.len(), 1);
        assert!(!r.missing[0].in_query);
        // Too small to be sure it would be seen, and nothing read near its
        // place on the other side: not counted.
        let small = [sign(0.3, 0.005, &[("AAAA 1111", 1.0)])];
        assert_eq!(run(&small, &elsewhere).absence, 0.0);
        // A sign of the same class near it, unread, is a counterpart.
        let unread = [object("sign", 0.5, 0.35, 0.5, 0.05)];
        assert_eq!(run(&q, &unread).absence, 0.0);
        // So is one that reads the same, or part of it.
        let partial = [sign(0.35, 0.05, &[("1111", 0.9)])];
        assert_eq!(run(&q, &partial).absence, 0.0);
        // Two distinctive signs, one missing: 0.833333 / 1.666667 = 0.5.
        let two = [
            sign(0.2, 0.05, &[("AAAA 1111", 1.0)]),
            sign(0.8, 0.05, &[("CCCC 3333", 1.0)]),
        ];
        let one = [sign(0.2, 0.05, &[("AAAA 1111", 1.0)])];
        assert!(close(run(&two, &one).absence, 0.5));
    }

    #[test]
    fn a_frame_that_read_nothing_is_no_proof_of_absence() {
        // The same large sign (area 0.05) against a frame whose OCR read
        // nothing at all (a night frame: bloom and noise, every sign
        // unreadable): no evidence that it could have read this one.
        let q = [sign(0.3, 0.05, &[("AAAA 1111", 1.0)])];
        assert_eq!(run(&q, &[]).absence, 0.0);
        assert_eq!(run(&[], &q).absence, 0.0);
        // Nor does an object it detected but could not read, far from the
        // sign (x 0.9): a detector that works is no OCR that reads.
        let unread_far = [object("sign", 0.9, 0.9, 0.5, 0.05)];
        let r = run(&q, &unread_far);
        assert_eq!(r.absence, 0.0, "{r:?}");
        assert!(r.missing.is_empty());
        // Once it reads one word anywhere, its OCR works in that frame, and
        // the large sign's absence counts in full: X_o = 1.
        let reads_far = [sign(0.9, 0.002, &[("EXIT", 1.0)])];
        assert_eq!(run(&q, &reads_far).absence, 1.0);
    }

    #[test]
    fn a_sign_that_reads_otherwise_is_no_counterpart() {
        // The query shows a distinctive sign (D 0.833333, area 0.05) where
        // the candidate's sign reads only "EXIT" (generic, D 0.023333) at
        // 0.05 of the width: the place holds another sign. Query side:
        // total 0.833333, missing 0.833333 → 1. Candidate side: EXIT's
        // neighbour reads a non-generic text, a counterpart (X_t weighs that
        // pair) → 0. X_o = 1, and with g_xt = 0, C = 0.5 · 1 = 0.5.
        let q = [sign(0.3, 0.05, &[("AAAA 1111", 1.0)])];
        let c = [sign(0.35, 0.05, &[("EXIT", 1.0)])];
        let no_text = VprParams {
            g_xt: 0.0,
            ..VprParams::default()
        };
        let r = contradiction(&q, &profile(&q), &c, &profile(&c), &no_text);
        assert_eq!(r.absence, 1.0, "{r:?}");
        assert!(close(r.score, 0.5));
        assert_eq!(r.missing.len(), 1);
        assert!(r.missing[0].in_query);
        // Two distinctive signs that disagree are X_t's, not absences.
        let other = [sign(0.35, 0.05, &[("BBBB 2222", 1.0)])];
        let r = contradiction(&q, &profile(&q), &other, &profile(&other), &no_text);
        assert_eq!(r.absence, 0.0, "{r:?}");
    }

    #[test]
    fn small_signs_count_where_the_other_side_read_text() {
        // A street-name sign (area 0.006, under absence_min_area) beside a
        // STOP sign that both frames read; the candidate reads only STOP.
        // Near KING AVE (x 0.8 against 0.84: G ≈ 0.987) the candidate read
        // text, so it would have read KING AVE: missing. Query side: KING
        // AVE has D = (0.3 + 0.5 · 7/12)(0.5 + 0.5) = 0.591667; STOP is
        // generic, D = (0.3 + 0.5 · 4/12) · 0.05 = 0.023333, and has its
        // counterpart. X_o = 0.591667 / 0.615 = 0.962060.
        let q = [
            sign(0.8, 0.006, &[("KING AVE", 0.95)]),
            sign(0.84, 0.003, &[("STOP", 0.97)]),
        ];
        let c = [sign(0.84, 0.002, &[("STOP", 1.0)])];
        let r = run(&q, &c);
        let w_king = 0.591667 * 1.0;
        let w_stop = 0.023333;
        assert!(close(r.absence, w_king / (w_king + w_stop)), "{r:?}");
        assert_eq!(r.missing.len(), 1);
        assert_eq!(r.missing[0].object, 0);
        // Where the candidate read nothing near it, the small sign may just
        // be unreadable there: not counted (a STOP far away does not help).
        let far = [sign(0.1, 0.002, &[("STOP", 1.0)])];
        assert_eq!(run(&q[..1], &far).absence, 0.0);
        assert_eq!(run(&q[..1], &[]).absence, 0.0);
    }

    proptest! {
        #[test]
        fn bounded(q in objects_strategy(5), c in objects_strategy(5)) {
            let r = run(&q, &c);
            for v in [r.text, r.absence, r.score] {
                prop_assert!((0.0..=1.0).contains(&v));
            }
            for k in &r.conflicts {
                prop_assert!(k.conflict > 0.0 && k.conflict <= 1.0);
            }
        }

        #[test]
        fn identical_keyframes_never_contradict(q in objects_strategy(5)) {
            prop_assert_eq!(run(&q, &q).score, 0.0);
        }
    }
}
