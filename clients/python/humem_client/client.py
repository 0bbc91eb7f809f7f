"""The HuMem client: a gRPC channel (plaintext, TLS, mutual TLS, bearer
token) to a ``humem serve`` and one typed method per RPC, with numpy arrays
in and out, errors raised as :class:`~humem_client.errors.HumemError`, and
latest-wins background queries (:meth:`Client.submit_query`).

    with humem_client.connect("127.0.0.1:50051", robot_id="car-1") as client:
        client.insert(Keyframe(keyframe_id=1, frame_id=10, features=descriptor))
        result = client.query(features=descriptor, frame_id=500)
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterable, Optional, Union

import grpc

from . import _convert
from .errors import error_for, from_rpc_error
from .latest_wins import OnResult, QueryLanes, QueryOutcome, Ticket
from .proto import humem_pb2 as pb
from .proto import humem_pb2_grpc as pb_grpc
from .types import (
    Candidate,
    EraseResult,
    InsertBatchResult,
    InsertResult,
    Keyframe,
    KeyframeRef,
    Pose,
    PoseUpdate,
    Query,
    QueryKind,
    QueryResult,
    Stats,
    UpdatePosesResult,
    VerificationKind,
    VerificationOutcome,
    VerificationResult,
)

PathLike = Union[str, os.PathLike]
_SCHEMES = ("http://", "https://", "grpc://")


def _address(target: str) -> str:
    """host:port from a target with or without a scheme (as the C++ client)."""
    for scheme in _SCHEMES:
        if target.startswith(scheme):
            return target[len(scheme):].rstrip("/")
    return target


def _read(path: PathLike, option: str) -> bytes:
    try:
        return Path(path).read_bytes()
    except OSError as e:
        raise ValueError(f"{option}: cannot read {path}: {e.strerror or e}") from e


class Client:
    """A connection to a HuMem server, for one robot and session by default.

    ``target``: ``host:port`` or ``http://host:port`` for plaintext (a
    loopback sidecar), ``https://host:port`` for TLS. With TLS, ``tls_ca``
    is the CA file the server's certificate chains to (default: the system's
    roots), ``tls_cert``/``tls_key`` a client certificate for mutual TLS,
    ``tls_server_name`` the name to check the certificate for when it
    differs from the target's host, and ``token`` a bearer token from
    ``humem token add`` (sent as ``authorization: Bearer``, only over TLS).

    ``robot_id``/``session_id`` are used by every call that does not name
    its own (both are attributes: set ``session_id`` after a full reset).
    ``timeout`` is the default deadline of each call in seconds (images run
    the server's models: allow for that); ``query_timeout`` that of the
    latest-wins queries. ``on_query_result`` is called with each
    :class:`QueryOutcome` of :meth:`submit_query`, on the lane's thread.

    Thread-safe: every method may be called from any thread. Use it as a
    context manager, or call :meth:`close`.
    """

    def __init__(
        self,
        target: str = "127.0.0.1:50051",
        *,
        robot_id: str = "",
        session_id: str = "",
        tls_ca: Optional[PathLike] = None,
        tls_cert: Optional[PathLike] = None,
        tls_key: Optional[PathLike] = None,
        tls_server_name: Optional[str] = None,
        token: Optional[str] = None,
        timeout: float = 30.0,
        query_timeout: float = 10.0,
        max_message_bytes: int = 64 << 20,
        reconnect_backoff_max: float = 1.0,
        on_query_result: Optional[OnResult] = None,
    ):
        self.target = target
        self.robot_id = robot_id
        self.session_id = session_id
        self.timeout = timeout
        self.tls = target.startswith("https://")
        tls_options = [n for n, v in (("tls_ca", tls_ca), ("tls_cert", tls_cert), ("tls_key", tls_key),
                                      ("tls_server_name", tls_server_name)) if v]
        if not self.tls:
            if tls_options:
                raise ValueError(f"{', '.join(tls_options)}: set, but target {target} is not an https:// URL")
            if token:
                raise ValueError(f"token: only sent over TLS, and target {target} is not an https:// URL")
        if bool(tls_cert) != bool(tls_key):
            raise ValueError("tls_cert/tls_key: give both or neither")

        backoff_max_ms = max(1, int(reconnect_backoff_max * 1000))
        options = [
            ("grpc.max_send_message_length", max_message_bytes),
            ("grpc.max_receive_message_length", max_message_bytes),
            ("grpc.initial_reconnect_backoff_ms", min(100, backoff_max_ms)),
            ("grpc.min_reconnect_backoff_ms", min(100, backoff_max_ms)),
            ("grpc.max_reconnect_backoff_ms", backoff_max_ms),
        ]
        address = _address(target)
        if self.tls:
            credentials = grpc.ssl_channel_credentials(
                root_certificates=_read(tls_ca, "tls_ca") if tls_ca else None,
                private_key=_read(tls_key, "tls_key") if tls_key else None,
                certificate_chain=_read(tls_cert, "tls_cert") if tls_cert else None,
            )
            if token:
                credentials = grpc.composite_channel_credentials(
                    credentials, grpc.access_token_call_credentials(token)
                )
            if tls_server_name:
                options.append(("grpc.ssl_target_name_override", tls_server_name))
            self._channel = grpc.secure_channel(address, credentials, options=options)
        else:
            self._channel = grpc.insecure_channel(address, options=options)
        self.stub = pb_grpc.PlaceRecognitionStub(self._channel)
        """The generated stub, for what the typed methods do not cover."""
        self._lanes = QueryLanes(
            lambda request, t: self.stub.Query.future(request, timeout=t), query_timeout, on_query_result
        )
        self._closed = False

    # --- plumbing ------------------------------------------------------------

    def _call(self, method: str, request, timeout: Optional[float]):
        if self._closed:
            raise ValueError("the client is closed")
        try:
            return getattr(self.stub, method)(request, timeout=self.timeout if timeout is None else timeout)
        except grpc.RpcError as e:
            raise from_rpc_error(e, method) from None

    def _ids(self, robot_id: Optional[str], session_id: Optional[str]):
        return (self.robot_id if robot_id is None else robot_id, self.session_id if session_id is None else session_id)

    def wait_ready(self, timeout: float = 10.0) -> None:
        """Blocks until the channel is connected (at most ``timeout`` s);
        raises UnavailableError if it is not. Calls do not need this: it
        only tells early that the server is unreachable."""
        try:
            grpc.channel_ready_future(self._channel).result(timeout=timeout)
        except grpc.FutureTimeoutError:
            raise error_for(grpc.StatusCode.UNAVAILABLE, f"{self.target} not reachable within {timeout} s") from None

    def close(self) -> None:
        """Resolves pending queries as CANCELLED, cancels those in flight,
        joins the query threads and closes the channel. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._lanes.close()
        self._channel.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- writes --------------------------------------------------------------

    def insert(self, keyframe: Keyframe, *, timeout: Optional[float] = None) -> InsertResult:
        """Stores one keyframe (or replaces the one with the same key).
        With an image, the result carries the features the server's models
        made of it (``result.features.global_descriptor``, a numpy array)."""
        request = pb.InsertRequest(keyframe=_convert.keyframe_to_proto(keyframe, self.robot_id, self.session_id))
        return _convert.insert_result_from_proto(self._call("Insert", request, timeout))

    def insert_batch(self, keyframes: Iterable[Keyframe], *, timeout: Optional[float] = None) -> InsertBatchResult:
        """Stores several keyframes atomically: all or none (at most 1024)."""
        request = pb.InsertBatchRequest(
            keyframes=[_convert.keyframe_to_proto(k, self.robot_id, self.session_id) for k in keyframes]
        )
        return _convert.insert_batch_result_from_proto(self._call("InsertBatch", request, timeout))

    def erase(
        self,
        keyframe_ids: Iterable[int],
        *,
        robot_id: Optional[str] = None,
        session_id: Optional[str] = None,
        timeout: Optional[float] = None,
    ) -> EraseResult:
        """Removes keyframes by id (ids not stored are ignored)."""
        robot, session = self._ids(robot_id, session_id)
        request = pb.EraseRequest(robot_id=robot, session_id=session, keyframe_ids=[int(i) for i in keyframe_ids])
        return _convert.erase_result_from_proto(self._call("Erase", request, timeout))

    def reset_map(
        self, map_id: int, *, robot_id: Optional[str] = None, session_id: Optional[str] = None,
        timeout: Optional[float] = None,
    ) -> EraseResult:
        """Removes every keyframe of one map."""
        robot, session = self._ids(robot_id, session_id)
        request = pb.ResetMapRequest(robot_id=robot, session_id=session, map_id=map_id)
        return _convert.erase_result_from_proto(self._call("ResetMap", request, timeout))

    def reset_session(
        self, *, robot_id: Optional[str] = None, session_id: Optional[str] = None, timeout: Optional[float] = None
    ) -> EraseResult:
        """Removes every keyframe of one session (after a full reset)."""
        robot, session = self._ids(robot_id, session_id)
        request = pb.ResetSessionRequest(robot_id=robot, session_id=session)
        return _convert.erase_result_from_proto(self._call("ResetSession", request, timeout))

    def update_poses(
        self, updates: Iterable[PoseUpdate], *, robot_id: Optional[str] = None, session_id: Optional[str] = None,
        timeout: Optional[float] = None,
    ) -> UpdatePosesResult:
        """Moves keyframes to corrected poses (and maps), atomically."""
        robot, session = self._ids(robot_id, session_id)
        request = pb.UpdatePosesRequest(robot_id=robot, session_id=session)
        for u in updates:
            message = request.updates.add(keyframe_id=u.keyframe_id, pose=_convert.pose_to_proto(u.pose))
            if u.map_id is not None:
                message.map_id = u.map_id
        return _convert.update_poses_result_from_proto(self._call("UpdatePoses", request, timeout))

    def report_verification(
        self,
        keyframe_id: int,
        candidate: Union[Candidate, KeyframeRef],
        kind: VerificationKind,
        accepted: bool,
        *,
        relative: Optional[Pose] = None,
        scale: float = 1.0,
        score: Optional[float] = None,
        inliers: int = 0,
        robot_id: Optional[str] = None,
        session_id: Optional[str] = None,
        timeout: Optional[float] = None,
    ) -> VerificationResult:
        """Reports the geometric verdict on a candidate the server proposed
        for the query keyframe ``keyframe_id``. ``relative``: T_qc when
        accepted; ``score`` defaults to the Candidate's."""
        robot, session = self._ids(robot_id, session_id)
        request = pb.ReportVerificationRequest(
            robot_id=robot,
            session_id=session,
            keyframe_id=keyframe_id,
            candidate=pb.KeyframeRef(
                robot_id=candidate.robot_id, session_id=candidate.session_id, keyframe_id=candidate.keyframe_id
            ),
            kind=int(kind),
            outcome=int(VerificationOutcome.ACCEPTED if accepted else VerificationOutcome.REJECTED),
            inliers=inliers,
        )
        if relative is not None:
            request.relative.pose.CopyFrom(_convert.pose_to_proto(relative))
            request.relative.scale = scale
        if score is None and isinstance(candidate, Candidate):
            score = candidate.score
        if score is not None:
            request.score = score
        return _convert.verification_result_from_proto(self._call("ReportVerification", request, timeout))

    # --- reads ---------------------------------------------------------------

    def _query_request(self, request: Optional[Query], fields: dict) -> pb.QueryRequest:
        if request is None:
            request = Query(**fields)
        elif fields:
            raise TypeError("query: give a Query or keyword fields, not both")
        return _convert.query_to_proto(request, self.robot_id, self.session_id)

    def query(self, request: Optional[Query] = None, *, timeout: Optional[float] = None, **fields) -> QueryResult:
        """Ranks stored keyframes against a query and waits for the answer.
        Takes a :class:`Query` or its fields as keywords
        (``client.query(features=d, frame_id=7, scope=Scope.ALL_MAPS)``).
        The result's ``status`` is SUPERSEDED if a newer query of the same
        robot, session and kind took this one's place on the server."""
        return _convert.query_result_from_proto(self._call("Query", self._query_request(request, fields), timeout))

    def submit_query(self, request: Optional[Query] = None, **fields) -> Ticket:
        """Latest wins: queues the query in its kind's lane and returns at
        once. The lane sends one query at a time; a query submitted while
        another waits replaces it (that ticket resolves SUPERSEDED). Wait
        with ``ticket.outcome(timeout)``, or pick up the newest answer with
        :meth:`latest`."""
        message = self._query_request(request, fields)
        return self._lanes.submit(QueryKind(message.kind or QueryKind.LOOP_CLOSURE), message)

    def latest(self, kind: QueryKind = QueryKind.LOOP_CLOSURE) -> Optional[QueryOutcome]:
        """The newest outcome of ``kind`` that went to the server, handed out
        once (None if there is none new since the last call)."""
        return self._lanes.latest(kind)

    def stats(self, *, timeout: Optional[float] = None) -> Stats:
        """What the store holds: keyframes, per-map counts, descriptor length, verdicts."""
        return _convert.stats_from_proto(self._call("Stats", pb.StatsRequest(), timeout))


def connect(target: str = "127.0.0.1:50051", **options) -> Client:
    """``Client(target, **options)``: see :class:`Client` for the options
    (robot_id, session_id, tls_ca, tls_cert, tls_key, tls_server_name, token,
    timeout, ...)."""
    return Client(target, **options)


__all__ = ["Client", "connect"]
