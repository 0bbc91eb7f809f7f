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
//! write lock (64 MB at the default 32 768 rows × 512); one that opens from
//! a large snapshot never holds them in memory, since its rows stay in the
//! snapshot's file ([`crate::snapshot::read`]). A smaller store, or one
//! scanned in f32, keeps its rows in memory.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use humem_core::index::Index;

/// The rule, and where the file goes.
#[derive(Debug)]
pub(crate) struct DescriptorPlacement {
    dir: PathBuf,
    /// Keyframes from which the rows leave memory; None: never.
    from: Option<usize>,
    /// Set after a failed move, so that it is not retried on every group.
    gave_up: AtomicBool,
}

impl DescriptorPlacement {
    pub(crate) fn new(dir: PathBuf, from: Option<usize>) -> Self {
        DescriptorPlacement {
            dir,
            from,
            gave_up: AtomicBool::new(false),
        }
    }

    /// The store's directory, where the file goes.
    pub(crate) fn dir(&self) -> &Path {
        &self.dir
    }

    /// Keyframes from which the descriptors leave memory (None: never).
    pub(crate) fn from(&self) -> Option<usize> {
        self.from
    }

    /// Moves `index`'s f32 descriptors to a file if the rule says so and
    /// they are still in memory. A failure is logged and leaves them in
    /// memory, where they work as before.
    pub(crate) fn apply(&self, index: &mut Index) {
        let Some(from) = self.from else { return };
        if index.len() < from
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
    use humem_core::keyframe::{Features, KeyframeKey, Pose, SemanticKeyframe};

    fn keyframe(id: u64) -> SemanticKeyframe {
        SemanticKeyframe {
            key: KeyframeKey {
                robot_id: "r".into(),
                session_id: "s".into(),
                keyframe_id: id,
            },
            frame_id: id,
            timestamp: id as f64,
            map_id: 0,
            pose: Pose::default(),
            features: Features {
                descriptor: vec![1.0, id as f32],
                appearance: Vec::new(),
                scene: Vec::new(),
                objects: Vec::new(),
            },
        }
    }

    #[test]
    fn rows_move_once_the_store_reaches_the_threshold() {
        let dir = tempfile::tempdir().unwrap();
        let placement = DescriptorPlacement::new(dir.path().to_path_buf(), Some(3));
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
        assert_eq!(&*index.descriptor(row), &[1.0, 3.0]);
    }

    #[test]
    fn a_failed_move_leaves_the_rows_in_memory() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("missing");
        let placement = DescriptorPlacement::new(missing, Some(0));
        let mut index = Index::new(0);
        index.upsert(keyframe(0));
        placement.apply(&mut index);
        assert!(index.descriptors_in_memory());
        assert!(placement.gave_up.load(Ordering::Relaxed));
    }
}
