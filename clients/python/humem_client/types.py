"""The typed values of the HuMem API: enums mirroring the proto's, and
dataclasses for keyframes, images, features, queries and their answers,
with numpy arrays for descriptors, poses and appearance thumbnails.

Field names follow ``proto/humem/v1/humem.proto``, which documents what each
one means; ``humem_client._convert`` turns these values into messages and
back.
"""

from __future__ import annotations

import enum
import io
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from .proto import humem_pb2 as pb

# ---------------------------------------------------------------------------
# Enums: the same numbers as the proto's (tests/test_types.py checks that
# every proto value has its member).


class Scope(enum.IntEnum):
    """Which stored maps a query searches (``humem.v1.Scope``)."""

    UNSPECIFIED = pb.SCOPE_UNSPECIFIED  # the server's default: ALL_MAPS
    SAME_MAP = pb.SCOPE_SAME_MAP  # loop closure
    OTHER_MAPS = pb.SCOPE_OTHER_MAPS  # map merging, multi-robot recognition
    ALL_MAPS = pb.SCOPE_ALL_MAPS  # relocalisation
    LISTED = pb.SCOPE_LISTED  # Query.robot_ids and Query.maps


class Layers(enum.IntEnum):
    """Which HuMem-VPR layers score the candidates (``humem.v1.Layers``)."""

    UNSPECIFIED = pb.LAYERS_UNSPECIFIED  # the server's default: FULL
    SCAL = pb.LAYERS_SCAL
    SCAL_OSRL = pb.LAYERS_SCAL_OSRL
    SCAL_OGTL = pb.LAYERS_SCAL_OGTL
    FULL = pb.LAYERS_FULL
    FULL_SUPPORT_ONLY = pb.LAYERS_FULL_SUPPORT_ONLY


class QueryKind(enum.IntEnum):
    """Why a query is asked (``humem.v1.QueryKind``); kinds never displace
    each other in latest-wins."""

    UNSPECIFIED = pb.QUERY_KIND_UNSPECIFIED  # the server's default: LOOP_CLOSURE
    LOOP_CLOSURE = pb.QUERY_KIND_LOOP_CLOSURE
    RELOCALISATION = pb.QUERY_KIND_RELOCALISATION


class QueryStatus(enum.IntEnum):
    """Whether the server answered a query (``humem.v1.QueryStatus``)."""

    UNSPECIFIED = pb.QUERY_STATUS_UNSPECIFIED
    ANSWERED = pb.QUERY_STATUS_ANSWERED
    SUPERSEDED = pb.QUERY_STATUS_SUPERSEDED  # a newer query of the same robot/session/kind took its place


class VerificationKind(enum.IntEnum):
    """Which geometric check the SLAM system ran (``humem.v1.VerificationKind``)."""

    UNSPECIFIED = pb.VERIFICATION_KIND_UNSPECIFIED
    LOOP = pb.VERIFICATION_KIND_LOOP
    MERGE = pb.VERIFICATION_KIND_MERGE
    RELOCALISATION = pb.VERIFICATION_KIND_RELOCALISATION


class VerificationOutcome(enum.IntEnum):
    """What the geometric check decided (``humem.v1.VerificationOutcome``)."""

    UNSPECIFIED = pb.VERIFICATION_OUTCOME_UNSPECIFIED
    ACCEPTED = pb.VERIFICATION_OUTCOME_ACCEPTED
    REJECTED = pb.VERIFICATION_OUTCOME_REJECTED


class ImageEncoding(enum.IntEnum):
    """How an image's bytes are encoded (``humem.v1.Image.Encoding``)."""

    UNSPECIFIED = pb.Image.ENCODING_UNSPECIFIED  # JPEG or PNG, recognised from the bytes
    JPEG = pb.Image.ENCODING_JPEG
    PNG = pb.Image.ENCODING_PNG
    GRAY8 = pb.Image.ENCODING_GRAY8  # raw, one byte per pixel
    RGB8 = pb.Image.ENCODING_RGB8  # raw, R, G, B per pixel
    BGR8 = pb.Image.ENCODING_BGR8  # raw, B, G, R per pixel (OpenCV's order)


# ---------------------------------------------------------------------------
# Poses


def _vector(value, length: int, name: str) -> np.ndarray:
    array = np.array(value, dtype=np.float64).reshape(-1)
    if array.shape != (length,):
        raise ValueError(f"{name}: expected {length} numbers, got shape {np.shape(value)}")
    return array


@dataclass(eq=False)
class Pose:
    """A camera-to-world pose T_wc: ``translation`` (x, y, z) and ``rotation``
    as a unit quaternion (w, x, y, z), both float64 numpy arrays."""

    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rotation: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0, 0.0]))

    def __post_init__(self) -> None:
        self.translation = _vector(self.translation, 3, "Pose.translation")
        self.rotation = _vector(self.rotation, 4, "Pose.rotation (w, x, y, z)")

    @classmethod
    def identity(cls) -> "Pose":
        return cls()

    @classmethod
    def from_matrix(cls, matrix) -> "Pose":
        """From a 4x4 (or 3x4) homogeneous transform, e.g. ORB-SLAM3's
        ``KeyFrame::GetPoseInverse().matrix()``."""
        m = np.asarray(matrix, dtype=np.float64)
        if m.shape not in ((4, 4), (3, 4)):
            raise ValueError(f"Pose.from_matrix: expected a 4x4 or 3x4 matrix, got shape {m.shape}")
        r = m[:3, :3]
        # Shepperd's method: the largest of w, x, y, z first, for stability.
        trace = np.trace(r)
        if trace > 0:
            s = 2.0 * np.sqrt(1.0 + trace)
            q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
        elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
            s = 2.0 * np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
            q = [(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
        elif r[1, 1] > r[2, 2]:
            s = 2.0 * np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
            q = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s]
        else:
            s = 2.0 * np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
            q = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s]
        q = np.array(q)
        q /= np.linalg.norm(q)
        if q[0] < 0:
            q = -q
        return cls(translation=m[:3, 3], rotation=q)

    def matrix(self) -> np.ndarray:
        """The 4x4 homogeneous transform (float64)."""
        w, x, y, z = self.rotation / np.linalg.norm(self.rotation)
        m = np.eye(4)
        m[:3, :3] = [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
        m[:3, 3] = self.translation
        return m

    def __repr__(self) -> str:
        return f"Pose(translation={self.translation.tolist()}, rotation={self.rotation.tolist()})"


# ---------------------------------------------------------------------------
# Images

_JPEG_MAGIC = b"\xff\xd8\xff"
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _sniff(data: bytes) -> ImageEncoding:
    if data.startswith(_JPEG_MAGIC):
        return ImageEncoding.JPEG
    if data.startswith(_PNG_MAGIC):
        return ImageEncoding.PNG
    return ImageEncoding.UNSPECIFIED


@dataclass(eq=False)
class Image:
    """A camera image for the server's models: an encoded JPEG/PNG file, or
    raw 8-bit pixels (GRAY8, RGB8, BGR8) with their size. Build one with
    :meth:`from_file`, :meth:`from_bytes` or :meth:`from_array`."""

    data: bytes
    encoding: ImageEncoding = ImageEncoding.UNSPECIFIED
    width: int = 0  # raw encodings only
    height: int = 0
    stride: int = 0  # raw encodings only: bytes per row; 0 = tightly packed

    @classmethod
    def from_file(cls, path: Union[str, os.PathLike]) -> "Image":
        """The bytes of a JPEG or PNG file, sent as they are (the server decodes them)."""
        data = Path(path).read_bytes()
        encoding = _sniff(data)
        if encoding == ImageEncoding.UNSPECIFIED:
            raise ValueError(f"Image.from_file: {path} is neither a JPEG nor a PNG file")
        return cls(data=data, encoding=encoding)

    @classmethod
    def from_bytes(cls, data: bytes, encoding: ImageEncoding = ImageEncoding.UNSPECIFIED) -> "Image":
        """An encoded JPEG or PNG file already in memory."""
        data = bytes(data)
        if encoding == ImageEncoding.UNSPECIFIED:
            encoding = _sniff(data)
            if encoding == ImageEncoding.UNSPECIFIED:
                raise ValueError("Image.from_bytes: the bytes are neither JPEG nor PNG; give the encoding")
        return cls(data=data, encoding=ImageEncoding(encoding))

    @classmethod
    def from_array(
        cls,
        array: np.ndarray,
        *,
        channels: str = "rgb",
        encode: Optional[str] = None,
        quality: int = 90,
    ) -> "Image":
        """From a uint8 numpy array: (H, W) or (H, W, 1) gray, or (H, W, 3)
        colour in ``channels`` order ("rgb", or "bgr" for OpenCV frames).

        Sent as raw pixels by default (no dependency, no compression); with
        ``encode="png"`` or ``"jpeg"`` it is compressed first with Pillow
        (``pip install humem-client[images]``), which also takes (H, W, 4)
        RGBA for PNG.
        """
        a = np.asarray(array)
        if a.dtype != np.uint8:
            raise ValueError(f"Image.from_array: expected uint8 pixels, got {a.dtype} (convert with .astype(np.uint8))")
        if a.ndim == 3 and a.shape[2] == 1:
            a = a[:, :, 0]
        if channels not in ("rgb", "bgr"):
            raise ValueError(f"Image.from_array: channels must be 'rgb' or 'bgr', not {channels!r}")
        if a.ndim == 2:
            kind = "gray"
        elif a.ndim == 3 and a.shape[2] == 3:
            kind = channels
        elif a.ndim == 3 and a.shape[2] == 4 and encode == "png":
            kind = "rgba" if channels == "rgb" else "bgra"
        else:
            hint = " (RGBA only with encode='png')" if a.ndim == 3 and a.shape[2] == 4 else ""
            raise ValueError(f"Image.from_array: expected shape (H, W), (H, W, 1) or (H, W, 3), got {a.shape}{hint}")
        height, width = a.shape[:2]
        if encode is None:
            encoding = {"gray": ImageEncoding.GRAY8, "rgb": ImageEncoding.RGB8, "bgr": ImageEncoding.BGR8}[kind]
            return cls(data=np.ascontiguousarray(a).tobytes(), encoding=encoding, width=width, height=height)
        if encode not in ("png", "jpeg"):
            raise ValueError(f"Image.from_array: encode must be None, 'png' or 'jpeg', not {encode!r}")
        try:
            from PIL import Image as PILImage
        except ImportError as e:
            raise ImportError(
                "Image.from_array(encode=...) needs Pillow: pip install 'humem-client[images]'"
            ) from e
        if kind in ("bgr", "bgra"):
            a = a[:, :, [2, 1, 0] + ([3] if kind == "bgra" else [])]
        picture = PILImage.fromarray(np.ascontiguousarray(a))
        out = io.BytesIO()
        if encode == "png":
            picture.save(out, format="PNG")
            return cls(data=out.getvalue(), encoding=ImageEncoding.PNG)
        picture.save(out, format="JPEG", quality=quality)
        return cls(data=out.getvalue(), encoding=ImageEncoding.JPEG)


ImageLike = Union[Image, str, os.PathLike, bytes, np.ndarray]


def as_image(value: ImageLike) -> Image:
    """An :class:`Image` from an Image, a file path, encoded bytes or a uint8 array (raw RGB or gray)."""
    if isinstance(value, Image):
        return value
    if isinstance(value, (bytes, bytearray, memoryview)):
        return Image.from_bytes(bytes(value))
    if isinstance(value, (str, os.PathLike)):
        return Image.from_file(value)
    if isinstance(value, np.ndarray):
        return Image.from_array(value)
    raise TypeError(f"expected an Image, a file path, JPEG/PNG bytes or a uint8 array, got {type(value).__name__}")


# ---------------------------------------------------------------------------
# Features


@dataclass
class TextObservation:
    """A string read by OCR on an object."""

    text: str
    confidence: float = 1.0


@dataclass
class ObjectObservation:
    """A stable object in the image: its class, confidence, mask centroid
    (x, y in [0, 1], origin top-left), area share and the texts read on it."""

    class_name: str
    confidence: float = 1.0
    x: float = 0.5
    y: float = 0.5
    area: float = 0.0
    texts: list = field(default_factory=list)  # TextObservation, or (text, confidence) pairs

    def __post_init__(self) -> None:
        self.texts = [t if isinstance(t, TextObservation) else TextObservation(*t) for t in self.texts]


APPEARANCE_SHAPE = (48, 64)


@dataclass(eq=False)
class Features:
    """Precomputed perception output for one image.

    ``global_descriptor``: 1-D float32 array (finite, not all zero; the
    server L2-normalises it). ``scene``: {class id: probability} of the top
    scene classes (see :meth:`top_scene`). ``objects``: ObjectObservation
    list. ``appearance``: None, or the 48x64 int8 thumbnail (see the proto).
    """

    global_descriptor: np.ndarray
    scene: dict = field(default_factory=dict)
    objects: list = field(default_factory=list)
    appearance: Optional[np.ndarray] = None

    def __post_init__(self) -> None:
        d = np.asarray(self.global_descriptor, dtype=np.float32)
        if d.ndim != 1:
            raise ValueError(f"Features.global_descriptor: expected a 1-D array, got shape {d.shape}")
        self.global_descriptor = d
        if isinstance(self.scene, Mapping):
            self.scene = {int(k): float(v) for k, v in self.scene.items()}
        else:
            self.scene = {int(k): float(v) for k, v in self.scene}
        if self.appearance is not None:
            a = np.asarray(self.appearance)
            if a.size == 0:
                self.appearance = None
            else:
                if a.size != APPEARANCE_SHAPE[0] * APPEARANCE_SHAPE[1]:
                    raise ValueError(f"Features.appearance: expected 48x64 = 3072 values, got {a.size}")
                self.appearance = a.astype(np.int8).reshape(APPEARANCE_SHAPE)

    @staticmethod
    def top_scene(probabilities, k: int = 16) -> dict:
        """The ``k`` most probable classes of a full scene distribution
        (e.g. a softmax over Places365), as {class id: probability}."""
        p = np.asarray(probabilities, dtype=np.float64).reshape(-1)
        top = np.argsort(-p, kind="stable")[:k]
        return {int(i): float(p[i]) for i in top}

    def __repr__(self) -> str:
        return (
            f"Features(global_descriptor=<{self.global_descriptor.size} float32>, scene={len(self.scene)} classes, "
            f"objects={len(self.objects)}, appearance={'yes' if self.appearance is not None else 'no'})"
        )


FeaturesLike = Union[Features, np.ndarray, Sequence[float]]


def as_features(value: FeaturesLike) -> Features:
    """A :class:`Features` from Features or a bare global descriptor."""
    return value if isinstance(value, Features) else Features(global_descriptor=value)


# ---------------------------------------------------------------------------
# Requests


@dataclass
class Keyframe:
    """A keyframe to store. Give ``features`` (or a bare descriptor array)
    or ``image`` (an :class:`Image`, a file path, JPEG/PNG bytes, or a uint8
    array), not both. ``robot_id``/``session_id`` default to the client's."""

    keyframe_id: int
    frame_id: int
    map_id: int = 0
    pose: Pose = field(default_factory=Pose)
    features: Optional[FeaturesLike] = None
    image: Optional[ImageLike] = None
    timestamp: float = 0.0
    robot_id: Optional[str] = None
    session_id: Optional[str] = None


@dataclass
class MapRef:
    """A map, for Scope.LISTED; ``session_id`` None matches every session."""

    robot_id: str
    map_id: int
    session_id: Optional[str] = None


@dataclass
class Query:
    """A query (``humem.v1.QueryRequest``). The content is ``features`` (or a
    bare descriptor), ``image``, or neither with ``keyframe_id`` naming a
    stored keyframe. ``None`` leaves a field to the server's default."""

    frame_id: Optional[int] = None
    keyframe_id: Optional[int] = None
    map_id: Optional[int] = None
    features: Optional[FeaturesLike] = None
    image: Optional[ImageLike] = None
    predecessor_keyframe_ids: Sequence[int] = ()
    scope: Scope = Scope.UNSPECIFIED
    robot_ids: Sequence[str] = ()
    maps: Sequence[MapRef] = ()
    min_frame_gap: Optional[int] = None
    top_n: Optional[int] = None
    threshold: Optional[float] = None
    layers: Layers = Layers.UNSPECIFIED
    kind: QueryKind = QueryKind.LOOP_CLOSURE
    min_log_sequence: Optional[int] = None
    exact: bool = False
    """Answer from a pass over every eligible keyframe, never from the
    server's neighbour graph (slower on a large store)."""
    robot_id: Optional[str] = None
    session_id: Optional[str] = None


@dataclass
class PoseUpdate:
    """A corrected pose for a stored keyframe, and its new map after a merge."""

    keyframe_id: int
    pose: Pose
    map_id: Optional[int] = None


@dataclass
class KeyframeRef:
    """A stored keyframe, by key."""

    robot_id: str
    session_id: str
    keyframe_id: int


# ---------------------------------------------------------------------------
# Answers


@dataclass(frozen=True)
class InsertResult:
    replaced: bool
    store_keyframes: int
    timings: dict  # stage -> seconds, when an image was sent
    features: Optional[Features]  # what the server's models made of the image, when one was sent
    log_sequence: int


@dataclass(frozen=True)
class InsertBatchResult:
    replaced: int
    store_keyframes: int
    log_sequence: int


@dataclass(frozen=True)
class EraseResult:
    """Erase, ResetMap and ResetSession: keyframes removed."""

    erased: int
    log_sequence: int


@dataclass(frozen=True)
class UpdatePosesResult:
    updated: int
    missing_keyframe_ids: Tuple[int, ...]
    log_sequence: int


@dataclass(frozen=True)
class VerificationResult:
    replaced: bool
    store_verdicts: int
    log_sequence: int


@dataclass(frozen=True)
class ObjectMatch:
    query_object: int
    candidate_object: int
    class_name: str
    affinity: float
    spatial: float


@dataclass(frozen=True)
class TextMatch:
    query_object: int
    candidate_object: int
    query_text: str
    candidate_text: str
    similarity: float
    score: float
    distinctiveness: float


@dataclass(frozen=True)
class TextConflict:
    query_object: int
    candidate_object: int
    query_text: str
    candidate_text: str
    agreement: float
    conflict: float


@dataclass(frozen=True)
class MissingObject:
    in_query: bool
    object: int
    class_name: str
    weight: float


@dataclass(frozen=True)
class DriftEnvelope:
    """Where a candidate of the query's own map lies against the map's
    drift (map units): beyond ``allowance`` its score lost ``penalty``
    (up to 0.1, at twice the allowed ratio)."""

    distance: float
    path: float
    ratio: float
    allowance: float
    penalty: float


@dataclass(frozen=True)
class Evidence:
    """Why a candidate was proposed; see ``humem.v1.Evidence`` for each term."""

    scene_score: float
    descriptor_cosine: float
    scene_compatibility: Optional[float]
    temporal_depth: int
    object_score: float
    text_score: float
    text_distinctiveness: float
    corroboration: float
    object_matches: Tuple[ObjectMatch, ...]
    text_matches: Tuple[TextMatch, ...]
    raw_score: float
    scene_confidence: float
    null_median: float
    null_samples: int
    contradiction: float
    text_contradiction: float
    object_absence: float
    text_conflicts: Tuple[TextConflict, ...]
    missing_objects: Tuple[MissingObject, ...]
    verdict_penalty: float
    verdict_support: float
    verdict_rejections: int
    verdict_acceptances: int
    drift: Optional[DriftEnvelope] = None


@dataclass(frozen=True)
class Candidate:
    """One proposed place: the stored keyframe, its pose, its score (what
    the threshold applies to) and the evidence."""

    robot_id: str
    session_id: str
    keyframe_id: int
    frame_id: int
    map_id: int
    timestamp: float
    pose: Pose
    score: float
    evidence: Evidence


@dataclass(frozen=True)
class QueryResult:
    """The server's answer to one query."""

    status: QueryStatus
    candidates: Tuple[Candidate, ...]
    eligible_keyframes: int
    used_predecessor_ids: Tuple[int, ...]
    timings: dict
    threshold: float
    operating_threshold: float

    @property
    def answered(self) -> bool:
        return self.status == QueryStatus.ANSWERED

    def keyframe_ids(self) -> list:
        """The candidates' keyframe ids, best first."""
        return [c.keyframe_id for c in self.candidates]


@dataclass(frozen=True)
class MapStats:
    robot_id: str
    session_id: str
    map_id: int
    keyframes: int


@dataclass(frozen=True)
class OperatingPoint:
    threshold: float
    configured_threshold: float
    estimated_precision: Optional[float]
    configured_precision: Optional[float]
    verdicts: int


@dataclass(frozen=True)
class NeighbourGraphStats:
    """The neighbour graph that proposes the candidates of large queries."""

    keyframes: int
    missing: int
    memory_bytes: int
    loaded: bool
    approximate_from: int
    #: Of ``keyframes``, those still waiting to enter the graph (scored exactly meanwhile).
    waiting: int = 0
    #: Maps with a graph of their own, walked by loop queries over one of them.
    map_graphs: int = 0
    #: Keyframes in the maps' graphs.
    map_graph_keyframes: int = 0
    #: Memory the maps' graphs hold, in bytes.
    map_graph_memory_bytes: int = 0
    #: Keyframes waiting to enter their map's graph (their loop queries are exact meanwhile).
    map_graph_waiting: int = 0


@dataclass(frozen=True)
class Stats:
    keyframes: int
    descriptor_dim: int
    maps: Tuple[MapStats, ...]
    disk_bytes: int
    format_version: int
    server_version: str
    log_position: int
    verdicts: int
    operating_point: Optional[OperatingPoint]
    neighbour_graph: Optional[NeighbourGraphStats] = None
