//! The single writer of the store, with group commit.
//!
//! Changes arrive on a bounded queue (a full queue is reported at once, so
//! callers push back instead of growing memory). The writer takes every
//! change that is waiting, applies each to sled in order and flushes once;
//! only after the flush is the group taken into the in-memory index and its
//! callers answered. That last step is a second thread, the publisher,
//! because it must wait for the index's write lock, which every running
//! scan holds for reading: on its own thread that wait overlaps the next
//! group's staging and flush instead of adding to every insert's latency.
//! One thread owns all writes to sled and one all changes to the index,
//! both in the same order, and no change is computed from a stale view
//! (staging reads sled, never the index).
//!
//! Its parts, one job each, none importing this module (it only maps them
//! and re-exports what the rest of the crate uses):
//!
//! - `queue`: the jobs and the sending side ([`WriterHandle`]);
//! - `trees`: the sled trees written ([`Trees`]);
//! - `staging`: what each change writes to sled and to the index,
//!   worked out from sled;
//! - `commit`: the writer thread (group commit, transactions, rollback of
//!   a failed flush, exports) and [`spawn`];
//! - `publisher`: the second thread, taking flushed groups into the index
//!   and answering their callers.

mod commit;
mod publisher;
mod queue;
mod staging;
mod trees;

pub(crate) use commit::spawn;
pub(crate) use queue::WriterHandle;
pub(crate) use trees::Trees;
