//! The neighbour graph's file beside the index snapshot, so that a restart
//! loads the graph instead of building it again (building takes minutes
//! at a million keyframes; loading, one read).
//!
//! The graph is saved after each snapshot has fixed its write sequence,
//! and renamed into place before the snapshot is, so the graph on disk is
//! never older than the snapshot it is loaded with. At open it is attached
//! to the snapshot's index *before* the journal is replayed, so the replay
//! updates it like any other change; rows the graph lacks (the replayed
//! keyframes) wait to enter it, and the writer adds them after the open
//! while queries score them exactly, so a restart does not wait for them.
//! Keys the graph holds that the index does not are never proposed. A
//! graph that is missing, of another descriptor length or unreadable is
//! rebuilt from the rows the same way, with a warning.
//!
//! A store restored from an export ([`crate::export`]) gets the graph the
//! export carried as [`restored_path`]: in step with the restored records,
//! it is taken by the first open, which otherwise would build one.

use std::path::{Path, PathBuf};
use std::time::Instant;

use humem_core::engine::graph::{GraphError, NeighbourGraph};
use humem_core::index::Index;
use parking_lot::RwLock;

/// File name of the neighbour graph in the data directory.
pub const FILE_NAME: &str = "index.graph";

/// Path of the neighbour graph in data directory `dir`.
pub fn path(dir: &Path) -> PathBuf {
    dir.join(FILE_NAME)
}

/// Where a restore leaves the graph an export carried, for the first open.
pub(crate) fn restored_path(dir: &Path) -> PathBuf {
    dir.join(format!("{FILE_NAME}.restored"))
}

/// How the index came to keep its neighbour graph at open.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GraphSource {
    /// Read from the file saved with the snapshot, or carried by the
    /// export the store was restored from.
    Loaded,
    /// Built from the rows (no usable file), in the background.
    Built,
}

fn temp_path(dir: &Path) -> PathBuf {
    dir.join(format!("{FILE_NAME}.tmp"))
}

/// A graph written to its temporary file, not yet in place.
#[derive(Debug)]
pub(crate) struct UnpublishedGraph {
    dir: PathBuf,
}

/// Writes the index's neighbour graph, if it keeps one, to a temporary
/// file in `dir`, under the index's read lock (changes wait for it:
/// about a second a million keyframes). Keyframes still waiting to enter
/// the graph are not in the file; the open that loads it adds them. A failure is logged and the old
/// file removed, so that the next open rebuilds the graph rather than load
/// one older than the snapshot.
pub(crate) fn save(dir: &Path, index: &RwLock<Index>) -> Option<UnpublishedGraph> {
    let temp = temp_path(dir);
    let started = Instant::now();
    let saved = index.read().save_neighbour_graph(&temp);
    match saved {
        Ok(None) => {
            // A graph left from when one was kept would be older than
            // this snapshot: the next open that wants one builds it.
            let _ = std::fs::remove_file(path(dir));
            None
        }
        Ok(Some(rows)) => {
            tracing::debug!(
                rows,
                ms = started.elapsed().as_millis() as u64,
                "neighbour graph written"
            );
            Some(UnpublishedGraph {
                dir: dir.to_path_buf(),
            })
        }
        Err(e) => {
            tracing::warn!(error = %e, "writing the neighbour graph failed: the next start rebuilds it");
            let _ = std::fs::remove_file(&temp);
            let _ = std::fs::remove_file(path(dir));
            None
        }
    }
}

impl UnpublishedGraph {
    /// Renames the graph into place (before its snapshot is).
    pub(crate) fn publish(self) {
        if let Err(e) = std::fs::rename(temp_path(&self.dir), path(&self.dir)) {
            tracing::warn!(error = %e, "placing the neighbour graph failed: the next start rebuilds it");
            let _ = std::fs::remove_file(path(&self.dir));
        }
    }
}

/// Starts `index` keeping a neighbour graph that shortens descriptors to
/// `short` values (0: not at all): the one saved in `dir` where it can be
/// read and was made alike, else an empty one. None where no graph could be kept.
/// Either way the rows the graph lacks wait to enter it, and from now on
/// so does every keyframe stored ([`Index::defer_graph_inserts`]): the
/// writer adds them in the background, so the open does not wait for
/// them (a million keyframes take more than ten minutes on two cores).
pub(crate) fn attach(dir: &Path, index: &mut Index, short: usize) -> Option<GraphSource> {
    index.defer_graph_inserts();
    index.shorten_graph_rows(short);
    let started = Instant::now();
    let file = path(dir);
    let saved = if file.exists() && index.dim() > 0 {
        match NeighbourGraph::load(&file, index.dim(), short) {
            Ok(graph) => Some(graph),
            Err(e) => {
                tracing::warn!(error = %e, "the saved neighbour graph is not used: rebuilding it");
                None
            }
        }
    } else {
        None
    };
    let loaded = saved.is_some();
    if let Err(e) = index.keep_neighbour_graph(saved) {
        tracing::warn!(error = %e, "no neighbour graph: every query scans its eligible keyframes");
        return None;
    }
    tracing::info!(
        keyframes = index.len(),
        waiting = index.neighbour_graph_waiting(),
        loaded,
        seconds = started.elapsed().as_secs_f64(),
        "neighbour graph attached"
    );
    Some(if loaded {
        GraphSource::Loaded
    } else {
        GraphSource::Built
    })
}

/// [`attach`] for an index just rebuilt from every record: a saved graph
/// may be older than the records and is dropped, unless a restore left
/// one in step with them ([`restored_path`]).
pub(crate) fn attach_rebuilt(dir: &Path, index: &mut Index, short: usize) -> Option<GraphSource> {
    let restored = restored_path(dir);
    let taken = restored.exists() && std::fs::rename(&restored, path(dir)).is_ok();
    if !taken {
        let _ = std::fs::remove_file(path(dir));
    }
    attach(dir, index, short)
}

/// Drops a graph a restore left, where the store keeps none.
pub(crate) fn discard_restored(dir: &Path) {
    let _ = std::fs::remove_file(restored_path(dir));
}

/// Writes the index's neighbour graph, if it keeps one, to `file` under
/// its read lock, for an export. Whether one was written.
pub(crate) fn save_for_export(file: &Path, index: &RwLock<Index>) -> Result<bool, GraphError> {
    index
        .read()
        .save_neighbour_graph(file)
        .map(|rows| rows.is_some())
}
