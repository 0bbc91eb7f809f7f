//! A replica: this server's place in the cluster. It writes by publishing
//! to the stream and waiting for the applier to apply the entry here; it
//! reads from its own store, optionally after waiting for a log position
//! (read-your-writes across replicas).

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use async_nats::jetstream::{self, context::PublishErrorKind, message::PublishMessage};
use parking_lot::Mutex;
use tokio::sync::{oneshot, watch};
use tokio::task::JoinHandle;

use humem_store::{Mutation, MutationOutcome, Store};

use crate::applier::{self, Shared};
use crate::config::ClusterConfig;
use crate::entry;
use crate::error::ClusterError;
use crate::nats;
use crate::observe::ClusterObserver;

/// Keyframes per log entry when a store written before cluster mode is
/// published: about 0.5 MB with images' features, under NATS' default
/// 1 MB message limit.
pub const IMPORT_BATCH: usize = 32;

/// A write, applied: what it did here, and its position in the log (the
/// token a client gives another replica to read its own writes).
#[derive(Debug, Clone, PartialEq)]
pub struct Written {
    /// What the change did.
    pub outcome: MutationOutcome,
    /// The entry's sequence in the stream.
    pub sequence: u64,
}

/// This server's replica of the cluster's store. Cheap to clone.
#[derive(Clone)]
pub struct Replica {
    inner: Arc<Inner>,
}

struct Inner {
    js: jetstream::Context,
    config: ClusterConfig,
    shared: Arc<Shared>,
    observer: Arc<dyn ClusterObserver>,
    /// The stream's last sequence when this replica started.
    start_target: u64,
    /// Message ids: unique to this process, counted.
    id_prefix: String,
    next_id: AtomicU64,
    stop: watch::Sender<bool>,
    tasks: Mutex<Vec<JoinHandle<()>>>,
}

impl Replica {
    /// Joins the cluster: connects to NATS, makes sure the stream exists,
    /// checks that the stream still holds every entry after this store's
    /// position, and starts applying it. Call [`Replica::catch_up`] before
    /// serving.
    pub async fn start(
        config: ClusterConfig,
        store: Store,
        observer: Arc<dyn ClusterObserver>,
    ) -> Result<Replica, ClusterError> {
        config.validate().map_err(ClusterError::Config)?;
        let client = nats::connect(&config, observer.clone()).await?;
        let mut js = jetstream::new(client);
        js.set_timeout(nats::ATTEMPT_TIMEOUT);
        let mut stream = nats::stream(&js, &config).await?;
        let position = store.log_position()?;
        let state = stream
            .info()
            .await
            .map_err(|e| ClusterError::Nats(format!("stream {}: {e}", config.stream)))?
            .state
            .clone();
        if position > state.last_sequence {
            return Err(ClusterError::Diverged(format!(
                "this store has applied the write log up to entry {position}, but stream {} ends at {}: the stream was deleted or replaced. Start this replica with an empty data directory, or restore the stream",
                config.stream, state.last_sequence
            )));
        }
        // A store written before cluster mode holds keyframes no log entry
        // carries. Into an empty stream it is published whole (below), so
        // the other replicas get it; next to another replica's entries it
        // cannot be placed in order, so it is refused.
        let existing = store.index().len();
        let import = position == 0 && existing > 0;
        if import && state.last_sequence > 0 {
            return Err(ClusterError::Diverged(format!(
                "this store holds {existing} keyframes written outside cluster mode, and stream {} already holds {} entries: start this replica on an empty data directory (it catches up from the stream), or put the keyframes into the cluster through the API",
                config.stream, state.last_sequence
            )));
        }
        if position + 1 < state.first_sequence {
            return Err(ClusterError::Diverged(format!(
                "this store has applied the write log up to entry {position}, but stream {} now starts at entry {} (older entries aged out, cluster.max_age_hours) and no store snapshot reaches it (cluster.snapshot_every; is any replica publishing?): seed this replica from a healthy one (docs/fleet-and-cluster.md, \"Retention\")",
                config.stream, state.first_sequence
            )));
        }
        let (applied, _) = watch::channel(position);
        let shared = Arc::new(Shared {
            waiters: Mutex::new(HashMap::new()),
            applied,
            halted: Mutex::new(None),
        });
        let (stop, stop_rx) = watch::channel(false);
        let name = nats::replica_name(&config);
        let nonce = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        tracing::info!(
            replica = %name,
            stream = %config.stream,
            position,
            stream_last = state.last_sequence,
            "joined the cluster; applying the write log"
        );
        let applier = tokio::spawn(applier::run(
            stream.clone(),
            config.subject.clone(),
            store.clone(),
            shared.clone(),
            observer.clone(),
            stop_rx.clone(),
        ));
        let mut tasks = vec![applier];
        if config.snapshot_every > 0 {
            let bucket = crate::snapshots::open_bucket(&js, &config).await?;
            tasks.push(tokio::spawn(crate::snapshots::publish_loop(
                bucket,
                store.clone(),
                store.dir().to_path_buf(),
                config.snapshot_every,
                shared.clone(),
                stop_rx.clone(),
            )));
        }
        tasks.push(tokio::spawn(watch_stream(
            stream,
            shared.clone(),
            observer.clone(),
            stop_rx,
        )));
        let replica = Replica {
            inner: Arc::new(Inner {
                js,
                start_target: state.last_sequence,
                id_prefix: format!("{name}-{nonce:x}-"),
                next_id: AtomicU64::new(0),
                config,
                shared,
                observer,
                stop,
                tasks: Mutex::new(tasks),
            }),
        };
        if import {
            replica.import(&store).await?;
        }
        Ok(replica)
    }

    /// Publishes every keyframe of a store written before cluster mode
    /// into the (empty) stream, [`IMPORT_BATCH`] to an entry, and waits
    /// for each to be applied here (which replaces each keyframe by
    /// itself and records the positions).
    async fn import(&self, store: &Store) -> Result<(), ClusterError> {
        let keys: Vec<_> = {
            let index = store.index();
            (0..index.len())
                .map(|row| index.meta(row).key.clone())
                .collect()
        };
        tracing::info!(
            keyframes = keys.len(),
            "publishing the keyframes of a store written before cluster mode to the empty write log"
        );
        let started = Instant::now();
        for chunk in keys.chunks(IMPORT_BATCH) {
            let keyframes: Vec<_> = chunk.iter().filter_map(|key| store.get(key)).collect();
            if !keyframes.is_empty() {
                self.write(Mutation::Insert(keyframes)).await?;
            }
        }
        tracing::info!(
            keyframes = keys.len(),
            entries = self.applied(),
            seconds = started.elapsed().as_secs_f64(),
            "store published to the write log"
        );
        Ok(())
    }

    /// Waits until this replica has applied every entry the stream held
    /// when it started, logging progress; a replica serves only then.
    pub async fn catch_up(&self) -> Result<(), ClusterError> {
        let target = self.inner.start_target;
        let mut applied = self.inner.shared.applied.subscribe();
        let started = Instant::now();
        let mut last_log = Instant::now();
        loop {
            let now = *applied.borrow_and_update();
            if now >= target {
                tracing::info!(
                    position = now,
                    seconds = started.elapsed().as_secs_f64(),
                    "caught up with the write log"
                );
                return Ok(());
            }
            self.check_halted()?;
            if last_log.elapsed() > Duration::from_secs(5) {
                tracing::info!(position = now, target, "catching up with the write log");
                last_log = Instant::now();
            }
            let _ = tokio::time::timeout(Duration::from_secs(1), applied.changed()).await;
        }
    }

    /// Writes a change through the log: publishes it (retrying with the
    /// same id, so JetStream stores it once, until `publish_timeout_ms`),
    /// then waits for this replica to apply it, and answers with what it
    /// did. Changes refused for what they are come back as
    /// [`ClusterError::Store`] with every replica refusing them alike.
    pub async fn write(&self, mutation: Mutation) -> Result<Written, ClusterError> {
        self.check_halted()?;
        let inner = &self.inner;
        let id = format!(
            "{}{}",
            inner.id_prefix,
            inner.next_id.fetch_add(1, Ordering::Relaxed)
        );
        let (waiter, applied) = oneshot::channel();
        inner.shared.waiters.lock().insert(id.clone(), waiter);
        let _forget = Forget {
            shared: &inner.shared,
            id: &id,
        };
        let payload = entry::encode(&mutation);
        let format = entry::format_of(&mutation);
        let sequence = self.publish(&id, payload, format).await?;
        match tokio::time::timeout(inner.config.apply_timeout(), applied).await {
            Ok(Ok(result)) => Ok(Written {
                outcome: result?,
                sequence,
            }),
            Ok(Err(_)) | Err(_) => Err(ClusterError::NotApplied {
                sequence,
                why: self
                    .halted()
                    .unwrap_or_else(|| "it is still behind (cluster.apply_timeout_ms)".into()),
            }),
        }
    }

    /// Publishes one entry and returns its sequence.
    async fn publish(&self, id: &str, payload: Vec<u8>, format: u32) -> Result<u64, ClusterError> {
        let inner = &self.inner;
        let started = Instant::now();
        let deadline = started + inner.config.publish_timeout();
        let payload = bytes::Bytes::from(payload);
        let mut attempt = 0u32;
        loop {
            attempt += 1;
            let message = PublishMessage::build()
                .payload(payload.clone())
                .message_id(id)
                .header(entry::FORMAT_HEADER, format.to_string().as_str());
            let result = match inner
                .js
                .send_publish(inner.config.subject.clone(), message)
                .await
            {
                Ok(ack) => ack.await,
                Err(e) => Err(e),
            };
            match result {
                Ok(ack) => {
                    let outcome = if ack.duplicate { "duplicate" } else { "ok" };
                    inner.observer.published(outcome, started.elapsed());
                    return Ok(ack.sequence);
                }
                Err(e) if e.kind() == PublishErrorKind::MaxPayloadExceeded => {
                    inner.observer.published("failed", started.elapsed());
                    return Err(ClusterError::TooLarge(e.to_string()));
                }
                Err(e) if Instant::now() + Duration::from_millis(100) < deadline => {
                    tracing::debug!(attempt, error = %e, "publishing to the write log failed; retrying");
                    let wait = Duration::from_millis(100 * u64::from(attempt.min(10)));
                    tokio::time::sleep(
                        wait.min(deadline.saturating_duration_since(Instant::now())),
                    )
                    .await;
                }
                Err(e) => {
                    inner.observer.published("failed", started.elapsed());
                    return Err(ClusterError::Nats(format!(
                        "the write log did not take the change within {} ms (cluster.publish_timeout_ms), after {attempt} attempts: {e}",
                        inner.config.publish_timeout_ms
                    )));
                }
            }
        }
    }

    /// Waits until this replica has applied the log up to `sequence`, for
    /// at most `cluster.max_read_wait_ms` or `within`, whichever is less.
    pub async fn wait_for(
        &self,
        sequence: u64,
        within: Option<Duration>,
    ) -> Result<(), ClusterError> {
        let mut applied = self.inner.shared.applied.subscribe();
        if *applied.borrow_and_update() >= sequence {
            return Ok(());
        }
        self.check_halted()?;
        // Answer before the caller's deadline, with time for the answer
        // to reach it.
        let wait = within.map_or(self.inner.config.max_read_wait(), |w| {
            w.mul_f32(0.8).min(self.inner.config.max_read_wait())
        });
        let reached = tokio::time::timeout(wait, applied.wait_for(|&a| a >= sequence)).await;
        match reached {
            Ok(Ok(_)) => Ok(()),
            _ => Err(ClusterError::Behind {
                applied: *self.inner.shared.applied.borrow(),
                wanted: sequence,
            }),
        }
    }

    /// The position this replica has applied up to.
    pub fn applied(&self) -> u64 {
        *self.inner.shared.applied.borrow()
    }

    /// Why the applier stopped for good, if it did (the replica is then
    /// not ready: its answers would grow stale).
    pub fn halted(&self) -> Option<String> {
        self.inner.shared.halted.lock().clone()
    }

    /// Whether this replica may answer a query: not once its applier has
    /// halted (its store no longer follows the log), unless
    /// `cluster.serve_stale_reads` says stale answers are wanted.
    pub fn check_reads(&self) -> Result<(), ClusterError> {
        if self.inner.config.serve_stale_reads {
            return Ok(());
        }
        self.check_halted()
    }

    fn check_halted(&self) -> Result<(), ClusterError> {
        match self.halted() {
            Some(why) => Err(ClusterError::Halted(why)),
            None => Ok(()),
        }
    }

    /// Stops applying (before the store is flushed at shutdown).
    pub async fn shutdown(&self) {
        let _ = self.inner.stop.send(true);
        let tasks = std::mem::take(&mut *self.inner.tasks.lock());
        for task in tasks {
            let _ = task.await;
        }
    }
}

/// Removes a write's waiter however the write ends.
struct Forget<'a> {
    shared: &'a Shared,
    id: &'a str,
}

impl Drop for Forget<'_> {
    fn drop(&mut self) {
        self.shared.waiters.lock().remove(self.id);
    }
}

/// Reports the stream's state every two seconds: its last sequence, how
/// many copies are current, and this replica's lag behind it.
async fn watch_stream(
    stream: jetstream::stream::Stream,
    shared: Arc<Shared>,
    observer: Arc<dyn ClusterObserver>,
    mut stop: watch::Receiver<bool>,
) {
    loop {
        match stream.get_info().await {
            Ok(info) => {
                let replicas = info.config.num_replicas.max(1);
                let current = match &info.cluster {
                    Some(cluster) if cluster.leader.is_some() => {
                        1 + cluster
                            .replicas
                            .iter()
                            .filter(|p| p.current && !p.offline)
                            .count()
                    }
                    Some(_) => 0,
                    None => 1,
                };
                observer.stream(info.state.last_sequence, current, replicas);
                let applied = *shared.applied.borrow();
                observer.lag(info.state.last_sequence.saturating_sub(applied));
            }
            Err(e) => {
                tracing::debug!(error = %e, "stream info unavailable");
                observer.stream(0, 0, 0);
            }
        }
        tokio::select! {
            _ = tokio::time::sleep(Duration::from_secs(2)) => {}
            _ = stop.changed() => return,
        }
    }
}
