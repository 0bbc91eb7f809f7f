from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class Scope(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    SCOPE_UNSPECIFIED: _ClassVar[Scope]
    SCOPE_SAME_MAP: _ClassVar[Scope]
    SCOPE_OTHER_MAPS: _ClassVar[Scope]
    SCOPE_ALL_MAPS: _ClassVar[Scope]
    SCOPE_LISTED: _ClassVar[Scope]

class Layers(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    LAYERS_UNSPECIFIED: _ClassVar[Layers]
    LAYERS_SCAL: _ClassVar[Layers]
    LAYERS_SCAL_OSRL: _ClassVar[Layers]
    LAYERS_SCAL_OGTL: _ClassVar[Layers]
    LAYERS_FULL: _ClassVar[Layers]
    LAYERS_FULL_SUPPORT_ONLY: _ClassVar[Layers]

class QueryKind(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    QUERY_KIND_UNSPECIFIED: _ClassVar[QueryKind]
    QUERY_KIND_LOOP_CLOSURE: _ClassVar[QueryKind]
    QUERY_KIND_RELOCALISATION: _ClassVar[QueryKind]

class QueryStatus(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    QUERY_STATUS_UNSPECIFIED: _ClassVar[QueryStatus]
    QUERY_STATUS_ANSWERED: _ClassVar[QueryStatus]
    QUERY_STATUS_SUPERSEDED: _ClassVar[QueryStatus]

class VerificationKind(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    VERIFICATION_KIND_UNSPECIFIED: _ClassVar[VerificationKind]
    VERIFICATION_KIND_LOOP: _ClassVar[VerificationKind]
    VERIFICATION_KIND_MERGE: _ClassVar[VerificationKind]
    VERIFICATION_KIND_RELOCALISATION: _ClassVar[VerificationKind]

class VerificationOutcome(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    VERIFICATION_OUTCOME_UNSPECIFIED: _ClassVar[VerificationOutcome]
    VERIFICATION_OUTCOME_ACCEPTED: _ClassVar[VerificationOutcome]
    VERIFICATION_OUTCOME_REJECTED: _ClassVar[VerificationOutcome]
SCOPE_UNSPECIFIED: Scope
SCOPE_SAME_MAP: Scope
SCOPE_OTHER_MAPS: Scope
SCOPE_ALL_MAPS: Scope
SCOPE_LISTED: Scope
LAYERS_UNSPECIFIED: Layers
LAYERS_SCAL: Layers
LAYERS_SCAL_OSRL: Layers
LAYERS_SCAL_OGTL: Layers
LAYERS_FULL: Layers
LAYERS_FULL_SUPPORT_ONLY: Layers
QUERY_KIND_UNSPECIFIED: QueryKind
QUERY_KIND_LOOP_CLOSURE: QueryKind
QUERY_KIND_RELOCALISATION: QueryKind
QUERY_STATUS_UNSPECIFIED: QueryStatus
QUERY_STATUS_ANSWERED: QueryStatus
QUERY_STATUS_SUPERSEDED: QueryStatus
VERIFICATION_KIND_UNSPECIFIED: VerificationKind
VERIFICATION_KIND_LOOP: VerificationKind
VERIFICATION_KIND_MERGE: VerificationKind
VERIFICATION_KIND_RELOCALISATION: VerificationKind
VERIFICATION_OUTCOME_UNSPECIFIED: VerificationOutcome
VERIFICATION_OUTCOME_ACCEPTED: VerificationOutcome
VERIFICATION_OUTCOME_REJECTED: VerificationOutcome

class Vec3(_message.Message):
    __slots__ = ("x", "y", "z")
    X_FIELD_NUMBER: _ClassVar[int]
    Y_FIELD_NUMBER: _ClassVar[int]
    Z_FIELD_NUMBER: _ClassVar[int]
    x: float
    y: float
    z: float
    def __init__(self, x: _Optional[float] = ..., y: _Optional[float] = ..., z: _Optional[float] = ...) -> None: ...

class Quaternion(_message.Message):
    __slots__ = ("w", "x", "y", "z")
    W_FIELD_NUMBER: _ClassVar[int]
    X_FIELD_NUMBER: _ClassVar[int]
    Y_FIELD_NUMBER: _ClassVar[int]
    Z_FIELD_NUMBER: _ClassVar[int]
    w: float
    x: float
    y: float
    z: float
    def __init__(self, w: _Optional[float] = ..., x: _Optional[float] = ..., y: _Optional[float] = ..., z: _Optional[float] = ...) -> None: ...

class Pose(_message.Message):
    __slots__ = ("translation", "rotation")
    TRANSLATION_FIELD_NUMBER: _ClassVar[int]
    ROTATION_FIELD_NUMBER: _ClassVar[int]
    translation: Vec3
    rotation: Quaternion
    def __init__(self, translation: _Optional[_Union[Vec3, _Mapping]] = ..., rotation: _Optional[_Union[Quaternion, _Mapping]] = ...) -> None: ...

class SceneClass(_message.Message):
    __slots__ = ("class_id", "probability")
    CLASS_ID_FIELD_NUMBER: _ClassVar[int]
    PROBABILITY_FIELD_NUMBER: _ClassVar[int]
    class_id: int
    probability: float
    def __init__(self, class_id: _Optional[int] = ..., probability: _Optional[float] = ...) -> None: ...

class TextObservation(_message.Message):
    __slots__ = ("text", "confidence")
    TEXT_FIELD_NUMBER: _ClassVar[int]
    CONFIDENCE_FIELD_NUMBER: _ClassVar[int]
    text: str
    confidence: float
    def __init__(self, text: _Optional[str] = ..., confidence: _Optional[float] = ...) -> None: ...

class ObjectObservation(_message.Message):
    __slots__ = ("class_name", "confidence", "x", "y", "area", "texts")
    CLASS_NAME_FIELD_NUMBER: _ClassVar[int]
    CONFIDENCE_FIELD_NUMBER: _ClassVar[int]
    X_FIELD_NUMBER: _ClassVar[int]
    Y_FIELD_NUMBER: _ClassVar[int]
    AREA_FIELD_NUMBER: _ClassVar[int]
    TEXTS_FIELD_NUMBER: _ClassVar[int]
    class_name: str
    confidence: float
    x: float
    y: float
    area: float
    texts: _containers.RepeatedCompositeFieldContainer[TextObservation]
    def __init__(self, class_name: _Optional[str] = ..., confidence: _Optional[float] = ..., x: _Optional[float] = ..., y: _Optional[float] = ..., area: _Optional[float] = ..., texts: _Optional[_Iterable[_Union[TextObservation, _Mapping]]] = ...) -> None: ...

class Image(_message.Message):
    __slots__ = ("encoding", "data", "width", "height", "stride")
    class Encoding(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        ENCODING_UNSPECIFIED: _ClassVar[Image.Encoding]
        ENCODING_JPEG: _ClassVar[Image.Encoding]
        ENCODING_PNG: _ClassVar[Image.Encoding]
        ENCODING_GRAY8: _ClassVar[Image.Encoding]
        ENCODING_RGB8: _ClassVar[Image.Encoding]
        ENCODING_BGR8: _ClassVar[Image.Encoding]
    ENCODING_UNSPECIFIED: Image.Encoding
    ENCODING_JPEG: Image.Encoding
    ENCODING_PNG: Image.Encoding
    ENCODING_GRAY8: Image.Encoding
    ENCODING_RGB8: Image.Encoding
    ENCODING_BGR8: Image.Encoding
    ENCODING_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    STRIDE_FIELD_NUMBER: _ClassVar[int]
    encoding: Image.Encoding
    data: bytes
    width: int
    height: int
    stride: int
    def __init__(self, encoding: _Optional[_Union[Image.Encoding, str]] = ..., data: _Optional[bytes] = ..., width: _Optional[int] = ..., height: _Optional[int] = ..., stride: _Optional[int] = ...) -> None: ...

class Features(_message.Message):
    __slots__ = ("global_descriptor", "scene", "objects", "appearance")
    GLOBAL_DESCRIPTOR_FIELD_NUMBER: _ClassVar[int]
    SCENE_FIELD_NUMBER: _ClassVar[int]
    OBJECTS_FIELD_NUMBER: _ClassVar[int]
    APPEARANCE_FIELD_NUMBER: _ClassVar[int]
    global_descriptor: _containers.RepeatedScalarFieldContainer[float]
    scene: _containers.RepeatedCompositeFieldContainer[SceneClass]
    objects: _containers.RepeatedCompositeFieldContainer[ObjectObservation]
    appearance: bytes
    def __init__(self, global_descriptor: _Optional[_Iterable[float]] = ..., scene: _Optional[_Iterable[_Union[SceneClass, _Mapping]]] = ..., objects: _Optional[_Iterable[_Union[ObjectObservation, _Mapping]]] = ..., appearance: _Optional[bytes] = ...) -> None: ...

class Keyframe(_message.Message):
    __slots__ = ("robot_id", "session_id", "keyframe_id", "frame_id", "timestamp", "map_id", "pose", "features", "image")
    ROBOT_ID_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    KEYFRAME_ID_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    MAP_ID_FIELD_NUMBER: _ClassVar[int]
    POSE_FIELD_NUMBER: _ClassVar[int]
    FEATURES_FIELD_NUMBER: _ClassVar[int]
    IMAGE_FIELD_NUMBER: _ClassVar[int]
    robot_id: str
    session_id: str
    keyframe_id: int
    frame_id: int
    timestamp: float
    map_id: int
    pose: Pose
    features: Features
    image: Image
    def __init__(self, robot_id: _Optional[str] = ..., session_id: _Optional[str] = ..., keyframe_id: _Optional[int] = ..., frame_id: _Optional[int] = ..., timestamp: _Optional[float] = ..., map_id: _Optional[int] = ..., pose: _Optional[_Union[Pose, _Mapping]] = ..., features: _Optional[_Union[Features, _Mapping]] = ..., image: _Optional[_Union[Image, _Mapping]] = ...) -> None: ...

class InsertRequest(_message.Message):
    __slots__ = ("keyframe",)
    KEYFRAME_FIELD_NUMBER: _ClassVar[int]
    keyframe: Keyframe
    def __init__(self, keyframe: _Optional[_Union[Keyframe, _Mapping]] = ...) -> None: ...

class InsertResponse(_message.Message):
    __slots__ = ("replaced", "store_keyframes", "timings", "features", "log_sequence")
    REPLACED_FIELD_NUMBER: _ClassVar[int]
    STORE_KEYFRAMES_FIELD_NUMBER: _ClassVar[int]
    TIMINGS_FIELD_NUMBER: _ClassVar[int]
    FEATURES_FIELD_NUMBER: _ClassVar[int]
    LOG_SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    replaced: bool
    store_keyframes: int
    timings: _containers.RepeatedCompositeFieldContainer[StageTiming]
    features: Features
    log_sequence: int
    def __init__(self, replaced: _Optional[bool] = ..., store_keyframes: _Optional[int] = ..., timings: _Optional[_Iterable[_Union[StageTiming, _Mapping]]] = ..., features: _Optional[_Union[Features, _Mapping]] = ..., log_sequence: _Optional[int] = ...) -> None: ...

class InsertBatchRequest(_message.Message):
    __slots__ = ("keyframes",)
    KEYFRAMES_FIELD_NUMBER: _ClassVar[int]
    keyframes: _containers.RepeatedCompositeFieldContainer[Keyframe]
    def __init__(self, keyframes: _Optional[_Iterable[_Union[Keyframe, _Mapping]]] = ...) -> None: ...

class InsertBatchResponse(_message.Message):
    __slots__ = ("replaced", "store_keyframes", "log_sequence")
    REPLACED_FIELD_NUMBER: _ClassVar[int]
    STORE_KEYFRAMES_FIELD_NUMBER: _ClassVar[int]
    LOG_SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    replaced: int
    store_keyframes: int
    log_sequence: int
    def __init__(self, replaced: _Optional[int] = ..., store_keyframes: _Optional[int] = ..., log_sequence: _Optional[int] = ...) -> None: ...

class MapRef(_message.Message):
    __slots__ = ("robot_id", "session_id", "map_id")
    ROBOT_ID_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    MAP_ID_FIELD_NUMBER: _ClassVar[int]
    robot_id: str
    session_id: str
    map_id: int
    def __init__(self, robot_id: _Optional[str] = ..., session_id: _Optional[str] = ..., map_id: _Optional[int] = ...) -> None: ...

class KeyframeRef(_message.Message):
    __slots__ = ("robot_id", "session_id", "keyframe_id")
    ROBOT_ID_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    KEYFRAME_ID_FIELD_NUMBER: _ClassVar[int]
    robot_id: str
    session_id: str
    keyframe_id: int
    def __init__(self, robot_id: _Optional[str] = ..., session_id: _Optional[str] = ..., keyframe_id: _Optional[int] = ...) -> None: ...

class QueryRequest(_message.Message):
    __slots__ = ("robot_id", "session_id", "map_id", "frame_id", "keyframe_id", "features", "image", "predecessor_keyframe_ids", "scope", "robot_ids", "maps", "min_frame_gap", "top_n", "threshold", "layers", "kind", "min_log_sequence", "exact")
    ROBOT_ID_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    MAP_ID_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    KEYFRAME_ID_FIELD_NUMBER: _ClassVar[int]
    FEATURES_FIELD_NUMBER: _ClassVar[int]
    IMAGE_FIELD_NUMBER: _ClassVar[int]
    PREDECESSOR_KEYFRAME_IDS_FIELD_NUMBER: _ClassVar[int]
    SCOPE_FIELD_NUMBER: _ClassVar[int]
    ROBOT_IDS_FIELD_NUMBER: _ClassVar[int]
    MAPS_FIELD_NUMBER: _ClassVar[int]
    MIN_FRAME_GAP_FIELD_NUMBER: _ClassVar[int]
    TOP_N_FIELD_NUMBER: _ClassVar[int]
    THRESHOLD_FIELD_NUMBER: _ClassVar[int]
    LAYERS_FIELD_NUMBER: _ClassVar[int]
    KIND_FIELD_NUMBER: _ClassVar[int]
    MIN_LOG_SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    EXACT_FIELD_NUMBER: _ClassVar[int]
    robot_id: str
    session_id: str
    map_id: int
    frame_id: int
    keyframe_id: int
    features: Features
    image: Image
    predecessor_keyframe_ids: _containers.RepeatedScalarFieldContainer[int]
    scope: Scope
    robot_ids: _containers.RepeatedScalarFieldContainer[str]
    maps: _containers.RepeatedCompositeFieldContainer[MapRef]
    min_frame_gap: int
    top_n: int
    threshold: float
    layers: Layers
    kind: QueryKind
    min_log_sequence: int
    exact: bool
    def __init__(self, robot_id: _Optional[str] = ..., session_id: _Optional[str] = ..., map_id: _Optional[int] = ..., frame_id: _Optional[int] = ..., keyframe_id: _Optional[int] = ..., features: _Optional[_Union[Features, _Mapping]] = ..., image: _Optional[_Union[Image, _Mapping]] = ..., predecessor_keyframe_ids: _Optional[_Iterable[int]] = ..., scope: _Optional[_Union[Scope, str]] = ..., robot_ids: _Optional[_Iterable[str]] = ..., maps: _Optional[_Iterable[_Union[MapRef, _Mapping]]] = ..., min_frame_gap: _Optional[int] = ..., top_n: _Optional[int] = ..., threshold: _Optional[float] = ..., layers: _Optional[_Union[Layers, str]] = ..., kind: _Optional[_Union[QueryKind, str]] = ..., min_log_sequence: _Optional[int] = ..., exact: _Optional[bool] = ...) -> None: ...

class ObjectMatch(_message.Message):
    __slots__ = ("query_object", "candidate_object", "class_name", "affinity", "spatial")
    QUERY_OBJECT_FIELD_NUMBER: _ClassVar[int]
    CANDIDATE_OBJECT_FIELD_NUMBER: _ClassVar[int]
    CLASS_NAME_FIELD_NUMBER: _ClassVar[int]
    AFFINITY_FIELD_NUMBER: _ClassVar[int]
    SPATIAL_FIELD_NUMBER: _ClassVar[int]
    query_object: int
    candidate_object: int
    class_name: str
    affinity: float
    spatial: float
    def __init__(self, query_object: _Optional[int] = ..., candidate_object: _Optional[int] = ..., class_name: _Optional[str] = ..., affinity: _Optional[float] = ..., spatial: _Optional[float] = ...) -> None: ...

class TextMatch(_message.Message):
    __slots__ = ("query_object", "candidate_object", "query_text", "candidate_text", "similarity", "score", "distinctiveness")
    QUERY_OBJECT_FIELD_NUMBER: _ClassVar[int]
    CANDIDATE_OBJECT_FIELD_NUMBER: _ClassVar[int]
    QUERY_TEXT_FIELD_NUMBER: _ClassVar[int]
    CANDIDATE_TEXT_FIELD_NUMBER: _ClassVar[int]
    SIMILARITY_FIELD_NUMBER: _ClassVar[int]
    SCORE_FIELD_NUMBER: _ClassVar[int]
    DISTINCTIVENESS_FIELD_NUMBER: _ClassVar[int]
    query_object: int
    candidate_object: int
    query_text: str
    candidate_text: str
    similarity: float
    score: float
    distinctiveness: float
    def __init__(self, query_object: _Optional[int] = ..., candidate_object: _Optional[int] = ..., query_text: _Optional[str] = ..., candidate_text: _Optional[str] = ..., similarity: _Optional[float] = ..., score: _Optional[float] = ..., distinctiveness: _Optional[float] = ...) -> None: ...

class Evidence(_message.Message):
    __slots__ = ("scene_score", "descriptor_cosine", "scene_compatibility", "temporal_depth", "object_score", "text_score", "text_distinctiveness", "corroboration", "object_matches", "text_matches", "raw_score", "scene_confidence", "null_median", "null_samples", "contradiction", "text_contradiction", "object_absence", "text_conflicts", "missing_objects", "verdict_penalty", "verdict_support", "verdict_rejections", "verdict_acceptances", "drift")
    SCENE_SCORE_FIELD_NUMBER: _ClassVar[int]
    DESCRIPTOR_COSINE_FIELD_NUMBER: _ClassVar[int]
    SCENE_COMPATIBILITY_FIELD_NUMBER: _ClassVar[int]
    TEMPORAL_DEPTH_FIELD_NUMBER: _ClassVar[int]
    OBJECT_SCORE_FIELD_NUMBER: _ClassVar[int]
    TEXT_SCORE_FIELD_NUMBER: _ClassVar[int]
    TEXT_DISTINCTIVENESS_FIELD_NUMBER: _ClassVar[int]
    CORROBORATION_FIELD_NUMBER: _ClassVar[int]
    OBJECT_MATCHES_FIELD_NUMBER: _ClassVar[int]
    TEXT_MATCHES_FIELD_NUMBER: _ClassVar[int]
    RAW_SCORE_FIELD_NUMBER: _ClassVar[int]
    SCENE_CONFIDENCE_FIELD_NUMBER: _ClassVar[int]
    NULL_MEDIAN_FIELD_NUMBER: _ClassVar[int]
    NULL_SAMPLES_FIELD_NUMBER: _ClassVar[int]
    CONTRADICTION_FIELD_NUMBER: _ClassVar[int]
    TEXT_CONTRADICTION_FIELD_NUMBER: _ClassVar[int]
    OBJECT_ABSENCE_FIELD_NUMBER: _ClassVar[int]
    TEXT_CONFLICTS_FIELD_NUMBER: _ClassVar[int]
    MISSING_OBJECTS_FIELD_NUMBER: _ClassVar[int]
    VERDICT_PENALTY_FIELD_NUMBER: _ClassVar[int]
    VERDICT_SUPPORT_FIELD_NUMBER: _ClassVar[int]
    VERDICT_REJECTIONS_FIELD_NUMBER: _ClassVar[int]
    VERDICT_ACCEPTANCES_FIELD_NUMBER: _ClassVar[int]
    DRIFT_FIELD_NUMBER: _ClassVar[int]
    scene_score: float
    descriptor_cosine: float
    scene_compatibility: float
    temporal_depth: int
    object_score: float
    text_score: float
    text_distinctiveness: float
    corroboration: float
    object_matches: _containers.RepeatedCompositeFieldContainer[ObjectMatch]
    text_matches: _containers.RepeatedCompositeFieldContainer[TextMatch]
    raw_score: float
    scene_confidence: float
    null_median: float
    null_samples: int
    contradiction: float
    text_contradiction: float
    object_absence: float
    text_conflicts: _containers.RepeatedCompositeFieldContainer[TextConflict]
    missing_objects: _containers.RepeatedCompositeFieldContainer[MissingObject]
    verdict_penalty: float
    verdict_support: float
    verdict_rejections: int
    verdict_acceptances: int
    drift: DriftEnvelope
    def __init__(self, scene_score: _Optional[float] = ..., descriptor_cosine: _Optional[float] = ..., scene_compatibility: _Optional[float] = ..., temporal_depth: _Optional[int] = ..., object_score: _Optional[float] = ..., text_score: _Optional[float] = ..., text_distinctiveness: _Optional[float] = ..., corroboration: _Optional[float] = ..., object_matches: _Optional[_Iterable[_Union[ObjectMatch, _Mapping]]] = ..., text_matches: _Optional[_Iterable[_Union[TextMatch, _Mapping]]] = ..., raw_score: _Optional[float] = ..., scene_confidence: _Optional[float] = ..., null_median: _Optional[float] = ..., null_samples: _Optional[int] = ..., contradiction: _Optional[float] = ..., text_contradiction: _Optional[float] = ..., object_absence: _Optional[float] = ..., text_conflicts: _Optional[_Iterable[_Union[TextConflict, _Mapping]]] = ..., missing_objects: _Optional[_Iterable[_Union[MissingObject, _Mapping]]] = ..., verdict_penalty: _Optional[float] = ..., verdict_support: _Optional[float] = ..., verdict_rejections: _Optional[int] = ..., verdict_acceptances: _Optional[int] = ..., drift: _Optional[_Union[DriftEnvelope, _Mapping]] = ...) -> None: ...

class DriftEnvelope(_message.Message):
    __slots__ = ("distance", "path", "ratio", "allowance", "penalty")
    DISTANCE_FIELD_NUMBER: _ClassVar[int]
    PATH_FIELD_NUMBER: _ClassVar[int]
    RATIO_FIELD_NUMBER: _ClassVar[int]
    ALLOWANCE_FIELD_NUMBER: _ClassVar[int]
    PENALTY_FIELD_NUMBER: _ClassVar[int]
    distance: float
    path: float
    ratio: float
    allowance: float
    penalty: float
    def __init__(self, distance: _Optional[float] = ..., path: _Optional[float] = ..., ratio: _Optional[float] = ..., allowance: _Optional[float] = ..., penalty: _Optional[float] = ...) -> None: ...

class TextConflict(_message.Message):
    __slots__ = ("query_object", "candidate_object", "query_text", "candidate_text", "agreement", "conflict")
    QUERY_OBJECT_FIELD_NUMBER: _ClassVar[int]
    CANDIDATE_OBJECT_FIELD_NUMBER: _ClassVar[int]
    QUERY_TEXT_FIELD_NUMBER: _ClassVar[int]
    CANDIDATE_TEXT_FIELD_NUMBER: _ClassVar[int]
    AGREEMENT_FIELD_NUMBER: _ClassVar[int]
    CONFLICT_FIELD_NUMBER: _ClassVar[int]
    query_object: int
    candidate_object: int
    query_text: str
    candidate_text: str
    agreement: float
    conflict: float
    def __init__(self, query_object: _Optional[int] = ..., candidate_object: _Optional[int] = ..., query_text: _Optional[str] = ..., candidate_text: _Optional[str] = ..., agreement: _Optional[float] = ..., conflict: _Optional[float] = ...) -> None: ...

class MissingObject(_message.Message):
    __slots__ = ("in_query", "object", "class_name", "weight")
    IN_QUERY_FIELD_NUMBER: _ClassVar[int]
    OBJECT_FIELD_NUMBER: _ClassVar[int]
    CLASS_NAME_FIELD_NUMBER: _ClassVar[int]
    WEIGHT_FIELD_NUMBER: _ClassVar[int]
    in_query: bool
    object: int
    class_name: str
    weight: float
    def __init__(self, in_query: _Optional[bool] = ..., object: _Optional[int] = ..., class_name: _Optional[str] = ..., weight: _Optional[float] = ...) -> None: ...

class Candidate(_message.Message):
    __slots__ = ("robot_id", "session_id", "keyframe_id", "frame_id", "map_id", "timestamp", "pose", "score", "evidence")
    ROBOT_ID_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    KEYFRAME_ID_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    MAP_ID_FIELD_NUMBER: _ClassVar[int]
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    POSE_FIELD_NUMBER: _ClassVar[int]
    SCORE_FIELD_NUMBER: _ClassVar[int]
    EVIDENCE_FIELD_NUMBER: _ClassVar[int]
    robot_id: str
    session_id: str
    keyframe_id: int
    frame_id: int
    map_id: int
    timestamp: float
    pose: Pose
    score: float
    evidence: Evidence
    def __init__(self, robot_id: _Optional[str] = ..., session_id: _Optional[str] = ..., keyframe_id: _Optional[int] = ..., frame_id: _Optional[int] = ..., map_id: _Optional[int] = ..., timestamp: _Optional[float] = ..., pose: _Optional[_Union[Pose, _Mapping]] = ..., score: _Optional[float] = ..., evidence: _Optional[_Union[Evidence, _Mapping]] = ...) -> None: ...

class StageTiming(_message.Message):
    __slots__ = ("stage", "seconds")
    STAGE_FIELD_NUMBER: _ClassVar[int]
    SECONDS_FIELD_NUMBER: _ClassVar[int]
    stage: str
    seconds: float
    def __init__(self, stage: _Optional[str] = ..., seconds: _Optional[float] = ...) -> None: ...

class QueryResponse(_message.Message):
    __slots__ = ("candidates", "eligible_keyframes", "used_predecessor_ids", "timings", "status", "threshold", "operating_threshold")
    CANDIDATES_FIELD_NUMBER: _ClassVar[int]
    ELIGIBLE_KEYFRAMES_FIELD_NUMBER: _ClassVar[int]
    USED_PREDECESSOR_IDS_FIELD_NUMBER: _ClassVar[int]
    TIMINGS_FIELD_NUMBER: _ClassVar[int]
    STATUS_FIELD_NUMBER: _ClassVar[int]
    THRESHOLD_FIELD_NUMBER: _ClassVar[int]
    OPERATING_THRESHOLD_FIELD_NUMBER: _ClassVar[int]
    candidates: _containers.RepeatedCompositeFieldContainer[Candidate]
    eligible_keyframes: int
    used_predecessor_ids: _containers.RepeatedScalarFieldContainer[int]
    timings: _containers.RepeatedCompositeFieldContainer[StageTiming]
    status: QueryStatus
    threshold: float
    operating_threshold: float
    def __init__(self, candidates: _Optional[_Iterable[_Union[Candidate, _Mapping]]] = ..., eligible_keyframes: _Optional[int] = ..., used_predecessor_ids: _Optional[_Iterable[int]] = ..., timings: _Optional[_Iterable[_Union[StageTiming, _Mapping]]] = ..., status: _Optional[_Union[QueryStatus, str]] = ..., threshold: _Optional[float] = ..., operating_threshold: _Optional[float] = ...) -> None: ...

class EraseRequest(_message.Message):
    __slots__ = ("robot_id", "session_id", "keyframe_ids")
    ROBOT_ID_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    KEYFRAME_IDS_FIELD_NUMBER: _ClassVar[int]
    robot_id: str
    session_id: str
    keyframe_ids: _containers.RepeatedScalarFieldContainer[int]
    def __init__(self, robot_id: _Optional[str] = ..., session_id: _Optional[str] = ..., keyframe_ids: _Optional[_Iterable[int]] = ...) -> None: ...

class EraseResponse(_message.Message):
    __slots__ = ("erased", "log_sequence")
    ERASED_FIELD_NUMBER: _ClassVar[int]
    LOG_SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    erased: int
    log_sequence: int
    def __init__(self, erased: _Optional[int] = ..., log_sequence: _Optional[int] = ...) -> None: ...

class ResetMapRequest(_message.Message):
    __slots__ = ("robot_id", "session_id", "map_id")
    ROBOT_ID_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    MAP_ID_FIELD_NUMBER: _ClassVar[int]
    robot_id: str
    session_id: str
    map_id: int
    def __init__(self, robot_id: _Optional[str] = ..., session_id: _Optional[str] = ..., map_id: _Optional[int] = ...) -> None: ...

class ResetMapResponse(_message.Message):
    __slots__ = ("erased", "log_sequence")
    ERASED_FIELD_NUMBER: _ClassVar[int]
    LOG_SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    erased: int
    log_sequence: int
    def __init__(self, erased: _Optional[int] = ..., log_sequence: _Optional[int] = ...) -> None: ...

class ResetSessionRequest(_message.Message):
    __slots__ = ("robot_id", "session_id")
    ROBOT_ID_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    robot_id: str
    session_id: str
    def __init__(self, robot_id: _Optional[str] = ..., session_id: _Optional[str] = ...) -> None: ...

class ResetSessionResponse(_message.Message):
    __slots__ = ("erased", "log_sequence")
    ERASED_FIELD_NUMBER: _ClassVar[int]
    LOG_SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    erased: int
    log_sequence: int
    def __init__(self, erased: _Optional[int] = ..., log_sequence: _Optional[int] = ...) -> None: ...

class PoseUpdate(_message.Message):
    __slots__ = ("keyframe_id", "pose", "map_id")
    KEYFRAME_ID_FIELD_NUMBER: _ClassVar[int]
    POSE_FIELD_NUMBER: _ClassVar[int]
    MAP_ID_FIELD_NUMBER: _ClassVar[int]
    keyframe_id: int
    pose: Pose
    map_id: int
    def __init__(self, keyframe_id: _Optional[int] = ..., pose: _Optional[_Union[Pose, _Mapping]] = ..., map_id: _Optional[int] = ...) -> None: ...

class UpdatePosesRequest(_message.Message):
    __slots__ = ("robot_id", "session_id", "updates")
    ROBOT_ID_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    UPDATES_FIELD_NUMBER: _ClassVar[int]
    robot_id: str
    session_id: str
    updates: _containers.RepeatedCompositeFieldContainer[PoseUpdate]
    def __init__(self, robot_id: _Optional[str] = ..., session_id: _Optional[str] = ..., updates: _Optional[_Iterable[_Union[PoseUpdate, _Mapping]]] = ...) -> None: ...

class UpdatePosesResponse(_message.Message):
    __slots__ = ("updated", "missing_keyframe_ids", "log_sequence")
    UPDATED_FIELD_NUMBER: _ClassVar[int]
    MISSING_KEYFRAME_IDS_FIELD_NUMBER: _ClassVar[int]
    LOG_SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    updated: int
    missing_keyframe_ids: _containers.RepeatedScalarFieldContainer[int]
    log_sequence: int
    def __init__(self, updated: _Optional[int] = ..., missing_keyframe_ids: _Optional[_Iterable[int]] = ..., log_sequence: _Optional[int] = ...) -> None: ...

class RelativeTransform(_message.Message):
    __slots__ = ("pose", "scale")
    POSE_FIELD_NUMBER: _ClassVar[int]
    SCALE_FIELD_NUMBER: _ClassVar[int]
    pose: Pose
    scale: float
    def __init__(self, pose: _Optional[_Union[Pose, _Mapping]] = ..., scale: _Optional[float] = ...) -> None: ...

class ReportVerificationRequest(_message.Message):
    __slots__ = ("robot_id", "session_id", "keyframe_id", "candidate", "kind", "outcome", "relative", "score", "inliers")
    ROBOT_ID_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    KEYFRAME_ID_FIELD_NUMBER: _ClassVar[int]
    CANDIDATE_FIELD_NUMBER: _ClassVar[int]
    KIND_FIELD_NUMBER: _ClassVar[int]
    OUTCOME_FIELD_NUMBER: _ClassVar[int]
    RELATIVE_FIELD_NUMBER: _ClassVar[int]
    SCORE_FIELD_NUMBER: _ClassVar[int]
    INLIERS_FIELD_NUMBER: _ClassVar[int]
    robot_id: str
    session_id: str
    keyframe_id: int
    candidate: KeyframeRef
    kind: VerificationKind
    outcome: VerificationOutcome
    relative: RelativeTransform
    score: float
    inliers: int
    def __init__(self, robot_id: _Optional[str] = ..., session_id: _Optional[str] = ..., keyframe_id: _Optional[int] = ..., candidate: _Optional[_Union[KeyframeRef, _Mapping]] = ..., kind: _Optional[_Union[VerificationKind, str]] = ..., outcome: _Optional[_Union[VerificationOutcome, str]] = ..., relative: _Optional[_Union[RelativeTransform, _Mapping]] = ..., score: _Optional[float] = ..., inliers: _Optional[int] = ...) -> None: ...

class ReportVerificationResponse(_message.Message):
    __slots__ = ("replaced", "store_verdicts", "log_sequence")
    REPLACED_FIELD_NUMBER: _ClassVar[int]
    STORE_VERDICTS_FIELD_NUMBER: _ClassVar[int]
    LOG_SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    replaced: bool
    store_verdicts: int
    log_sequence: int
    def __init__(self, replaced: _Optional[bool] = ..., store_verdicts: _Optional[int] = ..., log_sequence: _Optional[int] = ...) -> None: ...

class StatsRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class MapStats(_message.Message):
    __slots__ = ("robot_id", "session_id", "map_id", "keyframes")
    ROBOT_ID_FIELD_NUMBER: _ClassVar[int]
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    MAP_ID_FIELD_NUMBER: _ClassVar[int]
    KEYFRAMES_FIELD_NUMBER: _ClassVar[int]
    robot_id: str
    session_id: str
    map_id: int
    keyframes: int
    def __init__(self, robot_id: _Optional[str] = ..., session_id: _Optional[str] = ..., map_id: _Optional[int] = ..., keyframes: _Optional[int] = ...) -> None: ...

class StatsResponse(_message.Message):
    __slots__ = ("keyframes", "descriptor_dim", "maps", "disk_bytes", "format_version", "server_version", "log_position", "verdicts", "operating_point", "neighbour_graph")
    KEYFRAMES_FIELD_NUMBER: _ClassVar[int]
    DESCRIPTOR_DIM_FIELD_NUMBER: _ClassVar[int]
    MAPS_FIELD_NUMBER: _ClassVar[int]
    DISK_BYTES_FIELD_NUMBER: _ClassVar[int]
    FORMAT_VERSION_FIELD_NUMBER: _ClassVar[int]
    SERVER_VERSION_FIELD_NUMBER: _ClassVar[int]
    LOG_POSITION_FIELD_NUMBER: _ClassVar[int]
    VERDICTS_FIELD_NUMBER: _ClassVar[int]
    OPERATING_POINT_FIELD_NUMBER: _ClassVar[int]
    NEIGHBOUR_GRAPH_FIELD_NUMBER: _ClassVar[int]
    keyframes: int
    descriptor_dim: int
    maps: _containers.RepeatedCompositeFieldContainer[MapStats]
    disk_bytes: int
    format_version: int
    server_version: str
    log_position: int
    verdicts: int
    operating_point: OperatingPoint
    neighbour_graph: NeighbourGraphStats
    def __init__(self, keyframes: _Optional[int] = ..., descriptor_dim: _Optional[int] = ..., maps: _Optional[_Iterable[_Union[MapStats, _Mapping]]] = ..., disk_bytes: _Optional[int] = ..., format_version: _Optional[int] = ..., server_version: _Optional[str] = ..., log_position: _Optional[int] = ..., verdicts: _Optional[int] = ..., operating_point: _Optional[_Union[OperatingPoint, _Mapping]] = ..., neighbour_graph: _Optional[_Union[NeighbourGraphStats, _Mapping]] = ...) -> None: ...

class NeighbourGraphStats(_message.Message):
    __slots__ = ("keyframes", "missing", "memory_bytes", "loaded", "approximate_from", "waiting", "map_graphs", "map_graph_keyframes", "map_graph_memory_bytes", "map_graph_waiting")
    KEYFRAMES_FIELD_NUMBER: _ClassVar[int]
    MISSING_FIELD_NUMBER: _ClassVar[int]
    MEMORY_BYTES_FIELD_NUMBER: _ClassVar[int]
    LOADED_FIELD_NUMBER: _ClassVar[int]
    APPROXIMATE_FROM_FIELD_NUMBER: _ClassVar[int]
    WAITING_FIELD_NUMBER: _ClassVar[int]
    MAP_GRAPHS_FIELD_NUMBER: _ClassVar[int]
    MAP_GRAPH_KEYFRAMES_FIELD_NUMBER: _ClassVar[int]
    MAP_GRAPH_MEMORY_BYTES_FIELD_NUMBER: _ClassVar[int]
    MAP_GRAPH_WAITING_FIELD_NUMBER: _ClassVar[int]
    keyframes: int
    missing: int
    memory_bytes: int
    loaded: bool
    approximate_from: int
    waiting: int
    map_graphs: int
    map_graph_keyframes: int
    map_graph_memory_bytes: int
    map_graph_waiting: int
    def __init__(self, keyframes: _Optional[int] = ..., missing: _Optional[int] = ..., memory_bytes: _Optional[int] = ..., loaded: _Optional[bool] = ..., approximate_from: _Optional[int] = ..., waiting: _Optional[int] = ..., map_graphs: _Optional[int] = ..., map_graph_keyframes: _Optional[int] = ..., map_graph_memory_bytes: _Optional[int] = ..., map_graph_waiting: _Optional[int] = ...) -> None: ...

class OperatingPoint(_message.Message):
    __slots__ = ("threshold", "configured_threshold", "estimated_precision", "configured_precision", "verdicts")
    THRESHOLD_FIELD_NUMBER: _ClassVar[int]
    CONFIGURED_THRESHOLD_FIELD_NUMBER: _ClassVar[int]
    ESTIMATED_PRECISION_FIELD_NUMBER: _ClassVar[int]
    CONFIGURED_PRECISION_FIELD_NUMBER: _ClassVar[int]
    VERDICTS_FIELD_NUMBER: _ClassVar[int]
    threshold: float
    configured_threshold: float
    estimated_precision: float
    configured_precision: float
    verdicts: int
    def __init__(self, threshold: _Optional[float] = ..., configured_threshold: _Optional[float] = ..., estimated_precision: _Optional[float] = ..., configured_precision: _Optional[float] = ..., verdicts: _Optional[int] = ...) -> None: ...
