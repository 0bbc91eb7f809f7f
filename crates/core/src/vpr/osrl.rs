//! OSRL, the Object-Spatial Reasoning Layer: do the same kinds of objects
//! sit in the same places?
//!
//! Objects are compared through a Gaussian kernel on centroid and area
//! (`G`), gated by class and weighted by detector confidence (`M_o`). Each
//! object may vouch for at most one counterpart, so the pairing is a
//! maximum-weight one-to-one assignment per class (Hungarian, not greedy),
//! and the score is normalised by the query's own objects, so candidates
//! missing query objects are penalised. It runs on SCAL's top K only.

use std::collections::BTreeMap;

use crate::keyframe::ObjectObservation;
use crate::numeric::clip01;
use crate::vpr::assignment::max_weight_assignment;
use crate::vpr::params::VprParams;

/// `G = exp(−d² / (2σ_m²))` with
/// `d² = (x_q − x_c)² + (y_q − y_c)² + λ_a (a_q − a_c)²`.
pub fn spatial_kernel(q: &ObjectObservation, c: &ObjectObservation, params: &VprParams) -> f32 {
    let dx = q.centroid[0] - c.centroid[0];
    let dy = q.centroid[1] - c.centroid[1];
    let da = q.area - c.area;
    let d2 = dx * dx + dy * dy + params.lambda_a * da * da;
    (-d2 / (2.0 * params.sigma_m * params.sigma_m)).exp()
}

/// `M_o = 1[class_q = class_c] · sqrt(p_q p_c) · G` (confidences clamped to
/// [0, 1]).
pub fn object_affinity(q: &ObjectObservation, c: &ObjectObservation, params: &VprParams) -> f32 {
    if q.class_name != c.class_name {
        return 0.0;
    }
    (clip01(q.confidence) * clip01(c.confidence)).sqrt() * spatial_kernel(q, c, params)
}

/// One assigned object pair.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObjectMatch {
    /// Index into the query's objects.
    pub query_object: usize,
    /// Index into the candidate's objects.
    pub candidate_object: usize,
    /// `M_o` of the pair.
    pub affinity: f32,
    /// `G` of the pair.
    pub spatial: f32,
}

/// OSRL evidence for one candidate.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct OsrlResult {
    /// `S_o` ∈ [0, 1].
    pub score: f32,
    /// Assigned pairs with `M_o > 0`, sorted by query object.
    pub matches: Vec<ObjectMatch>,
}

/// `S_o = Σ_r ω_r Σ_{(u,v)∈A_r*} M^(r)_uv / Σ_{q∈O_Q} ω_{class_q}`, where
/// `A_r*` is the maximum-weight one-to-one assignment of class `r`.
/// No query objects, or zero total query weight, give 0.
pub fn osrl(
    query: &[ObjectObservation],
    candidate: &[ObjectObservation],
    params: &VprParams,
) -> OsrlResult {
    let total_weight: f32 = query
        .iter()
        .map(|q| params.class_weight(&q.class_name))
        .sum();
    if total_weight.is_nan() || total_weight <= 0.0 {
        return OsrlResult::default();
    }

    // Object indices of each class, query side and candidate side.
    let mut classes: BTreeMap<&str, (Vec<usize>, Vec<usize>)> = BTreeMap::new();
    for (i, q) in query.iter().enumerate() {
        classes.entry(&q.class_name).or_default().0.push(i);
    }
    for (j, c) in candidate.iter().enumerate() {
        if let Some(entry) = classes.get_mut(c.class_name.as_str()) {
            entry.1.push(j);
        }
    }

    let mut weighted_sum = 0.0f32;
    let mut matches = Vec::new();
    for (class, (qs, cs)) in &classes {
        if cs.is_empty() {
            continue;
        }
        let weights: Vec<f32> = qs
            .iter()
            .flat_map(|&i| cs.iter().map(move |&j| (i, j)))
            .map(|(i, j)| object_affinity(&query[i], &candidate[j], params))
            .collect();
        let mut class_sum = 0.0f32;
        for (a, b) in max_weight_assignment(qs.len(), cs.len(), &weights) {
            let affinity = weights[a * cs.len() + b];
            if affinity > 0.0 {
                class_sum += affinity;
                matches.push(ObjectMatch {
                    query_object: qs[a],
                    candidate_object: cs[b],
                    affinity,
                    spatial: spatial_kernel(&query[qs[a]], &candidate[cs[b]], params),
                });
            }
        }
        weighted_sum += params.class_weight(class) * class_sum;
    }
    matches.sort_unstable_by_key(|m| (m.query_object, m.candidate_object));
    OsrlResult {
        score: clip01(weighted_sum / total_weight),
        matches,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vpr::testing::{close, object, objects_strategy};
    use proptest::prelude::*;

    #[test]
    fn spatial_kernel_value() {
        let p = VprParams::default();
        // d² = 0.1² + 0.2² + 1 · 0.05² = 0.0525; 2σ² = 0.125;
        // G = exp(−0.42) = 0.657047.
        let q = object("sign", 1.0, 0.5, 0.5, 0.10);
        let c = object("sign", 1.0, 0.6, 0.3, 0.15);
        assert!(close(spatial_kernel(&q, &c, &p), 0.657047));
        // λ_a = 4: d² = 0.05 + 4 · 0.0025 = 0.06, G = exp(−0.48) = 0.618783.
        let p4 = VprParams {
            lambda_a: 4.0,
            ..VprParams::default()
        };
        assert!(close(spatial_kernel(&q, &c, &p4), 0.618783));
        // Identical layout: G = 1.
        assert!(close(spatial_kernel(&q, &q, &p), 1.0));
    }

    #[test]
    fn affinity_value_and_class_gate() {
        let p = VprParams::default();
        // sqrt(0.81 · 0.64) = 0.72; × G = 0.657047 → 0.473074.
        let q = object("sign", 0.81, 0.5, 0.5, 0.10);
        let c = object("sign", 0.64, 0.6, 0.3, 0.15);
        assert!(close(object_affinity(&q, &c, &p), 0.473074));
        let other = object("fence", 0.64, 0.5, 0.5, 0.10);
        assert_eq!(object_affinity(&q, &other, &p), 0.0);
    }

    #[test]
    fn hungarian_beats_greedy() {
        let p = VprParams::default();
        // G = exp(−8 dx²) (same y, same area, confidences 1):
        // q0 (x 0.5): c0 (0.45) exp(−0.02) = 0.980199, c1 (0.6) exp(−0.08) = 0.923116;
        // q1 (x 0.3): c0 exp(−0.18) = 0.835270, c1 exp(−0.72) = 0.486752.
        // Greedy (best first) q0–c0 + q1–c1 = 1.466951; optimal q0–c1 + q1–c0
        // = 1.758386; S_o = 1.758386 / 2 = 0.879193.
        let q = [
            object("building", 1.0, 0.5, 0.5, 0.2),
            object("building", 1.0, 0.3, 0.5, 0.2),
        ];
        let c = [
            object("building", 1.0, 0.45, 0.5, 0.2),
            object("building", 1.0, 0.6, 0.5, 0.2),
        ];
        let r = osrl(&q, &c, &p);
        assert!(close(r.score, 0.879193), "{}", r.score);
        let pairs: Vec<(usize, usize)> = r
            .matches
            .iter()
            .map(|m| (m.query_object, m.candidate_object))
            .collect();
        assert_eq!(pairs, vec![(0, 1), (1, 0)]);
        assert!(close(r.matches[0].spatial, 0.923116));
        assert!(close(r.matches[1].affinity, 0.835270));
    }

    #[test]
    fn class_weights_and_missing_candidate_objects() {
        let mut p = VprParams::default();
        p.class_weights.insert("building".into(), 2.0);
        p.class_weights.insert("sign".into(), 0.5);
        // building (ω 2): identical, M = 1. sign (ω 0.5): no candidate sign.
        // fence (default ω 1): identical place, confidences 1 and 0.64 →
        // M = 0.8. S_o = (2 · 1 + 1 · 0.8) / (2 + 0.5 + 1) = 2.8 / 3.5 = 0.8.
        let q = [
            object("building", 1.0, 0.2, 0.2, 0.3),
            object("sign", 1.0, 0.7, 0.3, 0.05),
            object("fence", 1.0, 0.5, 0.8, 0.1),
        ];
        let c = [
            object("fence", 0.64, 0.5, 0.8, 0.1),
            object("building", 1.0, 0.2, 0.2, 0.3),
            object("tree", 1.0, 0.7, 0.3, 0.05),
        ];
        let r = osrl(&q, &c, &p);
        assert!(close(r.score, 0.8), "{}", r.score);
        assert_eq!(r.matches.len(), 2);
        assert_eq!(
            (r.matches[0].query_object, r.matches[0].candidate_object),
            (0, 1)
        );
        assert_eq!(
            (r.matches[1].query_object, r.matches[1].candidate_object),
            (2, 0)
        );
    }

    #[test]
    fn no_query_objects_or_zero_weight() {
        let p = VprParams::default();
        let c = [object("sign", 1.0, 0.5, 0.5, 0.1)];
        assert_eq!(osrl(&[], &c, &p), OsrlResult::default());
        let p0 = VprParams {
            default_class_weight: 0.0,
            ..VprParams::default()
        };
        assert_eq!(osrl(&c, &c, &p0).score, 0.0);
        // A candidate with nothing scores 0 against a non-empty query.
        assert_eq!(osrl(&c, &[], &p).score, 0.0);
    }

    #[test]
    fn more_query_objects_than_candidates() {
        let p = VprParams::default();
        // Three query signs, one candidate sign identical to q1: S_o = 1/3.
        let q = [
            object("sign", 1.0, 0.1, 0.1, 0.1),
            object("sign", 1.0, 0.5, 0.5, 0.1),
            object("sign", 1.0, 0.9, 0.9, 0.1),
        ];
        let c = [object("sign", 1.0, 0.5, 0.5, 0.1)];
        let r = osrl(&q, &c, &p);
        assert!(close(r.score, 1.0 / 3.0));
        assert_eq!(r.matches.len(), 1);
        assert_eq!(r.matches[0].query_object, 1);
    }

    proptest! {
        #[test]
        fn score_in_unit_interval(q in objects_strategy(6), c in objects_strategy(6)) {
            let r = osrl(&q, &c, &VprParams::default());
            prop_assert!((0.0..=1.0).contains(&r.score));
            prop_assert!(r.matches.windows(2).all(|w| w[0].query_object < w[1].query_object));
        }

        #[test]
        fn invariant_under_permutation(
            (q, qp) in objects_strategy(6).prop_flat_map(|q| (Just(q.clone()), Just(q).prop_shuffle())),
            (c, cp) in objects_strategy(6).prop_flat_map(|c| (Just(c.clone()), Just(c).prop_shuffle())),
        ) {
            let p = VprParams::default();
            let a = osrl(&q, &c, &p).score;
            let b = osrl(&qp, &cp, &p).score;
            prop_assert!((a - b).abs() < 1e-4, "{} vs {}", a, b);
        }

        #[test]
        fn monotone_in_confidence(
            q in objects_strategy(6),
            c in objects_strategy(6),
            pick in any::<prop::sample::Index>(),
            raise in 0.0f32..1.0,
        ) {
            prop_assume!(!c.is_empty());
            let p = VprParams::default();
            let before = osrl(&q, &c, &p).score;
            let mut c2 = c.clone();
            let o = &mut c2[pick.index(c.len())];
            o.confidence = (o.confidence + raise).min(1.0);
            let after = osrl(&q, &c2, &p).score;
            prop_assert!(after >= before - 1e-5, "{} -> {}", before, after);
        }

        #[test]
        fn monotone_as_a_candidate_object_moves_closer(
            q in objects_strategy(6),
            c in objects_strategy(6),
            anchor in (0.0f32..1.0, 0.0f32..1.0, 0.0f32..0.5, 0.1f32..1.0),
            start in (0.0f32..1.0, 0.0f32..1.0, 0.0f32..0.5, 0.1f32..1.0),
            t0 in 0.0f32..1.0,
            t1 in 0.0f32..1.0,
        ) {
            // A class present once on each side ("pole") so that moving the
            // candidate pole only changes its affinity with the query pole.
            let (ax, ay, aa, ap) = anchor;
            let (sx, sy, sa, sp) = start;
            let mut q = q;
            q.push(object("pole", ap, ax, ay, aa));
            let (lo, hi) = if t0 <= t1 { (t0, t1) } else { (t1, t0) };
            let lerp = |s: f32, a: f32, t: f32| s + (a - s) * t;
            let at = |t: f32| {
                let mut c = c.clone();
                c.push(object("pole", sp, lerp(sx, ax, t), lerp(sy, ay, t), lerp(sa, aa, t)));
                osrl(&q, &c, &VprParams::default()).score
            };
            let (far, near) = (at(lo), at(hi));
            prop_assert!(near >= far - 1e-5, "{} -> {}", far, near);
        }
    }
}
