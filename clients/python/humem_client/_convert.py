"""Conversion between the typed values of ``humem_client.types`` and the
generated protobuf messages of ``humem_client.proto.humem_pb2``."""

from __future__ import annotations

from typing import Optional

import numpy as np

from .proto import humem_pb2 as pb
from .types import (
    Candidate,
    DriftEnvelope,
    EraseResult,
    Evidence,
    Features,
    Image,
    InsertBatchResult,
    InsertResult,
    Keyframe,
    MapStats,
    NeighbourGraphStats,
    MissingObject,
    ObjectMatch,
    ObjectObservation,
    OperatingPoint,
    Pose,
    Query,
    QueryResult,
    QueryStatus,
    Stats,
    TextConflict,
    TextMatch,
    TextObservation,
    UpdatePosesResult,
    VerificationResult,
    as_features,
    as_image,
)

# --- to messages -------------------------------------------------------------


def pose_to_proto(pose: Pose) -> pb.Pose:
    t, q = pose.translation, pose.rotation
    return pb.Pose(
        translation=pb.Vec3(x=float(t[0]), y=float(t[1]), z=float(t[2])),
        rotation=pb.Quaternion(w=float(q[0]), x=float(q[1]), y=float(q[2]), z=float(q[3])),
    )


def features_to_proto(features: Features) -> pb.Features:
    message = pb.Features(
        global_descriptor=features.global_descriptor.tolist(),
        scene=[pb.SceneClass(class_id=k, probability=v) for k, v in features.scene.items()],
        objects=[
            pb.ObjectObservation(
                class_name=o.class_name,
                confidence=o.confidence,
                x=o.x,
                y=o.y,
                area=o.area,
                texts=[pb.TextObservation(text=t.text, confidence=t.confidence) for t in o.texts],
            )
            for o in features.objects
        ],
    )
    if features.appearance is not None:
        message.appearance = features.appearance.astype(np.int8).tobytes()
    return message


def image_to_proto(image: Image) -> pb.Image:
    return pb.Image(
        encoding=int(image.encoding),
        data=image.data,
        width=image.width,
        height=image.height,
        stride=image.stride,
    )


def _content(message, features, image, owner: str) -> None:
    if features is not None and image is not None:
        raise ValueError(f"{owner}: give features or image, not both")
    if features is not None:
        message.features.CopyFrom(features_to_proto(as_features(features)))
    elif image is not None:
        message.image.CopyFrom(image_to_proto(as_image(image)))


def keyframe_to_proto(kf: Keyframe, robot_id: str, session_id: str) -> pb.Keyframe:
    message = pb.Keyframe(
        robot_id=robot_id if kf.robot_id is None else kf.robot_id,
        session_id=session_id if kf.session_id is None else kf.session_id,
        keyframe_id=kf.keyframe_id,
        frame_id=kf.frame_id,
        timestamp=kf.timestamp,
        map_id=kf.map_id,
        pose=pose_to_proto(kf.pose),
    )
    _content(message, kf.features, kf.image, "Keyframe")
    return message


def query_to_proto(q: Query, robot_id: str, session_id: str) -> pb.QueryRequest:
    message = pb.QueryRequest(
        robot_id=robot_id if q.robot_id is None else q.robot_id,
        session_id=session_id if q.session_id is None else q.session_id,
        predecessor_keyframe_ids=list(q.predecessor_keyframe_ids),
        scope=int(q.scope),
        robot_ids=list(q.robot_ids),
        maps=[pb.MapRef(robot_id=m.robot_id, session_id=m.session_id, map_id=m.map_id) for m in q.maps],
        layers=int(q.layers),
        kind=int(q.kind),
        exact=q.exact,
    )
    for name in ("map_id", "frame_id", "keyframe_id", "min_frame_gap", "top_n", "threshold", "min_log_sequence"):
        value = getattr(q, name)
        if value is not None:
            setattr(message, name, value)
    _content(message, q.features, q.image, "Query")
    return message


# --- from messages -----------------------------------------------------------


def pose_from_proto(message: pb.Pose) -> Pose:
    t, q = message.translation, message.rotation
    return Pose(translation=[t.x, t.y, t.z], rotation=[q.w, q.x, q.y, q.z])


def features_from_proto(message: pb.Features) -> Features:
    return Features(
        global_descriptor=np.array(message.global_descriptor, dtype=np.float32),
        scene={s.class_id: s.probability for s in message.scene},
        objects=[
            ObjectObservation(
                class_name=o.class_name,
                confidence=o.confidence,
                x=o.x,
                y=o.y,
                area=o.area,
                texts=[TextObservation(t.text, t.confidence) for t in o.texts],
            )
            for o in message.objects
        ],
        appearance=np.frombuffer(message.appearance, dtype=np.int8) if message.appearance else None,
    )


def _plain(cls, message, **overrides):
    """cls(**fields of `message` named like cls's fields), with overrides."""
    names = cls.__dataclass_fields__.keys()
    values = {n: getattr(message, n) for n in names if n not in overrides}
    values.update(overrides)
    return cls(**values)


def _optional(message, name: str) -> Optional[float]:
    return getattr(message, name) if message.HasField(name) else None


def evidence_from_proto(e: pb.Evidence) -> Evidence:
    return _plain(
        Evidence,
        e,
        scene_compatibility=_optional(e, "scene_compatibility"),
        object_matches=tuple(_plain(ObjectMatch, m) for m in e.object_matches),
        text_matches=tuple(_plain(TextMatch, m) for m in e.text_matches),
        text_conflicts=tuple(_plain(TextConflict, c) for c in e.text_conflicts),
        missing_objects=tuple(_plain(MissingObject, m) for m in e.missing_objects),
        drift=_plain(DriftEnvelope, e.drift) if e.HasField("drift") else None,
    )


def candidate_from_proto(c: pb.Candidate) -> Candidate:
    return _plain(Candidate, c, pose=pose_from_proto(c.pose), evidence=evidence_from_proto(c.evidence))


def _timings(timings) -> dict:
    return {t.stage: t.seconds for t in timings}


def query_result_from_proto(r: pb.QueryResponse) -> QueryResult:
    return _plain(
        QueryResult,
        r,
        status=QueryStatus(r.status),
        candidates=tuple(candidate_from_proto(c) for c in r.candidates),
        used_predecessor_ids=tuple(r.used_predecessor_ids),
        timings=_timings(r.timings),
    )


def insert_result_from_proto(r: pb.InsertResponse) -> InsertResult:
    return _plain(
        InsertResult,
        r,
        timings=_timings(r.timings),
        features=features_from_proto(r.features) if r.HasField("features") else None,
    )


def insert_batch_result_from_proto(r: pb.InsertBatchResponse) -> InsertBatchResult:
    return _plain(InsertBatchResult, r)


def erase_result_from_proto(r) -> EraseResult:
    return _plain(EraseResult, r)


def update_poses_result_from_proto(r: pb.UpdatePosesResponse) -> UpdatePosesResult:
    return _plain(UpdatePosesResult, r, missing_keyframe_ids=tuple(r.missing_keyframe_ids))


def verification_result_from_proto(r: pb.ReportVerificationResponse) -> VerificationResult:
    return _plain(VerificationResult, r)


def stats_from_proto(r: pb.StatsResponse) -> Stats:
    op = None
    if r.HasField("operating_point"):
        p = r.operating_point
        op = _plain(
            OperatingPoint,
            p,
            estimated_precision=_optional(p, "estimated_precision"),
            configured_precision=_optional(p, "configured_precision"),
        )
    graph = _plain(NeighbourGraphStats, r.neighbour_graph) if r.HasField("neighbour_graph") else None
    return _plain(
        Stats,
        r,
        maps=tuple(_plain(MapStats, m) for m in r.maps),
        operating_point=op,
        neighbour_graph=graph,
    )
