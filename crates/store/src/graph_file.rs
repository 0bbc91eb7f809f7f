//! The neighbour graph's file beside the index snapshot, so that a restart
//! loads the graph instead of building it again (building takes minutes
//! at a million keyframes; loading, one read).
//!
//! The graph is saved after each snapshot has fixed its write sequence,
//! and renamed into place before the snapshot is, so the graph on disk is
//! never older than the snapshot it is loaded with. At open it is attached
//! to the snapshot's index *before* the journal is replayed, so the replay
//! updates it like any other change; rows the graph lacks are added, and
//! keys it holds that the index does not are never proposed. A graph that
//! is missing, of another descriptor length or unreadable is rebuilt from
//! the rows, with a warning.

use std::path::{Path, PathBuf};
use std::time::Instant;

use humem_core::engine::graph::NeighbourGraph;
use humem_core::index::Index;
use parking_lot::RwLock;

/// File name of the neighbour graph in the data directory.
pub const FILE_NAME: &str = "index.graph";

/// Path of the neighbour graph in data directory `dir`.
pub fn path(dir: &Path) -> PathBuf {
    dir.join(FILE_NAME)
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
/// about a second a million keyframes). A failure is logged and the old
/// file removed, so that the next open rebuilds the graph rather than load
/// one older than the snapshot.
pub(crate) fn save(dir: &Path, index: &RwLock<Index>) -> Option<UnpublishedGraph> {
    let temp = temp_path(dir);
    let started = Instant::now();
    let saved = {
        let index = index.read();
        let Some(graph) = index.neighbour_graph() else {
            // A graph left from when one was kept would be older than
            // this snapshot: the next open that wants one builds it.
            let _ = std::fs::remove_file(path(dir));
            return None;
        };
        graph.save(&temp).map(|()| graph.len())
    };
    match saved {
        Ok(rows) => {
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

/// Starts `index` keeping a neighbour graph: the one saved in `dir` where
/// it can be read, else one built from the rows (on every core).
pub(crate) fn attach(dir: &Path, index: &mut Index) {
    let started = Instant::now();
    let file = path(dir);
    let saved = if file.exists() && index.dim() > 0 {
        match NeighbourGraph::load(&file, index.dim()) {
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
        return;
    }
    tracing::info!(
        keyframes = index.len(),
        loaded,
        seconds = started.elapsed().as_secs_f64(),
        "neighbour graph ready"
    );
}
