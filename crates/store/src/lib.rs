//! Durable storage of semantic keyframes in sled, and the in-memory index
//! that queries scan.
//!
//! sled is the source of truth. At start the [`Index`] is loaded from its
//! snapshot and brought up to date from the write journal, or, where there
//! is no usable snapshot, rebuilt from every record in sled.
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
//!   commit;
//! - [`journal`]: which keys each change touched, by write sequence;
//! - [`snapshot`]: the index snapshot file beside the tree;
//! - `checkpoint`: when snapshots are taken, on their own thread.

mod checkpoint;
pub mod disk;
pub mod export;
pub use checkpoint::SnapshotReport;
pub mod codec;
pub mod journal;
mod placement;
mod robot_counts;
mod rollback;
pub use placement::FileRule;
pub mod snapshot;
mod writer;

use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64};
use std::sync::Arc;
use std::time::{Duration, Instant};

use humem_core::observe::SharedObserver;
use parking_lot::RwLock;

pub use humem_core::index::{Index, MapKey};
use humem_core::keyframe::{KeyframeKey, Pose, SemanticKeyframe, SessionKey};
pub use humem_core::verdict::{RelativeTransform, Verdict, VerificationKind};

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

/// One change to the store, as the writer applies it. Serializable, so that
/// a replicated log can carry it (`humem-cluster`).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
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
    /// Record SLAM's verdict on a proposed candidate (both keyframes must
    /// be stored; the newest verdict on a pair and kind replaces older).
    /// Last but one, so that log entries of the other kinds keep their
    /// encoding.
    ReportVerdict(Verdict),
    /// Store keyframes as [`Mutation::Insert`] does, unless a robot would
    /// then hold more than `max_per_robot` keyframes (a replaced keyframe
    /// adds nothing): then the whole change is refused with
    /// [`StoreError::QuotaExceeded`]. The writer checks it against sled as
    /// it applies changes one by one, so concurrent inserts (and, in
    /// cluster mode, inserts through different replicas, applied in the
    /// log's order everywhere) can never pass the quota together. Last, so
    /// that log entries of the other kinds keep their encoding.
    InsertWithin {
        /// The keyframes, stored atomically.
        keyframes: Vec<SemanticKeyframe>,
        /// Keyframes a robot may hold.
        max_per_robot: u64,
    },
}

/// A corrected pose for one keyframe of a session.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
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
    /// Verdicts in the store afterwards.
    pub store_verdicts: u64,
}

/// A change taken from a replicated log, at its position there (1, 2, …).
#[derive(Debug, Clone)]
pub struct LogEntry {
    /// The entry's position in the log; recorded with the change.
    pub position: u64,
    /// The change.
    pub mutation: Mutation,
}

/// What became of a batch of [`LogEntry`]s ([`Store::apply_log`]).
#[derive(Debug, Default)]
pub struct LogApplied {
    /// One result per entry applied, in order. An entry refused for what it
    /// is ([`StoreError::is_refusal`]) is refused alike on every replica:
    /// it counts as applied, with its error.
    pub results: Vec<Result<MutationOutcome, StoreError>>,
    /// Why the entries after `results` were not applied (a full disk, a
    /// failed write): they must be given again, in order.
    pub stopped: Option<StoreError>,
}

/// How the store is opened.
#[derive(Debug, Clone)]
pub struct StoreOptions {
    /// Pins the descriptor length (0: taken from the first keyframe).
    pub dim: usize,
    /// Changes the writer's queue holds before refusing more.
    pub queue_capacity: usize,
    /// Journaled keyframe changes between automatic index snapshots, and
    /// the threshold for one right after open (0: snapshots only when
    /// asked, as at shutdown).
    pub snapshot_every: u64,
    /// Free bytes kept on the store's disk: inserts, pose updates and
    /// snapshots that would go below are refused (removals are not); 0:
    /// no reserve. See [`disk`].
    pub min_free_bytes: u64,
    /// When the index's f32 descriptors leave memory for unnamed files in
    /// the store's directory (their one-byte codes stay in memory); None:
    /// they stay in memory. Worth it for large stores scanned on their
    /// codes, which read few f32 rows a query.
    pub descriptors_to_file: Option<FileRule>,
    /// Bytes of sled's own page cache (sled's default: 1 GiB); most of
    /// the server's resident memory beyond the index once the store is
    /// large.
    pub cache_bytes: u64,
}

/// Default of [`StoreOptions::cache_bytes`]: sled's own.
pub const DEFAULT_CACHE_BYTES: u64 = 1 << 30;

impl Default for StoreOptions {
    fn default() -> Self {
        StoreOptions {
            dim: 0,
            queue_capacity: 1024,
            snapshot_every: DEFAULT_SNAPSHOT_EVERY,
            min_free_bytes: disk::DEFAULT_MIN_FREE_BYTES,
            descriptors_to_file: None,
            cache_bytes: DEFAULT_CACHE_BYTES,
        }
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

/// Default of [`StoreOptions::snapshot_every`]: replaying this many
/// changes at open costs well under a second.
pub const DEFAULT_SNAPSHOT_EVERY: u64 = 100_000;

/// Where the index came from at open.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum IndexSource {
    /// The snapshot, then `replayed` journaled keys read again from sled.
    Snapshot {
        /// Distinct keyframe keys replayed from the journal.
        replayed: usize,
    },
    /// Every record in sled; `reason` says why not from a snapshot.
    Tree {
        /// Why no snapshot was used.
        reason: String,
    },
}

/// How the store was opened, for logs, metrics and tests.
#[derive(Debug, Clone)]
pub struct OpenReport {
    /// Where the index came from.
    pub source: IndexSource,
    /// Keyframes in the index.
    pub keyframes: usize,
    /// Time from the call to a ready index.
    pub elapsed: Duration,
}

/// The store: sled plus the in-memory index, shared by the service.
#[derive(Clone)]
pub struct Store {
    db: sled::Db,
    index: Arc<RwLock<Index>>,
    writer: writer::WriterHandle,
    checkpoints: Arc<checkpoint::Checkpoints>,
    opened: Arc<OpenReport>,
}

const KEYFRAMES_TREE: &str = "keyframes";
/// Verdicts by query keyframe ([`codec::verdict_key`] → record).
const VERDICTS_TREE: &str = "verdicts";
/// The same verdicts by candidate keyframe ([`codec::verdict_candidate_key`]
/// → the verdicts tree's key), so erasing a candidate finds its verdicts.
const VERDICTS_BY_CANDIDATE_TREE: &str = "verdicts_by_candidate";
const META_TREE: &str = "meta";
const META_FORMAT: &[u8] = b"format_version";
const META_DIM: &[u8] = b"descriptor_dim";
/// Position of the last replicated-log entry applied (cluster mode).
const META_LOG_POSITION: &[u8] = b"log_position";

/// Version of the store's layout, recorded in its meta tree. 3 added the
/// write journal (and the index snapshot beside the tree) to version 2's
/// records; a build that predates the journal refuses a version 3 store
/// instead of writing to it unjournaled.
pub const STORE_FORMAT: u32 = 3;

/// The descriptor length the store in `dir` records, without creating or
/// changing a store: `None` where `dir` holds no store, or one whose length
/// is not fixed yet. Opens sled (which admits one process, so it fails
/// while a server runs on `dir`) and reads the meta tree only.
pub fn recorded_dim(dir: &Path) -> Result<Option<usize>, StoreError> {
    let Some(db) = open_existing(dir)? else {
        return Ok(None);
    };
    if !has_tree(&db, META_TREE) {
        return Ok(None);
    }
    let dim = db
        .open_tree(META_TREE)?
        .get(META_DIM)?
        .map(|v| u32::from_be_bytes(v.as_ref().try_into().unwrap_or([0; 4])) as usize);
    Ok(dim.filter(|&d| d > 0))
}

/// Opens the sled database in `dir` if one is there (its configuration or
/// log file exists), without creating one.
fn open_existing(dir: &Path) -> Result<Option<sled::Db>, StoreError> {
    // sled keeps its configuration and log in these two files.
    if !dir.join("conf").is_file() && !dir.join("db").is_file() {
        return Ok(None);
    }
    sled::Config::new()
        .path(dir)
        .open()
        .map(Some)
        .map_err(|source| StoreError::Open {
            path: dir.display().to_string(),
            source,
        })
}

/// Whether `db` has a tree named `tree` (without creating it).
fn has_tree(db: &sled::Db, tree: &str) -> bool {
    db.tree_names().iter().any(|name| name == tree.as_bytes())
}

/// Where the store in `dir` stands in a replicated write log, read
/// without creating or changing a store.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RecordedLog {
    /// The last entry applied (0: none, or no store).
    pub position: u64,
    /// Whether the store holds any keyframe.
    pub holds_keyframes: bool,
}

/// [`RecordedLog`] of the store in `dir`; like [`recorded_dim`], it fails
/// while a server runs on `dir`.
pub fn recorded_log(dir: &Path) -> Result<RecordedLog, StoreError> {
    let Some(db) = open_existing(dir)? else {
        return Ok(RecordedLog::default());
    };
    let has = |tree: &str| has_tree(&db, tree);
    let position = if has(META_TREE) {
        db.open_tree(META_TREE)?
            .get(META_LOG_POSITION)?
            .map_or(0, |v| {
                u64::from_be_bytes(v.as_ref().try_into().unwrap_or([0; 8]))
            })
    } else {
        0
    };
    let holds_keyframes = has(KEYFRAMES_TREE) && !db.open_tree(KEYFRAMES_TREE)?.is_empty();
    Ok(RecordedLog {
        position,
        holds_keyframes,
    })
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
        let started = Instant::now();
        let StoreOptions {
            dim,
            queue_capacity,
            snapshot_every,
            min_free_bytes,
            descriptors_to_file,
            cache_bytes,
        } = options;
        let db = sled::Config::new()
            .path(dir)
            .cache_capacity(cache_bytes)
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

        let journal_tree = db.open_tree(journal::TREE)?;
        let store_id = journal::store_id(&meta)?;
        let sequence = journal::last_sequence(&journal_tree, &meta)?;
        let placement = Arc::new(placement::DescriptorPlacement::new(
            dir.to_path_buf(),
            descriptors_to_file,
        ));
        let (index, source, snapshot_sequence) = load_index(
            &placement,
            &keyframes,
            &journal_tree,
            &meta,
            store_id,
            dim,
            sequence,
        )?;
        let verdicts = db.open_tree(VERDICTS_TREE)?;
        let verdicts_by_candidate = db.open_tree(VERDICTS_BY_CANDIDATE_TREE)?;
        let mut index = index;
        // A snapshot keeps the rows in the order they were grouped in, and
        // the tree is in key order (robot, session, keyframe): the writer
        // groups only what is appended from now on.
        index.mark_grouped();
        load_verdicts(&verdicts, &mut index)?;
        let opened = OpenReport {
            source,
            keyframes: index.len(),
            elapsed: started.elapsed(),
        };
        tracing::info!(
            dir = %dir.display(),
            keyframes = opened.keyframes,
            descriptor_dim = index.dim(),
            from = ?opened.source,
            seconds = opened.elapsed.as_secs_f64(),
            "store opened"
        );
        let index = Arc::new(RwLock::new(index));
        let checkpoints = Arc::new(checkpoint::Checkpoints {
            dir: dir.to_path_buf(),
            store_id,
            index: index.clone(),
            applied: Arc::new(AtomicU64::new(sequence)),
            journal: journal_tree.clone(),
            meta: meta.clone(),
            every: snapshot_every,
            since: AtomicU64::new(0),
            written: AtomicU64::new(snapshot_sequence.unwrap_or(u64::MAX)),
            running: AtomicBool::new(false),
            writing: parking_lot::Mutex::new(()),
            disk: disk::DiskGuard::new(dir, min_free_bytes),
            flush_faults: std::sync::atomic::AtomicU32::new(0),
        });
        // Without a current snapshot the next open would walk the tree (or
        // a long journal) again: write one now, in the background.
        let stale = match &opened.source {
            IndexSource::Tree { .. } => opened.keyframes > 0,
            IndexSource::Snapshot { replayed } => {
                *replayed as u64 >= snapshot_every.max(1) / 4 && *replayed > 0
            }
        };
        if stale && snapshot_every > 0 {
            checkpoints.start_background();
        }
        let writer = writer::spawn(
            writer::Trees {
                db: db.clone(),
                keyframes,
                meta,
                journal: journal_tree,
                verdicts,
                verdicts_by_candidate,
            },
            checkpoints.clone(),
            placement,
            queue_capacity,
            observer,
        );
        Ok(Store {
            db,
            index,
            writer,
            checkpoints,
            opened: Arc::new(opened),
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

/// Loads the index: from the snapshot brought up to date by the journal
/// when that is possible, else from every record in the tree. Returns the
/// index, where it came from, and the sequence of the snapshot it was
/// loaded from (none: rebuilt from the tree). The store's directory is
/// `placement`'s, and the descriptors leave memory as it says while they
/// load, not after.
fn load_index(
    placement: &placement::DescriptorPlacement,
    keyframes: &sled::Tree,
    journal_tree: &sled::Tree,
    meta: &sled::Tree,
    store_id: u128,
    dim: usize,
    sequence: u64,
) -> Result<(Index, IndexSource, Option<u64>), StoreError> {
    let reason = match from_snapshot(
        placement,
        keyframes,
        journal_tree,
        meta,
        store_id,
        dim,
        sequence,
    ) {
        Ok(Ok((index, replayed, snapshot_sequence))) => {
            return Ok((
                index,
                IndexSource::Snapshot { replayed },
                Some(snapshot_sequence),
            ))
        }
        Ok(Err(reason)) => reason,
        Err(StoreError::Snapshot(e)) => e.to_string(),
        Err(e) => return Err(e),
    };
    if reason != NO_SNAPSHOT {
        tracing::warn!(%reason, "index snapshot not used: rebuilding the index from the store");
    }
    let mut index = Index::new(dim);
    for (n, item) in keyframes.iter().enumerate() {
        let (key, value) = item?;
        let record = codec::decode_record(&value).map_err(|source| StoreError::Corrupt {
            key: key.to_vec(),
            source,
        })?;
        index.upsert(record);
        if n % 4096 == 0 {
            placement.apply(&mut index);
        }
    }
    placement.apply(&mut index);
    Ok((index, IndexSource::Tree { reason }, None))
}

/// Takes every stored verdict into the index. Verdicts are few (one per
/// verified candidate) and are not in the index snapshot: they are read
/// from their tree at every open, after the keyframes, which the erasure
/// cascade keeps them consistent with.
fn load_verdicts(tree: &sled::Tree, index: &mut Index) -> Result<(), StoreError> {
    for item in tree.iter() {
        let (key, value) = item?;
        let verdict = codec::decode_verdict(&value).map_err(|source| StoreError::Corrupt {
            key: key.to_vec(),
            source,
        })?;
        if index.row_of(&verdict.query).is_some() && index.row_of(&verdict.candidate).is_some() {
            index.record_verdict(verdict);
        } else {
            tracing::warn!(
                ?key,
                "a stored verdict names a keyframe that is not stored: ignored"
            );
        }
    }
    Ok(())
}

const NO_SNAPSHOT: &str = "no snapshot";

/// The snapshot's index plus the journal's changes since, with the number
/// of keys replayed and the snapshot's sequence; or why it cannot be used.
fn from_snapshot(
    placement: &placement::DescriptorPlacement,
    keyframes: &sled::Tree,
    journal_tree: &sled::Tree,
    meta: &sled::Tree,
    store_id: u128,
    dim: usize,
    sequence: u64,
) -> Result<Result<(Index, usize, u64), String>, StoreError> {
    let Some((header, mut index)) =
        snapshot::read(placement.dir(), store_id, dim, placement.rule())?
    else {
        return Ok(Err(NO_SNAPSHOT.into()));
    };
    let floor = journal::floor(meta)?;
    if header.sequence < floor {
        return Ok(Err(format!(
            "the snapshot (write {}) is older than the journal, which starts after write {floor}",
            header.sequence
        )));
    }
    if header.sequence > sequence {
        return Ok(Err(format!(
            "the snapshot (write {}) is newer than the store (write {sequence})",
            header.sequence
        )));
    }
    let pending = journal::pending(journal_tree, header.sequence)?;
    for key in &pending.keys {
        match keyframes.get(key)? {
            Some(value) => {
                let record =
                    codec::decode_record(&value).map_err(|source| StoreError::Corrupt {
                        key: key.clone(),
                        source,
                    })?;
                index.upsert(record);
            }
            None => {
                let key = codec::decode_key(key).map_err(|source| StoreError::Corrupt {
                    key: key.clone(),
                    source,
                })?;
                index.remove(&key);
            }
        }
    }
    let expected = pending.keyframes.unwrap_or(header.rows as u64);
    if index.len() as u64 != expected {
        return Ok(Err(format!(
            "the snapshot and journal give {} keyframes, the store holds {expected}",
            index.len()
        )));
    }
    placement.apply(&mut index);
    Ok(Ok((index, pending.keys.len(), header.sequence)))
}

/// Writes the format version into a new store, upgrades a store of an
/// older version this build still reads (its records stay as they are and
/// are read by their own version byte), and refuses one of a newer version.
fn check_format(meta: &sled::Tree) -> Result<(), StoreError> {
    let supported = STORE_FORMAT;
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
