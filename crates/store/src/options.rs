//! [`StoreOptions`]: how a store is opened (descriptor length, queue
//! depth, snapshot spacing, disk reserve, descriptor placement, sled's
//! cache), with their defaults.
//!
//! Kept apart from the opening itself ([`crate::open`]) so that the
//! settings, which the server reads from its configuration, are one short
//! module to read.

use crate::disk;
use crate::placement::FileRule;

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
    /// Whether the index keeps a neighbour graph over the descriptors (the
    /// approximate first stage of queries over many keyframes), saved
    /// beside its snapshot.
    pub neighbour_graph: bool,
    /// Length the neighbour graph shortens longer descriptors to (0: their
    /// own length); see [`humem_core::engine::graph::SHORT_LENGTH`].
    pub neighbour_graph_length: usize,
    /// Keyframes from which a map gets a neighbour graph of its own beside
    /// the store's, for loop queries over it (0: none; the server sets
    /// `vpr.approximate_from`). Only with `neighbour_graph`.
    pub map_graphs_from: usize,
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
            neighbour_graph: false,
            neighbour_graph_length: humem_core::engine::graph::SHORT_LENGTH,
            map_graphs_from: 0,
        }
    }
}

/// Default of [`StoreOptions::snapshot_every`]: replaying this many
/// changes at open costs well under a second.
pub const DEFAULT_SNAPSHOT_EVERY: u64 = 100_000;
