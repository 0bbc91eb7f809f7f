"""Latest-wins queries against the real server, made deterministic by
freezing it (SIGSTOP) as the C++ client's test does: one query of a kind
in flight, a burst of newer ones leaves only the newest pending and
supersedes the rest at once, the other kind is untouched; after the thaw
the in-flight and the newest are answered, and latest() hands out the
newest once. close() cancels what is pending and in flight."""

import threading
import unittest

import grpc

import humem_client as hc
from humem_server import HumemServer, near, random_descriptor, wait_until

FAR = 100_000


class LatestWinsTest(unittest.TestCase):
    def setUp(self):
        self.server = HumemServer()
        self.addCleanup(self.server.stop)
        self.published = []
        self.lock = threading.Lock()

        def on_result(outcome):
            with self.lock:
                self.published.append(outcome)

        self.client = hc.connect(self.server.url, robot_id="car-1", session_id="s", on_query_result=on_result)
        self.addCleanup(self.client.close)
        self.client.insert_batch(
            hc.Keyframe(keyframe_id=i, frame_id=100 * i, features=random_descriptor(i)) for i in range(1, 9)
        )

    def query(self, i: int, kind=hc.QueryKind.LOOP_CLOSURE) -> hc.Query:
        return hc.Query(features=near(random_descriptor(i), i), frame_id=FAR, kind=kind)

    def test_a_burst_keeps_the_running_and_the_newest_query_and_supersedes_the_rest(self):
        self.server.freeze()
        first = self.client.submit_query(self.query(1))
        self.assertTrue(wait_until(lambda: first.state == hc.TicketState.IN_FLIGHT), first)
        burst = [self.client.submit_query(self.query(i)) for i in range(2, 7)]
        reloc = self.client.submit_query(self.query(7, hc.QueryKind.RELOCALISATION))

        # Every burst ticket but the newest resolved as superseded at once.
        for ticket in burst[:-1]:
            outcome = ticket.outcome(timeout=0)
            self.assertEqual(outcome.state, hc.TicketState.SUPERSEDED, ticket)
            self.assertIsNone(outcome.error)
            self.assertEqual(outcome.candidates, ())
        self.assertEqual(burst[-1].state, hc.TicketState.QUEUED)
        self.assertEqual(first.state, hc.TicketState.IN_FLIGHT)
        with self.assertRaises(TimeoutError):
            first.outcome(timeout=0.05)
        # The other kind has its own lane.
        self.assertFalse(reloc.done())
        self.assertIsNone(self.client.latest(hc.QueryKind.LOOP_CLOSURE))

        self.server.thaw()
        running = first.outcome(timeout=10)
        self.assertEqual(running.state, hc.TicketState.ANSWERED, running.error)
        self.assertEqual(running.candidates[0].keyframe_id, 1)
        newest = burst[-1].outcome(timeout=10)
        self.assertEqual(newest.state, hc.TicketState.ANSWERED, newest.error)
        self.assertEqual(newest.candidates[0].keyframe_id, 6)
        self.assertEqual(newest.result.status, hc.QueryStatus.ANSWERED)
        relocalised = reloc.outcome(timeout=10)
        self.assertEqual(relocalised.state, hc.TicketState.ANSWERED, relocalised.error)
        self.assertEqual(relocalised.candidates[0].keyframe_id, 7)

        # latest(): the newest loop-closure answer, once.
        latest = self.client.latest(hc.QueryKind.LOOP_CLOSURE)
        self.assertEqual(latest.ticket, burst[-1].id)
        self.assertIsNone(self.client.latest(hc.QueryKind.LOOP_CLOSURE))
        self.assertEqual(self.client.latest(hc.QueryKind.RELOCALISATION).ticket, reloc.id)

        # The callback saw every ticket resolve exactly once.
        with self.lock:
            seen = [o.ticket for o in self.published]
            superseded = sum(o.state == hc.TicketState.SUPERSEDED for o in self.published)
        self.assertEqual(sorted(seen), sorted({t.id for t in [first, reloc, *burst]}))
        self.assertEqual(superseded, len(burst) - 1)

    def test_close_cancels_the_pending_and_the_running_query(self):
        self.server.freeze()
        running = self.client.submit_query(self.query(1))
        self.assertTrue(wait_until(lambda: running.state == hc.TicketState.IN_FLIGHT), running)
        pending = self.client.submit_query(self.query(2))
        self.client.close()
        for ticket in (running, pending):
            outcome = ticket.outcome(timeout=5)
            self.assertEqual(outcome.state, hc.TicketState.FAILED)
            self.assertIsInstance(outcome.error, hc.CancelledError)
            self.assertEqual(outcome.error.code, grpc.StatusCode.CANCELLED)
        # Submitting to a closed client resolves at once.
        late = self.client.submit_query(self.query(3))
        self.assertEqual(late.outcome(timeout=0).state, hc.TicketState.FAILED)
        self.server.thaw()

    def test_a_failed_query_resolves_with_its_error(self):
        ticket = self.client.submit_query(keyframe_id=12345)  # not stored
        outcome = ticket.outcome(timeout=10)
        self.assertEqual(outcome.state, hc.TicketState.FAILED)
        self.assertIsInstance(outcome.error, hc.NotFoundError)
        self.assertEqual(self.client.latest().ticket, ticket.id)


if __name__ == "__main__":
    unittest.main()
