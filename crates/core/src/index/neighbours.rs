//! The index's neighbour graph: the approximate first stage kept in step
//! with the rows.
//!
//! The graph ([`NeighbourGraph`]) names rows by a stable 64-bit hash of
//! their keyframe's key ([`graph_key`]), so that the rows can move
//! (erasures fill holes, grouping sorts them) and a saved graph can be
//! loaded beside an index whose rows are in another order; this module
//! keeps the hash → row table that turns the graph's answers back into
//! rows. Every insert, replacement and erasure updates the graph, so it
//! lives as long as the store without a rebuild.
//!
//! The graph is kept only where it was asked for
//! ([`Index::keep_neighbour_graph`]): a small store is scanned exactly and
//! would pay for it on every insert for nothing.

use std::collections::HashMap;

use rayon::prelude::*;

use crate::engine::graph::{GraphError, NeighbourGraph};
use crate::keyframe::KeyframeKey;

use super::table::{Index, Neighbours};

/// A keyframe's key in the neighbour graph: FNV-1a over its robot,
/// session and keyframe id, the same in every process and on every
/// replica.
pub fn graph_key(key: &KeyframeKey) -> u64 {
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            hash ^= u64::from(b);
            hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
        }
    };
    eat(key.robot_id.as_bytes());
    eat(&[0xff]);
    eat(key.session_id.as_bytes());
    eat(&[0xff]);
    eat(&key.keyframe_id.to_le_bytes());
    hash
}

impl Index {
    /// Keeps a neighbour graph over the stored descriptors from now on,
    /// building it from the rows stored (on every core) unless `saved` is
    /// given: a graph saved with [`Index::neighbour_graph`] earlier, which
    /// is brought up to date (rows it lacks are added; keys it holds that
    /// the index does not are never proposed). Nothing to do if a graph is
    /// kept already, or while the descriptor length is unknown (the first
    /// insert then starts one).
    pub fn keep_neighbour_graph(
        &mut self,
        saved: Option<NeighbourGraph>,
    ) -> Result<(), GraphError> {
        self.graph_wanted = true;
        if self.neighbours.is_some() || self.matrix.dim() == 0 {
            return Ok(());
        }
        let graph = match saved {
            Some(graph) if graph.dim() == self.matrix.dim() => graph,
            Some(graph) => {
                return Err(GraphError::Dimension {
                    expected: self.matrix.dim(),
                    found: graph.dim(),
                })
            }
            None => NeighbourGraph::new(self.matrix.dim())?,
        };
        let mut rows = HashMap::with_capacity(self.rows.len());
        let mut missing = 0;
        let mut absent = Vec::new();
        for (row, meta) in self.rows.iter().enumerate() {
            let key = graph_key(&meta.key);
            if rows.insert(key, row as u32).is_some() {
                missing += 1;
                continue;
            }
            if !graph.contains(key) {
                absent.push((key, row));
            }
        }
        graph.reserve(absent.len())?;
        let refused = absent
            .par_iter()
            .filter(|&&(key, row)| graph.add_shared(key, &self.matrix.row(row)).is_err())
            .count();
        self.neighbours = Some(Neighbours {
            graph,
            rows,
            missing: missing + refused,
            pending: None,
        });
        Ok(())
    }

    /// The neighbour graph, if one is kept (to save it, or to read its
    /// size).
    pub fn neighbour_graph(&self) -> Option<&NeighbourGraph> {
        self.neighbours.as_ref().map(|n| &n.graph)
    }

    /// Stored keyframes the neighbour graph lacks (a key hash shared with
    /// another keyframe, or a row the graph refused); an exact pass still
    /// finds them.
    pub fn neighbour_graph_missing(&self) -> usize {
        self.neighbours.as_ref().map_or(0, |n| n.missing)
    }

    /// The rows of up to `count` stored keyframes nearest to `query` by
    /// their descriptors among those `keep` accepts, nearest first; None
    /// without a graph.
    pub fn nearest_rows(
        &self,
        query: &[f32],
        count: usize,
        keep: &(dyn Fn(usize) -> bool + Sync),
    ) -> Option<Vec<usize>> {
        let neighbours = self.neighbours.as_ref()?;
        let row = |key: u64| neighbours.rows.get(&key).map(|&r| r as usize);
        let keys = neighbours
            .graph
            .search(query, count, |key| row(key).is_some_and(keep))
            .ok()?;
        Some(keys.into_iter().filter_map(row).collect())
    }

    /// Puts the keyframe of `row`, just stored, into the graph (starting
    /// one if it was asked for before the descriptor length was known).
    pub(super) fn graph_insert(&mut self, row: usize) {
        if self.neighbours.is_none() {
            if self.graph_wanted {
                // Built from every row, this one included; a graph that
                // cannot start leaves every query to the exact pass.
                let _ = self.keep_neighbour_graph(None);
            }
            return;
        }
        let key = graph_key(&self.rows[row].key);
        let descriptor = self.matrix.row(row);
        let Some(n) = self.neighbours.as_mut() else {
            return;
        };
        if let Some(&other) = n.rows.get(&key) {
            if other as usize != row {
                n.missing += 1;
                return;
            }
        }
        if let Some(pending) = n.pending.as_mut() {
            n.rows.insert(key, row as u32);
            pending.push(key);
            return;
        }
        if n.graph.add(key, &descriptor).is_ok() {
            n.rows.insert(key, row as u32);
        } else {
            n.missing += 1;
        }
    }

    /// From now until [`Index::flush_graph_inserts`], keyframes stored
    /// wait to enter the neighbour graph, so that a batch of them enters
    /// it on every core at once (an insert costs about a millisecond of
    /// one core at 1280 values). Their table entries are kept meanwhile,
    /// so erasures and moves in between are followed; a search before the
    /// flush does not find them.
    pub fn defer_graph_inserts(&mut self) {
        if let Some(n) = self.neighbours.as_mut() {
            n.pending.get_or_insert_with(Vec::new);
        }
    }

    /// Adds the keyframes stored since [`Index::defer_graph_inserts`] to
    /// the neighbour graph, in parallel, and adds each from now on as it
    /// is stored.
    pub fn flush_graph_inserts(&mut self) {
        let Index {
            neighbours, matrix, ..
        } = self;
        let Some(n) = neighbours.as_mut() else {
            return;
        };
        let Some(mut keys) = n.pending.take() else {
            return;
        };
        keys.sort_unstable();
        keys.dedup();
        // A key erased since has left the table: it is not added.
        let work: Vec<(u64, usize)> = keys
            .into_iter()
            .filter_map(|key| n.rows.get(&key).map(|&row| (key, row as usize)))
            .collect();
        let graph = &n.graph;
        let failed: Vec<u64> = if graph.reserve(work.len()).is_err() {
            work.iter().map(|&(key, _)| key).collect()
        } else {
            work.par_iter()
                .filter(|&&(key, row)| graph.add_shared(key, &matrix.row(row)).is_err())
                .map(|&(key, _)| key)
                .collect()
        };
        for key in failed {
            n.rows.remove(&key);
            n.missing += 1;
        }
    }

    /// Takes the keyframe of `row`, about to be erased, out of the graph.
    pub(super) fn graph_remove(&mut self, row: usize) {
        let key = graph_key(&self.rows[row].key);
        let Some(n) = self.neighbours.as_mut() else {
            return;
        };
        match n.rows.get(&key) {
            Some(&r) if r as usize == row => {
                n.rows.remove(&key);
                // A graph that cannot forget a key still names a row the
                // table no longer has: the search never proposes it.
                let _ = n.graph.remove(key);
            }
            // Left out at insert (its hash was another's).
            _ => n.missing = n.missing.saturating_sub(1),
        }
    }

    /// Notes that the keyframe now in row `to` moved there from `from`.
    pub(super) fn graph_moved(&mut self, from: usize, to: usize) {
        let key = graph_key(&self.rows[to].key);
        if let Some(n) = self.neighbours.as_mut() {
            match n.rows.get_mut(&key) {
                // Not if the hash names another keyframe's row.
                Some(r) if *r as usize == from => *r = to as u32,
                _ => {}
            }
        }
    }
}
