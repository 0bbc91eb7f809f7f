//! When index snapshots are taken, and the thread that takes them.
//!
//! The writer reports how many keys each committed change journaled; once
//! `every` keys have been journaled since the last snapshot, a background
//! thread writes a new one, so that replay at open stays bounded (about
//! `every` sled reads) whatever the store's age. A snapshot is also taken
//! at shutdown ([`crate::Store::snapshot`]), so a clean restart replays
//! nothing.
//!
//! The snapshot thread takes the index's read lock only for a few
//! milliseconds at a time (see [`snapshot::write`]), so the writer and the
//! queries go on while it writes. Snapshots are spaced by changes, not by
//! time: an idle store never writes one.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use humem_core::index::Index;
use parking_lot::{Mutex, RwLock};

use crate::error::StoreError;
use crate::{graph_file, journal, snapshot};

/// One snapshot written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SnapshotReport {
    /// The write sequence it reflects.
    pub sequence: u64,
    /// Keyframes in it.
    pub keyframes: usize,
    /// Its size in bytes.
    pub bytes: u64,
    /// Time to write it (into the page cache), before the sync.
    pub written: Duration,
    /// Time from start to the snapshot synced and in place.
    pub elapsed: Duration,
}

/// What the snapshot thread needs, shared with the writer and the store.
pub(crate) struct Checkpoints {
    pub dir: PathBuf,
    pub store_id: u128,
    pub index: Arc<RwLock<Index>>,
    /// The write sequence the index reflects; set by the writer while it
    /// holds the index's write lock.
    pub applied: Arc<AtomicU64>,
    pub journal: sled::Tree,
    pub meta: sled::Tree,
    /// Journaled keys between automatic snapshots; 0: only on request.
    pub every: u64,
    /// Journaled keys since the last snapshot began.
    pub since: AtomicU64,
    /// Sequence of the newest snapshot on disk that matches this store
    /// (`u64::MAX`: none).
    pub written: AtomicU64,
    /// Keyframes that waited to enter the neighbour graphs when the
    /// graphs on disk were written (or when the store was opened): a
    /// shutdown whose snapshot is current still saves the graphs if fewer
    /// wait now, so that what was built since is not built again.
    pub graph_waiting_saved: AtomicUsize,
    /// Set while a background snapshot runs.
    pub running: AtomicBool,
    /// One snapshot at a time.
    pub writing: Mutex<()>,
    /// Free space kept on the store's disk (the writer checks it too).
    pub disk: crate::disk::DiskGuard,
    /// Flushes the writer fails on purpose before it flushes again; only
    /// tests set it (through [`crate::Store::fail_next_flushes`]), to prove
    /// that a failed flush leaves the tree and the index equal.
    pub flush_faults: std::sync::atomic::AtomicU32,
}

impl Checkpoints {
    /// Counts `keys` more journaled keys; starts a background snapshot
    /// when enough have gathered and none is running.
    pub fn journaled(self: &Arc<Self>, keys: u64) {
        let since = self.since.fetch_add(keys, Ordering::Relaxed) + keys;
        if self.every > 0 && since >= self.every {
            self.start_background();
        }
    }

    /// Writes a snapshot on a background thread unless one is running.
    pub fn start_background(self: &Arc<Self>) {
        if self.running.swap(true, Ordering::AcqRel) {
            return;
        }
        let this = self.clone();
        let spawned = std::thread::Builder::new()
            .name("humem-snapshot".into())
            .spawn(move || {
                if let Err(e) = this.write_now() {
                    tracing::error!(error = %e, "writing the index snapshot failed");
                }
                this.running.store(false, Ordering::Release);
            });
        if let Err(e) = spawned {
            tracing::error!(error = %e, "could not start the snapshot thread");
            self.running.store(false, Ordering::Release);
        }
    }

    /// Writes a snapshot of the index as it is now, unless the newest one
    /// already reflects it; then drops the journal entries it covers.
    /// Says what was written, if anything.
    pub fn write_now(&self) -> Result<Option<SnapshotReport>, StoreError> {
        let _one = self.writing.lock();
        let started = Instant::now();
        let applied = self.applied.load(Ordering::Acquire);
        if applied == self.written.load(Ordering::Acquire) {
            self.save_graphs_built_since();
            return Ok(None);
        }
        // The new file is written beside the old one: room for a whole
        // snapshot (its last size, or the descriptors' if there is none)
        // must be left above the reserve.
        let estimate = std::fs::metadata(snapshot::path(&self.dir))
            .map(|m| m.len())
            .unwrap_or_else(|_| {
                let index = self.index.read();
                (index.len() * (index.dim() * 4 + 256)) as u64
            });
        self.disk.room_for(estimate)?;
        let keys = self.since.swap(0, Ordering::Relaxed);
        let (unpublished, sequence) =
            match snapshot::write(&self.dir, self.store_id, &self.index, &self.applied) {
                Ok(written) => written,
                Err(e) => {
                    self.since.fetch_add(keys, Ordering::Relaxed);
                    return Err(e.into());
                }
            };
        let graph = self.save_graphs();
        let rows = self.index.read().len();
        let written = started.elapsed();
        if let Some(graph) = graph {
            graph.publish();
        }
        let bytes = unpublished.publish()?;
        self.written.store(sequence, Ordering::Release);
        journal::truncate(&self.journal, &self.meta, sequence)?;
        let report = SnapshotReport {
            sequence,
            keyframes: rows,
            bytes,
            written,
            elapsed: started.elapsed(),
        };
        tracing::info!(
            sequence,
            keyframes = rows,
            bytes,
            written_ms = written.as_millis() as u64,
            total_ms = report.elapsed.as_millis() as u64,
            "index snapshot written"
        );
        Ok(Some(report))
    }

    /// Writes the neighbour graphs beside their files, to be published,
    /// and records how many keyframes waited to enter them then.
    fn save_graphs(&self) -> Option<graph_file::UnpublishedGraph> {
        let waiting = self.index.read().neighbour_graph_waiting();
        let graph = graph_file::save(&self.dir, &self.index)?;
        self.graph_waiting_saved.store(waiting, Ordering::Relaxed);
        Some(graph)
    }

    /// Saves the neighbour graphs alone, beside the current snapshot,
    /// where fewer keyframes wait to enter them than when they were last
    /// written: after a restart whose saved graphs lacked many keyframes
    /// (written while inserts came faster than the graphs took them, or
    /// a map's graph that was missing), the writer builds the rest in the
    /// background, and a store left idle since would otherwise lose that
    /// work at every clean shutdown. The graphs may hold keyframes newer
    /// than the snapshot, as those saved with a snapshot may.
    fn save_graphs_built_since(&self) {
        let waiting = self.index.read().neighbour_graph_waiting();
        if waiting >= self.graph_waiting_saved.load(Ordering::Relaxed) {
            return;
        }
        let started = Instant::now();
        if let Some(graph) = self.save_graphs() {
            graph.publish();
            tracing::info!(
                waiting,
                ms = started.elapsed().as_millis() as u64,
                "neighbour graphs saved beside the current snapshot"
            );
        }
    }
}
