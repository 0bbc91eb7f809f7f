"""Latest-wins queries, as the C++ client (client-cpp) does them.

Per query kind (loop closure, relocalisation) a lane keeps at most one query
in flight and one pending, and sends them from its own thread.
Submitting while a query is pending replaces it: the replaced ticket
resolves at once as SUPERSEDED (it was never sent). When the query in
flight is answered, the pending one is sent. So in a burst t1 ... tn of one
kind, t1 (already in flight) and tn are answered and t2 ... tn-1 are
superseded; the two kinds never displace each other. A query the server
itself superseded (another client with the same robot, session and kind)
resolves as SUPERSEDED_BY_SERVER.

Threads sleep on condition variables when idle (no polling); nothing here
uses asyncio.
"""

from __future__ import annotations

import enum
import itertools
import logging
import threading
import time
from dataclasses import dataclass
from typing import Callable, Dict, Optional, Tuple

import grpc

from . import _convert
from .errors import HumemError, error_for, from_rpc_error
from .proto import humem_pb2 as pb
from .types import Candidate, QueryKind, QueryResult, QueryStatus

log = logging.getLogger("humem_client")


class TicketState(enum.Enum):
    """Where a submitted query is."""

    QUEUED = "queued"  # pending in its lane, not sent yet
    IN_FLIGHT = "in_flight"  # sent, waiting for the server
    ANSWERED = "answered"  # the server ranked it: outcome.result holds the answer
    SUPERSEDED = "superseded"  # a newer query of its kind replaced it before it was sent
    SUPERSEDED_BY_SERVER = "superseded_by_server"  # the server answered QUERY_STATUS_SUPERSEDED
    FAILED = "failed"  # outcome.error holds why (the RPC's error, or CANCELLED by close())

    @property
    def resolved(self) -> bool:
        return self not in (TicketState.QUEUED, TicketState.IN_FLIGHT)


@dataclass(frozen=True)
class QueryOutcome:
    """How a submitted query ended."""

    ticket: int
    kind: QueryKind
    state: TicketState
    result: Optional[QueryResult] = None  # ANSWERED and SUPERSEDED_BY_SERVER
    error: Optional[HumemError] = None  # FAILED
    round_trip_seconds: float = 0.0  # time on the wire, when sent

    @property
    def candidates(self) -> Tuple[Candidate, ...]:
        """The answer's candidates (empty unless ANSWERED)."""
        return self.result.candidates if self.result is not None and self.state == TicketState.ANSWERED else ()


class Ticket:
    """A submitted query: its id (increasing in submission order), its kind,
    its current ``state``, and :meth:`outcome` to wait for how it ended."""

    def __init__(self, ticket_id: int, kind: QueryKind):
        self.id = ticket_id
        self.kind = kind
        self._cond = threading.Condition()
        self._state = TicketState.QUEUED
        self._outcome: Optional[QueryOutcome] = None

    @property
    def state(self) -> TicketState:
        with self._cond:
            return self._state

    def done(self) -> bool:
        return self.state.resolved

    def outcome(self, timeout: Optional[float] = None) -> QueryOutcome:
        """Blocks until the query is resolved (at most ``timeout`` seconds;
        None waits for good) and returns its outcome; raises TimeoutError
        if it is still queued or in flight then."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._outcome is not None, timeout):
                raise TimeoutError(f"query ticket {self.id} is still {self._state.value} after {timeout} s")
            return self._outcome

    def _set(self, state: TicketState, outcome: Optional[QueryOutcome] = None) -> None:
        with self._cond:
            self._state = state
            if outcome is not None:
                self._outcome = outcome
                self._cond.notify_all()

    def __repr__(self) -> str:
        return f"Ticket({self.id}, {self.kind.name}, {self.state.value})"


# Sends one query: (request, timeout in seconds) -> a grpc future.
Invoke = Callable[[pb.QueryRequest, float], "grpc.Future"]
OnResult = Callable[[QueryOutcome], None]


class _Lane:
    """One kind's slot (one in flight, one pending) and its sending thread."""

    def __init__(self, kind: QueryKind, lanes: "QueryLanes"):
        self.kind = kind
        self._lanes = lanes
        self._cond = threading.Condition()
        self._pending: Optional[Tuple[Ticket, pb.QueryRequest]] = None
        self._call = None  # the grpc future in flight
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=f"humem-query-{kind.name.lower()}", daemon=True)
        self._thread.start()

    def submit(self, request: pb.QueryRequest) -> Ticket:
        displaced = None
        with self._cond:
            ticket = Ticket(self._lanes._next_ticket(), self.kind)
            closed = self._closed
            if not closed:
                displaced = self._pending
                self._pending = (ticket, request)
                self._cond.notify_all()
        if closed:
            self._lanes._publish(self._unsent(ticket, "the client is closed"), ticket, from_server=False)
        elif displaced is not None:
            old = displaced[0]
            self._lanes._publish(QueryOutcome(old.id, self.kind, TicketState.SUPERSEDED), old, from_server=False)
        return ticket

    def _unsent(self, ticket: Ticket, why: str) -> QueryOutcome:
        error = error_for(grpc.StatusCode.CANCELLED, why, "Query")
        return QueryOutcome(ticket.id, self.kind, TicketState.FAILED, error=error)

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._closed or self._pending is not None)
                if self._closed:
                    return
                ticket, request = self._pending
                self._pending = None
                ticket._set(TicketState.IN_FLIGHT)
                sent = time.monotonic()
                # Started under the lock, so close() always sees it to cancel.
                call = self._call = self._lanes._invoke(request, self._lanes.query_timeout)
            outcome = self._wait(ticket, call, sent)
            with self._cond:
                self._call = None
            self._lanes._publish(outcome, ticket, from_server=True)

    def _wait(self, ticket: Ticket, call, sent: float) -> QueryOutcome:
        try:
            response = call.result()
        except grpc.FutureCancelledError:
            return self._unsent(ticket, "the client closed while the query was in flight")
        except grpc.RpcError as e:
            return QueryOutcome(
                ticket.id, self.kind, TicketState.FAILED, error=from_rpc_error(e, "Query"),
                round_trip_seconds=time.monotonic() - sent,
            )
        result = _convert.query_result_from_proto(response)
        state = TicketState.SUPERSEDED_BY_SERVER if result.status == QueryStatus.SUPERSEDED else TicketState.ANSWERED
        return QueryOutcome(ticket.id, self.kind, state, result=result, round_trip_seconds=time.monotonic() - sent)

    def close(self) -> None:
        with self._cond:
            self._closed = True
            left, self._pending = self._pending, None
            call = self._call
            self._cond.notify_all()
        if call is not None:
            call.cancel()
        if left is not None:
            self._lanes._publish(self._unsent(left[0], "the client closed before the query was sent"), left[0], False)
        if self._thread is not threading.current_thread():
            self._thread.join()


class QueryLanes:
    """The latest-wins lanes of one client (started on first use)."""

    def __init__(self, invoke: Invoke, query_timeout: float, on_result: Optional[OnResult] = None):
        self._invoke = invoke
        self.query_timeout = query_timeout
        self._on_result = on_result
        self._lock = threading.Lock()
        self._ids = itertools.count(1)
        self._lanes: Dict[QueryKind, _Lane] = {}
        self._latest: Dict[QueryKind, QueryOutcome] = {}
        self._latest_seen: Dict[QueryKind, int] = {}
        self._closed = False

    def _next_ticket(self) -> int:
        with self._lock:
            return next(self._ids)

    def submit(self, kind: QueryKind, request: pb.QueryRequest) -> Ticket:
        with self._lock:
            lane = self._lanes.get(kind)
            if lane is None:
                if self._closed:
                    lane = None
                else:
                    lane = self._lanes[kind] = _Lane(kind, self)
        if lane is None:
            ticket = Ticket(self._next_ticket(), kind)
            error = error_for(grpc.StatusCode.CANCELLED, "the client is closed", "Query")
            self._publish(QueryOutcome(ticket.id, kind, TicketState.FAILED, error=error), ticket, False)
            return ticket
        return lane.submit(request)

    def latest(self, kind: QueryKind) -> Optional[QueryOutcome]:
        """Hands out, once, the newest outcome of ``kind`` that went to the server."""
        with self._lock:
            return self._latest.pop(kind, None)

    def _publish(self, outcome: QueryOutcome, ticket: Ticket, from_server: bool) -> None:
        # The callback runs before waiters wake: once Ticket.outcome()
        # returns, its callback has run and latest() can hand it out.
        if self._on_result is not None:
            try:
                self._on_result(outcome)
            except Exception:  # a callback's bug must not stop the lane
                log.exception("humem_client: on_query_result raised")
        if from_server:
            with self._lock:
                if outcome.ticket > self._latest_seen.get(outcome.kind, 0):
                    self._latest_seen[outcome.kind] = outcome.ticket
                    self._latest[outcome.kind] = outcome
        ticket._set(outcome.state, outcome)

    def close(self) -> None:
        """Resolves pending queries as CANCELLED, cancels those in flight and joins the threads."""
        with self._lock:
            self._closed = True
            lanes = list(self._lanes.values())
        for lane in lanes:
            lane.close()
