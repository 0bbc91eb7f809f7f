//! The tonic implementation of `humem.v1.PlaceRecognition`.
//!
//! A thin adapter: each handler validates the whole request first (nothing
//! is changed by a bad request), hands the domain values to the
//! [`Pipeline`], which does the work (admission, perception, the store, the
//! scan on the blocking pool), and converts the answer or error to protobuf.

use std::sync::Arc;

use tonic::{Request, Response, Status};

use super::convert;
use super::validate::{self, InvalidField, Limits, Observation};
use crate::auth::Authenticator;
use crate::pipeline::{Pipeline, QueryAnswer};
use crate::proto;
use crate::proto::place_recognition_server::PlaceRecognition;
use crate::quota::Quotas;
use humem_core::verdict::unix_now;
use humem_store::{MapKey, Mutation};

/// What limits callers: who they are and what they may do ([`auth`]), and
/// how much ([`quota`]).
///
/// [`auth`]: crate::auth
/// [`quota`]: crate::quota
pub struct Policy {
    /// Credentials and access rules.
    pub auth: Authenticator,
    /// Per-robot rates and store size.
    pub quotas: Quotas,
}

/// The service state shared by all requests.
#[derive(Clone)]
pub struct PlaceRecognitionService {
    pipeline: Pipeline,
    limits: Limits,
    auth: Authenticator,
    quotas: Arc<Quotas>,
}

impl PlaceRecognitionService {
    /// The service over a pipeline, with its request limits and policy.
    pub fn new(pipeline: Pipeline, limits: Limits, policy: Policy) -> Self {
        PlaceRecognitionService {
            pipeline,
            limits,
            auth: policy.auth,
            quotas: Arc::new(policy.quotas),
        }
    }
}

/// The handlers, one per RPC: authenticate, validate, check that the caller
/// may act for the robot the request names, call the pipeline, convert.
/// Their metrics are recorded by one layer around the server
/// (`rpc_metrics`).
#[tonic::async_trait]
impl PlaceRecognition for PlaceRecognitionService {
    #[tracing::instrument(skip_all, fields(robot, session, keyframe))]
    async fn insert(
        &self,
        request: Request<proto::InsertRequest>,
    ) -> Result<Response<proto::InsertResponse>, Status> {
        let caller = self.auth.caller("Insert", &request)?;
        let pending = validate::keyframe("keyframe", request.into_inner().keyframe, &self.limits)?;
        self.auth.check_acts_for(
            "Insert",
            &caller,
            "keyframe.robot_id",
            &pending.key.robot_id,
        )?;
        self.quotas.inserts(&pending.key.robot_id, 1)?;
        self.quotas
            .store_size(self.pipeline.store(), &[&pending.key])
            .await?;
        let span = tracing::Span::current();
        span.record("robot", pending.key.robot_id.as_str());
        span.record("session", pending.key.session_id.as_str());
        span.record("keyframe", pending.key.keyframe_id);
        let from_image = matches!(pending.observation, Observation::Image(..));
        let inserted = self.pipeline.insert(pending).await?;
        let outcome = inserted.stored.outcome;
        Ok(Response::new(proto::InsertResponse {
            replaced: outcome.replaced > 0,
            store_keyframes: outcome.store_keyframes,
            timings: convert::timings(&inserted.timings),
            features: from_image.then(|| convert::features(&inserted.features)),
            log_sequence: inserted.stored.log_sequence,
        }))
    }

    #[tracing::instrument(skip_all, fields(keyframes))]
    async fn insert_batch(
        &self,
        request: Request<proto::InsertBatchRequest>,
    ) -> Result<Response<proto::InsertBatchResponse>, Status> {
        let caller = self.auth.caller("InsertBatch", &request)?;
        let pending = validate::batch(request.into_inner().keyframes, &self.limits)?;
        for (i, keyframe) in pending.iter().enumerate() {
            self.auth.check_acts_for(
                "InsertBatch",
                &caller,
                &format!("keyframes[{i}].robot_id"),
                &keyframe.key.robot_id,
            )?;
        }
        let mut per_robot: std::collections::BTreeMap<&str, usize> = Default::default();
        for keyframe in &pending {
            *per_robot.entry(keyframe.key.robot_id.as_str()).or_default() += 1;
        }
        for (robot, n) in per_robot {
            self.quotas.inserts(robot, n)?;
        }
        let keys: Vec<_> = pending.iter().map(|k| &k.key).collect();
        self.quotas.store_size(self.pipeline.store(), &keys).await?;
        tracing::Span::current().record("keyframes", pending.len());
        let stored = self.pipeline.insert_batch(pending).await?;
        Ok(Response::new(proto::InsertBatchResponse {
            replaced: u32::try_from(stored.outcome.replaced).unwrap_or(u32::MAX),
            store_keyframes: stored.outcome.store_keyframes,
            log_sequence: stored.log_sequence,
        }))
    }

    #[tracing::instrument(skip_all, fields(robot, session, map, frame))]
    async fn query(
        &self,
        request: Request<proto::QueryRequest>,
    ) -> Result<Response<proto::QueryResponse>, Status> {
        let deadline = request
            .metadata()
            .get("grpc-timeout")
            .and_then(|v| v.to_str().ok())
            .and_then(crate::pipeline::admission::grpc_timeout);
        let caller = self.auth.caller("Query", &request)?;
        let min_log_sequence = request.get_ref().min_log_sequence.unwrap_or(0);
        let mut spec = validate::query(request.into_inner(), &self.limits)?;
        self.auth
            .check_acts_for("Query", &caller, "robot_id", &spec.session.robot_id)?;
        self.quotas.query(&spec.session.robot_id)?;
        // Every scope is narrowed to the robots the caller may read.
        spec.readable_robots = caller.readable_robots(&self.auth.rules().groups);
        let span = tracing::Span::current();
        span.record("robot", spec.session.robot_id.as_str());
        span.record("session", spec.session.session_id.as_str());
        if let Some(map) = spec.map_id {
            span.record("map", map);
        }
        if let Some(frame) = spec.frame_id {
            span.record("frame", frame);
        }
        // Read-your-writes: the answer waits for this replica to apply the
        // write log up to the client's last write.
        self.pipeline
            .wait_for_log(min_log_sequence, deadline)
            .await?;
        let outcome = match self.pipeline.query(spec, deadline).await? {
            QueryAnswer::Superseded => {
                return Ok(Response::new(proto::QueryResponse {
                    status: proto::QueryStatus::Superseded as i32,
                    ..Default::default()
                }))
            }
            QueryAnswer::Answered(outcome) => outcome,
        };
        Ok(Response::new(convert::query_response(&outcome)))
    }

    #[tracing::instrument(skip_all)]
    async fn erase(
        &self,
        request: Request<proto::EraseRequest>,
    ) -> Result<Response<proto::EraseResponse>, Status> {
        let caller = self.auth.caller("Erase", &request)?;
        let (session, keyframe_ids) = validate::erase(request.get_ref())?;
        self.auth
            .check_acts_for("Erase", &caller, "robot_id", &session.robot_id)?;
        let outcome = self
            .pipeline
            .apply(Mutation::Erase {
                session,
                keyframe_ids,
            })
            .await?;
        Ok(Response::new(proto::EraseResponse {
            erased: outcome.outcome.affected,
            log_sequence: outcome.log_sequence,
        }))
    }

    #[tracing::instrument(skip_all)]
    async fn reset_map(
        &self,
        request: Request<proto::ResetMapRequest>,
    ) -> Result<Response<proto::ResetMapResponse>, Status> {
        let caller = self.auth.caller("ResetMap", &request)?;
        let r = request.get_ref();
        let session = validate::session("", &r.robot_id, &r.session_id)?;
        self.auth
            .check_acts_for("ResetMap", &caller, "robot_id", &session.robot_id)?;
        let map_id = r.map_id.ok_or_else(|| InvalidField {
            field: "map_id".into(),
            reason: "required".into(),
        })?;
        let outcome = self
            .pipeline
            .apply(Mutation::ResetMap(MapKey { session, map_id }))
            .await?;
        Ok(Response::new(proto::ResetMapResponse {
            erased: outcome.outcome.affected,
            log_sequence: outcome.log_sequence,
        }))
    }

    #[tracing::instrument(skip_all)]
    async fn reset_session(
        &self,
        request: Request<proto::ResetSessionRequest>,
    ) -> Result<Response<proto::ResetSessionResponse>, Status> {
        let caller = self.auth.caller("ResetSession", &request)?;
        let r = request.get_ref();
        let session = validate::session("", &r.robot_id, &r.session_id)?;
        self.auth
            .check_acts_for("ResetSession", &caller, "robot_id", &session.robot_id)?;
        let outcome = self.pipeline.apply(Mutation::ResetSession(session)).await?;
        Ok(Response::new(proto::ResetSessionResponse {
            erased: outcome.outcome.affected,
            log_sequence: outcome.log_sequence,
        }))
    }

    #[tracing::instrument(skip_all)]
    async fn update_poses(
        &self,
        request: Request<proto::UpdatePosesRequest>,
    ) -> Result<Response<proto::UpdatePosesResponse>, Status> {
        let caller = self.auth.caller("UpdatePoses", &request)?;
        let (session, updates) = validate::pose_updates(request.get_ref())?;
        self.auth
            .check_acts_for("UpdatePoses", &caller, "robot_id", &session.robot_id)?;
        let outcome = self
            .pipeline
            .apply(Mutation::UpdatePoses { session, updates })
            .await?;
        Ok(Response::new(proto::UpdatePosesResponse {
            updated: outcome.outcome.affected,
            missing_keyframe_ids: outcome.outcome.missing,
            log_sequence: outcome.log_sequence,
        }))
    }

    #[tracing::instrument(skip_all, fields(robot, kind, accepted))]
    async fn report_verification(
        &self,
        request: Request<proto::ReportVerificationRequest>,
    ) -> Result<Response<proto::ReportVerificationResponse>, Status> {
        let caller = self.auth.caller("ReportVerification", &request)?;
        let mut verdict = validate::verification(request.get_ref())?;
        // A verdict is a write of the robot that asked the query.
        self.auth.check_acts_for(
            "ReportVerification",
            &caller,
            "robot_id",
            &verdict.query.robot_id,
        )?;
        // It may only name a candidate the robot may read (one HuMem could
        // have proposed to it).
        if let Some(readable) = caller.readable_robots(&self.auth.rules().groups) {
            if !readable.contains(&verdict.candidate.robot_id) {
                return Err(Status::permission_denied(format!(
                    "candidate.robot_id: this caller may not read robot {:?}",
                    verdict.candidate.robot_id
                )));
            }
        }
        let span = tracing::Span::current();
        span.record("robot", verdict.query.robot_id.as_str());
        span.record("kind", tracing::field::debug(verdict.kind));
        span.record("accepted", verdict.accepted);
        verdict.reported_at = unix_now();
        let stored = self
            .pipeline
            .apply(Mutation::ReportVerdict(verdict))
            .await?;
        Ok(Response::new(proto::ReportVerificationResponse {
            replaced: stored.outcome.replaced > 0,
            store_verdicts: stored.outcome.store_verdicts,
            log_sequence: stored.log_sequence,
        }))
    }

    async fn stats(
        &self,
        request: Request<proto::StatsRequest>,
    ) -> Result<Response<proto::StatsResponse>, Status> {
        let caller = self.auth.caller("Stats", &request)?;
        // A caller that may read only some robots hears only of those: the
        // maps, keyframes and verdicts of its readable robots, and not the
        // size of a store that holds everyone's (disk_bytes 0).
        let readable = caller.readable_robots(&self.auth.rules().groups);
        let may_read = |robot: &str| {
            readable
                .as_ref()
                .is_none_or(|r| r.iter().any(|x| x == robot))
        };
        let (keyframes, descriptor_dim, maps, verdicts, point, graph) = {
            let index = self.pipeline.store().index_async().await;
            let graph = index
                .neighbour_graph()
                .filter(|_| readable.is_none())
                .map(|graph| {
                    let params = self.pipeline.params();
                    let (map_graphs, map_keyframes, map_bytes) = index.map_graphs();
                    let map_waiting = index.map_graphs_waiting();
                    proto::NeighbourGraphStats {
                        keyframes: (index.len() - index.neighbour_graph_missing()) as u64,
                        missing: index.neighbour_graph_missing() as u64,
                        memory_bytes: graph.memory_bytes() as u64,
                        loaded: self.pipeline.store().opened().graph
                            == Some(humem_store::graph_file::GraphSource::Loaded),
                        approximate_from: if params.exact {
                            0
                        } else {
                            params.approximate_from as u64
                        },
                        waiting: (index.neighbour_graph_waiting() - map_waiting) as u64,
                        map_graphs: map_graphs as u64,
                        map_graph_keyframes: map_keyframes as u64,
                        map_graph_memory_bytes: map_bytes as u64,
                        map_graph_waiting: map_waiting as u64,
                    }
                });
            let point = index.operating_point(self.pipeline.params(), unix_now());
            let maps: Vec<proto::MapStats> = index
                .map_counts()
                .into_iter()
                .filter(|(map, _)| may_read(&map.session.robot_id))
                .map(|(map, count)| proto::MapStats {
                    robot_id: map.session.robot_id,
                    session_id: map.session.session_id,
                    map_id: map.map_id,
                    keyframes: count as u64,
                })
                .collect();
            let (keyframes, verdicts) = match &readable {
                None => (index.len() as u64, index.verdicts().len() as u64),
                Some(_) => (
                    maps.iter().map(|m| m.keyframes).sum(),
                    index
                        .verdicts()
                        .iter()
                        .filter(|v| may_read(&v.query.robot_id))
                        .count() as u64,
                ),
            };
            (keyframes, index.dim() as u32, maps, verdicts, point, graph)
        };
        let disk_bytes = match readable {
            None => self.pipeline.store().disk_bytes(),
            Some(_) => 0,
        };
        Ok(Response::new(proto::StatsResponse {
            keyframes,
            descriptor_dim,
            maps,
            disk_bytes,
            format_version: humem_store::STORE_FORMAT,
            server_version: env!("CARGO_PKG_VERSION").into(),
            log_position: self.pipeline.log_position(),
            verdicts,
            operating_point: Some(proto::OperatingPoint {
                threshold: point.threshold,
                configured_threshold: self.pipeline.params().threshold(),
                estimated_precision: point.estimated_precision,
                configured_precision: point.base_precision,
                verdicts: point.verdicts as u64,
            }),
            neighbour_graph: graph,
        }))
    }
}
