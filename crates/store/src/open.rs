//! Opening a store: sled and its format (a new store gets the current
//! [`STORE_FORMAT`], an older one is upgraded in place, a newer one
//! refused), the descriptor length, then the index, loaded from its
//! snapshot brought up to date by the journal or rebuilt from every
//! record, and last the checkpoints and the writer thread.
//!
//! It returns the parts of a [`crate::Store`] rather than the store
//! itself, so that this module needs nothing of the crate root: the root
//! puts the parts together.

use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize};
use std::sync::Arc;
use std::time::{Duration, Instant};

use humem_core::index::Index;
use humem_core::observe::SharedObserver;
use parking_lot::RwLock;

use crate::checkpoint::Checkpoints;
use crate::error::StoreError;
use crate::graph_file::{GraphOptions, GraphSource};
use crate::layout::{
    KEYFRAMES_TREE, META_DIM, META_FORMAT, META_TREE, STORE_FORMAT, VERDICTS_BY_CANDIDATE_TREE,
    VERDICTS_TREE,
};
use crate::options::StoreOptions;
use crate::placement::DescriptorPlacement;
use crate::writer::{self, WriterHandle};
use crate::{codec, disk, graph_file, journal, settle, snapshot};

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
    /// Where its neighbour graph came from; None where it keeps none.
    pub graph: Option<GraphSource>,
    /// Large maps whose own graph was loaded from its file (the others'
    /// are built in the background).
    pub map_graphs_loaded: usize,
    /// Keyframes in the index.
    pub keyframes: usize,
    /// Time from the call to a ready index.
    pub elapsed: Duration,
}

/// What opening a store makes: the parts of a [`crate::Store`].
pub(crate) struct Opened {
    pub db: sled::Db,
    pub index: Arc<RwLock<Index>>,
    pub writer: WriterHandle,
    pub checkpoints: Arc<Checkpoints>,
    pub report: OpenReport,
}

/// Opens (or creates) the store in `dir` with `options` and loads its
/// index, the writer's queue depth reported to `observer`.
pub(crate) fn open(
    dir: &Path,
    options: StoreOptions,
    observer: SharedObserver,
) -> Result<Opened, StoreError> {
    let started = Instant::now();
    let StoreOptions {
        dim,
        queue_capacity,
        snapshot_every,
        min_free_bytes,
        descriptors_to_file,
        cache_bytes,
        neighbour_graph,
        neighbour_graph_length,
        map_graphs_from,
    } = options;
    let neighbour_graph = neighbour_graph.then_some(GraphOptions {
        short: neighbour_graph_length,
        map_graphs_from,
    });
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

    let dim = pinned_dim(&meta, dim)?;

    let journal_tree = db.open_tree(journal::TREE)?;
    let store_id = journal::store_id(&meta)?;
    let sequence = journal::last_sequence(&journal_tree, &meta)?;
    let placement = Arc::new(DescriptorPlacement::new(
        dir.to_path_buf(),
        descriptors_to_file,
    ));
    let LoadedIndex {
        index,
        source,
        snapshot_sequence,
        graph,
    } = load_index(
        &placement,
        &keyframes,
        &journal_tree,
        &meta,
        store_id,
        dim,
        sequence,
        neighbour_graph,
    )?;
    let verdicts = db.open_tree(VERDICTS_TREE)?;
    let verdicts_by_candidate = db.open_tree(VERDICTS_BY_CANDIDATE_TREE)?;
    let mut index = index;
    // A snapshot keeps the rows in the order they were grouped in, and
    // the tree is in key order (robot, session, keyframe): only the rows
    // the last run had not grouped yet are sorted now, and the writer
    // groups what is appended from now on.
    index.mark_grouped();
    regroup_at_open(&mut index);
    load_verdicts(&verdicts, &mut index)?;
    let opened = OpenReport {
        source,
        graph,
        map_graphs_loaded: index.saved_map_graphs_taken(),
        keyframes: index.len(),
        elapsed: started.elapsed(),
    };
    tracing::info!(
        dir = %dir.display(),
        keyframes = opened.keyframes,
        descriptor_dim = index.dim(),
        from = ?opened.source,
        graph = ?opened.graph,
        map_graphs_loaded = opened.map_graphs_loaded,
        seconds = opened.elapsed.as_secs_f64(),
        "store opened"
    );
    let index = Arc::new(RwLock::new(index));
    let checkpoints = Arc::new(Checkpoints {
        dir: dir.to_path_buf(),
        store_id,
        index: index.clone(),
        applied: Arc::new(AtomicU64::new(sequence)),
        journal: journal_tree.clone(),
        meta: meta.clone(),
        every: snapshot_every,
        since: AtomicU64::new(0),
        written: AtomicU64::new(snapshot_sequence.unwrap_or(u64::MAX)),
        graph_waiting_saved: AtomicUsize::new(index.read().neighbour_graph_waiting()),
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
    settle::settle_log(&db, &meta, settle::SETTLE_FROM_BYTES)?;
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
    Ok(Opened {
        db,
        index,
        writer,
        checkpoints,
        report: opened,
    })
}

/// The store's descriptor length: the one recorded in `meta`, or `asked`
/// (0: not fixed yet), which a store that records none records from now
/// on; the two must agree where both are set.
fn pinned_dim(meta: &sled::Tree, asked: usize) -> Result<usize, StoreError> {
    let stored_dim = meta
        .get(META_DIM)?
        .map(|v| u32::from_be_bytes(v.as_ref().try_into().unwrap_or([0; 4])) as usize)
        .unwrap_or(0);
    let dim = match (stored_dim, asked) {
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
    Ok(dim)
}

/// The index as loaded at open.
struct LoadedIndex {
    index: Index,
    source: IndexSource,
    /// The sequence of the snapshot it was loaded from (none: rebuilt
    /// from the tree).
    snapshot_sequence: Option<u64>,
    graph: Option<GraphSource>,
}

/// An index loaded from the snapshot and brought up to date.
struct SnapshotLoad {
    index: Index,
    /// Distinct keys replayed from the journal.
    replayed: usize,
    /// The snapshot's sequence.
    sequence: u64,
    graph: Option<GraphSource>,
}

/// Loads the index: from the snapshot brought up to date by the journal
/// when that is possible, else from every record in the tree. The store's directory is
/// `placement`'s, and the descriptors leave memory as it says while they
/// load, not after. With `neighbour_graph`, the index keeps one (and the
/// large maps theirs) from the start (see [`graph_file`]).
#[allow(clippy::too_many_arguments)]
fn load_index(
    placement: &DescriptorPlacement,
    keyframes: &sled::Tree,
    journal_tree: &sled::Tree,
    meta: &sled::Tree,
    store_id: u128,
    dim: usize,
    sequence: u64,
    neighbour_graph: Option<GraphOptions>,
) -> Result<LoadedIndex, StoreError> {
    let reason = match from_snapshot(
        placement,
        keyframes,
        journal_tree,
        meta,
        store_id,
        dim,
        sequence,
        neighbour_graph,
    ) {
        Ok(Ok(SnapshotLoad {
            index,
            replayed,
            sequence,
            graph,
        })) => {
            return Ok(LoadedIndex {
                index,
                source: IndexSource::Snapshot { replayed },
                snapshot_sequence: Some(sequence),
                graph,
            })
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
    let graph = if let Some(options) = neighbour_graph {
        // Built once from every row (on every core), not row by row,
        // unless a restore left one in step with the records.
        graph_file::attach_rebuilt(placement.dir(), &mut index, options)
    } else {
        graph_file::discard_restored(placement.dir());
        None
    };
    Ok(LoadedIndex {
        index,
        source: IndexSource::Tree { reason },
        snapshot_sequence: None,
        graph,
    })
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

/// The snapshot's index plus the journal's changes since; or why it cannot
/// be used.
/// With `neighbour_graph`, the graph is attached before the replay, whose
/// keyframes then wait to enter it (the writer adds them after the open).
#[allow(clippy::too_many_arguments)]
fn from_snapshot(
    placement: &DescriptorPlacement,
    keyframes: &sled::Tree,
    journal_tree: &sled::Tree,
    meta: &sled::Tree,
    store_id: u128,
    dim: usize,
    sequence: u64,
    neighbour_graph: Option<GraphOptions>,
) -> Result<Result<SnapshotLoad, String>, StoreError> {
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
    let graph = if let Some(options) = neighbour_graph {
        graph_file::attach(placement.dir(), &mut index, options)
    } else {
        None
    };
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
    Ok(Ok(SnapshotLoad {
        index,
        replayed: pending.keys.len(),
        sequence: header.sequence,
        graph,
    }))
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

/// How long the open spends sorting again the windows of rows left
/// scattered ([`regroup_at_open`]).
const REGROUP_AT_OPEN: Duration = Duration::from_secs(2);

/// Sorts again, before the store takes requests, the windows of rows
/// that the last run left scattered, for at most [`REGROUP_AT_OPEN`]:
/// the rows written after the last grouping before a shutdown always
/// form one such window, and the writer would otherwise sort it under
/// the first load, holding the index (and every insert behind it) for a
/// few hundred milliseconds at a million keyframes. A store scattered
/// all over by erasures leaves the rest to the writer, one window per
/// group of writes.
fn regroup_at_open(index: &mut Index) {
    let started = Instant::now();
    let mut windows = 0;
    while started.elapsed() < REGROUP_AT_OPEN && index.regroup_window_if_due() > 0 {
        windows += 1;
    }
    if windows > 0 {
        tracing::info!(
            windows,
            ms = started.elapsed().as_millis() as u64,
            "sorted again the rows the last run left scattered"
        );
    }
}
