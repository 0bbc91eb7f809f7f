//! Where the index keeps its f32 descriptors: in memory, or, once the
//! store is large, in an unnamed file in the store's directory.
//!
//! A store scanned on its one-byte codes reads only a few thousand f32
//! rows a query (the re-scored candidates and the null sample), so at
//! fleet scale the f32 rows, four fifths of the index, need not be
//! resident: the page cache serves the rows a query reads, and the server's
//! resident memory is the codes and the row table. The rule is checked when
//! the index is loaded and after each group the writer publishes. A store
//! that grows past the threshold moves its rows once, under the index's
//! write lock, so inserts and queries wait for that copy (the development
//! machine writes the page cache at about 400 MB/s: some 2.5 s per GiB);
//! one that opens from a large snapshot never holds them in
//! memory, since its rows stay in the snapshot's file
//! ([`crate::snapshot::read`]). A smaller store, or one scanned in f32,
//! keeps its rows in memory.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use humem_core::index::Index;

/// When the f32 descriptors leave memory: once the store holds at least
/// `min_keyframes` keyframes and its f32 descriptors take at least
/// `min_bytes`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FileRule {
    /// Keyframes from which the rows may leave memory.
    pub min_keyframes: usize,
    /// Bytes of f32 descriptors from which the rows may leave memory.
    pub min_bytes: u64,
}

impl FileRule {
    /// From `min_keyframes` keyframes, whatever their size.
    pub fn from_keyframes(min_keyframes: usize) -> FileRule {
        FileRule {
            min_keyframes,
            min_bytes: 0,
        }
    }

    /// Whether `keyframes` descriptors of `dim` values leave memory.
    pub fn applies(&self, keyframes: usize, dim: usize) -> bool {
        keyframes >= self.min_keyframes && (keyframes as u64) * (dim as u64) * 4 >= self.min_bytes
    }
}

/// The rule, and where the file goes.
#[derive(Debug)]
pub(crate) struct DescriptorPlacement {
    dir: PathBuf,
    /// When the rows leave memory; None: never.
    rule: Option<FileRule>,
    /// Set after a failed move, so that it is not retried on every group.
    gave_up: AtomicBool,
}

impl DescriptorPlacement {
    pub(crate) fn new(dir: PathBuf, rule: Option<FileRule>) -> Self {
        DescriptorPlacement {
            dir,
            rule,
            gave_up: AtomicBool::new(false),
        }
    }

    /// The store's directory, where the file goes.
    pub(crate) fn dir(&self) -> &Path {
        &self.dir
    }

    /// When the descriptors leave memory (None: never).
    pub(crate) fn rule(&self) -> Option<FileRule> {
        self.rule
    }

    /// Moves `index`'s f32 descriptors to a file if the rule says so and
    /// they are still in memory. A failure is logged and leaves them in
    /// memory, where they work as before.
    pub(crate) fn apply(&self, index: &mut Index) {
        let Some(rule) = self.rule else { return };
        if !rule.applies(index.len(), index.dim())
            || index.dim() == 0
            || !index.descriptors_in_memory()
            || self.gave_up.load(Ordering::Relaxed)
        {
            return;
        }
        let started = Instant::now();
        match index.move_descriptors_to_file(&self.dir) {
            Ok(()) => tracing::info!(
                keyframes = index.len(),
                megabytes = (index.len() * index.dim() * 4) as f64 / 1e6,
                seconds = started.elapsed().as_secs_f64(),
                dir = %self.dir.display(),
                "descriptors moved out of memory to an unnamed file (store.descriptors)"
            ),
            Err(error) => {
                self.gave_up.store(true, Ordering::Relaxed);
                tracing::warn!(
                    %error,
                    dir = %self.dir.display(),
                    "could not move the descriptors to a file: they stay in memory"
                );
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tests::kf;

    fn keyframe(id: u64) -> humem_core::keyframe::SemanticKeyframe {
        kf("r", "s", id, 0)
    }

    #[test]
    fn rows_move_once_the_store_reaches_the_threshold() {
        let dir = tempfile::tempdir().unwrap();
        let placement =
            DescriptorPlacement::new(dir.path().to_path_buf(), Some(FileRule::from_keyframes(3)));
        let never = DescriptorPlacement::new(dir.path().to_path_buf(), None);
        let mut index = Index::new(0);
        placement.apply(&mut index);
        assert!(index.descriptors_in_memory(), "empty, dimension unknown");
        for id in 0..3 {
            never.apply(&mut index);
            assert!(index.descriptors_in_memory());
            placement.apply(&mut index);
            assert!(index.descriptors_in_memory(), "{id} keyframes");
            index.upsert(keyframe(id));
        }
        placement.apply(&mut index);
        assert!(!index.descriptors_in_memory());
        index.upsert(keyframe(3));
        let row = index.row_of(&keyframe(3).key).unwrap();
        assert_eq!(&*index.descriptor(row), &[1.0, 0.0, 3.0]);
    }

    #[test]
    fn the_rule_counts_keyframes_and_bytes() {
        let rule = FileRule {
            min_keyframes: 10,
            min_bytes: 4000,
        };
        assert!(!rule.applies(9, 1000), "too few keyframes");
        assert!(!rule.applies(10, 99), "too few bytes");
        assert!(rule.applies(10, 100));
        assert!(FileRule::from_keyframes(0).applies(0, 0));
    }

    #[test]
    fn a_failed_move_leaves_the_rows_in_memory() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("missing");
        let placement = DescriptorPlacement::new(missing, Some(FileRule::from_keyframes(0)));
        let mut index = Index::new(0);
        index.upsert(keyframe(0));
        placement.apply(&mut index);
        assert!(index.descriptors_in_memory());
        assert!(placement.gave_up.load(Ordering::Relaxed));
    }
}
