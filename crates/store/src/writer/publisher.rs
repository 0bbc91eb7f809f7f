//! The second stage of the writer, the publisher: takes each group that
//! is durable in sled into the in-memory index, then answers its callers.
//!
//! It has a thread of its own because it must wait for the index's write
//! lock, which every running scan holds for reading: on its own thread
//! that wait overlaps the writer staging and flushing the next group
//! instead of adding to every insert's latency. Being the index's only
//! writer, it also regroups the index's rows by map when that is due, and
//! adds the keyframes waiting to enter the neighbour graph after the
//! group's callers are answered (under the read lock, while queries go
//! on), crossing them off under the write lock that publishes the next
//! group: a waiting write lock stops new scans from starting until the
//! scans in progress end, so at a fleet's insert rate every write lock
//! taken costs the second core part of a scan.

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::mpsc::TryRecvError;
use std::sync::Arc;

use humem_core::index::{GraphAdditions, Index, RowGrouping};
use parking_lot::RwLock;

use super::queue::{LogReply, Reply};
use super::staging::IndexChange;
use crate::checkpoint::Checkpoints;
use crate::error::StoreError;
use crate::mutation::{LogApplied, MutationOutcome};
use crate::placement::DescriptorPlacement;

/// A job's answer, sent after its group's flush.
pub(super) enum Answer {
    Change(Reply, Result<MutationOutcome, StoreError>),
    Log(LogReply, LogApplied),
}

/// A group that is durable in sled, waiting to be published to the index.
pub(super) struct Published {
    pub(super) changes: Vec<IndexChange>,
    pub(super) answers: Vec<Answer>,
    /// The last write sequence of the group.
    pub(super) sequence: u64,
    /// Journal keys the group wrote.
    pub(super) journaled: u64,
}

/// Steps of a write slower than this, in milliseconds, are logged at
/// debug level (`RUST_LOG=humem_store=debug`): what an insert's tail
/// latency is made of.
pub(super) const SLOW_MS: f64 = 50.0;

/// Groups flushed but not yet published, at most: the writer flushes the
/// next group while the publisher waits for the index, and blocks when
/// this many are behind, so memory stays bounded.
pub(super) const PUBLISH_BACKLOG: usize = 2;

/// Waiting keyframe entries (the store's graph's and the maps') added at
/// a time: about a millisecond of a core each at a million keyframes, and
/// a fleet's steady inserts are added on this thread alone
/// ([`humem_core::index::PARALLEL_BACKLOG`]), so a batch takes a few tens
/// of milliseconds, the longest a group of writes waits behind it.
const GRAPH_BATCH: usize = 16;

/// The second stage of the writer: takes each flushed group, in order,
/// into the in-memory index under its write lock, and only then answers
/// its callers. Waiting for the write lock means waiting out the scans
/// that hold the read lock; on its own thread, that wait overlaps the
/// writer staging and flushing the next group instead of adding to it.
pub(super) struct Publisher {
    pub(super) index: Arc<RwLock<Index>>,
    /// The sequence the index reflects, published with each group.
    pub(super) applied: Arc<AtomicU64>,
    pub(super) checkpoints: Arc<Checkpoints>,
    /// Moves the descriptors out of memory once the store is large.
    pub(super) placement: Arc<DescriptorPlacement>,
    /// Groupings put off in a row because a query's pass held the rows'
    /// order ([`MAX_DEFERRED_GROUPINGS`]).
    pub(super) deferred: AtomicU32,
}

/// Groups of writes after which a due grouping goes ahead although a
/// query's exact pass asks that rows keep their order (the pass then
/// starts over): on a server whose every query is an exact pass
/// (`vpr.exact`), some pass always runs, and the rows would never be
/// grouped.
const MAX_DEFERRED_GROUPINGS: u32 = 64;

impl Publisher {
    /// Groups the index's newest rows by map once enough have come
    /// ([`Index::group_tail_if_due`]), then sorts again at most one window
    /// of older rows that erasures have scattered
    /// ([`Index::regroup_window_if_due`]), unless a snapshot is being
    /// written or a query's exact pass is under way
    /// ([`Index::row_order_held`], for at most [`MAX_DEFERRED_GROUPINGS`]
    /// groups of writes in a row): both read the rows in pieces and rely
    /// on them not moving.
    /// The new order and the copies of the rows are made under the read
    /// lock, while queries go on; only putting them in place takes the
    /// write lock. This thread is the index's only writer, so nothing
    /// changes in between (and a plan that found a change would do
    /// nothing).
    fn group_rows(&self) {
        let (tail_due, _) = {
            let index = self.index.read();
            let due = (
                index.ungrouped_rows() >= humem_core::index::GROUP_TAIL_ROWS,
                index.window_due().is_some(),
            );
            if due == (false, false) {
                return;
            }
            if index.row_order_held()
                && self.deferred.fetch_add(1, Ordering::Relaxed) < MAX_DEFERRED_GROUPINGS
            {
                return;
            }
            self.deferred.store(0, Ordering::Relaxed);
            due
        };
        let Some(_no_snapshot) = self.checkpoints.writing.try_lock() else {
            return;
        };
        if tail_due {
            self.apply_planned("grouped the newest rows by map", |index| {
                index.plan_tail_grouping()
            });
        }
        self.apply_planned("sorted again a window scattered by erasures", |index| {
            index.plan_window_regrouping()
        });
    }

    /// Plans a grouping under the read lock and applies it under the
    /// write lock.
    fn apply_planned(&self, what: &str, plan: impl FnOnce(&Index) -> Option<RowGrouping>) {
        let started = std::time::Instant::now();
        let Some(plan) = plan(&self.index.read()) else {
            return;
        };
        let planned = started.elapsed();
        let rows = self.index.write().apply_grouping(plan);
        tracing::debug!(
            rows,
            planned_ms = planned.as_secs_f64() * 1e3,
            applied_ms = (started.elapsed() - planned).as_secs_f64() * 1e3,
            "{what}"
        );
    }

    /// Publishes each group as it comes; between groups, and after each,
    /// adds keyframes waiting to enter the neighbour graph, a batch at a
    /// time, so a restart's backlog never holds up a write for long. A
    /// batch's keyframes are crossed off under the write lock that
    /// publishes the next group, or under one of their own where no group
    /// waits, so that a fleet's inserts cost one write lock a group.
    pub(super) fn run(self, groups: std::sync::mpsc::Receiver<Published>) {
        let mut added: Option<GraphAdditions> = None;
        loop {
            let busy = added.is_some() || self.index.read().neighbour_graph_waiting() > 0;
            let group = if busy {
                match groups.try_recv() {
                    Ok(group) => Some(group),
                    Err(TryRecvError::Empty) => None,
                    Err(TryRecvError::Disconnected) => {
                        self.cross_off(added.take());
                        return;
                    }
                }
            } else {
                match groups.recv() {
                    Ok(group) => Some(group),
                    Err(_) => return,
                }
            };
            match group {
                Some(group) => self.publish(group, added.take()),
                None => self.cross_off(added.take()),
            }
            added = self.add_waiting_to_graph();
        }
    }

    /// Crosses the graph's `added` keyframes off under a write lock of
    /// their own, where no group's publish takes them.
    fn cross_off(&self, added: Option<GraphAdditions>) {
        if let Some(added) = added {
            self.index.write().graph_added(added);
        }
    }

    /// Adds up to [`GRAPH_BATCH`] waiting keyframes to the neighbour graph
    /// under the index's read lock, while queries go on; what it added,
    /// to be crossed off under the write lock before anything else
    /// changes the index (this thread is its only writer). None where
    /// nothing waits.
    fn add_waiting_to_graph(&self) -> Option<GraphAdditions> {
        let index = self.index.read();
        if index.neighbour_graph_waiting() == 0 {
            return None;
        }
        let started = std::time::Instant::now();
        let added = index.add_waiting_to_graph(GRAPH_BATCH);
        let added_ms = started.elapsed().as_secs_f64() * 1e3;
        if added_ms >= SLOW_MS {
            tracing::debug!(added_ms, "slow batch of graph additions");
        }
        Some(added)
    }

    /// Takes `group` into the index under one write lock, crossing off
    /// the graph's `added` keyframes first (they were added to the index
    /// as it was before the group), then answers its callers.
    fn publish(&self, group: Published, added: Option<GraphAdditions>) {
        let Published {
            changes,
            answers,
            sequence,
            journaled,
        } = group;
        let started = std::time::Instant::now();
        let (store_keyframes, store_verdicts) = {
            let mut index = self.index.write();
            let locked_ms = started.elapsed().as_secs_f64() * 1e3;
            if locked_ms >= SLOW_MS {
                tracing::debug!(locked_ms, "waited for the index's write lock");
            }
            if let Some(added) = added {
                index.graph_added(added);
            }
            // The group's keyframes wait to enter the neighbour graph
            // (searches score them exactly meanwhile), so that its callers
            // are answered before they enter it.
            for change in changes {
                match change {
                    IndexChange::Upsert(kf) => {
                        index.upsert(kf);
                    }
                    IndexChange::Remove(key) => {
                        index.remove(&key);
                    }
                    IndexChange::Move(key, pose, map) => {
                        index.update_pose(&key, pose, map);
                    }
                    IndexChange::Verdict(verdict) => {
                        index.record_verdict(verdict);
                    }
                }
            }
            self.placement.apply(&mut index);
            self.applied.store(sequence, Ordering::Release);
            (index.len() as u64, index.verdicts().len() as u64)
        };
        self.checkpoints.journaled(journaled);
        let counted = |outcome: Result<MutationOutcome, StoreError>| {
            outcome.map(|mut o| {
                o.store_keyframes = store_keyframes;
                o.store_verdicts = store_verdicts;
                o
            })
        };
        for answer in answers {
            match answer {
                Answer::Change(reply, outcome) => {
                    let _ = reply.send(counted(outcome));
                }
                Answer::Log(reply, mut applied) => {
                    applied.results = applied.results.into_iter().map(counted).collect();
                    let _ = reply.send(applied);
                }
            }
        }
        // After the answers: the callers do not wait for it.
        self.group_rows();
    }
}
