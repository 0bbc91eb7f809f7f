//! Binary visual vocabulary and tf-idf bag-of-words vectors, after DBoW2
//! (Gálvez-López & Tardós 2012), the library behind ORB-SLAM3's place
//! recognition.
//!
//! The vocabulary is a tree built by hierarchical k-majority: k-means on
//! Hamming distance whose centres are bitwise majorities, seeded by
//! k-means++, with branching `k` and up to `depth` levels; its leaves are the
//! words. A descriptor's word is found by descending to the nearest child at
//! each level. Word weights are DBoW2's idf, `ln(N / n_w)` over the training
//! images; a bag-of-words vector sums the idf of each descriptor's word and
//! is L1-normalised, and two vectors score `1 - 0.5 |v/|v| - w/|w||_1`.
//!
//! Written here rather than taken from the `abow` crate (the Rust DBoW port):
//! abow 0.4 has no idf (every word weighs 1), seeds k-means++ from
//! `thread_rng` so training cannot be reproduced, iterates k-means without a
//! bound, and pulls rand 0.8 / thiserror 1 beside the workspace's rand 0.10 /
//! thiserror 2. Training here is deterministic: each tree node draws from its
//! own generator seeded by `(seed, node index)`.

use std::collections::VecDeque;

use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

use super::orb::{hamming, Descriptor};

/// Index of a word (vocabulary leaf).
pub type WordId = u32;

/// Vocabulary training settings.
#[derive(Clone, Debug, PartialEq)]
pub struct BowParams {
    /// Children per tree node (`k`).
    pub branching: usize,
    /// Levels of clustering below the root (`L`): at most `k^L` words.
    pub depth: usize,
    /// Cap on k-majority iterations per node. DBoW2 iterates until the
    /// assignment stops changing, but bitwise-majority centres can cycle
    /// (about a fifth of the nodes hit 20 on 1000 real images), so the cap
    /// bounds training time; the last assignment is still to the nearest
    /// centre, as lookups descend.
    pub max_iterations: usize,
    /// Seed of the k-means++ draws.
    pub seed: u64,
}

impl Default for BowParams {
    /// k = 10, L = 4: at most 10^4 words, fitting vocabularies trained on a
    /// few hundred to a few thousand images (ORB-SLAM3's is k = 10, L = 6,
    /// trained on a large generic image set).
    fn default() -> Self {
        Self {
            branching: 10,
            depth: 4,
            max_iterations: 20,
            seed: 0x0DB0_5EED,
        }
    }
}

/// A vocabulary tree node; a leaf carries its word.
#[derive(Clone, Debug)]
struct Node {
    center: Descriptor,
    /// Range of this node's children in `Vocabulary::nodes` (empty for leaves).
    children: std::ops::Range<u32>,
    word: Option<WordId>,
}

/// Hierarchical binary vocabulary with idf word weights.
#[derive(Clone, Debug)]
pub struct Vocabulary {
    /// Tree in breadth-first order; node 0 is the root (its centre is unused).
    nodes: Vec<Node>,
    /// idf weight of each word.
    idf: Vec<f32>,
}

impl Vocabulary {
    /// Clusters all descriptors of `images` into a vocabulary and sets each
    /// word's idf from how many of `images` contain it.
    pub fn train(images: &[Vec<Descriptor>], params: &BowParams) -> Self {
        let all: Vec<Descriptor> = images.concat();
        let mut vocabulary = Self::cluster(&all, params);
        vocabulary.set_idf(images);
        vocabulary
    }

    /// Number of words (leaves).
    pub fn num_words(&self) -> usize {
        self.idf.len()
    }

    /// idf weight of `word` (0 for a word in every training image, or in none).
    pub fn idf(&self, word: WordId) -> f32 {
        self.idf.get(word as usize).copied().unwrap_or(0.0)
    }

    /// The word of a descriptor, by descending to the nearest child at each
    /// level (`None` only for an empty vocabulary).
    pub fn word(&self, descriptor: &Descriptor) -> Option<WordId> {
        let mut node = self.nodes.first()?;
        loop {
            if let Some(word) = node.word {
                return Some(word);
            }
            let children = &self.nodes[node.children.start as usize..node.children.end as usize];
            node = children
                .iter()
                .min_by_key(|c| hamming(&c.center, descriptor))?;
        }
    }

    /// tf-idf bag-of-words vector of an image's descriptors, L1-normalised.
    pub fn transform(&self, descriptors: &[Descriptor]) -> BowVector {
        BowVector::from_weights(
            descriptors
                .iter()
                .filter_map(|d| self.word(d))
                .map(|w| (w, self.idf(w))),
        )
    }

    /// Builds the tree breadth-first: each queued node is split by
    /// k-majority; a child becomes a word at the last level or when its
    /// descriptors cannot be split further (all equal).
    fn cluster(descriptors: &[Descriptor], params: &BowParams) -> Self {
        let mut nodes = vec![Node {
            center: [0; 32],
            children: 0..0,
            word: None,
        }];
        let mut words: WordId = 0;
        let k = params.branching.max(2);
        let mut queue = VecDeque::new();
        if !descriptors.is_empty() && params.depth > 0 {
            queue.push_back((
                0usize,
                (0..descriptors.len() as u32).collect::<Vec<_>>(),
                0usize,
            ));
        }
        while let Some((index, members, level)) = queue.pop_front() {
            let node_seed = params.seed ^ (index as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
            let mut rng = StdRng::seed_from_u64(node_seed);
            let groups = k_majority(descriptors, &members, k, params.max_iterations, &mut rng);
            let start = nodes.len() as u32;
            for (center, group) in groups {
                let child = nodes.len();
                let first = descriptors[group[0] as usize];
                let uniform = group.iter().all(|&i| descriptors[i as usize] == first);
                let word = if level + 1 >= params.depth || uniform {
                    words += 1;
                    Some(words - 1)
                } else {
                    queue.push_back((child, group, level + 1));
                    None
                };
                nodes.push(Node {
                    center,
                    children: 0..0,
                    word,
                });
            }
            nodes[index].children = start..nodes.len() as u32;
        }
        Self {
            nodes,
            idf: vec![0.0; words as usize],
        }
    }

    /// DBoW2's idf: `ln(N / n_w)`, `n_w` = training images whose
    /// descriptors fall in word `w` (0 when `n_w` = 0).
    fn set_idf(&mut self, images: &[Vec<Descriptor>]) {
        let mut containing = vec![0u32; self.idf.len()];
        let mut last_image = vec![usize::MAX; self.idf.len()];
        for (i, image) in images.iter().enumerate() {
            for d in image {
                if let Some(w) = self.word(d) {
                    let w = w as usize;
                    if last_image[w] != i {
                        last_image[w] = i;
                        containing[w] += 1;
                    }
                }
            }
        }
        let n = images.len() as f32;
        for (idf, &count) in self.idf.iter_mut().zip(&containing) {
            *idf = if count > 0 {
                (n / count as f32).ln()
            } else {
                0.0
            };
        }
    }
}

/// Splits `members` (indices into `descriptors`) into at most `k` groups by
/// k-majority; returns each group's centre and members, no group empty.
/// With at most `k` distinct descriptors each distinct value is a group.
fn k_majority(
    descriptors: &[Descriptor],
    members: &[u32],
    k: usize,
    max_iterations: usize,
    rng: &mut StdRng,
) -> Vec<(Descriptor, Vec<u32>)> {
    let desc = |m: u32| &descriptors[m as usize];
    let mut distinct: Vec<Descriptor> = Vec::with_capacity(k + 1);
    for &m in members {
        if !distinct.contains(desc(m)) {
            distinct.push(*desc(m));
            if distinct.len() > k {
                break;
            }
        }
    }
    let mut centers = if distinct.len() <= k {
        distinct
    } else {
        kmeans_pp_seeds(descriptors, members, k, rng)
    };

    let mut assignment = vec![usize::MAX; members.len()];
    for iteration in 0..max_iterations.max(1) {
        if iteration > 0 {
            update_centers(descriptors, members, &assignment, &mut centers);
        }
        let mut changed = false;
        for (slot, &m) in assignment.iter_mut().zip(members) {
            let nearest = nearest(&centers, desc(m));
            if *slot != nearest {
                *slot = nearest;
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }

    let mut groups = vec![Vec::new(); centers.len()];
    for (&c, &m) in assignment.iter().zip(members) {
        groups[c].push(m);
    }
    centers
        .into_iter()
        .zip(groups)
        .filter(|(_, g)| !g.is_empty())
        .collect()
}

/// Index of the centre nearest to `d` (the first one on ties, as in `word`).
fn nearest(centers: &[Descriptor], d: &Descriptor) -> usize {
    let mut best = (u32::MAX, 0);
    for (i, c) in centers.iter().enumerate() {
        let dist = hamming(c, d);
        if dist < best.0 {
            best = (dist, i);
        }
    }
    best.1
}

/// k-means++ seeding: the first centre uniformly, each next one with
/// probability proportional to the squared distance to the nearest chosen.
fn kmeans_pp_seeds(
    descriptors: &[Descriptor],
    members: &[u32],
    k: usize,
    rng: &mut StdRng,
) -> Vec<Descriptor> {
    let desc = |m: u32| &descriptors[m as usize];
    let first = *desc(members[rng.random_range(0..members.len())]);
    let mut nearest_sq: Vec<u64> = members
        .iter()
        .map(|&m| u64::from(hamming(desc(m), &first)).pow(2))
        .collect();
    let mut centers = vec![first];
    while centers.len() < k {
        let total: u64 = nearest_sq.iter().sum();
        if total == 0 {
            break;
        }
        let mut target = rng.random_range(0..total);
        let mut pick = members.len() - 1;
        for (i, &w) in nearest_sq.iter().enumerate() {
            if target < w {
                pick = i;
                break;
            }
            target -= w;
        }
        let center = *desc(members[pick]);
        for (sq, &m) in nearest_sq.iter_mut().zip(members) {
            *sq = (*sq).min(u64::from(hamming(desc(m), &center)).pow(2));
        }
        centers.push(center);
    }
    centers
}

/// Sets each centre to the bitwise majority of its members (a bit is set
/// when at least half of them have it, as DBoW2's `FORB::meanValue`);
/// a centre without members keeps its value.
fn update_centers(
    descriptors: &[Descriptor],
    members: &[u32],
    assignment: &[usize],
    centers: &mut [Descriptor],
) {
    let mut counters = vec![BitCounter::default(); centers.len()];
    for (&c, &m) in assignment.iter().zip(members) {
        counters[c].add(&descriptors[m as usize]);
    }
    for (center, counter) in centers.iter_mut().zip(&mut counters) {
        if let Some(majority) = counter.majority() {
            *center = majority;
        }
    }
}

/// `SPREAD[b]` has byte `j` equal to bit `j` of `b`, so adding it counts
/// eight bits at once in eight byte lanes.
const SPREAD: [u64; 256] = {
    let mut table = [0u64; 256];
    let mut b = 0;
    while b < 256 {
        let mut j = 0;
        while j < 8 {
            table[b] |= (((b >> j) & 1) as u64) << (8 * j);
            j += 1;
        }
        b += 1;
    }
    table
};

/// Per-bit set counts over many descriptors (SWAR: byte lanes, flushed
/// before they can overflow).
#[derive(Clone)]
struct BitCounter {
    lanes: [u64; 32],
    pending: u32,
    totals: [u32; 256],
    count: u32,
}

impl Default for BitCounter {
    fn default() -> Self {
        Self {
            lanes: [0; 32],
            pending: 0,
            totals: [0; 256],
            count: 0,
        }
    }
}

impl BitCounter {
    fn add(&mut self, d: &Descriptor) {
        for (lane, &byte) in self.lanes.iter_mut().zip(d) {
            *lane += SPREAD[byte as usize];
        }
        self.pending += 1;
        self.count += 1;
        if self.pending == 255 {
            self.flush();
        }
    }

    fn flush(&mut self) {
        for (i, lane) in self.lanes.iter_mut().enumerate() {
            for j in 0..8 {
                self.totals[i * 8 + j] += ((*lane >> (8 * j)) & 0xff) as u32;
            }
            *lane = 0;
        }
        self.pending = 0;
    }

    /// Bitwise majority (bit `i` = byte `i / 8`, bit `i % 8`), `None` if empty.
    fn majority(&mut self) -> Option<Descriptor> {
        if self.count == 0 {
            return None;
        }
        self.flush();
        let mut d = [0u8; 32];
        for (i, &t) in self.totals.iter().enumerate() {
            if 2 * t >= self.count {
                d[i / 8] |= 1 << (i % 8);
            }
        }
        Some(d)
    }
}

/// Sparse bag-of-words vector: `(word, weight)` sorted by word, weights
/// positive and summing to 1 (or empty).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BowVector {
    entries: Vec<(WordId, f32)>,
}

impl BowVector {
    /// Sums the weights per word, drops non-positive ones and L1-normalises.
    pub fn from_weights(weights: impl IntoIterator<Item = (WordId, f32)>) -> Self {
        let mut raw: Vec<(WordId, f32)> = weights.into_iter().collect();
        raw.sort_unstable_by_key(|&(w, _)| w);
        let mut entries: Vec<(WordId, f32)> = Vec::with_capacity(raw.len());
        for (w, v) in raw {
            match entries.last_mut() {
                Some(last) if last.0 == w => last.1 += v,
                _ => entries.push((w, v)),
            }
        }
        entries.retain(|&(_, v)| v > 0.0);
        let sum: f32 = entries.iter().map(|&(_, v)| v).sum();
        if sum > 0.0 {
            for e in &mut entries {
                e.1 /= sum;
            }
        }
        Self { entries }
    }

    /// `(word, weight)` pairs sorted by word.
    pub fn entries(&self) -> &[(WordId, f32)] {
        &self.entries
    }

    /// Whether no word has weight.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// DBoW2's L1 score `1 - 0.5 |v - w|_1` of two normalised vectors, in
    /// [0, 1]: computed over shared words as `0.5 Σ (|v_i| + |w_i| - |v_i - w_i|)`
    /// like DBoW2's `L1Scoring`; 0 if either is empty.
    pub fn l1_score(&self, other: &BowVector) -> f32 {
        let (mut i, mut j) = (0, 0);
        let mut sum = 0.0;
        while i < self.entries.len() && j < other.entries.len() {
            let (wa, va) = self.entries[i];
            let (wb, vb) = other.entries[j];
            match wa.cmp(&wb) {
                std::cmp::Ordering::Less => i += 1,
                std::cmp::Ordering::Greater => j += 1,
                std::cmp::Ordering::Equal => {
                    sum += va.abs() + vb.abs() - (va - vb).abs();
                    i += 1;
                    j += 1;
                }
            }
        }
        0.5 * sum
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// `center` with `flips` random bits flipped.
    pub(in super::super) fn noisy(
        center: &Descriptor,
        flips: usize,
        rng: &mut StdRng,
    ) -> Descriptor {
        let mut d = *center;
        for _ in 0..flips {
            let bit = rng.random_range(0..256usize);
            d[bit / 8] ^= 1 << (bit % 8);
        }
        d
    }

    pub(in super::super) fn random_descriptor(rng: &mut StdRng) -> Descriptor {
        let mut d = [0u8; 32];
        rng.fill(&mut d[..]);
        d
    }

    /// `n_clusters` random centres with `per_cluster` members each (≤ 8 bits off).
    fn clusters(n_clusters: usize, per_cluster: usize, seed: u64) -> Vec<Vec<Descriptor>> {
        let mut rng = StdRng::seed_from_u64(seed);
        (0..n_clusters)
            .map(|_| {
                let c = random_descriptor(&mut rng);
                (0..per_cluster).map(|_| noisy(&c, 8, &mut rng)).collect()
            })
            .collect()
    }

    /// Asserts every cluster's members share one word set, disjoint from the others'.
    fn assert_clusters_own_words(
        vocabulary: &Vocabulary,
        groups: &[Vec<Descriptor>],
        one_word_each: bool,
    ) {
        let mut seen: Vec<(WordId, usize)> = Vec::new();
        for (g, group) in groups.iter().enumerate() {
            let words: Vec<WordId> = group
                .iter()
                .map(|d| vocabulary.word(d).expect("non-empty vocabulary"))
                .collect();
            if one_word_each {
                assert!(
                    words.iter().all(|&w| w == words[0]),
                    "cluster {g} spread over {words:?}"
                );
            }
            for w in words {
                if let Some(&(_, other)) = seen.iter().find(|&&(sw, _)| sw == w) {
                    assert_eq!(other, g, "word {w} shared by clusters {other} and {g}");
                }
                seen.push((w, g));
            }
        }
    }

    #[test]
    fn distinct_clusters_get_their_own_words() {
        let groups = clusters(6, 40, 11);
        let params = BowParams {
            branching: 6,
            depth: 1,
            ..BowParams::default()
        };
        let vocabulary = Vocabulary::train(&groups, &params);
        assert_eq!(vocabulary.num_words(), 6);
        assert_clusters_own_words(&vocabulary, &groups, true);

        // Deeper trees split clusters further but never mix them.
        let deep = Vocabulary::train(
            &groups,
            &BowParams {
                branching: 3,
                depth: 3,
                ..BowParams::default()
            },
        );
        assert!(deep.num_words() > 6);
        assert_clusters_own_words(&deep, &groups, false);
    }

    #[test]
    fn few_distinct_descriptors_each_become_a_word() {
        let mut rng = StdRng::seed_from_u64(3);
        let a = random_descriptor(&mut rng);
        let b = random_descriptor(&mut rng);
        let images = vec![vec![a, a, b], vec![b]];
        let vocabulary = Vocabulary::train(&images, &BowParams::default());
        assert_eq!(vocabulary.num_words(), 2);
        assert_ne!(vocabulary.word(&a), vocabulary.word(&b));
        // a is in one image of two: ln 2; b is in both: 0.
        let wa = vocabulary.word(&a).expect("word");
        let wb = vocabulary.word(&b).expect("word");
        assert!((vocabulary.idf(wa) - 2f32.ln()).abs() < 1e-6);
        assert_eq!(vocabulary.idf(wb), 0.0);
    }

    #[test]
    fn word_in_every_image_has_zero_idf_and_no_weight() {
        let groups = clusters(5, 20, 5);
        // Every image holds part of cluster 0 plus its own cluster.
        let images: Vec<Vec<Descriptor>> = (1..5)
            .map(|i| {
                let mut d = groups[0][(i - 1) * 5..i * 5].to_vec();
                d.extend_from_slice(&groups[i]);
                d
            })
            .collect();
        let params = BowParams {
            branching: 5,
            depth: 1,
            ..BowParams::default()
        };
        let vocabulary = Vocabulary::train(&images, &params);
        let common = vocabulary.word(&groups[0][0]).expect("word");
        assert_eq!(vocabulary.idf(common), 0.0);
        let own = vocabulary.word(&groups[1][0]).expect("word");
        assert!((vocabulary.idf(own) - 4f32.ln()).abs() < 1e-6);

        let bow = vocabulary.transform(&images[0]);
        assert!(bow.entries().iter().all(|&(w, _)| w != common));
        assert_eq!(bow.entries(), &[(own, 1.0)]);
    }

    #[test]
    fn l1_score_is_one_for_identical_and_zero_for_disjoint() {
        let v = BowVector::from_weights([(3, 2.0), (7, 1.0), (9, 1.0)]);
        assert_eq!(v.entries(), &[(3, 0.5), (7, 0.25), (9, 0.25)]);
        assert!((v.l1_score(&v) - 1.0).abs() < 1e-6);
        let disjoint = BowVector::from_weights([(1, 1.0), (4, 3.0)]);
        assert_eq!(v.l1_score(&disjoint), 0.0);
        // 1 - 0.5 * (|0.5 - 0| + |0.25 - 0.5| + |0.25 - 0| + |0 - 0.5|) = 0.25
        let partial = BowVector::from_weights([(7, 1.0), (11, 1.0)]);
        assert!((v.l1_score(&partial) - 0.25).abs() < 1e-6);
        assert_eq!(v.l1_score(&BowVector::default()), 0.0);
    }

    #[test]
    fn training_is_deterministic() {
        let groups = clusters(30, 30, 9);
        let params = BowParams {
            branching: 4,
            depth: 3,
            ..BowParams::default()
        };
        let a = Vocabulary::train(&groups, &params);
        let b = Vocabulary::train(&groups, &params);
        assert_eq!(a.num_words(), b.num_words());
        for d in groups.iter().flatten() {
            assert_eq!(a.word(d), b.word(d));
        }
    }

    #[test]
    fn bit_counter_takes_the_majority_past_lane_overflow() {
        let mut counter = BitCounter::default();
        let mut ones = [0u8; 32];
        ones[0] = 0b0000_0101;
        ones[31] = 0x80;
        for i in 0..601 {
            // bits of `ones` set in 301 of 601, bit 1 of byte 0 in 300
            let mut d = if i % 2 == 0 { ones } else { [0; 32] };
            if i % 2 == 1 {
                d[0] |= 0b10;
            }
            counter.add(&d);
        }
        assert_eq!(counter.majority(), Some(ones));
        assert_eq!(BitCounter::default().majority(), None);
    }

    #[test]
    fn empty_training_gives_an_empty_vocabulary() {
        let vocabulary = Vocabulary::train(&[], &BowParams::default());
        assert_eq!(vocabulary.num_words(), 0);
        assert_eq!(vocabulary.word(&[0; 32]), None);
        assert!(vocabulary.transform(&[[1; 32]]).is_empty());
    }
}
