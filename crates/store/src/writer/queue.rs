//! The writer's bounded queue: the jobs it carries ([`Job`]) and the
//! sending side the store holds ([`WriterHandle`]).
//!
//! A full queue is reported at once ([`StoreError::QueueFull`]) instead of
//! waiting, so callers push back rather than grow memory; the queue's depth
//! is reported to the observer as jobs come and go.

use humem_core::observe::SharedObserver;
use tokio::sync::{mpsc, oneshot};

use crate::error::StoreError;
use crate::export::ExportHeader;
use crate::mutation::{LogApplied, LogEntry, Mutation, MutationOutcome};

pub(super) type Reply = oneshot::Sender<Result<MutationOutcome, StoreError>>;
pub(super) type LogReply = oneshot::Sender<LogApplied>;

/// What the writer is asked to do.
pub(super) enum Job {
    /// One change, answered with its outcome.
    Change(Mutation, Reply),
    /// Entries of a replicated log, applied in order, each recording its
    /// position; stops at the first that cannot be applied now.
    Log(Vec<LogEntry>, LogReply),
    /// Write the whole store to a file, after the group it arrived in.
    Export(std::path::PathBuf, ExportReply),
}

pub(super) type ExportReply = oneshot::Sender<Result<ExportHeader, StoreError>>;

impl Job {
    /// Changes this job holds, for the queue depth.
    pub(super) fn len(&self) -> usize {
        match self {
            Job::Change(..) => 1,
            Job::Log(entries, _) => entries.len(),
            Job::Export(..) => 0,
        }
    }
}

/// Sending side of the writer's queue.
#[derive(Clone)]
pub(crate) struct WriterHandle {
    pub(super) queue: mpsc::Sender<Job>,
    pub(super) capacity: usize,
    pub(super) observer: SharedObserver,
}

/// The writer's queue, as observers see it.
pub(super) const QUEUE: &str = "store_writer";

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
