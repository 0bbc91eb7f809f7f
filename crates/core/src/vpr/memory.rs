//! The view of the keyframe store that ranking needs.
//!
//! Ranking reads rows of an index, not the store itself: the descriptor
//! matrix, the per-row scene distribution, objects and temporal predecessor,
//! and the document frequencies used for text rarity. Expressing that as a
//! small object-safe trait keeps `vpr/` independent of `store/` (whose
//! in-memory index implements it) and lets tests and benchmarks use the plain
//! [`VecMemory`] below.

use crate::engine::filter::RowGroup;
use crate::engine::matrix::DescriptorMatrix;
use crate::keyframe::{Features, ObjectObservation, SceneClass};
use crate::vpr::appearance::AppearanceMatrix;
use crate::vpr::text::normalize;

/// Read access to the indexed keyframes, addressed by row.
pub trait KeyframeMemory: Sync {
    /// The descriptors, one row per stored keyframe.
    fn descriptors(&self) -> &DescriptorMatrix;
    /// The appearance thumbnails, row-aligned with the descriptors.
    fn appearance(&self) -> &AppearanceMatrix;
    /// Scene-class distribution of `row` (sparse top entries).
    fn scene(&self, row: usize) -> &[SceneClass];
    /// Row of the keyframe that precedes `row` in its robot/session/map
    /// track, if stored.
    fn predecessor(&self, row: usize) -> Option<usize>;
    /// Objects of `row`.
    fn objects(&self, row: usize) -> &[ObjectObservation];
    /// Number of stored keyframes whose text contains this normalised string
    /// (document frequency).
    fn text_document_frequency(&self, normalized: &str) -> u32;
    /// Number of stored keyframes.
    fn keyframe_count(&self) -> u32;
    /// The row's sample tag for the null model
    /// ([`crate::vpr::calibration::sample_tag`] of its key); by default the
    /// row itself, for memories without keys.
    fn sample_tag(&self, row: usize) -> u32 {
        row as u32
    }
    /// Every row whose sample tag has none of `mask`'s bits set, in row
    /// order: the approximate pass's null sample before eligibility. A
    /// memory that keeps its tags in one table reads it in one pass that
    /// the compiler vectorises; a merge query over a million keyframes
    /// otherwise spends more on this walk than on its graph search.
    fn rows_tagged(&self, mask: u32) -> Vec<usize> {
        (0..self.descriptors().len())
            .filter(|&row| self.sample_tag(row) & mask == 0)
            .collect()
    }
    /// The rows of up to `count` stored keyframes whose descriptors are
    /// nearest to `query`, among those `keep` accepts, nearest first, from
    /// an approximate index (a neighbour graph): with `group`, the graph
    /// of that group of rows only (every row `keep` accepts is in it);
    /// None for a memory that keeps no such graph, which is then scanned
    /// in full.
    fn nearest(
        &self,
        _query: &[f32],
        _count: usize,
        _group: Option<RowGroup>,
        _keep: &(dyn Fn(usize) -> bool + Sync),
    ) -> Option<Vec<usize>> {
        None
    }
}

/// A plain `Vec`-backed [`KeyframeMemory`] for tests and benchmarks.
#[derive(Debug, Clone, Default)]
pub struct VecMemory {
    descriptors: DescriptorMatrix,
    appearance: AppearanceMatrix,
    features: Vec<Features>,
    predecessors: Vec<Option<usize>>,
}

impl VecMemory {
    /// An empty memory for descriptors of dimension `dim`.
    pub fn new(dim: usize) -> Self {
        VecMemory {
            descriptors: DescriptorMatrix::new(dim),
            appearance: AppearanceMatrix::default(),
            features: Vec::new(),
            predecessors: Vec::new(),
        }
    }

    /// Appends a keyframe whose track predecessor is `predecessor` and
    /// returns its row. Panics if the descriptor has the wrong dimension.
    pub fn push(&mut self, features: Features, predecessor: Option<usize>) -> usize {
        let row = self.descriptors.push(&features.descriptor);
        self.appearance.push(&features.appearance);
        self.features.push(features);
        self.predecessors.push(predecessor);
        row
    }

    /// Moves the f32 descriptors to a file in `dir`, as a large store's
    /// index does (see [`DescriptorMatrix::move_to_file`]).
    pub fn move_descriptors_to_file(&mut self, dir: &std::path::Path) -> std::io::Result<()> {
        self.descriptors.move_to_file(dir)
    }

    /// The features stored at `row`.
    pub fn features(&self, row: usize) -> &Features {
        &self.features[row]
    }
}

impl KeyframeMemory for VecMemory {
    fn descriptors(&self) -> &DescriptorMatrix {
        &self.descriptors
    }

    fn appearance(&self) -> &AppearanceMatrix {
        &self.appearance
    }

    fn scene(&self, row: usize) -> &[SceneClass] {
        &self.features[row].scene
    }

    fn predecessor(&self, row: usize) -> Option<usize> {
        self.predecessors[row]
    }

    fn objects(&self, row: usize) -> &[ObjectObservation] {
        &self.features[row].objects
    }

    fn text_document_frequency(&self, normalized: &str) -> u32 {
        let count = self
            .features
            .iter()
            .filter(|f| {
                f.objects
                    .iter()
                    .flat_map(|o| &o.texts)
                    .any(|t| normalize(&t.text) == normalized)
            })
            .count();
        u32::try_from(count).unwrap_or(u32::MAX)
    }

    fn keyframe_count(&self) -> u32 {
        u32::try_from(self.features.len()).unwrap_or(u32::MAX)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::keyframe::TextObservation;

    fn with_texts(texts: &[&str]) -> Features {
        Features {
            descriptor: vec![1.0, 0.0],
            appearance: vec![],
            scene: vec![],
            objects: vec![ObjectObservation {
                class_name: "sign".into(),
                confidence: 1.0,
                centroid: [0.5, 0.5],
                area: 0.1,
                texts: texts
                    .iter()
                    .map(|t| TextObservation {
                        text: t.to_string(),
                        confidence: 1.0,
                    })
                    .collect(),
            }],
        }
    }

    #[test]
    fn vec_memory_counts_documents_not_occurrences() {
        let mut m = VecMemory::new(2);
        let a = m.push(with_texts(&["EXIT", "exit!"]), None);
        let b = m.push(with_texts(&["Exit", "B-214"]), Some(a));
        m.push(with_texts(&[]), Some(b));
        assert_eq!(m.keyframe_count(), 3);
        assert_eq!(m.text_document_frequency("exit"), 2);
        assert_eq!(m.text_document_frequency("b 214"), 1);
        assert_eq!(m.text_document_frequency("nothing"), 0);
        assert_eq!(m.predecessor(b), Some(a));
        assert_eq!(m.predecessor(a), None);
        assert_eq!(m.descriptors().len(), 3);
        assert_eq!(m.objects(b)[0].texts.len(), 2);
    }
}
