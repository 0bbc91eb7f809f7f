"""The exceptions of humem_client: every failed RPC is raised as a
:class:`HumemError` (or the subclass for its gRPC status code) carrying the
code, the server's message and its ``retry-after-ms`` hint, if any."""

from __future__ import annotations

from typing import Optional

import grpc


class HumemError(Exception):
    """An RPC to the HuMem server failed.

    ``code`` is the gRPC status code (``grpc.StatusCode``), ``message`` the
    server's text (for INVALID_ARGUMENT it names the offending field, e.g.
    ``keyframe.features.global_descriptor[3]: not a finite number``),
    ``method`` the RPC, and ``retry_after_ms`` the server's hint when it
    pushes back (RESOURCE_EXHAUSTED), else None.
    """

    def __init__(self, code: grpc.StatusCode, message: str, method: str = "", retry_after_ms: Optional[int] = None):
        self.code = code
        self.message = message
        self.method = method
        self.retry_after_ms = retry_after_ms
        prefix = f"{method}: " if method else ""
        super().__init__(f"{prefix}{code.name}: {message}")


class InvalidArgumentError(HumemError):
    """INVALID_ARGUMENT: the request is malformed; nothing was changed."""


class NotFoundError(HumemError):
    """NOT_FOUND: e.g. a query for a keyframe that is not stored."""


class FailedPreconditionError(HumemError):
    """FAILED_PRECONDITION: e.g. min_log_sequence on a server not in cluster mode."""


class UnauthenticatedError(HumemError):
    """UNAUTHENTICATED: no valid token or client certificate."""


class PermissionDeniedError(HumemError):
    """PERMISSION_DENIED: the credential may not act for that robot."""


class ResourceExhaustedError(HumemError):
    """RESOURCE_EXHAUSTED: a queue or quota is full; see ``retry_after_ms``."""


class UnavailableError(HumemError):
    """UNAVAILABLE: the server cannot be reached (or a TLS handshake failed)."""


class DeadlineExceededError(HumemError):
    """DEADLINE_EXCEEDED: no answer within the call's timeout."""


class CancelledError(HumemError):
    """CANCELLED: the call was cancelled, e.g. by Client.close()."""


_BY_CODE = {
    grpc.StatusCode.INVALID_ARGUMENT: InvalidArgumentError,
    grpc.StatusCode.NOT_FOUND: NotFoundError,
    grpc.StatusCode.FAILED_PRECONDITION: FailedPreconditionError,
    grpc.StatusCode.UNAUTHENTICATED: UnauthenticatedError,
    grpc.StatusCode.PERMISSION_DENIED: PermissionDeniedError,
    grpc.StatusCode.RESOURCE_EXHAUSTED: ResourceExhaustedError,
    grpc.StatusCode.UNAVAILABLE: UnavailableError,
    grpc.StatusCode.DEADLINE_EXCEEDED: DeadlineExceededError,
    grpc.StatusCode.CANCELLED: CancelledError,
}


def error_for(code: grpc.StatusCode, message: str, method: str = "", retry_after_ms: Optional[int] = None) -> HumemError:
    """The HumemError subclass for ``code``."""
    return _BY_CODE.get(code, HumemError)(code, message, method, retry_after_ms)


def from_rpc_error(error: grpc.RpcError, method: str) -> HumemError:
    """Wraps a failed call (a ``grpc.RpcError`` that is also a ``grpc.Call``)."""
    code = error.code() if hasattr(error, "code") else grpc.StatusCode.UNKNOWN
    message = error.details() if hasattr(error, "details") else str(error)
    retry_after = None
    try:
        for key, value in error.trailing_metadata() or ():
            if key == "retry-after-ms":
                retry_after = min(int(value), 60_000)  # a hint over a minute is not believed
    except (AttributeError, TypeError, ValueError):
        pass
    return error_for(code or grpc.StatusCode.UNKNOWN, message or "", method, retry_after)
