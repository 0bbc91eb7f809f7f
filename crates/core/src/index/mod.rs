//! The in-memory search index over the stored keyframes.
//!
//! It is rebuilt from sled at start and kept in step with it by the writer.
//! Descriptors live in one contiguous row-major matrix, because SCAL is a
//! scan over all of them and is bound by memory bandwidth; everything else
//! about a keyframe lives in a row-aligned table. Erasing swaps the last row
//! into the hole, so rows stay dense.
//!
//! Each row also knows its predecessor: the keyframe before it (by keyframe
//! id) in the same robot, session and map, which is what SCAL's temporal
//! context compares. Predecessor links are maintained on every change so a
//! query never has to look them up in a tree.
//!
//! The index is one type, [`Index`], whose methods are split by job:
//!
//! - `table`: the type, its row-aligned tables and the reads of one row or
//!   one map;
//! - `changes`: inserting, replacing, erasing and moving keyframes, with
//!   their predecessor links and text statistics;
//! - `eligible`: a query's eligibility rule bound to the rows, with the
//!   partition a scan visits;
//! - `places`: SLAM's verdicts, the operating point they give, and where
//!   stored keyframes are (map spacing, keyframes near a place);
//! - `paths`: the length of a map's track between two of its keyframes
//!   (the drift envelope's path);
//! - `restore`: rebuilding the index from a snapshot;
//! - `grouping`: sorting rows by map so a scoped scan reads long runs;
//! - `neighbours`: the neighbour graph (the approximate first stage of a
//!   large query) kept in step with the rows;
//! - `map_graphs`: a neighbour graph per large map, for loop queries over
//!   a robot's own map;
//! - `memory`: the view of the index that ranking reads
//!   ([`KeyframeMemory`](crate::vpr::memory::KeyframeMemory)).

mod changes;
mod eligible;
mod grouping;
mod map_graphs;
mod memory;
mod neighbours;
mod paths;
mod places;
mod restore;
mod table;
#[cfg(test)]
mod tests;

pub use eligible::{RowEligibility, PARTITION_MAX_SHARE};
pub use grouping::{
    RowGrouping, RowOrderHold, GROUP_TAIL_ROWS, GROUP_WINDOW_ROWS, REGROUP_DISPLACED_ROWS,
};
pub use map_graphs::map_graph_name;
pub use neighbours::{graph_key, GraphAdditions, PARALLEL_BACKLOG};
pub use places::OPERATING_POINT_REFRESH_S;
pub use restore::{IndexRestore, RestoreError};
pub use table::{Index, MapKey, RowMeta};
