//! Durable storage of semantic keyframes in sled, and the in-memory index
//! that queries scan.
//!
//! sled is the source of truth; the [`Index`] is rebuilt from it at start.
//! All changes go through one writer thread ([`writer`]), which applies them
//! to sled in arrival order, flushes once for every group of changes that
//! arrived together (group commit), and only then makes them visible in the
//! index and acknowledges them. So an acknowledged change survives a crash,
//! and a query never sees a keyframe that could still be lost.
//!
//! - the crate root: [`Store`] (open, apply a change, read the index), the
//!   [`Mutation`]s it applies and [`StoreError`];
//! - [`codec`]: the on-disk format, sled keys and versioned postcard
//!   records;
//! - `writer`: the single writer thread, its bounded queue and group
//!   commit.

pub mod codec;
mod writer;

use std::path::Path;
use std::sync::Arc;

use humem_core::observe::SharedObserver;
use parking_lot::RwLock;

pub use humem_core::index::{Index, MapKey};
use humem_core::keyframe::{KeyframeKey, Pose, SemanticKeyframe, SessionKey};

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
}

/// One change to the store, as the writer applies it.
#[derive(Debug, Clone)]
pub enum Mutation {
    /// Store keyframes (replacing same keys), atomically.
    Insert(Vec<SemanticKeyframe>),
    /// Remove keyframes of one session.
    Erase {
        /// The session the keyframes belong to.
        session: SessionKey,
        /// Keyframe ids within the session; ids not stored are skipped.
        keyframe_ids: Vec<u64>,
    },
    /// Remove every keyframe of one map.
    ResetMap(MapKey),
    /// Remove every keyframe of one session.
    ResetSession(SessionKey),
    /// Move keyframes of one session to new poses (and maybe maps).
    UpdatePoses {
        /// The session the keyframes belong to.
        session: SessionKey,
        /// One corrected pose per keyframe.
        updates: Vec<PoseUpdate>,
    },
}

/// A corrected pose for one keyframe of a session.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseUpdate {
    /// Keyframe id, unique within the session.
    pub keyframe_id: u64,
    /// The corrected camera pose in its map.
    pub pose: Pose,
    /// The map the keyframe now belongs to, if a merge moved it.
    pub map_id: Option<u64>,
}

/// What a mutation did.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct MutationOutcome {
    /// Keyframes inserted that replaced stored ones.
    pub replaced: u64,
    /// Keyframes removed, or updated for pose updates.
    pub affected: u64,
    /// Keyframe ids of a pose update that are not stored.
    pub missing: Vec<u64>,
    /// Keyframes in the store afterwards.
    pub store_keyframes: u64,
}

/// The store: sled plus the in-memory index, shared by the service.
#[derive(Clone)]
pub struct Store {
    db: sled::Db,
    index: Arc<RwLock<Index>>,
    writer: writer::WriterHandle,
}

const KEYFRAMES_TREE: &str = "keyframes";
const META_TREE: &str = "meta";
const META_FORMAT: &[u8] = b"format_version";
const META_DIM: &[u8] = b"descriptor_dim";

impl Store {
    /// Opens (or creates) the store in `dir` and rebuilds the index from it.
    /// `dim` pins the descriptor length (0: taken from the first keyframe).
    pub fn open(dir: &Path, dim: usize, queue_capacity: usize) -> Result<Store, StoreError> {
        Self::open_observed(dir, dim, queue_capacity, humem_core::observe::unobserved())
    }

    /// [`Store::open`], with the writer's queue depth reported to `observer`
    /// (queue `store_writer`).
    pub fn open_observed(
        dir: &Path,
        dim: usize,
        queue_capacity: usize,
        observer: SharedObserver,
    ) -> Result<Store, StoreError> {
        let db = sled::Config::new()
            .path(dir)
            .open()
            .map_err(|source| StoreError::Open {
                path: dir.display().to_string(),
                source,
            })?;
        let meta = db.open_tree(META_TREE)?;
        let keyframes = db.open_tree(KEYFRAMES_TREE)?;
        check_format(&meta)?;

        let stored_dim = meta
            .get(META_DIM)?
            .map(|v| u32::from_be_bytes(v.as_ref().try_into().unwrap_or([0; 4])) as usize)
            .unwrap_or(0);
        let dim = match (stored_dim, dim) {
            (0, d) => d,
            (s, 0) => s,
            (s, d) if s == d => s,
            (s, d) => {
                return Err(StoreError::DimensionMismatch {
                    expected: s,
                    found: d,
                })
            }
        };
        if dim != 0 && stored_dim == 0 {
            meta.insert(META_DIM, &(dim as u32).to_be_bytes())?;
        }

        let mut index = Index::new(dim);
        for item in keyframes.iter() {
            let (key, value) = item?;
            let record = codec::decode_record(&value).map_err(|source| StoreError::Corrupt {
                key: key.to_vec(),
                source,
            })?;
            index.upsert(record);
        }
        tracing::info!(
            dir = %dir.display(),
            keyframes = index.len(),
            descriptor_dim = index.dim(),
            "store opened"
        );
        let index = Arc::new(RwLock::new(index));
        let writer = writer::spawn(
            writer::Trees {
                db: db.clone(),
                keyframes,
                meta,
            },
            index.clone(),
            queue_capacity,
            observer,
        );
        Ok(Store { db, index, writer })
    }

    /// Applies a change durably; returns once it is flushed to disk and
    /// visible to queries.
    pub async fn apply(&self, mutation: Mutation) -> Result<MutationOutcome, StoreError> {
        self.writer.submit(mutation).await
    }

    /// Read access to the index, for queries. Hold it briefly.
    pub fn index(&self) -> parking_lot::RwLockReadGuard<'_, Index> {
        self.index.read()
    }

    /// The index handle itself, for blocking tasks that outlive a borrow.
    pub fn index_handle(&self) -> Arc<RwLock<Index>> {
        self.index.clone()
    }

    /// Size of the store on disk, in bytes.
    pub fn disk_bytes(&self) -> u64 {
        self.db.size_on_disk().unwrap_or(0)
    }

    /// Looks up one stored keyframe.
    pub fn get(&self, key: &KeyframeKey) -> Option<SemanticKeyframe> {
        let index = self.index.read();
        index.row_of(key).map(|row| index.keyframe(row))
    }

    /// Flushes everything to disk (at shutdown; acknowledged writes already are).
    pub fn flush(&self) -> Result<(), StoreError> {
        self.db.flush()?;
        Ok(())
    }
}

/// Writes the format version into a new store, upgrades a store of an
/// older version this build still reads (its records stay as they are and
/// are read by their own version byte), and refuses one of a newer version.
fn check_format(meta: &sled::Tree) -> Result<(), StoreError> {
    let supported = u32::from(codec::FORMAT_VERSION);
    match meta.get(META_FORMAT)? {
        None => {
            meta.insert(META_FORMAT, &supported.to_be_bytes())?;
            Ok(())
        }
        Some(v) => {
            let found = u32::from_be_bytes(v.as_ref().try_into().unwrap_or([0xff; 4]));
            if found == supported {
                Ok(())
            } else if (1..supported).contains(&found) {
                meta.insert(META_FORMAT, &supported.to_be_bytes())?;
                tracing::info!(from = found, to = supported, "store format upgraded");
                Ok(())
            } else {
                Err(StoreError::UnsupportedFormat { found, supported })
            }
        }
    }
}

#[cfg(test)]
mod tests;
