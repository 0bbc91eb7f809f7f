"""Against the real server (perception off, precomputed descriptors):
insert, query finding the inserted keyframe, scopes, erase, the other
writes, stats, and bad requests surfacing as typed errors with the gRPC
code and the server's message naming the field."""

import socket
import unittest

import grpc
import numpy as np

import humem_client as hc
from humem_server import HumemServer, near, random_descriptor

FAR = 100_000  # a frame id far beyond the stored ones (the minimum frame gap is 100)


def keyframe(i: int, map_id: int = 0, **kw) -> hc.Keyframe:
    pose = hc.Pose(translation=[i, 0.5 * i, 0], rotation=[np.cos(i / 10), 0, 0, np.sin(i / 10)])
    return hc.Keyframe(keyframe_id=i, frame_id=100 * i, map_id=map_id, pose=pose, timestamp=0.1 * i,
                       features=random_descriptor(i), **kw)


class ClientTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.server = HumemServer()
        cls.addClassCleanup(cls.server.stop)
        cls.client = hc.connect(cls.server.url, robot_id="car-1", session_id="s1")
        cls.addClassCleanup(cls.client.close)

    def setUp(self):
        self.client.reset_session()
        self.client.reset_session(session_id="s2")

    def test_insert_then_query_finds_the_keyframe(self):
        first = self.client.insert(keyframe(1))
        self.assertFalse(first.replaced)
        self.assertEqual(first.store_keyframes, 1)
        self.assertIsNone(first.features)  # features were sent, not computed
        self.assertTrue(self.client.insert(keyframe(1)).replaced)
        batch = self.client.insert_batch([keyframe(i) for i in range(2, 9)])
        self.assertEqual((batch.replaced, batch.store_keyframes), (0, 8))

        result = self.client.query(features=near(random_descriptor(5), 5), frame_id=FAR, threshold=0.0)
        self.assertIsInstance(result, hc.QueryResult)
        self.assertEqual(result.status, hc.QueryStatus.ANSWERED)
        self.assertEqual(result.eligible_keyframes, 8)
        best = result.candidates[0]
        self.assertEqual((best.robot_id, best.session_id, best.keyframe_id, best.frame_id), ("car-1", "s1", 5, 500))
        self.assertAlmostEqual(best.timestamp, 0.5)
        self.assertGreater(best.score, result.candidates[1].score)
        self.assertGreater(best.evidence.descriptor_cosine, 0.9)
        self.assertIsInstance(best.evidence, hc.Evidence)
        # Poses come back as numpy arrays, as stored.
        np.testing.assert_allclose(best.pose.translation, [5, 2.5, 0])
        np.testing.assert_allclose(best.pose.matrix(), keyframe(5).pose.matrix(), atol=1e-9)
        self.assertEqual(result.threshold, 0.0)
        self.assertIn("scal", result.timings)

        # The default threshold (raw rule here) keeps only the revisit.
        self.assertEqual(self.client.query(features=near(random_descriptor(5), 5), frame_id=FAR).keyframe_ids(), [5])

    def test_query_by_stored_keyframe_with_scopes_and_layers(self):
        self.client.insert_batch([keyframe(i, map_id=0) for i in range(1, 5)])
        # The same place seen again in another map of another session.
        other = keyframe(2, map_id=7, session_id="s2")
        other.features = near(random_descriptor(2), 2)
        self.client.insert(other)

        def ids(**kw):
            r = self.client.query(keyframe_id=2, threshold=0.0, top_n=10, layers=hc.Layers.SCAL, **kw)
            return {(c.session_id, c.keyframe_id) for c in r.candidates}

        # Stored keyframe 2 of s1 (map 0) is the query; s2's keyframe is in map 7.
        self.assertEqual(ids(map_id=0, scope=hc.Scope.OTHER_MAPS), {("s2", 2)})
        self.assertEqual(ids(map_id=0, scope=hc.Scope.SAME_MAP), {("s1", 1), ("s1", 3), ("s1", 4)})
        self.assertEqual(ids(map_id=0, scope=hc.Scope.ALL_MAPS), {("s1", 1), ("s1", 3), ("s1", 4), ("s2", 2)})
        listed = ids(scope=hc.Scope.LISTED, maps=[hc.MapRef(robot_id="car-1", map_id=7, session_id="s2")])
        self.assertEqual(listed, {("s2", 2)})

    def test_erase_removes_the_keyframe(self):
        self.client.insert_batch([keyframe(i) for i in range(1, 6)])
        query = hc.Query(features=near(random_descriptor(3), 3), frame_id=FAR, threshold=0.0)
        self.assertEqual(self.client.query(query).candidates[0].keyframe_id, 3)

        erased = self.client.erase([3, 999])
        self.assertEqual(erased.erased, 1)  # ids not stored are ignored
        self.assertNotIn(3, self.client.query(query).keyframe_ids())
        self.assertEqual(self.client.stats().keyframes, 4)
        with self.assertRaises(hc.NotFoundError) as caught:
            self.client.query(keyframe_id=3)
        self.assertEqual(caught.exception.code, grpc.StatusCode.NOT_FOUND)

    def test_other_writes_and_stats(self):
        self.client.insert_batch([keyframe(i, map_id=i % 2) for i in range(1, 7)])
        stats = self.client.stats()
        self.assertEqual((stats.keyframes, stats.descriptor_dim), (6, 64))
        self.assertEqual({(m.map_id, m.keyframes) for m in stats.maps if m.session_id == "s1"}, {(0, 3), (1, 3)})
        self.assertTrue(stats.server_version)
        self.assertIsNotNone(stats.operating_point)
        # The server keeps a neighbour graph by default, over every keyframe.
        self.assertIsNotNone(stats.neighbour_graph)
        self.assertEqual((stats.neighbour_graph.keyframes, stats.neighbour_graph.missing), (6, 0))
        self.assertFalse(stats.neighbour_graph.loaded)
        # Six keyframes: no map is large enough for a graph of its own.
        self.assertEqual((stats.neighbour_graph.map_graphs, stats.neighbour_graph.map_graph_waiting), (0, 0))

        moved = self.client.update_poses([hc.PoseUpdate(keyframe_id=2, pose=hc.Pose(translation=[9, 9, 9]), map_id=5),
                                          hc.PoseUpdate(keyframe_id=77, pose=hc.Pose())])
        self.assertEqual((moved.updated, moved.missing_keyframe_ids), (1, (77,)))
        result = self.client.query(features=random_descriptor(2), frame_id=FAR, threshold=0.0)
        candidate = next(c for c in result.candidates if c.keyframe_id == 2)
        self.assertEqual(candidate.map_id, 5)
        np.testing.assert_allclose(candidate.pose.translation, [9, 9, 9])

        verdict = self.client.report_verification(4, candidate, hc.VerificationKind.LOOP, accepted=False)
        self.assertFalse(verdict.replaced)
        self.assertGreaterEqual(verdict.store_verdicts, 1)

        self.assertEqual(self.client.reset_map(1).erased, 3)  # 1, 3, 5
        self.assertEqual(self.client.reset_session().erased, 3)
        self.assertEqual(self.client.stats().keyframes, 0)

    def test_a_bad_request_raises_invalid_argument_naming_the_field(self):
        self.client.insert(keyframe(1))
        bad = keyframe(2)
        bad.features = random_descriptor(2).copy()
        bad.features[3] = np.nan
        with self.assertRaises(hc.InvalidArgumentError) as caught:
            self.client.insert(bad)
        error = caught.exception
        self.assertIsInstance(error, hc.HumemError)
        self.assertEqual(error.code, grpc.StatusCode.INVALID_ARGUMENT)
        self.assertEqual(error.method, "Insert")
        self.assertIn("keyframe.features.global_descriptor[3]: not a finite number", error.message)
        self.assertIn("INVALID_ARGUMENT", str(error))
        # ... and nothing changed.
        self.assertEqual(self.client.stats().keyframes, 1)

        # A descriptor of another length than the store's.
        with self.assertRaises(hc.InvalidArgumentError) as caught:
            self.client.insert(hc.Keyframe(keyframe_id=3, frame_id=30, features=np.ones(65)))
        self.assertIn("has 65 values but this store holds 64-value descriptors", caught.exception.message)
        # A query without a robot id.
        with self.assertRaises(hc.InvalidArgumentError) as caught:
            self.client.query(robot_id="", features=random_descriptor(1), frame_id=FAR)
        self.assertIn("robot_id", caught.exception.message)

    def test_local_mistakes_are_refused_before_sending(self):
        with self.assertRaises(ValueError):
            self.client.insert(hc.Keyframe(keyframe_id=1, frame_id=1, features=np.ones(64), image=b"\xff\xd8\xff"))
        with self.assertRaises(ValueError):
            hc.Features(global_descriptor=np.ones((2, 32)))
        with self.assertRaises(TypeError):
            self.client.query(hc.Query(frame_id=1), top_n=3)


class UnreachableTest(unittest.TestCase):
    def test_a_server_that_is_not_there_is_unavailable(self):
        with socket.socket() as s:  # a free port nobody listens on
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        with hc.connect(f"127.0.0.1:{port}", robot_id="r", timeout=5) as client:
            with self.assertRaises(hc.UnavailableError) as caught:
                client.stats()
            self.assertEqual(caught.exception.code, grpc.StatusCode.UNAVAILABLE)
            with self.assertRaises(hc.UnavailableError):
                client.wait_ready(timeout=0.2)


if __name__ == "__main__":
    unittest.main()
