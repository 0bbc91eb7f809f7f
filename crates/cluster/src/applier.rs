//! The applier: this replica's one reader of the write log. It reads the
//! stream in order from the entry after the store's log position, applies
//! what is waiting as one batch (one flush), and wakes the writes of this
//! replica that wait for their entry.
//!
//! Order is everything: entries are applied strictly in stream order, and
//! the position is recorded with each change (`Store::apply_log`), so a
//! replica that stops anywhere resumes exactly after its last applied
//! entry. A failure of this replica (a full disk) stops the batch and is
//! retried; a gap in the sequence (entries aged out of the stream) or an
//! entry from a newer build halts the applier until an operator acts,
//! since going on would make this replica differ from the others.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use async_nats::jetstream::consumer::{pull::OrderedConfig, DeliverPolicy};
use async_nats::jetstream::stream::Stream;
use futures::StreamExt;
use parking_lot::Mutex;
use tokio::sync::{oneshot, watch};

use humem_core::keyframe::SessionKey;
use humem_store::{LogEntry, Mutation, MutationOutcome, Store, StoreError};

use crate::entry::{self, EntryError};
use crate::observe::ClusterObserver;

/// Most entries applied as one batch.
const MAX_BATCH: usize = 256;

/// A write of this replica waiting for its entry to be applied here.
pub(crate) type Waiter = oneshot::Sender<Result<MutationOutcome, StoreError>>;

/// What the applier shares with the replica's writers and readers.
pub(crate) struct Shared {
    /// Writes waiting for their entry, by message id.
    pub waiters: Mutex<HashMap<String, Waiter>>,
    /// The store's log position, published after each batch.
    pub applied: watch::Sender<u64>,
    /// Why the applier stopped for good, if it did.
    pub halted: Mutex<Option<String>>,
}

/// One entry read from the stream, ready to apply.
struct Read {
    position: u64,
    mutation: Mutation,
    id: Option<String>,
    /// When the stream stored it, in nanoseconds since the epoch.
    stored_ns: i128,
}

/// Reads and applies the stream until `stop` turns true or the applier
/// halts.
pub(crate) async fn run(
    stream: Stream,
    subject: String,
    store: Store,
    shared: Arc<Shared>,
    observer: Arc<dyn ClusterObserver>,
    mut stop: watch::Receiver<bool>,
) {
    let mut position = *shared.applied.borrow();
    loop {
        if *stop.borrow() {
            return;
        }
        let deliver_policy = if position == 0 {
            DeliverPolicy::All
        } else {
            DeliverPolicy::ByStartSequence {
                start_sequence: position + 1,
            }
        };
        let consumer = stream
            .create_consumer(OrderedConfig {
                filter_subject: subject.clone(),
                deliver_policy,
                ..Default::default()
            })
            .await;
        let messages = match consumer {
            Ok(consumer) => consumer.messages().await,
            Err(e) => {
                tracing::warn!(error = %e, "cannot read the write log; retrying");
                pause(&mut stop, Duration::from_secs(1)).await;
                continue;
            }
        };
        let mut chunks = match messages {
            Ok(messages) => messages.ready_chunks(MAX_BATCH),
            Err(e) => {
                tracing::warn!(error = %e, "cannot read the write log; retrying");
                pause(&mut stop, Duration::from_secs(1)).await;
                continue;
            }
        };
        loop {
            let chunk = tokio::select! {
                chunk = chunks.next() => chunk,
                _ = stop.changed() => return,
            };
            let Some(chunk) = chunk else { break };
            let mut batch = Vec::with_capacity(chunk.len());
            let mut pending = None;
            let mut broken = None;
            for message in chunk {
                let message = match message {
                    Ok(message) => message,
                    Err(e) => {
                        broken = Some(e.to_string());
                        break;
                    }
                };
                let Ok(info) = message.info() else {
                    broken = Some("a log message without its JetStream metadata".into());
                    break;
                };
                let sequence = info.stream_sequence;
                pending = Some(info.pending);
                let stored_ns = info.published.unix_timestamp_nanos();
                let expected = position + batch.len() as u64 + 1;
                if sequence < expected {
                    continue; // read again after a reconnect: already applied
                }
                if sequence > expected {
                    halt(
                        &shared,
                        &*observer,
                        format!(
                            "the write log has no entries {expected}..{sequence}: they were removed from stream {} (cluster.max_age_hours) before this replica applied them. Seed this replica from a healthy one (docs/fleet-and-cluster.md, \"Retention\")",
                            stream.cached_info().config.name
                        ),
                    );
                    return;
                }
                let headers = message.headers.as_ref();
                let header = |name: &str| {
                    headers
                        .and_then(|h| h.get(name))
                        .map(|v| v.as_str().to_string())
                };
                let id = header(async_nats::header::NATS_MESSAGE_ID.as_ref());
                let mutation = match entry::decode(
                    header(entry::FORMAT_HEADER).as_deref(),
                    &message.payload,
                ) {
                    Ok(mutation) => mutation,
                    Err(e @ EntryError::Newer { .. }) => {
                        halt(&shared, &*observer, format!("entry {sequence}: {e}"));
                        return;
                    }
                    Err(e @ EntryError::Garbage(_)) => {
                        // Every replica skips it alike; applied as a change
                        // that changes nothing, so its position is recorded.
                        tracing::error!(sequence, error = %e, "skipping a log entry");
                        observer.skipped();
                        nothing()
                    }
                };
                batch.push(Read {
                    position: sequence,
                    mutation,
                    id,
                    stored_ns,
                });
            }
            if !batch.is_empty() {
                match apply(&store, batch, &shared, &*observer, &mut stop).await {
                    Some(applied) => position = applied,
                    None => return,
                }
            }
            if let Some(pending) = pending {
                observer.lag(pending);
            }
            if let Some(error) = broken {
                tracing::warn!(%error, "reading the write log failed; reading again from the next entry");
                break;
            }
        }
        pause(&mut stop, Duration::from_millis(200)).await;
    }
}

/// A change that changes nothing (the stand-in for a skipped entry).
fn nothing() -> Mutation {
    Mutation::Erase {
        session: SessionKey {
            robot_id: String::new(),
            session_id: String::new(),
        },
        keyframe_ids: Vec::new(),
    }
}

/// Applies a batch in order, retrying from the first entry not applied
/// while this replica cannot apply it (a full disk, a busy writer). Wakes
/// the waiting writes. Returns the new position, or `None` when stopped.
async fn apply(
    store: &Store,
    mut batch: Vec<Read>,
    shared: &Shared,
    observer: &dyn ClusterObserver,
    stop: &mut watch::Receiver<bool>,
) -> Option<u64> {
    let mut backoff = Duration::from_millis(50);
    loop {
        let entries = batch
            .iter()
            .map(|r| LogEntry {
                position: r.position,
                mutation: r.mutation.clone(),
            })
            .collect();
        let (results, stopped) = match store.apply_log(entries).await {
            Ok(applied) => (applied.results, applied.stopped),
            Err(StoreError::WriterGone) => return None,
            Err(e) => (Vec::new(), Some(e)),
        };
        if !results.is_empty() {
            let done: Vec<Read> = batch.drain(..results.len()).collect();
            let last = done.last().expect("results are not empty");
            let position = last.position;
            let now_ns = SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos() as i128);
            let delay = Duration::from_nanos((now_ns - last.stored_ns).max(0) as u64);
            shared.applied.send_replace(position);
            observer.applied(done.len(), position, delay);
            let mut waiters = shared.waiters.lock();
            for (read, result) in done.into_iter().zip(results) {
                if let Some(waiter) = read.id.and_then(|id| waiters.remove(&id)) {
                    let _ = waiter.send(result);
                }
            }
        }
        match stopped {
            None => return Some(*shared.applied.borrow()),
            Some(e) => {
                tracing::warn!(error = %e, next = batch.first().map(|r| r.position), "cannot apply the next log entry here yet; retrying");
                pause(stop, backoff).await;
                if *stop.borrow() {
                    return None;
                }
                backoff = (backoff * 2).min(Duration::from_secs(5));
            }
        }
    }
}

/// Records why the applier stops for good.
fn halt(shared: &Shared, observer: &dyn ClusterObserver, why: String) {
    tracing::error!(%why, "the replica stopped applying the write log");
    observer.halted(true);
    *shared.halted.lock() = Some(why);
}

/// Sleeps, or returns early when asked to stop.
async fn pause(stop: &mut watch::Receiver<bool>, duration: Duration) {
    tokio::select! {
        _ = tokio::time::sleep(duration) => {}
        _ = stop.changed() => {}
    }
}
