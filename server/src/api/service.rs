//! The tonic implementation of `humem.v1.PlaceRecognition`.
//!
//! Each handler validates the whole request first (nothing is changed by a
//! bad request), then hands domain values to the store or the query
//! pipeline. Queries scan the index on tokio's blocking pool so that a large
//! scan never stalls the async runtime.

use std::sync::Arc;
use std::time::{Duration, Instant};

use tonic::{Request, Response, Status};

use super::convert;
use super::validate::{self, InvalidField, Limits, Observation, PendingKeyframe};
use crate::metrics;
use crate::pipeline;
use crate::pipeline::latest_wins::{Admission, LatestWins, SlotKey};
use crate::proto;
use crate::proto::place_recognition_server::PlaceRecognition;
use humem_core::keyframe::{Features, SemanticKeyframe};
use humem_core::vpr::VprParams;
use humem_perception::Perception;
use humem_store::{MapKey, Mutation, Store};

/// The service state shared by all requests.
#[derive(Clone)]
pub struct PlaceRecognitionService {
    store: Store,
    params: Arc<VprParams>,
    limits: Limits,
    /// The models; `None` when the server runs without perception.
    perception: Option<Perception>,
    /// Latest-wins slots of the queries.
    scheduler: Arc<LatestWins>,
}

/// Features of an observation and the time perception spent on them.
type Resolved = (Features, Vec<(&'static str, Duration)>);

impl PlaceRecognitionService {
    pub fn new(
        store: Store,
        params: VprParams,
        limits: Limits,
        perception: Option<Perception>,
        scheduler: Arc<LatestWins>,
    ) -> Self {
        PlaceRecognitionService {
            store,
            params: Arc::new(params),
            limits,
            perception,
            scheduler,
        }
    }

    /// The features of an observation: as sent, or made from its image.
    async fn resolve(&self, observation: Observation) -> Result<Resolved, Status> {
        match observation {
            Observation::Features(features) => Ok((features, Vec::new())),
            Observation::Image(image, field) => {
                let perception = self.perception.as_ref().ok_or_else(|| {
                    Status::failed_precondition(format!(
                        "{field}: this server runs without perception models (perception.enabled = false); send features instead"
                    ))
                })?;
                let extracted = perception
                    .extract(image)
                    .await
                    .map_err(|e| convert::perception_status(&field, e))?;
                Ok((extracted.features, extracted.timings))
            }
        }
    }

    /// Resolves the observations of keyframes, all at once so that their
    /// images share inferences.
    async fn resolve_all(
        &self,
        pending: Vec<PendingKeyframe>,
    ) -> Result<(Vec<SemanticKeyframe>, Vec<Resolved>), Status> {
        let mut metas = Vec::with_capacity(pending.len());
        let mut observations = Vec::with_capacity(pending.len());
        for mut p in pending {
            let observation = std::mem::replace(
                &mut p.observation,
                Observation::Features(Features::default()),
            );
            observations.push(observation);
            metas.push(p);
        }
        let resolved = futures::future::join_all(observations.into_iter().map(|o| self.resolve(o)))
            .await
            .into_iter()
            .collect::<Result<Vec<_>, Status>>()?;
        let keyframes = metas
            .into_iter()
            .zip(&resolved)
            .map(|(p, (features, _))| p.with_features(features.clone()))
            .collect();
        Ok((keyframes, resolved))
    }

    /// Refuses descriptors whose length differs from the store's, naming the
    /// keyframe (the writer checks again, for the very first keyframes).
    fn check_dims(
        &self,
        field: impl Fn(usize) -> String,
        keyframes: &[SemanticKeyframe],
    ) -> Result<(), Status> {
        let stored = self.store.index().dim();
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
                }
                .into());
            }
        }
        Ok(())
    }
}

/// The handlers, one per RPC; the trait implementation below wraps each
/// with its metrics.
impl PlaceRecognitionService {
    #[tracing::instrument(skip_all, fields(robot, session, keyframe))]
    async fn handle_insert(
        &self,
        request: Request<proto::InsertRequest>,
    ) -> Result<Response<proto::InsertResponse>, Status> {
        let pending = validate::keyframe("keyframe", request.into_inner().keyframe, &self.limits)?;
        let span = tracing::Span::current();
        span.record("robot", pending.key.robot_id.as_str());
        span.record("session", pending.key.session_id.as_str());
        span.record("keyframe", pending.key.keyframe_id);
        let from_image = matches!(pending.observation, Observation::Image(..));
        let (keyframes, mut resolved) = self.resolve_all(vec![pending]).await?;
        self.check_dims(|_| "keyframe".into(), &keyframes)?;
        let (features, timings) = resolved.pop().unwrap_or_default();
        let outcome = self
            .store
            .apply(Mutation::Insert(keyframes))
            .await
            .map_err(convert::store_status)?;
        metrics::KEYFRAMES_INSERTED.inc();
        metrics::observe_stages(&timings);
        Ok(Response::new(proto::InsertResponse {
            replaced: outcome.replaced > 0,
            store_keyframes: outcome.store_keyframes,
            timings: convert::timings(&timings),
            features: from_image.then(|| convert::features(&features)),
        }))
    }

    #[tracing::instrument(skip_all, fields(keyframes))]
    async fn handle_insert_batch(
        &self,
        request: Request<proto::InsertBatchRequest>,
    ) -> Result<Response<proto::InsertBatchResponse>, Status> {
        let pending = validate::batch(request.into_inner().keyframes, &self.limits)?;
        tracing::Span::current().record("keyframes", pending.len());
        let (keyframes, resolved) = self.resolve_all(pending).await?;
        for (_, timings) in &resolved {
            metrics::observe_stages(timings);
        }
        self.check_dims(|i| format!("keyframes[{i}]"), &keyframes)?;
        let count = keyframes.len() as u64;
        let outcome = self
            .store
            .apply(Mutation::Insert(keyframes))
            .await
            .map_err(convert::store_status)?;
        metrics::KEYFRAMES_INSERTED.inc_by(count);
        Ok(Response::new(proto::InsertBatchResponse {
            replaced: u32::try_from(outcome.replaced).unwrap_or(u32::MAX),
            store_keyframes: outcome.store_keyframes,
        }))
    }

    #[tracing::instrument(skip_all, fields(robot, session, map, frame))]
    async fn handle_query(
        &self,
        request: Request<proto::QueryRequest>,
    ) -> Result<Response<proto::QueryResponse>, Status> {
        let mut spec = validate::query(request.into_inner(), &self.limits)?;
        let span = tracing::Span::current();
        span.record("robot", spec.session.robot_id.as_str());
        span.record("session", spec.session.session_id.as_str());
        if let Some(map) = spec.map_id {
            span.record("map", map);
        }
        if let Some(frame) = spec.frame_id {
            span.record("frame", frame);
        }
        // Wait for this client's turn; a newer query may take our place.
        let slot = SlotKey {
            robot_id: spec.session.robot_id.clone(),
            session_id: spec.session.session_id.clone(),
            kind: spec.kind as i32,
        };
        let _turn = match self.scheduler.admit(slot).await {
            Admission::Run(turn) => turn,
            Admission::Superseded => {
                tracing::debug!("query superseded");
                metrics::QUERIES_SUPERSEDED
                    .with_label_values(&[kind_label(spec.kind)])
                    .inc();
                return Ok(Response::new(proto::QueryResponse {
                    status: proto::QueryStatus::Superseded as i32,
                    ..Default::default()
                }));
            }
        };
        let kind = spec.kind;
        let mut perception_timings = Vec::new();
        if let Some(observation) = spec.observation.take() {
            let (features, timings) = self.resolve(observation).await?;
            spec.observation = Some(Observation::Features(features));
            perception_timings = timings;
        }
        let index = self.store.index_handle();
        let params = self.params.clone();
        let mut outcome = tokio::task::spawn_blocking(move || {
            let index = index.read();
            pipeline::query::run(&index, &params, &spec)
        })
        .await
        .map_err(|e| Status::internal(format!("query task failed: {e}")))??;
        perception_timings.append(&mut outcome.timings);
        outcome.timings = perception_timings;
        metrics::observe_stages(&outcome.timings);
        let kind = kind_label(kind);
        metrics::CANDIDATES
            .with_label_values(&[kind])
            .observe(outcome.candidates.len() as f64);
        for c in &outcome.candidates {
            metrics::CANDIDATE_SCORE
                .with_label_values(&[kind])
                .observe(f64::from(c.score));
        }
        tracing::debug!(
            candidates = outcome.candidates.len(),
            eligible = outcome.eligible,
            "query answered"
        );
        Ok(Response::new(convert::query_response(&outcome)))
    }

    #[tracing::instrument(skip_all)]
    async fn handle_erase(
        &self,
        request: Request<proto::EraseRequest>,
    ) -> Result<Response<proto::EraseResponse>, Status> {
        let (session, keyframe_ids) = validate::erase(request.get_ref())?;
        let outcome = self
            .store
            .apply(Mutation::Erase {
                session,
                keyframe_ids,
            })
            .await
            .map_err(convert::store_status)?;
        Ok(Response::new(proto::EraseResponse {
            erased: outcome.affected,
        }))
    }

    #[tracing::instrument(skip_all)]
    async fn handle_reset_map(
        &self,
        request: Request<proto::ResetMapRequest>,
    ) -> Result<Response<proto::ResetMapResponse>, Status> {
        let r = request.get_ref();
        let session = validate::session("", &r.robot_id, &r.session_id)?;
        let map_id = r.map_id.ok_or_else(|| InvalidField {
            field: "map_id".into(),
            reason: "required".into(),
        })?;
        let outcome = self
            .store
            .apply(Mutation::ResetMap(MapKey { session, map_id }))
            .await
            .map_err(convert::store_status)?;
        Ok(Response::new(proto::ResetMapResponse {
            erased: outcome.affected,
        }))
    }

    #[tracing::instrument(skip_all)]
    async fn handle_reset_session(
        &self,
        request: Request<proto::ResetSessionRequest>,
    ) -> Result<Response<proto::ResetSessionResponse>, Status> {
        let r = request.get_ref();
        let session = validate::session("", &r.robot_id, &r.session_id)?;
        let outcome = self
            .store
            .apply(Mutation::ResetSession(session))
            .await
            .map_err(convert::store_status)?;
        Ok(Response::new(proto::ResetSessionResponse {
            erased: outcome.affected,
        }))
    }

    #[tracing::instrument(skip_all)]
    async fn handle_update_poses(
        &self,
        request: Request<proto::UpdatePosesRequest>,
    ) -> Result<Response<proto::UpdatePosesResponse>, Status> {
        let (session, updates) = validate::pose_updates(request.get_ref())?;
        let outcome = self
            .store
            .apply(Mutation::UpdatePoses { session, updates })
            .await
            .map_err(convert::store_status)?;
        Ok(Response::new(proto::UpdatePosesResponse {
            updated: outcome.affected,
            missing_keyframe_ids: outcome.missing,
        }))
    }

    async fn handle_stats(
        &self,
        _request: Request<proto::StatsRequest>,
    ) -> Result<Response<proto::StatsResponse>, Status> {
        let (keyframes, descriptor_dim, maps) = {
            let index = self.store.index();
            let maps = index
                .map_counts()
                .into_iter()
                .map(|(map, count)| proto::MapStats {
                    robot_id: map.session.robot_id,
                    session_id: map.session.session_id,
                    map_id: map.map_id,
                    keyframes: count as u64,
                })
                .collect();
            (index.len() as u64, index.dim() as u32, maps)
        };
        Ok(Response::new(proto::StatsResponse {
            keyframes,
            descriptor_dim,
            maps,
            disk_bytes: self.store.disk_bytes(),
            format_version: u32::from(humem_store::codec::FORMAT_VERSION),
            server_version: env!("CARGO_PKG_VERSION").into(),
        }))
    }
}

#[tonic::async_trait]
impl PlaceRecognition for PlaceRecognitionService {
    async fn insert(
        &self,
        request: Request<proto::InsertRequest>,
    ) -> Result<Response<proto::InsertResponse>, Status> {
        let rpc = RpcObserver::start("Insert");
        rpc.finish(self.handle_insert(request).await)
    }

    async fn insert_batch(
        &self,
        request: Request<proto::InsertBatchRequest>,
    ) -> Result<Response<proto::InsertBatchResponse>, Status> {
        let rpc = RpcObserver::start("InsertBatch");
        rpc.finish(self.handle_insert_batch(request).await)
    }

    async fn query(
        &self,
        request: Request<proto::QueryRequest>,
    ) -> Result<Response<proto::QueryResponse>, Status> {
        let rpc = RpcObserver::start("Query");
        rpc.finish(self.handle_query(request).await)
    }

    async fn erase(
        &self,
        request: Request<proto::EraseRequest>,
    ) -> Result<Response<proto::EraseResponse>, Status> {
        let rpc = RpcObserver::start("Erase");
        rpc.finish(self.handle_erase(request).await)
    }

    async fn reset_map(
        &self,
        request: Request<proto::ResetMapRequest>,
    ) -> Result<Response<proto::ResetMapResponse>, Status> {
        let rpc = RpcObserver::start("ResetMap");
        rpc.finish(self.handle_reset_map(request).await)
    }

    async fn reset_session(
        &self,
        request: Request<proto::ResetSessionRequest>,
    ) -> Result<Response<proto::ResetSessionResponse>, Status> {
        let rpc = RpcObserver::start("ResetSession");
        rpc.finish(self.handle_reset_session(request).await)
    }

    async fn update_poses(
        &self,
        request: Request<proto::UpdatePosesRequest>,
    ) -> Result<Response<proto::UpdatePosesResponse>, Status> {
        let rpc = RpcObserver::start("UpdatePoses");
        rpc.finish(self.handle_update_poses(request).await)
    }

    async fn stats(
        &self,
        request: Request<proto::StatsRequest>,
    ) -> Result<Response<proto::StatsResponse>, Status> {
        let rpc = RpcObserver::start("Stats");
        rpc.finish(self.handle_stats(request).await)
    }
}

/// The label of a query kind in metrics.
fn kind_label(kind: proto::QueryKind) -> &'static str {
    match kind {
        proto::QueryKind::Relocalisation => "relocalisation",
        _ => "loop_closure",
    }
}

/// Records an RPC's latency and status code when it finishes, and as
/// CANCELLED if the caller went away first (its future was dropped).
struct RpcObserver {
    rpc: &'static str,
    started: Instant,
    done: bool,
}

impl RpcObserver {
    fn start(rpc: &'static str) -> RpcObserver {
        RpcObserver {
            rpc,
            started: Instant::now(),
            done: false,
        }
    }

    fn finish<T>(mut self, result: Result<T, Status>) -> Result<T, Status> {
        let code = result
            .as_ref()
            .map_or_else(|s| s.code(), |_| tonic::Code::Ok);
        metrics::observe_rpc(self.rpc, code, self.started.elapsed().as_secs_f64());
        self.done = true;
        result
    }
}

impl Drop for RpcObserver {
    fn drop(&mut self) {
        if !self.done {
            metrics::observe_rpc(
                self.rpc,
                tonic::Code::Cancelled,
                self.started.elapsed().as_secs_f64(),
            );
        }
    }
}
