//! A neighbour graph per large map, beside the store's: what a loop query
//! over a robot's own map walks.
//!
//! The store's graph serves queries that may see much of the store (a
//! fleet's merge query over every other map). A loop query may see one
//! map only, a few per cent of a fleet's store: the store's graph, walked
//! with that filter, visits dozens of keyframes for each one it may
//! propose, and an exact pass over a map of 30 000 keyframes reads 40 MB.
//! So each map of [`Index::keep_map_graphs`]'s size or more gets a graph
//! of its own over the same keys (the rows' graph keys, in the store
//! graph's `rows` table), and a query whose filter names that one map
//! ([`RowFilter::group`](crate::engine::filter::RowFilter::group)) walks
//! it.
//!
//! A map's graph starts when its track reaches the size, with every row
//! of the map waiting to enter it; from then on each keyframe stored in
//! the map waits for it as it waits for the store's graph, and the same
//! writer step adds both ([`Index::add_waiting_to_graph`]). Until the
//! rows waiting are few, a query over the map takes the exact pass.
//!
//! The maps' graphs are saved beside the store's
//! ([`Index::save_map_graph`]), each named by its map
//! ([`map_graph_name`]), and offered back when the index opens
//! ([`Index::offer_saved_map_graphs`]): a map large when the store's graph
//! is attached takes its saved graph, and only the keyframes that graph
//! lacks wait to enter it. Keys a saved graph holds that its map no
//! longer does are never proposed (a loop query's filter admits the
//! map's rows only).

use std::collections::HashMap;
use std::path::Path;

use crate::engine::filter::RowGroup;
use crate::engine::graph::{stored_length, GraphError, NeighbourGraph};
use crate::numeric::fnv1a;

use super::neighbours::{graph_key, propose};
use super::table::{Index, MapGraph, MapKey, Neighbours};

/// A map's name for its saved graph: FNV-1a over its robot, session and
/// map id, the same in every process (unlike the index's row groups,
/// whose session numbers are given out as sessions are first seen).
pub fn map_graph_name(map: &MapKey) -> u64 {
    fnv1a(&[
        map.session.robot_id.as_bytes(),
        map.session.session_id.as_bytes(),
        &map.map_id.to_le_bytes(),
    ])
}

impl Index {
    /// Keeps a neighbour graph of its own for every map of `from`
    /// keyframes or more (0: none), beside the store's graph, from the
    /// moment the store's graph is kept. A loop query over such a map
    /// walks it ([`Index::nearest_rows_of_map`]). The rows of the maps
    /// large enough now wait to enter their graphs, unless inserts are
    /// not deferred: then they are added now, on every core.
    pub fn keep_map_graphs(&mut self, from: usize) {
        self.map_graphs_from = from;
        self.start_map_graphs();
        if !self.graph_deferred {
            self.flush_graph_inserts();
        }
    }

    /// The maps large enough for a graph of their own (with
    /// [`Index::keep_map_graphs`]' size), whose saved graphs an open may
    /// offer.
    pub fn large_maps(&self) -> Vec<MapKey> {
        if self.map_graphs_from == 0 {
            return Vec::new();
        }
        self.tracks
            .iter()
            .filter(|(_, track)| track.len() >= self.map_graphs_from)
            .map(|(map, _)| map.clone())
            .collect()
    }

    /// Offers maps' graphs saved earlier ([`Index::save_map_graph`]) to
    /// the maps' graphs that start with the next neighbour graph kept
    /// ([`Index::keep_neighbour_graph`]): a map large then takes its saved
    /// graph where it stores rows at the same length, and only its
    /// keyframes that graph lacks wait to enter it. Graphs no map takes
    /// then are dropped, so a map that grows large later (or while the
    /// journal is replayed, when a saved graph could hold an older
    /// descriptor of a replayed keyframe) starts an empty one.
    pub fn offer_saved_map_graphs(&mut self, saved: HashMap<MapKey, NeighbourGraph>) {
        self.saved_map_graphs = saved;
    }

    /// Saved maps' graphs their maps took so far
    /// ([`Index::offer_saved_map_graphs`]).
    pub fn saved_map_graphs_taken(&self) -> usize {
        self.saved_map_graphs_taken
    }

    /// The maps that have a graph of their own.
    pub fn maps_with_graphs(&self) -> Vec<MapKey> {
        self.neighbours.as_ref().map_or_else(Vec::new, |n| {
            n.maps.values().map(|m| m.map.clone()).collect()
        })
    }

    /// Writes `map`'s graph to `path`, while no keyframe is added to any
    /// graph (keyframes waiting to enter it are not in the file; the open
    /// that loads it has them wait again); false where the map has no
    /// graph.
    pub fn save_map_graph(&self, map: &MapKey, path: &Path) -> Result<bool, GraphError> {
        let Some(n) = self.neighbours.as_ref() else {
            return Ok(false);
        };
        let _no_adds = n.adding.lock().unwrap_or_else(|e| e.into_inner());
        match n.maps.values().find(|m| m.map == *map) {
            Some(m) => m.graph.save(path).map(|()| true),
            None => Ok(false),
        }
    }

    /// Maps with a graph of their own, the keyframes those hold, and the
    /// bytes they take in memory.
    pub fn map_graphs(&self) -> (usize, usize, usize) {
        self.neighbours.as_ref().map_or((0, 0, 0), |n| {
            n.maps.values().fold((0, 0, 0), |(maps, rows, bytes), m| {
                (
                    maps + 1,
                    rows + m.graph.len(),
                    bytes + m.graph.memory_bytes(),
                )
            })
        })
    }

    /// Keyframes waiting to enter their map's graph.
    pub fn map_graphs_waiting(&self) -> usize {
        self.neighbours.as_ref().map_or(0, Neighbours::map_waiting)
    }

    /// Starts the graph of every map that is large enough and has none,
    /// from its saved graph where one was offered; the offered graphs no
    /// map took are dropped.
    pub(super) fn start_map_graphs(&mut self) {
        if self.map_graphs_from == 0 || self.neighbours.is_none() {
            self.saved_map_graphs.clear();
            return;
        }
        let large: Vec<usize> = self
            .large_maps()
            .iter()
            .filter_map(|map| self.tracks[map].values().next().copied())
            .collect();
        for row in large {
            self.start_map_graph(row);
        }
        self.saved_map_graphs.clear();
    }

    /// Starts a graph for the map of `row`, unless it has one: the saved
    /// graph offered for the map where there is one alike, with every
    /// keyframe of the map the store's graph knows and it lacks waiting
    /// to enter it; else an empty one, with all of them waiting.
    fn start_map_graph(&mut self, row: usize) {
        let group = self.row_group(row);
        let map = self.rows[row].map_key();
        let (dim, short) = (self.matrix.dim(), self.graph_short);
        let saved = self
            .saved_map_graphs
            .remove(&map)
            .filter(|g| g.dim() == dim && g.stored_length() == stored_length(dim, short));
        let Some(n) = self.neighbours.as_mut() else {
            return;
        };
        if n.maps.contains_key(&group) {
            return;
        }
        let graph = match saved {
            Some(graph) => {
                self.saved_map_graphs_taken += 1;
                graph
            }
            None => match NeighbourGraph::shortened(dim, short) {
                Ok(graph) => graph,
                // No graph: the map's queries take the exact pass.
                Err(_) => return,
            },
        };
        let waiting: Vec<u64> = self.tracks[&map]
            .values()
            .map(|&r| graph_key(&self.rows[r].key))
            .filter(|key| n.rows.contains_key(key) && !graph.contains(*key))
            .collect();
        let _ = graph.reserve(waiting.len());
        n.maps.insert(
            group,
            MapGraph {
                map,
                graph,
                waiting,
            },
        );
    }

    /// Has the keyframe of `row`, just entered in the store graph's table
    /// under `key`, wait for its map's graph, starting that graph where
    /// the map has just become large enough.
    pub(super) fn map_graph_insert(&mut self, row: usize, key: u64) {
        if self.map_graphs_from == 0 {
            return;
        }
        let group = self.row_group(row);
        let Some(n) = self.neighbours.as_mut() else {
            return;
        };
        if let Some(m) = n.maps.get_mut(&group) {
            m.waiting.push(key);
            let _ = m.graph.reserve(m.waiting.len());
            return;
        }
        let map = self.rows[row].map_key();
        if self.tracks.get(&map).map_or(0, |t| t.len()) >= self.map_graphs_from {
            // Every row of the map, this one included.
            self.start_map_graph(row);
        }
    }

    /// Takes `key`, the keyframe of `row` about to be erased, out of its
    /// map's graph; a map's graph left empty goes.
    pub(super) fn map_graph_remove(&mut self, row: usize, key: u64) {
        let group = self.row_group(row);
        let Some(n) = self.neighbours.as_mut() else {
            return;
        };
        if let Some(m) = n.maps.get_mut(&group) {
            // One still waiting is skipped when its turn comes.
            let _ = m.graph.remove(key);
            if m.graph.is_empty() && m.waiting.iter().all(|k| *k == key) {
                n.maps.remove(&group);
            }
        }
    }

    /// The rows of up to `count` keyframes of the map `group` names
    /// nearest to `query` among those `keep` accepts, nearest first, from
    /// that map's graph, then every row `keep` accepts that waits to
    /// enter it, for the caller to score exactly. None where the map has
    /// no graph or more than a sixteenth of it waits: the caller takes
    /// the exact pass.
    pub fn nearest_rows_of_map(
        &self,
        query: &[f32],
        count: usize,
        group: RowGroup,
        keep: &(dyn Fn(usize) -> bool + Sync),
    ) -> Option<Vec<usize>> {
        let n = self.neighbours.as_ref()?;
        let m = n.maps.get(&group)?;
        if m.waiting.len() > m.graph.len() / 16 + count {
            return None;
        }
        propose(&m.graph, &m.waiting, &n.rows, query, count, keep)
    }
}

impl Neighbours {
    /// Keys waiting to enter the maps' graphs.
    pub(super) fn map_waiting(&self) -> usize {
        self.maps.values().map(|m| m.waiting.len()).sum()
    }
}
