//! Domain values to protobuf messages (the way out; the way in is
//! [`super::validate`]), and domain errors to gRPC statuses.

use tonic::Status;

use std::time::Duration;

use crate::pipeline::query::{Candidate, QueryError, QueryOutcome};
use crate::pipeline::PipelineError;
use crate::proto;
use humem_cluster::ClusterError;
use humem_core::keyframe::{Features, Pose};
use humem_perception::batcher::BatchError;
use humem_perception::PerceptionError;
use humem_store::StoreError;

/// A pose as its message: translation and `(w, x, y, z)` quaternion.
pub fn pose(p: &Pose) -> proto::Pose {
    let [x, y, z] = p.translation;
    let [w, qx, qy, qz] = p.rotation;
    proto::Pose {
        translation: Some(proto::Vec3 { x, y, z }),
        rotation: Some(proto::Quaternion {
            w,
            x: qx,
            y: qy,
            z: qz,
        }),
    }
}

fn index(i: usize) -> u32 {
    u32::try_from(i).unwrap_or(u32::MAX)
}

/// A candidate as its message, with its evidence spelled out (object
/// indices saturate at `u32::MAX`).
pub fn candidate(c: &Candidate) -> proto::Candidate {
    proto::Candidate {
        robot_id: c.key.robot_id.clone(),
        session_id: c.key.session_id.clone(),
        keyframe_id: c.key.keyframe_id,
        frame_id: c.frame_id,
        map_id: c.map_id,
        timestamp: c.timestamp,
        pose: Some(pose(&c.pose)),
        score: c.score,
        evidence: Some(proto::Evidence {
            scene_score: c.scene.score,
            descriptor_cosine: c.scene.cosine,
            scene_compatibility: c.scene.scene_compatibility,
            temporal_depth: index(c.scene.depth),
            object_score: c.object_score,
            text_score: c.text_score,
            text_distinctiveness: c.text_distinctiveness,
            corroboration: c.corroboration,
            object_matches: c
                .object_matches
                .iter()
                .map(|m| proto::ObjectMatch {
                    query_object: index(m.matched.query_object),
                    candidate_object: index(m.matched.candidate_object),
                    class_name: m.class_name.clone(),
                    affinity: m.matched.affinity,
                    spatial: m.matched.spatial,
                })
                .collect(),
            text_matches: c
                .text_matches
                .iter()
                .map(|m| proto::TextMatch {
                    query_object: index(m.matched.query_object),
                    candidate_object: index(m.matched.candidate_object),
                    query_text: m.query_text.clone(),
                    candidate_text: m.candidate_text.clone(),
                    similarity: m.matched.similarity,
                    score: m.matched.score,
                    distinctiveness: m.matched.distinctiveness,
                })
                .collect(),
            raw_score: c.raw_score,
            scene_confidence: c.scene_confidence,
            null_median: c.null.location,
            null_samples: c.null.samples as u64,
            contradiction: c.contradiction.score,
            text_contradiction: c.contradiction.text,
            object_absence: c.contradiction.absence,
            verdict_penalty: c.verdict.penalty,
            verdict_support: c.verdict.support,
            verdict_rejections: c.verdict.rejections,
            verdict_acceptances: c.verdict.acceptances,
            drift: c.drift.map(|d| proto::DriftEnvelope {
                distance: d.distance,
                path: d.path,
                ratio: d.ratio(),
                allowance: d.allowance,
                penalty: d.penalty,
            }),
            text_conflicts: c
                .text_conflicts
                .iter()
                .map(|p| proto::TextConflict {
                    query_object: index(p.conflict.query_object),
                    candidate_object: index(p.conflict.candidate_object),
                    query_text: p.query_text.clone(),
                    candidate_text: p.candidate_text.clone(),
                    agreement: p.conflict.agreement,
                    conflict: p.conflict.conflict,
                })
                .collect(),
            missing_objects: c
                .missing_objects
                .iter()
                .map(|p| proto::MissingObject {
                    in_query: p.missing.in_query,
                    object: index(p.missing.object),
                    class_name: p.class_name.clone(),
                    weight: p.missing.weight,
                })
                .collect(),
        }),
    }
}

/// Per-stage times as messages, in seconds.
pub fn timings(timings: &[(&'static str, Duration)]) -> Vec<proto::StageTiming> {
    timings
        .iter()
        .map(|(stage, d)| proto::StageTiming {
            stage: (*stage).to_string(),
            seconds: d.as_secs_f64(),
        })
        .collect()
}

/// Features as their message, e.g. those computed from a sent image.
pub fn features(f: &Features) -> proto::Features {
    proto::Features {
        global_descriptor: f.descriptor.clone(),
        appearance: f.appearance.iter().map(|&v| v as u8).collect(),
        scene: f
            .scene
            .iter()
            .map(|c| proto::SceneClass {
                class_id: c.class_id,
                probability: c.probability,
            })
            .collect(),
        objects: f
            .objects
            .iter()
            .map(|o| proto::ObjectObservation {
                class_name: o.class_name.clone(),
                confidence: o.confidence,
                x: o.centroid[0],
                y: o.centroid[1],
                area: o.area,
                texts: o
                    .texts
                    .iter()
                    .map(|t| proto::TextObservation {
                        text: t.text.clone(),
                        confidence: t.confidence,
                    })
                    .collect(),
            })
            .collect(),
    }
}

/// A perception failure as a status naming the image field.
fn perception_status(field: &str, e: PerceptionError) -> Status {
    match e {
        PerceptionError::Image(e) => Status::invalid_argument(format!("{field}.{e}")),
        PerceptionError::Model(BatchError::Busy { .. }) => {
            let mut status = Status::resource_exhausted(e.to_string());
            status.metadata_mut().insert(
                "retry-after-ms",
                tonic::metadata::MetadataValue::from(20u32),
            );
            status
        }
        PerceptionError::Model(BatchError::Stopped { .. }) => Status::unavailable(e.to_string()),
        other => {
            tracing::error!(error = %other, "perception failed");
            Status::internal(other.to_string())
        }
    }
}

/// The response of an answered query (superseded queries are answered
/// elsewhere).
pub fn query_response(outcome: &QueryOutcome) -> proto::QueryResponse {
    proto::QueryResponse {
        candidates: outcome.candidates.iter().map(candidate).collect(),
        eligible_keyframes: outcome.eligible,
        used_predecessor_ids: outcome.used_predecessors.clone(),
        timings: timings(&outcome.timings),
        status: proto::QueryStatus::Answered as i32,
        threshold: outcome.threshold,
        operating_threshold: outcome.operating_point.threshold,
    }
}

/// The status a store error answers with.
fn store_status(e: StoreError) -> Status {
    match e {
        StoreError::DimensionMismatch { .. } => {
            Status::invalid_argument(format!("features.global_descriptor: {e}"))
        }
        StoreError::QueueFull { .. } => {
            let mut status = Status::resource_exhausted(e.to_string());
            status.metadata_mut().insert(
                "retry-after-ms",
                tonic::metadata::MetadataValue::from(50u32),
            );
            status
        }
        StoreError::DiskFull { .. } => {
            let mut status = Status::resource_exhausted(e.to_string());
            status.metadata_mut().insert(
                "retry-after-ms",
                tonic::metadata::MetadataValue::from(60_000u32),
            );
            status
        }
        StoreError::QuotaExceeded { .. } => crate::quota::exhausted(
            "store_size",
            e.to_string(),
            std::time::Duration::from_secs(60),
        ),
        StoreError::WriterGone => Status::unavailable(e.to_string()),
        StoreError::UnknownKeyframe { role, .. } => {
            let field = if role == "query" {
                "keyframe_id"
            } else {
                "candidate"
            };
            Status::not_found(format!("{field}: {e}"))
        }
        _ => {
            tracing::error!(error = %e, "store failure");
            Status::internal(e.to_string())
        }
    }
}

/// Cluster errors: a change refused for what it is keeps its store status;
/// the write log or a replica not reachable or behind is UNAVAILABLE (retry,
/// maybe on another replica); a change too large is INVALID_ARGUMENT.
fn cluster_status(e: ClusterError) -> Status {
    match e {
        ClusterError::Store(e) => store_status(e),
        ClusterError::TooLarge(_) => Status::invalid_argument(e.to_string()),
        ClusterError::Config(_) | ClusterError::Diverged(_) => Status::internal(e.to_string()),
        ClusterError::Nats(_)
        | ClusterError::NotApplied { .. }
        | ClusterError::Behind { .. }
        | ClusterError::Halted(_) => Status::unavailable(e.to_string()),
    }
}

impl From<PipelineError> for Status {
    fn from(e: PipelineError) -> Status {
        match e {
            PipelineError::Invalid(field) => field.into(),
            PipelineError::NoPerception { .. } => Status::failed_precondition(e.to_string()),
            PipelineError::Perception { field, source } => perception_status(&field, source),
            PipelineError::Store(e) => store_status(e),
            PipelineError::Query(e) => e.into(),
            PipelineError::Task(_) => Status::internal(e.to_string()),
            PipelineError::NotClustered => Status::failed_precondition(e.to_string()),
            PipelineError::Cluster(e) => cluster_status(e),
            PipelineError::Busy(busy) => {
                let mut status = Status::resource_exhausted(busy.to_string());
                let retry = u32::try_from(busy.expected.as_millis()).unwrap_or(u32::MAX);
                status.metadata_mut().insert(
                    "retry-after-ms",
                    tonic::metadata::MetadataValue::from(retry.max(1)),
                );
                status
            }
        }
    }
}

impl From<QueryError> for Status {
    fn from(e: QueryError) -> Status {
        match e {
            QueryError::Invalid(field) => field.into(),
            QueryError::NotStored(_) => Status::not_found(format!("keyframe_id: {e}")),
        }
    }
}

impl From<super::validate::InvalidField> for Status {
    fn from(e: super::validate::InvalidField) -> Status {
        Status::invalid_argument(e.to_string())
    }
}
