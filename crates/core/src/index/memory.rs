//! The index as ranking sees it: the [`KeyframeMemory`] view the scoring
//! layers read rows through.

use crate::engine::filter::RowGroup;
use crate::engine::matrix::DescriptorMatrix;
use crate::keyframe::{ObjectObservation, SceneClass};
use crate::vpr::appearance::AppearanceMatrix;
use crate::vpr::memory::KeyframeMemory;

use super::table::Index;

impl KeyframeMemory for Index {
    fn descriptors(&self) -> &DescriptorMatrix {
        &self.matrix
    }

    fn appearance(&self) -> &AppearanceMatrix {
        &self.appearance
    }

    fn scene(&self, row: usize) -> &[SceneClass] {
        &self.rows[row].scene
    }

    fn predecessor(&self, row: usize) -> Option<usize> {
        self.prev(row)
    }

    fn objects(&self, row: usize) -> &[ObjectObservation] {
        &self.rows[row].objects
    }

    fn text_document_frequency(&self, normalized: &str) -> u32 {
        self.text_df.get(normalized).copied().unwrap_or(0)
    }

    fn keyframe_count(&self) -> u32 {
        u32::try_from(self.rows.len()).unwrap_or(u32::MAX)
    }

    fn sample_tag(&self, row: usize) -> u32 {
        self.tags[row]
    }

    fn rows_tagged(&self, mask: u32) -> Vec<usize> {
        const LANES: usize = 16;
        let mut rows = Vec::new();
        let chunks = self.tags.chunks(LANES);
        for (c, chunk) in chunks.enumerate() {
            // One vector compare a chunk; few chunks hold a sampled row.
            if chunk
                .iter()
                .fold(false, |any, &tag| any | (tag & mask == 0))
            {
                let first = c * LANES;
                rows.extend(
                    (first..)
                        .zip(chunk)
                        .filter(|&(_, &tag)| tag & mask == 0)
                        .map(|(row, _)| row),
                );
            }
        }
        rows
    }

    fn nearest(
        &self,
        query: &[f32],
        count: usize,
        group: Option<RowGroup>,
        keep: &(dyn Fn(usize) -> bool + Sync),
    ) -> Option<Vec<usize>> {
        match group {
            Some(group) => self.nearest_rows_of_map(query, count, group, keep),
            None => self.nearest_rows(query, count, keep),
        }
    }
}
