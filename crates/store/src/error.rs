//! [`StoreError`], the one error type of the store.
//!
//! A leaf module of its own (it names only the codec's, the snapshot's and
//! the disk check's errors), so that the writer, the journal, the
//! checkpoints and the export can all return it without importing the
//! crate root.

use humem_core::keyframe::KeyframeKey;

use crate::{codec, disk, snapshot};

/// Errors of the store.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// A descriptor's length differs from the store's, at open or insert.
    #[error("descriptor has {found} values but this store holds {expected}-value descriptors")]
    DimensionMismatch {
        /// Descriptor length the store holds.
        expected: usize,
        /// Descriptor length given.
        found: usize,
    },
    /// sled could not open the data directory.
    #[error("data directory {path}: {source}")]
    Open {
        /// The data directory, as given.
        path: String,
        /// What sled reported.
        #[source]
        source: sled::Error,
    },
    /// The store was written by a newer build (or its version is garbled).
    #[error("store format version {found} is not supported (this build reads {supported})")]
    UnsupportedFormat {
        /// Format version recorded in the store.
        found: u32,
        /// Newest format version this build reads and writes.
        supported: u32,
    },
    /// Any other sled error, while reading or writing.
    #[error("sled: {0}")]
    Sled(#[from] sled::Error),
    /// A stored key or record does not decode.
    #[error("corrupt record {key:?}: {source}")]
    Corrupt {
        /// The sled key of the record, as stored.
        key: Vec<u8>,
        /// Why it does not decode.
        #[source]
        source: codec::CodecError,
    },
    /// The writer thread has ended, so no change can be applied.
    #[error("the store writer has stopped")]
    WriterGone,
    /// The writer's queue is full; the change was not queued.
    #[error("the write queue is full ({capacity} pending changes); retry shortly")]
    QueueFull {
        /// Most changes the queue holds.
        capacity: usize,
    },
    /// The flush after a group of changes failed: none of the group is
    /// acknowledged or visible in the index. Holds sled's message.
    #[error("flushing to disk failed: {0}")]
    Flush(String),
    /// A journal entry could not be written.
    #[error("write journal: {0}")]
    Journal(String),
    /// The disk holding the store is nearly full: the change was refused
    /// before sled could run out of space (which it does not survive).
    #[error("the disk holding the store is nearly full: {available} bytes free, {reserve} kept in reserve (store.min_free_bytes); erase keyframes or free disk space")]
    DiskFull {
        /// Bytes free.
        available: u64,
        /// Bytes the store keeps free.
        reserve: u64,
    },
    /// A verdict names a keyframe that is not stored.
    #[error("{role}: keyframe {} of robot {:?}, session {:?} is not stored", .key.keyframe_id, .key.robot_id, .key.session_id)]
    UnknownKeyframe {
        /// Which end of the verdict: `query` or `candidate`.
        role: &'static str,
        /// The key named.
        key: KeyframeKey,
    },
    /// An insert would take a robot past its keyframe quota; nothing of it
    /// was stored.
    #[error("robot {robot:?} holds {held} keyframes and its quota is {max}: storing {adding} more would pass it; erase or reset some first")]
    QuotaExceeded {
        /// The robot.
        robot: String,
        /// Keyframes it holds.
        held: u64,
        /// New keyframes the insert would add.
        adding: u64,
        /// Keyframes it may hold.
        max: u64,
    },
    /// A store export could not be written or read.
    #[error("store export: {0}")]
    Export(String),
    /// Writing the index snapshot failed (the store itself is unharmed).
    #[error("index snapshot: {0}")]
    Snapshot(#[from] snapshot::SnapshotError),
}

impl StoreError {
    /// Whether the change itself is refused (a descriptor of the wrong
    /// length, a verdict on an unknown keyframe, a quota it would pass), so that every store refuses it alike; otherwise the failure
    /// is this store's (disk, sled, queue) and the same change may succeed
    /// later.
    pub fn is_refusal(&self) -> bool {
        matches!(
            self,
            StoreError::DimensionMismatch { .. }
                | StoreError::UnknownKeyframe { .. }
                | StoreError::QuotaExceeded { .. }
        )
    }
}

impl From<disk::Short> for StoreError {
    fn from(short: disk::Short) -> StoreError {
        StoreError::DiskFull {
            available: short.available,
            reserve: short.reserve,
        }
    }
}
