//! Classical ORB bag-of-words place recognition, the retrieval ORB-SLAM3 does
//! natively, as a baseline for `humem eval`.
//!
//! - [`orb`]: ORB features as ORB-SLAM3 extracts them (1000 per image,
//!   8-level pyramid, per-cell FAST thresholds, quadtree spreading, rBRIEF).
//! - `pattern` (private): the 256 rBRIEF test pairs of OpenCV's ORB, which
//!   [`orb`] samples for each descriptor bit.
//! - [`vocabulary`]: DBoW2-style hierarchical k-majority vocabulary, idf
//!   weights, L1-normalised tf-idf vectors and the L1 score.
//! - [`OrbBowIndex`]: a vocabulary trained on the reference images and an
//!   inverted file over their vectors, scoring a query against every
//!   reference the way DBoW2's database does.
//!
//! One difference from ORB-SLAM3 is deliberate: it loads a vocabulary
//! trained offline on a large generic set, while here the vocabulary is
//! trained on the references being searched (deterministically, fixed
//! seed), so the baseline needs no external file.

pub mod orb;
mod pattern;
pub mod vocabulary;

pub use orb::{detect_and_describe, extract, hamming, Descriptor, KeyPoint, OrbParams};
pub use vocabulary::{BowParams, BowVector, Vocabulary, WordId};

/// Reference images' bag-of-words vectors under a vocabulary trained on them,
/// stored as an inverted file (word → references holding it, with weight).
#[derive(Clone, Debug)]
pub struct OrbBowIndex {
    vocabulary: Vocabulary,
    /// For each word, `(reference index, weight)` of the references holding it.
    inverted: Vec<Vec<(u32, f32)>>,
    n_references: usize,
}

impl OrbBowIndex {
    /// Trains the vocabulary on all reference descriptors (idf over the
    /// references) and indexes each reference's tf-idf vector.
    pub fn build(references: &[Vec<Descriptor>], params: &BowParams) -> Self {
        let vocabulary = Vocabulary::train(references, params);
        let mut inverted = vec![Vec::new(); vocabulary.num_words()];
        for (r, descriptors) in references.iter().enumerate() {
            for &(word, weight) in vocabulary.transform(descriptors).entries() {
                inverted[word as usize].push((r as u32, weight));
            }
        }
        Self {
            vocabulary,
            inverted,
            n_references: references.len(),
        }
    }

    /// L1 score (DBoW2: `1 - 0.5 |q - r|_1` of the normalised tf-idf vectors,
    /// in [0, 1], higher is more similar) of the query against each
    /// reference, in reference order. References sharing no weighted word
    /// with the query score 0.
    pub fn score_all(&self, query: &[Descriptor]) -> Vec<f32> {
        let mut scores = vec![0.0f32; self.n_references];
        for &(word, q) in self.vocabulary.transform(query).entries() {
            for &(r, v) in &self.inverted[word as usize] {
                scores[r as usize] += q + v - (q - v).abs();
            }
        }
        for s in &mut scores {
            *s *= 0.5;
        }
        scores
    }

    /// The trained vocabulary.
    pub fn vocabulary(&self) -> &Vocabulary {
        &self.vocabulary
    }

    /// Number of indexed references.
    pub fn len(&self) -> usize {
        self.n_references
    }

    /// Whether no reference is indexed.
    pub fn is_empty(&self) -> bool {
        self.n_references == 0
    }
}

#[cfg(test)]
mod tests {
    use super::vocabulary::tests::{noisy, random_descriptor};
    use super::*;
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};

    /// 20 references, each 30 of 200 shared "visual words" seen 5 times with
    /// a few bits of noise.
    fn references(rng: &mut StdRng) -> Vec<Vec<Descriptor>> {
        let pool: Vec<Descriptor> = (0..200).map(|_| random_descriptor(rng)).collect();
        (0..20)
            .map(|_| {
                (0..30)
                    .flat_map(|_| {
                        let prototype = pool[rng.random_range(0..pool.len())];
                        (0..5)
                            .map(|_| noisy(&prototype, 6, rng))
                            .collect::<Vec<_>>()
                    })
                    .collect()
            })
            .collect()
    }

    #[test]
    fn noised_reference_ranks_itself_first() {
        let mut rng = StdRng::seed_from_u64(42);
        let refs = references(&mut rng);
        let index = OrbBowIndex::build(&refs, &BowParams::default());
        assert_eq!(index.len(), 20);
        for target in [0, 7, 19] {
            // Drop a fifth of the descriptors and flip 4 more bits in the rest.
            let query: Vec<Descriptor> = refs[target]
                .iter()
                .enumerate()
                .filter(|(i, _)| i % 5 != 0)
                .map(|(_, d)| noisy(d, 4, &mut rng))
                .collect();
            let scores = index.score_all(&query);
            assert_eq!(scores.len(), 20);
            let best = (0..scores.len())
                .max_by(|&a, &b| scores[a].total_cmp(&scores[b]))
                .expect("scores");
            assert_eq!(best, target, "scores {scores:?}");
            let runner_up = (0..20)
                .filter(|&r| r != target)
                .map(|r| scores[r])
                .fold(0.0, f32::max);
            assert!(scores[target] > runner_up + 0.1, "scores {scores:?}");
        }
    }

    #[test]
    fn inverted_file_scores_equal_pairwise_l1_scores() {
        let mut rng = StdRng::seed_from_u64(5);
        let refs = references(&mut rng);
        let index = OrbBowIndex::build(&refs, &BowParams::default());
        let query = &refs[3][..60];
        let q = index.vocabulary().transform(query);
        for (r, s) in index.score_all(query).into_iter().enumerate() {
            let expected = q.l1_score(&index.vocabulary().transform(&refs[r]));
            assert!(
                (s - expected).abs() < 1e-5,
                "reference {r}: {s} vs {expected}"
            );
        }
        assert!((index.score_all(&refs[3])[3] - 1.0).abs() < 1e-5);
    }

    #[test]
    fn empty_query_or_index_scores_nothing() {
        let mut rng = StdRng::seed_from_u64(1);
        let refs = references(&mut rng);
        let index = OrbBowIndex::build(&refs, &BowParams::default());
        assert!(index.score_all(&[]).iter().all(|&s| s == 0.0));
        let empty = OrbBowIndex::build(&[], &BowParams::default());
        assert!(empty.is_empty());
        assert!(empty.score_all(&refs[0]).is_empty());
        let blank = OrbBowIndex::build(&[Vec::new(), Vec::new()], &BowParams::default());
        assert_eq!(blank.score_all(&refs[0]), vec![0.0, 0.0]);
    }
}
