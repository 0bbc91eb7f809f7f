//! The writer thread: takes every job waiting on the queue as one group,
//! stages each change and applies it to sled in one transaction with its
//! journal entry (and log position), flushes once for the group, and hands
//! the group to the publisher, or, when the flush fails, puts back what
//! the group wrote and fails its callers.
//!
//! It owns everything that must follow sled change by change: the write
//! sequence, the keyframe count, the descriptor length, the per-robot
//! counts the quota is checked against, and the rollback record. What
//! each kind of change writes is worked out in [`super::staging`].

use std::sync::atomic::Ordering;
use std::sync::Arc;

use humem_core::keyframe::SemanticKeyframe;
use humem_core::observe::SharedObserver;
use sled::transaction::{ConflictableTransactionError, TransactionError, Transactional};
use tokio::sync::mpsc;

use super::publisher::{Answer, Published, Publisher, PUBLISH_BACKLOG, SLOW_MS};
use super::queue::{Job, WriterHandle, QUEUE};
use super::staging::{self, IndexChange, Staged};
use super::trees::Trees;
use crate::checkpoint::Checkpoints;
use crate::disk::Short;
use crate::error::StoreError;
use crate::export::{self, ExportHeader};
use crate::graph_file;
use crate::journal;
use crate::layout::{META_DIM, META_LOG_POSITION, STORE_FORMAT};
use crate::mutation::{LogApplied, LogEntry, Mutation, MutationOutcome};
use crate::placement::DescriptorPlacement;
use crate::robot_counts::{self, Deltas, RobotCounts};
use crate::rollback::{Counters, Rollback, TreeName};

/// Most changes committed by one flush.
const MAX_GROUP: usize = 256;

/// The longest an export waits for the publisher to take the flushed
/// groups into the index (it waits out the scans running).
const PUBLISH_WAIT: std::time::Duration = std::time::Duration::from_secs(60);

/// Whether a change adds data (refused near a full disk; removals are not).
fn adds_data(mutation: &Mutation) -> bool {
    matches!(
        mutation,
        Mutation::Insert(_) | Mutation::InsertWithin { .. } | Mutation::UpdatePoses { .. }
    )
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
        deferred: Default::default(),
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
        let graph = self.graph_for_export(file);
        let out = std::fs::File::create(file)
            .map_err(|e| StoreError::Export(format!("{}: {e}", file.display())))?;
        let trees = [
            (export::TREES[0].0, &self.trees.keyframes),
            (export::TREES[1].0, &self.trees.verdicts),
            (export::TREES[2].0, &self.trees.verdicts_by_candidate),
        ];
        let written = export::write(header, &trees, graph.as_deref(), &out);
        if let Some(graph) = &graph {
            let _ = std::fs::remove_file(graph);
        }
        written?;
        out.sync_all()
            .map_err(|e| StoreError::Export(format!("{}: {e}", file.display())))?;
        Ok(header)
    }

    /// The index's neighbour graph saved beside `file` for its export, in
    /// step with sled: once the publisher has taken every flushed group
    /// into the index (this thread sends no more meanwhile). None where
    /// the index keeps no graph, or it could not be saved (the export then
    /// goes without, and a store restored from it builds its own).
    fn graph_for_export(&self, file: &std::path::Path) -> Option<std::path::PathBuf> {
        let started = std::time::Instant::now();
        while self.checkpoints.applied.load(Ordering::Acquire) < self.sequence {
            if started.elapsed() > PUBLISH_WAIT {
                tracing::warn!("the index is behind the store: the export goes without its graph");
                return None;
            }
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        let mut name = file.as_os_str().to_owned();
        name.push(".graph");
        let graph = std::path::PathBuf::from(name);
        match graph_file::save_for_export(&graph, &self.checkpoints.index) {
            Ok(true) => Some(graph),
            Ok(false) => None,
            Err(e) => {
                tracing::warn!(error = %e, "saving the neighbour graph for an export failed: the export goes without it");
                let _ = std::fs::remove_file(&graph);
                None
            }
        }
    }

    /// Flushes a staged group and hands it to the publisher, or rolls it
    /// back and fails its callers.
    fn flush_group(&mut self, changes: Vec<IndexChange>, answers: Vec<Answer>, journaled: u64) {
        let started = std::time::Instant::now();
        let flushed = self.flush();
        let flush_ms = started.elapsed().as_secs_f64() * 1e3;
        if flush_ms >= SLOW_MS {
            tracing::debug!(flush_ms, changes = changes.len(), "slow flush of a group");
        }
        if let Err(e) = flushed {
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
        let started = std::time::Instant::now();
        if self.publisher.send(group).is_err() {
            tracing::error!("the index publisher is gone");
        }
        let handed_ms = started.elapsed().as_secs_f64() * 1e3;
        if handed_ms >= SLOW_MS {
            tracing::debug!(handed_ms, "waited for the publisher to take a group");
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
        short: Option<Short>,
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
            } => staging::erase(&self.trees, &session, keyframe_ids, &mut staged)?,
            Mutation::ResetSession(session) => {
                staging::reset_session(&self.trees, &session, &mut staged)?
            }
            Mutation::ResetMap(map) => staging::reset_map(&self.trees, &map, &mut staged)?,
            Mutation::UpdatePoses { session, updates } => {
                staging::pose_updates(&self.trees, &session, updates, &mut staged)?
            }
            Mutation::ReportVerdict(verdict) => {
                staging::verdict(&self.trees, verdict, &mut staged)?
            }
        }
        staging::verdict_cascade(&self.trees, &mut staged)?;
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

    /// Inserts or replaces keyframes; the first keyframe of an empty store
    /// sets its descriptor length. With `max_per_robot`, refuses the whole
    /// change if a robot would then hold more keyframes than that.
    fn stage_insert(
        &mut self,
        keyframes: Vec<SemanticKeyframe>,
        max_per_robot: Option<u64>,
        staged: &mut Staged,
    ) -> Result<(), StoreError> {
        let dim = staging::insert(&self.trees, self.dim, keyframes, staged)?;
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
}
