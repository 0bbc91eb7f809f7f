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
//! rows waiting are few, a query over the map takes the exact pass. Map
//! graphs are not saved: a restart starts them again in the background,
//! and loop queries take the exact pass until theirs is ready.

use crate::engine::filter::RowGroup;
use crate::engine::graph::NeighbourGraph;

use super::neighbours::{graph_key, propose};
use super::table::{Index, MapGraph, Neighbours};

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

    /// Starts the graph of every map that is large enough and has none.
    pub(super) fn start_map_graphs(&mut self) {
        if self.map_graphs_from == 0 || self.neighbours.is_none() {
            return;
        }
        let large: Vec<usize> = self
            .tracks
            .values()
            .filter(|track| track.len() >= self.map_graphs_from)
            .filter_map(|track| track.values().next().copied())
            .collect();
        for row in large {
            self.start_map_graph(row);
        }
    }

    /// Starts a graph for the map of `row`, with every keyframe of the
    /// map the store's graph knows waiting to enter it, unless it has one.
    fn start_map_graph(&mut self, row: usize) {
        let group = self.row_group(row);
        let map = self.rows[row].map_key();
        let (dim, short) = (self.matrix.dim(), self.graph_short);
        let Some(n) = self.neighbours.as_mut() else {
            return;
        };
        if n.maps.contains_key(&group) {
            return;
        }
        let Ok(graph) = NeighbourGraph::shortened(dim, short) else {
            // No graph: the map's queries take the exact pass.
            return;
        };
        let waiting: Vec<u64> = self.tracks[&map]
            .values()
            .map(|&r| graph_key(&self.rows[r].key))
            .filter(|key| n.rows.contains_key(key))
            .collect();
        let _ = graph.reserve(waiting.len());
        n.maps.insert(group, MapGraph { graph, waiting });
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
