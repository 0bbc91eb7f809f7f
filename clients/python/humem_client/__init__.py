"""humem_client: the Python client of HuMem, the place-recognition service
for visual SLAM (``proto/humem/v1/humem.proto``).

``connect()`` / ``Client`` speak to a ``humem serve`` over plaintext, TLS or
mutual TLS with a bearer token; keyframes and queries carry numpy
descriptors or images (numpy arrays or files); answers come back as typed
dataclasses; errors as ``HumemError`` subclasses with the gRPC code; and
``Client.submit_query`` runs latest-wins queries on background threads.
The generated messages and stub are ``humem_client.pb`` and
``humem_client.pb_grpc``.
"""

from .client import Client, connect
from .errors import (
    CancelledError,
    DeadlineExceededError,
    FailedPreconditionError,
    HumemError,
    InvalidArgumentError,
    NotFoundError,
    PermissionDeniedError,
    ResourceExhaustedError,
    UnauthenticatedError,
    UnavailableError,
)
from .latest_wins import QueryOutcome, Ticket, TicketState
from .proto import humem_pb2 as pb
from .proto import humem_pb2_grpc as pb_grpc
from .types import (
    Candidate,
    DriftEnvelope,
    EraseResult,
    Evidence,
    Features,
    Image,
    ImageEncoding,
    InsertBatchResult,
    InsertResult,
    Keyframe,
    KeyframeRef,
    Layers,
    MapRef,
    MapStats,
    NeighbourGraphStats,
    MissingObject,
    ObjectMatch,
    ObjectObservation,
    OperatingPoint,
    Pose,
    PoseUpdate,
    Query,
    QueryKind,
    QueryResult,
    QueryStatus,
    Scope,
    Stats,
    TextConflict,
    TextMatch,
    TextObservation,
    UpdatePosesResult,
    VerificationKind,
    VerificationOutcome,
    VerificationResult,
)

__version__ = "0.1.0"

__all__ = [
    "Candidate",
    "CancelledError",
    "Client",
    "DeadlineExceededError",
    "DriftEnvelope",
    "EraseResult",
    "Evidence",
    "FailedPreconditionError",
    "Features",
    "HumemError",
    "Image",
    "ImageEncoding",
    "InsertBatchResult",
    "InsertResult",
    "InvalidArgumentError",
    "Keyframe",
    "KeyframeRef",
    "Layers",
    "MapRef",
    "MapStats",
    "NeighbourGraphStats",
    "MissingObject",
    "NotFoundError",
    "ObjectMatch",
    "ObjectObservation",
    "OperatingPoint",
    "PermissionDeniedError",
    "Pose",
    "PoseUpdate",
    "Query",
    "QueryKind",
    "QueryOutcome",
    "QueryResult",
    "QueryStatus",
    "ResourceExhaustedError",
    "Scope",
    "Stats",
    "TextConflict",
    "TextMatch",
    "TextObservation",
    "Ticket",
    "TicketState",
    "UnauthenticatedError",
    "UnavailableError",
    "UpdatePosesResult",
    "VerificationKind",
    "VerificationOutcome",
    "VerificationResult",
    "connect",
    "pb",
    "pb_grpc",
]
