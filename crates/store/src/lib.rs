//! Durable storage of semantic keyframes in sled, and the in-memory index
//! that queries scan.
//!
//! sled is the source of truth. At start the [`Index`] is loaded from its
//! snapshot and brought up to date from the write journal, or, where there
//! is no usable snapshot, rebuilt from every record in sled.
//! All changes go through one writer thread (`writer`), which applies them
//! to sled in arrival order, flushes once for every group of changes that
//! arrived together (group commit), and only then makes them visible in the
//! index and acknowledges them. So an acknowledged change survives a crash,
//! and a query never sees a keyframe that could still be lost.
//!
//! - the crate root: [`Store`] (open, apply a change, read the index) and
//!   the re-exports of the types below that callers use;
//! - `error`: [`StoreError`];
//! - `mutation`: the [`Mutation`]s the store applies, what each did, and
//!   replicated-log entries ([`LogEntry`], [`LogApplied`]);
//! - `options`: [`StoreOptions`], how a store is opened;
//! - `open`: opening a store (format upgrade, the index from its snapshot
//!   or rebuilt from the tree, verdicts), [`OpenReport`];
//! - `recorded`: what a store on disk records, read without opening it
//!   ([`recorded_dim`], [`recorded_log`]);
//! - `layout`: the names of sled's trees and meta keys, [`STORE_FORMAT`];
//! - [`codec`]: the on-disk format, sled keys and versioned postcard
//!   records;
//! - `writer`: the single writer thread, its bounded queue and group
//!   commit (its parts in `writer/`);
//! - `robot_counts`: keyframes per robot as the writer sees sled, for the
//!   quota;
//! - `rollback`: what a group of writes replaced, put back if its flush
//!   fails;
//! - `placement`: whether the index's f32 descriptors stay in memory or
//!   go to a file ([`FileRule`]);
//! - [`journal`]: which keys each change touched, by write sequence;
//! - [`snapshot`]: the index snapshot file beside the tree;
//! - `checkpoint`: when snapshots are taken, on their own thread;
//! - [`disk`]: the free space kept on the store's disk;
//! - [`export`]: a whole store as one file, and a store made from one.
//!
//! Shared types live in leaf modules of their own; the crate root only
//! declares, re-exports and puts a [`Store`] together: no module imports
//! the root or an ancestor.

mod checkpoint;
pub mod codec;
pub mod disk;
mod error;
pub mod export;
pub mod graph_file;
pub mod journal;
mod layout;
mod mutation;
mod open;
mod options;
mod placement;
mod recorded;
mod robot_counts;
mod rollback;
mod settle;
pub mod snapshot;
mod writer;

use std::path::Path;
use std::sync::Arc;

use humem_core::keyframe::{KeyframeKey, SemanticKeyframe};
use humem_core::observe::SharedObserver;
use parking_lot::RwLock;

use layout::{META_LOG_POSITION, META_TREE};

pub use checkpoint::SnapshotReport;
pub use error::StoreError;
pub use humem_core::index::{Index, MapKey};
pub use humem_core::verdict::{RelativeTransform, Verdict, VerificationKind};
pub use layout::STORE_FORMAT;
pub use mutation::{LogApplied, LogEntry, Mutation, MutationOutcome, PoseUpdate};
pub use open::{IndexSource, OpenReport};
pub use options::{StoreOptions, DEFAULT_CACHE_BYTES, DEFAULT_SNAPSHOT_EVERY};
pub use placement::FileRule;
pub use recorded::{recorded_dim, recorded_log, RecordedLog};

/// How long [`Store::index_async`] sleeps before it tries the index again.
const INDEX_RETRY: std::time::Duration = std::time::Duration::from_millis(1);

/// The store: sled plus the in-memory index, shared by the service.
#[derive(Clone)]
pub struct Store {
    db: sled::Db,
    index: Arc<RwLock<Index>>,
    writer: writer::WriterHandle,
    checkpoints: Arc<checkpoint::Checkpoints>,
    opened: Arc<OpenReport>,
}

impl Store {
    /// Opens (or creates) the store in `dir` and loads its index.
    /// `dim` pins the descriptor length (0: taken from the first keyframe).
    pub fn open(dir: &Path, dim: usize, queue_capacity: usize) -> Result<Store, StoreError> {
        Self::open_with(
            dir,
            StoreOptions {
                dim,
                queue_capacity,
                ..StoreOptions::default()
            },
            humem_core::observe::unobserved(),
        )
    }

    /// Opens (or creates) the store in `dir` with `options`, the writer's
    /// queue depth reported to `observer` (queue `store_writer`).
    pub fn open_with(
        dir: &Path,
        options: StoreOptions,
        observer: SharedObserver,
    ) -> Result<Store, StoreError> {
        let open::Opened {
            db,
            index,
            writer,
            checkpoints,
            report,
        } = open::open(dir, options, observer)?;
        Ok(Store {
            db,
            index,
            writer,
            checkpoints,
            opened: Arc::new(report),
        })
    }

    /// The store's directory.
    pub fn dir(&self) -> &Path {
        &self.checkpoints.dir
    }

    /// How this store was opened.
    pub fn opened(&self) -> &OpenReport {
        &self.opened
    }

    /// Writes an index snapshot now, unless the newest one is current (as
    /// at shutdown, so the next start replays nothing). Says what was
    /// written, if anything.
    pub fn snapshot(&self) -> Result<Option<SnapshotReport>, StoreError> {
        self.checkpoints.write_now()
    }

    /// Applies a change durably; returns once it is flushed to disk and
    /// visible to queries.
    pub async fn apply(&self, mutation: Mutation) -> Result<MutationOutcome, StoreError> {
        self.writer.submit(mutation).await
    }

    /// Applies entries of a replicated log, in order, each recording its
    /// position in the same transaction as its change, so a replica that
    /// restarts resumes right after the last entry it applied
    /// ([`Store::log_position`]). Stops at the first entry that cannot be
    /// applied now; see [`LogApplied`].
    pub async fn apply_log(&self, entries: Vec<LogEntry>) -> Result<LogApplied, StoreError> {
        self.writer.submit_log(entries).await
    }

    /// Position of the last replicated-log entry applied (0: none).
    pub fn log_position(&self) -> Result<u64, StoreError> {
        let meta = self.db.open_tree(META_TREE)?;
        Ok(meta
            .get(META_LOG_POSITION)?
            .and_then(|v| v.as_ref().try_into().ok().map(u64::from_be_bytes))
            .unwrap_or(0))
    }

    /// Read access to the index, for queries. Hold it briefly.
    pub fn index(&self) -> parking_lot::RwLockReadGuard<'_, Index> {
        self.index.read()
    }

    /// Read access to the index from async code. While the writer waits
    /// for the index (it waits for the scans in progress to end, tens of
    /// milliseconds, or an exact pass over a large store, hundreds),
    /// [`Store::index`] blocks its thread, and a runtime whose few worker
    /// threads block so stops serving every request meanwhile, answers
    /// and inserts alike. This one sleeps a millisecond at a time instead.
    /// Hold it briefly, never across an `.await`.
    pub async fn index_async(&self) -> parking_lot::RwLockReadGuard<'_, Index> {
        loop {
            if let Some(index) = self.index.try_read() {
                return index;
            }
            tokio::time::sleep(INDEX_RETRY).await;
        }
    }

    /// Waits until no stored keyframe waits to enter the neighbour graph
    /// (after an open, the writer adds those the saved graph lacks in the
    /// background; queries score them exactly meanwhile), or until
    /// `timeout`; whether none waits.
    pub fn wait_for_neighbour_graph(&self, timeout: std::time::Duration) -> bool {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            if self.index.read().neighbour_graph_waiting() == 0 {
                return true;
            }
            if std::time::Instant::now() >= deadline {
                return false;
            }
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
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

    /// Writes the whole store to `file` ([`export`]), taken by the writer
    /// between two groups of changes so that it holds exactly the changes
    /// up to the log position it records. Writes wait meanwhile.
    pub async fn export(&self, file: &Path) -> Result<export::ExportHeader, StoreError> {
        self.writer.export(file.to_path_buf()).await
    }

    /// Flushes everything to disk (at shutdown; acknowledged writes already are).
    pub fn flush(&self) -> Result<(), StoreError> {
        self.db.flush()?;
        Ok(())
    }

    /// Makes the writer's next `count` group flushes fail as if sled could
    /// not write (tests of what a failed flush leaves behind).
    #[cfg(test)]
    pub(crate) fn fail_next_flushes(&self, count: u32) {
        self.checkpoints
            .flush_faults
            .store(count, std::sync::atomic::Ordering::Release);
    }
}

#[cfg(test)]
mod export_tests;
#[cfg(test)]
mod flush_failure_tests;
#[cfg(test)]
mod log_tests;
#[cfg(test)]
mod quota_tests;
#[cfg(test)]
mod restart_tests;
#[cfg(test)]
mod tests;
#[cfg(test)]
mod verdict_tests;
