//! Calibrated confidence: a scene score that means the same whatever
//! descriptor model produced it.
//!
//! A raw cosine says little on its own. The default EfficientNet GeM
//! descriptor scores unrelated places around 0.8 and revisits around 0.93;
//! EigenPlaces, for which the paper set `τ_s = 0.70`, scores unrelated
//! places far lower. So one threshold on the raw score cannot serve both.
//!
//! The scan that SCAL already runs over the eligible store gives, for free,
//! what this query scores on keyframes that are almost all other places:
//! its per-query null distribution. Its median `m` (robust to the few true
//! places among them) is where "an arbitrary place" lies on this
//! descriptor's scale, for this query. The calibrated scene score is the
//! share of the way from there to a perfect match:
//!
//! `c_s = clip((S_s − m) / (1 − m), 0, 1)`.
//!
//! It is unchanged by any map `s ↦ a s + (1 − a)` of the similarity
//! (`a > 0`), i.e. by where a descriptor puts its unrelated places, and it
//! also takes out a query's own "genericness" (a bland corridor frame that
//! scores high against everything). Measured on every dev data set (docs/scoring.md,
//! "Operating point"), it was chosen over a z-score against the null's MAD
//! or its 90th percentile (whose per-query spread estimates were too noisy:
//! recall at 100 % precision on `town-dev/loop` fell from 0.96 to 0.81 and
//! 0.59) and over the ratio to the query's similarity with its own
//! predecessor (DBoW2's η; undefined for queries without one, and turns make
//! it swing).
//!
//! With fewer than `null_min_samples` eligible keyframes the null is not
//! known and every calibrated score is 0: nothing can be shown to stand out
//! of a store that small.

use strength_reduce::StrengthReducedU32;

use crate::keyframe::KeyframeKey;
use crate::numeric::clip01;
use crate::vpr::params::VprParams;

/// Most scores the median is taken over; larger stores are sampled at an
/// even stride, which keeps the cost of calibration flat at fleet scale.
/// The sample is scored exactly (the compressed scan re-scores it), so it
/// is kept small: the median of 2048 scores is within 0.03 standard
/// deviations of the store's, and every dev data set's store is smaller.
pub const NULL_SAMPLE_CAP: usize = 2048;

/// A keyframe's sample tag: a hash of its key ([`KeyframeKey::stable_hash`], then a finaliser
/// that spreads every bit into the low ones), the same in every process
/// and build, so that the null's sample does not depend on row order.
pub fn sample_tag(key: &KeyframeKey) -> u32 {
    let mut h = key.stable_hash();
    h ^= h >> 33;
    h = h.wrapping_mul(0xff51_afd7_ed55_8ccd);
    h ^= h >> 33;
    (h ^ (h >> 32)) as u32
}

/// [`NullModel::sampled`] at one stride, for testing every row of a scan:
/// the division by the stride is done as a multiplication
/// ([`strength_reduce`]), which is several times faster than a 64-bit
/// division per row.
#[derive(Debug, Clone, Copy)]
pub struct Sampler(Stride);

#[derive(Debug, Clone, Copy)]
enum Stride {
    /// Stride 0 or 1: every keyframe.
    All,
    /// Tags that are multiples of the stride.
    Every(StrengthReducedU32),
    /// A stride past every `u32` tag: only tag 0 is a multiple.
    ZeroOnly,
}

impl Sampler {
    /// The sampler of `stride`.
    pub fn new(stride: usize) -> Sampler {
        Sampler(match u32::try_from(stride) {
            Ok(0 | 1) => Stride::All,
            Ok(stride) => Stride::Every(StrengthReducedU32::new(stride)),
            Err(_) => Stride::ZeroOnly,
        })
    }

    /// Whether the keyframe with sample tag `tag` is in the sample, as
    /// [`NullModel::sampled`] decides it.
    #[inline]
    pub fn keeps(&self, tag: u32) -> bool {
        match self.0 {
            Stride::All => true,
            Stride::Every(stride) => tag % stride == 0,
            Stride::ZeroOnly => tag == 0,
        }
    }
}

/// What a query scores on the eligible store.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct NullModel {
    /// `m`, the median `S_s` over the eligible keyframes (of the sample).
    pub location: f32,
    /// Eligible keyframes the null was estimated from (before sampling).
    pub samples: usize,
}

impl NullModel {
    /// The null of `scores`: `(S_s, sample tag)` of every eligible
    /// keyframe. The median of an even count is the upper of the two middle
    /// values; of more than [`NULL_SAMPLE_CAP`] scores, those whose tag
    /// [`NullModel::sampled`] keeps are taken.
    pub fn estimate(scores: impl ExactSizeIterator<Item = (f32, u32)>) -> NullModel {
        let samples = scores.len();
        let sampler = Sampler::new(Self::stride(samples));
        let sample: Vec<f32> = scores
            .filter(|&(_, tag)| sampler.keeps(tag))
            .map(|(score, _)| score)
            .collect();
        Self::from_sample(sample, samples)
    }

    /// The sampling stride for `samples` scores: every score up to
    /// [`NULL_SAMPLE_CAP`], then about one in `stride`.
    pub fn stride(samples: usize) -> usize {
        samples.div_ceil(NULL_SAMPLE_CAP).max(1)
    }

    /// Whether the keyframe with sample tag `tag` ([`sample_tag`]) is in
    /// the sample at `stride`. Chosen by the keyframe's key, not by its row,
    /// so that replicas and restarts, whose rows are in other orders, take
    /// the same sample and give the same scores.
    pub fn sampled(tag: u32, stride: usize) -> bool {
        stride <= 1 || (tag as usize).is_multiple_of(stride)
    }

    /// The null of a sample already taken at [`NullModel::stride`] from
    /// `samples` scores (the compressed scan scores only the sample).
    pub fn from_sample(mut sample: Vec<f32>, samples: usize) -> NullModel {
        if sample.is_empty() {
            return NullModel::default();
        }
        let middle = sample.len() / 2;
        let (_, median, _) = sample.select_nth_unstable_by(middle, f32::total_cmp);
        NullModel {
            location: *median,
            samples,
        }
    }

    /// `c_s` of a scene score `s` (0 below `null_min_samples`).
    pub fn calibrate(&self, s: f32, params: &VprParams) -> f32 {
        if self.samples < params.null_min_samples || self.location >= 1.0 {
            return 0.0;
        }
        clip01((s - self.location) / (1.0 - self.location))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vpr::testing::close;
    use proptest::prelude::*;

    #[test]
    fn the_sampler_keeps_what_sampled_keeps() {
        let tags = [
            0u32,
            1,
            2,
            3,
            488,
            489,
            978,
            2_217_906_302,
            u32::MAX - 1,
            u32::MAX,
        ];
        let strides = [
            0usize,
            1,
            2,
            3,
            489,
            1 << 20,
            u32::MAX as usize,
            u32::MAX as usize + 1,
        ];
        for stride in strides {
            let sampler = Sampler::new(stride);
            for tag in tags.into_iter().chain((0..5_000).map(|t| t * 7919)) {
                assert_eq!(
                    sampler.keeps(tag),
                    NullModel::sampled(tag, stride),
                    "{tag} at {stride}"
                );
            }
        }
    }

    fn params(min: usize) -> VprParams {
        VprParams {
            null_min_samples: min,
            ..VprParams::default()
        }
    }

    /// Scores tagged 0, 1, 2, … (as rows of a memory without keys).
    fn tagged(
        scores: impl IntoIterator<Item = f32, IntoIter: ExactSizeIterator>,
    ) -> impl ExactSizeIterator<Item = (f32, u32)> {
        scores.into_iter().enumerate().map(|(i, s)| (s, i as u32))
    }

    /// `sample_tag` of (car1, s, 7), computed independently in Python.
    const PINNED: u32 = 2_217_906_302;

    #[test]
    fn median_and_calibration_by_hand() {
        // Sorted 0.5, 0.6, 0.7, 0.8, 0.9: median 0.7.
        let null = NullModel::estimate(tagged([0.9, 0.5, 0.7, 0.6, 0.8]));
        assert_eq!(
            null,
            NullModel {
                location: 0.7,
                samples: 5
            }
        );
        let p = params(5);
        // (0.94 − 0.7) / 0.3 = 0.8.
        assert!(close(null.calibrate(0.94, &p), 0.8));
        // At or below the median: 0; a perfect match: 1.
        assert_eq!(null.calibrate(0.7, &p), 0.0);
        assert_eq!(null.calibrate(0.6, &p), 0.0);
        assert!(close(null.calibrate(1.0, &p), 1.0));
        // Even count: the upper middle value (0.6 of 0.5, 0.6).
        let even = NullModel::estimate(tagged([0.6, 0.5]));
        assert_eq!(even.location, 0.6);
    }

    #[test]
    fn too_few_samples_or_degenerate_null_give_zero() {
        let null = NullModel::estimate(tagged([0.2, 0.3, 0.4]));
        assert_eq!(null.calibrate(0.9, &params(4)), 0.0);
        assert!(close(null.calibrate(0.9, &params(3)), (0.9 - 0.3) / 0.7));
        assert_eq!(NullModel::estimate(tagged([])), NullModel::default());
        let all_ones = NullModel::estimate(tagged([1.0; 20]));
        assert_eq!(all_ones.calibrate(1.0, &params(1)), 0.0);
    }

    #[test]
    fn large_stores_are_sampled_at_an_even_stride() {
        // 20 000 scores, stride 3: every third of 0, 1, 2, ... (as i / 20 000)
        // gives 6 667 values with median index 3 333, value 9 999 / 20 000.
        let n = 20_000;
        let null = NullModel::estimate(tagged((0..n).map(|i| i as f32 / n as f32)));
        assert_eq!(null.samples, n);
        // Stride 10, tags 0, 1, 2, …: every tenth score, 2000 of them; the
        // middle is 10 000.
        assert!(close(null.location, 10_000.0 / 20_000.0));
    }

    #[test]
    fn the_sample_follows_the_keys_not_the_row_order() {
        let n = 20_000u32;
        let scores: Vec<(f32, u32)> = (0..n)
            .map(|i| {
                let key = KeyframeKey {
                    robot_id: "r".into(),
                    session_id: "s".into(),
                    keyframe_id: u64::from(i),
                };
                ((i as f32 * 0.618).fract(), sample_tag(&key))
            })
            .collect();
        let forward = NullModel::estimate(scores.iter().copied());
        let backward = NullModel::estimate(scores.iter().rev().copied());
        assert_eq!(forward, backward);
        // About one in ten keys is sampled.
        let kept = scores
            .iter()
            .filter(|(_, t)| NullModel::sampled(*t, 10))
            .count();
        assert!((1800..2200).contains(&kept), "{kept}");
    }

    #[test]
    fn sample_tags_are_pinned() {
        // The same in every build and process: replicas must agree.
        let key = |robot: &str, id| KeyframeKey {
            robot_id: robot.into(),
            session_id: "s".into(),
            keyframe_id: id,
        };
        assert_eq!(sample_tag(&key("car1", 7)), sample_tag(&key("car1", 7)));
        assert_ne!(sample_tag(&key("car1", 7)), sample_tag(&key("car1", 8)));
        assert_ne!(sample_tag(&key("car1", 7)), sample_tag(&key("car2", 7)));
        assert_eq!(sample_tag(&key("car1", 7)), PINNED);
    }

    proptest! {
        #[test]
        fn invariant_under_affine_maps_that_fix_one(
            scores in prop::collection::vec(0.0f32..1.0, 10..60),
            s in 0.0f32..1.0,
            a in 0.2f32..1.0,
        ) {
            // A descriptor that puts everything at a s + (1 − a) gives the same c_s.
            let p = params(10);
            let map = |x: f32| a * x + (1.0 - a);
            let c = NullModel::estimate(tagged(scores.iter().copied())).calibrate(s, &p);
            let c_mapped = NullModel::estimate(tagged(scores.iter().map(|&x| map(x)))).calibrate(map(s), &p);
            prop_assert!((c - c_mapped).abs() < 1e-3, "{} vs {}", c, c_mapped);
            prop_assert!((0.0..=1.0).contains(&c));
        }

        #[test]
        fn monotone_in_the_score(
            scores in prop::collection::vec(0.0f32..1.0, 10..60),
            s0 in 0.0f32..1.0,
            s1 in 0.0f32..1.0,
        ) {
            let null = NullModel::estimate(tagged(scores));
            let (lo, hi) = if s0 <= s1 { (s0, s1) } else { (s1, s0) };
            prop_assert!(null.calibrate(hi, &params(10)) >= null.calibrate(lo, &params(10)));
        }
    }
}
