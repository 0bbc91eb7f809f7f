//! SCAL, the Scene Context Attention Layer: the scene-primary hypothesis.
//!
//! The formulas of one candidate: the clipped cosine `s_e`, a mild scene
//! class modulation `s̃_e`, and a temporal average `S_s` over the query's
//! and the candidate's short histories (following each side's predecessor
//! chain). Scene compatibility uses the query side prepared once
//! ([`SceneProfile`]). The pass over every stored row that applies them, and
//! keeps the top `K` for the object and text layers, is
//! [`scan`](super::scan).

use crate::engine::matrix::dot;
use crate::keyframe::{Features, SceneClass};
use crate::numeric::clip01;
use crate::vpr::memory::KeyframeMemory;
use crate::vpr::params::{TemporalMode, VprParams};

/// `s_e = clip(ê_Qᵀ ê_C, 0, 1)` for L2-normalised descriptors.
pub fn cosine(a: &[f32], b: &[f32]) -> f32 {
    clip01(dot(a, b))
}

/// `C_cat`: Bhattacharyya coefficient `Σ_k sqrt(p_a(k) p_b(k))` over the
/// classes present in both sparse lists, clamped to [0, 1]; `None` when
/// either list is empty (no scene model ran).
pub fn scene_compatibility(a: &[SceneClass], b: &[SceneClass]) -> Option<f32> {
    SceneProfile::new(a).compatibility(b)
}

/// One side of `C_cat` prepared once per query, so that comparing it with
/// each of the many candidates costs one table lookup per candidate class,
/// and a square root only for the classes both share (a scan with a lookup
/// by search or a square root per class was most of SCAL's time). Scene
/// models have a few hundred classes (Places365, ImageNet), so the table is
/// dense, indexed by class id; ids from [`SceneProfile::DENSE_LIMIT`] up
/// fall back to a sorted list and binary search.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneProfile {
    /// `sqrt(p)` by class id, 0 for absent classes; empty when sparse.
    dense: Vec<f32>,
    /// `(class id, sqrt(p))` sorted by class id; empty when dense.
    sparse: Vec<(u32, f32)>,
}

impl SceneProfile {
    /// Class ids below this are looked up in a dense table.
    pub const DENSE_LIMIT: u32 = 1 << 16;

    /// Prepares one side's sparse scene distribution. Probabilities are
    /// clipped to [0, 1]; a class listed twice counts once.
    pub fn new(classes: &[SceneClass]) -> SceneProfile {
        let mut sparse: Vec<(u32, f32)> = classes
            .iter()
            .map(|c| (c.class_id, clip01(c.probability).sqrt()))
            .collect();
        sparse.sort_unstable_by_key(|&(class, _)| class);
        sparse.dedup_by_key(|&mut (class, _)| class);
        match sparse.last() {
            Some(&(max, _)) if max < Self::DENSE_LIMIT => {
                let mut dense = vec![0.0; max as usize + 1];
                for &(class, sqrt_p) in &sparse {
                    dense[class as usize] = sqrt_p;
                }
                SceneProfile {
                    dense,
                    sparse: Vec::new(),
                }
            }
            _ => SceneProfile {
                dense: Vec::new(),
                sparse,
            },
        }
    }

    fn sqrt_p(&self, class: u32) -> f32 {
        if self.sparse.is_empty() {
            self.dense.get(class as usize).copied().unwrap_or(0.0)
        } else {
            self.sparse
                .binary_search_by_key(&class, |&(c, _)| c)
                .map_or(0.0, |i| self.sparse[i].1)
        }
    }

    /// `C_cat` of this side and `other`; `None` when either has no classes.
    pub fn compatibility(&self, other: &[SceneClass]) -> Option<f32> {
        if (self.dense.is_empty() && self.sparse.is_empty()) || other.is_empty() {
            return None;
        }
        let mut bc = 0.0f32;
        for c in other {
            let sqrt_q = self.sqrt_p(c.class_id);
            if sqrt_q > 0.0 {
                bc += sqrt_q * clip01(c.probability).sqrt();
            }
        }
        Some(clip01(bc))
    }
}

/// `s̃_e = s_e (1 + λ_c C_cat) / (1 + λ_c)`.
///
/// With `C_cat = None` there is no modulation (`s̃_e = s_e`): treating a
/// missing scene model as `C_cat = 0` would scale every score by
/// `1 / (1 + λ_c)` and could push all of them below the selection threshold.
pub fn modulated(s_e: f32, c_cat: Option<f32>, lambda_c: f32) -> f32 {
    match c_cat {
        Some(c) => s_e * (1.0 + lambda_c * c) / (1.0 + lambda_c),
        None => s_e,
    }
}

/// The query side of SCAL.
#[derive(Debug, Clone, PartialEq)]
pub struct ScalQuery<'a> {
    /// `[0]` is the current observation `Q_t`, then its predecessors most
    /// recent first; at most `alpha.len() − 1` predecessors are used.
    pub history: Vec<&'a Features>,
}

/// One candidate's SCAL evidence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScalHit {
    /// Row in the [`KeyframeMemory`].
    pub row: usize,
    /// `S_s`, the temporal scene score.
    pub score: f32,
    /// `s_e` of the current pair `(Q_t, C_i)`.
    pub cosine: f32,
    /// `C_cat` of the current pair.
    pub scene_compatibility: Option<f32>,
    /// `k`, the number of temporal steps used (1 to 3).
    pub depth: usize,
}

/// `S_s = Σ_{j<k} α_j s̃_e(Q_{t−j}, C_{i−j}) / Σ_{j<k} α_j` for one row.
///
/// `C_{i−j}` follows `predecessor` `j` times; `k` is 1 plus the number of
/// steps for which both `Q_{t−j}` and `C_{i−j}` exist, contiguous from
/// `j = 0`, at most `min(steps, α.len())`. `pair(c, j)` gives `s_e` and
/// `C_cat` of query step `j` and stored row `c`. The result is monotone in
/// every `s_e` (each operation is), which the compressed scan relies on to
/// bound it from the codes.
#[inline]
pub(crate) fn temporal_hit<M: KeyframeMemory + ?Sized>(
    params: &VprParams,
    memory: &M,
    steps: usize,
    row: usize,
    pair: impl Fn(usize, usize) -> (f32, Option<f32>),
) -> ScalHit {
    let rows = memory.descriptors().len();
    let steps = STEPS.min(steps);
    let (mut num, mut den) = (0.0f32, 0.0f32);
    let (mut first_cos, mut first_cat, mut current) = (0.0, None, 0.0);
    let mut depth = 0;
    let mut c_row = row;
    for j in 0..steps {
        if j > 0 {
            match memory.predecessor(c_row) {
                Some(p) if p < rows => c_row = p,
                _ => break,
            }
        }
        let (s_e, c_cat) = pair(c_row, j);
        let s_tilde = modulated(s_e, c_cat, params.lambda_c);
        if j == 0 {
            (first_cos, first_cat, current) = (s_e, c_cat, s_tilde);
        }
        num += params.alpha[j] * s_tilde;
        den += params.alpha[j];
        depth = j + 1;
    }
    let average = if den > 0.0 { num / den } else { 0.0 };
    let score = clip01(match params.temporal {
        TemporalMode::Average => average,
        TemporalMode::Support => average.max(current),
    });
    ScalHit {
        row,
        score,
        cosine: first_cos,
        scene_compatibility: first_cat,
        depth,
    }
}

/// Temporal steps SCAL can use: the length of `α`.
pub(crate) const STEPS: usize = 3;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vpr::memory::VecMemory;
    use crate::vpr::scan::scal_scores;
    use crate::vpr::testing::{
        close, features, features_of, memory_strategy, scene_strategy, unit_vector,
    };
    use proptest::prelude::*;

    /// SCAL for one row written the plain way, one `cosine` per pair, as
    /// the reference the fused scan must reproduce exactly.
    fn reference_hit(
        params: &VprParams,
        history: &[&Features],
        m: &VecMemory,
        row: usize,
    ) -> ScalHit {
        let (mut num, mut den, mut depth) = (0.0f32, 0.0f32, 0);
        let (mut first_cos, mut first_cat, mut current) = (0.0, None, 0.0);
        let mut c_row = Some(row);
        for (j, q) in history.iter().enumerate().take(params.alpha.len()) {
            let Some(c) = c_row else { break };
            let s_e = cosine(&q.descriptor, &m.descriptors().row(c));
            let c_cat = scene_compatibility(&q.scene, m.scene(c));
            let s_tilde = modulated(s_e, c_cat, params.lambda_c);
            if j == 0 {
                (first_cos, first_cat, current) = (s_e, c_cat, s_tilde);
            }
            num += params.alpha[j] * s_tilde;
            den += params.alpha[j];
            depth = j + 1;
            c_row = m.predecessor(c);
        }
        ScalHit {
            row,
            score: clip01(match params.temporal {
                TemporalMode::Average => num / den,
                TemporalMode::Support => (num / den).max(current),
            }),
            cosine: first_cos,
            scene_compatibility: first_cat,
            depth,
        }
    }

    #[test]
    fn the_appearance_channel_blends_into_s_e_where_both_sides_have_it() {
        use crate::vpr::appearance::LEN;
        let stripes = |period: usize| -> Vec<i8> {
            (0..LEN)
                .map(|i| if i % period < period / 2 { 20 } else { -20 })
                .collect()
        };
        let with = |descriptor: &[f32], appearance: Vec<i8>| Features {
            appearance,
            ..features(descriptor, &[], vec![])
        };
        let mut m = VecMemory::new(2);
        // Same descriptor cosine 0.6 for both rows; row 1 has the query's
        // thumbnail, row 0 one that is uncorrelated with it, row 2 none.
        m.push(with(&[0.6, 0.8], stripes(4)), None);
        m.push(with(&[0.6, 0.8], stripes(2)), None);
        m.push(with(&[0.6, 0.8], vec![]), None);
        let query = with(&[1.0, 0.0], stripes(2));
        let q = ScalQuery {
            history: vec![&query],
        };
        let params = VprParams {
            appearance_weight: 0.25,
            lambda_c: 0.0,
            ..VprParams::default()
        };
        let hits = scal_scores(&params, &q, &m, &|_| true);
        let cosine_of = |row: usize| hits.iter().find(|h| h.row == row).unwrap().cosine;
        // ρ = 1: 0.75 × 0.6 + 0.25 × 1 = 0.7; ρ = 0: 0.75 × 0.6 = 0.45;
        // no thumbnail: the cosine alone, 0.6.
        assert_eq!(hits[0].row, 1);
        assert!(close(cosine_of(1), 0.7));
        assert!(close(cosine_of(0), 0.45));
        assert!(close(cosine_of(2), 0.6));
        // Weight 0: the channel is off.
        let off = VprParams {
            appearance_weight: 0.0,
            ..params
        };
        for hit in scal_scores(&off, &q, &m, &|_| true) {
            assert!(close(hit.cosine, 0.6));
        }
    }

    #[test]
    fn cosine_is_clipped() {
        // Dot = −0.6: clipped to 0.
        assert_eq!(cosine(&[1.0, 0.0], &[-0.6, 0.8]), 0.0);
        // Dot = 0.6.
        assert!(close(cosine(&[1.0, 0.0], &[0.6, 0.8]), 0.6));
        // Rounding above 1 is clipped to 1.
        assert_eq!(cosine(&[1.0000001, 0.0], &[1.0, 0.0]), 1.0);
        assert_eq!(cosine(&[f32::NAN], &[1.0]), 0.0);
    }

    #[test]
    fn bhattacharyya_compatibility() {
        let sc = |v: &[(u32, f32)]| -> Vec<SceneClass> {
            v.iter()
                .map(|&(class_id, probability)| SceneClass {
                    class_id,
                    probability,
                })
                .collect()
        };
        // Only class 1 is shared: sqrt(0.6 · 0.5) = sqrt(0.3) = 0.547723.
        let a = sc(&[(1, 0.6), (2, 0.4)]);
        let b = sc(&[(3, 0.5), (1, 0.5)]);
        assert!(close(scene_compatibility(&a, &b).unwrap(), 0.547723));
        // Class ids beyond the dense table take the sparse path:
        // sqrt(0.4 · 0.9) = 0.6, and sqrt(0.6 · 0.6) = 0.6.
        let far = sc(&[(1, 0.6), (u32::MAX, 0.4)]);
        let far2 = sc(&[(u32::MAX, 0.9)]);
        assert!(close(scene_compatibility(&far, &far2).unwrap(), 0.6));
        assert!(close(scene_compatibility(&far, &a).unwrap(), 0.6));
        // Identical: sqrt(.64²) + sqrt(.36²) = 1.
        let c = sc(&[(4, 0.64), (5, 0.36)]);
        assert!(close(scene_compatibility(&c, &c).unwrap(), 1.0));
        // Disjoint: 0.
        assert_eq!(scene_compatibility(&a, &c), Some(0.0));
        assert_eq!(scene_compatibility(&a, &[]), None);
        assert_eq!(scene_compatibility(&[], &a), None);
    }

    #[test]
    fn scene_modulation() {
        // 0.8 · (1 + 0.1 · 0.5) / 1.1 = 0.84 / 1.1 = 0.763636.
        assert!(close(modulated(0.8, Some(0.5), 0.1), 0.763636));
        // C = 1 leaves s_e unchanged; C = 0 gives 0.8 / 1.1 = 0.727273.
        assert!(close(modulated(0.8, Some(1.0), 0.1), 0.8));
        assert!(close(modulated(0.8, Some(0.0), 0.1), 0.727273));
        // No scene model: no modulation.
        assert_eq!(modulated(0.8, None, 0.1), 0.8);
    }

    /// Rows: 0 = (0, 1), 1 = (0.6, 0.8) after 0, 2 = (0.8, 0.6) after 1.
    /// Every query observation is (1, 0), so the cosines are the x parts.
    fn chain() -> VecMemory {
        let mut m = VecMemory::new(2);
        let r0 = m.push(features(&[0.0, 1.0], &[], vec![]), None);
        let r1 = m.push(features(&[0.6, 0.8], &[], vec![]), Some(r0));
        m.push(features(&[0.8, 0.6], &[], vec![]), Some(r1));
        m
    }

    /// The paper's temporal average.
    fn paper() -> VprParams {
        VprParams {
            temporal: TemporalMode::Average,
            ..VprParams::default()
        }
    }

    fn scores_with(params: &VprParams, history_len: usize, m: &VecMemory) -> Vec<ScalHit> {
        let q = features(&[1.0, 0.0], &[], vec![]);
        let history = vec![&q; history_len];
        let mut hits = scal_scores(params, &ScalQuery { history }, m, &|_| true);
        hits.sort_by_key(|h| h.row);
        hits
    }

    fn scores(history_len: usize, m: &VecMemory) -> Vec<ScalHit> {
        scores_with(&paper(), history_len, m)
    }

    #[test]
    fn temporal_support_raises_but_never_lowers() {
        let m = chain();
        let hits = scores_with(&VprParams::default(), 3, &m);
        // Row 2: average 0.58 < s̃_e 0.8, so 0.8.
        assert!(close(hits[2].score, 0.8));
        // Row 1: average 0.375 < 0.6.
        assert!(close(hits[1].score, 0.6));
        // A weak current pair with a strong history is raised:
        // (0.5 · 0.6 + 0.3 · 1) / 0.8 = 0.75 > 0.6.
        let mut m = VecMemory::new(2);
        let r0 = m.push(features(&[1.0, 0.0], &[], vec![]), None);
        m.push(features(&[0.6, 0.8], &[], vec![]), Some(r0));
        let hits = scores_with(&VprParams::default(), 2, &m);
        assert!(close(hits[1].score, 0.75));
    }

    #[test]
    fn temporal_score_depths() {
        let m = chain();
        let hits = scores(3, &m);
        // Row 2, k = 3: 0.5 · 0.8 + 0.3 · 0.6 + 0.2 · 0 = 0.58.
        assert_eq!(hits[2].depth, 3);
        assert!(close(hits[2].score, 0.58));
        assert!(close(hits[2].cosine, 0.8));
        // Row 1, k = 2 (no second predecessor): (0.5 · 0.6 + 0.3 · 0) / 0.8
        // = 0.375, i.e. α renormalised to 0.5/0.8 and 0.3/0.8.
        assert_eq!(hits[1].depth, 2);
        assert!(close(hits[1].score, 0.375));
        // Row 0, k = 1: s_e = 0.
        assert_eq!(hits[0].depth, 1);
        assert!(close(hits[0].score, 0.0));

        // A query history of two limits row 2 to k = 2:
        // (0.5 · 0.8 + 0.3 · 0.6) / 0.8 = 0.725.
        let hits = scores(2, &m);
        assert_eq!(hits[2].depth, 2);
        assert!(close(hits[2].score, 0.725));
        // History of one: k = 1, S_s = s_e = 0.8.
        let hits = scores(1, &m);
        assert_eq!(hits[2].depth, 1);
        assert!(close(hits[2].score, 0.8));
        // No history: nothing.
        assert!(scores(0, &m).is_empty());
    }

    #[test]
    fn temporal_score_with_scene_modulation() {
        // Current pair: s_e = 0.8, C_cat = sqrt(0.25) = 0.5 → 0.763636.
        // Previous pair: s_e = 0.6, no scene on the candidate → 0.6.
        // k = 2: (0.5 · 0.763636 + 0.3 · 0.6) / 0.8 = 0.702273.
        let mut m = VecMemory::new(2);
        let r0 = m.push(features(&[0.6, 0.8], &[], vec![]), None);
        let r1 = m.push(features(&[0.8, 0.6], &[(7, 0.25)], vec![]), Some(r0));
        let q0 = features(&[1.0, 0.0], &[(7, 1.0)], vec![]);
        let q1 = features(&[1.0, 0.0], &[(7, 1.0)], vec![]);
        let hits = scal_scores(
            &paper(),
            &ScalQuery {
                history: vec![&q0, &q1],
            },
            &m,
            &|row| row == r1,
        );
        assert_eq!(hits.len(), 1);
        assert_eq!(hits[0].row, r1);
        assert_eq!(hits[0].scene_compatibility, Some(0.5));
        assert!(close(hits[0].score, 0.702273));
    }

    #[test]
    fn eligibility_and_top_k_with_ties() {
        // Five identical rows: all S_s = 1; ties go to the lower row.
        let mut m = VecMemory::new(2);
        for _ in 0..5 {
            m.push(features(&[1.0, 0.0], &[], vec![]), None);
        }
        let q = features(&[1.0, 0.0], &[], vec![]);
        let params = VprParams {
            top_k: 2,
            ..VprParams::default()
        };
        let hits = scal_scores(&params, &ScalQuery { history: vec![&q] }, &m, &|row| {
            row != 0
        });
        let rows: Vec<usize> = hits.iter().map(|h| h.row).collect();
        assert_eq!(rows, vec![1, 2]);
    }

    proptest! {
        #[test]
        fn top_k_equals_brute_force(
            m in memory_strategy(4, 60),
            history in prop::collection::vec((unit_vector(4), scene_strategy()), 1..4),
            mask in prop::collection::vec(any::<bool>(), 60),
            k in 1usize..30,
        ) {
            let feats = features_of(history);
            let query = ScalQuery { history: feats.iter().collect() };
            let params = VprParams { top_k: k, ..VprParams::default() };
            let eligible = |row: usize| mask[row];
            let fast = scal_scores(&params, &query, &m, &eligible);

            let mut all: Vec<ScalHit> = (0..m.descriptors().len())
                .filter(|&r| eligible(r))
                .map(|r| reference_hit(&params, &query.history, &m, r))
                .collect();
            all.sort_by(crate::vpr::scan::by_score);
            all.truncate(k);
            prop_assert_eq!(fast, all);
        }

        #[test]
        fn scores_are_in_unit_interval(
            m in memory_strategy(4, 60),
            history in prop::collection::vec((unit_vector(4), scene_strategy()), 1..4),
        ) {
            let feats = features_of(history);
            let query = ScalQuery { history: feats.iter().collect() };
            for hit in scal_scores(&VprParams::default(), &query, &m, &|_| true) {
                prop_assert!((0.0..=1.0).contains(&hit.score));
                prop_assert!((1..=3).contains(&hit.depth));
            }
        }
    }
}
