//! Orchestration of one request: from validated domain values to an answer,
//! over the store, the models and the HuMem-VPR scoring. Knows nothing of
//! gRPC: the API layer validates a request into [`request`] types, calls one
//! method of [`Pipeline`] and converts what comes back.
//!
//! - [`request`]: the request domain types (a validated query, a keyframe
//!   still to perceive, the query kind, the invalid-field error);
//! - [`Pipeline`]: what each request does: latest-wins admission, turning
//!   images into features (batched across a request's images), the
//!   dimension check, the store write (through the replicated write log in
//!   cluster mode, `humem-cluster`), the query scan on the blocking pool,
//!   and the request-level metrics;
//! - [`query`]: one query over the index, end to end, synchronous;
//! - [`latest_wins`]: one pending query per client and kind, newest wins;
//! - [`admission`]: scan slots shared by all robots, refusing a query at
//!   once when its wait would outlast what it can wait.

pub mod admission;
pub mod latest_wins;
pub mod query;
pub mod request;

use std::sync::Arc;
use std::time::Duration;

use humem_cluster::{ClusterError, Replica};
use humem_core::keyframe::{Features, SemanticKeyframe, SessionKey};
use humem_core::vpr::params::VprParams;
use humem_perception::{Perception, PerceptionError};
use humem_store::{Mutation, MutationOutcome, Store, StoreError};

use crate::metrics;
use admission::{Busy, QueryAdmission, ScanKind};
use latest_wins::{Admission, LatestWins, SlotKey};
use query::{QueryError, QueryOutcome};
use request::{InvalidField, Observation, PendingKeyframe, QuerySpec};

/// Why a request could not be carried out.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// A field is wrong in a way only the store's state reveals (e.g. the
    /// descriptor length).
    #[error(transparent)]
    Invalid(#[from] InvalidField),
    /// An image was sent to a server that runs without models.
    #[error("{field}: this server runs without perception models (perception.enabled = false); send features instead")]
    NoPerception {
        /// The request field that holds the image.
        field: String,
    },
    /// The models could not turn an image into features.
    #[error("{field}: {source}")]
    Perception {
        /// The request field that holds the image.
        field: String,
        /// What went wrong.
        source: PerceptionError,
    },
    /// The store refused or failed the change.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The query could not be answered.
    #[error(transparent)]
    Query(#[from] QueryError),
    /// The blocking task of a query failed (panicked or was cancelled).
    #[error("query task failed: {0}")]
    Task(String),
    /// Too many scans ahead to answer within what the query can wait.
    #[error(transparent)]
    Busy(#[from] Busy),
    /// Cluster mode: the write log or this replica's place in it.
    #[error(transparent)]
    Cluster(#[from] ClusterError),
    /// A query asked for a log position from a server not in cluster mode.
    #[error("min_log_sequence: this server is not in cluster mode (cluster.enabled = false), so it has no write log")]
    NotClustered,
}

/// A change made durable: what it did, and where it is in the write log.
#[derive(Debug)]
pub struct Stored {
    /// What the store did.
    pub outcome: MutationOutcome,
    /// Cluster mode: the change's sequence in the write log (0 otherwise).
    pub log_sequence: u64,
}

/// Features of an observation and the time perception spent on them.
pub type Resolved = (Features, Vec<(&'static str, Duration)>);

/// A stored keyframe, with the features it was stored with.
#[derive(Debug)]
pub struct Inserted {
    /// What the store did, and the log position.
    pub stored: Stored,
    /// The keyframe's features (computed, when it came as an image).
    pub features: Features,
    /// Time per perception stage.
    pub timings: Vec<(&'static str, Duration)>,
}

/// What became of a query.
#[derive(Debug)]
pub enum QueryAnswer {
    /// A newer query of the same client and kind took its place.
    Superseded,
    /// Ranked and selected.
    Answered(QueryOutcome),
}

/// The service's parts a request needs, shared by all requests.
#[derive(Clone)]
pub struct Pipeline {
    store: Store,
    params: Arc<VprParams>,
    /// The models; `None` when the server runs without perception.
    perception: Option<Perception>,
    /// Latest-wins slots of the queries.
    scheduler: Arc<LatestWins>,
    /// Scan slots shared by all robots.
    admission: Arc<QueryAdmission>,
    /// Cluster mode: writes go through the replicated log.
    replica: Option<Replica>,
    /// Keyframes a robot may hold (0: no limit), checked by the store's
    /// writer as each insert is applied, so that no interleaving of
    /// inserts passes it (in cluster mode: in the log's order).
    max_keyframes_per_robot: u64,
}

impl Pipeline {
    /// A pipeline over these parts.
    pub fn new(
        store: Store,
        params: VprParams,
        perception: Option<Perception>,
        scheduler: Arc<LatestWins>,
        admission: Arc<QueryAdmission>,
        replica: Option<Replica>,
    ) -> Self {
        Pipeline {
            store,
            params: Arc::new(params),
            perception,
            scheduler,
            admission,
            replica,
            max_keyframes_per_robot: 0,
        }
    }

    /// Makes a change durable: through the write log in cluster mode (the
    /// answer waits until this replica has applied it), else straight to
    /// the store.
    /// The same pipeline, holding each robot to `max` keyframes (0: no
    /// limit).
    pub fn with_keyframe_quota(mut self, max: u64) -> Self {
        self.max_keyframes_per_robot = max;
        self
    }

    /// The change that stores `keyframes`, under the keyframe quota.
    fn insertion(&self, keyframes: Vec<SemanticKeyframe>) -> Mutation {
        match self.max_keyframes_per_robot {
            0 => Mutation::Insert(keyframes),
            max_per_robot => Mutation::InsertWithin {
                keyframes,
                max_per_robot,
            },
        }
    }

    /// [`stream_name`] with how many of the session's keyframes the store
    /// has erased ([`humem_core::index::Index::session_erasures`]): an
    /// erasure through any replica starts a new stream, so a read made
    /// before it is never carried over to the keyframes after it.
    async fn camera_stream(&self, robot_id: &str, session_id: &str) -> Option<String> {
        let name = stream_name(robot_id, session_id)?;
        let session = SessionKey {
            robot_id: robot_id.into(),
            session_id: session_id.into(),
        };
        let erasures = self.store.index_async().await.session_erasures(&session);
        Some(format!("{name}\u{1f}{erasures}"))
    }

    async fn write(&self, mutation: Mutation) -> Result<Stored, PipelineError> {
        // Keyframes of a session going away: the erasure count in its
        // stream's name keeps its last read from being carried into its
        // next keyframes (on every replica); this frees it at once.
        let erased = match &mutation {
            Mutation::Erase { session, .. } | Mutation::ResetSession(session) => Some(session),
            Mutation::ResetMap(map) => Some(&map.session),
            _ => None,
        };
        if let (Some(session), Some(perception)) = (erased, &self.perception) {
            if let Some(stream) = self
                .camera_stream(&session.robot_id, &session.session_id)
                .await
            {
                perception.forget_stream(&stream);
            }
        }
        match &self.replica {
            Some(replica) => {
                let written = replica.write(mutation).await?;
                Ok(Stored {
                    outcome: written.outcome,
                    log_sequence: written.sequence,
                })
            }
            None => Ok(Stored {
                outcome: self.store.apply(mutation).await?,
                log_sequence: 0,
            }),
        }
    }

    /// Waits until this replica has applied the write log up to
    /// `sequence` (read-your-writes), within `deadline` at most.
    pub async fn wait_for_log(
        &self,
        sequence: u64,
        deadline: Option<Duration>,
    ) -> Result<(), PipelineError> {
        match &self.replica {
            Some(replica) => Ok(replica.wait_for(sequence, deadline).await?),
            None if sequence == 0 => Ok(()),
            None => Err(PipelineError::NotClustered),
        }
    }

    /// Cluster mode: the write-log position this replica has applied (0
    /// otherwise).
    pub fn log_position(&self) -> u64 {
        self.replica.as_ref().map_or(0, Replica::applied)
    }

    /// The VPR settings queries are ranked with.
    pub fn params(&self) -> &VprParams {
        &self.params
    }

    /// The store that queries read and writes go to.
    pub fn store(&self) -> &Store {
        &self.store
    }

    /// Stores one keyframe, perceiving its image first if it sent one.
    pub async fn insert(&self, pending: PendingKeyframe) -> Result<Inserted, PipelineError> {
        let (keyframes, mut resolved) = self.resolve_all(vec![pending]).await?;
        self.check_dims(|_| "keyframe".into(), &keyframes).await?;
        let (features, timings) = resolved.pop().unwrap_or_default();
        let stored = self.write(self.insertion(keyframes)).await?;
        metrics::KEYFRAMES_INSERTED.inc();
        metrics::observe_stages(&timings);
        Ok(Inserted {
            stored,
            features,
            timings,
        })
    }

    /// Stores keyframes atomically; their images share inferences.
    pub async fn insert_batch(
        &self,
        pending: Vec<PendingKeyframe>,
    ) -> Result<Stored, PipelineError> {
        let (keyframes, resolved) = self.resolve_all(pending).await?;
        for (_, timings) in &resolved {
            metrics::observe_stages(timings);
        }
        self.check_dims(|i| format!("keyframes[{i}]"), &keyframes)
            .await?;
        let count = keyframes.len() as u64;
        let stored = self.write(self.insertion(keyframes)).await?;
        metrics::KEYFRAMES_INSERTED.inc_by(count);
        Ok(stored)
    }

    /// Any other change to the store (erase, resets, pose updates).
    pub async fn apply(&self, mutation: Mutation) -> Result<Stored, PipelineError> {
        self.write(mutation).await
    }

    /// Answers a query: waits for the client's turn (a newer query may take
    /// its place), perceives its image if it sent one, waits for a scan
    /// slot (or is refused if the wait would outlast `deadline`, what the
    /// caller will wait), then ranks on the blocking pool so that a large
    /// scan never stalls the async runtime.
    pub async fn query(
        &self,
        mut spec: QuerySpec,
        deadline: Option<Duration>,
    ) -> Result<QueryAnswer, PipelineError> {
        // A replica that stopped following the log answers nothing from
        // its stale store (unless configured to).
        if let Some(replica) = &self.replica {
            replica.check_reads()?;
        }
        let arrived = std::time::Instant::now();
        let kind = spec.kind.label();
        let slot = SlotKey {
            robot_id: spec.session.robot_id.clone(),
            session_id: spec.session.session_id.clone(),
            kind: spec.kind,
        };
        let _turn = match self.scheduler.admit(slot).await {
            Admission::Run(turn) => turn,
            Admission::Superseded => {
                tracing::debug!("query superseded");
                metrics::QUERIES_SUPERSEDED.with_label_values(&[kind]).inc();
                return Ok(QueryAnswer::Superseded);
            }
        };
        let mut perception_timings = Vec::new();
        if let Some(observation) = spec.observation.take() {
            let stream = self
                .camera_stream(&spec.session.robot_id, &spec.session.session_id)
                .await;
            let (features, timings) = self.resolve(observation, stream.as_deref()).await?;
            spec.observation = Some(Observation::Features(features));
            perception_timings = timings;
        }
        let scan_kind = if spec.exact || self.params.exact {
            ScanKind::Exact
        } else {
            ScanKind::Planned
        };
        let scan_slot = self
            .admission
            .admit(scan_kind, arrived.elapsed(), deadline)
            .await
            .inspect_err(|busy| {
                tracing::debug!(%busy, "query refused");
                metrics::QUERIES_REFUSED.with_label_values(&[kind]).inc();
            })?;
        let index = self.store.index_handle();
        let params = self.params.clone();
        let mut outcome = tokio::task::spawn_blocking(move || {
            // Between two pieces of an exact pass, the planned queries
            // waiting for a slot go first.
            let read = || {
                scan_slot.give_way();
                index.read()
            };
            query::run_releasing(index.read(), read, &params, &spec)
        })
        .await
        .map_err(|e| PipelineError::Task(e.to_string()))??;
        perception_timings.append(&mut outcome.timings);
        outcome.timings = perception_timings;
        metrics::observe_stages(&outcome.timings);
        metrics::CANDIDATES
            .with_label_values(&[kind])
            .observe(outcome.candidates.len() as f64);
        for c in &outcome.candidates {
            metrics::CANDIDATE_SCORE
                .with_label_values(&[kind])
                .observe(f64::from(c.score));
        }
        metrics::OPERATING_THRESHOLD.set(f64::from(outcome.operating_point.threshold));
        tracing::debug!(
            candidates = outcome.candidates.len(),
            eligible = outcome.eligible,
            "query answered"
        );
        Ok(QueryAnswer::Answered(outcome))
    }

    /// The features of an observation: as sent, or made from its image,
    /// one of the camera `stream` where it has one (see [`stream_name`]).
    async fn resolve(
        &self,
        observation: Observation,
        stream: Option<&str>,
    ) -> Result<Resolved, PipelineError> {
        match observation {
            Observation::Features(features) => Ok((features, Vec::new())),
            Observation::Image(image, field) => {
                let Some(perception) = self.perception.as_ref() else {
                    return Err(PipelineError::NoPerception { field });
                };
                let extracted = perception
                    .extract_in(image, stream)
                    .await
                    .map_err(|source| PipelineError::Perception { field, source })?;
                if extracted.objects_carried {
                    metrics::OBJECTS_CARRIED.inc();
                }
                Ok((extracted.features, extracted.timings))
            }
        }
    }

    /// Resolves the observations of keyframes, all at once so that their
    /// images share inferences.
    async fn resolve_all(
        &self,
        pending: Vec<PendingKeyframe>,
    ) -> Result<(Vec<SemanticKeyframe>, Vec<Resolved>), PipelineError> {
        let mut metas = Vec::with_capacity(pending.len());
        let mut observations = Vec::with_capacity(pending.len());
        for mut p in pending {
            let observation = std::mem::replace(
                &mut p.observation,
                Observation::Features(Features::default()),
            );
            let stream = self.camera_stream(&p.key.robot_id, &p.key.session_id).await;
            observations.push((observation, stream));
            metas.push(p);
        }
        let resolved = futures::future::join_all(
            observations
                .into_iter()
                .map(|(o, stream)| async move { self.resolve(o, stream.as_deref()).await }),
        )
        .await
        .into_iter()
        .collect::<Result<Vec<_>, PipelineError>>()?;
        let keyframes = metas
            .into_iter()
            .zip(&resolved)
            .map(|(p, (features, _))| p.with_features(features.clone()))
            .collect();
        Ok((keyframes, resolved))
    }

    /// Refuses descriptors whose length differs from the store's, naming the
    /// keyframe (the writer checks again, for the very first keyframes).
    async fn check_dims(
        &self,
        field: impl Fn(usize) -> String,
        keyframes: &[SemanticKeyframe],
    ) -> Result<(), InvalidField> {
        let stored = self.store.index_async().await.dim();
        let expected = if stored == 0 {
            keyframes.first().map_or(0, |k| k.features.descriptor.len())
        } else {
            stored
        };
        for (i, kf) in keyframes.iter().enumerate() {
            let found = kf.features.descriptor.len();
            if found != expected {
                return Err(InvalidField {
                    field: format!("{}.features.global_descriptor", field(i)),
                    reason: format!(
                        "has {found} values but this store holds {expected}-value descriptors"
                    ),
                });
            }
        }
        Ok(())
    }
}

/// The name of a robot's session as a camera stream of perception (whose
/// last read may serve its next keyframes, `perception.reuse`); none for
/// a request that names no robot, whose images belong to no one stream.
fn stream_name(robot_id: &str, session_id: &str) -> Option<String> {
    (!robot_id.is_empty()).then(|| format!("{robot_id}\u{1f}{session_id}"))
}
