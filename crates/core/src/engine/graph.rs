//! The approximate first stage: a navigable small-world graph (HNSW) over
//! the stored descriptors, which finds a query's nearest rows by visiting a
//! few thousand of them instead of all.
//!
//! An exact pass costs one read of every eligible row, so a fleet's merge
//! query grows with the whole fleet's store. The graph's search grows with
//! its logarithm. It is USearch's graph (a maintained crate with filtered
//! search, removal, and saving to a file); this module only decides what it
//! stores and hides its error type:
//!
//! - each row is first shortened to [`SHORT_LENGTH`] values by a fixed
//!   random rotation ([`projection`](super::projection)): an insert
//!   compares the row with hundreds of stored ones, and at 1280 values
//!   the graph's inserts took half of a fleet server's cores; the
//!   shortened rows' dot products are the originals' plus a small noise,
//!   and the candidates are scored exactly anyway;
//! - it is then stored as its one-byte code (scaled by its largest
//!   magnitude, as [`codes`](super::codes) does), under the cosine metric:
//!   the scaling is undone by the cosine, a quarter of the f32 bytes are
//!   read, and unit descriptors rank as their dot products do;
//! - rows are named by stable 64-bit keys chosen by the caller, not by row
//!   position: rows move (erasures fill holes, grouping sorts them) and the
//!   graph is saved and loaded with an index whose rows are in another
//!   order;
//! - a search takes a filter over keys, applied while the graph is walked
//!   (not to its results), so a query that may see a part of the store
//!   still gets its `count` nearest of that part.
//!
//! The graph only proposes candidates: every one is scored exactly by the
//! caller, so its error is only in what it may miss.

use std::path::Path;

use usearch::{Index as Hnsw, IndexOptions, MetricKind, ScalarKind};

use super::codes::i8_codes as code;
use super::projection::Projection;

/// Length the graph shortens longer descriptors to (`humem bench graph
/// --short-lengths`): 256 values keep the exact top-1 among the proposed
/// candidates as often as the full length does, at a fraction of an
/// insert's cost. Shorter descriptors are stored as they are.
pub const SHORT_LENGTH: usize = 256;

/// Links per node (HNSW's `M`): 16 is the usual default; fewer links make
/// inserts cheaper and recall lower (`humem bench scan`).
pub const CONNECTIVITY: usize = 16;

/// Candidates kept while a row is inserted (`efConstruction`).
pub const EXPANSION_ADD: usize = 128;

/// Candidates kept while a query walks the graph (`ef`), unless the query
/// asks for more results than that.
pub const EXPANSION_SEARCH: usize = 64;

/// Concurrent searches and adds the graph keeps scratch space for: the
/// writer adds on every core while queries search.
fn threads() -> usize {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    64.max(4 * cores)
}

/// Why the graph could not do what was asked.
#[derive(Debug, thiserror::Error)]
pub enum GraphError {
    /// USearch refused (out of memory, a file it cannot read, …).
    #[error("neighbour graph: {0}")]
    Native(String),
    /// A saved graph stores rows of another length than this one would.
    #[error(
        "the saved neighbour graph stores rows of {found} values, this one would store {expected}"
    )]
    Dimension {
        /// The length this graph stores rows at.
        expected: usize,
        /// The saved graph's.
        found: usize,
    },
}

/// USearch's error (a C++ exception) as a [`GraphError`].
fn native(e: impl std::fmt::Display) -> GraphError {
    GraphError::Native(e.to_string())
}

/// An HNSW graph over descriptors of one length, keyed by stable keys.
pub struct NeighbourGraph {
    graph: Hnsw,
    dim: usize,
    /// Shortens rows and queries before the graph sees them; None where
    /// they are stored at their own length.
    projection: Option<Projection>,
}

impl std::fmt::Debug for NeighbourGraph {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NeighbourGraph")
            .field("dim", &self.dim)
            .field("stored_length", &self.stored_length())
            .field("len", &self.len())
            .finish()
    }
}

fn options(dim: usize) -> IndexOptions {
    IndexOptions {
        dimensions: dim,
        metric: MetricKind::Cos,
        quantization: ScalarKind::I8,
        connectivity: CONNECTIVITY,
        expansion_add: EXPANSION_ADD,
        expansion_search: EXPANSION_SEARCH,
        multi: false,
    }
}

/// The length the graph stores `dim`-value descriptors at when asked to
/// shorten them to `short` (0: not at all).
pub fn stored_length(dim: usize, short: usize) -> usize {
    if short == 0 {
        dim
    } else {
        dim.min(short)
    }
}

impl NeighbourGraph {
    /// An empty graph for descriptors of length `dim` (> 0), stored at
    /// [`SHORT_LENGTH`] values where they are longer.
    pub fn new(dim: usize) -> Result<Self, GraphError> {
        Self::shortened(dim, SHORT_LENGTH)
    }

    /// An empty graph for descriptors of length `dim` (> 0), stored at
    /// `short` values where they are longer (0: at their own length).
    pub fn shortened(dim: usize, short: usize) -> Result<Self, GraphError> {
        let length = stored_length(dim, short);
        let graph = Hnsw::new(&options(length)).map_err(native)?;
        graph
            .reserve_capacity_and_threads(1024, threads())
            .map_err(native)?;
        Ok(NeighbourGraph {
            graph,
            dim,
            projection: projection(dim, length),
        })
    }

    /// Descriptor length.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Length the graph stores each row at.
    pub fn stored_length(&self) -> usize {
        self.projection
            .as_ref()
            .map_or(self.dim, Projection::output_dim)
    }

    /// What the graph stores of `row`: its one-byte code, shortened first
    /// where the graph shortens.
    fn stored(&self, row: &[f32]) -> Vec<i8> {
        match &self.projection {
            Some(p) => code(&p.apply(row)),
            None => code(row),
        }
    }

    /// Rows stored.
    pub fn len(&self) -> usize {
        self.graph.size()
    }

    /// Whether no row is stored.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Whether `key` is stored.
    pub fn contains(&self, key: u64) -> bool {
        self.graph.contains(key)
    }

    /// Bytes the graph holds in memory (codes, links and tables).
    pub fn memory_bytes(&self) -> usize {
        self.graph.memory_usage()
    }

    /// Room for `more` rows beyond those stored, so that concurrent
    /// [`NeighbourGraph::add_shared`] calls need not grow it.
    pub fn reserve(&self, more: usize) -> Result<(), GraphError> {
        let wanted = self.len() + more;
        if wanted > self.graph.capacity() {
            // Doubling keeps the growth amortised, as a Vec's.
            let capacity = wanted.max(2 * self.graph.capacity());
            self.graph
                .reserve_capacity_and_threads(capacity, threads())
                .map_err(native)?;
        }
        Ok(())
    }

    /// Whether `more` rows beyond those stored need a
    /// [`NeighbourGraph::reserve`] first.
    pub fn reserve_would_grow(&self, more: usize) -> bool {
        self.len() + more > self.graph.capacity()
    }

    /// Stores `row` under `key`, replacing what `key` held.
    pub fn add(&mut self, key: u64, row: &[f32]) -> Result<(), GraphError> {
        self.reserve(1)?;
        self.add_shared(key, row)
    }

    /// [`NeighbourGraph::add`] from several threads at once; room must have
    /// been made with [`NeighbourGraph::reserve`].
    pub fn add_shared(&self, key: u64, row: &[f32]) -> Result<(), GraphError> {
        debug_assert_eq!(row.len(), self.dim);
        if self.graph.contains(key) {
            self.graph.remove(key).map_err(native)?;
        }
        self.graph.add(key, &self.stored(row)).map_err(native)?;
        Ok(())
    }

    /// Forgets `key`; false if it was not stored.
    pub fn remove(&mut self, key: u64) -> Result<bool, GraphError> {
        Ok(self.graph.remove(key).map_err(native)? > 0)
    }

    /// The keys of up to `count` stored rows nearest to `query` among
    /// those `keep` accepts, nearest first. The graph's walk keeps
    /// [`EXPANSION_SEARCH`] candidates, or `count` where that is more.
    pub fn search(
        &self,
        query: &[f32],
        count: usize,
        keep: impl Fn(u64) -> bool,
    ) -> Result<Vec<u64>, GraphError> {
        if self.is_empty() || count == 0 {
            return Ok(Vec::new());
        }
        let found = self
            .graph
            .filtered_search(&self.stored(query), count, keep)
            .map_err(native)?;
        Ok(found.keys)
    }

    /// Writes the graph to `path` (one file, USearch's format).
    pub fn save(&self, path: &Path) -> Result<(), GraphError> {
        self.graph.save(&path_str(path)?).map_err(native)?;
        Ok(())
    }

    /// The graph saved at `path`, for descriptors of length `dim` stored
    /// at `short` values where they are longer (as the saving graph was
    /// made: a graph of another stored length is refused).
    pub fn load(path: &Path, dim: usize, short: usize) -> Result<Self, GraphError> {
        let path = path_str(path)?;
        let meta = Hnsw::metadata(&path).map_err(native)?;
        let length = stored_length(dim, short);
        if meta.dimensions as usize != length {
            return Err(GraphError::Dimension {
                expected: length,
                found: meta.dimensions as usize,
            });
        }
        let graph = Hnsw::new(&options(length)).map_err(native)?;
        graph.load(&path).map_err(native)?;
        let loaded = NeighbourGraph {
            graph,
            dim,
            projection: projection(dim, length),
        };
        loaded.reserve(1024)?;
        Ok(loaded)
    }
}

fn projection(dim: usize, length: usize) -> Option<Projection> {
    (length < dim).then(|| Projection::new(dim, length))
}

fn path_str(path: &Path) -> Result<String, GraphError> {
    path.to_str()
        .map(str::to_string)
        .ok_or_else(|| GraphError::Native(format!("{}: not UTF-8", path.display())))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::{place_descriptor, Rng};

    fn rows(n: usize, dim: usize) -> Vec<Vec<f32>> {
        let mut noise = Rng::new(3);
        (0..n)
            .map(|i| place_descriptor(dim, (i / 4) as u64, &mut noise))
            .collect()
    }

    #[test]
    fn finds_the_nearest_row_among_those_the_filter_keeps() {
        let data = rows(2_000, 64);
        let mut graph = NeighbourGraph::new(64).unwrap();
        for (i, row) in data.iter().enumerate() {
            graph.add(1000 + i as u64, row).unwrap();
        }
        assert_eq!(graph.len(), 2_000);
        // A stored row finds itself; with it filtered out, one of its place.
        let found = graph.search(&data[41], 5, |_| true).unwrap();
        assert_eq!(found[0], 1041);
        let found = graph.search(&data[41], 5, |k| k != 1041).unwrap();
        assert!(!found.contains(&1041));
        assert!((1040..1044).contains(&found[0]), "{found:?}");
        // Only even keys.
        let found = graph.search(&data[7], 20, |k| k % 2 == 0).unwrap();
        assert_eq!(found.len(), 20);
        assert!(found.iter().all(|k| k % 2 == 0));
    }

    #[test]
    fn replaced_and_removed_rows_are_found_as_they_are_now() {
        let data = rows(300, 32);
        let mut graph = NeighbourGraph::new(32).unwrap();
        for (i, row) in data.iter().enumerate() {
            graph.add(i as u64, row).unwrap();
        }
        // Key 5 now holds row 200's descriptor.
        graph.add(5, &data[200]).unwrap();
        assert_eq!(graph.len(), 300);
        let found = graph.search(&data[200], 2, |_| true).unwrap();
        assert!(found.contains(&5) && found.contains(&200), "{found:?}");
        assert!(graph.remove(200).unwrap());
        assert!(!graph.remove(200).unwrap());
        assert_eq!(graph.search(&data[200], 1, |_| true).unwrap(), vec![5]);
    }

    #[test]
    fn a_saved_graph_loads_with_the_same_answers() {
        let data = rows(500, 48);
        let mut graph = NeighbourGraph::new(48).unwrap();
        for (i, row) in data.iter().enumerate() {
            graph.add(i as u64 * 7, row).unwrap();
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("graph");
        graph.save(&path).unwrap();
        let loaded = NeighbourGraph::load(&path, 48, SHORT_LENGTH).unwrap();
        assert_eq!(loaded.len(), 500);
        for q in [0, 17, 499] {
            assert_eq!(
                loaded.search(&data[q], 10, |_| true).unwrap(),
                graph.search(&data[q], 10, |_| true).unwrap()
            );
        }
        assert!(matches!(
            NeighbourGraph::load(&path, 64, SHORT_LENGTH),
            Err(GraphError::Dimension {
                expected: 64,
                found: 48
            })
        ));
        let mut more = loaded;
        more.add(1, &data[3]).unwrap();
        assert_eq!(more.len(), 501);
    }

    #[test]
    fn a_shortened_graph_finds_places_and_loads_only_where_made_alike() {
        let data = rows(1_500, 512);
        let mut graph = NeighbourGraph::shortened(512, 64).unwrap();
        assert_eq!((graph.dim(), graph.stored_length()), (512, 64));
        for (i, row) in data.iter().enumerate() {
            graph.add(i as u64, row).unwrap();
        }
        for q in [3, 400, 1_499] {
            let found = graph.search(&data[q], 4, |k| k != q as u64).unwrap();
            assert_eq!(found[0] / 4, q as u64 / 4, "{q}: {found:?}");
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("graph");
        graph.save(&path).unwrap();
        let loaded = NeighbourGraph::load(&path, 512, 64).unwrap();
        assert_eq!(
            loaded.search(&data[7], 10, |_| true).unwrap(),
            graph.search(&data[7], 10, |_| true).unwrap()
        );
        // Made at another length: refused, so that the caller rebuilds it.
        assert!(matches!(
            NeighbourGraph::load(&path, 512, 0),
            Err(GraphError::Dimension {
                expected: 512,
                found: 64
            })
        ));
        assert!(NeighbourGraph::load(&path, 512, 128).is_err());
        // Descriptors no longer than the length are stored as they are.
        assert_eq!(
            NeighbourGraph::shortened(48, 64).unwrap().stored_length(),
            48
        );
        assert_eq!(
            NeighbourGraph::shortened(512, 0).unwrap().stored_length(),
            512
        );
    }

    #[test]
    fn codes_use_the_whole_byte_range() {
        assert_eq!(code(&[0.25, -1.0, 0.0]), vec![32, -127, 0]);
        assert_eq!(code(&[0.0, 0.0]), vec![0, 0]);
        assert_eq!(code(&[f32::NAN, 1.0]), vec![0, 0]);
    }
}
