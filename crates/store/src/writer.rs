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

use std::collections::HashSet;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use parking_lot::RwLock;
use sled::transaction::{ConflictableTransactionError, TransactionError, Transactional};
use tokio::sync::{mpsc, oneshot};

use crate::checkpoint::Checkpoints;
use crate::codec::{self, decode_record, encode_key, encode_record};
use crate::error::StoreError;
use crate::export::{self, ExportHeader};
use crate::journal;
use crate::layout::{META_DIM, META_LOG_POSITION, STORE_FORMAT};
use crate::mutation::{LogApplied, LogEntry, Mutation, MutationOutcome, PoseUpdate};
use crate::placement::DescriptorPlacement;
use crate::robot_counts::{self, Deltas, RobotCounts};
use crate::rollback::{Counters, Rollback, TreeName};
use humem_core::index::{Index, MapKey, RowGrouping};
use humem_core::keyframe::{KeyframeKey, Pose, SemanticKeyframe, SessionKey};
use humem_core::observe::SharedObserver;
use humem_core::verdict::Verdict;

/// Most changes committed by one flush.
const MAX_GROUP: usize = 256;

type Reply = oneshot::Sender<Result<MutationOutcome, StoreError>>;
type LogReply = oneshot::Sender<LogApplied>;

/// What the writer is asked to do.
enum Job {
    /// One change, answered with its outcome.
    Change(Mutation, Reply),
    /// Entries of a replicated log, applied in order, each recording its
    /// position; stops at the first that cannot be applied now.
    Log(Vec<LogEntry>, LogReply),
    /// Write the whole store to a file, after the group it arrived in.
    Export(std::path::PathBuf, ExportReply),
}

type ExportReply = oneshot::Sender<Result<ExportHeader, StoreError>>;

impl Job {
    /// Changes this job holds, for the queue depth.
    fn len(&self) -> usize {
        match self {
            Job::Change(..) => 1,
            Job::Log(entries, _) => entries.len(),
            Job::Export(..) => 0,
        }
    }
}

/// Whether a change adds data (refused near a full disk; removals are not).
fn adds_data(mutation: &Mutation) -> bool {
    matches!(
        mutation,
        Mutation::Insert(_) | Mutation::InsertWithin { .. } | Mutation::UpdatePoses { .. }
    )
}

/// A job's answer, sent after its group's flush.
enum Answer {
    Change(Reply, Result<MutationOutcome, StoreError>),
    Log(LogReply, LogApplied),
}

/// The trees the writer writes.
pub(crate) struct Trees {
    pub db: sled::Db,
    pub keyframes: sled::Tree,
    pub meta: sled::Tree,
    pub journal: sled::Tree,
    pub verdicts: sled::Tree,
    pub verdicts_by_candidate: sled::Tree,
}

impl Trees {
    /// The tree a rollback record names.
    fn named(&self, name: TreeName) -> &sled::Tree {
        match name {
            TreeName::Keyframes => &self.keyframes,
            TreeName::Journal => &self.journal,
            TreeName::Meta => &self.meta,
            TreeName::Verdicts => &self.verdicts,
            TreeName::VerdictsByCandidate => &self.verdicts_by_candidate,
        }
    }
}

/// Sending side of the writer's queue.
#[derive(Clone)]
pub(crate) struct WriterHandle {
    queue: mpsc::Sender<Job>,
    capacity: usize,
    observer: SharedObserver,
}

/// The writer's queue, as observers see it.
const QUEUE: &str = "store_writer";

impl WriterHandle {
    pub async fn submit(&self, mutation: Mutation) -> Result<MutationOutcome, StoreError> {
        let (reply, answer) = oneshot::channel();
        self.send(Job::Change(mutation, reply))?;
        answer.await.map_err(|_| StoreError::WriterGone)?
    }

    pub async fn export(&self, file: std::path::PathBuf) -> Result<ExportHeader, StoreError> {
        let (reply, answer) = oneshot::channel();
        self.send(Job::Export(file, reply))?;
        answer.await.map_err(|_| StoreError::WriterGone)?
    }

    pub async fn submit_log(&self, entries: Vec<LogEntry>) -> Result<LogApplied, StoreError> {
        let (reply, answer) = oneshot::channel();
        self.send(Job::Log(entries, reply))?;
        answer.await.map_err(|_| StoreError::WriterGone)
    }

    fn send(&self, job: Job) -> Result<(), StoreError> {
        let depth = job.len() as i64;
        // Counted before sending, so the writer's decrement never comes first.
        self.observer.depth_changed(QUEUE, depth);
        self.queue.try_send(job).map_err(|e| {
            self.observer.depth_changed(QUEUE, -depth);
            match e {
                mpsc::error::TrySendError::Full(_) => StoreError::QueueFull {
                    capacity: self.capacity,
                },
                mpsc::error::TrySendError::Closed(_) => StoreError::WriterGone,
            }
        })
    }
}

/// Starts the writer thread. It ends when every handle is dropped.
pub(crate) fn spawn(
    trees: Trees,
    checkpoints: Arc<Checkpoints>,
    placement: Arc<DescriptorPlacement>,
    capacity: usize,
    observer: SharedObserver,
) -> WriterHandle {
    let capacity = capacity.max(1);
    let (queue, receiver) = mpsc::channel(capacity);
    let (dim, keyframes, robots) = {
        let index = checkpoints.index.read();
        (index.dim(), index.len() as u64, RobotCounts::of(&index))
    };
    let (publisher, groups) = std::sync::mpsc::sync_channel(PUBLISH_BACKLOG);
    let stage = Publisher {
        index: checkpoints.index.clone(),
        applied: checkpoints.applied.clone(),
        checkpoints: checkpoints.clone(),
        placement,
    };
    let writer = Writer {
        trees,
        publisher,
        dim,
        sequence: checkpoints.applied.load(Ordering::Acquire),
        keyframes,
        checkpoints,
        observer: observer.clone(),
        rollback: Rollback::begin(Counters {
            dim,
            sequence: 0,
            keyframes,
        }),
        robots,
        group_robots: Deltas::new(),
    };
    std::thread::Builder::new()
        .name("humem-store-publisher".into())
        .spawn(move || stage.run(groups))
        .expect("spawning the store publisher thread");
    std::thread::Builder::new()
        .name("humem-store-writer".into())
        .spawn(move || writer.run(receiver))
        .expect("spawning the store writer thread");
    WriterHandle {
        queue,
        capacity,
        observer,
    }
}

/// One mutation's writes and outcome, gathered before its batch is applied.
#[derive(Default)]
struct Staged {
    batch: sled::Batch,
    /// The sled keys the batch writes or removes, for the journal.
    keys: Vec<Vec<u8>>,
    /// Keyframes the change adds to the store (negative: removes).
    added: i64,
    /// The same, per robot.
    added_by_robot: Deltas,
    outcome: MutationOutcome,
    changes: Vec<IndexChange>,
    /// Writes to the verdicts tree, and their count.
    verdicts: sled::Batch,
    /// Writes to the by-candidate tree of the verdicts.
    verdicts_by_candidate: sled::Batch,
    verdict_writes: usize,
    /// The keys the two verdict batches write or remove, for the rollback.
    verdict_keys: Vec<Vec<u8>>,
    by_candidate_keys: Vec<Vec<u8>>,
    /// Keys of the keyframes the change removes, whose verdicts go too.
    removed: Vec<Vec<u8>>,
}

impl Staged {
    /// Stages the removal of a stored keyframe.
    fn remove(&mut self, bytes: Vec<u8>, key: KeyframeKey) {
        self.batch.remove(bytes.clone());
        self.removed.push(bytes.clone());
        self.keys.push(bytes);
        self.added -= 1;
        *self.added_by_robot.entry(key.robot_id.clone()).or_default() -= 1;
        self.outcome.affected += 1;
        self.changes.push(IndexChange::Remove(key));
    }

    /// Stages a write to the verdicts tree.
    fn put_verdict(&mut self, key: Vec<u8>, value: Vec<u8>) {
        self.verdicts.insert(key.clone(), value);
        self.verdict_keys.push(key);
    }

    /// Stages a removal from the verdicts tree.
    fn remove_verdict(&mut self, key: Vec<u8>) {
        self.verdicts.remove(key.clone());
        self.verdict_keys.push(key);
    }

    /// Stages a write to the by-candidate tree.
    fn put_by_candidate(&mut self, key: Vec<u8>, value: Vec<u8>) {
        self.verdicts_by_candidate.insert(key.clone(), value);
        self.by_candidate_keys.push(key);
    }

    /// Stages a removal from the by-candidate tree.
    fn remove_by_candidate(&mut self, key: Vec<u8>) {
        self.verdicts_by_candidate.remove(key.clone());
        self.by_candidate_keys.push(key);
    }
}

/// A change to the index, made visible after the flush.
enum IndexChange {
    Upsert(SemanticKeyframe),
    Remove(KeyframeKey),
    Move(KeyframeKey, Pose, Option<u64>),
    /// A verdict to record (the removals of verdicts follow the removals of
    /// their keyframes in the index itself).
    Verdict(Verdict),
}

struct Writer {
    trees: Trees,
    /// Hands each flushed group to the [`Publisher`].
    publisher: std::sync::mpsc::SyncSender<Published>,
    /// Descriptor length of the store; 0 until the first keyframe.
    dim: usize,
    /// The last write sequence used.
    sequence: u64,
    /// Keyframes in sled after the last staged change.
    keyframes: u64,
    checkpoints: Arc<Checkpoints>,
    observer: SharedObserver,
    /// What the group being staged replaced, put back if its flush fails.
    rollback: Rollback,
    /// Keyframes per robot in sled after the last staged change.
    robots: RobotCounts,
    /// The changes to `robots` of the group being staged, taken back if
    /// its flush fails.
    group_robots: Deltas,
}

/// A group that is durable in sled, waiting to be published to the index.
struct Published {
    changes: Vec<IndexChange>,
    answers: Vec<Answer>,
    /// The last write sequence of the group.
    sequence: u64,
    /// Journal keys the group wrote.
    journaled: u64,
}

/// Groups flushed but not yet published, at most: the writer flushes the
/// next group while the publisher waits for the index, and blocks when
/// this many are behind, so memory stays bounded.
const PUBLISH_BACKLOG: usize = 2;

/// The second stage of the writer: takes each flushed group, in order,
/// into the in-memory index under its write lock, and only then answers
/// its callers. Waiting for the write lock means waiting out the scans
/// that hold the read lock; on its own thread, that wait overlaps the
/// writer staging and flushing the next group instead of adding to it.
struct Publisher {
    index: Arc<RwLock<Index>>,
    /// The sequence the index reflects, published with each group.
    applied: Arc<AtomicU64>,
    checkpoints: Arc<Checkpoints>,
    /// Moves the descriptors out of memory once the store is large.
    placement: Arc<DescriptorPlacement>,
}

impl Publisher {
    /// Groups the index's newest rows by map once enough have come
    /// ([`Index::group_tail_if_due`]), then sorts again at most one window
    /// of older rows that erasures have scattered
    /// ([`Index::regroup_window_if_due`]), unless a snapshot is being
    /// written: it reads the rows in pieces and relies on them not moving.
    /// The new order and the copies of the rows are made under the read
    /// lock, while queries go on; only putting them in place takes the
    /// write lock. This thread is the index's only writer, so nothing
    /// changes in between (and a plan that found a change would do
    /// nothing).
    fn group_rows(&self) {
        let (tail_due, window_due) = {
            let index = self.index.read();
            (
                index.ungrouped_rows() >= humem_core::index::GROUP_TAIL_ROWS,
                index.window_due().is_some(),
            )
        };
        if !tail_due && !window_due {
            return;
        }
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

    fn run(self, groups: std::sync::mpsc::Receiver<Published>) {
        for group in groups {
            self.publish(group);
        }
    }

    fn publish(&self, group: Published) {
        let Published {
            changes,
            answers,
            sequence,
            journaled,
        } = group;
        let (store_keyframes, store_verdicts) = {
            let mut index = self.index.write();
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

impl Writer {
    fn run(mut self, mut receiver: mpsc::Receiver<Job>) {
        while let Some(first) = receiver.blocking_recv() {
            let mut group = vec![first];
            while group.len() < MAX_GROUP {
                match receiver.try_recv() {
                    Ok(next) => group.push(next),
                    Err(_) => break,
                }
            }
            let depth: usize = group.iter().map(Job::len).sum();
            self.observer.depth_changed(QUEUE, -(depth as i64));
            self.commit(group);
        }
        if let Err(e) = self.trees.db.flush() {
            tracing::error!(error = %e, "final flush of the store failed");
        }
    }

    fn commit(&mut self, group: Vec<Job>) {
        // Near a full disk, what adds data is refused before sled sees it
        // (sled does not survive ENOSPC); removals go on, they make room.
        let short = self.checkpoints.disk.room_for(0).err();
        self.rollback = Rollback::begin(self.counters());
        self.group_robots.clear();
        let mut changes = Vec::new();
        let mut answers = Vec::with_capacity(group.len());
        let mut journaled = 0;
        let mut exports = Vec::new();
        for job in group {
            match job {
                Job::Change(mutation, reply) => {
                    let outcome = match short {
                        Some(short) if adds_data(&mutation) => Err(short.into()),
                        _ => self.stage(mutation, None, &mut changes, &mut journaled),
                    };
                    answers.push(Answer::Change(reply, outcome));
                }
                Job::Log(entries, reply) => {
                    let applied = self.stage_log(entries, short, &mut changes, &mut journaled);
                    answers.push(Answer::Log(reply, applied));
                }
                Job::Export(file, reply) => exports.push((file, reply)),
            }
        }
        self.flush_group(changes, answers, journaled);
        // After the flush (or the rollback of a failed one) the trees hold
        // exactly the changes acknowledged so far.
        for (file, reply) in exports {
            let _ = reply.send(self.export(&file));
        }
    }

    /// Writes the store to `file` as it is in sled now, if the disk has
    /// room for about sled's size above the reserve (sled does not survive
    /// a full disk, so an export must never be what fills it).
    fn export(&self, file: &std::path::Path) -> Result<ExportHeader, StoreError> {
        let estimate = self.trees.db.size_on_disk()?;
        self.checkpoints.disk.room_for(estimate)?;
        let position = self.trees.meta.get(META_LOG_POSITION)?.map_or(0, |v| {
            u64::from_be_bytes(v.as_ref().try_into().unwrap_or([0; 8]))
        });
        let header = ExportHeader {
            format: export::EXPORT_FORMAT,
            store_format: STORE_FORMAT,
            dim: self.dim as u32,
            log_position: position,
            keyframes: self.keyframes,
            verdicts: self.trees.verdicts.len() as u64,
        };
        let out = std::fs::File::create(file)
            .map_err(|e| StoreError::Export(format!("{}: {e}", file.display())))?;
        let trees = [
            (export::TREES[0].0, &self.trees.keyframes),
            (export::TREES[1].0, &self.trees.verdicts),
            (export::TREES[2].0, &self.trees.verdicts_by_candidate),
        ];
        export::write(header, &trees, &out)?;
        out.sync_all()
            .map_err(|e| StoreError::Export(format!("{}: {e}", file.display())))?;
        Ok(header)
    }

    /// Flushes a staged group and hands it to the publisher, or rolls it
    /// back and fails its callers.
    fn flush_group(&mut self, changes: Vec<IndexChange>, answers: Vec<Answer>, journaled: u64) {
        if let Err(e) = self.flush() {
            tracing::error!(error = %e, "flushing the store failed; its group is rolled back");
            self.roll_back();
            for answer in answers {
                let error = StoreError::Flush(e.to_string());
                match answer {
                    Answer::Change(reply, _) => {
                        let _ = reply.send(Err(error));
                    }
                    Answer::Log(reply, _) => {
                        let _ = reply.send(LogApplied {
                            results: Vec::new(),
                            stopped: Some(error),
                        });
                    }
                }
            }
            return;
        }
        let group = Published {
            changes,
            answers,
            sequence: self.sequence,
            journaled,
        };
        if self.publisher.send(group).is_err() {
            tracing::error!("the index publisher is gone");
        }
    }

    /// The writer's counters, as a rollback restores them.
    fn counters(&self) -> Counters {
        Counters {
            dim: self.dim,
            sequence: self.sequence,
            keyframes: self.keyframes,
        }
    }

    /// Flushes sled, or fails as a test asked (see
    /// [`Checkpoints::flush_faults`]).
    fn flush(&self) -> Result<(), StoreError> {
        let faults = &self.checkpoints.flush_faults;
        if faults
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| n.checked_sub(1))
            .is_ok()
        {
            return Err(StoreError::Flush("injected flush failure".into()));
        }
        self.trees.db.flush()?;
        Ok(())
    }

    /// Puts back everything the group wrote to sled, after its flush
    /// failed: the trees and counters return to where the index is, and
    /// the next flush persists that instead of the failed group.
    fn roll_back(&mut self) {
        let now = self.counters();
        let rollback = std::mem::replace(&mut self.rollback, Rollback::begin(now));
        let before = rollback.before;
        let trees = &self.trees;
        let undone = rollback.undo(|name| trees.named(name));
        match undone {
            Ok(keys) => tracing::warn!(keys, "rolled back a group whose flush failed"),
            // sled's in-memory trees refused a write: nothing in this
            // process can be trusted to match the index any more.
            Err(e) => {
                tracing::error!(error = %e, "rolling back a failed group failed; restart the service to reload the index from disk")
            }
        }
        self.dim = before.dim;
        self.sequence = before.sequence;
        self.keyframes = before.keyframes;
        self.robots.add(&std::mem::take(&mut self.group_robots), -1);
    }

    /// Records the value `key` of `name` holds before the group writes it.
    fn remember(&mut self, name: TreeName, key: &[u8]) -> Result<(), StoreError> {
        self.rollback.remember(name, self.trees.named(name), key)?;
        Ok(())
    }
    /// Stages log entries in order, each recording its position. An entry
    /// refused for what it is (a [`StoreError::is_refusal`]) is refused on
    /// every replica alike, so its position is recorded and the next one
    /// goes on; any other failure (a full disk, sled) stops the batch, so
    /// the log is never applied out of order.
    fn stage_log(
        &mut self,
        entries: Vec<LogEntry>,
        short: Option<crate::disk::Short>,
        changes: &mut Vec<IndexChange>,
        journaled: &mut u64,
    ) -> LogApplied {
        let mut applied = LogApplied::default();
        for LogEntry { position, mutation } in entries {
            if let Some(short) = short.filter(|_| adds_data(&mutation)) {
                applied.stopped = Some(short.into());
                break;
            }
            match self.stage(mutation, Some(position), changes, journaled) {
                Ok(outcome) => applied.results.push(Ok(outcome)),
                Err(refused) if refused.is_refusal() => match self.record_position(position) {
                    Ok(()) => applied.results.push(Err(refused)),
                    Err(e) => {
                        applied.stopped = Some(e);
                        break;
                    }
                },
                Err(e) => {
                    applied.stopped = Some(e);
                    break;
                }
            }
        }
        applied
    }

    /// Records the log position of a change that wrote nothing else.
    fn record_position(&mut self, position: u64) -> Result<(), StoreError> {
        self.remember(TreeName::Meta, META_LOG_POSITION)?;
        self.trees
            .meta
            .insert(META_LOG_POSITION, &position.to_be_bytes())?;
        Ok(())
    }

    /// Stages one mutation: checks it, applies its writes to sled as one
    /// transaction with its journal entry and, for a log entry, its log
    /// position (not yet flushed), and adds its
    /// index changes to `changes` (made visible after the group's flush).
    /// A change that fails writes nothing.
    fn stage(
        &mut self,
        mutation: Mutation,
        position: Option<u64>,
        changes: &mut Vec<IndexChange>,
        journaled: &mut u64,
    ) -> Result<MutationOutcome, StoreError> {
        let mut staged = Staged::default();
        match mutation {
            Mutation::Insert(keyframes) => self.stage_insert(keyframes, None, &mut staged)?,
            Mutation::InsertWithin {
                keyframes,
                max_per_robot,
            } => self.stage_insert(keyframes, Some(max_per_robot), &mut staged)?,
            Mutation::Erase {
                session,
                keyframe_ids,
            } => self.stage_erase(&session, keyframe_ids, &mut staged)?,
            Mutation::ResetSession(session) => self.stage_reset_session(&session, &mut staged)?,
            Mutation::ResetMap(map) => self.stage_reset_map(&map, &mut staged)?,
            Mutation::UpdatePoses { session, updates } => {
                self.stage_pose_updates(&session, updates, &mut staged)?
            }
            Mutation::ReportVerdict(verdict) => self.stage_verdict(verdict, &mut staged)?,
        }
        self.stage_verdict_cascade(&mut staged)?;
        if staged.keys.is_empty() && staged.verdict_writes == 0 {
            if let Some(position) = position {
                self.record_position(position)?;
            }
            return Ok(staged.outcome);
        }
        // Only keyframe changes are journaled (the index snapshot replays
        // them); verdicts are read whole from their tree at open.
        let journaled_change = !staged.keys.is_empty();
        let sequence = self.sequence + u64::from(journaled_change);
        let keyframes = self.keyframes.saturating_add_signed(staged.added);
        let journal_entry = journal::Entry {
            keyframes,
            keys: std::mem::take(&mut staged.keys),
        };
        let entry = postcard::to_allocvec(&journal_entry)
            .map_err(|e| StoreError::Journal(e.to_string()))?;
        let key = journal::key(sequence);
        for written in &journal_entry.keys {
            self.remember(TreeName::Keyframes, written)?;
        }
        if journaled_change {
            self.remember(TreeName::Journal, &key)?;
        }
        for written in &staged.verdict_keys {
            self.remember(TreeName::Verdicts, written)?;
        }
        for written in &staged.by_candidate_keys {
            self.remember(TreeName::VerdictsByCandidate, written)?;
        }
        if position.is_some() {
            self.remember(TreeName::Meta, META_LOG_POSITION)?;
        }
        (
            &self.trees.keyframes,
            &self.trees.journal,
            &self.trees.meta,
            &self.trees.verdicts,
            &self.trees.verdicts_by_candidate,
        )
            .transaction(|(keyframes, journal, meta, verdicts, by_candidate)| {
                keyframes.apply_batch(&staged.batch)?;
                if journaled_change {
                    journal.insert(&key, entry.as_slice())?;
                }
                verdicts.apply_batch(&staged.verdicts)?;
                by_candidate.apply_batch(&staged.verdicts_by_candidate)?;
                if let Some(position) = position {
                    meta.insert(META_LOG_POSITION, &position.to_be_bytes())?;
                }
                Ok::<_, ConflictableTransactionError<()>>(())
            })
            .map_err(|e| match e {
                TransactionError::Storage(e) => StoreError::Sled(e),
                TransactionError::Abort(()) => StoreError::Journal("transaction aborted".into()),
            })?;
        self.sequence = sequence;
        self.keyframes = keyframes;
        self.robots.add(&staged.added_by_robot, 1);
        robot_counts::merge(&mut self.group_robots, &staged.added_by_robot);
        *journaled += staged.changes.len() as u64;
        changes.extend(staged.changes);
        Ok(staged.outcome)
    }

    /// Records a verdict, whose two keyframes must be stored.
    fn stage_verdict(&self, verdict: Verdict, staged: &mut Staged) -> Result<(), StoreError> {
        for (role, key) in [("query", &verdict.query), ("candidate", &verdict.candidate)] {
            if !self.trees.keyframes.contains_key(encode_key(key))? {
                return Err(StoreError::UnknownKeyframe {
                    role,
                    key: key.clone(),
                });
            }
        }
        let key = codec::verdict_key(&verdict);
        if self.trees.verdicts.contains_key(&key)? {
            staged.outcome.replaced += 1;
        } else {
            staged.outcome.affected += 1;
        }
        staged.put_verdict(key.clone(), codec::encode_verdict(&verdict));
        staged.put_by_candidate(codec::verdict_candidate_key(&verdict), key);
        staged.verdict_writes += 1;
        staged.changes.push(IndexChange::Verdict(verdict));
        Ok(())
    }

    /// Removes the verdicts naming any keyframe the change removes, as query
    /// (a prefix range of the verdicts tree) or as candidate (one of the
    /// by-candidate tree).
    fn stage_verdict_cascade(&self, staged: &mut Staged) -> Result<(), StoreError> {
        for removed in std::mem::take(&mut staged.removed) {
            for item in self.trees.verdicts.scan_prefix(&removed).keys() {
                let key = item?;
                let twin = codec::verdict_twin_key(&key, removed.len());
                staged.remove_verdict(key.to_vec());
                staged.remove_by_candidate(twin);
                staged.verdict_writes += 1;
            }
            for item in self.trees.verdicts_by_candidate.scan_prefix(&removed) {
                let (key, primary) = item?;
                staged.remove_by_candidate(key.to_vec());
                staged.remove_verdict(primary.to_vec());
                staged.verdict_writes += 1;
            }
        }
        Ok(())
    }

    /// Inserts or replaces keyframes; the first keyframe of an empty store
    /// sets its descriptor length. With `max_per_robot`, refuses the whole
    /// change if a robot would then hold more keyframes than that.
    fn stage_insert(
        &mut self,
        keyframes: Vec<SemanticKeyframe>,
        max_per_robot: Option<u64>,
        staged: &mut Staged,
    ) -> Result<(), StoreError> {
        let dim = if self.dim == 0 {
            keyframes.first().map_or(0, |k| k.features.descriptor.len())
        } else {
            self.dim
        };
        for kf in &keyframes {
            let found = kf.features.descriptor.len();
            if found != dim {
                return Err(StoreError::DimensionMismatch {
                    expected: dim,
                    found,
                });
            }
        }
        let mut seen = HashSet::new();
        for kf in keyframes {
            let key = encode_key(&kf.key);
            if !seen.insert(key.clone()) || self.trees.keyframes.contains_key(&key)? {
                staged.outcome.replaced += 1;
            } else {
                staged.added += 1;
                *staged
                    .added_by_robot
                    .entry(kf.key.robot_id.clone())
                    .or_default() += 1;
            }
            staged.batch.insert(key.clone(), encode_record(&kf));
            staged.keys.push(key);
            staged.changes.push(IndexChange::Upsert(kf));
        }
        if let Some(max) = max_per_robot {
            self.check_quota(&staged.added_by_robot, max)?;
        }
        if self.dim == 0 && dim != 0 {
            self.remember(TreeName::Meta, META_DIM)?;
            self.trees
                .meta
                .insert(META_DIM, &(dim as u32).to_be_bytes())?;
            self.dim = dim;
        }
        Ok(())
    }

    /// Refuses an insert that would take a robot past `max` keyframes
    /// (the robot named first in order is reported).
    fn check_quota(&self, adding: &Deltas, max: u64) -> Result<(), StoreError> {
        let mut robots: Vec<_> = adding.iter().filter(|(_, &n)| n > 0).collect();
        robots.sort();
        for (robot, &n) in robots {
            let held = self.robots.held(robot);
            if held + n as u64 > max {
                return Err(StoreError::QuotaExceeded {
                    robot: robot.clone(),
                    held,
                    adding: n as u64,
                    max,
                });
            }
        }
        Ok(())
    }

    /// Removes the listed keyframes of a session that are stored.
    fn stage_erase(
        &self,
        session: &SessionKey,
        keyframe_ids: Vec<u64>,
        staged: &mut Staged,
    ) -> Result<(), StoreError> {
        let mut seen = HashSet::new();
        for keyframe_id in keyframe_ids {
            let key = session.keyframe(keyframe_id);
            let bytes = encode_key(&key);
            if seen.insert(keyframe_id) && self.trees.keyframes.contains_key(&bytes)? {
                staged.remove(bytes, key);
            }
        }
        Ok(())
    }

    /// Removes every keyframe of a session.
    fn stage_reset_session(
        &self,
        session: &SessionKey,
        staged: &mut Staged,
    ) -> Result<(), StoreError> {
        for item in self
            .trees
            .keyframes
            .scan_prefix(codec::session_prefix(session))
            .keys()
        {
            let bytes = item?;
            let key = corrupt_key(&bytes)?;
            staged.remove(bytes.to_vec(), key);
        }
        Ok(())
    }

    /// Removes every keyframe of one map of a session.
    fn stage_reset_map(&self, map: &MapKey, staged: &mut Staged) -> Result<(), StoreError> {
        for item in self
            .trees
            .keyframes
            .scan_prefix(codec::session_prefix(&map.session))
        {
            let (bytes, value) = item?;
            let record = decode(&bytes, &value)?;
            if record.map_id == map.map_id {
                staged.remove(bytes.to_vec(), record.key);
            }
        }
        Ok(())
    }

    /// Moves stored keyframes to new poses (and maps); ids not stored are
    /// reported missing.
    fn stage_pose_updates(
        &self,
        session: &SessionKey,
        updates: Vec<PoseUpdate>,
        staged: &mut Staged,
    ) -> Result<(), StoreError> {
        for PoseUpdate {
            keyframe_id,
            pose,
            map_id,
        } in updates
        {
            let key = session.keyframe(keyframe_id);
            let bytes = encode_key(&key);
            let Some(value) = self.trees.keyframes.get(&bytes)? else {
                staged.outcome.missing.push(keyframe_id);
                continue;
            };
            let mut record = decode(&bytes, &value)?;
            record.pose = pose;
            if let Some(map_id) = map_id {
                record.map_id = map_id;
            }
            staged.batch.insert(bytes.clone(), encode_record(&record));
            staged.keys.push(bytes);
            staged.outcome.affected += 1;
            staged.changes.push(IndexChange::Move(key, pose, map_id));
        }
        Ok(())
    }
}

fn decode(key: &[u8], value: &[u8]) -> Result<SemanticKeyframe, StoreError> {
    decode_record(value).map_err(|source| StoreError::Corrupt {
        key: key.to_vec(),
        source,
    })
}

fn corrupt_key(bytes: &[u8]) -> Result<KeyframeKey, StoreError> {
    codec::decode_key(bytes).map_err(|source| StoreError::Corrupt {
        key: bytes.to_vec(),
        source,
    })
}
