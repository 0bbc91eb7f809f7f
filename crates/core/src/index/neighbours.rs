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
//!
//! Adding a row to the graph costs about a millisecond of one core at a
//! million keyframes (rows shortened to 256 values), far more than
//! storing it. The store therefore defers it
//! ([`Index::defer_graph_inserts`]): a stored keyframe waits in a list
//! that every search scores exactly, so it is found from the moment it is
//! stored, and the store's writer adds the waiting rows under a shared
//! borrow ([`Index::add_waiting_to_graph`]), while queries go on, then
//! crosses them off under its exclusive one ([`Index::graph_added`]). The
//! same list lets a restart serve at once: rows the saved graph lacks
//! wait there instead of holding up the open.

use std::collections::{HashMap, HashSet};
use std::path::Path;
use std::sync::Mutex;

use rayon::prelude::*;
use rustc_hash::FxHashMap;

use crate::engine::filter::RowGroup;
use crate::engine::graph::{stored_length, GraphError, NeighbourGraph};
use crate::keyframe::KeyframeKey;

use super::table::{Index, Neighbours};

/// Waiting graph entries (the store's graph's and the maps' together)
/// above which [`Index::add_waiting_to_graph`] adds on every core: about
/// three seconds of a 32-robot fleet's inserts at 5 Hz. Below it a steady
/// stream of inserts is added on the caller's thread, which keeps up with
/// such a fleet on one core, and a fleet server's queries keep the others.
pub const PARALLEL_BACKLOG: usize = 1024;

/// A keyframe's key in the neighbour graph: FNV-1a over its robot,
/// session and keyframe id, the same in every process and on every
/// replica.
pub fn graph_key(key: &KeyframeKey) -> u64 {
    key.stable_hash()
}

impl Index {
    /// Keeps a neighbour graph over the stored descriptors from now on,
    /// building it from the rows stored (on every core) unless `saved` is
    /// given: a graph saved with [`Index::save_neighbour_graph`] earlier,
    /// which is brought up to date (rows it lacks are added; keys it holds
    /// that the index does not are never proposed). Where inserts are
    /// deferred ([`Index::defer_graph_inserts`]), the rows to add wait
    /// instead of being added now. Nothing to do if a graph is kept
    /// already, or while the descriptor length is unknown (the first
    /// insert then starts one).
    pub fn keep_neighbour_graph(
        &mut self,
        saved: Option<NeighbourGraph>,
    ) -> Result<(), GraphError> {
        self.graph_wanted = true;
        if self.neighbours.is_some() || self.matrix.dim() == 0 {
            return Ok(());
        }
        let dim = self.matrix.dim();
        let length = stored_length(dim, self.graph_short);
        let graph = match saved {
            Some(graph) if graph.dim() == dim && graph.stored_length() == length => graph,
            Some(graph) => {
                return Err(GraphError::Dimension {
                    expected: length,
                    found: graph.stored_length(),
                })
            }
            None => NeighbourGraph::shortened(dim, self.graph_short)?,
        };
        let mut rows = FxHashMap::with_capacity_and_hasher(self.rows.len(), Default::default());
        let mut missing = 0;
        let mut absent = Vec::new();
        for (row, meta) in self.rows.iter().enumerate() {
            let key = graph_key(&meta.key);
            if rows.insert(key, row as u32).is_some() {
                missing += 1;
                continue;
            }
            if !graph.contains(key) {
                absent.push(key);
            }
        }
        // Room for every row now: adds under a shared borrow cannot grow it.
        graph.reserve(absent.len())?;
        self.neighbours = Some(Neighbours {
            graph,
            rows,
            missing,
            waiting: absent,
            adding: Mutex::new(()),
            maps: HashMap::new(),
        });
        self.start_map_graphs();
        if !self.graph_deferred {
            self.flush_graph_inserts();
        }
        Ok(())
    }

    /// Has a graph started from now on shorten descriptors longer than
    /// `short` values to `short` (0: store them at their own length;
    /// [`crate::engine::graph::SHORT_LENGTH`] by default). A graph kept
    /// already is not changed.
    pub fn shorten_graph_rows(&mut self, short: usize) {
        self.graph_short = short;
    }

    /// The neighbour graph, if one is kept (to read its size).
    pub fn neighbour_graph(&self) -> Option<&NeighbourGraph> {
        self.neighbours.as_ref().map(|n| &n.graph)
    }

    /// Writes the neighbour graph, if one is kept, to `path`; the rows it
    /// holds, or None without a graph. Rows still waiting to enter it are
    /// not in the file: whoever loads it adds them again.
    pub fn save_neighbour_graph(&self, path: &Path) -> Result<Option<usize>, GraphError> {
        let Some(n) = self.neighbours.as_ref() else {
            return Ok(None);
        };
        let _no_adds = n.adding.lock().unwrap_or_else(|e| e.into_inner());
        n.graph.save(path).map(|()| Some(n.graph.len()))
    }

    /// Stored keyframes the neighbour graph lacks (a key hash shared with
    /// another keyframe, or a row the graph refused); an exact pass still
    /// finds them.
    pub fn neighbour_graph_missing(&self) -> usize {
        self.neighbours.as_ref().map_or(0, |n| n.missing)
    }

    /// Keyframe entries waiting to enter the neighbour graph or a map's
    /// (see [`Index::defer_graph_inserts`]); searches score them exactly
    /// meanwhile.
    pub fn neighbour_graph_waiting(&self) -> usize {
        self.neighbours
            .as_ref()
            .map_or(0, |n| n.waiting.len() + n.map_waiting())
    }

    /// The rows of up to `count` stored keyframes nearest to `query` by
    /// their descriptors among those `keep` accepts, nearest first, then
    /// every row `keep` accepts that waits to enter the graph, for the
    /// caller to score exactly. None without a graph, or while more than
    /// a sixteenth of the rows wait (after a restart that found no graph,
    /// or while inserts come faster than the graph takes them), where a
    /// full pass over the codes costs little more.
    pub fn nearest_rows(
        &self,
        query: &[f32],
        count: usize,
        keep: &(dyn Fn(usize) -> bool + Sync),
    ) -> Option<Vec<usize>> {
        let neighbours = self.neighbours.as_ref()?;
        if neighbours.waiting.len() > self.rows.len() / 16 + count {
            return None;
        }
        let graph = &neighbours.graph;
        propose(
            graph,
            &neighbours.waiting,
            &neighbours.rows,
            query,
            count,
            keep,
        )
    }

    /// Puts the keyframe of `row`, just stored, into the graph, or into
    /// its waiting list where inserts are deferred (starting a graph if
    /// one was asked for before the descriptor length was known).
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
        let deferred = self.graph_deferred;
        let Some(n) = self.neighbours.as_mut() else {
            return;
        };
        if let Some(&other) = n.rows.get(&key) {
            if other as usize != row {
                n.missing += 1;
                return;
            }
        }
        if deferred {
            n.rows.insert(key, row as u32);
            n.waiting.push(key);
            // Grows by doubling, so that adds under a shared borrow find
            // room; one that fails here fails again at the add.
            let _ = n.graph.reserve(n.waiting.len());
            self.map_graph_insert(row, key);
            return;
        }
        // Read only here: out of memory, a row read is a system call.
        if n.graph.add(key, &self.matrix.row(row)).is_ok() {
            n.rows.insert(key, row as u32);
            self.map_graph_insert(row, key);
            if self.neighbour_graph_waiting() > 0 {
                self.flush_graph_inserts();
            }
        } else {
            n.missing += 1;
        }
    }

    /// From now on, a keyframe stored waits to enter the neighbour graph
    /// until [`Index::add_waiting_to_graph`] (or
    /// [`Index::flush_graph_inserts`]) adds it; searches score the waiting
    /// rows exactly, so each is found from the moment it is stored. The
    /// store defers inserts so that they cost neither its writes nor its
    /// restarts their latency.
    pub fn defer_graph_inserts(&mut self) {
        self.graph_deferred = true;
    }

    /// Adds every waiting keyframe to the neighbour graph now, on every
    /// core.
    pub fn flush_graph_inserts(&mut self) {
        let added = self.add_waiting_to_graph(usize::MAX);
        self.graph_added(added);
    }

    /// Adds up to `limit` of the keyframes waiting to enter the neighbour
    /// graph, oldest first and on every core, under a shared borrow, so
    /// that queries go on meanwhile; [`Index::graph_added`] must follow
    /// before the index is changed otherwise, to cross them off.
    pub fn add_waiting_to_graph(&self, limit: usize) -> GraphAdditions {
        let Some(n) = self.neighbours.as_ref() else {
            return GraphAdditions::default();
        };
        let _saving = n.adding.lock().unwrap_or_else(|e| e.into_inner());
        let taken = n.waiting.len().min(limit);
        let mut work: Vec<(u64, usize)> = n.waiting[..taken]
            .iter()
            // A key erased since has left the table: it is not added.
            .filter_map(|&key| n.rows.get(&key).map(|&row| (key, row as usize)))
            .collect();
        work.sort_unstable();
        work.dedup();
        // Then the maps' graphs, with what the limit leaves.
        let mut left = limit - taken;
        let mut map_taken = Vec::new();
        let mut map_work: Vec<(&NeighbourGraph, u64, usize)> = Vec::new();
        for (&group, m) in &n.maps {
            if left == 0 {
                break;
            }
            let count = m.waiting.len().min(left);
            if count == 0 {
                continue;
            }
            left -= count;
            map_taken.push((group, count));
            let mut keys: Vec<(u64, usize)> = m.waiting[..count]
                .iter()
                .filter_map(|&key| n.rows.get(&key).map(|&row| (key, row as usize)))
                // Moved to another map since: that map's graph takes it.
                .filter(|&(_, row)| self.row_group(row) == group)
                .collect();
            keys.sort_unstable();
            keys.dedup();
            if m.graph.reserve_would_grow(keys.len()) {
                // No room was made (out of memory): these are crossed off
                // unadded, as the refusals below are.
                continue;
            }
            map_work.extend(keys.into_iter().map(|(key, row)| (&m.graph, key, row)));
        }
        // A backlog (a restart, a map's graph just started) is added on
        // every core; the few entries of a steady stream of inserts on
        // this thread alone, so that queries keep the other cores.
        let backlog = n.waiting.len() + n.maps.values().map(|m| m.waiting.len()).sum::<usize>();
        let min_len = if backlog > PARALLEL_BACKLOG {
            1
        } else {
            usize::MAX
        };
        let graph = &n.graph;
        let failed = if graph.reserve_would_grow(work.len()) {
            // No room was made (a failed reserve): nothing can be added.
            work.iter().map(|&(key, _)| key).collect()
        } else {
            work.par_iter()
                .with_min_len(min_len)
                .filter(|&&(key, row)| graph.add_shared(key, &self.matrix.row(row)).is_err())
                .map(|&(key, _)| key)
                .collect()
        };
        // A row a map's graph refuses (out of memory) is left out of it
        // for good: its map's loop queries no longer propose it, while
        // merge queries still find it through the store's graph.
        map_work
            .par_iter()
            .with_min_len(min_len)
            .for_each(|&(graph, key, row)| {
                let _ = graph.add_shared(key, &self.matrix.row(row));
            });
        GraphAdditions {
            taken,
            failed,
            map_taken,
        }
    }

    /// Crosses off the keyframes [`Index::add_waiting_to_graph`] added;
    /// those the graph refused are left to exact passes.
    pub fn graph_added(&mut self, added: GraphAdditions) {
        let Some(n) = self.neighbours.as_mut() else {
            return;
        };
        n.waiting.drain(..added.taken.min(n.waiting.len()));
        for key in added.failed {
            n.rows.remove(&key);
            n.missing += 1;
        }
        for (group, count) in added.map_taken {
            if let Some(m) = n.maps.get_mut(&group) {
                m.waiting.drain(..count.min(m.waiting.len()));
            }
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
                self.map_graph_remove(row, key);
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

/// The rows of up to `count` keyframes of `graph` nearest to `query`
/// among those `keep` accepts, nearest first, then every row `keep`
/// accepts among the keys `waiting` to enter it; keys name rows by
/// `rows`. None where the graph fails.
pub(super) fn propose(
    graph: &NeighbourGraph,
    waiting: &[u64],
    rows: &FxHashMap<u64, u32>,
    query: &[f32],
    count: usize,
    keep: &(dyn Fn(usize) -> bool + Sync),
) -> Option<Vec<usize>> {
    let row = |key: u64| rows.get(&key).map(|&r| r as usize);
    let keys = graph
        .search(query, count, |key| row(key).is_some_and(keep))
        .ok()?;
    let mut found: Vec<usize> = keys.into_iter().filter_map(row).collect();
    if !waiting.is_empty() {
        let mut seen: HashSet<usize> = found.iter().copied().collect();
        let waiting = waiting.iter().filter_map(|&key| row(key));
        found.extend(waiting.filter(|&r| keep(r) && seen.insert(r)));
    }
    Some(found)
}

/// What [`Index::add_waiting_to_graph`] did, for [`Index::graph_added`]:
/// how many waiting entries it took, and the keys the graph refused.
#[derive(Debug, Default)]
#[must_use = "the additions must be crossed off with Index::graph_added"]
pub struct GraphAdditions {
    taken: usize,
    failed: Vec<u64>,
    /// Waiting entries taken per map graph.
    map_taken: Vec<(RowGroup, usize)>,
}

impl GraphAdditions {
    /// Waiting entries taken (added, refused, or no longer stored), for
    /// the store's graph and the maps'.
    pub fn taken(&self) -> usize {
        self.taken + self.map_taken.iter().map(|(_, n)| n).sum::<usize>()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::index::MapKey;
    use crate::keyframe::SessionKey;

    /// Saved graphs name keyframes and maps by these hashes: they must
    /// not change from one release to the next (values computed
    /// independently, FNV-1a 64 over the bytes with 0xff between parts).
    #[test]
    fn graph_keys_and_map_names_are_stable() {
        let key = KeyframeKey {
            robot_id: "robot-a".into(),
            session_id: "session-1".into(),
            keyframe_id: 42,
        };
        assert_eq!(graph_key(&key), 0x1acc_7ab1_7f15_da3b);
        let map = MapKey {
            session: SessionKey {
                robot_id: "robot-a".into(),
                session_id: "session-1".into(),
            },
            map_id: 3,
        };
        assert_eq!(crate::index::map_graph_name(&map), 0xe354_5c81_7a95_8332);
    }
}
