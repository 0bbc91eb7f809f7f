//! Rebuilding an index from a snapshot: everything but the descriptors
//! row by row, joined at the end with a descriptor matrix loaded on its own
//! (so both load at once and no descriptor is copied).

use crate::engine::matrix::DescriptorMatrix;
use crate::keyframe::SemanticKeyframe;

use super::table::Index;

/// Why [`IndexRestore`] could not rebuild an index.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RestoreError {
    /// More or fewer keyframes were given than announced or than the
    /// matrix has rows.
    #[error("{keyframes} keyframes for {rows} descriptor rows")]
    CountMismatch {
        /// Rows of the loaded matrix.
        rows: usize,
        /// Keyframes given (so far, when too many).
        keyframes: usize,
    },
}

/// An index being rebuilt from a snapshot (see [`Index::restore`]); row
/// `i` of the matrix given to [`IndexRestore::finish`] belongs to the
/// `i`-th keyframe pushed.
#[derive(Debug)]
pub struct IndexRestore {
    index: Index,
    expected: usize,
    /// Rows pushed so far, duplicates included.
    pushed: usize,
    /// Rows whose key an earlier row already had.
    duplicates: Vec<usize>,
}

impl IndexRestore {
    /// Adds the next row's keyframe; its descriptor field is ignored (the
    /// matrix row stands for it). A key seen before is skipped, with its
    /// matrix row: a snapshot taken while the store changed may hold a
    /// keyframe twice, and both copies are the same.
    pub fn push(&mut self, keyframe: SemanticKeyframe) -> Result<(), RestoreError> {
        if self.pushed >= self.expected {
            return Err(RestoreError::CountMismatch {
                rows: self.expected,
                keyframes: self.pushed + 1,
            });
        }
        self.pushed += 1;
        let index = &mut self.index;
        if index.by_key.contains_key(&keyframe.key) {
            self.duplicates.push(self.pushed - 1);
            return Ok(());
        }
        let row = index.rows.len();
        index.attach(row, keyframe);
        Ok(())
    }

    /// The rebuilt index: every row's keyframe joined with `matrix`, whose
    /// row `i` is the `i`-th keyframe pushed's descriptor.
    pub fn finish(self, matrix: DescriptorMatrix) -> Result<Index, RestoreError> {
        let mut index = self.index;
        if self.pushed != matrix.len() {
            return Err(RestoreError::CountMismatch {
                rows: matrix.len(),
                keyframes: self.pushed,
            });
        }
        index.matrix = if self.duplicates.is_empty() {
            matrix
        } else {
            matrix.without_rows(&self.duplicates)
        };
        Ok(index)
    }
}

impl Index {
    /// Starts rebuilding an index of `rows` keyframes from a snapshot:
    /// everything but the descriptors is added row by row with
    /// [`IndexRestore::push`], and the descriptor matrix, loaded on its
    /// own (so both can be loaded at once, and no descriptor is copied),
    /// joins them in [`IndexRestore::finish`].
    pub fn restore(rows: usize) -> IndexRestore {
        let mut index = Index::new(0);
        index.rows.reserve(rows);
        index.ids.reserve(rows);
        index.preds.reserve(rows);
        index.by_key.reserve(rows);
        IndexRestore {
            index,
            expected: rows,
            pushed: 0,
            duplicates: Vec::new(),
        }
    }
}
