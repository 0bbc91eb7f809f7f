//! What a group of writes replaced in sled, so that a failed flush can put
//! it back.
//!
//! The writer applies each change of a group to sled's trees at once (in
//! memory) and flushes the group at the end; only a flushed group reaches
//! the in-memory index. When that flush fails, the callers are told so and
//! the index never sees the group, but sled still holds its writes in
//! memory, and the next successful flush would make them durable: the tree
//! would then hold keyframes, erasures or verdicts that every caller was
//! told had failed and that the index does not have. So before each write
//! the writer records here the value the key held (or that it held none),
//! and on a failed flush it writes those values back in reverse order,
//! which leaves every tree as it was before the group, equal to the index.
//!
//! A record per key written costs one sled read, which the group's writes
//! have just brought into sled's cache.

use sled::IVec;

/// The trees the writer writes, named so a record can say which.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum TreeName {
    Keyframes,
    Journal,
    Meta,
    Verdicts,
    VerdictsByCandidate,
}

/// The writer's own counters, restored with the trees.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Counters {
    /// Descriptor length of the store (0 until the first keyframe).
    pub dim: usize,
    /// The last write sequence used.
    pub sequence: u64,
    /// Keyframes in sled.
    pub keyframes: u64,
}

/// The values a group's writes replaced, in the order they were replaced.
pub(super) struct Rollback {
    /// The counters when the group began.
    pub before: Counters,
    /// `(tree, key, value before)`: `None` where the key held nothing.
    replaced: Vec<(TreeName, Vec<u8>, Option<IVec>)>,
}

impl Rollback {
    /// Starts recording a group, whose writer's counters are `before`.
    pub fn begin(before: Counters) -> Self {
        Rollback {
            before,
            replaced: Vec::new(),
        }
    }

    /// Records what `key` of `tree` holds now, before it is written.
    pub fn remember(&mut self, name: TreeName, tree: &sled::Tree, key: &[u8]) -> sled::Result<()> {
        let before = tree.get(key)?;
        self.replaced.push((name, key.to_vec(), before));
        Ok(())
    }

    /// Writes every recorded value back, newest first, through `tree_of`;
    /// afterwards each key holds what it held before its first record.
    /// Returns the count of keys written back.
    pub fn undo<'t>(self, tree_of: impl Fn(TreeName) -> &'t sled::Tree) -> sled::Result<usize> {
        let count = self.replaced.len();
        for (name, key, before) in self.replaced.into_iter().rev() {
            let tree = tree_of(name);
            match before {
                Some(value) => {
                    tree.insert(key, value)?;
                }
                None => {
                    tree.remove(key)?;
                }
            }
        }
        Ok(count)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn counters() -> Counters {
        Counters {
            dim: 0,
            sequence: 0,
            keyframes: 0,
        }
    }

    #[test]
    fn undo_restores_every_key_to_its_first_recorded_value() {
        let db = sled::Config::new().temporary(true).open().unwrap();
        let tree = db.open_tree("t").unwrap();
        tree.insert(b"kept", b"old".as_slice()).unwrap();
        tree.insert(b"gone", b"was here".as_slice()).unwrap();

        let mut rollback = Rollback::begin(counters());
        // Written twice: the first record (the value before the group) wins.
        rollback.remember(TreeName::Meta, &tree, b"kept").unwrap();
        tree.insert(b"kept", b"new".as_slice()).unwrap();
        rollback.remember(TreeName::Meta, &tree, b"kept").unwrap();
        tree.insert(b"kept", b"newer".as_slice()).unwrap();
        rollback.remember(TreeName::Meta, &tree, b"added").unwrap();
        tree.insert(b"added", b"x".as_slice()).unwrap();
        rollback.remember(TreeName::Meta, &tree, b"gone").unwrap();
        tree.remove(b"gone").unwrap();

        assert_eq!(rollback.undo(|_| &tree).unwrap(), 4);
        assert_eq!(tree.get(b"kept").unwrap().unwrap().as_ref(), b"old");
        assert_eq!(tree.get(b"gone").unwrap().unwrap().as_ref(), b"was here");
        assert!(tree.get(b"added").unwrap().is_none());
        assert_eq!(tree.len(), 2);
    }
}
