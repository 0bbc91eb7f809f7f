//! The store's layout in sled: the names of its trees, the keys of its
//! meta tree, and [`STORE_FORMAT`], the version of that layout.
//!
//! Opening, the writer, the export and the read-only look-ups all name
//! the same trees and meta keys; they take them from this one leaf module
//! so that the layout is written down once. (The journal's tree and meta
//! keys are the journal's own, in [`crate::journal`].)

/// Keyframe records by key ([`crate::codec::encode_key`] → record).
pub(crate) const KEYFRAMES_TREE: &str = "keyframes";
/// Verdicts by query keyframe ([`crate::codec::verdict_key`] → record).
pub(crate) const VERDICTS_TREE: &str = "verdicts";
/// The same verdicts by candidate keyframe ([`crate::codec::verdict_candidate_key`]
/// → the verdicts tree's key), so erasing a candidate finds its verdicts.
pub(crate) const VERDICTS_BY_CANDIDATE_TREE: &str = "verdicts_by_candidate";
pub(crate) const META_TREE: &str = "meta";
pub(crate) const META_FORMAT: &[u8] = b"format_version";
pub(crate) const META_DIM: &[u8] = b"descriptor_dim";
/// Position of the last replicated-log entry applied (cluster mode).
pub(crate) const META_LOG_POSITION: &[u8] = b"log_position";
/// When the store was last opened for writing (Unix seconds, big-endian
/// u64): written and flushed by every open (see `settle::settle_log`).
pub(crate) const META_OPENED: &[u8] = b"opened_at";

/// Version of the store's layout, recorded in its meta tree. 3 added the
/// write journal (and the index snapshot beside the tree) to version 2's
/// records; a build that predates the journal refuses a version 3 store
/// instead of writing to it unjournaled.
pub const STORE_FORMAT: u32 = 3;
