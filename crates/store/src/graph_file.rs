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
//! The large maps' own graphs are saved the same way, one file a map in
//! [`MAPS_DIR_NAME`] (named by [`map_graph_name`]), renamed into place
//! with the store's graph. At open a map large in the snapshot takes its
//! saved graph, attached before the replay as the store's is; a map
//! without one, or one whose file cannot be read, starts an empty graph
//! that the writer fills in the background (its loop queries take the
//! exact pass meanwhile).
//!
//! A store restored from an export ([`crate::export`]) gets the graph the
//! export carried as [`restored_path`]: in step with the restored records,
//! it is taken by the first open, which otherwise would build one. An
//! export carries no maps' graphs: they are built again.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use humem_core::engine::graph::{GraphError, NeighbourGraph};
use humem_core::index::{map_graph_name, Index, MapKey};
use parking_lot::RwLock;

/// File name of the neighbour graph in the data directory.
pub const FILE_NAME: &str = "index.graph";

/// Directory of the large maps' graphs in the data directory.
pub const MAPS_DIR_NAME: &str = "index.maps";

/// Path of the neighbour graph in data directory `dir`.
pub fn path(dir: &Path) -> PathBuf {
    dir.join(FILE_NAME)
}

/// Path of the maps' graphs' directory in data directory `dir`.
pub fn maps_path(dir: &Path) -> PathBuf {
    dir.join(MAPS_DIR_NAME)
}

fn maps_temp_path(dir: &Path) -> PathBuf {
    dir.join(format!("{MAPS_DIR_NAME}.tmp"))
}

/// The file of `map`'s graph in the maps' graphs' directory `maps`.
fn map_file(maps: &Path, map: &MapKey) -> PathBuf {
    maps.join(format!("{:016x}.graph", map_graph_name(map)))
}

/// How the index keeps its neighbour graphs.
#[derive(Debug, Clone, Copy)]
pub(crate) struct GraphOptions {
    /// The length the graphs shorten descriptors to (0: not at all).
    pub short: usize,
    /// Keyframes from which a map gets a graph of its own (0: none).
    pub map_graphs_from: usize,
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
    /// Whether the maps' graphs were written.
    maps: bool,
}

/// Writes the index's neighbour graph, if it keeps one, to a temporary
/// file in `dir`, under the index's read lock (changes wait for it:
/// about a second a million keyframes), then each large map's graph to a
/// temporary directory, each under a read lock of its own. Keyframes
/// still waiting to enter a graph are not in its file; the open that
/// loads it adds them. A failure is logged and the old file removed, so
/// that the next open rebuilds the graph rather than load one older than
/// the snapshot.
pub(crate) fn save(dir: &Path, index: &RwLock<Index>) -> Option<UnpublishedGraph> {
    let temp = temp_path(dir);
    let started = Instant::now();
    let saved = index.read().save_neighbour_graph(&temp);
    match saved {
        Ok(None) => {
            // A graph left from when one was kept would be older than
            // this snapshot: the next open that wants one builds it.
            let _ = std::fs::remove_file(path(dir));
            let _ = std::fs::remove_dir_all(maps_path(dir));
            None
        }
        Ok(Some(rows)) => {
            tracing::debug!(
                rows,
                ms = started.elapsed().as_millis() as u64,
                "neighbour graph written"
            );
            let maps = save_map_graphs(dir, index);
            Some(UnpublishedGraph {
                dir: dir.to_path_buf(),
                maps,
            })
        }
        Err(e) => {
            tracing::warn!(error = %e, "writing the neighbour graph failed: the next start rebuilds it");
            let _ = std::fs::remove_file(&temp);
            let _ = std::fs::remove_file(path(dir));
            let _ = std::fs::remove_dir_all(maps_path(dir));
            None
        }
    }
}

/// Writes every large map's graph to the maps' temporary directory in
/// `dir`; whether all were written (else the directory is removed).
fn save_map_graphs(dir: &Path, index: &RwLock<Index>) -> bool {
    let temp = maps_temp_path(dir);
    let started = Instant::now();
    match write_map_graphs(&temp, index) {
        Ok(maps) => {
            tracing::debug!(
                maps,
                ms = started.elapsed().as_millis() as u64,
                "maps' graphs written"
            );
            true
        }
        Err(e) => {
            tracing::warn!(error = %e, "writing the maps' graphs failed: the next start rebuilds them");
            let _ = std::fs::remove_dir_all(&temp);
            false
        }
    }
}

/// Writes every map's graph into a fresh directory `temp`, each under a
/// read lock of its own; how many were written.
fn write_map_graphs(temp: &Path, index: &RwLock<Index>) -> Result<usize, GraphError> {
    let _ = std::fs::remove_dir_all(temp);
    std::fs::create_dir_all(temp).map_err(|e| GraphError::Native(e.to_string()))?;
    let maps = index.read().maps_with_graphs();
    let mut written = 0;
    for map in maps {
        // A map erased or merged away since has no graph to write.
        if index.read().save_map_graph(&map, &map_file(temp, &map))? {
            written += 1;
        }
    }
    Ok(written)
}

impl UnpublishedGraph {
    /// Renames the graph, and the maps' graphs' directory, into place
    /// (before their snapshot is). Maps' graphs that could not be written
    /// leave none, so that the next open builds them rather than load
    /// graphs older than the snapshot.
    pub(crate) fn publish(self) {
        if let Err(e) = std::fs::rename(temp_path(&self.dir), path(&self.dir)) {
            tracing::warn!(error = %e, "placing the neighbour graph failed: the next start rebuilds it");
            let _ = std::fs::remove_file(path(&self.dir));
        }
        let maps = maps_path(&self.dir);
        let _ = std::fs::remove_dir_all(&maps);
        if self.maps {
            if let Err(e) = std::fs::rename(maps_temp_path(&self.dir), &maps) {
                tracing::warn!(error = %e, "placing the maps' graphs failed: the next start rebuilds them");
            }
        }
    }
}

/// The saved graphs of the maps large in `index` that can be read and
/// were made alike (descriptors shortened to `short` values), by map.
fn load_map_graphs(dir: &Path, index: &Index, short: usize) -> HashMap<MapKey, NeighbourGraph> {
    let maps = maps_path(dir);
    if !maps.is_dir() || index.dim() == 0 {
        return HashMap::new();
    }
    index
        .large_maps()
        .into_iter()
        .filter_map(|map| {
            let file = map_file(&maps, &map);
            if !file.exists() {
                return None;
            }
            match NeighbourGraph::load(&file, index.dim(), short) {
                Ok(graph) => Some((map, graph)),
                Err(e) => {
                    tracing::warn!(error = %e, file = %file.display(), "a saved map's graph is not used: rebuilding it");
                    None
                }
            }
        })
        .collect()
}

/// Starts `index` keeping a neighbour graph that shortens descriptors to
/// `options.short` values (0: not at all): the one saved in `dir` where
/// it can be read and was made alike, else an empty one; and each map of
/// `options.map_graphs_from` keyframes or more a graph of its own, its
/// saved one where there is one. None where no graph could be kept.
/// Either way the rows the graph lacks wait to enter it, and from now on
/// so does every keyframe stored ([`Index::defer_graph_inserts`]): the
/// writer adds them in the background, so the open does not wait for
/// them (a million keyframes take more than ten minutes on two cores).
pub(crate) fn attach(dir: &Path, index: &mut Index, options: GraphOptions) -> Option<GraphSource> {
    let short = options.short;
    index.defer_graph_inserts();
    index.shorten_graph_rows(short);
    index.keep_map_graphs(options.map_graphs_from);
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
    let maps = load_map_graphs(dir, index, short);
    let maps_loaded = maps.len();
    index.offer_saved_map_graphs(maps);
    if let Err(e) = index.keep_neighbour_graph(saved) {
        tracing::warn!(error = %e, "no neighbour graph: every query scans its eligible keyframes");
        return None;
    }
    tracing::info!(
        keyframes = index.len(),
        waiting = index.neighbour_graph_waiting(),
        loaded,
        maps_loaded,
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
/// one in step with them ([`restored_path`]); the maps' graphs are
/// dropped either way.
pub(crate) fn attach_rebuilt(
    dir: &Path,
    index: &mut Index,
    options: GraphOptions,
) -> Option<GraphSource> {
    let restored = restored_path(dir);
    let taken = restored.exists() && std::fs::rename(&restored, path(dir)).is_ok();
    if !taken {
        let _ = std::fs::remove_file(path(dir));
    }
    let _ = std::fs::remove_dir_all(maps_path(dir));
    attach(dir, index, options)
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
